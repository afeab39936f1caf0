"""One cell of a sweep: observe -> track -> score (the code that computes a cell's numbers).

Pipeline per cell (one point of the grid, one seed; :mod:`experiments.runner.run` hands
each worker its cells and the truth they share):

1. truth: each distinct (path, configuration) is simulated once, before its cells
   (:func:`simulate_truth`, through the on-disk truth cache, :mod:`sim.cache`);
2. noise: a stationary GPS session of ``spec.session_s`` seconds (the dissertation's ~4000 s
   recording, 000_8f82f8df647bf685.txt Section 4.1.1) is synthesized for the cell's seed,
   cut after its power failure, and a random stretch of it replayed onto the truth: truth +
   (observation - that receiver's session mean), Section 4.1.2. Cells that share (truth,
   noise model, seed) share the observations (common random numbers: techniques are
   compared on identical data);
3. estimate: :func:`estimator.tracking.track` with the cell's window, weighting, technique
   and solver, or a plug-in's tracker (:func:`estimator.trackers.base.run_tracker`);
4. score: Eq. 4.1 / 4.2 errors per evaluation mask (full path, no turns), summarised
   (:func:`estimator.scoring.score_track`).

A cell naming a ``recording`` (:mod:`sim.recording`) takes its observations from the
recording (or, for a recording with ``[replay]``, its reference plus the error replayed
for the cell's seed) instead of steps 1-2, and is scored against the recording's reference
with the same statistics; a recording without a reference gives coverage rows (epochs,
estimates, NaN estimates, status counts) only, and no per-epoch file. Every recording cell
also records the layout check of :func:`estimator.layout_check.check_layout` (mirror and
forward-axis verdicts, ``layout_*`` columns).

Randomness: every stream is a ``numpy.random.Generator`` seeded from
``SeedSequence([spec.seed, cell.seed, stream])``; the same spec and seed give bit-identical
numbers in any order, on any number of workers.

This module's source is part of the cell digest (:data:`CELL_SOURCES`); the store, the
scheduling and the CLI are not, so editing them recomputes nothing.
"""

from __future__ import annotations

import json
import math
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from estimator.memo import TrackCache
from estimator.scoring import ScoringReference, coverage_rows, score_track, status_counts
from estimator.track_options import FILTER_METHODS
from experiments.spec import REPO, Cell
from experiments.techniques import Technique, technique

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["CELL_SOURCES", "STREAM_ESTIMATOR", "STREAM_NOISE", "CellContext", "CellFn",
           "CellOutput", "cell_code_digest", "cell_rng", "evaluate_cell",
           "evaluate_recording_cell", "filter_params_for", "simulate_truth"]

#: Random streams derived per (spec seed, cell seed).
STREAM_NOISE, STREAM_ESTIMATOR = 0, 1

#: A cell function: (cell, truth, context) -> CellOutput. Pluggable for tests.
CellFn = Callable[[Cell, Any, "CellContext"], "CellOutput"]

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
def technique_of(cell) -> Technique:
    """The technique entry of a cell: its plug-in entry, else the registry's (duck-typed:
    anything with ``technique`` and optionally ``plugin``)."""
    plugin = getattr(cell, "plugin", None)
    return plugin if plugin is not None else technique(cell.technique)


def filter_params_for(truth):
    """The pose filter's parameters for a simulated vehicle (issue 14): its limits (the
    path's speed, acceleration, turn-rate and lateral-acceleration limits and the
    controller's yaw-acceleration limit, as the simulator drove them) and its no-slip point
    (the driven axle's midpoint, read from the vehicle model by the simulator). Nothing
    here is fitted to the truth's trajectory. A recording's reference has no simulator
    limits: its ``meta["platform"]`` (the [platform] block, PlatformLimits.to_dict) gives
    them, else the filter estimates limits and no-slip point from the observations
    (estimator.platform; issue 25)."""
    from estimator.platform import PlatformLimits
    from estimator.pose_filter import PoseFilterParams

    meta = truth.meta
    # simulated before issue 14: the rover, its axle under the CG
    ns = meta.get("no_slip_point_m", (0.0, 0.0) if "params" in meta else None)
    kw = {"no_slip_point_m": None if ns is None else (float(ns[0]), float(ns[1]))}
    if "params" not in meta and meta.get("platform") is not None:
        block = {k: v for k, v in meta["platform"].items() if k != "from" and v is not None}
        return PoseFilterParams.from_platform(PlatformLimits.from_dict(block), **kw)
    return PoseFilterParams.from_limits(meta.get("params", {}).get("controller") or {}, **kw)


#: Bounds of the worker memo's kinds (entries; least recently used out), each its own so
#: one kind never evicts another: a batch is one noise key's cells (backends.batches), so
#: the observations (n x m x 2 floats, 0.5 MB at 4000 epochs of 8 sensors) and the scoring
#: references (which hold a truth and its observations) of a few keys cover a worker whose
#: batches interleave chunks of keys (6: 3 MB); the configurations and noise names are one
#: small entry per model file of the spec (64: any spec's files, kilobytes).
MEMO_BOUNDS = {"obs": 6, "scoring": 6, "config": 64, "noise_name": 64}


def _memo_kind(ctx: CellContext, kind: str) -> OrderedDict:
    """The worker memo's entries of one kind (:data:`MEMO_BOUNDS`), an LRU dict."""
    return ctx.memo.setdefault((kind,), OrderedDict())


def _memoised(ctx: CellContext, kind: str, key: tuple, compute: Callable[[], Any]) -> Any:
    """``compute()`` through the worker memo's ``kind`` entries, bounded by
    :data:`MEMO_BOUNDS`."""
    memo = _memo_kind(ctx, kind)
    if key in memo:
        memo.move_to_end(key)
        return memo[key]
    value = memo[key] = compute()
    while len(memo) > MEMO_BOUNDS[kind]:
        memo.popitem(last=False)
    return value


def _observations(cell: Cell, truth, config, ctx: CellContext) -> np.ndarray:
    """Noisy observations (n, m, 2) for the cell's noise key, memoised per worker."""
    return _memoised(ctx, "obs", (ctx.spec_seed, ctx.session_s, *cell.noise_key),
                     lambda: _observe(cell, truth, config, ctx))


def _observe(cell: Cell, truth, config, ctx: CellContext) -> np.ndarray:
    from sim.gps import StationarySession, observe

    if cell.recording != "-":      # truth is the Recording (drawn per seed for a replay)
        return truth.observations(cell_rng(ctx.spec_seed, cell.seed, STREAM_NOISE),
                                  noise_overrides=json.loads(cell.noise_overrides) or None)
    if cell.noise == "none":
        return observe(truth, config, None)
    rng = cell_rng(ctx.spec_seed, cell.seed, STREAM_NOISE)
    noise = (StationarySession.load(cell.file("noise")) if cell.noise.startswith("session:")
             else cell.file("noise"))
    return observe(truth, config, noise, rng=rng, session_s=ctx.session_s,
                   noise_overrides=json.loads(cell.noise_overrides) or None)


def _scoring_reference(truth, obs: np.ndarray, ctx: CellContext) -> ScoringReference:
    """What the scoring needs of the truth and the observations, built once for the cells
    that share them (issue 27; the same numbers), by the identity of the objects (a
    reference holds both, so their ids stay theirs while it is memoised)."""
    return _memoised(ctx, "scoring", (id(truth), id(obs)),
                     lambda: ScoringReference.of(truth, obs))


def evaluate_cell(cell: Cell, truth, ctx: CellContext) -> CellOutput:
    """The real cell function: observations -> track -> scores (see the module docstring)."""
    import pandas as pd

    from estimator.configuration import SensorConfig

    if cell.recording != "-":
        return evaluate_recording_cell(cell, truth, ctx)
    t0 = time.perf_counter()
    config = _memoised(ctx, "config", (cell.file("config"),),
                       lambda: SensorConfig.load(cell.file("config")).planar())
    obs = _observations(cell, truth, config, ctx)
    t1 = time.perf_counter()
    fp = filter_params_for(truth) if technique_of(cell).uses_filter else None
    df = _track_cell(cell, truth.t, obs, config, truth.turning.astype(bool), ctx,
                     true_yaw=np.asarray(truth.yaw, dtype=float), filter_params=fp,
                     layout_check=False)
    t2 = time.perf_counter()
    rows, ep = score_track(df, truth, obs, config, ctx.masks, epochs=ctx.want_epochs,
                           reference=_scoring_reference(truth, obs, ctx))
    # the models' own names (a spec may name them by file, e.g. "rects/rect30.toml"): tables
    # and file names use these
    names = {"config_name": config.name,
             "path_name": str((getattr(truth, "meta", {}) or {}).get("path", {}).get("name", ""))
             or Path(cell.path).stem,
             "noise_name": _memo_noise_name(cell, ctx)}
    for row in rows:
        row.update(names)
    t3 = time.perf_counter()
    counts = status_counts(df)
    epochs = None
    if ctx.want_epochs:
        epochs = pd.concat([df.reset_index(drop=True), ep], axis=1)
    return CellOutput(rows=rows, epochs=epochs, status_counts=counts,
                      timings={"t_noise_s": t1 - t0, "t_track_s": t2 - t1, "t_score_s": t3 - t2})


def _memo_noise_name(cell: Cell, ctx: CellContext) -> str:
    """:func:`_noise_name` read once per noise file and worker memo (a TOML parse per cell
    was ~0.5 ms of its ~25 ms)."""
    return _memoised(ctx, "noise_name", (cell.noise, cell.file("noise")),
                     lambda: _noise_name(cell))


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

    tech = technique_of(cell)
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
    fp = None
    if technique_of(cell).uses_filter:
        # the recording's [platform] block (else its configuration's; None: limits from the
        # data), as filter_params_for reads it from a reference's meta (issue 25)
        from estimator.pose_filter import PoseFilterParams

        fp = PoseFilterParams.from_platform(rec.platform)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LayoutWarning)     # recorded in the rows instead
        df = _track_cell(cell, rec.t, obs, config,
                         None if truth is None else truth.turning.astype(bool), ctx,
                         true_yaw=None if truth is None else np.asarray(truth.yaw, dtype=float),
                         filter_params=fp)
    t2 = time.perf_counter()
    if truth is not None:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)   # all-NaN reference epochs
            rows, ep = score_track(df, truth, obs, config, ctx.masks, epochs=ctx.want_epochs)
        n_ref = int(np.isfinite(truth.cg[:, 0]).sum())
    else:           # no per-epoch file: the figures drawn from them need a reference
        rows, ep, n_ref = coverage_rows(df), None, 0
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
    counts = status_counts(df)
    epochs = None
    if ctx.want_epochs and ep is not None:
        epochs = pd.concat([df.reset_index(drop=True), ep], axis=1)
    return CellOutput(rows=rows, epochs=epochs, status_counts=counts,
                      timings={"t_noise_s": t1 - t0, "t_track_s": t2 - t1, "t_score_s": t3 - t2})




# --------------------------------------------------------------------------- versions
#: Source files whose code determines a cell's numbers (simulation, noise, estimation,
#: scoring: estimator/, sim/, the spec and its technique registry, this module). Their
#: digest is stored with every finished cell; a rerun recomputes the cells that other code
#: produced instead of mixing results of two code versions. The store, the scheduling and
#: the CLI (experiments/runner/{store,backends,worker,run}.py, experiments/sweep.py) are
#: not among them: a help-text typo recomputes nothing.
CELL_SOURCES = tuple(sorted(
    [*(REPO / "estimator").rglob("*.py"), *(REPO / "sim").glob("*.py"),
     REPO / "experiments" / "spec.py", REPO / "experiments" / "techniques.py",
     Path(__file__).resolve()]))


def cell_code_digest() -> str:
    """Digest (16 hex digits) of :data:`CELL_SOURCES` as they are on disk now."""
    from sim.cache import source_digest

    return source_digest(CELL_SOURCES)[:16]
