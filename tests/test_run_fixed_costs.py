"""The main job's fixed costs off its critical path (issue 27): the code version (git's
processes) is read in a background thread beside the plan, and the CLI ends the loky
workers once the last output unit is done, beside the page."""

import os
import threading
import time

import pytest

from experiments import outputs
from experiments.runner import backends
from experiments.runner import run as run_mod
from tests.test_outputs import TASKS, folder  # noqa: F401 - the fixture

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")


def test_code_version_is_read_beside_the_caller(monkeypatch):
    """start_code_version returns at once; the value comes from another thread; each run
    takes its own (a second take reads again)."""
    seen: list[str] = []

    def slow_version():
        time.sleep(0.3)
        seen.append(threading.current_thread().name)
        return {"git_describe": f"v{len(seen)}"}

    monkeypatch.setattr(run_mod, "code_version", slow_version)
    t0 = time.perf_counter()
    run_mod.start_code_version()
    run_mod.start_code_version()                 # idempotent until taken
    assert time.perf_counter() - t0 < 0.2        # did not wait for the 0.3 s read
    first = run_mod._take_code_version()
    assert first() == {"git_describe": "v1"}
    assert seen == ["code-version"]              # not the main thread
    assert run_mod._take_code_version()() == {"git_describe": "v2"}
    assert not run_mod._PENDING_VERSION


def test_a_failed_read_raises_where_the_value_is_used(monkeypatch):
    def broken():
        raise OSError("no git")

    monkeypatch.setattr(run_mod, "code_version", broken)
    get = run_mod._take_code_version()
    with pytest.raises(OSError, match="no git"):
        get()


def test_on_units_done_runs_after_the_units_and_before_the_page(folder):  # noqa: F811
    out, table, calls = folder
    seen: list[list[str]] = []
    outputs.write_outputs(table, out, jobs=1, on_units_done=lambda: seen.append(sorted(calls)))
    assert seen == [sorted(["report", "tables", "weighting", "orientation"])]
    assert calls[-1] == "page"
    calls.clear()
    seen.clear()
    outputs.write_outputs(table, out, jobs=1, on_units_done=lambda: seen.append(list(calls)))
    assert seen == [[]] and calls == []          # nothing rewritten: still called once


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


@pytest.mark.skipif(not os.path.isdir("/proc"), reason="reads /proc")
def test_stop_workers_soon_ends_the_workers_in_the_background():
    backends.one_blas_thread()
    pids = set(backends.Loky(2).map_unordered(os.getpid, [()] * 4))
    assert pids and all(_alive(p) for p in pids)
    backends.stop_workers_soon()
    assert backends.wait_workers_stopped()
    assert not backends.wait_workers_stopped()   # waited once
    deadline = time.time() + 10
    while any(_alive(p) for p in pids) and time.time() < deadline:
        time.sleep(0.05)
    assert not any(_alive(p) for p in pids)
