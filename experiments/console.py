"""The console scripts (``[project.scripts]`` in pyproject.toml): ``configpose-<cli>`` for
every ``python -m experiments.<cli>``, the same command through the same wrapper
(:func:`experiments.cli.run`: one-line errors, exit codes 2 / 130 / 143, ``--debug``).

Each script imports its module only when it runs, so ``configpose-page`` does not pay for
the sweep's imports. ``tests/test_console.py`` checks that every CLI module has its script
and that each installed entry point resolves to one of these callables.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import NoReturn

from experiments.cli import run

__all__ = ["CLIS", "script_name"]

#: The CLI modules of experiments/ (each has ``main(argv)``), by module name.
CLIS = ("bench", "export", "figures", "identification", "page", "paths_figure", "ranging",
        "render", "report", "rigid_ranging", "sensitivity", "stationary", "sweep", "ultrasonic")


def script_name(module: str) -> str:
    """The console script of ``python -m experiments.<module>``: ``configpose-<module>``
    with ``-`` for ``_`` (``paths_figure`` -> ``configpose-paths-figure``)."""
    return "configpose-" + module.replace("_", "-")


def _script(module: str) -> Callable[[], NoReturn]:
    def entry() -> NoReturn:
        run(importlib.import_module(f"experiments.{module}").main)

    entry.__name__ = entry.__qualname__ = module
    entry.__doc__ = f"``{script_name(module)}``: ``python -m experiments.{module}``."
    return entry


bench = _script("bench")
export = _script("export")
figures = _script("figures")
identification = _script("identification")
page = _script("page")
paths_figure = _script("paths_figure")
ranging = _script("ranging")
render = _script("render")
report = _script("report")
rigid_ranging = _script("rigid_ranging")
sensitivity = _script("sensitivity")
stationary = _script("stationary")
sweep = _script("sweep")
ultrasonic = _script("ultrasonic")
