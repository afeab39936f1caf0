"""The sensitivity study (experiments.sensitivity), the Summary's counts (experiments.report)
and the Cause lines that quote the study (experiments.causes), on synthetic tables: no
simulation except the spec's expansion."""

import json
import math

import numpy as np
import pandas as pd
import pytest

from experiments import causes, report, sensitivity
from experiments.claims import _derived, evaluate_claims
from experiments.tables import THESIS_ROWS, THESIS_TABLES


def _table_cells(factor) -> pd.DataFrame:
    """Path 1 Huff cells of every Table 4.1/4.2 row at ``factor(axis, window, row, stat)``
    times the published value, 3 seeds, no noise."""
    rows = []
    for (w, row) in THESIS_TABLES["x"]:
        tech, mask = THESIS_ROWS[row]
        for s in range(3):
            d = {"key": f"{w}-{tech}-{mask}-{s}", "path": "square100", "window": w,
                 "weighting": "huff", "technique": tech, "mask": mask, "seed": s}
            for ax in ("x", "y"):
                for st, pub in THESIS_TABLES[ax][(w, row)].items():
                    d[f"e{ax}_{st}"] = pub * factor(ax, w, row, st)
            rows.append(d)
    return pd.DataFrame(rows)


def test_agreement_counts_the_published_cells_by_ratio():
    # x: within 5 % (counted in both bands); y: LC rows 3x (beyond 2x, too high), others 0.8x
    def f(ax, w, row, st):
        return 1.05 if ax == "x" else 3.0 if row.startswith("LC") else 0.8
    a = report.agreement(_table_cells(f))
    n_lc = 3 * 3 * 3                                   # LC rows x windows x statistics
    assert a == {"cells": 90, "within10": 45, "within25": 45 + 45 - n_lc,
                 "beyond2x": n_lc, "misses": n_lc, "high": n_lc}


def test_agreement_band_edges():
    a = report.agreement(_table_cells(lambda *k: 1.12))
    assert (a["within10"], a["within25"], a["beyond2x"]) == (0, 90, 0)
    a = report.agreement(_table_cells(lambda *k: 0.45))
    assert (a["misses"], a["high"], a["beyond2x"]) == (90, 0, 90)


def test_verdict_counts_text():
    res = evaluate_claims(_derived(_table_cells(lambda *k: 1.0)))
    text = report.verdict_counts(res)
    got = {k: int(v) for k, v in (p.rsplit(" ", 1) for p in text.split(", "))}
    want = pd.Series([r.verdict for r in res]).value_counts().to_dict()
    assert got == {k: want.get(k, 0) for k in got} and sum(got.values()) == len(res)


def test_speed_bound_from_the_published_window_100_rows():
    lo, hi = sensitivity.speed_bound()
    x100, x10 = (THESIS_TABLES["x"][(w, "None")]["mean"] for w in (100, 10))
    y100, y10 = (THESIS_TABLES["y"][(w, "None")]["mean"] for w in (100, 10))
    assert hi == pytest.approx(max(x100, y100) / 24.75)
    assert lo == pytest.approx(min(x100 - x10, y100 - y10) / 24.75)
    assert 0.1 < lo < 0.2 < hi < 0.3          # the shipped 0.2 m/s is inside


def test_tau_bounds_match_a_simulated_ar1_error():
    """The high bound: an AR(1) error with that time constant shrinks the spread of
    10-sample means by 10 % (Monte Carlo, 400k samples: the ratio's standard error is
    about 0.005, so 0.02 is four of them); the low bound: its ACF at R's default maximum
    lag equals the significance bound (exact)."""
    n = 3700
    lo, hi = sensitivity.tau_bounds(n, order=1)
    lag = int(10 * math.log10(n))
    assert math.exp(-lag / lo) == pytest.approx(1.96 / math.sqrt(n), rel=1e-6)
    rng = np.random.default_rng(0)
    phi, m = math.exp(-1 / hi), 400_000
    e = np.empty(m)
    e[0] = rng.normal()
    w = rng.normal(scale=math.sqrt(1 - phi ** 2), size=m)
    for i in range(1, m):
        e[i] = phi * e[i - 1] + w[i]
    means = np.convolve(e, np.ones(10) / 10, mode="valid")
    assert means.std() / e.std() == pytest.approx(0.9, abs=0.02)
    lo2, hi2 = sensitivity.tau_bounds(n, order=2)
    assert hi2 < lo2          # no order-2 time constant satisfies both readings


def test_spec_has_every_variant_on_the_claim_grids():
    spec = sensitivity.sensitivity_spec(1)
    cells = spec.expand()
    per_variant = len(cells) // len(sensitivity.variants())
    assert len(cells) == per_variant * len(sensitivity.variants())
    assert not any(c.technique in sensitivity.DROP for c in cells)
    tau = [c for c in cells if "receiver_tau_s" in c.noise_overrides]
    ov = {json.dumps(json.loads(c.noise_overrides), sort_keys=True) for c in tau}
    assert json.dumps({"common_tau_s": 75.0, "receiver_tau_s": 15.0}, sort_keys=True) in ov
    assert {c.path for c in cells} == {"square100", "square200"}


def _weighting_cells(huff: float, over: str = "{}") -> pd.DataFrame:
    rows = []
    for p in ("square100", "square200"):
        for w in (1, 5, 10, 100):
            for wt, v in (("huff", huff), ("none", 1.0), ("random", 1.1)):
                for s in range(4):
                    rows.append({"key": f"{p}{w}{wt}{s}{over}", "path": p, "window": w,
                                 "weighting": wt, "technique": "none", "mask": "full", "seed": s,
                                 "noise_overrides": over, "path_overrides": "{}",
                                 "n_epochs": 100, **{f"e{a}_{st}": v + 0.01 * s for a in "xy"
                                                     for st in ("mean", "median")}})
    return pd.DataFrame(rows)


def test_evaluate_variants_flags_the_flip_and_feeds_the_cause_line(tmp_path):
    q = (sensitivity.Quantity("common_fraction", "common_fraction", "noise", "-", (0.0,), "a"),)
    cells = pd.concat([_weighting_cells(0.8), _weighting_cells(1.0, '{"common_fraction":0.0}')])
    sens, comps, _ = sensitivity.evaluate_variants(cells, q)
    c8 = sens[sens["claim"] == "C8"].set_index("quantity")
    assert c8.loc["shipped", "verdict"] == "reproduced"
    assert c8.loc["common_fraction", "verdict"] == "mixed"      # still below random
    assert c8.loc["common_fraction", "flipped"]
    assert not sens.loc[sens["claim"] == "C7", "flipped"].any()
    sensitivity.write_tables(tmp_path, {"sensitivity": sens, "comparisons": comps,
                                        "shipped": sensitivity.shipped_table(
                                            sensitivity.shipped())})
    study = causes.Sensitivity(str(tmp_path), tmp_path)
    text = causes._fraction_text(study, causes._fraction_gains(study))
    gain = "Huff lowers the w=1 mean |x| by "
    assert f"common_fraction 0.5 (shipped) **reproduced** (64/64), {gain}19." in text
    assert f"common_fraction 0 **mixed** (32/64), {gain}0.0 %" in text
    main = _derived(_weighting_cells(0.8))
    r = next(x for x in evaluate_claims(main) if x.claim.cid == "C8")
    ev = causes.Evidence(main, main, main.iloc[:0], study)
    assert "not the common part of the error" in causes._c8(ev, r)   # cf 0 gains 0 %
    ev = causes.Evidence(main, main, main.iloc[:0])                   # none declared
    assert "Not re-measured: the spec declares no sensitivity study" in causes._c8(ev, r)
    assert "the error common to all receivers moves them alike" in causes._c8(ev, r)


def test_shipped_csv_holds_every_quantity_as_shipped(tmp_path):
    """shipped.csv (what the Cause lines label "(shipped)") has one row per quantity with the
    value of its model / path file, exact through the 6-digit writer."""
    ship = sensitivity.shipped()
    sensitivity.write_tables(tmp_path, {"shipped": sensitivity.shipped_table(ship)})
    t = pd.read_csv(tmp_path / "shipped.csv").set_index("quantity")
    assert list(t.index) == [q.name for q in sensitivity.QUANTITIES]
    assert t["value"].to_dict() == ship
    assert t.loc["speed", "field"] == "cruise_speed_mps" and t.loc["speed", "unit"] == "m/s"


def test_the_committed_study_holds_the_shipped_values():
    """results/sensitivity/shipped.csv matches the model files (it was added from them)."""
    t = pd.read_csv(sensitivity.REFERENCE / "shipped.csv").set_index("quantity")
    assert t["value"].to_dict() == sensitivity.shipped()


def test_evaluate_variants_names_a_missing_variant():
    q = (sensitivity.Quantity("sigma", "sigma_m", "noise", "m", (3.0,), "c"),)
    with pytest.raises(ValueError, match="sigma = 3.0"):
        sensitivity.evaluate_variants(_weighting_cells(0.8), q)


def test_cli_rejects_out_with_reference(capsys):
    with pytest.raises(SystemExit) as e:
        sensitivity.main(["--reference", "--out", "/tmp/x"])
    assert e.value.code == 2 and "--out" in capsys.readouterr().err


def test_wide_mask_widens_the_window_on_both_sides():
    turning = np.array([0, 0, 0, 1, 0, 0, 0, 0], bool)
    w = np.full(8, 2)
    assert sensitivity.wide_mask(turning, w, 0).tolist() == [1, 1, 1, 0, 0, 1, 1, 1]
    assert sensitivity.wide_mask(turning, w, 1).tolist() == [1, 1, 0, 0, 0, 0, 1, 1]
    assert sensitivity.wide_mask(turning, np.full(8, 1), 0).tolist() == [1, 1, 1, 0, 1, 1, 1, 1]


def test_mask_table_feeds_c14_per_widening(tmp_path):
    """Two seeds of an LC cell whose |x| error is large on the turn and 10 epochs around
    it: the plain mask keeps the large errors beside the turn (C14's comparison stays
    inconclusive or worse), a 10 s widening drops them (full-path std > no-turns std)."""
    rng = np.random.default_rng(3)
    n, rows = 200, []
    turning = np.zeros(n, bool)
    turning[100:103] = True
    (tmp_path / "epochs").mkdir()
    for s in range(3):
        err = 0.1 * rng.normal(size=n)
        err[92:112] += 5.0
        key = f"k{s}"
        pd.DataFrame({"err_x": err, "err_y": err, "truth_turning": turning,
                      "window": np.full(n, 5)}).to_parquet(tmp_path / "epochs" / f"{key}.parquet")
        rows.append({"key": key, "mask": "full", "window": 5, "seed": s})
    m = sensitivity.evaluate_mask(sensitivity.mask_cells(pd.DataFrame(rows), tmp_path))
    m = m.set_index("dilate_s")
    assert m.loc[0.0, "small_evaluated"] == 2       # w=5 only, |x| and |y|
    assert m.loc[10.0, "small_supports"] == 2 and m.loc[10.0, "diff_w5_x"] > 1.0
    assert m.loc[0.0, "diff_w5_x"] < m.loc[10.0, "diff_w5_x"]
    assert m.loc[60.0, "dropped_w5"] > m.loc[0.0, "dropped_w5"]


class _Failed:
    """What the runner returns when a cell failed: main stops there (exit 1)."""

    n_failed, out_dir = 1, "nowhere"


def test_cli_quantity_runs_only_its_variants(monkeypatch, capsys):
    """``--quantity`` (repeatable): the sweep holds the shipped setting and the named
    quantities' values only, in QUANTITIES order; the runner is replaced (no cells run)."""
    from experiments.runner import run as runner

    specs = []
    monkeypatch.setattr(runner, "run", lambda spec, **kw: specs.append(spec) or _Failed())
    assert sensitivity.main(["--quantity", "tau", "--quantity", "sigma", "--seeds", "1"]) == 1
    cells = specs[0].expand()
    qs = [q for q in sensitivity.QUANTITIES if q.name in ("sigma", "tau")]
    want = {json.dumps(ov, sort_keys=True) for ov in [{}] + [q.overrides(v) for q in qs
                                                               for v in q.values]}
    assert {json.dumps(json.loads(c.noise_overrides), sort_keys=True) for c in cells} == want
    assert {c.path_overrides for c in cells} == {"{}"}
    assert len(cells) == len(sensitivity.sensitivity_spec(1).expand()) * 9 // 18
    names = [b["name"].split(":")[1].split("=")[0] for b in specs[0].raw["grid"]]
    assert list(dict.fromkeys(names)) == ["shipped", "sigma", "tau"]
    assert "9 variants" in capsys.readouterr().err


def test_cli_rejects_an_unknown_quantity_naming_it(capsys):
    with pytest.raises(SystemExit) as e:
        sensitivity.main(["--quantity", "sigma_m"])
    err = capsys.readouterr().err
    assert e.value.code == 2 and "'sigma_m'" in err and "turn_width" in err
    assert len(err.strip().splitlines()) == 1


def test_cli_rejects_quantity_with_reference(capsys):
    """The committed reference is always the full study."""
    with pytest.raises(SystemExit) as e:
        sensitivity.main(["--reference", "--quantity", "speed"])
    err = capsys.readouterr().err
    assert e.value.code == 2 and "--quantity speed" in err and "--reference" in err
    assert len(err.strip().splitlines()) == 1


def test_report_of_one_quantity_names_only_it_and_its_command(tmp_path):
    q = (sensitivity.Quantity("common_fraction", "common_fraction", "noise", "-", (0.0,), "a"),)
    cells = pd.concat([_weighting_cells(0.8), _weighting_cells(1.0, '{"common_fraction":0.0}')])
    sens, _, turns = sensitivity.evaluate_variants(cells, q)
    cmd = "python -m experiments.sensitivity --seeds 4 --quantity common_fraction"
    text = sensitivity.write_report(sens, turns, tmp_path, {"common_fraction": "none"},
                                    {"common_fraction": 0.5}, 4, None, q, cmd).read_text()
    assert f"Generated by `{cmd}`" in text
    assert "| Claim | Shipped | common_fraction |" in text
    assert "| common_fraction | `common_fraction` (noise, -) | 0.5 | 0 |" in text
    assert "sigma" not in text and "Flips per quantity: common_fraction 1" in text
