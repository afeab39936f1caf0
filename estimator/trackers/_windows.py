"""Window kernels of the windowed trackers (window fit, motion-compensated, naive): stacked
windows, weights, cumulative-sum means, batched fits, the dynamic window's sizes and turn
detector, the lag correction; and the options the windowed trackers share.

Source: 000_8f82f8df647bf685.txt (GPS dissertation), Sections 3.1.2, 3.3, 3.4 and 3.4.2.1
(described in :mod:`estimator.tracking`). No state: what may be reused between calls goes
through the ``cache`` argument (:class:`estimator.memo.TrackCache`, None: computed).
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from estimator import lag as _lag
from estimator import turns as _turns
from estimator import weights as _weights
from estimator._checks import check_int
from estimator.configuration import SensorConfig
from estimator.elastic import elastic_batch
from estimator.memo import ContentMemo, TrackCache, content_digest, freeze, memo_get
from estimator.rigid_fit import procrustes_poses
from estimator.track_options import GROWTH_RULES, DynamicWindow
from estimator.trackers._common import Rows, TrackerOptions, check_inputs
from estimator.weights import Weighting
from estimator.window import (
    CcpProblems,
    fit_window,
    procrustes_batch,
    window_means,
    window_moments,
)

#: Float arrays (positions m, yaw rad, weights) of the kernels.
Floats = npt.NDArray[np.float64]
#: One fit per row: positions (N, m, 2) m, yaw (N,) rad, status (N,) object.
Fits = tuple[Floats, Floats, np.ndarray]

#: Windows stacked per weight/solver call: keeps memory ~ this many samples x m x 2 floats.
CHUNK_SAMPLES = 200_000

#: Defaults of the turn detector used by ``turning="detect"`` (see :mod:`estimator.turns`).
#: Chosen once on synthetic data (Path 1 rover truth at 0.2 m/s, turns at ~0.056 rad/s,
#: gps_stationary errors, 3 sessions from seed 20261122, not used by tests or the sweep) by
#: the F1 score of the flags against the controller's flag over window {1, 5, 10} x span
#: {4, 8, 16} s x rate_on {0.02, 0.03, 0.05, 0.1} rad/s (rate_off = rate_on / 2) x source:
#: best F1 0.42 (112 true, 171 false, 143 missed turning epochs). Slow turns under metre-level
#: noise are hard to see on-line; the controller flag remains the reference.
DETECTOR_DEFAULTS: dict[str, Any] = {"window": 10, "source": "course", "span_s": 8.0,
                                     "rate_on": 0.05, "rate_off": 0.025, "min_speed": 0.05}



@dataclass(frozen=True, kw_only=True, eq=False)
class DynamicOptions(TrackerOptions):
    """The dynamic window of Section 3.4.2.1 (window, motion-compensated and naive trackers).

    dynamic_window : None, the small window (epochs, 1 <= small <= window) used on turning
        epochs, or a :class:`estimator.track_options.DynamicWindow` (stored as one).
    turning : with a dynamic window, the (n,) bool turning flags of the recording (the
        simulator's controller flag) or "detect" (:func:`detect_turning`); else None.
    """

    dynamic_window: int | DynamicWindow | None = None
    turning: Any = None

    def __post_init__(self) -> None:
        super().__post_init__()
        dyn = DynamicWindow.coerce(self.dynamic_window)
        object.__setattr__(self, "dynamic_window", dyn)
        turning = self.turning
        if dyn is not None:
            check_int(dyn.small, "dynamic_window", 1, self.window)
            if turning is None:
                raise ValueError("turning: dynamic_window needs turning flags (a (n,) bool "
                                 "array) or turning='detect'")
            if dyn.detector is not None and not isinstance(turning, str):
                raise ValueError("detector: only used with turning='detect'")
        elif turning is not None:
            raise ValueError("turning: only used together with dynamic_window")
        if isinstance(turning, str):
            if turning != "detect":
                raise ValueError(f"turning: must be a (n,) bool array or 'detect', got "
                                 f"{turning!r}")
        elif turning is not None:
            fl = np.asarray(turning)
            if fl.ndim != 1 or fl.dtype != bool:
                raise ValueError(f"turning: expected a 1-D bool array, got {fl.dtype} "
                                 f"{fl.shape}")

    @property
    def _dynamic(self) -> DynamicWindow | None:
        """``dynamic_window`` as the object ``__post_init__`` stored (None: fixed window)."""
        return DynamicWindow.coerce(self.dynamic_window)

    def _rows(self, tt: np.ndarray, o: np.ndarray, cfg: SensorConfig) -> Rows:
        """The rows of the track, with the turning flags (checked against n) and the dynamic
        window's sizes (:func:`dynamic_window_sizes`)."""
        n, s, dyn, turning = tt.size, self.window, self._dynamic, self.turning
        flags = np.zeros(n, dtype=bool)
        if isinstance(turning, str):
            flags = detect_turning(tt, o, cfg, **((dyn and dyn.detector) or {}))
        elif turning is not None:
            fl = np.asarray(turning)
            if fl.shape != (n,):
                raise ValueError(f"turning: expected a bool array of shape ({n},), got "
                                 f"{fl.dtype} {fl.shape}")
            flags = fl.copy()
        ends = np.arange(s - 1, n)
        wsize = np.full(ends.size, s, dtype=int)
        if dyn is not None:
            wsize = dynamic_window_sizes(flags[ends], s, dyn.small, dyn.growth)
        return Rows(ends, wsize, flags)


@dataclass(frozen=True, kw_only=True, eq=False)
class WeightedOptions(DynamicOptions):
    """Window weights of Section 3.3 (window and motion-compensated trackers).

    weighting : a :class:`estimator.weights.Weighting` or its text (``"huff:3.5"``; stored
        as a Weighting). rng : a numpy Generator, required by ``"random"`` (consumed by each
        track; ignored otherwise).
    """

    weighting: str | Weighting = "none"
    rng: np.random.Generator | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        wt = Weighting.parse(self.weighting)
        object.__setattr__(self, "weighting", wt)
        if wt.scheme == "random" and not isinstance(self.rng, np.random.Generator):
            raise ValueError(f"rng: weighting='random' needs a numpy.random.Generator, got "
                             f"{self.rng!r}")

    @property
    def _weighting(self) -> Weighting:
        """``weighting`` as the :class:`Weighting` ``__post_init__`` stored."""
        return Weighting.parse(self.weighting)

    def _common(self, cache: TrackCache | None) -> dict[str, Any]:
        """The weight arguments of the kernels (and the cache)."""
        wt = self._weighting
        return {"weighting": wt.scheme, "rng": self.rng, "huff_threshold": wt.huff_threshold,
                "huber_c": wt.huber_c, "cache": cache}


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
def stack_windows(obs: np.ndarray, ends: np.ndarray, w: int) -> np.ndarray:
    """(len(ends), w, m, 2) windows ending at ``ends`` (inclusive)."""
    idx = ends[:, None] - np.arange(w - 1, -1, -1)[None, :]
    return obs[idx]


def window_weights(stack: np.ndarray, cfg: SensorConfig, weighting: str,
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


def recording_huff(obs: np.ndarray, cfg: SensorConfig, huff_threshold: float | None,
                   cache: TrackCache | None) -> np.ndarray:
    """:func:`estimator.weights.huff_weights` of a whole recording (n, m), read-only; through
    ``cache.huff`` keyed by the content of ``obs``, the layout and the threshold (a sweep
    scores every Huff-weighted technique of a noise key on the same observations, and the
    weights of Section 3.3.3 depend on each sample alone)."""
    def key() -> tuple:
        return (content_digest(obs, cfg.body_positions), cfg.names, tuple(cfg.dead),
                repr(huff_threshold))

    return memo_get(cache, "huff", key,
                    lambda: freeze(_weights.huff_weights(obs, cfg, huff_threshold)))


def sample_huff(obs: np.ndarray, cfg: SensorConfig, weighting: str,
                huff_threshold: float | None, cache: TrackCache | None) -> np.ndarray | None:
    """Per-sample Huff weights (n, m) of the whole recording when ``weighting`` uses them
    (Section 3.3.3 weighs each time step on its own, so every window shares them)."""
    if weighting in ("huff", "huff_huber"):
        return recording_huff(obs, cfg, huff_threshold, cache)
    return None


def chunks(ends: np.ndarray, w: int, m: int) -> Iterator[np.ndarray]:
    """``ends`` in slices of at most :data:`CHUNK_SAMPLES` stacked samples (w x m each)."""
    size = max(1, CHUNK_SAMPLES // max(1, w * m))
    for a in range(0, ends.size, size):
        yield ends[a:a + size]


def cumsum_means(obs: np.ndarray, ends: np.ndarray, w: int | np.ndarray,
                 weights: np.ndarray | None = None, cache: TrackCache | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Window means (N, m, 2) and total weights (N, m) by cumulative sums: O(n).

    w : window size, an int or (N,) ints (one per window).
    weights : None (counts) or per-sample (n, m) >= 0, used when a weight depends on its
    own sample only (Huff weights, Section 3.3.3), so every window shares it.
    cache : the sums of a recording (:func:`prefix_sums`) through ``cache.prefix``.
    """
    ref, C, K = prefix_sums(obs, weights, cache)
    cnt = K[ends + 1] - K[ends + 1 - w]
    if weights is not None:
        # cancellation in K[b] - K[a] leaves ~1e-16 * K_total where the true sum is 0
        tiny = 1e-12 * np.maximum(K[-1], 1.0)[None, :]
        cnt = np.where(cnt > tiny, cnt, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        means = (C[ends + 1] - C[ends + 1 - w]) / cnt[..., None] + ref
    return np.where(cnt[..., None] > 0, means, np.nan), cnt


def prefix_sums(obs: np.ndarray, weights: np.ndarray | None, cache: TrackCache | None
                ) -> tuple[Floats, Floats, Floats]:
    """What :func:`cumsum_means` needs of a whole recording, whatever its windows: the
    reference point ref (2,) m (the mean of every observation), the cumulative weighted
    sums C (n + 1, m, 2) of ``obs - ref`` and K (n + 1, m) of the weights (read-only).
    Through ``cache.prefix`` keyed by the content of ``obs`` and ``weights``: a sweep's
    techniques of one noise key ask for many window sizes and row sets of the same sums
    (the mean over all samples alone was ~1/3 of a call)."""
    def compute() -> tuple[Floats, Floats, Floats]:
        present = ~np.isnan(obs[..., 0])
        ref = np.nanmean(obs.reshape(-1, 2), axis=0) if present.any() else np.zeros(2)
        wt = present.astype(float) if weights is None else np.where(present, weights, 0.0)
        o0 = np.where(present[..., None], obs - ref, 0.0) * wt[..., None]
        n, m = present.shape
        C = np.zeros((n + 1, m, 2))
        np.cumsum(o0, axis=0, out=C[1:])
        K = np.zeros((n + 1, m))
        np.cumsum(wt, axis=0, out=K[1:])
        return freeze(ref), freeze(C), freeze(K)

    def key() -> tuple:
        return ("counts", content_digest(obs)) if weights is None else \
            ("weights", content_digest(obs, np.asarray(weights)))

    return memo_get(cache, "prefix", key, compute)


def weighted_window_means(obs: np.ndarray, ends: np.ndarray, w: int, wts: np.ndarray
                           ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`estimator.window.window_means` of the windows ending at ``ends`` with
    per-window weights ``wts`` (N, w, m), without the (N, w, m, 2) stack: the sums of
    :func:`estimator.window_kernel.weighted_sums` (compiled; :func:`weighted_sums_numpy` is
    its reference), adding in the order of window_means' reduction over the window axis
    (j = 0 .. w-1), so the sums are the same floating-point numbers."""
    from estimator.window_kernel import weighted_sums

    num = np.zeros((ends.size, obs.shape[1], 2))
    W = np.zeros((ends.size, obs.shape[1]))
    weighted_sums(obs, np.ascontiguousarray(ends, dtype=np.int64), wts, num, W)
    return _ratio(num, W)


def weighted_sums_numpy(obs: np.ndarray, ends: np.ndarray, w: int, wts: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray]:
    """The numpy reference of :func:`estimator.window_kernel.weighted_sums`: one pass per
    window offset j; returns (num (N, m, 2), W (N, m))."""
    present = ~np.isnan(obs[..., 0])
    o = np.where(present[..., None], obs, 0.0)
    start = ends - (w - 1)
    contiguous = ends.size > 0 and bool(np.all(np.diff(ends) == 1))
    rows: slice | np.ndarray
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
    return num, W


def _ratio(num: np.ndarray, W: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted means num / W (NaN where W = 0) and the total weights (0 there)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        means = num / W[..., None]
    full = W > 0
    return np.where(full[..., None], means, np.nan), np.where(full, W, 0.0)


def fit_windows(obs: np.ndarray, cfg: SensorConfig, ends: np.ndarray, w: int | np.ndarray, *,
                weighting: str, rng: np.random.Generator | None, huff_threshold: float | None,
                huber_c: float, solver: str, eps: float, warm_start: bool,
                fit_kw: dict[str, Any], cache: TrackCache | None, prev: Floats | None = None
                ) -> tuple[Floats, Floats, np.ndarray, Floats | None]:
    """Window fits for rows ending at ``ends`` with window size w (an int, or with
    procrustes or elastic and no / Huff weights also an (N,) int array of per-row sizes).

    ``prev``: with ``warm_start``, the x0 of the first row (the last fit before ``ends[0]``,
    or None); each later row starts from the previous row's fit.
    Returns positions (N, m, 2), yaw (N,), status (N,) object and the last fit with data
    (the ``prev`` for the rows that follow; unchanged by procrustes). ``cache``: a
    :class:`estimator.memo.TrackCache` for the procrustes / elastic fits and Huff weights,
    or None.
    """
    N, m = ends.size, cfg.m
    if solver == "elastic":
        pos, yaw, status = elastic_fits(obs, cfg, ends, w, weighting=weighting, rng=rng,
                                        huff_threshold=huff_threshold, huber_c=huber_c,
                                        eps=eps, fit_kw=fit_kw, cache=cache)
        return pos, yaw, status, prev
    pos = np.full((N, m, 2), np.nan)
    yaw = np.full(N, np.nan)
    status = np.empty(N, dtype=object)
    if solver == "procrustes" and weighting in ("none", "huff"):
        pos, yaw, status = procrustes_fits(obs, cfg, ends, w, weighting, huff_threshold, cache)
        return pos, yaw, status, prev
    w = one_size(w)
    a = 0
    huff = sample_huff(obs, cfg, weighting, huff_threshold, cache)
    ccp_problems = CcpProblems() if solver == "ccp" else None   # built once for these rows
    for ch in chunks(ends, w, m):
        sl = slice(a, a + ch.size)
        if solver == "procrustes" and weighting == "random":
            # the weights need no data: sum the windows without stacking them
            rw = _weights.random_weights((ch.size, w, m), rng)
            means, sw = weighted_window_means(obs, ch, w, rw)
            pos[sl], yaw[sl], status[sl] = procrustes_poses(means, sw, cfg)
            a += ch.size
            continue
        st = stack_windows(obs, ch, w)
        wts = window_weights(st, cfg, weighting, rng, huff_threshold, huber_c,
                              None if huff is None else stack_windows(huff, ch, w))
        if solver == "procrustes":
            means, sw = window_means(st, wts)
            pos[sl], yaw[sl], status[sl] = procrustes_poses(means, sw, cfg)
        else:
            for r in range(ch.size):
                fit = fit_window(st[r], cfg, None if wts is None else wts[r], eps=eps,
                                 solver=solver, x0=prev if warm_start else None,
                                 ccp_problems=ccp_problems, **fit_kw)
                pos[a + r], yaw[a + r], status[a + r] = fit.positions, fit.yaw, fit.status
                if fit.status != "insufficient_data":
                    prev = fit.positions
        a += ch.size
    return pos, yaw, status, prev


def elastic_moments(obs: np.ndarray, cfg: SensorConfig, ends: np.ndarray, w: int | np.ndarray,
                    *, weighting: str, rng: np.random.Generator | None,
                    huff_threshold: float | None, huber_c: float, cache: TrackCache | None
                    ) -> tuple[Floats, Floats]:
    """Per-axis window means (N, m, 2) and axis weights (N, m, 2) of the windows ending at
    ``ends`` for the batched elastic solver: cumulative sums for per-sample weights (none,
    Huff), weighted sums for random weights, stacked windows (in chunks) for Huber."""
    if weighting in ("none", "huff"):
        sw = None if weighting == "none" else recording_huff(obs, cfg, huff_threshold, cache)
        means, cnt = cumsum_means(obs, ends, w, sw, cache)
        return means, np.repeat(cnt[..., None], 2, axis=-1)
    w = one_size(w)
    means = np.full((ends.size, cfg.m, 2), np.nan)
    wax = np.zeros((ends.size, cfg.m, 2))
    huff = sample_huff(obs, cfg, weighting, huff_threshold, cache)
    a = 0
    for ch in chunks(ends, w, cfg.m):
        sl = slice(a, a + ch.size)
        if weighting == "random":
            rw = _weights.random_weights((ch.size, w, cfg.m), rng)
            mu, sw = weighted_window_means(obs, ch, w, rw)
            means[sl], wax[sl] = mu, sw[..., None]
        else:
            st = stack_windows(obs, ch, w)
            wts = window_weights(st, cfg, weighting, rng, huff_threshold, huber_c,
                                  None if huff is None else stack_windows(huff, ch, w))
            means[sl], wax[sl] = window_moments(st, wts)
        a += ch.size
    return means, wax


def elastic_fits(obs: np.ndarray, cfg: SensorConfig, ends: np.ndarray, w: int | np.ndarray, *,
                 weighting: str, rng: np.random.Generator | None, huff_threshold: float | None,
                 huber_c: float, eps: float, fit_kw: dict[str, Any], cache: TrackCache | None
                 ) -> Fits:
    """(positions (N, m, 2), yaw (N,), status (N,) object) of the elastic fits of the windows
    ending at ``ends`` (:func:`estimator.elastic.elastic_batch`), through ``cache.elastic``
    keyed by content: a sweep fits the same windows of the same observations for several
    techniques (none, lc and lc_course share one track's fits; dyn, lc+dyn and lc_course+dyn
    another's). A hit is an identical request (the same observations, configuration, windows
    and options), so it returns exactly what the call would. Random weights are never
    cached (they consume the generator)."""
    def fits(rows: np.ndarray | slice = slice(None)) -> Fits:
        means, wax = elastic_moments(obs, cfg, ends[rows],
                                     w[rows] if isinstance(w, np.ndarray) else w,
                                     weighting=weighting, rng=rng,
                                     huff_threshold=huff_threshold, huber_c=huber_c,
                                     cache=cache)
        ef = elastic_batch(means, wax, cfg, eps, **fit_kw)
        return ef.positions, ef.yaw, ef.status.astype(object)

    if weighting == "random" or cache is None:
        return fits()

    def key(size: int | np.ndarray) -> tuple:
        return (content_digest(obs, ends, np.asarray(size), cfg.body_positions), weighting,
                repr(huff_threshold), float(huber_c), float(eps), repr(sorted(fit_kw.items())))

    def compute() -> Fits:
        assert isinstance(w, np.ndarray) and cache is not None
        return composed(cache.elastic, key, w, fits)

    pos, yaw, status = memo_get(cache, "elastic", lambda: key(w),
                                compute if isinstance(w, np.ndarray) else fits)
    return pos.copy(), yaw.copy(), status.copy()


def composed(memo: ContentMemo, key: Callable[[Any], tuple], w: np.ndarray,
             fits: Callable[..., Fits]) -> Fits:
    """Fits of rows with per-row sizes ``w`` (N,) (a dynamic window): the rows of the full
    size s are those of the fixed window-s request when ``memo`` holds it (its cell came
    first), since each window is fitted on its own (the elastic kernel's loop, the
    procrustes closed form and its start row by row): ``fits(rows)`` fits only the others.
    ``key(sizes)`` is the memo key of a request with those sizes."""
    s = int(w.max()) if w.size else 0
    full_key = key(np.full(w.shape, s, dtype=w.dtype))         # as the fixed rows' request
    if not w.size or (w == s).all() or full_key not in memo:
        return fits()
    fp, fy, fs = memo.get(full_key, fits)
    pos, yaw, status = fp.copy(), fy.copy(), fs.copy()
    rest = np.flatnonzero(w != s)
    pos[rest], yaw[rest], status[rest] = fits(rest)
    return pos, yaw, status


def procrustes_fits(obs: np.ndarray, cfg: SensorConfig, ends: np.ndarray, w: int | np.ndarray,
                    weighting: str, huff_threshold: float | None, cache: TrackCache | None
                    ) -> Fits:
    """(positions (N, m, 2), yaw (N,), status (N,) object) of the closed-form fits of the
    windows ending at ``ends`` with no or Huff weights, through ``cache.procrustes`` keyed
    by content like :func:`elastic_fits` (the techniques of one noise key that share a
    window size share the fits; in the thesis preset 470 of 840 calls were repeats). Huff
    weights are per sample (each time step on its own, Section 3.3.3 steps 1-9), so the
    stacked windows share them: one call on all epochs, then cumulative sums."""
    def fits(rows: np.ndarray | slice = slice(None)) -> Fits:
        sw = None if weighting == "none" else recording_huff(obs, cfg, huff_threshold, cache)
        means, cnt = cumsum_means(obs, ends[rows], w[rows] if isinstance(w, np.ndarray) else w,
                                  sw, cache)
        p, y, st = procrustes_poses(means, cnt, cfg)
        return p, y, st.astype(object)

    if cache is None:
        return fits()

    def key(size: int | np.ndarray) -> tuple:
        return (content_digest(obs, ends, np.asarray(size), cfg.body_positions), cfg.names,
                tuple(cfg.dead), weighting, repr(huff_threshold))

    def compute() -> Fits:
        assert isinstance(w, np.ndarray) and cache is not None
        return composed(cache.procrustes, key, w, fits)

    pos, yaw, status = memo_get(cache, "procrustes", lambda: key(w),
                                compute if isinstance(w, np.ndarray) else fits)
    return pos.copy(), yaw.copy(), status.copy()


def one_size(w: int | np.ndarray) -> int:
    """``w`` as one window size: per-row sizes (an array) take the cumulative-sum paths
    only (no or Huff weights, procrustes or elastic)."""
    if isinstance(w, np.ndarray):
        raise TypeError(f"w: per-row window sizes (shape {w.shape}) need no or Huff weights "
                        "and the procrustes or elastic solver")
    return w


def runs(values: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) of the runs of equal consecutive values."""
    cut = np.flatnonzero(np.diff(values) != 0) + 1
    edges = np.r_[0, cut, values.size]
    return [(int(a), int(b)) for a, b in itertools.pairwise(edges)]



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
    tt, o, cfg = check_inputs(t, obs, config)
    if "window" not in options:
        opt["window"] = min(DETECTOR_DEFAULTS["window"], tt.size)
    w = check_int(opt["window"], "detector.window", 1, tt.size)
    if opt["source"] not in ("course", "pose"):
        raise ValueError(f"detector.source: must be 'course' or 'pose', got {opt['source']!r}")
    ends = np.arange(w - 1, tt.size)
    means, cnt = cumsum_means(o, ends, w)
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



def lag_correct(tt: np.ndarray, o: np.ndarray, cfg: SensorConfig, ends: np.ndarray,
                wsize: np.ndarray, pos: Floats, cg: Floats, heading: Floats, s: int, mode: str,
                span: int, dynamic: bool, common: dict[str, Any], eps: float) -> Floats:
    """Section 3.4.2 shift for every row (see :mod:`estimator.lag`); ``heading`` (N,) rad
    is the orientation of step 5 (the law-of-cosines heading, or ``lag_heading``)."""
    first, fidx, vel = lag_inputs(tt, o, cfg, ends, wsize, cg, s, span, dynamic, common, eps)
    return _lag.lag_shift(tt, pos, first, fidx, tt[ends], vel, heading, wsize, mode)


def lag_inputs(tt: np.ndarray, o: np.ndarray, cfg: SensorConfig, ends: np.ndarray,
               wsize: np.ndarray, cg: Floats, s: int, span: int, dynamic: bool,
               common: dict[str, Any], eps: float) -> tuple[Floats, np.ndarray, Floats]:
    """What the lag correction of every row needs besides its mode and heading: the first
    observation (N, m, 2) m and its epoch (N, m) of each sensor in each window, and the
    velocity (N, 2) m/s; through ``common["cache"].lag`` (read-only), so the corrections of
    one fit (LC, LC (course), the smoothed and the oracle heading) share them. Random
    weights are never cached (the dynamic window's velocity series consumes the
    generator)."""
    def compute() -> tuple[Floats, np.ndarray, Floats]:
        if dynamic:
            # velocity from a uniform window-s series, so it is not polluted by the jump in
            # lag between small- and large-window rows
            # (procrustes, whatever the rows' solver: the series only feeds the velocity)
            p, _, _, _ = fit_windows(o, cfg, ends, s, solver="procrustes", eps=eps,
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
        return freeze(first), freeze(fidx), freeze(vel)

    cache = common["cache"]
    if cache is None or common["weighting"] == "random":
        return compute()

    def key() -> tuple:
        src = (("series", cfg.names, tuple(cfg.dead), common["weighting"],
                repr(common["huff_threshold"]), float(common["huber_c"]))
               if dynamic else ("rows", content_digest(cg)))
        return (content_digest(tt, o, ends, wsize, cfg.body_positions), int(s), int(span),
                bool(dynamic), src)

    return memo_get(cache, "lag", key, compute)
