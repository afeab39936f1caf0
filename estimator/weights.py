"""Observation weights for the window fit: Huber, deleted residuals, Huff, random.

Source: GPS dissertation (``000_8f82f8df647bf685.txt``), Section 3.3: Huber weights
(3.3.1, Eq. 3.11-3.12), standardized deleted residuals (3.3.2), the Huff weight function
(3.3.3, Eq. 3.13) and the product Huff x Huber (Eq. 3.14); random weights are the control.

Every function accepts leading batch dimensions: ``obs`` is ``(..., s, m, d)`` (d = 2 for
GPS; Huff also takes d = 3), so stacked sliding windows ``(N, s, m, d)`` are weighted in one
call. Statistics that the source computes "per sensor" (medians, MAD, the hat matrix) run over
the ``s`` axis of each window, i.e. within the window the estimate uses. Missing
observations (NaN) always get weight 0 (never NaN), and every result feeds
:func:`estimator.window.fit_window` unchanged.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

from estimator._checks import check_array, check_int, check_real
from estimator.configuration import SensorConfig
from estimator.window import MAX_COORD_M

__all__ = [
    "HUBER_C",
    "MAD_CONSISTENCY",
    "THRESHOLD_WEIGHTINGS",
    "WEIGHTINGS",
    "Weighting",
    "deleted_residual_mask",
    "huber_weights",
    "huff_huber_weights",
    "huff_weights",
    "random_weights",
    "weights_for",
]

#: Huber tuning constant (Section 3.3.1, step 3): 95 % efficiency at the normal
HUBER_C = 1.345
#: MAD / 0.6745 estimates the standard deviation of normal data (Section 3.3.1, step 1)
MAD_CONSISTENCY = 0.6745
#: Weighting schemes of the window fit (Section 3.3), the one vocabulary every caller uses:
#: no weights, random weights (the control), Huff (3.3.3), Huber per axis (3.3.1) and the
#: product Huff x Huber (Eq. 3.14). :class:`Weighting` adds their parameters.
WEIGHTINGS = ("none", "random", "huff", "huber", "huff_huber")
#: Schemes that take a Huff residual threshold, written ``"<scheme>:<metres>"`` (e.g.
#: ``"huff:3.5"``, the threshold of Section 4.8.2).
THRESHOLD_WEIGHTINGS = ("huff", "huff_huber")
_NUMBER = re.compile(r"\d+(\.\d*)?([eE][+-]?\d+)?")


def _obs(obs: Any) -> tuple[np.ndarray, np.ndarray]:
    """obs as a float array (NaN = missing; finite entries at most MAX_COORD_M metres, so
    residuals and their squares stay finite) and its NaN mask."""
    arr = check_array(obs, "obs", allow_nan=True, max_abs=MAX_COORD_M)
    if arr.ndim < 3 or arr.shape[-1] not in (2, 3):
        raise ValueError(f"obs: expected shape (..., s, m, d) with d = 2 or 3, got {arr.shape}")
    return arr, np.isnan(arr)


def _window_nanmedian(x: np.ndarray, n: np.ndarray) -> np.ndarray:
    """``np.nanmedian(a, axis=-3, keepdims=True)`` for ``x = np.moveaxis(a, -3, -1)`` and
    ``n`` its count of non-NaN values along the last axis (keepdims): one sort (NaN sorts
    last), then the mean of the two middle present values, as numpy computes it; NaN where
    nothing is present. nanmedian on many short windows loops over masked arrays and is
    ~10x slower."""
    if x.shape[-1] == 0:  # empty window: nothing present, NaN (n is 0 everywhere)
        return np.moveaxis(np.full(x.shape[:-1] + (1,), np.nan), -1, -3)
    srt = np.sort(x, axis=-1)
    last = x.shape[-1] - 1
    lo = np.take_along_axis(srt, np.clip((n - 1) // 2, 0, last), axis=-1)
    hi = np.take_along_axis(srt, np.clip(n // 2, 0, last), axis=-1)
    med = np.where(n > 0, (lo + hi) / 2.0, np.nan)
    return np.moveaxis(med, -1, -3)


def _robust_residuals(arr: np.ndarray, nan: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per sensor and axis over the window axis (-3): residuals from the median (Eq. 3.11),
    robust scale MAD/0.6745 (3.3.1 step 1) and the number of present samples n."""
    x = np.moveaxis(arr, -3, -1)
    cnt = (~np.isnan(x)).sum(axis=-1, keepdims=True)
    med = _window_nanmedian(x, cnt)
    e = arr - med
    mad = _window_nanmedian(np.abs(np.moveaxis(e, -3, -1)), cnt) / MAD_CONSISTENCY
    n = (~nan).sum(axis=-3, keepdims=True)
    return e, mad, n


def huber_weights(obs: Any, c: float = HUBER_C) -> np.ndarray:
    """Huber weights per sample, sensor and axis (Section 3.3.1, Eq. 3.11-3.12).

    obs : (..., s, m, d) metres, NaN = missing. Returns (..., s, m, d) in [0, 1].

    Steps, per sensor and axis over the window: residual ``e = x - median(x)`` (Eq. 3.11);
    scale ``MAD = median|e - median(e)| / 0.6745`` (median(e) = 0 here, so this is
    ``median|e| / 0.6745``); ``u = e / MAD``; ``w = 1`` if ``|u| <= c`` else ``c / |u|``.
    This is statsmodels' ``HuberT(t=c).weights(u)``. When MAD = 0 (more than half of the
    samples equal the median) the limit MAD -> 0 is used: weight 1 at zero residual, 0
    otherwise. Missing samples get 0.
    """
    c = check_real(c, "c", lo=0.0, lo_open=True)
    arr, nan = _obs(obs)
    e, mad, _ = _robust_residuals(arr, nan)
    ae = np.abs(e)
    with np.errstate(divide="ignore", invalid="ignore"):
        w = np.where(ae <= c * mad, 1.0, c * mad / ae)
    return np.where(nan, 0.0, w)


def deleted_residual_mask(obs: Any, threshold: float | None = None, *,
                          rule: str = "standardized") -> np.ndarray:
    """Keep-mask from standardized deleted residuals (Section 3.3.2). True = keep.

    obs : (..., s, m, d) metres, NaN = missing. Returns (..., s, m, d) bool, **True for
    observations kept** (so the mask can be passed to ``fit_window`` as weights directly),
    False for outliers and for missing samples.

    Reading of the source, per sensor and axis over the window (n present samples):

    * Steps 1-2: residual from the median, ``e = x - median(x)``.
    * Step 3, hat matrix: the "predicted response" is a location (one parameter per sensor
      and axis), i.e. the regression ``x_t = mu + error`` with design matrix a column of ones.
      Its hat matrix is ``H = 1 1^T / n``, so ``h_tt = 1/n`` for every sample, and the deleted
      residual is ``d = e / (1 - 1/n)``. (For the mean, ``d`` is exactly the residual from
      the mean of the other n - 1 samples; the source swaps in the median, which has no hat
      matrix, and we keep its leverage 1/n.) With n = 1, h = 1 and nothing can be judged:
      the sample is kept.
    * Step 4 says values ``<= 1.0`` are outliers. Read literally this removes every negative
      residual and every residual below 1 m, i.e. the inliers: the inequality reads
      inverted and the residual is not standardized (the section's title says
      "standardized"). The literal rule is therefore not offered. Two readings are:

      ``rule="standardized"`` (default): ``d* = d / (sigma / sqrt(1 - h)) = e / (sigma
      sqrt(1 - 1/n))`` with the robust scale ``sigma = MAD / 0.6745`` (as in 3.3.1; robust,
      so no leave-one-out refit of the scale is needed). Var(d) = sigma^2 / (1 - h) for
      the location model, so d* is unit-variance for normal data. Flag ``|d*| > threshold``,
      default 3.0 (the usual cut-off for studentized residuals). MAD = 0: any non-zero
      residual is flagged.

      ``rule="absolute"``: the text's number with the inequality turned around, in metres:
      flag ``|d| > threshold``, default 1.0 m.
    """
    if rule not in ("standardized", "absolute"):
        raise ValueError(f"rule: unknown {rule!r}; choose 'standardized' or 'absolute'")
    if threshold is None:
        threshold = 3.0 if rule == "standardized" else 1.0
    thr = check_real(threshold, "threshold", lo=0.0, lo_open=True)
    arr, nan = _obs(obs)
    e, mad, n = _robust_residuals(arr, nan)
    with np.errstate(divide="ignore", invalid="ignore"):
        one_minus_h = 1.0 - 1.0 / n
        if rule == "absolute":
            stat = np.abs(e) / one_minus_h
        else:
            stat = np.abs(e) / (mad * np.sqrt(one_minus_h))
            stat = np.where(e == 0, 0.0, stat)  # 0/0 when MAD = 0 and e = 0: not an outlier
    keep = np.where(n <= 1, True, stat <= thr)
    return keep & ~nan


def huff_weights(obs: Any, config: SensorConfig, threshold: float | None = None, *,
                 min_error: float = 1e-3) -> np.ndarray:
    """Huff weights per sample and sensor (Section 3.3.3, steps 1-9; used in Eq. 3.13).

    obs : (..., s, m, d) metres (d = config.d), NaN = missing. threshold : metres or None.
    min_error : floor on the relative error in metres (see below). Returns (..., s, m) >= 0.

    Reading of the steps, at each time step t (each sample, independently):

    1. A *relationship* of sensor i is another sensor j that also reported at t; the
       relationships at t are the unordered pairs of reporting sensors (k reporting sensors
       give k(k-1)/2 pairs, and each sensor has n_i = k - 1 relationships).
    2-3. For each pair, ``e_ij = | |o_i - o_j| - a_ij |`` (observed vs. known distance).
    4. Average error ``E_t`` = sum of e_ij over the pairs / number of pairs.
    5. If ``threshold`` is given and ``E_t >= threshold``, every sensor at t gets weight 0.
    6. Relative error of sensor i: ``r_i = sum_j e_ij / n_i`` over its relationships.
    7. If ``threshold`` is given and ``r_i >= threshold``, sensor i gets weight 0 at t.
    8-9. Otherwise ``w_i = (1 / r_i) * n_i / (m - 1)``, m = config.m (all sensors,
       including dead ones: m - 1 is the most relationships a sensor can have). We read
       "total number of relationships in time-step" as the sensor's own count n_i = k - 1
       (the text divides it by the maximum *per sensor*, m - 1, so the factor is the
       fraction of possible partners that reported, in [0, 1]); reading it as the number
       of pairs k(k-1)/2 would give factors up to m/2, which the normalization rules out.

    ``threshold=None`` skips steps 5 and 7 (the dissertation's "no threshold" runs, 4.8.1).
    A sensor with no relationship (the only one reporting, or missing) gets weight 0: it
    has no evidence of reliability and the step-8 factor n_i/(m-1) is 0 anyway.
    Zero relative error would give an infinite weight; ``r_i`` is floored at ``min_error``
    (default 1 mm, below the resolution of the GPS fixes this targets), so a sensor that
    agrees with the configuration to better than 1 mm weighs as much as one at 1 mm. On
    noise-free data all sensors then get equal weights and the fit stays exact.
    """
    if not isinstance(config, SensorConfig):
        raise ValueError(  # noqa: TRY004 (the project's bad-input contract is ValueError)
            f"config: expected a SensorConfig, got {type(config).__name__}")
    arr, nan = _obs(obs)
    if arr.shape[-2:] != (config.m, config.d):
        raise ValueError(f"obs: expected shape (..., s, {config.m}, {config.d}) for config "
                         f"{config.name!r}, got {arr.shape}")
    if threshold is not None:
        thr = check_real(threshold, "threshold", lo=0.0, lo_open=True)
    mf = check_real(min_error, "min_error", lo=0.0, lo_open=True)
    m = config.m
    present = ~np.any(nan, axis=-1)                               # (..., s, m)
    o = np.where(present[..., None], arr, 0.0)
    # pairwise distances (..., s, m, m), one coordinate at a time (no (..., m, m, d) array;
    # the squares are added in the order of a sum over the last axis, so same floats)
    dk = o[..., :, None, 0] - o[..., None, :, 0]
    dist2 = dk * dk
    for k in range(1, arr.shape[-1]):
        dk = o[..., :, None, k] - o[..., None, :, k]
        dist2 = dist2 + dk * dk
    dist = np.sqrt(dist2)
    rel = present[..., :, None] & present[..., None, :] & ~np.eye(m, dtype=bool)
    err = np.where(rel, np.abs(dist - config.distances()), 0.0)   # steps 2-3
    n_i = rel.sum(axis=-1)                                        # relationships per sensor
    sum_i = err.sum(axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = sum_i / n_i                                           # step 6
        r = np.maximum(r, mf)
        w = (1.0 / r) * n_i / (m - 1)                             # step 8
    w = np.where(n_i > 0, w, 0.0)
    if threshold is not None:
        n_pairs = n_i.sum(axis=-1) / 2.0                          # (..., s)
        with np.errstate(divide="ignore", invalid="ignore"):
            avg = err.sum(axis=(-2, -1)) / 2.0 / n_pairs          # step 4
        w = np.where((n_pairs > 0)[..., None] & (avg >= thr)[..., None], 0.0, w)  # step 5
        w = np.where((n_i > 0) & (sum_i / np.maximum(n_i, 1) >= thr), 0.0, w)   # step 7
    return w


def huff_huber_weights(obs: Any, config: SensorConfig, threshold: float | None = None,
                       c: float = HUBER_C, *, min_error: float = 1e-3) -> np.ndarray:
    """Product of Huff and Huber weights, per axis (Eq. 3.14): (..., s, m, d)."""
    return huff_weights(obs, config, threshold, min_error=min_error)[..., None] \
        * huber_weights(obs, c)


def random_weights(shape: int | Iterable[int], rng: np.random.Generator | None
                   ) -> np.ndarray:
    """Control weights, i.i.d. uniform on [0, 1) from the passed Generator (Section 3.3,
    "random weight functions"; the distribution is not stated there, uniform is our choice).
    Weights at missing observations are ignored by the fit, so no obs is needed here."""
    if not isinstance(rng, np.random.Generator):
        raise ValueError(  # noqa: TRY004 (the project's bad-input contract is ValueError)
            f"rng: expected a numpy.random.Generator, got {type(rng).__name__}")
    try:
        if isinstance(shape, (bool, np.bool_)):
            raise TypeError
        shp = (int(shape),) if isinstance(shape, (int, np.integer)) else tuple(shape)
    except TypeError:
        raise TypeError(f"shape: must be an integer or a tuple of integers, got "
                        f"{type(shape).__name__} {shape!r}") from None
    shp = tuple(check_int(k, "shape", lo=0) for k in shp)
    try:
        return rng.random(shp)
    except (MemoryError, ValueError) as exc:  # numpy refuses sizes it cannot allocate
        raise ValueError(f"shape: {shp} ({math.prod(shp)} weights) cannot be allocated: "
                         f"{exc}") from None


@dataclass(frozen=True)
class Weighting:
    """A weighting scheme of Section 3.3 with its parameters (one spelling everywhere).

    scheme : one of :data:`WEIGHTINGS`.
    huff_threshold : Huff residual threshold in metres (steps 5 and 7 of Section 3.3.3),
        > 0, or None for none; only for the schemes of :data:`THRESHOLD_WEIGHTINGS`.
    huber_c : Huber tuning constant (Eq. 3.12), > 0; only "huber" and "huff_huber" use it,
        so another value with another scheme is refused.

    As text (specs, tables, the ``weighting`` argument of ``track``): the scheme name, or
    ``"<scheme>:<threshold>"`` for a Huff threshold in metres, e.g. ``"huff:3.5"``;
    :meth:`parse` reads it and ``str()`` writes it back.
    """

    scheme: str = "none"
    huff_threshold: float | None = None
    huber_c: float = HUBER_C

    def __post_init__(self) -> None:
        if self.scheme not in WEIGHTINGS:
            raise ValueError(f"weighting: unknown weighting {self.scheme!r}; choose one of "
                             f"{list(WEIGHTINGS)}, or '<scheme>:<threshold m>' for "
                             f"{list(THRESHOLD_WEIGHTINGS)}")
        if self.huff_threshold is not None:
            if self.scheme not in THRESHOLD_WEIGHTINGS:
                raise ValueError(f"huff_threshold: applies to {list(THRESHOLD_WEIGHTINGS)} "
                                 f"only, not to weighting {self.scheme!r}")
            object.__setattr__(self, "huff_threshold", check_real(
                self.huff_threshold, "huff_threshold", lo=0.0, lo_open=True))
        c = check_real(self.huber_c, "huber_c", lo=0.0, lo_open=True)
        if c != HUBER_C and self.scheme not in ("huber", "huff_huber"):
            raise ValueError(f"huber_c: applies to 'huber' and 'huff_huber' only, not to "
                             f"weighting {self.scheme!r}")
        object.__setattr__(self, "huber_c", c)

    @classmethod
    def parse(cls, value: str | Weighting) -> Weighting:
        """A :class:`Weighting` from its text (``"huff"``, ``"huff:3.5"``, ...) or itself.

        Raises ValueError naming ``weighting`` and the value for an unknown scheme, a
        threshold on a scheme without one, or a threshold that is not a number > 0.
        """
        if isinstance(value, Weighting):
            return value
        if not isinstance(value, str):
            raise TypeError(f"weighting: must be a string such as 'huff:3.5' or a Weighting, "
                            f"got {type(value).__name__} {value!r}")
        scheme, sep, thr = value.partition(":")
        if not sep:
            return cls(scheme)
        if scheme not in THRESHOLD_WEIGHTINGS:
            raise ValueError(f"weighting: {value!r}: a threshold applies to "
                             f"{list(THRESHOLD_WEIGHTINGS)} only")
        t = float(thr) if _NUMBER.fullmatch(thr) else math.nan
        if not (math.isfinite(t) and t > 0):
            raise ValueError(f"weighting: {value!r}: the threshold after ':' must be a number "
                             f"of metres > 0")
        return cls(scheme, huff_threshold=t)

    def __str__(self) -> str:
        if self.huff_threshold is None:
            return self.scheme
        return f"{self.scheme}:{self.huff_threshold!r}"


def weights_for(obs: Any, config: SensorConfig, weighting: str | Weighting,
                rng: np.random.Generator | None = None) -> np.ndarray | None:
    """The weights of ``weighting`` for windows of observations: the one dispatcher.

    obs : (..., s, m, d) metres, NaN = missing. weighting : a :class:`Weighting` or its
    text. rng : numpy Generator, required by "random". Returns None for "none" (every
    observation weighs 1), ``(..., s, m)`` for "random" (uniform, :func:`random_weights`)
    and "huff" (:func:`huff_weights`), ``(..., s, m, d)`` for "huber" and "huff_huber"
    (per axis, Eq. 3.12 and 3.14).
    """
    w = Weighting.parse(weighting)
    if w.scheme == "none":
        return None
    if w.scheme == "random":
        return random_weights(np.shape(obs)[:-1], rng)
    if w.scheme == "huff":
        return huff_weights(obs, config, w.huff_threshold)
    if w.scheme == "huber":
        return huber_weights(obs, w.huber_c)
    return huff_huber_weights(obs, config, w.huff_threshold, w.huber_c)
