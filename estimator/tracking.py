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
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from estimator import lag as _lag
from estimator import pose_smoother as _smoother
from estimator import turns as _turns
from estimator import weights as _weights
from estimator._checks import check_increasing_times, check_int
from estimator.configuration import LayoutWarning, SensorConfig
from estimator.elastic import elastic_batch
from estimator.layout_check import check_layout
from estimator.memo import ContentMemo, content_digest, freeze
from estimator.motion import motion_compensated_batch, motion_compensated_series
from estimator.orientation import law_of_cosines_heading
from estimator.pose_filter import PoseFilterParams, memo_pose_filter
from estimator.track_options import (
    FILTER_METHODS,
    GROWTH_RULES,
    LAG_OPTIONS,
    METHODS,
    WEIGHTED_METHODS,
    DynamicWindow,
    FitOptions,
    LagCorrection,
    MotionOptions,
)
from estimator.weights import WEIGHTINGS, Weighting
from estimator.window import SOLVERS, fit_window, procrustes_batch, window_means, window_moments

__all__ = [
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

#: Windows stacked per weight/solver call: keeps memory ~ this many samples x m x 2 floats.
_CHUNK_SAMPLES = 200_000

#: Defaults of the turn detector used by ``turning="detect"`` (see :mod:`estimator.turns`).
#: Chosen once on synthetic data (Path 1 rover truth at 0.2 m/s, turns at ~0.056 rad/s,
#: gps_stationary errors, 3 sessions from seed 20261122, not used by tests or the sweep) by
#: the F1 score of the flags against the controller's flag over window {1, 5, 10} x span
#: {4, 8, 16} s x rate_on {0.02, 0.03, 0.05, 0.1} rad/s (rate_off = rate_on / 2) x source:
#: best F1 0.42 (112 true, 171 false, 143 missed turning epochs). Slow turns under metre-level
#: noise are hard to see on-line; the controller flag remains the reference.
DETECTOR_DEFAULTS = {"window": 10, "source": "course", "span_s": 8.0, "rate_on": 0.05,
                     "rate_off": 0.025, "min_speed": 0.05}


# ----------------------------------------------------------------------------- validation
def _check_inputs(t: Any, obs: Any, config: Any) -> tuple[np.ndarray, np.ndarray, SensorConfig]:
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
        a, b = alive[0], alive[-1]
        best = (None, int(a), int(b))
    _, i, j = best
    d = B[j] - B[i]
    return i, j, float(np.arctan2(d[1], d[0]))


def dynamic_window_sizes(turning: Any, window: int, small: int, growth: str = "jump"
                         ) -> np.ndarray:
    """Window size of every row of a dynamic-window track (Section 3.4.2.1, 3.4.1).

    turning : (N,) bool, True on the rows whose newest epoch is turning. window : the large
    window s >= 1 (epochs); small : the window while turning, 1 <= small <= window.
    growth : "jump" (back to ``window`` on the first row that is not turning) or "refill"
    (one more epoch per row after a turn: ``min(window, small + k - j)``, j the last turning
    row; the first-in-first-out queue of Section 3.4.1; see the module docstring).
    Returns (N,) int64 sizes; rows before the first turn use ``window``.
    """
    fl = np.asarray(turning)
    if fl.ndim != 1 or fl.dtype != bool:
        raise ValueError(f"turning: expected a 1-D bool array, got {fl.dtype} {fl.shape}")
    s = check_int(window, "window", 1, np.iinfo(np.int64).max // 2)
    w_small = check_int(small, "dynamic_window", 1, s)
    if growth not in GROWTH_RULES:
        raise ValueError(f"window_growth: must be one of {list(GROWTH_RULES)}, got {growth!r}")
    sizes = np.full(fl.size, s, dtype=np.int64)
    if growth == "jump":
        sizes[fl] = w_small
        return sizes
    k = np.arange(fl.size)
    last = np.maximum.accumulate(np.where(fl, k, -1)) if fl.size else k
    after = last >= 0
    sizes[after] = np.minimum(s, w_small + (k[after] - last[after]))
    return sizes


# ----------------------------------------------------------------------------- windows
def _stack(obs: np.ndarray, ends: np.ndarray, w: int) -> np.ndarray:
    """(len(ends), w, m, 2) windows ending at ``ends`` (inclusive)."""
    idx = ends[:, None] - np.arange(w - 1, -1, -1)[None, :]
    return obs[idx]


def _window_weights(stack: np.ndarray, cfg: SensorConfig, weighting: str,
                    rng: np.random.Generator | None, huff_threshold: float | None,
                    huber_c: float, huff: np.ndarray | None = None) -> np.ndarray | None:
    """Weights of stacked windows. ``huff``: the Huff weights of the same stack, gathered
    from one call on the whole recording (they depend on their own sample only)."""
    if weighting == "none":
        return None
    if weighting == "random":
        return _weights.random_weights(stack.shape[:3], rng)
    if weighting == "huff":
        return huff if huff is not None else _weights.huff_weights(stack, cfg, huff_threshold)
    if weighting == "huber":
        return _weights.huber_weights(stack, huber_c)
    if huff is None:
        return _weights.huff_huber_weights(stack, cfg, huff_threshold, huber_c)
    return huff[..., None] * _weights.huber_weights(stack, huber_c)  # Eq. 3.14


#: Per-sample Huff weights of whole recordings, memoised per process by content: a sweep
#: scores every Huff-weighted technique of a noise key on the same observations, and the
#: weights of Section 3.3.3 depend on each sample alone. One entry is (n, m) floats.
_HUFF_MEMO = ContentMemo(8)


def _recording_huff(obs: np.ndarray, cfg: SensorConfig, huff_threshold: float | None
                    ) -> np.ndarray:
    """:func:`estimator.weights.huff_weights` of a whole recording (n, m), read-only,
    memoised by the content of ``obs``, the layout and the threshold."""
    key = (content_digest(obs, cfg.body_positions), cfg.names, tuple(cfg.dead),
           repr(huff_threshold))
    return _HUFF_MEMO.get(key, lambda: freeze(_weights.huff_weights(obs, cfg, huff_threshold)))


def _sample_huff(obs: np.ndarray, cfg: SensorConfig, weighting: str,
                 huff_threshold: float | None) -> np.ndarray | None:
    """Per-sample Huff weights (n, m) of the whole recording when ``weighting`` uses them
    (Section 3.3.3 weighs each time step on its own, so every window shares them)."""
    if weighting in ("huff", "huff_huber"):
        return _recording_huff(obs, cfg, huff_threshold)
    return None


def _chunks(ends: np.ndarray, w: int, m: int):
    size = max(1, _CHUNK_SAMPLES // max(1, w * m))
    for a in range(0, ends.size, size):
        yield ends[a:a + size]


def _cumsum_means(obs: np.ndarray, ends: np.ndarray, w: int,
                  weights: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Window means (N, m, 2) and total weights (N, m) by cumulative sums: O(n).

    w : window size, an int or (N,) ints (one per window).
    weights : None (counts) or per-sample (n, m) >= 0, used when a weight depends on its
    own sample only (Huff weights, Section 3.3.3), so every window shares it.
    """
    present = ~np.isnan(obs[..., 0])
    ref = np.nanmean(obs.reshape(-1, 2), axis=0) if present.any() else np.zeros(2)
    wt = present.astype(float) if weights is None else np.where(present, weights, 0.0)
    o0 = np.where(present[..., None], obs - ref, 0.0) * wt[..., None]
    n, m = present.shape
    C = np.zeros((n + 1, m, 2))
    np.cumsum(o0, axis=0, out=C[1:])
    K = np.zeros((n + 1, m))
    np.cumsum(wt, axis=0, out=K[1:])
    cnt = K[ends + 1] - K[ends + 1 - w]
    if weights is not None:
        # cancellation in K[b] - K[a] leaves ~1e-16 * K_total where the true sum is 0
        tiny = 1e-12 * np.maximum(K[-1], 1.0)[None, :]
        cnt = np.where(cnt > tiny, cnt, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        means = (C[ends + 1] - C[ends + 1 - w]) / cnt[..., None] + ref
    return np.where(cnt[..., None] > 0, means, np.nan), cnt


def _weighted_window_means(obs: np.ndarray, ends: np.ndarray, w: int, wts: np.ndarray
                           ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`estimator.window.window_means` of the windows ending at ``ends`` with
    per-window weights ``wts`` (N, w, m), without the (N, w, m, 2) stack: one pass per
    window offset j, adding in the order of window_means' reduction over the window axis
    (j = 0 .. w-1), so the sums are the same floating-point numbers."""
    present = ~np.isnan(obs[..., 0])
    o = np.where(present[..., None], obs, 0.0)
    start = ends - (w - 1)
    contiguous = ends.size > 0 and bool(np.all(np.diff(ends) == 1))
    num = np.zeros((ends.size, obs.shape[1], 2))
    W = np.zeros((ends.size, obs.shape[1]))
    for j in range(w):
        if contiguous:
            rows = slice(int(start[0]) + j, int(start[0]) + j + ends.size)
        else:
            rows = start + j
        wj = np.where(present[rows], wts[:, j], 0.0)
        W += wj
        num += wj[..., None] * o[rows]
    with np.errstate(invalid="ignore", divide="ignore"):
        means = num / W[..., None]
    full = W > 0
    return np.where(full[..., None], means, np.nan), np.where(full, W, 0.0)


def _fit_windows(obs, cfg, ends, w, *, weighting, rng, huff_threshold, huber_c, solver, eps,
                 warm_start, fit_kw, prev=None):
    """Window fits for rows ending at ``ends`` with window size w (an int, or with
    procrustes or elastic and no / Huff weights also an (N,) int array of per-row sizes).

    ``prev``: with ``warm_start``, the x0 of the first row (the last fit before ``ends[0]``,
    or None); each later row starts from the previous row's fit.
    Returns positions (N, m, 2), yaw (N,), status (N,) object and the last fit with data
    (the ``prev`` for the rows that follow; unchanged by procrustes).
    """
    N, m = ends.size, cfg.m
    if solver == "elastic":
        pos, yaw, status = _elastic_fits(obs, cfg, ends, w, weighting=weighting, rng=rng,
                                         huff_threshold=huff_threshold, huber_c=huber_c,
                                         eps=eps, fit_kw=fit_kw)
        return pos, yaw, status, prev
    pos = np.full((N, m, 2), np.nan)
    yaw = np.full(N, np.nan)
    status = np.empty(N, dtype=object)
    if solver == "procrustes" and weighting in ("none", "huff"):
        pos, yaw, status = _procrustes_fits(obs, cfg, ends, w, weighting, huff_threshold)
        return pos, yaw, status, prev
    a = 0
    huff = _sample_huff(obs, cfg, weighting, huff_threshold)
    for ch in _chunks(ends, w, m):
        sl = slice(a, a + ch.size)
        if solver == "procrustes" and weighting == "random":
            # the weights need no data: sum the windows without stacking them
            wts = _weights.random_weights((ch.size, w, m), rng)
            means, sw = _weighted_window_means(obs, ch, w, wts)
            bf = procrustes_batch(means, sw, cfg)
            pos[sl], yaw[sl], status[sl] = bf.positions, bf.yaw, bf.status
            a += ch.size
            continue
        st = _stack(obs, ch, w)
        wts = _window_weights(st, cfg, weighting, rng, huff_threshold, huber_c,
                              None if huff is None else _stack(huff, ch, w))
        if solver == "procrustes":
            means, sw = window_means(st, wts)
            bf = procrustes_batch(means, sw, cfg)
            pos[sl], yaw[sl], status[sl] = bf.positions, bf.yaw, bf.status
        else:
            for r in range(ch.size):
                fit = fit_window(st[r], cfg, None if wts is None else wts[r], eps=eps,
                                 solver=solver, x0=prev if warm_start else None, **fit_kw)
                pos[a + r], yaw[a + r], status[a + r] = fit.positions, fit.yaw, fit.status
                if fit.status != "insufficient_data":
                    prev = fit.positions
        a += ch.size
    return pos, yaw, status, prev


def _elastic_moments(obs, cfg, ends, w, *, weighting, rng, huff_threshold, huber_c):
    """Per-axis window means (N, m, 2) and axis weights (N, m, 2) of the windows ending at
    ``ends`` for the batched elastic solver: cumulative sums for per-sample weights (none,
    Huff), weighted sums for random weights, stacked windows (in chunks) for Huber."""
    if weighting in ("none", "huff"):
        sw = None if weighting == "none" else _recording_huff(obs, cfg, huff_threshold)
        means, cnt = _cumsum_means(obs, ends, w, sw)
        return means, np.repeat(cnt[..., None], 2, axis=-1)
    means = np.full((ends.size, cfg.m, 2), np.nan)
    wax = np.zeros((ends.size, cfg.m, 2))
    huff = _sample_huff(obs, cfg, weighting, huff_threshold)
    a = 0
    for ch in _chunks(ends, w, cfg.m):
        sl = slice(a, a + ch.size)
        if weighting == "random":
            wts = _weights.random_weights((ch.size, w, cfg.m), rng)
            mu, sw = _weighted_window_means(obs, ch, w, wts)
            means[sl], wax[sl] = mu, sw[..., None]
        else:
            st = _stack(obs, ch, w)
            wts = _window_weights(st, cfg, weighting, rng, huff_threshold, huber_c,
                                  None if huff is None else _stack(huff, ch, w))
            means[sl], wax[sl] = window_moments(st, wts)
        a += ch.size
    return means, wax


#: Elastic window fits memoised per process, keyed by content (:mod:`estimator.memo`): a
#: sweep fits the same windows of the same observations for several techniques (none, lc and
#: lc_course share one track's fits; dyn, lc+dyn and lc_course+dyn another's). A hit is an
#: identical request (the same observations, configuration, windows and options), so it
#: returns exactly what the call would. Random weights are never memoised (they consume the
#: generator). One entry holds N x m x 2 positions (~0.5 MB for 4000 windows of 8 sensors).
_ELASTIC_MEMO = ContentMemo(16)


def _elastic_fits(obs, cfg, ends, w, *, weighting, rng, huff_threshold, huber_c, eps, fit_kw):
    """(positions (N, m, 2), yaw (N,), status (N,) object) of the elastic fits of the windows
    ending at ``ends`` (:func:`estimator.elastic.elastic_batch`), memoised by content."""
    def fits():
        means, wax = _elastic_moments(obs, cfg, ends, w, weighting=weighting, rng=rng,
                                      huff_threshold=huff_threshold, huber_c=huber_c)
        ef = elastic_batch(means, wax, cfg, eps, **fit_kw)
        return ef.positions, ef.yaw, ef.status.astype(object)

    if weighting == "random":
        return fits()
    key = (content_digest(obs, ends, np.asarray(w), cfg.body_positions), weighting,
           repr(huff_threshold), float(huber_c), float(eps), repr(sorted(fit_kw.items())))
    pos, yaw, status = _ELASTIC_MEMO.get(key, fits)
    return pos.copy(), yaw.copy(), status.copy()


#: Procrustes window fits with no or Huff weights, memoised per process by content like
#: :data:`_ELASTIC_MEMO` (the techniques of one noise key that share a window size share the
#: fits; in the thesis preset 470 of 840 calls were repeats). One entry ~0.5 MB.
_PROCRUSTES_MEMO = ContentMemo(16)


def _procrustes_fits(obs, cfg, ends, w, weighting, huff_threshold):
    """(positions (N, m, 2), yaw (N,), status (N,) object) of the closed-form fits of the
    windows ending at ``ends`` with no or Huff weights, memoised by content. Huff weights
    are per sample (each time step on its own, Section 3.3.3 steps 1-9), so the stacked
    windows share them: one call on all epochs, then cumulative sums."""
    def fits():
        sw = None if weighting == "none" else _recording_huff(obs, cfg, huff_threshold)
        means, cnt = _cumsum_means(obs, ends, w, sw)
        bf = procrustes_batch(means, cnt, cfg)
        return bf.positions, bf.yaw, bf.status.astype(object)

    key = (content_digest(obs, ends, np.asarray(w), cfg.body_positions), cfg.names,
           tuple(cfg.dead), weighting, repr(huff_threshold))
    pos, yaw, status = _PROCRUSTES_MEMO.get(key, fits)
    return pos.copy(), yaw.copy(), status.copy()


def _runs(values: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) of the runs of equal consecutive values."""
    cut = np.flatnonzero(np.diff(values) != 0) + 1
    edges = np.r_[0, cut, values.size]
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]


def _motion_windows(t, obs, cfg, ends, w, *, weighting, rng, huff_threshold, huber_c,
                    yaw_rate, omega_max):
    N, m = ends.size, cfg.m
    pos = np.full((N, m, 2), np.nan)
    out = {k: np.full(N, np.nan) for k in ("yaw", "yaw_rate", "vx", "vy")}
    status = np.empty(N, dtype=object)
    if not yaw_rate and weighting in ("none", "huff"):
        # per-sample weights and omega = 0: per-epoch sums, no stacking of the sensor axis
        sw = None if weighting == "none" else _recording_huff(obs, cfg, huff_threshold)
        fit = motion_compensated_series(t, obs, cfg, ends, w, sw)
        out = {"yaw": fit.yaw, "yaw_rate": fit.yaw_rate, "vx": fit.velocity[:, 0],
               "vy": fit.velocity[:, 1]}
        return fit.positions, out, fit.status.astype(object)
    a = 0
    huff = _sample_huff(obs, cfg, weighting, huff_threshold)
    for ch in _chunks(ends, w, m):
        st = _stack(obs, ch, w)
        wts = _window_weights(st, cfg, weighting, rng, huff_threshold, huber_c,
                              None if huff is None else _stack(huff, ch, w))
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


def detect_turning(t: np.ndarray, obs: np.ndarray, config: SensorConfig,
                   **options: Any) -> np.ndarray:
    """Turning flags (n,) bool computed from the observations alone (no controller).

    The dynamic window of Section 3.4.2.1 (000_8f82f8df647bf685.txt) switches to a small
    window while the platform turns, knowing the turns from the platform's control; a real
    log has no such flag, so this derives one from the estimates (:mod:`estimator.turns`).

    t : (n,) seconds, finite and strictly increasing. obs : (n, m, 2) metres (world x east,
    y north), NaN = missing (both coordinates). config : the sensor configuration (m
    sensors; a 3-D one is projected). options : ``window`` (int >= 1, epochs), ``source``
    ("course" | "pose"), ``span_s`` (s), ``rate_on``/``rate_off`` (rad/s), ``min_speed``
    (m/s, "course" only).

    A plain procrustes track with window ``options["window"]`` (default 10) gives CG and yaw
    per epoch; the heading is either the course of the CG over ``span_s`` seconds
    (``source="course"``, default) or the fitted yaw (``source="pose"``); then
    :func:`estimator.turns.detect_turns` with ``rate_on``/``rate_off`` (rad/s) and
    ``span_s``. Defaults in :data:`DETECTOR_DEFAULTS`; a recording shorter than the default
    window uses all its epochs (a window the user sets must fit). Epochs before the first
    estimate are not turning.
    """
    unknown = sorted(set(options) - set(DETECTOR_DEFAULTS))
    if unknown:
        raise ValueError(
            f"detector: unknown option(s) {unknown}; known: {sorted(DETECTOR_DEFAULTS)}")
    opt = {**DETECTOR_DEFAULTS, **options}
    tt, o, cfg = _check_inputs(t, obs, config)
    if "window" not in options:
        opt["window"] = min(DETECTOR_DEFAULTS["window"], tt.size)
    w = check_int(opt["window"], "detector.window", 1, tt.size)
    if opt["source"] not in ("course", "pose"):
        raise ValueError(f"detector.source: must be 'course' or 'pose', got {opt['source']!r}")
    ends = np.arange(w - 1, tt.size)
    means, cnt = _cumsum_means(o, ends, w)
    bf = procrustes_batch(means, cnt, cfg)
    tr = tt[ends]
    if opt["source"] == "course":
        heading = _turns.course_heading(tr, bf.cg, opt["span_s"], opt["min_speed"])
    else:
        heading = bf.yaw
    flags = np.zeros(tt.size, dtype=bool)
    flags[ends] = _turns.detect_turns(tr, heading, rate_on=opt["rate_on"],
                                      rate_off=opt["rate_off"], span_s=opt["span_s"])
    return flags


# ----------------------------------------------------------------------------- track
@dataclass(frozen=True)
class _Options:
    """track's arguments, validated against each other and the recording."""

    weighting: Weighting
    lag: LagCorrection | None
    dyn: DynamicWindow | None
    fit: FitOptions
    motion: MotionOptions


def _resolve_options(n: int, s: int, weighting: Any, lag_correction: Any, dynamic_window: Any,
                     turning: Any, solver: Any, rng: Any, method: Any, fit: Any, motion: Any,
                     filter_params: Any, layout_check: Any) -> _Options:
    """The cross-checks of :func:`track` (each option object checks itself): which option
    applies to which method and solver, and the lengths that depend on the recording."""
    if not isinstance(layout_check, (bool, np.bool_)):
        raise TypeError(f"layout_check: must be True or False, got {layout_check!r}")
    if method not in METHODS:
        raise ValueError(f"method: unknown {method!r}; choose one of {list(METHODS)}")
    wt = Weighting.parse(weighting)
    if wt.scheme != "none" and method not in WEIGHTED_METHODS:
        raise ValueError(f"weighting: method={method!r} takes no weights, got {weighting!r}")
    if wt.scheme == "random" and not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng: weighting='random' needs a numpy.random.Generator, got {rng!r}")
    if solver not in SOLVERS:
        raise ValueError(f"solver: unknown {solver!r}; choose one of {list(SOLVERS)}")
    if method != "window" and solver != "procrustes":
        raise ValueError(
            f"solver: {solver!r} applies to method='window' only (got method={method!r})")
    for name, value, kind, applies in (("fit", fit, FitOptions, method == "window"),
                                       ("motion", motion, MotionOptions,
                                        method == "motion_compensated"),
                                       ("filter_params", filter_params, PoseFilterParams,
                                        method in FILTER_METHODS)):
        if value is None:
            continue
        if not isinstance(value, kind):
            raise TypeError(f"{name}: expected a {kind.__name__}, got {type(value).__name__}")
        if not applies:
            raise ValueError(f"{name}: does not apply to method={method!r}")
    fit = fit or FitOptions()
    if fit.warm_start and solver == "elastic":
        raise ValueError("warm_start: the batched elastic solver starts every window from "
                         "its procrustes fit; warm_start applies to 'slsqp' and 'ccp'")
    lag = LagCorrection.coerce(lag_correction)
    if lag is not None:
        if method != "window":
            raise ValueError(f"lag_correction: applies to method='window' only (got "
                             f"method={method!r})")
        if lag.velocity_span is not None:
            check_int(lag.velocity_span, "velocity_span", 1, n)
        if lag.heading is not None and lag.heading.shape != (n,):
            raise ValueError(f"lag_heading: expected a float array of shape ({n},) (radians), "
                             f"got {lag.heading.dtype} {lag.heading.shape}")
    dyn = DynamicWindow.coerce(dynamic_window)
    if dyn is not None:
        if method in FILTER_METHODS:
            raise ValueError(f"dynamic_window: not applicable to method={method!r}")
        check_int(dyn.small, "dynamic_window", 1, s)
        if turning is None:
            raise ValueError("turning: dynamic_window needs turning flags (a (n,) bool array) "
                             "or turning='detect'")
        if dyn.detector is not None and not isinstance(turning, str):
            raise ValueError("detector: only used with turning='detect'")
    elif turning is not None:
        raise ValueError("turning: only used together with dynamic_window")
    if isinstance(turning, str):
        if turning != "detect":
            raise ValueError(f"turning: must be a (n,) bool array or 'detect', got {turning!r}")
    elif turning is not None:
        fl = np.asarray(turning)
        if fl.shape != (n,) or fl.dtype != bool:
            raise ValueError(
                f"turning: expected a bool array of shape ({n},), got {fl.dtype} {fl.shape}")
    return _Options(wt, lag, dyn, fit, motion or MotionOptions())


def track(t: Any, obs: Any, config: SensorConfig, window: int = 10,
          weighting: str | Weighting = "none",
          lag_correction: bool | str | LagCorrection = False,
          dynamic_window: int | DynamicWindow | None = None, turning: Any = None,
          solver: str = "procrustes", rng: np.random.Generator | None = None, *,
          method: str = "window", fit: FitOptions | None = None,
          motion: MotionOptions | None = None, filter_params: PoseFilterParams | None = None,
          layout_check: bool = True) -> pd.DataFrame:
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
    """
    tt, o, cfg = _check_inputs(t, obs, config)
    n, m = o.shape[:2]
    s = check_int(window, "window", 1, n)
    opt = _resolve_options(n, s, weighting, lag_correction, dynamic_window, turning, solver,
                           rng, method, fit, motion, filter_params, layout_check)
    wt, lag, dyn, fo, mo = opt.weighting, opt.lag, opt.dyn, opt.fit, opt.motion
    # the options as the internals take them
    eps, warm_start, fit_options = fo.eps, fo.warm_start, fo.solver_kwargs()
    lag_mode = None if lag is None else lag.mode
    heading_for_lag = None if lag is None else lag.heading
    velocity_span = None if lag is None else lag.velocity_span
    flags = np.zeros(n, dtype=bool)
    if isinstance(turning, str):
        flags = detect_turning(tt, o, cfg, **(dyn.detector or {}))
    elif turning is not None:
        flags = np.asarray(turning).copy()

    ends = np.arange(s - 1, n)
    N = ends.size
    wsize = np.full(N, s, dtype=int)
    if dyn is not None:
        wsize = dynamic_window_sizes(flags[ends], s, dyn.small, dyn.growth)
    pos = np.full((N, m, 2), np.nan)
    yaw = np.full(N, np.nan)
    status = np.empty(N, dtype=object)
    extra: dict[str, np.ndarray] = {}
    common = {"weighting": wt.scheme, "rng": rng, "huff_threshold": wt.huff_threshold,
              "huber_c": wt.huber_c}

    if method == "window":
        if solver in ("procrustes", "elastic") and weighting in ("none", "huff"):
            # per-sample weights: every row, whatever its window size, from one set of
            # cumulative sums (a refilling dynamic window has up to s - small + 1 sizes),
            # and one batched fit (the elastic solver ignores x0: no warm start to carry)
            pos, yaw, status, _ = _fit_windows(o, cfg, ends, wsize, solver=solver, eps=eps,
                                               warm_start=False, fit_kw=fit_options or {},
                                               **common)
        elif warm_start and solver != "procrustes":
            # x0 of every row is the previous row's fit (Section 3.1.2), whatever the window
            # size: fit the runs of equal size in time order, carrying the last fit across
            prev = None
            for a, b in _runs(wsize):
                sl = slice(a, b)
                pos[sl], yaw[sl], status[sl], prev = _fit_windows(
                    o, cfg, ends[sl], int(wsize[a]), solver=solver, eps=eps, warm_start=True,
                    fit_kw=fit_options or {}, prev=prev, **common)
        else:
            for w in np.unique(wsize):
                sel = wsize == w
                p, y, st, _ = _fit_windows(o, cfg, ends[sel], int(w), solver=solver, eps=eps,
                                           warm_start=warm_start, fit_kw=fit_options or {},
                                           **common)
                pos[sel], yaw[sel], status[sel] = p, y, st
    elif method == "motion_compensated":
        extra = {k: np.full(N, np.nan) for k in ("yaw_rate", "vx", "vy")}
        for w in np.unique(wsize):
            sel = wsize == w
            p, out, st = _motion_windows(tt, o, cfg, ends[sel], int(w), yaw_rate=mo.yaw_rate,
                                         omega_max=mo.omega_max, **common)
            pos[sel], yaw[sel], status[sel] = p, out["yaw"], st
            for k in extra:
                extra[k][sel] = out[k]
        extra = {"speed": np.hypot(extra["vx"], extra["vy"]), "yaw_rate": extra["yaw_rate"]}
    elif method == "naive":
        means, cnt = _cumsum_means(o, ends, wsize)
        # every CG member must be in the window (module docstring): the mean of a subset is
        # a different point of the platform
        full = (cnt[:, cfg.cg_mask] > 0).all(axis=1)
        pos = np.where(full[:, None, None], means, np.nan)
        status = np.where(full, "ok", "insufficient_data").astype(object)
    else:  # the pose-filter family
        pos, yaw, status, extra = _run_filter(tt, o, cfg, s, filter_params or PoseFilterParams(),
                                              method)

    # CG (Eq. 3.8; naive: of the raw window means, all CG members present or NaN)
    cg = cfg.cg_from_positions(pos)

    # law-of-cosines heading of the fitted positions (Section 3.2)
    if method == "naive":
        yaw_loc = np.full(N, np.nan)
    else:
        i, j, ang = heading_pair(cfg)
        yaw_loc = law_of_cosines_heading(pos[:, j] - pos[:, i], ang)

    lag_dx = np.zeros(N)
    lag_dy = np.zeros(N)
    if lag_mode is not None:
        heading = yaw_loc if heading_for_lag is None else heading_for_lag[ends]
        shift = _lag_correct(tt, o, cfg, ends, wsize, pos, cg, heading, s, lag_mode,
                             velocity_span or s, dyn is not None, common, eps)
        ok = np.all(np.isfinite(shift), axis=1)
        pos = pos + np.where(ok[:, None], shift, 0.0)[:, None, :]
        cg = cg + np.where(ok[:, None], shift, 0.0)
        lag_dx = np.where(ok, shift[:, 0], np.nan)
        lag_dy = np.where(ok, shift[:, 1], np.nan)

    cols: dict[str, Any] = {
        "t": tt[ends], "cg_x": cg[:, 0], "cg_y": cg[:, 1], "yaw": yaw, "yaw_loc": yaw_loc,
        "window": wsize, "solver_status": status.astype(str), "turning": flags[ends],
        "lag_dx": lag_dx, "lag_dy": lag_dy,
    }
    for k, name in enumerate(cfg.names):
        cols[f"x_{name}"] = pos[:, k, 0]
        cols[f"y_{name}"] = pos[:, k, 1]
    cols.update(extra)
    df = pd.DataFrame(cols)
    df.attrs["settings"] = {
        "method": method, "window": s, "weighting": wt.scheme,
        "lag_correction": lag_mode or False,
        "dynamic_window": None if dyn is None else dyn.small,
        "turning": ("detect" if isinstance(turning, str)
                    else "flags" if turning is not None else None),
        "solver": solver, "eps": eps, "huff_threshold": wt.huff_threshold,
        "huber_c": wt.huber_c, "warm_start": warm_start, "config": cfg.name,
        "window_growth": None if dyn is None else dyn.growth,
        "lag_heading": "given" if heading_for_lag is not None else None,
    }
    if layout_check:
        lc = check_layout(tt, o, cfg, window=s)
        df.attrs["layout_check"] = lc.to_dict()
        df.attrs["warnings"] = list(lc.warnings)
        for msg in lc.warnings:
            warnings.warn(msg, LayoutWarning, stacklevel=2)
    return df


def _lag_correct(tt, o, cfg, ends, wsize, pos, cg, heading, s, mode, span, dynamic, common,
                 eps):
    """Section 3.4.2 shift for every row (see :mod:`estimator.lag`); ``heading`` (N,) rad
    is the orientation of step 5 (the law-of-cosines heading, or ``lag_heading``)."""
    if dynamic:
        # velocity from a uniform window-s series, so it is not polluted by the jump in lag
        # between small- and large-window rows
        # (procrustes, whatever the rows' solver: the series only feeds the velocity)
        p, _, _, _ = _fit_windows(o, cfg, ends, s, solver="procrustes", eps=eps,
                                  warm_start=False, fit_kw={}, **common)
        vel_cg = cfg.cg_from_positions(p)
    else:
        vel_cg = cg
    # each window estimate is dated at its window's mean epoch time (see estimator.lag)
    w_vel = np.full(ends.size, s) if dynamic else wsize
    ct = np.concatenate([[0.0], np.cumsum(tt - tt[0])])
    t_mid = (ct[ends + 1] - ct[ends + 1 - w_vel]) / w_vel + tt[0]
    vel = _lag.estimate_velocity(t_mid, vel_cg, span)
    first, fidx = _lag.first_observations(o, ends - wsize + 1, ends)
    return _lag.lag_shift(tt, pos, first, fidx, tt[ends], vel, heading, wsize, mode)


def _run_filter(tt, o, cfg, s, params, method):
    """Rows from epoch s-1 of the pose filter, its smoothers or the GTSAM peer (module
    docstring; :mod:`estimator.pose_filter`)."""
    if not isinstance(params, PoseFilterParams):
        raise TypeError(f"filter_params: expected a PoseFilterParams, got "
                        f"{type(params).__name__}")
    k0 = s - 1
    offsets = cfg.body_positions - cfg.cg_body
    r_m = offsets - np.asarray(params.no_slip_point_m)
    if method == "gtsam":
        from estimator.gtsam_peer import run_gtsam_peer

        res = run_gtsam_peer(tt, o, offsets, params)
        X, status = res.fixed_lag, res.status
        extra = {}
    else:
        # one forward pass (and smoothing) per (observations, params) in this process,
        # shared by the rows at every window, the smoothers and the smoothed heading of the
        # lag correction (estimator.memo); the memoised arrays are read-only, the rows copy
        res = memo_pose_filter(tt, o, offsets, params)
        X, status = res.states, res.status
        if method == "ekf_smoother":
            X = _smoother.memo_smoothed_states(tt, o, offsets, params)
        elif method == "ekf_fixed_lag":
            X = _smoother.memo_smoothed_states(tt, o, offsets, params, params.lag_s)
        extra = {"n_used": res.n_used[k0:].copy(), "n_gated": res.n_gated[k0:].copy(),
                 "n_steps": res.n_steps[k0:].copy()}
    X = X[k0:]
    c, sn = np.cos(X[:, 2]), np.sin(X[:, 2])
    R = np.stack([np.stack([c, -sn], -1), np.stack([sn, c], -1)], -2)  # (N, 2, 2)
    pos = X[:, None, :2] + np.einsum("nab,mb->nma", R, r_m)
    extra = {"speed": X[:, 3].copy(), "yaw_rate": X[:, 5].copy(), **extra}
    return pos, X[:, 2].copy(), np.asarray(status[k0:], dtype=object), extra
