"""Provenance of generated results: which code, on which versions, produced them.

Every results folder records this (manifests, report headers) so a number can be traced to
the commit of the code that computed it (the newest commit that changed the code, so a
commit of regenerated results does not change it); ``-dirty`` marks uncommitted changes.
"""

from __future__ import annotations

import platform
import subprocess
from typing import Any

import numpy as np

from experiments.spec import REPO

__all__ = ["CODE_PATHS", "code_version", "git_describe"]

#: What "the code" is for provenance: uncommitted changes here mark a version ``-dirty``.
#: Generated results are not code, so regenerating them does not taint the next run.
CODE_PATHS = ("estimator", "sim", "experiments", "models", "pyproject.toml")


def _git(*args: str) -> str | None:
    try:
        out = subprocess.run(["git", "-C", str(REPO), *args], capture_output=True, text=True,
                             timeout=10, check=True)
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip()


def _code_commit(short: bool = True) -> str | None:
    """The newest commit that changed :data:`CODE_PATHS` (not HEAD: a commit of regenerated
    results changes no code, so a rerun at it must write the same provenance)."""
    return _git("log", "-1", f"--format={'%h' if short else '%H'}", "--", *CODE_PATHS) or None


def _code_commits() -> tuple[str | None, str | None]:
    """(abbreviated, full) hash of :func:`_code_commit`, from one git call."""
    out = _git("log", "-1", "--format=%h%n%H", "--", *CODE_PATHS)
    parts = out.split() if out else []
    return (parts[0], parts[1]) if len(parts) == 2 else (None, None)


def git_describe(rev: str | None = None) -> str:
    """Abbreviated hash of the newest commit that changed :data:`CODE_PATHS` (``rev``: that
    hash, known already), plus ``-dirty`` when they have uncommitted changes; "unknown (not
    a git checkout)" without git."""
    rev = rev or _code_commit()
    if not rev:
        return "unknown (not a git checkout)"
    dirty = _git("status", "--porcelain", "--untracked-files=no", "--", *CODE_PATHS)
    return rev + ("-dirty" if dirty else "")


def code_version() -> dict:
    """Git describe/commit of the checkout (if any) and the installed package version."""
    info: dict[str, Any] = {}
    try:
        from importlib.metadata import version

        info["package"] = version("configpose")
    except Exception:  # noqa: BLE001 - not installed: leave it out
        info["package"] = None
    short, full = _code_commits()          # one git process for both (a resume waits)
    describe = git_describe(short) if short else "unknown"
    info["git_describe"] = None if describe.startswith("unknown") else describe
    info["git_commit"] = full
    info["python"] = platform.python_version()
    info["numpy"] = np.__version__
    try:
        # the installed distribution's version (the same string as mujoco.__version__),
        # without importing mujoco: 0.5 s a resumed or a worker-simulated run does not need
        info["mujoco"] = version("mujoco")
    except Exception:  # noqa: BLE001
        info["mujoco"] = None
    return info
