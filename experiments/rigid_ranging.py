"""Score rigid-body ranging runs: ``python -m experiments.rigid_ranging RUN_DIR [...] --out OUT``.

Each RUN_DIR holds a ``setup.toml`` (:mod:`sim.range_recording`; e.g. the shared
``../shared/realdata/uwb_rigid/*/*``). Every method estimates the planar pose (x, y, yaw) at
every row of ranges, with physical defaults (range noise 0.05 m), nothing fitted to a run:

=====================  ========================================================================
``baseline``           the independent baseline of issue 26: per-tag trilateration + Procrustes
                       start, joint Gauss-Newton (LM) on the raw ranges, no robust weights
``robust``             joint fit with Huber IRLS weights (scale from the MAD), mirror checks
``robust_bias``        ``robust`` plus one common range-bias state
``filter``             tightly coupled EKF (one update per range, common bias state), initialised
                       and re-initialised from ``robust_bias``
``smoother``           RTS smoother over ``filter``
``*_calibrated``       ``baseline`` and ``robust_bias`` on the authors' calibrated ranges, for
                       runs with a ``[calibration]`` section
=====================  ========================================================================

Scoring. Static reference: errors against the known pose at every row. Trajectory reference:
one constant clock offset (reference time = range time + offset) is estimated per method by a
grid over +-1 s (5 ms) refined by a bounded scalar search, minimising the 2-D RMSE; the
reference is interpolated at the shifted times (yaw unwrapped). Columns of ``summary.csv``:
``run, method, rmse_2d_m, yaw_rmse_deg, max_error_2d_m, mean_error_2d_m, clock_offset_s,
coverage`` (share of rows, within the reference's span, with an estimate), ``flagged`` (share
of rows whose joint fit reported a status other than ``ok``), ``epochs``. Also
``summary.md`` and per run ``<run>/errors.png`` and ``<run>/trajectory.png``.

``run(dirs, out)`` is the callable entry point; ``main(argv)`` parses arguments.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from estimator import range_scoring
from experiments.deferred import deferred_attributes
from experiments.markdown import markdown_table

if TYPE_CHECKING:
    import pandas as pd

    from estimator import rigid_ranging as rr
    from sim.range_recording import RangeRecording, StaticReference, TrajectoryReference

#: imported where used, not here, so that --help and argument errors answer before
#: pandas / numba / scipy / matplotlib load; still importable from this module
__getattr__ = deferred_attributes(__name__, {
    "pd": ("pandas", None),
    "rr": ("estimator.rigid_ranging", None),
    "RangeRecording": ("sim.range_recording", "RangeRecording"),
    "StaticReference": ("sim.range_recording", "StaticReference"),
    "TrajectoryReference": ("sim.range_recording", "TrajectoryReference"),
    "load_range_recording": ("sim.range_recording", "load_range_recording"),
})

__all__ = ["COLUMNS", "METHODS", "estimate", "main", "run", "score", "score_static",
           "score_trajectory"]

#: range noise std (m) assumed by every method: the order of UWB ranging noise (the authors'
#: calibration gives 0.01-0.04 m per pair), never fitted to a run
SIGMA_M = 0.05
METHODS = ("baseline", "robust", "robust_bias", "filter", "smoother")
COLUMNS = ("run", "method", "rmse_2d_m", "yaw_rmse_deg", "max_error_2d_m", "mean_error_2d_m",
           "clock_offset_s", "coverage", "flagged", "epochs")
REPO = Path(__file__).resolve().parents[1]
DEFAULT_OUT = REPO / "results" / "local" / "rigid_ranging"


def _fit(rec: RangeRecording, D: np.ndarray, **kw) -> rr.RigidPoseFit:
    from estimator import rigid_ranging as rr

    return rr.fit_pose(rec.anchors, rec.body, D, origin_z_m=rec.origin_z_m, sigma_m=SIGMA_M,
                       **kw)


def estimate(rec: RangeRecording, calibrated: RangeRecording | None = None) -> dict:
    """{method: (pose (n, 3) x, y, yaw, flagged (n,) bool)} at the rows of ``rec``."""
    from estimator import rigid_ranging as rr

    out = {}
    base = _fit(rec, rec.ranges, robust="none", mirror_check=False)
    out["baseline"] = (base.pose, base.status != "ok")
    rob = _fit(rec, rec.ranges, robust="huber")
    out["robust"] = (rob.pose, rob.status != "ok")
    rb = _fit(rec, rec.ranges, robust="huber", bias="common")
    out["robust_bias"] = (rb.pose, rb.status != "ok")
    usable = np.isin(rb.status, ("ok", "maxiter"))
    init = np.where(usable[:, None], rb.pose, np.nan)
    t, tag, anc, r = rr.grid_to_stream(rec.times, rec.ranges)
    tr = rr.track(rec.anchors, rec.body, t, tag, anc, r, rec.times, init,
                  init_bias=rb.bias[:, 0], origin_z_m=rec.origin_z_m,
                  config=rr.FilterConfig(sigma_range_m=SIGMA_M))
    sm = rr.smooth(tr)
    for name, res in (("filter", tr), ("smoother", sm)):
        out[name] = (_at_rows(rec.times, res), np.zeros(rec.times.size, dtype=bool))
    out["_track"] = tr
    if calibrated is not None:
        cb = _fit(calibrated, calibrated.ranges, robust="none", mirror_check=False)
        out["baseline_calibrated"] = (cb.pose, cb.status != "ok")
        cr = _fit(calibrated, calibrated.ranges, robust="huber", bias="common")
        out["robust_bias_calibrated"] = (cr.pose, cr.status != "ok")
    return out


def _at_rows(times: np.ndarray, res: rr.TrackResult) -> np.ndarray:
    """The filter's pose at each row time (rows sharing a time get the same pose)."""
    k = np.searchsorted(res.times, times)
    pose = res.pose[np.clip(k, 0, res.times.size - 1)]
    pose[res.segment[np.clip(k, 0, res.times.size - 1)] < 0] = np.nan
    return pose


def score_static(pose: np.ndarray, ref: StaticReference) -> tuple[dict, np.ndarray]:
    """Scores against a fixed pose (:func:`estimator.range_scoring.score_static`)."""
    return range_scoring.score_static(pose, np.array([ref.x_m, ref.y_m, ref.yaw]))


def score_trajectory(times: np.ndarray, pose: np.ndarray, ref: TrajectoryReference
                     ) -> tuple[dict, np.ndarray]:
    """Scores after the clock offset that minimises the 2-D RMSE
    (:func:`estimator.range_scoring.score_trajectory`)."""
    return range_scoring.score_trajectory(times, pose, ref.times, ref.xyz, ref.yaw)


def score(rec: RangeRecording, pose: np.ndarray) -> tuple[dict, np.ndarray]:
    from sim.range_recording import StaticReference

    if isinstance(rec.reference, StaticReference):
        return score_static(pose, rec.reference)
    return score_trajectory(rec.times, pose, rec.reference)


def _label(folder: Path) -> str:
    p = folder.resolve().parts
    return "/".join(p[-2:])


def _plots(rec: RangeRecording, label: str, est: dict, errors: dict, out: Path) -> None:
    """errors.png (2-D error of every method vs time) and trajectory.png (overlay)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from sim.range_recording import TrajectoryReference

    t = rec.times - rec.times[0]
    fig, ax = plt.subplots(figsize=(9, 4))
    for m, e in errors.items():
        ax.plot(t, e, lw=0.7, label=m)
    ax.set_yscale("log")
    ax.set_xlabel("time since the first row (s)")
    ax.set_ylabel("2-D position error (m)")
    ax.set_title(f"{label}: error vs time")
    ax.legend(fontsize=7, ncol=3)
    fig.tight_layout()
    fig.savefig(out / "errors.png", dpi=90)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(6, 6))
    if isinstance(rec.reference, TrajectoryReference):
        ax.plot(rec.reference.xyz[:, 0], rec.reference.xyz[:, 1], "k-", lw=1.5,
                label="reference")
    else:
        ax.plot(rec.reference.x_m, rec.reference.y_m, "k+", ms=14, mew=2, label="reference")
    for m in ("baseline", "robust_bias", "smoother"):
        ax.plot(est[m][0][:, 0], est[m][0][:, 1], ".", ms=1.5, label=m)
    ax.plot(rec.anchors[:, 0], rec.anchors[:, 1], "k^", label="anchors")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"{label}: trajectory overlay")
    leg = ax.legend(fontsize=7)
    for h in leg.legend_handles[1:-1]:      # the estimates' tiny dots, enlarged in the key
        h.set_markersize(6)
    fig.tight_layout()
    fig.savefig(out / "trajectory.png", dpi=90)
    plt.close(fig)


def evaluate(folder: Path) -> tuple[list[dict], dict]:
    """Rows of the summary for one run folder, and the estimates."""
    from sim.range_recording import load_range_recording

    rec = load_range_recording(folder)
    cal = load_range_recording(folder, calibrate=True) if rec.calibration is not None else None
    est = estimate(rec, cal)
    tr = est.pop("_track")
    rows, errors, offsets = [], {}, {}
    for m, (pose, flagged) in est.items():
        fields, e = score(rec, pose)
        rows.append({"run": _label(folder), "method": m, **fields,
                     "flagged": float(flagged.mean()), "epochs": int(rec.times.size)})
        errors[m], offsets[m] = e, fields["clock_offset_s"]
    est["_track"] = tr
    return rows, {"rec": rec, "est": est, "errors": errors, "offsets": offsets}


def run(folders, out: str | Path = DEFAULT_OUT, *, figures: bool = True) -> pd.DataFrame:
    """Score each run folder; write ``out/summary.csv`` / ``summary.md`` (one table, a
    ``run`` column) and the figures. Returns the table."""
    import pandas as pd

    dirs = [Path(f) for f in folders]
    if not dirs:
        raise ValueError("folders: give at least one run folder")
    for d in dirs:
        if not (d / "setup.toml").is_file():
            raise ValueError(f"folders: {d} holds no setup.toml")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for d in dirs:
        r, ev = evaluate(d)
        rows += r
        tr = ev["est"]["_track"]
        print(f"{_label(d)}: filter {1e6 * tr.seconds / max(tr.updates, 1):.1f} us/update, "
              f"{(ev['rec'].times[-1] - ev['rec'].times[0]) / tr.seconds:.0f}x real time, "
              f"{int(tr.reinit.sum())} (re)initialisations", file=sys.stderr)
        if figures:
            sub = out / _label(d).replace("/", "_")
            sub.mkdir(parents=True, exist_ok=True)
            _plots(ev["rec"], _label(d), ev["est"], ev["errors"], sub)
    table = pd.DataFrame(rows, columns=list(COLUMNS))
    table.to_csv(out / "summary.csv", index=False, float_format="%.6g")
    (out / "summary.md").write_text(markdown_table(table, floatfmt=".3f") + "\n")
    return table


def main(argv: list[str] | None = None) -> int:
    from experiments.cli import ArgumentParser

    ap = ArgumentParser(prog="python -m experiments.rigid_ranging", description=__doc__,
                        formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("dirs", nargs="+", metavar="RUN_DIR", help="run folders with setup.toml")
    ap.add_argument("--out", default=str(DEFAULT_OUT),
                    help="output folder (default results/local/rigid_ranging/, untracked)")
    ap.add_argument("--no-figures", action="store_true")
    a = ap.parse_args(argv)
    try:
        table = run(a.dirs, a.out, figures=not a.no_figures)
    except (OSError, ValueError) as exc:
        print(f"{ap.prog}: error: {exc}", file=sys.stderr)
        return 2
    print(markdown_table(table, floatfmt=".3f"))
    print(f"written to {a.out}")
    return 0


if __name__ == "__main__":
    from experiments.cli import run as run_cli

    run_cli(main)
