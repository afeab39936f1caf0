"""The built-in trackers by method name (:data:`estimator.track_options.METHODS`), and
:func:`tracker_for`, which builds one from the arguments of :func:`estimator.tracking.track`.
"""

from __future__ import annotations

from dataclasses import fields
from typing import Any

from estimator.track_options import METHODS, LagCorrection
from estimator.trackers.ekf import (
    FixedLagSmootherTracker,
    IteratedSmootherTracker,
    PoseFilterTracker,
    RtsSmootherTracker,
)
from estimator.trackers.motion_compensated import MotionCompensatedTracker
from estimator.trackers.naive import NaiveTracker
from estimator.trackers.peer import GtsamPeerTracker
from estimator.trackers.sliding_window import WindowTracker
from estimator.weights import Weighting
from estimator.window import SOLVERS

__all__ = ["BUILTIN_TRACKERS", "option_names", "tracker_for"]

#: Method name -> tracker class, in the order of :data:`estimator.track_options.METHODS`.
BUILTIN_TRACKERS: dict[str, type] = {cls.name: cls for cls in (
    WindowTracker, MotionCompensatedTracker, PoseFilterTracker, NaiveTracker,
    FixedLagSmootherTracker, RtsSmootherTracker, GtsamPeerTracker, IteratedSmootherTracker)}
assert tuple(BUILTIN_TRACKERS) == METHODS, (tuple(BUILTIN_TRACKERS), METHODS)

#: ``track``'s arguments with their "not used" values: passing another value to a method
#: whose tracker has no such option is an error; ``rng`` is dropped where unused (a runner
#: hands every cell a generator).
_UNUSED: dict[str, Any] = {"weighting": "none", "lag_correction": False,
                           "dynamic_window": None, "turning": None, "solver": "procrustes",
                           "fit": None, "motion": None, "filter_params": None}


def option_names(cls: type) -> tuple[str, ...]:
    """The option (field) names of a built-in tracker class."""
    return tuple(f.name for f in fields(cls))


def tracker_for(method: str, **arguments: Any) -> Any:
    """The built-in tracker of ``method`` with :func:`estimator.tracking.track`'s
    ``arguments`` (window, weighting, lag_correction, dynamic_window, turning, solver, rng,
    fit, motion, filter_params, layout_check). Raises ValueError naming the argument when
    one does not apply to the method, and what the tracker's own validation raises."""
    if not isinstance(method, str) or method not in BUILTIN_TRACKERS:
        raise ValueError(f"method: unknown {method!r}; choose one of {list(METHODS)}")
    cls = BUILTIN_TRACKERS[method]
    known = option_names(cls)
    options: dict[str, Any] = {}
    for name, value in arguments.items():
        if name in known:
            options[name] = value
        elif name == "rng":
            continue
        elif name not in _UNUSED:
            raise TypeError(f"{name}: not an argument of track")
        elif not _is_unused(name, value):
            raise ValueError(_not_applicable(name, value, method))
    return cls(**options)


def _is_unused(name: str, value: Any) -> bool:
    """``value`` of argument ``name`` asks for nothing (bad values raise, naming ``name``)."""
    if name == "weighting":
        return Weighting.parse(value).scheme == "none"
    if name == "lag_correction":
        return LagCorrection.coerce(value) is None
    if name == "solver":
        if value not in SOLVERS:
            raise ValueError(f"solver: unknown {value!r}; choose one of {list(SOLVERS)}")
        return value == "procrustes"
    return value is None


def _not_applicable(name: str, value: Any, method: str) -> str:
    if name == "weighting":
        return f"weighting: method={method!r} takes no weights, got {value!r}"
    if name == "solver":
        return f"solver: {value!r} applies to method='window' only (got method={method!r})"
    if name == "lag_correction":
        return f"lag_correction: applies to method='window' only (got method={method!r})"
    return f"{name}: does not apply to method={method!r}"
