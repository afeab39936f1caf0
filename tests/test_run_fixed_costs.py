"""The main job's fixed costs off its critical path (issue 27): the code version (git's
processes) is read in a background thread beside the workers' start and the plan."""

import threading
import time

import pytest

from experiments.runner import run as run_mod

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


def test_the_cli_leaves_no_code_version_behind_a_bad_spec(monkeypatch, capsys):
    """A CLI call that stops before run() (an unknown preset) does not leave its code
    version for a later run of the process, which reads its own."""
    from experiments import sweep

    monkeypatch.setattr(run_mod, "code_version", lambda: {"git_describe": "old"})
    assert sweep.main(["--preset", "no-such-preset"]) == 2
    assert not run_mod._PENDING_VERSION
    monkeypatch.setattr(run_mod, "code_version", lambda: {"git_describe": "new"})
    assert run_mod._take_code_version()() == {"git_describe": "new"}
