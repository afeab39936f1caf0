"""GTSAM peer: a fixed-lag factor-graph smoother (iSAM2) on the same data, as the reference.

An independent estimator, built from GTSAM's own C++ factors (optional dependency:
``pip install -e '.[gtsam]'``; gtsam is imported only when this runs), against which the
harness's estimators are compared (issue 14). Factor graph, per epoch k:

- variables ``X_k`` (``Pose2`` of the platform's no-slip point, see
  :mod:`estimator.pose_filter`) and ``V_k`` (body twist ``(vx, vy, omega)``, ``Vector3``);
- one lever-arm GPS factor per antenna fix: ``KnownLandmarkFactorPose2(X_k, z_i, r_i)``,
  whose error ``R(yaw)^T (z_i - p) - r_i`` has the same norm as ``z_i - (p + R r_i)`` (R is
  a rotation), with a Huber noise model (threshold 1.345 sd: 95 % efficiency under Gaussian
  noise) on an isotropic ``sigma_abs``;
- a motion prior between consecutive epochs: ``WnoaMotionFactorPose2``, the white-noise-on-
  acceleration Gaussian-process prior on SE(2) (Anderson and Barfoot 2015) with power
  spectral densities from the platform's limits, the same rule as the EKF's process noise:
  ``q = (limit / 2)^2 dt_median`` per axis (longitudinal acceleration, yaw acceleration);
  the body-lateral axis gets ``q = NHC_SIGMA_MPS^2 / dt_median`` (a lateral-velocity random
  walk of ``NHC_SIGMA_MPS`` per sample): the no-slip point does not move sideways, so between
  two epochs the pose may not slide sideways either (with the longitudinal ``q`` there it
  could, by ~0.1 m per second on the rover, and the heading would come loose from the
  direction of motion);
- the non-holonomic constraint as a prior ``vy = 0`` on every twist, sd
  :data:`NHC_SIGMA_MPS` (the EKF has it as an exact constraint).

- with ``displacements=True`` (default), the EKF's second measurement: each antenna's
  displacement between consecutive epochs, ``(X_k r_i) - (X_(k-1) r_i) = z_i(t_k) -
  z_i(t_(k-1))``, sd ``sigma_step``, Huber as the fixes; a ``CustomFactor`` (the only factor
  evaluated in Python; Jacobians ``[R, R J r]`` in each pose's tangent space).

Why the displacements: with ``displacements=False`` (the textbook formulation of the issue,
lever-arm fixes plus a motion prior) the peer treats the fixes' errors as white, but GNSS
errors are correlated over minutes; over the smoother's window each antenna's error is then
an almost constant offset that rotates the fitted configuration, and the white-noise model
counts that biased heading once per epoch. Measured on Path 1 (square100, gps_stationary,
the sweep's seeds 0-2 of the thesis spec, fixed-lag estimates): heading RMS 53-81 degrees
with the platform pointing backwards on 11-29 % of the epochs, against 1.6-1.8 degrees with
the displacement factors; on white noise of 1 m the fixes-only graph gives 10 degrees. The
displacement factors give the peer the information the EKF has, so the two compare as
estimators, not as measurement models.

Solver: ``IncrementalFixedLagSmoother`` (iSAM2) with the lag of the EKF's fixed-lag
smoother. It starts at the same epoch and from the same state as the EKF
(:class:`estimator.pose_filter.FilterStart`, prior covariance = the EKF's P0), and each new
epoch is initialised by the constant-twist prediction from the previous estimate. Outputs:
the causal estimate (the newest state after each update) and the fixed-lag estimate
(each state's estimate after the last update within ``lag_s`` of it).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from estimator._checks import check_real
from estimator.orientation import wrap_angle
from estimator.pose_filter import (
    NX,
    OMEGA,
    V,
    FilterStart,
    PoseFilterParams,
    _check_run_args,
    estimate_noise,
)

__all__ = ["HUBER_K", "NHC_SIGMA_MPS", "RELINEARIZE_THRESHOLD", "GtsamPeerResult", "gtsam_available", "run_gtsam_peer"]

#: Huber threshold in units of the noise sd (Huber 1964: 95 % efficiency at the normal).
HUBER_K = 1.345
#: sd of the non-holonomic prior on the no-slip point's lateral speed, m/s: the constraint
#: is exact for a rolling wheel; 1 cm/s keeps the factor well conditioned.
NHC_SIGMA_MPS = 0.01


#: iSAM2 relinearizes a variable whose update exceeds this (tangent units: m, rad), checked
#: at every update. GTSAM's default 0.1 (with checks every 10 updates) leaves heading
#: linearisation errors of up to ~6 degrees in place, the size of what is measured here.
RELINEARIZE_THRESHOLD = 0.01


def gtsam_available() -> bool:
    """True if the optional ``gtsam`` package can be imported."""
    try:
        import gtsam  # noqa: F401
    except ImportError:
        return False
    return True


@dataclass(frozen=True)
class GtsamPeerResult:
    """causal (n, 6) and fixed_lag (n, 6) states ``(px, py, yaw, v, a, omega)`` of the
    no-slip point, the EKF's layout (a is NaN: the peer's motion prior has no acceleration;
    NaN before the start); status (n,) str ("waiting"/"no_data" before the start,
    then "ok" or "predicted"); update_s: wall time of the smoother updates, s; cg_offset (2,)
    as in :class:`estimator.pose_filter.PoseFilterResult`."""

    causal: np.ndarray
    fixed_lag: np.ndarray
    status: np.ndarray
    update_s: float
    cg_offset: np.ndarray


def _import_gtsam():
    try:
        import gtsam
    except ImportError as exc:  # pragma: no cover - exercised only without gtsam
        raise ImportError("the GTSAM peer needs the optional dependency gtsam: "
                          "pip install -e '.[gtsam]'") from exc
    return gtsam


def _displacement_factor(gtsam, noise, kj: int, kk: int, r: np.ndarray, d: np.ndarray):
    """CustomFactor: antenna at body offset r moved by d (world) from pose kj to pose kk."""
    rx, ry = float(r[0]), float(r[1])

    def error(this, values, H):
        pj = values.atPose2(this.keys()[0])
        pk = values.atPose2(this.keys()[1])
        e = np.asarray(pk.transformFrom(r)) - np.asarray(pj.transformFrom(r)) - d
        if H is not None:
            for idx, (p, sign) in enumerate(((pj, -1.0), (pk, 1.0))):
                c, s = math.cos(p.theta()), math.sin(p.theta())
                # d(p + R r)/d(xi) for X (+) xi: [R, R J r]
                H[idx] = sign * np.array([[c, -s, -s * rx - c * ry],
                                          [s, c, c * rx - s * ry]])
        return e

    return gtsam.CustomFactor(noise, [kj, kk], error)


def run_gtsam_peer(t: np.ndarray, obs: np.ndarray, offsets: np.ndarray,
                   params: PoseFilterParams = PoseFilterParams(),
                   lag_s: float | None = None, displacements: bool = True) -> GtsamPeerResult:
    """Run the GTSAM fixed-lag smoother over a recording (module docstring).

    t (n,) s strictly increasing; obs (n, m, 2) metres, NaN = missing; offsets (m, 2)
    antenna body positions relative to the configuration's CG; params : the same
    :class:`PoseFilterParams` as the EKF (limits, noise levels, no-slip point; ``reverse``
    is not modelled: the twist's forward speed is free in sign). lag_s : smoother lag, s
    (default ``params.lag_s``). displacements : add the displacement factors (module
    docstring). Raises ImportError without gtsam.
    """
    gtsam = _import_gtsam()
    tt, obs, off = _check_run_args(t, obs, offsets, params)
    # limits, noise and no-slip point estimated from the data where None (as the EKF)
    params = params.resolve(tt, obs, off)
    lag = check_real(params.lag_s if lag_s is None else lag_s, "lag_s", lo=0.0)
    n, m = obs.shape[:2]
    ns = np.asarray(params.no_slip_point_m, dtype=float)
    r_m = off - ns
    if params.sigma_abs_m is None or params.sigma_step_m is None:
        sa, ss = estimate_noise(obs, off)
    sigma_abs = params.sigma_abs_m if params.sigma_abs_m is not None else sa
    sigma_step = params.sigma_step_m if params.sigma_step_m is not None else ss
    dt_med = float(np.median(np.diff(tt))) if n > 1 else 1.0
    qa = (0.5 * params.max_accel_mps2) ** 2 * dt_med
    qy = (0.5 * params.max_yaw_accel_radps2) ** 2 * dt_med
    qc = np.array([qa, NHC_SIGMA_MPS ** 2 / dt_med, qy])
    def robust(sd: float):
        return gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(HUBER_K),
                                              gtsam.noiseModel.Isotropic.Sigma(2, sd))

    huber = robust(sigma_abs)
    step_noise = robust(sigma_step)
    nhc = gtsam.noiseModel.Diagonal.Sigmas(np.array([1e6, NHC_SIGMA_MPS, 1e6]))
    X = lambda k: gtsam.symbol("x", k)  # noqa: E731
    Vk = lambda k: gtsam.symbol("v", k)  # noqa: E731

    causal = np.full((n, NX), np.nan)
    fixed = np.full((n, NX), np.nan)
    status = np.full(n, "", dtype=object)
    present = np.isfinite(obs[..., 0])
    starter = FilterStart(tt, obs, r_m, sigma_abs, params)
    smoother = None
    pose = twist = None
    start = -1
    pending = []           # epochs whose fixed-lag estimate is not final yet
    spent = 0.0

    def state_of(est, k):
        p = est.atPose2(X(k))
        w = est.atVector(Vk(k))
        return [p.x(), p.y(), p.theta(), w[0], np.nan, w[2]]

    for k in range(n):
        ik = np.flatnonzero(present[k])
        if smoother is None:
            status[k], got = starter.wait(k)
            if got is None:
                continue
            x0, P0 = got
            start = k
            params_isam = gtsam.ISAM2Params()
            params_isam.setRelinearizeThreshold(RELINEARIZE_THRESHOLD)
            params_isam.relinearizeSkip = 1
            smoother = gtsam.IncrementalFixedLagSmoother(lag + 1.5 * dt_med, params_isam)
            pose = gtsam.Pose2(x0[0], x0[1], x0[2])
            twist = np.array([x0[V], 0.0, x0[OMEGA]])
            graph = gtsam.NonlinearFactorGraph()
            values = gtsam.Values()
            stamps = gtsam.FixedLagSmootherKeyTimestampMap()
            graph.add(gtsam.PriorFactorPose2(X(k), pose, gtsam.noiseModel.Gaussian.Covariance(
                P0[:3, :3])))
            graph.add(gtsam.PriorFactorVector(Vk(k), twist, gtsam.noiseModel.Diagonal.Sigmas(
                np.sqrt([P0[V, V], NHC_SIGMA_MPS ** 2, P0[OMEGA, OMEGA]]))))
        else:
            graph = gtsam.NonlinearFactorGraph()
            values = gtsam.Values()
            stamps = gtsam.FixedLagSmootherKeyTimestampMap()
            dt = tt[k] - tt[k - 1]
            pose = pose.compose(gtsam.Pose2.Expmap(twist * dt))
            graph.add(gtsam.WnoaMotionFactorPose2(
                gtsam.StateData(X(k - 1), Vk(k - 1), tt[k - 1]),
                gtsam.StateData(X(k), Vk(k), tt[k]), qc))
        graph.add(gtsam.PriorFactorVector(Vk(k), np.zeros(3), nhc))
        for i in ik:
            graph.add(gtsam.KnownLandmarkFactorPose2(X(k), obs[k, i], r_m[i], huber))
            if displacements and k > start and np.isfinite(obs[k - 1, i, 0]):
                graph.add(_displacement_factor(gtsam, step_noise, X(k - 1), X(k), r_m[i],
                                               obs[k, i] - obs[k - 1, i]))
        values.insert(X(k), pose)
        values.insert(Vk(k), twist)
        stamps.insert((X(k), tt[k]))
        stamps.insert((Vk(k), tt[k]))
        t0 = time.perf_counter()
        smoother.update(graph, values, stamps)
        est = smoother.calculateEstimate()
        spent += time.perf_counter() - t0
        causal[k] = state_of(est, k)
        pose = est.atPose2(X(k))
        twist = est.atVector(Vk(k))
        status[k] = "ok" if ik.size else "predicted"
        pending.append(k)
        nxt = tt[k + 1] if k + 1 < n else math.inf
        while pending and nxt > tt[pending[0]] + lag * (1 + 1e-12) + 1e-12:
            j = pending.pop(0)
            fixed[j] = state_of(est, j)
    if pending:
        est = smoother.calculateEstimate()
        for j in pending:
            fixed[j] = state_of(est, j)
    causal[:, 2] = wrap_angle(causal[:, 2])
    fixed[:, 2] = wrap_angle(fixed[:, 2])
    return GtsamPeerResult(causal=causal, fixed_lag=fixed, status=status.astype(str),
                           update_s=spent, cg_offset=-ns)
