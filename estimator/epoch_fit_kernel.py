"""The compiled loops of :func:`estimator.epoch_fit.epoch_rigid_fits` (issue 27: the pose
filter's set-up), in a module of their own so that importing :mod:`estimator.epoch_fit`
imports no numba (the command lines' usage errors stay light).

Every operation as the fit's array expressions in numpy: the same bits
(tests/test_epoch_fit.py).
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["fit_residuals", "fit_sums"]

_jit = numba.njit(cache=True, nogil=True, error_model="numpy")


@_jit
def _row_sum(a, m):
    """numpy's sum of a[:m] as one row of a C-contiguous (n, m) array (m <= 128): 0.0 +
    a_0 + ... + a_{m-1} in order below 8 terms, else numpy's pairwise_sum (8 accumulators
    over blocks of 8, combined ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7)), the rest
    added in order), then added to 0.0."""
    if m < 8:
        r = 0.0
        for i in range(m):
            r += a[i]
        return r
    r0, r1, r2, r3, r4, r5, r6, r7 = a[0], a[1], a[2], a[3], a[4], a[5], a[6], a[7]
    i = 8
    while i < m - m % 8:
        r0 += a[i]
        r1 += a[i + 1]
        r2 += a[i + 2]
        r3 += a[i + 3]
        r4 += a[i + 4]
        r5 += a[i + 5]
        r6 += a[i + 6]
        r7 += a[i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < m:
        res += a[i]
        i += 1
    return 0.0 + res


@_jit
def fit_sums(obs, offsets, zc, rc, cross, dot, cnt):
    """Per epoch of obs (n, m, 2), offsets (m, 2): the fixes' and their offsets' centroids
    zc, rc (n, 2), the Kabsch sums cross, dot (n,) and the number of fixes cnt (n,), with
    the operations of the array expressions of :func:`estimator.epoch_fit.epoch_rigid_fits`
    in numpy's order (a sum over the antenna axis 0.0 + a_0 + a_1 + ...; cross and dot as
    numpy sums rows, :func:`_row_sum`; a centroid of no fix 0 / 0)."""
    n, m = obs.shape[0], obs.shape[1]
    tc, td = np.empty(m), np.empty(m)
    for k in range(n):
        z0 = z1 = r0 = r1 = 0.0
        c = 0
        for i in range(m):
            if math.isfinite(obs[k, i, 0]):
                z0 += obs[k, i, 0]
                z1 += obs[k, i, 1]
                r0 += offsets[i, 0] * 1.0
                r1 += offsets[i, 1] * 1.0
                c += 1
            else:
                r0 += offsets[i, 0] * 0.0
                r1 += offsets[i, 1] * 0.0
        cnt[k] = c
        zc0, zc1, rc0, rc1 = z0 / c, z1 / c, r0 / c, r1 / c
        zc[k, 0], zc[k, 1], rc[k, 0], rc[k, 1] = zc0, zc1, rc0, rc1
        for i in range(m):
            w = 1.0 if math.isfinite(obs[k, i, 0]) else 0.0
            zi0 = obs[k, i, 0] if w else 0.0
            zi1 = obs[k, i, 1] if w else 0.0
            dz0, dz1 = (zi0 - zc0) * w, (zi1 - zc1) * w
            dr0, dr1 = (offsets[i, 0] - rc0) * w, (offsets[i, 1] - rc1) * w
            tc[i] = dr0 * dz1 - dr1 * dz0
            td[i] = dr0 * dz0 + dr1 * dz1
        cross[k], dot[k] = _row_sum(tc, m), _row_sum(td, m)


@_jit
def fit_residuals(obs, offsets, zc, rc, yaw, c, s, origin, res):
    """Origins (n, 2) and residuals (n, m, 2) from the centroids and the heading's cos c and
    sin s (n,), as the array expressions of :func:`estimator.epoch_fit.epoch_rigid_fits`;
    NaN where absent and for epochs with fewer than 2 fixes (yaw too)."""
    n, m = obs.shape[0], obs.shape[1]
    for k in range(n):
        ck, sk = c[k], s[k]
        o0 = zc[k, 0] - (ck * rc[k, 0] - sk * rc[k, 1])
        o1 = zc[k, 1] - (sk * rc[k, 0] + ck * rc[k, 1])
        cnt = 0
        for i in range(m):
            cnt += math.isfinite(obs[k, i, 0])
        bad = cnt < 2
        for i in range(m):
            if bad or not math.isfinite(obs[k, i, 0]):
                res[k, i, 0] = res[k, i, 1] = math.nan
            else:
                ox, oy = offsets[i, 0], offsets[i, 1]
                res[k, i, 0] = obs[k, i, 0] - (o0 + (ck * ox - sk * oy))
                res[k, i, 1] = obs[k, i, 1] - (o1 + (sk * ox + ck * oy))
        if bad:
            o0 = o1 = math.nan
            yaw[k] = math.nan
        origin[k, 0], origin[k, 1] = o0, o1
