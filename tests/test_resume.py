"""A resumed sweep redoes nothing whose inputs did not change (issue 27): no cell, no output,
no file rewritten (the git-ignored run.local.json sidecar aside)."""

import json
import time

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


def test_a_resumed_run_rewrites_no_file(tmp_path):
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
