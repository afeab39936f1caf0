"""Smoothers on the pose filter: full-batch Rauch-Tung-Striebel and fixed-lag.

Both run backwards over the forward pass of :func:`estimator.pose_filter.run_pose_filter`.
That filter keeps the previous epoch's state beside the current one (stochastic cloning),
so after each update it holds the joint Gaussian of ``(x_k, x_{k-1})`` given the data up to
k: the current estimate ``x_{k|k}``, ``P_{k|k}``, the re-estimated previous state
``x_{k-1|k}``, ``P_{k-1|k}`` and their cross-covariance ``B_k = cov(x_k, x_{k-1})``. The
measurements after k do not involve ``x_{k-1}`` once ``x_k`` is given (a displacement
links only consecutive epochs), so the smoothing recursion (the RTS recursion, Rauch, Tung
and Striebel 1965; Saerkkae, *Bayesian Filtering and Smoothing*, 2013, Section 8.2, written
with the one-step smoothed quantities) is

    C_k   = B_{k+1}^T P_{k+1|k+1}^-1
    x_k^s = x_{k|k+1} + C_k (x_{k+1}^s - x_{k+1|k+1})        (heading difference wrapped)
    P_k^s = P_{k|k+1} + C_k (P_{k+1}^s - P_{k+1|k+1}) C_k^T

(for a filter whose measurements each involve one epoch this is the textbook RTS
smoother; tested against FilterPy's ``rts_smoother``).

- :func:`rts_smooth`: every epoch smoothed with all the data of its segment (offline).
- :func:`iterated_rts_smooth`: the iterated extended RTS smoother (Gauss-Newton on the
  whole trajectory, Bell 1994): the forward pass re-run with its Jacobians and robust
  weights at the previous smoothed states, then smoothed again (technique "ekf_ieks").
- :func:`fixed_lag_smooth`: the estimate of epoch k using the data up to ``t_k + lag_s``,
  available ``lag_s`` seconds after the fact (on-line with a latency): the same recursion
  started from the filtered state at the lag's end (exact for a linear-Gaussian model; here
  the extended, linearised version, as the RTS smoother).

A segment is a stretch between filter (re)starts and flip corrections
(``PoseFilterResult.segment_start``); no smoother crosses its boundary. Epochs the filter
predicted through without data (an outage, status ``"predicted"``) are inside a segment and
smoothed like any other (the recursion carries the later data back across them); a row
without output (NaN: a lost track, or before the start) ends the stretch before it, which is
smoothed with its own data, and the smoothing resumes at the filter's restart (issues 23,
25). For a platform
without reverse (``reverse=False``) a smoothed speed below 0 is set to 0, the filter's own
constraint. :func:`smoothed_heading` is the one-call version for other estimators (e.g. the
lag correction of :mod:`estimator.lag` with a smoothed heading).
"""

from __future__ import annotations

import math
from contextlib import suppress
from dataclasses import dataclass, replace

import numpy as np

from estimator._checks import check_int, check_real
from estimator.configuration import SensorConfig
from estimator.memo import TrackCache, freeze, memo_get
from estimator.orientation import wrap_angle
from estimator.pose_filter import _CW as _PF_CW
from estimator.pose_filter import _HORNER_ARRAY as _PF_HORNER
from estimator.pose_filter import (
    ENGINES,
    INIT_MOTION_SIGMAS,
    MAX_SMOOTHER_ITERATIONS,
    NX,
    YAW,
    PoseFilterParams,
    PoseFilterResult,
    V,
    _bound_after_standstill_gap,
    _bound_yaw_rate,
    _check_run_args,
    _fill_measurements,
    _hold_state,
    _kernel_par,
    _outputs,
    _Pattern,
    _project_limits,
    _Setup,
    _setup,
    _standstill_hold,
    _wrap_array,
    memo_pose_filter,
    pass_key,
    run_pose_filter,
)
from estimator.pose_filter import _kalman_update as _pf_kalman_update
from estimator.pose_filter import _predict as _pf_predict

__all__ = ["HUBER_K", "IEKS_ITERATIONS", "ITERATION_TOL_RAD", "SmoothedStates", "fixed_lag_smooth",
           "iterated_rts_smooth", "memo_smoothed_states", "robust_variances", "rts_smooth",
           "smoothed_heading", "warm_kernels"]


@dataclass(frozen=True)
class SmoothedStates:
    """Smoothed states (n, 6) of the no-slip point ``(px, py, yaw, v, a, omega)``
    (:mod:`estimator.pose_filter`) and, for the RTS smoother, their covariances (n, 6, 6)
    (None for the fixed-lag smoother); NaN where the filter was not running.
    ``iterations``: Gauss-Newton passes of :func:`iterated_rts_smooth` (0: linearised once,
    about the filter)."""

    states: np.ndarray
    covariances: np.ndarray | None
    iterations: int = 0


def _gains(res: PoseFilterResult) -> tuple[np.ndarray, np.ndarray]:
    """Smoother gains C (n, 6, 6) (row k: from k+1 back to k) and a mask (n,) of the rows
    with a valid gain: k and k+1 both filtered (finite), in the same running segment, with
    the clone of k at k+1 and a finite gain. Any other row ends a stretch: the smoothers
    never carry a NaN (a lost track, a row without output) back into earlier rows."""
    n, nx = res.states.shape
    ok = np.zeros(n, dtype=bool)
    if n > 1:
        ok[:-1] = (np.isfinite(res.states[:-1, 0]) & np.isfinite(res.states[1:, 0])
                   & np.isfinite(res.prev_states[1:, 0]) & ~res.segment_start[1:])
    C = np.full((n, nx, nx), np.nan)
    k = np.flatnonzero(ok)
    if k.size:
        # C = B^T P^-1 with the symmetric P = P_{k+1|k+1}: C^T = P^-1 B
        Ct = _solve(res.covariances[k + 1], res.cross_covariances[k + 1])
        C[k] = Ct.transpose(0, 2, 1)
        ok[k] = np.isfinite(Ct).all(axis=(1, 2))
    return C, ok


def _solve(P: np.ndarray, B: np.ndarray) -> np.ndarray:
    """P^-1 B for batches (N, 6, 6); a singular or non-finite P gives a NaN row (that gain
    is then invalid) instead of failing the batch."""
    try:
        return np.linalg.solve(P, B)
    except np.linalg.LinAlgError:
        out = np.full(B.shape, np.nan)
        for i in range(P.shape[0]):
            with suppress(np.linalg.LinAlgError):
                out[i] = np.linalg.solve(P[i], B[i])
        return out


def _step(xf: np.ndarray, C: np.ndarray, xs_next: np.ndarray, xp_next: np.ndarray
          ) -> np.ndarray:
    """x_{k|k+1} + C (x_s' - x_{k+1|k+1}) for a batch (N, 6), the heading difference
    wrapped (xf: the one-step smoothed states, xp_next: the filtered next states)."""
    d = xs_next - xp_next
    d[:, YAW] = wrap_angle(d[:, YAW])
    out = xf + np.einsum("nij,nj->ni", C, d)
    out[:, YAW] = wrap_angle(out[:, YAW])
    return out


def _constrain(X: np.ndarray, reverse: bool) -> np.ndarray:
    if not reverse:
        X[:, V] = np.where(X[:, V] < 0, 0.0, X[:, V])
    return X


def rts_smooth(res: PoseFilterResult, reverse: bool = False, covariances: bool = True, *,
               engine: str = "numba") -> SmoothedStates:
    """Full-batch extended RTS smoother over a filter pass (module docstring).

    res : the forward pass (:func:`estimator.pose_filter.run_pose_filter`).
    reverse : the filter's ``params.reverse`` (False: smoothed speeds are kept >= 0).
    covariances : also smooth the covariances (False: states only, a third of the time).
    engine : "numba" (the recursion compiled, :func:`estimator.pose_filter_kernel.rts_kernel`)
        or "numpy" (the reference loop; the same operations per element, tested to 1e-12).
    Returns :class:`SmoothedStates` with states (n, 6) and covariances (n, 6, 6) or None.
    """
    if not isinstance(res, PoseFilterResult):
        raise TypeError(f"res: expected a PoseFilterResult, got {type(res).__name__}")
    if engine not in ENGINES:
        raise ValueError(f"engine: must be one of {ENGINES}, got {engine!r}")
    C, ok = _gains(res)
    Xs = res.states.copy()
    Ps = res.covariances.copy() if covariances else None
    if engine == "numba":
        from estimator.pose_filter_kernel import rts_kernel

        rts_kernel(np.flatnonzero(ok)[::-1].copy(), C, res.states, res.prev_states,
                   res.covariances, res.prev_covariances, Xs,
                   Ps if Ps is not None else np.empty((0, NX, NX)), covariances)
        return SmoothedStates(states=_constrain(Xs, reverse), covariances=Ps)
    for k in np.flatnonzero(ok)[::-1]:
        d = Xs[k + 1] - res.states[k + 1]
        d[YAW] = _wrap1(d[YAW])
        xs = res.prev_states[k + 1] + C[k] @ d
        xs[YAW] = _wrap1(xs[YAW])
        Xs[k] = xs
        if Ps is not None:
            Pk = res.prev_covariances[k + 1] + C[k] @ (Ps[k + 1] - res.covariances[k + 1]) @ C[k].T
            Ps[k] = 0.5 * (Pk + Pk.T)
    return SmoothedStates(states=_constrain(Xs, reverse), covariances=Ps)


def _wrap1(a: float) -> float:
    """One angle to (-pi, pi] (scalar :func:`estimator.orientation.wrap_angle`, which
    returns an angle already in range unchanged: checked here first, without numpy)."""
    a = float(a)
    if -math.pi < a <= math.pi:
        return a
    return float(wrap_angle(a))


def fixed_lag_smooth(res: PoseFilterResult, t: np.ndarray, lag_s: float,
                     reverse: bool = False) -> SmoothedStates:
    """Fixed-lag smoother: each epoch k estimated from the data up to ``t_k + lag_s``.

    res : the forward pass; t : (n,) s, its times; lag_s : latency >= 0, s (0 = the filter).
    reverse : the filter's ``params.reverse``. For every k the RTS recursion runs back from
    the filtered state at the last epoch of k's segment within the lag, all k at once (one
    batched step per sample of lag). Returns :class:`SmoothedStates` (covariances None).
    """
    if not isinstance(res, PoseFilterResult):
        raise TypeError(f"res: expected a PoseFilterResult, got {type(res).__name__}")
    lag = check_real(lag_s, "lag_s", lo=0.0)
    tt = np.asarray(t, dtype=float)
    n = res.states.shape[0]
    if tt.shape != (n,):
        raise ValueError(f"t: expected shape ({n},), got {tt.shape}")
    C, ok = _gains(res)
    # end of each row's smoothing window: the last j >= k with t_j <= t_k + lag reachable
    # from k through valid gains (same segment)
    reach = np.arange(n)
    for k in range(n - 2, -1, -1):  # furthest row linked to k by valid gains
        if ok[k]:
            reach[k] = reach[k + 1]
    horizon = np.searchsorted(tt, tt + lag * (1 + 1e-12) + 1e-12, side="right") - 1
    end = np.minimum(reach, horizon)
    Xs = res.states.copy()
    cur = res.states[end].copy()                 # running estimate of each row's window
    j = end.copy()
    active = np.flatnonzero(j > np.arange(n))
    while active.size:
        jj = j[active] - 1
        cur[active] = _step(res.prev_states[jj + 1], C[jj], cur[active], res.states[jj + 1])
        j[active] = jj
        active = active[jj > active]
    Xs = np.where(np.isfinite(res.states[:, :1]), cur, np.nan)
    return SmoothedStates(states=_constrain(Xs, reverse), covariances=None)


def memo_smoothed_states(t: np.ndarray, obs: np.ndarray, offsets: np.ndarray,
                         params: PoseFilterParams, lag_s: float | None = None,
                         cache: TrackCache | None = None, *, covariances: bool = False
                         ) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Smoothed states (n, 6) of a recording through ``cache.smoothed``
    (:class:`estimator.memo.TrackCache`; None: computed): the states of :func:`rts_smooth`
    (``lag_s`` None) or of :func:`fixed_lag_smooth` with latency ``lag_s`` (s), over
    :func:`estimator.pose_filter.memo_pose_filter` of (t, obs, offsets, params, cache)
    (shapes and units there), with ``params.reverse``; with ``params.smoother_iterations``
    > 0 the RTS states are :func:`iterated_rts_smooth`'s (the forward pass is the one of
    ``smoother_iterations=0``, shared). ``covariances`` (RTS only): return
    (states, covariances (n, 6, 6)). The same numbers as the direct calls;
    the RTS states serve the smoother row at every window and the smoothed heading of the
    lag correction. The arrays may be shared, so they are read-only."""
    lag = None if lag_s is None else check_real(lag_s, "lag_s", lo=0.0)
    if covariances and lag is not None:
        raise ValueError(f"covariances: only the RTS smoother (lag_s None) has them, got "
                         f"lag_s={lag_s!r}")

    def compute() -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        # the forward pass does not depend on the smoother's iterations: one pass for all
        its = params.smoother_iterations
        res = memo_pose_filter(t, obs, offsets, replace(params, smoother_iterations=0), cache)
        rev = res.params.reverse if res.params is not None else params.reverse
        if lag is None:
            sm = (iterated_rts_smooth(res, t, obs, offsets, its, covariances) if its
                  else rts_smooth(res, rev, covariances=covariances))
            if sm.covariances is not None:
                return freeze(sm.states), freeze(sm.covariances)
        else:
            sm = fixed_lag_smooth(res, np.asarray(t, dtype=float), lag, rev)
        return freeze(sm.states)

    return memo_get(cache, "smoothed",
                    lambda: (*pass_key(t, obs, offsets, params), lag, covariances), compute)


def smoothed_heading(t: np.ndarray, obs: np.ndarray, config: SensorConfig,
                     params: PoseFilterParams | None = None, lag_s: float | None = None,
                     *, cache: TrackCache | None = None) -> np.ndarray:
    """Smoothed heading of a recording, one value per epoch (rad, CCW from +x, (-pi, pi]).

    t (n,) s, obs (n, m, 2) metres (NaN = missing), config : the sensor configuration.
    params : filter parameters (default :class:`PoseFilterParams`: limits, noise levels
        and travel axis estimated from the data).
    lag_s : None = full RTS (every epoch from all the data); a number = fixed-lag.
    NaN before the filter starts (:mod:`estimator.pose_filter`). Meant as the heading input
    of other estimators, e.g. the lag correction (Section 3.4.2 of the dissertation uses the
    platform's orientation; a smoothed one removes most of its noise). ``cache``: a
    :class:`estimator.memo.TrackCache` for the forward pass and the smoothing
    (:func:`memo_smoothed_states`), so a heading of data the filter has already run on with
    that cache costs a look-up; None computes them.
    """
    if not isinstance(config, SensorConfig):
        raise TypeError(f"config: expected a SensorConfig, got {type(config).__name__}")
    cfg = config.planar()
    p = params if params is not None else PoseFilterParams()
    states = memo_smoothed_states(t, obs, cfg.body_positions - cfg.cg_body, p, lag_s, cache)
    assert isinstance(states, np.ndarray)            # covariances=False: the states alone
    return states[:, YAW].copy()


def warm_kernels() -> None:
    """Compile the compiled engines' kernels (forward pass, relinearised pass and RTS
    recursion; first use after a checkout, ~20 s CPU on the 2-core machine) or load them
    from numba's cache (~0.5 s), on a 6-epoch recording. A sweep's workers call it while
    warming up one at a time, so the first compiles and writes the cache and the others
    load it."""
    off = np.array([[0.5, 0.25], [0.5, -0.25], [-0.5, 0.0]])
    t = np.arange(6.0)
    obs = np.c_[t, np.zeros(6)][:, None, :] + off[None]
    res = run_pose_filter(t, obs, off, PoseFilterParams(
        sigma_abs_m=0.01, sigma_step_m=0.014, max_accel_mps2=1.0, max_yaw_accel_radps2=1.0,
        max_turn_rate_radps=1.0, max_lateral_accel_mps2=1.0, max_speed_mps=10.0,
        no_slip_point_m=(0.0, 0.0), travel_offset_rad=0.0))
    iterated_rts_smooth(res, t, obs, off, 1)      # the relinearised kernel and rts_kernel


# ----------------------------------------------------------------- iterated RTS (issue 25)
#: Huber threshold of the iterated smoother's measurement weights, in sd of a measurement's
#: whitened residual norm (Huber 1964: 95 % efficiency at the normal; the GTSAM peer's
#: ``HUBER_K``, so both minimise the same robust cost of the fixes and displacements).
HUBER_K = 1.345
#: Gauss-Newton passes of the iterated smoother technique ("ekf_ieks"): chosen on the thesis
#: paths and the issue-25 car (10 seeds each; README): one pass gives the thesis paths' gain,
#: the second helps the consumer-error car and changes the thesis paths by <= 0.004 deg.
IEKS_ITERATIONS = 2
#: The iterated smoother stops once no smoothed heading moved by more than this between two
#: iterations, rad (0.006 deg: 5 % of the smallest heading RMS the project reports, RTK car).
ITERATION_TOL_RAD = 1e-4


def robust_variances(e: np.ndarray, var: np.ndarray, gate: float
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Measurement variances (k,) reweighted at the linearisation point and the accepted
    mask (k,): e (k, 2) residuals (m) of the k measurements there, var (k,) their per-axis
    variances (m^2), gate the filter's chi-square(2) gate. With ``r^2 = |e|^2 / var``:
    rejected beyond the gate (the filter's test, now against the smoothed trajectory),
    Huber weight ``w = min(1, HUBER_K / r)`` inside it (iteratively reweighted least
    squares: the variance divided by w)."""
    r2 = (e * e).sum(1) / var
    w = np.where(r2 <= HUBER_K * HUBER_K, 1.0, HUBER_K / np.sqrt(np.maximum(r2, 1e-300)))
    return var / w, r2 <= gate


def _relinearised_pass(su: _Setup, res: PoseFilterResult, Xb: np.ndarray) -> tuple:
    """The forward pass again, every Jacobian and weight at the trajectory Xb (n, 6) (travel
    frame: heading + delta) instead of at the filter's own estimates (the reference of
    :func:`estimator.pose_filter_kernel.relinearised_kernel`). Rows the first pass started
    (or restarted, flipped, re-initialised) keep its state; elsewhere row k is predicted
    from row k-1 by the CTRA motion linearised at Xb[k-1] and updated once by epoch k's
    fixes and displacements linearised at (Xb[k], Xb[k-1]) (:func:`robust_variances`), with
    the first pass's standstill hold, yaw-rate bound and limits. Returns the output arrays
    (X, PP, XC, PC, PX_) of :func:`estimator.pose_filter._outputs`, travel frame."""
    X, PP, XC, PC, PX_ = _outputs(su.tt.size)[:5]
    X0 = res.states.copy()
    X0[:, YAW] = _wrap_array(X0[:, YAW] + su.delta)
    eye = np.eye(NX)
    for k in np.flatnonzero(np.isfinite(X0[:, 0])).tolist():
        if res.segment_start[k] or not (np.isfinite(res.prev_states[k, 0])
                                         and np.isfinite(X[k - 1, 0])):
            X[k], PP[k] = X0[k], res.covariances[k]
            continue
        x, P = X[k - 1].copy(), PP[k - 1].copy()
        dt = float(su.tt[k] - su.tt[k - 1])
        _bound_after_standstill_gap(P, PP, su.starter, k, su.kappa)   # as the first pass
        # the first pass's standstill decision (on its own row k-1, as it took it): part
        # of the model the iterations minimise, not re-decided on the iterate
        hold = _standstill_hold(X0[k - 1].copy(), res.covariances[k - 1].copy(), su.starter, k)
        if hold and _moving_off(su, k, X0[k - 1, YAW], res.covariances[k - 1][YAW, YAW]):
            hold = False       # hindsight: the platform pulled away here (_moving_off)
        if hold:
            _hold_state(x, P)
        qy = _bound_yaw_rate(x, P, dt, su.kappa, su.om_max,
                             0.0 if hold else su.qy * su.dt_med / dt)
        qa = su.qa * dt / su.dt_med
        fb, _, F = _pf_predict(Xb[k - 1], eye, dt, qa, qy)     # f(xb) and F (F @ I)
        _, Pp, FP = _pf_predict(Xb[k - 1], P, dt, qa, qy)
        d = x - Xb[k - 1]
        d[YAW] = _wrap1(d[YAW])
        y = np.concatenate((fb + F @ d, x))
        Y = np.block([[Pp, FP], [FP.T, P]])
        y, Y = _relinearised_update(su, k, y, Y, np.concatenate((Xb[k], Xb[k - 1])), hold)
        x, P = y[:NX].copy(), Y[:NX, :NX].copy()
        XC[k], PC[k], PX_[k] = y[NX:], Y[NX:, NX:], Y[:NX, NX:]
        _project_limits(su, x)
        X[k], PP[k] = x, P
    return X, PP, XC, PC, PX_


def _median_step(su: _Setup, j: int, c: float, s: float) -> tuple[float, float] | None:
    """Median over the antennas reporting at j-1 and j of their displacement to epoch j,
    along the heading ``(c, s) = (cos, sin)`` and across it (m); None without such an
    antenna."""
    pr = su.present
    both = pr[j] & pr[j - 1]
    if not both.any():
        return None
    d = su.obs[j, both] - su.obs[j - 1, both]
    return (float(np.median(d[:, 0] * c + d[:, 1] * s)),
            float(np.median(d[:, 1] * c - d[:, 0] * s)))


def _moving_off(su: _Setup, k: int, yaw: float, yaw_var: float) -> bool:
    """The iterated smoother's hindsight on a standstill hold of the interval (k-1, k): the
    platform pulled away there. The first pass decides the hold causally, on the state at
    k-1; a car that starts off while turning is then held at a yaw rate of 0 for an epoch
    or two, and the smoother, whose hold links the whole stop to those epochs with no yaw
    noise, carries that conflict back over the stop (issue 25, `common_plus_model` drive
    18: causal filter 1.1 deg through the 150 s stop, iterated RTS 8.6 deg there). A
    causal test cannot tell a start from a metre-level jump that every antenna shares
    (ending the hold on a moving displacement gave more flips, README). One epoch of
    hindsight can: a start is motion that goes on, along the heading (no-slip), while a
    shared jump is one step in any direction (a spike returns, a step stays).

    True when the displacements to k and to k+1 both show motion along the heading
    ``yaw`` (travel frame, the first pass's state at k-1, variance ``yaw_var``), in the same
    direction: per epoch j the median displacement over the antennas at j-1 and j, ``a``
    along the heading and ``l`` across it, moves (``a^2 + l^2`` beyond
    :data:`INIT_MOTION_SIGMAS` ``sigma_step``, the start's motion test) with ``|l| <= thr +
    |a| sin(3 sd_yaw + kappa s) + lever kappa |a|``: the heading's 3 sd plus the chord's
    turn on an arc of the platform's curvature limit kappa (``s`` the arc length to the
    chord's middle, ``|a_k| / 2`` and ``|a_k| + |a_(k+1)| / 2``), and the antennas' own
    sideways motion as the platform turns by at most ``kappa |a|`` in the step (``lever``
    the longest antenna lever arm from the no-slip point; antennas 1.3 m ahead of the rear
    axle move 0.4 m sideways in a 17 deg turn); without a curvature limit any direction
    counts.
    The first pass's state, not the iterate: the decision is the same in every pass."""
    if k + 1 >= su.tt.size:
        return False
    c, s = math.cos(yaw), math.sin(yaw)
    thr = INIT_MOTION_SIGMAS * math.sqrt(su.vs)
    sd3 = 3.0 * math.sqrt(max(yaw_var, 0.0))
    arc, sign = 0.0, 0.0
    for j in (k, k + 1):
        st = _median_step(su, j, c, s)
        if st is None:
            return False
        a, lat = st
        if a * a + lat * lat <= thr * thr or a * sign < 0.0:
            return False
        if math.isfinite(su.kappa):
            ang = min(sd3 + su.kappa * (arc + 0.5 * abs(a)), 0.5 * math.pi)
            turn = min(su.kappa * abs(a), 0.5 * math.pi)
            if abs(lat) > thr + abs(a) * math.sin(ang) + su.lever * turn:
                return False
        arc, sign = arc + abs(a), a
    return True


def _relinearised_update(su: _Setup, k: int, y: np.ndarray, Y: np.ndarray, yb: np.ndarray,
                         hold: bool) -> tuple[np.ndarray, np.ndarray]:
    """Epoch k's update of the stacked prior (y, Y) (12,), (12, 12) with its measurements
    linearised at yb (12,): one Gauss-Newton step, weights of :func:`robust_variances`."""
    pat = _Pattern(su.present[k], su.present[k - 1], su.r_m, su.va, su.vs)
    ik, js = pat.ik, pat.js
    if not ik.size:
        return y, Y
    z = su.obs[k, ik]
    if js.size:
        z = np.concatenate((z, su.obs[k, js] - su.obs[k - 1, js]))
    h, H = _fill_measurements(yb, pat.ax, pat.ay, pat.dx, pat.dy, pat.H0.copy())
    if hold:
        H[:ik.size, :, YAW] = 0.0
    e = z - h
    d = y - yb
    d[YAW], d[NX + YAW] = _wrap1(d[YAW]), _wrap1(d[NX + YAW])
    var, acc = robust_variances(e, pat.var, su.gate)
    if not acc.any():
        return y, Y
    try:
        y1, Y1, _ = _pf_kalman_update(y, Y, e - H @ d, H, np.repeat(var, 2), math.inf,
                                      accept=acc, cross=pat.cross)
    except np.linalg.LinAlgError:       # numerically singular: the prior (as the kernel)
        return y, Y
    y1 = y1.copy()
    y1[YAW], y1[NX + YAW] = _wrap1(y1[YAW]), _wrap1(y1[NX + YAW])
    return y1, Y1


def iterated_rts_smooth(res: PoseFilterResult, t: np.ndarray, obs: np.ndarray,
                        offsets: np.ndarray, iterations: int | None = None,
                        covariances: bool = True, *, engine: str = "numba",
                        tol: float = ITERATION_TOL_RAD) -> SmoothedStates:
    """Iterated extended RTS smoother: Gauss-Newton on the whole trajectory (Bell 1994,
    "The iterated Kalman smoother as a Gauss-Newton method"; Saerkkae 2013, Section 8.x,
    the IEKS).

    :func:`rts_smooth` linearises once, about the filter's own estimates. Here each
    iteration re-runs the forward pass with the motion and measurement Jacobians evaluated
    at the previous iteration's smoothed states and smooths again
    (:func:`_relinearised_pass`, compiled:
    :func:`estimator.pose_filter_kernel.relinearised_kernel`); the measurement weights
    come from the residuals at those states (:func:`robust_variances`: the filter's gate,
    then Huber weights, iteratively reweighted). The first pass's segments, starts, flips,
    re-initialisations and NaN rows are kept; the causal filter ``res`` is not changed.

    res : the forward pass of :func:`estimator.pose_filter.run_pose_filter` on t (n,) s,
        obs (n, m, 2) m and offsets (m, 2) m (the same arrays), with its resolved params.
    iterations : Gauss-Newton passes, 0..MAX_SMOOTHER_ITERATIONS (None:
        ``res.params.smoother_iterations``; 0 = :func:`rts_smooth`); stops earlier once no
        smoothed heading moves by more than ``tol`` rad (:data:`ITERATION_TOL_RAD`).
    covariances, engine : as :func:`rts_smooth` (the two engines agree to rounding).
    Returns :class:`SmoothedStates` with the number of iterations run.
    """
    if not isinstance(res, PoseFilterResult):
        raise TypeError(f"res: expected a PoseFilterResult, got {type(res).__name__}")
    if res.params is None:
        raise ValueError("res: has no params (a pass of run_pose_filter carries them)")
    p = res.params
    its = p.smoother_iterations if iterations is None else check_int(
        iterations, "iterations", lo=0, hi=MAX_SMOOTHER_ITERATIONS)
    tol = check_real(tol, "tol", lo=0.0)
    sm = rts_smooth(res, p.reverse, covariances, engine=engine)
    if its == 0:
        return sm
    tt, o, off = _check_run_args(t, obs, offsets, p)
    if tt.size != res.states.shape[0]:
        raise ValueError(f"t: expected {res.states.shape[0]} epochs (the pass's), got "
                         f"{tt.size}")
    su = _setup(tt, o, off, p)
    done = 0
    while done < its:
        done += 1
        Xb = sm.states.copy()
        Xb[:, YAW] = _wrap_array(Xb[:, YAW] + su.delta)
        X, PP, XC, PC, PX_ = (_relinearised_pass(su, res, Xb) if engine == "numpy"
                              else _relinearised_kernel(su, res, Xb))
        for S_ in (X, XC):
            S_[:, YAW] = _wrap_array(S_[:, YAW] - su.delta)
        new = rts_smooth(replace(res, states=X, covariances=PP, prev_states=XC,
                                 prev_covariances=PC, cross_covariances=PX_),
                         p.reverse, covariances, engine=engine)
        dyaw = np.abs(wrap_angle(new.states[:, YAW] - sm.states[:, YAW]))
        sm = new
        if not np.nanmax(dyaw, initial=0.0) > tol:
            break
    return replace(sm, iterations=done)


def _relinearised_kernel(su: _Setup, res: PoseFilterResult, Xb: np.ndarray) -> tuple:
    """:func:`_relinearised_pass` compiled (same arguments and outputs)."""
    from estimator.pose_filter_kernel import relinearised_kernel

    st = su.starter
    st.fit_heading(0)                            # fills the starter's spread
    spread = st._spread if st._spread is not None else np.zeros(su.tt.size)
    X0 = res.states.copy()
    X0[:, YAW] = _wrap_array(X0[:, YAW] + su.delta)
    out = _outputs(su.tt.size)[:5]
    relinearised_kernel(su.tt, su.obs, su.present, np.ascontiguousarray(su.r_m), st.yaw,
                        st.cnt.astype(float), spread, _kernel_par(su), _PF_HORNER, _PF_CW,
                        HUBER_K, X0, np.ascontiguousarray(res.covariances),
                        np.ascontiguousarray(res.prev_states), res.segment_start, Xb, *out)
    return out
