"""The dissertation's tracker: the configuration-constrained sliding-window fit.

Source: 000_8f82f8df647bf685.txt (GPS dissertation), Sections 3.1.2 (solvers, warm start),
3.3 (weights), 3.4.1 (sliding window, Eq. 3.9), 3.4.2 (lag correction) and 3.4.2.1 (dynamic
window); the method is described in :mod:`estimator.tracking` (``method="window"``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import pandas as pd

from estimator._checks import check_int
from estimator.configuration import SensorConfig
from estimator.memo import TrackCache, content_digest, freeze, memo_get
from estimator.track_options import FitOptions, LagCorrection
from estimator.trackers._common import Rows, cg_and_heading, frame, settings
from estimator.trackers._windows import WeightedOptions, fit_windows, lag_correct, runs
from estimator.window import SOLVERS

__all__ = ["WindowTracker"]


@dataclass(frozen=True, kw_only=True, eq=False)
class WindowTracker(WeightedOptions):
    """Sliding-window fit of the configuration (Section 3.4.1), one row per epoch from s-1.

    Options (keyword-only, validated here; see also :class:`WeightedOptions`,
    :class:`DynamicOptions`, :class:`TrackerOptions` of :mod:`estimator.trackers`):
    solver : "procrustes" | "slsqp" | "ccp" | "elastic" (:data:`estimator.window.SOLVERS`).
    fit : :class:`estimator.track_options.FitOptions` (eps band, warm start, iterations).
    lag_correction : False, True (= "pose"), "pose", "course" or a
        :class:`estimator.track_options.LagCorrection` (stored as one, or None).
    """

    name: ClassVar[str] = "window"

    solver: str = "procrustes"
    fit: FitOptions | None = None
    lag_correction: bool | str | LagCorrection | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.solver not in SOLVERS:
            raise ValueError(f"solver: unknown {self.solver!r}; choose one of {list(SOLVERS)}")
        if self.fit is not None and not isinstance(self.fit, FitOptions):
            raise TypeError(f"fit: expected a FitOptions, got {type(self.fit).__name__}")
        fit = self.fit or FitOptions()
        object.__setattr__(self, "fit", fit)
        if fit.warm_start and self.solver == "elastic":
            raise ValueError("warm_start: the batched elastic solver starts every window from "
                             "its procrustes fit; warm_start applies to 'slsqp' and 'ccp'")
        object.__setattr__(self, "lag_correction", self._lag)

    @property
    def _fit(self) -> FitOptions:
        """``fit`` as the object ``__post_init__`` stored (None: the defaults)."""
        return self.fit or FitOptions()

    @property
    def _lag(self) -> LagCorrection | None:
        """``lag_correction`` as the object ``__post_init__`` stored (None: no correction)."""
        lag = self.lag_correction
        return None if lag is None else LagCorrection.coerce(lag)

    def track(self, t: Any, obs: Any, config: Any, *, cache: TrackCache | None = None
              ) -> pd.DataFrame:
        """Track a recording: t (n,) s, obs (n, m, 2) m (NaN missing), config a
        :class:`estimator.configuration.SensorConfig`; ``cache`` a
        :class:`estimator.memo.TrackCache` or None. Columns in :func:`estimator.tracking.track`."""
        tt, o, cfg = self._start(t, obs, config)
        lag = self._lag
        if lag is not None:
            if lag.velocity_span is not None:
                check_int(lag.velocity_span, "velocity_span", 1, tt.size)
            if lag.heading is not None and lag.heading.shape != (tt.size,):
                raise ValueError(f"lag_heading: expected a float array of shape ({tt.size},) "
                                 f"(radians), got {lag.heading.dtype} {lag.heading.shape}")
        rows = self._rows(tt, o, cfg)
        common = self._common(cache)
        pos, yaw, status = self._fits(o, cfg, rows, common)
        cg, yaw_loc = self._heading(o, cfg, rows, pos, cache)
        lag_dx = lag_dy = None
        if lag is not None:
            heading = yaw_loc if lag.heading is None else lag.heading[rows.ends]
            s = self.window
            shift = lag_correct(tt, o, cfg, rows.ends, rows.wsize, pos, cg, heading, s,
                                lag.mode, lag.velocity_span or s,
                                self.dynamic_window is not None, common, self._fit.eps)
            ok = np.all(np.isfinite(shift), axis=1)
            pos = pos + np.where(ok[:, None], shift, 0.0)[:, None, :]
            cg = cg + np.where(ok[:, None], shift, 0.0)
            lag_dx = np.where(ok, shift[:, 0], np.nan)
            lag_dy = np.where(ok, shift[:, 1], np.nan)
        st = settings(self.name, self.window, cfg, weighting=self._weighting, lag=lag,
                      dyn=self._dynamic, turning=self.turning, solver=self.solver,
                      fit=self._fit)
        return frame(tt, o, cfg, rows, pos=pos, cg=cg, yaw=yaw, yaw_loc=yaw_loc, status=status,
                     extra={}, settings=st, layout_check=self.layout_check, lag_dx=lag_dx,
                     lag_dy=lag_dy)

    def _heading(self, o: np.ndarray, cfg: SensorConfig, rows: Rows, pos: np.ndarray,
                 cache: TrackCache | None) -> tuple[np.ndarray, np.ndarray]:
        """CG (N, 2) m and law-of-cosines heading (N,) rad of the fits ``pos`` (N, m, 2),
        through ``cache.poses`` when the fits are a memoised request (no / Huff weights,
        procrustes or elastic: the techniques of one fit share them, e.g. None, LC and LC
        (course)); the heading is relative to the first row's side (Section 3.2), so the
        key is the fits' own: the same observations, rows, solver and options."""
        wt, fo = self._weighting, self._fit
        if cache is None or self.solver not in ("procrustes", "elastic") \
                or wt.scheme not in ("none", "huff") or wt.huff_threshold is not None:
            return cg_and_heading(cfg, pos)
        key = ("window", content_digest(o, rows.ends, rows.wsize, cfg.body_positions),
               cfg.names, tuple(cfg.dead), self.solver, wt.scheme, float(fo.eps),
               repr(sorted((fo.solver_kwargs() or {}).items())))
        cg, yaw_loc = memo_get(cache, "poses", lambda: key,
                               lambda: tuple(freeze(a) for a in cg_and_heading(cfg, pos)))
        return cg.copy(), yaw_loc.copy()

    def _fits(self, o: np.ndarray, cfg: SensorConfig, rows: Rows, common: dict[str, Any]
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Positions (N, m, 2), yaw (N,) and status (N,) of every row's window fit."""
        ends, wsize, solver, fo = rows.ends, rows.wsize, self.solver, self._fit
        eps, warm_start, fit_kw = fo.eps, fo.warm_start, fo.solver_kwargs() or {}
        N = ends.size
        pos = np.full((N, cfg.m, 2), np.nan)
        yaw = np.full(N, np.nan)
        status = np.empty(N, dtype=object)
        wt = self._weighting
        if solver in ("procrustes", "elastic") and wt.scheme in ("none", "huff") \
                and wt.huff_threshold is None:
            # per-sample weights: every row, whatever its window size, from one set of
            # cumulative sums (a refilling dynamic window has up to s - small + 1 sizes),
            # and one batched fit (the elastic solver ignores x0: no warm start to carry)
            pos, yaw, status, _ = fit_windows(o, cfg, ends, wsize, solver=solver, eps=eps,
                                              warm_start=False, fit_kw=fit_kw, **common)
        elif warm_start and solver != "procrustes":
            # x0 of every row is the previous row's fit (Section 3.1.2), whatever the window
            # size: fit the runs of equal size in time order, carrying the last fit across
            prev = None
            for a, b in runs(wsize):
                sl = slice(a, b)
                pos[sl], yaw[sl], status[sl], prev = fit_windows(
                    o, cfg, ends[sl], int(wsize[a]), solver=solver, eps=eps, warm_start=True,
                    fit_kw=fit_kw, prev=prev, **common)
        else:
            for w in np.unique(wsize):
                sel = wsize == w
                p, y, st, _ = fit_windows(o, cfg, ends[sel], int(w), solver=solver, eps=eps,
                                          warm_start=warm_start, fit_kw=fit_kw, **common)
                pos[sel], yaw[sel], status[sel] = p, y, st
        return pos, yaw, status
