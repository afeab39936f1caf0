"""Configuration-constrained window fit of sensor positions (dissertation Eq. 3.7 / 3.9).

Source: ``000_8f82f8df647bf685.txt`` (GPS dissertation), Section 3.1. For a window of ``s``
samples of ``m`` sensors, find sensor positions ``p_i`` (metres, world frame) minimizing

    Z = sum_{w in window} sum_i sum_a  w_{w,i,a} (o_{w,i,a} - p_{i,a})^2          (Eq. 3.9,
                                                                         3.12-3.14)
    s.t. a_ij - eps <= |p_i - p_j| <= a_ij + eps   for all i < j                (Eq. 3.6/3.7)

where ``o`` are the observations (NaN = missing: the sample simply drops out of the sum,
Section 3.4.1), ``w`` the weights (isotropic ``(s, m)`` or per axis ``(s, m, d)``, Huber gives
the latter, Eq. 3.12) and ``a_ij`` the configuration's distances.

The reduction every solver here uses (it is exact): for each sensor and axis,

    sum_w w_{w,a} (o_{w,a} - p_a)^2 = W_a (p_a - obar_a)^2 + sum_w w_{w,a} (o_{w,a} - obar_a)^2

with ``W_a = sum_w w_{w,a}`` and ``obar_a`` the weighted window mean. The last term does
not depend on ``p``, so the window fit is a fit to ``m`` weighted means: its cost is
independent of the window length ``s`` once the means are formed (:func:`window_means`,
or :func:`sliding_window_means` for every sliding window of a recording in O(n)).

Solvers (all return the proper-handed configuration, never its mirror image):

``"procrustes"``
    Closed-form weighted rigid fit (rotation, det = +1, and translation; no scaling) of the
    body-frame configuration to the per-sensor means, with per-sensor weight ``W_i``
    (Kabsch/Umeyama without scale). Distances are exact, so every constraint holds for any
    ``eps``; it ignores the slack the constraints allow. With per-axis weights the exact
    problem has no closed form; procrustes uses the per-axis weighted means and the
    isotropic per-sensor weight ``W_i = mean_a W_{i,a}`` (the weight of a sensor whose axis
    weights are equal is unchanged; a sensor with one axis of zero weight gets weight 0,
    because its mean is not a point). The reported objective is still the exact Eq. 3.12
    value at the fitted positions, and slsqp/ccp solve the exact anisotropic problem.
``"slsqp"``
    scipy SLSQP on Eq. 3.9 with analytic gradient and constraint Jacobian, the objective
    divided by the total weight and the variables centred on the window, started from the
    procrustes fit (or ``x0``). Result checked (feasibility, objective not worse than
    procrustes, handedness); on failure the procrustes fit is returned with a status saying
    why.
``"elastic"``
    The same problem by a batched feasible primal-dual interior-point method
    (:mod:`estimator.elastic`, :func:`estimator.elastic.elastic_batch`): every window of a track
    in one vectorized iteration, started from the procrustes fit (or ``x0`` when it is strictly
    inside every band), converged per window to ~1e-7 relative objective. Status "maxiter" when
    the iteration limit is reached first (the last, feasible iterate is returned).
``"ccp"``
    The same problem by the convex-concave procedure in cvxpy + Clarabel: upper bounds as
    second-order cones, lower bounds linearized at the current iterate (a restriction, so
    every iterate is feasible and the objective never increases). The cvxpy problem is built
    once per ``(m, d)`` with Parameters (DPP) and reused. Stops when an iteration improves
    the objective by less than ``CCP_RTOL`` = 1e-6 (relative); the subproblems use a band
    narrowed by ``CCP_MARGIN`` = 1e-8 m so solver round-off cannot leave the true band.

Single calls (issue 27): ``fit_window(..., solver="procrustes")`` takes a fast path that
makes the same checks as whole-array screens (missing samples NaN as a whole, present
coordinates within range, weights in range), forms the window sums and solves the d = 2
closed form: in 2-D one compiled call (:mod:`estimator.window_kernel`, numba; about 7 us
instead of 35 us for the numpy fast path and 240 us for the general path on a 10-epoch,
8-antenna window, ``python -m experiments.bench --only fit_window``; the first call of a
process loads the compiled code, ~0.6 s, and the very first compiles it, ~8 s, cached on
disk), in 3-D a handful of numpy calls and one 3x3 SVD (``FAST_2D_ENGINE = "numpy"`` runs
2-D windows through those too: the reference the kernel is tested against). Any input it
does not take as it is (a check that would fail, insufficient data, nearly collinear 3-D
sensors, a total weight below 1e-250) goes to the general path, so every message and
status is the general path's; the results agree with it to round-off (1e-12 m + 2 ulp of
the coordinate, objectives 1e-12 relative; tests/test_window.py, test_window_kernel.py).

Handedness: pairwise distances do not distinguish the configuration from its mirror image,
and with metre-level noise on a metre-sized platform the mirror often fits the data better
(../shared/notes/window-solvers.md). The iterative solvers therefore start from the
proper-handed procrustes fit, and a result whose best orthogonal fit to the body frame has
det = -1 is rejected ("fallback_mirrored"). ``mirror_objective`` reports the objective of
the best det = -1 rigid fit so the ambiguity of each window is visible.

Insufficient data: fewer than 2 sensors with data (d = 2), or fewer than 3 whose body
positions are not collinear (d = 3), leave the rotation undetermined; the fit reports
"insufficient_data" (positions from ``x0`` if given, else NaN) instead of guessing.

Sensors without data (dead, or missing for the whole window) stay in the problem (their
distance constraints still bind the others) with zero data cost; procrustes places them by
the rigid transform, slsqp/ccp hold them at their start by a vanishing proximal term
(``PROX_WEIGHT``), because Eq. 3.9 leaves them free inside the eps band.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from estimator._checks import check_array, check_int
from estimator.configuration import SensorConfig
from estimator.rigid_fit import (
    MAX_COORD_M,
    MAX_WEIGHT,
    PROX_WEIGHT,
    BatchFit,
    _check_eps,
    _geometry,
    _pairs,
    check_window_means,
    procrustes_batch,
)

__all__ = [
    "MAX_COORD_M",
    "MAX_WEIGHT",
    "SOLVERS",
    "STATUSES",
    "BatchFit",
    "CcpProblems",
    "WindowFit",
    "check_window_means",
    "fit_stationary",
    "fit_window",
    "procrustes_batch",
    "sliding_window_means",
    "window_means",
    "window_moments",
]

SOLVERS = ("procrustes", "slsqp", "ccp", "elastic")

#: Status vocabulary of :class:`WindowFit` / :class:`BatchFit`.
STATUSES = {
    "ok": "solver result accepted (feasible, objective not worse than procrustes, proper-handed)",
    "insufficient_data": "fewer than 2 observed sensors (d=2) or fewer than 3 non-collinear "
                         "ones (d=3): positions from x0 if given, else NaN",
    "fallback_infeasible": "solver result violated a distance by more than eps + tolerance; "
                           "procrustes fit returned",
    "fallback_objective": "solver result worse than the procrustes start; procrustes returned",
    "fallback_mirrored": "solver result was the mirror image of the configuration; "
                         "procrustes returned",
    "fallback_failed": "solver raised or returned no solution; procrustes returned",
    "maxiter": "elastic: iteration limit reached before convergence; the last iterate "
               "(feasible, objective not worse than the start) returned",
}


# ----------------------------------------------------------------------------- results
@dataclass(frozen=True)
class WindowFit:
    """Result of one window fit.

    positions : (m, d) metres, world frame, every sensor (also those without data).
    cg : (d,) centre of gravity from the CG members (Eq. 3.8).
    yaw : heading of the body +x axis, rad, CCW from world +x, in (-pi, pi].
    objective : Eq. 3.9 value Z (weighted squared residuals, m^2, not normalized) at
        ``positions``; exact for per-axis weights too.
    mirror_objective : Z of the best det = -1 rigid fit (how ambiguous the window was; if it
        is below ``objective`` the data alone prefer the mirror image).
    max_violation : max_ij | |p_i - p_j| - a_ij |, metres; the constraints hold iff it is
        <= eps. Procrustes gives ~1e-15.
    solver : the solver asked for. iterations : solver iterations (0 for procrustes).
    status : one of :data:`STATUSES`.
    """

    positions: np.ndarray
    cg: np.ndarray
    yaw: float
    objective: float
    mirror_objective: float
    max_violation: float
    solver: str
    iterations: int
    status: str


# ----------------------------------------------------------------------------- validation


def _check_obs(obs: Any, *, min_ndim: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Return (obs as float array, present mask (..., s, m)). NaN marks missing samples."""
    arr = check_array(obs, "obs", allow_nan=True, max_abs=MAX_COORD_M)
    if arr.ndim < min_ndim:
        raise ValueError(f"obs: expected shape (..., s, m, d), got shape {arr.shape}")
    if arr.shape[-1] not in (2, 3):
        raise ValueError(f"obs: last axis must be d = 2 or 3 coordinates, got shape {arr.shape}")
    nan = np.isnan(arr)
    missing = nan.any(axis=-1)
    if (missing != nan.all(axis=-1)).any():
        idx = tuple(int(v) for v in np.argwhere(missing != nan.all(axis=-1))[0])
        raise ValueError(
            f"obs: sample {idx} has some coordinates NaN and others not; a missing "
            f"observation must be NaN in every coordinate")
    return arr, ~missing


def _check_weights(weights: Any, obs_shape: tuple[int, ...]) -> np.ndarray:
    w = check_array(weights, "weights", max_abs=MAX_WEIGHT)
    if w.shape != obs_shape[:-1] and w.shape != obs_shape:
        raise ValueError(
            f"weights: expected shape {obs_shape[:-1]} (per sample and sensor) or {obs_shape} "
            f"(per axis) to match obs, got {w.shape}")
    if (w < 0).any():
        raise ValueError(f"weights: must be >= 0, found minimum {w.min()!r}")
    return w


def _axis_weights(obs: np.ndarray, present: np.ndarray, weights: Any | None) -> np.ndarray:
    """Per-axis weights (..., s, m, d), zero at missing samples."""
    if weights is None:
        w = present.astype(float)
        return np.broadcast_to(w[..., None], obs.shape)
    w = _check_weights(weights, obs.shape)
    if w.ndim == obs.ndim - 1:
        w = w[..., None]
    return np.where(present[..., None], w, 0.0) * np.ones(obs.shape[-1])


def _moments(obs: np.ndarray, present: np.ndarray, weights: Any | None
             ) -> tuple[np.ndarray, np.ndarray]:
    """Per-axis weighted means (..., m, d) (NaN where the axis weight is 0) and axis weights."""
    wa = _axis_weights(obs, present, weights)
    o = np.where(present[..., None], obs, 0.0)
    Wa = wa.sum(axis=-3)
    with np.errstate(invalid="ignore", divide="ignore"):
        means = (wa * o).sum(axis=-3) / Wa
    means = np.where(Wa > 0, means, np.nan)
    return means, Wa


def window_means(obs: Any, weights: Any | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Weighted per-sensor window means: the sufficient statistics of Eq. 3.9.

    obs : (..., s, m, d) metres, NaN = missing sample (drops out).
    weights : None (all 1), (..., s, m) isotropic, or (..., s, m, d) per axis; finite, >= 0.
    Returns ``means (..., m, d)`` (NaN where the sensor has zero weight) and
    ``sensor_weight (..., m)`` = total weight per sensor (0 where no data). With per-axis
    weights the means are per axis and ``sensor_weight`` is the mean of the axis weights
    (0 if any axis has zero weight); see the module docstring for why.
    """
    arr, present = _check_obs(obs)
    means, Wa = _moments(arr, present, weights)
    full = np.asarray((Wa > 0).all(axis=-1))
    sw = np.where(full, Wa.mean(axis=-1), 0.0)
    means = np.where(full[..., None], means, np.nan)
    return means, sw


def window_moments(obs: Any, weights: Any | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per-axis weighted window means and per-axis total weights: the exact sufficient
    statistics of Eq. 3.9 with per-axis weights (Eq. 3.12-3.14), the input of
    :func:`estimator.elastic.elastic_batch`.

    obs : (..., s, m, d) metres, NaN = missing sample. weights : None (all 1), (..., s, m) or
    (..., s, m, d), finite and >= 0. Returns ``means (..., m, d)`` (NaN where the axis weight
    is 0) and ``axis_weight (..., m, d)``; unlike :func:`window_means` nothing is reduced to
    one weight per sensor.
    """
    arr, present = _check_obs(obs)
    return _moments(arr, present, weights)


def sliding_window_means(obs: Any, window: int, weights: Any | None = None
                         ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`window_means` of every sliding window of ``window`` samples, in O(n).

    obs : (n, m, d) metres, NaN = missing; weights : None, (n, m) or (n, m, d).
    Returns ``means (n - window + 1, m, d)`` and ``sensor_weight (n - window + 1, m)``;
    row k is the window of samples k .. k + window - 1, i.e. the estimate at the window's
    last sample t = k + window - 1 (Section 3.4.1: estimates from t = s on). Uses cumulative
    sums of window-centred values, so the cost does not grow with the window; the round-off
    is about 1e-16 x n x (extent of the recording), e.g. 1e-10 m for 10^4 samples over 1 km.
    """
    arr, present = _check_obs(obs)
    if arr.ndim != 3:
        raise ValueError(f"obs: expected shape (n, m, d), got {arr.shape}")
    n = arr.shape[0]
    check_int(window, "window", 1, max(n, 1))
    if n == 0:
        raise ValueError("obs: no samples (n = 0): a window needs at least one")
    wa = _axis_weights(arr, present, weights)
    ref = arr[present].mean(axis=0) if present.any() else np.zeros(arr.shape[-1])
    o = np.where(present[..., None], arr - ref, 0.0)
    zero = np.zeros((1,) + arr.shape[1:])
    cw = np.concatenate([zero, np.cumsum(wa, axis=0)])
    cwo = np.concatenate([zero, np.cumsum(wa * o, axis=0)])
    Wa = cw[window:] - cw[:-window]
    S = cwo[window:] - cwo[:-window]
    # exact zero where no weight entered the window (cumsum differences can leave 1e-17)
    cnt = np.concatenate([zero, np.cumsum(wa > 0, axis=0)])
    has = (cnt[window:] - cnt[:-window]) > 0
    Wa = np.where(has, Wa, 0.0)
    full = np.asarray((Wa > 0).all(axis=-1))
    with np.errstate(invalid="ignore", divide="ignore"):
        means = np.where(full[..., None], S / Wa + ref, np.nan)
    sw = np.where(full, Wa.mean(axis=-1), 0.0)
    return means, sw


# ----------------------------------------------------------------------------- procrustes


def _mirror_fit_positions(means: np.ndarray, sw: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Positions of the best det = -1 rigid fit (weighted), one window: (m, d)."""
    Bm = B.copy()
    Bm[:, -1] = -Bm[:, -1]  # reflect the body; a proper fit of it is an improper fit of B
    valid = sw > 0
    Y0 = np.where(valid[:, None], means, 0.0)
    W = sw.sum()
    ybar = (sw @ Y0) / W
    bbar = (sw @ Bm) / W
    M = ((sw[:, None] * (Y0 - ybar)).T) @ (Bm - bbar)
    U, _, Vt = np.linalg.svd(M)
    D = np.ones(B.shape[1])
    D[-1] = np.sign(np.linalg.det(U @ Vt)) or 1.0
    R = (U * D) @ Vt
    return Bm @ R.T + (ybar - R @ bbar)


def _is_mirrored(positions: np.ndarray, B: np.ndarray) -> bool:
    """True if the best orthogonal fit of the body ``B`` onto ``positions`` is improper."""
    P = positions - positions.mean(axis=0)
    Bc = B - B.mean(axis=0)
    M = P.T @ Bc
    if B.shape[1] == 2:
        proper = math.hypot(M[0, 0] + M[1, 1], M[1, 0] - M[0, 1])
        improper = math.hypot(M[0, 0] - M[1, 1], M[0, 1] + M[1, 0])
        return improper > proper * (1.0 + 1e-9) + 1e-12  # equal for collinear layouts
    U, S, Vt = np.linalg.svd(M)
    return bool(np.linalg.det(U @ Vt) < 0 and S[-1] > 1e-12 * S[0])


# ----------------------------------------------------------------------------- helpers


def _max_violation(positions: np.ndarray, config: SensorConfig) -> float:
    g = _geometry(config)
    diff = positions[g.I] - positions[g.J]
    dist = np.sqrt((diff * diff).sum(axis=1))
    return float(np.max(np.abs(dist - g.a)))


def _objective(obs0: np.ndarray, wa: np.ndarray, positions: np.ndarray) -> float:
    """Exact Eq. 3.9/3.12 value: sum w (o - p)^2 over present samples (obs0 has 0 there)."""
    r = obs0 - positions
    return float(np.add.reduce(wa * r * r, axis=None))


def _check_x0(x0: Any, config: SensorConfig) -> np.ndarray | None:
    if x0 is None:
        return None
    return check_array(x0, "x0", shape=(config.m, config.d), max_abs=MAX_COORD_M)


def _result(positions_c: np.ndarray, centre: np.ndarray, config: SensorConfig,
            objective: float, mirror: float, solver: str, iterations: int, status: str,
            yaw: float | None = None) -> WindowFit:
    """Assemble a WindowFit from window-centred positions (distances and yaw are computed
    before adding the centre back, so UTM-sized coordinates cost no precision)."""
    if np.isfinite(positions_c).all():
        if yaw is None:
            yaw = _yaw_of(positions_c, config)
        viol = _max_violation(positions_c, config)
    else:
        yaw, viol = float("nan"), float("nan")
    positions = positions_c + centre
    cg = positions[_geometry(config).cg_mask].mean(axis=0)  # Eq. 3.8
    return WindowFit(positions=positions, cg=cg,
                     yaw=float(yaw), objective=float(objective), mirror_objective=float(mirror),
                     max_violation=viol, solver=solver, iterations=int(iterations),
                     status=status)


def _yaw_of(positions: np.ndarray, config: SensorConfig) -> float:
    """Heading of the best proper rigid fit of the body onto ``positions`` (unweighted)."""
    fit = procrustes_batch(positions[None], np.ones((1, config.m)), config)
    return float(fit.yaw[0])


# ----------------------------------------------------------------------------- one-window fast path
# fit_window(solver="procrustes") on an ordinary 2-D window: the same checks as the general
# path as a few whole-array reductions (one isnan, one magnitude and one weight min/max),
# the window moments in a handful of numpy calls and the d = 2 closed form in Python floats.
# Anything unusual (a check that would fail, insufficient data, d = 3, tiny total weight)
# returns None and the general path below decides, so its messages and statuses hold.

#: smallest total window weight the fast path takes: below it the weighted sums underflow
#: towards subnormals, and the general path's order of operations is kept instead
FAST_MIN_WEIGHT = 1e-250

#: types of eps the fast path takes as they are (others: the general path's check_real)
_FAST_REALS = (float, int, np.float64)


def _x0_ok(x0: Any, config: SensorConfig) -> bool:
    """Whether ``x0`` passes :func:`_check_x0` (procrustes uses it only without data)."""
    try:
        _check_x0(x0, config)
    except (TypeError, ValueError):
        return False
    return True


def _fast_obs(obs: Any, config: SensorConfig):
    """(obs as float (s, m, d), its NaN mask, present (s, m), window centre (d,)) if ``obs``
    passes every check of :func:`_check_obs` and fit_window's shape check and has a sample;
    else None.

    A sample is present where x is not NaN; its other coordinates must then be finite (the
    magnitude check on the present samples catches a NaN), so they are NaN only where x is,
    and the count of NaNs (d per missing sample) says they are NaN at every one: together
    the general path's half-NaN check.
    """
    try:
        arr = np.asarray(obs, dtype=float)
    except (TypeError, ValueError):
        return None
    d = config.d
    if arr.ndim != 3 or arr.shape[1:] != (config.m, d):
        return None
    nan = np.isnan(arr)
    present = ~nan[..., 0]
    sel = arr.reshape(-1, d)[present.ravel()]  # == arr[present], a little cheaper
    k = sel.shape[0]
    if k == 0 or not np.maximum.reduce(np.abs(sel), axis=None) <= MAX_COORD_M:
        return None  # no sample, or an inf, a NaN y or a coordinate beyond MAX_COORD_M
    if np.count_nonzero(nan) != d * (present.size - k):
        return None  # a sample with x NaN and y (or z) not
    return arr, nan, present, np.add.reduce(sel, axis=0) / k  # == arr[present].mean(0)


def _fast_weights(weights: Any, present: np.ndarray, d: int
                  ) -> np.ndarray | None | Literal[False]:
    """Weights zeroed at missing samples, (s, m) isotropic or (s, m, d) per axis (None in:
    None out), or False if they would fail :func:`_check_weights` (shape, NaN, inf, < 0,
    > MAX_WEIGHT)."""
    if weights is None:
        return None
    try:
        w = np.asarray(weights, dtype=float)
    except (TypeError, ValueError):
        return False
    if w.shape == present.shape:
        mask = present
    elif w.shape == present.shape + (d,):
        mask = present[..., None]
    else:
        return False
    if not (w.min() >= 0.0 and w.max() <= MAX_WEIGHT):  # NaN fails both comparisons
        return False
    return np.where(mask, w, 0.0)


def _fast_moments(obs0: np.ndarray, present: np.ndarray, wa: np.ndarray | None):
    """Weighted sums ``sw_i * mean_i`` (m, 2) of the centred obs and the sensor weights
    ``sw`` (m,) of the rigid fit, as the general path forms them (a weight of 1 or 0 times a
    value is exact). Isotropic weights: the plain weighted sums. Per-axis weights: the
    per-axis means times the sensor weight (the mean of its axis weights; 0, and no means,
    if an axis has none: module docstring)."""
    if wa is None:
        return np.add.reduce(obs0, axis=0), np.add.reduce(present, axis=0, dtype=float)
    Wa = np.add.reduce(wa, axis=0)
    if wa.ndim == 2:
        return np.add.reduce(wa[..., None] * obs0, axis=0), Wa
    means = np.add.reduce(wa * obs0, axis=0) / np.maximum(Wa, 5e-324)  # 0 / tiny = 0
    full = (Wa > 0.0).all(axis=1)
    sw = np.where(full, np.add.reduce(Wa, axis=1) / Wa.shape[1], 0.0)  # == Wa.mean(axis=1)
    return means * sw[:, None], sw


def _fast_objective(obs0: np.ndarray, nan: np.ndarray, wa: np.ndarray | None,
                    p: np.ndarray) -> float:
    """:func:`_objective` at positions ``p`` (m, 2), bit for bit: unweighted, the residuals
    are zeroed at missing samples instead of multiplied by a 0/1 weight."""
    r = obs0 - p
    if wa is None:
        r[nan] = 0.0
        return float(np.add.reduce(r * r, axis=None))
    return float(np.add.reduce((wa[..., None] if wa.ndim == 2 else wa) * r * r, axis=None))


def _rigid_2d(wy: np.ndarray, sw: np.ndarray, B1: np.ndarray):
    """Closed-form weighted rigid fit in 2-D (Kabsch without scale, as procrustes_batch).

    wy (m, 2) = sw_i * mean_i (metres; 0 where ``sw`` is 0), sw (m,) weights, B1 = [body -
    centroid, 1] (m, 3) (:class:`~estimator.configuration.PairGeometry`). ``M = sum_i w_i
    (y_i - ybar)(b_i - bbar)^T`` from one product with the moments ``sum w y b^T - W ybar
    bbar^T`` (means and body are both centred, so nothing cancels). Returns None if the
    total weight W < FAST_MIN_WEIGHT, else (T, gap, T_m, yaw): the proper fit as the (3, 2)
    matrix ``T = [R^T; t]`` with window-centred positions ``B1 @ T`` (R = [[c, -s], [s, c]]),
    ``gap = best - best_mirror`` (half the objective gap to the mirror fit), the mirror fit
    as T_m (R_m = [[c, s], [s, -c]]) and the yaw of R, rad in (-pi, pi].
    """
    sb0, sb1, W = (sw @ B1).tolist()
    if not W >= FAST_MIN_WEIGHT:
        return None  # weights near underflow: the general path's order of operations
    (k00, k01, sy0), (k10, k11, sy1) = (wy.T @ B1).tolist()
    sy0, sy1, sb0, sb1 = sy0 / W, sy1 / W, sb0 / W, sb1 / W  # ybar, bbar
    m00, m01 = k00 - W * sy0 * sb0, k01 - W * sy0 * sb1
    m10, m11 = k10 - W * sy1 * sb0, k11 - W * sy1 * sb1
    pc, ps = m00 + m11, m10 - m01
    qc, qs = m00 - m11, m01 + m10
    th = math.atan2(ps, pc)
    c, s = math.cos(th), math.sin(th)
    T = [[c, s], [-s, c], [sy0 - (c * sb0 - s * sb1), sy1 - (s * sb0 + c * sb1)]]
    ph = math.atan2(qs, qc)
    cm, sm = math.cos(ph), math.sin(ph)
    T_m = [[cm, sm], [sm, -cm], [sy0 - (cm * sb0 + sm * sb1), sy1 - (sm * sb0 - cm * sb1)]]
    yaw = math.atan2(s, c)
    gap = math.hypot(pc, ps) - math.hypot(qc, qs)
    return T, gap, T_m, (math.pi if yaw <= -math.pi else yaw)


#: relative margin around procrustes_batch's 3-D collinearity threshold (1e-12) inside which
#: the fast path leaves the verdict to the general path (its moments round differently)
_COLLINEAR_MARGIN = 100.0


def _rigid_3d(wy: np.ndarray, sw: np.ndarray, B1: np.ndarray):
    """:func:`_rigid_2d` for d = 3 (B1 (m, 4), T (4, 3)): the weighted cross-covariance
    ``M`` from the moments, its SVD with the determinant correction (as procrustes_batch),
    ``gap = 2 det S_3``. None also when fewer than 3 sensors have weight or the weighted
    body points are (nearly) collinear: the general path decides those."""
    if np.count_nonzero(sw) < 3:
        return None
    G = (B1.T * sw) @ B1  # [[sum w b b^T, sum w b], [sum w b^T, W]]
    W = float(G[3, 3])
    if not W >= FAST_MIN_WEIGHT:
        return None
    bbar = G[:3, 3] / W
    ev = np.linalg.eigvalsh(G[:3, :3] - W * np.outer(bbar, bbar))
    if ev[1] <= _COLLINEAR_MARGIN * 1e-12 * max(ev[2], 1e-300):
        return None
    K = wy.T @ B1
    ybar = K[:, 3] / W
    U, S, Vt = np.linalg.svd(K[:, :3] - W * np.outer(ybar, bbar))
    det = float(np.sign(np.linalg.det(U @ Vt))) or 1.0
    R = (U * [1.0, 1.0, det]) @ Vt
    R_m = (U * [1.0, 1.0, -det]) @ Vt
    T = np.vstack([R.T, ybar - R @ bbar])
    T_m = np.vstack([R_m.T, ybar - R_m @ bbar])
    yaw = math.atan2(R[1, 0], R[0, 0])
    return T, 2.0 * det * float(S[2]), T_m, (math.pi if yaw <= -math.pi else yaw)


#: engine of the 2-D fast path: "numba" (:func:`estimator.window_kernel.fit_2d`, one
#: compiled call) or "numpy" (the ~30 numpy calls below, the reference the tests compare)
FAST_2D_ENGINE = "numba"
#: the weights argument of the kernel when there are none (never read)
_NO_WEIGHTS = np.zeros((1, 1, 1))


def _fast_procrustes(obs: Any, config: SensorConfig, weights: Any | None, eps: Any,
                     x0: Any, maxiter: Any) -> WindowFit | None:
    """fit_window(obs, config, weights, eps, "procrustes", x0, maxiter=maxiter) for a window
    that passes every check and has enough data: one compiled call (d = 2,
    :data:`FAST_2D_ENGINE`) or ~30 numpy calls; None sends the call to the general path
    (which checks again and names the field, or fits)."""
    g = config.pair_geometry
    if type(eps) not in _FAST_REALS or not 0.0 < eps < g.min_distance / 2.0:
        return None
    if type(maxiter) is not int or maxiter < 1:
        return None
    if config.d == 2 and FAST_2D_ENGINE == "numba":
        return None if x0 is not None and not _x0_ok(x0, config) else \
            _compiled_2d(obs, config, weights)
    got = _fast_obs(obs, config)
    if got is None:
        return None
    arr, nan, present, centre = got
    wa = _fast_weights(weights, present, config.d)
    if wa is False:
        return None
    obs0 = arr - centre
    obs0[nan] = 0.0
    wy, sw = _fast_moments(obs0, present, wa)
    if np.count_nonzero(sw) < 2:
        return None  # insufficient data: the general path reports it
    fit = (_rigid_2d if config.d == 2 else _rigid_3d)(wy, sw, g.body1)
    if fit is None or (x0 is not None and not _x0_ok(x0, config)):
        return None
    T, gap, T_m, yaw = fit
    p_c = g.body1 @ np.asarray(T)  # window-centred R b + t
    obj = _fast_objective(obs0, nan, wa, p_c)
    if wa is None or wa.ndim == 2:
        mirror = max(obj + 2.0 * gap, 0.0)  # isotropic: Z_mirror - Z = 2 (best - best_mirror)
    else:
        mirror = _objective(obs0, wa, g.body1 @ np.asarray(T_m))
    return _fast_result(p_c, centre, g, obj, mirror, yaw)


def _compiled_2d(obs: Any, config: SensorConfig, weights: Any | None) -> WindowFit | None:
    """The 2-D fast path as one call of :func:`estimator.window_kernel.fit_2d` (imported on
    first use: numba); None where the kernel (or an argument's shape or type) declines."""
    try:
        arr = np.asarray(obs, dtype=float)
        w = _NO_WEIGHTS if weights is None else np.asarray(weights, dtype=float)
    except (TypeError, ValueError):
        return None
    if arr.ndim != 3 or arr.shape[1:] != (config.m, 2):
        return None
    mode = 0 if weights is None else 1 if w.shape == arr.shape[:2] else 2
    if mode == 1:
        w = w[..., None]
    elif mode == 2 and w.shape != arr.shape:
        return None
    from estimator.window_kernel import fit_2d

    g = config.pair_geometry
    pos, cg, out = np.empty((config.m, 2)), np.empty(2), np.empty(4)
    if not fit_2d(np.ascontiguousarray(arr), np.ascontiguousarray(w), mode, g.body1, g.I,
                  g.J, g.a, g.cg_mask, MAX_COORD_M, MAX_WEIGHT, FAST_MIN_WEIGHT, pos, cg, out):
        return None
    yaw, obj, mirror, viol = out.tolist()
    fit = object.__new__(WindowFit)  # the frozen dataclass's fields, without 9 setattr calls
    fit.__dict__.update(positions=pos, cg=cg, yaw=yaw, objective=obj, mirror_objective=mirror,
                        max_violation=viol, solver="procrustes", iterations=0, status="ok")
    return fit


def _fast_result(p_c: np.ndarray, centre: np.ndarray, g: Any, obj: float, mirror: float,
                 yaw: float) -> WindowFit:
    """The WindowFit of :func:`_result` from window-centred positions (m, d): violation on
    the centred positions, CG (Eq. 3.8) as the mean of the members' world positions."""
    dif = g.difference @ p_c  # p[I] - p[J], exactly
    dist = np.hypot(dif[:, 0], dif[:, 1]) if p_c.shape[1] == 2 else \
        np.sqrt((dif * dif).sum(axis=1))
    viol = max(map(abs, (dist - g.a).tolist()))
    positions = p_c + centre
    rows = positions.tolist()  # mean of the members in order, as positions[cg].mean(axis=0)
    cg = np.array([sum(col) / len(col) for col in zip(*[rows[i] for i in g.cg_index])])
    fit = object.__new__(WindowFit)  # the frozen dataclass's fields, without 9 setattr calls
    fit.__dict__.update(positions=positions, cg=cg, yaw=yaw, objective=obj,
                        mirror_objective=mirror, max_violation=viol, solver="procrustes",
                        iterations=0, status="ok")
    return fit


# ----------------------------------------------------------------------------- public fit
def fit_window(obs: Any, config: SensorConfig, weights: Any | None = None, eps: float = 0.01,
               solver: str = "procrustes", x0: Any | None = None, *, maxiter: int = 100,
               ccp_problems: CcpProblems | None = None) -> WindowFit:
    """Fit the known configuration to one window of observations (Eq. 3.9; Eq. 3.7 when the
    window is the whole stationary recording; Eq. 3.12-3.14 with weights).

    obs : (s, m, d) metres, NaN = missing sample. weights : None, (s, m) or (s, m, d),
    finite and >= 0. eps : constraint slack in metres, 0 < eps < min_ij a_ij / 2.
    solver : "procrustes" | "slsqp" | "ccp" | "elastic" (module docstring). x0 : (m, d) start
    for slsqp/ccp/elastic (default: the procrustes fit; elastic uses it only when it is
    strictly inside every band) and the positions returned when the window has insufficient
    data. maxiter : iteration limit of slsqp / ccp / elastic. ccp_problems : the ccp
    solver's built problems (:class:`CcpProblems`) to reuse across calls (default: built for
    this call).
    Raises ValueError naming the field for malformed input; solver trouble is in ``status``.
    """
    if not isinstance(config, SensorConfig):
        raise ValueError(  # noqa: TRY004 (the project's bad-input contract is ValueError)
            f"config: expected a SensorConfig, got {type(config).__name__}")
    if solver == "procrustes":
        fast = _fast_procrustes(obs, config, weights, eps, x0, maxiter)
        if fast is not None:
            return fast
    arr, present = _check_obs(obs)
    if arr.ndim != 3 or arr.shape[1:] != (config.m, config.d):
        raise ValueError(
            f"obs: expected shape (s, {config.m}, {config.d}) for config {config.name!r} "
            f"(m={config.m}, d={config.d}), got {arr.shape}")
    if solver not in SOLVERS:
        raise ValueError(f"solver: unknown {solver!r}; choose one of {list(SOLVERS)}")
    e = _check_eps(eps, config)
    x0a = _check_x0(x0, config)
    check_int(maxiter, "maxiter", lo=1)

    wa = _axis_weights(arr, present, weights)
    # centre on the window (UTM coordinates are ~1e6 m): any fixed reference point works
    centre = arr[present].mean(axis=0) if present.any() else np.zeros(config.d)
    obs0 = np.where(present[..., None], arr - centre, 0.0)
    Wa = wa.sum(axis=0)  # (m, d)
    with np.errstate(invalid="ignore", divide="ignore"):
        means = np.where(Wa > 0, (wa * obs0).sum(axis=0) / Wa, np.nan)
    full = (Wa > 0).all(axis=-1)
    sw = np.where(full, Wa.mean(axis=-1), 0.0)
    bf = procrustes_batch(np.where(full[:, None], means, np.nan)[None], sw[None], config)

    if bf.status[0] != "ok":
        if x0a is not None:
            obj = _objective(obs0, wa, x0a - centre)
            return _result(x0a - centre, centre, config, obj, float("nan"), solver, 0,
                           "insufficient_data")
        nanpos = np.full((config.m, config.d), np.nan)
        return _result(nanpos, centre, config, float("nan"), float("nan"), solver, 0,
                       "insufficient_data")

    p_proc = bf.positions[0]
    obj_proc = _objective(obs0, wa, p_proc)
    if weights is None or np.ndim(weights) == 2:
        # isotropic weights: Z = reduced objective + within-window scatter (module docstring)
        scatter = float((wa * (obs0 - np.where(full[:, None], means, 0.0)) ** 2).sum())
        mirror = float(bf.mirror_objective[0]) + scatter
    else:
        mirror = _objective(obs0, wa, _mirror_fit_positions(
            np.where(full[:, None], means, 0.0), sw, config.body_positions))
    if solver == "procrustes":
        return _result(p_proc, centre, config, obj_proc, mirror, solver, 0, "ok",
                       yaw=float(bf.yaw[0]))

    start = p_proc if x0a is None else x0a - centre
    yc = np.where(Wa > 0, means, 0.0)
    if solver == "elastic":
        from estimator.elastic import elastic_batch  # numba: imported when used (issue 27)

        ef = elastic_batch(np.where(Wa > 0, means, np.nan)[None], Wa[None], config, e,
                           start=start[None], maxiter=maxiter)
        st = str(ef.status[0])
        p_el = ef.positions[0]
        obj = obj_proc if st.startswith("fallback") else _objective(obs0, wa, p_el)
        return _result(p_el, centre, config, obj, mirror, solver, int(ef.iterations[0]), st,
                       yaw=float(ef.yaw[0]))
    try:
        if solver == "slsqp":
            p_sol, iters = _solve_slsqp(yc, Wa, config, e, start, maxiter)
        else:
            p_sol, iters = _solve_ccp(yc, Wa, config, e, start, maxiter, ccp_problems)
    except (ValueError, ArithmeticError, np.linalg.LinAlgError, RuntimeError):
        p_sol, iters = None, 0
    if p_sol is not None and not full.all():
        p_sol = _restore_unobserved(p_sol, start, ~full, config, e)
    status = _accept(p_sol, obs0, wa, obj_proc, config, e)
    if status != "ok" or p_sol is None:          # (_accept says so when p_sol is None)
        return _result(p_proc, centre, config, obj_proc, mirror, solver, iters, status,
                       yaw=float(bf.yaw[0]))
    return _result(p_sol, centre, config, _objective(obs0, wa, p_sol), mirror, solver,
                   iters, "ok")


def fit_stationary(obs: Any, config: SensorConfig, **kw: Any) -> WindowFit:
    """Whole-recording estimate of a stationary platform (Eq. 3.7): :func:`fit_window` with
    the entire recording ``obs (n, m, d)`` as one window; keywords as for fit_window."""
    return fit_window(obs, config, **kw)


def _restore_unobserved(p: np.ndarray, start: np.ndarray, unobserved: np.ndarray,
                        config: SensorConfig, eps: float) -> np.ndarray:
    """Put sensors without data back at their start positions when that keeps every
    distance inside the eps band. They carry no cost, so the objective is unchanged; this
    removes the solver-tolerance wander of the free variables (module docstring)."""
    q = p.copy()
    q[unobserved] = start[unobserved]
    return q if _max_violation(q, config) <= eps else p


#: acceptance tolerances of slsqp / ccp results (metres, relative objective)
FEAS_TOL = 1e-9
OBJ_RTOL = 1e-9


def _accept(p: np.ndarray | None, obs0: np.ndarray, wa: np.ndarray, obj_proc: float,
            config: SensorConfig, eps: float) -> str:
    if p is None or not np.isfinite(p).all():
        return "fallback_failed"
    if _max_violation(p, config) > eps + FEAS_TOL:
        return "fallback_infeasible"
    if _objective(obs0, wa, p) > obj_proc * (1.0 + OBJ_RTOL) + 1e-12:
        return "fallback_objective"
    if _is_mirrored(p, config.body_positions):
        return "fallback_mirrored"
    return "ok"


# ----------------------------------------------------------------------------- slsqp


def _solver_weights(yc: np.ndarray, Wa: np.ndarray, start: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Normalized weights and targets of the solvers' objective.

    Data terms: ``Wa / sum(Wa)`` (the objective divided by the total weight) towards the
    window means. Sensors (axes) without data have no cost in Eq. 3.9, so their positions
    are free inside the eps band; a proximal term ``PROX_WEIGHT |z - start|^2`` pins them to
    the start (the procrustes fit or x0) and makes the optimum unique. It is zero at the
    start, so the data objective at the solution is still <= its value at the start.
    """
    Wn = Wa / Wa.sum()
    none = Wa <= 0
    Wn = np.where(none, PROX_WEIGHT, Wn)
    target = np.where(none, start, yc)
    return Wn, target


def _pair_jacobian_builder(m: int, d: int):
    I, J = _pairs(m)
    P = I.size
    rows = np.arange(P)
    colsI = I[:, None] * d + np.arange(d)
    colsJ = J[:, None] * d + np.arange(d)
    return I, J, rows, colsI, colsJ, P


def _solve_slsqp(yc: np.ndarray, Wa: np.ndarray, config: SensorConfig, eps: float,
                 start: np.ndarray, maxiter: int) -> tuple[np.ndarray, int]:
    """SLSQP on the reduced Eq. 3.9: f(z) = sum_ia Wn_ia (z_ia - yc_ia)^2 with Wn = Wa / sum Wa
    (objective divided by the total weight), variables centred on the window, constraints
    (a+eps)^2 - |z_i - z_j|^2 >= 0 and |z_i - z_j|^2 - (a-eps)^2 >= 0 (Eq. 3.6)."""
    from scipy.optimize import minimize

    m, d = config.m, config.d
    I, J, rows, colsI, colsJ, P = _pair_jacobian_builder(m, d)
    a = _geometry(config).a
    hi2 = (a + eps) ** 2
    lo2 = (a - eps) ** 2
    Wn, target = _solver_weights(yc, Wa, start)

    def fun(x: np.ndarray) -> tuple[float, np.ndarray]:
        r = x.reshape(m, d) - target
        g = Wn * r
        return float((g * r).sum()), (2.0 * g).ravel()

    def cons(x: np.ndarray) -> np.ndarray:
        z = x.reshape(m, d)
        diff = z[I] - z[J]
        q = (diff * diff).sum(axis=1)
        return np.concatenate([hi2 - q, q - lo2])

    def cons_jac(x: np.ndarray) -> np.ndarray:
        z = x.reshape(m, d)
        diff = 2.0 * (z[I] - z[J])
        Jq = np.zeros((P, m * d))
        Jq[rows[:, None], colsI] = diff
        Jq[rows[:, None], colsJ] = -diff
        return np.concatenate([-Jq, Jq])

    # (scipy's type annotations of minimize do not cover jac=True with a (f, grad) function)
    res = minimize(fun, start.ravel(), jac=True, method="SLSQP",  # type: ignore[call-overload]
                   constraints=[{"type": "ineq", "fun": cons, "jac": cons_jac}],
                   options={"maxiter": int(maxiter), "ftol": 1e-12})
    return res.x.reshape(m, d), int(res.nit)


# ----------------------------------------------------------------------------- ccp

#: Clarabel tolerances: tighter than the defaults (1e-8) so accepted iterates satisfy the
#: distance bounds to FEAS_TOL (1e-9 m) on metre-sized platforms
CLARABEL_OPTIONS = {"tol_feas": 1e-10, "tol_gap_abs": 1e-10, "tol_gap_rel": 1e-10}

#: metres by which the ccp subproblems tighten the eps band (guards solver round-off)
CCP_MARGIN = 1e-8

#: ccp stops when one iteration improves the normalized objective by less than this fraction
#: (measured on m = 7 GPS-like windows: final objective within 1.3e-6 relative of slsqp's,
#: 3-4 iterations; 1e-8 costs about twice the iterations for 1e-8 agreement)
CCP_RTOL = 1e-6


class CcpProblems:
    """The ccp solver's cvxpy problems, one per ``(m, d)``, built on first use and reused
    (DPP: only the Parameters change between windows). Building one costs far more than a
    window's solve, so a caller fitting many windows passes one instance to every
    :func:`fit_window` call (``ccp_problems=``; the trackers do); without it each call
    builds its own. An explicit object, not a module-level cache: the caller owns it."""

    def __init__(self) -> None:
        self._problems: dict[tuple[int, int], tuple] = {}

    def get(self, m: int, d: int) -> tuple:
        """(problem, z, sqrt_w, sqrt_w_y, U, ub, lb) for m sensors in d dimensions."""
        key = (m, d)
        if key not in self._problems:
            self._problems[key] = _ccp_problem(m, d)
        return self._problems[key]


def _ccp_problem(m: int, d: int) -> tuple:
    """The ccp subproblem of Eq. 3.9 for m sensors in d dimensions, with Parameters."""
    import cvxpy as cp

    I, J = _pairs(m)
    P = I.size
    E = np.zeros((P, m))
    E[np.arange(P), I] = 1.0
    E[np.arange(P), J] = -1.0
    z = cp.Variable((m, d))
    sqrt_w = cp.Parameter((m, d), nonneg=True)
    sqrt_w_y = cp.Parameter((m, d))
    U = cp.Parameter((P, d))
    ub = cp.Parameter(P, nonneg=True)
    lb = cp.Parameter(P)
    D = E @ z
    objective = cp.sum_squares(cp.multiply(sqrt_w, z) - sqrt_w_y)
    constraints = [cp.norm(D, 2, axis=1) <= ub,              # convex upper bound (SOC)
                   cp.sum(cp.multiply(U, D), axis=1) >= lb]  # linearized lower bound
    prob = cp.Problem(cp.Minimize(objective), constraints)
    # (cvxpy's type hints do not declare is_dcp's dpp argument)
    assert prob.is_dcp(dpp=True)  # type: ignore[call-arg]
    return (prob, z, sqrt_w, sqrt_w_y, U, ub, lb)


def _solve_ccp(yc: np.ndarray, Wa: np.ndarray, config: SensorConfig, eps: float,
               start: np.ndarray, maxiter: int, problems: CcpProblems | None = None
               ) -> tuple[np.ndarray, int]:
    """Convex-concave procedure for Eq. 3.9 (normalized by the total weight).

    Each iteration solves, with u_ij the unit direction of p_i - p_j at the current iterate,
        min sum Wn (z - yc)^2  s.t.  |z_i - z_j| <= a_ij + eps,  u_ij . (z_i - z_j) >= a_ij - eps.
    Because u . v <= |v|, the linearized lower bound implies the true one: every iterate is
    feasible for Eq. 3.9 and the objective is non-increasing. Stops when an iteration improves
    the objective by less than CCP_RTOL (relative) or after ``maxiter`` iterations.
    """
    import cvxpy as cp

    m, d = config.m, config.d
    prob, z, sqrt_w, sqrt_w_y, U, ub, lb = (problems or CcpProblems()).get(m, d)
    g = _geometry(config)
    I, J, a = g.I, g.J, g.a
    Wn, target = _solver_weights(yc, Wa, start)
    sw = np.sqrt(Wn)
    sqrt_w.value = sw
    sqrt_w_y.value = sw * target
    # solve inside the band by CCP_MARGIN so solver round-off (~1e-9 m seen) cannot break Eq. 3.6
    ub.value = a + eps - CCP_MARGIN
    lb.value = a - eps + CCP_MARGIN

    def f(x: np.ndarray) -> float:
        r = x - target
        return float((Wn * r * r).sum())

    cur = start.copy()
    f_cur = math.inf  # the start may be infeasible (x0): the first iterate is always taken
    it = 0
    for it in range(1, maxiter + 1):
        diff = cur[I] - cur[J]
        nrm = np.linalg.norm(diff, axis=1)
        # a degenerate start (coincident points) gets the body-frame direction
        fallback_dir = config.body_positions[I] - config.body_positions[J]
        diff = np.where(nrm[:, None] > 1e-12, diff, fallback_dir)
        U.value = diff / np.linalg.norm(diff, axis=1)[:, None]
        with warnings.catch_warnings():
            # "solution may be inaccurate": the iterate is checked below and in _accept
            warnings.simplefilter("ignore", UserWarning)
            try:
                prob.solve(solver=cp.CLARABEL, **CLARABEL_OPTIONS)
            except cp.error.SolverError as exc:  # reported as status "fallback_failed"
                if it == 1:
                    raise RuntimeError(f"ccp: Clarabel failed: {exc}") from exc
                break
        if z.value is None or prob.status not in ("optimal", "optimal_inaccurate"):
            if it == 1:
                raise RuntimeError(f"ccp: subproblem status {prob.status}")
            break
        nxt = np.asarray(z.value)
        f_nxt = f(nxt)
        if it > 1 and (f_nxt > f_cur or _max_violation(nxt, config) > eps + FEAS_TOL):
            break  # keep the last accepted iterate
        improved = f_cur - f_nxt
        cur, f_prev, f_cur = nxt, f_cur, f_nxt
        if it > 1 and improved <= CCP_RTOL * f_prev:
            break
    return cur, it
