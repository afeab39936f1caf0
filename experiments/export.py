"""Export a tracked run as TUM trajectory files, so it can be evaluated with evo.

TUM format (one pose per line): ``timestamp tx ty tz qx qy qz qw`` (seconds, metres, unit
quaternion). The platform is planar: ``tz`` is 0 and the quaternion is the rotation by the
heading about +z, ``(0, 0, sin(yaw/2), cos(yaw/2))`` (yaw CCW from +x, DESIGN.md).

The cell is chosen by ``--key`` or ``--where`` terms (:mod:`experiments.selection`; an
ambiguous selection names the axes that differ and the terms to add). Any cell of a results
folder can be exported: from its per-epoch file when the spec kept
one, otherwise the cell is recomputed from the spec recorded in the folder's manifest
(the truth comes from the simulation cache) and its per-epoch file is written first.

    python -m experiments.export results/thesis --where path=square100 window=100 \\
        technique=lc+dyn weighting=huff dyn_growth=refill 'noise_overrides={}' seed=0
    evo_ape tum results/thesis/tum/<key>_truth.tum results/thesis/tum/<key>_estimate.tum -a

Rows whose estimate is not finite (e.g. the naive baseline has no heading, windows with
insufficient data) cannot be written in TUM; they are left out and counted on stderr.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from experiments.deferred import deferred_attributes
from experiments.selection import find_cell, parse_where

if TYPE_CHECKING:
    import pandas as pd

#: imported where used, not here, so that --help and argument errors answer before
#: pandas / numba / scipy / matplotlib load; still importable from this module
__getattr__ = deferred_attributes(__name__, {
    "pd": ("pandas", None),
})

__all__ = ["export_tum", "find_cell", "main", "parse_where", "write_tum"]


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
        raise ValueError(f"xy/yaw: expected shapes ({n}, 2) and ({n},), got {xy.shape}, "
                         f"{yaw.shape}")
    zz = np.broadcast_to(np.asarray(z, dtype=float), (n,))
    ok = np.isfinite(t) & np.isfinite(xy).all(axis=1) & np.isfinite(yaw) & np.isfinite(zz)
    arr = np.column_stack([t, xy, zz, np.zeros(n), np.zeros(n), np.sin(yaw / 2),
                           np.cos(yaw / 2)])[ok]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(path, arr, fmt="%.6f", header="timestamp tx ty tz qx qy qz qw")
    return path, int(n - ok.sum())


def recorded_cell(results: Path, key: str):
    """(spec, cell) of ``key`` as the results folder's manifest recorded the spec: the
    cell's resolved files (``cell.file("config")`` ...), also for models named by path,
    whose label is their ``name``. ValueError when the cell is not in that spec."""
    from experiments.spec import REPO, Spec

    man = json.loads((results / "manifest.json").read_text())
    base = Path(man.get("spec_base_dir", "."))
    spec = Spec.from_dict(man["spec_raw"], source=man["spec"]["source"],
                          base_dir=base if base.is_absolute() else REPO / base)
    match = [c for c in spec.expand() if c.key == key]
    if not match:
        raise ValueError(f"cell {key}: not in the recorded spec (files changed since?)")
    return spec, match[0]


def _epochs(results: Path, cell: pd.Series) -> pd.DataFrame:
    import pandas as pd

    path = results / "epochs" / f"{cell['key']}.parquet"
    if path.exists():
        return pd.read_parquet(path)
    # recompute this one cell from the recorded spec (the truth comes from the cache)
    from collections import OrderedDict

    from experiments.sweep import CellContext, CellStore, evaluate_cell, simulate_truth

    spec, c = recorded_cell(results, str(cell["key"]))
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


#: The ``--help`` examples: each selects exactly one cell of the thesis preset's run
#: (tests/test_export.py checks them against a sweep's cell table).
EPILOG = """examples:
  python -m experiments.sweep --preset quick --out /tmp/quick
  python -m experiments.export /tmp/quick --where window=10 technique=lc seed=0
  python -m experiments.export results/thesis --where path=square100 window=100 \\
      technique=lc+dyn weighting=huff dyn_growth=refill 'noise_overrides={}' seed=0 \\
      --out /tmp/tum"""


def main(argv: list[str] | None = None) -> int:
    from experiments.cli import ArgumentParser

    p = ArgumentParser(
        prog="python -m experiments.export",
        description="Export one cell of a sweep as TUM trajectories (estimate and truth) for "
                    "evo.",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("results", help="results folder, e.g. results/thesis")
    p.add_argument("--key", help="the cell's key (see cells.parquet)")
    p.add_argument("--where", nargs="*", default=[], metavar="AXIS=VALUE",
                   help="select the cell by axis values (the columns of cells.parquet), e.g. "
                        "window=100 technique=lc seed=0; if several cells match, the error "
                        "lists the axes that differ and the terms to add")
    p.add_argument("--out", help="output folder (default <results>/tum)")
    args = p.parse_args(argv)
    try:
        est, tru = export_tum(args.results, args.key, parse_where(args.where), args.out)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"{est}\n{tru}")
    return 0


if __name__ == "__main__":
    from experiments.cli import run as run_cli

    run_cli(main)
