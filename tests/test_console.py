"""Console scripts (issue 24): every ``python -m experiments.<cli>`` has a
``configpose-<cli>`` entry point in pyproject.toml, the installed entry points (after
``pip install -e .``) resolve to callables of experiments.console, and a script runs its
CLI through the same wrapper (one-line usage error, exit 2)."""

from __future__ import annotations

import importlib.metadata
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from experiments import console

REPO = Path(__file__).resolve().parents[1]
CLI_MODULES = sorted(p.stem for p in (REPO / "experiments").glob("*.py")
                     if re.search(r"^def main\(", p.read_text(), re.MULTILINE))
SCRIPTS = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["scripts"]


def test_every_cli_has_a_console_script():
    assert sorted(console.CLIS) == CLI_MODULES
    assert {console.script_name(m): f"experiments.console:{m}" for m in CLI_MODULES} == SCRIPTS


def _installed() -> dict[str, importlib.metadata.EntryPoint]:
    eps = importlib.metadata.distribution("configpose").entry_points
    return {ep.name: ep for ep in eps if ep.group == "console_scripts"}


@pytest.mark.parametrize("name", sorted(SCRIPTS))
def test_installed_entry_point_resolves_to_a_callable(name):
    ep = _installed().get(name)
    assert ep is not None, f"{name} is not installed: run pip install -e ."
    assert ep.value == SCRIPTS[name]
    fn = ep.load()
    assert callable(fn) and fn is getattr(console, ep.value.rpartition(":")[2])


def test_a_console_script_runs_its_cli_through_the_wrapper():
    """configpose-sweep with an unknown option: the CLI's one-line usage error, exit 2 (the
    script installed beside this interpreter, else the entry point's callable run here)."""
    exe = Path(sys.executable).with_name("configpose-sweep")
    cmd = [str(exe)] if exe.exists() else [
        sys.executable, "-c", "import sys; from experiments.console import sweep; sweep()"]
    r = subprocess.run([*cmd, "--no-such-option"], cwd=REPO, capture_output=True, text=True,
                       check=False, timeout=120)
    err = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(err) == 1, r.stderr
    assert "error:" in err[0] and "--no-such-option" in err[0]
