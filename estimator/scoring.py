"""A sweep cell's scores: one track against its reference, summarised per evaluation mask.

The statistics are :mod:`estimator.metrics`' (the one scorer): Eq. 4.1 / 4.2 errors of
000_8f82f8df647bf685.txt (:func:`~estimator.metrics.track_errors`), their summaries
(:func:`~estimator.metrics.summarize`), the epoch-to-epoch jitter
(:func:`~estimator.metrics.jitter_rms`) and the evaluation masks
(:func:`~estimator.metrics.evaluation_masks`). This module lays them out as the rows and the
per-epoch table of a cell (the columns of ``cells.parquet`` and ``epochs/<key>.parquet``).

The reference is any object with the attributes of :class:`sim.truth.Truth` that are read
here: ``t`` (n,) s, ``cg`` (n, 2|3) m, ``yaw`` (n,) rad, ``turning`` (n,) bool,
``sensor_positions`` (n, m, 2|3) m, ``sensor_names`` (m,) and ``n``.
"""

from __future__ import annotations

import warnings
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from estimator._checks import check_increasing_times
from estimator.metrics import (
    STATISTICS,
    TrackErrors,
    error_steps,
    errors_at,
    index_rows,
    jitter_of_steps,
    nearest_samples,
    summaries,
    track_cg,
    travel_direction,
)
from estimator.orientation import wrap_angle

# pandas is imported where a table is built: the sweep's main process imports this module
# before it needs pandas (0.4 s off the critical path of a one-path sweep)
if TYPE_CHECKING:
    import pandas as pd

__all__ = ["CONSISTENCY_COLUMNS", "SERIES_COLUMNS", "ScoringReference", "consistency",
           "coverage_rows", "score_track", "status_counts"]

#: Column prefixes of the error series in cells.parquet (estimator.metrics.TrackErrors).
SERIES_COLUMNS = {"ex": "x", "ey": "y", "eu": "euclid", "eh": "heading"}
#: Consistency columns (issue 25): heading NEES from the row's ``yaw_sd`` against the truth
#: and the forward pass's NIS (``nis``, ``nis_dof``): the mean per dof (1 when consistent)
#: and the share of rows inside the central 95 % chi-square band (0.95 when consistent);
#: the share of rows whose status is not "ok" and of those flagged "inconsistent". NaN for
#: a track without the columns (window fits have no covariance, the GTSAM peer and the
#: fixed-lag smoother none of their own: :mod:`estimator.trackers.ekf`).
CONSISTENCY_COLUMNS = ("nees_mean", "nees_in_band", "nis_per_dof", "nis_in_band",
                       "status_not_ok", "status_inconsistent")
#: The central chi-square band of the consistency shares (nis_summary's default).
_BAND = 0.95
#: The track columns the consistency columns are computed from (when present).
_CONSISTENCY_INPUTS = ("yaw_sd", "nis", "nis_dof", "solver_status")
#: Columns of a row beside the series statistics.
_EXTRA = ("along_mean", "along_median", "jitter_rms", "obs_ex_mean", "obs_ey_mean",
          *CONSISTENCY_COLUMNS)


def score_track(df: pd.DataFrame, truth: Any, obs: np.ndarray, config: Any,
                masks: Iterable[str], epochs: bool = True, *,
                reference: ScoringReference | None = None
                ) -> tuple[list[dict], pd.DataFrame | None]:
    """Eq. 4.1/4.2 errors of a track against the truth, summarised per evaluation mask.

    df : the track (columns t, cg_x, cg_y, yaw; ``window`` (int) if the tracker has one,
    else each estimate counts as its own epoch's). obs (n, m, 2) m : the observations.
    reference : :meth:`ScoringReference.of` ``(truth, obs)``, for a caller that scores
    several tracks of the same truth and observations (what does not depend on the track,
    computed once); None: computed here.
    Returns one dict per mask with, for each error series (``ex`` = |x| CG error, ``ey`` =
    |y|, ``eu`` = Euclidean, ``eh`` = heading, rad), the statistics mean, median, std
    (ddof 1), rmse, p95, max and the box-plot outlier fraction; plus the signed along-track
    error (mean, median; negative = the estimate trails the truth, the lag of Section
    3.4.2; along the truth's direction of travel, :func:`estimator.metrics.travel_direction`),
    the epoch-to-epoch jitter (RMS change of the error vector between consecutive epochs,
    the "variation from one estimate to the next" of Section 4.10), the raw observations'
    own per-axis error for comparison, and counts. Also returns the per-epoch table (truth,
    errors, observations at the estimate times) when ``epochs`` is True, else None.

    Each column of ``df`` is read once, and the statistics of all series and masks come
    from :func:`estimator.metrics.summaries` (issue 27): the same numbers, bit for bit, as
    one :func:`estimator.metrics.summarize` per series and mask
    (``tests/test_scoring.py``).
    """
    cols = _TrackColumns.of(df)
    ref = ScoringReference.of(truth) if reference is None else reference.check(truth, obs)
    err = errors_at(nearest_samples(cols.t, ref.t, 1e-6), cols.cg, cols.yaw, ref.xy,
                    ref.direction, ref.yaw, cos_sin=ref.cos_sin)
    idx = err.index
    mk_all = _masks_at(ref, idx, cols.window)
    masks = list(masks)
    series = {q: getattr(err, attr) for q, attr in SERIES_COLUMNS.items()}
    sums = summaries({**series, "along": err.along}, {m: mk_all[m] for m in masks},
                     signed=("along",))
    obs_e = ref.obs_errors_at(idx) if reference is not None else \
        _obs_errors(obs, truth, index_rows(idx))
    steps = error_steps(err.dxy)
    cons = _ConsistencyInputs.of(cols.extra, err.heading)
    rows = []
    for mname in masks:
        row = _mask_row(mname, mk_all[mname], sums[mname], obs_e, steps)
        row.update(cons.at(mk_all[mname]))
        rows.append(row)
    if not epochs:
        return rows, None
    return rows, _epoch_table(cols.yaw, truth, obs, err, mk_all["no_turns_window"])


def status_counts(df: pd.DataFrame) -> dict[str, int]:
    """{status: rows} of a track's ``solver_status`` column ({} without one), most frequent
    first, ties in order of first appearance, missing values left out: pandas'
    ``value_counts`` of the column, counted by Arrow (an Arrow-backed column) or a Counter
    (pandas' own costs ~0.9 ms a cell on an Arrow-backed column, these ~0.05 ms)."""
    col = _columns(df, ("solver_status",)).get("solver_status")
    if col is None:
        return {}
    if hasattr(col, "__arrow_array__"):
        import pyarrow as pa  # type: ignore[import-untyped]
        import pyarrow.compute as pc  # type: ignore[import-untyped]

        vc = pc.value_counts(pa.array(col))
        pairs: Iterable[tuple[Any, int]] = zip(vc.field("values").to_pylist(),
                                               vc.field("counts").to_pylist())
    else:
        pairs = Counter(np.asarray(col, dtype=object).tolist()).items()
    counts = [(str(v), int(c)) for v, c in pairs if v is not None and v == v]  # NaN: not
    return dict(sorted(counts, key=lambda kv: -kv[1]))


def _columns(df: pd.DataFrame, names: Iterable[str]) -> dict[str, Any]:
    """The values (a numpy or pandas extension array) of each column of ``names`` that
    ``df`` has, without building a Series: ``DataFrame.__getitem__`` costs 30-70 us a call
    and ``name in df`` ~20 us (an Arrow-backed column index), ~1/3 of a cell's scoring;
    the column list once and pandas' own accessor of a column's array
    (``_get_column_array``, internal since pandas 1.3) ~2 us a column. Falls back to
    ``df[name].array`` where that accessor is missing or a name is not one unique column."""
    listed = df.columns.tolist()
    pos = {c: i for i, c in enumerate(listed)}
    get = getattr(df, "_get_column_array", None)
    unique = len(pos) == len(listed)
    return {c: get(pos[c]) if get is not None and unique else df[c].array
            for c in names if c in pos}


@dataclass(frozen=True)
class _TrackColumns:
    """The columns of a track table :func:`score_track` reads, each read once: t (k,) s,
    cg (k, 2) m, yaw (k,) rad, window (k,) int or None (no column), and ``extra``, the
    consistency columns present (name -> array)."""

    t: np.ndarray
    cg: np.ndarray
    yaw: np.ndarray
    window: np.ndarray | None
    extra: dict[str, Any]

    @classmethod
    def of(cls, df: pd.DataFrame) -> _TrackColumns:
        got = _columns(df, ("t", "cg_x", "cg_y", "yaw", "window", *_CONSISTENCY_INPUTS))
        for name in ("t", "cg_x", "cg_y", "yaw"):
            if name not in got:
                raise ValueError(f"df: the track has no column {name!r} (columns: "
                                 f"{sorted(map(str, df.columns))})")

        def num(name: str, dtype: type = float) -> np.ndarray:
            return np.asarray(got[name], dtype=dtype)

        return cls(t=_check_est_times(num("t")), cg=np.column_stack((num("cg_x"), num("cg_y"))),
                   yaw=num("yaw"), window=num("window", np.int64) if "window" in got else None,
                   extra={c: got[c] for c in _CONSISTENCY_INPUTS if c in got})


def _check_est_times(t: np.ndarray) -> np.ndarray:
    """``t`` (k,) s of the track, every time finite (:func:`estimator.metrics.align_to_truth`'s
    check of the estimate times)."""
    if t.ndim != 1:
        raise ValueError(f"est_t: expected shape (k,) of seconds, got shape {t.shape}")
    if not np.all(np.isfinite(t)):
        k = int(np.argmax(~np.isfinite(t)))
        raise ValueError(f"est_t: times must be finite; est_t[{k}] = {t[k]!r}")
    return t


@dataclass(frozen=True, eq=False)
class ScoringReference:
    """What :func:`score_track` needs of a reference and its observations that does not
    depend on the track (n epochs): t (n,) s strictly increasing, xy (n, 2) m, yaw (n,) rad,
    direction (n,) rad of travel (:func:`estimator.metrics.travel_direction`), turning (n,)
    bool, turn_count (n + 1,) the cumulative count of turning epochs (the window mask);
    obs_ex, obs_ey (n,) m the per-epoch mean |x| / |y| error of the observations over the
    sensors that have one and cos_sin the cosines and sines of ``direction`` (None: built
    without observations, for one track). ``truth`` and ``obs`` are the objects it was
    built from (:meth:`check`)."""

    t: np.ndarray
    xy: np.ndarray
    yaw: np.ndarray
    direction: np.ndarray
    turning: np.ndarray
    turn_count: np.ndarray
    obs_ex: np.ndarray | None = None
    obs_ey: np.ndarray | None = None
    cos_sin: tuple[np.ndarray, np.ndarray] | None = None
    truth: Any = None
    obs: Any = None

    @classmethod
    def of(cls, truth: Any, obs: np.ndarray | None = None) -> ScoringReference:
        """The reference quantities of ``truth`` (the attributes of the module docstring)
        and, with ``obs`` (n, m, 2) m, the observations' per-epoch errors."""
        tt = check_increasing_times(truth.t, "truth_t", min_size=1)
        xy = np.asarray(truth.cg, dtype=float)
        if xy.ndim != 2 or xy.shape[1] < 2 or xy.shape[0] != tt.size:
            raise ValueError(f"truth_xy: expected shape ({tt.size}, 2|3) (one row per truth "
                             f"time), got {xy.shape}")
        xy = xy[:, :2]
        yaw = np.asarray(truth.yaw, dtype=float)
        turning = np.asarray(truth.turning).astype(bool)
        if turning.shape != tt.shape:
            raise ValueError(f"turning: expected a 1-D bool array of shape {tt.shape}, got "
                             f"{turning.dtype} {turning.shape}")
        oe: tuple[np.ndarray | None, np.ndarray | None] = (None, None)
        direction = travel_direction(tt, xy, yaw)
        cos_sin = None
        if obs is not None:
            # a reference that serves many tracks: the direction's cosines and sines once
            cos_sin = (np.cos(direction), np.sin(direction))
            ob = np.asarray(obs)
            if ob.ndim != 3 or ob.shape[0] != tt.size or ob.shape[2] != 2:
                raise ValueError(f"obs: expected shape ({tt.size}, m, 2) (one row per truth "
                                 f"time), got {ob.shape}")
            oe = _obs_errors(ob, truth, slice(None))
        return cls(t=tt, xy=xy, yaw=yaw, direction=direction, turning=turning,
                   turn_count=np.concatenate([[0], np.cumsum(turning, dtype=np.int64)]),
                   obs_ex=oe[0], obs_ey=oe[1], cos_sin=cos_sin, truth=truth, obs=obs)

    def check(self, truth: Any, obs: np.ndarray) -> ScoringReference:
        """This reference, after checking it was built from ``truth`` and ``obs`` (the same
        objects) with the observations; else ValueError."""
        if self.truth is not truth or self.obs is not obs or self.obs_ex is None:
            raise ValueError("reference: built from another truth or observations (or "
                             "without observations); build it with "
                             "ScoringReference.of(truth, obs) of the same objects")
        return self

    def obs_errors_at(self, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The observations' per-epoch errors (obs_ex, obs_ey) at the epochs ``idx`` (k,)."""
        if self.obs_ex is None or self.obs_ey is None:
            raise ValueError("reference: built without observations (obs=None)")
        rows = index_rows(idx)
        return self.obs_ex[rows], self.obs_ey[rows]


def _masks_at(ref: ScoringReference, idx: np.ndarray, window: np.ndarray | None
              ) -> dict[str, np.ndarray]:
    """The :data:`estimator.metrics.MASKS` at the estimates ``idx`` (k,):
    :func:`estimator.metrics.evaluation_masks` (no margin) of the reference's turning flags
    with ``window`` (k,) int, or 1 per estimate without one, placed on the reference
    epochs."""
    n = ref.t.size
    win = np.zeros(n, dtype=np.int64)
    # a plug-in's table may have no window column: each estimate is its epoch's own
    win[idx] = window if window is not None else 1
    k = np.arange(n)
    bad = (win < 0) | (win > k + 1)
    if bad.any():
        j = int(np.argmax(bad))
        raise ValueError(f"window: window[{j}] = {win[j]} must be in [0, {j + 1}] (a "
                         "window cannot reach before the first epoch)")
    w = win[idx]
    c = ref.turn_count
    inside = c[idx + 1] - c[idx + 1 - w]
    return {"full": np.ones(idx.size, dtype=bool), "no_turns": ~ref.turning[idx],
            "no_turns_window": (w > 0) & (inside == 0)}


def _obs_errors(obs: np.ndarray, truth: Any, rows: slice | np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """Mean |x| and |y| error of the raw observations at the epochs ``rows`` (k,) m, over
    the sensors with an observation (NaN where none has one)."""
    sp = truth.sensor_positions
    ex = np.abs(obs[rows, :, 0] - sp[rows, :, 0])                 # (k, m)
    if not ex.size:
        return np.array([]), np.array([])
    return _nanmean_rows(ex), _nanmean_rows(np.abs(obs[rows, :, 1] - sp[rows, :, 1]))


def _nanmean_rows(a: np.ndarray) -> np.ndarray:
    """``np.nanmean(a, axis=1)`` of a C-contiguous (k, m) array the caller owns (changed in
    place): numpy's own arithmetic (NaN set to 0, the pairwise row sums over the count of
    values) without its copies; NaN for a row without a value, with no warning."""
    nan = np.isnan(a)
    if not nan.any():
        return np.add.reduce(a, axis=1) / a.shape[1]
    a[nan] = 0.0
    cnt = np.add.reduce(~nan, axis=1, dtype=np.intp)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.add.reduce(a, axis=1) / cnt


def _nanmean_at(v: np.ndarray, mk: np.ndarray) -> float:
    """``float(np.nanmean(v[mk]))`` (NaN without a value), without its copies when
    ``v[mk]`` has no NaN (the same pairwise sum over the same count)."""
    sel = v[mk]
    if not sel.size:
        return float("nan")
    if np.isnan(sel).any():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)      # all NaN: mean of nothing
            return float(np.nanmean(sel))
    return float(np.add.reduce(sel) / sel.size)


def _mask_row(mname: str, mk: np.ndarray, sums: dict[str, dict[str, float]],
              obs_e: tuple[np.ndarray, np.ndarray], steps: np.ndarray) -> dict[str, Any]:
    """The summary row of one mask (:func:`score_track`): sums the mask's summaries of
    the series (:func:`estimator.metrics.summaries`), steps (k - 1,) m the error's
    epoch-to-epoch steps (:func:`estimator.metrics.error_steps`)."""
    row: dict[str, Any] = {"mask": mname, "n_epochs": int(np.count_nonzero(mk))}
    for sname in SERIES_COLUMNS:
        sm = sums[sname]
        for k in (*STATISTICS, "outliers"):
            row[f"{sname}_{k}"] = sm[k]
        if sname == "ex":
            row["n_valid"], row["n_nan"] = sm["n"], sm["n_nan"]
    sa = sums["along"]
    row["along_mean"], row["along_median"] = sa["mean"], sa["median"]
    row["jitter_rms"] = jitter_of_steps(steps, mk)
    row["obs_ex_mean"] = _nanmean_at(obs_e[0], mk)
    row["obs_ey_mean"] = _nanmean_at(obs_e[1], mk)
    return row


def _epoch_table(yaw: np.ndarray, truth: Any, obs: np.ndarray, err: TrackErrors,
                 no_turns_window: np.ndarray) -> pd.DataFrame:
    """The per-epoch table of :func:`score_track`: truth, errors, observations (yaw (k,)
    rad: the track's heading)."""
    import pandas as pd

    idx = err.index
    tru = truth.cg[idx, :2]
    cols: dict[str, Any] = {
        "truth_cg_x": tru[:, 0], "truth_cg_y": tru[:, 1], "truth_yaw": truth.yaw[idx],
        "truth_turning": truth.turning[idx].astype(bool), "err_x": err.dx, "err_y": err.dy,
        "err_yaw": wrap_angle(yaw - truth.yaw[idx]),
        "along": err.along, "cross": err.cross, "no_turns_window": no_turns_window}
    # per-antenna truth and observations for plots: float32 (1e-5 m resolution at 200 m)
    # halves the files; the estimates, CG truth and errors stay float64
    for j, nm in enumerate(truth.sensor_names):
        cols[f"truth_{nm}_x"] = truth.sensor_positions[idx, j, 0].astype(np.float32)
        cols[f"truth_{nm}_y"] = truth.sensor_positions[idx, j, 1].astype(np.float32)
        cols[f"obs_{nm}_x"] = obs[idx, j, 0].astype(np.float32)
        cols[f"obs_{nm}_y"] = obs[idx, j, 1].astype(np.float32)
    return pd.DataFrame(cols)


def coverage_rows(df: pd.DataFrame) -> list[dict]:
    """Rows of a cell without a reference: mask "full" with the epoch and estimate counts
    (``n_epochs``, ``n_valid`` finite CG estimates, ``n_nan``); every error statistic of
    :func:`score_track` is NaN (nothing to score against), so the tables keep their shape."""
    cg = track_cg(df)
    ok = np.isfinite(cg).all(axis=1)
    row: dict[str, Any] = {"mask": "full", "n_epochs": len(df), "n_valid": int(ok.sum()),
                           "n_nan": int((~ok).sum())}
    nan = float("nan")
    for sname in SERIES_COLUMNS:
        row.update({f"{sname}_{k}": nan for k in (*STATISTICS, "outliers")})
    row.update(dict.fromkeys(_EXTRA, nan))
    row.update(consistency(df, None, np.ones(len(df), dtype=bool)))
    return [row]


def consistency(df: pd.DataFrame, heading_err: np.ndarray | None,
                mk: np.ndarray) -> dict[str, float]:
    """The :data:`CONSISTENCY_COLUMNS` of a track's rows ``mk`` (k,) bool.

    heading_err (n rows,) rad : the Eq. 4.2 heading error of every row (wrapped; None: no
    reference, NEES NaN).
    NEES per row ``(heading_err / yaw_sd)^2`` (chi-square, 1 dof;
    :func:`estimator.pose_filter.nees`), NIS from ``nis`` / ``nis_dof``; both summarised by
    :func:`estimator.pose_filter.nis_summary` (rows without a value are left out; none: NaN).
    """
    extra = _columns(df, _CONSISTENCY_INPUTS)
    return _ConsistencyInputs.of(extra, heading_err).at(np.asarray(mk))


@dataclass(frozen=True)
class _ConsistencyInputs:
    """The per-row inputs of :func:`consistency`, computed once per track: the NEES band
    (None: no ``yaw_sd`` or no reference), the NIS band (None: no ``nis`` / ``nis_dof``),
    not_ok and inconsistent (k,) bool of the status (None: no ``solver_status``)."""

    nees: _Band | None
    nis: _Band | None
    not_ok: np.ndarray | None
    inconsistent: np.ndarray | None

    @classmethod
    def of(cls, extra: dict[str, Any], heading_err: np.ndarray | None) -> _ConsistencyInputs:
        from estimator.pose_filter import nees

        ne = nis = not_ok = inc = None
        if "yaw_sd" in extra and heading_err is not None:
            sd = np.asarray(extra["yaw_sd"], dtype=float)
            e = np.asarray(heading_err, dtype=float)
            v = nees(e[:, None], (sd ** 2)[:, None, None])      # row by row: mask after
            ne = _Band.of(v, np.ones(v.size))
        if "nis" in extra and "nis_dof" in extra:
            nis = _Band.of(np.asarray(extra["nis"], dtype=float),
                           np.asarray(extra["nis_dof"], dtype=float))
        if "solver_status" in extra:
            not_ok, inc = _status_flags(extra["solver_status"])
        return cls(nees=ne, nis=nis, not_ok=not_ok, inconsistent=inc)

    def at(self, mk: np.ndarray) -> dict[str, float]:
        """The :data:`CONSISTENCY_COLUMNS` over the rows ``mk`` (k,) bool."""
        out = dict.fromkeys(CONSISTENCY_COLUMNS, float("nan"))
        if self.nees is not None:
            out["nees_mean"], out["nees_in_band"] = self.nees.at(mk)
        if self.nis is not None:
            out["nis_per_dof"], out["nis_in_band"] = self.nis.at(mk)
        n = int(np.count_nonzero(mk))
        if self.not_ok is not None and self.inconsistent is not None and n:
            # the shares as np.mean of the bools: an exact count over the same n
            out["status_not_ok"] = int(np.count_nonzero(self.not_ok & mk)) / n
            out["status_inconsistent"] = int(np.count_nonzero(self.inconsistent & mk)) / n
        return out


@dataclass(frozen=True)
class _Band:
    """:func:`estimator.pose_filter.nis_summary` of a track's rows, the per-row part done
    once: values v (k,) and their dof (k,), ok (k,) the rows with a value (finite, dof > 0)
    and inside (k,) those inside the central 95 % chi-square band of their dof."""

    v: np.ndarray
    dof: np.ndarray
    ok: np.ndarray
    inside: np.ndarray

    @classmethod
    def of(cls, v: np.ndarray, dof: np.ndarray) -> _Band:
        from estimator.pose_filter import _chdtri

        ok = np.isfinite(v) & (dof > 0)
        inside = np.zeros(v.size, dtype=bool)
        if ok.any():
            d = dof[ok]
            if (d == d[0]).all():         # one dof (the heading NEES): one band, no unique
                dof_u, row = d[:1], np.zeros(d.size, dtype=np.intp)
            else:
                dof_u, row = np.unique(d, return_inverse=True)
            # nis_summary's band (0.95) and the same expressions of its probabilities
            lo = _chdtri(dof_u, 0.5 + 0.5 * _BAND)[row]
            hi = _chdtri(dof_u, 0.5 - 0.5 * _BAND)[row]
            inside[ok] = (v[ok] >= lo) & (v[ok] <= hi)
        return cls(v=v, dof=dof, ok=ok, inside=inside)

    def at(self, mk: np.ndarray) -> tuple[float, float]:
        """(mean value per dof, share inside the band) of the rows ``mk``: nis_summary of
        those rows (the same sums of the same values in the same order); NaN without one."""
        ok = self.ok & mk
        n = int(np.count_nonzero(ok))
        if not n:
            return float("nan"), float("nan")
        return (float(self.v[ok].sum() / self.dof[ok].sum()),
                int(np.count_nonzero(self.inside & ok)) / n)


def _status_flags(status: Any) -> tuple[np.ndarray, np.ndarray]:
    """``status != "ok"`` and ``status == "inconsistent"`` (k,) bool of a status column (a
    numpy object array or a pandas string array; a missing status is not ok and not
    inconsistent, as comparing its object array). An Arrow-backed column is looked up in
    one Arrow pass (``pyarrow.compute.index_in``, ~1/4 of two pandas comparisons)."""
    if hasattr(status, "__arrow_array__"):
        import pyarrow as pa
        import pyarrow.compute as pc

        arr = pa.array(status)
        wanted = pa.array(["ok", "inconsistent"], type=arr.type)
        code = pc.fill_null(pc.index_in(arr, value_set=wanted), -1)
        c = np.asarray(code.to_numpy(zero_copy_only=False))
        return c != 0, c == 1
    ok = np.asarray(status, dtype=object) == "ok"
    inc = np.asarray(status, dtype=object) == "inconsistent"
    return ~np.asarray(ok, dtype=bool), np.asarray(inc, dtype=bool)
