"""Figures of a sweep, drawn from its saved files only (re-plotting never re-simulates).

``python -m experiments.figures results/thesis`` redraws every figure of a results folder
from ``cells.parquet``, the table CSVs and the per-epoch files in ``epochs/``. The figures
follow the GPS dissertation (000_8f82f8df647bf685.txt):

- ``fig_weights_<path>.png``: box plots of |x| and |y| CG error per window and weighting
  (none / random / Huff), Figs 4.114-4.117 (panel a all windows, panel b windows <= 10);
- ``fig_4_118_orientation.png``: heading against time per window, Fig 4.118;
- ``fig_4_119_orientation_box.png``: heading error per window, Fig 4.119;
- ``fig_4_120_121_lag_correction.png``: none vs LC, full path and no turns, Figs 4.120/4.121;
- ``fig_4_122_dynamic.png``: static vs dynamic window (Huff), Fig 4.122;
- ``fig_4_123_lc_dyn.png``: none / LC / Dyn / LC + Dyn (Huff), Fig 4.123;
- ``fig_beyond.png``: the dissertation's techniques beside the beyond-the-thesis trackers;
- ``fig_oracle_lag_heading.png``: the lag correction with the estimated heading beside the
  ORACLE rows fed the simulator's heading (hatched; diagnostics, not estimator results);
- ``fig_4_34_49_overlay_square100.png`` (Path 2: ``4_54_69``; Huff weights: ``4_74_89``,
  ``4_94_109``): every sensor's observed, fitted and true track with the CG estimate, a row
  per window, Figs 4.34-4.49, 4.54-4.69, 4.74-4.89, 4.94-4.109 (other paths:
  ``fig_overlay_<path>[_huff].png``);
- ``fig_4_50_53_sensor1_lag_square100.png`` (``4_70_73``; Huff ``4_90_93``, ``4_110_113``):
  sensor 1 x and y against time at windows 10 and 100, the steepest rise and fall
  magnified, Figs 4.50-4.53, 4.70-4.73, 4.90-4.93, 4.110-4.113 (the lag; with Huff weights
  beside the lag-corrected estimate; other paths: ``fig_sensor1_lag_<path>[_huff].png``);
- ``fig_tables.png``: Tables 4.1/4.2 as a chart, ours (mean and 95 % interval over seeds)
  beside the published values.

The rows of the overlay and lag figures (sensor tiles, time series) are drawn by
:mod:`experiments.track_panels`. Box plots pool the per-epoch errors of the seeds whose
per-epoch files the spec kept (the dissertation's box plots are one run); the seeds are
named in each title.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd

from experiments.png import save_png
from experiments.techniques import ORACLE_TECHNIQUES, REGISTRY, plugins_in_results
from experiments.track_panels import lag_row, legend, overlay_row

__all__ = ["draw_all", "draw_task", "figure_tasks", "load_epochs", "main"]

PATH_LABELS = {"square100": "Path 1", "square200": "Path 2"}
WEIGHT_COLORS = {"none": "#1f77b4", "random": "#7f7f7f", "huff": "#d62728"}
WEIGHT_LABELS = {"none": "no", "random": "random", "huff": "Huff"}
#: Each technique's colour, short label and oracle flag come from its registry entry
#: (experiments.techniques.REGISTRY): figures never re-spell technique names.
TECH_COLORS = {t.name: t.color for t in REGISTRY}
TECH_LABELS = {t.name: t.short or t.name for t in REGISTRY}
#: Oracle techniques: drawn hatched, labelled ORACLE.
ORACLES = ORACLE_TECHNIQUES


class _EpochColumns:
    """The columns of one per-epoch file, each read on first use (``ep[name]``: a float
    array (n,), flags 0/1 with NaN where unknown; ``ep.columns``, the names): a figure draws
    a few of its ~70 columns, so reading only those is what makes loading cheap."""

    def __init__(self, path: Path):
        import pyarrow.parquet as pq

        self._file = pq.ParquetFile(path)
        self.columns = list(self._file.schema_arrow.names)
        self._cols: dict[str, np.ndarray] = {}

    def prefetch(self, names: list[str]) -> None:
        """Read the unread ones of the columns ``names`` that exist, in one read."""
        todo = [n for n in names if n in self.columns and n not in self._cols]
        if todo:
            tab = self._file.read(columns=todo)
            self._cols.update({n: _as_array(tab.column(n)) for n in todo})

    def __getitem__(self, name: str) -> np.ndarray:
        if name not in self._cols:
            if name not in self.columns:
                raise KeyError(name)
            self.prefetch([name])
        return self._cols[name]


def _as_array(col) -> np.ndarray:
    """A pyarrow column as a numpy array: numbers and flags as float (null: NaN; pandas
    Series cost more than the drawing of them), anything else as pandas makes it."""
    import pyarrow as pa

    t = col.type
    if pa.types.is_boolean(t) or pa.types.is_integer(t) or pa.types.is_floating(t):
        return col.cast(pa.float64()).to_numpy()
    return col.to_pandas().to_numpy()


#: (per-epoch file, size, mtime) -> its columns read so far: the figure groups a worker
#: draws share one reading of each file (cleared when another results folder is drawn).
_FILE_CACHE: dict[tuple, _EpochColumns] = {}


def _epoch_file(path: Path) -> _EpochColumns:
    st = path.stat()
    key = (str(path.resolve()), st.st_size, st.st_mtime_ns)
    if key not in _FILE_CACHE:
        folder = str(path.resolve().parent)
        if any(k[0].rsplit("/", 1)[0] != folder for k in _FILE_CACHE):
            _FILE_CACHE.clear()
        _FILE_CACHE[key] = _EpochColumns(path)
    return _FILE_CACHE[key]


#: (cells.parquet path, size, mtime) -> (variant, index): the figure groups a worker draws
#: share one reading of the cell table.
_INDEX_CACHE: dict[tuple, tuple[str, pd.DataFrame]] = {}


def _epoch_index(cells_file: Path) -> tuple[str, pd.DataFrame]:
    """The cells with per-epoch files (one row each) of the figures' variant."""
    from experiments.tables import faithful, numpy_strings, variants

    st = cells_file.stat()
    key = (str(cells_file.resolve()), st.st_size, st.st_mtime_ns)
    if key not in _INDEX_CACHE:
        cells = numpy_strings(pd.read_parquet(cells_file))  # no Arrow strings: faster selects
        # several variants (e.g. two configurations): the figures show the first one; of a
        # dynamic window run under several growth rules, the faithful one (tables.faithful)
        variant, cells = variants(cells)[0]
        cells = faithful(cells)
        idx = cells[cells["has_epochs"]] if "has_epochs" in cells else cells.iloc[:0]
        _INDEX_CACHE.clear()
        _INDEX_CACHE[key] = (variant, idx.drop_duplicates("key").reset_index(drop=True))
    return _INDEX_CACHE[key]


class _Epochs:
    """Index of a results folder's per-epoch files, loaded lazily."""

    def __init__(self, out: Path):
        self.out = Path(out)
        self.variant, self.index = _epoch_index(self.out / "cells.parquet")
        self._cache: dict[str, _EpochColumns] = {}
        self._np: dict[str, np.ndarray] = {}

    def straights_mask(self) -> str:
        """The no-turns mask of the per-epoch files: whole window free of turns where they
        record it (estimator.metrics.evaluation_masks), else the epochs not turning."""
        if not self.index.empty and "no_turns_window" in self.load(
                self.index["key"].iloc[0]).columns:
            return "no_turns_window"
        return "no_turns"

    def find(self, **where) -> pd.DataFrame:
        """The index rows whose column ``k`` is ``v`` (a list or tuple: any of) for every
        ``k=v`` of ``where``."""
        mk = np.ones(len(self.index), dtype=bool)
        for k, v in where.items():
            if k not in self._np:                 # numpy columns: a figure asks ~100 times
                self._np[k] = self.index[k].to_numpy()
            col = self._np[k]
            mk &= np.isin(col, list(v)) if isinstance(v, (list, tuple)) else (col == v)
        return self.index.iloc[np.flatnonzero(mk)]

    def load(self, key: str) -> _EpochColumns:
        """The per-epoch table of cell ``key`` (its columns read on first use)."""
        if key not in self._cache:
            self._cache[key] = _epoch_file(self.out / "epochs" / f"{key}.parquet")
        return self._cache[key]

    def loaded(self) -> list[str]:
        """Keys of the per-epoch files read so far (a figure's inputs)."""
        return sorted(self._cache)

    def pooled(self, column: str, mask: str = "full", **where) -> tuple[np.ndarray, list[int]]:
        """Concatenated |column| over the matching cells' epochs (all saved seeds)."""
        rows = self.find(**where)
        vals, seeds = [], []
        for r in rows[["key", "seed"]].to_dict("records"):
            ep = self.load(r["key"])
            ep.prefetch([column, "truth_turning", "no_turns_window"])
            v = np.abs(ep[column])
            if mask == "no_turns":
                v = v[~_flag(ep["truth_turning"], True)]
            elif mask == "no_turns_window":
                v = v[_flag(ep["no_turns_window"], False)]
            vals.append(v[np.isfinite(v)])
            seeds.append(int(r["seed"]))
        return (np.concatenate(vals) if vals else np.array([])), sorted(set(seeds))


def _flag(col: pd.Series | np.ndarray, missing: bool) -> np.ndarray:
    """A per-epoch flag column (a Series, or floats 0/1 with NaN) as bool (n,), ``missing``
    where it is unknown (a gappy reference: NaN or NA rows; a NaN would otherwise count as
    True)."""
    if isinstance(col, np.ndarray) and col.dtype.kind == "f":
        return np.where(np.isnan(col), missing, col != 0)
    return pd.Series(col).astype("boolean").fillna(missing).to_numpy(dtype=bool)


def load_epochs(out_dir: str | Path, key: str) -> pd.DataFrame:
    """The per-epoch table of one cell (estimates, truth, errors, observations)."""
    return pd.read_parquet(Path(out_dir) / "epochs" / f"{key}.parquet")


def _seeds_txt(seeds: list[int]) -> str:
    if not seeds:
        return ""
    return f"seed {seeds[0]}" if len(seeds) == 1 else f"seeds {seeds[0]}-{seeds[-1]} pooled"


def _boxes(ax, groups: list[tuple[str, np.ndarray, str]], ylabel: str) -> None:
    """Box plots of ``groups`` (label, values, colour) at x = 1, 2, ...: matplotlib's
    statistics (``cbook.boxplot_stats``, whiskers at 1.5 IQR) drawn as a few collections
    (boxes, whiskers and caps, medians, one line of fliers) instead of seven artists per box
    (``ax.boxplot``), the same picture at a fraction of the cost; an empty group is a gap."""
    from matplotlib.cbook import boxplot_stats
    from matplotlib.collections import LineCollection, PolyCollection
    from matplotlib.colors import to_rgba

    boxes: dict[bool, list] = {False: [], True: []}
    faces: dict[bool, list] = {False: [], True: []}
    whisk, meds, fx, fy = [], [], [], []
    for i, (label, v, color) in enumerate(groups, start=1):
        if not v.size:
            continue
        st = boxplot_stats(v)[0]
        lo, hi, q1, q3 = st["whislo"], st["whishi"], st["q1"], st["q3"]
        oracle = "ORACLE" in label   # truth-fed diagnostics: hatched, never taken for a result
        boxes[oracle].append([(i - 0.3, q1), (i + 0.3, q1), (i + 0.3, q3), (i - 0.3, q3)])
        faces[oracle].append(to_rgba(color, 0.55))
        whisk += [[(i, q1), (i, lo)], [(i, q3), (i, hi)], [(i - 0.15, lo), (i + 0.15, lo)],
                  [(i - 0.15, hi), (i + 0.15, hi)]]
        meds.append([(i - 0.3, st["med"]), (i + 0.3, st["med"])])
        fx.append(np.full(st["fliers"].size, float(i)))
        fy.append(st["fliers"])
    for oracle, verts in boxes.items():
        if verts:
            ax.add_collection(PolyCollection(
                verts, facecolors=faces[oracle], linewidths=1, hatch="///" if oracle else None,
                edgecolors=to_rgba("#d62728" if oracle else "k", 0.55), zorder=2))
    ax.add_collection(LineCollection(whisk, colors="k", linewidths=1, zorder=2))
    ax.add_collection(LineCollection(meds, colors="C1", linewidths=1, zorder=2.1))
    if fx:
        ax.plot(np.concatenate(fx), np.concatenate(fy), ls="none", marker=".", ms=2, mfc="none",
                mec="k", alpha=0.4)
    ax.set_xlim(0.5, len(groups) + 0.5)
    ax.set_xticks(range(1, len(groups) + 1), [g[0] for g in groups], fontsize=8)
    ax.set_ylabel(ylabel)
    ax.grid(axis="y", alpha=0.3)


_PLT = None


def _pyplot():
    """matplotlib.pyplot, switched to the Agg backend once, at the first figure (as an
    import of this module did before): a sweep's main process imports this module for the
    names of its figure groups and draws nothing (matplotlib costs ~0.3 s to import)."""
    global _PLT
    if _PLT is None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        _PLT = plt
    return _PLT


def _subplots(rows: int, cols: int, figsize: tuple[float, float], *, left: float = 0.75,
              right: float = 0.15, bottom: float = 0.5, top: float = 0.6, hgap: float = 0.75,
              wgap: float = 0.75, **kw):
    """plt.subplots (``squeeze=False``) with fixed margins in inches around the axes
    (``left`` ... ``top``) and between them (``hgap``, ``wgap``): no layout engine, whose
    measuring of every tick label was up to half of a figure's drawing time. A layout made
    before in this figure group comes back wiped (:func:`_pooled`)."""
    def make():
        w, h = figsize
        fig, axes = _pyplot().subplots(rows, cols, squeeze=False, figsize=figsize, **kw)
        aw = (w - left - right - (cols - 1) * wgap) / cols
        ah = (h - top - bottom - (rows - 1) * hgap) / rows
        fig.subplots_adjust(left=left / w, right=1 - right / w, bottom=bottom / h,
                            top=1 - top / h, wspace=wgap / aw, hspace=hgap / ah)
        return fig, axes

    return _pooled(("subplots", rows, cols, tuple(figsize), left, right, bottom, top, hgap,
                    wgap, tuple(sorted(kw.items()))), make)


def _text_inches(text: str, size: float) -> float:
    """Width (inches) of ``text`` at ``size`` points, as the Agg renderer draws it."""
    from matplotlib.backends.backend_agg import RendererAgg
    from matplotlib.font_manager import FontProperties

    return RendererAgg(1, 1, 72).get_text_width_height_descent(
        text, FontProperties(size=size), False)[0] / 72


def _save(fig, path: Path, written: list[Path]) -> None:
    save_png(fig, path, dpi=100)
    written.append(path)


def _weighting_figs(E: _Epochs, out: Path, written: list[Path]) -> None:
    for path in sorted(E.index["path"].unique()):
        sub = E.find(path=path, technique="none")
        weights = [w for w in ("none", "random", "huff") if w in set(sub["weighting"])]
        windows = sorted(sub["window"].unique())
        if not weights or not windows:
            continue
        small = [w for w in windows if w <= 10]
        fig, axes = _subplots(2, 2 if small and len(small) < len(windows) else 1, (13, 8))
        seeds_all: list[int] = []
        for r, axis in enumerate(("x", "y")):
            for c, wins in enumerate([windows, small][:axes.shape[1]]):
                groups = []
                for w in wins:
                    for wt in weights:
                        v, s = E.pooled(f"err_{axis}", path=path, technique="none", window=w,
                                        weighting=wt)
                        seeds_all += s
                        groups.append((f"w={w}\n{wt}", v, WEIGHT_COLORS.get(wt, "C0")))
                _boxes(axes[r, c], groups, f"|{axis}| CG error (m)")
                axes[r, c].set_title(f"({'ab'[c]}) |{axis}|, windows "
                                     f"{wins[0]}-{wins[-1]}: no / random / Huff weights",
                                     fontsize=10)
        fig.suptitle(f"{PATH_LABELS.get(path, path)} ({path}): CG error by window and weighting "
                     f"(Figs 4.114-4.117), {_seeds_txt(sorted(set(seeds_all)))}")
        _save(fig, out / f"fig_weights_{path}.png", written)


def _path1(E: _Epochs) -> str | None:
    ps = list(E.index["path"].unique())
    return "square100" if "square100" in ps else (ps[0] if ps else None)


def _pick(E: _Epochs, **where) -> pd.Series | None:
    rows = E.find(**where)
    if rows.empty:
        return None
    return rows.sort_values("seed").iloc[0]


def _break_wraps(deg: np.ndarray) -> np.ndarray:
    """NaN where a heading wraps across +/-180 deg, so the line breaks instead of jumping."""
    d = np.asarray(deg, dtype=float).copy()
    jump = np.abs(np.diff(d)) > 180
    d[1:][jump] = np.nan
    return d


def _orientation_figs(E: _Epochs, out: Path, written: list[Path]) -> None:
    path = _path1(E)
    if path is None:
        return
    wt = "none" if not E.find(path=path, technique="none", weighting="none").empty else "huff"
    windows = sorted(E.find(path=path, technique="none", weighting=wt)["window"].unique())
    if not windows:
        return
    # the labels beside each row (x = 1.005 of the axes) on the right, one title per row
    fig, axes = _subplots(len(windows), 1, (12, 2.4 * len(windows)), sharex=True, right=1.0,
                          bottom=0.55, top=0.65, hgap=0.3)
    for ax, w in zip(axes[:, 0], windows):
        r = _pick(E, path=path, technique="none", weighting=wt, window=w)
        ep = E.load(r["key"])
        ax.plot(ep["t"], _break_wraps(np.degrees(ep["truth_yaw"])), color="k", lw=1.5)
        ax.plot(ep["t"], _break_wraps(np.degrees(ep["yaw"])), color="C3", lw=0.8, alpha=0.8)
        ax.text(1.005, 0.75, "truth", color="k", transform=ax.transAxes, fontsize=9)
        ax.text(1.005, 0.45, f"estimate\nw={w}", color="C3", transform=ax.transAxes, fontsize=9)
        ax.set_ylabel("heading (deg)")
        ax.set_ylim(-190, 190)
        ax.set_yticks([-180, -90, 0, 90, 180])
        ax.grid(alpha=0.3)
        ax.set_title(f"window {w}", fontsize=9, loc="left")
    axes[-1, 0].set_xlabel("time (s)")
    fig.suptitle(f"{PATH_LABELS.get(path, path)}: orientation against time (Fig 4.118), "
                 f"{WEIGHT_LABELS.get(wt, wt)} weights, seed {int(r['seed'])}")
    _save(fig, out / "fig_4_118_orientation.png", written)

    fig, axes = _subplots(1, 1, (8, 4.5), bottom=0.35, top=0.35)
    ax = axes[0, 0]
    groups, seeds = [], []
    for w in windows:
        v, s = E.pooled("err_yaw", path=path, technique="none", weighting=wt, window=w)
        seeds += s
        groups.append((f"w={w}", np.degrees(v), "C0"))
    _boxes(ax, groups, "|heading error| (deg)")
    ax.set_title(f"{PATH_LABELS.get(path, path)}: orientation error per window (Fig 4.119), "
                 f"{WEIGHT_LABELS.get(wt, wt)} weights, {_seeds_txt(sorted(set(seeds)))}",
                 fontsize=10)
    _save(fig, out / "fig_4_119_orientation_box.png", written)


def _tech_style(tech: str, plugins: dict) -> tuple[str, str]:
    """(short label, colour) of a technique: its registry entry's, or its plug-in entry's
    (experiments.techniques.plugin_entries: the spec's label and colour or the palette's)."""
    if tech in TECH_LABELS:
        return TECH_LABELS[tech], TECH_COLORS[tech]
    return plugins[tech].short, plugins[tech].color


def _technique_fig(E: _Epochs, out: Path, written: list[Path], name: str, title: str,
                   techs: list[str], masks: list[str], plugins: dict | None = None) -> None:
    path = _path1(E)
    if path is None:
        return
    wt = "huff" if not E.find(path=path, technique=techs[1:], weighting="huff").empty else "none"
    present = [t for t in techs if not E.find(path=path, technique=t).empty]
    if len(present) < 2:
        return
    windows = sorted(w for w in E.find(path=path, technique=present[1:])["window"].unique()
                     if w > 1)
    if not windows:
        return
    # (window, technique) pairs the sweep ran (e.g. an oracle only at window 100)
    pairs = [(w, t) for w in windows for t in present
             if not E.find(path=path, technique=t, window=w, weighting=[wt, "-"]).empty]
    width = max(6.5, 0.6 * len(pairs))
    oracle = any(t in ORACLES for t in present)     # a second line in the title
    lines = 2 + max(_tech_style(t, plugins or {})[0].count("\n") for _, t in pairs)
    fig, axes = _subplots(2, len(masks), (width * len(masks) + 1.5, 8), bottom=0.2 + 0.15 * lines,
                          hgap=0.5 + 0.15 * lines, top=0.85 if oracle else 0.6)
    seeds: list[int] = []
    for r, axis in enumerate(("x", "y")):
        for c, mask in enumerate(masks):
            groups = []
            for w, t in pairs:
                v, s = E.pooled(f"err_{axis}", mask=mask, path=path, technique=t, window=w,
                                weighting=[wt, "-"])
                seeds += s
                label, color = _tech_style(t, plugins or {})
                groups.append((f"w={w}\n{label}", v, color))
            _boxes(axes[r, c], groups, f"|{axis}| CG error (m)")
            where = {"full": "full path", "no_turns": "no turns (epochs not turning)",
                     "no_turns_window": "no turns (no turning epoch in the window)"}[mask]
            axes[r, c].set_title(f"|{axis}|, {where}", fontsize=10)
    fig.suptitle(f"{PATH_LABELS.get(path, path)}: {title}, {WEIGHT_LABELS.get(wt, wt)} weights, "
                 f"{_seeds_txt(sorted(set(seeds)))}"
                 + ("\nhatched ORACLE boxes use the simulator's heading: diagnostics, not "
                    "estimator results" if oracle else ""))
    _save(fig, out / name, written)


#: The dissertation's numbers of the all-sensor overlays and the sensor-1 lag figures per
#: (family, path, weighting), Sections 4.10 (no weights) and 4.11 (Huff): "4_34_49" stands
#: for Figs 4.34-4.49. Other paths are drawn alike, named by path ("as" the Path 1 numbers).
FIG_NUMBERS = {
    ("overlay", "square100", "none"): "4_34_49", ("overlay", "square200", "none"): "4_54_69",
    ("overlay", "square100", "huff"): "4_74_89", ("overlay", "square200", "huff"): "4_94_109",
    ("sensor1_lag", "square100", "none"): "4_50_53",
    ("sensor1_lag", "square200", "none"): "4_70_73",
    ("sensor1_lag", "square100", "huff"): "4_90_93",
    ("sensor1_lag", "square200", "huff"): "4_110_113"}


def _families(E: _Epochs, family: str):
    """(path, weighting, rows, file name, "Figs ..." text) per path and weighting (no /
    Huff) whose technique-"none" cells kept per-epoch files; rows: the first seed's cell
    of each window, ascending."""
    for path in sorted(E.index["path"].unique()):
        for wt in ("none", "huff"):
            sub = E.find(path=path, technique="none", weighting=wt)
            if sub.empty:
                continue
            rows = [_pick(E, path=path, technique="none", weighting=wt, window=w)
                    for w in sorted(sub["window"].unique())]
            nums = FIG_NUMBERS.get((family, path, wt))
            a, b, c = (nums or FIG_NUMBERS[(family, "square100", wt)]).split("_")
            name = (f"fig_{nums}_{family}_{path}.png" if nums else
                    f"fig_{family}_{path}{'' if wt == 'none' else '_' + wt}.png")
            yield path, wt, rows, name, f"{'' if nums else 'as '}Figs {a}.{b}-{a}.{c}"


#: The figures of the figure group being drawn, by layout (:func:`_pooled`); emptied
#: (and the figures closed) when the group is done.
_POOL: dict[tuple, tuple] = {}


def _pooled(key: tuple, make: Callable[[], tuple]) -> tuple:
    """(fig, axes) of layout ``key``: made by ``make`` the first time in a figure group,
    then the same figure wiped (:func:`_wipe`). A group draws several PNGs of one layout
    (the lag and overlay figures per path and weighting, the weighting boxes per path) and
    making the axes and their ticks was ~40 % of drawing the lag figures; the PNGs are the
    same byte for byte (tested)."""
    if key in _POOL:
        return _wipe(*_POOL[key])
    _POOL[key] = make()
    return _POOL[key]


def _grid(rows: int, cols: int, width: float, row_h: float, *, width_ratios=None, **adjust):
    """A figure of rows x cols axes, ``row_h`` inches per row (``width`` inches wide), with
    fixed margins: 1.05 in above (title, legend), 0.5 in below (labels); no layout engine
    (one layout pass less per figure); pooled like :func:`_subplots`."""
    def make():
        h = rows * row_h + 1.55
        fig, axes = _pyplot().subplots(rows, cols, squeeze=False, figsize=(width, h),
                                       width_ratios=width_ratios)
        fig.subplots_adjust(bottom=0.5 / h, top=1 - 1.05 / h, **adjust)
        return fig, axes

    return _pooled(("grid", rows, cols, width, row_h, tuple(width_ratios or ()),
                    tuple(sorted(adjust.items()))), make)


def _wipe(fig, axes):
    """``fig`` and its ``axes`` as :func:`_grid` made them, their ticks kept: every line,
    text, collection, patch, title, axis label, legend and the suptitle removed, the data
    limits forgotten and autoscaling on again."""
    for ax in axes.flat:
        for a in (*ax.lines, *ax.texts, *ax.collections, *ax.patches, *ax.images):
            a.remove()
        ax.containers.clear()
        for loc in ("left", "center", "right"):
            ax.set_title("", loc=loc)
        ax.set(xlabel="", ylabel="")
        ax.relim()
        ax.autoscale(True)
    for leg in list(fig.legends):
        leg.remove()
    if fig._suptitle is not None:
        fig._suptitle.remove()
        fig._suptitle = None
    return fig, axes


def _overlay_figs(E: _Epochs, out: Path, written: list[Path]) -> None:
    """Every sensor's observed, fitted and true track with the CG estimate, one row per
    window and one tile per sensor: Figs 4.34-4.49 / 4.54-4.69 (no weights, Section 4.10)
    and 4.74-4.89 / 4.94-4.109 (Huff, 4.11), one PNG per path and weighting; each tile
    names the RMS distance (m) of the observations and of the fit to the sensor's truth."""
    for path, wt, rows, name, figs in _families(E, "overlay"):
        sensors = [c[2:] for c in E.load(rows[0]["key"]).columns if c.startswith("x_")]
        fig, axes = _grid(len(rows), 1, max(9.0, 1.9 * len(sensors) + 0.7), 1.9, left=0.05,
                          right=0.995, hspace=0.2)
        for i, (ax, r) in enumerate(zip(axes[:, 0], rows)):
            overlay_row(ax, E.load(r["key"]), sensors, i == 0)
            ax.set_ylabel(f"window {int(r['window'])}\ny north (m)", fontsize=8)
        axes[-1, 0].set_xlabel("x east (m), per sensor", fontsize=8)
        legend(fig)
        fig.suptitle(f"{PATH_LABELS.get(path, path)} ({path}): every sensor observed, fitted "
                     f"and true, {WEIGHT_LABELS.get(wt, wt)} weights, seed {int(rows[0]['seed'])}"
                     f" ({figs});\nmid-tile: RMS distance (m) to the sensor's truth of the "
                     "observations / of the fit (none: no observations)", x=0.01, ha="left",
                     fontsize=10)
        _save(fig, out / name, written)


def _sensor1_lag_figs(E: _Epochs, out: Path, written: list[Path]) -> None:
    """Sensor 1's x and y against time at windows 10 and 100, rows x/y per window, columns
    (a) the whole run, (b) positive, (c) negative slope magnified: Figs 4.50-4.53 /
    4.70-4.73 (no weights) and 4.90-4.93 / 4.110-4.113 (Huff), one PNG per path and
    weighting, without lag correction as there; where the sweep ran the lag correction
    with these weights its estimate is drawn beside (dashed): what Section 4.12 removes."""
    for path, wt, rows, name, figs in _families(E, "sensor1_lag"):
        by_w = {int(r["window"]): r for r in rows}
        wins = [w for w in (10, 100) if w in by_w] or sorted(by_w)[-2:]
        s1 = _sensor1(E.load(by_w[wins[0]]["key"]))
        fig, axes = _grid(2 * len(wins), 3, 14, 2.2, left=0.06, right=0.99, wspace=0.15,
                          hspace=0.45, width_ratios=[2, 1, 1])
        any_lc = False
        for i, (w, axis) in enumerate((w, a) for w in wins for a in ("x", "y")):
            lc = _pick(E, path=path, technique="lc", weighting=wt, window=w)
            any_lc |= lc is not None
            lag_row(axes[i], E.load(by_w[w]["key"]), None if lc is None else E.load(lc["key"]),
                    s1, axis)
            axes[i, 0].set_ylabel(f"sensor {s1} {axis} (m)", fontsize=8)
            for c, what in enumerate((f"window {w}: sensor {s1} {axis} against time",
                                      "positive slope magnified", "negative slope magnified")):
                axes[i, c].set_title(f"({'abc'[c]}) {what}", fontsize=9, loc="left")
        for ax in axes[-1]:
            ax.set_xlabel("time (s)", fontsize=8)
        legend(fig, lc=any_lc)
        fig.suptitle(f"{PATH_LABELS.get(path, path)} ({path}): sensor {s1} against time, "
                     f"{WEIGHT_LABELS.get(wt, wt)} weights, windows {' and '.join(map(str, wins))},"
                     f" seed {int(rows[0]['seed'])} ({figs}): the estimate trails the truth "
                     "(lag)\nx east, y north (the dissertation's X is north)", x=0.01,
                     ha="left", fontsize=10)
        _save(fig, out / name, written)


def _sensor1(ep: _EpochColumns) -> str:
    names = [c[2:] for c in ep.columns if c.startswith("x_")]
    return "1" if "1" in names else names[0]


def _tables_fig(out: Path, written: list[Path]) -> None:
    """Tables 4.1/4.2 as a dot chart: one horizontal row per (window, technique) with its
    label written out level, |x| and |y| side by side on a shared row axis, windows
    separated by bands; ours (mean over seeds, 95 % CI) and the published value."""
    files = [(ax, out / f"table_4_{n}.csv") for ax, n in (("x", 1), ("y", 2))]
    if not all(f.exists() for _, f in files):
        return
    from matplotlib.lines import Line2D
    from matplotlib.ticker import FormatStrFormatter, LogLocator

    tabs = {}
    for axis, f in files:
        df = pd.read_csv(f, keep_default_na=False, na_values=[""])   # "None" is a row label
        df = df[df["window"] > 1].drop_duplicates(["window", "technique"])
        tabs[axis] = df.set_index(["window", "technique"])
    rows = list(dict.fromkeys([*tabs["x"].index, *tabs["y"].index]))
    if not rows:
        return
    n = len(rows)
    ys = np.arange(n)[::-1]                  # first row at the top
    oracle_any = any(("kind" in t and (t["kind"] == "oracle").any()) for t in tabs.values())
    n_leg = 1 + oracle_any                   # legend rows (two entries each with the oracle)
    # left: the row labels, 70 pt (0.97 in) left of the axes, the window names between
    left = 1.3 + _text_inches(max((f"{t}   " for _, t in rows), key=len), 10)
    fig, axes = _subplots(1, 2, (13, 1.35 + 0.3 * n + 0.25 * n_leg), sharey=True, left=left,
                          right=0.25, bottom=0.6 + 0.25 * n_leg, top=0.85, wgap=0.2)
    axes = axes[0]
    for ax_plot, axis in zip(axes, ("x", "y")):
        df = tabs[axis].reindex(rows)
        m = df["mean"].to_numpy(float)
        err = np.vstack([m - df["mean_lo"].to_numpy(float), df["mean_hi"].to_numpy(float) - m])
        err = np.where(np.isfinite(err), err, 0)
        thesis = df["thesis_row"].fillna(False).astype(bool).to_numpy()
        # oracle rows (simulator heading fed to the lag correction): diagnostics, drawn apart
        oracle = (df["kind"] == "oracle").fillna(False).to_numpy(bool) if "kind" in df \
            else np.zeros(n, bool)
        for sel, color, fmt in ((thesis & ~oracle, "C0", "o"), (~thesis & ~oracle, "#7f7f7f", "o"),
                                (oracle, "C1", "s")):
            ax_plot.errorbar(m[sel], ys[sel], xerr=err[:, sel], fmt=fmt, color=color, ms=5,
                             mfc="none" if fmt == "s" else color, capsize=3, lw=1.4)
        for y in ys[oracle]:
            ax_plot.axhspan(y - 0.5, y + 0.5, color="C1", alpha=0.08, lw=0, zorder=0)
        ax_plot.plot(df["mean_thesis"], ys, "x", color="C3", ms=9, mew=2.2)
        wins = [w for w, _ in rows]
        for k, w in enumerate(dict.fromkeys(wins)):
            idx = [i for i, ww in enumerate(wins) if ww == w]
            if k % 2 == 0:
                ax_plot.axhspan(ys[idx[-1]] - 0.5, ys[idx[0]] + 0.5, color="#eef1f4", zorder=0)
            if axis == "x":
                ax_plot.text(-0.005, ys[idx[0]] + 0.45, f"window {w}", ha="right", va="top",
                             transform=ax_plot.get_yaxis_transform(), fontsize=10,
                             fontweight="bold")
        ax_plot.set_xscale("log")
        ax_plot.xaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
        ax_plot.xaxis.set_major_formatter(FormatStrFormatter("%g"))
        ax_plot.xaxis.set_minor_formatter(FormatStrFormatter(""))
        ax_plot.grid(axis="x", alpha=0.35, which="both")
        ax_plot.set_xlabel(f"mean |{axis}| CG error (m, log scale)")
        ax_plot.set_ylim(-0.6, n - 0.4)
        w_label = df["weighting"].dropna().iloc[0] if df["weighting"].notna().any() else ""
        ax_plot.set_title(f"Table 4.{1 if axis == 'x' else 2}: |{axis}| error, {w_label} weights",
                          fontsize=11)
    axes[0].set_yticks(ys, [f"{t}   " for _, t in rows], fontsize=10)
    axes[0].tick_params(axis="y", length=0, pad=70)
    handles = [Line2D([], [], color="C0", marker="o", ls="-", label="ours, dissertation row "
                      "(mean over seeds, 95 % CI)"),
               Line2D([], [], color="#7f7f7f", marker="o", ls="-", label="ours, beyond the "
                      "dissertation"),
               Line2D([], [], color="C3", marker="x", ls="none", ms=9, mew=2.2,
                      label="dissertation (one run)")]
    if oracle_any:
        handles.append(Line2D([], [], color="C1", marker="s", mfc="none", ls="-",
                              label="ORACLE (simulator heading): a diagnostic, not a result"))
    fig.legend(handles=handles, loc="lower center", ncol=2 if n_leg == 2 else 3, fontsize=10,
               frameon=False, bbox_to_anchor=(0.5, 0.05 / fig.get_figheight()))
    fig.suptitle("Tables 4.1/4.2 as a chart: Path 1, our mean over seeds beside the published "
                 "value")
    _save(fig, out / "fig_tables.png", written)


_TASKS = ("weighting", "orientation", "lag_correction", "dynamic", "lc_dyn", "beyond",
          "overlay", "sensor1", "tables", "oracle")


def _draw(out: Path, task: str) -> list[Path]:
    """One group of figures (a task of :func:`draw_all`)."""
    return draw_task(out, task)[0]


#: Matplotlib settings of every figure. ``axes.titley = 1.0`` places each title where the
#: automatic placement puts it on these axes (nothing drawn above them: the PNGs are the
#: same pixel for pixel), without measuring the top tick labels at every layout pass and
#: draw, ~10 % of the drawing time.
_RC = {"axes.titley": 1.0}


def draw_task(out_dir: str | Path, task: str) -> tuple[list[Path], list[str]]:
    """Draw one group of figures (:func:`figure_tasks`) of a results folder; returns the
    files written and the keys of the per-epoch files read (the group's inputs besides
    cells.parquet; the "tables" group reads the table CSVs instead)."""
    plt = _pyplot()
    try:
        with plt.rc_context(_RC):
            return _draw_task(Path(out_dir), task)
    finally:
        for fig, _ in _POOL.values():
            plt.close(fig)
        _POOL.clear()


def _draw_task(out: Path, task: str) -> tuple[list[Path], list[str]]:
    written: list[Path] = []
    if task == "tables":
        _tables_fig(out, written)
        return written, []
    E = _Epochs(out)
    if E.index.empty:
        return written, []
    if task == "weighting":
        _weighting_figs(E, out, written)
    elif task == "orientation":
        _orientation_figs(E, out, written)
    elif task == "lag_correction":
        _technique_fig(E, out, written, "fig_4_120_121_lag_correction.png",
                       "lag correction on the full path and without turns (Figs 4.120/4.121)",
                       ["none", "lc"], ["full", E.straights_mask()])
    elif task == "oracle" and not E.find(technique=list(ORACLES)).empty:
        # (without an oracle row it would repeat the lag-correction figures)
        _technique_fig(E, out, written, "fig_oracle_lag_heading.png",
                       "lag correction with the estimated vs the simulator's heading (ORACLE)",
                       ["none", "lc", "lc_sim_heading", "lc+dyn", "lc_sim_heading+dyn"],
                       ["full", E.straights_mask()])
    elif task == "dynamic":
        _technique_fig(E, out, written, "fig_4_122_dynamic.png",
                       "static vs dynamic window (Fig 4.122)", ["none", "dyn"], ["full"])
    elif task == "lc_dyn":
        _technique_fig(E, out, written, "fig_4_123_lc_dyn.png",
                       "lag correction combined with the dynamic window (Fig 4.123)",
                       ["none", "lc", "dyn", "lc+dyn"], ["full"])
    elif task == "beyond":
        # the spec's plug-in trackers beside the built-in ones, in their own colours
        plugins = plugins_in_results(E.index["technique"], out)
        _technique_fig(E, out, written, "fig_beyond.png",
                       "the dissertation's techniques and the beyond-the-thesis trackers",
                       ["none", "lc+dyn", "lc_course+dyn", "motion_compensated", "ekf", "naive",
                        *plugins], ["full"], plugins)
    elif task == "overlay":
        _overlay_figs(E, out, written)
    elif task == "sensor1":
        _sensor1_lag_figs(E, out, written)
    return written, E.loaded()


def figure_tasks() -> tuple:
    """The figure groups :func:`draw_all` draws (one unit of progress each)."""
    return tuple(_TASKS)


def draw_all(out_dir: str | Path, jobs: int = 1,
             on_done: Callable[[list[Path]], object] | None = None) -> list[Path]:
    """Draw every figure whose data the results folder holds; returns the files written.

    jobs > 1 draws the figure groups in that many processes (joblib loky). ``on_done`` is
    called with each group's files as the group finishes (progress).
    """
    out = Path(out_dir)
    parts = []
    if jobs > 1:
        from joblib import Parallel, delayed

        it = Parallel(n_jobs=jobs, backend="loky", return_as="generator")(
            delayed(_draw)(out, t) for t in _TASKS)
    else:
        it = (_draw(out, t) for t in _TASKS)
    for part in it:
        parts.append(part)
        if on_done is not None:
            on_done(part)
    return [p for part in parts for p in part]


def main(argv: list[str] | None = None) -> int:
    from experiments.cli import ArgumentParser

    p = ArgumentParser(
        prog="python -m experiments.figures",
        description="Redraw the figures of a sweep results folder from its saved files "
                    "(no simulation). Example: python -m experiments.figures results/thesis")
    p.add_argument("results", help="results folder, e.g. results/thesis")
    args = p.parse_args(argv)
    out = Path(args.results)
    if not (out / "cells.parquet").exists():
        print(f"error: {out}/cells.parquet not found (run python -m experiments.sweep first)",
              file=sys.stderr)
        return 2
    files = draw_all(out)
    print(json.dumps([str(f) for f in files], indent=0))
    return 0


if __name__ == "__main__":
    from experiments.cli import run as run_cli

    run_cli(main)
