"""Deferred module attributes: names a CLI module no longer imports at its top.

A ``python -m experiments.X`` command runs its module's top level before ``main`` parses the
arguments, so every import there is paid by ``--help`` and by a mistyped option: pandas
~0.4 CPU-s, numba ~0.5 (through the compiled range kernels), scipy, matplotlib. The CLI
modules therefore import those inside the functions that use them, and keep the names they
used to bind at the top reachable as module attributes (``experiments.ranging.localize``,
``from experiments.identification_chain import kalman_steady_state``) through a PEP 562
module ``__getattr__`` built here, which imports on first access.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping

__all__ = ["deferred_attributes"]


def deferred_attributes(module: str, names: Mapping[str, tuple[str, str | None]]
                        ) -> Callable[[str], object]:
    """A module ``__getattr__`` for ``module`` (its ``__name__``) resolving each deferred
    name: ``names[name] = (source module, attribute)`` (attribute None: the source module
    itself, as ``import pandas as pd``). Any other name raises AttributeError as usual."""
    table = dict(names)

    def __getattr__(name: str) -> object:
        if name not in table:
            raise AttributeError(f"module {module!r} has no attribute {name!r}")
        source, attr = table[name]
        value = importlib.import_module(source)
        return value if attr is None else getattr(value, attr)

    return __getattr__
