"""Scoring of range-based localisation against a reference, pure functions over arrays.

Two families, both used by the ranging studies (``experiments.ranging``,
``experiments.rigid_ranging``), which read the files and call these:

* the UWB dataset authors' metric (their ``localization_error_analysis.py``, re-implemented):
  :func:`scoring_window`, :func:`authors_metric`, :func:`epoch_coverage`, and the range-lag
  diagnostic :func:`reference_ranges` / :func:`range_lag`;
* planar rigid-body poses (x, y, yaw) against a static pose or a trajectory with one unknown
  constant clock offset: :func:`pose_errors`, :func:`score_static`, :func:`score_trajectory`.

Units: times s, positions m, yaw rad (yaw errors are reported in degrees where named _deg).
"""

from __future__ import annotations

import numpy as np

from estimator.metrics import summarize
from estimator.orientation import wrap_angle

__all__ = ["OFFSET_SPAN_S", "OFFSET_STEP_S", "TAG_HEIGHT_M", "authors_metric", "epoch_coverage",
           "pose_errors", "range_lag", "reference_ranges", "score_static", "score_trajectory",
           "scoring_window"]

#: the tag's height above the reference point (m), as the UWB authors' scoring states
TAG_HEIGHT_M = 1.0
#: clock-offset search of :func:`score_trajectory`: grid half-width and step (s)
OFFSET_SPAN_S, OFFSET_STEP_S = 1.0, 0.005


# =============================================================================================
# the UWB authors' metric
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
    s2, s3 = summarize(e2), summarize(e3)      # NaN statistics when nothing is scored
    return {
        "rmse_2d_m": s2["rmse"], "rmse_3d_m": s3["rmse"], "max_error_2d_m": s2["max"],
        "n": int(e2.size), "window": (t0, t1), "t": et, "err_2d": e2, "err_3d": e3,
    }


def epoch_coverage(t: np.ndarray, est: np.ndarray, grid: np.ndarray,
                   window: tuple[float, float], tolerance_s: float = 0.0) -> float:
    """Share of the epochs ``grid`` (s) inside ``window`` (s, s) with an estimate (t (p,) s,
    est (p, 3) m, NaN = none) within ``tolerance_s`` of the epoch (0: exactly at it); NaN
    when no epoch lies in the window."""
    g = np.asarray(grid, dtype=float)
    t0, t1 = window
    g = g[(g >= t0) & (g <= t1)]
    have = np.asarray(t, dtype=float)[np.all(np.isfinite(est), axis=1)]
    if not (g.size and have.size):
        return 0.0 if g.size else float("nan")
    j = np.clip(np.searchsorted(have, g), 1, have.size) if have.size > 1 else np.zeros(
        g.size, dtype=int)
    near = np.minimum(np.abs(have[np.clip(j, 0, have.size - 1)] - g),
                      np.abs(have[np.clip(j - 1, 0, have.size - 1)] - g))
    return float(np.mean(near <= tolerance_s))


def reference_ranges(sample_t: np.ndarray, sample_anchor_xyz: np.ndarray, ref_t: np.ndarray,
                     ref_xyz: np.ndarray, lag_s: float, tag_height_m: float = TAG_HEIGHT_M
                     ) -> np.ndarray:
    """Ranges the reference implies for every range sample, (N,) m: the tag (reference
    (M, 3) + tag height) interpolated at the sample time (N,) s minus ``lag_s``, to the
    sample's anchor (N, 3) m; NaN outside the reference's span."""
    tq = sample_t - lag_s
    pts = np.stack([np.interp(tq, ref_t, ref_xyz[:, a]) for a in range(3)], 1)
    pts[:, 2] += tag_height_m
    r = np.linalg.norm(pts - sample_anchor_xyz, axis=1)
    return np.where((tq >= ref_t[0]) & (tq <= ref_t[-1]), r, np.nan)


def range_lag(ranges: np.ndarray, sample_t: np.ndarray, sample_anchor_xyz: np.ndarray,
              ref_t: np.ndarray, ref_xyz: np.ndarray, tag_height_m: float = TAG_HEIGHT_M
              ) -> float:
    """Diagnostic only (no estimator uses it): the delay (s) of the ranges (N,) m behind
    the reference, the lag in [0, 0.6] s (5 ms steps) minimising the median absolute
    deviation of the range residuals (arguments as :func:`reference_ranges`)."""
    best, lag_best = np.inf, 0.0
    for lag in np.arange(0.0, 0.6001, 0.005):
        e = ranges - reference_ranges(sample_t, sample_anchor_xyz, ref_t, ref_xyz, lag,
                                      tag_height_m)
        e = e[np.isfinite(e)]
        mad = np.median(np.abs(e - np.median(e)))
        if mad < best:
            best, lag_best = mad, float(lag)
    return lag_best


# =============================================================================================
# planar rigid-body poses
# =============================================================================================


def pose_errors(pose: np.ndarray, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """2-D position error (n,) m and absolute yaw error (n,) deg of poses (n, 3) x, y, yaw
    against reference poses (n, 3)."""
    e = np.hypot(pose[:, 0] - ref[:, 0], pose[:, 1] - ref[:, 1])
    return e, np.degrees(np.abs(wrap_angle(pose[:, 2] - ref[:, 2])))


def _summary(e: np.ndarray, ey: np.ndarray, inside: np.ndarray, offset: float) -> dict:
    ok = np.isfinite(e) & inside
    if not ok.any():
        return {"rmse_2d_m": np.nan, "yaw_rmse_deg": np.nan, "max_error_2d_m": np.nan,
                "mean_error_2d_m": np.nan, "clock_offset_s": offset, "coverage": 0.0}
    return {"rmse_2d_m": float(np.sqrt(np.mean(e[ok] ** 2))),
            "yaw_rmse_deg": float(np.sqrt(np.mean(ey[ok] ** 2))),
            "max_error_2d_m": float(np.max(e[ok])), "mean_error_2d_m": float(np.mean(e[ok])),
            "clock_offset_s": offset, "coverage": float(ok.sum() / max(inside.sum(), 1))}


def score_static(pose: np.ndarray, ref_pose: np.ndarray) -> tuple[dict, np.ndarray]:
    """Scores of poses (n, 3) against one fixed pose (3,) x, y, yaw: the summary fields
    (rmse_2d_m, yaw_rmse_deg, max/mean_error_2d_m, clock_offset_s NaN, coverage) and the 2-D
    error (n,) m."""
    r = np.broadcast_to(ref_pose, pose.shape)
    e, ey = pose_errors(pose, r)
    return _summary(e, ey, np.ones(e.size, dtype=bool), np.nan), e


def _reference_at(ref_t: np.ndarray, ref_xy: np.ndarray, ref_yaw: np.ndarray, t: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    yaw = np.unwrap(ref_yaw)
    r = np.column_stack([np.interp(t, ref_t, ref_xy[:, 0]), np.interp(t, ref_t, ref_xy[:, 1]),
                         np.interp(t, ref_t, yaw)])
    return r, (t >= ref_t[0]) & (t <= ref_t[-1])


def score_trajectory(times: np.ndarray, pose: np.ndarray, ref_t: np.ndarray,
                     ref_xy: np.ndarray, ref_yaw: np.ndarray) -> tuple[dict, np.ndarray]:
    """Scores of poses (n, 3) at ``times`` (n,) s against a reference trajectory (ref_t (M,)
    s, ref_xy (M, >=2) m, ref_yaw (M,) rad, interpolated linearly, yaw unwrapped) after one
    constant clock offset (reference time = time + offset): a grid over +-OFFSET_SPAN_S in
    OFFSET_STEP_S steps refined by a bounded scalar search, minimising the 2-D RMSE over the
    rows inside the reference (more than half of them must be). Returns the summary fields
    of :func:`score_static` (clock_offset_s the offset) and the 2-D error (n,) m; raises
    ValueError naming the reference when no offset overlaps enough rows."""
    from scipy.optimize import minimize_scalar

    def rmse(off):
        r, inside = _reference_at(ref_t, ref_xy, ref_yaw, times + off)
        e, _ = pose_errors(pose, r)
        ok = inside & np.isfinite(e)
        return float(np.sqrt(np.mean(e[ok] ** 2))) if ok.sum() > 0.5 * ok.size else np.inf

    grid = np.arange(-OFFSET_SPAN_S, OFFSET_SPAN_S + OFFSET_STEP_S / 2, OFFSET_STEP_S)
    costs = np.array([rmse(o) for o in grid])
    if not np.isfinite(costs).any():
        raise ValueError("reference: overlaps fewer than half of the ranges' rows at every "
                         f"clock offset within +-{OFFSET_SPAN_S} s")
    g = grid[int(np.argmin(costs))]
    best = minimize_scalar(rmse, bounds=(g - OFFSET_STEP_S, g + OFFSET_STEP_S),
                           method="bounded", options={"xatol": 1e-5})
    off = float(best.x) if best.fun <= costs.min() else float(g)
    r, inside = _reference_at(ref_t, ref_xy, ref_yaw, times + off)
    e, ey = pose_errors(pose, r)
    return _summary(e, ey, inside, off), e
