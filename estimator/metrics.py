"""Tracking accuracy metrics of the GPS dissertation (000_8f82f8df647bf685.txt, Section 4.12).

- Per-axis absolute CG error, Eq. 4.1: ``|x_hat - x|``, ``|y_hat - y|`` (metres), plus the
  Euclidean error ``|p_hat - p|`` and the signed along-track and cross-track errors (the
  lag of a sliding window shows up as a negative along-track error).
- Along-track, one definition (:func:`travel_direction`): the component of the CG error
  along the reference's direction of travel, the course of the reference CG (central
  differences), and the reference heading only where the reference stands still. The
  course, not the heading, because the trail of a window lies along the path the CG
  travelled: the two differ by the side-slip of the CG in a turn, by pi when the platform
  reverses, and a reference without heading (a CG-only recording reference) still has a
  course. (On the simulated square paths they differ by < 0.01 rad, so the along-track
  error moves by < 0.3 mm; see the commit of issue 18.)
- Absolute heading error, Eq. 4.2: ``|theta - theta_hat|``, wrapped to [0, pi] first (the
  dissertation's Figure 4.118 shows why: a heading near +/-pi must not score 2 pi).
- Summaries: mean, median and standard deviation (Tables 4.1/4.2; sample standard deviation,
  ddof = 1, as MATLAB's ``std``), plus rmse, p95 and max, each over an evaluation mask:
  the full path, "no turns" (estimates dated at an epoch that is not turning) and "no turns
  in the window" (estimates whose whole window is free of turning epochs). The
  dissertation's "LC No Turns" column (Section 4.12.2) was made by "manually selecting
  sections of time-steps around which turning occurs": a window estimate still carries a
  turn for as long as the turn's samples are in its window, so "no_turns_window" is the
  faithful reading and "no_turns" the lenient one. Beside them the share of box-plot
  outliers (above Q3 + 1.5 IQR, Figs 4.114-4.123) and the jitter of the error from one
  estimate to the next (Section 4.10).

Everything takes plain arrays, so estimates from any source (this package, a log, another
tool) can be scored; :func:`align_to_truth` pairs a track's rows with truth samples by time.
NaN estimates (e.g. windows with insufficient data) are never dropped silently: summaries
report how many there were (``n_nan``) and are computed over the finite ones.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from estimator._checks import check_increasing_times, check_real
from estimator.orientation import wrap_angle

# pandas is imported where it is used: a sweep's main process simulates before it needs it
if TYPE_CHECKING:
    import pandas as pd

__all__ = [
    "MASKS",
    "STATISTICS",
    "TrackErrors",
    "align_to_truth",
    "along_cross_errors",
    "cg_errors",
    "evaluate_track",
    "evaluation_masks",
    "heading_error",
    "jitter_rms",
    "summarize",
    "track_cg",
    "track_errors",
    "travel_direction",
]

#: Summary statistics, in table order.
STATISTICS = ("mean", "median", "std", "rmse", "p95", "max")
#: Evaluation masks (:func:`evaluation_masks`): every estimate; those dated at an epoch that
#: is not turning; those whose whole window is free of turning epochs.
MASKS = ("full", "no_turns", "no_turns_window")


def _as_xy(a: object, field: str) -> np.ndarray:
    arr = np.asarray(a, dtype=float)
    if arr.ndim != 2 or arr.shape[1] < 2:
        raise ValueError(f"{field}: expected shape (n, 2) (x, y metres), got {arr.shape}")
    return arr[:, :2]


def cg_errors(est_xy: object, true_xy: object) -> dict[str, np.ndarray]:
    """Eq. 4.1 per-axis absolute errors and the Euclidean error.

    est_xy, true_xy : (n, 2) (or (n, 3), z ignored) metres.
    Returns {"x": (n,), "y": (n,), "euclid": (n,)} metres; NaN where the estimate is NaN.
    """
    e = _as_xy(est_xy, "est_xy")
    g = _as_xy(true_xy, "true_xy")
    if e.shape != g.shape:
        raise ValueError(f"est_xy/true_xy: shapes differ, {e.shape} vs {g.shape}")
    d = e - g
    return {"x": np.abs(d[:, 0]), "y": np.abs(d[:, 1]), "euclid": np.hypot(d[:, 0], d[:, 1])}


def heading_error(est_yaw: object, true_yaw: object) -> np.ndarray:
    """Eq. 4.2 ``|theta - theta_hat|`` with the difference wrapped first: (n,) in [0, pi]."""
    a = np.asarray(est_yaw, dtype=float)
    b = np.asarray(true_yaw, dtype=float)
    if a.shape != b.shape:
        raise ValueError(f"est_yaw/true_yaw: shapes differ, {a.shape} vs {b.shape}")
    return np.abs(wrap_angle(a - b))


def along_cross_errors(est_xy: object, true_xy: object, direction: object
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Signed along-track and cross-track errors (metres).

    est_xy, true_xy : (n, 2) (or (n, 3), z ignored) metres. direction : (n,) yaw of the
    direction of travel (rad, CCW from +x), e.g. the true course.
    Returns ``(along, cross)``, each (n,) metres (NaN where the estimate is NaN).
    along > 0 means the estimate is ahead of the truth; a lagging window gives
    along < 0. cross > 0 means to the left of the direction of travel.
    """
    e = _as_xy(est_xy, "est_xy")
    g = _as_xy(true_xy, "true_xy")
    th = np.asarray(direction, dtype=float)
    if e.shape != g.shape or th.shape != (e.shape[0],):
        raise ValueError(f"est_xy/true_xy/direction: shapes {e.shape}, {g.shape}, {th.shape} "
                         f"do not match")
    d = e - g
    c, s = np.cos(th), np.sin(th)
    return d[:, 0] * c + d[:, 1] * s, -d[:, 0] * s + d[:, 1] * c


def _percentile_sorted(srt: np.ndarray, q: float) -> float:
    """``np.percentile(srt, q)`` (linear interpolation) of a sorted, finite, non-empty
    array, the same floating-point operations as numpy's: one sort serves every quantile."""
    v = (srt.size - 1) * (q / 100)
    lo = math.floor(v)
    hi = min(lo + 1, srt.size - 1)
    a, b, g = float(srt[lo]), float(srt[hi]), v - lo
    d = b - a
    return b - d * (1 - g) if g >= 0.5 else a + d * g


def _median_sorted(srt: np.ndarray) -> float:
    """``np.median`` of a sorted, finite, non-empty array (the mean of the two middle values
    when the size is even, as numpy computes it)."""
    k = srt.size // 2
    return float(srt[k]) if srt.size % 2 else float((srt[k - 1] + srt[k]) / 2)


def summarize(errors: object, mask: object | None = None, *,
              signed: bool = False) -> dict[str, float]:
    """Summary of an error series over a mask (Tables 4.1/4.2 and more).

    errors : (n,) errors (NaN = no estimate); non-negative unless ``signed``.
    mask : (n,) bool or None (all).
    signed : the series is signed (along- or cross-track): mean, median and std are of the
        signed values (the mean is the bias, e.g. the lag), rmse, p95, max and outliers of
        their magnitudes.
    Returns {"n": finite count, "n_nan": NaN count inside the mask, "mean", "median",
    "std" (ddof = 1, the dissertation's sample standard deviation), "rmse",
    "p95" (linear interpolation, numpy's default), "max", "outliers" (the share of values
    above the upper box-plot whisker Q3 + 1.5 IQR, the outliers of Figs 4.114-4.123; NaN
    with fewer than 4 values)}. Statistics are NaN when no finite error is inside the mask
    (std also when only one is). Infinite errors count as NaN (no estimate to score).
    """
    e = np.asarray(errors, dtype=float)
    if e.ndim != 1:
        raise ValueError(f"errors: expected shape (n,), got {e.shape}")
    if mask is not None:
        mk = np.asarray(mask)
        if mk.shape != e.shape or mk.dtype != bool:
            raise ValueError(
                f"mask: expected bool array of shape {e.shape}, got {mk.dtype} {mk.shape}")
        e = e[mk]
    fin = e[np.isfinite(e)]
    out: dict[str, float] = {"n": int(fin.size), "n_nan": int(e.size - fin.size)}
    if fin.size == 0:
        out.update({k: float("nan") for k in (*STATISTICS, "outliers")})
        return out
    srt = np.sort(fin)
    out["mean"] = float(fin.mean())
    out["median"] = _median_sorted(srt)
    out["std"] = float(fin.std(ddof=1)) if fin.size > 1 else float("nan")
    out["rmse"] = float(np.sqrt(np.mean(fin * fin)))
    if signed:
        srt = np.sort(np.abs(fin))
    out["p95"] = _percentile_sorted(srt, 95)
    out["max"] = float(srt[-1])
    if srt.size < 4:
        out["outliers"] = float("nan")
    else:
        q1, q3 = _percentile_sorted(srt, 25), _percentile_sorted(srt, 75)
        above = srt.size - int(np.searchsorted(srt, q3 + 1.5 * (q3 - q1), side="right"))
        out["outliers"] = above / srt.size
    return out


def jitter_rms(error_xy: object, mask: object | None = None) -> float:
    """Epoch-to-epoch jitter of a track's error: the RMS of ``|e_k - e_(k-1)|`` over the
    consecutive pairs of estimates that are both inside ``mask`` (Section 4.10's "variation
    from one estimate to the next").

    error_xy : (k,) + (2,) signed CG errors (estimate - truth, metres), one row per estimate
    in time order (NaN = no estimate). mask : (k,) bool or None (all).
    Returns metres; NaN without a finite pair.
    """
    d = _as_xy(error_xy, "error_xy")
    mk = np.ones(len(d), dtype=bool) if mask is None else np.asarray(mask)
    if mk.shape != (len(d),) or mk.dtype != bool:
        raise ValueError(f"mask: expected bool array of shape ({len(d)},), got {mk.dtype} "
                         f"{mk.shape}")
    if len(d) < 2:
        return float("nan")
    step = np.hypot(*(np.diff(d, axis=0).T))
    jm = step[mk[1:] & mk[:-1]]
    jm = jm[np.isfinite(jm)]
    return float(np.sqrt(np.mean(jm ** 2))) if jm.size else float("nan")


def travel_direction(t: object, cg: object, yaw: object | None = None, *,
                     min_speed_mps: float = 0.0) -> np.ndarray:
    """Direction of travel of a reference trajectory, (n,) rad (CCW from +x): the axis of
    the along-track error (module docstring).

    t : (n,) seconds, strictly increasing. cg : (n, 2) (or (n, 3), z ignored) reference CG,
    metres (NaN = unknown). yaw : (n,) reference heading in radians, or None.
    min_speed_mps : the course is used where the reference CG moves faster than this
        (>= 0; default 0: wherever it moves at all, right for a noise-free reference; a
        measured reference standing still has a random course, set the speed its noise
        cannot fake there).
    The course is ``atan2`` of the central-difference velocity (one-sided at the ends,
    ``numpy.gradient`` on uneven times); where the CG does not move fast enough, or a
    neighbour is NaN, the reference heading (NaN without one).
    """
    tt = check_increasing_times(t, "t", min_size=1)
    g = _as_xy(cg, "cg")
    if g.shape[0] != tt.size:
        raise ValueError(f"cg: expected {tt.size} rows (one per time), got {g.shape[0]}")
    y = np.full(tt.size, np.nan) if yaw is None else np.asarray(yaw, dtype=float)
    if y.shape != tt.shape:
        raise ValueError(f"yaw: expected shape {tt.shape}, got {y.shape}")
    v_min = check_real(min_speed_mps, "min_speed_mps", lo=0.0)
    if tt.size < 2:
        return y.copy()
    with np.errstate(invalid="ignore"):
        vel = np.gradient(g, tt, axis=0)
        speed = np.hypot(vel[:, 0], vel[:, 1])
        moving = speed > v_min
    return np.where(moving, np.arctan2(vel[:, 1], vel[:, 0]), y)


def evaluation_masks(turning: object, t: object | None = None, margin_s: float = 0.0,
                     window: object | None = None) -> dict[str, np.ndarray]:
    """Masks for "full path", "no turns" and "no turns in the window" (Section 4.12.2).

    turning : (n,) bool, True on turning epochs (controller flag or a detector).
    t : (n,) seconds, needed when ``margin_s > 0``.
    margin_s : epochs within this many seconds of a turning epoch count as turning too
        (the dissertation removed "sections of time-steps around which turning occurs").
    window : None, or (n,) int >= 0: the size of the window of the estimate dated at each
        epoch (the estimate at epoch k fits epochs ``k - window[k] + 1 .. k``; 0 = no
        estimate at that epoch). Adds "no_turns_window".
    Returns {"full": all True, "no_turns": not turning (dilated by the margin)} and, with
    ``window``, "no_turns_window": an estimate is there and no epoch of its window is
    turning (dilated by the margin) -- every estimate that a turn's samples reach is
    dropped, however long after the turn.
    """
    tr = np.asarray(turning)
    if tr.ndim != 1 or tr.dtype != bool:
        raise ValueError(f"turning: expected a 1-D bool array, got {tr.dtype} {tr.shape}")
    margin_s = check_real(margin_s, "margin_s", lo=0.0)
    win = None
    if window is not None:
        win = np.asarray(window)
        if win.shape != tr.shape or not np.issubdtype(win.dtype, np.integer):
            raise ValueError(f"window: expected an integer array of shape {tr.shape}, got "
                             f"{win.dtype} {win.shape}")
        k = np.arange(tr.size)
        bad = (win < 0) | (win > k + 1)
        if bad.any():
            j = int(np.argmax(bad))
            raise ValueError(f"window: window[{j}] = {win[j]} must be in [0, {j + 1}] (a "
                             "window cannot reach before the first epoch)")
    near = tr.copy()
    if margin_s > 0 and tr.any():
        if t is None:
            raise ValueError("t: required when margin_s > 0")
        tt = np.asarray(t, dtype=float)
        if tt.shape != tr.shape:
            raise ValueError(f"t: expected shape {tr.shape}, got {tt.shape}")
        tt_turn = tt[tr]
        # distance in time to the nearest turning epoch, via searchsorted on the sorted times
        idx = np.searchsorted(tt_turn, tt)
        lo = np.abs(tt - tt_turn[np.clip(idx - 1, 0, tt_turn.size - 1)])
        hi = np.abs(tt_turn[np.clip(idx, 0, tt_turn.size - 1)] - tt)
        near = np.minimum(lo, hi) <= margin_s
    out = {"full": np.ones(tr.shape, dtype=bool), "no_turns": ~near}
    if win is not None:
        # turning epochs inside each window, by a cumulative count
        c = np.concatenate([[0], np.cumsum(near, dtype=np.int64)])
        k = np.arange(tr.size)
        inside = c[k + 1] - c[k + 1 - win]
        out["no_turns_window"] = (win > 0) & (inside == 0)
    return out


def align_to_truth(est_t: object, truth_t: object, *, tol: float = 1e-6) -> np.ndarray:
    """Index into ``truth_t`` of each estimate time: (k,) int.

    Estimates are matched to truth samples at the same time (within ``tol`` seconds); a time
    with no truth sample raises ValueError naming it (no interpolation, nothing dropped).
    """
    te = np.asarray(est_t, dtype=float)
    if te.ndim != 1:
        raise ValueError(f"est_t: expected shape (k,) of seconds, got shape {te.shape}")
    if not np.all(np.isfinite(te)):
        k = int(np.argmax(~np.isfinite(te)))
        raise ValueError(f"est_t: times must be finite; est_t[{k}] = {te[k]!r}")
    tt = check_increasing_times(truth_t, "truth_t", min_size=1)
    if tt.size > 1:
        idx = np.clip(np.searchsorted(tt, te), 1, tt.size - 1)
    else:
        idx = np.zeros(te.size, int)
    if tt.size > 1:
        left = idx - 1
        idx = np.where(np.abs(tt[left] - te) <= np.abs(tt[idx] - te), left, idx)
    bad = np.abs(tt[idx] - te) > tol
    if bad.any():
        k = int(np.argmax(bad))
        raise ValueError(f"est_t: time {te[k]!r} has no truth sample within {tol} s")
    return idx


@dataclass(frozen=True)
class TrackErrors:
    """Errors of a track's estimates against a reference (Section 4.12), one per estimate.

    index : (k,) the reference sample of each estimate (:func:`align_to_truth`).
    dx, dy : signed CG error, estimate - reference, metres (NaN = no estimate).
    x, y : Eq. 4.1 ``|dx|``, ``|dy|``. euclid : ``|(dx, dy)|``. heading : Eq. 4.2, radians
    in [0, pi] (NaN without an estimated or a reference heading). along, cross : signed
    along- and cross-track errors along :func:`travel_direction` (along > 0: ahead of the
    reference, a lagging window gives along < 0; cross > 0: left of the direction of travel).
    """

    index: np.ndarray
    dx: np.ndarray
    dy: np.ndarray
    x: np.ndarray
    y: np.ndarray
    euclid: np.ndarray
    heading: np.ndarray
    along: np.ndarray
    cross: np.ndarray

    @property
    def dxy(self) -> np.ndarray:
        """(k, 2) signed CG errors."""
        return np.column_stack([self.dx, self.dy])


def track_cg(track: pd.DataFrame) -> np.ndarray:
    """The (n, 2) CG estimates (m) of a :func:`estimator.tracking.track` table, from its
    ``cg_x`` and ``cg_y`` columns one by one (``track[["cg_x", "cg_y"]]`` costs ~5 ms: pandas
    takes every block of the table, its string status column included)."""
    return np.column_stack((track["cg_x"].to_numpy(dtype=float),
                            track["cg_y"].to_numpy(dtype=float)))


def track_errors(est_t: object, est_xy: object, est_yaw: object | None, truth_t: object,
                 truth_xy: object, truth_yaw: object | None = None, *, tol: float = 1e-6,
                 min_speed_mps: float = 0.0) -> TrackErrors:
    """Every per-estimate error of a track against a reference, the one scorer's core.

    est_t (k,) s, est_xy (k, 2) m, est_yaw (k,) rad or None : the estimates (NaN = none).
    truth_t (n,) s strictly increasing, truth_xy (n, 2|3) m, truth_yaw (n,) rad or None :
    the reference, any superset of the estimates' times (matched within ``tol`` seconds,
    :func:`align_to_truth`). min_speed_mps : of :func:`travel_direction`.
    Returns :class:`TrackErrors`.
    """
    tt = check_increasing_times(truth_t, "truth_t", min_size=1)
    g = _as_xy(truth_xy, "truth_xy")
    if g.shape[0] != tt.size:
        raise ValueError(f"truth_xy: expected {tt.size} rows (one per truth time), got "
                         f"{g.shape[0]}")
    idx = align_to_truth(est_t, tt, tol=tol)
    est = _as_xy(est_xy, "est_xy")
    if est.shape[0] != idx.size:
        raise ValueError(f"est_xy: expected {idx.size} rows (one per estimate time), got "
                         f"{est.shape[0]}")
    ref = g[idx]
    d = est - ref
    direction = travel_direction(tt, g, truth_yaw, min_speed_mps=min_speed_mps)[idx]
    along, cross = along_cross_errors(est, ref, direction)
    if est_yaw is None or truth_yaw is None:
        heading = np.full(idx.size, np.nan)
    else:
        heading = heading_error(est_yaw, np.asarray(truth_yaw, dtype=float)[idx])
    return TrackErrors(index=idx, dx=d[:, 0], dy=d[:, 1], x=np.abs(d[:, 0]), y=np.abs(d[:, 1]),
                       euclid=np.hypot(d[:, 0], d[:, 1]), heading=heading, along=along,
                       cross=cross)


def evaluate_track(track: pd.DataFrame, truth_t: object, truth_cg: object,
                   truth_yaw: object, turning: object | None = None, *,
                   margin_s: float = 0.0, masks: Mapping[str, object] | None = None,
                   heading_columns: tuple[str, ...] = ("yaw", "yaw_loc")) -> pd.DataFrame:
    """Score a :func:`estimator.tracking.track` result against truth arrays.

    track : DataFrame with columns t, cg_x, cg_y and the heading columns present.
    truth_t (n,), truth_cg (n, 2|3), truth_yaw (n,) : the truth, any superset of the track's
        times. turning : (n,) bool truth turning flags for the "no_turns" mask (optional;
        with a ``window`` column in ``track`` whose rows are consecutive truth epochs, also
        "no_turns_window", see :func:`evaluation_masks`).
    masks : extra masks over the track's rows, name -> (k,) bool.
    Returns a long DataFrame, one row per (mask, quantity) with columns
    ``mask, quantity, n, n_nan``, :data:`STATISTICS` and ``outliers``; quantities are ``x``,
    ``y`` (Eq. 4.1), ``euclid``, ``along`` (signed, along the direction of travel of
    :func:`travel_direction`; its mean is the lag; p95 / max / outliers of its magnitude),
    and ``<heading column>`` (Eq. 4.2, radians).
    """
    import pandas as pd

    for col in ("t", "cg_x", "cg_y"):
        if col not in track.columns:
            raise ValueError(f"track: missing column {col!r}")
    tt = np.asarray(truth_t, dtype=float)
    cg = np.asarray(truth_cg, dtype=float)
    yaw = np.asarray(truth_yaw, dtype=float)
    if cg.ndim != 2 or cg.shape[0] != tt.shape[0] or yaw.shape != tt.shape:
        raise ValueError(f"truth_cg/truth_yaw: shapes {cg.shape}, {yaw.shape} do not match "
                         f"truth_t {tt.shape}")
    te = track_errors(track["t"].to_numpy(), track_cg(track), None, tt, cg, yaw)
    idx = te.index
    errs = {"x": te.x, "y": te.y, "euclid": te.euclid, "along": te.along}
    for col in heading_columns:
        if col in track.columns:
            errs[col] = heading_error(track[col].to_numpy(dtype=float), yaw[idx])
    all_masks: dict[str, np.ndarray] = {"full": np.ones(len(track), dtype=bool)}
    if turning is not None:
        tr = np.asarray(turning)
        if tr.shape != tt.shape:
            raise ValueError(f"turning: expected shape {tt.shape}, got {tr.shape}")
        win = None
        # the window mask counts truth epochs: only when the track's rows are consecutive
        # truth epochs (one estimate per epoch, the truth sampled like the observations)
        if "window" in track.columns and np.all(np.diff(idx) == 1):
            win = np.zeros(tt.shape, dtype=np.int64)
            win[idx] = track["window"].to_numpy(dtype=np.int64)
        em = evaluation_masks(tr, tt, margin_s, window=win)
        all_masks["no_turns"] = em["no_turns"][idx]
        if win is not None:
            all_masks["no_turns_window"] = em["no_turns_window"][idx]
    for name, mk in (masks or {}).items():
        mk = np.asarray(mk)
        if mk.shape != (len(track),) or mk.dtype != bool:
            raise ValueError(f"masks[{name!r}]: expected bool array of shape ({len(track)},)")
        all_masks[name] = mk
    rows = [{"mask": mname, "quantity": q, **summarize(e, mk, signed=q == "along")}
            for mname, mk in all_masks.items() for q, e in errs.items()]
    return pd.DataFrame(rows, columns=["mask", "quantity", "n", "n_nan", *STATISTICS,
                                       "outliers"])
