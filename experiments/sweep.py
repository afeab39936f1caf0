"""The main job: run an experiment spec as a reproducible, parallel, resumable sweep.

``python -m experiments.sweep`` regenerates the GPS dissertation's moving-platform
performance results (000_8f82f8df647bf685.txt, Sections 4.10-4.12, Tables 4.1 and 4.2) from
the ``thesis`` preset; any spec (see :mod:`experiments.spec`) runs the same way.

Pipeline per cell (one point of the grid, one seed):

1. truth: each distinct (path, configuration) is simulated ONCE, up front, before any cell
   (through the on-disk truth cache, :mod:`sim.cache`; with several paths and jobs > 1 the
   parent runs the simulations side by side in worker processes), then handed to the workers;
2. noise: a stationary GPS session of ``spec.session_s`` seconds (the dissertation's ~4000 s
   recording, Section 4.1.1) is synthesized for the cell's seed, cut after its power failure,
   and a random stretch of it replayed onto the truth: truth + (observation - that
   receiver's session mean), Section 4.1.2. Cells that share (truth, noise model, seed) share
   the observations (common random numbers: techniques are compared on identical data);
3. estimate: :func:`estimator.tracking.track` with the cell's window, weighting, technique
   and solver;
4. score: Eq. 4.1 / 4.2 errors per evaluation mask (full path, no turns), summarised.

A cell naming a ``recording`` (:mod:`sim.recording`) takes its observations from the
recording (or, for a recording with ``[replay]``, its reference plus the error replayed
for the cell's seed) instead of steps 1-2, and is scored against the recording's reference
with the same statistics; a recording without a reference gives coverage rows (epochs,
estimates, NaN estimates, status counts) only, and no per-epoch file (the figures drawn
from those need a reference; run ``track`` on the recording for its estimates). Every recording cell also records the
layout check of :func:`estimator.layout_check.check_layout` (mirror and forward-axis
verdicts, ``layout_*`` columns).

Randomness: every stream is a ``numpy.random.Generator`` seeded from
``SeedSequence([spec.seed, cell.seed, stream])``; the same spec and seed give bit-identical
numbers in any order, on any number of workers.

Persistence: each finished cell is written atomically as ``cells/<key>.json`` (temp file +
``os.replace``; per-epoch estimates, when asked for, go to ``epochs/<key>.parquet`` first)
by the worker that computed it the moment it finishes (Dask workers, which may not share
the file system, send it back and the parent writes it),
so a run killed at any moment (SIGKILL included) loses no finished cell and never duplicates
one; rerunning skips finished cells, ``--force`` recomputes. ``cells.parquet`` is assembled
from the cell files at the end. Errors inside a cell are recorded (``errors/<key>.json``,
with the cell's parameters and traceback) and reported; they do not stop the sweep and are
retried on the next run.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
import traceback
import uuid
import warnings
from collections import OrderedDict
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from estimator.memo import TrackCache, ledger
from estimator.track_options import FILTER_METHODS
from estimator.window import SOLVERS
from experiments import cli
from experiments.provenance import code_version
from experiments.techniques import technique
from experiments.spec import (
    REPO,
    RESULTS_ROOT,
    Cell,
    Spec,
    SpecError,
    available_presets,
    load_spec,
)
from sim.atomic import atomic_write, atomic_write_text

# pandas is imported where it is used: the main process simulates before it needs pandas
# (0.4 s of imports off the critical path of a one-path sweep)
if TYPE_CHECKING:
    import pandas as pd

__all__ = [
    "Results",
    "SweepError",
    "cell_rng",
    "code_version",
    "evaluate_cell",
    "filter_params_for",
    "main",
    "run",
    "simulate_truth",
]

RESULTS_DIR = RESULTS_ROOT
#: Runs whose default folder is results/<name>/: the committed reference runs and the quick
#: smoke run (ignored by .gitignore). Any other spec (the example presets, a spec file)
#: defaults to results/local/<name>/, which git ignores, so no run dirties the checkout.
TOP_LEVEL_RUNS = frozenset({"thesis", "thesis-elastic", "speed", "quick"})


def default_out(name: str) -> Path:
    """The results folder of a run named ``name`` without ``--out`` (see TOP_LEVEL_RUNS)."""
    return RESULTS_DIR / name if name in TOP_LEVEL_RUNS else RESULTS_DIR / "local" / name
#: Random streams derived per (spec seed, cell seed).
STREAM_NOISE, STREAM_ESTIMATOR = 0, 1

#: A cell function: (cell, truth, context) -> CellOutput. Pluggable for tests.
CellFn = Callable[[Cell, Any, "CellContext"], "CellOutput"]


class SweepError(RuntimeError):
    """A run cannot go on (unreachable scheduler, unwritable results folder); the message is
    one line that names the cause and what to do. The CLI prints it without a traceback."""


# --------------------------------------------------------------------------- records
@dataclass
class CellContext:
    """What a cell function gets besides its cell and truth."""

    spec_seed: int
    masks: tuple[str, ...]
    session_s: float
    want_epochs: bool
    memo: OrderedDict[tuple, Any]
    #: the trackers' memos (fits, Huff weights, filter passes) shared by the cells of a
    #: worker and run (estimator.memo.TrackCache); None: each cell computes everything
    cache: TrackCache | None = None


@dataclass
class CellOutput:
    """Result of one cell: one summary row per mask, optional per-epoch table, extras."""

    rows: list[dict]
    epochs: pd.DataFrame | None = None
    timings: dict = field(default_factory=dict)
    status_counts: dict = field(default_factory=dict)


@dataclass
class Results:
    """What :func:`run` returns (and writes to ``out_dir``)."""

    spec: Spec
    out_dir: Path
    cells: pd.DataFrame               # one row per cell x mask
    errors: list[dict]                # one dict per failed cell: params, error, traceback
    n_cells: int
    n_computed: int
    n_resumed: int
    wall_s: float
    timings: dict = field(default_factory=dict)

    @property
    def n_failed(self) -> int:
        return len(self.errors)

    def summary(self) -> str:
        """One-line summary of the run."""
        rate = self.n_computed / self.timings.get("cells_s", self.wall_s) if self.n_computed else 0
        return (f"{self.spec.name}: {self.n_cells} cells ({self.n_computed} computed, "
                f"{self.n_resumed} resumed, {self.n_failed} failed) in {self.wall_s:.1f} s "
                f"[simulation {self.timings.get('simulate_s', 0):.1f} s, cells "
                f"{self.timings.get('cells_s', 0):.1f} s = {rate:.0f} cells/s{self._beside()}, "
                "outputs "
                f"{self.timings.get('outputs_s', 0):.1f} s{self._outputs_note()}] -> "
                f"{self.out_dir}")

    def _beside(self) -> str:
        """" (2.1 s beside the simulation)" when cells ran while truths were simulated."""
        t = self.timings.get("cells_beside_simulation_s", 0.0)
        return f" ({t:.1f} s beside the simulation)" if t >= 0.05 else ""

    def _outputs_note(self) -> str:
        """", 3 of 12 rewritten" when the outputs phase skipped unchanged outputs."""
        o = self.timings.get("outputs")
        if not o or not o.get("unchanged"):
            return ""
        n = len(o["written"]) + len(o["unchanged"])
        return f", {len(o['written'])} of {n} rewritten"


# --------------------------------------------------------------------------- randomness
def cell_rng(spec_seed: int, seed: int, stream: int) -> np.random.Generator:
    """Generator for one random stream of one seed: SeedSequence([spec_seed, seed, stream])."""
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence([spec_seed, seed, stream])))


# --------------------------------------------------------------------------- truth
def _load_path(path_file: str, overrides_json: str):
    from sim.paths import Path as SimPath
    from sim.paths import load_path

    p = load_path(path_file)
    ov = json.loads(overrides_json)
    if ov:
        d = p.to_dict()
        d.update(ov)
        p = SimPath.from_dict(d, source=f"{path_file} + overrides {ov}")
    return p


def simulate_truth(path_file: str, path_overrides: str, config_file: str, sim_seed: int,
                   cache_dir: str | None = None):
    """Simulate (or load from the truth cache) the rover on a path with a configuration.

    cache_dir : truth cache folder (default results/cache/truth, see :mod:`sim.cache`).
    """
    from estimator.configuration import SensorConfig
    from sim.rover import simulate_rover

    return simulate_rover(_load_path(path_file, path_overrides), SensorConfig.load(config_file),
                          seed=sim_seed, cache_dir=cache_dir)


# --------------------------------------------------------------------------- cells
def _entry(cell):
    """The technique entry of a cell: its plug-in entry, else the registry's (duck-typed:
    anything with ``technique`` and optionally ``plugin``)."""
    plugin = getattr(cell, "plugin", None)
    return plugin if plugin is not None else technique(cell.technique)


def filter_params_for(truth):
    """The pose filter's parameters for a simulated vehicle (issue 14): its limits (the
    path's speed, acceleration, turn-rate and lateral-acceleration limits and the
    controller's yaw-acceleration limit, as the simulator drove them) and its no-slip point
    (the driven axle's midpoint, read from the vehicle model by the simulator). Nothing
    here is fitted to the truth's trajectory. A truth without them (a recording's
    reference) gets None for each: the filter estimates them from the observations
    (estimator.platform; issue 25). ``meta["platform"]`` (a [platform] block as a dict),
    when present, gives the limits (estimator.platform.PlatformLimits.from_dict)."""
    from estimator.platform import PlatformLimits
    from estimator.pose_filter import PoseFilterParams

    meta = truth.meta
    # simulated before issue 14: the rover, its axle under the CG
    ns = meta.get("no_slip_point_m", (0.0, 0.0) if "params" in meta else None)
    kw = {"no_slip_point_m": None if ns is None else (float(ns[0]), float(ns[1]))}
    if meta.get("platform") is not None:
        return PoseFilterParams.from_platform(PlatformLimits.from_dict(meta["platform"]), **kw)
    return PoseFilterParams.from_limits(meta.get("params", {}).get("controller") or {}, **kw)


def _observations(cell: Cell, truth, config, ctx: CellContext) -> np.ndarray:
    """Noisy observations (n, m, 2) for the cell's noise key, memoised per worker."""
    key = (ctx.spec_seed, ctx.session_s, *cell.noise_key)
    if key in ctx.memo:
        ctx.memo.move_to_end(key)
        return ctx.memo[key]
    from sim.gps import StationarySession, observe

    if cell.recording != "-":      # truth is the Recording (drawn per seed for a replay)
        obs = truth.observations(cell_rng(ctx.spec_seed, cell.seed, STREAM_NOISE),
                                 noise_overrides=json.loads(cell.noise_overrides) or None)
    elif cell.noise == "none":
        obs = observe(truth, config, None)
    else:
        rng = cell_rng(ctx.spec_seed, cell.seed, STREAM_NOISE)
        noise = (StationarySession.load(cell.file("noise")) if cell.noise.startswith("session:")
                 else cell.file("noise"))
        obs = observe(truth, config, noise, rng=rng, session_s=ctx.session_s,
                      noise_overrides=json.loads(cell.noise_overrides) or None)
    ctx.memo[key] = obs
    while len(ctx.memo) > 6:
        ctx.memo.popitem(last=False)
    return obs


#: Column prefixes of the error series in cells.parquet (estimator.metrics.TrackErrors).
SERIES_COLUMNS = {"ex": "x", "ey": "y", "eu": "euclid", "eh": "heading"}


def score_track(df: pd.DataFrame, truth, obs: np.ndarray, config, masks: Iterable[str],
                epochs: bool = True) -> tuple[list[dict], pd.DataFrame | None]:
    """Eq. 4.1/4.2 errors of a track against the truth, summarised per evaluation mask, all
    by :mod:`estimator.metrics` (:func:`~estimator.metrics.track_errors`,
    :func:`~estimator.metrics.summarize`, :func:`~estimator.metrics.jitter_rms`).

    Returns one dict per mask with, for each error series (``ex`` = |x| CG error, ``ey`` = |y|,
    ``eu`` = Euclidean, ``eh`` = heading, rad), the statistics mean, median, std (ddof 1),
    rmse, p95, max and the box-plot outlier fraction; plus the signed along-track error
    (mean, median; negative = the estimate trails the truth, the lag of Section 3.4.2; along
    the truth's direction of travel, :func:`estimator.metrics.travel_direction`), the
    epoch-to-epoch jitter (RMS change of the error vector between consecutive epochs, the
    "variation from one estimate to the next" of Section 4.10), the raw observations' own
    per-axis error for comparison, and counts. Also returns the per-epoch table (truth,
    errors, observations at the estimate times) when ``epochs`` is True, else None.
    """
    import pandas as pd

    from estimator.metrics import (
        STATISTICS,
        evaluation_masks,
        jitter_rms,
        summarize,
        track_cg,
        track_errors,
    )
    from estimator.orientation import wrap_angle

    err = track_errors(df["t"].to_numpy(dtype=float), track_cg(df),
                       df["yaw"].to_numpy(dtype=float), truth.t, truth.cg, truth.yaw)
    idx = err.index
    ob = obs[idx] - truth.sensor_positions[idx, :, :2]            # (k, m, 2)
    obs_ex = np.nanmean(np.abs(ob[..., 0]), axis=1) if ob.size else np.array([])
    obs_ey = np.nanmean(np.abs(ob[..., 1]), axis=1) if ob.size else np.array([])
    win = np.zeros(truth.n, dtype=np.int64)
    # a plug-in's table may have no window column: each estimate is its epoch's own
    win[idx] = df["window"].to_numpy(dtype=np.int64) if "window" in df else 1
    mk_all = {k: v[idx] for k, v in evaluation_masks(truth.turning.astype(bool),
                                                      window=win).items()}
    dxy = err.dxy
    rows = []
    for mname in masks:
        mk = mk_all[mname]
        row: dict[str, Any] = {"mask": mname, "n_epochs": int(mk.sum())}
        for sname, q in SERIES_COLUMNS.items():
            sm = summarize(getattr(err, q), mk)
            for k in (*STATISTICS, "outliers"):
                row[f"{sname}_{k}"] = sm[k]
            if sname == "ex":
                row["n_valid"], row["n_nan"] = sm["n"], sm["n_nan"]
        sa = summarize(err.along, mk, signed=True)
        row["along_mean"], row["along_median"] = sa["mean"], sa["median"]
        row["jitter_rms"] = jitter_rms(dxy, mk)
        with np.errstate(all="ignore"):
            row["obs_ex_mean"] = float(np.nanmean(obs_ex[mk])) if mk.any() else float("nan")
            row["obs_ey_mean"] = float(np.nanmean(obs_ey[mk])) if mk.any() else float("nan")
        rows.append(row)
    if not epochs:
        return rows, None
    tru = truth.cg[idx, :2]
    cols: dict[str, Any] = {
        "truth_cg_x": tru[:, 0], "truth_cg_y": tru[:, 1], "truth_yaw": truth.yaw[idx],
        "truth_turning": truth.turning[idx].astype(bool), "err_x": err.dx, "err_y": err.dy,
        "err_yaw": wrap_angle(df["yaw"].to_numpy(float) - truth.yaw[idx]),
        "along": err.along, "cross": err.cross, "no_turns_window": mk_all["no_turns_window"]}
    # per-antenna truth and observations for plots: float32 (1e-5 m resolution at 200 m)
    # halves the files; the estimates, CG truth and errors stay float64
    for j, nm in enumerate(truth.sensor_names):
        cols[f"truth_{nm}_x"] = truth.sensor_positions[idx, j, 0].astype(np.float32)
        cols[f"truth_{nm}_y"] = truth.sensor_positions[idx, j, 1].astype(np.float32)
        cols[f"obs_{nm}_x"] = obs[idx, j, 0].astype(np.float32)
        cols[f"obs_{nm}_y"] = obs[idx, j, 1].astype(np.float32)
    return rows, pd.DataFrame(cols)


def evaluate_cell(cell: Cell, truth, ctx: CellContext) -> CellOutput:
    """The real cell function: observations -> track -> scores (see the module docstring)."""
    import pandas as pd

    from estimator.configuration import SensorConfig

    if cell.recording != "-":
        return evaluate_recording_cell(cell, truth, ctx)
    t0 = time.perf_counter()
    ckey = ("config", cell.file("config"))
    if ckey not in ctx.memo:
        ctx.memo[ckey] = SensorConfig.load(cell.file("config")).planar()
    config = ctx.memo[ckey]
    obs = _observations(cell, truth, config, ctx)
    t1 = time.perf_counter()
    fp = filter_params_for(truth) if _entry(cell).uses_filter else None
    df = _track_cell(cell, truth.t, obs, config, truth.turning.astype(bool), ctx,
                     true_yaw=np.asarray(truth.yaw, dtype=float), filter_params=fp,
                     layout_check=False)
    t2 = time.perf_counter()
    rows, ep = score_track(df, truth, obs, config, ctx.masks, epochs=ctx.want_epochs)
    # the models' own names (a spec may name them by file, e.g. "rects/rect30.toml"): tables
    # and file names use these
    names = {"config_name": config.name,
             "path_name": str((getattr(truth, "meta", {}) or {}).get("path", {}).get("name", ""))
             or Path(cell.path).stem,
             "noise_name": _noise_name(cell)}
    for row in rows:
        row.update(names)
    t3 = time.perf_counter()
    counts = {str(k): int(v) for k, v in df["solver_status"].value_counts().items()} \
        if "solver_status" in df else {}
    epochs = None
    if ctx.want_epochs:
        epochs = pd.concat([df.reset_index(drop=True), ep], axis=1)
    return CellOutput(rows=rows, epochs=epochs, status_counts=counts,
                      timings={"t_noise_s": t1 - t0, "t_track_s": t2 - t1, "t_score_s": t3 - t2})


def _noise_name(cell: Cell) -> str:
    """The noise model's ``name`` field (or "none" / the session file's stem)."""
    f = cell.file("noise")
    if cell.noise == "none" or f is None:
        return "none"
    if cell.noise.startswith("session:"):
        return "session:" + Path(f).stem
    import tomllib

    try:
        return str(tomllib.loads(Path(f).read_text(encoding="utf-8")).get("name") or Path(f).stem)
    except (OSError, ValueError):
        return Path(f).stem


def _track_cell(cell: Cell, t: np.ndarray, obs: np.ndarray, config, turning, ctx: CellContext,
                true_yaw: np.ndarray | None = None, filter_params=None,
                **kw_extra: Any) -> pd.DataFrame:
    """:func:`estimator.tracking.track` with the cell's window, weighting, technique and
    solver, the technique's arguments from the registry
    (:meth:`experiments.techniques.Technique.track_arguments`); ``turning`` is the
    "controller" flag (n,) bool (None: none available, the dynamic window then uses the
    detector); ``true_yaw`` (n,) rad the reference heading the oracle techniques hand to the
    lag correction (None: no reference, such a cell fails); ``filter_params`` the pose
    filter's parameters (the filter techniques, and the smoothed heading of
    "lc_smoothed_heading"; None = the rover's defaults)."""
    from estimator.tracking import track

    tech = _entry(cell)
    if tech.kind == "plugin":
        return _track_plugin(tech, t, obs, config, ctx)
    heading = None
    if tech.lag_heading == "truth":
        heading = true_yaw
    elif tech.lag_heading == "smoothed":
        # an estimator of its own (issue 14): the pose filter's RTS heading from the same
        # observations replaces the law-of-cosines heading in step 5 of 3.4.2
        from estimator.pose_smoother import smoothed_heading

        heading = smoothed_heading(t, obs, config, filter_params, cache=ctx.cache)
    kw = tech.track_arguments(dyn_window=cell.dyn_window, dyn_growth=cell.dyn_growth,
                              heading=heading)
    flags = None
    if tech.dynamic:
        flags = turning if cell.turning == "controller" and turning is not None else "detect"
    if tech.method in FILTER_METHODS and filter_params is not None:
        kw["filter_params"] = filter_params
    return track(t, obs, config, window=cell.window,
                 weighting="none" if cell.weighting == "-" else cell.weighting, turning=flags,
                 solver="procrustes" if cell.solver == "-" else cell.solver,
                 rng=cell_rng(ctx.spec_seed, cell.seed, STREAM_ESTIMATOR), cache=ctx.cache,
                 **kw, **kw_extra)


def _track_plugin(tech, t: np.ndarray, obs: np.ndarray, config, ctx: CellContext
                  ) -> pd.DataFrame:
    """A plug-in's track (:func:`estimator.trackers.base.run_tracker`: its table checked),
    its tracker built from the entry's import path and options. The sweep keeps the
    columns t, cg_x, cg_y, yaw (and an integer ``window`` column, if any): the scores and
    the page need those, and other names could clash with the per-epoch scores."""
    from estimator.trackers.base import REQUIRED_COLUMNS, load_tracker, run_tracker

    tracker = load_tracker(tech.tracker, json.loads(tech.options))
    df = run_tracker(tracker, t, obs[..., :2], config, cache=ctx.cache)
    keep = [*REQUIRED_COLUMNS]
    if "window" in df and np.issubdtype(df["window"].dtype, np.integer):
        keep.append("window")
    out = df[keep].reset_index(drop=True)
    for c in REQUIRED_COLUMNS:
        out[c] = out[c].to_numpy(dtype=float)
    return out


def evaluate_recording_cell(cell: Cell, rec, ctx: CellContext) -> CellOutput:
    """A recording cell (module docstring): the recording's observations -> track -> scores
    against its reference (:func:`score_track` on :meth:`sim.recording.Recording.truth`), or
    coverage rows when it has none; plus the layout check's verdicts."""
    import warnings

    import pandas as pd

    from estimator.configuration import LayoutWarning, SensorConfig

    t0 = time.perf_counter()
    config = rec.config.planar()
    cfile = cell.file("config")
    if cfile and Path(cfile).resolve() != Path(rec.meta.get("config_file", cfile)).resolve():
        config = SensorConfig.load(cfile).planar()      # the block's layout (spec docstring)
        if config.names != rec.config.names:
            raise ValueError(f"config: {cell.config!r} names antennas {list(config.names)}, "
                             f"recording {cell.recording!r} has {list(rec.config.names)}")
    obs = _observations(cell, rec, config, ctx)
    truth = rec.truth() if rec.reference is not None else None
    t1 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LayoutWarning)     # recorded in the rows instead
        df = _track_cell(cell, rec.t, obs, config,
                         None if truth is None else truth.turning.astype(bool), ctx,
                         true_yaw=None if truth is None else np.asarray(truth.yaw, dtype=float))
    t2 = time.perf_counter()
    if truth is not None:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)   # all-NaN reference epochs
            rows, ep = score_track(df, truth, obs, config, ctx.masks, epochs=ctx.want_epochs)
        n_ref = int(np.isfinite(truth.cg[:, 0]).sum())
    else:           # no per-epoch file: the figures drawn from them need a reference
        rows, ep, n_ref = _coverage_rows(df), None, 0
    lc = df.attrs.get("layout_check", {})
    for row in rows:
        row.update({"config_name": config.name, "path_name": str(cell.path),
                    "noise_name": _noise_name(cell)})
        row.update({"n_reference": n_ref,
                    "layout_mirror_fraction": lc.get("mirror_fraction", float("nan")),
                    "layout_mirror_ratio": lc.get("mirror_objective_ratio", float("nan")),
                    "layout_mirror_verdict": lc.get("mirror_verdict", "-"),
                    "layout_forward_offset_deg": math.degrees(
                        lc.get("forward_offset_rad", float("nan"))),
                    "layout_forward_verdict": lc.get("forward_verdict", "-")})
    t3 = time.perf_counter()
    counts = {str(k): int(v) for k, v in df["solver_status"].value_counts().items()} \
        if "solver_status" in df else {}
    epochs = None
    if ctx.want_epochs and ep is not None:
        epochs = pd.concat([df.reset_index(drop=True), ep], axis=1)
    return CellOutput(rows=rows, epochs=epochs, status_counts=counts,
                      timings={"t_noise_s": t1 - t0, "t_track_s": t2 - t1, "t_score_s": t3 - t2})


def _coverage_rows(df: pd.DataFrame) -> list[dict]:
    """Rows of a cell without a reference: mask "full" with the epoch and estimate counts
    (``n_epochs``, ``n_valid`` finite CG estimates, ``n_nan``); every error statistic of
    :func:`score_track` is NaN (nothing to score against), so the tables keep their shape."""
    from estimator.metrics import STATISTICS, track_cg

    cg = track_cg(df)
    ok = np.isfinite(cg).all(axis=1)
    row: dict[str, Any] = {"mask": "full", "n_epochs": len(df), "n_valid": int(ok.sum()),
                           "n_nan": int((~ok).sum())}
    nan = float("nan")
    for sname in ("ex", "ey", "eu", "eh"):
        row.update({f"{sname}_{k}": nan for k in (*STATISTICS, "outliers")})
    row.update(dict.fromkeys(("along_mean", "along_median", "jitter_rms", "obs_ex_mean",
                              "obs_ey_mean"), nan))
    return [row]


# --------------------------------------------------------------------------- workers
_WORKER_MEMO: OrderedDict[tuple, Any] = OrderedDict()
#: The trackers' memos of this worker (the techniques of one noise key share fits and filter
#: passes: in the thesis preset 470 of 840 procrustes fits are repeats); reset with the memo.
_WORKER_CACHE = TrackCache()
_WORKER_RUN = ""  # the run the memo belongs to


def _run_batch(cells: list[Cell], truth, spec_seed: int, masks: tuple[str, ...],
               session_s: float, want: list[bool], cell_fn: CellFn | None,
               store_dir: str | None = None, run_id: str = "") -> list[dict]:
    """Run a batch of cells (same truth) in one worker; never raises for a cell's error.

    With ``store_dir`` (workers sharing the results folder: in-process and loky) each cell
    is persisted the moment it finishes and only its key comes back; without it (Dask
    workers on other machines) the results travel back and the parent writes them.
    The worker's memo (observations, configurations) lives for one ``run_id`` only: worker
    processes outlive a run, and files may change between runs.
    """
    global _WORKER_RUN
    if _WORKER_RUN != run_id:
        _WORKER_MEMO.clear()
        _WORKER_CACHE.clear()
        _WORKER_RUN = run_id
    fn = cell_fn or evaluate_cell
    store = CellStore(Path(store_dir)) if store_dir else None
    out = []
    for cell, w in zip(cells, want):
        ctx = CellContext(spec_seed=spec_seed, masks=masks, session_s=session_s,
                          want_epochs=w, memo=_WORKER_MEMO, cache=_WORKER_CACHE)
        t0 = time.perf_counter()
        try:
            with ledger() as reused:
                res = fn(cell, truth, ctx)
            res.timings["t_cell_s"] = time.perf_counter() - t0
            # what the cell took from the per-process memo (estimator.memo), at the cost it
            # had when computed: t_track_s + t_reused_s is the cell's stand-alone cost
            res.timings["t_reused_s"] = reused.seconds
            out.append({"key": cell.key, "ok": True, "rows": res.rows, "epochs": res.epochs,
                        "timings": res.timings, "status_counts": res.status_counts})
        except Exception as exc:  # noqa: BLE001 - a cell's failure is data, not a crash
            out.append({"key": cell.key, "ok": False,
                        "error": f"{type(exc).__name__}: {exc}",
                        "traceback": traceback.format_exc(limit=20)})
        if store is not None:
            store.write(cell, out[-1])
            out[-1] = {"key": cell.key, "ok": out[-1]["ok"], "written": True}
    return out


# --------------------------------------------------------------------------- store
class CellStore:
    """One JSON file per finished cell (atomic), one parquet per cell's per-epoch table."""

    def __init__(self, out: Path):
        self.out = Path(out)
        self.cells_dir = self.out / "cells"
        self.epochs_dir = self.out / "epochs"
        self.errors_dir = self.out / "errors"
        for d in (self.cells_dir, self.epochs_dir, self.errors_dir):
            d.mkdir(parents=True, exist_ok=True)

    _atomic = staticmethod(atomic_write)

    def done(self) -> set[str]:
        """Keys of every finished cell, whatever code computed it."""
        return {p.stem for p in self.cells_dir.glob("*.json")}

    def check(self, keys: Iterable[str], code: str) -> tuple[set[str], set[str]]:
        """Sort finished ``keys`` into (stale, damaged); a resumed run recomputes both.

        stale : the stored record was computed by other code than ``code``
            (see :func:`cell_code_digest`).
        damaged : the record cannot be read (empty, truncated or not JSON, e.g. a disk that
            filled up), or it says it has per-epoch estimates and their parquet is missing
            or unreadable (only the parquet footer is read: cheap, and it catches truncation).
        """
        stale, damaged = set(), set()
        for k in keys:
            try:
                rec = json.loads((self.cells_dir / f"{k}.json").read_text())
                ok = isinstance(rec, dict) and isinstance(rec.get("rows"), list)
            except (OSError, ValueError):
                ok = False
            if not ok or (rec.get("epochs")
                          and not _parquet_readable(self.epochs_dir / f"{k}.parquet")):
                damaged.add(k)
            elif rec.get("code") != code:
                stale.add(k)
        return stale, damaged

    def clear(self, keys: Iterable[str]) -> None:
        for k in keys:
            for p in (self.cells_dir / f"{k}.json", self.epochs_dir / f"{k}.parquet",
                      self.errors_dir / f"{k}.json"):
                if p.exists():
                    p.unlink()

    def write(self, cell: Cell, res: dict) -> None:
        if not res["ok"]:
            rec = {"key": cell.key, "params": cell.params(), "error": res["error"],
                   "traceback": res["traceback"]}
            self._atomic(self.errors_dir / f"{cell.key}.json",
                         lambda p: p.write_text(json.dumps(rec, indent=1)))
            return
        if res.get("epochs") is not None:
            ep = res["epochs"]
            # no dictionary encoding: per-epoch floats rarely repeat, so it only costs
            # (half the write time, files 18 % smaller on the thesis preset)
            self._atomic(self.epochs_dir / f"{cell.key}.parquet",
                         lambda p: ep.to_parquet(p, index=False, use_dictionary=False))
        rec = {"key": cell.key, "params": cell.params(), "rows": res["rows"],
               "timings": res["timings"], "status_counts": res["status_counts"],
               "epochs": res.get("epochs") is not None, "code": cell_code_digest()}
        self._atomic(self.cells_dir / f"{cell.key}.json",
                     lambda p: p.write_text(json.dumps(rec, allow_nan=True)))
        err = self.errors_dir / f"{cell.key}.json"
        if err.exists():
            err.unlink()

    def read_cells(self, keys: Iterable[str]) -> pd.DataFrame:
        import pandas as pd
        recs = []
        for k in keys:
            p = self.cells_dir / f"{k}.json"
            if not p.exists():
                continue
            r = json.loads(p.read_text())
            n_ok = int(r["status_counts"].get("ok", 0))
            n_all = int(sum(r["status_counts"].values()))
            for row in r["rows"]:
                recs.append({"key": k, **r["params"], **row, **r["timings"],
                             "status_counts": json.dumps(r["status_counts"], sort_keys=True),
                             "n_status_ok": n_ok, "n_status_other": n_all - n_ok,
                             "has_epochs": bool(r.get("epochs"))})
        return pd.DataFrame.from_records(recs)

    def read_errors(self, keys: Iterable[str]) -> list[dict]:
        out = []
        for k in keys:
            p = self.errors_dir / f"{k}.json"
            if p.exists():
                out.append(json.loads(p.read_text()))
        return out


#: The lock of a results folder: one run at a time (holder's pid inside; git-ignored name).
LOCK_FILE = "lock.local.json"


@contextmanager
def folder_lock(out_dir: Path) -> Iterator[OSError | None]:
    """Hold ``out_dir``'s lock (:data:`LOCK_FILE`) for the block: one run per results folder.

    Another live run holding it: :class:`SweepError` at once, naming the folder and its pid.
    A lock left by a dead process is taken over (the lock is an advisory ``flock`` the
    kernel drops when its holder dies; without ``fcntl``, a pid that no longer runs). The
    block gets None, or the ``OSError`` that kept the lock file from being written (a
    read-only folder: the run may go on only if it has nothing to write)."""
    path = out_dir / LOCK_FILE
    try:
        fh = _take_lock(path)
    except OSError as exc:
        yield exc
        return
    try:
        yield None
    finally:
        with suppress(OSError):
            path.unlink()
        fh.close()


def _take_lock(path: Path):
    """Open and lock ``path``, write this process's pid; returns the open file."""
    for _ in range(3):
        fh = open(path, "a+", encoding="utf-8")  # noqa: SIM115 - held until folder_lock ends
        if _locked_by_other(fh):
            fh.seek(0)
            holder = _lock_pid(fh.read())
            fh.close()
            raise SweepError(f"{path.parent} is in use by another sweep (pid {holder}, lock "
                             f"{path}); wait for it to finish, or give another --out")
        if not path.exists() or os.stat(path).st_ino != os.fstat(fh.fileno()).st_ino:
            fh.close()              # the holder removed the file meanwhile: lock the new one
            continue
        fh.seek(0)
        fh.truncate()
        fh.write(json.dumps({"pid": os.getpid()}) + "\n")
        fh.flush()
        return fh
    raise SweepError(f"{path.parent}: its lock {path} keeps changing; is another sweep "
                     "starting there?")


def _locked_by_other(fh) -> bool:
    """Whether another process holds ``fh``'s file: its ``flock``, or (no ``fcntl``) the
    recorded pid of another process that still runs."""
    try:
        import fcntl
    except ImportError:
        fh.seek(0)
        pid = _lock_pid(fh.read())
        return pid not in (None, os.getpid()) and _pid_alive(pid)
    try:
        fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    return False


def _lock_pid(text: str) -> int | None:
    try:
        pid = json.loads(text)["pid"]
    except (ValueError, TypeError, KeyError):
        return None
    return pid if isinstance(pid, int) else None


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True                 # it exists, owned by someone else
    return True


def _unwritable(out_dir: Path, why: OSError) -> SweepError:
    return SweepError(f"cannot write {out_dir}: {why.strerror or why}; the run has cells or "
                      "outputs to write there (fix the permissions or give another --out)")


def _parquet_readable(path: Path) -> bool:
    """Whether ``path`` is a complete parquet file (its footer parses)."""
    import pyarrow.parquet as pq

    try:
        pq.read_metadata(path)
    except (OSError, ValueError, Exception):  # noqa: BLE001 - pyarrow raises ArrowInvalid etc.
        return False
    return True


# --------------------------------------------------------------------------- versions
#: Source files whose code determines a cell's numbers (simulation, noise, estimation,
#: scoring). Their digest is stored with every finished cell; a rerun recomputes the cells
#: that other code produced instead of mixing results of two code versions.
CELL_SOURCES = tuple(sorted(
    [*(REPO / "estimator").rglob("*.py"), *(REPO / "sim").glob("*.py"),
     REPO / "experiments" / "sweep.py", REPO / "experiments" / "spec.py",
     REPO / "experiments" / "techniques.py"]))


def cell_code_digest() -> str:
    """Digest (16 hex digits) of :data:`CELL_SOURCES` as they are on disk now."""
    from sim.cache import source_digest

    return source_digest(CELL_SOURCES)[:16]


def _json_text(obj: Any) -> str:
    return json.dumps(obj, indent=1, default=str)


def _write_json(path: Path, obj: Any) -> None:
    _write_text(path, _json_text(obj))


def _write_text(path: Path, text: str) -> None:
    """Write ``text`` atomically unless ``path`` holds it already (so a rerun with nothing
    to compute writes nothing and runs on a read-only folder)."""
    if _read_text(path) != text:
        atomic_write_text(path, text)


def _read_text(path: Path) -> str | None:
    try:
        return path.read_text(encoding="utf-8")
    except (OSError, ValueError):
        return None


# --------------------------------------------------------------------------- scheduling
#: Cost of the pose filter's forward pass in cells' worth of work (per epoch: ~135 us for the
#: pass against ~17 us for a window cell tracked and scored; measured on the thesis preset).
_PASS_COST_CELLS = 8


def _uses_pose_filter(cell: Cell) -> bool:
    """Whether a cell runs the pose filter's forward pass: the filter family, and the lag
    correction fed the smoothed heading (see :func:`evaluate_cell`)."""
    return _entry(cell).uses_filter



def _store_results(it, store, by_key: dict, bar) -> int:
    """Persist the cell results an iterator of batches yields (workers that wrote their own
    cells say so with ``written``), advance ``bar``; return the number of cells seen. A
    warm-up's process id (an int) is skipped."""
    n = 0
    for results in it:
        if isinstance(results, int):
            continue
        for res in results:
            if not res.get("written"):
                store.write(by_key[res["key"]], res)
        n += len(results)
        bar.update(len(results))
    return n


def _batches(todo: list[Cell], jobs: int, epochs: Callable[[Cell], int] | None = None
             ) -> list[list[Cell]]:
    """Tasks for the workers, largest first.

    The cells of one noise key share their observations and, those that run the pose
    filter, one forward pass (both memoised per worker process: ``CellContext.memo`` and
    :mod:`estimator.memo`), so a noise key is one task when there are enough keys for load
    balance (4 tasks per worker); otherwise its cells are chunked, the pose-filter cells
    kept in one chunk. Tasks are ordered by estimated cost (cells x ``epochs(cell)``, a
    forward pass counted as :data:`_PASS_COST_CELLS` cells), largest first, so the tasks
    that finish last are short and the workers finish together.
    """
    groups: OrderedDict[tuple, list[Cell]] = OrderedDict()
    for c in todo:
        groups.setdefault(c.noise_key, []).append(c)
    size = max(1, math.ceil(len(todo) / max(1, 4 * jobs)))      # cells per task
    out = []
    for cells in groups.values():
        if len(cells) <= size:
            out.append(cells)
            continue
        pf = [c for c in cells if _uses_pose_filter(c)]
        rest = [c for c in cells if not _uses_pose_filter(c)]
        if pf:
            out.append(pf)
        n_chunks = max(1, round(len(rest) / size))
        step = math.ceil(len(rest) / n_chunks) if rest else 1
        out.extend(rest[i:i + step] for i in range(0, len(rest), step))
    n_ep = epochs or (lambda _c: 1)

    def cost(b: list[Cell]) -> float:
        passes = _PASS_COST_CELLS if any(_uses_pose_filter(c) for c in b) else 0
        return (len(b) + passes) * n_ep(b[0])

    out.sort(key=cost, reverse=True)       # stable: equal costs keep the spec's order
    return out


def _iter_loky(batches, truths, spec, wants, jobs, cell_fn, store_dir, run_id
               ) -> Iterator[list[dict]]:
    """The batches on the loky workers; they start at once (several such iterators may run
    side by side on the same workers). Results arrive in completion order; each carries its
    cells' keys."""
    from joblib import Parallel, delayed

    par = Parallel(n_jobs=jobs, backend="loky", return_as="generator_unordered")
    return par(delayed(_run_batch)(b, truths[b[0].truth_key], spec.seed, spec.masks,
                                   spec.session_s, w, cell_fn, store_dir, run_id)
               for b, w in zip(batches, wants))


#: Seconds to wait for a Dask scheduler before giving up with a clear message.
_CONNECT_TIMEOUT_S = 5


def _no_scheduler(address: str, why: object) -> str:
    return (f"cannot reach the Dask scheduler at {address} ({why}); start one with "
            f"'dask scheduler --port 8786' and workers with 'dask worker {address}', "
            "or drop --scheduler to use a local cluster")


def check_scheduler(address: str, timeout_s: float = _CONNECT_TIMEOUT_S) -> None:
    """Raise :class:`SweepError` unless a TCP connection to a ``tcp://host:port`` Dask
    scheduler opens within ``timeout_s`` (checked before any simulation, so a wrong address
    fails in seconds, not after the truths are built). Other schemes are left to Dask."""
    import socket
    from urllib.parse import urlsplit

    u = urlsplit(address if "://" in address else f"tcp://{address}")
    if u.scheme != "tcp":
        return
    try:
        host, port = u.hostname, u.port
    except ValueError as exc:
        raise SweepError(f"--scheduler: bad address {address!r} ({exc})") from None
    if not host or not port:
        raise SweepError(f"--scheduler: expected tcp://HOST:PORT, got {address!r}")
    try:
        socket.create_connection((host, port), timeout=timeout_s).close()
    except OSError as exc:
        raise SweepError(_no_scheduler(address, exc)) from None


def _iter_dask(batches, truths, spec, wants, jobs, cell_fn, scheduler, run_id):
    from distributed import Client, LocalCluster, as_completed

    cluster = None
    if scheduler:
        try:
            client = Client(scheduler, timeout=f"{_CONNECT_TIMEOUT_S}s")
        except (OSError, TimeoutError) as exc:
            raise SweepError(_no_scheduler(scheduler, exc)) from None
    else:
        cluster = LocalCluster(n_workers=jobs, threads_per_worker=1, processes=True,
                               dashboard_address=None)
        client = Client(cluster)
    try:
        tfut = {k: client.scatter(v, broadcast=False) for k, v in truths.items()}
        futs = [client.submit(_run_batch, b, tfut[b[0].truth_key], spec.seed, spec.masks,
                              spec.session_s, w, cell_fn, None, run_id, pure=False)
                for b, w in zip(batches, wants)]
        for fut in as_completed(futs):
            yield fut.result()
            fut.release()
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def _simulate_all(cells: list[Cell], spec: Spec, jobs: int, truth_fn, cache_dir,
                  progress: bool = False) -> dict:
    """The truth of every distinct (path, configuration) of ``cells``, simulated once (or
    loaded from the truth cache), side by side in worker processes when jobs > 1."""
    from tqdm import tqdm

    keys = list(OrderedDict.fromkeys(c.truth_key for c in cells))
    bar = tqdm(total=len(keys), unit="truth", desc=f"{spec.name}: simulate",
               disable=not progress, dynamic_ncols=True)
    out: dict = {}
    try:
        for k, tr in _iter_truths(cells, spec, jobs, truth_fn, cache_dir):
            out[k] = tr
            bar.update()
    finally:
        bar.close()
    return {k: out[k] for k in keys}


def _keyed_truth(fn: Callable, key: tuple, *args: Any) -> tuple[tuple, Any]:
    return key, fn(*args)


def _iter_truths(cells: list[Cell], spec: Spec, jobs: int, truth_fn, cache_dir,
                 on_queued: Callable[[], object] | None = None
                 ) -> Iterator[tuple[tuple, Any]]:
    """(truth key, truth) of every distinct (path, configuration) of ``cells`` as each is
    ready: recordings loaded here, simulations (or truth-cache loads) side by side in the
    worker processes when jobs > 1 and there are several, else here. ``on_queued`` is
    called once the worker simulations are queued, or before this process simulates (e.g.
    to give idle workers something to do meanwhile)."""
    keys = list(OrderedDict.fromkeys(c.truth_key for c in cells))
    if any(k[0] == "recording" for k in keys):
        from sim.recording import load_recording

        for k in [k for k in keys if k[0] == "recording"]:
            yield k, load_recording(k[1])           # its logs, once, in the parent
        keys = [k for k in keys if k[0] != "recording"]
    fn = truth_fn or simulate_truth
    args = [(fn, k, *k, spec.sim_seed, cache_dir) for k in keys]
    if jobs > 1 and len(keys) > 1:
        from joblib import Parallel, delayed

        # n_jobs = jobs (not fewer): the cells reuse the same worker processes
        sims = Parallel(n_jobs=jobs, backend="loky", return_as="generator_unordered")(
            delayed(_keyed_truth)(*a) for a in args)
        if on_queued is not None:
            on_queued()
        yield from sims
    else:
        if on_queued is not None:
            on_queued()
        for a in args:
            yield _keyed_truth(*a)


def _warm_up(outputs: bool, lock_path: str | None = None) -> int:
    """A worker's first task beside the simulations: import what the cells (and, with
    ``outputs``, the tables, report and figures) need and load matplotlib's fonts, so
    that start-up cost is paid while a simulation runs, not on the critical path.

    ``lock_path``: the workers warm up one at a time (an exclusive lock on that file), so
    that beside a simulation running in the main process they take the one spare core
    instead of competing with the simulation for both (two workers warming up at once
    beside it made a 3.0 s simulation take 3.7 s). Returns the worker's process id."""
    with _exclusive(lock_path):
        _warm_up_imports(outputs)
    return os.getpid()


@contextmanager
def _exclusive(lock_path: str | None) -> Iterator[None]:
    """Hold an exclusive advisory lock on ``lock_path`` (created if absent) for the block;
    no lock where there is no path, no ``fcntl`` (Windows) or the file cannot be opened or
    locked (e.g. a read-only temporary folder): the lock only orders work, nothing needs it."""
    try:
        import fcntl
    except ImportError:                                   # pragma: no cover - Windows
        fcntl = None
    fh = None
    if lock_path is not None and fcntl is not None:
        try:
            fh = open(lock_path, "a")                     # noqa: SIM115 (closed below)
            fcntl.flock(fh, fcntl.LOCK_EX)
        except OSError:
            if fh is not None:
                fh.close()
            fh = None
    try:
        yield
    finally:
        if fh is not None:
            fcntl.flock(fh, fcntl.LOCK_UN)
            fh.close()


def _warm_up_imports(outputs: bool) -> None:
    import estimator.tracking  # noqa: F401
    import sim.gps  # noqa: F401

    if outputs:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        import experiments.figures
        import experiments.report  # noqa: F401

        fig = plt.figure(figsize=(1, 1))
        fig.text(0.5, 0.5, "x")
        fig.canvas.draw()
        plt.close(fig)


def _import_for_outputs() -> None:
    """Import what the end of a run needs in this process (pandas and pyarrow for the cell
    table, the outputs phase, the page and its Markdown renderer; ~0.5 s). Called once the
    cells are queued on the workers, when this process would otherwise wait for them:
    imported at the end instead, they were on the critical path of a one-path sweep.
    (experiments.figures is imported for its figure groups' names: it imports matplotlib
    only to draw.)"""
    import importlib

    for name in _OUTPUT_MODULES:
        importlib.import_module(name)


#: What :func:`_import_for_outputs` imports.
_OUTPUT_MODULES = ("pandas", "pyarrow.parquet", "markdown_it", "experiments.figures",
                   "experiments.outputs", "experiments.page")


# --------------------------------------------------------------------------- run
def run(spec: Spec | str | Path, *, out: str | Path | None = None, jobs: int | None = None,
        backend: str = "loky", scheduler: str | None = None, force: bool = False,
        progress: bool = True, outputs: bool = True, figures: bool = True,
        cache_dir: str | Path | None = None, cell_fn: CellFn | None = None,
        truth_fn: Callable | None = None) -> Results:
    """Run a spec; returns :class:`Results` and writes ``out`` (default :func:`default_out`).

    spec : a :class:`Spec`, a spec file, or a preset name.
    jobs : worker processes (default: all cores); 1 runs in this process.
    backend : "loky" (joblib processes) or "dask" (``scheduler`` = address of a running
        Dask scheduler; without one, a LocalCluster of ``jobs`` workers is started).
    force : recompute cells that are already finished.
    outputs / figures : write tables, REPORT.md, index.html (and figures) after the cells.
    cache_dir : truth cache folder (default results/cache/truth).
    cell_fn, truth_fn : replace :func:`evaluate_cell` / :func:`simulate_truth` (tests).
    """
    t_start = time.perf_counter()
    if not isinstance(spec, Spec):
        spec = load_spec(spec)
    if backend not in ("loky", "dask"):
        raise ValueError(f"backend: must be 'loky' or 'dask', got {backend!r}")
    if scheduler and backend != "dask":
        raise ValueError("scheduler: only meaningful with backend='dask'")
    if scheduler:
        check_scheduler(scheduler)
    jobs = int(jobs) if jobs else (os.cpu_count() or 1)
    if jobs < 1:
        raise ValueError(f"jobs: must be >= 1, got {jobs!r}")
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    out_dir = Path(out) if out is not None else default_out(spec.name)
    out_dir.mkdir(parents=True, exist_ok=True)
    with folder_lock(out_dir) as locked:
        return _run_in(spec, out_dir, locked, t_start, jobs=jobs, backend=backend,
                       scheduler=scheduler, force=force, progress=progress, outputs=outputs,
                       figures=figures, cache_dir=cache_dir, cell_fn=cell_fn,
                       truth_fn=truth_fn)


def _run_in(spec: Spec, out_dir: Path, locked: OSError | None, t_start: float, *, jobs: int,
            backend: str, scheduler: str | None, force: bool, progress: bool, outputs: bool,
            figures: bool, cache_dir, cell_fn: CellFn | None, truth_fn: Callable | None
            ) -> Results:
    """:func:`run` in its results folder ``out_dir``, held by :func:`folder_lock`
    (``locked``: why the lock file could not be written, if it could not)."""
    store = CellStore(out_dir)
    cells = spec.expand()
    by_key = {c.key: c for c in cells}
    if force and locked is not None:
        raise _unwritable(out_dir, locked)
    if force:
        store.clear(by_key)
    done = store.done() & set(by_key)
    code = cell_code_digest()
    stale, damaged = store.check(done, code)
    if stale:
        print(f"{spec.name}: {len(stale)} of {len(done)} finished cells were computed by other "
              "code (estimator/, sim/ or the runner changed since); recomputing them",
              file=sys.stderr)
    if damaged:
        print(f"{spec.name}: {len(damaged)} of {len(done)} finished cells have damaged files "
              "(unreadable cell record or per-epoch parquet, e.g. from a full disk); "
              "recomputing them", file=sys.stderr)
    if locked is not None and (stale or damaged or len(done) < len(by_key)):
        raise _unwritable(out_dir, locked)       # cells to compute: the folder must be writable
    store.clear(stale | damaged)
    done -= stale | damaged
    todo = [c for c in cells if c.key not in done]
    run_id = uuid.uuid4().hex
    before = _read_text(out_dir / "manifest.json")

    # manifest.json (tracked in reference runs) holds only what determines the numbers, with
    # paths relative to the project, so a rerun of the same code and spec leaves it
    # byte-identical; what varies per run (times, machine, resume counts) goes to the
    # git-ignored sidecar run.local.json
    manifest = {"spec": {**spec.to_dict(), "source": _rel(spec.source)}, "spec_raw": spec.raw,
                "spec_base_dir": _rel(spec.base_dir), "spec_seed": spec.seed,
                "seeds": list(spec.seeds), "code": code_version(), "cell_code": code,
                "n_cells": len(cells), "status": "running"}
    run_info = {"started_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                "backend": backend, "jobs": jobs, "cpu_count": os.cpu_count(),
                "n_stale": len(stale), "n_damaged": len(damaged)}
    # with nothing to compute, a finished run writes only what changed (a read-only
    # folder can be rerun)
    if todo:
        _write_json(out_dir / "manifest.json", manifest)
    _write_run_info(out_dir, run_info, required=bool(todo))
    _write_spec_toml(spec, out_dir / "spec.toml")

    try:
        t_sim0 = time.perf_counter()
        n_done_now, t_overlap = 0, 0.0
        from tqdm import tqdm

        bar = None
        try:
            if todo and backend == "loky" and jobs > 1:
                # pipelined: the cells of a truth start on the workers the moment it is ready,
                # beside the simulations still running
                sbar = tqdm(total=len({c.truth_key for c in todo}), unit="truth",
                            desc=f"{spec.name}: simulate", disable=not progress,
                            dynamic_ncols=True)
                by_truth: OrderedDict[tuple, list[Cell]] = OrderedDict()
                for c in todo:
                    by_truth.setdefault(c.truth_key, []).append(c)
                truths: dict = {}
                running = []
                t_cells0 = None
                warm: list = []

                lock = os.path.join(tempfile.gettempdir(), f"configpose-warm-up-{run_id}.lock")

                def warm_up() -> None:
                    from joblib import Parallel, delayed

                    warm.append(Parallel(n_jobs=jobs, backend="loky",
                                         return_as="generator_unordered")(
                        delayed(_warm_up)(outputs and figures, lock) for _ in range(jobs)))

                try:
                    for key, tr in _iter_truths(todo, spec, jobs, truth_fn,
                                                str(cache_dir) if cache_dir else None,
                                                on_queued=warm_up):
                        truths[key] = tr
                        sbar.update()
                        batches = _batches(by_truth[key], jobs,
                                           lambda c: len(getattr(truths[c.truth_key], "t", ()))
                                           or 1)
                        wants = [[spec.epochs_wanted(c) for c in b] for b in batches]
                        t_cells0 = t_cells0 or time.perf_counter()
                        running.append(_iter_loky(batches, truths, spec, wants, jobs, cell_fn,
                                                  str(out_dir), run_id))
                finally:
                    sbar.close()
                t_sim = time.perf_counter() - t_sim0
                t_overlap = max(0.0, t_sim0 + t_sim - (t_cells0 or t_sim0 + t_sim))
                if outputs:
                    _import_for_outputs()      # while the workers compute the cells
                bar = tqdm(total=len(todo), unit="cell", desc=spec.name, disable=not progress,
                           smoothing=0.1, dynamic_ncols=True)
                for it in (*warm, *running):
                    n_done_now += _store_results(it, store, by_key, bar)
                if warm:
                    with suppress(OSError):
                        os.remove(lock)
            else:
                truths = _simulate_all(todo, spec, jobs, truth_fn,
                                       str(cache_dir) if cache_dir else None,
                                       progress=progress) if todo else {}
                t_sim = time.perf_counter() - t_sim0
                t_cells0 = time.perf_counter()
                if todo:
                    batches = _batches(todo, jobs,
                                       lambda c: len(getattr(truths[c.truth_key], "t", ())) or 1)
                    wants = [[spec.epochs_wanted(c) for c in b] for b in batches]
                    bar = tqdm(total=len(todo), unit="cell", desc=spec.name,
                               disable=not progress, smoothing=0.1, dynamic_ncols=True)
                    if jobs == 1 and backend == "loky":
                        it = (_run_batch(b, truths[b[0].truth_key], spec.seed, spec.masks,
                                         spec.session_s, w, cell_fn, str(out_dir), run_id)
                              for b, w in zip(batches, wants))
                    elif backend == "loky":
                        it = _iter_loky(batches, truths, spec, wants, jobs, cell_fn,
                                        str(out_dir), run_id)
                    else:
                        it = _iter_dask(batches, truths, spec, wants, jobs, cell_fn, scheduler,
                                        run_id)
                    n_done_now += _store_results(it, store, by_key, bar)
        finally:
            if bar is not None:
                bar.close()
        t_cells = time.perf_counter() - t_cells0 if todo else 0.0

        t_out0 = time.perf_counter()
        keys = [c.key for c in cells]
        table = store.read_cells(keys)
        errors = store.read_errors(keys)
        final = _json_text({**manifest, "status": _final_status(errors)})
        if n_done_now or final != before or not (out_dir / "cells.parquet").exists():
            _write_table(table, out_dir / "cells.parquet")
        _write_json(out_dir / "errors.json", errors)
        res = Results(spec=spec, out_dir=out_dir, cells=table, errors=errors, n_cells=len(cells),
                      n_computed=n_done_now - len(errors), n_resumed=len(done), wall_s=0.0)
        out_info: dict = {}
        if outputs and not table.empty:
            from tqdm import tqdm

            from experiments.outputs import n_steps, write_outputs

            # tables, report, figures (side by side in the workers) and index.html, each
            # only where its inputs changed (experiments.outputs)
            obar = tqdm(total=n_steps(figures), unit="step", desc=f"{spec.name}: outputs",
                        disable=not progress, dynamic_ncols=True)
            try:
                out_info = write_outputs(table, out_dir, spec=spec,
                                         jobs=jobs if backend == "loky" else 1,
                                         figures=figures, on_step=lambda _name: obar.update())
            finally:
                obar.close()
            if figures and ("has_epochs" not in table or not table["has_epochs"].any()):
                print(f"{spec.name}: note: no cell kept per-epoch estimates (the spec has no "
                      "[epochs] table), so the figures drawn from per-epoch errors were not written "
                      "(box plots, orientation, overlays, sensor-1 lag): add "
                      "'[epochs]' with 'seeds = [0]' to the spec", file=sys.stderr)
        t_out = time.perf_counter() - t_out0
    except OSError as exc:
        # a full disk or a write-protected folder: the cells written so far are safe (each
        # one is atomic), the rerun resumes them; say so in one line, no traceback
        manifest["status"] = "interrupted"
        try:
            _write_json(out_dir / "manifest.json", manifest)
            marked = f"marked interrupted in {out_dir / 'manifest.json'}"
        except OSError:
            marked = "could not be marked interrupted (the folder is not writable)"
        where = exc.filename or out_dir
        raise SweepError(f"cannot write {where}: {exc.strerror or exc}; the run {marked}; "
                         "free space or fix permissions and rerun the same command to "
                         "resume") from None
    except KeyboardInterrupt as exc:
        # Ctrl-C or SIGTERM (experiments.cli): no worker outlives the run, the manifest says
        # so, and the finished cells (each written atomically) are resumed by the rerun
        _stop_workers()
        manifest["status"] = "interrupted"
        with suppress(OSError):
            _write_json(out_dir / "manifest.json", manifest)
        n_kept = len(store.done() & set(by_key))
        exc.args = (f"{n_kept} of {len(cells)} cells are finished in {out_dir}, marked "
                    "interrupted in its manifest.json; rerun the same command to resume",)
        raise
    res.wall_s = time.perf_counter() - t_start
    res.timings = {"simulate_s": t_sim, "cells_s": t_cells, "cells_beside_simulation_s":
                   t_overlap, "outputs_s": t_out, "wall_s": res.wall_s}
    if out_info:
        res.timings["outputs"] = {"written": out_info["written"],
                                  "unchanged": out_info["skipped"],
                                  "seconds": out_info["seconds"]}
    manifest["status"] = _final_status(errors)
    run_info.update({"finished_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                     "n_computed": res.n_computed, "n_resumed": res.n_resumed,
                     "n_failed": res.n_failed, "timings_s": res.timings})
    _write_json(out_dir / "manifest.json", manifest)
    _write_run_info(out_dir, run_info, required=bool(todo))
    return res


def _final_status(errors: list) -> str:
    return "complete" if not errors else "complete_with_errors"


def _write_run_info(out_dir: Path, info: dict, required: bool) -> None:
    """run.local.json (this run's times and counts, git-ignored): when the run computed
    nothing, written where the folder allows it (a read-only finished run can be rerun)."""
    try:
        _write_json(out_dir / "run.local.json", info)
    except OSError:
        if required:
            raise


def _write_spec_toml(spec: Spec, path: Path) -> None:
    """The spec as run (command-line overrides such as --solver and --seeds applied), as
    TOML that :func:`experiments.spec.load_spec` reads back to the same cells when it is
    placed beside the spec's files (relative names resolve against ``spec_base_dir``)."""
    import tomli_w

    header = (f"# The spec as run by python -m experiments.sweep (overrides applied).\n"
              f"# Source: {_rel(spec.source)}; relative file names resolve against "
              f"{_rel(spec.base_dir)}.\n")
    _write_text(path, header + tomli_w.dumps(spec.raw))


def _rel(path: str | Path) -> str:
    """``path`` relative to the project when it lies inside it (machine-independent in
    tracked files), else as given (e.g. "<dict>" or a spec elsewhere)."""
    p = Path(path)
    try:
        return p.resolve().relative_to(REPO).as_posix() if p.is_absolute() else str(path)
    except ValueError:
        return str(path)


def _write_table(df: pd.DataFrame, path: Path) -> None:
    atomic_write(path, lambda p: df.to_parquet(p, index=False))


# --------------------------------------------------------------------------- CLI
_EPILOG = """examples:
  python -m experiments.sweep                      # the default preset (thesis), all cores
  python -m experiments.sweep --preset quick       # one path, 2 seeds, a few seconds
  python -m experiments.sweep my_spec.toml --out /tmp/run --jobs 2
  python -m experiments.sweep --preset thesis --solver slsqp   # faithful solver -> results/local/thesis-slsqp/
  python -m experiments.sweep --preset thesis --solver elastic # the same fit, batched -> results/thesis-elastic/
  python -m experiments.sweep --preset thesis --backend dask --scheduler tcp://10.0.0.5:8786
  python -m experiments.figures results/thesis     # re-plot from saved files, no simulation

A rerun of the same spec resumes: finished cells are skipped (--force recomputes).
One run per results folder at a time (its lock.local.json names the holder's pid; a lock
left by a dead process is taken over). Ctrl-C / SIGTERM: exit 130 / 143 in one line, the
manifest says "interrupted", no worker is left running, the rerun resumes. --debug shows
the traceback of an error.
presets: {presets}

{axes}
"""


def _epilog() -> str:
    """The help's epilog: examples, presets and the values of the spec's named axes (from
    the technique registry and the estimators' vocabularies, experiments.spec.axis_help)."""
    from experiments.spec import axis_help

    return _EPILOG.format(presets=", ".join(available_presets()), axes=axis_help())

DEFAULT_PRESET = "thesis"


def build_parser() -> argparse.ArgumentParser:
    p = cli.ArgumentParser(
        prog="python -m experiments.sweep",
        description="Run an experiment spec (TOML) as a parallel, resumable sweep and write "
                    "cells.parquet, tables.md/CSV, REPORT.md and figures to results/<name>/.",
        epilog=_epilog(),
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("spec", nargs="?", help="spec TOML file (default: --preset thesis)")
    p.add_argument("--preset", metavar="NAME",
                   help=f"run a shipped preset from experiments/presets/ (default {DEFAULT_PRESET!r}); "
                        "e.g. --preset quick")
    p.add_argument("--out", metavar="DIR",
                   help="results folder (default results/<spec name>/ for "
                        f"{', '.join(sorted(TOP_LEVEL_RUNS))}, else the ignored "
                        "results/local/<spec name>/), e.g. --out /tmp/thesis")
    p.add_argument("--jobs", type=cli.jobs_arg, metavar="N",
                   help=f"worker processes (default all cores = {os.cpu_count()}); 1 = in-process")
    p.add_argument("--backend", choices=("loky", "dask"), default="loky",
                   help="loky: joblib processes on this machine (default); dask: a Dask cluster")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="Dask scheduler address for --backend dask, e.g. tcp://127.0.0.1:8786 "
                        "(default: start a LocalCluster of --jobs workers)")
    p.add_argument("--force", action="store_true", help="recompute finished cells")
    p.add_argument("--solver", choices=SOLVERS,
                   help="override every cell's solver; results go to results/<name>-<solver>/, "
                        "e.g. --solver slsqp")
    p.add_argument("--seeds", type=cli.positive_int, metavar="N",
                   help="override the number of seeds (seeds 0..N-1), e.g. --seeds 3")
    p.add_argument("--cache-dir", metavar="DIR",
                   help="simulated-truth cache (default results/cache/truth), e.g. "
                        "--cache-dir /tmp/empty to time a cold run")
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


def _started() -> int:
    """A worker's first task: the imports of a simulation (its likely next task)."""
    import sim.rover  # noqa: F401

    return os.getpid()


def _prestart(jobs: int) -> Iterator[int]:
    """Start the ``jobs`` loky workers now, before the spec is read and checked here (their
    interpreter start and first imports overlap that, about 1 s); returns the iterator of
    their first tasks, to keep until the run is done."""
    from joblib import Parallel, delayed

    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")      # as run() sets them, before any worker starts
    return Parallel(n_jobs=jobs, backend="loky", return_as="generator_unordered")(
        delayed(_started)() for _ in range(jobs))


def _likely_work(args: argparse.Namespace) -> bool:
    """Whether the run will probably compute cells (so starting the workers early pays):
    --force, or a results folder without finished cells. For a spec file without --out the
    folder is not known before the spec is read: yes."""
    if args.force:
        return True
    if args.out is None and args.spec:
        return True
    name = (args.preset or DEFAULT_PRESET) + (f"-{args.solver}" if args.solver else "")
    cells = (Path(args.out) if args.out is not None else default_out(name)) / "cells"
    return not (cells.is_dir() and any(cells.glob("*.json")))


def main(argv: list[str] | None = None) -> int:
    """CLI entry point; returns the exit code (0 ok, 1 some cells failed, 2 bad spec or
    option, 3 the run could not go on: unreachable scheduler, unwritable results folder,
    the folder in use by another run). Through :mod:`experiments.cli` (``python -m``):
    130 on Ctrl-C, 143 on SIGTERM, the manifest marked ``interrupted``, no worker left."""
    args = build_parser().parse_args(argv)
    if args.spec and args.preset:
        print("error: give a spec file or --preset, not both", file=sys.stderr)
        return 2
    # joblib warns on an interrupt that it cancelled the workers' tasks: the CLI reports the
    # interrupt in one line (experiments.cli)
    warnings.filterwarnings("ignore", message=r"\d+ tasks (which were still|have been successfully)",
                            category=UserWarning)
    jobs = args.jobs or (os.cpu_count() or 1)
    started = (_prestart(jobs) if args.backend == "loky" and jobs > 1 and _likely_work(args)
               else iter(()))
    try:
        code = _main(args)
    except BaseException:
        _stop_workers()         # interrupted: the workers' tasks are not waited for
        raise
    for _ in started:           # (long done)
        pass
    _stop_workers()
    return code


def _stop_workers() -> None:
    """End the loky workers of this process now, busy or idle, through loky's public API:
    the CLI is done with them (at interpreter exit each would first tear itself down and
    the exit wait, ~0.3 s), or the run was interrupted (no worker may outlive it).
    ``reuse=False`` replaces the process's executor instead of resizing it (no worker is
    started), ``kill_workers=True`` ends the workers of the one it replaces."""
    from joblib.externals.loky import get_reusable_executor

    get_reusable_executor(reuse=False, kill_workers=True).shutdown(wait=True,
                                                                   kill_workers=True)


def _main(args: argparse.Namespace) -> int:
    try:
        spec = load_spec(args.spec or args.preset or DEFAULT_PRESET)
        if args.solver:
            spec = spec.with_solver(args.solver)
        if args.seeds is not None:
            spec = spec.with_seeds(range(args.seeds))
    except SpecError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    try:
        res = run(spec, out=args.out, jobs=args.jobs, backend=args.backend,
                  scheduler=args.scheduler, force=args.force, progress=not args.quiet,
                  figures=not args.no_figures, cache_dir=args.cache_dir)
    except SweepError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 3
    except OSError as exc:  # e.g. the results folder cannot even be created
        print(f"error: cannot write {exc.filename or args.out or 'the results folder'}: "
              f"{exc.strerror or exc}", file=sys.stderr)
        return 3
    for e in res.errors[:10]:
        print(f"FAILED cell {e['key']} {json.dumps(e['params'])}: {e['error']}", file=sys.stderr)
    if len(res.errors) > 10:
        print(f"... and {len(res.errors) - 10} more failed cells, see {res.out_dir}/errors.json",
              file=sys.stderr)
    print(res.summary())
    return 1 if res.errors else 0


if __name__ == "__main__":
    cli.run(main)
