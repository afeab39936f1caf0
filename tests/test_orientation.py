"""Headings: wrapping, atan2 heading, the law-of-cosines construction (Eq. 3.10, Fig. 3.1)."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimator.orientation import (
    angle_diff,
    bearing_from_yaw,
    heading_from_points,
    law_of_cosines_angle,
    law_of_cosines_bearing,
    law_of_cosines_heading,
    unwrap_angle,
    wrap_angle,
    yaw_from_bearing,
)

finite_angles = st.floats(-1e4, 1e4, allow_nan=False)


def test_wrap_angle_values_and_types():
    assert wrap_angle(-math.pi) == math.pi  # (-pi, pi]: -pi maps to +pi
    assert wrap_angle(math.pi) == math.pi
    assert wrap_angle(3 * math.pi) == pytest.approx(math.pi)
    assert wrap_angle(2 * math.pi) == pytest.approx(0.0, abs=1e-15)
    assert isinstance(wrap_angle(1.0), float)
    out = wrap_angle(np.array([-math.pi, 0.5, 7.0, np.nan]))
    assert out.shape == (4,)
    assert out[0] == math.pi and out[1] == 0.5
    assert out[2] == pytest.approx(7.0 - 2 * math.pi)
    assert np.isnan(out[3])
    # tiny negative values must not round to -pi (np.mod(-1e-20, 2 pi) == 2 pi in floats)
    assert wrap_angle(np.array([-1e-20]))[0] == pytest.approx(-1e-20, abs=1e-30)


@given(finite_angles)
def test_wrap_angle_range_and_equivalence(a):
    w = wrap_angle(a)
    assert -math.pi < w <= math.pi
    # same direction: the difference is a whole number of turns (tolerance: rounding of a)
    k = (a - w) / (2 * math.pi)
    assert abs(k - round(k)) < 1e-9
    assert wrap_angle(w) == pytest.approx(w, abs=1e-12)


def test_angle_diff_across_pi():
    assert angle_diff(math.pi - 0.01, -math.pi + 0.01) == pytest.approx(-0.02)
    assert angle_diff(-math.pi + 0.01, math.pi - 0.01) == pytest.approx(0.02)
    np.testing.assert_allclose(angle_diff(np.array([3.1, -3.1]), np.array([-3.1, 3.1])),
                               [6.2 - 2 * math.pi, 2 * math.pi - 6.2])


def test_heading_from_points_cardinal_and_3d():
    rear = np.zeros((4, 3))
    front = np.array([[1, 0, 5], [0, 1, 0], [-1, 0, 0], [0, -1, -2]], dtype=float)
    np.testing.assert_allclose(heading_from_points(front, rear),
                               [0, math.pi / 2, math.pi, -math.pi / 2])
    assert heading_from_points([1.0, 1.0], [0.0, 0.0]) == pytest.approx(math.pi / 4)
    with pytest.raises(ValueError, match="front/rear"):
        heading_from_points(np.zeros((3, 4)), np.zeros((3, 4)))


def test_bearing_yaw_mapping():
    # North = bearing 0 = yaw pi/2; East = bearing pi/2 = yaw 0; West = bearing 3pi/2 = yaw pi
    assert yaw_from_bearing(0.0) == pytest.approx(math.pi / 2)
    assert yaw_from_bearing(math.pi / 2) == pytest.approx(0.0)
    assert yaw_from_bearing(3 * math.pi / 2) == pytest.approx(math.pi)
    assert bearing_from_yaw(math.pi / 2) == pytest.approx(0.0)
    assert bearing_from_yaw(-math.pi / 2) == pytest.approx(math.pi)
    y = np.linspace(-3, 3, 13)
    np.testing.assert_allclose(angle_diff(yaw_from_bearing(bearing_from_yaw(y)), y), 0, atol=1e-12)


def test_law_of_cosines_angle_hand_values():
    # 3-4-5 triangle: the angle opposite the hypotenuse is 90 degrees
    assert law_of_cosines_angle(3.0, 4.0, 5.0) == pytest.approx(math.pi / 2)
    # equilateral: 60 degrees
    assert law_of_cosines_angle(2.0, 2.0, 2.0) == pytest.approx(math.pi / 3)
    with pytest.raises(ValueError, match="triangle"):
        law_of_cosines_angle(1.0, 1.0, 3.0)


@pytest.mark.parametrize("vec, bearing", [
    ((1, 1), math.pi / 4),        # quadrant I (North-East): C
    ((1, -1), 3 * math.pi / 4),   # quadrant II (South-East): pi - C
    ((-1, -1), 5 * math.pi / 4),  # quadrant III (South-West): pi + C
    ((-1, 1), 7 * math.pi / 4),   # quadrant IV (North-West): 2 pi - C
    ((0, 1), 0.0), ((1, 0), math.pi / 2), ((0, -1), math.pi), ((-1, 0), 3 * math.pi / 2),
    ((math.sin(0.3), math.cos(0.3)), 0.3),
])
def test_quadrant_rules_hand_values(vec, bearing):
    """Figure 3.1's quadrants against hand-computed compass bearings (x east, y north)."""
    assert law_of_cosines_bearing(np.array(vec, float)) == pytest.approx(bearing, abs=1e-7)


@settings(max_examples=200, deadline=None)
@given(st.floats(-math.pi, math.pi), st.floats(-math.pi, math.pi), st.floats(0.05, 50))
def test_law_of_cosines_agrees_with_atan2(yaw, ref_yaw, length):
    """Relative to any reference, the construction reproduces the atan2 angle. Tolerance
    1e-6 rad: arccos loses precision near 0 and pi (derivative unbounded, error ~sqrt(eps))."""
    v = length * np.array([math.cos(yaw), math.sin(yaw)])
    r = np.array([math.cos(ref_yaw), math.sin(ref_yaw)])
    rel = law_of_cosines_bearing(v, r)  # clockwise from the reference
    assert 0 <= rel < 2 * math.pi
    assert abs(angle_diff(-rel, yaw - ref_yaw)) < 1e-6


def test_law_of_cosines_heading_sequence_relative_to_first():
    yaw = np.array([2.0, 2.5, 3.1, -3.1, -2.0, 0.0, np.nan, 1.0])
    side = np.c_[np.cos(yaw), np.sin(yaw)] * 1.5
    out = law_of_cosines_heading(side)
    assert np.isnan(out[6])
    ok = ~np.isnan(yaw)
    np.testing.assert_allclose(angle_diff(out[ok], yaw[ok]), 0, atol=1e-6)
    # a side that is not the body x axis: body angle removed
    body_angle = 0.4
    side2 = np.c_[np.cos(yaw + body_angle), np.sin(yaw + body_angle)]
    out2 = law_of_cosines_heading(side2, body_angle)
    np.testing.assert_allclose(angle_diff(out2[ok], yaw[ok]), 0, atol=1e-6)
    with pytest.raises(ValueError, match="side"):
        law_of_cosines_heading(np.zeros((3, 3)))
    assert np.isnan(law_of_cosines_heading(np.full((2, 2), np.nan))).all()


def test_unwrap_angle_skips_nan():
    a = wrap_angle(np.array([3.0, 3.1, np.nan, 3.3, 3.5]))
    u = unwrap_angle(a)
    assert np.isnan(u[2])
    np.testing.assert_allclose(u[[0, 1, 3, 4]], [3.0, 3.1, 3.3, 3.5])


def test_law_of_cosines_clips_rounding_and_refuses_non_triangles():
    """Rounding excess of |cos C| over 1 (up to the module's tolerance) is clipped, a larger
    excess raises. Sides a = 1, b = 2, c = 1 - d give cos C = 1 + d/2 - d^2/4, an excess of
    ~d/2: d = tol leaves tol/2 (clipped), d = 4 tol leaves 2 tol (refused)."""
    from estimator.orientation import _COS_EXCESS_TOL as tol

    assert law_of_cosines_angle(1.0, 2.0, 1.0 - tol) == 0.0
    with pytest.raises(ValueError, match="triangle"):
        law_of_cosines_angle(1.0, 2.0, 1.0 - 4.0 * tol)
    # a real triangle against the closed form (3-4-5: the right angle is opposite c = 5)
    assert law_of_cosines_angle(3.0, 4.0, 5.0) == pytest.approx(np.pi / 2, abs=1e-15)


@pytest.mark.parametrize("func", [yaw_from_bearing, bearing_from_yaw])
def test_bearing_conversions_keep_shapes(func):
    a = np.linspace(-7.0, 7.0, 12).reshape(3, 4)
    assert func(a).shape == (3, 4)
    assert isinstance(func(0.3), float)
