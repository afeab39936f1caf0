"""Statistics of a position-error series: autocorrelation, AR(1), normality, robust spread.

Source: ``000_8f82f8df647bf685.txt`` (GPS dissertation), Sections 2.2 (AR(1), Eq. 2.2) and
4.3 (ACF of the coordinates and of the AR(1) residuals against +-1.96/sqrt(n); normal
probability plots, Figs 4.7-4.8). Robust statistics beyond the dissertation: the standard
deviation of a real receiver log can be set by one sample (a reacquisition fix hundreds of
metres off), so every spread is reported beside its robust counterparts and the outliers
that drive it are flagged.

Series are 1-D float arrays in metres (any unit works) with NaN = missing sample; time is
the sample index (an evenly sampled grid, as :class:`sim.gps.StationarySession` provides).
Infinite values are rejected (ValueError naming ``x``), and so are magnitudes above
:data:`MAX_ABS` (their squares would overflow float64).

Robust statistics (per series, over present samples):

- ``mad_sigma``: ``1.4826 * median(|x - median(x)|)``, the median absolute deviation scaled
  to estimate the standard deviation of a normal sample (1.4826 = 1 / Phi^-1(3/4)).
- ``p95``: 95th percentile of ``|x - median(x)|``.
- outliers: the modified z-score of Iglewicz and Hoaglin (1993),
  ``M_i = 0.6745 (x_i - median) / MAD``, flagged where ``|M_i| > 3.5`` (their recommended
  cut-off, :data:`OUTLIER_Z`). When MAD = 0 (more than half the samples identical, e.g. a
  quantized RTK log) the scale falls back to ``1.2533 * mean(|x - median|)`` (the mean
  absolute deviation scaled to sigma, sqrt(pi/2)); when that is 0 too nothing is flagged.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from estimator._checks import check_array, check_int, check_real

__all__ = [
    "MAX_ABS",
    "OUTLIER_Z",
    "NoiseSummary",
    "abs_dev_percentile",
    "acf",
    "ar1_fit",
    "mad_sigma",
    "noise_summary",
    "npp_r",
    "robust_outliers",
    "tau_from_phi",
]

#: Largest accepted magnitude of a sample: squares and sums of 1e6 squares stay finite.
MAX_ABS = 1e100
#: Modified z-score cut-off of Iglewicz & Hoaglin (1993) for a potential outlier.
OUTLIER_Z = 3.5
_MAD_TO_SIGMA = 1.482602218505602      # 1 / scipy.stats.norm.ppf(0.75)
_MEANAD_TO_SIGMA = math.sqrt(math.pi / 2.0)


def _series(x: Any, name: str = "x") -> np.ndarray:
    return check_array(x, name, shape=(None,), allow_nan=True, max_abs=MAX_ABS)


# --------------------------------------------------------------------------- time series
def acf(x: Any, nlags: int) -> np.ndarray:
    """Sample autocorrelation r_0..r_nlags of a series with NaN = missing (Section 4.3).

    ``r_k = sum_t d_t d_{t+k} / sum_t d_t^2`` with ``d = x - mean(x)`` over present samples
    and products only where both samples are present (Box-Jenkins estimator; for a series
    without gaps it equals statsmodels ``acf(x, adjusted=False)``, with gaps statsmodels'
    ``missing="conservative"``). x (n,) -> (nlags + 1,); ``0 <= nlags <= max(n - 1, 0)``.
    All NaN (fewer than 2 present samples, or a constant series).
    """
    v = _series(x)
    n = v.size
    k = check_int(nlags, "nlags", 0, max(n - 1, 0))
    ok = np.isfinite(v)
    if ok.sum() < 2:
        return np.full(k + 1, np.nan)
    d = np.where(ok, v - v[ok].mean(), 0.0)
    den = float((d * d).sum())
    if den == 0.0:
        return np.full(k + 1, np.nan)
    # all lags at once via FFT of the zero-filled deviations (missing contribute 0)
    nfft = 1 << math.ceil(math.log2(2 * n))
    f = np.fft.rfft(d, nfft)
    return np.fft.irfft(f * np.conj(f), nfft)[: k + 1] / den


def ar1_fit(x: Any) -> tuple[float, float, float, np.ndarray]:
    """AR(1) of Eq. 2.2, ``x_t = delta + phi x_{t-1} + w_t``, by least squares on present pairs.

    Returns ``(delta, phi, sigma_w, residuals (n,))`` with residuals NaN where x_t or
    x_{t-1} is missing (and at t = 0); NaN parameters with fewer than 3 pairs or when the
    previous values are all equal (phi undetermined). Equals statsmodels
    ``AutoReg(x, 1, trend="c")`` (conditional least squares) for a series without gaps.
    """
    v = _series(x)
    res = np.full(v.shape, np.nan)
    prev, cur = v[:-1], v[1:]
    ok = np.isfinite(prev) & np.isfinite(cur)
    if ok.sum() < 3:
        return math.nan, math.nan, math.nan, res
    p, c = prev[ok], cur[ok]
    # normal equations of [1, x_{t-1}] solved on centred values: the same least-squares
    # solution, without the ill-conditioning of the [1, x] design when |mean| >> spread
    # (UTM coordinates: np.linalg.lstsq on [1, x] returned phi 0.93 for a true 0.99999)
    pm, cm = float(p.mean()), float(c.mean())
    dp = p - pm
    sxx = float((dp * dp).sum())
    if sxx == 0.0:             # all previous values equal (or their spread underflows)
        return math.nan, math.nan, math.nan, res
    phi = float((dp * (c - cm)).sum() / sxx)
    delta = cm - phi * pm
    r = c - (delta + phi * p)
    res[1:][ok] = r
    sigma = float(np.sqrt((r * r).sum() / max(ok.sum() - 2, 1)))
    return delta, phi, sigma, res


def tau_from_phi(phi: float, dt_s: float) -> float:
    """Correlation time ``-dt / ln(phi)`` (s) of an AR(1) with 0 < phi < 1 sampled every
    ``dt_s`` seconds (a first-order Gauss-Markov process); NaN outside that range."""
    dt = check_real(dt_s, "dt_s", lo=0.0, lo_open=True)
    if isinstance(phi, (float, np.floating)) and math.isnan(phi):
        return math.nan          # an undetermined AR(1) (ar1_fit's NaN) has no time constant
    p = check_real(phi, "phi", finite=False)
    return -dt / math.log(p) if 0.0 < p < 1.0 else math.nan


def npp_r(x: Any) -> float:
    """Correlation coefficient of the normal probability plot (scipy.stats.probplot's r);
    1 for a perfect normal sample (Figs 4.7-4.8). NaN below 3 present samples or for a
    constant series."""
    from scipy import stats

    v = _series(x)
    v = v[np.isfinite(v)]
    if v.size < 3 or np.ptp(v) == 0:
        return math.nan
    (_, _), (_, _, r) = stats.probplot(v, dist="norm")
    return float(r)


# --------------------------------------------------------------------------- robust spread
def _abs_dev(v: np.ndarray) -> np.ndarray:
    """|x - median| over present samples (empty when none)."""
    p = v[np.isfinite(v)]
    return np.abs(p - np.median(p)) if p.size else p


def mad_sigma(x: Any) -> float:
    """Median absolute deviation from the median, times 1.4826 (a standard deviation for a
    normal sample; statsmodels ``robust.scale.mad``). NaN without present samples."""
    a = _abs_dev(_series(x))
    return float(_MAD_TO_SIGMA * np.median(a)) if a.size else math.nan


def abs_dev_percentile(x: Any, q: float = 95.0) -> float:
    """``q``-th percentile (0-100) of ``|x - median(x)|`` over present samples; NaN without."""
    qq = check_real(q, "q", lo=0.0, hi=100.0)
    a = _abs_dev(_series(x))
    return float(np.percentile(a, qq)) if a.size else math.nan


def robust_outliers(x: Any, z: float = OUTLIER_Z) -> np.ndarray:
    """(n,) bool: samples whose modified z-score ``0.6745 |x - median| / MAD`` exceeds ``z``
    (Iglewicz & Hoaglin; fallback scale when MAD = 0 in the module docstring). Missing
    samples are never outliers."""
    zz = check_real(z, "z", lo=0.0, lo_open=True)
    v = _series(x)
    out = np.zeros(v.shape, dtype=bool)
    ok = np.isfinite(v)
    if not ok.any():
        return out
    med = float(np.median(v[ok]))
    a = np.abs(v[ok] - med)
    scale = _MAD_TO_SIGMA * float(np.median(a))
    if scale == 0.0:
        scale = _MEANAD_TO_SIGMA * float(a.mean())
    if scale == 0.0:
        return out
    out[ok] = a > zz * scale        # not a / scale: a tiny scale would overflow
    return out


@dataclass(frozen=True)
class NoiseSummary:
    """Spread and correlation of one series, with and without its flagged outliers.

    n : present samples; std : population std (m); mad_sigma, p95 : robust spread (m);
    outliers : number flagged by :func:`robust_outliers`; std_inliers : std without them;
    worst_index / worst_abs_dev : sample farthest from the median and its distance (m);
    ar1_phi / ar1_phi_inliers : AR(1) coefficient (Eq. 2.2) with all samples / with the
    outliers set missing; npp_r : normal-probability-plot correlation.
    """

    n: int
    std: float
    mad_sigma: float
    p95: float
    outliers: int
    std_inliers: float
    worst_index: int
    worst_abs_dev: float
    ar1_phi: float
    ar1_phi_inliers: float
    npp_r: float

    def to_dict(self) -> dict:
        return asdict(self)


def noise_summary(x: Any, z: float = OUTLIER_Z) -> NoiseSummary:
    """All statistics of :class:`NoiseSummary` for a series (n,) with NaN = missing."""
    v = _series(x)
    ok = np.isfinite(v)
    n = int(ok.sum())
    if n == 0:
        return NoiseSummary(0, *(math.nan,) * 3, 0, math.nan, -1, *(math.nan,) * 4)
    flags = robust_outliers(v, z)
    inl = np.where(flags, np.nan, v)
    dev = np.where(ok, np.abs(v - np.median(v[ok])), -1.0)
    worst = int(np.argmax(dev))
    return NoiseSummary(
        n=n, std=float(np.std(v[ok])), mad_sigma=mad_sigma(v), p95=abs_dev_percentile(v),
        outliers=int(flags.sum()), std_inliers=float(np.nanstd(inl)) if (~flags & ok).any()
        else math.nan, worst_index=worst, worst_abs_dev=float(dev[worst]),
        ar1_phi=ar1_fit(v)[1], ar1_phi_inliers=ar1_fit(inl)[1], npp_r=npp_r(v))
