"""estimator.rigid_fit: the written-out sums of the d = 2 procrustes fit give the same
floating-point numbers as the einsum expressions they replaced (issue 27: bit-identical
sweep results), and procrustes_batch matches that einsum formulation bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from estimator.configuration import SensorConfig
from estimator.orientation import wrap_angle
from estimator.rigid_fit import _cross_moments, procrustes_batch, rotate


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    """The same float64 numbers bit for bit (signed zeros and NaN included)."""
    return a.shape == b.shape and a.tobytes() == b.tobytes()


def _rotations(rng: np.random.Generator, n: int) -> np.ndarray:
    th = rng.uniform(-np.pi, np.pi, n)
    c, s = np.cos(th), np.sin(th)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], 1)


@pytest.mark.parametrize("m", [1, 2, 3, 8])
def test_rotate_matches_einsum(m: int) -> None:
    rng = np.random.default_rng(m)
    R = _rotations(rng, 500)
    P = rng.normal(0, 50, (500, m, 2))
    P[:, 0] = 0.0                                   # a sensor at the origin: signed zeros
    R[:50] = np.round(R[:50])                       # and rotations with zero entries
    t = rng.normal(0, 1e3, (500, 2))
    assert _same(rotate(R, P), np.einsum("nab,nmb->nma", R, P))
    assert _same(rotate(R, P[:1]), np.einsum("nab,mb->nma", R, P[0]))
    assert _same(rotate(R, P, t), np.einsum("nab,nmb->nma", R, P) + t[:, None, :])
    R3 = rng.normal(size=(20, 3, 3))
    P3 = rng.normal(size=(20, m, 3))
    assert _same(rotate(R3, P3), np.einsum("nab,nmb->nma", R3, P3))


@pytest.mark.parametrize("m", [1, 2, 5, 8, 13])
def test_cross_moments_matches_einsum(m: int) -> None:
    rng = np.random.default_rng(10 + m)
    a = rng.normal(0, 3, (800, m, 2)) * rng.uniform(0, 5, (800, m, 1))
    b = rng.normal(0, 1, (800, m, 2))
    a[rng.random((800, m)) < 0.2] = 0.0          # sensors without weight
    a[:5] = -0.0                                   # signed zeros: every product -0
    b[:5] = np.abs(b[:5]) + 0.1
    assert _same(_cross_moments(a, b), np.einsum("nma,nmb->nab", a, b))


def _einsum_procrustes(Y: np.ndarray, w: np.ndarray, B: np.ndarray) -> tuple:
    """The d = 2 fit as it was written with einsum (the reference of the fast sums)."""
    valid = w > 0
    Y0 = np.where(valid[..., None], Y, 0.0)
    Wsum = w.sum(axis=1)
    safe = np.where(Wsum > 0, Wsum, 1.0)
    ybar = np.einsum("nm,nma->na", w, Y0) / safe[:, None]
    bbar = (w @ B) / safe[:, None]
    wYc = w[..., None] * (Y0 - ybar[:, None, :])
    M = np.einsum("nma,nmb->nab", wYc, B[None, :, :] - bbar[:, None, :])
    theta = np.arctan2(M[:, 1, 0] - M[:, 0, 1], M[:, 0, 0] + M[:, 1, 1])
    c, s = np.cos(theta), np.sin(theta)
    R = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], 1)
    t = ybar - np.einsum("nab,nb->na", R, bbar)
    pos = np.einsum("nab,mb->nma", R, B) + t[:, None, :]
    ok = valid.sum(axis=1) >= 2
    pos[~ok] = np.nan
    return pos, wrap_angle(np.arctan2(R[:, 1, 0], R[:, 0, 0])), ok


def test_procrustes_batch_matches_einsum_formula() -> None:
    rng = np.random.default_rng(3)
    B = rng.normal(0, 0.5, (8, 2))
    cfg = SensorConfig([f"s{i}" for i in range(8)], B)
    yaw = rng.uniform(-np.pi, np.pi, 2000)
    c, s = np.cos(yaw), np.sin(yaw)
    R = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], 1)
    Y = np.einsum("nab,mb->nma", R, B) + rng.normal(0, 100, (2000, 1, 2)) \
        + rng.normal(0, 0.8, (2000, 8, 2))
    w = rng.uniform(0, 3, (2000, 8)) * (rng.random((2000, 8)) > 0.3)
    Y[w == 0] = np.nan
    pos, yw, ok = _einsum_procrustes(Y, w, cfg.body_positions)
    bf = procrustes_batch(Y, w, cfg)
    assert np.array_equal(bf.positions, pos, equal_nan=True)
    assert np.array_equal(bf.yaw[ok], yw[ok])
    assert (bf.status == "ok").tolist() == ok.tolist()


def test_procrustes_poses_are_procrustes_batchs_fields() -> None:
    from estimator.rigid_fit import procrustes_poses

    rng = np.random.default_rng(8)
    cfg = SensorConfig([f"s{i}" for i in range(5)], rng.normal(0, 0.5, (5, 2)))
    Y = rng.normal(0, 30, (400, 5, 2))
    w = rng.uniform(0, 2, (400, 5)) * (rng.random((400, 5)) > 0.4)
    Y[w == 0] = np.nan
    bf = procrustes_batch(Y, w, cfg)
    pos, yaw, status = procrustes_poses(Y, w, cfg)
    assert _same(pos, bf.positions) and _same(yaw, bf.yaw)
    assert status.tolist() == bf.status.tolist() and "insufficient_data" in status
    with pytest.raises(ValueError, match="sensor_weight"):
        procrustes_poses(Y, -w, cfg)
