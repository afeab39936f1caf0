"""Correction for the lag of a sliding-window estimate (000_8f82f8df647bf685.txt, Section 3.4.2).

A window fit (Eq. 3.9) of the epochs ``t-s+1 .. t`` places each sensor at its window mean,
which on a straight line at speed v lies ``(s-1) v dt / 2`` behind the newest epoch. The
dissertation corrects it in six steps; our reading of each, with velocity and orientation
taken from the estimates themselves (never the truth):

1. The window estimate: fitted sensor positions ``P_i`` (and CG, Eq. 3.8).
2. "The distance between the first complete set of observed data for a particular sensor in
   that window and the estimate ... generates the time position in that sliding window where
   the estimate occurs." Reading: for every sensor ``i`` with data in the window, take its
   first observation in the window (the earliest epoch ``f_i`` at which it reported both
   coordinates), ``o_i``, and the distance ``dist_i = |P_i - o_i|``. Travelling at speed v,
   the estimate sits ``dist_i / v`` seconds after ``t_{f_i}``: that is its time position.
   Counting positions from 1 at the first epoch (the window holds positions 1..s), the
   position is ``1 + dist_i / (v dt)``.
3. Time remaining = window size - time position = ``s - 1 - dist_i / (v dt)`` epochs, i.e.
   ``(t_end - t_{f_i}) - dist_i / v`` seconds. (Counting from 1 is what makes step 3 exact:
   for noise-free data on a straight the remaining time is ``(s-1) dt / 2``, the known trail.
   Counting from 0 would overshoot by one epoch, v dt.) With uneven sampling we work in
   seconds throughout.
4. d = v * time remaining = ``v (t_end - t_{f_i}) - dist_i``; no division by v, so a
   stationary platform is handled. We average d over the sensors with data (the text says
   "a particular sensor"; the mean over all of them uses every sensor's information and
   reduces to the same value without noise).
5./6. Shift the estimate by ``d (cos theta, sin theta)``. The dissertation's frame has +x
   North and +y East (Figure 4.113) with theta from North, so its ``(d cos, d sin)`` is the
   shift along the heading; in our frame (x east, yaw CCW from east) that is
   ``d (cos yaw, sin yaw)``. Every sensor and the CG move by the same vector.

Velocity ("multiply the time remaining by the velocity"): the speed from the estimates, as
the causal finite difference of the window CG over ``span`` estimates (default the window
size: two windows that do not overlap, so their noise is independent); see
:func:`estimate_velocity`. Each window estimate is dated at the mean time of its window's
epochs (a property of the window, not of the truth): with even sampling that changes
nothing (consecutive windows are one dt apart either way), with uneven sampling dividing by
the difference of the newest epochs' times would mis-scale the speed by the local spacing.

Two variants, each a row in tables:

- ``"pose"`` (as written): theta = the platform orientation of Section 3.2 (law of cosines),
  distance Euclidean.
- ``"course"`` (ours): theta = the direction of the estimated velocity, and the distance in
  step 2 is the signed along-track component ``(P_i - o_i) . u``. With metre-level noise the
  orientation of a 1.5 m platform is poorly observed (../shared/notes/window-solvers.md) while
  the course over tens of metres is not; and a Euclidean distance cannot be negative, so
  step 4 is biased by the cross-track noise.

Windows of size 1 are not corrected (Section 4.12.2: "prediction and lag correction in that
case is unnecessary"); as written, step 4 would shift them by the fit residual.
"""

from __future__ import annotations

import numpy as np

from estimator._checks import check_increasing_times

__all__ = ["LAG_MODES", "estimate_velocity", "first_observations", "lag_shift"]

#: Lag-correction variants (see module docstring).
LAG_MODES = ("pose", "course")


def estimate_velocity(t: np.ndarray, xy: np.ndarray, span: int) -> np.ndarray:
    """Causal velocity of a track: ``(xy[k] - xy[k - span']) / (t[k] - t[k - span'])``.

    t : (N,) seconds (the estimates' dates), strictly increasing. xy : (N, 2) metres (NaN
    rows allowed: a NaN at either end gives NaN). span : >= 1 rows; near the start
    ``span' = min(span, k)``, so row 0 has no velocity (NaN).
    Returns (N, 2) m/s.
    """
    t = check_increasing_times(t, "t")
    xy = np.asarray(xy, dtype=float)
    if xy.ndim != 2 or xy.shape != (t.shape[0], 2):
        raise ValueError(f"xy: expected shape ({t.shape[0]}, 2), got {xy.shape}")
    if int(span) != span or span < 1:
        raise ValueError(f"span: must be an integer >= 1, got {span!r}")
    n = t.shape[0]
    k = np.arange(n)
    j = np.maximum(k - int(span), 0)
    out = np.full((n, 2), np.nan)
    ok = k > 0
    dt = t[k[ok]] - t[j[ok]]
    out[ok] = (xy[k[ok]] - xy[j[ok]]) / dt[:, None]
    return out


def first_observations(obs: np.ndarray, start: np.ndarray, end: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray]:
    """First complete observation of every sensor inside windows ``start..end`` (inclusive):
    the "first complete set of observed data for a particular sensor in that window" of
    Section 3.4.2, step 2 (module docstring).

    obs : (n, m, 2) metres, NaN = missing. start, end : (N,) int epoch indices.
    Returns ``first_obs (N, m, 2)`` (NaN where the sensor has no data in the window) and
    ``first_idx (N, m)`` int epoch indices (-1 where none).
    """
    obs = np.asarray(obs, dtype=float)
    n, m = obs.shape[:2]
    present = np.all(np.isfinite(obs), axis=-1)  # (n, m)
    # next present epoch at or after j, per sensor (n where none): reverse cumulative minimum
    cand = np.where(present, np.arange(n)[:, None], n)
    nxt = np.minimum.accumulate(cand[::-1], axis=0)[::-1]
    idx = nxt[np.asarray(start, dtype=int)]  # (N, m)
    ok = idx <= np.asarray(end, dtype=int)[:, None]
    safe = np.where(ok, idx, 0)
    first = np.where(ok[..., None], obs[safe, np.arange(m)[None, :]], np.nan)
    return first, np.where(ok, idx, -1)


def lag_shift(t: np.ndarray, positions: np.ndarray, first_obs: np.ndarray,
              first_idx: np.ndarray, t_end: np.ndarray, velocity: np.ndarray,
              heading: np.ndarray, window: np.ndarray, mode: str = "pose") -> np.ndarray:
    """Steps 2-5 of Section 3.4.2: the shift (N, 2) metres to add to each window estimate.

    t : (n,) epoch times. positions : (N, m, 2) fitted sensor positions of each window.
    first_obs, first_idx : from :func:`first_observations`. t_end : (N,) time of each
    window's newest epoch. velocity : (N, 2) m/s from the estimates. heading : (N,) yaw
    (rad, CCW from +x) used by ``mode="pose"``. window : (N,) window sizes (size 1: no shift).
    Sensors without data in a window are skipped; a window with no usable sensor, or
    without a velocity, gets NaN (the caller reports the uncorrected estimate and says so).
    """
    if mode not in LAG_MODES:
        raise ValueError(f"mode: must be one of {LAG_MODES}, got {mode!r}")
    t = np.asarray(t, dtype=float)
    ok = first_idx >= 0
    T = np.where(ok, t_end[:, None] - t[np.where(ok, first_idx, 0)], np.nan)  # (N, m) seconds
    diff = positions - first_obs  # (N, m, 2)
    speed = np.hypot(velocity[:, 0], velocity[:, 1])
    if mode == "pose":
        dist = np.hypot(diff[..., 0], diff[..., 1])  # step 2, Euclidean
        u = np.stack([np.cos(heading), np.sin(heading)], axis=-1)
    else:
        with np.errstate(invalid="ignore", divide="ignore"):
            u = velocity / speed[:, None]
        u = np.where(speed[:, None] > 0, u, np.nan)
        # signed along-track component (the two-term sum of einsum "nmk,nk->nm" written
        # out, from +0 as einsum's: the same numbers, several times faster on (N, m, 2))
        dist = (diff[..., 0] * u[:, None, 0] + 0.0) + diff[..., 1] * u[:, None, 1]
    d_i = speed[:, None] * T - dist  # step 4 per sensor, metres
    with np.errstate(invalid="ignore"):
        cnt = np.isfinite(d_i).sum(axis=1)
        d = np.where(cnt > 0, np.nansum(d_i, axis=1) / np.maximum(cnt, 1), np.nan)
    shift = d[:, None] * u  # step 5
    if mode == "course":
        # standing still: no direction of travel, and nothing to catch up with
        shift = np.where(((speed == 0) & ok.any(axis=1))[:, None], 0.0, shift)
    return np.where((np.asarray(window) <= 1)[:, None], 0.0, shift)
