"""The sweep's scheduling (issue 27): the longest simulation is queued first, and the
timeline a run writes when CONFIGPOSE_TIMELINE names a file."""

import json
import os

from experiments.runner.backends import Loky, iter_truths, stop_workers
from experiments.runner.worker import TIMELINE_ENV, CellJob, run_batch
from experiments.spec import load_spec


def test_the_longest_simulation_is_queued_first():
    """Path 2 (square200, 4000 s simulated) before Path 1 (square100, 2000 s), whatever the
    spec's order: with one worker free, the critical path starts at t = 0."""
    spec = load_spec("thesis")
    cells = spec.expand()
    assert "square100" in cells[0].path             # the spec lists Path 1 first
    order = []

    def fake_truth(path_file, overrides, config_file, seed, cache_dir):
        order.append(path_file)
        return path_file

    list(iter_truths(cells, spec, 1, fake_truth, None))
    assert [p.rsplit("/", 1)[-1] for p in order] == ["square200.toml", "square100.toml"]


def test_a_batch_writes_its_timeline_line(tmp_path, monkeypatch):
    """One JSON line per batch with its start, end, CPU seconds and cell count; nothing
    without the variable."""
    spec = load_spec("quick")
    cells = spec.expand()[:2]
    job = CellJob(spec_seed=spec.seed, masks=spec.masks, session_s=spec.session_s,
                  run_id="t", cell_fn=lambda c, truth, ctx: (_ for _ in ()).throw(
                      ValueError("no cell here")))
    path = tmp_path / "timeline.jsonl"
    run_batch(cells, None, [False, False], job)
    assert not path.exists()
    monkeypatch.setenv(TIMELINE_ENV, str(path))
    recs = run_batch(cells, None, [False, False], job)
    assert [r["ok"] for r in recs] == [False, False]
    (line,) = [json.loads(s) for s in path.read_text().splitlines()]
    assert line["what"].startswith("cells ") and line["n"] == 2
    assert line["end"] >= line["start"] and line["cpu_s"] >= 0.0


def test_a_worker_start_does_not_import_the_simulator():
    """``started`` (every loky worker's first task) imports what the cells need, not MuJoCo:
    a one-truth run simulates in the main process (issue 27: ~0.2 CPU-s per worker)."""
    import subprocess
    import sys
    from pathlib import Path

    code = ("import sys; from experiments.runner.worker import started; started(); "
            "print('mujoco' in sys.modules, 'sim.rover' in sys.modules, "
            "'estimator.tracking' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=str(Path(__file__).parents[1]))
    assert out.stdout.split() == ["False", "False", "True"]


def test_timeline_lines_carry_the_resident_size_and_main_phases(tmp_path, monkeypatch):
    """Each line has ``rss_mb`` (what loky's leak check compares); :func:`mark` writes a
    span that began before the call (the main process's start-up, from its start time)."""
    import time

    from experiments.runner.worker import mark, process_started

    path = tmp_path / "timeline.jsonl"
    monkeypatch.setenv(TIMELINE_ENV, str(path))
    t0 = process_started()
    assert t0 <= time.time() and time.time() - t0 < 3600     # this process, not the epoch
    mark("main start-up", t0)
    (line,) = [json.loads(s) for s in path.read_text().splitlines()]
    assert line["what"] == "main start-up" and line["start"] == t0
    assert line["rss_mb"] is None or line["rss_mb"] > 1.0


def test_the_outputs_phase_releases_a_workers_cell_memos():
    """The first output unit in a worker drops the run's memos (loky replaced a worker whose
    memos and figures grew 300 MB past its reference size); a second call is a no-op."""
    from experiments.runner import worker

    state = worker.WORKER.for_run("run-1")
    state.memo[("obs",)] = bytearray(10)
    worker.release_memos()
    assert not worker.WORKER.memo and worker.WORKER.run_id == ""
    worker.release_memos()
    assert worker.WORKER.for_run("run-2").run_id == "run-2"


def test_the_kernel_lock_is_one_per_checkout():
    """Workers of one checkout load or compile the numba kernels one at a time; workers of
    another checkout (another numba cache) do not wait for them (issue 27: 17 s waited)."""
    import hashlib
    import tempfile
    from pathlib import Path

    from experiments.runner import worker

    root = Path(worker.__file__).resolve().parents[2]
    tag = hashlib.blake2b(str(root).encode(), digest_size=6).hexdigest()
    lock = worker.KERNEL_LOCK
    assert lock == str(Path(tempfile.gettempdir()) / f"configpose-kernels-{tag}.lock")


def test_every_loky_worker_runs_started_in_its_first_task(tmp_path, monkeypatch):
    """Workers the sweep did not start early (a rerun that must recompute a folder's cells)
    still hold the cells' imports in their first task, whatever it is: loky's leak check
    takes the reference size after it (a first task that loaded only a cached truth let
    the cells grow both workers past 300 MB: replaced, with a UserWarning, twice a rerun)."""
    tl = tmp_path / "timeline.jsonl"
    monkeypatch.setenv(TIMELINE_ENV, str(tl))
    stop_workers()                   # a fresh executor: its workers inherit the variable
    try:
        pids = set(Loky(2).map_unordered(os.getpid, [() for _ in range(6)]))
    finally:
        stop_workers()
    lines = [json.loads(line) for line in tl.read_text().splitlines()]
    first = {}
    for line in sorted(lines, key=lambda r: r["start"]):
        first.setdefault(line["pid"], line["what"])
    assert pids and all(first.get(p) == "started" for p in pids), first
    assert sum(line["what"] == "started" for line in lines) == len(pids)   # once each
