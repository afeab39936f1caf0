"""sim.paths: TOML schema validation, shipped paths, polyline geometry, tracking errors."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sim.paths import Path, PathError, available_paths, load_path, path_errors, project_to_polyline

GOOD = """
name = "{name}"
waypoints = [[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]]
closed = true
target_radius_m = 1.0
cruise_speed_mps = 1.0
"""


def write(tmp_path, text, name="p"):
    f = tmp_path / f"{name}.toml"
    f.write_text(text)
    return f


def test_shipped_paths_are_the_dissertation_squares():
    # Section 4.9: Path 1 and Path 2
    assert {"square100", "square200", "square20"} <= set(available_paths())
    for name, side in (("square100", 100.0), ("square200", 200.0), ("square20", 20.0)):
        p = load_path(name)
        assert p.closed and p.d == 2 and p.sample_rate_hz == 1.0
        np.testing.assert_array_equal(
            p.polyline, [[0, 0], [side, 0], [side, side], [0, side], [0, 0]])
        np.testing.assert_array_equal(p.corner_indices, [1, 2, 3])
        assert p.length_m == 4 * side
        assert Path.from_dict(p.to_dict(), source="rt").to_dict() == p.to_dict()


def test_load_by_file_and_defaults(tmp_path):
    p = load_path(write(tmp_path, GOOD.format(name="p")))
    assert p.sample_rate_hz == 1.0 and p.altitude_m is None and p.max_accel_mps2 is None
    assert load_path(p) is p
    np.testing.assert_array_equal(p.targets, [[10, 0], [10, 10], [0, 0]])


@pytest.mark.parametrize("edit, field", [
    ('\nspeed = 3', "speed"),                                        # unknown key
    ('\nsample_rate_hz = 0', "sample_rate_hz"),
    ('\nsample_rate_hz = "fast"', "sample_rate_hz"),
    ('\nmax_turn_rate_radps = -1', "max_turn_rate_radps"),
    ('\naltitude_m = nan', "altitude_m"),
])
def test_bad_fields_are_named(tmp_path, edit, field):
    f = write(tmp_path, GOOD.format(name="p") + edit)
    with pytest.raises(PathError, match=field) as exc:
        load_path(f)
    assert str(f) in str(exc.value)


@pytest.mark.parametrize("old, new, field", [
    ("target_radius_m = 1.0", "target_radius_m = 6.0", "target_radius_m"),   # areas overlap
    ("closed = true", "closed = 1", "closed"),
    ("[10.0, 10.0]]", "[10.0, 10.0], [0.0, 0.0]]", "repeats the start"),
    ("[10.0, 10.0]]", "[10.0, 10.0, 1.0]]", r"waypoints\[2\]"),
    ("[10.0, 10.0]]", "[10.0, 0.0]]", "coincide"),
    ("cruise_speed_mps = 1.0", "", "cruise_speed_mps"),                      # missing
])
def test_bad_structure_is_named(tmp_path, old, new, field):
    text = GOOD.format(name="p").replace(old, new)
    with pytest.raises(PathError, match=field):
        load_path(write(tmp_path, text))


def test_name_must_match_file_and_unknown_name_lists_known(tmp_path):
    with pytest.raises(PathError, match="stem"):
        load_path(write(tmp_path, GOOD.format(name="other"), name="p"))
    with pytest.raises(PathError, match="square100"):
        load_path("no_such_path")


finite = st.floats(-50, 50, allow_nan=False)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(finite, finite), min_size=2, max_size=6, unique=True),
       st.lists(st.tuples(finite, finite), min_size=1, max_size=5))
def test_projection_matches_dense_sampling(verts, pts):
    V = np.array(verts)
    if np.min(np.linalg.norm(np.diff(V, axis=0), axis=1)) < 1e-3:
        return
    P = np.array(pts)
    dist, seg, foot, s = project_to_polyline(P, V)
    # reference: 20001 samples per segment; the true distance is at most the sample's distance
    # and at least it minus half the sample spacing (spacing <= 142/20000 m here)
    u = np.linspace(0, 1, 20001)
    dense = np.concatenate([a + u[:, None] * (b - a) for a, b in itertools.pairwise(V)])
    ref = np.linalg.norm(P[:, None] - dense[None], axis=-1).min(axis=1)
    assert np.all(dist <= ref + 1e-9) and np.all(dist >= ref - 0.004)
    np.testing.assert_allclose(np.linalg.norm(P - foot, axis=1), dist, atol=1e-9)
    # the foot lies on its segment, and the arclength agrees with the segment position
    a, b = V[seg], V[seg + 1]
    cross = (b - a)[:, 0] * (foot - a)[:, 1] - (b - a)[:, 1] * (foot - a)[:, 0]
    assert np.all(np.abs(cross) <= 1e-6 * (1 + np.linalg.norm(b - a, axis=1) ** 2))
    cum = np.concatenate([[0], np.cumsum(np.linalg.norm(np.diff(V, axis=0), axis=1))])
    np.testing.assert_allclose(s, cum[seg] + np.linalg.norm(foot - a, axis=1), atol=1e-9)


def test_path_errors_on_a_synthetic_trajectory():
    p = load_path("square100")
    # exact square corners with a constant 0.05 m lateral offset on the straights, and a
    # 45-degree chamfer of the first corner that passes 2 m from the corner point
    x = np.linspace(0, 100, 1001)
    leg = np.c_[x, np.full_like(x, 0.05)]
    c = 2.0 * np.sqrt(2.0)
    chamfer = np.c_[np.linspace(100 - c, 100, 50), np.linspace(0, c, 50)]
    traj = np.vstack([leg[x < 100 - c], chamfer])
    e = path_errors(traj, p, corner_zone_m=12.0)
    np.testing.assert_allclose(e.straight_max_m, 0.05, atol=1e-12)
    np.testing.assert_allclose(e.cut_in_m[0], 2.0, atol=1e-3)   # chamfer sampled at 0.06 m
    # the sample at x = 88 m sits on the zone boundary (rounding decides its side)
    assert abs(e.n_straight - np.sum(x < 100 - 12.0)) <= 1
    np.testing.assert_allclose(e.closure_m, np.linalg.norm(traj[-1]))


@pytest.mark.parametrize("field, value", [
    ("cruise_speed_mps", 1e-300), ("cruise_speed_mps", 1e9), ("sample_rate_hz", 1e300),
    ("target_radius_m", 1e-300), ("max_accel_mps2", 1e12), ("lookahead_m", 1e-9)])
def test_physical_ranges_of_path_fields(field, value):
    """A value outside the physical range (a unit typo) would simulate for days or never
    move; it is refused naming the field (issue 13)."""
    from sim.paths import Path, load_path

    d = load_path("square20").to_dict()
    d[field] = value
    with pytest.raises(ValueError, match=f"{field} = .* outside its physical range"):
        Path.from_dict(d)


def test_route_longer_than_a_week_is_refused():
    from sim.paths import Path, load_path

    d = load_path("square20").to_dict()
    d["waypoints"] = [[0, 0], [1e6, 0], [1e6, 1e6]]
    d["cruise_speed_mps"] = 0.05
    with pytest.raises(ValueError, match="more than 7 days"):
        Path.from_dict(d)
