"""Frozen copy of estimator.pose_filter's filter loop before the speed rewrite (commit
2a66557), kept as the reference the fast implementation must reproduce."""

import math

import numpy as np
from scipy.stats import chi2

from estimator.pose_filter import PoseFilterParams, PoseFilterResult


def _wrap(a: float) -> float:
    a = float(a)
    if -math.pi < a <= math.pi:
        return a
    return math.pi - math.fmod(math.fmod(math.pi - a, _TWO_PI) + _TWO_PI, _TWO_PI)


_TWO_PI = 2.0 * math.pi


def ctrv_predict(x: np.ndarray, P: np.ndarray, dt: float, sigma_accel: float,
                 sigma_yaw_accel: float) -> tuple[np.ndarray, np.ndarray]:
    """CTRV prediction of state (5,) and covariance (5, 5) over dt seconds (EKF).

    Scalar math on purpose: this runs once per epoch in a Python loop.
    """
    px, py, yaw, v, om = (float(e) for e in x)
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
    xn = np.array([px + vdt * ax, py + vdt * ay, _wrap(yaw + q), v, om])
    # Q = G diag(sa^2, sy^2) G^T, G = [[h c0, 0], [h s0, 0], [0, h], [dt, 0], [0, dt]]
    h = 0.5 * dt * dt
    qa, qy = sigma_accel**2, sigma_yaw_accel**2
    ga = np.array([h * c0, h * s0, 0.0, dt, 0.0])
    gy = np.array([0.0, 0.0, h, 0.0, dt])
    Q = qa * np.outer(ga, ga) + qy * np.outer(gy, gy)
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
    out. The joint update of the accepted antennas is done in information form, which is
    the same update as the textbook gain form (tested against FilterPy) but only needs
    5x5 inverses: each antenna's Jacobian ``[I, J R r_i, 0, 0]`` touches (px, py, yaw) only,
    so the k antennas add ``M = sum H_i^T H_i / sigma^2`` (a 3x3 block) to the information
    and ``b = sum H_i^T nu_i / sigma^2`` to the information vector:
    ``P+ = (P^-1 + M)^-1``, ``x+ = x + P+ b``. Returns (x (5,), P (5, 5), accepted (k,)).
    """
    c, s = math.cos(x[2]), math.sin(x[2])
    rx = c * r[:, 0] - s * r[:, 1]  # R(yaw) r, world frame
    ry = s * r[:, 0] + c * r[:, 1]
    nux = z[:, 0] - (x[0] + rx)
    nuy = z[:, 1] - (x[1] + ry)
    r2 = sigma_meas**2
    if np.isfinite(gate):
        # S_i = h_i P[:3, :3] h_i^T + sigma^2 I with h_i = [[1, 0, -ry], [0, 1, rx]]
        P00, P01, P02, P11, P12, P22 = P[0, 0], P[0, 1], P[0, 2], P[1, 1], P[1, 2], P[2, 2]
        a = P00 - 2.0 * ry * P02 + ry * ry * P22 + r2
        b = P01 + rx * P02 - ry * P12 - rx * ry * P22
        d = P11 + 2.0 * rx * P12 + rx * rx * P22 + r2
        nis = (d * nux * nux - 2.0 * b * nux * nuy + a * nuy * nuy) / (a * d - b * b)
        acc = nis <= gate
    else:
        acc = np.ones(z.shape[0], dtype=bool)
    if not acc.any():
        return x, P, acc
    rx, ry, nux, nuy = rx[acc], ry[acc], nux[acc], nuy[acc]
    k = float(rx.size)
    M = np.zeros((5, 5))
    M[0, 0] = M[1, 1] = k
    M[0, 2] = M[2, 0] = -ry.sum()
    M[1, 2] = M[2, 1] = rx.sum()
    M[2, 2] = (rx * rx + ry * ry).sum()
    bvec = np.array([nux.sum(), nuy.sum(), (rx * nuy - ry * nux).sum(), 0.0, 0.0])
    Pn = np.linalg.inv(np.linalg.inv(P) + M / r2)
    Pn = 0.5 * (Pn + Pn.T)
    xn = x + Pn @ (bvec / r2)
    xn[2] = _wrap(xn[2])
    return xn, Pn, acc




def run_pose_filter(t: np.ndarray, obs: np.ndarray, offsets: np.ndarray, x0: np.ndarray,
                    P0: np.ndarray, k0: int, params: PoseFilterParams
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
