"""Extended Kalman filter on the antennas with the sensor configuration as measurement model.

The dissertation's future work (000_8f82f8df647bf685.txt, Section 5.2): "a system that takes
advantage of extended Kalman Filter and the quadratic optimization framework using sensor
configuration knowledge". Here the configuration enters the measurement model directly, and
the filter is built to hold its heading on any wheeled platform, from a 0.2 m/s rover to a
20 m/s car (issue 14). Its smoother (fixed-lag and full RTS) is :mod:`estimator.pose_smoother`.

State and non-holonomic constraint
----------------------------------
``x = (px, py, yaw, v, a, omega)``: position (m) of the platform's *no-slip point* M,
heading (rad, CCW from +x), speed of M along the heading (m/s), its rate of change (m/s^2)
and the yaw rate (rad/s). M is the point of the body whose velocity has no lateral
component: the middle of the driven axle of a differential drive (the rover's axle passes
under its CG), the middle of the rear axle of a car. Writing the velocity of M as
``v (cos yaw, sin yaw)`` with no lateral term IS the non-holonomic constraint, exactly (a
hard constraint, not a soft prior). Every other body point moves sideways in a turn: the
CG, ``b_cg - b_M`` ahead of M, at ``omega (b_cg - b_M)_x``. M is given in
:attr:`PoseFilterParams.no_slip_point_m` (body frame, relative to the configuration's CG;
(0, 0) for the rover, (-1.3, 0) for models/car.xml). Tyre slip (a real car's rear axle slides
by a few tenths of a degree to a few degrees at high lateral acceleration) violates the
constraint and enters as model error.

Motion model: constant turn rate and acceleration (CTRA) over each step, integrated exactly.
With ``q = omega dt`` and ``F_k(q) = integral_0^1 u^(k-1) exp(i q u) du`` (complex, x + i y;
:func:`motion_integrals`),

    p' = p + exp(i yaw) (v dt F1(q) + a dt^2 F2(q)),  yaw' = yaw + q,  v' = v + a dt,
    a' = a,  omega' = omega.

The acceleration is in the state because a vehicle accelerates at its limit for seconds
(a car from 5 to 15 m/s at 3 m/s^2): a constant-velocity filter then lags, and at 10 Hz with
centimetre fixes it fails its own gates (measured on models/paths/car_block.toml: ~100
restarts per run with constant velocity, none with CTRA).

Process noise and gates from the platform's limits (never tuned on truth)
-------------------------------------------------------------------------
Bar-Shalom, Li and Kirubarajan, *Estimation with Applications to Tracking and Navigation*
(2001), Section 6.3: discrete-time process noise whose sd is "of the order of" the largest
change the platform can make, in ``[0.5, 1]`` of it; we take the lower end, a ground
vehicle spending most of its time below its limits:

- along the heading, the discrete Wiener-process acceleration model (6.3.3): the
  acceleration changes between samples by a random increment of sd ``max_accel_mps2 / 2``
  (it can switch from 0 to the limit from one sample to the next), gain
  ``(dt^2/2 cos yaw, dt^2/2 sin yaw, 0, dt, 1, 0)``; over a longer gap the increments add
  (variance times ``dt / dt_median``);
- in yaw, the discrete white-noise acceleration model (6.3.2): a yaw acceleration of sd
  ``max_yaw_accel_radps2 / 2``, constant over the sample (the rate-limited turn command of
  a wheeled platform changes smoothly over a turn, which lasts longer than a sample), gain
  ``(-v dt^3/6 sin yaw, v dt^3/6 cos yaw, dt^2/2, 0, 0, dt)``: it turns the platform and,
  through the turn over the sample, moves M sideways (at 1 Hz and 1.5 m/s by 0.125 m per
  sd; without that term the filter is sure of its lateral position at the onset of a sharp
  turn and rejects centimetre fixes that are right).

The limits also bound the state, by projection after each update: ``|a| <= max_accel_mps2``
and ``|omega| <= min(max_turn_rate_radps, max_lateral_accel_mps2 / |v|)`` (the lateral
acceleration ``v omega``). With a curvature limit (``max_curvature_1pm``: a steered car,
not a platform that turns on the spot) the no-slip kinematics also bound the yaw rate by
``kappa |v|`` (:func:`_bound_yaw_rate`, before each prediction: where that is below the
turn-rate limit the yaw rate, its variance and its process noise are kept within it, ``v``
taken by its second moment over the step), so at rest the predicted heading sd grows only
as far as the speed's uncertainty lets the car move. Gates are chi-square tests on the
innovation covariance, which carries that process noise, so they widen with the platform's
agility and the time since the last update. The limits come from the vehicle: the path
file's ``max_accel_mps2``, ``max_turn_rate_radps``, ``max_lateral_accel_mps2`` and the
controller's yaw-acceleration limit (the sweep reads them from the simulated vehicle;
:meth:`PoseFilterParams.from_limits`).

Measurements and stochastic cloning
-----------------------------------
For every antenna ``i`` with body offset ``r_i`` from M:

- its fix, ``z_i = p + R(yaw) r_i + e``, ``e ~ N(0, sigma_abs^2 I)``; Jacobian
  ``[I, J R r_i, 0, 0, 0]`` (J the 90 degree rotation);
- if it also reported at the previous epoch, its displacement, ``z_i(t_k) - z_i(t_(k-1)) =
  (p_k + R(yaw_k) r_i) - (p_(k-1) + R(yaw_(k-1)) r_i) + e``, sd ``sigma_step``. It contains
  the same antenna's fix error at k, so the two are correlated (cross-covariance
  ``min(sigma_step^2 / 2, sigma_abs^2)`` per axis, :func:`fix_step_covariance`), which the
  update's joint noise covariance carries (issue 25).

The displacement involves two epochs, so the filter keeps the previous state beside the
current one (stochastic cloning, Roumeliotis and Burdick 2002): each epoch predicts
``x_k`` from ``x_(k-1)`` and updates the stacked ``(x_k, x_(k-1))``, whose covariance
``[[F P F^T + Q, F P], [P F^T, P]]`` is singular (the update is in gain form). The
displacement is then exact, whatever the platform did between the samples; the motion
model enters only through the prediction and its process noise. (Expressing the
displacement through the current speed and yaw rate instead needs constant motion over the
sample; at 1 Hz a platform entering a sharp turn breaks that, measured on square20 with
centimetre fixes: the track was lost at every corner.) Updates are robust
(:func:`kalman_update`: prior gate and leave-one-out test) and iterated while they turn the
heading far (:func:`_iterated_update`).

Why the displacements: GNSS position errors are strongly correlated in time (multipath and
atmosphere change over minutes; the dissertation's Section 4.3 sees no "sharp jaggedness"),
so one antenna's error changes little from one sample to the next even when it is metres
large. Its epoch-to-epoch displacement therefore measures the platform's motion far better
than two absolute fixes do, and with the non-holonomic constraint the direction of motion is
the heading; differences between antennas' displacements measure the turn through the
configuration. (The correlation of a displacement with the fix at the previous epoch,
already used there, and the slow drift of the error are left out of the model; the second
is what limits the heading, see the README. With white noise and the true sigmas the NIS
stays above its dof mostly through a few manoeuvre epochs: the motion model's surprises.)

Noise levels from the data through the configuration (no truth, no tuning)
--------------------------------------------------------------------------
``sigma_abs`` and ``sigma_step`` default to :func:`estimate_noise`: the rigid fit of the
configuration to every epoch leaves residuals that are each antenna's own error (the error
all antennas share moves the fit and cancels); their robust scale is ``sigma_abs``, and the
robust scale of each antenna's residual change between consecutive epochs is ``sigma_step``.
This is a calibration over the whole recording (two numbers); a strictly on-line user passes
the receivers' values instead.

Forward speed that cannot flip silently
---------------------------------------
With ``reverse=False`` (a platform that does not reverse: the default) the speed is
non-negative: at every epoch (after an update, and on rows predicted through an outage,
where ``v + a dt`` of a braking platform passes 0) a negative speed is projected to 0. A
heading that is off by pi shows as sustained backward travel: when the distance the no-slip
point travelled backwards (its displacement from the previous pose along the heading, both
re-estimated with the epoch's data) over consecutive intervals exceeds the start's motion
threshold (:data:`INIT_MOTION_SIGMAS` sd of a displacement between two fits), the layout's own
size (its largest antenna distance) and the travel of one sample at the acceleration limit
(``a_max dt^2``: the filter's own overshoot when the platform stops; with centimetre fixes the
statistical threshold alone is a few centimetres, which such a transient exceeds), the state is
turned around, ``yaw += pi, v = -v, a = -a`` (the same motion, the covariance mapped by
``diag(1, 1, 1, -1, -1, 1)``), and the epoch's status is ``"flip_corrected"``: reported, never
silent. (A single significant negative speed is not enough: a car standing still with
centimetre fixes shows -1 cm/s at 3 sd now and then.) With ``reverse=True`` the speed is signed
(negative = reversing) and the direction is decided by the configuration: a running
log-likelihood ratio of the antennas' fixes under the heading and under the heading + pi
(exponential forgetting over ``flip_memory_s``) flips the state when the reversed pose is more
likely by ``chi2_1(gate_prob)``; also reported as ``"flip_corrected"``.

Initialisation waits for data, resets are reported
--------------------------------------------------
The filter starts at the first epoch where the heading is known: either the configuration
fixes it (heading sd ``sigma_abs / sqrt(sum |r_i|^2)`` below :data:`INIT_MAX_YAW_SD`, e.g.
centimetre receivers; then at the second of two consecutive epochs with fits, which give the
speed) or the platform has moved, relative to the first fix, by more than
:data:`INIT_MOTION_SIGMAS` times the sd of that displacement (then heading = course). Before
that, rows are NaN with status ``"waiting"`` (``"no_data"`` when no antenna reported), so a
recording that starts inside an outage, or a receiver that starts late, simply starts later.
If every fix (or every displacement) is rejected for ``max_rejects`` consecutive epochs, or the
heading's sd has grown beyond :data:`LOST_YAW_SD` (a few seconds without any fix: the
prediction, acceleration included, means nothing any more), the track is lost: the filter
returns to waiting and restarts from the data (status ``"reset"`` on the restart epoch).
Two rules keep a lost or missed track short (issue 25). A motion-model miss: when every fix
of an epoch fails its gate together while the epoch's own rigid fit agrees with the layout
(chi-square of its residuals) and gives the heading to :data:`MAX_FIT_YAW_SD`, the data are
right and the prediction wrong (a hard acceleration beyond the limits): the filter
re-initialises from the fit at once (status ``"reinit"``, :meth:`FilterStart.refit`, whose
yaw rate comes from the fits of that epoch and the one before, clipped to the platform's
limits) instead of coasting. A standstill restart: a lost track whose fixes, when they
return, show the platform where it stood at the last update (every common antenna within
:data:`INIT_MOTION_SIGMAS` sd of its displacement noise) restarts from its last heading, its
variance grown by ``(kappa x that travel)^2`` (:meth:`FilterStart._standstill_start`): a car
at rest cannot turn, so a short all-antenna gap at a stop no longer costs the stop's output.
The same bound holds when the track survives such a gap (:func:`_bound_after_standstill_gap`):
predicted through it unheld, with the speed's sd growing by the acceleration limit, the
heading's sd grows by the yaw rate the platform could reach at that speed (cpm drive 14: 4 deg
to 42 deg in a 2 s gap at the stop), and the returning fixes, metre-level errors drifting,
then turn that heading freely (50 deg off before the car moved off); when the fixes show the
platform where it stood at the gap's start, the heading's variance is at most the one it had
there plus ``(kappa x that travel)^2``.
So is a prediction too wide for an update in double precision (after an hour's gap in
``t``: its spread at the antennas beyond :data:`MAX_PRIOR_RATIO` times the fixes'
variance); the epoch's own data then restart it. A lost row is NaN and carries no clone,
so no smoother links across it. A value that overflowed also counts as lost: a row is
either finite or NaN, never inf.
"""

from __future__ import annotations

import math
from contextlib import suppress
from dataclasses import dataclass, field, replace
from statistics import NormalDist
from typing import Any

import numpy as np
from scipy.linalg.lapack import dgetrf as _dgetrf
from scipy.linalg.lapack import dgetri as _dgetri
from scipy.special import chdtri as _chdtri

from estimator._checks import check_array, check_increasing_times, check_int, check_real
from estimator.epoch_fit import epoch_rigid_fits
from estimator.memo import TrackCache, content_digest, freeze, memo_get
from estimator.platform import PlatformLimits, estimate_limits, estimate_travel_axis

__all__ = [
    "INIT_MAX_YAW_SD",
    "INIT_MOTION_SIGMAS",
    "LOST_YAW_SD",
    "MAX_ITERATIONS",
    "MAX_SMOOTHER_ITERATIONS",
    "FilterStart",
    "PoseFilterParams",
    "PoseFilterResult",
    "antenna_jacobians",
    "ctra_predict",
    "estimate_noise",
    "fix_step_covariance",
    "kalman_update",
    "memo_pose_filter",
    "motion_integrals",
    "nees",
    "nis_summary",
    "pass_key",
    "run_pose_filter",
]

#: Heading sd (rad) from the configuration alone below which the filter starts at once.
#: 0.1 rad: the EKF's linearisation of R(yaw) is good to ~0.5 % there.
INIT_MAX_YAW_SD = 0.1
#: Otherwise it starts once the CG has moved this many sd from the first fix (heading =
#: course, error below ~1/5 rad, which the filter then removes).
INIT_MOTION_SIGMAS = 5.0
#: Heading sd (rad) beyond which a track is lost (45 degrees: R(yaw) is no longer near its
#: linearisation within 2 sd); reached after a few seconds without data.
LOST_YAW_SD = math.pi / 4
#: Time scale of the jerk limit, s: the acceleration's change over a sample is bounded by
#: the jerk times max(sample interval, this) (the data give the jerk over ~1 s).
JERK_SCALE_S = 1.0
#: Window of the NIS consistency test, s, and its fewest epochs.
NIS_WINDOW_S = 10.0
NIS_MIN_EPOCHS = 5
#: Heading sd (rad) of an epoch's rigid fit below which the layout checks the state's heading
#: (3 deg: centimetre fixes on a 0.8 m frame give ~0.1-1 deg).
MAX_FIT_YAW_SD = math.radians(3.0)
#: A speed within this many sd of 0 is a standstill (:func:`_standstill_hold`).
STANDSTILL_SIGMAS = 2.0
#: Consecutive contradicting epochs before a re-initialisation from the rigid fit.
REINIT_EPOCHS = 3
#: Smallest heading contradiction that re-initialises, rad (5 deg: far above any bias of a
#: consistent filter, far below a lock-out's tens of degrees).
REINIT_MIN_YAW_RAD = math.radians(5.0)
#: Most relinearisations of one update (iterated EKF, see the loop).
MAX_ITERATIONS = 4
#: Most Gauss-Newton passes of the iterated RTS smoother (``smoother_iterations``).
MAX_SMOOTHER_ITERATIONS = 20
#: Fewest displacement values for their robust scale (MAD of 50 values: ~15 % sd).
MIN_NOISE_SAMPLES = 50
#: Numerical floor of the estimated noise levels, m (noise-free data would give 0).
NOISE_FLOOR_M = 1e-3
#: Physically sensible ranges of :class:`PoseFilterParams` (closed intervals, SI units).
#: Platform limits (m/s^2, rad/s^2, rad/s) from a creeping platform to ~1000 g: beyond
#: them the process noise (the limits squared, times up to dt^4) leaves the range where
#: the filter's covariances keep their digits.
LIMIT_RANGE = (1e-6, 1e4)
#: Noise levels, m: a micrometre to 1000 km (any receiver on Earth lies inside).
SIGMA_RANGE_M = (1e-6, 1e6)
#: Time constants (``flip_memory_s``, ``lag_s``), s: a microsecond to ~30 years.
TIME_RANGE_S = (1e-6, 1e9)
#: Largest |coordinate| of a fix, m (as :data:`estimator.window.MAX_COORD_M`: any
#: projected coordinate on Earth is below 1e8 m); larger values are refused, never squared.
MAX_COORD_M = 1e9
#: Largest |antenna offset| or |no-slip point| in the body frame, m (a rigid platform).
MAX_OFFSET_M = 1e4
#: Smallest layout (largest antenna distance), m: below it the heading is unobservable.
MIN_EXTENT_M = 1e-6
#: Largest |time|, s (seconds since an epoch are ~2e9; nanoseconds would be ~2e18).
MAX_TIME_S = 1e12
#: Shortest time step, s (a nanosecond: far below any receiver's interval; at 1e-300 s the
#: start's speed, a displacement over the step, overflowed when squared).
MIN_STEP_S = 1e-9
#: A prediction whose spread at the antennas (position variance + lever^2 x heading
#: variance) exceeds this many times the smallest measurement variance means nothing any
#: more: the gain-form update ``P - K S K^T`` would cancel ~12 of the 16 digits (relative
#: error ~1e-4 of the posterior at 1e12); the track is lost and restarts from the data.
MAX_PRIOR_RATIO = 1e12

STATUSES = ("", "no_data", "waiting", "init", "reset", "ok", "predicted", "flip_corrected",
            "reinit", "inconsistent")
#: The platform limits of :class:`PoseFilterParams` (None = estimated from the data).
LIMIT_FIELDS = ("max_accel_mps2", "max_yaw_accel_radps2", "max_turn_rate_radps",
                "max_lateral_accel_mps2", "max_speed_mps")
#: Optional limit: None with a given acceleration limit = unbounded within a sample.
#: Fields :meth:`PoseFilterParams.resolve` fills from the data.
RESOLVED_FIELDS = (*LIMIT_FIELDS, "sigma_abs_m", "sigma_step_m", "no_slip_point_m",
                   "travel_offset_rad")


@dataclass(frozen=True)
class PoseFilterParams:
    """Platform limits and measurement model of the pose filter (SI units).

    Limits (module docstring): ``max_accel_mps2`` (longitudinal), ``max_yaw_accel_radps2``,
    ``max_turn_rate_radps``, ``max_lateral_accel_mps2``, ``max_speed_mps``, each in
    :data:`LIMIT_RANGE`; None (the default) = estimated from the recording
    (:func:`estimator.platform.estimate_limits`: robust percentiles of the per-epoch rigid
    fits' motion, with floors), so a car is not filtered with a rover's limits (issue 25).
    ``max_curvature_1pm`` (1/m): the yaw rate is at most ``|v|`` times it (no-slip
    kinematics of a steered platform: at rest it cannot turn); None = unbounded, or, when
    the turn rate too is None, estimated from the data's course changes.
    A caller who knows the platform passes them (:meth:`from_platform`, :meth:`from_limits`).
    ``sigma_abs_m`` / ``sigma_step_m``: per-axis sd of an antenna fix and of its displacement
    over one sample interval, in :data:`SIGMA_RANGE_M`; None = :func:`estimate_noise` on the
    recording. ``flip_memory_s`` and ``lag_s`` in :data:`TIME_RANGE_S`. A value outside its
    range raises ValueError naming the field and the value.
    ``no_slip_point_m``: (x, y) of the no-slip point in the body frame relative to the
    configuration's CG; None = estimated with the travel axis
    (:func:`estimator.platform.estimate_travel_axis`; (0, 0) where the data cannot tell).
    ``travel_offset_rad``: direction of travel in the layout's body frame (CCW from its x
    axis; a frame mounted 3.4 deg off the car's axis has -3.4 deg), |value| <= pi/4; None =
    estimated from the data (0 where they cannot tell). ``reverse``: the platform may drive
    backwards (signed speed).
    ``gate_prob``: chi-square gate probability (1 = no gating). ``max_rejects``: consecutive
    all-rejected epochs before the track is declared lost. ``flip_memory_s``: memory of the
    configuration's heading test (reverse mode). ``lag_s``: latency of the fixed-lag smoother
    (:mod:`estimator.pose_smoother`), s. ``smoother_iterations``: Gauss-Newton passes of
    the full smoother (:func:`estimator.pose_smoother.iterated_rts_smooth`), 0 to
    :data:`MAX_SMOOTHER_ITERATIONS` (0: the RTS smoother linearised once, about the
    filter). :meth:`resolve` fills every None from the data.
    """

    max_accel_mps2: float | None = None
    max_yaw_accel_radps2: float | None = None
    max_turn_rate_radps: float | None = None
    max_lateral_accel_mps2: float | None = None
    sigma_abs_m: float | None = None
    sigma_step_m: float | None = None
    no_slip_point_m: tuple[float, float] | None = None
    reverse: bool = False
    gate_prob: float = 0.999
    max_rejects: int = 5
    flip_memory_s: float = 30.0
    lag_s: float = 10.0
    max_speed_mps: float | None = None
    travel_offset_rad: float | None = None
    max_jerk_mps3: float | None = None
    max_curvature_1pm: float | None = None
    smoother_iterations: int = 0

    def __post_init__(self) -> None:
        check_int(self.smoother_iterations, "smoother_iterations", lo=0,
                  hi=MAX_SMOOTHER_ITERATIONS)
        for name in LIMIT_FIELDS:
            if getattr(self, name) is not None:
                check_real(getattr(self, name), name, lo=LIMIT_RANGE[0], hi=LIMIT_RANGE[1])
        for name in ("max_jerk_mps3", "max_curvature_1pm"):
            if getattr(self, name) is not None:
                check_real(getattr(self, name), name, lo=LIMIT_RANGE[0], hi=LIMIT_RANGE[1])
        if self.travel_offset_rad is not None:
            check_real(self.travel_offset_rad, "travel_offset_rad", lo=-math.pi / 4,
                       hi=math.pi / 4)
        for name in ("flip_memory_s", "lag_s"):
            check_real(getattr(self, name), name, lo=TIME_RANGE_S[0], hi=TIME_RANGE_S[1])
        for name in ("sigma_abs_m", "sigma_step_m"):
            if getattr(self, name) is not None:
                check_real(getattr(self, name), name, lo=SIGMA_RANGE_M[0],
                           hi=SIGMA_RANGE_M[1])
        check_real(self.gate_prob, "gate_prob", lo=0.0, hi=1.0, lo_open=True)
        check_int(self.max_rejects, "max_rejects", lo=1)
        if not isinstance(self.reverse, bool):
            raise TypeError(f"reverse: must be True or False, got {self.reverse!r}")
        ns = self.no_slip_point_m
        if ns is None:
            return
        if not isinstance(ns, (tuple, list)) or len(ns) != 2:
            raise ValueError(f"no_slip_point_m: must be (x, y) metres, got {ns!r}")
        object.__setattr__(self, "no_slip_point_m", tuple(
            check_real(ns[i], f"no_slip_point_m[{i}]", lo=-MAX_OFFSET_M, hi=MAX_OFFSET_M)
            for i in range(2)))

    @property
    def sigma_accel_step(self) -> float:
        """sd of the longitudinal acceleration's change over one sample interval, m/s^2:
        half the limit (module docstring, discrete Wiener-process acceleration)."""
        return 0.5 * self._limit("max_accel_mps2")

    @property
    def sigma_yaw_accel(self) -> float:
        """sd of the yaw acceleration, constant over a sample interval, rad/s^2: half the
        limit (module docstring, discrete white-noise acceleration)."""
        return 0.5 * self._limit("max_yaw_accel_radps2")

    def _limit(self, name: str) -> float:
        v = getattr(self, name)
        if v is None:
            raise ValueError(f"{name}: None (estimated from the data); call resolve(t, obs, "
                             "offsets) first")
        return v

    @property
    def resolved(self) -> bool:
        """Every field that may be estimated from the data is set."""
        return all(getattr(self, k) is not None for k in RESOLVED_FIELDS)

    def resolve(self, t: np.ndarray, obs: np.ndarray, offsets: np.ndarray
                ) -> PoseFilterParams:
        """These parameters with every None filled from the recording (t (n,) s, obs
        (n, m, 2) m, offsets (m, 2) m relative to the CG): noise levels
        (:func:`estimate_noise`), limits (:func:`estimator.platform.estimate_limits`),
        travel axis and no-slip point (:func:`estimator.platform.estimate_travel_axis`).
        Given fields are kept. Returns self when nothing is None."""
        if self.resolved:
            return self

        t, obs, off = np.asarray(t, dtype=float), np.asarray(obs, dtype=float), offsets
        kw: dict = {}
        if self.sigma_abs_m is None or self.sigma_step_m is None:
            sa, ss = estimate_noise(obs, off)
            kw["sigma_abs_m"] = self.sigma_abs_m if self.sigma_abs_m is not None else sa
            kw["sigma_step_m"] = self.sigma_step_m if self.sigma_step_m is not None else ss
        sigma = kw["sigma_abs_m"] if "sigma_abs_m" in kw else self._limit("sigma_abs_m")
        if any(getattr(self, k) is None for k in LIMIT_FIELDS):
            step = kw.get("sigma_step_m", self.sigma_step_m)
            lim = estimate_limits(t, obs, off, sigma, step).to_dict()
            kw.update({k: lim[k] for k in LIMIT_FIELDS if getattr(self, k) is None})
            if self.max_accel_mps2 is None and self.max_jerk_mps3 is None:
                kw["max_jerk_mps3"] = lim["max_jerk_mps3"]
            if self.max_turn_rate_radps is None and self.max_curvature_1pm is None:
                kw["max_curvature_1pm"] = lim["max_curvature_1pm"]
        if self.travel_offset_rad is None or self.no_slip_point_m is None:
            ax = estimate_travel_axis(t, obs, off, sigma)
            if self.travel_offset_rad is None:
                kw["travel_offset_rad"] = ax.offset_rad
            if self.no_slip_point_m is None:
                kw["no_slip_point_m"] = ax.no_slip_point()
        return replace(self, **kw)

    @classmethod
    def from_platform(cls, limits: object, **overrides: Any) -> PoseFilterParams:
        """Parameters from a :class:`estimator.platform.PlatformLimits` (a ``[platform]``
        block) or None (= estimated from the data); ``overrides`` set any field."""

        if limits is None:
            return cls(**overrides)
        if not isinstance(limits, PlatformLimits):
            raise TypeError(f"limits: expected a PlatformLimits or None, got "
                            f"{type(limits).__name__}")
        return cls.from_limits(limits.to_dict(), **overrides)

    @classmethod
    def from_limits(cls, limits: dict, **overrides: Any) -> PoseFilterParams:
        """Parameters from a platform's limits, e.g. a path file's fields plus the
        controller's: keys ``max_accel_mps2``, ``max_yaw_accel_radps2``,
        ``max_turn_rate_radps``, ``max_lateral_accel_mps2``, ``max_speed_mps`` (absent or
        None: estimated from the data);
        other keys are ignored. ``overrides`` set any field."""
        kw = {k: limits[k] for k in (*LIMIT_FIELDS, "max_jerk_mps3", "max_curvature_1pm")
              if limits.get(k) is not None}
        kw.update(overrides)
        return cls(**kw)


@dataclass(frozen=True)
class PoseFilterResult:
    """The filter's forward pass, everything the smoother needs.

    states (n, 6) and covariances (n, 6, 6): filtered state of the no-slip point
    ``(px, py, yaw, v, a, omega)`` and its covariance (NaN where the filter was not
    running). prev_states (n, 6), prev_covariances (n, 6, 6): the previous epoch's state
    re-estimated with this epoch's data (the clone after the update, ``x_{k-1|k}``), and
    cross_covariances (n, 6, 6): ``cov(x_k, x_{k-1} | data to k)`` (NaN at segment starts).
    segment_start (n,) bool: the filter (re)started here, or the state was flipped (a
    smoother never crosses such an epoch). status (n,) str (:data:`STATUSES`). n_used /
    n_gated (n,): antenna fixes accepted / rejected; n_steps (n,): displacements accepted.
    sigma_abs_m, sigma_step_m: the noise levels used. cg_offset (2,): CG in the body frame
    relative to the no-slip point (CG = p + R(yaw) cg_offset). nis (n,): normalised
    innovation squared of the epoch's fixes and displacements against the prediction (all of
    them, gated ones included; NaN without data or while waiting), nis_dof (n,): its degrees
    of freedom (2 per measurement; chi-square with nis_dof dof when the filter is
    consistent). params: the parameters used, every None filled from the data
    (:meth:`PoseFilterParams.resolve`). The heading of every row is the layout's.
    """

    states: np.ndarray
    covariances: np.ndarray
    prev_states: np.ndarray
    prev_covariances: np.ndarray
    cross_covariances: np.ndarray
    segment_start: np.ndarray
    status: np.ndarray
    n_used: np.ndarray
    n_gated: np.ndarray
    n_steps: np.ndarray
    sigma_abs_m: float
    sigma_step_m: float
    cg_offset: np.ndarray = field(default_factory=lambda: np.zeros(2))
    nis: np.ndarray | None = None
    nis_dof: np.ndarray | None = None
    params: PoseFilterParams | None = None

    def cg(self, states: np.ndarray | None = None) -> np.ndarray:
        """CG (n, 2) metres of ``states`` (default the filtered ones)."""
        X = self.states if states is None else states
        c, s = np.cos(X[:, 2]), np.sin(X[:, 2])
        ox, oy = self.cg_offset
        return np.c_[X[:, 0] + c * ox - s * oy, X[:, 1] + s * ox + c * oy]


# ----------------------------------------------------------------------------- motion
#: State layout: position of the no-slip point (m), heading (rad), speed (m/s),
#: longitudinal acceleration (m/s^2), yaw rate (rad/s).
PX, PY, YAW, V, A, OMEGA = range(6)
NX = 6

#: Below this |q| = |omega tau| the integrals F_k are summed as series (module docstring):
#: the closed forms lose digits to cancellation below it (6.6e-15 at q = 0.25, 5.8e-13 at
#: q = 0.05, against 40-digit quadrature), the 20-term series is exact to 1e-16 up to it.
SERIES_BELOW = 1.0
_SERIES_TERMS = 20
# F_k(q) = sum_n (iq)^n / (n! (n + k)): real part from the even n, imaginary from the odd n,
# each a polynomial in q^2 (coefficients highest power first, for Horner)
_EVEN = tuple(tuple((-1) ** (j % 2) / (math.factorial(2 * j) * (2 * j + k))
                    for j in range(_SERIES_TERMS // 2 - 1, -1, -1)) for k in (1, 2, 3))
_ODD = tuple(tuple((-1) ** (j % 2) / (math.factorial(2 * j + 1) * (2 * j + 1 + k))
                   for j in range(_SERIES_TERMS // 2 - 1, -1, -1)) for k in (1, 2, 3))


def motion_integrals(q: np.ndarray | float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``F_k(q) = integral_0^1 u^(k-1) exp(i q u) du`` for k = 1, 2, 3 (complex).

    The CTRA motion over tau (turn q = omega tau) moves the platform by
    ``exp(i yaw) (v tau F1 + a tau^2 F2)`` (x + i y), and ``dF_k/dq = i F_(k+1)``.
    Closed forms ``F1 = (e^iq - 1)/(iq)``, ``F2 = (e^iq - F1)/(iq)``,
    ``F3 = (e^iq - 2 F2)/(iq)`` for |q| >= :data:`SERIES_BELOW`; below, where they cancel,
    the series ``sum_n (iq)^n / (n! (n + k))`` to n = 19 (truncation < 1e-19 there).
    q : any shape; returns three complex arrays of that shape (NaN for non-finite q).
    """
    q = np.asarray(q, dtype=float)
    small = np.abs(q) < SERIES_BELOW
    qs = np.where(small, 1.0, q)
    e = np.exp(1j * qs)
    f1 = (e - 1.0) / (1j * qs)
    f2 = (e - f1) / (1j * qs)
    f3 = (e - 2.0 * f2) / (1j * qs)
    if small.any():
        qq = np.where(small, q, 0.0)
        q2 = qq * qq
        out = []
        for k, f in enumerate((f1, f2, f3)):
            re = np.polyval(_EVEN[k], q2)
            im = qq * np.polyval(_ODD[k], q2)
            out.append(np.where(small, re + 1j * im, f))
        f1, f2, f3 = out
    return f1, f2, f3


def _integrals_scalar(q: float) -> tuple[complex, complex, complex]:
    """:func:`motion_integrals` for one q (Python complex numbers, same formulas; the series
    is cut where its next term is below 1e-17 for this |q|: 6 terms below |q| = 0.01, 10
    below 0.1, 14 below 0.5, else 20)."""
    aq = abs(q)
    if aq >= SERIES_BELOW:
        e = complex(math.cos(q), math.sin(q))
        iq = 1j * q
        f1 = (e - 1.0) / iq
        f2 = (e - f1) / iq
        return f1, f2, (e - 2.0 * f2) / iq
    half = 3 if aq < 0.01 else 5 if aq < 0.1 else 7 if aq < 0.5 else _SERIES_TERMS // 2
    q2 = q * q
    # the three Horner recursions side by side (one loop; the same operations in the same
    # order as one recursion per k)
    r1 = r2 = r3 = i1 = i2 = i3 = 0.0
    for e1, e2, e3, o1, o2, o3 in _HORNER[_SERIES_TERMS // 2 - half:]:
        r1 = r1 * q2 + e1
        r2 = r2 * q2 + e2
        r3 = r3 * q2 + e3
        i1 = i1 * q2 + o1
        i2 = i2 * q2 + o2
        i3 = i3 * q2 + o3
    return complex(r1, q * i1), complex(r2, q * i2), complex(r3, q * i3)


#: The series coefficients of F1, F2, F3 (real, then imaginary parts), highest power first,
#: one row per power (for :func:`_integrals_scalar`).
_HORNER = tuple(zip(*_EVEN, *_ODD))
#: The same as an array (10, 6), for the compiled loop.
_HORNER_ARRAY = np.array(_HORNER)


_EYE = np.eye(NX)


def _predict(x: np.ndarray, P: np.ndarray, dt: float, qa: float, qy: float
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """CTRA prediction: (x', P', F P) (F P: the cross-covariance of the prediction with the
    state it came from, which the filter's clone needs). See :func:`ctra_predict`."""
    px, py, yaw, v, acc, om = x.tolist()
    f1, f2, f3 = _integrals_scalar(om * dt)
    rot = complex(math.cos(yaw), math.sin(yaw))
    d = rot * (v * dt * f1 + acc * dt * dt * f2)          # displacement
    dv = rot * dt * f1
    da = rot * dt * dt * f2
    dq = rot * 1j * (v * dt * f2 + acc * dt * dt * f3) * dt   # d/domega = dt d/dq
    F = _EYE.copy()
    F[PX, YAW], F[PY, YAW] = -d.imag, d.real              # d/dyaw = J d
    F[PX, V], F[PY, V] = dv.real, dv.imag
    F[PX, A], F[PY, A] = da.real, da.imag
    F[PX, OMEGA], F[PY, OMEGA] = dq.real, dq.imag
    F[YAW, OMEGA] = dt
    F[V, A] = dt
    # process noise (module docstring): continuous white jerk along the heading and white
    # yaw acceleration, each with the variance of its rate's change over the sample given
    # (qa: of the acceleration, qy / dt^2 ... of the yaw rate: qy dt^2), full rank
    FP = F @ P
    Pn = FP @ F.T
    _add_noise(Pn, rot, v, dt, qa, qy)
    xn = np.array([px + d.real, py + d.imag, _wrap(yaw + om * dt), v + acc * dt, acc, om])
    return xn, Pn, FP


#: Moments of the continuous white-noise models over a step (Bar-Shalom et al. 2001,
#: Section 6.2): integral_0^dt of (dt - s)^i (dt - s)^j / (i! j!) ds, divided by dt^(i+j+1),
#: for i, j = 0, 1, 2 (rate, its integral, the double integral).
_CW = np.array([[1.0, 1 / 2, 1 / 6], [1 / 2, 1 / 3, 1 / 8], [1 / 6, 1 / 8, 1 / 20]])


def _add_noise(Pn: np.ndarray, rot: complex, v: float, dt: float, qa: float, qy: float
               ) -> None:
    """Add the process noise over dt to Pn (6, 6) in place: white jerk along the heading
    (acceleration change of variance ``qa`` over the sample: density qa / dt) acting on
    (a, v, along-track position), and white yaw acceleration (yaw-rate change of variance
    ``qy dt^2``: density qy dt) acting on (omega, yaw, and through the turn the sideways
    position, v times the yaw's integral). Continuous models (Bar-Shalom et al. 2001,
    Sections 6.2.2-6.2.3): full rank, so a yaw rate that steps early in the sample (a
    steering input) and one that ramps are both inside the model."""
    c, s = rot.real, rot.imag
    ja = (qa / dt) if dt > 0 else 0.0
    jy = qy * dt
    # along: (a, v, s) = (dt^0, dt^1, dt^2) moments; yaw: (omega, yaw, v x yaw integral)
    pw = np.array([1.0, dt, dt * dt])
    Ma = ja * dt * _CW * np.outer(pw, pw)
    My = jy * dt * _CW * np.outer(pw, pw)
    lat = np.array([1.0, 1.0, v])
    My = My * np.outer(lat, lat)
    ia = (A, V)
    for i in range(2):
        for j in range(2):
            Pn[ia[i], ia[j]] += Ma[i, j]
    for i, k in enumerate(ia):                 # along-track position: (c, s) Ma[2, i]
        Pn[PX, k] += c * Ma[2, i]
        Pn[k, PX] += c * Ma[2, i]
        Pn[PY, k] += s * Ma[2, i]
        Pn[k, PY] += s * Ma[2, i]
    iy = (OMEGA, YAW)
    for i in range(2):
        for j in range(2):
            Pn[iy[i], iy[j]] += My[i, j]
    for i, k in enumerate(iy):                 # sideways position: (-s, c) My[2, i]
        Pn[PX, k] -= s * My[2, i]
        Pn[k, PX] -= s * My[2, i]
        Pn[PY, k] += c * My[2, i]
        Pn[k, PY] += c * My[2, i]
    Pn[PX, PX] += c * c * Ma[2, 2] + s * s * My[2, 2]
    Pn[PY, PY] += s * s * Ma[2, 2] + c * c * My[2, 2]
    Pn[PX, PY] += c * s * (Ma[2, 2] - My[2, 2])
    Pn[PY, PX] += c * s * (Ma[2, 2] - My[2, 2])


def ctra_predict(x: np.ndarray, P: np.ndarray, dt: float, sigma_accel_step: float,
                 sigma_yaw_accel: float) -> tuple[np.ndarray, np.ndarray]:
    """CTRA prediction of state (6,) and covariance (6, 6) over dt seconds (module
    docstring: motion model and Q); sigma_accel_step (m/s^2): sd of the acceleration's
    change over this step, sigma_yaw_accel (rad/s^2): sd of the yaw acceleration.
    Returns (x', P')."""
    xn, Pn, _ = _predict(np.asarray(x, dtype=float), np.asarray(P, dtype=float), float(dt),
                         float(sigma_accel_step) ** 2, float(sigma_yaw_accel) ** 2)
    return xn, Pn


def _wrap(a: float) -> float:
    a = float(a)
    if -math.pi < a <= math.pi:
        return a
    return math.pi - math.fmod(math.fmod(math.pi - a, _TWO_PI) + _TWO_PI, _TWO_PI)


_TWO_PI = 2.0 * math.pi


# ----------------------------------------------------------------------------- measurements
def antenna_jacobians(x: np.ndarray, r: np.ndarray, x_prev: np.ndarray | None = None
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Predicted measurements and Jacobians for antennas at body offsets r (k, 2) from M.

    x_prev None: fixes, ``h (k, 2) = p + R(yaw) r``, H (k, 2, 6). x_prev (6,): each
    antenna's displacement from the state x_prev to the state x, ``h = (p + R(yaw) r) -
    (p' + R(yaw') r)``, H (k, 2, 12) over the stacked state ``(x, x_prev)``.
    """
    x = np.asarray(x, dtype=float)
    r = np.asarray(r, dtype=float)
    if x_prev is None:
        h, H = _measurements(np.concatenate((x, x)), r, r[:0])
        return h, H[:, :, :NX]
    return _measurements(np.concatenate((x, np.asarray(x_prev, dtype=float))), r[:0], r)


def _measurements(y: np.ndarray, ra: np.ndarray, rd: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Fixes of the antennas at offsets ra (ka, 2) and displacements since the previous
    epoch of those at rd (kd, 2), stacked, for the stacked state ``y = (x, x_prev)`` (12,):
    h (ka + kd, 2) and H (ka + kd, 2, 12) (a fix touches x only, a displacement both)."""
    return _fill_measurements(y, ra[:, 0], ra[:, 1], rd[:, 0], rd[:, 1],
                              _jacobian_template(ra.shape[0], rd.shape[0]))


def _jacobian_template(ka: int, kd: int) -> np.ndarray:
    """H (ka + kd, 2, 12) of :func:`_measurements` with its constant entries (the position
    columns) set and the heading columns 0."""
    H = np.zeros((ka + kd, 2, 2 * NX))
    H[:, 0, PX] = 1.0
    H[:, 1, PY] = 1.0
    H[ka:, 0, NX + PX] = -1.0
    H[ka:, 1, NX + PY] = -1.0
    return H


def _fill_measurements(y: np.ndarray, ax: np.ndarray, ay: np.ndarray, dx: np.ndarray,
                       dy: np.ndarray, H: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_measurements` with the offsets as columns (fixes ``ax, ay``, displacements
    ``dx, dy``) and ``H`` a :func:`_jacobian_template` of that size, filled in place."""
    ka, kd = ax.shape[0], dx.shape[0]
    c, s = math.cos(y[YAW]), math.sin(y[YAW])
    h = np.empty((ka + kd, 2))
    if ka:
        rx = c * ax - s * ay
        ry = s * ax + c * ay
        H[:ka, 0, YAW] = -ry
        H[:ka, 1, YAW] = rx
        h[:ka, 0] = y[PX] + rx
        h[:ka, 1] = y[PY] + ry
    if kd:
        cp, sp = math.cos(y[NX + YAW]), math.sin(y[NX + YAW])
        rx = c * dx - s * dy
        ry = s * dx + c * dy
        px = cp * dx - sp * dy
        py = sp * dx + cp * dy
        h[ka:, 0] = y[PX] - y[NX + PX] + rx - px
        h[ka:, 1] = y[PY] - y[NX + PY] + ry - py
        H[ka:, 0, YAW] = -ry
        H[ka:, 1, YAW] = rx
        H[ka:, 0, NX + YAW] = py
        H[ka:, 1, NX + YAW] = -px
    return h, H


def _quad_form(a, b, c, e: np.ndarray, guard: bool) -> np.ndarray:
    """e_i^T [[a, b], [b, c]]_i^-1 e_i, vectorised; with ``guard``, 0 where the matrix is
    singular to rounding (no redundancy left to test against)."""
    ex, ey = e[:, 0], e[:, 1]
    det = a * c - b * b
    num = c * ex * ex - 2.0 * b * ex * ey + a * ey * ey
    if not guard:
        return num / det
    return np.divide(num, det, out=np.zeros_like(num), where=det > 1e-12 * np.abs(a * c))


def _quad2(M: np.ndarray, e: np.ndarray, guard: bool = False) -> np.ndarray:
    """e_i^T M_i^-1 e_i for symmetric 2 x 2 matrices M (k, 2, 2) and vectors e (k, 2)."""
    return _quad_form(M[:, 0, 0], M[:, 0, 1], M[:, 1, 1], e, guard)


def _inv(S: np.ndarray) -> np.ndarray:
    """Inverse of a small non-singular matrix through LAPACK's LU (dgetrf/dgetri): half the
    time of numpy.linalg.inv at the 10-30 rows of an innovation covariance (its per-call
    overhead dominates there); numpy's on the rare failure, which then raises."""
    lu, piv, info = _dgetrf(S)
    if info == 0:
        inv, info = _dgetri(lu, piv)
        if info == 0:
            return inv
    return np.linalg.inv(S)


def _block_quad(M: np.ndarray, e: np.ndarray) -> np.ndarray:
    """e_i^T B_i^-1 e_i for the 2 x 2 diagonal blocks B_i of the symmetric positive
    definite M (2k, 2k)."""
    d = M.ravel()[::M.shape[0] + 1]
    a, c = d[0::2], d[1::2]
    b = M.ravel()[1::2 * M.shape[0] + 2]
    ex, ey = e[:, 0], e[:, 1]
    return (c * ex * ex - 2.0 * b * ex * ey + a * ey * ey) / (a * c - b * b)


def kalman_update(x: np.ndarray, P: np.ndarray, nu: np.ndarray, H: np.ndarray,
                  var: np.ndarray, gate: float = math.inf, max_deleted: int = 3,
                  accept: np.ndarray | None = None
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Joint EKF update with k two-dimensional measurements, robustly gated.

    nu (k, 2) innovations, H (k, 2, n) Jacobians, var (k,) per-axis noise variances (R_i =
    var_i I); P may be singular (the filter's stacked state of two epochs is). Gain form:
    ``S = H P H^T + R`` over the accepted measurements, ``x+ = x + P H^T S^-1 nu``,
    ``P+ = P - P H^T S^-1 H P`` (tested against FilterPy). Two tests, both at the
    chi-square(2) quantile ``gate``:

    1. prior gate: a measurement whose NIS ``nu_i^T S_ii^-1 nu_i`` exceeds ``gate`` is left
       out;
    2. deleted residual (the dissertation's Section 3.3.2 idea on the filter): each
       accepted measurement's residual after the joint update, ``e_i = (R S^-1 nu)_i``,
       against its covariance ``C_i = (R S^-1 R)_ii`` is the test of that measurement
       against all the others and the prior (leave-one-out); with ``u = S^-1 nu`` the
       statistic is ``u_i^T ((S^-1)_ii)^-1 u_i``. The worst one above ``gate`` is removed
       and the update redone, at most ``max_deleted`` times. This catches a gross error
       that the prior alone cannot (e.g. a displacement from an outlying fix while the
       platform's agility makes the predicted spread wide).

    The yaw component of x+ is not wrapped here. ``accept`` (k,) bool replaces test 1 (the
    caller's own choice of candidates; test 2 still runs). Returns (x+, P+, accepted (k,)).
    """
    if nu.shape[0] == 0:
        return x, P, np.zeros(0, dtype=bool)
    return _kalman_update(x, P, nu, H, np.repeat(var, 2), gate, max_deleted, accept)


def _kalman_update(x: np.ndarray, P: np.ndarray, nu: np.ndarray, H: np.ndarray,
                   var2: np.ndarray, gate: float, max_deleted: int = 3,
                   accept: np.ndarray | None = None, nis_out: list | None = None,
                   cross: tuple | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`kalman_update` (k >= 1 measurements) with the noise variances per row of the
    stacked measurement vector, ``var2 = repeat(var, 2)`` (2k,). ``nis_out``: a list that
    receives the NIS of all k measurements, ``nu^T S^-1 nu``, before any gating. ``cross``
    ``(rows_a, rows_b, c)``: the noise covariance c between those rows of the stacked
    vector (:func:`fix_step_covariance`); the prior gate tests the marginal 2 x 2 blocks,
    the deleted-residual test and the update use the joint S over the accepted ones."""
    k = nu.shape[0]
    Hf = H.reshape(2 * k, -1)
    PHt = P @ Hf.T
    S = Hf @ PHt
    S.ravel()[::2 * k + 1] += var2       # + R on the diagonal (S is a fresh C array)
    if cross is not None and cross[0].size:
        S[cross[0], cross[1]] += cross[2]
        S[cross[1], cross[0]] += cross[2]
    if nis_out is not None:
        nf = nu.reshape(-1)
        nis_out.append(float(nf @ np.linalg.solve(S, nf)))
    if accept is not None:
        acc = np.array(accept, dtype=bool)
    elif gate != math.inf:
        acc = _block_quad(S, nu) <= gate
    else:
        acc = np.ones(k, dtype=bool)
    nuf = nu.reshape(-1)
    deletions = max_deleted if gate != math.inf else 0
    while acc.any():
        ia = np.flatnonzero(acc)
        if ia.size < k:
            rows = np.empty(2 * ia.size, dtype=int)
            rows[0::2], rows[1::2] = 2 * ia, 2 * ia + 1
            Sa = S[np.ix_(rows, rows)]
        else:
            rows, Sa = slice(None), S  # type: ignore[assignment]  # all rows
        Sinv = _inv(Sa)
        u = Sinv @ nuf[rows]
        if deletions and ia.size >= 2:
            # S^-1 is positive definite, so are its diagonal blocks: no singular case
            stat = _block_quad(Sinv, u.reshape(-1, 2))
            worst = int(stat.argmax())
            if stat[worst] > gate:
                acc[ia[worst]] = False
                deletions -= 1
                continue
        K = PHt[:, rows]
        Pn = P - K @ Sinv @ K.T
        return x + K @ u, 0.5 * (Pn + Pn.T), acc
    return x, P, acc


def fix_step_covariance(va: float, vs: float) -> float:
    """Per-axis cross-covariance (m^2) of an antenna's fix error and its displacement's
    error within one epoch (issue 25), from the filter's own noise variances ``va =
    sigma_abs^2`` and ``vs = sigma_step^2`` (m^2).

    Derivation: the fix error e_k is stationary with variance va and lag-one covariance
    ``g = cov(e_k, e_(k-1))``; the displacement's error ``e_k - e_(k-1)`` has variance
    ``vs = 2 (va - g)``, so ``g = va - vs / 2`` and ``C = cov(e_k, e_k - e_(k-1)) = va - g =
    vs / 2``. GNSS errors are positively correlated in time (``g >= 0``): ``vs > 2 va``
    (sampling noise of :func:`estimate_noise`, or values the user gives) is taken as white
    fix noise plus independent displacement noise, ``C = va``. So ``C = min(vs / 2, va)``;
    the pair's 2 x 2 covariance ``[[va, C], [C, vs]]`` is positive definite (``va vs - C^2
    >= va vs / 2``, resp. ``va (vs - va) > 0``). Different antennas' errors are independent
    in the model, and so is the displacement from the fix at k-1 (already used there): the
    correlation across epochs is left out (module docstring).

    How the update uses it (:func:`_kalman_update`): the joint R of the epoch's fixes and
    displacements carries C between each displacement and its own fix. The gates test each
    measurement on its marginal block (unchanged by C); the update over the accepted ones
    is the exact joint one, equivalent to decorrelating each accepted pair (Gram-Schmidt:
    ``d' = d - rho z``, ``H_d' = H_d - rho H_z``, variance ``vs - C^2 / va``, ``rho = C /
    va``; Simon 2006, *Optimal State Estimation*, Sec. 6.1) and updating with independent
    blocks; a displacement whose fix is gated enters alone, with its marginal variance vs.
    The NIS is ``nu^T S^-1 nu`` with the joint R: chi-square with 2 dof per fix and per
    displacement.
    """
    return min(0.5 * vs, va)


# ----------------------------------------------------------------------------- noise levels
def _studentize(offsets: np.ndarray, present: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """1 / sqrt(1 - h) per residual component (n, m, 2) of the rigid fits (linearised):
    the fit's hat matrix for antenna i has the translation part 1/k and the rotation part
    ``(J R rt_i)(J R rt_i)^T / sum_j |rt_j|^2`` (rt: offsets about the present antennas'
    centroid), so ``h_xx = 1/k + (R rt_i)_y^2 / S``, ``h_yy = 1/k + (R rt_i)_x^2 / S``."""
    w = present.astype(float)
    k = w.sum(1)
    with np.errstate(invalid="ignore", divide="ignore"):
        rc = (offsets[None] * w[..., None]).sum(1) / k[:, None]
        rt = offsets[None] - rc[:, None]                      # (n, m, 2)
        c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
        wx = c * rt[..., 0] - s * rt[..., 1]
        wy = s * rt[..., 0] + c * rt[..., 1]
        S = ((wx * wx + wy * wy) * w).sum(1)[:, None]
        hx = 1.0 / k[:, None] + wy * wy / S
        hy = 1.0 / k[:, None] + wx * wx / S
        return np.stack([1.0 / np.sqrt(1.0 - hx), 1.0 / np.sqrt(1.0 - hy)], -1)


def estimate_noise(obs: np.ndarray, offsets: np.ndarray) -> tuple[float, float]:
    """Per-axis noise sd of one antenna's fix and of its one-sample displacement, metres,
    from the data alone through the configuration (module docstring).

    obs (n, m, 2) metres, NaN = missing; offsets (m, 2) body positions (any origin).
    Each epoch with k >= 3 fixes is fitted rigidly (2-D Kabsch); each residual component is
    studentised by its leverage in the fit, ``1 / sqrt(1 - h)`` (:func:`_studentize`: the 3
    pose parameters take 3 of the 2k degrees of freedom, unevenly between antennas), and
    ``sigma_abs = 1.4826 median |residual|`` (MAD, robust to outliers). ``sigma_step`` is the
    same statistic of one antenna's residual change between consecutive epochs with the same
    antennas reporting (its fit removes the shared motion); with fewer than
    :data:`MIN_NOISE_SAMPLES` such values, ``sqrt(2) sigma_abs`` (white noise). The error
    every antenna shares is invisible to both (it moves the fit). Both are floored at
    :data:`NOISE_FLOOR_M`. The leverages are those of the linearised fit, for noise small
    next to the layout; when the noise is as large as the layout (consumer GPS on a 1.5 m
    roof) the fitted rotation absorbs less of it and the estimate is high by up to
    ``sqrt((1 - 2/(2k)) / (1 - 3/(2k)))`` (4 % with 7 fixes, 15 % with 3).
    Raises ValueError if no epoch has 3 or more fixes (nothing to estimate from), and for
    the bad obs / offsets :func:`run_pose_filter` refuses (naming the argument).
    """
    obs, off = _check_obs_offsets(obs, offsets)
    _, yaw, cnt, res = epoch_rigid_fits(obs, off)
    good = cnt >= 3
    if not good.any():
        raise ValueError("obs: no epoch has 3 or more antenna fixes, the noise levels cannot "
                         "be estimated; give sigma_abs_m and sigma_step_m")
    scale = _studentize(off, np.isfinite(obs[..., 0]), yaw)
    r = (res[good] * scale[good]).ravel()
    sigma_abs = 1.4826 * float(np.median(np.abs(r[np.isfinite(r)])))
    present = np.isfinite(obs[..., 0])
    same = good[1:] & good[:-1] & np.all(present[1:] == present[:-1], axis=1)
    d = ((res[1:] - res[:-1]) * scale[1:])[same].ravel()
    d = d[np.isfinite(d)]
    # too few displacement samples for a robust scale: the white-noise relation (an upper
    # value: time-correlated errors change less between samples)
    sigma_step = (1.4826 * float(np.median(np.abs(d))) if d.size >= MIN_NOISE_SAMPLES
                  else sigma_abs * math.sqrt(2))
    return max(sigma_abs, NOISE_FLOOR_M), max(sigma_step, NOISE_FLOOR_M)


# ----------------------------------------------------------------------------- the filter
class FilterStart:
    """When and where the filter starts (module docstring, "Initialisation waits for data").

    t (n,), obs (n, m, 2), r (m, 2) antenna offsets from the no-slip point, sigma_abs (m),
    params. :meth:`offer` is asked epoch by epoch while waiting; it returns (x0 (6,),
    P0 (6, 6)) at the start epoch, else None. Shared by the EKF and the GTSAM peer
    (:mod:`estimator.gtsam_peer`), so both start at the same epoch from the same state.
    """

    def __init__(self, t: np.ndarray, obs: np.ndarray, r: np.ndarray, sigma_abs: float,
                 params: PoseFilterParams) -> None:
        self.t = t
        self.obs = obs
        self.origin, self.yaw, self.cnt, res = epoch_rigid_fits(obs, r)  # origin = no-slip point
        # the epoch's fixes agree with the layout: chi-square of the fit's residuals (2 m - 3
        # dof) within the gate probability (:meth:`motion_miss`)
        pg = params.gate_prob if params.gate_prob < 1 else 0.999
        dof = np.maximum(2 * self.cnt - 3, 1)
        with np.errstate(invalid="ignore"):
            ssr = np.nansum(res * res, axis=(1, 2)) / (sigma_abs * sigma_abs)
            # the quantile per distinct dof (a few small integers), not per epoch: the same
            # numbers in 1/20 of the time (0.6 ms -> 0.03 ms on a 1500-epoch drive)
            dof_u, row = np.unique(dof, return_inverse=True)
            self.fit_ok = (self.cnt >= 2) & (ssr <= _chdtri(dof_u, 1.0 - pg)[row])
        self.present = np.isfinite(obs[..., 0])
        self.r2 = (r ** 2).sum(1)
        self.sigma_abs = sigma_abs
        self.params = params
        self.anchor = -1
        self.r = r
        self._spread: np.ndarray | None = None
        self.last_fix: np.ndarray | None = None   # per epoch: the last epoch <= it with a fix
        self.memory = (-1, 0.0, 0.0)      # (epoch, heading, its variance) of the last update

    def remember(self, k: int, x: np.ndarray, P: np.ndarray) -> None:
        """Epoch k's updated heading and its variance: a lost track's last word, from which
        a platform that stood since restarts (:meth:`_standstill_start`)."""
        self.memory = (k, float(x[YAW]), float(P[YAW, YAW]))

    def _standstill_start(self, k: int) -> tuple[float, float, float, float] | None:
        """(yaw0, yaw sd, v0, v sd) when the platform stood since the remembered epoch j: every
        antenna present at both moved by at most ``INIT_MOTION_SIGMAS sigma_step sqrt(k -
        j)`` (the start's motion test, the displacement noise growing as a random walk), so
        its heading turned by at most the curvature limit times that travel (issue 25: a
        car cannot turn at rest). None without a memory, a common antenna or a curvature
        limit, or when that bound leaves the heading sd above :data:`LOST_YAW_SD`."""
        j, yaw, var = self.memory
        kappa = self.params.max_curvature_1pm
        moved = self.travel(j, k) if j >= 0 else None
        if moved is None or kappa is None:
            return None
        thr, dmax = moved
        ysd = math.sqrt(var + (kappa * thr) ** 2)
        if not (dmax <= thr and ysd <= LOST_YAW_SD):
            return None
        dt = self.t[k] - self.t[j]
        return yaw, ysd, 0.0, math.hypot(self.params._limit("max_accel_mps2") * dt, thr / dt)

    def travel(self, j: int, k: int) -> tuple[float, float] | None:
        """(thr, dmax) from epoch j to k: the motion bound ``INIT_MOTION_SIGMAS sigma_step
        sqrt(k - j)`` (m; the displacement noise growing as a random walk) and the largest
        move of an antenna present at both (m); None without such an antenna."""
        both = self.present[k] & self.present[j]
        if not both.any():
            return None
        d = self.obs[k, both] - self.obs[j, both]
        thr = INIT_MOTION_SIGMAS * self.params._limit("sigma_step_m") * math.sqrt(k - j)
        return thr, float(np.sqrt((d * d).sum(1)).max())

    def reset(self) -> None:
        """Forget the anchor (after a lost track)."""
        self.anchor = -1

    def fit_heading(self, k: int) -> tuple[float, float]:
        """Epoch k's rigid-fit heading (rad, the filter's frame) and its sd,
        ``sigma_abs / sqrt(sum |r_i - rbar|^2)`` over the present antennas (inf with < 2)."""
        if self.cnt[k] < 2:
            return math.nan, math.inf
        if self._spread is None:
            pr = self.present
            w = pr.astype(float)
            with np.errstate(invalid="ignore", divide="ignore"):
                rbar = (w @ self.r) / w.sum(1)[:, None]
            # |r_i - rbar|^2 as d_x^2 + d_y^2 (the bits of (d * d).sum(-1), whose 0.0 + d_x^2
            # cannot differ: a square is never -0.0), without the slow length-2 reduction
            dx, dy = self.r[:, 0] - rbar[:, :1], self.r[:, 1] - rbar[:, 1:]
            self._spread = ((dx * dx + dy * dy) * w).sum(1)
        sp = self._spread[k]
        return float(self.yaw[k]), (self.sigma_abs / math.sqrt(sp) if sp > 0 else math.inf)

    def motion_miss(self, k: int) -> bool:
        """Epoch k can re-initialise the filter when all its fixes fail their gates together
        (issue 25: a motion-model miss at a hard acceleration, not bad fixes): its fixes
        agree with the layout (``fit_ok``), the layout gives the heading to
        :data:`MAX_FIT_YAW_SD` and epoch k-1 has a fit (the speed)."""
        return bool(k > 0 and self.fit_ok[k] and self.cnt[k - 1] >= 2
                    and self.fit_heading(k)[1] <= MAX_FIT_YAW_SD)

    def refit(self, k: int, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A re-initialised state at epoch k from its rigid fit: position and heading of the
        fit, speed from the previous epoch's fit when there is one (else the state's
        ``x[V]``), zero acceleration, the yaw rate of :meth:`_fit_rate`; covariance as at a
        start."""
        p, sa = self.params, self.sigma_abs
        amax = p._limit("max_accel_mps2")
        yaw0, ysd = self.fit_heading(k)
        v0, vsd = float(x[V]), max(abs(float(x[V])), amax)
        if k > 0 and self.cnt[k - 1] >= 2:
            v0, vsd = self._fit_speed(k, yaw0)
        om0, omsd = self._fit_rate(k, float(x[OMEGA]), v0, vsd)
        pvar = sa * sa / self.cnt[k]
        xn = np.array([self.origin[k, 0], self.origin[k, 1], _wrap(yaw0), v0, 0.0, om0])
        P = np.diag(np.array([pvar, pvar, ysd ** 2, vsd ** 2, amax ** 2, omsd ** 2]))
        return xn, P

    def _fit_rate(self, k: int, om: float, v0: float, vsd: float) -> tuple[float, float]:
        """A re-initialisation's yaw rate (rad/s) and sd, consistent with the fits it uses
        and the platform (issue 25: a state's 90 deg/s carried into a refit): the rate of
        the fits of k-1 and k when both give the heading (sd: theirs over dt and the
        yaw-acceleration limit over dt), else ``om`` with sd half the turn-rate limit;
        clipped to the turn-rate limit, ``max_lateral_accel / |v0|`` and ``kappa (|v0| +
        vsd)``."""
        p = self.params
        om_max = p._limit("max_turn_rate_radps")
        lim = om_max if v0 == 0 else min(om_max, p._limit("max_lateral_accel_mps2") / abs(v0))
        if p.max_curvature_1pm is not None:
            lim = min(lim, p.max_curvature_1pm * (abs(v0) + vsd))
        omsd = 0.5 * om_max
        y1, s1 = self.fit_heading(k)
        y0, s0 = self.fit_heading(k - 1) if k > 0 else (math.nan, math.inf)
        if s1 <= MAX_FIT_YAW_SD and s0 <= MAX_FIT_YAW_SD:
            dt = self.t[k] - self.t[k - 1]
            om = _wrap(y1 - y0) / dt
            omsd = math.hypot(math.hypot(s0, s1) / dt, p._limit("max_yaw_accel_radps2") * dt)
        return max(-lim, min(lim, om)), omsd

    def _fit_speed(self, k: int, yaw0: float) -> tuple[float, float]:
        """Speed along ``yaw0`` (m/s) from the rigid fits of epochs k-1 and k (both with >= 2
        fixes) and its sd: the acceleration limit over the step and the fits' noise; not
        negative unless the platform may reverse."""
        p, sa = self.params, self.sigma_abs
        dt = self.t[k] - self.t[k - 1]
        d = self.origin[k] - self.origin[k - 1]
        v0 = (d[0] * math.cos(yaw0) + d[1] * math.sin(yaw0)) / dt
        vsd = math.hypot(p.max_accel_mps2 * dt, sa * math.sqrt(
            1.0 / self.cnt[k] + 1.0 / self.cnt[k - 1]) / dt)
        if not p.reverse:
            v0 = max(v0, 0.0)
        return v0, vsd

    def wait(self, k: int) -> tuple[str, tuple[np.ndarray, np.ndarray] | None]:
        """One waiting epoch: ("no_data", None) without any fix, else ("waiting", None) or
        ("waiting", (x0, P0)) when the filter starts here (:meth:`offer`)."""
        if not self.present[k].any():
            return "no_data", None
        return "waiting", self.offer(k)

    def offer(self, k: int) -> tuple[np.ndarray, np.ndarray] | None:
        """The start state at epoch k, or None to keep waiting."""
        if self.cnt[k] < 2:
            return None
        sa, p = self.sigma_abs, self.params
        r2 = self.r2[self.present[k]].sum()
        # the present antennas all at the no-slip point: no heading from the layout
        yaw_sd = sa / math.sqrt(r2) if r2 > 0 else math.inf
        if yaw_sd < INIT_MAX_YAW_SD:
            # the configuration fixes the heading; the speed along it comes from the
            # previous epoch's fit, so wait for two consecutive fits (a start on the move,
            # e.g. after an outage, must not assume the platform at rest)
            if k == 0 or self.cnt[k - 1] < 2:
                return None
            yaw0, ysd = float(self.yaw[k]), yaw_sd
            v0, vsd = self._fit_speed(k, yaw0)
        elif (still := self._standstill_start(k)) is not None:
            yaw0, ysd, v0, vsd = still
        elif self.anchor < 0:
            self.anchor = k
            return None
        else:
            # heading = course once the platform has clearly moved from the anchor fix
            a = self.anchor
            d = self.origin[k] - self.origin[a]
            dist = math.hypot(d[0], d[1])
            sd = sa * math.sqrt(1.0 / self.cnt[k] + 1.0 / self.cnt[a])
            if dist <= INIT_MOTION_SIGMAS * sd:
                return None
            course = math.atan2(d[1], d[0])
            sp = dist / (self.t[k] - self.t[a])
            ysd, vsd = sd / dist, max(sp, p.max_accel_mps2)
            if p.reverse and math.cos(course - self.yaw[k]) < 0:
                yaw0, v0 = course + math.pi, -sp
            else:
                yaw0, v0 = course, sp
        self.anchor = -1
        pvar = sa * sa / self.cnt[k]
        x = np.array([self.origin[k, 0], self.origin[k, 1], _wrap(yaw0), v0, 0.0, 0.0])
        P = np.diag(np.array([pvar, pvar, ysd ** 2, vsd ** 2, p._limit("max_accel_mps2") ** 2,
                              (0.5 * p._limit("max_turn_rate_radps")) ** 2]))
        return x, P


class _Monitor:
    """Consistency of the running filter and its guard against gate lock-out (issue 25).

    NIS tests, both at the upper ``gate_prob`` quantile ``q(d)`` of chi-square with d
    degrees of freedom (Bar-Shalom 2001, Section 5.4.2); an epoch is "inconsistent" when
    either fails:

    1. per epoch: its own NIS above ``q(dof)`` (its innovations are beyond the model there);
    2. window: the last ``window`` epochs with data (:data:`NIS_WINDOW_S`, at least
       :data:`NIS_MIN_EPOCHS`), each epoch's NIS winsorised at its own ``q(dof)``, summed,
       above ``q`` of the summed dof. A consistent filter's winsorised sum is at most its
       chi-square sum, so the window's false-alarm rate stays below ``1 - gate_prob``.

    A single spike adds at most ``q(d) - d`` above its mean, so it cannot flag the window on
    its own; s saturated epochs with the others at their mean flag W epochs of d dof when
    ``s (q(d) - d) > q(W d) - W d``. At 0.999: 3 epochs of 10 (1 Hz) at d = 4-28 (s > 2.3 -
    2.7); 8-9 of 100 (10 Hz) at d = 8-28 (s > 7.1 - 8.2); with the others at 0.55 of their
    dof (the car's median epoch) 4-5 of 10. Innovations 2x too large in every epoch (NIS ~
    2 chi2_d: winsorised mean 1.80-1.92 d at d = 8-28, so 10 epochs sum to 1.23-1.41x the
    window's quantile) and a lock-out (every epoch saturated) flag it.

    Geometry: an epoch with two or more fixes whose layout gives the heading to within
    :data:`MAX_FIT_YAW_SD` (the rigid fit of :class:`FilterStart`) tests the state's heading
    against it (chi-square, 1 dof, ``gate_prob``, and at least :data:`REINIT_MIN_YAW_RAD`
    off); so does a window test (2) failing while fixes are gated: the lock-out guard counts
    the window flag only, not the per-epoch one, since a lock-out persists (every epoch
    saturates, so the window fails within s epochs) while a manoeuvre's spike, with its
    fixes gated for an epoch or two, is no lock-out and must not re-initialise.
    :data:`REINIT_EPOCHS` such epochs in a row: re-initialise from the epoch's fit
    (:meth:`FilterStart.refit`)."""

    def __init__(self, starter: FilterStart, dt_med: float, gate_prob: float) -> None:
        self.starter = starter
        self.window = max(NIS_MIN_EPOCHS, round(NIS_WINDOW_S / dt_med))
        self.p = gate_prob if gate_prob < 1 else 0.999
        self.thr1 = chi2_ppf(self.p, 1)
        self.thr: dict[int, float] = {}      # chi-square quantiles by (summed) dof
        self.clear()

    def clear(self) -> None:
        self.nis: list[tuple[float, int]] = []   # (winsorised NIS, dof) of the window
        self.disagree = 0
        self.locked = 0

    def quantile(self, df: int) -> float:
        """Upper ``p`` quantile of chi-square with df degrees of freedom (cached)."""
        thr = self.thr.get(df)
        if thr is None:
            thr = self.thr[df] = float(_chdtri(df, 1.0 - self.p))
        return thr

    def tests(self, nis: float, dof: int) -> tuple[bool, bool]:
        """(per-epoch, window) test failed, after adding epoch (nis, dof) to the window."""
        q = self.quantile(dof)
        self.nis.append((min(q, nis), dof))
        if len(self.nis) > self.window:
            self.nis.pop(0)
        tot = sum(v for v, _ in self.nis)
        df = sum(d for _, d in self.nis)
        return nis > q, tot > self.quantile(df)

    def check(self, k: int, nis: float, dof: int, x: np.ndarray, P: np.ndarray,
              n_gated: int) -> tuple[bool, tuple[np.ndarray, np.ndarray] | None]:
        """(inconsistent, refit (x0, P0) or None) after epoch k's update."""
        if dof == 0 or not math.isfinite(nis):
            return False, None
        spike, window = self.tests(nis, dof)
        bad = spike or window
        yaw, sd = self.starter.fit_heading(k)
        if not sd <= MAX_FIT_YAW_SD:
            self.disagree = self.locked = 0
            return bad, None
        d = _wrap(yaw - x[YAW])
        var = P[YAW, YAW] + sd * sd
        off = d * d > self.thr1 * var and abs(d) > REINIT_MIN_YAW_RAD
        self.disagree = self.disagree + 1 if off else 0
        self.locked = self.locked + 1 if (window and n_gated > 0) else 0
        if max(self.disagree, self.locked) >= REINIT_EPOCHS:
            self.clear()
            return bad, self.starter.refit(k, x)
        return bad, None


def _cap_variance(P: np.ndarray, j: int, bound: float) -> float:
    """P (6, 6)'s variance j at most ``bound`` by a congruence (row and column j scaled by
    ``sqrt(bound / P[j, j])``, in place: P stays PSD, the correlations kept); returns the
    variance after."""
    var = float(P[j, j])
    if var > bound:
        s = math.sqrt(bound / var)
        P[j, :] *= s
        P[:, j] *= s
        var = bound
    return var


def _bound_yaw_rate(x: np.ndarray, P: np.ndarray, dt: float, kappa: float, om_max: float,
                    qy: float) -> float:
    """Keep the yaw rate within the no-slip kinematics over the next step (issue 25): it is
    at most ``b = kappa |v|`` (kappa the curvature limit, 1/m) where that is below the turn
    -rate limit om_max (there, e.g. near a standstill, it binds; above, om_max bounds the
    state's mean only, as the projection does, and nothing changes here), with ``v^2``
    taken as the speed's second moment at the step's end, ``v^2 + P_vv + dt^2 (a^2 +
    P_aa)``. So ``|omega| <= b`` (clipped in place) and its variance, that of a variable
    within [-b, b], at most ``b^2``: beyond it omega's row and column of P (6, 6) are scaled
    in place by ``b / sqrt(P_ww)`` (a congruence: P stays PSD), and the yaw-rate noise qy
    (its change's variance over the step / dt^2) is cut to what the bound leaves. A car at
    rest with a 1 m/s speed sd and kappa 0.2 1/m: yaw-rate sd <= 11 deg/s. Returns the
    yaw-rate noise to use."""
    v2 = x[V] * x[V] + P[V, V] + dt * dt * (x[A] * x[A] + P[A, A])
    b2 = kappa * kappa * v2 if kappa < math.inf else math.inf
    if not b2 < om_max * om_max:
        return qy
    if x[OMEGA] * x[OMEGA] > b2:
        x[OMEGA] = math.copysign(math.sqrt(b2), x[OMEGA])
    var = _cap_variance(P, OMEGA, b2)
    return min(qy, max(b2 - var, 0.0) / (dt * dt))


def _after_gap(starter: FilterStart, k: int) -> bool:
    """No antenna reported at both k-2 and k-1 (k < 2 included): the speed of the state at
    k-1 came from no displacement, so its sd (3.3 m/s 1 s after a 1 s all-antenna outage,
    issue 25) says nothing about rest."""
    return k < 2 or not bool((starter.present[k - 1] & starter.present[k - 2]).any())


def _moved(starter: FilterStart, k: int) -> bool:
    """The displacements to epoch k show the platform moving: the median over the antennas
    reporting at both k-1 and k of their displacement exceeds :data:`INIT_MOTION_SIGMAS`
    ``sigma_step`` (the start's motion test on one displacement; the median, so one
    antenna's spike does not count as motion). False without such an antenna. A speed
    whose sd merely covers 0 is no evidence of rest (issue 25, cpm drive 7, epoch 872: 1 s
    after an all-antenna outage the speed sd was 3.3 m/s while the car drove at 3.2 m/s,
    turning at 17 deg/s; a hold froze its yaw rate at 0 and the heading went 90 deg off)."""
    if k == 0:
        return False
    both = starter.present[k] & starter.present[k - 1]
    if not both.any():
        return False
    d = starter.obs[k, both] - starter.obs[k - 1, both]
    thr = INIT_MOTION_SIGMAS * starter.params._limit("sigma_step_m")
    return bool(np.median((d * d).sum(1)) > thr * thr)


def _standstill_hold(x: np.ndarray, P: np.ndarray, starter: FilterStart, k: int) -> bool:
    """Standing still where the layout cannot give the heading: epoch k has a fix, the
    speed is within :data:`STANDSTILL_SIGMAS` sd of 0 (right after a gap, where no
    displacement measured that speed (:func:`_after_gap`), the displacements to epoch k must
    also not show motion, :func:`_moved`) and epoch k's rigid-fit heading sd is above
    :data:`MAX_FIT_YAW_SD` (or fewer than two fixes). Then neither the motion nor the
    layout measures the heading, and metre-level errors wandering by centimetres per second
    would turn it at will (issue 25: 65 deg off after a 150 s stop with consumer errors):
    the yaw rate is set to 0 (x, P changed in place: a platform at rest does not turn) and
    the prediction adds no yaw noise. A layout that does give the heading is never held
    (a rover turning on the spot with centimetre fixes is followed)."""
    if not starter.present[k].any():
        return False                # an outage: predicted as usual (its sd grows, lost)
    if not x[V] <= STANDSTILL_SIGMAS * math.sqrt(max(P[V, V], 0.0)):
        return False
    if starter.fit_heading(k)[1] <= MAX_FIT_YAW_SD:
        return False
    if _after_gap(starter, k) and _moved(starter, k):
        return False
    _hold_state(x, P)
    return True


def _standstill_gap(starter: FilterStart, k: int) -> tuple[int, float] | None:
    """(j, thr) when epoch k has a fix, epoch k-1 none (an all-antenna gap) and the platform
    stood since j, the last epoch before k with a fix: every antenna present at both moved
    by at most ``thr = INIT_MOTION_SIGMAS sigma_step sqrt(k - j)`` (m; the test of
    :meth:`FilterStart._standstill_start`, the displacement noise growing as a random walk).
    None otherwise (no such antenna, or one moved farther)."""
    pr = starter.present
    if k < 2 or pr[k - 1].any() or not pr[k].any():
        return None
    if starter.last_fix is None:
        idx = np.where(pr.any(1), np.arange(pr.shape[0]), -1)
        starter.last_fix = np.maximum.accumulate(idx)
    j = int(starter.last_fix[k - 1])
    if j < 0:
        return None
    moved = starter.travel(j, k)
    if moved is None or not moved[1] <= moved[0]:
        return None
    return j, moved[0]


def _bound_after_standstill_gap(P: np.ndarray, PP: np.ndarray, starter: FilterStart, k: int,
                                kappa: float) -> None:
    """A car that did not move cannot have turned (issue 25): before epoch k's prediction,
    when the platform stood through the all-antenna gap before k (:func:`_standstill_gap`,
    since epoch j, travel at most thr), the heading's variance of P (6, 6, the state at k-1,
    changed in place) is at most ``PP[j]``'s (the pass's covariances (n, 6, 6)) plus
    ``(kappa thr)^2`` (kappa the curvature limit, 1/m: its yaw changed by at most kappa times
    the distance travelled); beyond it the heading's row and column are scaled by ``sqrt(bound
    / var)`` (a congruence: P stays PSD, the heading's correlations kept), which also shrinks
    the position-heading covariance the unheld prediction built on a speed clipped at 0.
    Without a curvature limit nothing changes."""
    g = _standstill_gap(starter, k) if kappa < math.inf else None
    if g is None:
        return
    _cap_variance(P, YAW, PP[g[0]][YAW, YAW] + (kappa * g[1]) ** 2)


def _hold_state(x: np.ndarray, P: np.ndarray) -> None:
    """A standstill hold's change of a state (6,) and covariance (6, 6), in place: yaw rate
    0, its variance at most 1e-12 and uncorrelated."""
    x[OMEGA] = 0.0
    var = P[OMEGA, OMEGA]
    P[OMEGA, :] = 0.0
    P[:, OMEGA] = 0.0
    P[OMEGA, OMEGA] = min(var, 1e-12)


def _project_limits(su: _Setup, x: np.ndarray) -> None:
    """The filter's limits on a state (6,), in place: no reverse unless allowed, speed,
    yaw rate (and lateral acceleration) and acceleration clipped to the platform's."""
    if not su.params.reverse and x[V] < 0.0:
        x[V] = 0.0
    if abs(x[V]) > su.v_max:
        x[V] = math.copysign(su.v_max, x[V])
    lim = su.om_max if x[V] == 0 else min(su.om_max, su.alat / abs(x[V]))
    if abs(x[OMEGA]) > lim:
        x[OMEGA] = math.copysign(lim, x[OMEGA])
    if abs(x[A]) > su.a_max:
        x[A] = math.copysign(su.a_max, x[A])


def _rotate(r: np.ndarray, a: float) -> np.ndarray:
    """Body offsets r (m, 2) rotated by a (rad)."""
    c, s = math.cos(a), math.sin(a)
    return np.c_[c * r[:, 0] - s * r[:, 1], s * r[:, 0] + c * r[:, 1]]


def _wrap_array(a: np.ndarray) -> np.ndarray:
    """Angles (n,) to (-pi, pi] (NaN kept)."""
    w = np.angle(np.exp(1j * a))
    return np.where(w == -math.pi, math.pi, w)


class _Pattern:
    """What an epoch measures, given which antennas reported at it (``now``, (m,) bool) and
    at the epoch before (``before``): the fixes ``ik`` and displacements ``js`` (antenna
    indices), their per-axis noise variances ``var`` (k,) and ``var2`` (2k,, per row of the
    stacked measurement vector), the lever arms as columns (``ax, ay`` of the fixes, ``dx,
    dy`` of the displacements), the Jacobian's template ``H0`` and the joint R's
    off-diagonal entries ``cross`` (rows of the fixes, rows of their displacements, the
    covariance :func:`fix_step_covariance`) for :func:`_kalman_update`."""

    __slots__ = ("H0", "ax", "ay", "cross", "dx", "dy", "ik", "js", "var", "var2")

    def __init__(self, now: np.ndarray, before: np.ndarray, r: np.ndarray, va: float,
                 vs: float) -> None:
        self.ik = np.flatnonzero(now)
        self.js = np.flatnonzero(now & before)
        self.var = np.concatenate((np.full(self.ik.size, va), np.full(self.js.size, vs)))
        self.var2 = np.repeat(self.var, 2)
        ra, rd = r[self.ik], r[self.js]
        self.ax, self.ay, self.dx, self.dy = ra[:, 0], ra[:, 1], rd[:, 0], rd[:, 1]
        self.H0 = _jacobian_template(self.ik.size, self.js.size)
        rf = 2 * np.searchsorted(self.ik, self.js)          # each displacement's fix
        rd = 2 * (self.ik.size + np.arange(self.js.size))
        self.cross = (np.r_[rf, rf + 1], np.r_[rd, rd + 1], fix_step_covariance(va, vs))


def _iterated_update(y, Y, z, pat, gate, lever, tol, nis_out=None, hold=False):
    """One epoch's update of the stacked state ``y = (x, x_prev)`` (12,), covariance Y,
    with the measurements z of the epoch's :class:`_Pattern` ``pat``: iterated EKF
    (Gauss-Newton on the same cost; Bell and Cathey 1993) with robust acceptance.

    The first pass gates against the prior (:func:`kalman_update`, tests 1 and 2). While a
    step turns a heading so far that R(yaw)'s linearisation error (``dyaw^2/2 |r|``, ``|r|``
    the longest lever arm) exceeds ``tol`` (a tenth of the fix sd), the measurements are
    relinearised at the new
    estimate; each pass also re-admits the measurements the prior gate had rejected if they
    agree with the current posterior (a prior far off, e.g. at the onset of a sharp turn
    sampled at 1 Hz, must not discard centimetre fixes that agree with each other), and the
    deleted-residual test removes the ones that contradict the rest. ``hold`` (a standstill
    hold, :func:`_standstill_hold`): the fixes do not measure the heading (their Jacobian's
    heading column is 0; the displacements still measure its change). A standing platform
    repeats one geometry, and the fixes' errors are correlated in time (module docstring),
    so the same biased layout heading, epoch after epoch, is one measurement, not N: taken
    as N it walked the heading by 60 deg over a 150 s stop while its sd shrank to 2 deg
    (issue 25). The noise is the joint one of :func:`fix_step_covariance` (``pat.cross``);
    the re-admission test takes each rejected measurement on its own (its correlation with
    an accepted one left out: a test, not the update, which is exact).
    """
    yl = y
    acc = y1 = Y1 = None
    var = pat.var
    for _ in range(MAX_ITERATIONS):
        h, H = _fill_measurements(yl, pat.ax, pat.ay, pat.dx, pat.dy, pat.H0.copy())
        if hold:
            H[:pat.ik.size, :, YAW] = 0.0
        nu = z - h if yl is y else z - h - H @ (y - yl)
        if acc is not None and not acc.all():
            out = np.flatnonzero(~acc)
            Ho = H[out]
            S = (Ho @ Y1) @ Ho.transpose(0, 2, 1)
            S[:, 0, 0] += var[out]
            S[:, 1, 1] += var[out]
            acc[out[_quad2(S, nu[out] - Ho @ (y1 - y)) <= gate]] = True
        y1, Y1, acc = _kalman_update(y, Y, nu, H, pat.var2, gate, accept=acc,
                                     nis_out=nis_out if yl is y and acc is None else None,
                                     cross=pat.cross)
        if not acc.any():
            break
        turn = max(abs(_wrap(y1[YAW] - yl[YAW])), abs(_wrap(y1[NX + YAW] - yl[NX + YAW])))
        if 0.5 * turn * turn * lever < tol:      # R(yaw) r's second-order term
            break
        yl = y1
    return y1, Y1, acc


def _check_obs_offsets(obs, offsets) -> tuple[np.ndarray, np.ndarray]:
    """obs (n, m, 2) m (NaN = missing, |value| <= MAX_COORD_M) and offsets (m, 2) m
    (|value| <= MAX_OFFSET_M, layout extent >= MIN_EXTENT_M) as float arrays, or a
    ValueError naming the argument."""
    obs = check_array(obs, "obs", allow_nan=True, max_abs=MAX_COORD_M)
    if obs.ndim != 3 or obs.shape[2] != 2:
        raise ValueError(f"obs: expected shape (n, m, 2) metres, got {obs.shape}")
    m = obs.shape[1]
    off = check_array(offsets, "offsets", shape=(m, 2), max_abs=MAX_OFFSET_M)
    if _extent(off) < MIN_EXTENT_M:
        at = f"({off[0, 0]:g}, {off[0, 1]:g})" if m else "(none)"
        raise ValueError(f"offsets: the {m} antenna(s) are all at one point {at} m (layout "
                         f"extent below {MIN_EXTENT_M:g} m): the layout cannot give the "
                         "heading; the filter needs two antennas at distinct positions")
    return obs, off


def _check_times(t, n: int) -> np.ndarray:
    """t (n,) s: finite, strictly increasing, |t| <= MAX_TIME_S, steps >= MIN_STEP_S."""
    tt = check_increasing_times(t, "t", n=n, min_size=1)
    if abs(tt[0]) > MAX_TIME_S or abs(tt[-1]) > MAX_TIME_S:
        k = 0 if abs(tt[0]) > MAX_TIME_S else n - 1
        raise ValueError(f"t: |time| must be <= {MAX_TIME_S:g} s; t[{k}] = {tt[k]!r} "
                         "(nanoseconds? pass seconds)")
    if n > 1:
        step = np.diff(tt)
        k = int(step.argmin())
        if step[k] < MIN_STEP_S:
            raise ValueError(f"t: steps must be >= {MIN_STEP_S:g} s; t[{k + 1}] - t[{k}] = "
                             f"{step[k]!r} s")
    return tt


def _check_run_args(t, obs, offsets, params):
    obs, off = _check_obs_offsets(obs, offsets)
    tt = _check_times(t, obs.shape[0])
    if not isinstance(params, PoseFilterParams):
        raise TypeError(f"params: expected a PoseFilterParams, got {type(params).__name__}")
    nan = np.isnan(obs)
    if np.any(nan[..., 0] != nan[..., 1]):
        k, i = np.argwhere(nan[..., 0] != nan[..., 1])[0]
        raise ValueError(f"obs: epoch {k}, antenna {i} has one coordinate NaN; a missing fix "
                         f"must be NaN in both")
    return tt, obs, off


def chi2_ppf(p: float, df: int) -> float:
    """Quantile of the chi-square distribution with df = 1 or 2 degrees of freedom at
    probability 0 <= p < 1, in closed form (the gates' thresholds, without a dependency on
    scipy.stats): df 2 is -2 ln(1 - p), df 1 the squared standard-normal quantile of
    (1 - p) / 2."""
    if df == 2:
        return -2.0 * math.log1p(-p)
    if df == 1:
        return NormalDist().inv_cdf(0.5 * (1.0 - p)) ** 2   # the lower tail: no cancellation
    raise ValueError(f"df: must be 1 or 2, got {df!r}")


def run_pose_filter(t: np.ndarray, obs: np.ndarray, offsets: np.ndarray,
                    params: PoseFilterParams = PoseFilterParams(), *,
                    engine: str = "numba") -> PoseFilterResult:
    """Run the filter over a recording (module docstring for the model).

    t : (n,) s, finite and strictly increasing (uneven steps are fine), steps >= 1 ns
        (:data:`MIN_STEP_S`), |t| <= :data:`MAX_TIME_S`.
    obs : (n, m, 2) metres (world x east, y north), NaN = the antenna did not report;
        |value| <= :data:`MAX_COORD_M`.
    offsets : (m, 2) metres, antenna body positions relative to the configuration's CG
        (body x forward, y left); dead antennas simply never report. At least two distinct
        positions (layout extent >= :data:`MIN_EXTENT_M`: a layout at one point gives no
        heading), |offset| <= :data:`MAX_OFFSET_M`.
    params : :class:`PoseFilterParams` (limits, noise levels or None = estimated, no-slip
        point, reverse mode, gates).
    engine : "numba" (default: the compiled loop of :mod:`estimator.pose_filter_kernel`)
        or "numpy" (the reference: the loop below, numpy calls per epoch). They agree to
        rounding: the same status, gate, deletion and restart decisions, states within
        the tolerance of tests/test_pose_filter_kernel.py.

    Returns a :class:`PoseFilterResult` of n rows; rows before the start are NaN with status
    "waiting" or "no_data". Wrong shapes or values raise ValueError/TypeError naming the
    argument.
    """
    tt, obs, off = _check_run_args(t, obs, offsets, params)
    if engine not in ENGINES:
        raise ValueError(f"engine: must be one of {ENGINES}, got {engine!r}")
    su = _setup(tt, obs, off, params.resolve(tt, obs, off))
    n, m = obs.shape[:2]
    out = _outputs(n)
    if engine == "numba" and _thr_table_size(n, m, su.monitor.window) <= MAX_THR_TABLE:
        status = _run_kernel(tt, obs, su.present, su.r_m, su.starter, su.monitor,
                             _kernel_par(su), out)
    else:
        status = _ReferencePass(su, out).run()
    return _result(out, status, su.delta, su.params, su.cg_offset)


@dataclass(frozen=True, eq=False)
class _Setup:
    """The constants of one forward pass, from the resolved parameters (SI units; module
    docstring): the travel frame (``delta``, lever arms ``r_m`` from the no-slip point,
    ``cg_offset``), noise variances ``va`` / ``vs``, gates, process noise ``qa`` / ``qy``,
    limits, the flip distance, the start and the consistency monitor."""

    tt: np.ndarray
    obs: np.ndarray
    present: np.ndarray
    params: PoseFilterParams
    delta: float
    r_m: np.ndarray
    cg_offset: np.ndarray
    sigma_abs: float
    va: float
    vs: float
    v_max: float
    dt_med: float
    gate: float
    flip_thr: float
    qa: float
    qy: float
    om_max: float
    alat: float
    a_max: float
    kappa: float
    lever: float
    flip_dist: float
    starter: FilterStart
    monitor: _Monitor


def _setup(tt: np.ndarray, obs: np.ndarray, off: np.ndarray, params: PoseFilterParams
           ) -> _Setup:
    """:class:`_Setup` of a pass over t (n,), obs (n, m, 2), offsets (m, 2) with resolved
    ``params``."""
    n, m = obs.shape[:2]
    ns = np.asarray(params.no_slip_point_m, dtype=float)
    delta = float(params._limit("travel_offset_rad"))
    # the filter runs in the travel frame (x along the no-slip point's velocity): antenna
    # offsets from the no-slip point rotated by -delta, heading = layout heading + delta
    r_m = _rotate(off - ns, -delta)
    sigma_abs, sigma_step = params._limit("sigma_abs_m"), params._limit("sigma_step_m")
    dt_med = float(np.median(np.diff(tt))) if n > 1 else 1.0
    # the acceleration's increment per sample: half the limit, or half the jerk limit's
    # change over a sample when that is smaller (a car at 1 Hz: 4 m/s^2 but ~3 m/s^3); the
    # jerk is measured over ~1 s (estimator.platform), so it bounds no shorter interval
    jerk_step = (params.max_jerk_mps3 * max(dt_med, JERK_SCALE_S)
                 if params.max_jerk_mps3 is not None else math.inf)
    a_max = params._limit("max_accel_mps2")
    present = np.isfinite(obs[..., 0])
    n_alive = max(int(present.any(axis=0).sum()), 1)
    starter = FilterStart(tt, obs, r_m, sigma_abs, params)
    return _Setup(
        tt=tt, obs=obs, present=present, params=params, delta=delta, r_m=r_m,
        cg_offset=-ns,                     # CG relative to the no-slip point (layout frame)
        sigma_abs=sigma_abs, va=sigma_abs ** 2, vs=sigma_step ** 2,
        v_max=params._limit("max_speed_mps"), dt_med=dt_med,
        gate=chi2_ppf(params.gate_prob, 2) if params.gate_prob < 1 else math.inf,
        flip_thr=chi2_ppf(params.gate_prob, 1) if params.gate_prob < 1 else 10.83,
        qa=(0.5 * min(a_max, jerk_step)) ** 2, qy=params.sigma_yaw_accel ** 2,
        om_max=params._limit("max_turn_rate_radps"),
        alat=params._limit("max_lateral_accel_mps2"), a_max=a_max,
        kappa=params.max_curvature_1pm if params.max_curvature_1pm is not None else math.inf,
        lever=float(np.sqrt((r_m ** 2).sum(1).max())) if m else 0.0,
        flip_dist=max(INIT_MOTION_SIGMAS * sigma_abs * math.sqrt(2.0 / n_alive), _extent(off),
                      a_max * dt_med * dt_med),
        starter=starter, monitor=_Monitor(starter, dt_med, params.gate_prob))


def _outputs(n: int) -> tuple:
    """The forward pass's output arrays for n epochs, NaN / 0 (see :func:`_run_kernel`):
    X, PP, XC, PC, PX_, seg, n_used, n_gated, n_steps, nis, nis_dof."""
    return (np.full((n, NX), np.nan), np.full((n, NX, NX), np.nan), np.full((n, NX), np.nan),
            np.full((n, NX, NX), np.nan), np.full((n, NX, NX), np.nan),
            np.zeros(n, dtype=bool), np.zeros(n, dtype=int), np.zeros(n, dtype=int),
            np.zeros(n, dtype=int), np.full(n, np.nan), np.zeros(n, dtype=int))


def _kernel_par(su: _Setup) -> np.ndarray:
    """The compiled loop's scalars (:data:`estimator.pose_filter_kernel.N_PAR`, in the
    order of its ``I_*`` indices)."""
    p = su.params
    return np.array([su.sigma_abs, su.va, su.vs, su.dt_med, su.gate, su.flip_thr, su.qa, su.qy,
                     su.om_max, su.alat, su.a_max, su.v_max, su.lever, su.flip_dist,
                     min(su.va, su.vs), p.flip_memory_s, su.monitor.thr1, float(p.reverse),
                     float(p.max_rejects), float(su.monitor.window), INIT_MAX_YAW_SD,
                     INIT_MOTION_SIGMAS, LOST_YAW_SD, MAX_FIT_YAW_SD, STANDSTILL_SIGMAS,
                     REINIT_EPOCHS, REINIT_MIN_YAW_RAD, MAX_ITERATIONS, MAX_PRIOR_RATIO,
                     su.kappa, p._limit("max_yaw_accel_radps2")])


class _ReferencePass:
    """The forward pass in numpy (``engine="numpy"``, the reference the compiled loop is
    tested against), one method per step of an epoch: predict (:meth:`_predict`), wait /
    start (:meth:`_wait`), update (:meth:`_update`), the monitor's re-initialisation
    (:meth:`_refit`), direction of travel (:meth:`_direction`), lost track and limits
    (:meth:`_finish`). ``out``: the arrays of :func:`_outputs`, filled in place."""

    def __init__(self, su: _Setup, out: tuple) -> None:
        self.su = su
        (self.X, self.PP, self.XC, self.PC, self.PX_, self.seg, self.n_used, self.n_gated,
         self.n_steps, self.nis, self.nis_dof) = out
        n = su.tt.size
        self.status = np.full(n, "", dtype=object)
        self.x: np.ndarray | None = None
        self.P: np.ndarray | None = None
        self.lost = False          # the next start is a restart
        self.rej_abs = self.rej_step = 0
        self.llr = 0.0             # reverse mode: log-likelihood ratio for the flipped heading
        self.back = 0.0            # forward mode: backward travel over consecutive epochs, m
        # what each epoch measures depends only on which antennas reported at it and at the
        # epoch before: built once per such pattern (_Pattern), the same numbers every time
        self.rows = [row.tobytes() for row in su.present]
        self.patterns: dict[tuple[bytes, bytes], _Pattern] = {}
        self.dts = np.diff(su.tt).tolist()
        self.var_min = min(su.va, su.vs)

    def run(self) -> np.ndarray:
        """Every epoch in turn; returns the status (n,) object array."""
        for k in range(self.su.tt.size):
            pred = self._predict(k) if self.x is not None else None
            if self.x is None:
                self._wait(k)
                continue
            assert pred is not None
            self._epoch(k, *pred)
        return self.status

    def _lose(self) -> None:
        """The track is lost: wait for data and restart (reported on the restart)."""
        self.x = self.P = None
        self.su.starter.reset()
        self.lost = True

    def _clear_flags(self) -> None:
        self.rej_abs, self.rej_step, self.llr, self.back = 0, 0, 0.0, 0.0

    def _predict(self, k: int) -> tuple | None:
        """Stochastic cloning: predict x_k and keep x_{k-1} beside it, jointly Gaussian.
        Returns (xp, Pp, FP, dt, hold), or None when the prediction means nothing (e.g.
        after an hour's gap in t: the track is lost; this epoch's data start it again)."""
        su, x, P = self.su, self.x, self.P
        assert x is not None and P is not None
        dt = self.dts[k - 1]
        _bound_after_standstill_gap(P, self.PP, su.starter, k, su.kappa)
        # continuous noise of constant density: the variances of the rates' changes
        # given per median step, scaled to this step (longer gaps: larger)
        hold = _standstill_hold(x, P, su.starter, k)
        qy_k = _bound_yaw_rate(x, P, dt, su.kappa, su.om_max,
                               0.0 if hold else su.qy * su.dt_med / dt)
        xp, Pp, FP = _predict(x, P, dt, su.qa * dt / su.dt_med, qy_k)
        if su.present[k].any() and _prior_lost(Pp, su.lever, self.var_min):
            self._lose()
            return None
        return xp, Pp, FP, dt, hold

    def _wait(self, k: int) -> None:
        """A waiting epoch: start (or restart) here when the data allow."""
        self.status[k], got = self.su.starter.wait(k)
        if got is None:
            return
        self.x, self.P = got
        self.X[k], self.PP[k], self.seg[k] = self.x, self.P, True
        self.status[k] = "reset" if self.lost else "init"
        self.n_used[k] = np.count_nonzero(self.su.present[k])
        self._clear_flags()
        self.su.monitor.clear()

    def _pattern(self, k: int) -> _Pattern:
        su = self.su
        pat = self.patterns.get((self.rows[k], self.rows[k - 1]))
        if pat is None:
            pat = self.patterns[self.rows[k], self.rows[k - 1]] = _Pattern(
                su.present[k], su.present[k - 1], su.r_m, su.va, su.vs)
        return pat

    def _epoch(self, k: int, xp: np.ndarray, Pp: np.ndarray, FP: np.ndarray, dt: float,
               hold: bool) -> None:
        """A running epoch: update, monitor, direction, limits."""
        assert self.x is not None and self.P is not None
        y: np.ndarray = np.concatenate((xp, self.x))
        Y = np.empty((2 * NX, 2 * NX))
        Y[:NX, :NX], Y[:NX, NX:], Y[NX:, :NX], Y[NX:, NX:] = Pp, FP, FP.T, self.P
        st = "predicted"
        pat = self._pattern(k)
        acc_abs = np.zeros(0, dtype=bool)
        if pat.ik.size:
            upd = self._update(k, y, Y, pat, hold)
            if upd is None:
                return
            y, Y, st, acc_abs = upd
        x, P = y[:NX].copy(), Y[:NX, :NX].copy()
        self.XC[k], self.PC[k], self.PX_[k] = y[NX:], Y[NX:, NX:], Y[:NX, NX:]
        bad, refit = self.su.monitor.check(k, self.nis[k], self.nis_dof[k], x, P,
                                           self.n_gated[k])
        if refit is not None:
            self._refit(k, *refit)
            return
        if bad and st == "ok":
            st = "inconsistent"
        if pat.ik.size:
            x, P, st = self._direction(k, x, P, y, pat.ik, acc_abs, dt, st)
        self._finish(k, x, P, st)

    def _update(self, k: int, y: np.ndarray, Y: np.ndarray, pat: _Pattern, hold: bool
                ) -> tuple | None:
        """Epoch k's fixes and displacements (:func:`_iterated_update`), the motion-model
        miss and the lost track; returns (y, Y, status, accepted fixes) or None when the
        row is done (re-initialised or lost)."""
        su, obs = self.su, self.su.obs
        ik, js = pat.ik, pat.js            # fixes; displacements since k-1
        zk = obs[k, ik]
        z = np.concatenate((zk, obs[k, js] - obs[k - 1, js])) if js.size else zk
        box: list[float] = []           # the prior NIS, from the first pass's S
        try:
            y1, Y1, acc = _iterated_update(y, Y, z, pat, su.gate, su.lever, 0.1 * su.sigma_abs,
                                           box, hold)
        except np.linalg.LinAlgError:   # numerically singular: nothing to trust
            y1, Y1, acc = y, Y, np.zeros(ik.size + js.size, dtype=bool)
            self.rej_abs = self.rej_step = su.params.max_rejects
        if box:
            self.nis[k], self.nis_dof[k] = box[0], 2 * z.shape[0]
        acc_abs, acc_step = acc[:ik.size], acc[ik.size:]
        self.n_used[k] = np.count_nonzero(acc_abs)
        self.n_gated[k] = ik.size - self.n_used[k]
        self.n_steps[k] = np.count_nonzero(acc_step)
        if ik.size >= 2 and self.n_used[k] == 0 and su.starter.motion_miss(k):
            # every fix gated while the epoch's own fit agrees with the layout: the motion
            # model missed (a hard acceleration), the data did not; re-initialise from the
            # fit at once instead of coasting on a wrong prediction
            assert self.x is not None
            self.x, self.P = su.starter.refit(k, self.x)
            su.monitor.clear()
            self.X[k], self.PP[k], self.seg[k], self.status[k] = self.x, self.P, True, "reinit"
            self._clear_flags()
            su.starter.remember(k, self.x, self.P)
            return None
        self.rej_abs = self.rej_abs + 1 if self.n_used[k] == 0 else 0
        self.rej_step = self.rej_step + 1 if (js.size >= 2 and self.n_steps[k] == 0) else 0
        if max(self.rej_abs, self.rej_step) >= su.params.max_rejects:
            self._lose()
            self.status[k] = "waiting"
            return None
        st = "predicted"
        if acc.any():
            y, Y, st = y1, Y1, "ok"
            y[YAW] = _wrap(y[YAW])
            y[NX + YAW] = _wrap(y[NX + YAW])
        return y, Y, st, acc_abs

    def _refit(self, k: int, x: np.ndarray, P: np.ndarray) -> None:
        """The state contradicts the layout's own geometry (or its innovations stay
        inconsistent) for REINIT_EPOCHS epochs: re-initialised from the epoch's rigid fit;
        a new segment (no smoother links across it)."""
        self.x, self.P = x, P
        self.X[k], self.PP[k], self.seg[k], self.status[k] = x, P, True, "reinit"
        self.XC[k], self.PC[k], self.PX_[k] = np.nan, np.nan, np.nan
        self._clear_flags()

    def _direction(self, k: int, x: np.ndarray, P: np.ndarray, y: np.ndarray, ik: np.ndarray,
                   acc_abs: np.ndarray, dt: float, st: str) -> tuple[np.ndarray, np.ndarray, str]:
        """Direction of travel (module docstring): the forward mode's backward-travel test
        or the reverse mode's log-likelihood ratio; a flip is reported."""
        su = self.su
        if not su.params.reverse:
            # backward travel of the no-slip point over consecutive intervals (its
            # displacement from the previous pose, re-estimated with this epoch's data,
            # along the mean heading: the speed itself may swing when only the mean
            # over each interval is well measured); beyond the threshold: flip
            mh = y[YAW] + 0.5 * _wrap(y[NX + YAW] - y[YAW])
            step = ((y[PX] - y[NX + PX]) * math.cos(mh) + (y[PY] - y[NX + PY]) * math.sin(mh))
            self.back = self.back - step if step < 0.0 else 0.0
            if self.back > su.flip_dist:
                x, P = _flip(x, P)
                st, self.back = "flip_corrected", 0.0
            elif x[V] < 0.0:
                x[V] = 0.0
        elif np.count_nonzero(acc_abs) >= 2:
            good = ik[acc_abs]
            # configuration's evidence for yaw + pi: residuals of the accepted fixes
            # with R(yaw) r and -R(yaw) r; LLR = (|e+|^2 - |e-|^2) / (2 var)
            hz, _ = antenna_jacobians(x, su.r_m[good])
            e_plus = su.obs[k, good] - hz
            e_minus = e_plus + 2.0 * (hz - x[:2])
            self.llr = self.llr * math.exp(-dt / su.params.flip_memory_s) + float(
                ((e_plus ** 2).sum() - (e_minus ** 2).sum()) / (2.0 * su.va))
            if self.llr > su.flip_thr:
                x, P = _flip(x, P)
                st, self.llr = "flip_corrected", 0.0
        return x, P, st

    def _finish(self, k: int, x: np.ndarray, P: np.ndarray, st: str) -> None:
        """A lost track (heading sd beyond LOST_YAW_SD, or an overflow), else the row with
        the platform's limits (projection)."""
        su = self.su
        if not (P[YAW, YAW] <= LOST_YAW_SD ** 2 and _finite(x, P)):
            # predicted so long without data that the heading means nothing (or a value
            # overflowed): lost; wait for data and restart (e.g. a long outage). The row
            # holds nothing, its clone neither (a smoother must not link across it).
            self._lose()
            self.status[k] = "waiting"
            self.XC[k], self.PC[k], self.PX_[k] = np.nan, np.nan, np.nan
            return
        _project_limits(su, x)  # forward mode on every row: predicted ones and flips too
        self.x, self.P = x, P
        self.X[k], self.PP[k], self.status[k] = x, P, st
        if st != "predicted":
            su.starter.remember(k, x, P)
        if st == "flip_corrected":
            self.seg[k] = True


#: The filter's engines (:func:`run_pose_filter`).
ENGINES = ("numba", "numpy")


#: Largest table of chi-square quantiles the compiled loop takes (entries, 8 bytes each);
#: beyond it (an NIS window of thousands of epochs) the numpy loop runs.
MAX_THR_TABLE = 1 << 20


def _thr_table_size(n: int, m: int, window: int) -> int:
    """Entries of the NIS window's quantile table: every even summed dof up to the window's
    epochs (at most n) times 2 dof per fix and per displacement (2m measurements)."""
    return min(window, n) * 2 * m + 1


def _run_kernel(tt: np.ndarray, obs: np.ndarray, present: np.ndarray, r_m: np.ndarray,
                starter: FilterStart, monitor: _Monitor, par: np.ndarray, out: tuple
                ) -> np.ndarray:
    """The forward pass in :func:`estimator.pose_filter_kernel.forward_kernel`, filling
    ``out`` (X, PP, XC, PC, PX_, seg, n_used, n_gated, n_steps, nis, nis_dof) as the
    reference loop does; returns the status (n,) object array of strings."""
    from estimator import pose_filter_kernel as kern

    n, m = obs.shape[:2]
    starter.fit_heading(0)                       # fills starter._spread
    spread = starter._spread if starter._spread is not None else np.zeros(n)
    r2 = (present * starter.r2[None, :]).sum(1)
    j = np.arange(_thr_table_size(n, m, monitor.window))
    with np.errstate(invalid="ignore"):
        thr = _chdtri(2.0 * j, 1.0 - monitor.p)
    code = np.zeros(n, dtype=np.int64)
    X, PP, XC, PC, PX_, seg, n_used, n_gated, n_steps, nis, nis_dof = out
    kern.forward_kernel(tt, obs, present, np.ascontiguousarray(r_m), starter.origin,
                        starter.yaw, starter.cnt.astype(float), spread, r2, starter.fit_ok, par,
                        thr,
                        _HORNER_ARRAY, _CW, X, PP, XC, PC, PX_, seg, code, n_used, n_gated,
                        n_steps, nis, nis_dof)
    return _status_strings(code)


def _status_strings(code: np.ndarray) -> np.ndarray:
    """The status codes (n,) as strings: the array ``np.asarray(STATUSES, dtype=object)[code]
    .astype(str)`` (dtype as wide as the longest status present, at least 1), without n
    Python objects."""
    used = np.flatnonzero(np.bincount(code, minlength=len(STATUSES)))
    width = max([1] + [len(STATUSES[c]) for c in used])
    return np.asarray(STATUSES).astype(f"<U{width}")[code]


def _result(out: tuple, status: np.ndarray, delta: float, params: PoseFilterParams,
            cg_offset: np.ndarray) -> PoseFilterResult:
    """The :class:`PoseFilterResult` of a forward pass's arrays ``out`` (see
    :func:`_run_kernel`), headings turned back to the layout's (by -delta)."""
    X, PP, XC, PC, PX_, seg, n_used, n_gated, n_steps, nis, nis_dof = out
    for S_ in (X, XC):
        S_[:, YAW] = _wrap_array(S_[:, YAW] - delta)
    return PoseFilterResult(states=X, covariances=PP, prev_states=XC, prev_covariances=PC,
                            cross_covariances=PX_, segment_start=seg,
                            status=status.astype(str, copy=False), n_used=n_used, n_gated=n_gated,
                            n_steps=n_steps, sigma_abs_m=float(params._limit("sigma_abs_m")),
                            sigma_step_m=float(params._limit("sigma_step_m")), cg_offset=cg_offset,
                            nis=nis, nis_dof=nis_dof, params=params)


def nis_summary(nis: np.ndarray, dof: np.ndarray, band: float = 0.95) -> dict[str, float]:
    """Consistency of a filter's innovations: nis (n,) and dof (n,) per row (NaN / 0 where
    no data). Returns ``mean_nis_per_dof`` (1 for a consistent filter), ``share_in_band``
    (share of rows whose NIS lies inside the central ``band`` interval of chi-square with
    that row's dof; ``band`` for a consistent filter) and ``n`` rows used."""
    v = np.asarray(nis, dtype=float)
    d = np.asarray(dof, dtype=float)
    ok = np.isfinite(v) & (d > 0)
    if not ok.any():
        return {"mean_nis_per_dof": math.nan, "share_in_band": math.nan, "n": 0}
    # the band per distinct dof (a few small integers), not per row: the same numbers, and
    # ~0.2 ms instead of ~2 ms per call on a 4000-epoch track (1440 calls in the thesis preset)
    dof_u, row = np.unique(d[ok], return_inverse=True)
    lo = _chdtri(dof_u, 0.5 + 0.5 * band)[row]
    hi = _chdtri(dof_u, 0.5 - 0.5 * band)[row]
    inside = (v[ok] >= lo) & (v[ok] <= hi)
    return {"mean_nis_per_dof": float(v[ok].sum() / d[ok].sum()),
            "share_in_band": float(inside.mean()), "n": int(ok.sum())}


def nees(err: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Normalised estimation error squared per row: err (n, k) (truth minus estimate, any
    state components, angles wrapped by the caller) and cov (n, k, k) their covariance;
    NaN where either is NaN or cov is singular. Chi-square with k dof when consistent."""
    e = np.asarray(err, dtype=float)
    C = np.asarray(cov, dtype=float)
    out = np.full(e.shape[0], np.nan)
    ok = np.isfinite(e).all(1) & np.isfinite(C).all((1, 2))
    if ok.any():
        try:
            sol = np.linalg.solve(C[ok], e[ok][..., None])[..., 0]
            out[ok] = (e[ok] * sol).sum(1)
        except np.linalg.LinAlgError:
            for i in np.flatnonzero(ok):
                with suppress(np.linalg.LinAlgError):
                    out[i] = float(e[i] @ np.linalg.solve(C[i], e[i]))
    return out


def pass_key(t: np.ndarray, obs: np.ndarray, offsets: np.ndarray, params: PoseFilterParams
             ) -> tuple:
    """Memo key of a forward pass: digest of the validated t, obs and offsets, and params
    (raises like :func:`run_pose_filter` on bad input)."""
    tt, o, off = _check_run_args(t, obs, offsets, params)
    return (content_digest(tt, o, off), params)


def memo_pose_filter(t: np.ndarray, obs: np.ndarray, offsets: np.ndarray,
                     params: PoseFilterParams = PoseFilterParams(),
                     cache: TrackCache | None = None) -> PoseFilterResult:
    """:func:`run_pose_filter` through ``cache.filter_pass``
    (:class:`estimator.memo.TrackCache`; None: computed): the same numbers, computed once
    per (t, obs, offsets, params) and cache. A sweep runs the EKF at several windows (it only
    drops the first s-1 rows), its smoothers and the smoothed heading of the lag correction on
    the same observations; one pass serves them all. The result may be shared, so its arrays
    are read-only."""
    def compute() -> PoseFilterResult:
        res = run_pose_filter(t, obs, offsets, params)
        for v in vars(res).values():
            if isinstance(v, np.ndarray):
                freeze(v)
        return res

    return memo_get(cache, "filter_pass", lambda: pass_key(t, obs, offsets, params), compute)


def _prior_lost(Pp: np.ndarray, lever: float, var_min: float) -> bool:
    """The prediction (covariance Pp (6, 6)) is too wide for an update in double precision:
    its spread at the antennas (position variance + ``lever^2`` x heading variance, m^2;
    lever: the longest lever arm, m) beyond :data:`MAX_PRIOR_RATIO` times the smallest
    measurement variance ``var_min`` (m^2), or not finite. (A wide heading alone is left to
    the update: the layout's fixes pull it in; the check after the update decides.)"""
    spread = max(Pp[PX, PX], Pp[PY, PY]) + lever * lever * Pp[YAW, YAW]
    return not spread <= MAX_PRIOR_RATIO * var_min


def _finite(x: np.ndarray, P: np.ndarray) -> bool:
    """Every entry of the state (6,) and covariance (6, 6) finite."""
    return bool(np.isfinite(x).all() and np.isfinite(P).all())


def _extent(offsets: np.ndarray) -> float:
    """Largest distance between two antennas of the layout, m."""
    d = offsets[:, None, :] - offsets[None, :, :]
    return float(np.sqrt((d * d).sum(-1)).max()) if len(offsets) else 0.0


def _flip(x: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The same motion with the heading turned by pi: (yaw + pi, -v, -a); P mapped by
    diag(1, 1, 1, -1, -1, 1) (the no-slip point's position and the yaw rate are kept)."""
    xn = x.copy()
    xn[YAW] = _wrap(x[YAW] + math.pi)
    xn[V] = -x[V]
    xn[A] = -x[A]
    J = np.array([1.0, 1.0, 1.0, -1.0, -1.0, 1.0])
    return xn, P * J[:, None] * J[None, :]
