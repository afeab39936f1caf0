"""Range localization on a recorded UWB run: ``python -m experiments.ranging DIR --out OUT``.

DIR holds one recording in the format of the Hanyang outdoor UWB dataset
(``../shared/realdata/uwb_hanyang/<LOS|NLOS>/Trajectory_A/Case_1``; see its README):

* ``A<id>.csv`` per anchor (ROS dumps): ``field.stamp`` (ns), ``field.x/y/z`` (the anchor's
  position, m), ``field.distanceFromTag`` (m); any number of anchors >= 3;
* ``trajectory.csv``: the RTK reference, ``timestamp`` (ns), ``x``, ``y``, ``z`` (m);
* optional ``LS.csv`` / ``ESKF.csv``: the dataset authors' own estimates (``timestamp``, ``x``,
  ``y``, ``z``), scored as the rows ``authors_ls`` and ``authors_eskf``.

The run: :func:`estimator.ranging.localize` with :meth:`RangingConfig.uwb_ground_tag` (physical
defaults, never fitted to a recording), once in known-height mode (the tag rides
``--tag-height`` = 1.0 m above the reference point, whose z is ground level, as the authors'
scoring states) and once solving z freely; every method is scored with the authors' metric
(:func:`authors_metric`, a re-implementation of their ``localization_error_analysis.py``,
checked against their ``RMSD_results.txt`` to 1e-9 m in the tests). Outputs in ``--out``:
``summary.csv`` (one row per method: ``method, rmse_2d_m, rmse_3d_m, max_error_2d_m,
coverage``), ``summary.md``, ``stages.csv`` (gate and filter diagnostics), figures
(trajectories against the reference, error over time, ranges before and after gating), and
``run_info.json`` (settings and code version; wall times go to the untracked
``timings.json``).

``run(directory, out)`` is the callable entry point; ``main`` only parses arguments.
"""

from __future__ import annotations

import argparse
import json
import re
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from estimator.ranging import RangeStreams, RangingConfig, RangingResult, localize

__all__ = [
    "METHODS",
    "RangeRecording",
    "authors_metric",
    "load_recording",
    "main",
    "run",
    "score",
    "scoring_window",
]

#: anchor files: ``A<id>.csv``
_ANCHOR_RE = re.compile(r"^A(\d+)\.csv$")
_ANCHOR_COLS = ("field.stamp", "field.x", "field.y", "field.z", "field.distanceFromTag")
_POSE_COLS = ("timestamp", "x", "y", "z")
#: the tag rides this far above the reference point (authors' scoring: reference z + 1)
TAG_HEIGHT_M = 1.0


# =============================================================================================
# loading
# =============================================================================================


@dataclass(frozen=True)
class RangeRecording:
    """One recorded run, times in seconds since the first reference sample.

    name; anchors (k,) ids; anchor_positions (k, 3) m; streams :class:`RangeStreams`
    (one transmitter); reference_t (m,) s and reference (m, 3) m (RTK, ground level);
    authors {name: (t (p,) s, xyz (p, 3) m)}; t0_ns the time origin (ns since the epoch).
    """

    name: str
    anchors: tuple
    anchor_positions: np.ndarray
    streams: RangeStreams
    reference_t: np.ndarray
    reference: np.ndarray
    authors: dict
    t0_ns: int


def _read_csv(path: Path, columns: tuple[str, ...]) -> pd.DataFrame:
    """A CSV with the given numeric columns; errors name the file, the column and the row."""
    if not path.is_file():
        raise FileNotFoundError(f"{path}: file not found")
    try:
        df = pd.read_csv(path, dtype=str, keep_default_na=False)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not a readable CSV ({type(exc).__name__}: {exc})") from exc
    missing = [c for c in columns if c not in df.columns]
    if missing:
        raise ValueError(f"{path}: missing column(s) {missing}; found {list(df.columns)}")
    if len(df) == 0:
        raise ValueError(f"{path}: no data rows")
    out = {}
    for c in columns:
        vals = pd.to_numeric(df[c].str.strip(), errors="coerce")
        bad = vals.isna() | ~np.isfinite(vals.to_numpy(dtype=float))
        if bad.any():
            i = int(np.argmax(bad.to_numpy()))
            raise ValueError(f"{path}: column {c!r}, data row {i + 1}: not a finite number: "
                             f"{df[c].iloc[i]!r}")
        out[c] = vals
    return pd.DataFrame(out)


def _ns(values: pd.Series) -> np.ndarray:
    """Nanosecond timestamps as int64 (integers exactly; float text such as 1.73e+18 to the
    nearest representable value, as the authors' script reads them)."""
    return np.array([int(v) if float(v).is_integer() else int(round(float(v)))
                     for v in values], dtype=np.int64)


def load_recording(directory: str | Path) -> RangeRecording:
    """Read one run (see the module docstring). Raises FileNotFoundError / ValueError naming
    the file (and column and row) for anything missing or malformed."""
    d = Path(directory)
    if not d.is_dir():
        raise FileNotFoundError(f"{d}: not a directory")
    anchor_files = sorted((p for p in d.iterdir() if _ANCHOR_RE.match(p.name)),
                          key=lambda p: int(_ANCHOR_RE.match(p.name).group(1)))
    if len(anchor_files) < 3:
        raise ValueError(f"{d}: needs >= 3 anchor files A<id>.csv, found "
                         f"{[p.name for p in anchor_files]}")
    traj = _read_csv(d / "trajectory.csv", _POSE_COLS)
    ref_ns = _ns(traj["timestamp"])
    if np.any(np.diff(ref_ns) <= 0):
        raise ValueError(f"{d / 'trajectory.csv'}: timestamps must be strictly increasing")
    t0 = int(ref_ns[0])
    channels, ids, pos = {}, [], []
    for j, p in enumerate(anchor_files):
        a = _read_csv(p, _ANCHOR_COLS)
        xyz = a[["field.x", "field.y", "field.z"]].to_numpy(dtype=float)
        if np.ptp(xyz, axis=0).max() > 0:
            raise ValueError(f"{p}: the anchor position changes within the file "
                             f"(spread {np.ptp(xyz, axis=0).max():.3g} m)")
        ns = _ns(a["field.stamp"])
        if np.any(np.diff(ns) <= 0):
            i = int(np.argmax(np.diff(ns) <= 0))
            raise ValueError(f"{p}: column 'field.stamp' must be strictly increasing; data row "
                             f"{i + 2} repeats or goes back")
        r = a["field.distanceFromTag"].to_numpy(dtype=float)
        if np.any(r < 0):
            raise ValueError(f"{p}: column 'field.distanceFromTag' has a negative range "
                             f"({r.min()!r} m)")
        channels[j] = ((ns - t0) * 1e-9, r)
        ids.append(int(_ANCHOR_RE.match(p.name).group(1)))
        pos.append(xyz[0])
    streams = RangeStreams.from_channels(channels, n_receivers=len(anchor_files))
    authors = {}
    for name, fname in (("authors_ls", "LS.csv"), ("authors_eskf", "ESKF.csv")):
        if (d / fname).exists():
            e = _read_csv(d / fname, _POSE_COLS)
            authors[name] = ((_ns(e["timestamp"]) - t0) * 1e-9,
                             e[["x", "y", "z"]].to_numpy(dtype=float))
    return RangeRecording(d.name if d.name not in ("Case_1", "") else "/".join(d.parts[-3:]),
                          tuple(ids), np.array(pos), streams, (ref_ns - t0) * 1e-9,
                          traj[["x", "y", "z"]].to_numpy(dtype=float), authors, t0)


# =============================================================================================
# the authors' metric
# =============================================================================================


def scoring_window(ref_t: np.ndarray, ref_xyz: np.ndarray, trajectory: str = "A"
                   ) -> tuple[float, float]:
    """The authors' scoring window (s): Trajectory A from the first reference sample with
    x > 49.3 and y > -5 to the first later one with x <= 12 and y > 3.4; Trajectory B from
    x < 8.6 and y < -7 to the first later x > 8.6 and y < -7 (their
    ``find_start_and_end_times``). Raises ValueError if the reference never enters it."""
    x, y = ref_xyz[:, 0], ref_xyz[:, 1]
    if trajectory == "A":
        start_ok, end_ok = (x > 49.3) & (y > -5), (x <= 12) & (y > 3.4)
    elif trajectory == "B":
        start_ok, end_ok = (x < 8.6) & (y < -7), (x > 8.6) & (y < -7)
    else:
        raise ValueError(f"trajectory: must be 'A' or 'B', got {trajectory!r}")
    if not start_ok.any():
        raise ValueError(f"reference: never enters the Trajectory {trajectory} scoring window")
    i = int(np.argmax(start_ok))
    later = np.flatnonzero(end_ok[i:])
    if later.size == 0:
        raise ValueError(f"reference: never leaves the Trajectory {trajectory} scoring window")
    return float(ref_t[i]), float(ref_t[i + later[0]])


def authors_metric(ref_t: np.ndarray, ref_xyz: np.ndarray, est_t: np.ndarray,
                   est_xyz: np.ndarray, *, trajectory: str = "A",
                   tag_height_m: float = TAG_HEIGHT_M) -> dict:
    """The dataset authors' scores (their ``localization_error_analysis.py``, re-implemented).

    Estimates with times in the scoring window (inclusive) are compared with the reference
    (rows in the window with |z| < 0.5) interpolated linearly at their times (the last
    reference sample at or before, the first after; the nearest one at the ends); the 2-D
    error uses x, y, the 3-D error also z against reference z + ``tag_height_m``. Estimates
    with a NaN coordinate are not scored (the authors' estimates have none).
    Returns rmse_2d_m, rmse_3d_m, max_error_2d_m, n (scored estimates), window (s, s), and
    the per-estimate t, err_2d, err_3d arrays.
    """
    t0, t1 = scoring_window(ref_t, ref_xyz, trajectory)
    inwin = (ref_t >= t0) & (ref_t <= t1)
    keep = inwin & (np.abs(ref_xyz[:, 2]) < 0.5)
    rt, rp = ref_t[keep], ref_xyz[keep]
    et = np.asarray(est_t, dtype=float)
    ep = np.asarray(est_xyz, dtype=float)
    sel = (et >= t0) & (et <= t1) & np.all(np.isfinite(ep), axis=1)
    et, ep = et[sel], ep[sel]
    after = np.searchsorted(rt, et, side="right")            # first reference > t
    before = after - 1
    b = np.clip(before, 0, rt.size - 1)
    a = np.clip(after, 0, rt.size - 1)
    span = rt[a] - rt[b]
    w = np.where((before >= 0) & (after < rt.size) & (span > 0),
                 (et - rt[b]) / np.where(span > 0, span, 1.0), 0.0)
    w = np.where(before < 0, 1.0, w)                          # before the first: the first
    ref = rp[b] + w[:, None] * (rp[a] - rp[b])
    ref = np.where((before < 0)[:, None], rp[a], ref)
    e2 = np.hypot(ref[:, 0] - ep[:, 0], ref[:, 1] - ep[:, 1])
    e3 = np.sqrt(e2 ** 2 + (ref[:, 2] + tag_height_m - ep[:, 2]) ** 2)
    n = int(e2.size)
    return {
        "rmse_2d_m": float(np.sqrt(np.mean(e2 ** 2))) if n else float("nan"),
        "rmse_3d_m": float(np.sqrt(np.mean(e3 ** 2))) if n else float("nan"),
        "max_error_2d_m": float(np.max(e2)) if n else float("nan"),
        "n": n, "window": (t0, t1), "t": et, "err_2d": e2, "err_3d": e3,
    }
