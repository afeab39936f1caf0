"""The one-window procrustes fit in 2-D as one compiled loop (numba, ``@njit(cache=True)``):
what :func:`estimator.window.fit_window` runs for a single 2-D procrustes call (issue 27);
and the per-window weighted sums of randomly weighted windows (:func:`weighted_sums`, the
loop of :func:`estimator.trackers._windows.weighted_window_means`, bit-identical to its numpy
reference).

:func:`fit_2d` makes the fast path's screens (a sample is missing only as a whole, present
coordinates finite and within ``max_coord``, weights in [0, ``max_weight``]), forms the
window moments, solves the d = 2 closed form of :func:`estimator.window._rigid_2d` (the same
formulas in the same order) and returns the positions, CG, yaw, objective, mirror objective
and constraint violation; it returns 0 (and ``fit_window`` takes its numpy path, which
checks again and names the field) for any input it does not take as it is. The sums run
in sample order where numpy's add.reduce pairs them, so objectives agree with the numpy
path to round-off (tests/test_window.py: 1e-12 relative, positions 1e-12 m + 2 ulp).
Imported on the first call (numba's own import and target set-up cost ~0.5-1 s once per
process; the compiled code is cached on disk). ``NUMBA_DISABLE_JIT=1`` runs the same
function as Python (same results, ~100x slower).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["fit_2d", "weighted_sums"]


@njit(cache=True, nogil=True)
def _screen(arr: np.ndarray, max_coord: float, centre: np.ndarray) -> bool:
    """Every sample whole-NaN or finite within max_coord, one at least; ``centre`` (2,) is
    set to the mean of the present samples (in sample order, as numpy's axis-0 sum)."""
    s, m = arr.shape[0], arr.shape[1]
    cx = cy = 0.0
    k = 0
    for i in range(s):
        for j in range(m):
            x, y = arr[i, j, 0], arr[i, j, 1]
            if math.isnan(x):
                if not math.isnan(y):
                    return False
            elif not (abs(x) <= max_coord and abs(y) <= max_coord):
                return False          # an inf, a NaN y or a coordinate out of range
            else:
                cx += x
                cy += y
                k += 1
    if k == 0:
        return False
    centre[0], centre[1] = cx / k, cy / k
    return True


@njit(cache=True, nogil=True)
def _moments(arr: np.ndarray, centre: np.ndarray, w: np.ndarray, wmode: int,
             obs0: np.ndarray, wy: np.ndarray, sw: np.ndarray) -> None:
    """Centred obs (0 where missing), weighted sums wy (m, 2) and sensor weights sw (m,) as
    :func:`estimator.window._fast_moments` (wmode 0 none, 1 per sample, 2 per axis)."""
    s, m = arr.shape[0], arr.shape[1]
    Wa = np.zeros((m, 2))
    for i in range(s):
        for j in range(m):
            if math.isnan(arr[i, j, 0]):
                obs0[i, j, 0] = obs0[i, j, 1] = 0.0
                continue
            for c in range(2):
                o = arr[i, j, c] - centre[c]
                obs0[i, j, c] = o
                wt = 1.0 if wmode == 0 else w[i, j, 0 if wmode == 1 else c]
                wy[j, c] += wt * o
                Wa[j, c] += wt
    for j in range(m):
        if wmode != 2:
            sw[j] = Wa[j, 0]
        elif Wa[j, 0] > 0.0 and Wa[j, 1] > 0.0:
            sw[j] = (Wa[j, 0] + Wa[j, 1]) / 2.0
            for c in range(2):
                wy[j, c] = wy[j, c] / Wa[j, c] * sw[j]
        else:
            sw[j] = wy[j, 0] = wy[j, 1] = 0.0


@njit(cache=True, nogil=True)
def _rigid(wy: np.ndarray, sw: np.ndarray, B1: np.ndarray, min_weight: float,
           T: np.ndarray, T_m: np.ndarray) -> tuple[bool, float, float]:
    """:func:`estimator.window._rigid_2d` into T, T_m (3, 2); returns (ok, gap, yaw)."""
    sb0 = sb1 = wsum = 0.0
    k00 = k01 = sy0 = k10 = k11 = sy1 = 0.0
    for j in range(B1.shape[0]):
        sb0 += sw[j] * B1[j, 0]
        sb1 += sw[j] * B1[j, 1]
        wsum += sw[j] * B1[j, 2]
        k00 += wy[j, 0] * B1[j, 0]
        k01 += wy[j, 0] * B1[j, 1]
        sy0 += wy[j, 0] * B1[j, 2]
        k10 += wy[j, 1] * B1[j, 0]
        k11 += wy[j, 1] * B1[j, 1]
        sy1 += wy[j, 1] * B1[j, 2]
    if not wsum >= min_weight:
        return False, 0.0, 0.0
    sy0, sy1, sb0, sb1 = sy0 / wsum, sy1 / wsum, sb0 / wsum, sb1 / wsum
    m00, m01 = k00 - wsum * sy0 * sb0, k01 - wsum * sy0 * sb1
    m10, m11 = k10 - wsum * sy1 * sb0, k11 - wsum * sy1 * sb1
    pc, ps = m00 + m11, m10 - m01
    qc, qs = m00 - m11, m01 + m10
    th = math.atan2(ps, pc)
    c, s = math.cos(th), math.sin(th)
    T[0, 0], T[0, 1], T[1, 0], T[1, 1] = c, s, -s, c
    T[2, 0], T[2, 1] = sy0 - (c * sb0 - s * sb1), sy1 - (s * sb0 + c * sb1)
    ph = math.atan2(qs, qc)
    cm, sm = math.cos(ph), math.sin(ph)
    T_m[0, 0], T_m[0, 1], T_m[1, 0], T_m[1, 1] = cm, sm, sm, -cm
    T_m[2, 0], T_m[2, 1] = sy0 - (cm * sb0 + sm * sb1), sy1 - (sm * sb0 - cm * sb1)
    yaw = math.atan2(s, c)
    return True, math.hypot(pc, ps) - math.hypot(qc, qs), math.pi if yaw <= -math.pi else yaw


@njit(cache=True, nogil=True)
def _place(B1: np.ndarray, T: np.ndarray, p: np.ndarray) -> None:
    """Window-centred positions p = B1 @ T (m, 2)."""
    for j in range(B1.shape[0]):
        for c in range(2):
            p[j, c] = B1[j, 0] * T[0, c] + B1[j, 1] * T[1, c] + B1[j, 2] * T[2, c]


@njit(cache=True, nogil=True)
def _objective(obs0: np.ndarray, present: np.ndarray, w: np.ndarray, wmode: int,
               p: np.ndarray) -> float:
    """sum w (o - p)^2 over the present samples (Eq. 3.9 / 3.12)."""
    z = 0.0
    for i in range(obs0.shape[0]):
        for j in range(obs0.shape[1]):
            if not present[i, j]:
                continue
            for c in range(2):
                r = obs0[i, j, c] - p[j, c]
                z += r * r if wmode == 0 else w[i, j, 0 if wmode == 1 else c] * r * r
    return z


@njit(cache=True, nogil=True)
def fit_2d(arr: np.ndarray, w: np.ndarray, wmode: int, B1: np.ndarray, I: np.ndarray,
           J: np.ndarray, a: np.ndarray, cg_mask: np.ndarray, max_coord: float,
           max_weight: float, min_weight: float, pos: np.ndarray, cg: np.ndarray,
           out: np.ndarray) -> bool:
    """One 2-D window (module docstring). arr (s, m, 2) m, NaN = missing; w (s, m, 1) per
    sample or (s, m, 2) per axis weights (``wmode`` 1 / 2; 0: none, w unused); B1, I, J, a,
    cg_mask from :class:`estimator.configuration.PairGeometry`. Fills pos (m, 2) world
    positions, cg (2,) and out = [yaw, objective, mirror objective, max violation]; returns
    False (nothing to trust in the outputs) for an input the numpy path must decide."""
    s, m = arr.shape[0], arr.shape[1]
    if wmode != 0:
        for i in range(w.shape[0]):
            for j in range(w.shape[1]):
                for c in range(w.shape[2]):
                    if not (w[i, j, c] >= 0.0 and w[i, j, c] <= max_weight):
                        return False      # NaN fails both
    centre = np.empty(2)
    if not _screen(arr, max_coord, centre):
        return False
    present = np.empty((s, m), dtype=np.bool_)
    for i in range(s):
        for j in range(m):
            present[i, j] = not math.isnan(arr[i, j, 0])
    obs0 = np.empty((s, m, 2))
    wy = np.zeros((m, 2))
    sw = np.zeros(m)
    _moments(arr, centre, w, wmode, obs0, wy, sw)
    if np.count_nonzero(sw) < 2:
        return False
    T, T_m = np.empty((3, 2)), np.empty((3, 2))
    ok, gap, yaw = _rigid(wy, sw, B1, min_weight, T, T_m)
    if not ok:
        return False
    p = np.empty((m, 2))
    _place(B1, T, p)
    obj = _objective(obs0, present, w, wmode, p)
    if wmode == 2:
        p_m = np.empty((m, 2))
        _place(B1, T_m, p_m)
        mirror = _objective(obs0, present, w, wmode, p_m)
    else:
        mirror = max(obj + 2.0 * gap, 0.0)   # isotropic: Z_mirror - Z = 2 (best - best_mirror)
    viol = 0.0
    for k in range(I.shape[0]):
        dx, dy = p[I[k], 0] - p[J[k], 0], p[I[k], 1] - p[J[k], 1]
        viol = max(viol, abs(math.hypot(dx, dy) - a[k]))
    n_cg = 0
    cg[0] = cg[1] = 0.0
    for j in range(m):
        pos[j, 0], pos[j, 1] = p[j, 0] + centre[0], p[j, 1] + centre[1]
        if cg_mask[j]:
            cg[0] += pos[j, 0]
            cg[1] += pos[j, 1]
            n_cg += 1
    cg[0], cg[1] = cg[0] / n_cg, cg[1] / n_cg
    out[0], out[1], out[2], out[3] = yaw, obj, mirror, viol
    return True


@njit(cache=True, nogil=True)
def weighted_sums(obs: np.ndarray, ends: np.ndarray, wts: np.ndarray, num: np.ndarray,
                  W: np.ndarray) -> None:
    """Per-window weighted sums of the windows ending at ``ends`` (N,) with per-window
    weights ``wts`` (N, w, m): num (N, m, 2) += weight x obs and W (N, m) += weight over
    the window's present samples (obs (n, m, 2) m, NaN = missing: weight 0), adding the
    window offsets j = 0 .. w-1 in order, as the numpy reference
    (``estimator.trackers._windows.weighted_sums_numpy``) does: the same floating-point
    numbers. num and W must start at 0."""
    N, w, m = wts.shape
    for r in range(N):
        a = ends[r] - (w - 1)
        for j in range(w):
            i = a + j
            for k in range(m):
                x = obs[i, k, 0]
                if math.isnan(x):
                    continue      # weight 0 and obs 0: adds +0.0, which changes no sum
                wj = wts[r, j, k]
                W[r, k] += wj
                num[r, k, 0] += wj * x
                num[r, k, 1] += wj * obs[i, k, 1]
