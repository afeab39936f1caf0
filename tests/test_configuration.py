"""SensorConfig: distances, MDS recovery, TOML loading and validation."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimator.configuration import CONFIGS_DIR, ConfigError, SensorConfig


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
        ("colour = 'red'\n[[sensor]]\nname='a'\nposition_m=[0,0]\n", r"unknown key\(s\) \['colour'\]"),
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
    with pytest.raises(ConfigError, match=r"config 'sub/rover_gps8': no such file"):
        resolve_model_file("sub/rover_gps8", folder, "config", error=ConfigError)
    bad = tmp_path / "bad.toml"
    bad.write_text("[[sensor\n")
    with pytest.raises(ValueError, match=r"bad\.toml: not valid TOML"):
        read_model_toml(bad, folder, "config")
