"""estimator.noise_stats: ACF / AR(1) / NPP against statsmodels and scipy, robust spread
against statsmodels' MAD and numpy percentiles, outlier flags, and extreme inputs."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from estimator.noise_stats import (
    MAX_ABS,
    abs_dev_percentile,
    acf,
    ar1_fit,
    mad_sigma,
    noise_summary,
    npp_r,
    robust_outliers,
    tau_from_phi,
)
from sim.gps import gauss_markov


def _series(n=3000, seed=0):
    rng = np.random.default_rng(seed)
    return 3.0 + gauss_markov(n, (), 1.0, 20.0, 1.0, rng) + 0.1 * rng.standard_normal(n)


def test_acf_matches_statsmodels():
    from statsmodels.tsa.stattools import acf as sm_acf

    x = _series()
    # identical estimator (unadjusted Box-Jenkins); differences are FFT rounding only
    assert np.allclose(acf(x, 60), sm_acf(x, nlags=60, adjusted=False, fft=False), atol=1e-10)


def test_acf_with_gaps_matches_statsmodels_conservative():
    from statsmodels.tsa.stattools import acf as sm_acf

    x = _series(seed=1)
    x[np.random.default_rng(2).random(x.size) < 0.1] = np.nan
    # statsmodels' missing="conservative": nan-aware mean and cross-products, same normalisation
    ref = sm_acf(x, nlags=40, adjusted=False, fft=False, missing="conservative")
    assert np.allclose(acf(x, 40), ref, atol=1e-10)


def test_ar1_matches_statsmodels_autoreg():
    from statsmodels.tsa.ar_model import AutoReg

    x = _series(seed=3)
    delta, phi, _, res = ar1_fit(x)
    fit = AutoReg(x, lags=1, trend="c").fit()
    # both are conditional least squares on the same pairs: agreement to rounding
    assert np.allclose([delta, phi], fit.params, atol=1e-10)
    assert np.allclose(res[1:], fit.resid, atol=1e-10)
    assert np.isnan(res[0])


def test_npp_r_matches_scipy_and_detects_heavy_tails():
    from scipy import stats

    rng = np.random.default_rng(4)
    g = rng.standard_normal(4000)
    assert npp_r(g) == pytest.approx(stats.probplot(g)[1][2], abs=1e-12)
    assert npp_r(g) > 0.999
    assert npp_r(rng.standard_t(2, 4000)) < 0.95


def test_robust_spread_matches_statsmodels_and_numpy():
    from statsmodels.robust.scale import mad as sm_mad

    rng = np.random.default_rng(5)
    x = rng.standard_t(3, 2001) * 2.0 + 7.0
    assert mad_sigma(x) == pytest.approx(sm_mad(x), rel=1e-12)   # MAD / Phi^-1(3/4)
    assert abs_dev_percentile(x) == pytest.approx(np.percentile(np.abs(x - np.median(x)), 95),
                                                  rel=1e-12)
    x[::7] = np.nan                                               # NaN = missing, dropped
    p = x[np.isfinite(x)]
    assert mad_sigma(x) == pytest.approx(sm_mad(p), rel=1e-12)
    # the scale is that of a normal sample: 1.4826 * MAD -> sigma (sampling error of the
    # MAD for n = 2e5 is about 1.7 / sqrt(n) relative, 0.4 %; 2 % leaves 5 sigma)
    g = rng.normal(0.0, 3.0, 200_000)
    assert mad_sigma(g) == pytest.approx(3.0, rel=0.02)


def test_one_reacquisition_fix_drives_std_and_phi_and_is_flagged():
    """The issue's case: a slowly wandering receiver (AR(1) phi 0.99) whose first fix is
    309 m off. The fix sets the std and ruins phi; it is the only sample flagged, and the
    statistics without it equal those of the series without it."""
    rng = np.random.default_rng(6)
    n = 1200
    x = np.empty(n)
    x[0] = 0.0
    e = rng.normal(0.0, 3.0 * math.sqrt(1 - 0.99 ** 2), n)
    for k in range(1, n):
        x[k] = 0.99 * x[k - 1] + e[k]
    clean = x.copy()
    x[0] = 309.0
    s = noise_summary(x)
    assert robust_outliers(x)[0] and s.outliers == 1
    assert s.worst_index == 0 and s.worst_abs_dev > 300.0
    assert s.std > 2.0 * s.std_inliers
    assert s.std_inliers == pytest.approx(np.std(clean[1:]), rel=1e-12)
    assert s.ar1_phi_inliers == pytest.approx(ar1_fit(np.r_[np.nan, clean[1:]])[1], rel=1e-12)
    assert s.ar1_phi < 0.8 and s.ar1_phi_inliers > 0.95
    # robust spread barely moves: one sample of 1200 shifts the median by < 1 rank
    assert s.mad_sigma == pytest.approx(mad_sigma(clean), rel=0.02)


def test_outliers_fallback_scale_when_mad_is_zero():
    x = np.zeros(100)
    x[:30] = 0.01                  # quantized: more than half identical -> MAD = 0
    x[50] = 5.0
    flags = robust_outliers(x)
    assert flags[50] and flags.sum() == 1
    assert not robust_outliers(np.full(10, 2.0)).any()   # constant: nothing flagged


def test_gaussian_flags_rarely():
    # P(|M| > 3.5) for a normal sample is 4.7e-4; 1e5 samples -> ~47 expected, 5 sigma ~ 34
    g = np.random.default_rng(7).standard_normal(100_000)
    assert robust_outliers(g).sum() < 47 + 34


def test_tau_from_phi():
    assert tau_from_phi(math.exp(-1.0 / 120.0), 1.0) == pytest.approx(120.0, rel=1e-12)
    assert math.isnan(tau_from_phi(1.0, 1.0)) and math.isnan(tau_from_phi(-0.2, 1.0))
    assert math.isnan(tau_from_phi(math.nan, 1.0))
    with pytest.raises(ValueError, match="dt_s"):
        tau_from_phi(0.5, 0.0)
    with pytest.raises(TypeError, match="phi"):
        tau_from_phi("0.5", 1.0)


# --------------------------------------------------------------------------- extremes
def test_bad_inputs_name_the_argument():
    with pytest.raises(ValueError, match="x"):
        acf(np.array([1.0, np.inf, 2.0]), 1)
    with pytest.raises(ValueError, match="x"):
        mad_sigma(np.array([1e300, 0.0]))
    with pytest.raises(ValueError, match="x"):
        ar1_fit(np.zeros((3, 2)))
    with pytest.raises(TypeError, match="x"):
        npp_r(["a", "b"])
    with pytest.raises(ValueError, match="nlags"):
        acf(np.arange(5.0), 5)
    with pytest.raises(TypeError, match="nlags"):
        acf(np.arange(5.0), 2.0)
    with pytest.raises(ValueError, match="z"):
        robust_outliers(np.arange(5.0), z=math.nan)
    with pytest.raises(ValueError, match="q"):
        abs_dev_percentile(np.arange(5.0), q=101)


def test_empty_and_all_missing_give_nan_not_errors():
    for x in (np.array([]), np.full(5, np.nan)):
        assert np.isnan(acf(x, 0)).all()
        assert math.isnan(mad_sigma(x)) and math.isnan(abs_dev_percentile(x))
        assert math.isnan(npp_r(x)) and math.isnan(ar1_fit(x)[1])
        assert not robust_outliers(x).any()
        s = noise_summary(x)
        assert s.n == 0 and s.outliers == 0 and math.isnan(s.std)


finite = st.floats(-MAX_ABS, MAX_ABS, allow_nan=False, allow_infinity=False)
elements = st.one_of(finite, st.just(np.nan), st.sampled_from([0.0, 1e-300, -1e-300, 1e99, -1e99]))


@settings(max_examples=150, deadline=None)
@given(hnp.arrays(np.float64, st.integers(0, 60), elements=elements))
def test_property_summary_never_raises_and_is_consistent(x):
    """Any series of finite values up to MAX_ABS (and NaN): no exception, no overflow; the
    robust spreads are non-negative and ordered like the definitions say."""
    with np.errstate(over="raise", invalid="raise"):   # an overflow would raise here
        s = noise_summary(x)
        r = acf(x, max(x.size - 1, 0))
    present = np.isfinite(x).sum()
    assert s.n == present
    assert r.shape == (max(x.size - 1, 0) + 1,)
    if present:
        assert s.mad_sigma >= 0 and s.p95 >= 0 and s.worst_abs_dev >= s.p95
        assert 0 <= s.outliers <= present
        assert np.isfinite(s.std)
    ok = np.isfinite(r)
    assert np.all(np.abs(r[ok]) <= 1.0 + 1e-9)    # autocorrelations are bounded by r_0 = 1


@settings(max_examples=50, deadline=None)
@given(st.integers(0, 2000), st.floats(1e-3, 1e6), st.floats(-1e6, 1e6))
def test_property_scale_and_shift_equivariance(seed, scale, shift):
    """mad_sigma and p95 scale with |scale| and ignore a shift; outlier flags and phi are
    invariant (relative tolerance: float rounding of shifted sums, 1e-6)."""
    x = _series(300, seed % 50)
    y = x * scale + shift
    assert mad_sigma(y) == pytest.approx(mad_sigma(x) * scale, rel=1e-6)
    assert abs_dev_percentile(y) == pytest.approx(abs_dev_percentile(x) * scale, rel=1e-6)
    assert np.array_equal(robust_outliers(y), robust_outliers(x)) or \
        abs(robust_outliers(y).sum() - robust_outliers(x).sum()) <= 1   # ties at the cut-off
    assert ar1_fit(y)[1] == pytest.approx(ar1_fit(x)[1], rel=1e-6, abs=1e-9)
