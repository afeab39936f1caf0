"""Experiment specs: validation errors name the field, grid expansion, cell identity."""

import shutil
import textwrap
from pathlib import Path

import pytest

from experiments.spec import NO_SOLVER, NO_WEIGHTS, Spec, SpecError, available_presets, load_spec

REPO = Path(__file__).resolve().parents[1]

BASE = {
    "name": "t",
    "seeds": 2,
    "defaults": {"noise": "none"},
    "grid": [{"path": "square20", "window": [1, 5], "weighting": ["none", "huff"]}],
}


def _spec(**changes):
    d = {**BASE, **changes}
    return Spec.from_dict(d, source="spec")


def _grid(**block):
    return _spec(grid=[{"path": "square20", "window": [1, 5], **block}])


def test_presets_load_and_have_the_thesis_axes():
    assert {"thesis", "quick", "example_gps4"} <= set(available_presets())
    thesis = load_spec("thesis")
    cells = thesis.expand()
    assert len(thesis.seeds) >= 10
    assert {c.path for c in cells} == {"square100", "square200"}
    assert {c.window for c in cells} == {1, 5, 10, 100}
    assert {"none", "random", "huff"} <= {c.weighting for c in cells}
    assert {"none", "lc", "dyn", "lc+dyn", "lc_course", "lc_course+dyn", "motion_compensated",
            "ekf", "naive", "lc_sim_heading", "lc_sim_heading+dyn", "ekf_fixed_lag",
            "ekf_smoother", "lc_smoothed_heading"} == {c.technique for c in cells}
    assert thesis.masks == ("full", "no_turns", "no_turns_window")
    # the faithful growth rule for the tables, the other one beside it (issue 15)
    assert {c.dyn_growth for c in cells if c.technique == "dyn"} == {"refill", "jump"}
    assert {c.dyn_growth for c in cells if c.technique == "none"} == {"-"}
    quick = load_spec("quick")
    assert len(quick.seeds) == 2 and {c.path for c in quick.expand()} == {"square100"}


@pytest.mark.parametrize("changes, field", [
    ({"bogus": 1}, "bogus"),
    ({"seeds": 0}, "seeds"),
    ({"seeds": [1, 1]}, "seeds"),
    ({"seeds": [1, -2]}, "seeds[1]"),
    ({"seed": -1}, "seed"),
    ({"masks": ["full", "corners"]}, "masks[1]"),
    ({"session_s": 0}, "session_s"),
    ({"name": "bad name"}, "name"),
    ({"grid": []}, "grid"),
    ({"defaults": {"windw": 3}}, "windw"),
    ({"epochs": {"seeds": [0], "colour": 1}}, "colour"),
    ({"epochs": {"where": {"technique": ["lcc"]}}}, "epochs.where.technique[0]"),
])
def test_top_level_errors_name_the_field(changes, field):
    with pytest.raises(SpecError, match=field.replace("[", r"\[").replace("]", r"\]")):
        _spec(**changes)


@pytest.mark.parametrize("block, field", [
    ({"windw": [1]}, r"grid\[0\]: unknown key 'windw'"),
    ({"noise": "gps_stationary", "noise_overrides": {"common_fractio": 0.2}},
     r"grid\[0\].noise_overrides: .*common_fractio"),
    ({"noise": "gps_stationary", "noise_overrides": {"common_fraction": 2.0}},
     r"grid\[0\].noise_overrides: .*common_fraction"),
    ({"path_overrides": {"cruise_speed_mps": -1}}, r"grid\[0\].path_overrides: .*cruise_speed"),
    ({"window": [1, 0]}, r"grid\[0\].window\[1\]: must be a positive integer, got 0"),
    ({"window": [1, 2.5]}, r"grid\[0\].window\[1\]"),
    ({"weighting": "huf"}, r"grid\[0\].weighting: unknown weighting 'huf'"),
    ({"weighting": "huff:-1"}, r"grid\[0\].weighting"),
    ({"technique": ["none", "kalman"]}, r"grid\[0\].technique\[1\]: unknown technique"),
    ({"solver": "ipopt"}, r"grid\[0\].solver: unknown solver"),
    ({"path": "square999"}, r"grid\[0\].path: unknown name 'square999' .*; known names"),
    ({"config": "rover_gps99"}, r"grid\[0\].config: unknown name 'rover_gps99' .*; known names"),
    ({"noise": "gps_nope"}, r"grid\[0\].noise: unknown name 'gps_nope'"),
    ({"noise_overrides": 3}, r"grid\[0\].noise_overrides: must be a table"),
    ({"path_overrides": {"waypoints": []}}, r"grid\[0\].path_overrides"),
    ({"technique": "dyn", "dyn_window": 10}, r"dyn_window: 10 exceeds window"),
    ({"turning": "psychic"}, r"grid\[0\].turning"),
    ({"technique": "dyn", "dyn_growth": "grow"}, r"grid\[0\].dyn_growth: unknown growth rule"),
    ({"technique": "lc_sim_headin"}, r"grid\[0\].technique: unknown technique"),
])
def test_grid_errors_name_the_field(block, field):
    with pytest.raises(SpecError, match=field):
        _grid(**block)


def test_missing_required_axis_is_named():
    with pytest.raises(SpecError, match=r"grid\[0\].window: required"):
        _spec(grid=[{"path": "square20"}])


def test_load_spec_reports_file_and_toml_errors(tmp_path):
    with pytest.raises(SpecError, match="preset 'nope'"):
        load_spec("nope")
    bad = tmp_path / "bad.toml"
    bad.write_text("name = \n")
    with pytest.raises(SpecError, match="not valid TOML"):
        load_spec(bad)
    bad.write_text(textwrap.dedent("""
        name = "x"
        [[grid]]
        path = "square20"
        window = -1
    """))
    with pytest.raises(SpecError, match=r"bad.toml: grid\[0\].window"):
        load_spec(bad)


def test_grid_expansion_is_the_union_of_blocks_without_duplicates():
    spec = _spec(grid=[
        {"path": "square20", "window": [1, 5], "weighting": ["none", "huff"]},
        {"path": "square20", "window": [5], "weighting": "huff",
         "technique": ["none", "lc", "dyn"]},        # (5, huff, none) repeats block 0
    ])
    cells = spec.expand()
    assert len(cells) == (2 * 2 + 2) * 2
    assert len({c.key for c in cells}) == len(cells)
    assert {(c.window, c.weighting, c.technique) for c in cells} == {
        (1, "none", "none"), (1, "huff", "none"), (5, "none", "none"), (5, "huff", "none"),
        (5, "huff", "lc"), (5, "huff", "dyn")}
    dyn = [c for c in cells if c.technique == "dyn"]
    assert all(c.dyn_window == 1 and c.turning == "controller" for c in dyn)
    assert all(c.dyn_window == 0 and c.turning == "-" for c in cells if c.technique != "dyn")


def test_growth_rule_and_oracle_cells():
    """Issue 15: the growth rule is an axis of the dynamic techniques only ("-" elsewhere,
    so the others are not duplicated); the oracle techniques expand like any other; the
    window mask is accepted and the default masks are unchanged."""
    spec = _grid(technique=["none", "lc+dyn", "lc_sim_heading", "lc_sim_heading+dyn"],
                 dyn_growth=["jump", "refill"])
    cells = spec.expand()
    by = {(c.technique, c.dyn_growth) for c in cells}
    assert by == {("none", "-"), ("lc_sim_heading", "-"), ("lc+dyn", "jump"),
                  ("lc+dyn", "refill"), ("lc_sim_heading+dyn", "jump"),
                  ("lc_sim_heading+dyn", "refill")}
    assert len(cells) == 2 * 2 * 6 and len({c.key for c in cells}) == len(cells)
    assert {c.params()["dyn_growth"] for c in cells} == {"-", "jump", "refill"}
    assert _spec().masks == ("full", "no_turns")
    assert _spec(masks=["full", "no_turns_window"]).masks == ("full", "no_turns_window")


def test_not_applicable_axes_are_marked_and_deduplicated():
    spec = _grid(weighting=["none", "huff"], technique=["ekf", "naive", "motion_compensated"],
                 solver=["procrustes", "slsqp"])
    cells = spec.expand()
    for c in cells:
        if c.technique in NO_SOLVER:
            assert c.solver == "-"
        if c.technique in NO_WEIGHTS:
            assert c.weighting == "-"
    # ekf/naive: 2 windows x 2 seeds each; motion_compensated: x 2 weightings
    assert len(cells) == 2 * 2 * 2 + 2 * 2 * 2


def test_cell_keys_are_stable_and_follow_file_contents(tmp_path):
    a = [c.key for c in _spec().expand()]
    b = [c.key for c in _spec().expand()]
    assert a == b
    assert len(set(a)) == len(a)
    # a copy of a configuration under another file gives the same key only if identical
    cfg = tmp_path / "mycfg.toml"
    shutil.copy(REPO / "models/configs/rover_gps8.toml", cfg)
    s1 = Spec.from_dict({**BASE, "defaults": {"noise": "none", "config": "mycfg.toml"}},
                        source="spec", base_dir=tmp_path)
    k1 = {c.key for c in s1.expand()}
    cfg.write_text(cfg.read_text().replace("position_m = [0.75, 0.5]", "position_m = [0.8, 0.5]"))
    s2 = Spec.from_dict({**BASE, "defaults": {"noise": "none", "config": "mycfg.toml"}},
                        source="spec", base_dir=tmp_path)
    assert k1.isdisjoint({c.key for c in s2.expand()})
    # another spec seed changes every key
    assert set(a).isdisjoint({c.key for c in _spec(seed=5).expand()})


def test_with_solver_and_with_seeds():
    spec = _grid(technique=["none", "ekf"])
    s2 = spec.with_solver("slsqp")
    assert s2.name == "t-slsqp" and s2.raw["name"] == "t-slsqp"
    assert {c.solver for c in s2.expand() if c.technique == "none"} == {"slsqp"}
    assert {c.solver for c in s2.expand() if c.technique == "ekf"} == {"-"}
    with pytest.raises(SpecError, match="solver"):
        spec.with_solver("gurobi")
    s3 = spec.with_seeds(range(3))
    assert s3.seeds == (0, 1, 2) and len(s3.expand()) == 3 * len(spec.expand()) // 2


def test_epochs_selection():
    spec = _spec(epochs={"seeds": [1], "where": {"window": [5]}})
    want = {(c.seed, c.window) for c in spec.expand() if spec.epochs_wanted(c)}
    assert want == {(1, 5)}
    assert not any(_spec().epochs_wanted(c) for c in _spec().expand())


# ---------------------------------------------------------------- limits and kinds (issue 13)
@pytest.mark.parametrize("changes, field", [
    ({"session_s": 1e15}, "session_s: must be a number of seconds in"),
    ({"seeds": 1_000_000_000}, r"seeds: count must be in \[1, 10000\]"),
    ({"seeds": list(range(10_001))}, "seeds: must be a count"),
    ({"grid": [{"path": "square20", "window": [1_000_000_000]}]},
     r"window\[0\]: must be a positive integer"),
])
def test_physical_ranges_are_checked_on_load(changes, field):
    with pytest.raises(SpecError, match=field):
        _spec(**changes)


def test_grid_size_is_checked_before_expansion():
    import time

    t0 = time.perf_counter()
    with pytest.raises(SpecError, match=r"grid: 1000 axis combinations x 1000 seeds = 1000000 "
                                        r"cells, more than"):
        _spec(seeds=1000, grid=[{"path": "square20", "window": list(range(1, 1001))}])
    assert time.perf_counter() - t0 < 2.0   # refused before any expansion (was ~1 min)


@pytest.mark.parametrize("axis, value, what", [
    ("config", "square20.toml", "is not a sensor configuration"),   # a path file as config
    ("path", "rover_gps8.toml", "is not a path file"),              # a config as path
    ("noise", "rover_gps8.toml", "is not a GPS noise model"),
])
def test_a_file_of_the_wrong_kind_is_refused_on_load(tmp_path, axis, value, what):
    kind = {"square20.toml": "paths", "rover_gps8.toml": "configs"}[value]
    shutil.copy(REPO / "models" / kind / value, tmp_path / value)
    block = {"path": "square20", "window": 1, "noise": "none", axis: value}
    spec = tmp_path / "s.toml"
    spec.write_text('name = "k"\n[[grid]]\n' + "".join(
        f"{k} = {v!r}\n".replace("'", '"') for k, v in block.items()))
    with pytest.raises(SpecError, match=f"grid\\[0\\].{axis}: '{value}' {what}"):
        load_spec(spec)


def test_relative_paths_may_not_leave_the_spec_folder_and_the_project(tmp_path):
    sub = tmp_path / "specs"
    sub.mkdir()
    (sub / "s.toml").write_text(textwrap.dedent("""
        name = "k"
        [[grid]]
        path = "square20"
        window = 1
        config = "../../../../../../../../../etc/hostname"
    """))
    with pytest.raises(SpecError, match="leaves the folder of the file naming it"):
        load_spec(sub / "s.toml")


def test_non_utf8_spec_is_a_spec_error(tmp_path):
    p = tmp_path / "s.toml"
    p.write_bytes(b'name = "k\xff\xfe"\n')
    with pytest.raises(SpecError, match="not UTF-8"):
        load_spec(p)


def _block_spec(tmp_path, **block) -> Path:
    sub = tmp_path / "specs"
    sub.mkdir(exist_ok=True)
    block = {"path": "square20", **block}
    lines = ['name = "k"', "[[grid]]", "window = 1"]
    lines += [f'{k} = "{v}"' for k, v in block.items()]
    (sub / "s.toml").write_text("\n".join(lines) + "\n")
    return sub / "s.toml"


@pytest.mark.parametrize("value", ["session:../../../../../../../../etc/passwd",
                                   "session:/etc/passwd"])
def test_session_files_follow_the_path_rule(tmp_path, value):
    # issue 23: a session: file escaped the rule every other file follows
    with pytest.raises(SpecError, match=r"grid\[0\].noise: .* leaves the folder"):
        load_spec(_block_spec(tmp_path, noise=value))


def test_absolute_paths_outside_the_spec_folder_and_project_are_refused(tmp_path):
    with pytest.raises(SpecError, match=r"grid\[0\].config: '/etc/hostname' leaves the folder"):
        load_spec(_block_spec(tmp_path, config="/etc/hostname"))


def test_absolute_and_relative_paths_inside_the_spec_folder_are_accepted(tmp_path):
    spec = _block_spec(tmp_path)
    shutil.copy(Path("models/configs/rover_gps4.toml"), spec.parent / "mine.toml")
    for value in ("mine.toml", str(spec.parent / "mine.toml")):
        cells = load_spec(_block_spec(tmp_path, config=value)).expand()
        assert cells[0].file("config") == str((spec.parent / "mine.toml").resolve())


def test_a_file_given_by_path_is_labelled_by_its_name_never_toml(tmp_path):
    # issue 23: labels and file names kept ".toml" ("my.toml"); a model file's label is its
    # name field (issue 13: tables show it), a path file's name is its stem
    spec = _block_spec(tmp_path)
    (spec.parent / "my.toml").write_text(
        Path("models/paths/square20.toml").read_text().replace('"square20"', '"my"'))
    shutil.copy(Path("models/configs/rover_gps4.toml"), spec.parent / "layout.toml")
    cell = load_spec(_block_spec(tmp_path, path="my.toml", config="layout.toml")).expand()[0]
    assert (cell.path, cell.config) == ("my", "rover_gps4")


def test_two_files_with_one_label_are_an_error(tmp_path):
    spec = _block_spec(tmp_path)
    (spec.parent / "a").mkdir()
    (spec.parent / "a" / "x.toml").write_text(Path("models/configs/rover_gps4.toml").read_text()
                                              .replace('"rover_gps4"', '"rover_gps8"'))
    spec.write_text(spec.read_text().replace(
        'window = 1', 'window = 1\nconfig = ["rover_gps8", "a/x.toml"]'))
    with pytest.raises(SpecError, match="would both be labelled 'rover_gps8'"):
        load_spec(spec)


def test_deeply_nested_toml_is_a_one_line_spec_error(tmp_path):
    # issue 23: a 3,000-deep array raised RecursionError out of load_spec
    p = tmp_path / "deep.toml"
    p.write_text('name = "k"\nx = ' + "[" * 3000 + "]" * 3000 + "\n")
    with pytest.raises(SpecError, match="deep.toml: not usable TOML: .*nested too deeply") as ei:
        load_spec(p)
    assert "\n" not in str(ei.value)


def test_a_replay_model_in_noise_overrides_is_a_name_not_a_file(tmp_path):
    # the last file a spec could name outside the path rule (loaded at run time by name)
    np = pytest.importorskip("numpy")
    from sim.gps import StationarySession

    spec = _block_spec(tmp_path)
    StationarySession(t=np.arange(10.0), obs=np.zeros((10, 1, 2)), names=("a",)).save(
        spec.parent / "one.npz")
    spec.write_text(spec.read_text() + 'noise = "session:one.npz"\nnoise_overrides = '
                    '{replay = "common_plus_model", model = "../../../../../etc/hostname"}\n')
    with pytest.raises(SpecError, match=r"noise_overrides.model: must be a noise-model name"):
        load_spec(spec)


# ---------------------------------------------------------------- one schema per axis (issue 24)
def test_the_axis_schema_drives_the_cell_type_defaults_and_columns():
    """Each axis is declared once (experiments.spec.AXIS_SCHEMA): the Cell's fields, AXES
    (defaults), the validation's unknown-key list and the cells.parquet columns follow."""
    import dataclasses

    from experiments.spec import AXES, AXIS_SCHEMA, Cell

    names = [a.name for a in AXIS_SCHEMA]
    assert [f.name for f in dataclasses.fields(Cell)] == [*names, "seed", "key", "files",
                                                          "plugin"]
    assert list(AXES) == names and AXES["config"] == "rover_gps8" and AXES["path"] is None
    cell = _spec().expand()[0]
    assert list(cell.params()) == [*names, "seed"]
    with pytest.raises(SpecError, match=r"unknown key 'windw'; allowed axes: \['config', "):
        _grid(windw=3)


def test_axes_that_do_not_apply_take_their_unset_value_from_the_schema():
    from experiments.spec import AXIS_SCHEMA
    from experiments.techniques import technique

    per_tech = [a for a in AXIS_SCHEMA if a.applies is not None]
    assert {a.name for a in per_tech} == {"weighting", "solver", "dyn_window", "turning",
                                          "dyn_growth"}
    cells = _grid(technique=["none", "ekf", "dyn"], weighting="huff").expand()
    for c in cells:
        for a in per_tech:
            applies = a.applies(technique(c.technique))
            assert (getattr(c, a.name) == a.unset) != applies, (c.technique, a.name)


def _documented_key(spec, cell) -> str:
    """The cell key as defined before the schema (issue 24 keeps it byte-identical): sha256
    of the canonical JSON of the spec seeds, the session length, the 13 axis values and the
    seed (``recording`` only when set), the files' digests, and a plug-in's options."""
    import hashlib
    import json

    params = {"path": cell.path, "config": cell.config, "noise": cell.noise,
              "noise_overrides": cell.noise_overrides, "path_overrides": cell.path_overrides,
              "window": cell.window, "weighting": cell.weighting, "technique": cell.technique,
              "solver": cell.solver, "dyn_window": cell.dyn_window, "turning": cell.turning,
              "recording": cell.recording, "dyn_growth": cell.dyn_growth, "seed": cell.seed}
    if params["recording"] == "-":
        del params["recording"]
    files = {}
    for kind, path in cell.files:
        data = Path(path).read_bytes() if kind != "recording" else None
        files[kind] = hashlib.sha256(data).hexdigest()[:16] if data is not None else None
    if cell.recording != "-":
        from sim.recording import recording_digest

        files["recording"] = recording_digest(cell.file("recording"))
    ident = {"v": 1, "spec_seed": spec.seed, "sim_seed": spec.sim_seed,
             "session_s": spec.session_s, **params, "files": dict(sorted(files.items()))}
    if cell.plugin is not None:
        ident["plugin"] = {"tracker": cell.plugin.tracker,
                           "options": json.loads(cell.plugin.options)}
    text = json.dumps(ident, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:20]


@pytest.mark.parametrize("preset", ["thesis", "example_recording"])
def test_cell_keys_are_those_of_the_documented_identity(preset):
    """Every key of the preset recomputed by the formula the keys always had (so cached
    cells of earlier runs are found: a key that moved recomputes every cell)."""
    spec = load_spec(preset)
    cells = spec.expand()
    assert len(cells) == len({c.key for c in cells})
    for c in cells:
        assert c.key == _documented_key(spec, c), c
