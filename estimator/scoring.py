"""A sweep cell's scores: one track against its reference, summarised per evaluation mask.

The statistics are :mod:`estimator.metrics`' (the one scorer): Eq. 4.1 / 4.2 errors of
000_8f82f8df647bf685.txt (:func:`~estimator.metrics.track_errors`), their summaries
(:func:`~estimator.metrics.summarize`), the epoch-to-epoch jitter
(:func:`~estimator.metrics.jitter_rms`) and the evaluation masks
(:func:`~estimator.metrics.evaluation_masks`). This module lays them out as the rows and the
per-epoch table of a cell (the columns of ``cells.parquet`` and ``epochs/<key>.parquet``).

The reference is any object with the attributes of :class:`sim.truth.Truth` that are read
here: ``t`` (n,) s, ``cg`` (n, 2|3) m, ``yaw`` (n,) rad, ``turning`` (n,) bool,
``sensor_positions`` (n, m, 2|3) m, ``sensor_names`` (m,) and ``n``.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

import numpy as np

from estimator.metrics import (
    STATISTICS,
    TrackErrors,
    evaluation_masks,
    jitter_rms,
    summarize,
    track_cg,
    track_errors,
)
from estimator.orientation import wrap_angle

# pandas is imported where a table is built: the sweep's main process imports this module
# before it needs pandas (0.4 s off the critical path of a one-path sweep)
if TYPE_CHECKING:
    import pandas as pd

__all__ = ["CONSISTENCY_COLUMNS", "SERIES_COLUMNS", "consistency", "coverage_rows",
           "score_track"]

#: Column prefixes of the error series in cells.parquet (estimator.metrics.TrackErrors).
SERIES_COLUMNS = {"ex": "x", "ey": "y", "eu": "euclid", "eh": "heading"}
#: Consistency columns (issue 25): heading NEES from the row's ``yaw_sd`` against the truth
#: and the forward pass's NIS (``nis``, ``nis_dof``): the mean per dof (1 when consistent)
#: and the share of rows inside the central 95 % chi-square band (0.95 when consistent);
#: the share of rows whose status is not "ok" and of those flagged "inconsistent". NaN for
#: a track without the columns (window fits have no covariance, the GTSAM peer and the
#: fixed-lag smoother none of their own: :mod:`estimator.trackers.ekf`).
CONSISTENCY_COLUMNS = ("nees_mean", "nees_in_band", "nis_per_dof", "nis_in_band",
                       "status_not_ok", "status_inconsistent")
#: Columns of a row beside the series statistics.
_EXTRA = ("along_mean", "along_median", "jitter_rms", "obs_ex_mean", "obs_ey_mean",
          *CONSISTENCY_COLUMNS)


def score_track(df: pd.DataFrame, truth: Any, obs: np.ndarray, config: Any,
                masks: Iterable[str], epochs: bool = True
                ) -> tuple[list[dict], pd.DataFrame | None]:
    """Eq. 4.1/4.2 errors of a track against the truth, summarised per evaluation mask.

    df : the track (columns t, cg_x, cg_y, yaw; ``window`` (int) if the tracker has one,
    else each estimate counts as its own epoch's). obs (n, m, 2) m : the observations.
    Returns one dict per mask with, for each error series (``ex`` = |x| CG error, ``ey`` =
    |y|, ``eu`` = Euclidean, ``eh`` = heading, rad), the statistics mean, median, std
    (ddof 1), rmse, p95, max and the box-plot outlier fraction; plus the signed along-track
    error (mean, median; negative = the estimate trails the truth, the lag of Section
    3.4.2; along the truth's direction of travel, :func:`estimator.metrics.travel_direction`),
    the epoch-to-epoch jitter (RMS change of the error vector between consecutive epochs,
    the "variation from one estimate to the next" of Section 4.10), the raw observations'
    own per-axis error for comparison, and counts. Also returns the per-epoch table (truth,
    errors, observations at the estimate times) when ``epochs`` is True, else None.
    """
    err = track_errors(df["t"].to_numpy(dtype=float), track_cg(df),
                       df["yaw"].to_numpy(dtype=float), truth.t, truth.cg, truth.yaw)
    idx = err.index
    win = np.zeros(truth.n, dtype=np.int64)
    # a plug-in's table may have no window column: each estimate is its epoch's own
    win[idx] = df["window"].to_numpy(dtype=np.int64) if "window" in df else 1
    mk_all = {k: v[idx] for k, v in evaluation_masks(truth.turning.astype(bool),
                                                      window=win).items()}
    obs_e = _obs_errors(obs, truth, idx)
    rows = [_mask_row(mname, mk_all[mname], err, obs_e) for mname in masks]
    for row in rows:
        row.update(consistency(df, err.heading, mk_all[row["mask"]]))
    if not epochs:
        return rows, None
    return rows, _epoch_table(df, truth, obs, err, mk_all["no_turns_window"])


def _obs_errors(obs: np.ndarray, truth: Any, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean |x| and |y| error of the raw observations at the estimate epochs (k,) m."""
    ob = obs[idx] - truth.sensor_positions[idx, :, :2]            # (k, m, 2)
    obs_ex = np.nanmean(np.abs(ob[..., 0]), axis=1) if ob.size else np.array([])
    obs_ey = np.nanmean(np.abs(ob[..., 1]), axis=1) if ob.size else np.array([])
    return obs_ex, obs_ey


def _mask_row(mname: str, mk: np.ndarray, err: TrackErrors,
              obs_e: tuple[np.ndarray, np.ndarray]) -> dict[str, Any]:
    """The summary row of one mask (:func:`score_track`)."""
    row: dict[str, Any] = {"mask": mname, "n_epochs": int(mk.sum())}
    for sname, q in SERIES_COLUMNS.items():
        sm = summarize(getattr(err, q), mk)
        for k in (*STATISTICS, "outliers"):
            row[f"{sname}_{k}"] = sm[k]
        if sname == "ex":
            row["n_valid"], row["n_nan"] = sm["n"], sm["n_nan"]
    sa = summarize(err.along, mk, signed=True)
    row["along_mean"], row["along_median"] = sa["mean"], sa["median"]
    row["jitter_rms"] = jitter_rms(err.dxy, mk)
    obs_ex, obs_ey = obs_e
    with np.errstate(all="ignore"):
        row["obs_ex_mean"] = float(np.nanmean(obs_ex[mk])) if mk.any() else float("nan")
        row["obs_ey_mean"] = float(np.nanmean(obs_ey[mk])) if mk.any() else float("nan")
    return row


def _epoch_table(df: pd.DataFrame, truth: Any, obs: np.ndarray, err: TrackErrors,
                 no_turns_window: np.ndarray) -> pd.DataFrame:
    """The per-epoch table of :func:`score_track`: truth, errors, observations."""
    import pandas as pd

    idx = err.index
    tru = truth.cg[idx, :2]
    cols: dict[str, Any] = {
        "truth_cg_x": tru[:, 0], "truth_cg_y": tru[:, 1], "truth_yaw": truth.yaw[idx],
        "truth_turning": truth.turning[idx].astype(bool), "err_x": err.dx, "err_y": err.dy,
        "err_yaw": wrap_angle(df["yaw"].to_numpy(float) - truth.yaw[idx]),
        "along": err.along, "cross": err.cross, "no_turns_window": no_turns_window}
    # per-antenna truth and observations for plots: float32 (1e-5 m resolution at 200 m)
    # halves the files; the estimates, CG truth and errors stay float64
    for j, nm in enumerate(truth.sensor_names):
        cols[f"truth_{nm}_x"] = truth.sensor_positions[idx, j, 0].astype(np.float32)
        cols[f"truth_{nm}_y"] = truth.sensor_positions[idx, j, 1].astype(np.float32)
        cols[f"obs_{nm}_x"] = obs[idx, j, 0].astype(np.float32)
        cols[f"obs_{nm}_y"] = obs[idx, j, 1].astype(np.float32)
    return pd.DataFrame(cols)


def coverage_rows(df: pd.DataFrame) -> list[dict]:
    """Rows of a cell without a reference: mask "full" with the epoch and estimate counts
    (``n_epochs``, ``n_valid`` finite CG estimates, ``n_nan``); every error statistic of
    :func:`score_track` is NaN (nothing to score against), so the tables keep their shape."""
    cg = track_cg(df)
    ok = np.isfinite(cg).all(axis=1)
    row: dict[str, Any] = {"mask": "full", "n_epochs": len(df), "n_valid": int(ok.sum()),
                           "n_nan": int((~ok).sum())}
    nan = float("nan")
    for sname in SERIES_COLUMNS:
        row.update({f"{sname}_{k}": nan for k in (*STATISTICS, "outliers")})
    row.update(dict.fromkeys(_EXTRA, nan))
    row.update(consistency(df, None, np.ones(len(df), dtype=bool)))
    return [row]


def consistency(df: pd.DataFrame, heading_err: np.ndarray | None,
                mk: np.ndarray) -> dict[str, float]:
    """The :data:`CONSISTENCY_COLUMNS` of a track's rows ``mk`` (k,) bool.

    heading_err (n rows,) rad : the Eq. 4.2 heading error of every row (wrapped; None: no
    reference, NEES NaN).
    NEES per row ``(heading_err / yaw_sd)^2`` (chi-square, 1 dof;
    :func:`estimator.pose_filter.nees`), NIS from ``nis`` / ``nis_dof``; both summarised by
    :func:`estimator.pose_filter.nis_summary` (rows without a value are left out; none: NaN).
    """
    from estimator.pose_filter import nees, nis_summary

    nan = float("nan")
    out = dict.fromkeys(CONSISTENCY_COLUMNS, nan)
    if "yaw_sd" in df and heading_err is not None:
        sd = df["yaw_sd"].to_numpy(dtype=float)[mk]
        e = np.asarray(heading_err, dtype=float)[mk]
        s = nis_summary(nees(e[:, None], (sd ** 2)[:, None, None]), np.ones(e.size))
        out["nees_mean"], out["nees_in_band"] = s["mean_nis_per_dof"], s["share_in_band"]
    if "nis" in df and "nis_dof" in df:
        s = nis_summary(df["nis"].to_numpy(dtype=float)[mk],
                        df["nis_dof"].to_numpy(dtype=float)[mk])
        out["nis_per_dof"], out["nis_in_band"] = s["mean_nis_per_dof"], s["share_in_band"]
    if "solver_status" in df and mk.any():
        st = df["solver_status"].to_numpy(dtype=object)[mk]
        out["status_not_ok"] = float(np.mean(st != "ok"))
        out["status_inconsistent"] = float(np.mean(st == "inconsistent"))
    return out
