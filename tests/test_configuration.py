"""SensorConfig: distances, MDS recovery, TOML loading and validation, handedness and the
layout check."""

import math
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimator.configuration import CONFIGS_DIR, ConfigError, LayoutWarning, SensorConfig


def test_default_rover_config_matches_dissertation_layout():
    cfg = SensorConfig.load("rover_gps8")
    assert cfg.names == tuple("12345678")
    assert cfg.dead == ("4",)
    assert cfg.cg_members == ("2", "3", "6", "7")
    np.testing.assert_allclose(cfg.cg_body, [0.0, 0.0], atol=1e-15)
    D = cfg.distances()
    assert D.shape == (8, 8)
    assert D[0, 1] == pytest.approx(0.5)       # front-left to front-centre
    assert D[0, 7] == pytest.approx(np.hypot(1.5, 1.0))  # diagonal corner to corner
    assert cfg.mount_height_m == pytest.approx(0.6)


def test_cg_from_positions_is_mean_of_members():
    cfg = SensorConfig.load(CONFIGS_DIR / "rover_gps8.toml")
    pos = np.arange(16.0).reshape(8, 2)
    np.testing.assert_allclose(cfg.cg_from_positions(pos), pos[[1, 2, 5, 6]].mean(0))
    batched = np.stack([pos, pos + 1])
    np.testing.assert_allclose(cfg.cg_from_positions(batched)[1], pos[[1, 2, 5, 6]].mean(0) + 1)


def _pairwise(x):
    return np.sqrt(((x[:, None] - x[None]) ** 2).sum(-1))


@settings(max_examples=60, deadline=None)
@given(
    m=st.integers(3, 9),
    d=st.sampled_from([2, 3]),
    seed=st.integers(0, 2**32 - 1),
)
def test_from_distances_recovers_distances(m, d, seed):
    rng = np.random.default_rng(seed)
    X = rng.uniform(-5, 5, size=(m, d))
    D = _pairwise(X)
    cfg = SensorConfig.from_distances([f"s{k}" for k in range(m)], D, d=d)
    # tolerance: MDS is exact in exact arithmetic; eigen-decomposition error ~1e-12 * scale
    np.testing.assert_allclose(cfg.distances(), D, atol=1e-8)
    assert cfg.d == d


def test_from_distances_rejects_bad_matrices():
    names = ["a", "b", "c"]
    good = _pairwise(np.array([[0, 0], [1, 0], [0, 1.0]]))
    with pytest.raises(ConfigError, match="D: expected shape"):
        SensorConfig.from_distances(names, good[:2, :2])
    asym = good.copy()
    asym[0, 1] += 0.5
    with pytest.raises(ConfigError, match="not symmetric.*'a', 'b'"):
        SensorConfig.from_distances(names, asym)
    neg = good.copy()
    neg[0, 1] = neg[1, 0] = -1
    with pytest.raises(ConfigError, match="negative distance"):
        SensorConfig.from_distances(names, neg)
    tri = np.array([[0, 1, 5], [1, 0, 1], [5, 1, 0.0]])
    with pytest.raises(ConfigError, match="triangle inequality.*'a', 'c'"):
        SensorConfig.from_distances(names, tri)
    # four points with all pairwise distances 1: a regular tetrahedron, not planar
    tet = np.ones((4, 4)) - np.eye(4)
    with pytest.raises(ConfigError, match="not realizable in 2 dimensions"):
        SensorConfig.from_distances(list("abcd"), tet, d=2)
    SensorConfig.from_distances(list("abcd"), tet, d=3)  # realizable in 3-D
    diag = good.copy()
    diag[1, 1] = 0.3
    with pytest.raises(ConfigError, match="diagonal entry for 'b'"):
        SensorConfig.from_distances(names, diag)
    nan = good.copy()
    nan[0, 2] = np.nan
    with pytest.raises(ConfigError, match="not finite"):
        SensorConfig.from_distances(names, nan)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(names=["a", "a"], body_positions=[[0, 0], [1, 0]]), "names: duplicate"),
        (dict(names=["a"], body_positions=[[0, 0]]), "at least 2 sensors"),
        (dict(names=["a", "b"], body_positions=[[0, 0, 0, 0], [1, 0, 0, 0]]), "dimension d"),
        (dict(names=["a", "b"], body_positions=[[0, 0], [0, 0]]), "coincide"),
        (dict(names=["a", "b"], body_positions=[[0, np.nan], [1, 0]]), "non-finite"),
        (dict(names=["a", "b", "c"], body_positions=[[0, 0], [1, 0], [0, 1]], dead=["z"]),
         "dead: unknown sensor 'z'"),
        (dict(names=["a", "b", "c"], body_positions=[[0, 0], [1, 0], [0, 1]], cg_members=[]),
         "cg_members: must name"),
        (dict(names=["a", "b", "c"], body_positions=[[0, 0], [1, 0], [0, 1]], dead=["a", "b"]),
         "dead: at most"),
    ],
)
def test_constructor_validation(kwargs, match):
    with pytest.raises(ConfigError, match=match):
        SensorConfig(**kwargs)


def _write(tmp_path, text):
    p = tmp_path / "c.toml"
    p.write_text(text)
    return p


@pytest.mark.parametrize(
    "text, match",
    [
        ("colour = 'red'\n[[sensor]]\nname='a'\nposition_m=[0,0]\n",
         r"unknown key\(s\) \['colour'\]"),
        ("name = 'x'\n", "'sensor' must be a non-empty array"),
        ("[[sensor]]\nname='a'\nposition_m=[0]\n[[sensor]]\nname='b'\nposition_m=[1,0]\n",
         r"sensor\[0\].position_m"),
        ("[[sensor]]\nname='a'\nposition_m=[0,0]\n[[sensor]]\nname='b'\nposition_m=[1,0,0]\n",
         r"sensor\[1\].position_m: has 3 coordinates"),
        ("[[sensor]]\nposition_m=[0,0]\n", r"sensor\[0\].name: missing"),
        ("[[sensor]]\nname='a'\nposition_m=[0,0]\nheight=3\n", r"sensor\[0\]: unknown key"),
        ("mount_height_m = -1\n[[sensor]]\nname='a'\nposition_m=[0,0]\n", "mount_height_m"),
        ("dead = 'a'\n[[sensor]]\nname='a'\nposition_m=[0,0]\n", "dead must be a list"),
        ("[[sensor\n", "not valid TOML"),
    ],
)
def test_toml_validation_names_the_field(tmp_path, text, match):
    with pytest.raises(ConfigError, match=match):
        SensorConfig.load(_write(tmp_path, text))


def test_load_unknown_name_lists_known():
    with pytest.raises(ConfigError, match="known names: .*rover_gps8"):
        SensorConfig.load("no_such_config")


def test_planar_projection():
    cfg = SensorConfig(["a", "b", "c"], [[0, 0, 1], [1, 0, 1], [0, 1, 2]], dead=["c"])
    p = cfg.planar()
    assert p.d == 2 and p.dead == ("c",)
    np.testing.assert_array_equal(p.body_positions, [[0, 0], [1, 0], [0, 1]])


def test_model_files_resolution_and_errors(tmp_path):
    from estimator.model_files import MODELS_DIR, read_model_toml, resolve_model_file

    folder = MODELS_DIR / "configs"
    assert resolve_model_file("rover_gps8", folder, "config") == folder / "rover_gps8.toml"
    # a name with a directory part or a suffix is a file path, never looked up in the folder
    own = tmp_path / "rover_gps8.toml"
    own.write_text('name = "x"\n')
    assert read_model_toml(own, folder, "config") == ({"name": "x"}, own)
    with pytest.raises(ConfigError, match=r"config: no such file 'sub/rover_gps8'"):
        resolve_model_file("sub/rover_gps8", folder, "config", error=ConfigError)
    bad = tmp_path / "bad.toml"
    bad.write_text("[[sensor\n")
    with pytest.raises(ValueError, match=r"bad\.toml: not valid TOML"):
        read_model_toml(bad, folder, "config")
    deep = tmp_path / "deep.toml"
    deep.write_text("a = " + "[" * 3000 + "]" * 3000 + "\n")
    with pytest.raises(ConfigError, match=r"deep\.toml: not usable TOML: .*nested too deeply"):
        read_model_toml(deep, folder, "config", error=ConfigError)


def test_one_rule_for_files_named_inside_a_file(tmp_path):
    """Issue 24: a file named inside a spec or recording (``base`` = its folder) resolves
    against that folder, then the project, and never outside them and the shared data."""
    from estimator.model_files import MODELS_DIR, PROJECT_DIR, resolve_model_file

    (tmp_path / "sub").mkdir()
    mine = tmp_path / "mine.toml"
    mine.write_text('name = "x"\n')
    base = tmp_path / "sub"
    assert resolve_model_file("mine.toml", None, "f", base=tmp_path) == mine.resolve()
    assert resolve_model_file(str(mine), None, "f", base=tmp_path) == mine.resolve()
    # the project is the second place a relative name is looked up
    rel = "models/configs/rover_gps8.toml"
    assert resolve_model_file(rel, None, "f", base=base) == (PROJECT_DIR / rel).resolve()
    for bad in ("../mine.toml", str(mine), "../../../../../../../../etc/hostname",
                "/etc/hostname"):
        with pytest.raises(ConfigError, match=r"f: .* leaves the folder of the file naming"):
            resolve_model_file(bad, None, "f", base=base, error=ConfigError)
    # a symbolic link inside the folder that points outside it is outside
    (base / "link.toml").symlink_to("/etc/hostname")
    with pytest.raises(ConfigError, match="leaves the folder"):
        resolve_model_file("link.toml", None, "f", base=base, error=ConfigError)
    with pytest.raises(ConfigError, match=r"f: no such file 'nope.toml'"):
        resolve_model_file("nope.toml", None, "f", base=base, error=ConfigError)
    with pytest.raises(ConfigError, match=r"f: must be a file name or path"):
        resolve_model_file(3, MODELS_DIR / "configs", "f", base=base, error=ConfigError)


# --------------------------------------------------------------------------- issue 13 classes
@pytest.mark.parametrize("kwargs, exc, match", [
    (dict(names=["a", "b"], body_positions=[[0, 0], [1e200, 0]]), ConfigError, "MAX_BODY_M"),
    (dict(names=[], body_positions=np.zeros((0, 2))), ConfigError, "at least 2 sensors"),
    (dict(names=["a", "b"], body_positions=[[0, 0], [1, 0]], mount_height_m=-1), ConfigError,
     "mount_height_m"),
    (dict(names=["a", "b"], body_positions=[[0, 0], [1, 0]], mount_height_m="1"), TypeError,
     "mount_height_m"),
    (dict(names=["a", "b"], body_positions=[["x", 0], [1, 0]]), TypeError, "body_positions"),
    (dict(names="ab", body_positions=[[0, 0], [1, 0]]), TypeError, "names"),
    (dict(names=["a", "b"], body_positions=[[0, 0], [1, 0]], dead="a"), TypeError, "dead"),
])
def test_constructor_rejects_the_issue_13_classes(kwargs, exc, match):
    with pytest.raises(exc, match=match):
        SensorConfig(**kwargs)


def _square():
    return _pairwise(np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]))


@pytest.mark.parametrize("kwargs, exc, match", [
    (dict(D=_square() * 1e200), ConfigError, "MAX_BODY_M"),
    (dict(D=_square(), tol_m=math.nan), ValueError, "tol_m"),
    (dict(D=_square(), tol_m=math.inf), ValueError, "tol_m"),
    (dict(D=_square(), tol_m=-0.1), ValueError, "tol_m"),
    (dict(D=_square(), d=2.0), TypeError, "d: must be an integer"),
    (dict(D=_square(), d=4), ConfigError, "d: must be 2 or 3"),
    (dict(D=_square(), rtol=1e-6), TypeError, "rtol"),
    (dict(D=np.ones((4, 4)) - np.eye(4), tol_m=math.inf), ValueError, "tol_m"),
    (dict(D=[["a"] * 4] * 4), TypeError, "D: must be a numeric array"),
])
def test_from_distances_rejects_the_issue_13_classes(kwargs, exc, match):
    with pytest.raises(exc, match=match):
        SensorConfig.from_distances(list("abcd"), forward="b", left="d", **kwargs)


def test_from_distances_needs_two_names():
    with pytest.raises(ConfigError, match="at least 2 sensors"):
        SensorConfig.from_distances([], np.zeros((0, 0)))


# --------------------------------------------------------------------------- tolerance
@pytest.mark.parametrize("name", ["rover_gps8", "rover_gps4"])
def test_cm_level_measured_distances_pass_the_default_tolerance(name):
    """Distances with 1 cm (std) independent errors, 50 draws: all accepted by the default
    tol_m (DISTANCE_TOL_M = 0.05 m), and the embedding reproduces them within it. (1.5 cm
    errors also all passed in 500 draws; 2 cm failed 2 % of rover_gps8 draws: the default
    is for cm-level instruments, see its comment.)"""
    from estimator.configuration import DISTANCE_TOL_M

    cfg = SensorConfig.load(name)
    D = cfg.distances()
    rng = np.random.default_rng(11)
    for _ in range(50):
        E = np.triu(rng.normal(0.0, 0.01, D.shape), 1)
        Dn = D + E + E.T
        got = SensorConfig.from_distances(cfg.names, Dn, forward=cfg.names[1], left=cfg.names[0])
        assert np.abs(got.distances() - Dn).max() <= DISTANCE_TOL_M


def test_a_gross_distance_error_is_rejected_naming_the_pair():
    cfg = SensorConfig.load("rover_gps8")
    D = cfg.distances()
    D[0, 7] += 0.2
    D[7, 0] += 0.2
    with pytest.raises(ConfigError, match=r"worst pair \('1', '8'\)"):
        SensorConfig.from_distances(cfg.names, D, forward="2", left="1")


def test_least_squares_embedding_beats_classical_mds():
    """With noisy distances the refined embedding's stress is at most MDS's (independent
    reference: scipy's generic minimizer on the same stress from the MDS start)."""
    from scipy.optimize import minimize

    from estimator.configuration import _embed, _refine_embedding

    cfg = SensorConfig.load("rover_gps8")
    rng = np.random.default_rng(3)
    E = np.triu(rng.normal(0.0, 0.02, (8, 8)), 1)
    D = cfg.distances() + E + E.T
    iu = np.triu_indices(8, 1)

    def stress(x):
        X = x.reshape(8, 2)
        return float(((_pairwise(X)[iu] - D[iu]) ** 2).sum())

    X0 = _embed(D, 2)
    X1 = _refine_embedding(X0, D)
    ref = minimize(stress, X0.ravel(), method="BFGS", options={"gtol": 1e-12})
    assert stress(X1.ravel()) <= stress(X0.ravel())
    # both reach the same minimum to 1e-9 m^2 (BFGS's stopping tolerance)
    assert stress(X1.ravel()) == pytest.approx(ref.fun, abs=1e-9)


# --------------------------------------------------------------------------- handedness
def _random_layout(seed: int, m: int = 5) -> SensorConfig:
    """Sensors 'r' and 'f' on a line along body x (rear, front), others anywhere, CG = all
    at the origin; sensor 's2' at least 0.3 m left of the CG (body y > 0.3)."""
    rng = np.random.default_rng(seed)
    B = np.vstack([[-1.0, 0.0], [1.0, 0.0], rng.uniform(-2, 2, (m - 2, 2))])
    B -= B.mean(axis=0)
    if B[2, 1] < 0.3:        # raise s2 so that it sits at y = 0.3 after re-centring
        B[2, 1] += (0.3 - B[2, 1]) * m / (m - 1)
        B -= B.mean(axis=0)
    return SensorConfig(["r", "f", *[f"s{k}" for k in range(2, m)]], B)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), m=st.integers(3, 8))
def test_forward_and_left_fix_the_frame_exactly(seed, m):
    """Noise-free distances: the named rear/front pair and left sensor give back the body
    layout itself, whichever hand the embedding came out in (1e-8 m: eigen round-off)."""
    cfg = _random_layout(seed, m)
    got = SensorConfig.from_distances(cfg.names, cfg.distances(), forward=("r", "f"),
                                      left="s2")
    np.testing.assert_allclose(got.body_positions, cfg.body_positions, atol=1e-8)
    # a single name: +x from the CG to it (no left: the hand stays open, and says so)
    with pytest.warns(LayoutWarning, match="handedness"):
        one = SensorConfig.from_distances(cfg.names, cfg.distances(), forward="f")
    v = one.body_positions[1]
    assert abs(v[1]) < 1e-8 and v[0] > 0


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), heading=st.floats(-math.pi, math.pi),
       mirror=st.booleans())
def test_observed_positions_and_heading_fix_the_frame(seed, heading, mirror):
    """World positions = R(heading) b + c (+ 1 cm noise): the recovered layout is b (the
    observation decides the hand: a mirrored world gives the mirrored layout)."""
    cfg = _random_layout(seed)
    B = cfg.body_positions.copy()
    if mirror:
        B[:, 1] = -B[:, 1]
    rng = np.random.default_rng(seed)
    c, s = math.cos(heading), math.sin(heading)
    W = B @ np.array([[c, -s], [s, c]]).T + [512000.0, 4400000.0] + rng.normal(0, 0.01, B.shape)
    got = SensorConfig.from_distances(cfg.names, cfg.distances(), observed=W, heading=heading)
    # 1 cm observation noise moves the fitted rotation by ~1e-2 / 2 m; the layout (exact
    # distances) is rotated by at most that: < 0.05 m at 3 m from the CG
    assert np.abs(got.body_positions - B).max() < 0.05
    assert "observed positions" in got.description


def test_frame_errors_and_warnings():
    cfg = _random_layout(1)
    D = cfg.distances()
    with pytest.warns(LayoutWarning, match="arbitrary"):
        SensorConfig.from_distances(cfg.names, D)
    with pytest.warns(LayoutWarning, match="handedness"):
        SensorConfig.from_distances(cfg.names, D, forward=("r", "f"))
    with pytest.raises(ConfigError, match="left: needs forward"):
        SensorConfig.from_distances(cfg.names, D, left="s2")
    r8 = SensorConfig.load("rover_gps8")
    with pytest.raises(ConfigError, match="left: sensor '2' lies"):     # on the centre line
        SensorConfig.from_distances(r8.names, r8.distances(), forward=("7", "2"), left="2",
                                    cg_members=r8.cg_members)
    with pytest.raises(ConfigError, match="unknown sensor 'zz'"):
        SensorConfig.from_distances(cfg.names, D, forward="zz", left="s2")
    with pytest.raises(ConfigError, match="not both"):
        SensorConfig.from_distances(cfg.names, D, forward="f", observed=np.zeros((5, 2)),
                                    heading=0.0)
    with pytest.raises(ConfigError, match="observed and heading"):
        SensorConfig.from_distances(cfg.names, D, observed=cfg.body_positions)
    with pytest.raises(ValueError, match="heading"):
        SensorConfig.from_distances(cfg.names, D, observed=cfg.body_positions, heading=math.nan)
    with pytest.raises(ConfigError, match="observed: expected shape"):
        SensorConfig.from_distances(cfg.names, D, observed=np.zeros((4, 2)), heading=0.0)
    two = np.full((5, 2), np.nan)
    two[:2] = cfg.body_positions[:2]
    with pytest.raises(ConfigError, match="at least 3"):
        SensorConfig.from_distances(cfg.names, D, observed=two, heading=0.0)
    tet = np.ones((4, 4)) - np.eye(4)
    with pytest.raises(ConfigError, match="d = 2 layout only|2-D layout only"):
        SensorConfig.from_distances(list("abcd"), tet, d=3, forward="a", left="b")
    noisy = cfg.body_positions + np.random.default_rng(0).normal(0, 3.0, (5, 2))
    with pytest.warns(LayoutWarning, match="barely prefer"):
        SensorConfig.from_distances(cfg.names, D, observed=noisy, heading=0.0)


def test_to_dict_round_trips():
    cfg = SensorConfig.load("rover_gps8")
    back = SensorConfig.from_dict(cfg.to_dict())
    assert back.names == cfg.names and back.dead == cfg.dead
    assert back.cg_members == cfg.cg_members and back.mount_height_m == cfg.mount_height_m
    np.testing.assert_array_equal(back.body_positions, cfg.body_positions)


# --------------------------------------------------------------------------- extremes
_EXTREME = st.one_of(st.floats(allow_nan=True, allow_infinity=True),
                     st.sampled_from([0.0, -0.0, 1e-300, 1e300, -1e300, 1e6, 1e7, math.nan]))


@settings(max_examples=80, deadline=None)
@given(st.lists(st.tuples(_EXTREME, _EXTREME), min_size=0, max_size=6),
       _EXTREME)
def test_constructor_extremes_raise_or_give_finite_distances(pts, height):
    names = [f"s{k}" for k in range(len(pts))]
    try:
        cfg = SensorConfig(names, np.array(pts, dtype=float).reshape(-1, 2),
                           mount_height_m=height)
    except (ConfigError, TypeError, ValueError) as exc:
        assert any(k in str(exc) for k in ("body_positions", "names", "mount_height_m"))
        return
    assert np.isfinite(cfg.distances()).all() and cfg.mount_height_m >= 0


@settings(max_examples=80, deadline=None)
@given(m=st.integers(0, 6), fill=_EXTREME, tol=_EXTREME, seed=st.integers(0, 1000))
def test_from_distances_extremes_raise_or_embed_within_tolerance(m, fill, tol, seed):
    rng = np.random.default_rng(seed)
    X = rng.uniform(-3, 3, (m, 2))
    D = _pairwise(X)
    if m >= 2 and rng.random() < 0.5:
        i, j = rng.choice(m, 2, replace=False)
        D[i, j] = D[j, i] = fill
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", LayoutWarning)
            cfg = SensorConfig.from_distances([f"s{k}" for k in range(m)], D, tol_m=tol)
    except (ConfigError, TypeError, ValueError) as exc:
        assert any(k in str(exc) for k in ("D:", "tol_m", "names", "body_positions"))
        return
    assert np.abs(cfg.distances() - D).max() <= tol + 1e-6


_VALUES = st.one_of(st.none(), st.booleans(), st.integers(-10, 10), _EXTREME, st.text(max_size=3),
                    st.lists(_EXTREME, max_size=4))


@settings(max_examples=80, deadline=None)
@given(st.dictionaries(st.sampled_from(["name", "description", "mount_height_m", "cg_sensors",
                                        "dead", "sensor", "colour"]), _VALUES, max_size=5),
       st.lists(st.dictionaries(st.sampled_from(["name", "position_m", "height"]), _VALUES,
                                max_size=3), max_size=4))
def test_from_dict_extremes_raise_config_errors(data, sensors):
    if sensors:
        data = {**data, "sensor": sensors}
    try:
        cfg = SensorConfig.from_dict(data)
    except (ConfigError, TypeError) as exc:
        assert str(exc)
        return
    assert np.isfinite(cfg.body_positions).all()


# --------------------------------------------------------------------------- layout check
def test_layout_check_verdicts_on_a_known_track():
    """A straight run with a turn (rover_gps8, 0.05 m errors): the right layout is
    consistent, its mirror image is "mirrored", a layout rotated by 90 degrees or reversed
    is "not forward"; standing still the forward check does not apply."""
    from synth_tracks import corner_path

    from estimator.layout_check import check_layout

    cfg, t, _cg, _yaw, _turning, obs = corner_path()
    rng = np.random.default_rng(0)
    noisy = obs + rng.normal(0.0, 0.05, obs.shape)
    ok = check_layout(t, noisy, cfg, window=5)
    assert (ok.mirror_verdict, ok.forward_verdict) == ("consistent", "consistent")
    assert ok.warnings == () and abs(ok.forward_offset_rad) < 0.1
    B = cfg.body_positions
    mir = SensorConfig(cfg.names, B * [1, -1], cfg.cg_members, cfg.dead)
    rot = SensorConfig(cfg.names, B @ np.array([[0, -1], [1, 0]]).T, cfg.cg_members, cfg.dead)
    back = SensorConfig(cfg.names, -B, cfg.cg_members, cfg.dead)
    lm = check_layout(t, noisy, mir, window=5)
    assert lm.mirror_verdict == "mirrored" and lm.warnings[0].startswith("layout may be mirrored")
    lr = check_layout(t, noisy, rot, window=5)
    assert lr.forward_verdict == "not_forward"
    assert math.degrees(lr.forward_offset_rad) == pytest.approx(-90, abs=5)
    lb = check_layout(t, noisy, back, window=5)
    assert lb.forward_verdict == "not_forward" and abs(lb.forward_offset_rad) > 3.0
    still = np.broadcast_to(noisy[:1], noisy.shape) + rng.normal(0, 0.05, noisy.shape)
    ls = check_layout(t, still, cfg, window=5)
    assert ls.forward_verdict == "not_applicable" and ls.n_moving == 0


def test_layout_check_with_metre_errors_is_undetermined_not_alarmed():
    """Errors much larger than the platform (2 m independent): neither hand explains the
    data better by the factor 2 (module docstring), so no "mirrored" claim either way."""
    from synth_tracks import straight

    from estimator.layout_check import check_layout

    cfg, t, _cg, _yaw, obs = straight(n=400)
    rng = np.random.default_rng(1)
    noisy = obs + rng.normal(0.0, 2.0, obs.shape)
    for c in (cfg, SensorConfig(cfg.names, cfg.body_positions * [1, -1], cfg.cg_members,
                                cfg.dead)):
        assert check_layout(t, noisy, c, window=10).mirror_verdict == "undetermined"


@settings(max_examples=40, deadline=None)
@given(window=st.sampled_from([0, 1, 5, 10**9, 2.0, None]),
       fill=st.sampled_from([math.nan, math.inf, 1e300, 0.0]),
       span=st.sampled_from([8.0, 0.0, -1.0, math.nan, math.inf]))
def test_layout_check_extremes(window, fill, span):
    from synth_tracks import straight

    from estimator.layout_check import check_layout

    cfg, t, _cg, _yaw, obs = straight(n=30)
    obs = obs.copy()
    obs[3] = fill
    try:
        out = check_layout(t, obs, cfg, window=window, span_s=span)
    except (ValueError, TypeError) as exc:
        assert any(k in str(exc) for k in ("window", "obs", "span_s"))
        return
    assert out.mirror_verdict in ("consistent", "mirrored", "undetermined", "not_applicable")
    assert out.to_dict()["warnings"] == list(out.warnings)


# --------------------------------------------------------------------------- issue 23
# from_distances
def _noisy_layout(m: int, seed: int = 0, sigma: float = 0.001) -> tuple[list[str], np.ndarray]:
    rng = np.random.default_rng(seed)
    X = rng.uniform(0.0, 5.0, (m, 2))
    D = np.hypot(*(X[:, None] - X[None]).transpose(2, 0, 1))
    E = np.triu(rng.normal(0.0, sigma, (m, m)), 1)
    return [f"s{i}" for i in range(m)], D + E + E.T


@pytest.mark.parametrize("forward, left", [(("b", "a"), "a"), (("b", "a"), "b"), ("a", "a")])
def test_left_on_the_forward_axis_is_refused(forward, left):
    # before: with a (rear, front) pair off the CG, one of the pair itself was accepted as
    # "left" and the hand followed where the CG lay
    c = SensorConfig(list("abcd"), [[1, 0], [-1, 0.5], [-1, -0.5], [0, 1]])
    with pytest.raises(ConfigError, match=r"left: sensor '.' lies on the forward axis"):
        SensorConfig.from_distances(c.names, c.distances(), forward=forward, left=left)


def test_from_distances_250_sensors_is_fast_and_quadratic_in_memory():
    import time
    import tracemalloc

    names, D = _noisy_layout(250)
    tracemalloc.start()
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LayoutWarning)
        got = SensorConfig.from_distances(names, D)
    elapsed = time.perf_counter() - t0
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    # before: 24 s and m^3 arrays (250^3 x 8 B = 125 MB for the triangle check alone, plus
    # a dense (m^2/2, 2m) Jacobian); now ~0.2 s and ~16 MB measured. Bounds with room for
    # a loaded machine: 2 s (the brief's target) x 2.5, 60 MB
    assert elapsed < 5.0, elapsed
    assert peak < 60e6, peak
    resid = np.abs(got.distances() - D)
    assert resid.max() < 0.01                       # 1 mm noise, least-squares fit


def test_from_distances_bounds_the_number_of_sensors():
    from estimator.configuration import MAX_DISTANCE_SENSORS

    names = [f"s{i}" for i in range(MAX_DISTANCE_SENSORS + 1)]
    with pytest.raises(ConfigError, match="names: from_distances takes at most"):
        SensorConfig.from_distances(names, np.zeros((len(names), len(names))))


def test_sparse_refinement_matches_the_dense_least_squares_optimum():
    # the cost of the least-squares embedding (the dense exact solve before the change gave
    # 1.7784249316247922e-05 in units of max(D) on this layout; relative 1e-9)
    from estimator.configuration import _embed, _refine_embedding

    _, D = _noisy_layout(60)
    X = _refine_embedding(_embed(D, 2), D)
    diff = X[:, None] - X[None]
    iu = np.triu_indices(60, 1)
    cost = 0.5 * float((((np.sqrt((diff**2).sum(-1)) - D) / D.max())[iu] ** 2).sum())
    assert cost == pytest.approx(1.7784249316247922e-05, rel=1e-9)


# --------------------------------------------------------------------------- [platform]
def test_platform_block_is_read_validated_and_round_trips():
    from estimator.platform import PlatformLimits

    car = SensorConfig.load("car_rtk4")
    assert isinstance(car.platform, PlatformLimits)
    assert (car.platform.max_speed_mps, car.platform.max_accel_mps2,
            car.platform.max_turn_rate_radps) == (40.0, 6.0, 1.0)
    # the rover's block is the pose filter's limits before issue 25 (0.5 m/s^2, 1 rad/s^2,
    # 0.8 rad/s, 0.8 m/s^2), so a recording with the rover layout keeps them
    for name in ("rover_gps4", "rover_gps8"):
        lim = SensorConfig.load(name).platform.to_dict()
        assert {k: lim[k] for k in ("max_accel_mps2", "max_yaw_accel_radps2",
                                    "max_turn_rate_radps", "max_lateral_accel_mps2")} == {
            "max_accel_mps2": 0.5, "max_yaw_accel_radps2": 1.0, "max_turn_rate_radps": 0.8,
            "max_lateral_accel_mps2": 0.8}
    assert SensorConfig.load("home_square4").platform is None      # absent: from the data
    back = SensorConfig.from_dict(car.to_dict())
    assert back.platform == car.platform
    assert car.planar().platform == car.platform


@pytest.mark.parametrize("block, match", [
    ({"max_speed_mps": 10.0, "max_accel_mps2": 2.0}, r"platform\.max_turn_rate_radps: required"),
    ({"max_speed_mps": -1.0, "max_accel_mps2": 2.0, "max_turn_rate_radps": 1.0},
     r"platform\.max_speed_mps: must be in .*-1"),
    ({"max_speed_mps": 10.0, "max_accel_mps2": "fast", "max_turn_rate_radps": 1.0},
     r"platform\.max_accel_mps2: must be a number, got 'fast'"),
    ({"max_speed_mps": 10.0, "max_accel_mps2": 2.0, "max_turn_rate_radps": 1.0,
      "max_yaw_rate_degps": 30}, r"platform\.max_yaw_rate_degps: unknown key"),
    ("fast", r"platform: must be a table"),
])
def test_platform_block_errors_name_the_field(block, match):
    data = {"name": "x", "sensor": [{"name": "a", "position_m": [0.5, 0.0]},
                                    {"name": "b", "position_m": [-0.5, 0.0]}],
            "platform": block}
    with pytest.raises(ConfigError, match=match) as ei:
        SensorConfig.from_dict(data, source="cfg.toml")
    assert str(ei.value).startswith("cfg.toml: platform")       # the file once, then the field
    with pytest.raises(ConfigError, match="platform: expected"):
        SensorConfig(["a", "b"], [[0.5, 0.0], [-0.5, 0.0]], platform={"max_speed_mps": 1})
