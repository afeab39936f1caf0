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

Tuning (done once, on synthetic data; ``tests/tune_pose_filter.py`` reruns it): Path 1
(square100, 270 epochs at 1 Hz) driven by the MuJoCo rover with the rover_gps8 layout, GPS
errors from models/noise/gps_stationary.toml (2 m per axis, half common-mode, Gauss-Markov
120 s / 600 s, plateaus, outliers, bursty dropouts) in 4000 s sessions replayed onto the
truth; four sessions spawned from seed 20261122, which no test and no sweep preset uses.
Criterion: mean Euclidean CG error over the whole path, averaged over the sessions. A first
grid (sigma_meas {0.5, 1, 2, 3} m x sigma_accel {0.2, 0.5, 1, 2} m/s^2 x sigma_yaw_accel
{0.02, 0.05, 0.1, 0.2} rad/s^2) was best at its edge (3, 2, 0.02: 2.018 m) and flat in
sigma_accel; a second grid ({2, 3, 4, 6} x {0.5, 1, 2} x {0.005, 0.01, 0.02, 0.05}) gave
the defaults below, 1.995 m (worst of that grid 2.62 m). For comparison on the same data:
window 1 (procrustes) 1.908 m, motion-compensated window 10 1.974 m, window 10 6.74 m.
With errors this time-correlated (the filter's white-noise model is wrong, and the common
mode is invisible to any configuration method) the EKF does not beat the plain window-1 fit;
it is kept as the Section 5.2 proposal, measured, not as a recommendation. ``TUNING`` holds
these numbers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

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
    sigma_accel: float = 2.0
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
    "data": "square100 rover truth, gps_stationary replay, 4 sessions from seed 20261122",
    "best": {"sigma_meas": 3.0, "sigma_accel": 2.0, "sigma_yaw_accel": 0.01,
             "mean_cg_error_m": 1.995},
    "references_m": {"window_1": 1.908, "motion_compensated_10": 1.974, "window_10": 6.740,
                     "naive_10": 6.694},
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
    return float(np.pi - np.mod(np.pi - a, 2.0 * np.pi))


def ctrv_predict(x: np.ndarray, P: np.ndarray, dt: float, sigma_accel: float,
                 sigma_yaw_accel: float) -> tuple[np.ndarray, np.ndarray]:
    """CTRV prediction of state (5,) and covariance (5, 5) over dt seconds (EKF)."""
    px, py, yaw, v, om = x
    # exact CTRV written with f1 = sin(q)/q, f2 = (1 - cos q)/q, q = omega dt, which are
    # smooth through omega = 0 (no branch, so state and Jacobian always agree)
    q = om * dt
    f1 = float(np.sinc(q / np.pi))
    f2 = float(np.sin(q / 2.0) * np.sinc(q / (2.0 * np.pi)))
    if abs(q) > 1e-4:
        g1 = (q * np.cos(q) - np.sin(q)) / q**2  # d f1 / d q
        g2 = (q * np.sin(q) - (1.0 - np.cos(q))) / q**2  # d f2 / d q
    else:  # series: f1 = 1 - q^2/6, f2 = q/2 - q^3/24
        g1 = -q / 3.0
        g2 = 0.5 - q * q / 8.0
    c0, s0 = np.cos(yaw), np.sin(yaw)
    ax = c0 * f1 - s0 * f2  # displacement direction / (v dt)
    ay = s0 * f1 + c0 * f2
    nx = px + v * dt * ax
    ny = py + v * dt * ay
    th = yaw + q
    F = np.eye(5)
    F[0, 2] = -v * dt * ay
    F[1, 2] = v * dt * ax
    F[0, 3] = dt * ax
    F[1, 3] = dt * ay
    F[0, 4] = v * dt * dt * (c0 * g1 - s0 * g2)
    F[1, 4] = v * dt * dt * (s0 * g1 + c0 * g2)
    F[2, 4] = dt
    xn = np.array([nx, ny, _wrap(th), v, om])
    h = 0.5 * dt * dt
    G = np.array([[h * np.cos(yaw), 0.0], [h * np.sin(yaw), 0.0], [0.0, h], [dt, 0.0], [0.0, dt]])
    Q = G @ np.diag([sigma_accel**2, sigma_yaw_accel**2]) @ G.T
    return xn, F @ P @ F.T + Q


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


def antenna_update(x: np.ndarray, P: np.ndarray, z: np.ndarray, r: np.ndarray,
                   sigma_meas: float, gate: float = np.inf
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """EKF update with antenna fixes z (k, 2) at body offsets r (k, 2) from the CG.

    Antennas whose innovation NIS (2 dof, predicted covariance) exceeds ``gate`` are left
    out. Joseph-form covariance update. Returns (x (5,), P (5, 5), accepted (k,) bool).
    """
    zp, H = _h(x, r)
    nu = z - zp
    k = z.shape[0]
    R2 = sigma_meas**2 * np.eye(2)
    acc = np.ones(k, dtype=bool)
    if np.isfinite(gate):
        for i in range(k):
            Hi = H[2 * i:2 * i + 2]
            S = Hi @ P @ Hi.T + R2
            acc[i] = float(nu[i] @ np.linalg.solve(S, nu[i])) <= gate
    if not acc.any():
        return x, P, acc
    rows = np.repeat(acc, 2)
    Ha = H[rows]
    nua = nu[acc].reshape(-1)
    Ra = sigma_meas**2 * np.eye(Ha.shape[0])
    S = Ha @ P @ Ha.T + Ra
    K = np.linalg.solve(S, Ha @ P).T  # P H^T S^-1 (S, P symmetric)
    xn = x + K @ nua
    xn[2] = _wrap(xn[2])
    IKH = np.eye(5) - K @ Ha
    Pn = IKH @ P @ IKH.T + K @ Ra @ K.T
    return xn, 0.5 * (Pn + Pn.T), acc


def run_pose_filter(t: np.ndarray, obs: np.ndarray, offsets: np.ndarray, x0: np.ndarray,
                    P0: np.ndarray, k0: int, params: PoseFilterParams = PoseFilterParams()
                    ) -> PoseFilterResult:
    """Run the filter from epoch ``k0`` (state x0, covariance P0 there) to the end.

    t : (n,) s; obs : (n, m, 2) metres, NaN = missing; offsets : (m, 2) body offsets of the
    antennas from the CG (dead antennas simply never report). Rows before k0 are NaN.
    """
    n, _m = obs.shape[:2]
    X = np.full((n, 5), np.nan)
    PP = np.full((n, 5, 5), np.nan)
    status = np.full(n, "", dtype=object)
    n_used = np.zeros(n, dtype=int)
    n_gated = np.zeros(n, dtype=int)
    gate = float(chi2.ppf(params.gate_prob, 2)) if params.gate_prob < 1 else np.inf
    present = np.all(np.isfinite(obs), axis=-1)
    x = np.asarray(x0, dtype=float).copy()
    P = np.asarray(P0, dtype=float).copy()
    X[k0], PP[k0], status[k0] = x, P, "init"
    rejects = 0
    for k in range(k0 + 1, n):
        x, P = ctrv_predict(x, P, float(t[k] - t[k - 1]), params.sigma_accel,
                            params.sigma_yaw_accel)
        pk = present[k]
        st = "predicted"
        if pk.any():
            x1, P1, acc = antenna_update(x, P, obs[k, pk], offsets[pk], params.sigma_meas, gate)
            if acc.any():
                x, P, rejects, st = x1, P1, 0, "ok"
                n_used[k] = int(acc.sum())
                n_gated[k] = int((~acc).sum())
            else:
                rejects += 1
                n_gated[k] = int(pk.sum())
                if rejects >= params.max_rejects:
                    P = np.asarray(P0, dtype=float).copy()
                    x, P, acc = antenna_update(x, P, obs[k, pk], offsets[pk], params.sigma_meas)
                    n_used[k], n_gated[k], rejects, st = int(pk.sum()), 0, 0, "reset"
        X[k], PP[k], status[k] = x, P, st
    return PoseFilterResult(states=X, covariances=PP, status=status.astype(str),
                            n_used=n_used, n_gated=n_gated)
