"""The technique registry (experiments.techniques): one definition drives the spec's
validation, the sweep's dispatch, the table rows, the CLI help and the README's list."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from synth_tracks import corner_path

from estimator.track_options import FILTER_METHODS
from experiments import tables
from experiments.spec import Spec, SpecError
from experiments.techniques import (
    DYNAMIC,
    NO_SOLVER,
    NO_WEIGHTS,
    ORACLE_TECHNIQUES,
    REGISTRY,
    TECHNIQUES,
    Technique,
    technique,
)

README = (Path(__file__).resolve().parents[1] / "README.md").read_text(encoding="utf-8")


def test_every_technique_is_validated_expanded_and_marked_by_its_entry():
    """A spec naming every technique loads, and each cell marks exactly the axes its entry
    says do not apply ("-", 0)."""
    names = [t for t in TECHNIQUES if technique(t).requires is None]
    spec = Spec.from_dict({"name": "t", "defaults": {"noise": "none"},
                           "grid": [{"path": "square20", "window": 5, "technique": names,
                                     "weighting": "huff", "solver": "slsqp"}]})
    cells = {c.technique: c for c in spec.expand()}
    assert set(cells) == set(names)
    for name, c in cells.items():
        t = technique(name)
        assert (c.solver == "-") == (name in NO_SOLVER) == (not t.uses_solver)
        assert (c.weighting == "-") == (name in NO_WEIGHTS) == (not t.uses_weights)
        assert (c.dyn_growth != "-") == (name in DYNAMIC) == t.dynamic
    with pytest.raises(SpecError, match=r"technique: unknown technique 'lcc'"):
        Spec.from_dict({"name": "t", "defaults": {"noise": "none"},
                        "grid": [{"path": "square20", "window": 5, "technique": "lcc"}]})


def test_track_arguments_follow_the_entry():
    dyn = technique("lc_sim_heading+dyn").track_arguments(dyn_window=2, dyn_growth="refill",
                                                          heading=np.zeros(3))
    assert dyn["method"] == "window" and dyn["lag_correction"].mode == "pose"
    assert dyn["dynamic_window"].small == 2 and dyn["dynamic_window"].growth == "refill"
    assert technique("ekf").track_arguments(dyn_window=0, dyn_growth="-") == {"method": "ekf"}
    assert technique("lc_course").track_arguments(
        dyn_window=0, dyn_growth="-")["lag_correction"].mode == "course"
    with pytest.raises(ValueError, match="truth heading"):
        technique("lc_sim_heading").track_arguments(dyn_window=0, dyn_growth="-")


def test_every_window_technique_runs_through_the_sweep_dispatch():
    """Each technique's arguments make a valid track on a noise-free corner (the filter
    family and gtsam are run by tests/test_heading_study.py on a tiny sweep)."""
    from experiments.sweep import CellContext, _track_cell

    cfg, t, _cg, yaw, turning, obs = corner_path(leg_steps=20, turn_steps=4)
    ctx = CellContext(spec_seed=0, masks=("full",), session_s=100.0, want_epochs=False,
                      memo={})
    for tech in REGISTRY:
        if tech.uses_filter:
            continue

        class Cell:                         # the fields _track_cell reads
            technique, window, weighting, solver, seed = tech.name, 4, "huff:3.5", "-", 0
            dyn_window, dyn_growth, turning = 1, "refill", "controller"

        if tech.uses_solver:
            Cell.solver = "procrustes"
        if not tech.uses_weights:
            Cell.weighting = "-"
        df = _track_cell(Cell, t, obs, cfg, turning, ctx, true_yaw=yaw, layout_check=False)
        assert len(df) == t.size - 3 and np.isfinite(df["cg_x"]).all(), tech.name
        assert df.attrs["settings"]["method"] == tech.method
        assert (df.attrs["settings"]["dynamic_window"] is not None) == tech.dynamic


def test_table_rows_come_from_the_registry():
    assert list(tables.THESIS_ROWS) == ["None", "LC Full Path", "LC No Turns", "Dyn SW",
                                        "LC + Dyn SW"]
    labels = [*tables.THESIS_ROWS, *tables.READING_ROWS, *tables.ORACLE_ROWS,
              *tables.BEYOND_ROWS]
    assert len(labels) == len(set(labels))             # no label names two rows
    shown = {t for t, *_ in (*tables.THESIS_ROWS.values(), *tables.ORACLE_ROWS.values(),
                             *tables.BEYOND_ROWS.values())}
    assert shown == set(TECHNIQUES)                     # every technique has a table row
    assert {t for t, _ in tables.ORACLE_ROWS.values()} == set(ORACLE_TECHNIQUES)
    heading = list(tables.HEADING_ROWS.values())
    n_filter = sum(technique(t).method in FILTER_METHODS for t in heading)
    assert all(technique(t).method in FILTER_METHODS for t in heading[:n_filter])
    assert tables.THESIS_CORRECTIONS == ("lc", "dyn", "lc+dyn")


def test_registry_entries_are_checked():
    with pytest.raises(ValueError, match="oracle"):
        Technique("x", "beyond", "s", "s", lag="pose", lag_heading="truth")
    with pytest.raises(ValueError, match="lag"):
        Technique("x", "beyond", "s", "s", method="ekf", lag="pose")
    with pytest.raises(ValueError, match="dynamic"):
        Technique("x", "beyond", "s", "s", method="ekf", dynamic=True)
    with pytest.raises(ValueError, match="kind"):
        Technique("x", "published", "s", "s")
    with pytest.raises(ValueError, match="oracle_of"):
        Technique("x", "oracle", "s", "s", lag="pose", lag_heading="truth")
    with pytest.raises(ValueError, match="oracle_of"):
        Technique("x", "beyond", "s", "s", oracle_of="lc")
    with pytest.raises(ValueError, match="course_of"):
        Technique("x", "beyond", "s", "s", lag="pose", course_of="lc")


def test_figures_and_report_pairings_come_from_the_registry():
    """Every technique has a figure colour and label (a technique added to the registry
    cannot be a KeyError in a figure), distinct colours, and the report's oracle and
    course pairings name registered techniques of the right kind."""
    from experiments import causes, claims, figures

    assert set(figures.TECH_COLORS) == set(TECHNIQUES) == set(figures.TECH_LABELS)
    assert len(set(figures.TECH_COLORS.values())) == len(TECHNIQUES)
    assert set(figures.ORACLES) == set(ORACLE_TECHNIQUES)
    assert causes.ORACLE_SWAP == {"lc": "lc_sim_heading", "lc+dyn": "lc_sim_heading+dyn"}
    assert claims._COURSE == {"lc": "lc_course", "lc+dyn": "lc_course+dyn"}
    for plain, oracle in causes.ORACLE_SWAP.items():
        assert technique(oracle).oracle and not technique(plain).oracle
        assert technique(oracle).dynamic == technique(plain).dynamic
    for plain, course in claims._COURSE.items():
        assert technique(course).lag == "course" and technique(plain).lag == "pose"
        assert technique(course).dynamic == technique(plain).dynamic


def test_help_and_readme_list_every_technique():
    """The CLI help is built from the registry; the README's axis list is written by hand,
    so this catches a technique added without documentation."""
    from experiments.sweep import build_parser

    text = build_parser().format_help()
    readme_axis = README[README.index("`technique` ("):README.index("`solver` (")]
    for name in TECHNIQUES:
        assert re.search(rf"^\s+{re.escape(name)}\s", text, re.MULTILINE), name
        assert f"`{name}`" in readme_axis, name
