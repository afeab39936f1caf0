"""The sensitivity study a spec declares for its report (``[report] sensitivity``, issue 24):
the Cause lines quote only the declared folder, say "not re-measured" without one, and the
declaration is validated like ``[page] flight``. The report runs on the cells of a small
sweep of the thesis preset's own rows (:func:`claims_run`: the committed thesis cells.parquet
is git-ignored, so the tests run in CI too); the expected numbers are read from the committed
results/sensitivity/ tables, so the tests follow a regenerated study."""

from __future__ import annotations

import json
import re
import shutil
import tomllib
from pathlib import Path

import pandas as pd
import pytest

from experiments import causes, report
from experiments.spec import REPO, Spec, SpecError, load_spec
from experiments.sweep import run

PRESETS = REPO / "experiments" / "presets"
STUDY = REPO / "results" / "sensitivity"
TINY = {"name": "tiny", "seed": 1, "seeds": 1,
        "grid": [{"path": "square20", "window": 1, "technique": "none"}]}
#: The thesis preset's grids (by name) that C2, C8 and C14 and their Cause lines read, Path 1
#: only, with the techniques kept (None: all): technique none at every window and weighting,
#: LC, the oracle LC; its three masks and seed root. With 4 seeds the three verdicts are the
#: thesis run's (mixed, mixed, not reproduced): 3.1 s of simulation and 3.9 s of cells with
#: an empty truth cache (measured at load 4.4, --jobs 1).
CLAIM_GRIDS = {"weighting": None, "techniques": ["lc"], "oracle": None}
CLAIM_SEEDS = 4


@pytest.fixture(scope="module")
def claims_run(tmp_path_factory) -> Path:
    """A sweep of the thesis preset cut to :data:`CLAIM_GRIDS` (cells only, one process, its
    own truth cache): the folder with cells.parquet and manifest.json."""
    d = tomllib.loads((PRESETS / "thesis.toml").read_text())
    d["grid"] = [{**g, "path": "square100"} for g in d["grid"] if g["name"] in CLAIM_GRIDS]
    for g in d["grid"]:
        g["technique"] = CLAIM_GRIDS[g["name"]] or g["technique"]
    d = {**{k: v for k, v in d.items() if k not in ("page", "epochs")}, "seeds": CLAIM_SEEDS}
    out = tmp_path_factory.mktemp("claims_run")
    res = run(Spec.from_dict(d, source="thesis.toml (cut)", base_dir=PRESETS), out=out, jobs=1,
              progress=False, outputs=False, cache_dir=tmp_path_factory.mktemp("truth"))
    assert res.n_failed == 0
    return out


def _run(dest: Path, sensitivity: str | None, src: Path) -> Path:
    """A copy of the run ``src``'s cells and manifest whose spec declares ``sensitivity``
    (what a sweep of such a spec records; None: no ``[report]`` table), relative to the
    project."""
    dest.mkdir()
    shutil.copyfile(src / "cells.parquet", dest / "cells.parquet")
    man = json.loads((src / "manifest.json").read_text())
    man["spec"].pop("report", None)
    if sensitivity is not None:
        man["spec"]["report"] = {"sensitivity": sensitivity}
    man["spec_base_dir"] = "experiments/presets"
    (dest / "manifest.json").write_text(json.dumps(man))
    return dest


def _causes(run_dir: Path) -> dict[str, str]:
    """{claim id: its Cause line} of the run's REPORT.md, written from its cells."""
    report.write_report(pd.read_parquet(run_dir / "cells.parquet"), run_dir)
    out, cid = {}, None
    for line in (run_dir / "REPORT.md").read_text().splitlines():
        m = re.match(r"## (C\w+) \(", line)
        cid = m.group(1) if m else cid
        if line.startswith("Cause:") and cid:
            out[cid] = line
    return out


def _verdicts(folder: Path, cid: str, quantity: str) -> list[str]:
    """"**verdict** (k/n)" of ``cid`` at the shipped setting and every value of ``quantity``."""
    s = pd.read_csv(folder / "sensitivity.csv")
    s = s[(s["claim"] == cid) & s["quantity"].isin(["shipped", quantity])]
    return [f"**{r.verdict}** ({r.supports}/{r.evaluated})" for r in s.itertuples()]


def test_without_a_declared_study_nothing_under_results_sensitivity_is_read(
        tmp_path, monkeypatch, claims_run):
    """No ``[report]`` table: C2, C8 and C14 say not re-measured, and no file of the
    committed study is opened (the report used to read it for every run)."""
    read_csv = pd.read_csv

    def guarded(f, *a, **k):
        assert STUDY not in Path(f).resolve().parents, f"read {f} without a declared study"
        return read_csv(f, *a, **k)

    monkeypatch.setattr(pd, "read_csv", guarded)
    lines = _causes(_run(tmp_path / "run", None, claims_run))
    assert {"C2", "C8", "C14"} <= set(lines)             # mixed, mixed, not reproduced
    said = "Not re-measured: the spec declares no sensitivity study ([report] sensitivity)."
    assert said in lines["C2"] and said in lines["C8"]
    assert ("Not re-measured with wider turns: the spec declares no sensitivity study "
            "([report] sensitivity); at window 100") in lines["C14"]
    assert not any("Re-measured with" in v for v in lines.values())


def test_a_declared_study_is_quoted_with_its_numbers(tmp_path, claims_run):
    """``results/sensitivity`` declared: the C2, C8 and C14 lines quote the committed
    study's verdicts (what the code printed before the declaration: the whole REPORT.md was
    byte-identical on the committed thesis cells), and the rest of the C2 line is the same
    as without the study."""
    lines = _causes(_run(tmp_path / "run", "results/sensitivity", claims_run))
    for cid, q in (("C2", "speed"), ("C8", "common_fraction"), ("C14", "turn_width")):
        assert "(sensitivity study, results/sensitivity/, " in lines[cid]
        if cid != "C14":                                   # C14 quotes supports below w=100
            for v in _verdicts(STUDY, cid, q):
                assert v in lines[cid], (cid, v)
    assert "0.2 m/s (shipped) **" in lines["C2"] and "3 m (shipped)" in lines["C14"]
    mask = pd.read_csv(STUDY / "mask.csv")
    for r in mask.itertuples():
        assert f"{r.dilate_s:g} s, {100 * r.dropped_w5:.0f} % of the w=5 estimates" in lines["C14"]
    none = _causes(_run(tmp_path / "none", None, claims_run))
    head = lines["C2"].split(" Re-measured with")[0]
    assert none["C2"].startswith(head + " Not re-measured")


def test_the_cause_lines_read_the_declared_folder_only(tmp_path, claims_run):
    """A copy of the study with one verdict changed, declared instead: its verdict is
    quoted; a declared folder without shipped.csv (an older study) is named, not read."""
    copy = tmp_path / "study"
    shutil.copytree(STUDY, copy, ignore=shutil.ignore_patterns("*.md", "*.json"))
    s = pd.read_csv(copy / "sensitivity.csv")
    at = (s["claim"] == "C2") & (s["quantity"] == "speed") & (s["value"] == 0.1)
    s.loc[at, ["verdict", "supports"]] = ["not reproduced", 0]
    s.to_csv(copy / "sensitivity.csv", index=False)
    run_dir = _run(tmp_path / "run", str(copy.relative_to(tmp_path)), claims_run)
    man = json.loads((run_dir / "manifest.json").read_text())
    man["spec_base_dir"] = str(tmp_path)                   # the spec's folder: tmp_path
    (run_dir / "manifest.json").write_text(json.dumps(man))
    assert causes.declared_sensitivity(run_dir).folder == copy
    c2 = _causes(run_dir)["C2"]
    assert "0.1 m/s **not reproduced** (0/8)" in c2 and "(sensitivity study, study/, " in c2
    (copy / "shipped.csv").unlink()
    c2 = _causes(run_dir)["C2"]
    assert ("Not re-measured: study ([report] sensitivity) lacks the sensitivity study's "
            "sensitivity.csv, comparisons.csv, shipped.csv") in c2


def test_the_thesis_preset_declares_its_sensitivity_study():
    spec = load_spec("thesis")
    assert spec.report == {"sensitivity": "results/sensitivity"}
    assert spec.to_dict()["report"] == spec.with_solver("elastic").to_dict()["report"]
    assert "report" not in load_spec("quick").to_dict()        # recorded only when present
    assert causes.declared_sensitivity("unused", spec).folder == STUDY
    assert causes.declared_sensitivity("unused", load_spec("quick")) == causes.Sensitivity()


@pytest.mark.parametrize("table, match", [
    ({"sensitivity": 3}, r"report\.sensitivity: must be a folder path \(string\).*got 3"),
    ({"sensitivity": " "}, r"report\.sensitivity: must be a folder path"),
    ({"sensitivity": "../../../etc"},
     r"report\.sensitivity: '\.\./\.\./\.\./etc' must be named relative"),
    ({"sensitivity": "/etc"}, r"report\.sensitivity: '/etc' must be named relative"),
    ({"sensitivty": "results/sensitivity"}, r"report: unknown key\(s\) \['sensitivty'\]"),
    ("results/sensitivity", r"report: must be a table"),
])
def test_a_bad_report_table_is_a_one_line_spec_error(tmp_path, table, match):
    with pytest.raises(SpecError, match=match) as ei:
        Spec.from_dict({**TINY, "report": table}, source="s.toml", base_dir=tmp_path)
    assert "\n" not in str(ei.value)


def test_a_study_outside_the_project_is_refused(tmp_path):
    """A folder holding the study but outside the spec's folder and the project: the one
    path rule of every file a spec names refuses it, naming the field."""
    (tmp_path / "elsewhere").mkdir()
    (tmp_path / "elsewhere" / "sensitivity.csv").write_text("claim\n")
    (tmp_path / "specs").mkdir()
    (tmp_path / "specs" / "s.toml").write_text(
        'name = "s"\n[report]\nsensitivity = "../elsewhere"\n'
        '[[grid]]\npath = "square20"\nwindow = 1\n')
    with pytest.raises(SpecError, match=r"report\.sensitivity: .*leaves the folder of the file"):
        load_spec(tmp_path / "specs" / "s.toml")


def test_a_bad_value_in_a_manifest_names_the_field(tmp_path):
    (tmp_path / "manifest.json").write_text(json.dumps(
        {"spec": {"report": {"sensitivity": 7}}, "spec_base_dir": str(tmp_path)}))
    with pytest.raises(SpecError, match=r"manifest\.json: spec\.report\.sensitivity: must be"):
        causes.declared_sensitivity(tmp_path)
    (tmp_path / "manifest.json").write_text("{damaged")
    assert causes.declared_sensitivity(tmp_path) == causes.Sensitivity()


def _section(run_dir: Path) -> list[str]:
    """The lines of REPORT.md's "Sensitivity of the verdicts" section (empty: none)."""
    text = (run_dir / "REPORT.md").read_text().split("\n## ")
    return next((s.splitlines() for s in text if s.startswith("Sensitivity of the verdicts")),
                [])


def _flip_rows(lines: list[str]) -> set[str]:
    return {m.group(1) for r in lines if (m := re.match(r"\| (C\d+c?) \|", r))}


def test_the_sensitivity_section_tables_the_studys_flips(tmp_path):
    """A row for every claim whose verdict flips in sensitivity.csv and none for the others,
    with the flipped values and their verdicts; a verdict changed in a copy of the study adds
    its claim; no declared study: no section (needs only the committed study's CSVs)."""
    copy = tmp_path / "study"
    shutil.copytree(STUDY, copy, ignore=shutil.ignore_patterns("*.md", "*.json"))
    sens = causes.Sensitivity("study", copy)
    s = pd.read_csv(copy / "sensitivity.csv")
    flipped = set(s[s["flipped"] & (s["quantity"] != "shipped")]["claim"])
    steady = sorted(set(s["claim"]) - flipped)
    lines = causes.sensitivity_section(sens)
    assert lines[0] == "## Sensitivity of the verdicts" and _flip_rows(lines) == flipped
    at = (s["claim"] == steady[0]) & (s["quantity"] == "sigma") & (s["value"] == 1.5)
    assert at.sum() == 1
    s.loc[at, ["verdict", "supports", "flipped"]] = ["odd verdict", 0, True]
    s.to_csv(copy / "sensitivity.csv", index=False)
    row = next(r for r in causes.sensitivity_section(sens) if r.startswith(f"| {steady[0]} |"))
    assert "1.5: **odd verdict** (0/" in row
    assert causes.sensitivity_section(causes.Sensitivity()) == []


def test_the_report_carries_the_sensitivity_section(tmp_path, claims_run):
    """REPORT.md of a run whose spec declares the study has the section; without: none."""
    run_dir = _run(tmp_path / "run", "results/sensitivity", claims_run)
    man = json.loads((run_dir / "manifest.json").read_text())
    man["spec_base_dir"] = str(REPO)
    (run_dir / "manifest.json").write_text(json.dumps(man))
    report.write_report(pd.read_parquet(run_dir / "cells.parquet"), run_dir)
    assert _flip_rows(_section(run_dir))
    bare = _run(tmp_path / "bare", None, claims_run)
    report.write_report(pd.read_parquet(bare / "cells.parquet"), bare)
    assert _section(bare) == []
