"""The closed-form rigid fit of a configuration to window means, batched (Kabsch/Umeyama).

Source: 000_8f82f8df647bf685.txt (GPS dissertation), Section 3.1: with every distance held
exactly, the window fit of Eq. 3.9 reduces to a weighted rigid fit of the body-frame
configuration to the per-sensor window means (the reduction is in :mod:`estimator.window`'s
docstring). This module holds that fit and the checks and per-configuration constants the
iterative solvers share: :mod:`estimator.window` (one window, every solver) and
:mod:`estimator.elastic` (the batched eps-elastic fit) both import it, and it imports
neither, so the two solvers' modules do not import each other.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from estimator._checks import check_array, check_real
from estimator.configuration import PairGeometry, SensorConfig
from estimator.orientation import wrap_angle

__all__ = [
    "MAX_COORD_M",
    "MAX_WEIGHT",
    "MAX_WEIGHT_SUM",
    "PROX_WEIGHT",
    "BatchFit",
    "check_window_means",
    "procrustes_batch",
    "procrustes_poses",
]


@dataclass(frozen=True)
class BatchFit:
    """Batched procrustes result for N windows.

    positions (N, m, d), rotation (N, d, d) (world = rotation @ body + translation),
    translation (N, d), cg (N, d), yaw (N,), status (N,) str ("ok" | "insufficient_data"),
    objective (N,) and mirror_objective (N,): sum_i W_i |p_i - mean_i|^2 of the proper and
    of the best mirrored (det = -1) rigid fit, i.e. Z without the within-window scatter term.
    Windows with insufficient data have NaN in every numeric field.
    """

    positions: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    cg: np.ndarray
    yaw: np.ndarray
    status: np.ndarray
    objective: np.ndarray
    mirror_objective: np.ndarray


#: largest accepted |coordinate| in metres: ECEF coordinates are < 6.4e6 m and UTM northings
#: < 1e7 m; 1e9 m keeps every squared spread (< 4e18 m^2) and Eq. 3.9 sum far from overflow
MAX_COORD_M = 1e9


#: largest accepted weight: the fit depends only on ratios of weights (Huber <= 1, Huff <= 1 /
#: min_error = 1e3 by default); with 1e100 no weight sum or weighted square can overflow
MAX_WEIGHT = 1e100


#: largest accepted total weight of a sensor (procrustes_batch): sums of up to 1e100 windows
#: of MAX_WEIGHT; products with squared coordinates stay below 1e220
MAX_WEIGHT_SUM = 1e200


def _body_collinear(Bc: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(N,) True where the weighted observed body points span fewer than 2 dimensions (d=3)."""
    C = np.einsum("nm,nmi,nmj->nij", w, Bc, Bc)
    ev = np.linalg.eigvalsh(C)  # ascending
    return ev[:, -2] <= 1e-12 * np.maximum(ev[:, -1], 1e-300)


def check_window_means(means: Any, weight: Any, config: SensorConfig, weight_name: str,
                       per_axis: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """The batched fits' input check: ``means`` (N, m, d) metres of ``config``'s sensors,
    NaN only where the weight is 0, up to :data:`MAX_COORD_M`; ``weight`` (N, m) per sensor
    or, ``per_axis``, (N, m, d) per axis, finite, >= 0, up to :data:`MAX_WEIGHT_SUM`.
    Returns both as float arrays; ValueError naming ``means`` / ``weight_name`` otherwise."""
    Y = check_array(means, "means", allow_nan=True, max_abs=MAX_COORD_M)
    W = check_array(weight, weight_name, max_abs=MAX_WEIGHT_SUM)
    m, d = config.m, config.d
    if Y.ndim != 3 or Y.shape[1:] != (m, d):
        raise ValueError(f"means: expected shape (N, {m}, {d}) for config {config.name!r}, "
                         f"got {Y.shape}")
    shape = Y.shape if per_axis else Y.shape[:2]
    if W.shape != shape:
        what = "sensor and axis" if per_axis else "sensor"
        raise ValueError(f"{weight_name}: expected shape {shape} (one weight per window and "
                         f"{what}), got {W.shape}")
    if (W < 0).any():
        raise ValueError(f"{weight_name}: must be >= 0, found minimum {W.min()!r}")
    bad = np.isnan(Y) & ((W if per_axis else W[..., None]) > 0)
    if bad.any():
        k = tuple(int(i) for i in np.argwhere(bad)[0])
        raise ValueError(f"means: must be finite wherever {weight_name} > 0; means{list(k)} = "
                         f"{Y[k]!r}")
    return Y, W


def procrustes_batch(means: Any, sensor_weight: Any, config: SensorConfig) -> BatchFit:
    """Closed-form weighted rigid fit of ``config`` to N windows' means in one numpy call.

    Kabsch/Umeyama without scale: minimize ``sum_i W_i |R b_i + t - mean_i|^2`` over
    rotations ``R`` (det = +1) and translations ``t``; by the reduction in the module
    docstring this is Eq. 3.9 with every distance held exactly. d = 2 uses the closed form
    ``theta = atan2(M10 - M01, M00 + M11)`` with ``M = sum_i W_i (y_i - ybar)(b_i - bbar)^T``;
    d = 3 uses a batched SVD with the determinant correction.

    means : (N, m, d) metres (NaN allowed where the weight is 0); sensor_weight : (N, m) >= 0.
    Windows with fewer than 2 weighted sensors (d = 2), or fewer than 3 non-collinear ones
    (d = 3), get status "insufficient_data" and NaN fields. Sensors with zero weight still
    get positions from the rigid transform.
    """
    if not isinstance(config, SensorConfig):
        raise TypeError(f"config: expected a SensorConfig, got {type(config).__name__}")
    Y, w = check_window_means(means, sensor_weight, config, "sensor_weight")
    N, d = Y.shape[0], config.d
    B = config.body_positions
    nobs, ybar, bbar, Yc, Bc, wYc, M = _centred(Y, w, B)
    Sy = np.einsum("nma,nma->n", wYc, Yc)
    Sb = np.einsum("nm,nma->n", w, Bc * Bc)
    if d == 2:
        ok = nobs >= 2
        R, best = _rotation_2d(M)
        best_mirror = np.hypot(M[:, 0, 0] - M[:, 1, 1], M[:, 0, 1] + M[:, 1, 0])
    else:
        ok = nobs >= 3
        if ok.any():
            ok = ok & ~_body_collinear(Bc, w)
        U, S, Vt = np.linalg.svd(M)
        det = np.sign(np.linalg.det(U @ Vt))
        det = np.where(det == 0, 1.0, det)
        Dg = np.ones((N, 3))
        Dg[:, 2] = det
        R = np.einsum("nab,nb,nbc->nac", U, Dg, Vt)
        best = S[:, 0] + S[:, 1] + det * S[:, 2]
        best_mirror = S[:, 0] + S[:, 1] - det * S[:, 2]
    obj = np.maximum(Sy + Sb - 2.0 * best, 0.0)
    mobj = np.maximum(Sy + Sb - 2.0 * best_mirror, 0.0)
    t, pos, yaw = _placed(R, ybar, bbar, B)
    bad = ~ok
    if bad.any():
        pos[bad] = np.nan
        R[bad] = np.nan
        t[bad] = np.nan
        yaw[bad] = np.nan
        obj[bad] = np.nan
        mobj[bad] = np.nan
    status = np.where(ok, "ok", "insufficient_data")
    return BatchFit(positions=pos, rotation=R, translation=t, cg=config.cg_from_positions(pos),
                    yaw=yaw, status=status, objective=obj, mirror_objective=mobj)


def procrustes_poses(means: Any, sensor_weight: Any, config: SensorConfig
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(positions, yaw, status) of :func:`procrustes_batch`, the same numbers, without the
    fields the trackers do not read (objectives, rotation, translation, CG): ~1/4 less
    work for d = 2 (the d = 3 fit is :func:`procrustes_batch`'s)."""
    if not isinstance(config, SensorConfig):
        raise TypeError(f"config: expected a SensorConfig, got {type(config).__name__}")
    if config.d != 2:
        bf = procrustes_batch(means, sensor_weight, config)
        return bf.positions, bf.yaw, bf.status
    Y, w = check_window_means(means, sensor_weight, config, "sensor_weight")
    B = config.body_positions
    nobs, ybar, bbar, _, _, _, M = _centred(Y, w, B)
    R, _ = _rotation_2d(M)
    _, pos, yaw = _placed(R, ybar, bbar, B)
    ok = nobs >= 2
    if not ok.all():
        pos[~ok] = np.nan
        yaw[~ok] = np.nan
    return pos, yaw, np.where(ok, "ok", "insufficient_data")


def _centred(Y: np.ndarray, w: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, ...]:
    """The weighted centring of the fit: sensors observed (N,), means ybar (N, d) and bbar
    (N, d), centred Yc and Bc (N, m, d), wYc = w Yc and the cross moments M (N, d, d)."""
    valid = w > 0
    Y0 = np.where(valid[..., None], Y, 0.0)
    Wsum = w.sum(axis=1)
    nobs = valid.sum(axis=1)
    safe = np.where(Wsum > 0, Wsum, 1.0)
    ybar = np.einsum("nm,nma->na", w, Y0) / safe[:, None]
    bbar = (w @ B) / safe[:, None]
    Yc = Y0 - ybar[:, None, :]
    Bc = B[None, :, :] - bbar[:, None, :]
    wYc = w[..., None] * Yc
    return nobs, ybar, bbar, Yc, Bc, wYc, _cross_moments(wYc, Bc)


def _rotation_2d(M: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The d = 2 closed form: R (N, 2, 2) of ``theta = atan2(M10 - M01, M00 + M11)`` and
    the best value ``hypot`` of the two (N,)."""
    p_c = M[:, 0, 0] + M[:, 1, 1]
    p_s = M[:, 1, 0] - M[:, 0, 1]
    theta = np.arctan2(p_s, p_c)
    c, s = np.cos(theta), np.sin(theta)
    R = np.empty((M.shape[0], 2, 2))
    R[:, 0, 0] = c
    R[:, 0, 1] = -s
    R[:, 1, 0] = s
    R[:, 1, 1] = c
    return R, np.hypot(p_c, p_s)


def _placed(R: np.ndarray, ybar: np.ndarray, bbar: np.ndarray, B: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Translation t (N, d), positions (N, m, d) and yaw (N,) of the rotations R."""
    t = ybar - rotate(R, bbar[:, None, :])[:, 0]
    pos = rotate(R, B[None], t)
    yaw = wrap_angle(np.arctan2(R[:, 1, 0], R[:, 0, 0]))  # atan2 can give -pi
    return t, pos, yaw


def rotate(R: np.ndarray, P: np.ndarray, t: np.ndarray | None = None) -> np.ndarray:
    """``R @ p (+ t)`` for every point: R (N, d, d), P (N or 1, m, d), t (N, d) -> (N, m, d).
    For d = 2 the two-term sums are written out: the same floating-point numbers as
    ``np.einsum("nab,nmb->nma", R, P) + t[:, None]`` (each product rounded, then one
    addition, signed zeros included; tests/test_rigid_fit.py) at a fifth of its time on
    (N, 2, 2) rotations."""
    if R.shape[-1] != 2:
        out = np.einsum("nab,nmb->nma", R, P)
        return out if t is None else out + t[:, None, :]
    out = np.empty((R.shape[0], P.shape[1], 2))
    for a in range(2):
        # einsum's sum starts from +0: "+ 0.0" gives a zero its sign as einsum does
        out[..., a] = (R[:, None, a, 0] * P[..., 0] + 0.0) + R[:, None, a, 1] * P[..., 1]
        if t is not None:
            out[..., a] += t[:, None, a]
    return out


def _cross_moments(wYc: np.ndarray, Bc: np.ndarray) -> np.ndarray:
    """``sum_i wYc_i Bc_i^T`` (N, d, d) of (N, m, d) arrays, the sum over i in index order:
    the numbers of ``np.einsum("nma,nmb->nab", wYc, Bc)`` (which adds its terms in that
    order; tests/test_rigid_fit.py) at a sixth of its time (N = 2000, m = 8)."""
    d = wYc.shape[2]
    M = np.empty((wYc.shape[0], d, d))
    for a in range(d):
        for b in range(d):
            x = wYc[:, :, a] * Bc[:, :, b]
            acc = x[:, 0] + 0.0              # einsum starts from +0 (a zero's sign)
            for i in range(1, x.shape[1]):
                acc += x[:, i]
            M[:, a, b] = acc
    return M


def _geometry(config: SensorConfig) -> PairGeometry:
    """Per-configuration constants (pairs i < j, distances a_ij, CG mask): the config's own
    :attr:`~estimator.configuration.SensorConfig.pair_geometry`, computed once per config."""
    return config.pair_geometry


def _pairs(m: int) -> tuple[np.ndarray, np.ndarray]:
    return np.triu_indices(m, 1)


def _check_eps(eps: Any, config: SensorConfig) -> float:
    e = check_real(eps, "eps")
    dmin = config.pair_geometry.min_distance
    if not 0.0 < e < dmin / 2.0:
        raise ValueError(
            f"eps: must satisfy 0 < eps < min distance / 2 = {dmin / 2.0:.6g} m for config "
            f"{config.name!r}, got {eps!r}")
    return e


#: normalized weight of the proximal term that holds sensors (axes) without data at their
#: start position (relative to a total data weight of 1)
PROX_WEIGHT = 1e-6
