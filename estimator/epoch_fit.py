"""The closed-form rigid fit of a planar layout to each epoch's fixes, one epoch at a time.

Source: 000_8f82f8df647bf685.txt (GPS dissertation), Section 3.1 with a window of one epoch
and equal weights (the weighted window form is :func:`estimator.rigid_fit.procrustes_batch`).
The pose filter checks its heading against it and :mod:`estimator.platform` estimates the
platform's limits from it. It imports nothing else of the project (its compiled loops,
:mod:`estimator.epoch_fit_kernel`, when first called), so both can import it.
"""

from __future__ import annotations

import numpy as np

__all__ = ["epoch_rigid_fits"]

#: Largest layout the compiled sums take (numpy's orders,
#: :func:`estimator.epoch_fit_kernel._row_sum`, checked up to it); beyond, numpy sums.
MAX_COMPILED_M = 64


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
    :data:`MAX_COMPILED_M` antennas the sums are compiled loops
    (:mod:`estimator.epoch_fit_kernel`) in numpy's orders, the angle and its cosine and
    sine numpy's; beyond, the sums over the antennas run antenna by antenna on (n, 2)
    columns in numpy's order (``0.0 + a_0 + a_1 + ...``) and the sums of (n, m) arrays are
    numpy's own.
    """
    n, m = obs.shape[:2]
    if m <= MAX_COMPILED_M:
        from estimator.epoch_fit_kernel import fit_residuals, fit_sums

        ob = np.ascontiguousarray(obs, dtype=float)
        of = np.ascontiguousarray(offsets, dtype=float)
        zc, rc, cross, dot = np.empty((n, 2)), np.empty((n, 2)), np.empty(n), np.empty(n)
        cnt = np.empty(n, dtype=np.int64)
        fit_sums(ob, of, zc, rc, cross, dot, cnt)
        # the heading and its cos / sin in numpy (its SIMD arctan2 is not libm's)
        yaw = np.arctan2(cross, dot)
        c, s = np.cos(yaw), np.sin(yaw)
        origin, res = np.empty((n, 2)), np.empty((n, m, 2))
        fit_residuals(ob, of, zc, rc, yaw, c, s, origin, res)
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
