"""The outputs phase's fast paths (issue 27) give the numbers of the plain ones bit for bit."""

import math

import numpy as np
import pandas as pd
import pytest

from experiments import tables


def _same(a: float, b: float) -> bool:
    return (math.isnan(a) and math.isnan(b)) or a == b


@pytest.mark.parametrize("k", [1, 2, 3, 7, 8, 9, 10, 17, 130])
def test_seed_ci_columns_match_seed_ci(k):
    rng = np.random.default_rng(k)
    sub = rng.gamma(2.0, 1.3, size=(k, 6)) * 10 ** rng.uniform(-3, 3, size=6)
    sub[:, 4] -= 5.0                       # signed column
    if k > 2:
        sub[1, 2] = np.nan                  # a column with a NaN: one by one
        sub[0, 5] = np.inf
    lower = [0.0, 0.0, 0.0, None, None, 0.0]
    got = tables._seed_ci_columns(sub, lower)
    for j in range(sub.shape[1]):
        want = tables.seed_ci(sub[:, j], lower[j])[:3]
        assert all(_same(g[j], w) for g, w in zip(got, want)), (k, j)


def _cells(rng) -> pd.DataFrame:
    rows = []
    for seed in range(4):
        for w in (1, 5, 10):
            for tech, growth in (("none", "-"), ("lc", "-"), ("dyn", "refill"), ("dyn", "jump")):
                for mask in ("full", "no_turns"):
                    rows.append({"path": "square100", "weighting": "huff", "window": w,
                                 "technique": tech, "mask": mask, "dyn_growth": growth,
                                 "seed": seed, "ex_mean": rng.gamma(2.0),
                                 "ex_median": rng.gamma(2.0), "ex_std": rng.gamma(1.0)})
    df = pd.DataFrame(rows)
    df.loc[3, "ex_mean"] = np.nan
    return df.sample(frac=1.0, random_state=1).reset_index(drop=True)


def test_row_groups_are_the_selections():
    cells = _cells(np.random.default_rng(0))
    for rule in (None, "refill", "jump"):
        groups = tables._row_groups(cells, rule)
        src = tables.faithful(cells) if rule is None else tables.select(cells, dyn_growth=rule)
        for w in (1, 5, 10):
            for tech in ("none", "lc", "dyn"):
                for mask in ("full", "no_turns"):
                    sub = tables.select(src, window=w, technique=tech, mask=mask)
                    idx = groups.get((w, tech, mask))
                    got = [] if idx is None else list(cells.index[idx])
                    assert got == list(sub.index), (rule, w, tech, mask)


def _per_seed_reference(cells, cond, metric):
    """The pandas selection the claims used before the integer codes (issue 27)."""
    sub = cells
    for k, v in cond.items():
        if v is None:
            continue
        sub = sub[sub[k].isin(list(v))] if isinstance(v, (list, tuple, set)) else sub[sub[k] == v]
    vals = pd.Series(sub[metric].to_numpy(), index=sub["seed"].to_numpy())
    return vals.sort_index().astype(float)


def test_claims_per_seed_and_compare_match_pandas():
    from experiments import claims

    cells = _cells(np.random.default_rng(3))
    cells.loc[5, "window"] = np.nan
    cases = [{"window": 5, "technique": "lc", "mask": "full"},
             {"window": 5.0, "technique": ["lc", "zzz"], "mask": "no_turns", "path": None},
             {"window": 10, "technique": "dyn", "mask": "full", "dyn_growth": "jump"},
             {"window": 7, "technique": "lc", "mask": "full"},
             {"window": 1, "technique": "none", "mask": ["full"], "weighting": "huff"}]
    claims._COLUMNS.clear()
    for cond in cases:
        got = claims._per_seed(cells, cond, "ex_mean")
        want = _per_seed_reference(cells, cond, "ex_mean")
        assert list(got.index) == list(want.index) and np.array_equal(got, want, equal_nan=True)
    with pytest.raises(ValueError, match="several cells per seed"):
        claims._per_seed(cells, {"window": 5, "technique": "dyn", "mask": "full"}, "ex_mean")
    assert claims._per_seed(cells, {"nope": 1}, "ex_mean").empty
    for a, b in ((cases[0], cases[4]), (cases[2], cases[0]), (cases[3], cases[0])):
        for rel in ("<", "~"):
            c = claims.Comparison(a, rel, b, "ex_mean", "t")
            o = claims.compare(cells, c)
            pa = _per_seed_reference(cells, a, "ex_mean")
            pa, pb = pa.align(_per_seed_reference(cells, b, "ex_mean"), join="inner")
            ok = np.isfinite(pa.to_numpy()) & np.isfinite(pb.to_numpy())
            pa, pb = pa[ok], pb[ok]
            assert o.n == len(pa)
            if o.n:
                d = (pa - pb).to_numpy()
                assert (o.mean_a, o.mean_b, o.diff) == (pa.mean(), pb.mean(), d.mean())


def test_young_gc_freezes_only_for_the_unit():
    """The outputs units freeze the objects alive before them out of the full collections
    and unfreeze them after: a cycle made before and dropped inside is collected after."""
    import gc
    import weakref

    from experiments.outputs import _young_gc

    class Node:
        pass

    a = Node()
    a.self = a
    ref = weakref.ref(a)
    with _young_gc():
        assert gc.get_freeze_count() > 0
        del a
        gc.collect()
        assert ref() is not None          # frozen: not collected during the unit
    assert gc.get_freeze_count() == 0
    gc.collect()
    assert ref() is None


def test_select_matches_pandas_comparisons():
    """tables.select's numpy comparisons pick the rows pandas' ``==`` / ``isin`` pick."""
    df = pd.DataFrame({"s": ["a", "b", None, "a", "-"], "w": [1, 5, 10, 5, 1],
                       "f": [1.0, np.nan, 5.0, 5.0, 1.0], "o": [0, "-", "x", 0, 1.0]})
    df["n"] = pd.array(["a", None, "b", "a", "c"], dtype="str")   # Arrow strings: the pandas path
    for col, vals in (("s", ["a", ("a", "-"), "zz", ["b", None]]), ("w", [5, [1, 10], 5.0]),
                      ("f", [5.0, [np.nan, 1.0], np.nan]), ("o", [0, ["-", 1], "x"]),
                      ("n", ["a", ["a", "c"]])):
        for v in vals:
            many = isinstance(v, (list, tuple, set))
            want = df[df[col].isin(v) if many else df[col] == v]
            assert list(tables.select(df, **{col: v}).index) == list(want.index), (col, v)
