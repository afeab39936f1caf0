"""Trackers as objects: one class per method, each with its own validated, keyword-only
options, and a small protocol for plug-ins (:mod:`estimator.trackers.base`).

Built-ins (:data:`BUILTIN_TRACKERS`, by method name):

- :class:`WindowTracker` ("window"): the dissertation's sliding-window fit, weights, lag
  correction, dynamic window (:mod:`estimator.trackers.sliding_window`);
- :class:`MotionCompensatedTracker` ("motion_compensated");
- :class:`PoseFilterTracker` ("ekf"), :class:`FixedLagSmootherTracker` ("ekf_fixed_lag"),
  :class:`RtsSmootherTracker` ("ekf_smoother") (:mod:`estimator.trackers.ekf`);
- :class:`NaiveTracker` ("naive"); :class:`GtsamPeerTracker` ("gtsam").

Each has ``track(t, obs, config, *, cache=None) -> DataFrame``;
:func:`estimator.tracking.track` is the one-call convenience that builds one.
"""

from estimator.trackers.base import (
    ENTRY_POINT_GROUP,
    REQUIRED_COLUMNS,
    Tracker,
    TrackerLoadError,
    check_track_output,
    load_tracker,
    resolve_tracker_class,
    run_tracker,
)
from estimator.trackers.ekf import FixedLagSmootherTracker, PoseFilterTracker, RtsSmootherTracker
from estimator.trackers.motion_compensated import MotionCompensatedTracker
from estimator.trackers.naive import NaiveTracker
from estimator.trackers.peer import GtsamPeerTracker
from estimator.trackers.registry import BUILTIN_TRACKERS, tracker_for
from estimator.trackers.sliding_window import WindowTracker

__all__ = [
    "BUILTIN_TRACKERS",
    "ENTRY_POINT_GROUP",
    "REQUIRED_COLUMNS",
    "FixedLagSmootherTracker",
    "GtsamPeerTracker",
    "MotionCompensatedTracker",
    "NaiveTracker",
    "PoseFilterTracker",
    "RtsSmootherTracker",
    "Tracker",
    "TrackerLoadError",
    "WindowTracker",
    "check_track_output",
    "load_tracker",
    "resolve_tracker_class",
    "run_tracker",
    "tracker_for",
]
