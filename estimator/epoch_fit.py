"""The closed-form rigid fit of a planar layout to each epoch's fixes, one epoch at a time.

Source: 000_8f82f8df647bf685.txt (GPS dissertation), Section 3.1 with a window of one epoch
and equal weights (the weighted window form is :func:`estimator.rigid_fit.procrustes_batch`).
The pose filter checks its heading against it and :mod:`estimator.platform` estimates the
platform's limits from it. It imports nothing of the project, so both can import it.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["epoch_rigid_fits"]

#: Largest layout the compiled sums take (numpy's orders, :func:`_row_sum`, checked up to
#: it); beyond, numpy sums.
MAX_COMPILED_M = 64

_jit = numba.njit(cache=True, nogil=True, error_model="numpy")  # type: ignore[call-overload]


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
def _sums(obs, offsets, zc, rc, cross, dot, cnt):
    """Per epoch: the fixes' and their offsets' centroids zc, rc (n, 2), the Kabsch sums
    cross, dot (n,) and the number of fixes cnt (n,), with the operations of the array
    expressions of :func:`epoch_rigid_fits` in numpy's order (every sum 0.0 + a_0 + a_1 +
    ...; cross and dot as numpy sums rows, :func:`_row_sum`; a centroid of no fix 0 / 0)."""
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
def _residuals(obs, offsets, zc, rc, yaw, c, s, origin, res):
    """Origins (n, 2) and residuals (n, m, 2) from the centroids and the heading's cos c and
    sin s (n,), as the array expressions of :func:`epoch_rigid_fits`; NaN where absent and
    for epochs with fewer than 2 fixes (yaw too)."""
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



def epoch_rigid_fits(obs: np.ndarray, offsets: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Closed-form 2-D rigid fit of the offsets to every epoch's fixes (Kabsch in 2-D): the
    per-epoch fit the pose filter checks its heading against and the platform limits are
    estimated from (unweighted, one epoch at a time; :func:`procrustes_batch` is the
    weighted window form).

    obs (n, m, 2) m (NaN = absent), offsets (m, 2) m. Returns origin (n, 2) (the world
    position of offset (0, 0)), yaw (n,), number of fixes (n,) and residuals (n, m, 2) (NaN
    where absent); epochs with < 2 fixes are NaN.

    The same bits as the plain array expressions (tests/test_epoch_fit.py holds them as the
    reference), in a fraction of their time (issue 27: the filter's set-up): up to
    :data:`MAX_COMPILED_M` antennas the sums are compiled loops (:func:`_sums`,
    :func:`_residuals`) in numpy's orders (:func:`_row_sum`), the angle and its cosine and
    sine numpy's; beyond, the sums over the antennas run antenna by antenna on (n, 2)
    columns in numpy's order (``0.0 + a_0 + a_1 + ...``) and the sums of (n, m) arrays are
    numpy's own.
    """
    n, m = obs.shape[:2]
    if m <= MAX_COMPILED_M:
        ob = np.ascontiguousarray(obs, dtype=float)
        of = np.ascontiguousarray(offsets, dtype=float)
        zc, rc, cross, dot = np.empty((n, 2)), np.empty((n, 2)), np.empty(n), np.empty(n)
        cnt = np.empty(n, dtype=np.int64)
        _sums(ob, of, zc, rc, cross, dot, cnt)
        # the heading and its cos / sin in numpy (its SIMD arctan2 is not libm's)
        yaw = np.arctan2(cross, dot)
        c, s = np.cos(yaw), np.sin(yaw)
        origin, res = np.empty((n, 2)), np.empty((n, m, 2))
        _residuals(ob, of, zc, rc, yaw, c, s, origin, res)
        return origin, yaw, cnt, res
    present = np.isfinite(obs[..., 0])
    cnt = present.sum(axis=1)
    w = present.astype(float)
    z = np.where(present[..., None], obs, 0.0)
    # centroids: sum_i z_i w_i = sum_i z_i (z is 0 where w is), sum_i r_i w_i
    zs = np.zeros((n, 2))
    rs = np.zeros((n, 2))
    for i in range(m):
        zs += z[:, i]
        rs += offsets[i] * w[:, i, None]
    with np.errstate(invalid="ignore", divide="ignore"):
        zc = zs / cnt[:, None]
        rc = rs / cnt[:, None]
    dz = z - zc[:, None]
    dz *= w[..., None]
    dr = offsets[None] - rc[:, None]
    dr *= w[..., None]
    dr0, dr1, dz0, dz1 = dr[..., 0], dr[..., 1], dz[..., 0], dz[..., 1]
    yaw = np.arctan2((dr0 * dz1 - dr1 * dz0).sum(1), (dr0 * dz0 + dr1 * dz1).sum(1))
    c, s = np.cos(yaw), np.sin(yaw)
    origin = np.empty((n, 2))
    origin[:, 0] = zc[:, 0] - (c * rc[:, 0] - s * rc[:, 1])
    origin[:, 1] = zc[:, 1] - (s * rc[:, 0] + c * rc[:, 1])
    c, s = c[:, None], s[:, None]
    res = np.empty((n, m, 2))
    res[..., 0] = obs[..., 0] - (origin[:, :1] + (c * offsets[:, 0] - s * offsets[:, 1]))
    res[..., 1] = obs[..., 1] - (origin[:, 1:] + (s * offsets[:, 0] + c * offsets[:, 1]))
    bad = cnt < 2
    origin[bad] = np.nan
    yaw[bad] = np.nan
    np.copyto(res, np.nan, where=~(present & ~bad[:, None])[..., None])
    return origin, yaw, cnt, res
