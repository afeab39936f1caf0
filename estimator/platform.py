"""The platform's limits and its travel axis, given by the caller or estimated from the data.

The pose filter (:mod:`estimator.pose_filter`) takes its process noise, state bounds and
(through the innovation covariance) its gates from the platform's speed, acceleration and
turn-rate limits (Bar-Shalom, Li and Kirubarajan 2001, Section 6.3). A configuration or a
recording states them in a ``[platform]`` block (:meth:`PlatformLimits.from_dict`); where
none is given they are estimated from the recording itself (:func:`estimate_limits`): the
rigid fit of the layout to every epoch gives a pose per epoch, whose changes over about one
second give speed, acceleration, yaw rate, yaw acceleration and lateral acceleration; the
limits are robust high percentiles of those with a margin, floored (a platform standing
still all the time still gets a usable filter) and capped (a metre-level error that makes a
few fits jump must not claim a 10 g car).

:func:`estimate_travel_axis` estimates, from the same fits, the direction in which the
platform travels in the layout's body frame (a frame mounted a few degrees off the car's
axis, issue 25) and how far ahead of the no-slip point (the rear axle) the layout's CG sits:
regress the CG's lateral body velocity on its forward velocity and the yaw rate.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields

import numpy as np

from estimator.epoch_fit import epoch_rigid_fits

__all__ = ["CURVATURE_FLOOR_1PM", "FALLBACK_TURN_RATE_RADPS", "FLOORS", "PlatformLimits",
           "TravelAxis",
           "estimate_limits", "estimate_travel_axis"]

#: Closed ranges of the limits (SI): a creeping platform to ~1000 g.
LIMIT_RANGE = (1e-6, 1e4)
#: Floors of estimated limits (speed m/s, accel m/s^2, turn rate rad/s, yaw accel rad/s^2,
#: lateral accel m/s^2, jerk m/s^3): a platform that barely moved in the recording is still
#: allowed to start (0.5 m/s^2 and 0.3 rad/s: the project's slowest rover,
#: models/paths/square100).
FLOORS = (0.5, 0.5, 0.3, 0.5, 0.5, 0.5)
#: Caps of estimated limits (same order): 60 m/s, 1 g, 3 rad/s, 10 rad/s^2, 1 g, 2 g/s.
CAPS = (60.0, 9.81, 3.0, 10.0, 9.81, 20.0)
#: Margin on the robust percentile (the recording rarely shows the limit itself).
MARGIN = 1.25
#: Percentile of the per-interval values taken as the observed extreme (p99: one sample in
#: a hundred may be a bad fit).
PERCENTILE = 99.0
#: Turn rate when the layout cannot give the heading (consumer noise on a small frame), rad/s.
FALLBACK_TURN_RATE_RADPS = 1.0
#: Fewest intervals for an estimate (below: floors / fallback).
MIN_INTERVALS = 30
#: Heading sd of a fit below which its yaw is used for rates, rad (3 deg).
MAX_FIT_YAW_SD = math.radians(3.0)
#: Travel axis: largest standard error of the offset (rad) and of the lever (m) accepted.
MAX_AXIS_SE_RAD = math.radians(0.5)
MAX_LEVER_SE_M = 0.2
#: Contiguous stretches of the batch-means standard errors of the travel axis.
AXIS_BLOCKS = 10
#: The offset is used only when it is this many standard errors from 0 (else 0: a layout
#: mounted along the axis must not get a noise-made offset).
AXIS_SIGMAS = 3.0

#: Floor of an estimated curvature limit, 1/m (a 20 m turning radius: wider than any road
#: vehicle's turning circle, so a recording that never turned sharply still allows a turn).
CURVATURE_FLOOR_1PM = 0.05
#: Course changes count for the curvature only over intervals whose travel exceeds this many
#: sd of a displacement (course sd below 1/10 rad).
CURVATURE_MIN_SIGMAS = 10.0

_NAMES = ("max_speed_mps", "max_accel_mps2", "max_turn_rate_radps", "max_yaw_accel_radps2",
          "max_lateral_accel_mps2", "max_jerk_mps3", "max_curvature_1pm")
#: Limits that may be None (unbounded).
_OPTIONAL = ("max_jerk_mps3", "max_curvature_1pm")


@dataclass(frozen=True)
class PlatformLimits:
    """Speed (m/s), longitudinal acceleration (m/s^2), turn rate (rad/s), yaw acceleration
    (rad/s^2) and lateral acceleration (m/s^2) limits of a ground platform, each finite and
    in :data:`LIMIT_RANGE`. ``max_yaw_accel_radps2`` None: the turn rate reached in 1 s;
    ``max_lateral_accel_mps2`` None: the longitudinal limit; ``max_jerk_mps3`` (m/s^3) None:
    the acceleration may change by its whole range within a sample (the filter's model before
    issue 25). ``source``: "given" or "data"."""

    max_speed_mps: float
    max_accel_mps2: float
    max_turn_rate_radps: float
    max_yaw_accel_radps2: float | None = None
    max_lateral_accel_mps2: float | None = None
    max_jerk_mps3: float | None = None
    max_curvature_1pm: float | None = None
    source: str = "given"

    def __post_init__(self) -> None:
        if self.max_yaw_accel_radps2 is None:
            object.__setattr__(self, "max_yaw_accel_radps2", self.max_turn_rate_radps)
        if self.max_lateral_accel_mps2 is None:
            object.__setattr__(self, "max_lateral_accel_mps2", self.max_accel_mps2)
        for name in _NAMES:
            v = getattr(self, name)
            if v is None and name in _OPTIONAL:
                continue
            if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)):
                raise ValueError(  # noqa: TRY004 (project contract: bad input is ValueError)
                    f"{name}: must be a number, got {v!r}")
            if not (LIMIT_RANGE[0] <= float(v) <= LIMIT_RANGE[1]):
                raise ValueError(f"{name}: must be in [{LIMIT_RANGE[0]:g}, {LIMIT_RANGE[1]:g}] "
                                 f"(SI units), got {v!r}")
            object.__setattr__(self, name, float(v))
        if self.source not in ("given", "data"):
            raise ValueError(f"source: must be 'given' or 'data', got {self.source!r}")

    @classmethod
    def from_dict(cls, data: object, where: str = "platform") -> PlatformLimits:
        """From a TOML ``[platform]`` table: keys :data:`_NAMES` (the first three required);
        an unknown or missing key is a ValueError naming ``where.key``."""
        if not isinstance(data, Mapping):
            raise ValueError(  # noqa: TRY004 (project contract: bad input is ValueError)
                f"{where}: must be a table, got {type(data).__name__}")
        allowed = {f.name for f in fields(cls)} - {"source"}
        for k in data:
            if k not in allowed:
                raise ValueError(f"{where}.{k}: unknown key (allowed: {sorted(allowed)})")
        for k in _NAMES[:3]:
            if k not in data:
                raise ValueError(f"{where}.{k}: required (SI units)")
        try:
            return cls(**dict(data))
        except ValueError as e:
            raise ValueError(f"{where}.{e}") from None

    def to_dict(self) -> dict:
        """The limits as plain floats or None (the filter's
        :meth:`PoseFilterParams.from_limits`)."""
        return {k: getattr(self, k) for k in _NAMES}


def _intervals(t: np.ndarray, origin: np.ndarray, yaw: np.ndarray, ok_yaw: np.ndarray
               ) -> tuple[np.ndarray, ...]:
    """Pairs of fitted epochs about 1 s apart (lag L = round(1 s / dt), at least 1 sample,
    time gap at most 1.5 L dt): (k, j, dt (N,), CG displacement (N, 2), heading change (N,)
    NaN where either heading is imprecise, mean heading (N,))."""
    n = t.size
    dt_med = float(np.median(np.diff(t))) if n > 1 else 1.0
    lag = max(1, round(1.0 / dt_med))
    k = np.arange(max(n - lag, 0))
    j = k + lag
    dt = t[j] - t[k]
    good = np.isfinite(origin[k, 0]) & np.isfinite(origin[j, 0]) & (dt <= 1.5 * lag * dt_med)
    k, j, dt = k[good], j[good], dt[good]
    d = origin[j] - origin[k]
    dyaw = np.angle(np.exp(1j * (yaw[j] - yaw[k])))
    dyaw = np.where(ok_yaw[k] & ok_yaw[j], dyaw, np.nan)
    ymean = yaw[k] + 0.5 * np.angle(np.exp(1j * (yaw[j] - yaw[k])))
    return k, j, dt, d, dyaw, ymean


def _robust_max(x: np.ndarray, floor: float, cap: float) -> float | None:
    x = np.abs(x[np.isfinite(x)])
    if x.size < MIN_INTERVALS:
        return None
    return float(min(max(MARGIN * np.percentile(x, PERCENTILE), floor), cap))


def _fits(obs: np.ndarray, offsets: np.ndarray, sigma_abs: float):
    """Per-epoch rigid fits (origin (n, 2) = the offsets' origin, yaw (n,)) and which yaws
    are precise (heading sd sigma_abs / sqrt(sum |r_i - rbar|^2) of the present antennas <=
    :data:`MAX_FIT_YAW_SD`)."""

    origin, yaw, cnt, _ = epoch_rigid_fits(obs, offsets)
    present = np.isfinite(obs[..., 0])
    with np.errstate(invalid="ignore", divide="ignore"):
        rbar = (present.astype(float) @ offsets) / present.sum(1)[:, None]
        spread = (((offsets[None] - rbar[:, None]) ** 2).sum(-1) * present).sum(1)
        yaw_sd = np.where((cnt >= 2) & (spread > 0), sigma_abs / np.sqrt(spread), np.inf)
    return origin, yaw, yaw_sd <= MAX_FIT_YAW_SD


#: Cap of an estimated curvature, 1/m (a 0.1 m turning radius: beyond it, on the spot).
CURVATURE_CAP_1PM = 10.0


def _curvature(tt: np.ndarray, origin: np.ndarray, yaw: np.ndarray, ok_yaw: np.ndarray,
               present: np.ndarray, sigma_d: float) -> float | None:
    """Curvature limit, 1/m: ``MARGIN x p99`` of the course change between consecutive ~1 s
    intervals over their mean travel, both travelling more than :data:`CURVATURE_MIN_SIGMAS`
    x ``sigma_d`` (m, sd of an interval's displacement) with the same antennas (``present``
    (n, m)) at both ends (a fit of another subset moves by the antennas' own errors), clipped to
    [:data:`CURVATURE_FLOOR_1PM`, :data:`CURVATURE_CAP_1PM`]. None (unbounded) when more
    than ``100 - PERCENTILE`` % of the precise-heading intervals turn at the turn-rate floor
    or faster without that travel (a platform turning on the spot), or too few intervals."""
    k, j, dt, d, dyaw, _ = _intervals(tt, origin, yaw, ok_yaw)
    dist = np.hypot(d[:, 0], d[:, 1])
    same = (present[k] == present[j]).all(axis=1)
    travelled = dist >= CURVATURE_MIN_SIGMAS * sigma_d
    moving = travelled & same
    turns = np.isfinite(dyaw)
    pivot = turns & ~travelled & (np.abs(dyaw) >= FLOORS[2] * dt)
    if turns.any() and pivot.sum() > (1.0 - PERCENTILE / 100.0) * turns.sum():
        return None
    course = np.full(tt.size, np.nan)
    dist_full = np.full(tt.size, np.nan)
    course[k[moving]] = np.arctan2(d[moving, 1], d[moving, 0])
    dist_full[k] = dist
    kk, jj, _, _, dcourse, _ = _intervals(tt, np.c_[dist_full, dist_full], course,
                                          np.isfinite(course))
    mean_dist = 0.5 * (dist_full[kk] + dist_full[jj])
    with np.errstate(invalid="ignore", divide="ignore"):
        kappa = np.abs(dcourse) / mean_dist
    return _robust_max(kappa, CURVATURE_FLOOR_1PM, CURVATURE_CAP_1PM)


def estimate_limits(t: np.ndarray, obs: np.ndarray, offsets: np.ndarray, sigma_abs: float,
                    sigma_step: float | None = None) -> PlatformLimits:
    """Limits from the recording (module docstring): t (n,) s, obs (n, m, 2) m (NaN
    missing), offsets (m, 2) m, sigma_abs the per-axis fix noise (m; e.g.
    :func:`estimator.pose_filter.estimate_noise`). Over intervals of ~1 s between fitted
    epochs: speed of the CG, its change (acceleration) and the change of that (jerk), yaw
    rate and its change (only where both fits' headings are precise), speed x yaw rate
    (lateral); each limit is
    ``MARGIN x p99`` clipped to [:data:`FLOORS`, :data:`CAPS`]. Without precise headings the
    turn rate is :data:`FALLBACK_TURN_RATE_RADPS`, yaw acceleration = turn rate / 1 s,
    lateral acceleration = the longitudinal limit. The curvature from the course changes
    (:func:`_curvature`; ``sigma_step``, m, the per-axis sd of a fix's change over one sample,
    default ``sigma_abs sqrt(2)``, sets which intervals travelled). Returns ``source="data"``
    limits."""
    tt = np.asarray(t, dtype=float)
    origin, yaw, ok_yaw = _fits(obs, offsets, sigma_abs)
    k, _, dt, d, dyaw, _ = _intervals(tt, origin, yaw, ok_yaw)
    speed = np.hypot(d[:, 0], d[:, 1]) / dt if dt.size else np.zeros(0)
    omega = dyaw / dt if dt.size else np.zeros(0)
    sp_full = np.full(tt.size, np.nan)
    om_full = np.full(tt.size, np.nan)
    sp_full[k], om_full[k] = speed, omega
    k2, j2, dt2, _, _, _ = _intervals(tt, np.c_[sp_full, om_full], np.zeros(tt.size),
                                      np.ones(tt.size, bool))
    accel = (sp_full[j2] - sp_full[k2]) / dt2
    yacc = (om_full[j2] - om_full[k2]) / dt2
    ac_full = np.full(tt.size, np.nan)
    ac_full[k2] = accel
    k3, j3, dt3, _, _, _ = _intervals(tt, np.c_[ac_full, ac_full], np.zeros(tt.size),
                                      np.ones(tt.size, bool))
    jerk = (ac_full[j3] - ac_full[k3]) / dt3
    vals = (speed, accel, omega, yacc, speed * omega, jerk)
    est = [_robust_max(v, lo, hi) for v, lo, hi in zip(vals, FLOORS, CAPS, strict=True)]
    dt_med = float(np.median(np.diff(tt))) if tt.size > 1 else 1.0
    ss = sigma_step if sigma_step is not None else sigma_abs * math.sqrt(2.0)
    lag = max(1, round(1.0 / dt_med))
    kappa = _curvature(tt, origin, yaw, ok_yaw, np.isfinite(obs[..., 0]), ss * math.sqrt(lag))
    v_max = est[0] if est[0] is not None else FLOORS[0]
    a_max = est[1] if est[1] is not None else FLOORS[1]
    w_max = est[2] if est[2] is not None else FALLBACK_TURN_RATE_RADPS
    return PlatformLimits(max_speed_mps=v_max, max_accel_mps2=a_max, max_turn_rate_radps=w_max,
                          max_yaw_accel_radps2=est[3] if est[3] is not None else w_max,
                          max_lateral_accel_mps2=est[4] if est[4] is not None else a_max,
                          max_jerk_mps3=est[5], max_curvature_1pm=kappa, source="data")


@dataclass(frozen=True)
class TravelAxis:
    """Direction of travel in the layout's body frame, ``offset_rad`` (CCW from the layout's
    x axis), the CG's distance ahead of the no-slip point along it, ``lever_m``, their
    standard errors and the number of intervals used; ``known`` False when the data do not
    determine the offset (then 0)."""

    offset_rad: float
    lever_m: float
    offset_se_rad: float
    lever_se_m: float
    n: int
    known: bool

    def no_slip_point(self) -> tuple[float, float]:
        """The no-slip point in the layout's body frame relative to the CG, m."""
        return (-self.lever_m * math.cos(self.offset_rad),
                -self.lever_m * math.sin(self.offset_rad))


def _huber_fit(A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, float]:
    """Huber-weighted least squares b ~ A x (3 passes, k = 1.5 robust sd): (x, scale)."""
    wts = np.ones(b.size)
    scale = 0.0
    for _ in range(3):
        sol, *_ = np.linalg.lstsq(A * wts[:, None], b * wts, rcond=None)
        r = b - A @ sol
        scale = 1.4826 * float(np.median(np.abs(r))) + 1e-12
        wts = np.sqrt(np.minimum(1.0, 1.5 * scale / np.maximum(np.abs(r), 1e-300)))
    return sol, scale


def estimate_travel_axis(t: np.ndarray, obs: np.ndarray, offsets: np.ndarray,
                         sigma_abs: float) -> TravelAxis:
    """The travel axis from the per-epoch rigid fits (module docstring): over ~1 s
    intervals with precise headings and a CG speed of at least 1 m/s and 20 sd of its
    noise, the CG's body-frame velocity (u_x, u_y) and the yaw rate w satisfy
    ``u_y = tan(offset) u_x + lever w`` (no-slip point behind the CG on the travel axis);
    Huber-weighted least squares, standard errors by batch means over :data:`AXIS_BLOCKS`
    stretches. offsets (m, 2) relative to the CG. The offset is not known (0) with an se
    above :data:`MAX_AXIS_SE_RAD` or within :data:`AXIS_SIGMAS` se of 0 (the lever is then
    fitted alone, ``u_y = lever w``); the lever is kept only with se <=
    :data:`MAX_LEVER_SE_M`; both 0 with fewer than :data:`MIN_INTERVALS` intervals."""
    tt = np.asarray(t, dtype=float)
    origin, yaw, ok_yaw = _fits(obs, offsets, sigma_abs)
    _, _, dt, d, dyaw, ym = _intervals(tt, origin, yaw, ok_yaw)
    c, s = np.cos(ym), np.sin(ym)
    ux = (c * d[:, 0] + s * d[:, 1]) / dt
    uy = (-s * d[:, 0] + c * d[:, 1]) / dt
    w = dyaw / dt
    noise = sigma_abs * math.sqrt(2.0) / np.maximum(dt, 1e-9)
    use = np.isfinite(w) & (np.abs(ux) >= np.maximum(1.0, 20.0 * noise))
    none = TravelAxis(0.0, 0.0, math.inf, math.inf, int(use.sum()), False)
    if use.sum() < MIN_INTERVALS:
        return none
    A = np.c_[ux[use], w[use]]
    b = uy[use]
    sol, _ = _huber_fit(A, b)
    # standard errors by batch means over AXIS_BLOCKS contiguous stretches: GNSS errors are
    # correlated over tens of seconds, so the least-squares se (independent rows) is far too
    # small (car_block, 45 s of 1.5 cm fixes: LS se 0.05 deg, the estimate 0.32 deg off)
    blocks = np.array_split(np.arange(b.size), AXIS_BLOCKS)
    est = np.array([_huber_fit(A[i], b[i])[0] for i in blocks if i.size >= 10])
    if est.shape[0] < 3:
        return none
    se = est.std(axis=0, ddof=1) / math.sqrt(est.shape[0])
    off = math.atan(sol[0])
    known = bool(np.isfinite(sol).all() and se[0] <= MAX_AXIS_SE_RAD
                 and abs(off) > AXIS_SIGMAS * se[0])
    lever, lever_se = float(sol[1]), float(se[1])
    if not known:
        # the layout is along the travel axis as far as the data tell: the lever alone
        off = 0.0
        lever = float(_huber_fit(A[:, 1:], b)[0][0])
        lever_se = float(np.std([_huber_fit(A[i, 1:], b[i])[0][0] for i in blocks
                                 if i.size >= 10], ddof=1) / math.sqrt(est.shape[0]))
    if not lever_se <= MAX_LEVER_SE_M:
        lever = 0.0
    return TravelAxis(off, lever, float(se[0]), lever_se, int(use.sum()), known)
