"""Position-velocity Kalman filter with uneven time steps (thesis 003, Section 3.2.3,
Eqs. 3.1-3.3, and Appendix C ``RangeKalmanFilter``).

State ``x = [position, rate]``, measurement ``z = position``. For a step of ``dt`` seconds:

    A = [[1, dt], [0, 1]]                               (constant-velocity model, Eq. 3.3)
    Q = sigma_process^2 [[dt^4/4, dt^3/2], [dt^3/2, dt^2]]   (white acceleration noise)
    R = sigma_measurement^2,  C = [1, 0]

    predict:  x = A x;  P = A P A' + Q
    update:   K = P C' (C P C' + R)^-1;  x = x + K (z - C x);  P = (I - K C) P

Appendix C's initialisation, reproduced exactly: ``x0 = [mean(z[0:10]), 0]``,
``P0 = Q(mean(diff(t)))``, the first output is ``x0[0]`` without any update, and every later
sample predicts (with its own dt) then updates. ``sigma_process`` has the unit of the signal
per s^2 (an acceleration for a position), ``sigma_measurement`` the unit of the signal; the
thesis used 3 mm/s^2 and 2 mm for positions, 1 deg/s^2 and 1 deg for the heading.

Missing measurements (NaN) are a predict-only step (the output is the prediction); the
initial mean uses the first 10 *finite* measurements (identical to the thesis when there are
no NaN). :func:`pv_kalman` is the batch form; :class:`PVKalman` the same filter for streaming
use, and the two agree bit for bit (tested), as does filterpy's ``KalmanFilter`` stepped with
the same matrices (to 1e-12).
"""

from __future__ import annotations

import numpy as np

from estimator._checks import check_increasing_times

__all__ = ["N_INIT", "PVKalman", "process_noise", "pv_kalman"]

#: measurements averaged for the initial position (Appendix C: ``mean(Distance_Vector(1:10))``)
N_INIT = 10


def process_noise(dt: float, sigma_process: float) -> np.ndarray:
    """Q for a white-acceleration PV model over ``dt`` s: sigma^2 [[dt^4/4, dt^3/2],
    [dt^3/2, dt^2]] (Appendix C ``Error_Process``). Returns (2, 2)."""
    return sigma_process ** 2 * np.array([[dt ** 4 / 4.0, dt ** 3 / 2.0],
                                          [dt ** 3 / 2.0, dt ** 2]])


def _check_sigmas(sigma_process: float, sigma_measurement: float) -> tuple[float, float]:
    sp, sm = float(sigma_process), float(sigma_measurement)
    if not (np.isfinite(sp) and sp >= 0):
        raise ValueError(f"sigma_process: must be finite and >= 0, got {sigma_process!r}")
    if not (np.isfinite(sm) and sm > 0):
        raise ValueError(f"sigma_measurement: must be finite and > 0, got {sigma_measurement!r}")
    return sp, sm


class PVKalman:
    """Streaming form of :func:`pv_kalman` (one scalar channel).

    ``PVKalman(x0, P0, sigma_process, sigma_measurement)`` then ``predict(dt)`` and
    ``update(z)`` (NaN ``z``: no update). Attributes ``x`` (2,), ``P`` (2, 2), ``K`` (2,) of the
    last update. ``PVKalman.from_thesis(t, z, ...)`` builds the Appendix C initial state.
    """

    def __init__(self, x0: np.ndarray, P0: np.ndarray, sigma_process: float,
                 sigma_measurement: float) -> None:
        self.sigma_process, self.sigma_measurement = _check_sigmas(sigma_process,
                                                                   sigma_measurement)
        x = np.asarray(x0, dtype=float).reshape(-1)
        P = np.asarray(P0, dtype=float)
        if x.shape != (2,) or not np.all(np.isfinite(x)):
            raise ValueError(f"x0: expected 2 finite values, got {x0!r}")
        if P.shape != (2, 2) or not np.all(np.isfinite(P)):
            raise ValueError(f"P0: expected a finite (2, 2) matrix, got shape {P.shape}")
        self.x = x.copy()
        self.P = P.copy()
        self.R = self.sigma_measurement ** 2
        self.K = np.zeros(2)

    @classmethod
    def from_thesis(cls, t: np.ndarray, z: np.ndarray, sigma_process: float,
                    sigma_measurement: float) -> PVKalman:
        """Appendix C initial state: x0 = [mean of the first 10 finite z, 0], P0 = Q(mean dt)."""
        tt, zz = _check_tz(t, z)
        sp, _ = _check_sigmas(sigma_process, sigma_measurement)
        finite = zz[np.isfinite(zz)]
        if finite.size == 0:
            raise ValueError("z: no finite measurement to initialise the filter")
        dt_avg = float(np.mean(np.diff(tt))) if tt.size > 1 else 0.0
        return cls([np.mean(finite[:N_INIT]), 0.0], process_noise(dt_avg, sp),
                   sigma_process, sigma_measurement)

    def predict(self, dt: float) -> np.ndarray:
        """x = A x, P = A P A' + Q(dt). Returns the predicted state (2,)."""
        if not (np.isfinite(dt) and dt > 0):
            raise ValueError(f"dt: must be finite and > 0 s, got {dt!r}")
        A = np.array([[1.0, dt], [0.0, 1.0]])
        self.x = A @ self.x
        self.P = A @ self.P @ A.T + process_noise(dt, self.sigma_process)
        return self.x

    def update(self, z: float) -> np.ndarray:
        """Measurement update with position ``z`` (NaN: skipped). Returns the state (2,)."""
        if np.isnan(z):
            return self.x
        if not np.isfinite(z):
            raise ValueError(f"z: must be finite or NaN, got {z!r}")
        S = self.P[0, 0] + self.R                 # C P C' + R
        K = self.P[:, 0] / S                      # P C' S^-1
        self.x = self.x + K * (z - self.x[0])
        self.P = (np.eye(2) - np.outer(K, [1.0, 0.0])) @ self.P
        self.K = K
        return self.x


def _check_tz(t: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    tt = check_increasing_times(t, "t", min_size=1)
    zz = np.asarray(z, dtype=float)
    if zz.shape != tt.shape:
        raise ValueError(f"z: expected shape {tt.shape}, got {zz.shape}")
    if np.any(np.isinf(zz)):
        raise ValueError("z: must be finite or NaN (NaN = missing), got inf")
    return tt, zz


def pv_kalman(t: np.ndarray, z: np.ndarray, sigma_process: float,
              sigma_measurement: float) -> np.ndarray:
    """Appendix C ``RangeKalmanFilter``: PV Kalman filter of one signal on uneven samples.

    t (n,) s strictly increasing; z (n,) signal (NaN = missing, predict only);
    sigma_process (signal unit / s^2); sigma_measurement (signal unit). Returns the filtered
    position (n,): element 0 is the initial state (mean of the first 10 finite z), element i
    the estimate after predicting over t[i] - t[i-1] and updating with z[i].
    """
    tt, zz = _check_tz(t, z)
    kf = PVKalman.from_thesis(tt, zz, sigma_process, sigma_measurement)
    out = np.empty(tt.size)
    out[0] = kf.x[0]
    for i in range(1, tt.size):
        kf.predict(tt[i] - tt[i - 1])
        kf.update(zz[i])
        out[i] = kf.x[0]
    return out
