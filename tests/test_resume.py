"""A resumed sweep redoes nothing whose inputs did not change (issue 27): no cell, no output,
no file rewritten (the git-ignored run.local.json sidecar aside)."""

import json
import time

import pytest

from experiments import outputs
from experiments.spec import Spec
from experiments.sweep import run

# one path, a few techniques: the real cells, tables, report and page (figures are drawn by
# the same skip rule and cost seconds each: tests/test_outputs.py covers them with fakes)
SMALL = {
    "name": "small",
    "seed": 5,
    "seeds": 1,
    "grid": [{"path": "square20", "window": [1, 5], "weighting": "huff",
              "technique": ["none", "lc"]}],
    "epochs": {"seeds": [0]},
}


def _stamps(folder):
    return {p: p.stat().st_mtime_ns for p in folder.rglob("*")
            if p.is_file() and p.name != "run.local.json"}


@pytest.fixture
def frozen_code(monkeypatch):
    """The code digests and version as constants: the code is an input of every cell and
    output, and in a working tree edited (and committed to) meanwhile it may change between
    the runs of a test."""
    from experiments.runner import run as run_mod
    from experiments.runner import store

    for mod in (run_mod, store):
        monkeypatch.setattr(mod, "cell_code_digest", lambda: "cells-code")
    monkeypatch.setattr(outputs, "code_digest", lambda: "outputs-code")
    monkeypatch.setattr(run_mod, "outputs_code_digest", lambda: "outputs-code")
    monkeypatch.setattr(run_mod, "code_version", lambda: {"git_describe": "frozen"})


def test_a_resumed_run_rewrites_no_file(tmp_path, frozen_code):
    """The first run writes its outputs while manifest.json says "running" and then marks
    it "complete": that status must not count as an input of the report or the page (it
    did: every resume redrew both, 2 of the 12 outputs of the quick preset)."""
    spec = Spec.from_dict(SMALL, source="small")
    out = tmp_path / "run"

    def go():
        return run(spec, out=out, jobs=1, progress=False, figures=False,
                   cache_dir=tmp_path / "cache")

    first = go()
    assert first.n_failed == 0 and first.n_computed == 2 * 2
    assert json.loads((out / "manifest.json").read_text())["status"] == "complete"
    before = _stamps(out)
    time.sleep(0.01)                    # a rewrite would show as a newer mtime
    again = go()
    assert (again.n_computed, again.n_resumed) == (0, first.n_computed)
    assert again.timings["outputs"]["written"] == []
    assert set(again.timings["outputs"]["unchanged"]) == {"tables", "report", "page"}
    assert _stamps(out) == before


def test_manifest_status_is_not_an_input(tmp_path):
    man = tmp_path / "manifest.json"
    man.write_text(json.dumps({"spec": {"name": "x"}, "status": "running", "n_cells": 3}))
    running = outputs._manifest_inputs(man)
    man.write_text(json.dumps({"n_cells": 3, "status": "complete", "spec": {"name": "x"}},
                              indent=1))
    assert outputs._manifest_inputs(man) == running
    man.write_text(json.dumps({"spec": {"name": "x"}, "status": "complete", "n_cells": 4}))
    assert outputs._manifest_inputs(man) != running          # anything else still counts
    assert outputs._manifest_inputs(tmp_path / "absent.json") == ""
    man.write_text("not json")
    assert outputs._manifest_inputs(man) == "not json"



def test_a_resume_reads_the_cell_table_not_the_cell_files(tmp_path, monkeypatch, frozen_code):
    """The store's index (cells.local.json) says which cell files cells.parquet was assembled
    from: while they are as they were, a resume reads the one table (0.1 s) instead of every
    cell file (1.0 s for the thesis preset's 1160), and an edited cell file is read again."""
    from types import SimpleNamespace

    from experiments.runner import store
    from tests.test_sweep import _fake_run, _fake_spec, fake_cell

    spec = _fake_spec()
    first = _fake_run(spec, tmp_path, cell_fn=fake_cell)
    assert (tmp_path / store.INDEX_FILE).exists()
    parsed: list[str] = []

    def loads(text):
        parsed.append(text)
        return json.loads(text)

    def no_read(self, keys):
        raise AssertionError("read every cell file")

    with monkeypatch.context() as m:
        m.setattr(store, "json", SimpleNamespace(loads=loads, dumps=json.dumps))
        m.setattr(store.CellStore, "read_cells", no_read)
        again = _fake_run(spec, tmp_path, cell_fn=fake_cell)
    assert again.n_resumed == first.n_cells and again.cells.equals(first.cells)
    index = (tmp_path / store.INDEX_FILE).read_text()
    assert parsed and all(t == index for t in parsed)       # the index, no cell file
    # an edited cell file (its size and mtime change) is read and checked again
    f = next((tmp_path / "cells").glob("*.json"))
    f.write_text("{")
    r = _fake_run(spec, tmp_path, cell_fn=fake_cell)
    assert (r.n_computed, r.n_resumed) == (1, first.n_cells - 1)


def _small_run(tmp_path, spec=None):
    return run(spec or Spec.from_dict(SMALL, source="small"), out=tmp_path / "run", jobs=1,
               progress=False, figures=False, cache_dir=tmp_path / "cache")


def test_the_report_shows_the_code_of_the_run_that_wrote_it(tmp_path, monkeypatch,
                                                            frozen_code):
    """After a code change that recomputes no cell, the report is redrawn (its manifest
    input changed) and must show the new code: it read manifest.json before the run wrote
    it (the run wrote it only after the outputs), so it lagged one run behind."""
    from experiments.runner import run as run_mod

    _small_run(tmp_path)
    report = tmp_path / "run" / "REPORT.md"
    assert "code frozen (package" in report.read_text()
    monkeypatch.setattr(run_mod, "code_version", lambda: {"git_describe": "abc1234-dirty"})
    again = _small_run(tmp_path)
    assert again.n_computed == 0 and "report" in again.timings["outputs"]["written"]
    assert "code abc1234-dirty (package" in report.read_text()
    assert json.loads((tmp_path / "run" / "manifest.json").read_text())["code"] == {
        "git_describe": "abc1234-dirty"}


def _spy_outputs(monkeypatch):
    """Count the outputs phases and the reads of the cell table."""
    from experiments.runner import store

    calls = {"outputs": 0, "table": 0}
    write_outputs, read_table = outputs.write_outputs, store.CellStore.read_table

    def counted_outputs(*a, **k):
        calls["outputs"] += 1
        return write_outputs(*a, **k)

    def counted_table(self, keys):
        calls["table"] += 1
        return read_table(self, keys)

    monkeypatch.setattr(outputs, "write_outputs", counted_outputs)
    monkeypatch.setattr(store.CellStore, "read_table", counted_table)
    return calls


def test_a_settled_resume_reads_no_table_and_runs_no_outputs_phase(tmp_path, monkeypatch,
                                                                   frozen_code):
    """Nothing changed since the last run finished (the store's index holds the digest of
    its inputs and files): the resume neither reads the cell table (pandas) nor runs the
    outputs phase; the table is read when asked for, and is the same."""
    first = _small_run(tmp_path)
    calls = _spy_outputs(monkeypatch)
    before = _stamps(tmp_path / "run")
    again = _small_run(tmp_path)
    assert calls == {"outputs": 0, "table": 0}
    assert again.timings["outputs"] == {"written": [], "seconds": {},
                                        "unchanged": ["page", "report", "tables"]}
    assert "0 of 3 rewritten" in again.summary()
    assert _stamps(tmp_path / "run") == before
    assert again.cells.equals(first.cells) and calls["table"] == 1


@pytest.mark.parametrize("change", ["output", "outputs_code", "errors", "declared"])
def test_a_resume_after_a_change_runs_the_outputs_phase(tmp_path, monkeypatch, frozen_code,
                                                        change):
    """Any change the settled digest covers sends the resume through the outputs phase,
    which redraws what changed: a touched output, the code of experiments/, a file in
    errors/, the folder of a declared study ([report] sensitivity)."""
    from experiments.runner import run as run_mod

    study = tmp_path / "study"
    study.mkdir()
    spec = Spec.from_dict({**SMALL, "report": {"sensitivity": str(study)}}, source="small")
    _small_run(tmp_path, spec)
    out = tmp_path / "run"
    if change == "output":
        (out / "tables.md").write_text("edited")
    elif change == "outputs_code":
        monkeypatch.setattr(run_mod, "outputs_code_digest", lambda: "other")
    elif change == "errors":
        (out / "errors" / "stray.json").write_text("{}")
    else:
        (study / "sensitivity.csv").write_text("a,b\n")
    calls = _spy_outputs(monkeypatch)
    again = _small_run(tmp_path, spec)
    assert calls["outputs"] == 1
    if change == "output":
        assert again.timings["outputs"]["written"] == ["tables", "page"]
        assert (out / "tables.md").read_text() != "edited"
    calls["outputs"] = 0
    _small_run(tmp_path, spec)                      # settled again
    assert calls["outputs"] == 0


_FRESH_PROCESS_RUN = """
import json, sys
from experiments import sweep
from experiments.runner import run as r, store
# the code as constants, as in frozen_code: the tree may be edited between the two processes
r.cell_code_digest = store.cell_code_digest = lambda: "cells-code"
r.outputs_code_digest = lambda: "outputs-code"
r.code_version = lambda: {"git_describe": "frozen"}
code = sweep.main([*sys.argv[1:], "--jobs", "1", "--quiet", "--no-figures"])
heavy = ("pandas", "pyarrow", "numba", "scipy", "matplotlib", "mujoco", "joblib", "cvxpy")
print(json.dumps({"code": code, "imported": [m for m in heavy if m in sys.modules]}))
"""


def test_a_settled_resume_imports_no_heavy_package(tmp_path):
    """The command line in a fresh process: a resume with nothing to do imports none of
    pandas, pyarrow, numba, scipy, matplotlib, mujoco, joblib (no loky executor is made to
    be stopped) or cvxpy (issue 27: they were 0.9 s of a 1.5 s resume)."""
    import subprocess
    import sys

    import tomli_w

    from experiments.spec import REPO

    spec = tmp_path / "small.toml"
    spec.write_text(tomli_w.dumps(SMALL))

    def go() -> tuple[dict, str]:
        proc = subprocess.run([sys.executable, "-c", _FRESH_PROCESS_RUN, str(spec), "--out",
                               str(tmp_path / "run"), "--cache-dir", str(tmp_path / "cache")],
                              cwd=REPO, capture_output=True, text=True, check=True)
        lines = proc.stdout.strip().splitlines()
        return json.loads(lines[-1]), lines[-2]

    first, summary = go()
    assert first["code"] == 0 and "pandas" in first["imported"], summary
    again, summary = go()
    assert again == {"code": 0, "imported": []}
    assert "small: 4 cells (0 computed, 4 resumed, 0 failed)" in summary
    assert "0 of 3 rewritten" in summary
