"""Extended Kalman filter on the antennas with the sensor configuration as measurement model.

The dissertation's future work (000_8f82f8df647bf685.txt, Section 5.2): "a system that takes
advantage of extended Kalman Filter and the quadratic optimization framework using sensor
configuration knowledge". Here the configuration enters the measurement model directly:

State ``x = (px, py, yaw, v, omega)``: CG position (m), heading (rad, CCW from +x), speed
along the heading (m/s, negative = reversing) and yaw rate (rad/s). Motion model: constant
turn rate and velocity (CTRV),

    px' = px + v/omega (sin(yaw + omega dt) - sin yaw)   (v cos(yaw) dt as omega -> 0)
    py' = py + v/omega (cos yaw - cos(yaw + omega dt))   (v sin(yaw) dt as omega -> 0)
    yaw' = yaw + omega dt,   v' = v,   omega' = omega,

driven by white longitudinal acceleration (``sigma_accel``, m/s^2) and yaw acceleration
(``sigma_yaw_accel``, rad/s^2): ``Q = G diag(sa^2, sy^2) G^T`` with
``G = [[dt^2/2 cos yaw, 0], [dt^2/2 sin yaw, 0], [0, dt^2/2], [dt, 0], [0, dt]]``.

Measurements: every antenna ``i`` that reported, ``z_i = p + R(yaw) r_i + noise``, with
``r_i = b_i - cg_body`` its known body offset from the CG and noise ``N(0, sigma_meas^2 I)``;
Jacobian ``[I, R(yaw) J r_i, 0, 0]`` with J the 90 degree rotation. So the filter uses the
configuration as the window fit does, sample by sample, with every antenna at its own time.

Robust gating: each antenna's innovation is tested against the predicted covariance,
``nu_i^T S_i^{-1} nu_i <= chi2_2(gate_prob)`` (13.8 at 0.999); failures are dropped from the
update (counted in ``n_gated``). If every reporting antenna fails for ``max_rejects``
consecutive epochs the filter has lost track: the covariance is reset to its initial value
and the epoch's antennas are used (status "reset"); a warning sign, reported, not hidden.

Initialisation (by :func:`estimator.tracking.track`): the motion-compensated window fit
(:mod:`estimator.motion`, constant velocity) over the first ``s`` epochs gives position,
heading and the speed along it.

Tuning (done once, on synthetic data; ``tests/tune_pose_filter.py`` reruns it, ~4 min): Path
1 (square100 at 0.2 m/s, 1985 epochs at 1 Hz) driven by the MuJoCo rover with the rover_gps8
layout, GPS errors from models/noise/gps_stationary.toml (2 m per axis, half common-mode,
smooth Gauss-Markov, plateaus, outliers, bursty dropouts) in 4000 s sessions replayed onto
the truth; four sessions spawned from seed 20261122, which no test and no sweep preset uses.
Criterion: mean Euclidean CG error over the whole path, averaged over the sessions. First
grid sigma_meas {0.5, 1, 2, 3} m x sigma_accel {0.2, 0.5, 1, 2} m/s^2 x sigma_yaw_accel
{0.02, 0.05, 0.1, 0.2} rad/s^2: best 1.621 m at (3, 2, 0.05), worst 2.217 m; second grid {2,
3, 4, 6} x {0.5, 1, 2} x {0.005, 0.01, 0.02, 0.05}: best 1.563 m at the defaults below (3,
0.5, 0.01), worst 1.702 m. Same data: window-1 fit 1.535 m, motion-compensated window 10
with yaw rate 1.533 m, window 10 1.688 m, naive window 10 1.850 m. With errors this time-
correlated (the filter's white-noise model is wrong, and the common mode is invisible to any
configuration method) the EKF does not beat the window-1 fit on position; its heading,
carried by the motion model, is far better (median 0.18 rad against ~0.8 rad for the window
fits on one such session). ``TUNING`` holds these numbers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from estimator._checks import check_increasing_times

__all__ = [
    "TUNING",
    "PoseFilterParams",
    "PoseFilterResult",
    "antenna_update",
    "ctrv_predict",
    "run_pose_filter",
]


@dataclass(frozen=True)
class PoseFilterParams:
    """Noise and gating parameters (SI units). See the module docstring for the tuning."""

    sigma_meas: float = 3.0
    sigma_accel: float = 0.5
    sigma_yaw_accel: float = 0.01
    gate_prob: float = 0.999
    max_rejects: int = 5

    def __post_init__(self) -> None:
        for name in ("sigma_meas", "sigma_accel", "sigma_yaw_accel"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise ValueError(f"{name}: must be a positive number, got {v!r}")
        if not (0.0 < self.gate_prob <= 1.0):
            raise ValueError(f"gate_prob: must be in (0, 1], got {self.gate_prob!r}")
        if int(self.max_rejects) != self.max_rejects or self.max_rejects < 1:
            raise ValueError(f"max_rejects: must be an integer >= 1, got {self.max_rejects!r}")


#: Measured tuning results (module docstring; mean Euclidean CG error in metres).
TUNING: dict[str, object] = {
    "data": "square100 rover truth (0.2 m/s, 1985 epochs), gps_stationary replay, "
            "4 sessions from seed 20261122",
    "best": {"sigma_meas": 3.0, "sigma_accel": 0.5, "sigma_yaw_accel": 0.01,
             "mean_cg_error_m": 1.563},
    "references_m": {"window_1": 1.535, "motion_compensated_yaw_rate_10": 1.533,
                     "window_10": 1.688, "naive_10": 1.850},
}


@dataclass(frozen=True)
class PoseFilterResult:
    """states (n, 5), covariances (n, 5, 5), status (n,) str ("init" | "ok" | "predicted" |
    "reset"), n_used (n,) antennas used in the update, n_gated (n,) antennas rejected."""

    states: np.ndarray
    covariances: np.ndarray
    status: np.ndarray
    n_used: np.ndarray
    n_gated: np.ndarray


def _wrap(a: float) -> float:
    a = float(a)
    if -math.pi < a <= math.pi:
        return a
    return math.pi - math.fmod(math.fmod(math.pi - a, _TWO_PI) + _TWO_PI, _TWO_PI)


_TWO_PI = 2.0 * math.pi


def _predict(x: list, P: np.ndarray, dt: float, qa: float, qy: float
             ) -> tuple[list, np.ndarray]:
    """CTRV prediction on a state list [px, py, yaw, v, omega] (see :func:`ctrv_predict`)."""
    px, py, yaw, v, om = x
    # exact CTRV written with f1 = sin(q)/q, f2 = (1 - cos q)/q, q = omega dt, which are
    # smooth through omega = 0 (no branch, so state and Jacobian always agree)
    q = om * dt
    if abs(q) > 1e-4:
        sq, cq = math.sin(q), math.cos(q)
        f1 = sq / q
        f2 = (1.0 - cq) / q
        g1 = (q * cq - sq) / (q * q)  # d f1 / d q
        g2 = (q * sq - (1.0 - cq)) / (q * q)  # d f2 / d q
    else:  # series: f1 = 1 - q^2/6, f2 = q/2 - q^3/24
        f1 = 1.0 - q * q / 6.0
        f2 = 0.5 * q - q * q * q / 24.0
        g1 = -q / 3.0
        g2 = 0.5 - q * q / 8.0
    c0, s0 = math.cos(yaw), math.sin(yaw)
    ax = c0 * f1 - s0 * f2  # displacement direction / (v dt)
    ay = s0 * f1 + c0 * f2
    vdt = v * dt
    F = np.array([
        [1.0, 0.0, -vdt * ay, dt * ax, vdt * dt * (c0 * g1 - s0 * g2)],
        [0.0, 1.0, vdt * ax, dt * ay, vdt * dt * (s0 * g1 + c0 * g2)],
        [0.0, 0.0, 1.0, 0.0, dt],
        [0.0, 0.0, 0.0, 1.0, 0.0],
        [0.0, 0.0, 0.0, 0.0, 1.0],
    ])
    Pn = F @ P @ F.T
    # + Q = qa ga ga^T + qy gy gy^T, ga = [h c0, h s0, 0, dt, 0], gy = [0, 0, h, 0, dt]
    # (added entry by entry: the outer products are sparse)
    h = 0.5 * dt * dt
    hc, hs = h * c0, h * s0
    qhc, qhs, qdt = qa * hc, qa * hs, qa * dt
    Pn[0, 0] += qhc * hc
    Pn[0, 1] += qhc * hs
    Pn[1, 0] += qhs * hc
    Pn[1, 1] += qhs * hs
    Pn[0, 3] += qhc * dt
    Pn[3, 0] += qdt * hc
    Pn[1, 3] += qhs * dt
    Pn[3, 1] += qdt * hs
    Pn[3, 3] += qdt * dt
    qh, qyd = qy * h, qy * dt
    Pn[2, 2] += qh * h
    Pn[2, 4] += qh * dt
    Pn[4, 2] += qyd * h
    Pn[4, 4] += qyd * dt
    return [px + vdt * ax, py + vdt * ay, _wrap(yaw + q), v, om], Pn


def ctrv_predict(x: np.ndarray, P: np.ndarray, dt: float, sigma_accel: float,
                 sigma_yaw_accel: float) -> tuple[np.ndarray, np.ndarray]:
    """CTRV prediction of state (5,) and covariance (5, 5) over dt seconds (EKF).

    Scalar math on purpose: this runs once per epoch in a Python loop.
    """
    xn, Pn = _predict([float(e) for e in x], np.asarray(P, dtype=float), float(dt),
                      sigma_accel**2, sigma_yaw_accel**2)
    return np.array(xn), Pn


def _h(x: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Predicted antenna positions (k, 2) and stacked Jacobian (2k, 5) for offsets r (k, 2)."""
    c, s = np.cos(x[2]), np.sin(x[2])
    Rr = np.stack([c * r[:, 0] - s * r[:, 1], s * r[:, 0] + c * r[:, 1]], axis=1)
    z = x[:2] + Rr
    k = r.shape[0]
    H = np.zeros((2 * k, 5))
    H[0::2, 0] = 1.0
    H[1::2, 1] = 1.0
    H[0::2, 2] = -Rr[:, 1]  # d/dyaw R r = J R r = (-(Rr)_y, (Rr)_x)
    H[1::2, 2] = Rr[:, 0]
    return z, H


def _update(x: list, P: np.ndarray, zs: list, rs: list, r2: float, gate: float
            ) -> tuple[list, np.ndarray, list]:
    """Information-form update (see :func:`antenna_update`) on Python scalars: x a state
    list, zs/rs lists of (x, y) fixes and body offsets. Returns (x, P, accepted flags)."""
    c, s = math.cos(x[2]), math.sin(x[2])
    x0, x1 = x[0], x[1]
    if gate != math.inf:
        P00, P01, P02 = float(P[0, 0]), float(P[0, 1]), float(P[0, 2])
        P11, P12, P22 = float(P[1, 1]), float(P[1, 2]), float(P[2, 2])
    acc = []
    k = 0
    sx = sy = sr = sny = snx = s3 = 0.0
    for (zx, zy), (r0, r1) in zip(zs, rs):
        rx = c * r0 - s * r1  # R(yaw) r, world frame
        ry = s * r0 + c * r1
        nux = zx - (x0 + rx)
        nuy = zy - (x1 + ry)
        if gate != math.inf:
            # S_i = h_i P[:3, :3] h_i^T + sigma^2 I with h_i = [[1, 0, -ry], [0, 1, rx]]
            a = P00 - 2.0 * ry * P02 + ry * ry * P22 + r2
            b = P01 + rx * P02 - ry * P12 - rx * ry * P22
            d = P11 + 2.0 * rx * P12 + rx * rx * P22 + r2
            ok = (d * nux * nux - 2.0 * b * nux * nuy + a * nuy * nuy) / (a * d - b * b) <= gate
        else:
            ok = True
        acc.append(ok)
        if ok:  # running sums in antenna order (numpy's order for these short sums)
            k += 1
            sy += ry
            sx += rx
            sr += rx * rx + ry * ry
            snx += nux
            sny += nuy
            s3 += rx * nuy - ry * nux
    if k == 0:
        return x, P, acc
    # P+ = (P^-1 + E M3 E^T / r2)^-1 with E the first three unit vectors and
    # M3 = [[k, 0, -sy], [0, k, sx], [-sy, sx, sr]]; by the push-through identity
    # P+ = P - P E G E^T P with G = (r2 I + M3 P3)^-1 M3 (P3 = E^T P E): one 3x3 inverse
    # (closed form, adjugate) instead of two 5x5 inverses; valid for any k >= 1 (M3 is
    # singular for k = 1).
    kf = float(k)
    if gate == math.inf:
        P00, P01, P02 = float(P[0, 0]), float(P[0, 1]), float(P[0, 2])
        P11, P12, P22 = float(P[1, 1]), float(P[1, 2]), float(P[2, 2])
    c00 = kf * P00 - sy * P02 + r2
    c01 = kf * P01 - sy * P12
    c02 = kf * P02 - sy * P22
    c10 = kf * P01 + sx * P02
    c11 = kf * P11 + sx * P12 + r2
    c12 = kf * P12 + sx * P22
    c20 = -sy * P00 + sx * P01 + sr * P02
    c21 = -sy * P01 + sx * P11 + sr * P12
    c22 = -sy * P02 + sx * P12 + sr * P22 + r2
    i00 = c11 * c22 - c12 * c21
    i01 = c02 * c21 - c01 * c22
    i02 = c01 * c12 - c02 * c11
    i10 = c12 * c20 - c10 * c22
    i11 = c00 * c22 - c02 * c20
    i12 = c02 * c10 - c00 * c12
    i20 = c10 * c21 - c11 * c20
    i21 = c01 * c20 - c00 * c21
    i22 = c00 * c11 - c01 * c10
    det = c00 * i00 + c01 * i10 + c02 * i20
    G = np.array([[kf * i00 - sy * i02, kf * i01 + sx * i02, -sy * i00 + sx * i01 + sr * i02],
                  [kf * i10 - sy * i12, kf * i11 + sx * i12, -sy * i10 + sx * i11 + sr * i12],
                  [kf * i20 - sy * i22, kf * i21 + sx * i22, -sy * i20 + sx * i21 + sr * i22]])
    PE = P[:, :3]
    Pn = P - (PE @ (G / det)) @ PE.T
    Pn = 0.5 * (Pn + Pn.T)
    dx = Pn[:, :3] @ [snx / r2, sny / r2, s3 / r2]
    xn = [x[0] + dx[0], x[1] + dx[1], _wrap(x[2] + dx[2]), x[3] + dx[3], x[4] + dx[4]]
    return xn, Pn, acc


def antenna_update(x: np.ndarray, P: np.ndarray, z: np.ndarray, r: np.ndarray,
                   sigma_meas: float, gate: float = np.inf
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """EKF update with antenna fixes z (k, 2) at body offsets r (k, 2) from the CG.

    Antennas whose innovation NIS (2 dof, predicted covariance) exceeds ``gate`` are left
    out. The joint update of the accepted antennas is done in information form, which is
    the same update as the textbook gain form (tested against FilterPy) without a 2k x 2k
    innovation covariance: each antenna's Jacobian ``[I, J R r_i, 0, 0]`` touches
    (px, py, yaw) only, so the k antennas add ``M = sum H_i^T H_i / sigma^2`` (a 3x3 block)
    to the information and ``b = sum H_i^T nu_i / sigma^2`` to the information vector:
    ``P+ = (P^-1 + M)^-1``, ``x+ = x + P+ b``; ``P+`` is evaluated through the 3x3 block
    (push-through identity, one closed-form 3x3 inverse). Returns (x (5,), P (5, 5),
    accepted (k,)).
    """
    P = np.asarray(P, dtype=float)
    xn, Pn, acc = _update([float(e) for e in x], P, np.asarray(z, dtype=float).tolist(),
                          np.asarray(r, dtype=float).tolist(), float(sigma_meas) ** 2,
                          float(gate))
    return np.array(xn, dtype=float), Pn, np.array(acc, dtype=bool)


def run_pose_filter(t: np.ndarray, obs: np.ndarray, offsets: np.ndarray, x0: np.ndarray,
                    P0: np.ndarray, k0: int, params: PoseFilterParams = PoseFilterParams()
                    ) -> PoseFilterResult:
    """Run the filter from epoch ``k0`` (state x0, covariance P0 there) to the end.

    t : (n,) s, finite and strictly increasing (uneven steps are fine: each prediction uses
        its own dt).
    obs : (n, m, 2) metres (world x east, y north), NaN = the antenna did not report.
    offsets : (m, 2) metres, body offsets ``r_i = b_i - cg_body`` of the antennas from the CG
        (body x forward, y left); dead antennas simply never report.
    x0 : (5,) the state at epoch k0, ``(px m, py m, yaw rad CCW from +x, v m/s,
        omega rad/s)`` (module docstring), finite.
    P0 : (5, 5) its covariance in the same units, finite; also the covariance a "reset"
        restarts from.
    k0 : int in [0, n - 1], the first epoch. params : :class:`PoseFilterParams`.

    Returns a :class:`PoseFilterResult` of n rows; row k0 holds x0, P0 with status "init",
    rows before k0 are NaN (status ""). Wrong shapes or values raise ValueError naming the
    field.
    """
    obs = np.asarray(obs, dtype=float)
    if obs.ndim != 3 or obs.shape[2] != 2:
        raise ValueError(f"obs: expected shape (n, m, 2) metres, got {obs.shape}")
    n, m = obs.shape[:2]
    check_increasing_times(t, "t", n=n)
    off_arr = np.asarray(offsets, dtype=float)
    if off_arr.shape != (m, 2) or not np.all(np.isfinite(off_arr)):
        raise ValueError(f"offsets: expected finite values of shape ({m}, 2) metres, got "
                         f"shape {off_arr.shape}")
    x0_arr = np.asarray(x0, dtype=float)
    if x0_arr.shape != (5,) or not np.all(np.isfinite(x0_arr)):
        raise ValueError(f"x0: expected 5 finite values (px, py, yaw, v, omega), got "
                         f"{x0_arr.tolist() if x0_arr.size <= 5 else x0_arr.shape}")
    P0_arr = np.asarray(P0, dtype=float)
    if P0_arr.shape != (5, 5) or not np.all(np.isfinite(P0_arr)):
        raise ValueError(f"P0: expected a finite (5, 5) covariance, got shape {P0_arr.shape}")
    if isinstance(k0, bool) or not isinstance(k0, (int, np.integer)) or not 0 <= k0 < n:
        raise ValueError(f"k0: must be an integer in [0, {n - 1}], got {k0!r}")
    if not isinstance(params, PoseFilterParams):
        raise ValueError(  # noqa: TRY004 (bad input is ValueError by contract)
            f"params: expected a PoseFilterParams, got {type(params).__name__}")
    X = np.full((n, 5), np.nan)
    PP = np.full((n, 5, 5), np.nan)
    status = np.full(n, "", dtype=object)
    n_used = np.zeros(n, dtype=int)
    n_gated = np.zeros(n, dtype=int)
    gate = float(chi2.ppf(params.gate_prob, 2)) if params.gate_prob < 1 else np.inf
    present = np.all(np.isfinite(obs), axis=-1)
    x = [float(e) for e in np.asarray(x0, dtype=float)]
    P = np.asarray(P0, dtype=float).copy()
    X[k0], PP[k0], status[k0] = x, P, "init"
    # per-epoch Python lists of the reporting antennas' fixes and offsets (scalar math in
    # the loop: numpy's per-call overhead dominates arrays of <= m elements)
    off = np.asarray(offsets, dtype=float).tolist()
    zl = obs.tolist()
    idx = [np.flatnonzero(p).tolist() for p in present]
    tl = np.asarray(t, dtype=float).tolist()
    qa, qy, r2 = params.sigma_accel**2, params.sigma_yaw_accel**2, params.sigma_meas**2
    rejects = 0
    for k in range(k0 + 1, n):
        x, P = _predict(x, P, tl[k] - tl[k - 1], qa, qy)
        ik = idx[k]
        st = "predicted"
        if ik:
            zs = [zl[k][i] for i in ik]
            rs = [off[i] for i in ik]
            x1, P1, acc = _update(x, P, zs, rs, r2, gate)
            na = sum(acc)
            if na:
                x, P, rejects, st = x1, P1, 0, "ok"
                n_used[k] = na
                n_gated[k] = len(ik) - na
            else:
                rejects += 1
                n_gated[k] = len(ik)
                if rejects >= params.max_rejects:
                    P = np.asarray(P0, dtype=float).copy()
                    x, P, acc = _update(x, P, zs, rs, r2, math.inf)
                    n_used[k], n_gated[k], rejects, st = len(ik), 0, 0, "reset"
        X[k], PP[k], status[k] = x, P, st
    return PoseFilterResult(states=X, covariances=PP, status=status.astype(str),
                            n_used=n_used, n_gated=n_gated)
