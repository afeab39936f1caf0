"""Tests of experiments.bench: the in-process reference every section reports (issue 27)
and the single-call fit_window section. Correctness only: no timing is asserted."""

from __future__ import annotations

import re

import pytest

from experiments import bench


def test_numpy_probe_and_reference_ratio():
    """The probe returns a positive time per iteration; ratio() divides by it."""
    ref = bench.Reference(reps=1)
    assert 0 < ref.probe_s < 1e-2 and ref.load >= 0
    assert ref.ratio(10 * ref.probe_s) == "10"
    line = ref.line()
    assert line.startswith("reference: numpy probe ") and "load" in line and "x probe" in line


def test_help_explains_the_reference(capsys):
    with pytest.raises(SystemExit) as exc:
        bench.main(["--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert "fit_window" in out and "Reference:" in out and "x probe" in out


def _table(out: str) -> tuple[list[str], list[list[str]]]:
    lines = [ln for ln in out.splitlines() if ln.startswith("|")]
    cells = [[c.strip() for c in ln.strip("|").split("|")] for ln in lines]
    return cells[0], cells[2:]


def test_fit_window_section_reports_ratios(capsys):
    """--only fit_window --quick (300 windows): every row has the absolute time, the
    probe ratio, the batched ratio and the SLSQP speed-up, and the reference line is there;
    the rows' ratios are consistent with their times."""
    assert bench.main(["--only", "fit_window", "--quick"]) == 0
    out = capsys.readouterr().out
    assert re.search(r"^reference: numpy probe [\d.]+ us per iteration", out, re.MULTILINE)
    head, rows = _table(out)
    assert head == ["case", "wall per call", "CPU per call (mean)", "x probe", "x batched",
                    "speed-up", "target", "met"]
    assert [r[0] for r in rows] == ["2-D, unweighted", "2-D, weights (s, m)",
                                    "2-D, weights (s, m, d)", "3-D, unweighted"]
    probe_us = float(re.search(r"numpy probe ([\d.]+) us", out).group(1))
    for r in rows:
        wall_us = float(r[1].split()[0]) * (1e3 if r[1].endswith("ms") else 1.0)
        # x probe = wall / probe; wall (>= 10 us), probe and ratio are each printed to >= 3
        # significant digits (<= 0.5 % rounding each): 2 % covers it
        assert float(r[3]) == pytest.approx(wall_us / probe_us, rel=0.02)
        assert r[5].endswith("x") and float(r[4]) > 0
        assert r[7] in (("yes", "NO") if r[0].startswith("2-D") else ("-",))

