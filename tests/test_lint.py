"""Lint and type check as tests: ``ruff check .`` over the tree and ``mypy`` over the core.

The rule sets live in pyproject.toml ([tool.ruff.lint], [tool.mypy]); any finding fails.
Each test skips, naming the tool, when the tool is not installed (``pip install -e '.[test]'``).
"""

from __future__ import annotations

import importlib.util
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _run(cmd: list[str]) -> subprocess.CompletedProcess:
    return subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=600)


def test_ruff_clean():
    exe = Path(sys.executable).with_name("ruff")  # this environment's first, then PATH's
    exe = str(exe) if exe.exists() else shutil.which("ruff")
    if exe is None:
        pytest.skip("ruff is not installed (pip install -e '.[test]')")
    r = _run([exe, "check", "--no-cache", "--output-format", "concise", "."])
    assert r.returncode == 0, f"ruff findings:\n{r.stdout}{r.stderr}"


def test_mypy_clean():
    if importlib.util.find_spec("mypy") is None:
        pytest.skip("mypy is not installed (pip install -e '.[test]')")
    # --cache-dir /dev/null: no .mypy_cache in the tree
    r = _run([sys.executable, "-m", "mypy", "--cache-dir", "/dev/null"])
    assert r.returncode == 0, f"mypy findings:\n{r.stdout}{r.stderr}"
