"""Run a spec: ``run(spec) -> Results``, the sweep's one pipeline from a spec to its tables.

Data flow: the spec expands into cells (:meth:`experiments.spec.Spec.expand`); the store
(:mod:`experiments.runner.store`) says which are finished; the truths of the rest are
simulated once per (path, configuration) (:func:`experiments.runner.backends.iter_truths`)
and their cells run on an executor (:mod:`experiments.runner.backends`: this process, loky
or Dask), each cell observe -> track -> score (:mod:`experiments.runner.cell`) and written
by its worker as it finishes; ``cells.parquet`` is assembled from the cell files, and the
outputs phase (:mod:`experiments.outputs`) writes the tables, REPORT.md, figures and page.

With loky and several jobs the run is pipelined: the cells of a truth start on the workers
the moment it is ready, beside the simulations still running, and idle workers warm up
(imports, fonts) meanwhile. ``manifest.json`` (tracked in reference runs) holds only what
determines the numbers; what varies per run goes to the git-ignored ``run.local.json``.

A finished run records in the store's index the digest of everything its outputs depend on
and of the files it left (:func:`settled_digest`); a resume that finds them all unchanged
stops after checking the cell files (no cell table, no outputs phase, no pandas: 0.2-0.3 s
inside the thesis preset's resume instead of 1.1-1.6 s, load 7; tests/test_resume.py).
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
import tempfile
import threading
import time
import uuid
from collections import OrderedDict
from collections.abc import Callable
from contextlib import suppress
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from experiments.provenance import code_version
from experiments.runner.backends import (
    Loky,
    batches,
    check_scheduler,
    executor,
    iter_truths,
    one_blas_thread,
    simulate_all,
    stop_workers,
)
from experiments.runner.cell import CellFn, cell_code_digest
from experiments.runner.store import (
    CellStore,
    SweepError,
    folder_lock,
    json_text,
    read_text,
    unwritable,
    write_json,
    write_table,
    write_text,
)
from experiments.runner.worker import CellJob, timeline, warm_up
from experiments.spec import PROJECT_DIR, REPO, RESULTS_ROOT, Cell, Spec, load_spec
from sim.atomic import file_stat

# pandas is imported where it is used: the main process simulates before it needs pandas
# (0.4 s of imports off the critical path of a one-path sweep)
if TYPE_CHECKING:
    import pandas as pd

__all__ = ["RESULTS_DIR", "TOP_LEVEL_RUNS", "Results", "default_out", "import_for_outputs",
           "discard_code_version", "run", "start_code_version"]

RESULTS_DIR = RESULTS_ROOT
#: Runs whose default folder is results/<name>/: the committed reference runs and the quick
#: smoke run (ignored by .gitignore). Any other spec (the example presets, a spec file)
#: defaults to results/local/<name>/, which git ignores, so no run dirties the checkout.
TOP_LEVEL_RUNS = frozenset({"thesis", "thesis-elastic", "speed", "quick"})
#: What :func:`import_for_outputs` imports.
OUTPUT_MODULES = ("pandas", "pyarrow.parquet", "markdown_it", "experiments.figures",
                  "experiments.outputs", "experiments.page", "experiments.causes")


def default_out(name: str) -> Path:
    """The results folder of a run named ``name`` without ``--out`` (see TOP_LEVEL_RUNS)."""
    return RESULTS_DIR / name if name in TOP_LEVEL_RUNS else RESULTS_DIR / "local" / name


@dataclass
class Results:
    """What :func:`run` returns (and writes to ``out_dir``)."""

    spec: Spec
    out_dir: Path
    errors: list[dict]                # one dict per failed cell: params, error, traceback
    n_cells: int
    n_computed: int
    n_resumed: int
    wall_s: float
    timings: dict = field(default_factory=dict)
    #: the cell table, or what reads it (a settled resume reads cells.parquet when asked)
    table: pd.DataFrame | Callable[[], pd.DataFrame] | None = field(default=None, repr=False)

    @property
    def cells(self) -> pd.DataFrame:
        """The cell table, one row per cell x mask."""
        if callable(self.table):
            self.table = self.table()
        return self.table

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
    cell_fn, truth_fn : replace :func:`experiments.runner.cell.evaluate_cell` /
        :func:`experiments.runner.cell.simulate_truth` (tests).
    """
    t_start = time.perf_counter()
    version = _take_code_version()       # git's processes run beside the plan
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
    one_blas_thread()
    out_dir = Path(out) if out is not None else default_out(spec.name)
    out_dir.mkdir(parents=True, exist_ok=True)
    opts = _Options(jobs=jobs, backend=backend, scheduler=scheduler, force=force,
                    progress=progress, outputs=outputs, figures=figures,
                    cache_dir=str(cache_dir) if cache_dir else None, cell_fn=cell_fn,
                    truth_fn=truth_fn)
    with folder_lock(out_dir) as locked:
        with timeline("main open"):
            r = _Run(spec, out_dir, opts, version)
        return r.go(locked, t_start)


#: The code version being read in the background (:func:`start_code_version`), if any.
_PENDING_VERSION: list[Callable[[], dict]] = []


def start_code_version() -> None:
    """Start reading :func:`experiments.provenance.code_version` (git's processes: ~0.3 s
    of wall time for ~0.03 CPU-s while a sweep's workers start on the same cores) in a
    background thread; the next :func:`run` of this process takes the result. The CLI calls
    it first thing, so the wait is spent beside the workers' start, the spec and the
    plan, not before the simulation. Idempotent until a run takes it."""
    if _PENDING_VERSION:
        return
    box: dict = {}

    def read() -> None:
        try:
            box["value"] = code_version()
        except BaseException as exc:  # noqa: BLE001 - re-raised where the value is used
            box["error"] = exc

    th = threading.Thread(target=read, name="code-version", daemon=True)
    th.start()

    def result() -> dict:
        th.join()
        if "error" in box:
            raise box["error"]
        return box["value"]

    _PENDING_VERSION.append(result)


def discard_code_version() -> None:
    """Forget a code version started by :func:`start_code_version` that no run took (the
    CLI, when it stops before :func:`run`: a later run of this process reads its own)."""
    _PENDING_VERSION.clear()


def _take_code_version() -> Callable[[], dict]:
    """The pending code version (started now if none is), removed from the module: each
    run reads its own."""
    start_code_version()
    return _PENDING_VERSION.pop()


@dataclass(frozen=True)
class _Options:
    """:func:`run`'s options after validation."""

    jobs: int
    backend: str
    scheduler: str | None
    force: bool
    progress: bool
    outputs: bool
    figures: bool
    cache_dir: str | None
    cell_fn: CellFn | None
    truth_fn: Callable | None


class _Run:
    """One run in its results folder (held by :func:`folder_lock`): plan, compute, finish."""

    def __init__(self, spec: Spec, out_dir: Path, opts: _Options,
                 version: Callable[[], dict] = code_version):
        self.spec, self.out_dir, self.o = spec, out_dir, opts
        self.version = version          # the code version, read in the background
        self.store = CellStore(out_dir)
        self.cells = spec.expand()
        self.by_key = {c.key: c for c in self.cells}
        self.run_id = uuid.uuid4().hex
        self.epochs_note = False        # the outputs phase's note on per-epoch estimates
        self.job = CellJob(spec_seed=spec.seed, masks=spec.masks, session_s=spec.session_s,
                           run_id=self.run_id, cell_fn=opts.cell_fn, store_dir=str(out_dir))

    def go(self, locked: OSError | None, t_start: float) -> Results:
        with timeline("main plan"):
            todo, done, n_stale, n_damaged = self._plan(locked)
            manifest, run_info = self._start(todo, n_stale, n_damaged)
        settled = None if todo else self._settled(manifest, done)
        if settled is not None:
            return self._resumed(settled, t_start, manifest, run_info)
        try:
            n_now, t = self._compute(todo)
            res, out_info, t["outputs_s"] = self._finish(todo, done, n_now, manifest)
        except OSError as exc:
            raise self._disk_error(exc, manifest) from None
        except KeyboardInterrupt as exc:
            self._interrupted(exc, manifest)
            raise
        res.wall_s = time.perf_counter() - t_start
        res.timings = {**t, "wall_s": res.wall_s}
        if out_info:
            res.timings["outputs"] = {"written": out_info["written"],
                                      "unchanged": out_info["skipped"],
                                      "seconds": out_info["seconds"]}
        manifest["status"] = _final_status(res.errors)
        run_info.update({"finished_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                         "n_computed": res.n_computed, "n_resumed": res.n_resumed,
                         "n_failed": res.n_failed, "timings_s": res.timings})
        with timeline("main settle"):
            write_json(self.out_dir / "manifest.json", manifest)
            _write_run_info(self.out_dir, run_info, required=bool(todo))
            self._settle(json_text(manifest), out_info)
        return res

    # ---------------------------------------------------------------- settled
    def _settled(self, manifest: dict, done: set[str]) -> Results | None:
        """A resume with nothing to do: when the cells, cells.parquet, the outputs and every
        input of the outputs are as the last finished run left them (the store's index
        records their digest, :func:`settled_digest`), the results without reading the cell
        table (read when asked for) or running the outputs phase; else None."""
        t0 = time.perf_counter()
        keys = [c.key for c in self.cells]
        rec = self.store.settled(keys, self.code)
        if rec is None:
            return None
        errors = self.store.read_errors(keys)
        final = json_text({**manifest, "status": _final_status(errors)})
        if rec.get("digest") != settled_digest(self.out_dir, self.spec, self.o, self.code,
                                               final):
            return None
        res = Results(spec=self.spec, out_dir=self.out_dir, errors=errors,
                      n_cells=len(self.cells), n_computed=0, n_resumed=len(done), wall_s=0.0,
                      table=lambda: self.store.read_table(keys))
        res.timings = {"simulate_s": 0.0, "cells_s": 0.0, "outputs_s": time.perf_counter() - t0}
        if self.o.outputs and rec.get("units"):
            res.timings["outputs"] = {"written": [], "unchanged": rec["units"], "seconds": {}}
        if rec.get("epochs_note"):
            _epochs_note(self.spec.name)
        return res

    def _resumed(self, res: Results, t_start: float, manifest: dict, run_info: dict
                 ) -> Results:
        """Finish a settled resume: only run.local.json is written (where it can be)."""
        res.wall_s = time.perf_counter() - t_start
        res.timings["wall_s"] = res.wall_s
        manifest["status"] = _final_status(res.errors)
        run_info.update({"finished_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                         "n_computed": 0, "n_resumed": res.n_resumed,
                         "n_failed": res.n_failed, "timings_s": res.timings, "settled": True})
        write_json(self.out_dir / "manifest.json", manifest)      # unchanged: not rewritten
        _write_run_info(self.out_dir, run_info, required=False)
        return res

    def _settle(self, manifest_text: str, out_info: dict) -> None:
        """Record in the store's index the digest of the finished run (the next resume
        compares it, :meth:`_settled`)."""
        rec = {"digest": settled_digest(self.out_dir, self.spec, self.o, self.code,
                                        manifest_text),
               "units": sorted([*out_info.get("written", []), *out_info.get("skipped", [])]),
               "epochs_note": self.epochs_note}
        self.store.write_index([c.key for c in self.cells], self.code, settled=rec)

    # ---------------------------------------------------------------- plan
    def _plan(self, locked: OSError | None) -> tuple[list[Cell], set[str], int, int]:
        """The cells to compute (finished ones resume unless stale or damaged)."""
        store, by_key, name = self.store, self.by_key, self.spec.name
        if self.o.force and locked is not None:
            raise unwritable(self.out_dir, locked)
        if self.o.force:
            store.clear(by_key)
        done = store.done() & set(by_key)
        self.code = cell_code_digest()
        stale, damaged = store.check(done, self.code)
        if stale:
            print(f"{name}: {len(stale)} of {len(done)} finished cells were computed by "
                  "other code (estimator/, sim/ or the runner changed since); recomputing "
                  "them", file=sys.stderr)
        if damaged:
            print(f"{name}: {len(damaged)} of {len(done)} finished cells have damaged files "
                  "(unreadable cell record or per-epoch parquet, e.g. from a full disk); "
                  "recomputing them", file=sys.stderr)
        if locked is not None and (stale or damaged or len(done) < len(by_key)):
            raise unwritable(self.out_dir, locked)   # cells to compute: must be writable
        store.clear(stale | damaged)
        done -= stale | damaged
        return [c for c in self.cells if c.key not in done], done, len(stale), len(damaged)

    def _start(self, todo: list[Cell], n_stale: int, n_damaged: int) -> tuple[dict, dict]:
        """manifest.json (only what determines the numbers, paths relative to the project,
        so a rerun leaves it byte-identical), run.local.json and spec.toml; with nothing to
        compute only what changed is written (a read-only finished folder can be rerun)."""
        spec, out_dir = self.spec, self.out_dir
        self.before = read_text(out_dir / "manifest.json")
        manifest = {"spec": {**spec.to_dict(), "source": _rel(spec.source)},
                    "spec_raw": spec.raw, "spec_base_dir": _rel(spec.base_dir),
                    "spec_seed": spec.seed, "seeds": list(spec.seeds), "code": self.version(),
                    "cell_code": self.code, "n_cells": len(self.cells), "status": "running"}
        run_info = {"started_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                    "backend": self.o.backend, "jobs": self.o.jobs,
                    "cpu_count": os.cpu_count(), "n_stale": n_stale, "n_damaged": n_damaged}
        if todo:
            write_json(out_dir / "manifest.json", manifest)
        _write_run_info(out_dir, run_info, required=bool(todo))
        _write_spec_toml(spec, out_dir / "spec.toml")
        return manifest, run_info

    # ---------------------------------------------------------------- compute
    def _compute(self, todo: list[Cell]) -> tuple[int, dict]:
        """Simulate and compute ``todo``; returns (cells finished now, timings)."""
        from tqdm import tqdm

        self.bar = None
        t_sim0 = time.perf_counter()
        try:
            if todo and self.o.backend == "loky" and self.o.jobs > 1:
                n_now, t_sim, t_cells0 = self._pipelined(todo, t_sim0)
            else:
                truths = simulate_all(todo, self.spec, self.o.jobs, self.o.truth_fn,
                                      self.o.cache_dir, progress=self.o.progress) if todo else {}
                t_sim = time.perf_counter() - t_sim0
                t_cells0 = time.perf_counter()
                n_now = 0
                if todo:
                    self.bar = self._cell_bar(tqdm, len(todo))
                    ex = executor(self.o.backend, self.o.jobs, self.o.scheduler)
                    bs, wants = self._tasks(todo, truths)
                    n_now = self._store_results(ex.run_batches(bs, truths, wants, self.job))
        finally:
            if self.bar is not None:
                self.bar.close()
        t_overlap = max(0.0, t_sim0 + t_sim - (t_cells0 or t_sim0 + t_sim))
        t_cells = time.perf_counter() - t_cells0 if todo else 0.0
        return n_now, {"simulate_s": t_sim, "cells_s": t_cells,
                       "cells_beside_simulation_s": t_overlap}

    def _pipelined(self, todo: list[Cell], t_sim0: float) -> tuple[int, float, float | None]:
        """loky, several jobs: each truth's cells start on the workers the moment it is
        ready, beside the simulations still running; idle workers warm up meanwhile."""
        from tqdm import tqdm

        spec, jobs = self.spec, self.o.jobs
        by_truth: OrderedDict[tuple, list[Cell]] = OrderedDict()
        for c in todo:
            by_truth.setdefault(c.truth_key, []).append(c)
        sbar = tqdm(total=len(by_truth), unit="truth", desc=f"{spec.name}: simulate",
                    disable=not self.o.progress, dynamic_ncols=True)
        truths: dict = {}
        running, warm, t_cells0 = [], [], None
        loky = Loky(jobs)
        lock = os.path.join(tempfile.gettempdir(), f"configpose-warm-up-{self.run_id}.lock")

        elastic = any(c.solver == "elastic" for c in todo)

        def queue_warm_up() -> None:
            outputs = self.o.outputs and self.o.figures
            warm.append(loky.map_unordered(warm_up, ((outputs, lock, elastic)
                                                     for _ in range(jobs))))

        try:
            with timeline("main simulate"):
                for key, tr in iter_truths(todo, spec, jobs, self.o.truth_fn,
                                           self.o.cache_dir, on_queued=queue_warm_up):
                    truths[key] = tr
                    sbar.update()
                    bs, wants = self._tasks(by_truth[key], truths)
                    t_cells0 = t_cells0 or time.perf_counter()
                    running.append(loky.run_batches(bs, truths, wants, self.job))
        finally:
            sbar.close()
        t_sim = time.perf_counter() - t_sim0
        if self.o.outputs:
            with timeline("main import for outputs"):
                import_for_outputs()      # while the workers compute the cells
        self.bar = self._cell_bar(tqdm, len(todo))
        with timeline("main wait for cells"):
            n_now = sum(self._store_results(it) for it in (*warm, *running))
        if warm:
            with suppress(OSError):
                os.remove(lock)
        return n_now, t_sim, t_cells0

    def _tasks(self, cells: list[Cell], truths: dict) -> tuple[list, list]:
        """The batches of ``cells`` and, per cell, whether to keep its per-epoch table."""
        bs = batches(cells, self.o.jobs,
                     lambda c: len(getattr(truths[c.truth_key], "t", ())) or 1)
        return bs, [[self.spec.epochs_wanted(c) for c in b] for b in bs]

    def _cell_bar(self, tqdm, n: int):
        return tqdm(total=n, unit="cell", desc=self.spec.name, disable=not self.o.progress,
                    smoothing=0.1, dynamic_ncols=True)

    def _store_results(self, it) -> int:
        """Persist the cell records an iterator of batches yields (workers that wrote their
        own cells say so with ``written``), advance the bar; return the number of cells
        seen. A warm-up's process id (an int) is skipped."""
        n = 0
        for results in it:
            if isinstance(results, int):
                continue
            for res in results:
                if not res.get("written"):
                    self.store.write(self.by_key[res["key"]], res)
            self.store.prefetch(r["key"] for r in results if r["ok"])
            n += len(results)
            self.bar.update(len(results))
        return n

    # ---------------------------------------------------------------- finish
    def _finish(self, todo: list[Cell], done: set[str], n_now: int, manifest: dict
                ) -> tuple[Results, dict, float]:
        """cells.parquet, errors.json and the outputs phase; returns (results, the outputs
        phase's record, its seconds)."""
        t_out0 = time.perf_counter()
        out_dir = self.out_dir
        keys = [c.key for c in self.cells]
        with timeline("main table"):
            table = self.store.read_table(keys)
            errors = self.store.read_errors(keys)
            final = json_text({**manifest, "status": _final_status(errors)})
            if n_now or final != self.before or not (out_dir / "cells.parquet").exists():
                write_table(table, out_dir / "cells.parquet")
            self.store.write_index(keys, self.code)
            write_json(out_dir / "errors.json", errors)
            # the manifest of this run before the outputs (the report and the page show
            # it): with nothing to compute it was not written yet, and the report showed
            # the code line of the run before
            write_text(out_dir / "manifest.json", final)
        res = Results(spec=self.spec, out_dir=out_dir, table=table, errors=errors,
                      n_cells=len(self.cells), n_computed=n_now - len(errors),
                      n_resumed=len(done), wall_s=0.0)
        self.epochs_note = bool(self.o.outputs and self.o.figures and not table.empty
                                and ("has_epochs" not in table or not table["has_epochs"].any()))
        out_info = self._outputs(table) if self.o.outputs and not table.empty else {}
        return res, out_info, time.perf_counter() - t_out0

    def _outputs(self, table: pd.DataFrame) -> dict:
        """Tables, report, figures (side by side in the workers) and index.html, each only
        where its inputs changed (experiments.outputs)."""
        from tqdm import tqdm

        from experiments.outputs import n_steps, write_outputs

        spec, figures = self.spec, self.o.figures
        obar = tqdm(total=n_steps(figures), unit="step", desc=f"{spec.name}: outputs",
                    disable=not self.o.progress, dynamic_ncols=True)
        try:
            out_info = write_outputs(table, self.out_dir, spec=spec,
                                     jobs=self.o.jobs if self.o.backend == "loky" else 1,
                                     figures=figures, on_step=lambda _name: obar.update())
        finally:
            obar.close()
        if figures and ("has_epochs" not in table or not table["has_epochs"].any()):
            _epochs_note(spec.name)
        return out_info

    def _disk_error(self, exc: OSError, manifest: dict) -> SweepError:
        """A full disk or a write-protected folder: the cells written so far are safe
        (each one is atomic), the rerun resumes them; one line, no traceback."""
        manifest["status"] = "interrupted"
        try:
            write_json(self.out_dir / "manifest.json", manifest)
            marked = f"marked interrupted in {self.out_dir / 'manifest.json'}"
        except OSError:
            marked = "could not be marked interrupted (the folder is not writable)"
        where = exc.filename or self.out_dir
        return SweepError(f"cannot write {where}: {exc.strerror or exc}; the run {marked}; "
                          "free space or fix permissions and rerun the same command to "
                          "resume")

    def _interrupted(self, exc: KeyboardInterrupt, manifest: dict) -> None:
        """Ctrl-C or SIGTERM (experiments.cli): no worker outlives the run, the manifest
        says so, and the finished cells (each written atomically) are resumed by the rerun."""
        stop_workers()
        manifest["status"] = "interrupted"
        with suppress(OSError):
            write_json(self.out_dir / "manifest.json", manifest)
        n_kept = len(self.store.done() & set(self.by_key))
        exc.args = ((f"{n_kept} of {len(self.cells)} cells are finished in {self.out_dir}, "
                     "marked interrupted in its manifest.json; rerun the same command to "
                     "resume"),)


def import_for_outputs() -> None:
    """Import what the end of a run needs in this process (pandas and pyarrow for the cell
    table, the outputs phase, the page and its Markdown renderer; ~0.5 s). Called once the
    cells are queued on the workers, when this process would otherwise wait for them:
    imported at the end instead, they were on the critical path of a one-path sweep.
    (experiments.figures is imported for its figure groups' names: it imports matplotlib
    only to draw.)"""
    import importlib

    for name in OUTPUT_MODULES:
        importlib.import_module(name)


def _epochs_note(name: str) -> None:
    print(f"{name}: note: no cell kept per-epoch estimates (the spec has no [epochs] table), "
          "so the figures drawn from per-epoch errors were not written (box plots, "
          "orientation, overlays, sensor-1 lag): add '[epochs]' with 'seeds = [0]' to the "
          "spec", file=sys.stderr)


#: Files of a results folder that are not inputs of a settled resume: this run's sidecar,
#: the lock, the store's index (which holds the digest).
_VOLATILE = frozenset({"run.local.json", "lock.local.json", "cells.local.json"})
_EXPERIMENTS = Path(__file__).resolve().parents[1]


def outputs_code_digest() -> str:
    """Digest of every module of ``experiments/`` and the page's assets (a superset of
    :func:`experiments.outputs.code_digest`, without importing pandas)."""
    h = hashlib.blake2b(digest_size=16)
    files = [*_EXPERIMENTS.rglob("*.py"), *(_EXPERIMENTS / "page_assets").glob("*")]
    for f in sorted(files):
        if f.is_file() and "__pycache__" not in f.parts:
            h.update(f.relative_to(_EXPERIMENTS).as_posix().encode() + b"\0")
            h.update(f.read_bytes() + b"\0")
    return h.hexdigest()


def _folder_stats(folder: Path) -> dict[str, list[int] | None]:
    """{name: [size, mtime ns]} of the files directly in ``folder`` ({} when absent)."""
    try:
        names = [e.name for e in os.scandir(folder) if e.is_file()]
    except OSError:
        return {}
    return {n: file_stat(folder / n) for n in sorted(names) if n not in _VOLATILE}


def _declared_folders(spec: Spec) -> dict[str, list]:
    """The folders of the studies the spec declares ([report] sensitivity, [page] flight),
    each as every place its value may resolve to (experiments.spec._study_folder: the
    spec's folder, the project, the value itself), with their files' stats: what the
    outputs phase reads outside the results folder."""
    out: dict[str, list] = {}
    for table, field_ in (("report", "sensitivity"), ("page", "flight")):
        value = (spec.raw.get(table) or {}).get(field_)
        if isinstance(value, str):
            cands = {Path(value), Path(spec.base_dir) / value, PROJECT_DIR / value,
                     REPO / value}
            out[f"{table}.{field_}"] = [[str(c), _folder_stats(c)] for c in sorted(cands)]
    return out


def settled_digest(out_dir: Path, spec: Spec, opts: _Options, code: str,
                   manifest_text: str) -> str:
    """Digest of everything a finished run's outputs depend on and of what it left in
    ``out_dir``: the cell code and the code of experiments/ (which holds every rule of the
    outputs phase), the spec, the options that shape the outputs, this run's manifest,
    the stats of the folder's files (cells.parquet, errors.json, every output and
    outputs.local.json; the cell files are the index's) and of errors/, and the declared
    studies' folders. Equal on a resume: the outputs are current, nothing needs doing."""
    parts = {"cell_code": code, "outputs_code": outputs_code_digest(), "spec": spec.raw,
             "outputs": opts.outputs, "figures": opts.figures, "manifest": manifest_text,
             "folder": _folder_stats(out_dir), "errors": _folder_stats(out_dir / "errors"),
             "declared": _declared_folders(spec)}
    return hashlib.blake2b(json.dumps(parts, sort_keys=True, default=str).encode(),
                           digest_size=16).hexdigest()


def _final_status(errors: list) -> str:
    return "complete" if not errors else "complete_with_errors"


def _write_run_info(out_dir: Path, info: dict, required: bool) -> None:
    """run.local.json (this run's times and counts, git-ignored): when the run computed
    nothing, written where the folder allows it (a read-only finished run can be rerun)."""
    try:
        write_json(out_dir / "run.local.json", info)
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
    write_text(path, header + tomli_w.dumps(spec.raw))


def _rel(path: str | Path) -> str:
    """``path`` relative to the project when it lies inside it (machine-independent in
    tracked files), else as given (e.g. "<dict>" or a spec elsewhere)."""
    p = Path(path)
    try:
        return p.resolve().relative_to(REPO).as_posix() if p.is_absolute() else str(path)
    except ValueError:
        return str(path)

