"""Motion-compensated window fit (constant twist): exactness, equivalences, equivariance."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from synth_tracks import antennas, constant_twist, rover

from estimator.motion import motion_compensated_batch
from estimator.orientation import angle_diff
from estimator.window import procrustes_batch, window_means


def _windows(t, obs, ends, s):
    idx = ends[:, None] - np.arange(s - 1, -1, -1)[None, :]
    return t[idx] - t[ends][:, None], obs[idx]


@pytest.mark.parametrize("yaw_rate", [0.0, 0.15, -0.3])
def test_exact_on_constant_twist_with_missing_and_uneven_samples(yaw_rate):
    rng = np.random.default_rng(4)
    cfg = rover()
    t = np.cumsum(rng.uniform(0.3, 1.0, 60))
    cg, yaw = constant_twist(t, 1.4, 0.4, yaw_rate)
    obs = antennas(cfg, cg, yaw)
    obs[rng.random(obs.shape[:2]) < 0.15] = np.nan
    ends = np.arange(9, 60, 5)
    tau, st_ = _windows(t, obs, ends, 10)
    fit = motion_compensated_batch(tau, st_, cfg)
    # 1e-6: only rounding and the omega search's final precision stand between us and 0
    np.testing.assert_allclose(fit.cg, cg[ends], atol=1e-6)
    np.testing.assert_allclose(angle_diff(fit.yaw, yaw[ends]), 0, atol=1e-6)
    np.testing.assert_allclose(fit.yaw_rate, yaw_rate, atol=1e-6)
    speed = np.hypot(fit.velocity[:, 0], fit.velocity[:, 1])
    np.testing.assert_allclose(speed, 1.4, atol=1e-5)


def test_single_epoch_equals_procrustes():
    """All samples at one time: no velocity to fit, the fit is the ordinary window fit."""
    rng = np.random.default_rng(1)
    cfg = rover()
    obs = rng.normal(0, 2.0, (5, 1, 8, 2)) + 10.0
    obs[:, :, 3] = np.nan
    fit = motion_compensated_batch(np.zeros((5, 1)), obs, cfg)
    means, sw = window_means(obs)
    ref = procrustes_batch(means, sw, cfg)
    np.testing.assert_allclose(fit.positions, ref.positions, atol=1e-9)
    np.testing.assert_allclose(fit.velocity, 0.0)


@settings(max_examples=25, deadline=None)
@given(st.floats(-math.pi, math.pi), st.floats(-50, 50), st.floats(-50, 50))
def test_rigid_motion_equivariance(theta, dx, dy):
    """Rotating and translating the world rotates and translates the fit (noisy data)."""
    rng = np.random.default_rng(7)
    cfg = rover()
    t = np.arange(12.0)
    cg, yaw = constant_twist(t, 1.0, 0.3, 0.05)
    obs = antennas(cfg, cg, yaw) + rng.normal(0, 0.8, (12, 8, 2))
    tau, o = _windows(t, obs, np.array([11]), 12)
    R = np.array([[math.cos(theta), -math.sin(theta)], [math.sin(theta), math.cos(theta)]])
    o2 = o @ R.T + np.array([dx, dy])
    a = motion_compensated_batch(tau, o, cfg, yaw_rate=False)
    b = motion_compensated_batch(tau, o2, cfg, yaw_rate=False)
    # 1e-7 m: the transform adds rounding of ~1e-14 relative on 50 m coordinates
    np.testing.assert_allclose(b.positions, a.positions @ R.T + np.array([dx, dy]), atol=1e-7)
    assert abs(angle_diff(b.yaw[0], a.yaw[0] + theta)) < 1e-9


def test_insufficient_data_and_bad_input():
    cfg = rover()
    obs = np.full((1, 3, 8, 2), np.nan)
    obs[0, :, 0] = [[0, 0], [1, 0], [2, 0]]  # one sensor only
    fit = motion_compensated_batch(np.array([[-2.0, -1.0, 0.0]]), obs, cfg)
    assert fit.status[0] == "insufficient_data" and np.isnan(fit.cg).all()
    with pytest.raises(ValueError, match="tau"):
        motion_compensated_batch(np.zeros((1, 2)), obs, cfg)
    with pytest.raises(ValueError, match="weights"):
        motion_compensated_batch(np.zeros((1, 3)), obs, cfg, np.ones((1, 3)))
    with pytest.raises(ValueError, match="omega_max"):
        motion_compensated_batch(np.zeros((1, 3)), obs, cfg, omega_max=0.0)


def test_heading_minus_pi_is_wrapped_to_plus_pi():
    # a platform driving exactly west: the fitted rotation is z = -1 - 0j, for which
    # np.angle returns -pi, outside the convention's (-pi, pi]
    from estimator.motion import motion_compensated_series

    cfg = rover()
    t = np.arange(12.0)
    cg, yaw = constant_twist(t, 1.0, -math.pi)
    obs = antennas(cfg, cg, yaw)
    ends = np.arange(4, 12)
    tau, st_ = _windows(t, obs, ends, 5)
    for fit in (motion_compensated_batch(tau, st_, cfg),
                motion_compensated_series(t, obs, cfg, ends, 5)):
        assert np.all(fit.yaw == math.pi)
