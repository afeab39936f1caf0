"""A user's tracker through a spec, end to end (issue 24): a plug-in named by import path
(tests/plugin_tracker.py:MeanTracker) is validated at load, swept, scored, tabled (Tables
4.1/4.2 beyond rows, by_cell.csv, the heading table), reported and replayed on the page
beside the built-in rows; a plug-in that raises is one failed cell with its reason; each
validation error names the field.

Tiny runs only (square20, 1-2 seeds, window 5, no figures): a few seconds in-process.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from experiments.spec import Spec, SpecError
from experiments.sweep import run

MEAN = "plugin_tracker:MeanTracker"
PLUGIN_SPEC = {
    "name": "plugins",
    "seed": 5,
    "seeds": 2,
    "techniques": {
        "mean_swapped": {"tracker": MEAN, "options": {"rear": 4, "front": 0},
                         "label": "Mean, antennas swapped", "color": "#123456"},
    },
    "grid": [{"path": "square20", "window": 5, "weighting": "huff",
              "technique": ["none", "lc", "ekf", MEAN, "mean_swapped"]}],
    "epochs": {"seeds": [0]},
}


@pytest.fixture(scope="module")
def plugin_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("plugin_run")
    cache = tmp_path_factory.mktemp("truth_cache")
    spec = Spec.from_dict(PLUGIN_SPEC, source="plugins")
    return run(spec, out=out, jobs=1, progress=False, figures=False, cache_dir=cache)


def test_plugin_cells_are_swept_and_scored_beside_the_builtin_ones(plugin_run):
    r = plugin_run
    assert r.n_failed == 0, r.errors
    full = r.cells[r.cells["mask"] == "full"]
    assert set(full["technique"]) == {"none", "lc", "ekf", MEAN, "mean_swapped"}
    plug = full[full["technique"] == MEAN]
    assert len(plug) == 2 and np.isfinite(plug["ex_mean"]).all()
    # the axes a plug-in does not take are recorded as not applicable
    assert set(plug["solver"]) == {"-"} and set(plug["weighting"]) == {"-"}
    assert set(plug["dyn_growth"]) == {"-"}


def test_plugin_per_epoch_file_holds_what_the_tracker_computed(plugin_run):
    """The saved CG estimate is the per-epoch mean of the observed antennas (MeanTracker's
    definition), recomputed from the observations saved beside it (float32: 1e-5 m at
    coordinates of ~20 m is ~100 float32 ulps, far below any error that matters)."""
    c = plugin_run.cells
    key = c.loc[(c["technique"] == MEAN) & (c["seed"] == 0), "key"].iloc[0]
    ep = pd.read_parquet(plugin_run.out_dir / "epochs" / f"{key}.parquet")
    obs_x = ep[[k for k in ep.columns if k.startswith("obs_") and k.endswith("_x")]]
    assert obs_x.shape[1] == 8
    np.testing.assert_allclose(ep["cg_x"], np.nanmean(obs_x.to_numpy(float), axis=1),
                               atol=1e-5)
    row = c[(c["key"] == key) & (c["mask"] == "full")].iloc[0]
    assert np.nanmean(np.abs(ep["err_x"])) == pytest.approx(row["ex_mean"], rel=1e-12)


def test_plugin_rows_in_the_tables(plugin_run):
    out = plugin_run.out_dir
    t41 = pd.read_csv(out / "table_4_1_square20.csv", keep_default_na=False)  # "None" row
    kinds = dict(zip(t41["technique"], t41["kind"]))
    assert kinds["MeanTracker"] == "plugin" and kinds["Mean, antennas swapped"] == "plugin"
    assert kinds["None"] == "thesis" and kinds["EKF (causal)"] == "beyond"
    md = (out / "tables.md").read_text()
    assert "| MeanTracker |" in md and "| Mean, antennas swapped |" in md
    by = pd.read_csv(out / "by_cell.csv")
    assert {MEAN, "mean_swapped"} <= set(by["technique"])
    assert not by.loc[by["technique"] == MEAN, "oracle"].any()
    heading = pd.read_csv(out / "heading.csv")
    assert {"MeanTracker", "Mean, antennas swapped", "EKF (causal)"} <= set(heading["estimator"])


def test_plugin_rows_in_the_report_and_on_the_page(plugin_run):
    from experiments.page import replay_source

    out = plugin_run.out_dir
    report = (out / "REPORT.md").read_text()
    assert "## Plug-in trackers" in report and "`plugin_tracker:MeanTracker`" in report
    assert "Mean, antennas swapped" in report
    src = replay_source(out)
    techs = {c["axes"]["technique"] for c in src["cells"]}
    assert {MEAN, "mean_swapped", "none"} <= techs
    assert MEAN in (out / "index.html").read_text()


def test_plugin_labels_and_colours_come_from_the_spec(plugin_run):
    from experiments.techniques import PLUGIN_PALETTE, plugins_in_results

    ent = plugins_in_results(plugin_run.cells["technique"], plugin_run.out_dir)
    assert ent["mean_swapped"].color == "#123456"
    assert ent["mean_swapped"].short == "Mean, antennas swapped"
    assert ent[MEAN].short == "MeanTracker" and ent[MEAN].color in PLUGIN_PALETTE
    assert ent[MEAN].kind == "plugin" and not ent[MEAN].uses_solver


def test_a_raising_plugin_is_one_failed_cell_with_its_reason(tmp_path):
    spec = Spec.from_dict({"name": "failing", "seeds": 1, "defaults": {"noise": "none"},
                           "grid": [{"path": "square20", "window": 5,
                                     "technique": ["none", "plugin_failing:RaisingTracker",
                                                   "plugin_failing:NoYawTracker"]}]})
    r = run(spec, out=tmp_path, jobs=1, progress=False, figures=False,
            cache_dir=tmp_path / "cache")
    assert r.n_cells == 3 and r.n_failed == 2 and r.n_computed == 1
    errors = {e["params"]["technique"]: e["error"]
              for e in json.loads((tmp_path / "errors.json").read_text())}
    assert errors["plugin_failing:RaisingTracker"] == "RuntimeError: diverged at epoch 3"
    assert "lacks column(s) ['yaw']" in errors["plugin_failing:NoYawTracker"]
    assert set(r.cells["technique"]) == {"none"}        # the run went on and wrote its tables
    assert (tmp_path / "tables.md").exists()


def _spec(**kw):
    tech = "m" if isinstance(kw.get("techniques"), dict) and "m" in kw["techniques"] else MEAN
    base = {"name": "t", "defaults": {"noise": "none"},
            "grid": [{"path": "square20", "window": 5, "technique": tech}]}
    return Spec.from_dict({**base, **kw}, source="s")


def _grid(technique):
    return {"grid": [{"path": "square20", "window": 5, "technique": technique}]}


@pytest.mark.parametrize("kw, message", [
    ({"techniques": 3}, r"s: techniques: must be a table"),
    ({"techniques": {"none": {}}}, r"techniques.none: 'none' is a built-in technique"),
    ({"techniques": {"m": []}}, r"techniques.m: must be a table"),
    ({"techniques": {"m": {"colour": "#ffffff"}}},
     r"techniques.m: unknown key\(s\) \['colour'\]; allowed: \['tracker', 'options'"),
    ({"techniques": {"m": {"tracker": 3}}}, r"techniques.m.tracker: must be an import path"),
    ({"techniques": {"m": {"tracker": MEAN, "options": [1]}}},
     r"techniques.m.options: must be a table"),
    ({"techniques": {"m": {"tracker": MEAN, "label": ""}}},
     r"techniques.m.label: must be a non-empty string"),
    ({"techniques": {"m": {"tracker": MEAN, "label": "None"}}},
     r"techniques.m.label: 'None' is already the label of a built-in row"),
    ({"techniques": {"m": {"tracker": MEAN, "color": "red"}}},
     r"techniques.m.color: must be a colour '#rrggbb', got 'red'"),
    ({"techniques": {"m": {"tracker": MEAN, "options": {"speed": 1}}}},
     r"techniques.m: technique 'plugin_tracker:MeanTracker': unknown option\(s\) \['speed'\]"),
    ({"techniques": {"m": {"tracker": MEAN, "options": {"rear": -1}}}},
     r"techniques.m: .*bad options: rear: must be a sensor index >= 0, got -1"),
    ({"techniques": {"m": {"tracker": "h7_no_such_tracker"}}},
     r"techniques.m: technique 'h7_no_such_tracker': not a built-in tracker nor an entry"),
    ({"techniques": {"a": {"tracker": MEAN, "label": "Same"},
                     "b": {"tracker": MEAN, "label": "Same"}}},
     r"techniques.b.label: 'Same' is already the label of 'a'"),
    (_grid("no_such_module_h7:Tracker"),
     r"s: grid\[0\].technique: technique 'no_such_module_h7:Tracker': cannot import module"),
    (_grid(["none", "plugin_tracker:Nope"]),
     r"grid\[0\].technique\[1\]: .*module 'plugin_tracker' has no attribute 'Nope'"),
    (_grid("plugin_tracker:not_a_class"), r"grid\[0\].technique: .*names a function"),
    (_grid("plugin_tracker:BadSignature"), r"grid\[0\].technique: .*must take \(t, obs, conf"),
    (_grid("plugin tracker:X"), r"grid\[0\].technique: technique name 'plugin tracker:X'"),
    (_grid("lcc"), r"grid\[0\].technique: unknown technique 'lcc'; allowed: \['none'"),
])
def test_each_validation_error_names_the_field(kw, message):
    with pytest.raises(SpecError, match=message):
        _spec(**kw)


def test_plugin_by_entry_point_name(monkeypatch):
    """A technique that names an installed entry point of group configpose.trackers."""
    import importlib.metadata

    ep = importlib.metadata.EntryPoint("h7mean", MEAN, "configpose.trackers")
    real = importlib.metadata.entry_points

    def fake(**kw):
        return (importlib.metadata.EntryPoints([ep]) if kw.get("group") == "configpose.trackers"
                else real(**kw))

    monkeypatch.setattr(importlib.metadata, "entry_points", fake)
    cells = _spec(**_grid(["none", "h7mean"])).expand()
    plug = [c for c in cells if c.technique == "h7mean"]
    assert len(plug) == 1 and plug[0].entry.tracker == "h7mean"
    assert plug[0].entry.rows == (("h7mean", "full"),)


def test_plugin_cell_keys_follow_its_source_and_options(tmp_path, monkeypatch):
    """Editing the plug-in's source file or its options changes its cells' keys (they are
    recomputed); the built-in cells' keys do not move."""
    src = Path(__file__).with_name("plugin_tracker.py")
    mod = tmp_path / "h7_user_tracker.py"
    shutil.copy(src, mod)
    monkeypatch.syspath_prepend(str(tmp_path))

    def keys(options=None):
        tabs = {"m": {"tracker": "h7_user_tracker:MeanTracker", "options": options or {}}}
        return {c.technique: c.key for c in _spec(techniques=tabs, **_grid(["none", "m"]))
                .expand()}

    k0 = keys()
    assert keys() == k0
    assert keys({"front": 2})["m"] != k0["m"]
    mod.write_text(mod.read_text() + "\n# edited\n")
    k1 = keys()
    assert k1["m"] != k0["m"] and k1["none"] == k0["none"]


def test_plugin_boxes_in_fig_beyond_have_the_spec_colours(plugin_run, monkeypatch):
    """fig_beyond.png draws the plug-ins beside the built-in trackers, each in its colour
    (the spec's, else the palette's) and with its label."""
    from experiments import figures
    from experiments.techniques import PLUGIN_PALETTE

    drawn = []
    real = figures._boxes

    def spy(ax, groups, *a, **kw):
        drawn.extend((label, color) for label, _v, color in groups)
        return real(ax, groups, *a, **kw)

    monkeypatch.setattr(figures, "_boxes", spy)
    written, _ = figures.draw_task(plugin_run.out_dir, "beyond")
    assert [p.name for p in written] == ["fig_beyond.png"]
    colors = dict(drawn)
    assert colors["w=5\nMean, antennas swapped"] == "#123456"
    assert colors["w=5\nMeanTracker"] in PLUGIN_PALETTE
    assert colors["w=5\nEKF"] == figures.TECH_COLORS["ekf"]
