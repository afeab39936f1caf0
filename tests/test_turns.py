"""Turn detector from estimates (dynamic window on real logs, Section 3.4.2.1)."""

import math

import numpy as np
import pytest

from estimator.orientation import wrap_angle
from estimator.turns import course_heading, detect_turns, heading_rate, hysteresis


def test_heading_rate_exact_for_linear_heading_across_pi():
    t = np.arange(0.0, 30.0, 0.5)
    h = wrap_angle(3.0 + 0.2 * t)  # crosses +/-pi: the rate must not see the jump
    r = heading_rate(t, h, span_s=3.0)
    assert np.isnan(r[0])
    np.testing.assert_allclose(r[1:], 0.2, atol=1e-9)
    h2 = h.copy()
    h2[10] = np.nan
    assert np.isfinite(heading_rate(t, h2, 3.0)[11])
    with pytest.raises(ValueError, match="span_s"):
        heading_rate(t, h, 0.0)
    with pytest.raises(ValueError, match="t:"):
        heading_rate(t[::-1], h, 1.0)


def test_hysteresis_hand_example():
    sig = np.array([0.0, 0.2, 0.12, 0.06, 0.04, 0.1, np.nan, 0.2, np.nan])
    out = hysteresis(sig, on=0.15, off=0.05)
    np.testing.assert_array_equal(out, [0, 1, 1, 1, 0, 0, 0, 1, 1])
    with pytest.raises(ValueError, match="off <= on"):
        hysteresis(sig, on=0.05, off=0.1)


def test_course_heading_and_standstill():
    t = np.arange(10.0)
    xy = np.c_[-t, np.zeros(10)]  # heading west
    xy[6:] = xy[5]  # then stops
    c = course_heading(t, xy, span_s=2.0, min_speed=0.1)
    assert np.isnan(c[:2]).all()
    np.testing.assert_allclose(np.abs(c[2:7]), math.pi)
    assert np.isnan(c[7:]).all()  # displacement over the span below min_speed


def test_detect_turns_on_a_clean_corner():
    t = np.arange(100.0)
    h = np.where(t < 40, 0.0, np.where(t < 44, (t - 40) * (math.pi / 8), math.pi / 2))
    flags = detect_turns(t, h, rate_on=0.15, rate_off=0.05, span_s=4.0)
    on = np.flatnonzero(flags)
    assert on.size > 0 and on.min() >= 41 and on.max() <= 48
    assert not flags[:41].any() and not flags[49:].any()


@pytest.mark.parametrize("bad", [np.nan, 2.0], ids=["nan", "repeated"])
def test_nan_or_repeated_time_raises_naming_t(bad):
    # a NaN used to pass the `diff <= 0` test (comparisons with NaN are False)
    t = np.arange(10.0)
    t[3] = bad
    h = np.zeros(10)
    with pytest.raises(ValueError, match=r"^t: .*t\[3\]"):
        heading_rate(t, h, 2.0)
    with pytest.raises(ValueError, match=r"^t: .*t\[3\]"):
        course_heading(t, np.zeros((10, 2)), 2.0)
