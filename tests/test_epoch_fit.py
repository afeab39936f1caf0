"""estimator.epoch_fit: the per-epoch rigid fit, against the plain array expressions it was
written as (bit for bit: the pose filter's outputs depend on every bit of its heading) and
against exact rigid motions."""

from __future__ import annotations

import numpy as np
import pytest

from estimator.epoch_fit import epoch_rigid_fits


def _reference(obs: np.ndarray, offsets: np.ndarray):
    """The fit as plain numpy expressions over (n, m, 2) arrays (the form before issue 27's
    set-up work): centroids, Kabsch angle, origin, residuals."""
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


def _bits(a: np.ndarray) -> np.ndarray:
    """The array's bit patterns (signed zeros distinct), every NaN alike."""
    b = np.array(a, dtype=float)
    b[np.isnan(b)] = np.nan
    return b.view(np.int64)


@pytest.mark.parametrize("m", [1, 2, 3, 4, 5, 7, 8, 9, 12, 16, 17, 25, 64, 65])
@pytest.mark.parametrize("n", [0, 1, 3, 50, 1500])
def test_bit_identical_to_the_array_expressions(n, m):
    """Random layouts and fixes (a third absent), values from a small set (exact zeros of
    both signs, ties) and continuous ones: every output bit as the reference's."""
    rng = np.random.default_rng(100 * n + m)
    for kind in ("continuous", "discrete"):
        if kind == "continuous":
            off = rng.normal(0.0, 0.8, (m, 2))
            obs = rng.normal(0.0, 50.0, (n, 1, 2)) + off + rng.normal(0.0, 0.02, (n, m, 2))
        else:
            vals = np.array([0.0, -0.0, 0.5, -0.5, 1.0, -1.0, 3.0])
            off = rng.choice(vals, (m, 2))
            obs = rng.choice(vals, (n, m, 2))
        obs[rng.random((n, m)) < 0.33] = np.nan
        got, want = epoch_rigid_fits(obs, off), _reference(obs, off)
        for g, r in zip(got, want, strict=True):
            assert g.shape == r.shape and g.dtype == r.dtype
            if g.dtype.kind == "f":
                np.testing.assert_array_equal(_bits(g), _bits(r))
            else:
                np.testing.assert_array_equal(g, r)


def test_exact_rigid_motion_recovered():
    """Fixes that are an exact rotation and translation of the layout: the fit returns
    them (origin, yaw), zero residuals, NaN for epochs with fewer than two fixes."""
    rng = np.random.default_rng(5)
    off = np.array([[0.7, 0.4], [0.7, -0.4], [-0.9, 0.4], [-0.9, -0.4], [0.0, 0.0]])
    n = 200
    yaw = rng.uniform(-3.0, 3.0, n)
    org = rng.normal(0.0, 100.0, (n, 2))
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    obs = np.stack([org[:, :1] + c * off[:, 0] - s * off[:, 1],
                    org[:, 1:] + s * off[:, 0] + c * off[:, 1]], -1)
    drop = rng.random((n, 5)) < 0.4
    obs[drop] = np.nan
    o, y, cnt, res = epoch_rigid_fits(obs, off)
    ok = cnt >= 2
    np.testing.assert_array_equal(cnt, (~drop).sum(1))
    # two fixes at the same layout point cannot occur: every pair has distinct offsets
    np.testing.assert_allclose(o[ok], org[ok], atol=1e-9)
    assert np.all(np.abs(np.angle(np.exp(1j * (y[ok] - yaw[ok])))) < 1e-9)
    assert np.all(np.abs(res[ok][~drop[ok]]) < 1e-9)
    assert np.isnan(res[ok][drop[ok]]).all() and np.isnan(o[~ok]).all()
    assert np.isnan(y[~ok]).all() and np.isnan(res[~ok]).all()
