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
per s^2 (an acceleration for a position), ``sigma_measurement`` the unit of the signal. The
defaults are Appendix C's position values in SI units: ``Sigma_Process = 3`` and
``Sigma_Measurement = 2`` in the thesis's millimetres, i.e. 0.003 m/s^2 and 0.002 m (a very
stiff filter for a flying platform; the thesis's heading filter used 1 deg/s^2 and 1 deg).
``sigma_measurement`` may also be an ``(n,)`` array: one standard deviation per sample (e.g.
the covariance of each trilateration fix, which grows with the distance from the array).

Innovation gate (not in the thesis, ``gate``): a measurement whose innovation exceeds ``gate``
standard deviations of the innovation, ``|z - x_pos| > gate sqrt(P_pos + R)``, is not used
(predict only) and is flagged; after ``reinit_after`` consecutive gated measurements the
filter is re-initialised on the newest one (position = z with variance R, velocity and its
variance kept, cross-covariance zero): a lasting change is a new level, not a run of spikes.
``gate=None`` (default) is Appendix C's filter.

Bounds (so no number overflows; each raises ``ValueError`` naming the argument): sigmas in
[1e-50, 1e50] (squares in [1e-100, 1e100]), ``|z| <= 1e100``, initial covariances up to 1e200,
time steps ``dt <= MAX_DT_S`` (1e6 s, 11.6 days: a larger step is a unit error, e.g.
nanoseconds, not a gap).

Missing measurements (NaN) are a predict-only step (the output is the prediction); the
initial mean uses the first 10 *finite* measurements (identical to the thesis when there are
no NaN). :func:`pv_kalman` is the batch form; :class:`PVKalman` the same filter for streaming
use, and the two agree bit for bit (tested), as does filterpy's ``KalmanFilter`` stepped with
the same matrices (to 1e-12).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import cast

import numpy as np
from numpy.typing import ArrayLike
from scipy import linalg

from estimator._checks import check_array, check_increasing_times, check_int, check_real

__all__ = ["MAX_DT_S", "N_INIT", "SIGMA_MEASUREMENT_M", "SIGMA_PROCESS_MPS2", "KalmanInfo",
           "PVKalman", "kalman_steady_state", "process_noise", "pv_kalman"]

#: measurements averaged for the initial position (Appendix C: ``mean(Distance_Vector(1:10))``)
N_INIT = 10
#: Appendix C ``Sigma_Process = 3`` (mm/s^2) in SI
SIGMA_PROCESS_MPS2 = 0.003
#: Appendix C ``Sigma_Measurement = 2`` (mm) in SI
SIGMA_MEASUREMENT_M = 0.002
#: largest time step (s) of a predict: 11.6 days; larger steps are unit errors (nanoseconds)
MAX_DT_S = 1e6
_SIGMA_LO, _SIGMA_HI = 1e-50, 1e50
_P_MAX = 1e200
_Z_MAX = 1e100


def process_noise(dt: float, sigma_process: float) -> np.ndarray:
    """Q for a white-acceleration PV model over ``dt`` s: sigma^2 [[dt^4/4, dt^3/2],
    [dt^3/2, dt^2]] (Appendix C ``Error_Process``). dt in [0, MAX_DT_S], sigma_process 0 or
    in [1e-50, 1e50] (ValueError/TypeError naming them otherwise). Returns (2, 2)."""
    dt = check_real(dt, "dt", lo=0.0, hi=MAX_DT_S)
    sigma_process = _check_sigma(sigma_process, "sigma_process", allow_zero=True)
    return sigma_process ** 2 * np.array([[dt ** 4 / 4.0, dt ** 3 / 2.0],
                                          [dt ** 3 / 2.0, dt ** 2]])


def _check_sigma(value, name: str, allow_zero: bool = False) -> float:
    v = check_real(value, name, lo=0.0 if allow_zero else _SIGMA_LO, hi=_SIGMA_HI)
    if allow_zero and 0.0 < v < _SIGMA_LO:
        raise ValueError(f"{name}: must be 0 or >= {_SIGMA_LO:g}, got {value!r}")
    return v


def _check_sigmas(sigma_process: float, sigma_measurement: float) -> tuple[float, float]:
    return (_check_sigma(sigma_process, "sigma_process", allow_zero=True),
            _check_sigma(sigma_measurement, "sigma_measurement"))


def _check_dt(dt) -> float:
    return check_real(dt, "dt", lo=0.0, lo_open=True, hi=MAX_DT_S)


class PVKalman:
    """Streaming form of :func:`pv_kalman` (one scalar channel).

    ``PVKalman(x0, P0, sigma_process, sigma_measurement)`` then ``predict(dt)`` and
    ``update(z)`` (NaN ``z``: no update). Attributes ``x`` (2,), ``P`` (2, 2), ``K`` (2,) of the
    last update. ``PVKalman.from_thesis(t, z, ...)`` builds the Appendix C initial state.
    ``update(z, sigma=..., gate=...)`` takes a per-sample measurement std and the innovation
    gate of :func:`pv_kalman`; ``last_gated`` tells whether the last update was gated out.
    """

    def __init__(self, x0: ArrayLike, P0: ArrayLike, sigma_process: float = SIGMA_PROCESS_MPS2,
                 sigma_measurement: float = SIGMA_MEASUREMENT_M) -> None:
        self.sigma_process, self.sigma_measurement = _check_sigmas(sigma_process,
                                                                   sigma_measurement)
        x = check_array(x0, "x0", max_abs=_Z_MAX).reshape(-1)
        P = check_array(P0, "P0", max_abs=_P_MAX)
        if x.shape != (2,):
            raise ValueError(f"x0: expected 2 finite values, got {x0!r}")
        if P.shape != (2, 2):
            raise ValueError(f"P0: expected a finite (2, 2) matrix, got shape {P.shape}")
        self.x = x.copy()
        self.P = P.copy()
        self.R = self.sigma_measurement ** 2
        self.K = np.zeros(2)
        self.last_gated = False

    @classmethod
    def from_thesis(cls, t: np.ndarray, z: np.ndarray, sigma_process: float = SIGMA_PROCESS_MPS2,
                    sigma_measurement: float = SIGMA_MEASUREMENT_M) -> PVKalman:
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
        """x = A x, P = A P A' + Q(dt); dt in (0, MAX_DT_S] s. Returns the predicted state (2,)."""
        dt = _check_dt(dt)
        A = np.array([[1.0, dt], [0.0, 1.0]])
        self.x = A @ self.x
        self.P = A @ self.P @ A.T + process_noise(dt, self.sigma_process)
        return self.x

    def update(self, z: float, sigma: float | None = None,
               gate: float | None = None) -> np.ndarray:
        """Measurement update with position ``z`` (NaN: skipped). ``sigma``: this sample's
        measurement std (default the filter's); ``gate``: skip (and flag ``last_gated``) when
        the innovation exceeds ``gate`` innovation standard deviations. Returns the state (2,).
        """
        self.last_gated = False
        z = check_real(z, "z", finite=False) if not isinstance(z, float) else z
        if np.isnan(z):
            return self.x
        if not abs(z) <= _Z_MAX:
            raise ValueError(f"z: must be finite with |z| <= {_Z_MAX:g}, or NaN; got {z!r}")
        R = self.R if sigma is None else _check_sigma(sigma, "sigma") ** 2
        S = self.P[0, 0] + R                      # C P C' + R
        innov = z - self.x[0]
        if gate is not None and innov * innov > gate * gate * S:
            self.last_gated = True
            return self.x
        K = self.P[:, 0] / S                      # P C' S^-1
        self.x = self.x + K * innov
        self.P = (np.eye(2) - np.outer(K, [1.0, 0.0])) @ self.P
        self.K = K
        return self.x

    def reinitialise(self, z: float, sigma: float | None = None) -> np.ndarray:
        """Re-initialise on measurement ``z``: position z with variance R (this sample's), the
        velocity and its variance kept, cross-covariance zero. Returns the state (2,)."""
        z = check_real(z, "z", lo=-_Z_MAX, hi=_Z_MAX)
        R = self.R if sigma is None else _check_sigma(sigma, "sigma") ** 2
        self.x = np.array([z, self.x[1]])
        self.P = np.array([[R, 0.0], [0.0, self.P[1, 1]]])
        return self.x


@dataclass(frozen=True)
class KalmanInfo:
    """Per-sample diagnostics of :func:`pv_kalman` (each (n,) bool).

    gated : the measurement was finite but rejected by the innovation gate (predict only).
    reinitialised : the filter was re-initialised on this measurement (after ``reinit_after``
        gated measurements in a row).
    """

    gated: np.ndarray
    reinitialised: np.ndarray


def _check_tz(t: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    tt = check_increasing_times(t, "t", min_size=1)
    if tt.size > 1:
        big = np.diff(tt) > MAX_DT_S
        if big.any():
            k = int(np.argmax(big))
            raise ValueError(f"t: step t[{k + 1}] - t[{k}] = {tt[k + 1] - tt[k]!r} s exceeds "
                             f"{MAX_DT_S:g} s (nanoseconds? pass seconds)")
    zz = check_array(z, "z", allow_nan=True, max_abs=_Z_MAX)
    if zz.shape != tt.shape:
        raise ValueError(f"z: expected shape {tt.shape}, got {zz.shape}")
    return tt, zz


def pv_kalman(t: np.ndarray, z: np.ndarray, sigma_process: float = SIGMA_PROCESS_MPS2,
              sigma_measurement: float | np.ndarray = SIGMA_MEASUREMENT_M, *,
              gate: float | None = None, reinit_after: int = 5,
              return_info: bool = False) -> np.ndarray | tuple[np.ndarray, KalmanInfo]:
    """Appendix C ``RangeKalmanFilter``: PV Kalman filter of one signal on uneven samples.

    t (n,) s strictly increasing; z (n,) signal (NaN = missing, predict only);
    sigma_process (signal unit / s^2, default Appendix C's 0.003 m/s^2); sigma_measurement
    (signal unit, default Appendix C's 0.002 m), a scalar or (n,) per-sample stds (NaN where
    z is NaN); gate (innovation standard deviations, None = no gate as in the thesis) and
    reinit_after (consecutive gated samples that re-initialise; see the module docstring).
    Returns the filtered position (n,): element 0 is the initial state (mean of the first 10
    finite z), element i the estimate after predicting over t[i] - t[i-1] and updating with
    z[i] [and a :class:`KalmanInfo`].
    """
    tt, zz = _check_tz(t, z)
    per_sample = np.ndim(sigma_measurement) > 0
    if per_sample:
        sm = check_array(sigma_measurement, "sigma_measurement", allow_nan=True,
                         max_abs=_SIGMA_HI)
        if sm.shape != tt.shape:
            raise ValueError(f"sigma_measurement: expected a scalar or shape {tt.shape}, "
                             f"got {sm.shape}")
        bad = np.isfinite(zz) & ~(sm >= _SIGMA_LO)
        if bad.any():
            k = int(np.argmax(bad))
            raise ValueError(f"sigma_measurement: must be >= {_SIGMA_LO:g} where z is finite; "
                             f"sigma_measurement[{k}] = {sm[k]!r}")
        s0 = float(np.nanmedian(sm)) if np.isfinite(sm).any() else 1.0
    else:
        s0 = cast(float, sigma_measurement)  # 0-d here; from_thesis checks it
    g = None if gate is None else check_real(gate, "gate", lo=0.0, lo_open=True, hi=_SIGMA_HI)
    reinit_after = check_int(reinit_after, "reinit_after", lo=1, hi=2**31 - 1)
    kf = PVKalman.from_thesis(tt, zz, sigma_process, s0)
    out = np.empty(tt.size)
    gated = np.zeros(tt.size, dtype=bool)
    reinit = np.zeros(tt.size, dtype=bool)
    out[0] = kf.x[0]
    run = 0
    for i in range(1, tt.size):
        kf.predict(tt[i] - tt[i - 1])
        sig = sm[i] if per_sample else None
        kf.update(zz[i], sig, g)
        if kf.last_gated:
            run += 1
            if run >= reinit_after:
                kf.reinitialise(zz[i], sig)
                reinit[i], run = True, 0
            else:
                gated[i] = True
        elif np.isfinite(zz[i]):
            run = 0
        out[i] = kf.x[0]
    if return_info:
        return out, KalmanInfo(gated, reinit)
    return out


def kalman_steady_state(sigma_process: float, sigma_measurement: float,
                        dt: float) -> dict[str, float]:
    """Steady state of the Appendix C PV Kalman (this module's filter) at a constant step
    ``dt`` (s), against which the identification chain's filter lag is checked: the gain
    ``K`` (2,) from the discrete Riccati equation and the filter's poles (those of
    ``(I - K C) A``) as the continuous ``w`` (rad/s) and ``zeta``; the closed form is
    ``w = sqrt(sigma_process / sigma_measurement)``, zeta = 1/sqrt(2)."""
    for name, v in (("sigma_process", sigma_process),
                    ("sigma_measurement", sigma_measurement), ("dt", dt)):
        check_real(v, name, lo=0.0, lo_open=True)
    A = np.array([[1.0, dt], [0.0, 1.0]])
    C = np.array([[1.0, 0.0]])
    Q = sigma_process ** 2 * np.array([[dt ** 4 / 4, dt ** 3 / 2], [dt ** 3 / 2, dt ** 2]])
    R = np.array([[sigma_measurement ** 2]])
    P = linalg.solve_discrete_are(A.T, C.T, Q, R)          # predicted covariance
    K = (P @ C.T / (C @ P @ C.T + R)).ravel()
    z = np.linalg.eigvals((np.eye(2) - np.outer(K, [1.0, 0.0])) @ A).astype(complex)
    s = np.log(z[0]) / dt
    return {"K_pos": float(K[0]), "K_vel": float(K[1]), "w_rad_s": float(abs(s)),
            "zeta": float(-s.real / abs(s)), "settle_s": float(-1.0 / s.real),
            "w_closed_form": math.sqrt(sigma_process / sigma_measurement)}
