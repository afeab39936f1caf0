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
from dataclasses import dataclass

import numpy as np

from estimator._checks import check_real
from estimator.configuration import SensorConfig
from estimator.memo import TrackCache, freeze, memo_get
from estimator.orientation import wrap_angle
from estimator.pose_filter import (
    ENGINES,
    NX,
    YAW,
    PoseFilterParams,
    PoseFilterResult,
    V,
    memo_pose_filter,
    pass_key,
    run_pose_filter,
)

__all__ = ["SmoothedStates", "fixed_lag_smooth", "memo_smoothed_states", "rts_smooth",
           "smoothed_heading", "warm_kernels"]


@dataclass(frozen=True)
class SmoothedStates:
    """Smoothed states (n, 6) of the no-slip point ``(px, py, yaw, v, a, omega)``
    (:mod:`estimator.pose_filter`) and, for the RTS smoother, their covariances (n, 6, 6)
    (None for the fixed-lag smoother); NaN where the filter was not running."""

    states: np.ndarray
    covariances: np.ndarray | None


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
    (shapes and units there), with ``params.reverse``. ``covariances`` (RTS only): return
    (states, covariances (n, 6, 6)). The same numbers as the direct calls;
    the RTS states serve the smoother row at every window and the smoothed heading of the
    lag correction. The arrays may be shared, so they are read-only."""
    lag = None if lag_s is None else check_real(lag_s, "lag_s", lo=0.0)
    if covariances and lag is not None:
        raise ValueError(f"covariances: only the RTS smoother (lag_s None) has them, got "
                         f"lag_s={lag_s!r}")

    def compute() -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        res = memo_pose_filter(t, obs, offsets, params, cache)
        rev = res.params.reverse if res.params is not None else params.reverse
        if lag is None:
            sm = rts_smooth(res, rev, covariances=covariances)
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
    """Compile the compiled engines' kernels (forward pass and RTS recursion; first use
    after a checkout, ~20 s CPU on the 2-core machine) or load them from numba's cache
    (~0.5 s), on a 6-epoch recording. A sweep's workers call it while warming up one at a
    time, so the first compiles and writes the cache and the others load it."""
    off = np.array([[0.5, 0.25], [0.5, -0.25], [-0.5, 0.0]])
    t = np.arange(6.0)
    obs = np.c_[t, np.zeros(6)][:, None, :] + off[None]
    rts_smooth(run_pose_filter(t, obs, off, PoseFilterParams(
        sigma_abs_m=0.01, sigma_step_m=0.014, max_accel_mps2=1.0, max_yaw_accel_radps2=1.0,
        max_turn_rate_radps=1.0, max_lateral_accel_mps2=1.0, max_speed_mps=10.0,
        no_slip_point_m=(0.0, 0.0), travel_offset_rad=0.0)))
