"""The pose filter (causal EKF on the antennas with the configuration as measurement model)
and its two smoothers, fixed-lag and full RTS, as trackers.

Beyond the dissertation (000_8f82f8df647bf685.txt); the filter is :mod:`estimator.pose_filter`,
the smoothers :mod:`estimator.pose_smoother`; described in :mod:`estimator.tracking`
(``method="ekf"``, ``"ekf_fixed_lag"``, ``"ekf_smoother"``).
"""

from __future__ import annotations

import abc
from dataclasses import dataclass, replace
from typing import Any, ClassVar

import numpy as np
import pandas as pd

from estimator._checks import check_int
from estimator.configuration import SensorConfig
from estimator.memo import TrackCache, content_digest, freeze, memo_get
from estimator.pose_filter import (
    MAX_SMOOTHER_ITERATIONS,
    PoseFilterParams,
    PoseFilterResult,
    memo_pose_filter,
)
from estimator.pose_smoother import IEKS_ITERATIONS, memo_smoothed_states
from estimator.rigid_fit import rotate
from estimator.trackers._common import Rows, TrackerOptions, frame, loc_heading, settings

__all__ = ["FilterOptions", "FixedLagSmootherTracker", "IteratedSmootherTracker",
           "PoseFilterTracker", "RtsSmootherTracker"]


@dataclass(frozen=True, kw_only=True, eq=False)
class FilterOptions(TrackerOptions, abc.ABC):
    """Options of the pose-filter family: filter_params, a
    :class:`estimator.pose_filter.PoseFilterParams` (platform limits, noise levels, no-slip
    point, reverse mode, smoother lag; None: the rover's defaults). ``window`` s only drops
    the first s-1 rows (the filter starts when the data allow: rows before that are NaN,
    status "waiting"/"no_data"). Extra columns ``speed`` (m/s), ``yaw_rate`` (rad/s),
    ``yaw_sd`` (rad: the heading's sd from the estimate's own covariance; NaN where it has
    none, e.g. the fixed-lag smoother), and the forward pass's consistency: ``nis``
    (normalised innovation squared of the epoch's fixes and displacements against the
    prediction, NaN without data) with ``nis_dof`` degrees of freedom (chi-square with
    nis_dof dof when the filter is consistent; :func:`estimator.pose_filter.nis_summary`
    gives the mean NIS / dof and the share inside the 95 % band). Heading NEES at scoring:
    ``(yaw error / yaw_sd)^2``, chi-square with 1 dof (:func:`estimator.pose_filter.nees`).
    Status "inconsistent" (not "ok"): the epoch's NIS is above the ``gate_prob`` quantile of
    chi-square with its dof, or the last 10 s's NIS, each epoch's winsorised at that quantile,
    sum above the quantile with the summed dof (one spike cannot flag the window; a few
    saturated epochs or a persistent excess do: ``estimator.pose_filter._Monitor``);
    "reinit": re-initialised from the epoch's rigid fit."""

    filter_params: PoseFilterParams | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        fp = self.filter_params
        if fp is not None and not isinstance(fp, PoseFilterParams):
            raise TypeError(f"filter_params: expected a PoseFilterParams, got "
                            f"{type(fp).__name__}")
        object.__setattr__(self, "filter_params", fp or PoseFilterParams())

    @property
    def params(self) -> PoseFilterParams:
        """The filter parameters (``filter_params``, never None after construction)."""
        fp = self.filter_params
        assert fp is not None                      # __post_init__ fills the default
        return fp

    @abc.abstractmethod
    def _states(self, tt: np.ndarray, o: np.ndarray, offsets: np.ndarray,
                cache: TrackCache | None
                ) -> tuple[np.ndarray, np.ndarray, PoseFilterResult | dict[str, Any]]:
        """States (n, 6) [x, y, yaw, v, a, yaw rate], their heading sd (n,) rad, and the
        forward pass (status, counts, NIS, the parameters it used); or (states, status (n,),
        extra columns dict) for a tracker without a pose-filter pass. Each tracker of the
        family defines it (an abstract method: the base is not a tracker)."""

    def track(self, t: Any, obs: Any, config: Any, *, cache: TrackCache | None = None
              ) -> pd.DataFrame:
        """Track a recording: t (n,) s, obs (n, m, 2) m (NaN missing), config a
        :class:`estimator.configuration.SensorConfig`; ``cache`` a
        :class:`estimator.memo.TrackCache` (the forward pass and the smoothing) or None."""
        tt, o, cfg = self._start(t, obs, config)
        k0 = self.window - 1
        offsets = cfg.body_positions - cfg.cg_body
        X, second, res = self._states(tt, o, offsets, cache)
        if isinstance(res, dict):
            # (states, status, extra columns): a tracker of the family without a forward
            # pass of its own (the GTSAM peer); "_no_slip_point_m" in extra: the point it used
            extra = dict(res)
            ns = extra.pop("_no_slip_point_m", self.params.no_slip_point_m)
            status = second
        else:
            ns = (res.params or self.params).no_slip_point_m    # as the pass resolved it
            status = res.status
            extra = {**_filter_counts(res), "yaw_sd": second}
        r_m = offsets - np.asarray(ns if ns is not None else (0.0, 0.0), dtype=float)
        pos_all, cg_all = state_poses(X, r_m, cfg, cache)
        pos, cg = pos_all[k0:].copy(), cg_all[k0:].copy()
        # the law-of-cosines heading is relative to the first row's side (Section 3.2), so
        # it is not a suffix of the whole recording's: each window computes its own
        yaw_loc = loc_heading(cfg, pos)
        X = X[k0:]
        extra = {"speed": X[:, 3].copy(), "yaw_rate": X[:, 5].copy(),
                 **{k: v[k0:].copy() for k, v in extra.items()}}
        rows = Rows.fixed(tt.size, self.window)
        return frame(tt, o, cfg, rows, pos=pos, cg=cg, yaw=X[:, 2].copy(), yaw_loc=yaw_loc,
                     status=np.asarray(status[k0:], dtype=object), extra=extra,
                     settings=settings(self.name, self.window, cfg),
                     layout_check=self.layout_check)


def state_poses(X: np.ndarray, r_m: np.ndarray, cfg: SensorConfig, cache: TrackCache | None
                ) -> tuple[np.ndarray, np.ndarray]:
    """Antenna positions (n, m, 2) m of the states X (n, 6) with lever arms r_m (m, 2) m
    from the no-slip point and their CG (n, 2) m, through ``cache.poses`` (read-only). A
    row depends on its state alone, so the rows of every window are a suffix of these: the
    filter's rows at windows 1, 5, 10, 100 are computed once."""
    def compute() -> tuple[np.ndarray, np.ndarray]:
        c, sn = np.cos(X[:, 2]), np.sin(X[:, 2])
        R = np.stack([np.stack([c, -sn], -1), np.stack([sn, c], -1)], -2)  # (n, 2, 2)
        pos = rotate(R, r_m[None], X[:, :2])     # X[:, None, :2] + R r_m, the same bits
        return freeze(pos), freeze(cfg.cg_from_positions(pos))

    return memo_get(cache, "poses", lambda: ("filter", content_digest(X, r_m,
                                                                      cfg.body_positions),
                                             cfg.names, tuple(cfg.dead)), compute)


def _filter_counts(res: PoseFilterResult) -> dict[str, Any]:
    """Fixes accepted / rejected and displacements accepted per epoch (n,), the NIS and
    its degrees of freedom."""
    return {"n_used": res.n_used, "n_gated": res.n_gated, "n_steps": res.n_steps,
            "nis": res.nis, "nis_dof": res.nis_dof}


def _yaw_sd(P: np.ndarray | None, n: int) -> np.ndarray:
    """Heading sd (n,) rad from covariances (n, 6, 6), NaN without them."""
    if P is None:
        return np.full(n, np.nan)
    return np.sqrt(np.maximum(P[:, 2, 2], 0.0))


@dataclass(frozen=True, kw_only=True, eq=False)
class PoseFilterTracker(FilterOptions):
    """The causal pose filter (``method="ekf"``, :mod:`estimator.pose_filter`); extra
    columns ``n_used, n_gated, n_steps``. Options: :class:`FilterOptions`."""

    name: ClassVar[str] = "ekf"

    def _states(self, tt, o, offsets, cache):
        # one forward pass per (observations, params) and cache, shared by the rows at every
        # window, the smoothers and the smoothed heading of the lag correction; the cached
        # arrays are read-only, the rows copy
        res = memo_pose_filter(tt, o, offsets, self.params, cache)
        return res.states, _yaw_sd(res.covariances, tt.size), res


@dataclass(frozen=True, kw_only=True, eq=False)
class FixedLagSmootherTracker(FilterOptions):
    """The filter's fixed-lag smoother (``method="ekf_fixed_lag"``, latency
    ``filter_params.lag_s``; :func:`estimator.pose_smoother.fixed_lag_smooth`); the status
    and counts of the forward pass. Options: :class:`FilterOptions`."""

    name: ClassVar[str] = "ekf_fixed_lag"

    def _states(self, tt, o, offsets, cache):
        p = self.params
        res = memo_pose_filter(tt, o, offsets, p, cache)
        X = memo_smoothed_states(tt, o, offsets, p, p.lag_s, cache)
        return X, _yaw_sd(None, tt.size), res


@dataclass(frozen=True, kw_only=True, eq=False)
class RtsSmootherTracker(FilterOptions):
    """The filter's full RTS smoother (``method="ekf_smoother"``;
    :func:`estimator.pose_smoother.rts_smooth`); the status and counts of the forward pass.
    Options: :class:`FilterOptions`."""

    name: ClassVar[str] = "ekf_smoother"

    def _states(self, tt, o, offsets, cache):
        p = self.params
        res = memo_pose_filter(tt, o, offsets, p, cache)
        X, P = memo_smoothed_states(tt, o, offsets, p, None, cache, covariances=True)
        return X, _yaw_sd(P, tt.size), res


@dataclass(frozen=True, kw_only=True, eq=False)
class IteratedSmootherTracker(FilterOptions):
    """The filter's iterated RTS smoother (``method="ekf_ieks"``, issue 25: Gauss-Newton on
    the whole trajectory, :func:`estimator.pose_smoother.iterated_rts_smooth`) with
    ``iterations`` passes (1 to MAX_SMOOTHER_ITERATIONS, default
    :data:`estimator.pose_smoother.IEKS_ITERATIONS`); the status and counts of the forward
    pass, which it shares with the other trackers of the family. Options:
    :class:`FilterOptions`, ``iterations``."""

    name: ClassVar[str] = "ekf_ieks"
    iterations: int = IEKS_ITERATIONS

    def __post_init__(self) -> None:
        super().__post_init__()
        check_int(self.iterations, "iterations", lo=1, hi=MAX_SMOOTHER_ITERATIONS)

    def _states(self, tt, o, offsets, cache):
        p = replace(self.params, smoother_iterations=0)
        res = memo_pose_filter(tt, o, offsets, p, cache)
        X, P = memo_smoothed_states(tt, o, offsets, replace(p, smoother_iterations=self.iterations),
                                    None, cache, covariances=True)
        return X, _yaw_sd(P, tt.size), res
