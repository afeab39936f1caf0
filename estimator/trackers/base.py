"""The tracker protocol and the plug-in loader.

A tracker is an object with one method::

    tracker.track(t, obs, config) -> pandas.DataFrame

t : (n,) seconds, strictly increasing. obs : (n, m, 2) metres (world x east, y north; a
tracker may also accept (n, m, 3)), NaN = missing (both coordinates). config : the
:class:`estimator.configuration.SensorConfig` of the m sensors. The table has one row per
estimate with at least the columns :data:`REQUIRED_COLUMNS`: ``t`` (s, a time of ``t``),
``cg_x, cg_y`` (m, the CG of Eq. 3.8 of 000_8f82f8df647bf685.txt) and ``yaw`` (rad, CCW from
+x; NaN where unknown). A tracker may accept ``cache=`` (an
:class:`estimator.memo.TrackCache`) to reuse intermediate results across calls;
:func:`run_tracker` passes it only to those that do. Options are the tracker's own,
validated when it is built (the built-ins: frozen dataclasses, keyword-only options).

Plug-ins: :func:`load_tracker` builds a tracker from a technique string and an options
mapping, either ``"package.module:ClassName"`` (an import path) or a name: a built-in method
(:data:`estimator.trackers.registry.BUILTIN_TRACKERS`) or an entry point of the group
:data:`ENTRY_POINT_GROUP` (``[project.entry-points."configpose.trackers"]`` in a package's
pyproject.toml: ``mytracker = "mypkg.mod:MyTracker"``). Every failure is a
:class:`TrackerLoadError` (a ValueError) naming the technique and the problem.
"""

from __future__ import annotations

import dataclasses
import importlib
import importlib.metadata
import inspect
import re
from collections.abc import Mapping
from typing import Any, Protocol, runtime_checkable

import numpy as np
import pandas as pd

from estimator.trackers.registry import BUILTIN_TRACKERS

__all__ = ["ENTRY_POINT_GROUP", "REQUIRED_COLUMNS", "Tracker", "TrackerLoadError",
           "check_track_output", "load_tracker", "resolve_tracker_class", "run_tracker"]

#: The entry-point group a package registers its trackers in (by name).
ENTRY_POINT_GROUP = "configpose.trackers"
#: Columns every tracker's table has.
REQUIRED_COLUMNS = ("t", "cg_x", "cg_y", "yaw")

_IMPORT_PATH = re.compile(r"^[A-Za-z_]\w*(\.[A-Za-z_]\w*)*:[A-Za-z_]\w*(\.[A-Za-z_]\w*)*$")
_NAME = re.compile(r"^[A-Za-z_][\w.-]*$")


@runtime_checkable
class Tracker(Protocol):
    """What the harness runs (module docstring): ``track(t, obs, config) -> DataFrame``."""

    def track(self, t: np.ndarray, obs: np.ndarray, config: Any) -> pd.DataFrame:
        """One row per estimate; at least :data:`REQUIRED_COLUMNS`."""
        ...


class TrackerLoadError(ValueError):
    """A technique string or its options cannot make a tracker; the message names both."""


def _entry_points() -> Any:
    """The entry points of :data:`ENTRY_POINT_GROUP` (an indirection tests replace)."""
    return importlib.metadata.entry_points(group=ENTRY_POINT_GROUP)


def resolve_tracker_class(technique: str) -> type:
    """The tracker class a technique string names (module docstring); raises
    :class:`TrackerLoadError` for a malformed string, a module or attribute that is not
    there, an unknown name, or an object that is not a class with a ``track`` method."""
    if not isinstance(technique, str):
        raise TrackerLoadError(f"technique: expected a string such as 'pkg.module:Name', got "
                               f"{type(technique).__name__} {technique!r}")
    if ":" in technique:
        if not _IMPORT_PATH.match(technique):
            raise TrackerLoadError(f"technique {technique!r}: not an import path of the form "
                                   "'package.module:ClassName'")
        obj = _import(technique, technique)
    elif technique in BUILTIN_TRACKERS:
        return BUILTIN_TRACKERS[technique]
    elif _NAME.match(technique):
        obj = _from_entry_point(technique)
    else:
        raise TrackerLoadError(f"technique {technique!r}: neither an import path "
                               "'package.module:ClassName' nor a tracker name")
    _check_class(technique, obj)
    return obj


def _import(technique: str, path: str) -> Any:
    mod_name, _, attr = path.partition(":")
    try:
        obj: Any = importlib.import_module(mod_name)
    except ImportError as exc:
        raise TrackerLoadError(f"technique {technique!r}: cannot import module {mod_name!r} "
                               f"({type(exc).__name__}: {exc})") from exc
    for part in attr.split("."):
        if not hasattr(obj, part):
            raise TrackerLoadError(f"technique {technique!r}: module {mod_name!r} has no "
                                   f"attribute {attr!r}")
        obj = getattr(obj, part)
    return obj


def _from_entry_point(technique: str) -> Any:
    eps = [ep for ep in _entry_points() if ep.name == technique]
    if not eps:
        known = sorted({*BUILTIN_TRACKERS, *(ep.name for ep in _entry_points())})
        raise TrackerLoadError(f"technique {technique!r}: not a built-in tracker nor an entry "
                               f"point of group {ENTRY_POINT_GROUP!r}; known: {known}")
    if len({ep.value for ep in eps}) > 1:
        raise TrackerLoadError(f"technique {technique!r}: several entry points of group "
                               f"{ENTRY_POINT_GROUP!r} have this name: "
                               f"{sorted(ep.value for ep in eps)}")
    value = eps[0].value
    if not _IMPORT_PATH.match(value):
        raise TrackerLoadError(f"technique {technique!r}: entry point value {value!r} is not "
                               "of the form 'package.module:ClassName'")
    return _import(technique, value)


def _check_class(technique: str, obj: Any) -> None:
    if not inspect.isclass(obj):
        raise TrackerLoadError(f"technique {technique!r}: names a {type(obj).__name__}, not a "
                               "tracker class (a class with a track(t, obs, config) method)")
    track = getattr(obj, "track", None)
    if not callable(track):
        raise TrackerLoadError(f"technique {technique!r}: class {obj.__name__} has no "
                               "track(t, obs, config) method")
    try:
        inspect.signature(track).bind(None, None, None, None)
    except TypeError:
        raise TrackerLoadError(f"technique {technique!r}: {obj.__name__}.track must take "
                               "(t, obs, config)") from None
    except ValueError:        # no signature (a builtin): trust it
        pass


def load_tracker(technique: str, options: Mapping[str, Any] | None = None) -> Any:
    """A tracker built from a technique string (module docstring) and its options
    (keyword arguments of the class, e.g. a spec's ``[options]`` table; None: none).

    Raises :class:`TrackerLoadError` (a ValueError) naming the technique: the string's
    problems (:func:`resolve_tracker_class`), options that are not a mapping of names,
    unknown options (with the known ones), and the class's own validation errors.
    """
    cls = resolve_tracker_class(technique)
    opts = _check_options(technique, cls, options)
    try:
        return cls(**opts)
    except (TypeError, ValueError) as exc:
        raise TrackerLoadError(f"technique {technique!r}: bad options: {exc}") from exc


def _check_options(technique: str, cls: type, options: Any) -> dict[str, Any]:
    if options is None:
        return {}
    if not isinstance(options, Mapping):
        raise TrackerLoadError(f"technique {technique!r}: options must be a table of "
                               f"name = value, got {type(options).__name__}")
    bad = sorted(repr(k) for k in options if not isinstance(k, str))
    if bad:
        raise TrackerLoadError(f"technique {technique!r}: option names must be strings, got "
                               f"{', '.join(bad)}")
    known = _accepted_options(cls)
    if known is not None:
        unknown = sorted(set(options) - set(known))
        if unknown:
            raise TrackerLoadError(f"technique {technique!r}: unknown option(s) {unknown}; "
                                   f"{cls.__name__} takes {sorted(known)}")
    return dict(options)


def _accepted_options(cls: type) -> tuple[str, ...] | None:
    """The keyword names ``cls(...)`` takes (None: any, it has ``**kwargs``)."""
    if dataclasses.is_dataclass(cls):
        return tuple(f.name for f in dataclasses.fields(cls) if f.init)
    try:
        params = inspect.signature(cls).parameters.values()
    except (TypeError, ValueError):
        return None
    if any(p.kind is p.VAR_KEYWORD for p in params):
        return None
    return tuple(p.name for p in params
                 if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY))


def run_tracker(tracker: Any, t: np.ndarray, obs: np.ndarray, config: Any, *,
                cache: Any = None) -> pd.DataFrame:
    """``tracker.track(t, obs, config)`` (with ``cache=`` when its track takes it), its table
    checked (:func:`check_track_output`)."""
    kw = {}
    if cache is not None and _takes_cache(tracker):
        kw["cache"] = cache
    return check_track_output(tracker.track(t, obs, config, **kw), len(t), tracker)


def _takes_cache(tracker: Any) -> bool:
    try:
        return "cache" in inspect.signature(tracker.track).parameters
    except (TypeError, ValueError):
        return False


def check_track_output(df: Any, n: int, tracker: Any = None) -> pd.DataFrame:
    """``df`` if it is a tracker's table for a recording of n epochs (a DataFrame of at
    most n rows with :data:`REQUIRED_COLUMNS`), else TypeError (not a DataFrame) or
    ValueError naming the tracker."""
    who = type(tracker).__name__ if tracker is not None else "tracker"
    if not isinstance(df, pd.DataFrame):
        raise TypeError(f"{who}.track: must return a pandas.DataFrame, got "
                         f"{type(df).__name__}")
    missing = [c for c in REQUIRED_COLUMNS if c not in df.columns]
    if missing:
        raise ValueError(f"{who}.track: the table lacks column(s) {missing} (needs "
                         f"{list(REQUIRED_COLUMNS)})")
    if len(df) > n:
        raise ValueError(f"{who}.track: {len(df)} rows for {n} epochs (at most one per epoch)")
    return df
