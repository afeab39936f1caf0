"""Turn detection from estimates alone, for the dynamic sliding window on real logs.

The dissertation switches to a small window while the platform turns and takes the turning
information from "the control information of the mobile platform" (000_8f82f8df647bf685.txt,
Section 3.4.2.1). A real log has no controller flag, so this module derives one from the
estimated heading: the heading rate is the causal least-squares slope of the unwrapped
heading over the last ``span_s`` seconds, and a hysteresis switch turns the flag on when
``|rate| >= rate_on`` and off again when ``|rate| < rate_off`` (``rate_off <= rate_on``), so
noise near one threshold does not make the flag chatter.

Which heading to feed it (both are "computed from the estimates"):

- ``course_heading``: direction of the CG displacement over ``span_s`` seconds; robust when
  antenna errors are larger than the platform, meaningless when standing still (NaN below
  ``min_speed``).
- the fitted pose's yaw (the ``yaw`` column of a track): works at rest, but is noisy when the
  independent part of the antenna error approaches the platform size.

Being causal, the regression reports a turn about ``span_s / 2`` late; that delay is the
price of running on-line and is part of what the detector's evaluation measures.
"""

from __future__ import annotations

import math

import numpy as np

from estimator._checks import check_increasing_times, check_real
from estimator.orientation import unwrap_angle

__all__ = ["course_heading", "detect_turns", "heading_rate", "hysteresis"]


def _check_t(t: object, n: int | None = None) -> np.ndarray:
    return check_increasing_times(t, "t", n)


def heading_rate(t: object, heading: object, span_s: float) -> np.ndarray:
    """Causal heading rate (rad/s): LS slope of the unwrapped heading over ``(t_k - span_s, t_k]``.

    t : (n,) s, heading : (n,) rad (NaN allowed; NaN samples drop out of the regression).
    Returns (n,) rad/s, NaN where fewer than two finite samples fall in the span.
    """
    tt = _check_t(t)
    h = np.asarray(heading, dtype=float)
    if h.shape != tt.shape:
        raise ValueError(f"heading: expected shape {tt.shape}, got {h.shape}")
    span_s = check_real(span_s, "span_s", lo=0.0, lo_open=True)
    if tt.size == 0:
        return np.zeros(0)
    hu = unwrap_angle(h)
    ok = np.isfinite(hu)
    x = np.where(ok, tt - tt[0], 0.0)
    y = np.where(ok, hu - (hu[ok][0] if ok.any() else 0.0), 0.0)
    w = ok.astype(float)

    def csum(a: np.ndarray) -> np.ndarray:
        return np.concatenate([[0.0], np.cumsum(a)])

    C = [csum(v) for v in (w, w * x, w * y, w * x * x, w * x * y)]
    hi = np.arange(1, tt.size + 1)
    lo = np.searchsorted(tt, tt - span_s, side="right")
    S0, Sx, Sy, Sxx, Sxy = (c[hi] - c[lo] for c in C)
    den = S0 * Sxx - Sx * Sx
    with np.errstate(invalid="ignore", divide="ignore"):
        rate = (S0 * Sxy - Sx * Sy) / den
    return np.where((S0 >= 2) & (den > 1e-12 * np.maximum(S0 * Sxx, 1e-300)), rate, np.nan)


def hysteresis(signal: object, on: float, off: float) -> np.ndarray:
    """Boolean switch: True once ``signal >= on``, False again once ``signal < off``.

    signal : (n,) (NaN keeps the previous state; the initial state is False).
    """
    sig = np.asarray(signal, dtype=float)
    if sig.ndim != 1:
        raise ValueError(f"signal: expected shape (n,), got {sig.shape}")
    on, off = check_real(on, "on"), check_real(off, "off")
    if off > on:
        raise ValueError(
            f"on/off: need finite thresholds with off <= on, got on={on!r}, off={off!r}")
    out = np.zeros(sig.shape, dtype=bool)
    state = False
    for k, v in enumerate(sig):
        if not math.isnan(v):
            state = v >= off if state else v >= on
        out[k] = state
    return out


def course_heading(t: object, xy: object, span_s: float, min_speed: float = 0.1
                   ) -> np.ndarray:
    """Direction of travel (rad, CCW from +x): atan2 of ``xy[k] - xy[j]`` where ``t_j`` is
    the latest time ``<= t_k - span_s``; NaN at the start, where xy is NaN, or where the mean
    speed over the span is below ``min_speed`` m/s.

    t : (n,) s, xy : (n, 2) metres.
    """
    tt = _check_t(t)
    p = np.asarray(xy, dtype=float)
    if p.shape != (tt.size, 2):
        raise ValueError(f"xy: expected shape ({tt.size}, 2), got {p.shape}")
    span_s = check_real(span_s, "span_s", lo=0.0, lo_open=True)
    min_speed = check_real(min_speed, "min_speed", lo=0.0)
    j = np.searchsorted(tt, tt - span_s, side="right") - 1
    ok = j >= 0
    js = np.where(ok, j, 0)
    d = p - p[js]
    dt = tt - tt[js]
    with np.errstate(invalid="ignore", divide="ignore"):
        fast = np.hypot(d[:, 0], d[:, 1]) >= min_speed * dt
    out = np.arctan2(d[:, 1], d[:, 0])
    return np.where(ok & fast & np.all(np.isfinite(d), axis=1), out, np.nan)


def detect_turns(t: object, heading: object, *, rate_on: float = 0.05, rate_off: float = 0.025,
                 span_s: float = 8.0) -> np.ndarray:
    """Turning flags (n,) bool from a heading series: :func:`heading_rate` then
    :func:`hysteresis` on ``|rate|``.

    Defaults (0.05 rad/s on, 0.025 rad/s off, 8 s span) are the ones chosen for the
    simulated rover (see ``estimator.tracking.DETECTOR_DEFAULTS``); a straight has zero
    rate, so the thresholds sit where the heading noise of the estimate allows. Tune them
    per platform.
    """
    rate = heading_rate(t, heading, span_s)
    return hysteresis(np.abs(rate), rate_on, rate_off)
