"""Tables and the claim report on synthetic cell tables (no simulation).

The verdict rule (experiments/report.py RULE) is checked on cell tables built by hand, where
the right verdict is known; the seed intervals against statsmodels' t interval.
"""

import math

import numpy as np
import pandas as pd
import pytest

from experiments import causes as causes_mod
from experiments import claims, report, tables
from experiments.claims import CLAIMS, Comparison, compare, evaluate_claims, verdict


def _cells(values: dict, seeds=range(5), noise=0.01, rng_seed=0) -> pd.DataFrame:
    """A synthetic cell table: ``values[(path, window, weighting, technique, mask)]`` ->
    dict of metric -> mean; each seed adds small independent noise."""
    rng = np.random.default_rng(rng_seed)
    rows = []
    for (path, w, wt, tech, mask), metrics in values.items():
        for s in seeds:
            row = {"key": f"{path}-{w}-{wt}-{tech}-{s}", "path": path, "window": w,
                   "weighting": wt, "technique": tech, "mask": mask, "seed": s,
                   "config": "rover_gps8", "noise": "gps_stationary", "noise_overrides": "{}",
                   "path_overrides": "{}", "solver": "procrustes", "dyn_window": 0,
                   "turning": "-"}
            for k, v in metrics.items():
                row[k] = v + noise * rng.normal()
            rows.append(row)
    return pd.DataFrame(rows)


def _weights(huff: float, none: float, random: float, noise: float = 0.01) -> pd.DataFrame:
    vals = {}
    for p in ("square100", "square200"):
        for w in (1, 5, 10, 100):
            for wt, v in (("huff", huff), ("none", none), ("random", random)):
                vals[(p, w, wt, "none", "full")] = {"ex_mean": v, "ex_median": v, "ey_mean": v,
                                                    "ey_median": v}
    return _cells(vals, noise=noise)


def _claim(cid):
    return next(c for c in CLAIMS if c.cid == cid)


def test_seed_interval_matches_statsmodels():
    from statsmodels.stats.weightstats import DescrStatsW

    v = np.array([1.0, 1.4, 0.7, 1.9, 1.2, 0.8])
    m, lo, hi, n = tables.seed_ci(v)
    ref = DescrStatsW(v).tconfint_mean(alpha=0.05)
    assert n == 6 and m == pytest.approx(v.mean())
    assert (lo, hi) == pytest.approx(ref, rel=1e-12)
    m1, lo1, hi1, n1 = tables.seed_ci([2.0, np.nan])
    assert (m1, n1) == (2.0, 1) and math.isnan(lo1) and math.isnan(hi1)


def test_interval_of_a_non_negative_mean_respects_the_support():
    """Two seeds of an absolute error: the t-interval reaches below 0 (issue 13); cut at the
    support bound the upper end is unchanged, and the table marks it unreliable."""
    from statsmodels.stats.weightstats import DescrStatsW

    v = np.array([0.1, 0.428])
    raw_lo, raw_hi = DescrStatsW(v).tconfint_mean(alpha=0.05)
    assert raw_lo < 0
    m, lo, hi, n = tables.seed_ci(v, lower=0.0)
    assert (lo, n) == (0.0, 2) and hi == pytest.approx(raw_hi, rel=1e-12)
    assert tables.fmt_ci(m, lo, hi, 3, n).endswith("]†")
    assert not tables.fmt_ci(m, lo, hi, 3, 10).endswith("†")
    # signed statistics (along-track error) keep the plain interval
    cells = pd.DataFrame({"g": ["a", "a"], "seed": [0, 1], "along_mean": [-1.0, 0.5],
                          "ex_mean": [0.1, 0.428]})
    agg = tables.aggregate(cells, ["g"], ["along_mean", "ex_mean"])
    assert agg["along_mean_lo"].iloc[0] < -1.0 and agg["ex_mean_lo"].iloc[0] == 0.0


def test_comparison_relations():
    cells = _cells({("square100", 5, "huff", "none", "full"): {"ex_mean": 1.0},
                    ("square100", 5, "huff", "lc", "full"): {"ex_mean": 0.5},
                    ("square100", 5, "huff", "dyn", "full"): {"ex_mean": 1.001}})
    a = {"path": "square100", "window": 5, "weighting": "huff", "mask": "full"}
    lc, none, dyn = ({**a, "technique": t} for t in ("lc", "none", "dyn"))
    assert compare(cells, Comparison(lc, "<", none, "ex_mean", "")).result == "supports"
    assert compare(cells, Comparison(lc, ">", none, "ex_mean", "")).result == "contradicts"
    # a difference of 0.001 m under 0.01 m noise per seed: no decision either way
    assert compare(cells, Comparison(dyn, "<", none, "ex_mean", "")).result == "inconclusive"
    assert compare(cells, Comparison(dyn, "<=", none, "ex_mean", "")).result == "supports"
    assert compare(cells, Comparison(lc, "~", none, "ex_mean", "", tol=0.25)).result == \
        "contradicts"
    assert compare(cells, Comparison(dyn, "~", none, "ex_mean", "", tol=0.25)).result == \
        "supports"
    assert compare(cells, Comparison(lc, "<", 0.7, "ex_mean", "")).result == "supports"
    o = compare(cells, Comparison({**a, "technique": "ekf"}, "<", none, "ex_mean", ""))
    assert o.result == "missing" and o.n == 0
    # paired difference and its interval, by hand
    o = compare(cells, Comparison(lc, "<", none, "ex_mean", ""))
    d = (cells[cells.technique == "lc"]["ex_mean"].to_numpy()
         - cells[cells.technique == "none"]["ex_mean"].to_numpy())
    assert o.diff == pytest.approx(d.mean()) and o.n == 5
    h = 2.7764451051977987 * d.std(ddof=1) / math.sqrt(5)     # t_{0.975, 4}
    assert (o.lo, o.hi) == pytest.approx((d.mean() - h, d.mean() + h), rel=1e-9)


def test_verdict_rule():
    assert verdict(["supports", "supports", "missing"]) == "reproduced"
    assert verdict(["contradicts", "inconclusive"]) == "not reproduced"
    assert verdict(["supports", "inconclusive"]) == "mixed"
    assert verdict(["missing"]) == "not evaluated"


@pytest.mark.parametrize("huff, none, random, c7, c8", [
    (0.8, 1.0, 1.1, "reproduced", "reproduced"),        # clearly better everywhere
    (1.0, 1.0, 1.0, "reproduced", "not reproduced"),    # equal: C7 holds, no improvement
    (1.3, 1.0, 1.1, "not reproduced", "not reproduced"),
    (1.05, 1.0, 1.1, "mixed", "mixed"),                 # better than random, worse than none
])
def test_huff_claims_on_synthetic_tables(huff, none, random, c7, c8):
    # equal values: no noise, so every paired difference is exactly 0 (interval [0, 0])
    cells = _weights(huff, none, random, noise=0.0 if huff == none == random else 0.01)
    res = {r.claim.cid: r for r in evaluate_claims(cells,
                                                   [_claim("C7"), _claim("C8")])}
    assert res["C7"].verdict == c7
    assert res["C8"].verdict == c8
    # paths x windows x others x axes x stats
    assert len(res["C7"].outcomes) == 2 * 4 * 2 * 2 * 2


def test_thesis_own_tables_are_checked_by_the_same_rule():
    # the claims about Tables 4.1/4.2 carry the published numbers: C20 (Dyn SW does not
    # scale) holds in all 8 comparisons of the published tables; C18 ("any method is
    # better than none") does not hold everywhere in them (e.g. Table 4.2, window 10,
    # median: None 0.620 < LC 0.785).
    empty = _cells({("square100", 1, "none", "none", "full"): {"ex_mean": 1.0}})
    res = {r.claim.cid: r for r in evaluate_claims(empty)}
    assert res["C20"].thesis_verdict == "reproduced"
    assert res["C18"].thesis_verdict == "mixed"
    assert res["C20"].verdict == "not evaluated"
    lc_med = next(o for o in res["C18"].outcomes
                  if o.comparison.label == "Path 1 w=10 median |y|: LC Full Path < None")
    assert lc_med.comparison.thesis == (0.785, 0.620) and lc_med.thesis_result == "contradicts"


def test_published_tables_are_transcribed():
    t = tables.THESIS_TABLES
    assert t["x"][(5, "None")] == {"mean": 1.095, "median": 0.950, "std": 0.795}
    assert t["x"][(100, "LC + Dyn SW")]["mean"] == 0.923
    assert t["y"][(100, "None")] == {"mean": 5.126, "median": 5.889, "std": 4.355}
    assert t["y"][(10, "Dyn SW")]["std"] == 0.626
    assert len(t["x"]) == len(t["y"]) == 15


def test_thesis_table_shape_and_report_files(tmp_path):
    vals = {}
    for w in (5, 10, 100):
        for tech, mask in tables.THESIS_ROWS.values():
            vals[("square100", w, "huff", tech, mask)] = {
                f"{a}_{s}": 1.0 + w / 100 for a in ("ex", "ey") for s in ("mean", "median", "std")}
    cells = _cells(vals)
    df = tables.thesis_table(cells, "x")
    assert len(df) == 15 and list(df["technique"][:5]) == list(tables.THESIS_ROWS)
    assert df.loc[0, "mean_thesis"] == 1.095 and df["n_seeds"].eq(5).all()
    assert df.loc[0, "mean_lo"] < df.loc[0, "mean"] < df.loc[0, "mean_hi"]
    path = report.write_report(cells, tmp_path)
    text = path.read_text()
    assert "## Rule" in text and "C21" in text and (tmp_path / "claims.csv").exists()
    claims = pd.read_csv(tmp_path / "claims.csv")
    assert set(claims["result"]) <= {"supports", "contradicts", "inconclusive", "missing"}


def test_variants_are_reported_separately(tmp_path):
    a = _weights(0.8, 1.0, 1.1)
    b = _weights(1.3, 1.0, 1.1)
    b["config"] = "rover_gps4"
    cells = pd.concat([a, b], ignore_index=True)
    labels = [lab for lab, _ in tables.variants(cells)]
    assert labels == ["config=rover_gps8", "config=rover_gps4"]
    text = report.write_report(cells, tmp_path).read_text()
    assert "Verdict (config=rover_gps8)" in text and "Verdict (config=rover_gps4)" in text


def test_report_cli_rewrites_outputs_from_cells_parquet(tmp_path, capsys):
    cells = _weights(0.8, 1.0, 1.1)
    cells.to_parquet(tmp_path / "cells.parquet", index=False)
    assert report.main([str(tmp_path)]) == 0
    assert (tmp_path / "REPORT.md").exists() and (tmp_path / "tables.md").exists()
    assert "C7" in (tmp_path / "REPORT.md").read_text()
    assert report.main([str(tmp_path / "nothing")]) == 2


# ----------------------------------------------------------------------------- issue 15
def _table_cells(rows: dict, seeds=range(5), growth=None, noise_overrides="{}", rng_seed=1):
    """Path 1 cells: ``rows[(window, technique, mask)]`` -> value of every |x|/|y| statistic
    (and jitter / outliers / heading), Huff weights; ``growth`` sets dyn_growth of the
    dynamic techniques ("-" elsewhere)."""
    vals = {}
    for (w, tech, mask), v in rows.items():
        vals[("square100", w, "huff", tech, mask)] = {
            **{f"{a}_{s}": v for a in ("ex", "ey") for s in ("mean", "median", "std", "p95")},
            "ex_outliers": v / 10, "ey_outliers": v / 10, "eh_median": 0.3, "n_epochs": 100,
            "jitter_rms": v, "along_mean": -v}
    df = _cells(vals, seeds=seeds, rng_seed=rng_seed)
    dyn = df["technique"].str.contains("dyn")
    df["dyn_growth"] = np.where(dyn, growth or "jump", "-")
    df["noise_overrides"] = noise_overrides
    df["key"] = df["key"] + "-" + df["dyn_growth"] + noise_overrides
    return df


def _thesis_like(lc=1.2, oracle=0.5, growth="refill"):
    """None 1.0 everywhere; LC (and LC + Dyn SW) at ``lc``; Dyn SW 0.9; oracle rows at
    ``oracle``; all five rows with the three masks."""
    rows = {}
    for w in (5, 10, 100):
        for mask in ("full", "no_turns", "no_turns_window"):
            rows.update({(w, "none", mask): 1.0, (w, "lc", mask): lc, (w, "dyn", mask): 0.9,
                         (w, "lc+dyn", mask): lc, (w, "lc_sim_heading", mask): oracle,
                         (w, "lc_sim_heading+dyn", mask): oracle * 0.9})
    return _table_cells(rows, growth=growth)


def test_oracle_rows_are_labelled_and_never_counted(tmp_path):
    """Oracle rows (the lag correction fed the simulator's heading) appear only in their
    own, labelled table; the claims' verdicts are the same with or without them."""
    cells = _thesis_like(lc=1.2, oracle=0.5)
    df = tables.thesis_table(cells, "x")
    orc = df[df["kind"] == "oracle"]
    assert len(orc) == 9 and orc["technique"].str.startswith("Oracle: ").all()
    assert not df.loc[df["kind"] == "thesis", "technique"].str.contains("Oracle").any()
    # the thesis rows are the estimated-heading ones: LC at 1.2, not the oracle's 0.5
    lc = df[(df["technique"] == "LC Full Path")]
    np.testing.assert_allclose(lc["mean"], 1.2, atol=0.02)
    md = tables.write_tables(cells, tmp_path).read_text()
    head = md.index("Oracle rows, not estimator results")
    first = md.index("| 5 | Oracle: LC (simulator heading)")
    assert head < first < md.index("## Table 4.2")
    assert pd.read_csv(tmp_path / "by_cell.csv").query("technique == 'lc_sim_heading'")[
        "oracle"].all()
    no_oracle = cells[~cells["technique"].str.startswith("lc_sim")]
    with_o = {r.claim.cid: r.verdict for r in evaluate_claims(claims._derived(cells))}
    without = {r.claim.cid: r.verdict for r in evaluate_claims(claims._derived(no_oracle))}
    assert with_o == without
    text = report.write_report(cells, tmp_path).read_text()
    # LC + Dyn SW worse than None at window 100: C21 not reproduced; its Cause line names
    # the oracle re-check, which holds
    c21 = text[text.index("## C21 "):text.index("## C22 ")]
    assert "**not reproduced**" in c21
    cause = next(line for line in c21.splitlines() if line.startswith("Cause:"))
    assert "simulator's heading" in cause and "**reproduced**" in cause


def test_every_mixed_or_not_reproduced_claim_has_one_cause_line(tmp_path):
    w = _weights(1.3, 1.0, 1.1)
    w = w[~((w["path"] == "square100") & (w["weighting"] == "huff") & (w["window"] > 1))]
    cells = pd.concat([_thesis_like(lc=1.2, oracle=0.5), w], ignore_index=True)
    cells["dyn_growth"] = cells["dyn_growth"].fillna("-")
    text = report.write_report(cells, tmp_path).read_text()
    sections = text.split("\n## ")[1:]
    checked = 0
    for sec in sections:
        verdict = next((ln for ln in sec.splitlines() if ln.startswith("Verdict:")), "")
        causes = [ln for ln in sec.splitlines() if ln.startswith("Cause:")]
        if "**mixed**" in verdict or "**not reproduced**" in verdict:
            assert len(causes) == 1, sec.splitlines()[0]
            checked += 1
        else:
            assert not causes, sec.splitlines()[0]
    assert checked >= 5


def test_faithful_reading_in_tables_and_claims():
    """Dyn SW under both growth rules: the tables and claims use "refill", the jump rule is
    shown as another reading; "LC No Turns" is the window mask, or the epoch mask when the
    sweep has no window mask."""
    rows = {(w, t, m): v for w in (5, 10, 100) for m in ("full", "no_turns", "no_turns_window")
            for t, v in (("none", 1.0), ("lc", 1.1), ("dyn", 0.8), ("lc+dyn", 0.7))}
    rows[(100, "lc", "no_turns_window")] = 0.4
    refill = _table_cells(rows, growth="refill")
    jump = _table_cells({k: v + 0.3 for k, v in rows.items() if "dyn" in k[1]}, growth="jump")
    cells = pd.concat([refill, jump], ignore_index=True)
    assert len(tables.faithful(cells)) == len(refill)
    df = tables.thesis_table(cells, "x").set_index(["window", "technique"])
    assert df.loc[(100, "Dyn SW"), "mean"] == pytest.approx(0.8, abs=0.02)
    assert df.loc[(100, "Dyn SW (jump back)"), "mean"] == pytest.approx(1.1, abs=0.02)
    assert df.loc[(100, "LC No Turns"), "mean"] == pytest.approx(0.4, abs=0.02)
    assert df.loc[(100, "LC No Turns"), "mask"] == "no_turns_window"
    assert df.loc[(100, "LC No Turns (turning epochs only)"), "mean"] == pytest.approx(
        1.1, abs=0.02)
    # without the window mask the row falls back to the epoch mask, and no reading repeats it
    old = cells[cells["mask"] != "no_turns_window"]
    df2 = tables.thesis_table(old, "x").set_index(["window", "technique"])
    assert df2.loc[(100, "LC No Turns"), "mask"] == "no_turns"
    assert "LC No Turns (turning epochs only)" not in df2.index.get_level_values(1)
    # claims run on one growth rule per seed (no "matches several cells" error)
    res = {r.claim.cid: r for r in evaluate_claims(claims._derived(tables.faithful(cells)))}
    assert res["C16"].verdict == "reproduced"


def test_side_study_is_reported_apart_with_the_implied_setting(tmp_path):
    """A noise split re-run on a few rows is a side study, not a variant; REPORT.md gets
    the heading-observability section and names the setting the published numbers imply."""
    main = _thesis_like(lc=3.6, oracle=1.5)
    main["noise"] = "gps_stationary"
    study = []
    for cf, lc in ((0.9, 2.7), (0.99, 1.3)):
        rows = {(100, t, "full"): v for t, v in (("none", 5.0), ("lc", lc), ("lc+dyn", lc),
                                                 ("lc_sim_heading", 1.5))}
        rows[(1, "none", "full")] = 1.0
        s = _table_cells(rows, growth="refill", noise_overrides=f'{{"common_fraction":{cf}}}')
        s["eh_median"] = np.radians(20.0 if cf == 0.9 else 5.0)
        study.append(s)
    cells = pd.concat([main, *study], ignore_index=True)
    assert [lab for lab, _ in tables.variants(cells)] == [""]
    assert set(tables.side_studies(cells)["noise_overrides"]) == {
        '{"common_fraction":0.9}', '{"common_fraction":0.99}'}
    text = report.write_report(cells, tmp_path).read_text()
    sec = text[text.index("## Heading observability"):]
    assert "| 0.99 |" in sec and "| 0.5 (shipped) |" in sec
    # published LC Full Path at w=100 is 1.454 / 1.811: only 0.99 (1.3 m) reaches it
    assert "is reached with the estimated heading from common_fraction 0.99 on" in sec
    assert tables.write_tables(cells, tmp_path).read_text().count("## Side studies") == 1


def test_a_layout_on_paths_of_its_own_is_a_variant_not_a_side_study():
    """The peer preset's car: a second configuration used only on its own path covers
    combinations no other configuration has, so it gets its own tables (a variant, with
    its heading table), while a few rover rows re-run under another noise split stay a
    side study."""
    rover = _thesis_like(lc=3.6, oracle=1.5)
    rover["config"] = "rover_gps8"
    car = _thesis_like(lc=0.1, oracle=0.1)
    car["path"], car["config"] = "car_block", "car_rtk4"
    rerun = _table_cells({(100, "lc", "full"): 2.7}, growth="refill")
    rerun["config"] = "rover_gps8"
    rerun["noise_overrides"] = '{"common_fraction":0.9}'
    cells = pd.concat([rover, car, rerun], ignore_index=True)
    assert set(tables.side_studies(cells)["noise_overrides"]) == {'{"common_fraction":0.9}'}
    labels = [lab for lab, _ in tables.variants(cells)]
    assert len(labels) == 2 and any("car_rtk4" in lab for lab in labels)
    by = dict(tables.variants(cells))
    car_sub = next(sub for lab, sub in by.items() if "car_rtk4" in lab)
    assert set(car_sub["path"]) == {"car_block"}


def test_seed_spread_section_compares_the_published_single_runs():
    """Per-seed min - max of the None rows beside the published value (Table 4.1 w=5 mean
    |x| = 1.095): inside the spread when the seeds straddle it, outside when they do not."""
    rows = {(w, t, "full"): 1.0 for w in (5, 10, 100) for t in ("none", "dyn")}
    cells = _table_cells(rows, seeds=range(4))
    sel = (cells["technique"] == "none") & (cells["window"] == 5)
    cells.loc[sel, "ex_mean"] = [1.00, 1.05, 1.10, 1.20]
    cells.loc[sel, "ey_mean"] = [1.00, 1.05, 1.10, 1.20]        # published 1.639: outside
    lines = "\n".join(causes_mod.seed_spread_section(cells))
    assert "| 5 | x | mean | 1.095 | 1.087 [" in lines and "| 1.000 - 1.200 | yes |" in lines
    assert "| 5 | y | mean | 1.639 |" in lines
    row_y = next(ln for ln in lines.splitlines() if ln.startswith("| 5 | y | mean"))
    assert row_y.endswith("| no |")


def test_oracle_technique_end_to_end_in_a_tiny_sweep(tmp_path):
    """A real (tiny) sweep: the oracle cell is fed the simulator's heading, so on a
    noise-free straight it equals the as-written correction (whose estimated heading is
    exact there), and its rows carry the oracle label in the table CSV."""
    from experiments.spec import Spec
    from experiments.sweep import run

    spec = Spec.from_dict({
        "name": "tiny_oracle", "seeds": 1, "masks": ["full", "no_turns_window"],
        "defaults": {"noise": "none", "path": "square20"},
        "grid": [{"window": 5, "weighting": "huff",
                  "technique": ["none", "lc", "dyn", "lc+dyn", "lc_sim_heading"],
                  "dyn_growth": "refill"}]}, source="spec")
    res = run(spec, out=tmp_path, jobs=1, progress=False, figures=False)
    assert res.n_failed == 0
    c = res.cells.set_index(["technique", "mask"])
    assert c.loc[("lc_sim_heading", "full"), "ex_mean"] < c.loc[("none", "full"), "ex_mean"]
    t41 = pd.read_csv(tmp_path / "table_4_1_square20.csv", keep_default_na=False,
                      na_values=[""])
    kinds = dict(zip(t41["technique"], t41["kind"]))
    assert kinds["Oracle: LC (simulator heading)"] == "oracle" and kinds["None"] == "thesis"
    assert c.loc[("dyn", "full"), "dyn_growth"] == "refill"


def test_seed_ci_is_scipys_t_interval():
    """seed_ci's 95 % interval equals scipy.stats.t.interval on the same values (an
    independent reference for the quantile it takes from scipy.special)."""
    import numpy as np
    from scipy import stats

    from experiments.tables import seed_ci

    rng = np.random.default_rng(5)
    for n in (2, 3, 10, 100):
        v = rng.normal(1.0, 0.3, n)
        m, lo, hi, k = seed_ci(v)
        ref = stats.t.interval(0.95, n - 1, loc=v.mean(), scale=stats.sem(v))
        assert k == n and m == v.mean()
        np.testing.assert_allclose([lo, hi], ref, rtol=1e-13)


def test_tables_and_report_are_the_same_from_arrow_or_numpy_string_columns(tmp_path):
    """write_tables/write_report convert pandas' Arrow-backed string columns (what
    read_parquet gives) to numpy object arrays for speed (tables.numpy_strings); the files
    must not depend on which the caller passes."""
    cells = _thesis_like(lc=1.2, oracle=0.5)
    arrow = cells.astype({c: "string[pyarrow]" for c in cells.columns
                          if cells[c].dtype == object or pd.api.types.is_string_dtype(cells[c])})
    assert any(str(t).startswith("string") for t in arrow.dtypes)
    plain = tables.numpy_strings(arrow)
    strs = [c for c in arrow.columns if pd.api.types.is_string_dtype(arrow[c].dtype)]
    assert strs and all(plain[c].dtype == object for c in strs)
    assert all(plain[c].dtype == arrow[c].dtype for c in arrow.columns if c not in strs)
    assert plain.astype({c: arrow[c].dtype for c in strs}).equals(arrow)
    files = {}
    for name, df in (("arrow", arrow), ("plain", plain)):
        out = tmp_path / "run"                    # the same folder name: tables.md names it
        tables.write_tables(df, out)
        report.write_report(df, out)
        files[name] = {p.name: p.read_bytes() for p in sorted(out.iterdir()) if p.is_file()}
        for p in out.iterdir():
            p.unlink()
    assert files["arrow"].keys() == files["plain"].keys() and files["arrow"]
    for n in files["arrow"]:
        assert files["arrow"][n] == files["plain"][n], n
