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
from collections.abc import Collection, Mapping
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
    "error_steps",
    "errors_at",
    "evaluate_track",
    "evaluation_masks",
    "heading_error",
    "index_rows",
    "jitter_of_steps",
    "jitter_rms",
    "nearest_samples",
    "summaries",
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
    return _along_cross(e - g, np.cos(th), np.sin(th))


def _along_cross(d: np.ndarray, c: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The (k, 2) error ``d`` rotated into the direction whose cosines / sines are c, s."""
    return d[:, 0] * c + d[:, 1] * s, -d[:, 0] * s + d[:, 1] * c


def _quantile_at(part: np.ndarray, q: float) -> float:
    """``np.percentile(x, q)`` (linear interpolation) of a finite, non-empty array ``part``
    whose elements at the positions :func:`_quantile_positions` names for ``q`` are in
    sorted position (a sorted array, or one ``np.partition``-ed at them): the same
    floating-point operations as numpy's."""
    lo, hi, g = _quantile_positions(part.size, q)
    a, b = float(part[lo]), float(part[hi])
    d = b - a
    return b - d * (1 - g) if g >= 0.5 else a + d * g


def _quantile_positions(n: int, q: float) -> tuple[int, int, float]:
    """The two order statistics (0-based) and the weight of the ``q`` % percentile of ``n``
    values (numpy's linear interpolation)."""
    v = (n - 1) * (q / 100)
    lo = math.floor(v)
    return lo, min(lo + 1, n - 1), v - lo


def _median_sorted(srt: np.ndarray) -> float:
    """``np.median`` of a finite, non-empty array sorted (or partitioned) at its middle
    position(s) (the mean of the two middle values when the size is even, as numpy)."""
    k = srt.size // 2
    return float(srt[k]) if srt.size % 2 else float((srt[k - 1] + srt[k]) / 2)


def _median_positions(n: int) -> list[int]:
    """The middle position(s) of ``n`` values (two when ``n`` is even)."""
    return [n // 2] if n % 2 else [n // 2 - 1, n // 2]


def _order_stats(x: np.ndarray) -> np.ndarray:
    """``x`` (finite, non-empty) partitioned so that every order statistic
    :func:`summarize` reads is in sorted position (:func:`_order_positions`): ``np.partition``
    at these ~9 positions instead of a full sort, the same values at those positions, so
    the same numbers, in ~1/4 of the time."""
    return np.partition(x, _order_positions(x.size))


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
    if signed:
        median = _median_sorted(np.partition(fin, _median_positions(fin.size)))
        part = _order_stats(np.abs(fin))
    else:
        part = _order_stats(fin)
        median = _median_sorted(part)
    out["mean"], out["median"] = float(fin.mean()), median
    out["std"] = float(fin.std(ddof=1)) if fin.size > 1 else float("nan")
    out["rmse"] = float(np.sqrt(np.mean(fin * fin)))
    out["p95"] = _quantile_at(part, 95)
    out["max"] = float(part[-1])
    if part.size < 4:
        out["outliers"] = float("nan")
    else:
        q1, q3 = _quantile_at(part, 25), _quantile_at(part, 75)
        out["outliers"] = int(np.count_nonzero(part > q3 + 1.5 * (q3 - q1))) / part.size
    return out


def summaries(series: Mapping[str, object], masks: Mapping[str, object | None], *,
              signed: Collection[str] = ()) -> dict[str, dict[str, dict[str, float]]]:
    """:func:`summarize` of several error series over several masks, bit for bit the same
    numbers, computed together: ``{mask name: {series name: summary}}``.

    series : name -> (k,) errors, all of one length. masks : name -> (k,) bool or None
    (all). signed : the names of the signed series (:func:`summarize`'s ``signed``).
    Per mask the series whose finite values sit at the same rows (typically all of a
    track's: a missing estimate is NaN in every series) share one compress, one reduction
    per sum and one partition (about 1/6 of the time of one :func:`summarize` per series
    and mask, issue 27). The sums are numpy's pairwise sums of the same contiguous rows,
    so every statistic equals :func:`summarize`'s exactly (``tests/test_metrics.py``).
    """
    names = list(series)
    rows = [np.asarray(series[nm], dtype=float) for nm in names]
    k = rows[0].shape if rows else (0,)
    for nm, r in zip(names, rows):
        if r.ndim != 1 or r.shape != k:
            raise ValueError(f"series[{nm!r}]: expected shape {k} like the first series, "
                             f"got {r.shape}")
    E = np.vstack(rows) if rows else np.zeros((0, 0))
    sg = np.array([nm in signed for nm in names], dtype=bool)
    groups = _finite_groups(E)
    out: dict[str, dict[str, dict[str, float]]] = {}
    for mname, mask in masks.items():
        mk = None
        if mask is not None:
            mk = np.asarray(mask)
            if mk.shape != k or mk.dtype != bool:
                raise ValueError(f"masks[{mname!r}]: expected bool array of shape {k}, got "
                                 f"{mk.dtype} {mk.shape}")
        size = k[0] if mk is None else int(np.count_nonzero(mk))
        res: dict[int, dict[str, float]] = {}
        for idx, fin, Eg in groups:
            sel = fin if mk is None else (mk if fin is None else mk & fin)
            F = Eg if sel is None else np.compress(sel, Eg, axis=1)
            res.update(zip(idx, _joint_summaries(F, sg[idx], size)))
        out[mname] = {nm: res[i] for i, nm in enumerate(names)}
    return out


def _finite_groups(E: np.ndarray
                   ) -> list[tuple[list[int], np.ndarray | None, np.ndarray]]:
    """The rows of E (s, k) grouped by where they are finite: (row numbers, their finite
    columns (k,) bool or None (every column), those rows of E), rows finite at the same
    columns together."""
    fin = np.isfinite(E)
    if fin.all():
        return [(list(range(E.shape[0])), None, E)]
    pats: dict[bytes, list[int]] = {}
    for i in range(E.shape[0]):
        pats.setdefault(fin[i].tobytes(), []).append(i)
    return [(idx, None if fin[idx[0]].all() else fin[idx[0]], E[idx])
            for idx in pats.values()]


def _joint_summaries(F: np.ndarray, signed: np.ndarray, size: int) -> list[dict[str, float]]:
    """:func:`summarize` of each row of F (g, n) finite values (C-contiguous: each row's
    sums are numpy's pairwise sums of that row, as for a 1-D array), ``signed`` (g,)
    bool; ``size`` the number of values inside the mask (finite or not)."""
    g, n = F.shape
    base = {"n": n, "n_nan": size - n}
    if n == 0:
        return [{**base, **{k: float("nan") for k in (*STATISTICS, "outliers")}}
                for _ in range(g)]
    mean = np.add.reduce(F, axis=1) / n
    if n > 1:
        D = F - mean[:, None]
        std = np.sqrt(np.add.reduce(D * D, axis=1) / (n - 1))
    else:
        std = np.full(g, np.nan)
    rmse = np.sqrt(np.add.reduce(F * F, axis=1) / n)
    # one partition: the magnitudes of the signed rows (and the other rows as they are),
    # then the signed rows' own values for their median
    A = np.where(signed[:, None], np.abs(F), F)
    if signed.any():
        A = np.vstack((A, F[signed]))
    A.partition(_order_positions(n), axis=1)
    P = A[:g]
    med = _median_cols(P)
    if signed.any():
        med[signed] = _median_cols(A[g:])
    p95, mx = _quantile_cols(P, 95), P[:, -1]
    if n < 4:
        outl = np.full(g, np.nan)
    else:
        q1, q3 = _quantile_cols(P, 25), _quantile_cols(P, 75)
        fence = q3 + 1.5 * (q3 - q1)                  # the upper whisker, per row
        outl = np.count_nonzero(np.greater(P, fence[:, None]), axis=1) / n
    stats = np.column_stack([mean, med, std, rmse, p95, mx, outl]).tolist()
    return [{**base, **dict(zip((*STATISTICS, "outliers"), r))} for r in stats]


def _order_positions(n: int) -> list[int]:
    """Every order statistic (0-based) :func:`summarize` reads of ``n`` values: the p25 /
    p75 / p95 pairs, the middle and the maximum."""
    kth = {n - 1, *_median_positions(n)}
    for q in (25, 75, 95):
        lo, hi, _ = _quantile_positions(n, q)
        kth.update((lo, hi))
    return sorted(kth)


def _median_cols(P: np.ndarray) -> np.ndarray:
    """The median of each row of P (g, n), partitioned at its middle (:func:`_median_sorted`)."""
    k = P.shape[1] // 2
    return P[:, k].copy() if P.shape[1] % 2 else (P[:, k - 1] + P[:, k]) / 2


def _quantile_cols(P: np.ndarray, q: float) -> np.ndarray:
    """:func:`_quantile_at` of each row of P (g, n) (the same operations, elementwise)."""
    lo, hi, g = _quantile_positions(P.shape[1], q)
    a, b = P[:, lo], P[:, hi]
    d = b - a
    return b - d * (1 - g) if g >= 0.5 else a + d * g


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
    return jitter_of_steps(error_steps(d), mk)


def error_steps(error_xy: np.ndarray) -> np.ndarray:
    """``|e_k - e_(k-1)|`` (k - 1,) m of (k, 2) signed CG errors (:func:`jitter_rms`)."""
    return np.hypot(np.diff(error_xy[:, 0]), np.diff(error_xy[:, 1]))


def jitter_of_steps(step: np.ndarray, mask: np.ndarray) -> float:
    """:func:`jitter_rms` from the steps of :func:`error_steps` and the (k,) bool mask."""
    jm = step[mask[1:] & mask[:-1]]
    jm = jm[np.isfinite(jm)]
    # np.mean's own arithmetic (the pairwise sum over the count) without its overhead
    return float(np.sqrt(np.add.reduce(jm * jm) / jm.size)) if jm.size else float("nan")


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
    return nearest_samples(te, check_increasing_times(truth_t, "truth_t", min_size=1), tol)


def nearest_samples(te: np.ndarray, tt: np.ndarray, tol: float) -> np.ndarray:
    """:func:`align_to_truth` on checked times: te (k,) finite s, tt (n,) strictly
    increasing s (:func:`estimator._checks.check_increasing_times`). Estimates dated exactly
    at truth samples take one ``searchsorted``, and those at a run of consecutive samples
    (a track on the truth's own time line) one comparison."""
    if te.size:
        i0 = int(np.searchsorted(tt, te[0]))
        if i0 + te.size <= tt.size and np.array_equal(tt[i0:i0 + te.size], te):
            return np.arange(i0, i0 + te.size)
    j = np.searchsorted(tt, te)
    if j.size and int(j.max()) < tt.size and np.array_equal(tt[j], te):
        return j
    if tt.size > 1:
        idx = np.clip(j, 1, tt.size - 1)
        left = idx - 1
        idx = np.where(np.abs(tt[left] - te) <= np.abs(tt[idx] - te), left, idx)
    else:
        idx = np.zeros(te.size, int)
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
    direction = travel_direction(tt, g, truth_yaw, min_speed_mps=min_speed_mps)
    return errors_at(idx, est, est_yaw, g, direction,
                     None if truth_yaw is None else np.asarray(truth_yaw, dtype=float))


def index_rows(idx: np.ndarray) -> slice | np.ndarray:
    """The rows ``idx`` (k,) int as a slice when they are one ascending run (a track on the
    reference's time line: a view instead of a gathered copy of each (n, ...) array, the
    same values), else ``idx``."""
    if idx.size and int(idx[-1]) - int(idx[0]) == idx.size - 1 and \
            np.array_equal(idx, np.arange(idx[0], idx[0] + idx.size)):
        return slice(int(idx[0]), int(idx[0]) + idx.size)
    return idx


def errors_at(idx: np.ndarray, est: np.ndarray, est_yaw: object | None, truth_xy: np.ndarray,
              direction: np.ndarray, truth_yaw: np.ndarray | None, *,
              cos_sin: tuple[np.ndarray, np.ndarray] | None = None) -> TrackErrors:
    """:func:`track_errors` once the estimates are aligned: idx (k,) the reference sample
    of each estimate, est (k, 2) m, est_yaw (k,) rad or None; truth_xy (n, 2) m, direction
    (n,) rad (:func:`travel_direction`), truth_yaw (n,) rad or None, all of the whole
    reference (a scorer computes the direction once per reference,
    :mod:`estimator.scoring`); cos_sin : (n,) cosines and sines of ``direction`` when the
    caller has them (the same values numpy computes for the rows)."""
    rows = index_rows(idx)
    ref = truth_xy[rows]
    d = est - ref
    if cos_sin is None:
        along, cross = along_cross_errors(est, ref, direction[rows])
    else:
        along, cross = _along_cross(d, cos_sin[0][rows], cos_sin[1][rows])
    if est_yaw is None or truth_yaw is None:
        heading = np.full(idx.size, np.nan)
    else:
        heading = heading_error(est_yaw, truth_yaw[rows])
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
