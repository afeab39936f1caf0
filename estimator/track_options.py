"""Options of the trackers (:mod:`estimator.trackers`) and of :func:`estimator.tracking.track`,
grouped by what they configure.

Source: 000_8f82f8df647bf685.txt (GPS dissertation), Sections 3.1.2, 3.4.1, 3.4.2 and
3.4.2.1; the methods beyond it are described in :mod:`estimator.tracking`.

``track`` keeps the signature of DESIGN.md (``window``, ``weighting``, ``lag_correction``,
``dynamic_window``, ``turning``, ``solver``, ``rng``); what a method needs beyond that
comes as one small object per concern, each validated once, where it is built:

- :class:`FitOptions`: the window solver's eps band, warm start and iteration limit
  (method "window", Eq. 3.9);
- :class:`LagCorrection`: the lag correction of Section 3.4.2 (``lag_correction=True`` is
  ``LagCorrection()``): variant, velocity span and the heading of its step 5;
- :class:`DynamicWindow`: the dynamic window of Section 3.4.2.1 (``dynamic_window=1`` is
  ``DynamicWindow(1)``): small window, growth rule after a turn, turn-detector options;
- :class:`MotionOptions`: the motion-compensated window's yaw-rate model;
- the pose-filter family takes :class:`estimator.pose_filter.PoseFilterParams`.

What depends on another option (the method, the solver, the window) is checked by the
tracker class that takes them, where it is built; what depends on the recording (lengths)
by its ``track``.

Vocabularies (defined here once; experiments derive theirs from them): :data:`METHODS`,
:data:`FILTER_METHODS`, :data:`WEIGHTED_METHODS`, :data:`GROWTH_RULES`, and
:data:`estimator.lag.LAG_MODES` for the lag-correction variants.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from estimator._checks import check_int, check_real
from estimator.lag import LAG_MODES

__all__ = [
    "FILTER_METHODS",
    "GROWTH_RULES",
    "LAG_OPTIONS",
    "METHODS",
    "WEIGHTED_METHODS",
    "DynamicWindow",
    "FitOptions",
    "LagCorrection",
    "MotionOptions",
]

#: The trackers of ``track`` (module docstring of :mod:`estimator.tracking`): the
#: dissertation's window fit, and beyond it the motion-compensated window, the pose filter
#: (causal EKF), the naive CG mean, the filter's fixed-lag and RTS smoothers and the GTSAM
#: fixed-lag peer.
METHODS = ("window", "motion_compensated", "ekf", "naive", "ekf_fixed_lag", "ekf_smoother",
           "gtsam", "ekf_ieks")
#: The pose-filter family (one forward pass; smoothers and the GTSAM peer on top).
FILTER_METHODS = ("ekf", "ekf_fixed_lag", "ekf_smoother", "gtsam", "ekf_ieks")
#: Methods that weigh the observations of a window (Section 3.3); the others take none.
WEIGHTED_METHODS = ("window", "motion_compensated")
#: How a dynamic window grows back after a turn (:func:`estimator.tracking.dynamic_window_sizes`):
#: "jump" back to the full window at the first epoch that is not turning, or "refill" one
#: epoch per step (the first-in-first-out queue of Section 3.4.1).
GROWTH_RULES = ("jump", "refill")
#: What ``track(lag_correction=...)`` accepts besides a :class:`LagCorrection`.
LAG_OPTIONS = (False, True, *LAG_MODES)


def _check_bool(value: Any, name: str) -> bool:
    if not isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{name}: must be True or False, got {type(value).__name__} {value!r}")
    return bool(value)


@dataclass(frozen=True)
class FitOptions:
    """Window-solver options (method "window"; :func:`estimator.window.fit_window`).

    eps : constraint slack of Eq. 3.6 in metres, > 0 (the configuration's bound
        ``eps < min distance / 2`` is checked by the solver); procrustes holds every
        distance exactly and ignores it.
    warm_start : "slsqp" / "ccp" only: each window starts from the previous row's fit
        (the dissertation's start, Section 3.1.2) instead of its procrustes fit.
    maxiter : iteration limit of slsqp / ccp / elastic (None: the solver's default, 100).
    """

    eps: float = 0.01
    warm_start: bool = False
    maxiter: int | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "eps", check_real(self.eps, "fit.eps", lo=0.0, lo_open=True))
        object.__setattr__(self, "warm_start", _check_bool(self.warm_start, "fit.warm_start"))
        if self.maxiter is not None:
            object.__setattr__(self, "maxiter", check_int(self.maxiter, "fit.maxiter", lo=1))

    def solver_kwargs(self) -> dict[str, int]:
        """Keywords for the solver beyond eps and x0 (``{"maxiter": n}`` when set)."""
        return {} if self.maxiter is None else {"maxiter": self.maxiter}


@dataclass(frozen=True, eq=False)
class LagCorrection:
    """The lag correction of Section 3.4.2 (method "window"; :mod:`estimator.lag`).

    mode : "pose" (as written: the platform orientation of Section 3.2, Euclidean
        distances) or "course" (ours: the direction of the estimated velocity, signed
        along-track distances), :data:`estimator.lag.LAG_MODES`.
    velocity_span : rows between the two estimates of the velocity (>= 1; None: the window
        size, two windows that do not overlap).
    heading : None, or (n,) radians (CCW from +x; NaN allowed, no infinities) used by step 5
        in place of the estimated law-of-cosines heading; row k takes the value of its
        newest epoch, and a NaN leaves that row uncorrected (lag_dx NaN). Mode "pose" only.
        The simulator's heading here makes the oracle rows "LC (simulator heading)"; a
        smoothed heading series is an estimator of its own.
    """

    mode: str = "pose"
    velocity_span: int | None = None
    heading: np.ndarray | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        if self.mode not in LAG_MODES:
            raise ValueError(f"lag_correction.mode: must be one of {list(LAG_MODES)}, got "
                             f"{self.mode!r}")
        if self.velocity_span is not None:
            object.__setattr__(self, "velocity_span",
                               check_int(self.velocity_span, "velocity_span", lo=1))
        if self.heading is not None:
            if self.mode != "pose":
                raise ValueError(f"lag_heading: only used with the 'pose' lag correction "
                                 f"(got mode {self.mode!r})")
            h = np.asarray(self.heading)
            if h.ndim != 1 or not np.issubdtype(h.dtype, np.floating):
                raise ValueError(f"lag_heading: expected a 1-D float array (radians), got "
                                 f"{h.dtype} {h.shape}")
            if np.isinf(h).any():
                k = int(np.argmax(np.isinf(h)))
                raise ValueError(f"lag_heading: lag_heading[{k}] = {h[k]!r} is infinite (use "
                                 "NaN where the heading is unknown)")
            object.__setattr__(self, "heading", h)

    @classmethod
    def coerce(cls, value: bool | str | LagCorrection) -> LagCorrection | None:
        """``track``'s ``lag_correction`` argument as an object: False -> None, True ->
        ``LagCorrection()``, "pose" / "course" -> that mode, a LagCorrection -> itself."""
        if isinstance(value, LagCorrection):
            return value
        if isinstance(value, (bool, np.bool_)):
            return cls() if value else None
        if isinstance(value, str) and value in LAG_MODES:
            return cls(value)
        raise ValueError(f"lag_correction: must be one of {list(LAG_OPTIONS)} or a "
                         f"LagCorrection, got {value!r}")


@dataclass(frozen=True)
class DynamicWindow:
    """The dynamic window of Section 3.4.2.1: a small window on turning epochs.

    small : the window (epochs, >= 1) used while turning; ``track`` checks small <= window.
    growth : how the window grows back after a turn, one of :data:`GROWTH_RULES`.
    detector : options of :func:`estimator.tracking.detect_turning` for
        ``turning="detect"`` (None: its defaults).
    """

    small: int = 1
    growth: str = "jump"
    detector: Mapping[str, Any] | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "small", check_int(self.small, "dynamic_window", lo=1))
        if self.growth not in GROWTH_RULES:
            raise ValueError(f"window_growth: must be one of {list(GROWTH_RULES)}, got "
                             f"{self.growth!r}")
        if self.detector is not None and not isinstance(self.detector, Mapping):
            raise TypeError(f"detector: must be a mapping of option -> value, got "
                            f"{type(self.detector).__name__}")

    @classmethod
    def coerce(cls, value: int | DynamicWindow | None) -> DynamicWindow | None:
        """``track``'s ``dynamic_window`` argument as an object: None -> None, an integer
        ``k`` -> ``DynamicWindow(k)``, a DynamicWindow -> itself."""
        if value is None or isinstance(value, DynamicWindow):
            return value
        return cls(value)


@dataclass(frozen=True)
class MotionOptions:
    """The motion-compensated window (method "motion_compensated"; :mod:`estimator.motion`).

    yaw_rate : also fit a constant yaw rate (default False: constant velocity and heading;
        on Path 1 under gps_stationary noise the yaw rate changed the mean CG error by
        < 0.01 m for windows 5-30 at 6-9x the time).
    omega_max : bound on |yaw rate|, rad/s, > 0.
    """

    yaw_rate: bool = False
    omega_max: float = 1.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "yaw_rate", _check_bool(self.yaw_rate, "motion.yaw_rate"))
        object.__setattr__(self, "omega_max", check_real(self.omega_max, "motion.omega_max",
                                                         lo=0.0, lo_open=True))
