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
scoring states) and once solving z freely (the per-epoch fixes and their Kalman filter held in
the preset's plausible interval, the anchors' heights +/- 2 m, with the interval's middle as
the known-height fallback where the geometry cannot resolve z); every method is scored with
the authors' metric (:func:`estimator.range_scoring.authors_metric`, re-exported here, a
re-implementation of their ``localization_error_analysis.py``, checked against their
``RMSD_results.txt`` to 1e-9 m in the tests). Outputs: one folder ``OUT/<label>/`` per
recording DIR (``<label>``: the last three parts of DIR joined by ``_`` when DIR is a
``Case_*`` folder, e.g. ``LOS_Trajectory_A_Case_1``, else DIR's name) with ``summary.csv``
(one row per method: ``method, rmse_2d_m, rmse_3d_m, max_error_2d_m, coverage``),
``summary.md``, ``stages.csv`` (fixes before/after the gates), ``gates.csv`` (spikes and the
gates, judged against the reference), ``estimates.csv.gz`` (every method at the epochs),
figures (trajectories against the reference, error over time, ranges before and after
gating), and ``run_info.json`` (settings and code version); and, for all recordings together,
``OUT/summary.md`` and the untracked wall times ``OUT/timings.json``.

``run(directory, out)`` is the callable entry point; ``main`` only parses arguments.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from estimator import range_scoring
from estimator.range_scoring import (  # re-exported: the authors' metric lives in the core
    TAG_HEIGHT_M,
    authors_metric,
    epoch_coverage,
    scoring_window,
)
from experiments.deferred import deferred_attributes
from experiments.markdown import markdown_table
from experiments.provenance import git_describe

if TYPE_CHECKING:
    import pandas as pd

    from estimator.ranging import RangeStreams, RangingConfig, RangingResult

#: imported where used, not here, so that --help and argument errors answer before
#: pandas / numba / scipy / matplotlib load; still importable from this module
__getattr__ = deferred_attributes(__name__, {
    "pd": ("pandas", None),
    "RangeStreams": ("estimator.ranging", "RangeStreams"),
    "RangingConfig": ("estimator.ranging", "RangingConfig"),
    "RangingResult": ("estimator.ranging", "RangingResult"),
    "localize": ("estimator.ranging", "localize"),
})

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


#: Largest coordinate or range accepted from a file, m (the estimators' own bound,
#: estimator.ranging): larger values are not metres of a UWB run.
_MAX_ABS_M = 1e8
#: Time-stamp columns (checked by _ns instead).
_STAMP_COLS = ("field.stamp", "timestamp")


def _read_csv(path: Path, columns: tuple[str, ...]) -> pd.DataFrame:
    """A CSV with the given numeric columns; errors name the file, the column and the row."""
    import pandas as pd

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
        big = ~bad & (vals.abs() > _MAX_ABS_M) & (c not in _STAMP_COLS)
        if big.any():
            i = int(np.argmax(big.to_numpy()))
            raise ValueError(f"{path}: column {c!r}, data row {i + 1}: |value| "
                             f"{abs(float(vals.iloc[i])):.6g} m exceeds {_MAX_ABS_M:g} m")
        out[c] = vals
    return pd.DataFrame(out)


#: Latest plausible time stamp, ns since 1970 (2100-01-01): larger ones are not nanosecond
#: stamps (and past 2**63 do not fit the int64 times at all).
_MAX_STAMP_NS = 4_102_444_800 * 10**9


def _ns(values: pd.Series, path: Path, column: str) -> np.ndarray:
    """Nanosecond timestamps as int64 (integers exactly; float text such as 1.73e+18 to the
    nearest representable value, as the authors' script reads them). A stamp before 1970 or
    after 2100 is a ValueError naming ``path``, ``column`` and the data row."""
    v = values.to_numpy(dtype=float)
    bad = (v < 0) | (v > _MAX_STAMP_NS)
    if bad.any():
        i = int(np.argmax(bad))
        raise ValueError(f"{path}: column {column!r}, data row {i + 1}: time stamp "
                         f"{v[i]:.6g} is not nanoseconds between 1970 and 2100")
    return np.array([int(x) if float(x).is_integer() else round(float(x))
                     for x in values], dtype=np.int64)


def load_recording(directory: str | Path) -> RangeRecording:
    """Read one run (see the module docstring). Raises FileNotFoundError / ValueError naming
    the file (and column and row) for anything missing or malformed."""
    from estimator.ranging import RangeStreams

    d = Path(directory)
    if not d.is_dir():
        raise FileNotFoundError(f"{d}: not a directory")
    anchor_files = sorted((p for p in d.iterdir() if _ANCHOR_RE.match(p.name)),
                          key=lambda p: int(_ANCHOR_RE.match(p.name).group(1)))
    if len(anchor_files) < 3:
        raise ValueError(f"{d}: needs >= 3 anchor files A<id>.csv, found "
                         f"{[p.name for p in anchor_files]}")
    traj = _read_csv(d / "trajectory.csv", _POSE_COLS)
    ref_ns = _ns(traj["timestamp"], d / "trajectory.csv", "timestamp")
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
        ns = _ns(a["field.stamp"], p, "field.stamp")
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
            authors[name] = ((_ns(e["timestamp"], d / fname, "timestamp") - t0) * 1e-9,
                             e[["x", "y", "z"]].to_numpy(dtype=float))
    return RangeRecording(d.name if d.name not in ("Case_1", "") else "/".join(d.parts[-3:]),
                          tuple(ids), np.array(pos), streams, (ref_ns - t0) * 1e-9,
                          traj[["x", "y", "z"]].to_numpy(dtype=float), authors, t0)


# =============================================================================================
# scoring every method
# =============================================================================================

#: method -> (run, what): ``run`` "2d" (known height) or "3d" (free z)
METHODS = {
    "fix_2d": ("2d", "damped least squares per epoch, known height, after the gates"),
    "kalman_2d": ("2d", "PV Kalman per axis on fix_2d (per-fix sigmas, innovation gate)"),
    "tight_2d": ("2d", "tightly coupled range filter, known height"),
    "fix_3d": ("3d", ("damped least squares per epoch, free z held in the anchors' heights "
                      "+/- 2 m (known-height fallback where z is unresolved), after the gates")),
    "kalman_3d": ("3d", "PV Kalman per axis on fix_3d (z held in the same interval)"),
    "tight_3d": ("3d", "tightly coupled range filter, free z"),
}
SUMMARY_COLUMNS = ("method", "rmse_2d_m", "rmse_3d_m", "max_error_2d_m", "coverage")


def method_estimates(res: RangingResult) -> dict[str, np.ndarray]:
    """(n, 3) estimates at the epochs per method family of one :func:`localize` result."""
    fx = np.where(res.fixes.ok[:, 0, None], res.fixes.position[:, 0], np.nan)
    return {"fix": fx, "kalman": res.position, "tight": res.tight.position}


def score(rec: RangeRecording, t: np.ndarray, est: np.ndarray, *, trajectory: str = "A",
          tag_height_m: float = TAG_HEIGHT_M, grid: np.ndarray | None = None,
          tolerance_s: float = 0.0) -> dict:
    """The authors' metric of estimates (t (p,) s, est (p, 3) m, NaN = none) plus coverage:
    the share of scored epochs with an estimate, where the scored epochs are ``grid`` (our
    epoch times) inside the scoring window, covered when an estimate lies within
    ``tolerance_s`` of the epoch (0: an estimate at exactly that epoch)."""
    m = authors_metric(rec.reference_t, rec.reference, t, est, trajectory=trajectory,
                       tag_height_m=tag_height_m)
    m["coverage"] = epoch_coverage(t, est, t if grid is None else grid, m["window"],
                                   tolerance_s)
    return m


def reference_ranges(rec: RangeRecording, lag_s: float, tag_height_m: float = TAG_HEIGHT_M
                     ) -> np.ndarray:
    """Ranges the reference implies for every sample of ``rec``, (N,) m
    (:func:`estimator.range_scoring.reference_ranges`)."""
    s = rec.streams
    return range_scoring.reference_ranges(s.t, rec.anchor_positions[s.receiver],
                                          rec.reference_t, rec.reference, lag_s, tag_height_m)


def range_lag(rec: RangeRecording, tag_height_m: float = TAG_HEIGHT_M) -> float:
    """Diagnostic only: the delay (s) of the ranges of ``rec`` behind its reference
    (:func:`estimator.range_scoring.range_lag`)."""
    s = rec.streams
    return range_scoring.range_lag(s.r, s.t, rec.anchor_positions[s.receiver],
                                   rec.reference_t, rec.reference, tag_height_m)


def evaluate(rec: RangeRecording, *, trajectory: str = "A", tag_height_m: float = TAG_HEIGHT_M,
             config: RangingConfig | None = None) -> dict:
    """Run the pipeline on a recording (known height and free z) and score every method.

    Returns {"summary": DataFrame (SUMMARY_COLUMNS), "stages" and "gates": DataFrames (see
    :func:`_stages`), "results": {"2d": RangingResult, "3d": RangingResult}, "series":
    DataFrame of every method's estimates at the epochs, "timings": dict}.
    """
    import pandas as pd

    from estimator.ranging import RangingConfig, localize

    base = config or RangingConfig.uwb_ground_tag()
    results, timings = {}, {}
    for mode, h in (("2d", tag_height_m), ("3d", None)):
        t0 = time.perf_counter()
        results[mode] = localize(rec.streams, rec.anchor_positions, base.replace(height_m=h))
        timings[f"localize_{mode}_s"] = time.perf_counter() - t0
    te = results["2d"].epochs
    tol = 0.5 * results["2d"].extra["nominal_interval_s"]
    rows, series = [], {"t": te}
    for name, (mode, _) in METHODS.items():
        est = method_estimates(results[mode])[name.split("_")[0]]
        m = score(rec, te, est, trajectory=trajectory, tag_height_m=tag_height_m)
        rows.append({"method": name, **{k: m[k] for k in SUMMARY_COLUMNS[1:]}})
        for a, ax in enumerate("xyz"):
            series[f"{name}_{ax}"] = est[:, a]
    for name, (ta, xyz) in rec.authors.items():
        m = score(rec, ta, xyz, trajectory=trajectory, tag_height_m=tag_height_m, grid=te,
                  tolerance_s=tol)
        rows.append({"method": name, **{k: m[k] for k in SUMMARY_COLUMNS[1:]}})
    summary = pd.DataFrame(rows, columns=list(SUMMARY_COLUMNS))
    stages, gates = _stages(rec, results, trajectory, tag_height_m)
    return {"summary": summary, "stages": stages, "gates": gates, "results": results,
            "series": pd.DataFrame(series), "timings": timings}


def _stages(rec: RangeRecording, results: dict, trajectory: str, tag_height_m: float
            ) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Diagnostics: (1) the fixes before and after the gates, scored; (2) per run, the range
    samples, Filter 1 and the tightly coupled filter's gate, with the spikes judged against
    the reference (|range - reference range| > 10 sigma after shifting the reference by the
    measured lag; no estimator sees the reference)."""
    import pandas as pd

    lag = range_lag(rec, tag_height_m)
    resid = rec.streams.r - reference_ranges(rec, lag, tag_height_m)
    spike = np.abs(resid) > 10.0 * results["2d"].config.sigma_range_m
    rows, gates = [], []
    for mode, res in results.items():
        te = res.epochs
        for stage, fx in (("raw ranges -> fix", res.fixes_raw),
                          ("gated ranges -> fix", res.fixes)):
            est = np.where(np.all(np.isfinite(fx.position[:, 0]), axis=1)[:, None],
                           fx.position[:, 0], np.nan)
            m = score(rec, te, est, trajectory=trajectory, tag_height_m=tag_height_m)
            rows.append({"run": mode, "stage": stage, "rmse_2d_m": m["rmse_2d_m"],
                         "max_error_2d_m": m["max_error_2d_m"], "coverage": m["coverage"]})
        rej = res.gate.rejected
        tr = res.tight
        gates.append({
            "run": mode, "samples": int(np.isfinite(rec.streams.r).sum()),
            "lag_s": lag, "spikes": int(spike.sum()),
            "filter1_rejected": int(rej.sum()), "spikes_past_filter1": int((spike & ~rej).sum()),
            "tight_gated": int(tr.gated.sum()),
            "spikes_used_by_tight": int((spike & tr.used).sum()),
            "tight_reinitialised": len(tr.reinitialised),
            "fixes_usable_pct": 100.0 * float(res.fixes.ok.mean()) if res.fixes.ok.size else 0.0,
        })
    return pd.DataFrame(rows), pd.DataFrame(gates)


# =============================================================================================
# figures
# =============================================================================================

_FIG_METHODS = (("fix_2d", "0.65", "."), ("kalman_2d", "tab:orange", "-"),
                ("tight_2d", "tab:blue", "-"))


def plot_recording(rec: RangeRecording, estimates: pd.DataFrame, res: RangingResult,
                   out: Path, *, trajectory: str = "A",
                   tag_height_m: float = TAG_HEIGHT_M) -> list[Path]:
    """Trajectories against the reference, 2-D error over time (from the saved estimates
    table) and ranges before/after gating (from the recording and the gates)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    files = []
    t = estimates["t"].to_numpy()
    fig, ax = plt.subplots(figsize=(9, 4.2), constrained_layout=True)
    ax.plot(rec.reference[:, 0], rec.reference[:, 1], "k-", lw=1.2, label="reference (RTK)")
    if "authors_eskf" in rec.authors:
        xyz = rec.authors["authors_eskf"][1]
        ax.plot(xyz[:, 0], xyz[:, 1], color="tab:red", lw=0.7, alpha=0.8, label="authors' ESKF")
    for name, color, style in _FIG_METHODS:
        ax.plot(estimates[f"{name}_x"], estimates[f"{name}_y"], style, color=color,
                lw=0.8, ms=1.5, label=name)
    ax.plot(rec.anchor_positions[:, 0], rec.anchor_positions[:, 1], "k^", ms=6,
            label="anchors")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.legend(fontsize=7, ncol=3, loc="upper center")
    ax.set_title(f"{rec.name}: estimates and reference")
    files.append(out / "trajectory.png")
    fig.savefig(files[-1], dpi=90)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(9, 3.6), constrained_layout=True)
    curves = [(n, t, estimates[[f"{n}_x", f"{n}_y", f"{n}_z"]].to_numpy(), c)
              for n, c, _ in _FIG_METHODS]
    if "authors_eskf" in rec.authors:
        curves.append(("authors_eskf", *rec.authors["authors_eskf"], "tab:red"))
    for name, tt, est, color in curves:
        m = authors_metric(rec.reference_t, rec.reference, tt, est, trajectory=trajectory,
                           tag_height_m=tag_height_m)
        ax.plot(m["t"], m["err_2d"], lw=0.8, color=color,
                label=f"{name} (RMSE {m['rmse_2d_m']:.2f} m)")
    ax.set_xlabel("time since the first reference sample (s)")
    ax.set_ylabel("2-D error (m)")
    ax.set_title("2-D error in the authors' scoring window")
    ax.legend(fontsize=7)
    files.append(out / "error.png")
    fig.savefig(files[-1], dpi=90)
    plt.close(fig)

    s = rec.streams
    k = s.n_receivers
    fig, axes = plt.subplots(k, 1, figsize=(9, 1.8 * k + 0.6), sharex=True,
                             constrained_layout=True)
    ref_r = reference_ranges(rec, range_lag(rec, tag_height_m), tag_height_m)
    for j, ax in enumerate(np.atleast_1d(axes)):
        sel = s.receiver == j
        tj, rj = s.t[sel], s.r[sel]
        rej = res.gate.rejected[sel]
        gated = res.tight.gated[sel]
        ax.plot(tj, ref_r[sel], "k-", lw=0.8, label="implied by the reference")
        ax.plot(tj, rj, ".", color="0.6", ms=1.5, label="raw")
        ax.plot(tj[rej], rj[rej], "x", color="tab:red", ms=4, label="rejected by Filter 1")
        ax.plot(tj[gated], rj[gated], "o", mfc="none", color="tab:orange", ms=4,
                label="gated by the tight filter")
        ax.set_ylabel(f"A{rec.anchors[j]} (m)")
    np.atleast_1d(axes)[0].legend(fontsize=7, ncol=4, loc="upper left")
    np.atleast_1d(axes)[-1].set_xlabel("time since the first reference sample (s)")
    fig.suptitle(f"{rec.name}: ranges before and after gating")
    files.append(out / "ranges.png")
    fig.savefig(files[-1], dpi=90)
    plt.close(fig)
    return files


# =============================================================================================
# driver
# =============================================================================================

REPO = Path(__file__).resolve().parents[1]
#: the committed reference run (``--reference``) and the shared runs it is made of
REFERENCE_OUT = REPO / "results" / "ranging"
REFERENCE_RUNS = tuple(REPO.parent / "shared" / "realdata" / "uwb_hanyang" / c / "Trajectory_A"
                       / "Case_1" for c in ("LOS", "NLOS"))
#: default output of every other run (git-ignored)
DEFAULT_OUT = REPO / "results" / "local" / "ranging"


def _label(directory: Path) -> str:
    parts = directory.resolve().parts
    return "_".join(parts[-3:]) if parts[-1].lower().startswith("case") else parts[-1]


def _shown_path(p: Path) -> str:
    """A path for the tracked outputs, never machine-specific: relative to the repository
    (``../shared/...`` for the shared data folder beside it), else the last three parts."""
    q = Path(p).resolve()
    for root, prefix in ((REPO.resolve(), ""), ((REPO.parent / "shared").resolve(),
                                                "../shared/")):
        try:
            return prefix + q.relative_to(root).as_posix()
        except ValueError:
            continue
    return "/".join(q.parts[-3:])


def published_scores(directory: Path) -> dict:
    """The authors' RMSD_results.txt as {"authors_ls": (rmse_3d, rmse_2d), ...} (empty when
    absent)."""
    p = Path(directory) / "RMSD_results.txt"
    if not p.is_file():
        return {}
    vals = {}
    for line in p.read_text().splitlines():
        m = re.match(r"\s*(LS|ESKF) RMSE(_2d)?:\s*([0-9.eE+-]+)", line)
        if m:
            vals[(m.group(1), bool(m.group(2)))] = float(m.group(3))
    out = {}
    for key, name in (("LS", "authors_ls"), ("ESKF", "authors_eskf")):
        if (key, False) in vals and (key, True) in vals:
            out[name] = (vals[(key, False)], vals[(key, True)])
    return out


def _md_table(df: pd.DataFrame) -> str:
    return markdown_table(df, floatfmt=".3f")


def _trajectory_of(directory: Path) -> str:
    """The scoring window a recording folder's path implies: B under Trajectory_B, else A."""
    return "B" if "Trajectory_B" in directory.resolve().parts else "A"


def _check_window(directory: Path, rec: RangeRecording, trajectory: str) -> None:
    """ValueError naming the recording's trajectory.csv when its reference never enters or
    never leaves the ``trajectory`` scoring window."""
    try:
        scoring_window(rec.reference_t, rec.reference, trajectory)
    except ValueError as exc:
        why = str(exc).removeprefix("reference: ")
        raise ValueError(f"{directory / 'trajectory.csv'}: the reference {why} (Trajectory "
                         f"{trajectory}: from --trajectory, else from the folder's path)"
                         ) from exc


def run(directories, out: str | Path = DEFAULT_OUT, *, trajectory: str | None = None,
        tag_height_m: float = TAG_HEIGHT_M, figures: bool = True) -> dict:
    """Evaluate each recording directory; write ``out/<label>/`` per recording and a combined
    ``out/summary.md``. Returns {label: evaluate(...) result}."""
    import pandas as pd

    from estimator.ranging import RangingConfig

    out = Path(out)
    dirs = [Path(d) for d in directories]
    if not dirs:
        raise ValueError("directories: give at least one recording directory")
    recs = [load_recording(d) for d in dirs]              # fail before writing anything
    for d, rec in zip(dirs, recs, strict=True):
        _check_window(d, rec, trajectory or _trajectory_of(d))
    out.mkdir(parents=True, exist_ok=True)
    done, md, timings = {}, [], {}
    config = RangingConfig.uwb_ground_tag()
    for d, rec in zip(dirs, recs, strict=True):
        label = _label(d)
        traj = trajectory or _trajectory_of(d)
        sub = out / label
        sub.mkdir(parents=True, exist_ok=True)
        t0 = time.perf_counter()
        ev = evaluate(rec, trajectory=traj, tag_height_m=tag_height_m, config=config)
        ev["summary"].to_csv(sub / "summary.csv", index=False, float_format="%.6g")
        ev["stages"].to_csv(sub / "stages.csv", index=False, float_format="%.6g")
        ev["gates"].to_csv(sub / "gates.csv", index=False, float_format="%.6g")
        ev["series"].to_csv(sub / "estimates.csv.gz", index=False, float_format="%.3f",
                            compression={"method": "gzip", "mtime": 0})   # reruns: same bytes
        pub = published_scores(d)
        table = ev["summary"].copy()
        table["published_rmse_2d_m"] = [pub.get(m, (np.nan, np.nan))[1] for m in table.method]
        (sub / "summary.md").write_text(_md_table(table) + "\n")
        if figures:
            plot_recording(rec, pd.read_csv(sub / "estimates.csv.gz"), ev["results"]["2d"],
                           sub, trajectory=traj, tag_height_m=tag_height_m)
        timings[label] = {**ev["timings"], "total_s": time.perf_counter() - t0}
        info = {"recording": _shown_path(d), "trajectory": traj, "tag_height_m": tag_height_m,
                "config": asdict(config), "methods": {k: v[1] for k, v in METHODS.items()},
                "code_version": git_describe(), "epochs": int(ev["results"]["2d"].epochs.size),
                "scoring_window_s": list(scoring_window(rec.reference_t, rec.reference,
                                                        traj)),
                "published": {k: {"rmse_3d_m": v[0], "rmse_2d_m": v[1]} for k, v in pub.items()}}
        (sub / "run_info.json").write_text(json.dumps(info, indent=2, default=float) + "\n")
        md += [f"## {label}", "", (f"Recording `{_shown_path(d)}`, Trajectory {traj}; "
                                   "the authors' metric (their scoring window, reference z + "
                                   f"{tag_height_m:g} m for 3-D)."), "", _md_table(table), "",
               _md_table(ev["stages"]), "", _md_table(ev["gates"]), ""]
        done[label] = ev
    head = ["# Range localization on recorded UWB runs", "",
            "Generated by `python -m experiments.ranging` (code "
            f"`{git_describe()}`) with `RangingConfig.uwb_ground_tag()`: physical defaults, "
            "nothing fitted to these recordings. Methods: "
            + "; ".join(f"`{k}` {v[1]}" for k, v in METHODS.items())
            + "; `authors_ls` / `authors_eskf` the dataset authors' own estimates. Coverage: "
            "share of the 10 Hz epochs in the scoring window with an estimate. "
            "`published_rmse_2d_m`: the authors' RMSD_results.txt. Stages: scores before the "
            "gates, and range spikes (|range - reference range| > 10 sigma, the reference "
            "shifted by the measured range lag `lag_s`; a diagnostic only) past each gate.",
            ""]
    (out / "summary.md").write_text("\n".join(head + md) + "\n")
    (out / "timings.json").write_text(json.dumps(timings, indent=2) + "\n")
    return done


def main(argv: list[str] | None = None) -> int:
    from experiments.cli import ArgumentParser

    ap = ArgumentParser(prog="python -m experiments.ranging", description=__doc__,
                        formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("dirs", nargs="*", metavar="DIR", help="recording directories")
    ap.add_argument("--out", default=None,
                    help="output folder (default results/local/ranging/, untracked)")
    ap.add_argument("--trajectory", choices=("A", "B"), default=None,
                    help="scoring window (default: from the path, else A)")
    ap.add_argument("--tag-height", type=float, default=TAG_HEIGHT_M,
                    help="known tag z in m for the 2-D runs (default 1.0: the dataset's tag "
                         "rides 1.0 m above the ground-level reference)")
    ap.add_argument("--no-figures", action="store_true")
    ap.add_argument("--reference", action="store_true",
                    help="regenerate the committed results/ranging/ from the two shared runs "
                         "(../shared/realdata/uwb_hanyang/{LOS,NLOS}/Trajectory_A/Case_1)")
    args = ap.parse_args(argv)
    if args.dirs and all((Path(d) / "setup.toml").is_file() for d in args.dirs):
        # rigid-body runs (a setup.toml, issue 26) are scored by experiments.rigid_ranging
        from experiments import rigid_ranging
        return rigid_ranging.main([*args.dirs, *(["--out", args.out] if args.out else []),
                                   *(["--no-figures"] if args.no_figures else [])])
    if not np.isfinite(args.tag_height) or abs(args.tag_height) > 1e4:
        ap.error(f"--tag-height: must be a finite height in metres, got {args.tag_height}")
    if args.reference:
        if args.dirs or args.out is not None or args.trajectory or args.no_figures \
                or args.tag_height != TAG_HEIGHT_M:
            ap.error("--reference takes no DIR, --out, --trajectory, --tag-height or "
                     "--no-figures")
        dirs, out = list(REFERENCE_RUNS), REFERENCE_OUT
    else:
        if not args.dirs:
            ap.error("give at least one recording DIR (or --reference)")
        dirs, out = args.dirs, Path(args.out) if args.out is not None else DEFAULT_OUT
    try:
        res = run(dirs, out, trajectory=args.trajectory, tag_height_m=args.tag_height,
                  figures=not args.no_figures)
    except (FileNotFoundError, ValueError) as exc:
        print(f"{ap.prog}: error: {exc}", file=sys.stderr)
        return 2
    import pandas as pd

    pd.set_option("display.width", 200)
    for label, ev in res.items():
        print(f"{label}\n{ev['summary'].to_string(index=False, float_format='%.3f')}\n")
    print(f"written to {out}")
    return 0


if __name__ == "__main__":
    from experiments.cli import run as run_cli

    run_cli(main)
