"""Tracking a moving platform with the configuration-constrained window fit.

Source: 000_8f82f8df647bf685.txt (GPS dissertation), Sections 3.1.2, 3.2, 3.4 and 4.12.

``method="window"`` is the dissertation's tracker:

- Sliding window of size s (Section 3.4.1, Eq. 3.9): the window of epochs
  ``k-s+1 .. k``; the first estimate at epoch s (row index s-1), then one per epoch.
- Weights computed on each window's data: ``"none"``, ``"random"`` (control), ``"huff"``
  (3.3.3; ``"huff:3.5"`` with a 3.5 m threshold), ``"huber"`` (3.3.1, per axis),
  ``"huff_huber"`` (Eq. 3.14), from :mod:`estimator.weights` (:class:`Weighting`), all
  windows stacked into one call.
- Solvers from :mod:`estimator.window`: ``"procrustes"`` (closed form; all windows in one
  batched call, cumulative sums when unweighted), ``"elastic"`` (Eq. 3.9 with the eps slack,
  all windows of the track in one batched interior-point call, :mod:`estimator.elastic`),
  ``"slsqp"``/``"ccp"`` (Eq. 3.9 with the eps slack, one window at a time, cold-started
  from procrustes; ``fit=FitOptions(warm_start=True)`` passes the
  previous row's fit as ``x0``, the dissertation's start, Section 3.1.2; with a dynamic
  window too, the rows are fitted in time order so the previous row may have either size;
  a row with insufficient data passes on the fit before it).
- CG from the configured CG sensors (Eq. 3.8); heading both as the fitted rigid pose's
  atan2 (``yaw``) and by the law-of-cosines construction of Section 3.2 (``yaw_loc``,
  :func:`estimator.orientation.law_of_cosines_heading`, relative to the first estimate).
- Lag correction (3.4.2, :mod:`estimator.lag`): ``lag_correction=True`` or ``"pose"`` as
  written, ``"course"`` our variant; :class:`LagCorrection` for the velocity span and the
  heading of step 5.
- Dynamic window (3.4.2.1): ``dynamic_window=w_small`` with ``turning`` either a (n,) bool
  array (the simulator's controller flag: the dissertation's "control information") or
  ``"detect"`` (a detector on the estimates alone, :mod:`estimator.turns`, so it runs on
  real logs). Row k uses the small window when ``turning[k]`` is True. After a turn the
  window grows back by one of two rules (``DynamicWindow(small, growth)``,
  :data:`GROWTH_RULES`):

  - ``"jump"``: back to ``window`` at the first epoch that is not turning;
  - ``"refill"``: the first-in-first-out queue of Section 3.4.1 ("refreshed ... by deleting
    the oldest member of the queue and adding the ... newly observed data") keeps only the
    small window's samples when the turn ends and adds one sample per epoch without
    deleting any until it holds ``window`` again: row k uses
    ``min(window, small + (k - j))`` epochs, j the last turning row. Section 4.12.4 traces
    the outliers of LC + Dyn SW "back to the use of sliding window = 1 during the turning
    sections", which fits a window that is short for a while after each turn; the jump rule
    has no such stretch. :func:`dynamic_window_sizes` gives the sizes.
- ``LagCorrection(heading=...)``: a (n,) heading (rad) used by the lag correction in place
  of the estimated law-of-cosines heading; row k uses ``heading[k]`` of its newest epoch. It
  separates the method from the heading it is fed: with the simulator's heading it is the
  oracle "LC (simulator heading)" (is Section 3.4.2 right when the heading is right?); with
  a smoothed heading series, an estimator of its own.

Beyond the dissertation (each selectable, each a row in tables):

- ``method="motion_compensated"``: the pose at the newest epoch of each window under a
  constant-velocity model, with ``motion=MotionOptions(yaw_rate=True)`` also a constant
  yaw rate (:mod:`estimator.motion`).
- ``method="ekf"``: an EKF on the antennas with the configuration as measurement model
  (each antenna's fix and its displacement since the previous fix), the non-holonomic
  constraint, process noise from the platform's limits, robust gating and a forward speed
  that cannot flip silently (:mod:`estimator.pose_filter`); it starts when the data allow
  (rows before that are NaN, status "waiting"/"no_data"). ``"ekf_fixed_lag"``: its
  fixed-lag smoother (latency ``filter_params.lag_s``); ``"ekf_smoother"``: its full RTS
  smoother (:mod:`estimator.pose_smoother`). ``"gtsam"``: the GTSAM fixed-lag factor-graph
  peer on the same measurements (:mod:`estimator.gtsam_peer`; optional dependency).
- ``method="naive"``: no configuration knowledge; CG = mean of the CG antennas' own window
  means (Eq. 3.8 on raw means), no heading (NaN). What the configuration buys. A naive
  estimate needs every CG antenna observed at least once in the window: averaging only the
  ones present would move the CG by up to the platform's size (~0.3 m on rover_gps8) while
  looking valid, so such a row is NaN (every position and the CG) with status
  "insufficient_data". (A configuration with a dead CG member therefore has no naive
  estimate at all.)

Observations are planar ``(n, m, 2)``; a 3-D configuration is projected (``config.planar()``).

Each method is a tracker object with its own options (:mod:`estimator.trackers`, one module
per tracker); :func:`track` is the one-call convenience that builds and runs one. Nothing is
cached between calls unless a :class:`estimator.memo.TrackCache` is passed (``cache=``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

from estimator.configuration import SensorConfig
from estimator.memo import TrackCache
from estimator.pose_filter import PoseFilterParams
from estimator.track_options import (
    FILTER_METHODS,
    GROWTH_RULES,
    LAG_OPTIONS,
    METHODS,
    DynamicWindow,
    FitOptions,
    LagCorrection,
    MotionOptions,
)
from estimator.trackers import tracker_for
from estimator.trackers._common import heading_pair
from estimator.trackers._windows import DETECTOR_DEFAULTS, detect_turning, dynamic_window_sizes
from estimator.weights import WEIGHTINGS, Weighting

__all__ = [
    "DETECTOR_DEFAULTS",
    "FILTER_METHODS",
    "GROWTH_RULES",
    "LAG_OPTIONS",
    "METHODS",
    "WEIGHTINGS",
    "DynamicWindow",
    "FitOptions",
    "LagCorrection",
    "MotionOptions",
    "Weighting",
    "detect_turning",
    "dynamic_window_sizes",
    "heading_pair",
    "track",
]


def track(t: Any, obs: Any, config: SensorConfig, window: int = 10,
          weighting: str | Weighting = "none",
          lag_correction: bool | str | LagCorrection = False,
          dynamic_window: int | DynamicWindow | None = None, turning: Any = None,
          solver: str = "procrustes", rng: np.random.Generator | None = None, *,
          method: str = "window", fit: FitOptions | None = None,
          motion: MotionOptions | None = None, filter_params: PoseFilterParams | None = None,
          layout_check: bool = True, cache: TrackCache | None = None) -> pd.DataFrame:
    """Track the platform over a recording; one row per estimate.

    t : (n,) seconds, strictly increasing. obs : (n, m, 2) metres (world x east, y north),
    NaN = missing. config : the sensor configuration (m sensors).
    window : s >= 1; the first estimate is at epoch s (row index s-1), then one per epoch.
    weighting : a :class:`estimator.weights.Weighting` or its text (:data:`WEIGHTINGS`,
        ``"huff:3.5"`` = Huff with a 3.5 m threshold); ``rng`` (numpy Generator) is
        required for ``"random"``. Methods "window" and "motion_compensated" only.
    lag_correction : False, True (= "pose", Section 3.4.2 as written), "course" (our
        variant) or a :class:`LagCorrection` (velocity span, the heading of step 5);
        method "window" only.
    dynamic_window : None, the small window size (e.g. 1) used on turning epochs (Section
        3.4.2.1), or a :class:`DynamicWindow` (small window, growth rule "jump" / "refill"
        after a turn, :func:`dynamic_window_sizes`, turn-detector options). Requires
        ``turning``: a (n,) bool array or "detect" (:func:`detect_turning`).
    solver : "procrustes" | "slsqp" | "ccp" | "elastic" (method "window" only); ``fit``
        (:class:`FitOptions`: eps, warm start, iteration limit) passes to
        :func:`estimator.window.fit_window` (elastic: :func:`estimator.elastic.elastic_batch`).
    method : one of :data:`METHODS` (module docstring); "naive" gives a row only where every
        CG sensor has data in the window, else NaN and "insufficient_data".
        motion : :class:`MotionOptions` of "motion_compensated" (constant yaw rate or not).
        filter_params : :class:`PoseFilterParams` of the filter methods (platform limits,
        noise levels, no-slip point, reverse mode, smoother lag); default the rover's.

    Returns a DataFrame with columns ``t, cg_x, cg_y, yaw, yaw_loc, window, solver_status,
    turning, lag_dx, lag_dy`` then ``x_<name>, y_<name>`` per sensor, plus ``speed,
    yaw_rate`` for "motion_compensated" and the filter methods and ``n_used, n_gated, n_steps``
    for the EKF family (fixes accepted / rejected, displacements accepted).
    ``yaw`` is the fitted pose's heading (atan2, CCW from +x, (-pi, pi]); ``yaw_loc`` the
    law-of-cosines heading (Section 3.2); ``lag_dx/lag_dy`` the applied lag shift (0 when
    off, NaN where it could not be computed and the estimate is left uncorrected).
    ``df.attrs["settings"]`` records the arguments.

    layout_check : run :func:`estimator.layout_check.check_layout` on the observations
        with window s (about the cost of one procrustes track): ``df.attrs["layout_check"]``
        holds its result (mirror fraction and verdict, forward-axis offset and verdict),
        ``df.attrs["warnings"]`` its findings (e.g. "layout may be mirrored ..."), each also
        issued as a :class:`estimator.configuration.LayoutWarning`.
    cache : an :class:`estimator.memo.TrackCache` whose memos the fits, Huff weights and
        filter passes go through (a runner tracking many techniques on the same data
        reuses them); None (default) computes everything. The numbers are the same.

    The method's tracker (:data:`estimator.trackers.BUILTIN_TRACKERS`) is built from these
    arguments (:func:`estimator.trackers.tracker_for`) and run; an argument the method does
    not take raises ValueError naming it (``rng`` is ignored where unused).
    """
    tracker = tracker_for(method, window=window, weighting=weighting,
                          lag_correction=lag_correction, dynamic_window=dynamic_window,
                          turning=turning, solver=solver, rng=rng, fit=fit, motion=motion,
                          filter_params=filter_params, layout_check=layout_check)
    return tracker.track(t, obs, config, cache=cache)
