"""The claims of the GPS dissertation and the rule that checks them against a sweep's data.

REPORT.md (:mod:`experiments.report`) writes them, with the causes of
:mod:`experiments.causes`; both import this module, neither imports the other's writer.

The claims are those of 000_8f82f8df647bf685.txt Sections 3.4.2, 4.10-4.12 and 5.1 about the
moving platform. Each claim is a list of elementary comparisons between two conditions of the
sweep (or a condition and a constant), evaluated on per-seed numbers; the verdict follows
from the comparisons by a fixed rule (:data:`RULE`), never by hand.

Elementary comparison "A < B" on metric M: for every seed s present in both conditions,
d_s = M(A, s) - M(B, s) (paired: the conditions share the seed's noise); over seeds, the
mean of d and its 95 % Student-t interval [lo, hi]. It *supports* the claim when hi < 0,
*contradicts* it when lo > 0, and is *inconclusive* otherwise. "A > B" is the mirror image.
"A <= B" (equal or better) supports unless it contradicts. "A ~ B (r)" (little difference)
supports when |mean d| < r * mean M(B), else contradicts.

Where a claim is about the numbers in Tables 4.1/4.2, the same comparisons are also applied
to the published values (one run, so a plain comparison of two numbers) and reported
beside ours: this shows where the dissertation's own table agrees with its text.
"""

from __future__ import annotations

import itertools
import math
import weakref
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from experiments.tables import (
    MASK_FALLBACK,
    PATH_LABELS,
    THESIS_TABLES,
    _t975,
    select,
    thesis_row,
)
from experiments.techniques import course_pairs

__all__ = [
    "CLAIMS",
    "COURSE_CLAIMS",
    "RULE",
    "Claim",
    "Comparison",
    "compare",
    "evaluate_claims",
    "swap_techniques",
    "verdict",
]

RULE = (
    "Each claim is split into elementary comparisons between two conditions on one metric, "
    "computed per seed and paired by seed (the conditions share that seed's simulated noise). "
    "For \"A < B\" the per-seed difference A - B is averaged over seeds with a 95 % Student-t "
    "interval: it *supports* the claim if the whole interval is below 0, *contradicts* it if "
    "the whole interval is above 0, and is *inconclusive* otherwise (\">\" mirrored). "
    "\"A <= B\" (equal or better) supports unless it contradicts. \"A ~ B (r)\" (little "
    "difference) supports if the mean difference is smaller than r times the mean of B. "
    "Verdict: **reproduced** if every comparison supports the claim, **not reproduced** if "
    "none does, **mixed** otherwise. A claim whose conditions are absent from the sweep is "
    "**not evaluated**.")

P1, P2 = "square100", "square200"
LARGE = (5, 10, 100)


@dataclass(frozen=True)
class Comparison:
    """``metric(a) <rel> metric(b)``; ``b`` may be a float constant. ``label`` is for humans."""

    a: dict
    rel: str
    b: dict | float
    metric: str
    label: str
    thesis: tuple[float, float] | None = None   # published (A, B) values where they exist
    tol: float = 0.25                            # for "~"


@dataclass
class Claim:
    cid: str
    section: str
    text: str
    comparisons: Callable[[pd.DataFrame], list[Comparison]]
    note: str = ""


@dataclass
class Outcome:
    comparison: Comparison
    n: int
    mean_a: float
    mean_b: float
    diff: float
    lo: float
    hi: float
    result: str               # supports / contradicts / inconclusive / missing
    thesis_result: str | None = None


@dataclass
class ClaimResult:
    claim: Claim
    outcomes: list[Outcome] = field(default_factory=list)
    verdict: str = "not evaluated"
    thesis_verdict: str | None = None


# --------------------------------------------------------------------------- evaluation
_COLUMNS: dict[int, tuple[weakref.ref, dict[str, np.ndarray]]] = {}


def _column(cells: pd.DataFrame, name: str) -> np.ndarray:
    """``cells[name]`` as a numpy array, converted once per table (a weak reference keeps
    the cache from outliving it or answering for another table at the same address). The
    public entry points (:func:`evaluate_claims`, :func:`write_report`) clear it, so a
    table changed in place between two calls is read afresh."""
    ref, cols = _COLUMNS.get(id(cells), (None, None))
    if ref is None or ref() is not cells:
        for k in [k for k, (r, _) in _COLUMNS.items() if r() is None]:
            del _COLUMNS[k]
        cols = {}
        _COLUMNS[id(cells)] = (weakref.ref(cells), cols)
    if name not in cols:
        cols[name] = cells[name].to_numpy()
    return cols[name]


def _codes(cells: pd.DataFrame, name: str) -> tuple[np.ndarray, dict]:
    """Column ``name`` as integer codes (n,) and value -> code (NaN: -1, in no dict), made
    once per table like :func:`_column`: a condition's mask is then an integer compare."""
    key = f"codes:{name}"
    cols = _COLUMNS[id(cells)][1] if id(cells) in _COLUMNS else None
    if cols is None or key not in cols:
        _column(cells, name)                          # registers the table's cache
        cols = _COLUMNS[id(cells)][1]
        codes, uniques = pd.factorize(cells[name].to_numpy(), use_na_sentinel=True)
        cols[key] = (codes, {v: i for i, v in enumerate(uniques)})
    return cols[key]


def _mask(cells: pd.DataFrame, cond: dict) -> np.ndarray | None:
    """The rows matching ``cond`` (None values ignored) as a bool array; None when a
    condition's column is missing."""
    mk = np.ones(len(cells), dtype=bool)
    for k, v in cond.items():
        if v is None:
            continue
        if k not in cells.columns:
            return None
        codes, code_of = _codes(cells, k)
        if isinstance(v, (list, tuple, set)):
            mk &= np.isin(codes, [code_of[x] for x in v if _hashable(x) and x in code_of])
        elif not _hashable(v) or v not in code_of:
            return np.zeros(len(cells), dtype=bool)
        else:
            mk &= codes == code_of[v]
    return mk


def _hashable(v) -> bool:
    try:
        hash(v)
    except TypeError:
        return False
    return True


def _seed_values(cells: pd.DataFrame, cond: dict, metric: str) -> tuple[np.ndarray, np.ndarray]:
    """(seeds, values) of ``metric`` in the cells matching ``cond``, sorted by seed (float
    values; empty arrays when nothing matches). Raises ValueError when a seed matches
    several cells."""
    empty = (np.array([], dtype=np.int64), np.array([], dtype=float))
    if metric not in cells.columns:
        return empty
    # the matching rows by integer codes of the condition's columns only: taking whole rows
    # of a 60-column table for each of the report's ~1000 conditions dominated its time
    mk = _mask(cells, cond)
    if mk is None or not mk.any():
        return empty
    seeds = _column(cells, "seed")[mk]
    order = np.argsort(seeds, kind="stable")
    seeds = seeds[order]
    # one value per seed; several matching cells (e.g. other solvers) would be ambiguous
    if seeds.size > 1 and (seeds[1:] == seeds[:-1]).any():
        raise ValueError(f"condition {cond} matches several cells per seed; add axis values")
    return seeds, np.asarray(_column(cells, metric)[mk][order], dtype=float)


def _per_seed(cells: pd.DataFrame, cond: dict, metric: str) -> pd.Series:
    """``metric`` per seed (index: seed, ascending) in the cells matching ``cond``."""
    seeds, vals = _seed_values(cells, cond, metric)
    return pd.Series(vals, index=seeds, dtype=float) if seeds.size else pd.Series(dtype=float)


def compare(cells: pd.DataFrame, c: Comparison) -> Outcome:
    """Evaluate one elementary comparison (see the module docstring)."""
    sa, a = _seed_values(cells, c.a, c.metric)
    if isinstance(c.b, dict):
        sb, b = _seed_values(cells, c.b, c.metric)
        _, ia, ib = np.intersect1d(sa, sb, assume_unique=True, return_indices=True)
        a, b = a[ia], b[ib]                        # the seeds of both, ascending
    else:
        b = np.full(a.size, float(c.b))
    ok = np.isfinite(a) & np.isfinite(b)
    a, b = a[ok], b[ok]
    n = len(a)
    thesis_result = None
    if c.thesis is not None:
        ta, tb = c.thesis
        thesis_result = _relation(c.rel, ta - tb, ta - tb, ta - tb, tb, c.tol)
    if n == 0:
        return Outcome(c, 0, math.nan, math.nan, math.nan, math.nan, math.nan, "missing",
                       thesis_result)
    d = a - b
    m = float(d.mean())
    if n > 1:
        h = float(_t975(n - 1) * d.std(ddof=1) / math.sqrt(n))
    else:
        h = math.inf
    res = _relation(c.rel, m, m - h, m + h, float(b.mean()), c.tol)
    return Outcome(c, n, float(a.mean()), float(b.mean()), m, m - h, m + h, res, thesis_result)


def _relation(rel: str, m: float, lo: float, hi: float, mean_b: float, tol: float) -> str:
    if rel == "<":
        return "supports" if hi < 0 else "contradicts" if lo > 0 else "inconclusive"
    if rel == ">":
        return "supports" if lo > 0 else "contradicts" if hi < 0 else "inconclusive"
    if rel == "<=":
        return "contradicts" if lo > 0 else "supports"
    if rel == ">=":
        return "contradicts" if hi < 0 else "supports"
    if rel == "~":
        return "supports" if abs(m) < tol * abs(mean_b) else "contradicts"
    raise ValueError(f"rel: unknown relation {rel!r}")


def verdict(results: list[str]) -> str:
    """The stated rule: reproduced / not reproduced / mixed (missing ones are ignored)."""
    r = [x for x in results if x != "missing"]
    if not r:
        return "not evaluated"
    s = sum(x == "supports" for x in r)
    if s == len(r):
        return "reproduced"
    if s == 0:
        return "not reproduced"
    return "mixed"


def evaluate_claims(cells: pd.DataFrame, claims: list[Claim] | None = None) -> list[ClaimResult]:
    """Evaluate every claim on a cell table (one row per cell x mask)."""
    _COLUMNS.clear()
    out = []
    for cl in claims or CLAIMS:
        comps = cl.comparisons(cells)
        outs = [compare(cells, c) for c in comps]
        cr = ClaimResult(cl, outs, verdict([o.result for o in outs]))
        th = [o.thesis_result for o in outs if o.thesis_result is not None]
        if th and len(th) == len(outs):
            cr.thesis_verdict = verdict(th)
        out.append(cr)
    return out


# --------------------------------------------------------------------------- claims
def _paths(cells: pd.DataFrame) -> list[str]:
    ps = list(dict.fromkeys(cells["path"]))
    return [p for p in (P1, P2) if p in ps] or ps


def _windows(cells: pd.DataFrame, **where) -> list[int]:
    return sorted(int(w) for w in select(cells, **where)["window"].unique())


def _wlabel(p: str) -> str:
    return PATH_LABELS.get(p, p)


def _tw(cells: pd.DataFrame) -> str:
    """Weighting of the technique comparison (Tables 4.1/4.2): Huff when present."""
    ws = set(select(cells, technique=["lc", "dyn", "lc+dyn"])["weighting"])
    return "huff" if "huff" in ws or not ws else min(ws)


def _cond(path, window, weighting, technique="none", mask="full", **kw) -> dict:
    return {"path": path, "window": window, "weighting": weighting, "technique": technique,
            "mask": mask, **kw}


def _thesis(axis: str, window: int, row: str, stat: str) -> float | None:
    v = THESIS_TABLES[axis].get((window, row))
    return None if v is None else v[stat]


def _tcmp(cells, a_row, rel, b_row, stat, windows, axes=("x", "y"), path=P1) -> list[Comparison]:
    """Comparisons between Table 4.1/4.2 rows, with the published values attached."""
    w8 = _tw(cells)
    out = []
    for w in windows:
        for ax in axes:
            ta, tb = _thesis(ax, w, a_row, stat), _thesis(ax, w, b_row, stat)
            tech_a, mask_a = thesis_row(cells, a_row)
            tech_b, mask_b = thesis_row(cells, b_row)
            out.append(Comparison(
                _cond(path, w, w8, tech_a, mask_a), rel, _cond(path, w, w8, tech_b, mask_b),
                f"e{ax}_{stat}", f"{_wlabel(path)} w={w} {stat} |{ax}|: {a_row} {rel} {b_row}",
                thesis=(ta, tb) if ta is not None and tb is not None and path == P1 else None))
    return out


def _c_jitter(cells):
    out = []
    for p in _paths(cells):
        ws = _windows(cells, path=p, technique="none", weighting="none")
        for w0, w1 in itertools.pairwise(ws):
            out.append(Comparison(_cond(p, w1, "none"), "<", _cond(p, w0, "none"), "jitter_rms",
                                  f"{_wlabel(p)}: estimate-to-estimate jitter w={w1} < w={w0}"))
    return out


def _straight(cells) -> str:
    """The mask of the estimates on straights: whole window free of turns where the sweep
    has it, else the epochs that are not turning."""
    m = "no_turns_window"
    return m if m in set(cells["mask"]) else MASK_FALLBACK[m]


def _c_lag(cells):
    out = []
    nt = _straight(cells)
    for p in _paths(cells):
        ws = _windows(cells, path=p, technique="none", weighting="none")
        if 100 in ws and 10 in ws:
            out.append(Comparison(_cond(p, 100, "none", mask=nt), "<",
                                  _cond(p, 10, "none", mask=nt), "along_mean",
                                  f"{_wlabel(p)}: along-track error w=100 < w=10 "
                                  "(more negative = trails further behind)"))
            out.append(Comparison(_cond(p, 100, "none", mask=nt), "<",
                                  _cond(p, 100, "none", technique="__noise__", mask=nt),
                                  "along_mean", f"{_wlabel(p)} w=100: trail > noise level "
                                  "(median Euclidean CG error at window 1)"))
        for w in (w for w in ws if 1 < w <= 10):
            out.append(Comparison(_cond(p, w, "none", mask=nt), ">",
                                  _cond(p, w, "none", technique="__noise__", mask=nt),
                                  "along_mean", f"{_wlabel(p)} w={w}: trail < noise level "
                                  "(median Euclidean CG error at window 1)"))
    return out


def _c_lag_path2(cells):
    if not {P1, P2} <= set(cells["path"]):
        return []
    nt = _straight(cells)
    return [Comparison(_cond(P2, 100, "none", mask=nt), "<",
                       _cond(P1, 100, "none", mask=nt), "along_mean",
                       "w=100 along-track error: Path 2 < Path 1 (Path 2 trails further)")]


def _c_outliers_small(cells):
    out = []
    for p in _paths(cells):
        for w8 in ("none", "huff"):
            if {1, 10} <= set(_windows(cells, path=p, weighting=w8, technique="none")):
                for ax in ("x", "y"):
                    out.append(Comparison(_cond(p, 10, w8), "<", _cond(p, 1, w8), f"e{ax}_p95",
                                          f"{_wlabel(p)} {w8}: p95 |{ax}| w=10 < w=1"))
    return out


def _c_median_small(cells):
    out = []
    for p in _paths(cells):
        for w8 in ("none", "huff"):
            if {1, 10} <= set(_windows(cells, path=p, weighting=w8, technique="none")):
                for ax in ("x", "y"):
                    out.append(Comparison(_cond(p, 10, w8), "~", _cond(p, 1, w8),
                                          f"e{ax}_median",
                                          f"{_wlabel(p)} {w8}: median |{ax}| w=10 ~ w=1 (25 %)"))
    return out


def _c_large_window_lag(cells):
    out = []
    for p in _paths(cells):
        for w8 in ("none", "huff"):
            if {10, 100} <= set(_windows(cells, path=p, weighting=w8, technique="none")):
                for ax in ("x", "y"):
                    out.append(Comparison(_cond(p, 100, w8), ">", _cond(p, 10, w8),
                                          f"e{ax}_mean",
                                          f"{_wlabel(p)} {w8}: mean |{ax}| w=100 > w=10"))
    return out


def _c_huff(rel):
    def f(cells):
        out = []
        for p in _paths(cells):
            for w in _windows(cells, path=p, technique="none", weighting="huff"):
                for other in ("none", "random"):
                    if select(cells, path=p, window=w, weighting=other, technique="none").empty:
                        continue
                    for ax in ("x", "y"):
                        for st in ("mean", "median"):
                            out.append(Comparison(
                                _cond(p, w, "huff"), rel, _cond(p, w, other), f"e{ax}_{st}",
                                f"{_wlabel(p)} w={w} {st} |{ax}|: huff {rel} {other}"))
        return out
    return f


def _c_heading_match(cells):
    out = []
    for w in _windows(cells, path=P1, technique="none", weighting="none"):
        out.append(Comparison(_cond(P1, w, "none"), "<", math.radians(10.0), "eh_median",
                              f"Path 1 w={w}: median heading error < 10 deg"))
    return out


def _c_heading_median(cells):
    if not {1, 100} <= set(_windows(cells, path=P1, technique="none", weighting="none")):
        return []
    return [Comparison(_cond(P1, 100, "none"), "<", _cond(P1, 1, "none"), "eh_median",
                       "Path 1: median heading error w=100 < w=1")]


def _c_heading_outliers(cells):
    ws = _windows(cells, path=P1, technique="none", weighting="none")
    if 100 not in ws:
        return []
    return [Comparison(_cond(P1, 100, "none"), ">", _cond(P1, w, "none"), "eh_p95",
                       f"Path 1: p95 heading error w=100 > w={w}") for w in ws if w < 100]


def _c_lc_median(cells):
    return _tcmp(cells, "LC Full Path", "<", "None", "median", LARGE)


def _c_lc_full_vs_noturns(cells):
    return _tcmp(cells, "LC Full Path", ">", "LC No Turns", "std", LARGE)


def _c_dyn_small(cells):
    return _tcmp(cells, "Dyn SW", "~", "None", "median", (5, 10))


def _c_dyn_100(cells):
    return _tcmp(cells, "Dyn SW", "<", "None", "median", (100,))


def _c_lcdyn_outliers(cells):
    w8 = _tw(cells)
    return [Comparison(_cond(P1, w, w8, "lc+dyn"), "<", _cond(P1, w, w8, "lc"),
                       f"e{ax}_outliers",
                       f"Path 1 w={w}: box-plot outlier fraction |{ax}| LC+Dyn < LC")
            for w in LARGE for ax in ("x", "y")]


def _c_any_method(cells):
    out = []
    for row in ("LC Full Path", "Dyn SW", "LC + Dyn SW"):
        for st in ("mean", "median", "std"):
            out += _tcmp(cells, row, "<", "None", st, LARGE)
    return out


def _c_lc_vs_lcdyn(cells):
    out = []
    for st in ("mean", "median", "std"):
        out += _tcmp(cells, "LC Full Path", ">", "LC + Dyn SW", st, (10, 100))
    return out


def _c_dyn_scaling(cells):
    out = []
    for st in ("mean", "std"):
        for ax in ("x", "y"):
            for w0 in (5, 10):
                ta, tb = _thesis(ax, 100, "Dyn SW", st), _thesis(ax, w0, "Dyn SW", st)
                w8 = _tw(cells)
                out.append(Comparison(_cond(P1, 100, w8, "dyn"), ">", _cond(P1, w0, w8, "dyn"),
                                      f"e{ax}_{st}",
                                      f"Path 1 Dyn SW {st} |{ax}|: w=100 > w={w0}",
                                      thesis=(ta, tb)))
    return out


def _c_lcdyn_best(cells):
    out = []
    for other in ("None", "LC Full Path", "Dyn SW"):
        for st in ("mean", "median"):
            out += _tcmp(cells, "LC + Dyn SW", "<", other, st, (100,))
    return out


def _c_concl_median(cells):
    out = []
    for other in ("None", "Dyn SW"):
        out += _tcmp(cells, "LC + Dyn SW", "<", other, "median", LARGE)
    return out


def _derived(cells: pd.DataFrame) -> pd.DataFrame:
    """Pseudo-conditions that let one metric be compared with another, per seed.

    - technique "__obs__" (window 1, no weights): ``ex_mean``/``ey_mean`` hold the raw
      antenna observations' own mean absolute error (C12);
    - technique "__noise__" (every window, no weights, each mask): ``along_mean`` holds
      minus the median Euclidean CG error at window 1 of the same seed and mask, the noise
      level a lag must exceed to be "apparent" (C2).
    """
    extra = []
    sub = select(cells, technique="none", window=1, weighting="none").copy()
    if not sub.empty and "obs_ex_mean" in sub:
        o = sub.copy()
        o["technique"] = "__obs__"
        o["ex_mean"], o["ey_mean"] = o["obs_ex_mean"], o["obs_ey_mean"]
        extra.append(o)
    if not sub.empty and "eu_median" in sub:
        base = sub.set_index(["path", "seed", "mask"])["eu_median"]
        allw = select(cells, technique="none", weighting="none").copy()
        idx = pd.MultiIndex.from_frame(allw[["path", "seed", "mask"]])
        allw["along_mean"] = -base.reindex(idx).to_numpy()
        allw["technique"] = "__noise__"
        extra.append(allw)
    # consolidated (the concat leaves ~20 blocks; a selection of rows takes each apart)
    return pd.concat([cells, *extra], ignore_index=True).copy() if extra else cells


def _c_cg_vs_obs(cells):
    out = []
    for p in _paths(cells):
        if 1 in _windows(cells, path=p, technique="none", weighting="none"):
            for ax in ("x", "y"):
                out.append(Comparison(_cond(p, 1, "none"), "<",
                                      _cond(p, 1, "none", technique="__obs__"), f"e{ax}_mean",
                                      f"{_wlabel(p)} w=1: mean |{ax}| CG estimate < raw "
                                      "antenna observation"))
    return out



CLAIMS: list[Claim] = [
    Claim("C1", "4.10.1, 4.10.2",
          "As the sliding window grows, the variation from one estimate to the next is greatly "
          "reduced.", _c_jitter,
          "Metric: RMS change of the CG error vector between consecutive epochs (m), no weights."),
    Claim("C2", "3.4.2, 4.10.1",
          "Lag only becomes apparent at very large windows such as 100; it is not very apparent "
          "for windows 1-10.", _c_lag,
          "Metric: mean signed along-track CG error on the straights (estimates whose window "
          "holds no turning epoch; m; negative = behind the truth). 'Apparent' read as a trail "
          "larger than the noise level, the median Euclidean CG error at window 1 of the same "
          "seed; 'not very apparent' as smaller."),
    Claim("C3", "4.10.2", "The lag effects are more pronounced for Path 2 than for Path 1.",
          _c_lag_path2, "Metric: along-track error at window 100 on the straights (as C2)."),
    Claim("C4", "4.12",
          "Larger windows make the outliers of small windows all but disappear (window 10 vs "
          "window 1) ...", _c_outliers_small, "Metric: 95th percentile of |x| and |y| CG error."),
    Claim("C5", "4.12",
          "... without a large change in the median error.", _c_median_small,
          "Metric: median |x|, |y|; 'no large change' read as within 25 %."),
    Claim("C6", "4.12",
          "A large window may not be useful because of the lag (window 100 worse than 10).",
          _c_large_window_lag, "Metric: mean |x|, |y| CG error, technique none."),
    Claim("C7", "4.12 (Figs 4.114-4.117)",
          "In all cases Huff weights perform equal or better than no weights and random weights, "
          "at every window size, on both paths.", _c_huff("<="),
          "Metric: mean and median |x|, |y| CG error, technique none, full path."),
    Claim("C8", "5.1",
          "Huff weights over sliding windows show a marked improvement over no weights or random "
          "weights.", _c_huff("<"), "As C7, but a strict improvement is required."),
    Claim("C9", "4.12.1",
          "Overall, the estimated orientation matches the actual heading of the vehicle.",
          _c_heading_match, "Metric: median absolute heading error (Eq. 4.2); 'matches' read "
          "as below 10 degrees. No weights."),
    Claim("C10", "4.12.1",
          "The median orientation error at window 100 is lower than at window 1 ...",
          _c_heading_median, "Metric: median absolute heading error, Path 1, no weights."),
    Claim("C11", "4.12.1", "... but window 100 has many (large) orientation outliers.",
          _c_heading_outliers, "Metric: 95th percentile of the heading error, Path 1."),
    Claim("C12", "4.10.1",
          "The fitted CG shows a significant decrease in noise compared with the observed data.",
          _c_cg_vs_obs, "Metric: mean |x|, |y| error of the CG estimate at window 1 vs the mean "
          "per-antenna error of the raw observations (obs_e*_mean)."),
    Claim("C13", "4.12.2",
          "Lag correction lowers the median error for all large window sizes (5, 10, 100).",
          _c_lc_median, "Tables 4.1/4.2 rows LC Full Path vs None, Path 1, Huff weights."),
    Claim("C14", "4.12.2",
          "With lag correction, the full path has many more outliers than the no-turns path.",
          _c_lc_full_vs_noturns, "Metric: standard deviation of |x|, |y| (Tables 4.1/4.2)."),
    Claim("C15", "4.12.3",
          "Dynamic window vs static (Huff): not much difference in the median at windows 5 and "
          "10 ...", _c_dyn_small, "'Not much difference' read as within 25 %."),
    Claim("C16", "4.12.3", "... but a significant drop in the median at window 100.",
          _c_dyn_100, "Dyn SW vs None, median |x|, |y|, Path 1."),
    Claim("C17", "4.12.4",
          "Combining lag correction with the dynamic window gives significantly fewer outliers "
          "than lag correction alone (full path).", _c_lcdyn_outliers,
          "Metric: fraction of epochs above the box-plot whisker Q3 + 1.5 IQR."),
    Claim("C18", "4.12.5",
          "Any method of correction for lag or dynamic window has a lower mean error, median "
          "error and standard deviation than no method at all.", _c_any_method,
          "LC Full Path, Dyn SW, LC + Dyn SW vs None; windows 5, 10, 100; |x| and |y|."),
    Claim("C19", "4.12.5",
          "For windows 10 and 100, lag correction on the full path has a higher mean, median "
          "and standard deviation than lag correction with the dynamic window.",
          _c_lc_vs_lcdyn, "LC Full Path vs LC + Dyn SW."),
    Claim("C20", "4.12.5",
          "The dynamic window alone does not scale well as the window size increases.",
          _c_dyn_scaling, "Dyn SW mean and std at window 100 vs windows 5 and 10."),
    Claim("C21", "4.12.5",
          "Lag correction plus dynamic window gives the lowest error at window 100 (the most "
          "promise).", _c_lcdyn_best, "LC + Dyn SW vs None, LC Full Path, Dyn SW at window 100."),
    Claim("C22", "5.1",
          "Lag correction with the dynamic window gives a significant decrease in the median "
          "error, at large and small windows, compared with no correction or the dynamic window "
          "alone.", _c_concl_median, "LC + Dyn SW vs None and vs Dyn SW, windows 5, 10, 100."),
]


_COURSE = course_pairs()


def swap_techniques(claim: Claim, mapping: dict[str, str], cid_suffix: str,
                    relabel: Callable[[str], str], note: str = "",
                    keep_unchanged: bool = False) -> Claim:
    """The same claim with its conditions' techniques replaced by ``mapping``; comparisons
    that the mapping leaves unchanged are dropped unless ``keep_unchanged``. No published
    values are attached (they belong to the original rows)."""

    def comps(cells):
        out = []
        for c in claim.comparisons(cells):
            a = {**c.a, "technique": mapping.get(c.a.get("technique"), c.a.get("technique"))}
            b = c.b if not isinstance(c.b, dict) else \
                {**c.b, "technique": mapping.get(c.b.get("technique"), c.b.get("technique"))}
            if a == c.a and b == c.b and not keep_unchanged:
                continue
            out.append(Comparison(a, c.rel, b, c.metric, relabel(c.label), None, c.tol))
        return out

    return Claim(claim.cid + cid_suffix, claim.section, claim.text, comps, note + claim.note)


def _course_variant(claim: Claim) -> Claim:
    """The same claim with the course-based lag correction (estimator.lag "course", beyond
    the dissertation) in place of the as-written one; no published values to compare."""
    return swap_techniques(claim, _COURSE, "c", lambda s: s.replace("LC", "LC(course)"),
                           "Lag correction along the estimated course (our variant) instead "
                           "of the platform orientation. ")


#: Claims about lag correction, re-evaluated with the course-based variant (beyond the thesis).
COURSE_CLAIMS = [_course_variant(c) for c in CLAIMS
                 if c.cid in ("C13", "C14", "C17", "C18", "C19", "C21", "C22")]
