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
from typing import Any

import numpy as np

from estimator._checks import check_real
from estimator.orientation import wrap_angle
from estimator.pose_filter import (
    NX,
    OMEGA,
    FilterStart,
    PoseFilterParams,
    V,
    _check_run_args,
)

__all__ = ["HUBER_K", "MAX_BRIDGE_S", "NHC_SIGMA_MPS", "RELINEARIZE_THRESHOLD",
           "GtsamPeerError", "GtsamPeerResult", "gtsam_available", "run_gtsam_peer"]

#: Huber threshold in units of the noise sd (Huber 1964: 95 % efficiency at the normal).
HUBER_K = 1.345
#: sd of the non-holonomic prior on the no-slip point's lateral speed, m/s: the constraint
#: is exact for a rolling wheel; 1 cm/s keeps the factor well conditioned.
NHC_SIGMA_MPS = 0.01


#: iSAM2 relinearizes a variable whose update exceeds this (tangent units: m, rad), checked
#: at every update. GTSAM's default 0.1 (with checks every 10 updates) leaves heading
#: linearisation errors of up to ~6 degrees in place, the size of what is measured here.
RELINEARIZE_THRESHOLD = 0.01

#: Longest time without any fix that the motion prior bridges, s; a longer outage ends the
#: segment (its epochs NaN, status "no_data") and the peer restarts from the data as at the
#: start (:class:`estimator.pose_filter.FilterStart`, as the EKF after a lost track). 5 s:
#: the car of issue 25 drives up to 80 m in it, turning up to ~150 deg: the constant-twist
#: guess iSAM2 starts from means nothing beyond that, and an all-antenna outage of 34 s
#: made GTSAM raise ``Indeterminate linear system`` 8 s into it (1 Hz, 2 s lag).
MAX_BRIDGE_S = 5.0


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
    then "ok" or "predicted"); update_s: wall time of the smoother updates, s; update_cpu_s:
    their CPU time (``time.process_time``, every thread of the process), s, the figure to
    compare with the EKF's CPU time on a shared machine (wall time grows with the others'
    load); cg_offset (2,) as in :class:`estimator.pose_filter.PoseFilterResult`."""

    causal: np.ndarray
    fixed_lag: np.ndarray
    status: np.ndarray
    update_s: float
    cg_offset: np.ndarray
    segments: int = 1
    notes: tuple[str, ...] = ()
    update_cpu_s: float = 0.0


class GtsamPeerError(RuntimeError):
    """The peer failed where it cannot restart; the message is one line (a sweep cell's
    error column)."""


def _one_line(exc: BaseException) -> str:
    """GTSAM's multi-line message in one line: its first line and the variable named."""
    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
    head = lines[0] if lines else type(exc).__name__
    sym = next((ln for ln in lines if "Symbol:" in ln), "")
    return f"{head} {sym}".strip()


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


_DEFAULT_PARAMS = PoseFilterParams()  # frozen: one shared default is safe


def run_gtsam_peer(t: np.ndarray, obs: np.ndarray, offsets: np.ndarray,
                   params: PoseFilterParams = _DEFAULT_PARAMS,
                   lag_s: float | None = None, displacements: bool = True,
                   max_bridge_s: float = MAX_BRIDGE_S) -> GtsamPeerResult:
    """Run the GTSAM fixed-lag smoother over a recording (module docstring).

    t (n,) s strictly increasing; obs (n, m, 2) metres, NaN = missing; offsets (m, 2)
    antenna body positions relative to the configuration's CG; params : the same
    :class:`PoseFilterParams` as the EKF (limits, noise levels, no-slip point; ``reverse``
    is not modelled: the twist's forward speed is free in sign). lag_s : smoother lag, s
    (default ``params.lag_s``). displacements : add the displacement factors (module
    docstring). max_bridge_s : longest time without a fix bridged by the motion prior, s
    (:data:`MAX_BRIDGE_S`); a longer outage, or an update GTSAM rejects (an indeterminate
    system), starts a new segment (``segments``, ``notes``). Raises ImportError without
    gtsam, :class:`GtsamPeerError` (one line) when GTSAM fails to start a segment.
    """
    gtsam = _import_gtsam()
    tt, obs, off = _check_run_args(t, obs, offsets, params)
    # limits, noise and no-slip point estimated from the data where None (as the EKF)
    params = params.resolve(tt, obs, off)
    lag = check_real(params.lag_s if lag_s is None else lag_s, "lag_s", lo=0.0)
    bridge = check_real(max_bridge_s, "max_bridge_s", lo=0.0, lo_open=True)
    run = _PeerRun(gtsam, tt, obs, off, params, lag, displacements, bridge)
    for k in range(tt.size):
        run.step(k)
    run.flush()
    causal, fixed = run.causal, run.fixed
    causal[:, 2] = wrap_angle(causal[:, 2])
    fixed[:, 2] = wrap_angle(fixed[:, 2])
    return GtsamPeerResult(causal=causal, fixed_lag=fixed, status=run.status.astype(str),
                           update_s=run.spent, cg_offset=-run.ns, segments=run.segments,
                           notes=tuple(run.notes), update_cpu_s=run.spent_cpu)


class _PeerRun:
    """The peer's loop state: one smoother per segment (module docstring; a segment ends
    with an outage longer than the bridge or a failed update)."""

    def __init__(self, gtsam, tt, obs, off, params, lag, displacements, bridge):
        self.g, self.tt, self.obs, self.params = gtsam, tt, obs, params
        self.lag, self.displacements, self.bridge = lag, displacements, bridge
        n = tt.size
        self.ns = np.asarray(params.no_slip_point_m, dtype=float)
        self.r_m = off - self.ns
        sigma_abs, sigma_step = params.sigma_abs_m, params.sigma_step_m
        self.dt_med = float(np.median(np.diff(tt))) if n > 1 else 1.0
        qa = (0.5 * params.max_accel_mps2) ** 2 * self.dt_med
        qy = (0.5 * params.max_yaw_accel_radps2) ** 2 * self.dt_med
        self.qc = np.array([qa, NHC_SIGMA_MPS ** 2 / self.dt_med, qy])

        def robust(sd: float):
            return gtsam.noiseModel.Robust.Create(
                gtsam.noiseModel.mEstimator.Huber.Create(HUBER_K),
                gtsam.noiseModel.Isotropic.Sigma(2, sd))

        self.huber, self.step_noise = robust(sigma_abs), robust(sigma_step)
        self.nhc = gtsam.noiseModel.Diagonal.Sigmas(np.array([1e6, NHC_SIGMA_MPS, 1e6]))
        self.causal = np.full((n, NX), np.nan)
        self.fixed = np.full((n, NX), np.nan)
        self.status = np.full(n, "", dtype=object)
        self.present = np.isfinite(obs[..., 0])
        self.starter = FilterStart(tt, obs, self.r_m, sigma_abs, params)
        # GTSAM objects (untyped); None outside a segment
        self.smoother: Any = None
        self.est: Any = None
        self.pose: Any = None
        self.twist: Any = None
        self.start = self.last = self.last_fix = -1
        self.pending: list[int] = []     # epochs whose fixed-lag estimate is not final yet
        self.spent = 0.0
        self.spent_cpu = 0.0
        self.segments = 0
        self.notes: list[str] = []

    def X(self, k):
        return self.g.symbol("x", k)

    def V(self, k):
        return self.g.symbol("v", k)

    def state_of(self, k):
        p = self.est.atPose2(self.X(k))
        w = self.est.atVector(self.V(k))
        return [p.x(), p.y(), p.theta(), w[0], np.nan, w[2]]

    def flush(self) -> None:
        """Final fixed-lag estimates of the pending epochs (end of a segment or the run)."""
        if self.est is not None:
            for j in self.pending:
                self.fixed[j] = self.state_of(j)
        self.pending = []

    def end_segment(self, k: int, note: str | None = None) -> None:
        self.flush()
        self.smoother = self.est = None
        self.starter.reset()
        if note:
            self.notes.append(f"t = {self.tt[k]:.6g} s (epoch {k}): {note}")

    def step(self, k: int) -> None:
        g, tt = self.g, self.tt
        ik = np.flatnonzero(self.present[k])
        if self.smoother is not None and tt[k] - tt[self.last_fix] > self.bridge:
            gap = tt[k] - tt[self.last_fix]
            self.end_segment(k, f"no fix for {gap:.3g} s (> max_bridge_s = "
                                f"{self.bridge:g} s): new segment from the data")
        if self.smoother is None:
            self.status[k], got = self.starter.wait(k)
            if got is None:
                return
            graph, values, stamps = self.begin(k, *got)
        else:
            graph, values, stamps = g.NonlinearFactorGraph(), g.Values(), \
                g.FixedLagSmootherKeyTimestampMap()
            j = self.last
            self.pose = self.pose.compose(g.Pose2.Expmap(self.twist * (tt[k] - tt[j])))
            graph.add(g.WnoaMotionFactorPose2(g.StateData(self.X(j), self.V(j), tt[j]),
                                              g.StateData(self.X(k), self.V(k), tt[k]),
                                              self.qc))
        self.add_measurements(graph, k, ik)
        values.insert(self.X(k), self.pose)
        values.insert(self.V(k), self.twist)
        stamps.insert((self.X(k), tt[k]))
        stamps.insert((self.V(k), tt[k]))
        t0, c0 = time.perf_counter(), time.process_time()
        try:
            self.smoother.update(graph, values, stamps)
            est = self.smoother.calculateEstimate()
        except RuntimeError as exc:
            self.spent += time.perf_counter() - t0
            self.spent_cpu += time.process_time() - c0
            if k == self.start:
                raise GtsamPeerError(f"gtsam_peer: GTSAM failed to start at t = {tt[k]:.6g} s "
                                     f"(epoch {k}): {_one_line(exc)}") from None
            self.end_segment(k, f"GTSAM: {_one_line(exc)}; new segment from the data")
            self.status[k] = "reset"
            return
        self.spent += time.perf_counter() - t0
        self.spent_cpu += time.process_time() - c0
        self.est = est
        self.causal[k] = self.state_of(k)
        self.pose, self.twist = est.atPose2(self.X(k)), est.atVector(self.V(k))
        self.status[k] = "ok" if ik.size else "predicted"
        self.last = k
        if ik.size:
            self.last_fix = k
        self.pending.append(k)
        nxt = tt[k + 1] if k + 1 < tt.size else math.inf
        while self.pending and nxt > tt[self.pending[0]] + self.lag * (1 + 1e-12) + 1e-12:
            j = self.pending.pop(0)
            self.fixed[j] = self.state_of(j)

    def begin(self, k: int, x0: np.ndarray, P0: np.ndarray):
        """A new segment at epoch k from the start state (x0, P0): the smoother and the
        priors."""
        g = self.g
        params_isam = g.ISAM2Params()
        params_isam.setRelinearizeThreshold(RELINEARIZE_THRESHOLD)
        params_isam.relinearizeSkip = 1
        self.smoother = g.IncrementalFixedLagSmoother(self.lag + 1.5 * self.dt_med, params_isam)
        self.segments += 1
        self.start = self.last_fix = k
        self.pose = g.Pose2(x0[0], x0[1], x0[2])
        self.twist = np.array([x0[V], 0.0, x0[OMEGA]])
        graph, values = g.NonlinearFactorGraph(), g.Values()
        stamps = g.FixedLagSmootherKeyTimestampMap()
        graph.add(g.PriorFactorPose2(self.X(k), self.pose,
                                     g.noiseModel.Gaussian.Covariance(P0[:3, :3])))
        graph.add(g.PriorFactorVector(self.V(k), self.twist, g.noiseModel.Diagonal.Sigmas(
            np.sqrt([P0[V, V], NHC_SIGMA_MPS ** 2, P0[OMEGA, OMEGA]]))))
        return graph, values, stamps

    def add_measurements(self, graph, k: int, ik: np.ndarray) -> None:
        """The NHC prior, the lever-arm fixes and (after the segment's first epoch, from a
        consecutive epoch in the graph) the displacements of epoch k."""
        g, obs = self.g, self.obs
        graph.add(g.PriorFactorVector(self.V(k), np.zeros(3), self.nhc))
        for i in ik:
            graph.add(g.KnownLandmarkFactorPose2(self.X(k), obs[k, i], self.r_m[i],
                                                 self.huber))
            if (self.displacements and k > self.start and self.last == k - 1
                    and np.isfinite(obs[k - 1, i, 0])):
                graph.add(_displacement_factor(g, self.step_noise, self.X(k - 1), self.X(k),
                                               self.r_m[i], obs[k, i] - obs[k - 1, i]))
