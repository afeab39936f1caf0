"""Export a tracked run as TUM trajectory files, so it can be evaluated with evo.

TUM format (one pose per line): ``timestamp tx ty tz qx qy qz qw`` (seconds, metres, unit
quaternion). The platform is planar: ``tz`` is 0 and the quaternion is the rotation by the
heading about +z, ``(0, 0, sin(yaw/2), cos(yaw/2))`` (yaw CCW from +x, DESIGN.md).

Any cell of a results folder can be exported: from its per-epoch file when the spec kept
one, otherwise the cell is recomputed from the spec recorded in the folder's manifest
(the truth comes from the simulation cache) and its per-epoch file is written first.

    python -m experiments.export results/thesis --where path=square100 window=100 \\
        technique=lc+dyn weighting=huff seed=0
    evo_ape tum results/thesis/tum/<key>_truth.tum results/thesis/tum/<key>_estimate.tum -a

Rows whose estimate is not finite (e.g. the naive baseline has no heading, windows with
insufficient data) cannot be written in TUM; they are left out and counted on stderr.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd

__all__ = ["export_tum", "find_cell", "main", "write_tum"]


def write_tum(path: str | Path, t: np.ndarray, xy: np.ndarray, yaw: np.ndarray,
              z: float | np.ndarray = 0.0) -> tuple[Path, int]:
    """Write a planar trajectory as TUM; returns (path, number of rows left out as non-finite).

    t (n,) s, xy (n, 2) m, yaw (n,) rad.
    """
    t = np.asarray(t, dtype=float)
    xy = np.asarray(xy, dtype=float)
    yaw = np.asarray(yaw, dtype=float)
    n = t.shape[0]
    if xy.shape != (n, 2) or yaw.shape != (n,):
        raise ValueError(f"xy/yaw: expected shapes ({n}, 2) and ({n},), got {xy.shape}, {yaw.shape}")
    zz = np.broadcast_to(np.asarray(z, dtype=float), (n,))
    ok = np.isfinite(t) & np.isfinite(xy).all(axis=1) & np.isfinite(yaw) & np.isfinite(zz)
    arr = np.column_stack([t, xy, zz, np.zeros(n), np.zeros(n), np.sin(yaw / 2),
                           np.cos(yaw / 2)])[ok]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(path, arr, fmt="%.6f", header="timestamp tx ty tz qx qy qz qw")
    return path, int(n - ok.sum())


def _parse_where(items: list[str]) -> dict:
    out = {}
    for it in items:
        if "=" not in it:
            raise ValueError(f"--where: expected axis=value, got {it!r}")
        k, v = it.split("=", 1)
        out[k] = int(v) if k in ("window", "seed", "dyn_window") else v
    return out


def find_cell(results: str | Path, key: str | None = None, where: dict | None = None
              ) -> pd.Series:
    """The one cell of a results folder matching ``key`` or every ``where`` axis value."""
    cells = pd.read_parquet(Path(results) / "cells.parquet").drop_duplicates("key")
    if key is not None:
        sel = cells[cells["key"] == key]
    else:
        sel = cells
        for k, v in (where or {}).items():
            if k not in sel.columns:
                raise ValueError(f"where: unknown axis {k!r}")
            sel = sel[sel[k] == v]
    if len(sel) != 1:
        cols = ["key", "path", "window", "weighting", "technique", "solver", "seed"]
        raise ValueError(f"expected exactly one matching cell, found {len(sel)}"
                         + (f":\n{sel[cols].head(10).to_string(index=False)}" if len(sel) else ""))
    return sel.iloc[0]


def _epochs(results: Path, cell: pd.Series) -> pd.DataFrame:
    path = results / "epochs" / f"{cell['key']}.parquet"
    if path.exists():
        return pd.read_parquet(path)
    # recompute this one cell from the recorded spec (the truth comes from the cache)
    from collections import OrderedDict

    from experiments.spec import REPO, Spec
    from experiments.sweep import CellContext, CellStore, evaluate_cell, simulate_truth

    man = json.loads((results / "manifest.json").read_text())
    base = Path(man.get("spec_base_dir", "."))
    spec = Spec.from_dict(man["spec_raw"], source=man["spec"]["source"],
                          base_dir=base if base.is_absolute() else REPO / base)
    match = [c for c in spec.expand() if c.key == cell["key"]]
    if not match:
        raise ValueError(f"cell {cell['key']}: not in the recorded spec (files changed since?)")
    c = match[0]
    truth = simulate_truth(c.file("path"), c.path_overrides, c.file("config"), spec.sim_seed)
    ctx = CellContext(spec_seed=spec.seed, masks=spec.masks, session_s=spec.session_s,
                      want_epochs=True, memo=OrderedDict())
    res = evaluate_cell(c, truth, ctx)
    store = CellStore(results)
    store._atomic(path, lambda p: res.epochs.to_parquet(p, index=False))
    return res.epochs


def export_tum(results: str | Path, key: str | None = None, where: dict | None = None,
               out: str | Path | None = None) -> tuple[Path, Path]:
    """Write ``<key>_estimate.tum`` (CG estimate) and ``<key>_truth.tum`` for one cell.

    Returns the two paths (default folder ``<results>/tum/``).
    """
    results = Path(results)
    cell = find_cell(results, key, where)
    ep = _epochs(results, cell)
    out = Path(out) if out is not None else results / "tum"
    k = cell["key"]
    est, n_bad = write_tum(out / f"{k}_estimate.tum", ep["t"], ep[["cg_x", "cg_y"]].to_numpy(),
                           ep["yaw"].to_numpy())
    tru, _ = write_tum(out / f"{k}_truth.tum", ep["t"],
                       ep[["truth_cg_x", "truth_cg_y"]].to_numpy(), ep["truth_yaw"].to_numpy())
    if n_bad:
        print(f"export: left out {n_bad} of {len(ep)} estimate rows with non-finite position "
              "or heading", file=sys.stderr)
    return est, tru


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m experiments.export",
        description="Export one cell of a sweep as TUM trajectories (estimate and truth) for "
                    "evo. Example: python -m experiments.export results/thesis --where "
                    "path=square100 window=100 technique=lc+dyn weighting=huff seed=0")
    p.add_argument("results", help="results folder, e.g. results/thesis")
    p.add_argument("--key", help="the cell's key (see cells.parquet)")
    p.add_argument("--where", nargs="*", default=[], metavar="AXIS=VALUE",
                   help="select the cell by axis values, e.g. window=100 technique=lc seed=0")
    p.add_argument("--out", help="output folder (default <results>/tum)")
    args = p.parse_args(argv)
    try:
        est, tru = export_tum(args.results, args.key, _parse_where(args.where), args.out)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"{est}\n{tru}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
