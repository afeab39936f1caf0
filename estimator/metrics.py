"""Tracking accuracy metrics of the GPS dissertation (000_8f82f8df647bf685.txt, Section 4.12).

- Per-axis absolute CG error, Eq. 4.1: ``|x_hat - x|``, ``|y_hat - y|`` (metres), plus the
  Euclidean error ``|p_hat - p|`` and, given the direction of travel, the signed along-track
  and cross-track errors (the lag of a sliding window shows up as a negative along-track
  error).
- Absolute heading error, Eq. 4.2: ``|theta - theta_hat|``, wrapped to [0, pi] first (the
  dissertation's Figure 4.118 shows why: a heading near +/-pi must not score 2 pi).
- Summaries: mean, median and standard deviation (Tables 4.1/4.2; sample standard deviation,
  ddof = 1, as MATLAB's ``std``), plus rmse, p95 and max, each over an evaluation mask:
  the full path, "no turns" (estimates dated at an epoch that is not turning) and "no turns
  in the window" (estimates whose whole window is free of turning epochs). The
  dissertation's "LC No Turns" column (Section 4.12.2) was made by "manually selecting
  sections of time-steps around which turning occurs": a window estimate still carries a
  turn for as long as the turn's samples are in its window, so "no_turns_window" is the
  faithful reading and "no_turns" the lenient one.

Everything takes plain arrays, so estimates from any source (this package, a log, another
tool) can be scored; :func:`align_to_truth` pairs a track's rows with truth samples by time.
NaN estimates (e.g. windows with insufficient data) are never dropped silently: summaries
report how many there were (``n_nan``) and are computed over the finite ones.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import pandas as pd

from estimator._checks import check_increasing_times, check_real
from estimator.orientation import wrap_angle

__all__ = [
    "MASKS",
    "STATISTICS",
    "align_to_truth",
    "along_cross_errors",
    "cg_errors",
    "evaluate_track",
    "evaluation_masks",
    "heading_error",
    "summarize",
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


def summarize(errors: object, mask: object | None = None) -> dict[str, float]:
    """Summary of an error series over a mask (Tables 4.1/4.2 and more).

    errors : (n,) non-negative errors (NaN = no estimate). mask : (n,) bool or None (all).
    Returns {"n": finite count, "n_nan": NaN count inside the mask, "mean", "median",
    "std" (ddof = 1, the dissertation's sample standard deviation), "rmse",
    "p95" (linear interpolation, numpy's default), "max"}. Statistics are NaN when no
    finite error is inside the mask (std also when only one is).
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
        out.update({k: float("nan") for k in STATISTICS})
        return out
    out["mean"] = float(fin.mean())
    out["median"] = float(np.median(fin))
    out["std"] = float(fin.std(ddof=1)) if fin.size > 1 else float("nan")
    out["rmse"] = float(np.sqrt(np.mean(fin * fin)))
    out["p95"] = float(np.percentile(fin, 95))
    out["max"] = float(fin.max())
    return out


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
    ``mask, quantity, n, n_nan`` and :data:`STATISTICS`; quantities are ``x``, ``y``
    (Eq. 4.1), ``euclid``, ``along`` (signed, along the true course; its mean is the lag),
    and ``<heading column>`` (Eq. 4.2, radians).
    """
    for col in ("t", "cg_x", "cg_y"):
        if col not in track.columns:
            raise ValueError(f"track: missing column {col!r}")
    tt = np.asarray(truth_t, dtype=float)
    cg = np.asarray(truth_cg, dtype=float)
    yaw = np.asarray(truth_yaw, dtype=float)
    if cg.ndim != 2 or cg.shape[0] != tt.shape[0] or yaw.shape != tt.shape:
        raise ValueError(f"truth_cg/truth_yaw: shapes {cg.shape}, {yaw.shape} do not match "
                         f"truth_t {tt.shape}")
    idx = align_to_truth(track["t"].to_numpy(), tt)
    est = track[["cg_x", "cg_y"]].to_numpy(dtype=float)
    g = cg[idx, :2]
    errs = cg_errors(est, g)
    # direction of travel from the truth CG (central differences); falls back to the yaw
    vel = np.gradient(cg[:, :2], tt, axis=0) if tt.size > 1 else np.zeros((1, 2))
    course = np.where(np.hypot(vel[:, 0], vel[:, 1]) > 1e-9,
                      np.arctan2(vel[:, 1], vel[:, 0]), yaw)[idx]
    errs["along"] = along_cross_errors(est, g, course)[0]
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
    rows = []
    for mname, mk in all_masks.items():
        for q, e in errs.items():
            s = summarize(e, mk)
            if q == "along":  # signed: mean/median/std of the signed error, p95/max of |e|
                sa = summarize(np.abs(e), mk)
                s["p95"], s["max"] = sa["p95"], sa["max"]
            rows.append({"mask": mname, "quantity": q, **s})
    return pd.DataFrame(rows, columns=["mask", "quantity", "n", "n_nan", *STATISTICS])
