"""Where a sweep's cells run: one small executor interface over this process, joblib's loky
processes and a Dask cluster, plus the tasks they are given.

An :class:`Executor` takes batches of cells (:func:`batches`: one noise key per task when
there are enough for load balance, largest first) and yields each batch's records as it
finishes, in completion order (:func:`experiments.runner.worker.run_batch`). The truths are
simulated once per (path, configuration) before their cells (:func:`iter_truths`), side by
side in the loky workers when there are several. Loky workers are started early
(:func:`prestart`) and ended through loky's public API (:func:`stop_workers`); no private
API of Python or joblib is used.
"""

from __future__ import annotations

import math
import os
from collections import OrderedDict
from collections.abc import Callable, Iterable, Iterator
from typing import Any, Protocol

from experiments.runner.cell import simulate_truth, technique_of
from experiments.runner.store import SweepError
from experiments.runner.worker import CellJob, after_started, run_batch, started, timeline
from experiments.spec import Cell, Spec

__all__ = ["PASS_COST_CELLS", "Dask", "Executor", "InProcess", "Loky", "batches",
           "check_scheduler", "executor", "iter_truths", "prestart", "simulate_all",
           "stop_workers", "uses_pose_filter"]

#: Seconds to wait for a Dask scheduler before giving up with a clear message.
CONNECT_TIMEOUT_S = 5
#: Cost of the pose filter's forward pass in cells' worth of work (per epoch: ~135 us for the
#: pass against ~17 us for a window cell tracked and scored; measured on the thesis preset).
PASS_COST_CELLS = 8
_BLAS_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


class Executor(Protocol):
    """Runs batches of cells; yields each batch's records as it finishes (any order)."""

    def run_batches(self, batches: list[list[Cell]], truths: dict, wants: list[list[bool]],
                    job: CellJob) -> Iterator[list[dict]]:
        """The records of every batch (``truths``: truth key -> truth; ``wants``: per cell
        of each batch, keep its per-epoch table)."""
        ...


class InProcess:
    """Every batch in this process, one after the other (``--jobs 1``)."""

    def run_batches(self, batches, truths, wants, job) -> Iterator[list[dict]]:
        return (run_batch(b, truths[b[0].truth_key], w, job) for b, w in zip(batches, wants))


class Loky:
    """joblib's loky worker processes on this machine (reused across calls: several
    iterators may run side by side on the same workers, and start at once)."""

    def __init__(self, jobs: int):
        self.jobs = jobs

    def map_unordered(self, fn: Callable, args: Iterable[tuple]) -> Iterator[Any]:
        """``fn(*a)`` for each ``a`` of ``args`` on the workers, in completion order."""
        from joblib import Parallel, delayed

        par = Parallel(n_jobs=self.jobs, backend="loky", return_as="generator_unordered")
        return par(delayed(after_started)(fn, *a) for a in args)

    def run_batches(self, batches, truths, wants, job) -> Iterator[list[dict]]:
        return self.map_unordered(run_batch, ((b, truths[b[0].truth_key], w, job)
                                              for b, w in zip(batches, wants)))


class Dask:
    """A Dask cluster: the scheduler at ``scheduler`` (an address), else a LocalCluster of
    ``jobs`` worker processes. Workers may not share the file system: the records travel
    back and the parent writes them."""

    def __init__(self, jobs: int, scheduler: str | None = None):
        self.jobs, self.scheduler = jobs, scheduler

    def run_batches(self, batches, truths, wants, job) -> Iterator[list[dict]]:
        from dataclasses import replace

        from distributed import as_completed

        job = replace(job, store_dir=None)
        client, cluster = self._connect()
        try:
            tfut = {k: client.scatter(v, broadcast=False) for k, v in truths.items()}
            futs = [client.submit(run_batch, b, tfut[b[0].truth_key], w, job, pure=False)
                    for b, w in zip(batches, wants)]
            for fut in as_completed(futs):
                yield fut.result()
                fut.release()
        finally:
            client.close()
            if cluster is not None:
                cluster.close()

    def _connect(self):
        from distributed import Client, LocalCluster

        if self.scheduler:
            try:
                return Client(self.scheduler, timeout=f"{CONNECT_TIMEOUT_S}s"), None
            except (OSError, TimeoutError) as exc:
                raise SweepError(_no_scheduler(self.scheduler, exc)) from None
        cluster = LocalCluster(n_workers=self.jobs, threads_per_worker=1, processes=True,
                               dashboard_address=None)
        return Client(cluster), cluster


def executor(backend: str, jobs: int, scheduler: str | None = None) -> Executor:
    """The executor of ``backend`` ("loky": in this process when ``jobs`` is 1; "dask")."""
    if backend == "dask":
        return Dask(jobs, scheduler)
    return InProcess() if jobs == 1 else Loky(jobs)


# --------------------------------------------------------------------------- tasks
def uses_pose_filter(cell: Cell) -> bool:
    """Whether a cell runs the pose filter's forward pass: the filter family, and the lag
    correction fed the smoothed heading (see :func:`experiments.runner.cell.evaluate_cell`)."""
    return technique_of(cell).uses_filter


def batches(todo: list[Cell], jobs: int, epochs: Callable[[Cell], int] | None = None
            ) -> list[list[Cell]]:
    """Tasks for the workers, largest first.

    The cells of one noise key share their observations and, those that run the pose
    filter, one forward pass (both memoised per worker process: ``CellContext.memo`` and
    :mod:`estimator.memo`), so a noise key is one task when there are enough keys for load
    balance (4 tasks per worker); otherwise its cells are chunked, the pose-filter cells
    kept in one chunk. Tasks are ordered by estimated cost (cells x ``epochs(cell)``, a
    forward pass counted as :data:`PASS_COST_CELLS` cells), largest first, so the tasks
    that finish last are short and the workers finish together.
    """
    groups: OrderedDict[tuple, list[Cell]] = OrderedDict()
    for c in todo:
        groups.setdefault(c.noise_key, []).append(c)
    size = max(1, math.ceil(len(todo) / max(1, 4 * jobs)))      # cells per task
    out = []
    for cells in groups.values():
        out.extend([cells] if len(cells) <= size else _chunks(cells, size))
    n_ep = epochs or (lambda _c: 1)

    def cost(b: list[Cell]) -> float:
        passes = PASS_COST_CELLS if any(uses_pose_filter(c) for c in b) else 0
        return (len(b) + passes) * n_ep(b[0])

    out.sort(key=cost, reverse=True)       # stable: equal costs keep the spec's order
    return out


def _chunks(cells: list[Cell], size: int) -> list[list[Cell]]:
    """One noise key's cells in chunks of about ``size``, its pose-filter cells together."""
    pf = [c for c in cells if uses_pose_filter(c)]
    rest = [c for c in cells if not uses_pose_filter(c)]
    n_chunks = max(1, round(len(rest) / size))
    step = math.ceil(len(rest) / n_chunks) if rest else 1
    return ([pf] if pf else []) + [rest[i:i + step] for i in range(0, len(rest), step)]


# --------------------------------------------------------------------------- truths
def simulate_all(cells: list[Cell], spec: Spec, jobs: int, truth_fn, cache_dir,
                 progress: bool = False) -> dict:
    """The truth of every distinct (path, configuration) of ``cells``, simulated once (or
    loaded from the truth cache), side by side in worker processes when jobs > 1."""
    from tqdm import tqdm

    keys = list(OrderedDict.fromkeys(c.truth_key for c in cells))
    bar = tqdm(total=len(keys), unit="truth", desc=f"{spec.name}: simulate",
               disable=not progress, dynamic_ncols=True)
    out: dict = {}
    try:
        for k, tr in iter_truths(cells, spec, jobs, truth_fn, cache_dir):
            out[k] = tr
            bar.update()
    finally:
        bar.close()
    return {k: out[k] for k in keys}


def _keyed_truth(fn: Callable, key: tuple, *args: Any) -> tuple[tuple, Any]:
    with timeline(f"simulate {os.path.basename(str(key[0]))}"):
        return key, fn(*args)


def iter_truths(cells: list[Cell], spec: Spec, jobs: int, truth_fn, cache_dir,
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
    keys.sort(key=_simulated_s, reverse=True)      # the longest first: the critical path
    args = [(fn, k, *k, spec.sim_seed, cache_dir) for k in keys]
    if jobs > 1 and len(keys) > 1:
        # n_jobs = jobs (not fewer): the cells reuse the same worker processes
        sims = Loky(jobs).map_unordered(_keyed_truth, args)
        if on_queued is not None:
            on_queued()
        yield from sims
    else:
        if on_queued is not None:
            on_queued()
        for a in args:
            yield _keyed_truth(*a)


def _simulated_s(key: tuple) -> float:
    """Simulated seconds of a truth key's path (length / cruise speed), what its simulation
    costs; 0 when the path cannot be read here (its simulation reports why)."""
    from experiments.runner.cell import _load_path

    try:
        p = _load_path(key[0], key[1])
        return float(p.length_m / p.cruise_speed_mps)
    except Exception:  # noqa: BLE001 - only an ordering hint
        return 0.0


# --------------------------------------------------------------------------- workers
def one_blas_thread() -> None:
    """One BLAS / OpenMP thread per worker (set before any worker starts; a value in the
    environment wins): the cells' linear algebra is on tiny matrices."""
    for var in _BLAS_VARS:
        os.environ.setdefault(var, "1")


def prestart(jobs: int) -> Iterator[int]:
    """Start the ``jobs`` loky workers now, before the spec is read and checked here (their
    interpreter start and first imports overlap that, about 1 s); returns the iterator of
    their first tasks, to keep until the run is done."""
    one_blas_thread()
    return Loky(jobs).map_unordered(started, (() for _ in range(jobs)))


def stop_workers() -> None:
    """End the loky workers of this process now, busy or idle, through loky's public API:
    the CLI is done with them (at interpreter exit each would first tear itself down and
    the exit wait, ~0.3 s), or the run was interrupted (no worker may outlive it).
    ``reuse=False`` replaces the process's executor instead of resizing it (no worker is
    started), ``kill_workers=True`` ends the workers of the one it replaces."""
    from joblib.externals.loky import get_reusable_executor

    get_reusable_executor(reuse=False, kill_workers=True).shutdown(wait=True,
                                                                   kill_workers=True)


# --------------------------------------------------------------------------- Dask
def _no_scheduler(address: str, why: object) -> str:
    return (f"cannot reach the Dask scheduler at {address} ({why}); start one with "
            f"'dask scheduler --port 8786' and workers with 'dask worker {address}', "
            "or drop --scheduler to use a local cluster")


def check_scheduler(address: str, timeout_s: float = CONNECT_TIMEOUT_S) -> None:
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
