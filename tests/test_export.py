"""Choosing a cell by --key / --where (experiments.selection, shared by export and render):
ambiguous selections name the differing axes and the terms to add, bad values are one-line
errors, and every documented --where example selects exactly one cell."""

import re
import shlex
from pathlib import Path

import pandas as pd
import pytest

from experiments import export, render, selection
from experiments.selection import AmbiguousSelection, parse_where, select_cell
from experiments.spec import load_spec

REPO = Path(__file__).resolve().parents[1]


def _cells(**extra) -> pd.DataFrame:
    """A small cell table in the sweep's column layout (key, axes..., mask, statistics):
    two growth rules of lc+dyn and a second noise split, like the thesis preset."""
    rows = []
    for i, (tech, growth, nov) in enumerate([("lc+dyn", "refill", "{}"),
                                             ("lc+dyn", "jump", "{}"),
                                             ("lc+dyn", "refill", '{"common_fraction":0.9}'),
                                             ("none", "-", "{}")]):
        for mask in ("full", "no_turns"):
            rows.append({"key": f"k{i}", "path": "square100", "noise_overrides": nov,
                         "window": 100, "weighting": "huff", "technique": tech,
                         "dyn_growth": growth, "seed": 0, "mask": mask, "ex_mean": 0.1 * i})
    return pd.DataFrame(rows)


@pytest.fixture(scope="module")
def thesis_cells() -> pd.DataFrame:
    """The thesis preset's cells as cells.parquet lays them out (key, axes, mask), from the
    spec's expansion: the same keys and axis values as a run, without running it."""
    return pd.DataFrame([{"key": c.key, **c.params(), "mask": "full"}
                         for c in load_spec("thesis").expand()])


def test_ambiguous_selection_names_the_differing_axes_and_their_terms():
    with pytest.raises(AmbiguousSelection) as ei:
        select_cell(_cells(), where=parse_where(["technique=lc+dyn", "window=100"]))
    e = ei.value
    assert e.differing == {"noise_overrides": ["{}", '{"common_fraction":0.9}'],
                           "dyn_growth": ["refill", "jump"]}
    msg = str(e)
    assert "found 3" in msg and "differ in noise_overrides, dyn_growth" in msg
    assert "dyn_growth=refill / dyn_growth=jump" in msg
    # JSON terms come quoted for the shell, ready to paste
    assert "'noise_overrides={}' / 'noise_overrides={\"common_fraction\":0.9}'" in msg
    # axes that are the same in every match are not listed as differing
    first = msg.splitlines()[0]
    assert "window" not in first and "path" not in first and "weighting" not in first


def test_adding_the_suggested_terms_selects_one_cell():
    """The listed terms, pasted through a shell (shlex), narrow the selection to one cell."""
    cells = _cells()
    base = ["technique=lc+dyn", "window=100"]
    with pytest.raises(AmbiguousSelection) as ei:
        select_cell(cells, where=parse_where(base))
    lines = str(ei.value).splitlines()
    picked = [shlex.split(line.split(": ", 1)[1].split(" / ")[0])[0] for line in lines[1:3]]
    assert picked == ["noise_overrides={}", "dyn_growth=refill"]
    assert select_cell(cells, where=parse_where([*base, *picked]))["key"] == "k0"


@pytest.mark.parametrize("terms, pattern", [
    (["window=abc"], r"^--where window=abc: window takes an integer, got 'abc'$"),
    (["seed=1.5"], r"^--where seed=1.5: seed takes an integer"),
    (["noise_overrides={oops"], r"^--where noise_overrides=\{oops: noise_overrides takes a JSON"),
    (["colour=red"], r"^--where colour=\.\.\.: unknown axis 'colour'; the axes are path, "),
    (["technique=lc+dyn", "window=7"],
     r"^--where window=7: no cell with technique=lc\+dyn has it; window takes window=100$"),
])
def test_bad_where_terms_are_one_line_errors_naming_the_term(terms, pattern):
    with pytest.raises(ValueError, match=pattern) as ei:
        select_cell(_cells(), where=parse_where(terms))
    assert "\n" not in str(ei.value)


@pytest.mark.parametrize("items, pattern", [
    (["window"], r"--where: expected AXIS=VALUE, got 'window'"),
    (["=5"], r"--where: expected AXIS=VALUE, got '=5'"),
    (["seed=0", "seed=1"], r"--where: seed given twice"),
])
def test_parse_where_rejects_malformed_terms(items, pattern):
    with pytest.raises(ValueError, match=pattern):
        parse_where(items)


def test_json_axes_compare_as_json_and_values_take_the_column_type():
    cells = _cells()
    row = select_cell(cells, where=parse_where(
        ['noise_overrides={"common_fraction": 0.9}', "technique=lc+dyn"]))
    assert row["key"] == "k2"
    assert select_cell(cells, where={"technique": "none", "window": 100})["key"] == "k3"
    assert select_cell(cells, key="k1")["dyn_growth"] == "jump"
    with pytest.raises(ValueError, match="key: no cell has key 'nope'"):
        select_cell(cells, key="nope")


def test_cli_bad_value_is_one_line_and_exit_2(tmp_path, capsys):
    _cells().to_parquet(tmp_path / "cells.parquet")
    for main in (export.main, render.main):
        argv = [str(tmp_path), "--where", "window=abc"]
        if main is render.main:
            argv += ["--out", str(tmp_path / "x.gif")]
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert err == "error: --where window=abc: window takes an integer, got 'abc'\n"


def test_missing_cell_table_is_a_clear_error(tmp_path):
    with pytest.raises(ValueError, match=r"^results: .*cells.parquet not found"):
        selection.find_cell(tmp_path, where={"window": 5})


def _documented_where_examples() -> list[tuple[str, list[str]]]:
    """(source, --where terms) of every export/render example on results/thesis in the
    README, the modules' docstrings and their --help epilogs."""
    texts = {"README.md": (REPO / "README.md").read_text(),
             "export docstring": export.__doc__, "export --help": export.EPILOG,
             "render docstring": render.__doc__}
    import contextlib
    import io
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf), contextlib.suppress(SystemExit):
        render.main(["--help"])
    texts["render --help"] = buf.getvalue()
    out = []
    for src, text in texts.items():
        joined = re.sub(r"\\\\?\n\s*", " ", text)              # shell line continuations
        for m in re.finditer(r"python -m experiments\.(?:export|render) results/thesis[^\n`]*",
                             joined):
            words = shlex.split(m.group(0).split("#")[0])
            if "--where" not in words:
                continue
            i = words.index("--where") + 1
            terms = []
            while i < len(words) and not words[i].startswith("--"):
                terms.append(words[i])
                i += 1
            out.append((src, terms))
    return out


def test_every_documented_where_example_selects_exactly_one_thesis_cell(thesis_cells):
    examples = _documented_where_examples()
    srcs = {s for s, _ in examples}
    assert {"README.md", "export --help", "render --help"} <= srcs, srcs
    for src, terms in examples:
        try:
            select_cell(thesis_cells, where=parse_where(terms))
        except ValueError as exc:                      # pragma: no cover - the failure text
            pytest.fail(f"{src}: --where {' '.join(terms)}: {exc}")


def test_the_old_readme_example_is_ambiguous_with_its_reasons(thesis_cells):
    """The example the README had (issue 23): 4 matches, differing in exactly these axes."""
    with pytest.raises(AmbiguousSelection) as ei:
        select_cell(thesis_cells, where=parse_where(
            ["path=square100", "window=100", "technique=lc+dyn", "weighting=huff", "seed=0"]))
    assert set(ei.value.differing) == {"dyn_growth", "noise_overrides"}
    assert "found 4" in str(ei.value)
