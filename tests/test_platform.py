"""The curvature limit estimated from a recording (estimator.platform, issue 25)."""

from __future__ import annotations

import numpy as np

from estimator.platform import CURVATURE_FLOOR_1PM, PlatformLimits, estimate_limits

OFF = np.array([[0.4, 0.4], [0.4, -0.4], [-0.4, 0.4], [-0.4, -0.4]])


def _drive(speed: np.ndarray, yaw_rate: np.ndarray, noise_m: float = 0.01, seed: int = 2):
    """Antenna fixes (n, 4, 2) of a platform at 1 Hz with the given speed (m/s) and yaw rate
    (rad/s) per epoch (integrated exactly per step, midpoint heading)."""
    rng = np.random.default_rng(seed)
    n = speed.size
    yaw = np.concatenate(([0.0], np.cumsum(yaw_rate[:-1])))
    mid = yaw[:-1] + 0.5 * yaw_rate[:-1]
    step = np.c_[speed[:-1] * np.cos(mid), speed[:-1] * np.sin(mid)]
    pos = np.vstack((np.zeros(2), np.cumsum(step, axis=0)))
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    obs = np.stack((pos[:, None, 0] + c * OFF[:, 0] - s * OFF[:, 1],
                    pos[:, None, 1] + s * OFF[:, 0] + c * OFF[:, 1]), axis=-1)
    return np.arange(float(n)), obs + rng.normal(0.0, noise_m, (n, 4, 2))


def test_curvature_from_the_course_changes():
    """A car weaving at 4 m/s with curvature up to 0.15 1/m (yaw rate 0.6 sin(t / 8)): the
    estimate is MARGIN (1.25) x p99 of the observed curvature: at least 0.15 and at most
    1.25 x (0.15 + 3 x 0.0013), 0.0013 1/m being the sd of one curvature sample (1 cm fixes
    on a 0.8 m frame: course sd ~0.0035 rad per interval, two courses over 4 m)."""
    t = np.arange(400.0)
    t_, obs = _drive(np.full(t.size, 4.0), 0.6 * np.sin(t / 8.0))
    k = estimate_limits(t_, obs, OFF, 0.01, 0.014).max_curvature_1pm
    assert k is not None and 0.15 <= k <= 1.25 * (0.15 + 3 * 0.0013)


def test_curvature_unbounded_for_a_platform_turning_on_the_spot():
    """A rover that stops and pivots at 0.5 rad/s a tenth of the time: no curvature limit
    (None: the yaw rate is not bounded by the speed); one that never turns gets the floor."""
    t = np.arange(400.0)
    pivot = (t % 50) < 5
    _, obs = _drive(np.where(pivot, 0.0, 1.0), np.where(pivot, 0.5, 0.0))
    assert estimate_limits(t, obs, OFF, 0.01, 0.014).max_curvature_1pm is None
    _, obs = _drive(np.full(t.size, 1.0), np.zeros(t.size))
    assert estimate_limits(t, obs, OFF, 0.01, 0.014).max_curvature_1pm == CURVATURE_FLOOR_1PM


def test_curvature_limit_is_optional_and_checked():
    """A [platform] block may give the curvature (1/m) or leave it out (None: unbounded); a
    bad value names the key."""
    base = {"max_speed_mps": 16.0, "max_accel_mps2": 4.0, "max_turn_rate_radps": 1.0}
    assert PlatformLimits.from_dict(base).max_curvature_1pm is None
    assert PlatformLimits.from_dict({**base, "max_curvature_1pm": 0.2}).max_curvature_1pm == 0.2
    try:
        PlatformLimits.from_dict({**base, "max_curvature_1pm": -1.0})
    except ValueError as e:
        assert "platform.max_curvature_1pm" in str(e) and "-1" in str(e)
    else:
        raise AssertionError("a negative curvature was accepted")
