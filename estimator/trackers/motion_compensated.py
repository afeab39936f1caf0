"""The motion-compensated window: the pose at the newest epoch of each window under a
constant-velocity (optionally constant yaw-rate) model (:mod:`estimator.motion`).

Beyond the dissertation (000_8f82f8df647bf685.txt); windows, weights and the dynamic window
as in Sections 3.3, 3.4.1 and 3.4.2.1; described in :mod:`estimator.tracking`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import pandas as pd

from estimator.configuration import SensorConfig
from estimator.memo import TrackCache
from estimator.motion import motion_compensated_batch, motion_compensated_series
from estimator.track_options import MotionOptions
from estimator.trackers._common import cg_and_heading, frame, settings
from estimator.trackers._windows import (
    Floats,
    WeightedOptions,
    chunks,
    recording_huff,
    sample_huff,
    stack_windows,
    window_weights,
)

__all__ = ["MotionCompensatedTracker"]


@dataclass(frozen=True, kw_only=True, eq=False)
class MotionCompensatedTracker(WeightedOptions):
    """Motion-compensated window (``method="motion_compensated"``); extra columns ``speed``
    (m/s) and ``yaw_rate`` (rad/s).

    Options (keyword-only; see also :class:`WeightedOptions`, :class:`DynamicOptions`,
    :class:`TrackerOptions`): motion : :class:`estimator.track_options.MotionOptions`
    (constant yaw rate or not, its bound).
    """

    name: ClassVar[str] = "motion_compensated"

    motion: MotionOptions | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.motion is not None and not isinstance(self.motion, MotionOptions):
            raise TypeError(f"motion: expected a MotionOptions, got {type(self.motion).__name__}")
        object.__setattr__(self, "motion", self._motion)

    @property
    def _motion(self) -> MotionOptions:
        """``motion`` as the object ``__post_init__`` stored (None: the defaults)."""
        return self.motion or MotionOptions()

    def track(self, t: Any, obs: Any, config: Any, *, cache: TrackCache | None = None
              ) -> pd.DataFrame:
        """Track a recording: t (n,) s, obs (n, m, 2) m (NaN missing), config a
        :class:`estimator.configuration.SensorConfig`; ``cache`` a
        :class:`estimator.memo.TrackCache` or None. Columns in :func:`estimator.tracking.track`."""
        tt, o, cfg = self._start(t, obs, config)
        rows = self._rows(tt, o, cfg)
        ends, wsize, N, mo = rows.ends, rows.wsize, rows.ends.size, self._motion
        pos = np.full((N, cfg.m, 2), np.nan)
        yaw = np.full(N, np.nan)
        status = np.empty(N, dtype=object)
        extra = {k: np.full(N, np.nan) for k in ("yaw_rate", "vx", "vy")}
        for w in np.unique(wsize):
            sel = wsize == w
            p, out, fit_status = motion_windows(tt, o, cfg, ends[sel], int(w), yaw_rate=mo.yaw_rate,
                                        omega_max=mo.omega_max, **self._common(cache))
            pos[sel], yaw[sel], status[sel] = p, out["yaw"], fit_status
            for k, col in extra.items():
                col[sel] = out[k]
        extra = {"speed": np.hypot(extra["vx"], extra["vy"]), "yaw_rate": extra["yaw_rate"]}
        cg, yaw_loc = cg_and_heading(cfg, pos)
        st = settings(self.name, self.window, cfg, weighting=self._weighting,
                      dyn=self._dynamic, turning=self.turning)
        return frame(tt, o, cfg, rows, pos=pos, cg=cg, yaw=yaw, yaw_loc=yaw_loc, status=status,
                     extra=extra, settings=st, layout_check=self.layout_check)


def motion_windows(t: np.ndarray, obs: np.ndarray, cfg: SensorConfig, ends: np.ndarray, w: int,
                   *, weighting: str, rng: np.random.Generator | None,
                   huff_threshold: float | None, huber_c: float, yaw_rate: bool,
                   omega_max: float, cache: TrackCache | None
                   ) -> tuple[Floats, dict[str, Floats], np.ndarray]:
    """Motion-compensated fits (:mod:`estimator.motion`) of the windows of size w ending at
    ``ends``: positions (N, m, 2), {"yaw", "yaw_rate", "vx", "vy"} (N,) each, status (N,)."""
    N, m = ends.size, cfg.m
    pos = np.full((N, m, 2), np.nan)
    out = {k: np.full(N, np.nan) for k in ("yaw", "yaw_rate", "vx", "vy")}
    status = np.empty(N, dtype=object)
    if not yaw_rate and weighting in ("none", "huff"):
        # per-sample weights and omega = 0: per-epoch sums, no stacking of the sensor axis
        sw = None if weighting == "none" else recording_huff(obs, cfg, huff_threshold, cache)
        fit = motion_compensated_series(t, obs, cfg, ends, w, sw)
        out = {"yaw": fit.yaw, "yaw_rate": fit.yaw_rate, "vx": fit.velocity[:, 0],
               "vy": fit.velocity[:, 1]}
        return fit.positions, out, fit.status.astype(object)
    a = 0
    huff = sample_huff(obs, cfg, weighting, huff_threshold, cache)
    for ch in chunks(ends, w, m):
        st = stack_windows(obs, ch, w)
        wts = window_weights(st, cfg, weighting, rng, huff_threshold, huber_c,
                              None if huff is None else stack_windows(huff, ch, w))
        idx = ch[:, None] - np.arange(w - 1, -1, -1)[None, :]
        tau = t[idx] - t[ch][:, None]
        fit = motion_compensated_batch(tau, st, cfg, wts, yaw_rate=yaw_rate,
                                       omega_max=omega_max)
        sl = slice(a, a + ch.size)
        pos[sl] = fit.positions
        out["yaw"][sl], out["yaw_rate"][sl] = fit.yaw, fit.yaw_rate
        out["vx"][sl], out["vy"][sl] = fit.velocity[:, 0], fit.velocity[:, 1]
        status[sl] = fit.status
        a += ch.size
    return pos, out, status

