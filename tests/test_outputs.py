"""The outputs phase (experiments.outputs): each unit is rewritten exactly when its inputs
or its files changed. The units' work is replaced by fakes that write small files (the real
tables, report, figures and page have tests of their own; tests/test_sweep.py runs the real
units on a small sweep)."""

import json
import os
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from experiments import figures, outputs, page

TASKS = ("weighting", "orientation", "tables")        # "tables": the chart, drawn with tables


@pytest.fixture
def folder(tmp_path, monkeypatch):
    """A results folder with a cell table, two per-epoch files and fake units that record
    their calls; each figure group reads the per-epoch file(s) named in ``reads``."""
    calls: list[str] = []
    reads = {"weighting": ["a"], "orientation": ["b"]}
    (tmp_path / "epochs").mkdir()
    for k in ("a", "b"):
        (tmp_path / "epochs" / f"{k}.parquet").write_bytes(b"epochs " + k.encode())
    table = pd.DataFrame({"key": ["a", "b", "c"], "path": ["p"] * 3, "window": [1, 5, 10],
                          "seed": [0, 0, 1], "mask": ["full"] * 3,
                          "has_epochs": [True, True, False], "ex_mean": [0.1, 0.2, 0.3]})
    table.to_parquet(tmp_path / "cells.parquet")

    def tables_unit(table, out, figs):
        calls.append("tables")
        (out / "tables.md").write_text(f"{len(table)} rows, {table['ex_mean'].sum()}")
        files = ["tables.md"]
        if figs:
            (out / "fig_tables.png").write_bytes(b"chart")
            files.append("fig_tables.png")
        return {"files": files, "tables_s": 0.0, "chart_s": 0.0}

    def report_unit(table, out, spec):
        calls.append("report")
        (out / "REPORT.md").write_text("report")
        return {"files": ["REPORT.md"], "report_s": 0.0}

    def draw_task(out, task):
        calls.append(task)
        f = Path(out) / f"fig_{task}.png"
        f.write_bytes(task.encode())
        return [f], reads[task]

    def write_page(out, replay=None):
        calls.append("page")
        (Path(out) / "index.html").write_text(f"page {replay}")

    monkeypatch.setattr(outputs, "_tables_unit", tables_unit)
    monkeypatch.setattr(outputs, "_report_unit", report_unit)
    monkeypatch.setattr(figures, "draw_task", draw_task)
    monkeypatch.setattr(figures, "figure_tasks", lambda: TASKS)
    monkeypatch.setattr(page, "write_page", write_page)
    monkeypatch.setattr(page, "own_replay", lambda out: ({"cells": []}, ""))
    return tmp_path, table, calls


def _write(folder_, table=None, **kw):
    out, t, calls = folder_
    calls.clear()
    res = outputs.write_outputs(t if table is None else table, out, jobs=1, **kw)
    return sorted(calls), res


def test_first_run_writes_all_and_a_rerun_nothing(folder):
    calls, res = _write(folder)
    assert calls == ["orientation", "page", "report", "tables", "weighting"]
    assert sorted(res["written"]) == calls and res["skipped"] == []
    state = json.loads((folder[0] / outputs.STATE_FILE).read_text())
    assert state["units"]["weighting"]["loaded"] == ["a"]
    calls, res = _write(folder)
    assert calls == [] and res["written"] == []
    assert res["skipped"] == ["orientation", "page", "report", "tables", "weighting"]


def test_a_number_changed_rewrites_tables_report_and_page_only(folder):
    _write(folder)
    t = folder[1].copy()
    t.loc[2, "ex_mean"] = 0.31                  # a statistic of a cell without epochs
    calls, _ = _write(folder, table=t)
    assert calls == ["page", "report", "tables"]


def test_a_new_cell_changes_the_layout_and_redraws_the_figures(folder):
    _write(folder)
    t = pd.concat([folder[1], folder[1].iloc[[2]].assign(key="d", seed=2)],
                  ignore_index=True)
    calls, _ = _write(folder, table=t)
    assert calls == ["orientation", "page", "report", "tables", "weighting"]


def test_a_changed_epoch_file_redraws_the_figures_that_read_it(folder):
    out = folder[0]
    _write(folder)
    f = out / "epochs" / "b.parquet"
    f.write_bytes(b"recomputed b, longer")
    calls, _ = _write(folder)
    assert calls == ["orientation", "page"]     # the page replays every per-epoch file


@pytest.mark.parametrize("name, unit", [("fig_weighting.png", "weighting"),
                                        ("REPORT.md", "report"), ("tables.md", "tables"),
                                        ("index.html", "page")])
def test_a_deleted_or_edited_output_is_rewritten(folder, name, unit):
    out = folder[0]
    _write(folder)
    (out / name).unlink()
    calls, _ = _write(folder)
    assert unit in calls and len(calls) <= 2   # the unit (and the page that shows it)
    (out / name).write_text("edited by hand")
    st = (out / name).stat()
    os.utime(out / name, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    calls, _ = _write(folder)
    assert unit in calls


def test_code_or_option_changes_rewrite(folder, monkeypatch):
    _write(folder)
    calls, _ = _write(folder, figures=False)    # the tables unit knows whether it drew
    assert calls == ["page", "tables"]          # the chart; figure groups are not drawn
    monkeypatch.setattr(outputs, "code_digest", lambda: "other code")
    calls, _ = _write(folder)
    assert calls == ["orientation", "page", "report", "tables", "weighting"]


def test_damaged_state_file_means_rewrite(folder):
    out = folder[0]
    _write(folder)
    (out / outputs.STATE_FILE).write_text("{not json")
    calls, _ = _write(folder)
    assert calls == ["orientation", "page", "report", "tables", "weighting"]


def test_frame_digest():
    a = pd.DataFrame({"x": [1.0, np.nan, 1e300], "s": ["a", None, "c"]})
    assert outputs.frame_digest(a) == outputs.frame_digest(a.copy())
    assert outputs.frame_digest(a) == outputs.frame_digest(a.set_axis([5, 6, 7]))
    assert outputs.frame_digest(a) != outputs.frame_digest(a.assign(x=[1.0, np.nan, 1e299]))
    b = a.iloc[:2]
    assert outputs.frame_digest(b) != outputs.frame_digest(b.astype({"x": "float32"}))
    assert outputs.frame_digest(a, ["s"]) == outputs.frame_digest(a.assign(x=0.0), ["s"])
    assert outputs.frame_digest(a.iloc[:0]) != outputs.frame_digest(a)


def test_a_changed_sensitivity_study_redraws_the_report_only(folder):
    """The report's inputs cover the CSVs of the study the spec declared (``[report]
    sensitivity``, recorded in manifest.json): a changed table redraws REPORT.md (and the
    page that shows it), the same bytes rewritten do not, and an undeclared folder is not
    watched."""
    out = folder[0]
    study = out / "study"
    study.mkdir()
    for name in ("sensitivity", "comparisons", "shipped"):
        (study / f"{name}.csv").write_text(f"{name}\n1\n")
    (out / "manifest.json").write_text(json.dumps(
        {"spec": {"report": {"sensitivity": "study"}}, "spec_base_dir": str(out)}))
    _write(folder)
    f = study / "comparisons.csv"
    f.write_text(f.read_text())                 # same contents, new modification time
    st = f.stat()
    os.utime(f, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    calls, _ = _write(folder)
    assert calls == []
    f.write_text("comparisons\n2\n")            # the study re-measured
    calls, _ = _write(folder)
    assert calls == ["page", "report"]
    (study / "mask.csv").write_text("dilate_s\n0\n")    # a new table of the study
    calls, _ = _write(folder)
    assert calls == ["page", "report"]
    (out / "manifest.json").write_text(json.dumps({"spec": {}, "spec_base_dir": str(out)}))
    _write(folder)
    f.write_text("comparisons\n3\n")            # no longer declared: not an input
    calls, _ = _write(folder)
    assert calls == []


def test_the_replay_is_handed_out_after_the_tables_and_report(folder, monkeypatch):
    """The units go to the workers in this order: the tables, the report, the page's replay,
    then the figure groups largest first (``_FIGURE_ORDER``); the page last, here. Queued
    after the figures, the replay (0.36-0.41 CPU-s on the thesis preset, about a larger
    figure group's cost) was the last unit to finish, 0.4 s after the other worker's."""
    out, t, calls = folder
    monkeypatch.setattr(page, "own_replay",
                        lambda out: (calls.append("replay"), ({"cells": []}, ""))[1])
    calls.clear()
    outputs.write_outputs(t, out, jobs=1)
    assert calls == ["tables", "report", "replay", "weighting", "orientation", "page"]
    # with only figure groups to redraw, the replay still goes first
    (out / "epochs" / "b.parquet").write_bytes(b"recomputed b, longer")
    calls.clear()
    outputs.write_outputs(t, out, jobs=1)
    assert calls == ["replay", "orientation", "page"]


def test_each_unit_run_writes_its_timeline_line(folder, monkeypatch):
    """With CONFIGPOSE_TIMELINE set, every unit run (tables, report, each figure group, the
    replay) appends one line "output <unit>" (issue 27: where the outputs phase's time goes);
    the page, written in this process, one "main page" line."""
    from experiments.runner.worker import TIMELINE_ENV

    path = folder[0] / "timeline.jsonl"
    monkeypatch.setenv(TIMELINE_ENV, str(path))
    _write(folder)
    lines = [json.loads(s) for s in path.read_text().splitlines()]
    assert sorted(x["what"] for x in lines) == [
        "main page", "output orientation", "output replay", "output report",
        "output tables", "output weighting"]
    assert all(x["end"] >= x["start"] and x["cpu_s"] >= 0.0 for x in lines)
