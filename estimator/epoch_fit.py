"""The closed-form rigid fit of a planar layout to each epoch's fixes, one epoch at a time.

Source: 000_8f82f8df647bf685.txt (GPS dissertation), Section 3.1 with a window of one epoch
and equal weights (the weighted window form is :func:`estimator.rigid_fit.procrustes_batch`).
The pose filter checks its heading against it and :mod:`estimator.platform` estimates the
platform's limits from it. It imports nothing of the project, so both can import it.
"""

from __future__ import annotations

import numpy as np

__all__ = ["epoch_rigid_fits"]


def epoch_rigid_fits(obs: np.ndarray, offsets: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Closed-form 2-D rigid fit of the offsets to every epoch's fixes (Kabsch in 2-D): the
    per-epoch fit the pose filter checks its heading against and the platform limits are
    estimated from (unweighted, one epoch at a time; :func:`procrustes_batch` is the
    weighted window form).

    Returns origin (n, 2) (the world position of offset (0, 0)), yaw (n,), number of fixes
    (n,) and residuals (n, m, 2) (NaN where absent); epochs with < 2 fixes are NaN.
    """
    present = np.isfinite(obs[..., 0])
    cnt = present.sum(axis=1)
    w = present.astype(float)
    z = np.where(present[..., None], obs, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        zc = (z * w[..., None]).sum(1) / cnt[:, None]
        rc = (offsets[None] * w[..., None]).sum(1) / cnt[:, None]
    dz = (z - zc[:, None]) * w[..., None]
    dr = (offsets[None] - rc[:, None]) * w[..., None]
    yaw = np.arctan2((dr[..., 0] * dz[..., 1] - dr[..., 1] * dz[..., 0]).sum(1),
                     (dr * dz).sum(-1).sum(1))
    c, s = np.cos(yaw), np.sin(yaw)
    origin = zc - np.c_[c * rc[:, 0] - s * rc[:, 1], s * rc[:, 0] + c * rc[:, 1]]
    fit = origin[:, None] + np.stack([c[:, None] * offsets[None, :, 0]
                                      - s[:, None] * offsets[None, :, 1],
                                      s[:, None] * offsets[None, :, 0]
                                      + c[:, None] * offsets[None, :, 1]], -1)
    bad = cnt < 2
    origin[bad] = np.nan
    yaw[bad] = np.nan
    res = np.where(present[..., None] & ~bad[:, None, None], obs - fit, np.nan)
    return origin, yaw, cnt, res
