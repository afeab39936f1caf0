"""Tables from a sweep's cell table: Tables 4.1/4.2 in the dissertation's shape, and more.

Source: 000_8f82f8df647bf685.txt, Section 4.12.5, Table 4.1 (UTM x) and Table 4.2 (UTM y):
mean, median and standard deviation of the absolute CG error (Eq. 4.1) of Path 1 for
windows 5, 10, 100 and the techniques None / LC Full Path / LC No Turns / Dyn SW /
LC + Dyn SW. The dissertation reports one run; we report, for each number, the mean over
seeds of the per-seed statistic with a 95 % Student-t interval over seeds, and print the
published value beside it.

Reading of the dissertation used here (it does not say it in so many words): the tables are
Path 1 with Huff weights (Figures 4.122/4.123, which the tables summarise, are Huff
weighted); "LC No Turns" is the lag-corrected estimate scored without "sections of
time-steps around which turning occurs" (Section 4.12.2), read as the estimates whose
window holds no turning epoch (mask ``no_turns_window``; a sweep without it falls back to
``no_turns``, the estimates dated at an epoch that is not turning); the dynamic window
refills one epoch per step after a turn (``dyn_growth = "refill"``, the first-in-first-out
queue of Section 3.4.1) where the sweep ran it. All other rows are scored on the full path.
The other readings are shown beside them (:data:`READING_ROWS`), and the oracle rows
(:data:`ORACLE_ROWS`: the lag correction fed the simulator's heading) in a table of their
own: they answer "is the method right when the heading is right?" and are never counted as
estimator results.

All functions take the ``cells`` DataFrame of :mod:`experiments.sweep` (one row per
cell x mask) and never re-run anything.
"""

from __future__ import annotations

import functools
import math
from pathlib import Path

import numpy as np
import pandas as pd

from estimator.scoring import CONSISTENCY_COLUMNS
from experiments.markdown import markdown_table, md_row, md_separator
from experiments.techniques import (
    FILTER_TECHNIQUES,
    ORACLE_TECHNIQUES,
    REGISTRY,
    heading_rows,
    plugins_in_results,
    reading_rows,
    table_rows,
)
from sim.atomic import atomic_write, atomic_write_text

__all__ = ["BEYOND_ROWS", "GROWTH_ORDER", "HEADING_ROWS", "ORACLE_ROWS", "PATH_LABELS",
           "READING_ROWS", "THESIS_ROWS", "THESIS_TABLES", "aggregate", "faithful", "fmt_ci",
           "heading_table", "merge_window_repeats", "numpy_strings", "orientation_table",
           "plugin_section", "run_name", "seed_ci", "side_studies", "thesis_row", "thesis_table",
           "weighting_table", "write_tables"]

PATH_LABELS = {"square100": "Path 1", "square200": "Path 2"}

#: Table rows: label -> (technique, mask), in the dissertation's order (all rows come from
#: the technique registry, experiments.techniques).
THESIS_ROWS = table_rows("thesis")
#: Masks of the faithful reading and what a sweep without them falls back to.
MASK_FALLBACK = {"no_turns_window": "no_turns"}
#: Dynamic-window growth rules, most faithful first (Section 3.4.1's first-in-first-out
#: queue refills one epoch per step; see estimator.tracking.dynamic_window_sizes).
GROWTH_ORDER = ("refill", "jump")
#: The other readings of Table 4.1/4.2 rows: label -> (technique, mask, growth rule or None).
READING_ROWS = reading_rows()
#: Oracle rows (experiments.techniques.ORACLE_TECHNIQUES): the lag correction fed the
#: simulator's heading. Diagnostics: they use the truth and never count as estimator results.
ORACLE_ROWS = table_rows("oracle")
#: Beyond-the-dissertation rows (issues 5 and 14), scored on the full path.
BEYOND_ROWS = table_rows("beyond")
#: Rows of the heading table (issue 14): the pose-filter family and the window fits.
HEADING_ROWS = heading_rows()
#: The dissertation's corrections of the window fit (LC, Dyn SW, LC + Dyn SW): Tables 4.1/4.2
#: use the weighting they ran with.
THESIS_CORRECTIONS = tuple(t.name for t in REGISTRY if t.kind == "thesis"
                           and (t.lag is not None or t.dynamic))

# Published values, Table 4.1 (x) and Table 4.2 (y): (window, row) -> (mean, median, std).
_T41 = """5 None 1.095 0.950 0.795
5 LC_Full_Path 0.629 0.471 0.723
5 LC_No_Turns 0.568 0.453 0.505
5 Dyn_SW 0.510 0.472 0.337
5 LC_+_Dyn_SW 0.630 0.476 0.588
10 None 1.064 1.028 0.562
10 LC_Full_Path 0.62 0.458 0.781
10 LC_No_Turns 0.541 0.428 0.447
10 Dyn_SW 0.768 0.659 0.503
10 LC_+_Dyn_SW 0.606 0.451 0.546
100 None 5.564 4.16 4.691
100 LC_Full_Path 1.454 0.9 2.052
100 LC_No_Turns 0.879 0.785 0.971
100 Dyn_SW 5.691 0.941 5.818
100 LC_+_Dyn_SW 0.923 0.879 0.731"""
_T42 = """5 None 1.639 0.81 1.768
5 LC_Full_Path 0.939 0.773 0.85
5 LC_No_Turns 0.895 0.772 0.63
5 Dyn_SW 0.674 0.631 0.395
5 LC_+_Dyn_SW 0.982 0.797 0.811
10 None 1.419 0.620 1.562
10 LC_Full_Path 0.969 0.785 1.07
10 LC_No_Turns 0.874 0.773 0.596
10 Dyn_SW 0.926 0.852 0.626
10 LC_+_Dyn_SW 0.963 0.798 0.791
100 None 5.126 5.889 4.355
100 LC_Full_Path 1.811 1.224 2.287
100 LC_No_Turns 1.232 1.044 1.342
100 Dyn_SW 5.939 1.117 5.981
100 LC_+_Dyn_SW 1.325 1.066 1.410"""


def _parse(text: str) -> dict[tuple[int, str], dict[str, float]]:
    out = {}
    for line in text.splitlines():
        w, row, mean, med, std = line.split()
        out[(int(w), row.replace("_", " "))] = {"mean": float(mean), "median": float(med),
                                                "std": float(std)}
    return out


#: {"x": Table 4.1, "y": Table 4.2}, each {(window, row label): {"mean", "median", "std"}}.
THESIS_TABLES = {"x": _parse(_T41), "y": _parse(_T42)}
THESIS_WINDOWS = (5, 10, 100)
STATS = ("mean", "median", "std")


# --------------------------------------------------------------------------- statistics
#: Intervals over fewer seeds than this are marked unreliable (†) in the tables: a Student-t
#: interval from 2-4 values is very wide and its coverage rests entirely on normality.
MIN_RELIABLE_SEEDS = 5
#: Metric-name prefixes of signed statistics (every other metric is >= 0: absolute errors,
#: RMS, jitter, times, counts).
SIGNED_PREFIXES = ("along_",)


def seed_ci(values: np.ndarray | pd.Series, lower: float | None = None
            ) -> tuple[float, float, float, int]:
    """Mean over seeds and its 95 % Student-t interval: (mean, lo, hi, n). NaNs are dropped.

    lower : the statistic's support bound (0 for absolute errors): the interval is
        intersected with [lower, inf). The mean of a non-negative quantity cannot lie below
        0, so the intersection keeps the interval's coverage while a plain t-interval over
        2 seeds can reach far below zero (e.g. 0.264 [-1.443, 1.971]).
    With one seed the interval is (nan, nan).
    """
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    n = int(v.size)
    if n == 0:
        return math.nan, math.nan, math.nan, 0
    m = float(v.mean())
    if n == 1:
        return m, math.nan, math.nan, 1
    h = float(_t975(n - 1) * v.std(ddof=1) / math.sqrt(n))
    lo, hi = m - h, m + h
    if lower is not None:
        lo = max(lo, float(lower))
    return m, lo, hi, n


@functools.lru_cache(maxsize=256)
def _t975(dof: int) -> float:
    """Student-t 97.5 % quantile (scipy's ppf costs ~0.1 ms a call; tables make thousands).
    ``scipy.special.stdtrit`` is what ``scipy.stats.t.ppf`` evaluates, without importing
    scipy.stats (0.5 s) in a process that has not already."""
    from scipy.special import stdtrit

    return float(stdtrit(dof, 0.975))


def fmt_ci(m: float, lo: float, hi: float, digits: int = 3, n: int | None = None) -> str:
    """'1.234 [1.100, 1.370]' (or just the mean when the interval is undefined); with
    ``n`` < :data:`MIN_RELIABLE_SEEDS` the interval is marked '†' (unreliable)."""
    if not np.isfinite(m):
        return "n/a"
    if not (np.isfinite(lo) and np.isfinite(hi)):
        return f"{m:.{digits}f}"
    mark = "†" if n is not None and n < MIN_RELIABLE_SEEDS else ""
    return f"{m:.{digits}f} [{lo:.{digits}f}, {hi:.{digits}f}]{mark}"


def select(cells: pd.DataFrame, **where) -> pd.DataFrame:
    """Rows of ``cells`` matching every ``column=value`` (a list/tuple value = any of)."""
    mk = np.ones(len(cells), dtype=bool)
    for k, v in where.items():
        if v is None:
            continue
        mk &= _matches(cells[k], v)
    return cells[mk]


def _matches(col: pd.Series, v) -> np.ndarray:
    """``col == v`` (a list, tuple or set: ``col.isin(v)``) as a bool array; on a plain
    numpy column with numpy (the same element comparisons, without the Series machinery:
    the report selects ~200 times)."""
    many = isinstance(v, (list, tuple, set))
    if isinstance(col.dtype, np.dtype) and not (many and any(pd.isna(x) for x in v)):
        arr = col.to_numpy()
        if not many:
            return np.asarray(arr == v, dtype=bool)
        out = np.zeros(len(arr), dtype=bool)
        for x in v:                                   # isin's equality, value by value
            out |= np.asarray(arr == x, dtype=bool)
        return out
    return col.isin(v).to_numpy() if many else (col == v).to_numpy()


def aggregate(cells: pd.DataFrame, by: list[str], metrics: list[str]) -> pd.DataFrame:
    """Per group of ``by``: for each metric the mean over seeds and its 95 % interval.

    Columns: by..., n_seeds, then <metric>, <metric>_lo, <metric>_hi.
    """
    metrics = [m for m in metrics if m in cells.columns]
    # the metric columns as one float array and the groups as row indices (in the groupby's
    # order, rows in table order): the same numbers as one Series per group and metric, at
    # a fraction of the pandas overhead
    vals = cells[metrics].to_numpy(dtype=float) if metrics else np.zeros((len(cells), 0))
    lower = [None if mcol.startswith(SIGNED_PREFIXES) else 0.0 for mcol in metrics]
    pos = pd.Series(np.arange(len(cells)), index=cells.index)
    seeds = cells["seed"].to_numpy()
    rows = []
    for key, g in pos.groupby([cells[b] for b in by], sort=True, dropna=False):
        idx = g.to_numpy()
        key = key if isinstance(key, tuple) else (key,)
        row = dict(zip(by, key))
        s = seeds[idx]
        row["n_seeds"] = len(np.unique(s[~pd.isna(s)]))      # Series.nunique, faster
        for mcol, m, lo, hi in zip(metrics, *_seed_ci_columns(vals[idx], lower)):
            row[mcol], row[f"{mcol}_lo"], row[f"{mcol}_hi"] = m, lo, hi
        rows.append(row)
    return pd.DataFrame(rows)


def _seed_ci_columns(sub: np.ndarray, lower: list[float | None]
                     ) -> tuple[list[float], list[float], list[float]]:
    """:func:`seed_ci` of every column of ``sub`` (seeds x metrics; ``lower`` per column):
    the columns without NaN at once, bit for bit the same numbers (each column reduced as
    one contiguous row, the order of :func:`seed_ci`'s 1-D reductions), the others one by
    one. Returns (means, los, his)."""
    k, n_col = sub.shape
    full = np.isfinite(sub).all(axis=0)
    if k < 2 or not full.any():
        res = [seed_ci(sub[:, j], lower[j])[:3] for j in range(n_col)]
        return tuple(list(c) for c in zip(*res)) if res else ([], [], [])  # type: ignore
    rows = np.ascontiguousarray(sub[:, full].T)
    m = rows.mean(axis=1)
    h = _t975(k - 1) * rows.std(axis=1, ddof=1) / math.sqrt(k)
    fm, flo, fhi = iter(m.tolist()), iter((m - h).tolist()), iter((m + h).tolist())
    ms, los, his = [], [], []
    for j in range(n_col):
        if full[j]:
            mj, lo, hi = next(fm), next(flo), next(fhi)
            if lower[j] is not None:
                lo = max(lo, float(lower[j]))
        else:
            mj, lo, hi, _ = seed_ci(sub[:, j], lower[j])
        ms.append(mj)
        los.append(lo)
        his.append(hi)
    return ms, los, his


#: Axes other than those the tables/claims are laid out by. Cells that differ in them are
#: separate "variants" (e.g. two configurations); each gets its own tables and verdicts.
#: A cell whose value is the not-applicable marker ("-" or 0) belongs to every variant.
VARIANT_AXES = ("config", "noise", "noise_overrides", "path_overrides", "solver", "dyn_window",
                "turning")
_NA = {"-", 0}


def model_name(cells: pd.DataFrame, axis: str, value) -> str:
    """The display name of a ``path`` / ``config`` / ``noise`` axis value: the model's own
    ``name`` (recorded by the sweep as ``<axis>_name``) when the spec named it by file, e.g.
    ``rects/rect30.toml`` -> ``rect30``; else the value itself."""
    col = f"{axis}_name"
    if col in cells.columns and isinstance(value, str) and (value.endswith(".toml")
                                                           or "/" in value):
        names = cells.loc[cells[axis] == value, col].dropna()
        if not names.empty and str(names.iloc[0]):
            return str(names.iloc[0])
    if isinstance(value, str) and value.endswith(".toml"):
        return Path(value).stem
    return str(value)


def _vlabel(axis: str, value, cells: pd.DataFrame | None = None) -> str:
    """'config=rover_gps4'; overrides as their fields ('cruise_speed_mps=0.5',
    '{}' = as shipped)."""
    if cells is not None and axis in ("config", "noise"):
        return f"{axis}={model_name(cells, axis, value)}"
    if axis.endswith("_overrides"):
        import json

        d = json.loads(value) if isinstance(value, str) else value
        what = axis.split("_")[0]
        return f"{what} as shipped" if not d else ", ".join(f"{k}={v}" for k, v in d.items())
    return f"{axis}={value}"


_LAYOUT = ("path", "window", "weighting", "technique", "mask")


def _study_mask(cells: pd.DataFrame) -> np.ndarray:
    """True on the cells of side studies: along a variant axis, a value whose cells cover
    fewer (path, window, weighting, technique, mask) combinations than another value's on
    the same paths (a few of its rows re-run). A value on paths of its own (e.g. a car
    layout on a car path beside the rover's) is a variant, not a side study."""
    study = np.zeros(len(cells), dtype=bool)
    lay_cols = [c for c in _LAYOUT if c in cells.columns]
    for a in (a for a in VARIANT_AXES if a in cells.columns):
        vals = [v for v in dict.fromkeys(cells[a]) if v not in _NA]
        if len(vals) < 2:
            continue
        size = {v: len(cells.loc[cells[a] == v, lay_cols].drop_duplicates()) for v in vals}
        paths = {v: set(cells.loc[cells[a] == v, "path"]) if "path" in cells.columns
                 else set() for v in vals}
        for v in vals:
            if any(size[v] < size[w] and paths[v] <= paths[w] for w in vals if w != v):
                study |= (cells[a] == v).to_numpy()
    return study


def side_studies(cells: pd.DataFrame) -> pd.DataFrame:
    """The cells of side studies (:func:`variants`): e.g. a few rows re-run under another
    noise split. They are reported in sections of their own, never as a variant whose
    claims would mostly be "not evaluated"."""
    return cells[_study_mask(cells)]


def variants(cells: pd.DataFrame) -> list[tuple[str, pd.DataFrame]]:
    """Split ``cells`` into variants over :data:`VARIANT_AXES`; returns (label, subset).

    A variant is a value of such an axis (e.g. a second configuration) whose cells cover the
    same grid as the others; a value that covers only part of it is a side study
    (:func:`side_studies`) and is left out here. With a single variant the label is "" and
    the subset is ``cells`` without the side studies.
    """
    cells = cells[~_study_mask(cells)]
    axes = [a for a in VARIANT_AXES if a in cells.columns]
    values = {a: [v for v in dict.fromkeys(cells[a]) if v not in _NA] for a in axes}
    multi = [a for a in axes if len(values[a]) > 1]
    if not multi:
        return [("", cells)]
    import itertools

    out = []
    for combo in itertools.product(*(values[a] for a in multi)):
        mk = np.ones(len(cells), dtype=bool)
        for a, v in zip(multi, combo):
            col = cells[a]
            mk &= ((col == v) | col.isin(list(_NA))).to_numpy()
        sub = cells[mk]
        if not sub.empty:
            out.append((", ".join(_vlabel(a, v, cells) for a, v in zip(multi, combo)), sub))
    return out


def faithful(cells: pd.DataFrame) -> pd.DataFrame:
    """``cells`` with, for every dynamic technique that ran under several growth rules, only
    the rows of the most faithful one present (:data:`GROWTH_ORDER`), so a condition on a
    technique names one cell per seed. Other rules stay visible through
    :data:`READING_ROWS`."""
    return cells if "dyn_growth" not in cells.columns else cells[_faithful_mask(cells)]


def _faithful_mask(cells: pd.DataFrame) -> np.ndarray:
    """The rows :func:`faithful` keeps, as a bool array (n,)."""
    keep = np.ones(len(cells), dtype=bool)
    if "dyn_growth" not in cells.columns:
        return keep
    g = cells["dyn_growth"].to_numpy()
    tech = cells["technique"].to_numpy()
    for t in pd.unique(tech[~pd.isna(g) & (g != "-")]):
        sel = tech == t
        present = set(g[sel])
        best = next((r for r in GROWTH_ORDER if r in present), None)
        if best is not None:
            keep &= ~sel | (g == best)
    return keep


def thesis_row(cells: pd.DataFrame, label: str) -> tuple[str, str]:
    """(technique, mask) of a Table 4.1/4.2 row (:data:`THESIS_ROWS`) in this sweep: the
    faithful mask, or its fall-back (:data:`MASK_FALLBACK`) when the sweep lacks it."""
    tech, mask = THESIS_ROWS[label]
    if "mask" in cells.columns and mask in MASK_FALLBACK and mask not in set(cells["mask"]):
        mask = MASK_FALLBACK[mask]
    return tech, mask


def _default_weighting(cells: pd.DataFrame, path: str) -> str | None:
    sub = select(cells, path=path, technique=list(THESIS_CORRECTIONS))
    if sub.empty:
        return None
    ws = sub["weighting"].unique().tolist()
    return "huff" if "huff" in ws else ws[0]


# --------------------------------------------------------------------------- tables
def _plugins(cells: pd.DataFrame, plugins: dict | None) -> dict:
    """The plug-in entries of ``cells`` (experiments.techniques): ``plugins`` as given,
    else built from the technique names alone."""
    if plugins is not None:
        return plugins
    return plugins_in_results(cells["technique"]) if "technique" in cells.columns else {}


def _row_defs(cells: pd.DataFrame, beyond: bool, plugins: dict | None = None
              ) -> dict[str, tuple[str, str, str | None]]:
    """label -> (technique, mask, growth rule or None = the faithful one) of every table row
    this sweep can show, in table order (plug-in rows after the built-in beyond rows);
    readings that would repeat a thesis row (the sweep has no other rule or mask) are left
    out."""
    defs: dict[str, tuple[str, str, str | None]] = {}
    for label in THESIS_ROWS:
        defs[label] = (*thesis_row(cells, label), None)
    masks = set(cells["mask"]) if "mask" in cells.columns else set()
    growth = set(cells["dyn_growth"]) if "dyn_growth" in cells.columns else set()
    for label, (tech, mask, rule) in READING_ROWS.items():
        if mask not in masks:
            continue
        if rule is None and (tech, mask, None) in defs.values():
            continue            # the sweep has no other mask: the thesis row shows this one
        if rule is not None:
            best = faithful(select(cells, technique=tech))
            if rule not in growth or best.empty or rule in set(best["dyn_growth"]):
                continue        # the thesis row already uses this rule
        defs[label] = (tech, mask, rule)
    if beyond:
        defs.update({k: (*v, None) for k, v in BEYOND_ROWS.items()})
        defs.update({k: (t, m if m in masks else MASK_FALLBACK.get(m, m), None)
                     for k, (t, m) in ORACLE_ROWS.items()})
        defs.update({label: (t.name, mask, None) for t in _plugins(cells, plugins).values()
                     for label, mask in t.rows})
    return defs


def row_kind(label: str, plugins: dict | None = None) -> str:
    """"thesis", "reading", "oracle", "plugin" or "beyond": what a table row is."""
    if label in THESIS_ROWS:
        return "thesis"
    if label in READING_ROWS:
        return "reading"
    if any(label == r[0] for t in (plugins or {}).values() for r in t.rows):
        return "plugin"
    return "oracle" if label in ORACLE_ROWS else "beyond"


def _row_groups(cells: pd.DataFrame, rule: str | None) -> dict[tuple, np.ndarray]:
    """(window, technique, mask) -> positions (table order) in ``cells`` of the rows of
    growth rule ``rule`` (None: :func:`faithful`'s): one grouping instead of a selection
    per table row (the same rows, so the same numbers)."""
    pos = np.flatnonzero(_faithful_mask(cells) if rule is None
                         else (cells["dyn_growth"] == rule).to_numpy())
    sub = cells.iloc[pos]
    g = sub.groupby(["window", "technique", "mask"], sort=False, dropna=False).indices
    return {k: pos[v] for k, v in g.items()}


def thesis_table(cells: pd.DataFrame, axis: str, path: str = "square100",
                 weighting: str | None = None, beyond: bool = True,
                 plugins: dict | None = None) -> pd.DataFrame:
    """Table 4.1 (axis "x") or 4.2 (axis "y") in the dissertation's shape.

    One row per (window, technique row) present in ``cells``: for mean, median and std of the
    absolute CG error, our mean over seeds with its 95 % interval and the published value
    (Path 1 only; NaN elsewhere); for the "None" rows also the smallest and largest per-seed
    value (``<stat>_seed_min``/``_seed_max``: the spread a single run, like the published
    one, can land in). ``weighting`` defaults to Huff when present. Column ``kind`` says
    what a row is (:func:`row_kind`): the thesis rows in their faithful reading, other
    readings of them, oracle rows (truth-fed diagnostics), beyond-the-thesis trackers, or
    plug-ins (``plugins``: name -> entry, default built from the technique names,
    :func:`experiments.techniques.plugins_in_results`).
    """
    if axis not in ("x", "y"):
        raise ValueError(f"axis: must be 'x' or 'y', got {axis!r}")
    weighting = weighting or _default_weighting(cells, path)
    pref = "ex" if axis == "x" else "ey"
    plugins = _plugins(cells, plugins)
    rows_def = _row_defs(cells, beyond, plugins)
    # only the columns used below: each select() takes whole rows
    cells = select(cells, path=path, weighting=[weighting, "-"])
    cells = cells[[c for c in (*_LAYOUT, "dyn_growth", "seed", *(f"{pref}_{s}" for s in STATS))
                   if c in cells.columns]]
    published = THESIS_TABLES[axis] if path == "square100" else {}
    windows = sorted(cells["window"].unique())
    seed = cells["seed"].to_numpy()
    vals = {s: cells[f"{pref}_{s}"].to_numpy(dtype=float) for s in STATS
            if f"{pref}_{s}" in cells.columns}    # a missing one: KeyError at its first row
    groups: dict = {}       # growth rule (None: the faithful rows) -> {(w, tech, mask): rows}
    out = []
    for w in windows:
        if w == 1 and not beyond:
            continue
        for label, (tech, mask, rule) in rows_def.items():
            # ekf / naive take no weights (weighting "-"): shown beside the weighted rows
            if rule not in groups:
                groups[rule] = _row_groups(cells, rule)
            idx = groups[rule].get((w, tech, mask))
            if idx is None:
                continue
            row = {"path": path, "weighting": weighting, "window": int(w), "technique": label,
                   "thesis_row": label in THESIS_ROWS, "kind": row_kind(label, plugins),
                   "mask": mask, "n_seeds": len(np.unique(seed[idx]))}
            for s in STATS:
                v = vals[s][idx]
                m, lo, hi, _ = seed_ci(v, lower=0.0)   # |error| >= 0
                row[s], row[f"{s}_lo"], row[f"{s}_hi"] = m, lo, hi
                row[f"{s}_thesis"] = published.get((int(w), label), {}).get(s, np.nan)
                v = v[np.isfinite(v)]
                spread = label == "None" and v.size > 0
                row[f"{s}_seed_min"] = float(v.min()) if spread else np.nan
                row[f"{s}_seed_max"] = float(v.max()) if spread else np.nan
            out.append(row)
    return pd.DataFrame(out)


def weighting_table(cells: pd.DataFrame, technique: str = "none") -> pd.DataFrame:
    """Figures 4.114-4.117 as numbers: none / random / huff per path and window (full path).

    Mean over seeds (95 % interval) of the per-seed mean and median |x| and |y| CG error.
    """
    sub = select(cells, technique=technique, mask="full")
    if sub.empty:
        return pd.DataFrame()
    return aggregate(sub, ["path", "window", "weighting"],
                     ["ex_mean", "ex_median", "ey_mean", "ey_median", "ex_p95", "ey_p95"])


def orientation_table(cells: pd.DataFrame, technique: str = "none") -> pd.DataFrame:
    """Section 4.12.1 / Figure 4.119 as numbers: heading error (degrees) per path, window."""
    sub = select(cells, technique=technique, mask="full").copy()
    if sub.empty or "eh_mean" not in sub:
        return pd.DataFrame()
    for s in ("mean", "median", "rmse", "p95", "max"):
        if f"eh_{s}" in sub:
            sub[f"eh_{s}_deg"] = np.degrees(sub[f"eh_{s}"])
    sub["eh_outliers_pct"] = 100 * sub["eh_outliers"]
    return aggregate(sub, ["path", "weighting", "window"],
                     ["eh_mean_deg", "eh_median_deg", "eh_rmse_deg", "eh_p95_deg",
                      "eh_outliers_pct"])


def heading_table(cells: pd.DataFrame, plugins: dict | None = None) -> pd.DataFrame:
    """Heading side by side (issue 14): the pose filter (causal), its fixed-lag and RTS
    smoothers, the GTSAM peer and the window fits, per path, full path.

    One row per (path, :data:`HEADING_ROWS` technique, window, weighting) present: over
    seeds, the mean and 95 % interval of the heading RMS (Eq. 4.2 errors, degrees), the
    heading p95 (degrees), the mean Euclidean CG error (m), the time per epoch of the
    estimator (``(t_track_s + t_reused_s) / n_epochs``, microseconds: its stand-alone
    cost, a forward pass shared with another row counted in full), and ``flip_seeds``: the
    number of seeds with a heading error above 90 degrees at some epoch; the consistency
    columns (:data:`estimator.scoring.CONSISTENCY_COLUMNS`: heading NEES and NIS, mean per
    dof and share inside the 95 % chi-square band; shares of rows not "ok" and
    "inconsistent"), NaN where the technique has none. The filter family ignores the
    window (it only sets the first row), so only its smallest window is listed; window fits
    and the motion-compensated window are listed at every window, with Huff weights where
    present (else none). Plug-ins (``plugins``, as in :func:`thesis_table`) follow, at
    their smallest window (a plug-in takes no window).
    """
    rows_of = {**HEADING_ROWS, **{t.heading_row: t.name
                                  for t in _plugins(cells, plugins).values()}}
    sub = select(cells, mask="full", technique=list(rows_of.values())).copy()
    if sub.empty or "eh_rmse" not in sub:
        return pd.DataFrame()
    sub["eh_rmse_deg"] = np.degrees(sub["eh_rmse"])
    sub["eh_p95_deg"] = np.degrees(sub["eh_p95"])
    # stand-alone cost: what the cell took from the sweep's per-process memo (a forward
    # pass another row of the same data ran, experiments.sweep's t_reused_s) counts too
    reused = sub["t_reused_s"].fillna(0.0) if "t_reused_s" in sub else 0.0
    sub["us_per_epoch"] = 1e6 * (sub["t_track_s"] + reused) / sub["n_epochs"].clip(lower=1)
    rows = []
    label_of = {v: k for k, v in rows_of.items()}
    for path in dict.fromkeys(sub["path"]):
        sp = sub[sub["path"] == path]
        for tech in rows_of.values():
            st = sp[sp["technique"] == tech]
            if st.empty:
                continue
            wts = set(st["weighting"])
            wt = "-" if "-" in wts else ("huff" if "huff" in wts else sorted(wts)[0])
            st = st[st["weighting"] == wt]
            windows = sorted(set(st["window"]))
            if tech in FILTER_TECHNIQUES or tech not in HEADING_ROWS.values():
                windows = windows[:1]
            for w in windows:
                g = st[st["window"] == w]
                row = {"path": path, "estimator": label_of[tech], "technique": tech,
                       "window": int(w), "weighting": wt, "n_seeds": int(g["seed"].nunique()),
                       "flip_seeds": int((g["eh_max"] > np.pi / 2).sum())}
                for col in ("eh_rmse_deg", "eh_p95_deg", "eu_mean", "us_per_epoch",
                            *CONSISTENCY_COLUMNS):
                    # NaN where the technique has none (a sweep from before issue 25 too)
                    vals = g[col] if col in g else np.full(len(g), np.nan)
                    m, lo, hi, _ = seed_ci(vals, lower=0.0 if col in CONSISTENCY_COLUMNS
                                           else None)        # NEES, NIS, shares >= 0
                    row[col], row[f"{col}_lo"], row[f"{col}_hi"] = m, lo, hi
                rows.append(row)
    return pd.DataFrame(rows)


# --------------------------------------------------------------------------- markdown
def _md(df: pd.DataFrame, cols: list[tuple[str, str]]) -> str:
    """A table of ``cols`` (header, column or function of the row); values as ``str``."""
    return markdown_table(df, cols, floatfmt=None, nan=None)


def _ci(prefix: str, digits: int = 3):
    return lambda r: fmt_ci(r[prefix], r[f"{prefix}_lo"], r[f"{prefix}_hi"], digits,
                            r.get("n_seeds"))


def _num(col: str, digits: int = 3):
    return lambda r: "" if not np.isfinite(r[col]) else f"{r[col]:.{digits}f}"


def _window_text(r: pd.Series) -> str:
    """The Window cell: the row's window, or the windows a merged row stands for
    (:func:`merge_window_repeats`)."""
    w = r.get("windows")
    return str(r["window"]) if not isinstance(w, str) or not w else w


def merge_window_repeats(df: pd.DataFrame, plugins: dict | None = None) -> pd.DataFrame:
    """Rows of a :func:`thesis_table` whose technique ignores the window (the pose-filter
    family, :data:`FILTER_TECHNIQUES`: the window only sets where its first estimate is
    scored) merged across windows where every number is identical; the kept row (the
    first window's) gets ``windows`` = the windows it stands for, e.g. "1, 5, 10".

    Only exact repeats merge (the numbers compared by their ``repr``, i.e. bit for bit), so
    no value changes and a window whose numbers differ (window 100's later first estimate)
    keeps its own row. Plug-in rows (``plugins``) merge the same way: a plug-in takes no
    window. Other rows are untouched (``windows`` "").
    """
    if df.empty or "technique" not in df.columns:
        return df
    labels = {lab for lab, (tech, _) in BEYOND_ROWS.items() if tech in FILTER_TECHNIQUES}
    labels |= {r[0] for t in (plugins or {}).values() for r in t.rows}
    out = df.copy()
    out["windows"] = ""
    vals = [c for c in df.columns if c != "window"]
    drop: list = []
    for lab in labels & set(df["technique"]):
        idx = df.index[df["technique"] == lab]
        groups: dict[tuple, list] = {}
        for i in sorted(idx, key=lambda i: df.at[i, "window"]):
            groups.setdefault(tuple(repr(df.at[i, c]) for c in vals), []).append(i)
        for members in groups.values():
            if len(members) > 1:
                out.at[members[0], "windows"] = ", ".join(str(int(df.at[i, "window"]))
                                                          for i in members)
                drop += members[1:]
    return out.drop(index=drop)


def thesis_table_md(df: pd.DataFrame) -> str:
    cols = [("Window", _window_text), ("Technique", "technique")]
    for s in STATS:
        cols += [(f"{s.capitalize()} (ours, 95 % CI)", _ci(s)), (f"{s.capitalize()} (thesis)",
                                                                  _num(f"{s}_thesis"))]
    return _md(df, cols)


def _reading_note(no_turns_mask: str, cells: pd.DataFrame) -> str:
    """One sentence: which reading of the ambiguous rows this table shows."""
    nt = ("the estimates whose window holds no turning epoch" if no_turns_mask ==
          "no_turns_window" else "the estimates dated at an epoch that is not turning")
    rules = set(faithful(cells).get("dyn_growth", pd.Series(dtype=object))) - {"-"}
    grow = {"refill": "refills one epoch per step after a turn (Section 3.4.1's queue)",
            "jump": "returns to full size at the first epoch after a turn"}
    g = "; ".join(grow[r] for r in GROWTH_ORDER if r in rules)
    return (f"Reading: \"LC No Turns\" is scored on {nt}"
            + (f"; the dynamic window {g}." if g else "."))


def _variant_tables(cells: pd.DataFrame, out: Path, vlabel: str, plugins: dict | None = None
                    ) -> list[str]:
    """Markdown (and CSVs) for one variant of the sweep (``plugins`` as in
    :func:`thesis_table`)."""
    tag = "" if not vlabel else "_" + "".join(ch if ch.isalnum() else "_" for ch in vlabel)
    md: list[str] = []
    paths = [p for p in ("square100", "square200") if p in set(cells["path"])] + \
        sorted(set(cells["path"]) - {"square100", "square200"})
    for axis, tno in (("x", "4.1"), ("y", "4.2")):
        for p in paths:
            df = thesis_table(cells, axis, path=p, plugins=plugins)
            if df.empty:
                continue
            pname = model_name(cells, "path", p)
            label = PATH_LABELS.get(p, pname)
            suffix = "" if p == "square100" else f"_{pname}"
            atomic_write(out / f"table_{tno.replace('.', '_')}{suffix}{tag}.csv",
                         lambda f, df=df: df.to_csv(f, index=False))
            thesis = df[df["thesis_row"] & df["window"].isin(THESIS_WINDOWS)]
            readings = df[(df["kind"] == "reading") & df["window"].isin(THESIS_WINDOWS)]
            oracle = df[df["kind"] == "oracle"]
            beyond = df[~df.index.isin(thesis.index) & ~df.index.isin(readings.index)
                        & ~df.index.isin(oracle.index)]
            nt = thesis.loc[thesis["technique"] == "LC No Turns", "mask"]
            md += [(f"## Table {tno}: |{axis}| CG error, {label} ({p}), "
                   f"{df['weighting'].iloc[0]} weights"), ""]
            if not nt.empty:
                md += [_reading_note(nt.iloc[0], cells), ""]
            md += [thesis_table_md(thesis), ""]
            if not readings.empty:
                md += [(f"Other readings of the same rows (the faithful one is in the table "
                       f"above), |{axis}| error:"), "", thesis_table_md(readings), ""]
            if not oracle.empty:
                md += [(f"**Oracle rows, not estimator results**: the lag correction of "
                       f"Section 3.4.2 fed the simulator's true heading instead of the "
                       f"estimated one. They show what the method gives when the heading is "
                       f"right, |{axis}| error:"), "", thesis_table_md(oracle), ""]
            if not beyond.empty:
                merged = merge_window_repeats(beyond, plugins)
                same = (" The pose-filter rows do not use the window (it only sets the first "
                        "scored estimate): a row with the same numbers at several windows is "
                        "shown once, its windows listed."
                        if (merged["windows"] != "").any() else "")
                if plugins and (merged["kind"] == "plugin").any():
                    same += (" Plug-in rows (the spec's own trackers, README: Plug-in "
                             "trackers) take no window either.")
                md += [(f"Beyond the dissertation (and window 1), same path and weights, full "
                       f"path, |{axis}| error.{same}"), "", thesis_table_md(merged), ""]
    wt = weighting_table(cells)
    if not wt.empty:
        atomic_write(out / f"weighting{tag}.csv", lambda p: wt.to_csv(p, index=False))
        md += ["## Weighting comparison (Figures 4.114-4.117): no / random / Huff weights", "",
               ("Technique none, full path; mean over seeds of the per-seed mean and median "
               "absolute error (m)."), ""]
        md += [_md(wt, [("Path", lambda r: PATH_LABELS.get(r["path"], r["path"])),
                        ("Window", "window"), ("Weights", "weighting"),
                        ("mean |x|", _ci("ex_mean")), ("median |x|", _ci("ex_median")),
                        ("mean |y|", _ci("ey_mean")), ("median |y|", _ci("ey_median"))]), ""]
    ot = orientation_table(cells)
    if not ot.empty:
        atomic_write(out / f"orientation{tag}.csv", lambda p: ot.to_csv(p, index=False))
        md += ["## Orientation error per window (Section 4.12.1, Figure 4.119)", "",
               "Absolute heading error, Eq. 4.2, degrees; technique none, full path.", ""]
        md += [_md(ot, [("Path", lambda r: PATH_LABELS.get(r["path"], r["path"])),
                        ("Weights", "weighting"), ("Window", "window"),
                        ("mean", _ci("eh_mean_deg", 1)), ("median", _ci("eh_median_deg", 1)),
                        ("RMS", _ci("eh_rmse_deg", 1)), ("p95", _ci("eh_p95_deg", 1)),
                        ("outliers %", _ci("eh_outliers_pct", 1))]), ""]
    ht = heading_table(cells, plugins)
    if not ht.empty:
        # wall times stay out of the tracked tables (a rerun must reproduce them byte for
        # byte): the estimators' time per epoch goes to an untracked *.local.csv
        tcols = [c for c in ht.columns if c.startswith("us_per_epoch")]
        keys = ["path", "estimator", "technique", "window", "weighting", "n_seeds"]
        atomic_write(out / f"heading{tag}.csv",
                     lambda p: ht.drop(columns=tcols).to_csv(p, index=False))
        atomic_write(out / f"heading_timings{tag}.local.csv",
                     lambda p: ht[keys + tcols].to_csv(p, index=False))
        md += ["## Heading: pose filter, smoothers, GTSAM peer and window fits (issue 14)", "",
               ("Full path. Heading RMS and p95 of the Eq. 4.2 error in degrees, mean "
                "Euclidean CG error in metres; 95 % intervals over seeds. \"flips\": seeds "
                "with a heading error above 90 degrees at some epoch. Each estimator's time "
                f"per epoch in this run (microseconds, with intervals) is in the untracked "
                f"`heading_timings{tag}.local.csv`. Consistency (issue 25; n/a where the "
                "estimator has none): \"NEES\" is the mean heading NEES "
                "(error / own heading sd)^2 and \"NIS/dof\" the forward pass's mean "
                "normalised innovation squared per degree of freedom, both 1 for a "
                "consistent estimate; \"in band\" is the share of epochs inside the central "
                "95 % chi-square band (0.95 when consistent); \"not ok\" and "
                "\"inconsistent\" the shares of epochs with such a status."), ""]
        md += [_md(ht, [("Path", lambda r: PATH_LABELS.get(r["path"], r["path"])),
                        ("Estimator", "estimator"), ("Window", "window"),
                        ("Weights", "weighting"), ("Heading RMS (deg)", _ci("eh_rmse_deg", 2)),
                        ("Heading p95 (deg)", _ci("eh_p95_deg", 2)),
                        ("CG error (m)", _ci("eu_mean", 3)),
                        ("Flips", lambda r: f"{r['flip_seeds']}/{r['n_seeds']}"),
                        ("NEES", _ci("nees_mean", 2)), ("NEES in band", _ci("nees_in_band", 2)),
                        ("NIS/dof", _ci("nis_per_dof", 2)),
                        ("NIS in band", _ci("nis_in_band", 2)),
                        ("not ok", _ci("status_not_ok", 2)),
                        ("inconsistent", _ci("status_inconsistent", 2))]), ""]
    return md


def _side_study_md(study: pd.DataFrame, out: Path) -> list[str]:
    """Side studies (:func:`side_studies`) as one table (full path) and ``side_studies.csv``."""
    axes = [a for a in ("path", *VARIANT_AXES, "weighting", "technique", "window")
            if a in ("technique", "window") or a in study.columns
            and len(set(study[a]) - _NA) > 1]
    sub = select(study, mask="full").copy()
    if sub.empty:
        return []
    sub["eh_median_deg"] = np.degrees(sub["eh_median"])
    sub["technique"] = [f"{t} (ORACLE: simulator heading, not a result)"
                        if t in ORACLE_TECHNIQUES else t for t in sub["technique"]]
    agg = aggregate(sub, axes, ["ex_mean", "ey_mean", "eh_median_deg"])
    atomic_write(out / "side_studies.csv", lambda p: agg.to_csv(p, index=False))
    cols = [(a, a) for a in axes] + [("mean |x| (m)", _ci("ex_mean")),
                                     ("mean |y| (m)", _ci("ey_mean")),
                                     ("median heading error (deg)", _ci("eh_median_deg", 1))]
    return ["## Side studies", "",
            ("Rows re-run under another value of an axis that covers only part of the grid "
             "(e.g. the heading-observability study's noise splits); full path. REPORT.md "
             "discusses them; `side_studies.csv` has the numbers."), "", _md(agg, cols), ""]


def plugin_section(cells: pd.DataFrame, out_dir: str | Path, spec=None) -> list[str]:
    """REPORT.md's section on the spec's plug-in trackers (none: no lines): each plug-in's
    tracker and options, and its full-path errors beside the window fit ("none") on the
    same paths and windows, mean over seeds with 95 % intervals. The claims are the
    dissertation's and never use a plug-in row."""
    plugins = plugins_in_results(cells["technique"], out_dir, getattr(spec, "raw", None))
    if not plugins:
        return []
    cells = numpy_strings(cells)
    lines = ["## Plug-in trackers", "",
             ("The spec's own trackers (README: Plug-in trackers), run on the same observations "
              "as the built-in rows and scored the same way; full path, errors in metres, "
              "heading in degrees. No claim below uses them."), "",
             md_row(["Technique", "Label", "Tracker", "Options"]), md_separator(4)]
    lines += [md_row([f"`{t.name}`", t.short, f"`{t.tracker}`", f"`{t.options}`"])
              for t in plugins.values()]
    sub = select(cells, mask="full", technique=["none", *plugins]).copy()
    windows = set(select(sub, technique=list(plugins))["window"])
    sub = sub[sub["window"].isin(windows)]
    sub["eh_rmse_deg"] = np.degrees(sub["eh_rmse"])
    sub["technique"] = [plugins[t].short if t in plugins else "Window fit (none)"
                        for t in sub["technique"]]
    agg = aggregate(sub, ["path", "window", "weighting", "technique"],
                    ["ex_mean", "ey_mean", "eh_rmse_deg"])
    return [*lines, "", _md(agg, [("Path", "path"), ("Window", "window"),
                                  ("Weights", "weighting"), ("Technique", "technique"),
                                  ("mean |x|", _ci("ex_mean")), ("mean |y|", _ci("ey_mean")),
                                  ("heading RMS", _ci("eh_rmse_deg", 1))]), ""]


def numpy_strings(cells: pd.DataFrame) -> pd.DataFrame:
    """``cells`` with its string columns held as numpy object arrays instead of pandas'
    Arrow-backed ``str`` dtype (what ``read_parquet`` gives): the tables and the report
    select rows by these columns ~1000 times, and each selection of an Arrow column goes
    through pyarrow's ``take`` (about a third of their time on the thesis preset). The
    values are the same, so are the tables (tested). The copy is consolidated (one block
    per dtype: the conversion left one per column, and a selection of rows takes each block
    apart, 7x the time of four blocks)."""
    cols = {c: object for c in cells.columns if pd.api.types.is_string_dtype(cells[c].dtype)
            and cells[c].dtype != object}
    return (cells.astype(cols) if cols else cells).copy()


def run_name(out_dir: str | Path, spec=None) -> str:
    """The run's name for titles: ``spec.name``, else the spec name recorded in
    ``<out_dir>/manifest.json``, else the folder's name (a folder without a manifest)."""
    if spec is not None and getattr(spec, "name", None):
        return str(spec.name)
    import json

    try:
        name = json.loads((Path(out_dir) / "manifest.json").read_text())["spec"]["name"]
    except (OSError, ValueError, KeyError, TypeError):
        name = None
    return str(name) if isinstance(name, str) and name else Path(out_dir).name


def write_tables(cells: pd.DataFrame, out_dir: str | Path, spec=None) -> Path:
    """Write tables.md and the CSVs (table_4_1*.csv, table_4_2*.csv, weighting.csv,
    orientation.csv, heading.csv, by_cell.csv) to ``out_dir``; returns the path of
    tables.md. The title names the run (:func:`run_name`: the spec's name, not the
    folder's)."""
    cells = numpy_strings(cells)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    plugins = plugins_in_results(cells["technique"], out, getattr(spec, "raw", None))
    n_seeds = int(cells["seed"].nunique())
    solvers = sorted(set(cells["solver"]) - {"-"})
    md = [f"# Tables ({run_name(out, spec)})", "",
          (f"Every number is the mean over {n_seeds} seed(s) of the per-seed statistic, with "
          "its 95 % Student-t interval over seeds in brackets; \"thesis\" is the value "
          "published in the dissertation (000_8f82f8df647bf685.txt, Tables 4.1 and 4.2, "
          f"Path 1, one run). Errors in metres (Eq. 4.1). Solver(s): {', '.join(solvers)}. "
          "Intervals of non-negative statistics are cut at 0 (the mean cannot be negative)"
          + (f"; with fewer than {MIN_RELIABLE_SEEDS} seeds they are marked † (unreliable: "
             "a t-interval from so few values is wide and rests on normality)"
             if n_seeds < MIN_RELIABLE_SEEDS else "") + "."),
          ""]
    for vlabel, vcells in variants(cells):
        if vlabel:
            md += [f"# Variant: {vlabel}", ""]
        md += _variant_tables(vcells, out, vlabel, plugins)
    study = side_studies(cells)
    if not study.empty:
        md += _side_study_md(study, out)
    axes = ["path", "config", "noise", "noise_overrides", "path_overrides", "solver",
            "weighting", "technique", "window", "dyn_window", "turning", "dyn_growth", "mask"]
    by = aggregate(cells, [a for a in axes if a in cells.columns],
                   ["ex_mean", "ex_median", "ex_std", "ey_mean", "ey_median", "ey_std",
                    "eu_mean", "eu_rmse", "eh_median", "eh_rmse", "along_mean", "jitter_rms",
                    *CONSISTENCY_COLUMNS])
    by["oracle"] = by["technique"].isin(ORACLE_TECHNIQUES)   # truth-fed: not a result
    atomic_write(out / "by_cell.csv", lambda p: by.to_csv(p, index=False))
    # wall times depend on the machine and its load: kept out of the tracked tables, in a
    # git-ignored sidecar beside them
    tcols = [c for c in ("t_noise_s", "t_track_s", "t_score_s", "t_cell_s", "t_reused_s")
             if c in cells]
    if tcols:
        tim = aggregate(cells, [a for a in axes if a in cells.columns], tcols)
        atomic_write(out / "timings.local.csv", lambda p: tim.to_csv(p, index=False))
    md += [("All cells, aggregated over seeds: `by_cell.csv`; one row per cell x mask: "
           "`cells.parquet`."), ""]
    path = out / "tables.md"
    atomic_write_text(path, "\n".join(md))
    return path
