"""Extended Kalman filter on the antennas with the sensor configuration as measurement model.

The dissertation's future work (000_8f82f8df647bf685.txt, Section 5.2): "a system that takes
advantage of extended Kalman Filter and the quadratic optimization framework using sensor
configuration knowledge". Here the configuration enters the measurement model directly, and
the filter is built to hold its heading on any wheeled platform, from a 0.2 m/s rover to a
20 m/s car (issue 14). Its smoother (fixed-lag and full RTS) is :mod:`estimator.pose_smoother`.

State and non-holonomic constraint
----------------------------------
``x = (px, py, yaw, v, omega)``: position (m) of the platform's *no-slip point* M, heading
(rad, CCW from +x), speed of M along the heading (m/s) and yaw rate (rad/s). M is the point of
the body whose velocity has no lateral component: the middle of the driven axle of a
differential drive (the rover's axle passes under its CG), the middle of the rear axle of a
car. Writing the velocity of M as ``v (cos yaw, sin yaw)`` with no lateral term IS the
non-holonomic constraint, exactly (a hard constraint, not a soft prior). Every other body point
moves sideways in a turn: the CG, ``b_cg - b_M`` ahead of M, has lateral speed
``omega (b_cg - b_M)_x``. M is given in :attr:`PoseFilterParams.no_slip_point_m` (body frame,
relative to the configuration's CG; (0, 0) for the rover). Tyre slip (a car's few degrees of
slip angle at high lateral acceleration) violates the constraint; it enters as model error.

Motion model: constant turn rate and velocity (CTRV),

    px' = px + v dt (cos(yaw) f1 - sin(yaw) f2),  py' = py + v dt (sin(yaw) f1 + cos(yaw) f2)
    yaw' = yaw + omega dt,   v' = v,   omega' = omega,
    f1 = sin(q)/q, f2 = (1 - cos q)/q, q = omega dt (series below |q| = 1e-4),

driven by white longitudinal acceleration (sd ``sigma_accel``) and yaw acceleration
(``sigma_yaw_accel``): ``Q = G diag(sa^2, sy^2) G^T`` with ``G = [[dt^2/2 cos yaw, 0],
[dt^2/2 sin yaw, 0], [0, dt^2/2], [dt, 0], [0, dt]]`` (discrete white-noise acceleration).

Process noise and gates from the platform's limits (never tuned on truth)
-------------------------------------------------------------------------
``sigma_accel = max_accel_mps2 / 2`` and ``sigma_yaw_accel = max_yaw_accel_radps2 / 2``: the
rule for the white-noise acceleration model of Bar-Shalom, Li and Kirubarajan, *Estimation
with Applications to Tracking and Navigation* (2001), Section 6.3.2: the noise sd "of the order
of the maximum acceleration magnitude a_M", in ``[0.5 a_M, a_M]``; we take the lower end since
a ground vehicle spends most of its time below its limits. The turn rate is bounded by the
platform: ``|omega| <= min(max_turn_rate_radps, max_lateral_accel_mps2 / |v|)`` (the
lateral-acceleration limit ``|v omega| <= a_lat``), enforced by projection after each update.
Gates are chi-square tests on the innovation covariance, which carries that process noise, so
they widen with the platform's agility and the time since the last update. The limits come
from the vehicle: the path file's ``max_accel_mps2``, ``max_turn_rate_radps``,
``max_lateral_accel_mps2`` and the controller's yaw-acceleration limit (the sweep reads them
from the simulated vehicle; :meth:`PoseFilterParams.from_limits`).

Measurements
------------
For every antenna ``i`` with body offset ``r_i`` from M:

- its fix, ``z_i = p + R(yaw) r_i + e``, ``e ~ N(0, sigma_abs^2 I)``; Jacobian
  ``[I, J R r_i, 0, 0]`` (J the 90 degree rotation);
- its displacement since its last accepted fix ``tau`` seconds earlier (at most
  :data:`MAX_STEP_GAP` sample intervals), as a function of the current state through the CTRV
  motion run backwards: ``z_i(t) - z_i(t - tau) = R(yaw) u_i`` with
  ``u_i = (v tau f1 + (1 - cos q) r_x - sin q r_y, -v tau f2 + sin q r_x + (1 - cos q) r_y)``,
  ``q = omega tau``; noise sd ``sigma_step * sqrt(max(1, tau / dt_median))``.

Why the displacements: GNSS position errors are strongly correlated in time (multipath and
atmosphere change over minutes; the dissertation's Section 4.3 sees no "sharp jaggedness"),
so one antenna's error changes little from one sample to the next even when it is metres
large. Its epoch-to-epoch displacement therefore measures the platform's motion far better
than two absolute fixes do, and with the non-holonomic constraint the direction of motion is
the heading; differences between antennas' displacements measure the yaw rate through the
configuration. (The correlation of consecutive displacements through their shared fix, and
the slow drift of the error, are left out of the model; the first is small next to the
absolute fixes' noise, the second is what limits the heading, see the README.)

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
non-negative. After each update a negative speed is either insignificant (``v > -3 sd``:
projected to 0) or means the heading is off by pi: then ``yaw += pi, v = -v`` (the same
motion, the covariance mapped by ``diag(1, 1, 1, -1, 1)``) and the epoch's status is
``"flip_corrected"``: reported, never silent. With ``reverse=True`` the speed is signed
(negative = reversing) and the direction is decided by the configuration: a running
log-likelihood ratio of the antennas' fixes under the heading and under the heading + pi
(exponential forgetting over ``flip_memory_s``) flips the state when the reversed pose is
more likely by ``chi2_1(gate_prob)``; also reported as ``"flip_corrected"``.

Initialisation waits for data, resets are reported
--------------------------------------------------
The filter starts at the first epoch where the heading is known: either the configuration
fixes it (heading sd ``sigma_abs / sqrt(sum |r_i|^2)`` below :data:`INIT_MAX_YAW_SD`, e.g.
centimetre receivers) or the platform has moved, relative to the first fix, by more than
:data:`INIT_MOTION_SIGMAS` times the sd of that displacement (then heading = course). Before
that, rows are NaN with status ``"waiting"`` (``"no_data"`` when no antenna reported), so a
recording that starts inside an outage, or a receiver that starts late, simply starts later.
If every fix (or every displacement) is rejected for ``max_rejects`` consecutive epochs the
track is lost: the filter returns to waiting and restarts from the data (status ``"reset"`` on
the restart epoch).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2

from estimator._checks import check_array, check_fields, check_increasing_times, check_int
from estimator._checks import check_real

__all__ = [
    "FilterStart",
    "INIT_MAX_YAW_SD",
    "INIT_MOTION_SIGMAS",
    "MAX_STEP_GAP",
    "PoseFilterParams",
    "PoseFilterResult",
    "antenna_jacobians",
    "ctra_predict",
    "motion_integrals",
    "estimate_noise",
    "kalman_update",
    "run_pose_filter",
]

#: Heading sd (rad) from the configuration alone below which the filter starts at once.
#: 0.1 rad: the EKF's linearisation of R(yaw) is good to ~0.5 % there.
INIT_MAX_YAW_SD = 0.1
#: Otherwise it starts once the CG has moved this many sd from the first fix (heading =
#: course, error below ~1/5 rad, which the filter then removes).
INIT_MOTION_SIGMAS = 5.0
#: Displacements span at most this many median sample intervals (a longer gap: fix only).
MAX_STEP_GAP = 5
#: Numerical floor of the estimated noise levels, m (noise-free data would give 0).
NOISE_FLOOR_M = 1e-3

STATUSES = ("", "no_data", "waiting", "init", "reset", "ok", "predicted", "flip_corrected")


@dataclass(frozen=True)
class PoseFilterParams:
    """Platform limits and measurement model of the pose filter (SI units).

    Limits (module docstring; defaults: the rover of models/paths/square100.toml and the
    controller's yaw-acceleration limit, sim.controllers): ``max_accel_mps2`` (longitudinal),
    ``max_yaw_accel_radps2``, ``max_turn_rate_radps``, ``max_lateral_accel_mps2``.
    ``sigma_abs_m`` / ``sigma_step_m``: per-axis sd of an antenna fix and of its displacement
    over one sample interval; None = :func:`estimate_noise` on the recording.
    ``no_slip_point_m``: (x, y) of the no-slip point in the body frame relative to the
    configuration's CG. ``reverse``: the platform may drive backwards (signed speed).
    ``gate_prob``: chi-square gate probability (1 = no gating). ``max_rejects``: consecutive
    all-rejected epochs before the track is declared lost. ``flip_memory_s``: memory of the
    configuration's heading test (reverse mode). ``lag_s``: latency of the fixed-lag smoother
    (:mod:`estimator.pose_smoother`), s.
    """

    max_accel_mps2: float = 0.5
    max_yaw_accel_radps2: float = 1.0
    max_turn_rate_radps: float = 0.8
    max_lateral_accel_mps2: float = 0.8
    sigma_abs_m: float | None = None
    sigma_step_m: float | None = None
    no_slip_point_m: tuple[float, float] = (0.0, 0.0)
    reverse: bool = False
    gate_prob: float = 0.999
    max_rejects: int = 5
    flip_memory_s: float = 30.0
    lag_s: float = 10.0

    def __post_init__(self) -> None:
        check_fields(self, ("max_accel_mps2", "max_yaw_accel_radps2", "max_turn_rate_radps",
                            "max_lateral_accel_mps2", "flip_memory_s", "lag_s"))
        for name in ("sigma_abs_m", "sigma_step_m"):
            if getattr(self, name) is not None:
                check_real(getattr(self, name), name, lo=0.0, lo_open=True)
        check_real(self.gate_prob, "gate_prob", lo=0.0, hi=1.0, lo_open=True)
        check_int(self.max_rejects, "max_rejects", lo=1)
        if not isinstance(self.reverse, bool):
            raise TypeError(f"reverse: must be True or False, got {self.reverse!r}")
        ns = self.no_slip_point_m
        if not isinstance(ns, (tuple, list)) or len(ns) != 2:
            raise ValueError(f"no_slip_point_m: must be (x, y) metres, got {ns!r}")
        object.__setattr__(self, "no_slip_point_m", (
            check_real(ns[0], "no_slip_point_m[0]"), check_real(ns[1], "no_slip_point_m[1]")))

    @property
    def sigma_accel_step(self) -> float:
        """sd of the longitudinal acceleration's change over one sample interval, m/s^2:
        half the limit (module docstring, discrete Wiener-process acceleration)."""
        return 0.5 * self.max_accel_mps2

    @property
    def sigma_yaw_accel(self) -> float:
        """sd of the yaw acceleration, constant over a sample interval, rad/s^2: half the
        limit (module docstring, discrete white-noise acceleration)."""
        return 0.5 * self.max_yaw_accel_radps2

    @classmethod
    def from_limits(cls, limits: dict, **overrides: object) -> PoseFilterParams:
        """Parameters from a platform's limits, e.g. a path file's fields plus the
        controller's: keys ``max_accel_mps2``, ``max_yaw_accel_radps2``,
        ``max_turn_rate_radps``, ``max_lateral_accel_mps2`` (absent or None: the default);
        other keys are ignored. ``overrides`` set any field."""
        kw = {k: limits[k] for k in ("max_accel_mps2", "max_yaw_accel_radps2",
                                     "max_turn_rate_radps", "max_lateral_accel_mps2")
              if limits.get(k) is not None}
        kw.update(overrides)
        return cls(**kw)


@dataclass(frozen=True)
class PoseFilterResult:
    """The filter's forward pass, everything the smoother needs.

    states (n, 6) and covariances (n, 6, 6): filtered state of the no-slip point
    ``(px, py, yaw, v, a, omega)`` and its covariance (NaN where the filter was not
    running). pred_states / pred_covariances (n, 6) / (n, 6, 6): the prediction into each
    epoch from the previous one, transition (n, 6, 6) its Jacobian F (row k maps epoch k-1
    to k; NaN at segment starts).
    segment_start (n,) bool: the filter (re)started here, or the state was flipped (a smoother
    never crosses such an epoch). status (n,) str (:data:`STATUSES`). n_used / n_gated (n,):
    antenna fixes accepted / rejected; n_steps (n,): displacements accepted.
    sigma_abs_m, sigma_step_m: the noise levels used. cg_offset (2,): CG in the body frame
    relative to the no-slip point (CG = p + R(yaw) cg_offset).
    """

    states: np.ndarray
    covariances: np.ndarray
    pred_states: np.ndarray
    pred_covariances: np.ndarray
    transition: np.ndarray
    segment_start: np.ndarray
    status: np.ndarray
    n_used: np.ndarray
    n_gated: np.ndarray
    n_steps: np.ndarray
    sigma_abs_m: float
    sigma_step_m: float
    cg_offset: np.ndarray = field(default_factory=lambda: np.zeros(2))

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

#: Below this |q| = |omega tau| the integrals F_k are summed as series (module docstring).
SERIES_BELOW = 0.25
_SERIES_TERMS = 12
_FACT = np.array([math.factorial(n) for n in range(_SERIES_TERMS)], dtype=float)


def motion_integrals(q: np.ndarray | float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``F_k(q) = integral_0^1 u^(k-1) exp(i q u) du`` for k = 1, 2, 3 (complex).

    The CTRA motion over tau (turn q = omega tau) moves the platform by
    ``exp(i yaw) (v tau F1 + a tau^2 F2)`` (x + i y), and ``dF_k/dq = i F_(k+1)``.
    Closed forms ``F1 = (e^iq - 1)/(iq)``, ``F2 = (e^iq - F1)/(iq)``,
    ``F3 = (e^iq - 2 F2)/(iq)`` for |q| >= :data:`SERIES_BELOW`; below, where they cancel,
    the series ``sum_n (iq)^n / (n! (n + k))`` to n = 11 (truncation < 1e-16 there).
    q : any shape; returns three complex arrays of that shape.
    """
    q = np.asarray(q, dtype=float)
    small = np.abs(q) < SERIES_BELOW
    qs = np.where(small, 1.0, q)
    e = np.exp(1j * qs)
    f1 = (e - 1.0) / (1j * qs)
    f2 = (e - f1) / (1j * qs)
    f3 = (e - 2.0 * f2) / (1j * qs)
    if small.any():
        z = (1j * np.where(small, q, 0.0))[..., None] ** np.arange(_SERIES_TERMS) / _FACT
        n = np.arange(_SERIES_TERMS)
        f1 = np.where(small, (z / (n + 1)).sum(-1), f1)
        f2 = np.where(small, (z / (n + 2)).sum(-1), f2)
        f3 = np.where(small, (z / (n + 3)).sum(-1), f3)
    return f1, f2, f3


def _integrals_scalar(q: float) -> tuple[complex, complex, complex]:
    """:func:`motion_integrals` for one q (Python complex numbers, same formulas)."""
    if abs(q) >= SERIES_BELOW:
        e = complex(math.cos(q), math.sin(q))
        iq = 1j * q
        f1 = (e - 1.0) / iq
        f2 = (e - f1) / iq
        return f1, f2, (e - 2.0 * f2) / iq
    f1 = f2 = f3 = 0j
    term = 1.0 + 0j                    # (iq)^n / n!
    for n in range(_SERIES_TERMS):
        f1 += term / (n + 1)
        f2 += term / (n + 2)
        f3 += term / (n + 3)
        term *= 1j * q / (n + 1)
    return f1, f2, f3


def _predict(x: np.ndarray, P: np.ndarray, dt: float, qa: float, qy: float
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """CTRA prediction: (x', P', F). See :func:`ctra_predict`."""
    yaw, v, acc, om = float(x[YAW]), float(x[V]), float(x[A]), float(x[OMEGA])
    f1, f2, f3 = _integrals_scalar(om * dt)
    rot = complex(math.cos(yaw), math.sin(yaw))
    d = rot * (v * dt * f1 + acc * dt * dt * f2)          # displacement
    dv = rot * dt * f1
    da = rot * dt * dt * f2
    dq = rot * 1j * (v * dt * f2 + acc * dt * dt * f3) * dt   # d/domega = dt d/dq
    F = np.eye(NX)
    F[PX, YAW], F[PY, YAW] = -d.imag, d.real              # d/dyaw = J d
    F[PX, V], F[PY, V] = dv.real, dv.imag
    F[PX, A], F[PY, A] = da.real, da.imag
    F[PX, OMEGA], F[PY, OMEGA] = dq.real, dq.imag
    F[YAW, OMEGA] = dt
    F[V, A] = dt
    # discrete process noise (module docstring): the acceleration changes by a random
    # increment (variance qa, per sample) along the heading, the yaw acceleration is a
    # random constant (variance qy) over the sample
    c, s = rot.real, rot.imag
    h = 0.5 * dt * dt
    ga = np.array([h * c, h * s, 0.0, dt, 1.0, 0.0])
    gy = np.array([0.0, 0.0, h, 0.0, 0.0, dt])
    Q = qa * np.outer(ga, ga) + qy * np.outer(gy, gy)
    Pn = F @ P @ F.T + Q
    xn = np.array([x[PX] + d.real, x[PY] + d.imag, _wrap(yaw + om * dt), v + acc * dt, acc,
                   om])
    return xn, 0.5 * (Pn + Pn.T), F


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
def antenna_jacobians(x: np.ndarray, r: np.ndarray, tau: np.ndarray | None = None
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Predicted measurements and Jacobians for antennas at body offsets r (k, 2) from M.

    tau None: fixes, ``h (k, 2) = p + R(yaw) r``. tau (k,) seconds: displacements since
    ``tau`` ago under CTRA (module docstring), ``h = exp(i yaw) (v tau conj(F1) -
    a tau^2 conj(F2) + (1 - exp(-iq)) r)``. Returns h (k, 2) and H (k, 2, 6).
    """
    x = np.asarray(x, dtype=float)
    r = np.asarray(r, dtype=float)
    c, s = math.cos(x[YAW]), math.sin(x[YAW])
    k = r.shape[0]
    H = np.zeros((k, 2, NX))
    h = np.empty((k, 2))
    if tau is None:
        rx = c * r[:, 0] - s * r[:, 1]
        ry = s * r[:, 0] + c * r[:, 1]
        H[:, 0, PX] = 1.0
        H[:, 1, PY] = 1.0
        H[:, 0, YAW] = -ry
        H[:, 1, YAW] = rx
        h[:, 0] = x[PX] + rx
        h[:, 1] = x[PY] + ry
        return h, H
    tau = np.asarray(tau, dtype=float)
    v, acc, om = x[V], x[A], x[OMEGA]
    rc = r[:, 0] + 1j * r[:, 1]
    if tau.size and (tau == tau[0]).all():   # the usual case: one sample interval for all
        f1, f2, f3 = (np.conj(f) for f in _integrals_scalar(om * float(tau[0])))
        eq = complex(math.cos(om * tau[0]), -math.sin(om * tau[0]))
    else:
        f1, f2, f3 = (np.conj(f) for f in motion_integrals(om * tau))
        eq = np.exp(-1j * om * tau)
    rot = complex(c, s)
    u = rot * (v * tau * f1 - acc * tau * tau * f2 + (1.0 - eq) * rc)
    du_v = rot * tau * f1 * np.ones(k)
    du_a = -rot * tau * tau * f2 * np.ones(k)
    # d/domega = tau d/dq; d conj(F_k)/dq = -i conj(F_(k+1)), d(1 - e^-iq)/dq = i e^-iq
    du_q = rot * tau * (-1j * v * tau * f2 + 1j * acc * tau * tau * f3 + 1j * eq * rc)
    h[:, 0], h[:, 1] = u.real, u.imag
    H[:, 0, YAW], H[:, 1, YAW] = -u.imag, u.real           # d/dyaw = J h
    H[:, 0, V], H[:, 1, V] = du_v.real, du_v.imag
    H[:, 0, A], H[:, 1, A] = du_a.real, du_a.imag
    H[:, 0, OMEGA], H[:, 1, OMEGA] = du_q.real, du_q.imag
    return h, H


def _quad2(M: np.ndarray, e: np.ndarray, guard: bool = False) -> np.ndarray:
    """e_i^T M_i^-1 e_i for symmetric 2 x 2 matrices M (k, 2, 2) and vectors e (k, 2).
    With ``guard``, 0 where M_i is singular to rounding (no redundancy left to test)."""
    a, b, c = M[:, 0, 0], M[:, 0, 1], M[:, 1, 1]
    ex, ey = e[:, 0], e[:, 1]
    det = a * c - b * b
    num = c * ex * ex - 2.0 * b * ex * ey + a * ey * ey
    if not guard:
        return num / det
    return np.divide(num, det, out=np.zeros_like(num), where=det > 1e-12 * np.abs(a * c))


def _info_update(x: np.ndarray, Pinv: np.ndarray, nu: np.ndarray, H: np.ndarray,
                 w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Information-form update with the measurements given (H (a, 2, n), weights w (a,))."""
    Hf = H.reshape(-1, H.shape[-1])
    HtW = Hf.T * np.repeat(w, 2)                            # (n, 2a)
    Pn = np.linalg.inv(Pinv + HtW @ Hf)
    Pn = 0.5 * (Pn + Pn.T)
    return x + Pn @ (HtW @ nu.reshape(-1)), Pn


def kalman_update(x: np.ndarray, P: np.ndarray, nu: np.ndarray, H: np.ndarray,
                  var: np.ndarray, gate: float = math.inf, max_deleted: int = 3
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Joint EKF update with k two-dimensional measurements, robustly gated.

    nu (k, 2) innovations, H (k, 2, n) Jacobians, var (k,) per-axis noise variances (R_i =
    var_i I). Two tests, both at the chi-square(2) quantile ``gate``:

    1. prior gate: a measurement whose NIS ``nu_i^T S_i^-1 nu_i`` (``S_i = H_i P H_i^T +
       R_i``) exceeds ``gate`` is left out;
    2. deleted residual (the dissertation's Section 3.3.2 idea on the filter): after the
       update, each accepted measurement's residual ``e_i = nu_i - H_i (x+ - x)`` against
       ``C_i = R_i - H_i P+ H_i^T`` is the test of that measurement against all the others
       and the prior (leave-one-out); the worst one above ``gate`` is removed and the update
       redone, at most ``max_deleted`` times. This catches a gross error that the prior
       alone cannot (e.g. a displacement from an outlying fix while the platform's agility
       makes the predicted spread wide).

    The accepted measurements update in information form, ``P+ = (P^-1 + sum H_i^T H_i /
    var_i)^-1``, ``x+ = x + P+ sum H_i^T nu_i / var_i``, the same update as the textbook
    gain form (tested against FilterPy) with n x n inverses only. The yaw component of x+
    is not wrapped here. Returns (x+, P+, accepted (k,)).
    """
    k = nu.shape[0]
    if k == 0:
        return x, P, np.zeros(0, dtype=bool)
    if gate != math.inf:
        S = (H @ P) @ H.transpose(0, 2, 1)
        S[:, 0, 0] += var
        S[:, 1, 1] += var
        acc = _quad2(S, nu) <= gate
        if not acc.any():
            return x, P, acc
    else:
        acc = np.ones(k, dtype=bool)
    Pinv = np.linalg.inv(P)
    w = 1.0 / var
    if acc.all():
        xn, Pn = _info_update(x, Pinv, nu, H, w)
        ia, Ha, nua, vara = np.arange(k), H, nu, var
    else:
        ia = np.flatnonzero(acc)
        Ha, nua, vara = H[ia], nu[ia], var[ia]
        xn, Pn = _info_update(x, Pinv, nua, Ha, w[ia])
    for _ in range(max_deleted if gate != math.inf else 0):
        if ia.size < 2:
            break
        C = -((Ha @ Pn) @ Ha.transpose(0, 2, 1))
        C[:, 0, 0] += vara
        C[:, 1, 1] += vara
        stat = _quad2(C, nua - Ha @ (xn - x), guard=True)
        worst = int(stat.argmax())
        if not stat[worst] > gate:
            break
        acc[ia[worst]] = False
        keep = np.arange(ia.size) != worst
        ia, Ha, nua, vara = ia[keep], Ha[keep], nua[keep], vara[keep]
        xn, Pn = _info_update(x, Pinv, nua, Ha, 1.0 / vara)
    return xn, Pn, acc


# ----------------------------------------------------------------------------- noise levels
def _rigid_fits(obs: np.ndarray, offsets: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Closed-form 2-D rigid fit of the offsets to every epoch's fixes (Kabsch in 2-D).

    Returns origin (n, 2) (the world position of offset (0, 0)), yaw (n,), number of fixes
    (n,) and residuals (n, m, 2) (NaN where absent); epochs with < 2 fixes are NaN.
    """
    present = np.isfinite(obs[..., 0])
    cnt = present.sum(axis=1)
    w = present.astype(float)
    z = np.where(present[..., None], obs, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        zc = (z * w[..., None]).sum(1) / cnt[:, None]
        rc = (offsets[None] * w[..., None]).sum(1) / cnt[:, None]
    dz = (z - zc[:, None]) * w[..., None]
    dr = (offsets[None] - rc[:, None]) * w[..., None]
    yaw = np.arctan2((dr[..., 0] * dz[..., 1] - dr[..., 1] * dz[..., 0]).sum(1),
                     (dr * dz).sum(-1).sum(1))
    c, s = np.cos(yaw), np.sin(yaw)
    origin = zc - np.c_[c * rc[:, 0] - s * rc[:, 1], s * rc[:, 0] + c * rc[:, 1]]
    fit = origin[:, None] + np.stack([c[:, None] * offsets[None, :, 0]
                                      - s[:, None] * offsets[None, :, 1],
                                      s[:, None] * offsets[None, :, 0]
                                      + c[:, None] * offsets[None, :, 1]], -1)
    bad = cnt < 2
    origin[bad] = np.nan
    yaw[bad] = np.nan
    res = np.where(present[..., None] & ~bad[:, None, None], obs - fit, np.nan)
    return origin, yaw, cnt, res


def estimate_noise(obs: np.ndarray, offsets: np.ndarray) -> tuple[float, float]:
    """Per-axis noise sd of one antenna's fix and of its one-sample displacement, metres,
    from the data alone through the configuration (module docstring).

    obs (n, m, 2) metres, NaN = missing; offsets (m, 2) body positions (any origin).
    Each epoch with k >= 2 fixes is fitted rigidly (2-D Kabsch); its residuals are scaled by
    ``1 / sqrt(1 - 3 / (2k))`` (3 pose parameters taken from 2k numbers) and
    ``sigma_abs = 1.4826 median |residual|`` (MAD, robust to outliers). ``sigma_step`` is the
    same statistic of one antenna's residual change between consecutive epochs with the same
    antennas reporting (its fit removes the shared motion). The error every antenna shares is
    invisible to both (it moves the fit). Both are floored at :data:`NOISE_FLOOR_M`.
    Raises ValueError if no epoch has 3 or more fixes (nothing to estimate from).
    """
    obs = np.asarray(obs, dtype=float)
    off = np.asarray(offsets, dtype=float)
    _, _, cnt, res = _rigid_fits(obs, off)
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = 1.0 / np.sqrt(1.0 - 3.0 / (2.0 * cnt))
    good = cnt >= 3
    if not good.any():
        raise ValueError("obs: no epoch has 3 or more antenna fixes, the noise levels cannot "
                         "be estimated; give sigma_abs_m and sigma_step_m")
    r = (res[good] * scale[good, None, None]).ravel()
    sigma_abs = 1.4826 * float(np.median(np.abs(r[np.isfinite(r)])))
    present = np.isfinite(obs[..., 0])
    same = good[1:] & good[:-1] & np.all(present[1:] == present[:-1], axis=1)
    d = ((res[1:] - res[:-1]) * scale[1:, None, None])[same].ravel()
    d = d[np.isfinite(d)]
    sigma_step = 1.4826 * float(np.median(np.abs(d))) if d.size else sigma_abs * math.sqrt(2)
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
        self.origin, self.yaw, self.cnt, _ = _rigid_fits(obs, r)   # origin = no-slip point
        self.present = np.isfinite(obs[..., 0])
        self.r2 = (r ** 2).sum(1)
        self.sigma_abs = sigma_abs
        self.params = params
        self.anchor = -1

    def reset(self) -> None:
        """Forget the anchor (after a lost track)."""
        self.anchor = -1

    def offer(self, k: int) -> tuple[np.ndarray, np.ndarray] | None:
        """The start state at epoch k, or None to keep waiting."""
        if self.cnt[k] < 2:
            return None
        sa, p = self.sigma_abs, self.params
        yaw_sd = sa / math.sqrt(self.r2[self.present[k]].sum())
        if yaw_sd < INIT_MAX_YAW_SD:
            # the configuration fixes the heading; speed along it from the previous
            # epoch's fit if there is one (a restart on the move must not start at rest)
            yaw0, ysd = float(self.yaw[k]), yaw_sd
            v0, vsd = 0.0, p.max_accel_mps2
            if k > 0 and self.cnt[k - 1] >= 2:
                dt = self.t[k] - self.t[k - 1]
                d = self.origin[k] - self.origin[k - 1]
                v0 = (d[0] * math.cos(yaw0) + d[1] * math.sin(yaw0)) / dt
                vsd = math.hypot(p.max_accel_mps2 * dt, sa * math.sqrt(
                    1.0 / self.cnt[k] + 1.0 / self.cnt[k - 1]) / dt)
                if not p.reverse:
                    v0 = max(v0, 0.0)
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
        P = np.diag([pvar, pvar, ysd ** 2, vsd ** 2, p.max_accel_mps2 ** 2,
                     (0.5 * p.max_turn_rate_radps) ** 2])
        return x, P


def _check_run_args(t, obs, offsets, params):
    obs = check_array(obs, "obs", allow_nan=True)
    if obs.ndim != 3 or obs.shape[2] != 2:
        raise ValueError(f"obs: expected shape (n, m, 2) metres, got {obs.shape}")
    n, m = obs.shape[:2]
    tt = check_increasing_times(t, "t", n=n, min_size=1)
    off = check_array(offsets, "offsets", shape=(m, 2))
    if not isinstance(params, PoseFilterParams):
        raise TypeError(f"params: expected a PoseFilterParams, got {type(params).__name__}")
    nan = np.isnan(obs)
    if np.any(nan[..., 0] != nan[..., 1]):
        k, i = np.argwhere(nan[..., 0] != nan[..., 1])[0]
        raise ValueError(f"obs: epoch {k}, antenna {i} has one coordinate NaN; a missing fix "
                         f"must be NaN in both")
    return tt, obs, off


def run_pose_filter(t: np.ndarray, obs: np.ndarray, offsets: np.ndarray,
                    params: PoseFilterParams = PoseFilterParams()) -> PoseFilterResult:
    """Run the filter over a recording (module docstring for the model).

    t : (n,) s, finite and strictly increasing (uneven steps are fine).
    obs : (n, m, 2) metres (world x east, y north), NaN = the antenna did not report.
    offsets : (m, 2) metres, antenna body positions relative to the configuration's CG
        (body x forward, y left); dead antennas simply never report.
    params : :class:`PoseFilterParams` (limits, noise levels or None = estimated, no-slip
        point, reverse mode, gates).

    Returns a :class:`PoseFilterResult` of n rows; rows before the start are NaN with status
    "waiting" or "no_data". Wrong shapes or values raise ValueError/TypeError naming the
    argument.
    """
    tt, obs, off = _check_run_args(t, obs, offsets, params)
    n, m = obs.shape[:2]
    ns = np.asarray(params.no_slip_point_m, dtype=float)
    r_m = off - ns                         # antenna offsets from the no-slip point
    cg_offset = -ns                        # CG relative to the no-slip point
    if params.sigma_abs_m is None or params.sigma_step_m is None:
        sa, ss = estimate_noise(obs, off)
    sigma_abs = params.sigma_abs_m if params.sigma_abs_m is not None else sa
    sigma_step = params.sigma_step_m if params.sigma_step_m is not None else ss
    va, vs = sigma_abs ** 2, sigma_step ** 2
    dt_med = float(np.median(np.diff(tt))) if n > 1 else 1.0
    max_gap = MAX_STEP_GAP * dt_med * (1.0 + 1e-9)
    gate = float(chi2.ppf(params.gate_prob, 2)) if params.gate_prob < 1 else math.inf
    flip_thr = float(chi2.ppf(params.gate_prob, 1)) if params.gate_prob < 1 else 10.83
    qa, qy = params.sigma_accel_step ** 2, params.sigma_yaw_accel ** 2
    om_max, alat = params.max_turn_rate_radps, params.max_lateral_accel_mps2
    a_max = params.max_accel_mps2

    X = np.full((n, NX), np.nan)
    PP = np.full((n, NX, NX), np.nan)
    XP = np.full((n, NX), np.nan)
    PPp = np.full((n, NX, NX), np.nan)
    FF = np.full((n, NX, NX), np.nan)
    seg = np.zeros(n, dtype=bool)
    status = np.full(n, "", dtype=object)
    n_used = np.zeros(n, dtype=int)
    n_gated = np.zeros(n, dtype=int)
    n_steps = np.zeros(n, dtype=int)

    present = np.isfinite(obs[..., 0])
    starter = FilterStart(tt, obs, r_m, sigma_abs, params)

    x = P = None
    lost = False          # the next start is a restart
    rej_abs = rej_step = 0
    llr = 0.0             # reverse mode: log-likelihood ratio for the flipped heading
    back = 0.0            # forward mode: backward travel over consecutive epochs, m
    n_alive = max(int(present.any(axis=0).sum()), 1)
    flip_dist = INIT_MOTION_SIGMAS * sigma_abs * math.sqrt(2.0 / n_alive)
    last_t = np.full(m, np.nan)
    last_z = np.full((m, 2), np.nan)
    for k in range(n):
        ik = np.flatnonzero(present[k])
        if x is None:
            # ---------------------------------------------------------------- waiting
            if ik.size == 0:
                status[k] = "no_data"
                continue
            status[k] = "waiting"
            got = starter.offer(k)
            if got is None:
                continue
            x, P = got
            X[k], PP[k], seg[k] = x, P, True
            status[k] = "reset" if lost else "init"
            n_used[k] = ik.size
            last_t[:] = np.nan
            last_t[ik] = tt[k]
            last_z[ik] = obs[k, ik]
            rej_abs, rej_step, llr, back = 0, 0, 0.0, 0.0
            continue
        # -------------------------------------------------------------------- running
        dt = tt[k] - tt[k - 1]
        # the acceleration's increments add up over a longer gap (random walk)
        x, P, F = _predict(x, P, dt, qa * max(1.0, dt / dt_med), qy)
        XP[k], PPp[k], FF[k] = x, P, F
        st = "predicted"
        if ik.size:
            h, H = antenna_jacobians(x, r_m[ik])
            nu = obs[k, ik] - h
            tau = tt[k] - last_t[ik]
            sel = np.isfinite(tau) & (tau <= max_gap)
            js = ik[sel]
            if js.size:
                hd, Hd = antenna_jacobians(x, r_m[js], tau[sel])
                nu = np.concatenate((nu, obs[k, js] - last_z[js] - hd))
                H = np.concatenate((H, Hd))
                var = np.concatenate((np.full(ik.size, va),
                                      vs * np.maximum(1.0, tau[sel] / dt_med)))
            else:
                var = np.full(ik.size, va)
            x1, P1, acc = kalman_update(x, P, nu, H, var, gate)
            acc_abs, acc_step = acc[:ik.size], acc[ik.size:]
            n_used[k] = int(acc_abs.sum())
            n_gated[k] = ik.size - n_used[k]
            n_steps[k] = int(acc_step.sum())
            rej_abs = rej_abs + 1 if n_used[k] == 0 else 0
            rej_step = rej_step + 1 if (js.size >= 2 and n_steps[k] == 0) else 0
            if max(rej_abs, rej_step) >= params.max_rejects:
                # lost: back to waiting, restart from the data (reported on the restart)
                x = P = None
                starter.reset()
                lost = True
                status[k] = "waiting"
                continue
            if acc.any():
                x, P, st = x1, P1, "ok"
                x[YAW] = _wrap(x[YAW])
            good = ik[acc_abs]
            last_t[good] = tt[k]
            last_z[good] = obs[k, good]
            # ------------------------------------------------------- direction of travel
            if not params.reverse:
                # backward travel accumulates over consecutive epochs of negative speed;
                # beyond the start's motion threshold the heading is off by pi: flip
                back = back - x[V] * dt if x[V] < 0.0 else 0.0
                if back > flip_dist:
                    x, P = _flip(x, P)
                    st, back = "flip_corrected", 0.0
                elif x[V] < 0.0:
                    x[V] = 0.0
            elif good.size >= 2:
                # configuration's evidence for yaw + pi: residuals of the accepted fixes
                # with R(yaw) r and -R(yaw) r; LLR = (|e+|^2 - |e-|^2) / (2 var)
                hz, _ = antenna_jacobians(x, r_m[good])
                e_plus = obs[k, good] - hz
                e_minus = e_plus + 2.0 * (hz - x[:2])
                llr = llr * math.exp(-dt / params.flip_memory_s) + float(
                    ((e_plus ** 2).sum() - (e_minus ** 2).sum()) / (2.0 * va))
                if llr > flip_thr:
                    x, P = _flip(x, P)
                    st, llr = "flip_corrected", 0.0
        # turn-rate limit of the platform (projection)
        lim = om_max if x[V] == 0 else min(om_max, alat / abs(x[V]))
        if abs(x[OMEGA]) > lim:
            x[OMEGA] = math.copysign(lim, x[OMEGA])
        if abs(x[A]) > a_max:
            x[A] = math.copysign(a_max, x[A])
        X[k], PP[k], status[k] = x, P, st
        if st == "flip_corrected":
            seg[k] = True
    return PoseFilterResult(states=X, covariances=PP, pred_states=XP, pred_covariances=PPp,
                            transition=FF, segment_start=seg, status=status.astype(str),
                            n_used=n_used, n_gated=n_gated, n_steps=n_steps,
                            sigma_abs_m=float(sigma_abs), sigma_step_m=float(sigma_step),
                            cg_offset=cg_offset)


def _flip(x: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The same motion with the heading turned by pi: (yaw + pi, -v, -a); P mapped by
    diag(1, 1, 1, -1, -1, 1) (the no-slip point's position and the yaw rate are kept)."""
    xn = x.copy()
    xn[YAW] = _wrap(x[YAW] + math.pi)
    xn[V] = -x[V]
    xn[A] = -x[A]
    J = np.array([1.0, 1.0, 1.0, -1.0, -1.0, 1.0])
    return xn, P * J[:, None] * J[None, :]
