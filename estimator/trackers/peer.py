"""The GTSAM fixed-lag factor-graph peer of the pose filter, as a tracker.

Beyond the dissertation (000_8f82f8df647bf685.txt): the same measurements as the pose
filter in a factor graph (:mod:`estimator.gtsam_peer`, optional dependency ``[gtsam]``);
described in :mod:`estimator.tracking` (``method="gtsam"``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from estimator.gtsam_peer import run_gtsam_peer
from estimator.trackers.ekf import FilterOptions

__all__ = ["GtsamPeerTracker"]


@dataclass(frozen=True, kw_only=True, eq=False)
class GtsamPeerTracker(FilterOptions):
    """The GTSAM fixed-lag smoother on the filter's measurements (``method="gtsam"``; its
    latency ``filter_params.lag_s``); needs the optional ``gtsam`` package at track time.
    Options: :class:`estimator.trackers.ekf.FilterOptions`. ``cache`` is unused."""

    name: ClassVar[str] = "gtsam"

    def _states(self, tt, o, offsets, cache):
        assert self.filter_params is not None  # FilterOptions.__post_init__ sets it
        res = run_gtsam_peer(tt, o, offsets, self.filter_params)
        return res.fixed_lag, res.status, {"_no_slip_point_m": tuple(-res.cg_offset)}
