"""Lag-correction building blocks (Section 3.4.2) against hand-computed values."""

import numpy as np
import pytest

from estimator.lag import estimate_velocity, first_observations, lag_shift


def test_estimate_velocity_exact_on_a_line_and_causal():
    t = np.array([0.0, 1.0, 3.0, 4.0, 7.0])
    xy = np.c_[2.0 * t, -t]
    v = estimate_velocity(t, xy, span=2)
    assert np.isnan(v[0]).all()  # no earlier estimate
    np.testing.assert_allclose(v[1:], np.tile([2.0, -1.0], (4, 1)))
    # causal: changing a later row does not change earlier velocities
    xy2 = xy.copy()
    xy2[4] += 10.0
    np.testing.assert_array_equal(estimate_velocity(t, xy2, 2)[:4], v[:4])
    with pytest.raises(ValueError, match="span"):
        estimate_velocity(t, xy, 0)
    with pytest.raises(ValueError, match="xy"):
        estimate_velocity(t, xy[:3], 1)


def test_first_observations_hand_example():
    obs = np.full((5, 2, 2), np.nan)
    obs[1, 0] = [1.0, 1.0]
    obs[3, 0] = [3.0, 3.0]
    obs[4, 1] = [4.0, 4.0]
    first, idx = first_observations(obs, np.array([0, 2, 0]), np.array([2, 4, 3]))
    np.testing.assert_array_equal(idx, [[1, -1], [3, 4], [1, -1]])
    np.testing.assert_array_equal(first[0, 0], [1.0, 1.0])
    np.testing.assert_array_equal(first[1, 1], [4.0, 4.0])
    assert np.isnan(first[0, 1]).all()


def test_lag_shift_noise_free_straight_and_window_one():
    """Window of s epochs at 2 m/s east, dt 1: fitted positions at the window's mid time,
    first observations at its start; both modes shift by exactly (s-1) v / 2 east."""
    s, v = 11, 2.0
    t = np.arange(20.0)
    m = 2
    offs = np.array([[0.5, 0.0], [-0.5, 0.0]])
    end = 15
    first = np.array([[v * (end - s + 1), 0.0]]) + offs  # (m, 2) at the window start
    pos = np.array([[v * (end - (s - 1) / 2), 0.0]]) + offs
    args = (t, pos[None], first[None], np.full((1, m), end - s + 1), np.array([t[end]]),
            np.array([[v, 0.0]]), np.array([0.0]))
    for mode in ("pose", "course"):
        sh = lag_shift(*args, np.array([s]), mode=mode)
        np.testing.assert_allclose(sh, [[(s - 1) * v / 2, 0.0]], atol=1e-12)
        assert (lag_shift(*args, np.array([1]), mode=mode) == 0).all()
    with pytest.raises(ValueError, match="mode"):
        lag_shift(*args, np.array([s]), mode="predict")


def test_course_mode_standing_still_does_not_move():
    t = np.arange(5.0)
    pos = np.zeros((1, 1, 2))
    first = np.array([[[0.3, -0.2]]])  # noise: first fix off the estimate
    sh = lag_shift(t, pos, first, np.array([[0]]), np.array([4.0]), np.zeros((1, 2)),
                   np.array([0.0]), np.array([5]), mode="course")
    np.testing.assert_array_equal(sh, [[0.0, 0.0]])
    # as written ("pose") shifts backwards by the distance: the flaw the variant avoids
    sp = lag_shift(t, pos, first, np.array([[0]]), np.array([4.0]), np.zeros((1, 2)),
                   np.array([0.0]), np.array([5]), mode="pose")
    np.testing.assert_allclose(sp, [[-np.hypot(0.3, 0.2), 0.0]])


@pytest.mark.parametrize("bad", [np.nan, 1.0], ids=["nan", "repeated"])
def test_estimate_velocity_rejects_nan_or_repeated_time(bad):
    # used to divide by a zero or NaN time difference without a word
    t = np.array([0.0, 1.0, 3.0, 4.0, 7.0])
    t[2] = bad
    with pytest.raises(ValueError, match=r"^t: .*t\[2\]"):
        estimate_velocity(t, np.zeros((5, 2)), 2)
    with pytest.raises(ValueError, match=r"^t: "):
        estimate_velocity(np.zeros((5, 1)), np.zeros((5, 2)), 2)


def test_first_observations_against_a_row_by_row_reference():
    """Section 3.4.2, step 2: the first complete observation of each sensor inside each
    window, against a plain loop (a sensor with one NaN coordinate is not complete)."""
    rng = np.random.default_rng(3)
    n, m = 40, 4
    obs = rng.normal(size=(n, m, 2))
    obs[rng.random((n, m)) < 0.4] = np.nan
    obs[5, 1, 0] = np.nan                                       # half an observation
    start = rng.integers(0, n, 25)
    end = np.minimum(start + rng.integers(0, 8, 25), n - 1)
    first, idx = first_observations(obs, start, end)
    for r, (a, b) in enumerate(zip(start, end)):
        for j in range(m):
            ks = [k for k in range(a, b + 1) if np.isfinite(obs[k, j]).all()]
            if ks:
                assert idx[r, j] == ks[0]
                np.testing.assert_array_equal(first[r, j], obs[ks[0], j])
            else:
                assert idx[r, j] == -1 and np.isnan(first[r, j]).all()
