"""What a sweep's worker process runs: batches of cells, and its warm-up.

A batch is the cells of one truth (usually one noise key: they share the observations and
the trackers' memos). :func:`run_batch` never raises for a cell's error: a failed cell is
a record with the error and its traceback. The worker's memos (observations,
configurations, the trackers' :class:`estimator.memo.TrackCache`) live for one run only:
worker processes outlive a run, and files may change between runs.
"""

from __future__ import annotations

import ctypes
import hashlib
import json
import os
import tempfile
import time
import traceback
from collections import OrderedDict
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from estimator.memo import TrackCache, ledger
from experiments.runner.cell import CellContext, CellFn, cell_code_digest, evaluate_cell
from experiments.runner.store import CellStore
from experiments.spec import Cell

__all__ = ["KERNEL_LOCK", "TIMELINE_ENV", "CellJob", "after_started", "mark",
           "process_started", "release_memos", "run_batch", "started", "timeline",
           "trim_heap", "warm_up"]

#: Lock file under which a worker compiles or loads the numba kernels (one at a time), one
#: per checkout (numba's cache is the checkout's ``__pycache__``), so that sweeps of other
#: checkouts do not wait for it (a quick run's workers once waited 17 s for a sweep's lock).
KERNEL_LOCK = os.path.join(tempfile.gettempdir(), "configpose-kernels-" + hashlib.blake2b(
    str(Path(__file__).resolve().parents[2]).encode(), digest_size=6).hexdigest() + ".lock")
#: Environment variable naming a file to which every worker task (simulation, warm-up,
#: batch of cells, output unit) and each phase of the main process appends one JSON line
#: {what, pid, start, end (Unix s), cpu_s, n, rss_mb}: the sweep's timeline, for measuring
#: the scheduling (unset: nothing is written).
TIMELINE_ENV = "CONFIGPOSE_TIMELINE"


@contextmanager
def timeline(what: str, n: int = 0) -> Iterator[None]:
    """Append this task's line to the file named by :data:`TIMELINE_ENV`, if set (one
    ``write`` of one line in append mode: lines of several processes do not interleave)."""
    path = os.environ.get(TIMELINE_ENV)
    if not path:
        yield
        return
    t0, c0 = time.time(), time.process_time()
    try:
        yield
    finally:
        mark(what, t0, c0, n)


def mark(what: str, t0: float, c0: float = 0.0, n: int = 0) -> None:
    """Append one line of the timeline (:func:`timeline`) for a span that began at ``t0``
    (Unix s) with this process's CPU time ``c0``; the line's ``rss_mb`` is the process's
    resident memory at its end (Linux; what loky's leak check compares). Nothing when
    :data:`TIMELINE_ENV` is unset."""
    path = os.environ.get(TIMELINE_ENV)
    if not path:
        return
    line = json.dumps({"what": what, "pid": os.getpid(), "start": t0, "end": time.time(),
                       "cpu_s": time.process_time() - c0, "n": n, "rss_mb": _rss_mb()})
    with open(path, "a", encoding="utf-8") as fh:
        fh.write(line + "\n")


def process_started() -> float:
    """When this process started (Unix s, Linux: /proc, 10 ms resolution); now elsewhere."""
    try:
        with open("/proc/self/stat", encoding="ascii") as fh:
            ticks = int(fh.read().rsplit(")", 1)[1].split()[19])
        age = time.clock_gettime(time.CLOCK_BOOTTIME) - ticks / os.sysconf("SC_CLK_TCK")
        return time.time() - age
    except (OSError, ValueError, IndexError, AttributeError):
        return time.time()


def _rss_mb() -> float | None:
    """This process's resident set size in MB (None where /proc is absent)."""
    try:
        with open("/proc/self/statm", encoding="ascii") as fh:
            return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6
    except (OSError, ValueError, IndexError):
        return None


@dataclass(frozen=True)
class CellJob:
    """What every batch of a run shares (sent with each batch to its worker).

    spec_seed, masks, session_s : the spec's. run_id : the run the worker's memos belong
    to. cell_fn : replaces :func:`experiments.runner.cell.evaluate_cell` (tests).
    store_dir : the results folder the worker writes each finished cell to (workers that
    share the file system: in-process and loky); None: the results travel back (Dask).
    """

    spec_seed: int
    masks: tuple[str, ...]
    session_s: float
    run_id: str = ""
    cell_fn: CellFn | None = None
    store_dir: str | None = None


class _WorkerMemo:
    """This process's memos and the run they belong to."""

    def __init__(self) -> None:
        self.memo: OrderedDict[tuple, Any] = OrderedDict()
        #: the trackers' memos (the techniques of one noise key share fits and filter
        #: passes: in the thesis preset 470 of 840 procrustes fits are repeats)
        self.cache = TrackCache()
        self.run_id = ""
        self._code = ""

    def for_run(self, run_id: str) -> _WorkerMemo:
        if self.run_id != run_id:
            self.memo.clear()
            self.cache.clear()
            self.run_id = run_id
            self._code = ""
        return self

    @property
    def code(self) -> str:
        """The cell code digest, read once per run (not once per cell)."""
        if not self._code:
            self._code = cell_code_digest()
        return self._code


WORKER = _WorkerMemo()


def release_memos() -> None:
    """Forget this process's per-run memos and hand the freed heap back to the OS (glibc's
    ``malloc_trim``; elsewhere only the memos go): called when the outputs phase starts
    in a worker, whose cells are all done. loky replaces a worker whose resident size grew
    300 MB past its size after its first task as "leaking": what a worker grew by during
    the thesis preset's cells (~240 MB, its memos among it) plus a figure group crossed
    that (a worker replaced during the outputs, its start-up on the critical path, and a
    UserWarning). Once per run; no
    ``gc.collect`` (0.08 CPU-s in a worker, on the critical path of the first output unit:
    the memos' arrays go with their last reference, and loky collects before it replaces)."""
    if not WORKER.run_id:
        return
    WORKER.memo.clear()
    WORKER.cache.clear()
    WORKER.run_id = ""
    trim_heap()


def trim_heap() -> None:
    """Hand the heap's free pages back to the OS (glibc's ``malloc_trim``, ~1 ms; nothing
    elsewhere), so that the resident size loky's leak check reads after a task is what is
    alive, not what the task freed."""
    with suppress(OSError, AttributeError):        # no glibc (macOS, Windows, musl)
        ctypes.CDLL(None).malloc_trim(0)


def run_batch(cells: list[Cell], truth: Any, want: list[bool], job: CellJob) -> list[dict]:
    """Run a batch of cells (same truth) in this worker; ``want[i]``: keep cell i's
    per-epoch table. Returns one record per cell: with ``job.store_dir`` each cell is
    persisted the moment it finishes and only its key and status come back; without it
    the whole result (the parent writes it)."""
    with timeline(f"cells {Path(str(cells[0].path)).stem if cells else ''}", len(cells)):
        return _run_batch(cells, truth, want, job)


def _run_batch(cells: list[Cell], truth: Any, want: list[bool], job: CellJob) -> list[dict]:
    state = WORKER.for_run(job.run_id)
    store = CellStore(Path(job.store_dir), state.code) if job.store_dir else None
    out = []
    for cell, w in zip(cells, want):
        ctx = CellContext(spec_seed=job.spec_seed, masks=job.masks, session_s=job.session_s,
                          want_epochs=w, memo=state.memo, cache=state.cache)
        out.append(_one_cell(job.cell_fn or evaluate_cell, cell, truth, ctx))
        if store is not None:
            store.write(cell, out[-1])
            out[-1] = {"key": cell.key, "ok": out[-1]["ok"], "written": True}
    return out


def _one_cell(fn: CellFn, cell: Cell, truth: Any, ctx: CellContext) -> dict:
    """One cell's record: its result, or its error (a cell's failure is data)."""
    t0 = time.perf_counter()
    try:
        with ledger() as reused:
            res = fn(cell, truth, ctx)
        res.timings["t_cell_s"] = time.perf_counter() - t0
        # what the cell took from the per-process memo (estimator.memo), at the cost it
        # had when computed: t_track_s + t_reused_s is the cell's stand-alone cost
        res.timings["t_reused_s"] = reused.seconds
        return {"key": cell.key, "ok": True, "rows": res.rows, "epochs": res.epochs,
                "timings": res.timings, "status_counts": res.status_counts}
    except Exception as exc:  # noqa: BLE001 - a cell's failure is data, not a crash
        return {"key": cell.key, "ok": False, "error": f"{type(exc).__name__}: {exc}",
                "traceback": traceback.format_exc(limit=20)}


def warm_up(outputs: bool, lock_path: str | None = None, elastic: bool = False) -> int:
    """A worker's first task beside the simulations: import what the cells (and, with
    ``outputs``, the tables, report and figures) need and load matplotlib's fonts, so
    that start-up cost is paid while a simulation runs, not on the critical path.

    ``lock_path``: the workers warm up one at a time (an exclusive lock on that file), so
    that beside a simulation running in the main process they take the one spare core
    instead of competing with the simulation for both (two workers warming up at once
    beside it made a 3.0 s simulation take 3.7 s). ``elastic``: the run has elastic-solver
    cells, so the elastic fit's compiled kernel is loaded (or, on a fresh checkout, compiled
    by the first worker under the lock) too. Returns the worker's process id.

    A worker that finds the lock taken (another is warming up) skips its warm-up instead of
    waiting for it, unless ``elastic`` (one compile of that kernel): it goes on to the cells
    queued behind, and its imports come with its first output unit (the quick preset: the
    second worker waited ~0.5 s, its core idle, with the cells queued)."""
    with _exclusive(lock_path, wait=elastic) as mine:
        if not mine:
            return os.getpid()
        with timeline("warm-up"):
            _warm_up_imports(outputs)
            if elastic:
                from estimator.elastic import warm_kernel

                warm_kernel()
    return os.getpid()


@contextmanager
def _exclusive(lock_path: str | None, wait: bool = True) -> Iterator[bool]:
    """Hold an exclusive advisory lock on ``lock_path`` (created if absent) for the block;
    no lock where there is no path, no ``fcntl`` (Windows) or the file cannot be opened or
    locked (e.g. a read-only temporary folder): the lock only orders work, nothing needs it.
    The block gets True, or False when ``wait`` is off and another process holds the lock
    (then it is not taken)."""
    try:
        import fcntl
    except ImportError:                                   # pragma: no cover - Windows
        fcntl = None
    fh = None
    if lock_path is not None and fcntl is not None:
        try:
            fh = open(lock_path, "a")                     # noqa: SIM115 (closed below)
            fcntl.flock(fh, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
        except BlockingIOError:
            fh.close()
            yield False
            return
        except OSError:
            if fh is not None:
                fh.close()
            fh = None
    try:
        yield True
    finally:
        if fh is not None:
            fcntl.flock(fh, fcntl.LOCK_UN)
            fh.close()


def _warm_up_imports(outputs: bool) -> None:
    import estimator.tracking  # noqa: F401
    import sim.gps  # noqa: F401
    from estimator.pose_smoother import warm_kernels

    warm_kernels()      # compiled once (first worker, under the lock), then cache loads

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


def started() -> int:
    """A worker's first task: the imports of the cells (~150 MB). loky takes a worker's
    reference memory size after its first task and replaces a worker that grows 300 MB
    beyond it as "leaking": measured after the simulation's imports alone (~60 MB), the
    cells' imports, numba and the per-run memos crossed that mid-run (thesis preset: a
    worker replaced, with its memos and warm-up lost, and a UserWarning "A worker stopped
    while some jobs were given to the executor"). The pose filter's kernels are loaded here
    too, one worker at a time (:data:`KERNEL_LOCK`): on a fresh checkout the first compiles
    them, which holds ~100 MB more of LLVM's memory, and counted after the reference size
    that alone made a worker "leak" mid-run (thesis preset with an empty numba cache: a
    worker replaced).

    Not the simulator (:mod:`sim.rover`, MuJoCo: ~0.2 CPU-s, ~20 MB): a one-truth run (the
    quick preset) simulates in the main process and its workers never need it; a worker
    that simulates imports it with its first simulation (20 MB beyond the reference size,
    far below loky's 300 MB).

    Idempotent: a worker runs it once (:func:`after_started` runs it before any loky task
    of a worker that has not, so it is in the first task even where the sweep started no
    workers early: a rerun over a folder whose cells the current code must recompute)."""
    global _STARTED
    if not _STARTED:
        with timeline("started"):
            import estimator.tracking  # noqa: F401
            import sim.gps  # noqa: F401
            from estimator.pose_smoother import warm_kernels

            with _exclusive(KERNEL_LOCK):
                warm_kernels()  # the compile's memory (first use of a checkout): in the reference
        _STARTED = True
    return os.getpid()


#: Whether this process ran :func:`started`.
_STARTED = False


def after_started(fn: Callable, *args: Any) -> Any:
    """``fn(*args)`` in a loky worker, after :func:`started` if this worker has not run it
    yet, so that its first task holds the cells' imports whatever that task is: loky takes
    the reference size after a worker's first task, and a first task that only loaded a
    cached truth (~75 MB) let the cells grow the worker past its 300 MB limit, replaced
    twice per thesis rerun with "A worker stopped while some jobs were given to the
    executor" (measured: a rerun after a code change, no early start)."""
    started()
    return fn(*args)

