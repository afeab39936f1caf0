"""Tables and the claim report on synthetic cell tables (no simulation).

The verdict rule (experiments/report.py RULE) is checked on cell tables built by hand, where
the right verdict is known; the seed intervals against statsmodels' t interval.
"""

import math

import numpy as np
import pandas as pd
import pytest

from experiments import report, tables
from experiments.report import CLAIMS, Comparison, compare, evaluate_claims, verdict


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
    assert len(res["C7"].outcomes) == 2 * 4 * 2 * 2 * 2     # paths x windows x others x axes x stats


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
