"""What every built-in tracker shares: input checks, the options every one takes, the rows
of a track and the output table (columns, settings, layout check).

Source: 000_8f82f8df647bf685.txt (GPS dissertation), Sections 3.2 (law-of-cosines heading)
and 3.4.1 (the first estimate at epoch s); the columns are described in
:func:`estimator.tracking.track`.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import pandas as pd

from estimator._checks import check_increasing_times, check_int
from estimator.configuration import LayoutWarning, SensorConfig
from estimator.layout_check import check_layout
from estimator.orientation import law_of_cosines_heading
from estimator.track_options import DynamicWindow, FitOptions, LagCorrection
from estimator.weights import Weighting

__all__ = ["Rows", "TrackerOptions", "check_inputs", "frame", "heading_pair", "settings"]

#: The weighting of a tracker that takes none (its settings record "none").
NO_WEIGHTS = Weighting.parse("none")


def check_inputs(t: Any, obs: Any, config: Any) -> tuple[np.ndarray, np.ndarray, SensorConfig]:
    """(t (n,) s, obs (n, m, 2) m, the planar config) checked: strictly increasing finite
    times, the configuration's m sensors, no infinities, NaN in both coordinates or none."""
    if not isinstance(config, SensorConfig):
        raise ValueError(  # noqa: TRY004 (bad input is ValueError by contract)
            f"config: expected a SensorConfig, got {type(config).__name__}")
    cfg = config.planar()
    tt = check_increasing_times(t, "t", min_size=1)
    o = np.asarray(obs, dtype=float)
    if o.shape != (tt.size, cfg.m, 2):
        raise ValueError(f"obs: expected shape ({tt.size}, {cfg.m}, 2) (epochs, sensors of "
                         f"{cfg.name!r}, xy), got {o.shape}")
    if np.isinf(o).any():
        raise ValueError("obs: contains infinite values (use NaN for missing samples)")
    nan = np.isnan(o)
    if np.any(nan[..., 0] != nan[..., 1]):
        k, i = np.argwhere(nan[..., 0] != nan[..., 1])[0]
        raise ValueError(f"obs: epoch {k}, sensor {cfg.names[i]!r} has one coordinate NaN; "
                         f"a missing observation must be NaN in both")
    return tt, o, cfg


def heading_pair(config: SensorConfig) -> tuple[int, int, float]:
    """The platform side used for the law-of-cosines heading (Section 3.2).

    Among alive sensors, the pair (rear i, front j) with the longest body-x extent, ties
    broken by the smallest lateral offset (a side along the body axis). Returns
    (i, j, body angle of the side i -> j in radians).
    """
    B = config.body_positions[:, :2]
    alive = np.flatnonzero(config.alive_mask)
    best = None
    for a in alive:
        for b in alive:
            dx = B[b, 0] - B[a, 0]
            if dx <= 0:
                continue
            key = (round(dx, 9), -round(abs(B[b, 1] - B[a, 1]), 9))
            if best is None or key > best[0]:
                best = (key, int(a), int(b))
    if best is None:  # all alive sensors share body x: use the longest pair
        i, j = int(alive[0]), int(alive[-1])
    else:
        _, i, j = best
    d = B[j] - B[i]
    return i, j, float(np.arctan2(d[1], d[0]))



@dataclass(frozen=True, kw_only=True, eq=False)
class TrackerOptions:
    """Options of every built-in tracker.

    window : s >= 1 epochs; the first row is at epoch s (row index s-1), then one per epoch
        (Section 3.4.1); the tracker checks s <= n against the recording.
    layout_check : run :func:`estimator.layout_check.check_layout` on the observations
        (``df.attrs["layout_check"]``, ``df.attrs["warnings"]``, a
        :class:`estimator.configuration.LayoutWarning` per finding).
    """

    #: The method name of :data:`estimator.track_options.METHODS` (the registry's key).
    name: ClassVar[str] = ""

    window: int = 10
    layout_check: bool = True

    def __post_init__(self) -> None:
        object.__setattr__(self, "window", check_int(self.window, "window", lo=1))
        if not isinstance(self.layout_check, (bool, np.bool_)):
            raise TypeError(f"layout_check: must be True or False, got {self.layout_check!r}")

    def _start(self, t: Any, obs: Any, config: Any) -> tuple[np.ndarray, np.ndarray,
                                                              SensorConfig]:
        """Checked (t, obs, planar config) and window <= n."""
        tt, o, cfg = check_inputs(t, obs, config)
        check_int(self.window, "window", 1, tt.size)
        return tt, o, cfg


@dataclass(frozen=True)
class Rows:
    """The rows of a track: ``ends`` (N,) the newest epoch of each row's window, ``wsize``
    (N,) their window sizes, ``flags`` (n,) the turning flags of every epoch."""

    ends: np.ndarray
    wsize: np.ndarray
    flags: np.ndarray

    @classmethod
    def fixed(cls, n: int, s: int) -> Rows:
        """Rows from epoch s-1, all of window s, nothing turning."""
        ends = np.arange(s - 1, n)
        return cls(ends, np.full(ends.size, s, dtype=int), np.zeros(n, dtype=bool))


def cg_and_heading(cfg: SensorConfig, pos: np.ndarray, naive: bool = False
                   ) -> tuple[np.ndarray, np.ndarray]:
    """CG (N, 2) of the positions (N, m, 2) (Eq. 3.8) and their law-of-cosines heading (N,)
    rad (Section 3.2; NaN for the naive tracker, which has no pose)."""
    cg = cfg.cg_from_positions(pos)
    if naive:
        return cg, np.full(pos.shape[0], np.nan)
    return cg, loc_heading(cfg, pos)


def loc_heading(cfg: SensorConfig, pos: np.ndarray) -> np.ndarray:
    """The law-of-cosines heading (N,) rad of positions (N, m, 2) (Section 3.2; the side of
    :func:`heading_pair`, relative to the first row's)."""
    i, j, ang = heading_pair(cfg)
    return law_of_cosines_heading(pos[:, j] - pos[:, i], ang)


def settings(name: str, s: int, cfg: SensorConfig, *, weighting: Weighting = NO_WEIGHTS,
             lag: LagCorrection | None = None, dyn: DynamicWindow | None = None,
             turning: Any = None, solver: str = "procrustes", fit: FitOptions | None = None
             ) -> dict[str, Any]:
    """``df.attrs["settings"]`` of a track (the arguments of :func:`estimator.tracking.track`
    that made it; a tracker without an option records its default)."""
    fit = fit or FitOptions()
    return {
        "method": name, "window": s, "weighting": weighting.scheme,
        "lag_correction": False if lag is None else lag.mode,
        "dynamic_window": None if dyn is None else dyn.small,
        "turning": ("detect" if isinstance(turning, str)
                    else "flags" if turning is not None else None),
        "solver": solver, "eps": fit.eps, "huff_threshold": weighting.huff_threshold,
        "huber_c": weighting.huber_c, "warm_start": fit.warm_start, "config": cfg.name,
        "window_growth": None if dyn is None else dyn.growth,
        "lag_heading": "given" if lag is not None and lag.heading is not None else None,
    }


def status_values(status: np.ndarray) -> np.ndarray:
    """The ``solver_status`` column's values, ``status.astype(str)`` as pandas stores them:
    an object array of str (every built-in tracker's) is handed over as it is, since pandas
    makes the same column of it (pandas >= 3: one Arrow string array; 2.x: object) without
    the '<U' copy (0.4 ms of a 4000-row table's 0.7 ms, tests/test_trackers.py)."""
    s = np.asarray(status)
    if s.dtype == object and all(type(v) is str for v in set(s.tolist())):
        return s
    return s.astype(str)


def table(cols: dict[str, Any], n: int) -> pd.DataFrame:
    """``pd.DataFrame(cols)`` of 1-D columns of length ``n``, built from one block per
    dtype (``pandas.api.internals.create_dataframe_from_blocks``, pandas >= 3): the same
    table (columns, dtypes, values; tests/test_trackers.py) at ~0.4 of the dict
    constructor's cost, which checks and converts column by column (~1 ms of a cell).
    Anything else (other pandas, a column that is not 1-D numbers or bools of length n,
    or strings) takes the dict constructor."""
    try:
        from pandas.api.internals import (  # type: ignore[import-not-found,unused-ignore]
            create_dataframe_from_blocks,
        )
    except ImportError:
        return pd.DataFrame(cols)
    groups: dict[np.dtype, list[int]] = {}
    arrays = [np.asarray(v) for v in cols.values()]
    blocks: list[tuple[Any, np.ndarray]] = []
    for i, a in enumerate(arrays):
        if a.shape != (n,):
            return pd.DataFrame(cols)
        if a.dtype.kind in "fiub":
            groups.setdefault(a.dtype, []).append(i)
            continue
        # an object column: the extension array pandas infers for it (strings: its string
        # dtype), by the conversion the dict constructor applies; anything else: that one
        ext = pd.Series(a, copy=False).array if a.dtype == object else None
        if ext is None or not isinstance(ext.dtype, pd.StringDtype):
            return pd.DataFrame(cols)
        blocks.append((ext, np.array([i], dtype=np.intp)))
    for dtype, idx in groups.items():
        blk = np.empty((len(idx), n), dtype=dtype)
        for r, i in enumerate(idx):
            blk[r] = arrays[i]
        blocks.append((blk, np.array(idx, dtype=np.intp)))
    return create_dataframe_from_blocks(blocks, index=pd.RangeIndex(n),
                                        columns=pd.Index(list(cols)))


def frame(tt: np.ndarray, o: np.ndarray, cfg: SensorConfig, rows: Rows, *, pos: np.ndarray,
          cg: np.ndarray, yaw: np.ndarray, yaw_loc: np.ndarray, status: np.ndarray,
          extra: dict[str, np.ndarray], settings: dict[str, Any], layout_check: bool,
          lag_dx: np.ndarray | None = None, lag_dy: np.ndarray | None = None) -> pd.DataFrame:
    """The output table of a track (columns in :func:`estimator.tracking.track`): one row
    per entry of ``rows.ends``; positions (N, m, 2) m, cg (N, 2) m, yaw / yaw_loc (N,) rad,
    lag shifts (N,) m (None: 0, no correction), ``extra`` columns last."""
    N = rows.ends.size
    cols: dict[str, Any] = {
        "t": tt[rows.ends], "cg_x": cg[:, 0], "cg_y": cg[:, 1], "yaw": yaw, "yaw_loc": yaw_loc,
        "window": rows.wsize, "solver_status": status_values(status),
        "turning": rows.flags[rows.ends],
        "lag_dx": np.zeros(N) if lag_dx is None else lag_dx,
        "lag_dy": np.zeros(N) if lag_dy is None else lag_dy,
    }
    for k, name in enumerate(cfg.names):
        cols[f"x_{name}"] = pos[:, k, 0]
        cols[f"y_{name}"] = pos[:, k, 1]
    cols.update(extra)
    df = table(cols, N)
    df.attrs["settings"] = settings
    if layout_check:
        lc = check_layout(tt, o, cfg, window=settings["window"])
        df.attrs["layout_check"] = lc.to_dict()
        df.attrs["warnings"] = list(lc.warnings)
        for msg in lc.warnings:
            warnings.warn(msg, LayoutWarning, stacklevel=4)
    return df
