"""Layout outlines (experiments/outline.py): the convex hull, never an order by angle.

An antenna at the body origin has no angle; ordering by angle round the origin then crosses
the polygon (a bow-tie) whenever the origin is on the layout's edge. The hull is compared with
SciPy's Qhull on random layouts (general position: exactly the same vertex set)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial import ConvexHull

from experiments.outline import is_simple_polygon, layout_outline

#: An antenna at the origin (the reference point on the layout's rear edge), four ahead of it.
ORIGIN_ON_EDGE = np.array([[0.0, 0.0], [1.0, 1.0], [1.0, -1.0], [2.0, 0.2], [2.0, -0.2]])


def _area(poly: np.ndarray) -> float:
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def test_angle_order_crosses_and_the_hull_does_not():
    by_angle = np.argsort(np.arctan2(ORIGIN_ON_EDGE[:, 1], ORIGIN_ON_EDGE[:, 0]))
    assert not is_simple_polygon(ORIGIN_ON_EDGE[by_angle])        # the bow-tie of issue 23
    idx = layout_outline(ORIGIN_ON_EDGE)
    assert is_simple_polygon(ORIGIN_ON_EDGE[idx])
    assert sorted(idx) == sorted(ConvexHull(ORIGIN_ON_EDGE).vertices)
    assert idx == [0, 2, 4, 3, 1]                   # from the smallest x, counter-clockwise
    assert not is_simple_polygon([[0, 0], [1, 1], [1, 0], [0, 1]])              # a bow-tie


def test_antenna_at_the_origin_inside_is_a_point_not_a_corner():
    rover = np.array([[0.0, 0.0], [0.75, 0.5], [0.75, -0.5], [-0.75, 0.5], [-0.75, -0.5]])
    idx = layout_outline(rover)
    assert 0 not in idx and sorted(idx) == [1, 2, 3, 4] and is_simple_polygon(rover[idx])


@pytest.mark.parametrize("pts, want", [([[1.0, 2.0]], [0]), ([[1.0, 2.0], [1.0, 2.0]], [0]),
                                        ([[0, 0], [2, 2], [1, 1]], [0, 1]),
                                        ([[0, 0], [1, 0], [2, 0], [1, 1]], [0, 2, 3])])
def test_degenerate_layouts(pts, want):
    assert layout_outline(pts) == want


@pytest.mark.parametrize("pts, match", [(np.zeros((0, 2)), "points"), (np.zeros(3), "points"),
                                         (np.zeros((3, 3)), "points"),
                                         ([[0, 0], [1, np.nan]], r"points\[1\]")])
def test_bad_points_are_named(pts, match):
    with pytest.raises(ValueError, match=match):
        layout_outline(pts)


@given(st.integers(3, 12), st.integers(0, 2**32 - 1), st.booleans(), st.floats(0.01, 1e3))
def test_hull_is_simple_ccw_contains_every_point_and_matches_qhull(m, seed, origin, scale):
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(m, 2)) * scale
    if origin:
        p[0] = 0.0
    idx = layout_outline(p)
    poly = p[idx]
    assert is_simple_polygon(poly) and _area(poly) > 0                  # simple, counter-clockwise
    for a, b in zip(poly, np.roll(poly, -1, axis=0)):                   # every point on the left
        cross = (b[0] - a[0]) * (p[:, 1] - a[1]) - (b[1] - a[1]) * (p[:, 0] - a[0])
        assert (cross >= -1e-9 * scale**2).all()
    assert sorted(idx) == sorted(ConvexHull(p).vertices)       # normal draws: general position


def test_stationary_figures_outline_is_the_hull():
    """experiments.stationary_figures draws the configuration polygon along the hull (it
    ordered the antennas by angle round their mean) and every antenna as a marker."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from experiments.stationary_figures import _config_poly

    fig, ax = plt.subplots()
    try:
        _config_poly(ax, ORIGIN_ON_EDGE, list(range(5)), "k", "truth")
        line, dots = ax.get_lines()
        hull = layout_outline(ORIGIN_ON_EDGE)
        np.testing.assert_array_equal(line.get_xydata(), ORIGIN_ON_EDGE[hull + hull[:1]])
        assert is_simple_polygon(line.get_xydata()[:-1]) and len(dots.get_xdata()) == 5
    finally:
        plt.close(fig)
