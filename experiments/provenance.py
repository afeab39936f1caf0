"""Provenance of generated results: which code, on which versions, produced them.

Every results folder records this (manifests, report headers) so a number can be traced to
the commit that computed it; ``--dirty`` marks uncommitted changes.
"""

from __future__ import annotations

import platform
import subprocess
from typing import Any

import numpy as np

from experiments.spec import REPO

__all__ = ["code_version", "git_describe"]


def git_describe() -> str:
    """``git describe --always --dirty`` of the checkout, or "unknown (not a git checkout)"."""
    try:
        out = subprocess.run(["git", "-C", str(REPO), "describe", "--always", "--dirty"],
                             capture_output=True, text=True, timeout=10, check=True)
        return out.stdout.strip() or "unknown (not a git checkout)"
    except (OSError, subprocess.SubprocessError):
        return "unknown (not a git checkout)"


def code_version() -> dict:
    """Git describe/commit of the checkout (if any) and the installed package version."""
    info: dict[str, Any] = {}
    try:
        from importlib.metadata import version

        info["package"] = version("configpose")
    except Exception:  # noqa: BLE001 - not installed: leave it out
        info["package"] = None
    for key, cmd in (("git_describe", ["git", "describe", "--always", "--dirty", "--tags"]),
                     ("git_commit", ["git", "rev-parse", "HEAD"])):
        try:
            info[key] = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, check=False,
                                       timeout=10).stdout.strip() or None
        except Exception:  # noqa: BLE001 - no git: leave it out
            info[key] = None
    info["python"] = platform.python_version()
    info["numpy"] = np.__version__
    try:
        import mujoco

        info["mujoco"] = mujoco.__version__
    except Exception:  # noqa: BLE001
        info["mujoco"] = None
    return info
