"""Markdown tables (experiments.markdown): every header and cell is escaped, so a header
such as ``mean |x|`` keeps its table's shape; every table of a generated tables.md and
REPORT.md (quick run) and of the committed results/*/*.md has the header's column count on
every row, and the page renders them as tables with those headers."""

import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from experiments import tables
from experiments.markdown import (
    escape_cell,
    markdown_table,
    md_row,
    md_separator,
    split_row,
)

REPO = Path(__file__).resolve().parents[1]



def md_tables(text: str) -> list[tuple[int, list[str], list[list[str]]]]:
    """Every GFM table of ``text``: (line number of the header, header cells, body rows'
    cells), split at unescaped ``|`` (GFM's rule)."""
    lines = text.splitlines()
    out, i = [], 0
    while i < len(lines):
        sep = lines[i + 1] if i + 1 < len(lines) else ""
        if lines[i].startswith("|") and sep.startswith("|") and set(sep) <= set("|-: "):
            j = i + 2
            while j < len(lines) and lines[j].startswith("|"):
                j += 1
            out.append((i + 1, split_row(lines[i]), [split_row(r) for r in lines[i + 2:j]]))
            i = j
        else:
            i += 1
    return out


def bad_rows(text: str) -> list[str]:
    """'line N: k cells, header has h' for every row whose cell count is not the header's."""
    bad = []
    for ln, head, rows in md_tables(text):
        for k, r in enumerate(rows):
            if len(r) != len(head):
                bad.append(f"line {ln + 2 + k}: {len(r)} cells, header has {len(head)}")
    return bad


# --------------------------------------------------------------------------- the writer
@pytest.mark.parametrize("text, cell", [
    ("mean |x|", r"mean \|x\|"),
    ("a\nb", "a b"),
    (r"already \| escaped", r"already \| escaped"),
    ("||", r"\|\|"),
    (3.5, "3.5"),
])
def test_escape_cell(text, cell):
    assert escape_cell(text) == cell


def test_rows_round_trip_through_the_gfm_split():
    cells = ["mean |x|", "{replay = \"a|b\"}", "", "`|y|`"]
    assert split_row(md_row(cells)) == cells
    assert md_separator(3) == "|---|---|---|"
    with pytest.raises(ValueError, match="n: a table has at least one column, got 0"):
        md_separator(0)
    with pytest.raises(ValueError, match="line: not a Markdown table row"):
        split_row("mean |x|")


def test_markdown_table_escapes_headers_and_cells():
    df = pd.DataFrame({"mean |x|": [0.5, np.nan], "label": ["a|b", "c"]})
    text = markdown_table(df)
    assert text.splitlines()[0] == r"| mean \|x\| | label |"
    assert bad_rows(text) == []
    (_, head, rows), = md_tables(text)
    assert head == ["mean |x|", "label"] and rows == [["0.5", "a|b"], ["-", "c"]]
    via_fn = markdown_table(df, [("|y|", lambda r: f"|{r['label']}|")])
    assert md_tables(via_fn)[0][2] == [["|a|b|"], ["|c|"]]


def test_side_study_table_keeps_its_shape(tmp_path):
    """The "Side studies" table (headers "mean |x| (m)"), from a small synthetic study."""
    rows = [{"path": "square100", "noise_overrides": ov, "weighting": "huff",
             "technique": "lc", "window": 100, "mask": "full", "seed": s,
             "ex_mean": 1.0 + s, "ey_mean": 2.0, "eh_median": 0.1}
            for ov in ('{"common_fraction":0.9}', '{"common_fraction":0.99}') for s in (0, 1)]
    md = "\n".join(tables._side_study_md(pd.DataFrame(rows), tmp_path))
    (_, head, body), = md_tables(md)
    assert "mean |x| (m)" in head and bad_rows(md) == []
    assert len(body) == 2


# --------------------------------------------------------------------------- generated
@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    """The quick preset run into a temporary folder (one process, no figures)."""
    from experiments.sweep import run

    out = tmp_path_factory.mktemp("quick")
    res = run("quick", out=out, jobs=1, progress=False, figures=False)
    assert res.n_failed == 0
    return out


@pytest.mark.parametrize("name", ["tables.md", "REPORT.md"])
def test_every_generated_table_has_the_header_column_count(quick_run, name):
    text = (quick_run / name).read_text()
    found = md_tables(text)
    assert len(found) >= 3, f"{name}: only {len(found)} tables"
    assert bad_rows(text) == []


def test_weighting_table_headers_survive(quick_run):
    text = (quick_run / "tables.md").read_text()
    sec = text[text.index("## Weighting comparison"):]
    (_, head, rows) = md_tables(sec)[0]
    assert head == ["Path", "Window", "Weights", "mean |x|", "median |x|", "mean |y|",
                    "median |y|"]
    assert rows and all(len(r) == 7 for r in rows)


def test_the_page_renders_the_weighting_table_as_a_table(quick_run):
    """page.py renders tables.md with markdown-it (GFM tables): the escaped headers come
    out as one <th> each, and every body row has as many cells."""
    from experiments.page import _markdown

    html = _markdown((quick_run / "tables.md").read_text())
    sec = html[html.index("Weighting comparison"):]
    table = sec[sec.index("<table>"):sec.index("</table>")]
    heads = re.findall(r"<th[^>]*>(.*?)</th>", table)
    assert heads == ["Path", "Window", "Weights", "mean |x|", "median |x|", "mean |y|",
                     "median |y|"]
    for row in re.findall(r"<tr>(.*?)</tr>", table.split("<tbody>")[1], re.DOTALL):
        assert len(re.findall(r"<td", row)) == 7


def test_tables_title_is_the_spec_name(quick_run):
    """The run went to a folder named quick0 (or so); the title names the spec."""
    assert quick_run.name != "quick"
    assert (quick_run / "tables.md").read_text().splitlines()[0] == "# Tables (quick)"
    assert "(quick)" in (quick_run / "REPORT.md").read_text().splitlines()[0]


# --------------------------------------------------------------------------- committed
COMMITTED = sorted(str(p.relative_to(REPO)) for p in REPO.glob("results/*/*.md"))


@pytest.mark.parametrize("rel", COMMITTED)
def test_committed_tables_have_the_header_column_count(rel):
    assert bad_rows((REPO / rel).read_text()) == []


# --------------------------------------------------------------------------- small items
def _beyond(label: str, window: int, mean: float) -> dict:
    row = {"path": "square100", "window": window, "technique": label, "kind": "beyond",
           "n_seeds": 3}
    for k, s in enumerate(tables.STATS):
        v = mean + k
        row.update({s: v, f"{s}_lo": v - 0.1, f"{s}_hi": v + 0.1, f"{s}_thesis": np.nan})
    return row


def test_filter_rows_repeated_per_window_are_shown_once_with_their_windows():
    """EKF rows (the window only sets the first scored estimate) with identical numbers at
    windows 1, 5, 10 merge into one row "1, 5, 10"; window 100 (other numbers) keeps its
    row; a window fit with equal numbers at two windows is not merged; no number changes."""
    df = pd.DataFrame([_beyond("EKF (causal)", 1, 0.8236), _beyond("Naive CG mean", 1, 0.9),
                       _beyond("EKF (causal)", 5, 0.8236), _beyond("Naive CG mean", 5, 0.9),
                       _beyond("EKF (causal)", 10, 0.8236),
                       _beyond("EKF (causal)", 100, 0.8076)])
    merged = tables.merge_window_repeats(df)
    ekf = merged[merged["technique"] == "EKF (causal)"]
    assert list(ekf["windows"]) == ["1, 5, 10", ""] and list(ekf["window"]) == [1, 100]
    assert list(ekf["mean"]) == [0.8236, 0.8076]
    assert len(merged[merged["technique"] == "Naive CG mean"]) == 2
    pd.testing.assert_frame_equal(merged.drop(columns="windows"), df.loc[merged.index])
    md = tables.thesis_table_md(merged)
    assert "| 1, 5, 10 | EKF (causal) |" in md and "| 100 | EKF (causal) |" in md
    assert bad_rows(md) == []
    # a last-digit difference is not a repeat
    df.loc[4, "mean_hi"] += 1e-15
    assert list(tables.merge_window_repeats(df).query("technique == 'EKF (causal)'")
                ["windows"]) == ["1, 5", "", ""]
