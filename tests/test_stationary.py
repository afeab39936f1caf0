"""experiments.stationary: ACF / AR(1) against statsmodels, exact recovery on noise-free
sessions, and an end-to-end run of the CLI on a short synthetic session."""

from __future__ import annotations

import json

import numpy as np
import pytest

from estimator.configuration import SensorConfig
from experiments.stationary import acf, ar1_fit, main, npp_r, weighting_estimates, window_spreads
from sim.gps import GpsNoiseModel, gauss_markov, synthesize_session

CFG = SensorConfig.load("rover_gps8")


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


QUIET = GpsNoiseModel(sigma_m=0.0, common_fraction=0.0, receiver_sigma_spread=0.0,
                      white_sigma_m=0.0, bias_sigma_m=0.0, step_rate_per_h=0.0,
                      step_sigma_m=0.0, outlier_rate=0.0, missing_fraction=0.2,
                      mean_burst_s=3.0, power_failure_duration_s=0.0)


def test_noise_free_session_recovers_truth_exactly():
    """Invariant: without error every scheme and window returns the true layout (missing
    samples only remove data). Tolerance: SLSQP stops within its 1e-9 tolerances; the
    eps = 0.01 m slack cannot pull an exact fit away from zero residual."""
    s = synthesize_session(QUIET, CFG, 300.0, np.random.default_rng(5),
                           position=(100.0, -50.0), yaw=0.7)
    for e in weighting_estimates(s, CFG, np.random.default_rng(6)):
        assert e.pos_rmse_m < 1e-6, e
        assert e.yaw_err_deg < 1e-4, e
    tab, _ = window_spreads(s, CFG, sizes=(1, 3), schemes=("none", "huff"))
    assert (tab["rmse_m"] < 1e-9).all() and (tab["spread_m"] < 1e-9).all()


def test_split_sensitivity_heading_improves_with_common_share():
    """With all error common-mode the layout is seen exactly (heading error 0 up to the white
    jitter and outliers); with none, heading is much worse (notes: 60-70 deg RMS)."""
    from experiments.stationary import split_sensitivity

    model = GpsNoiseModel.load().with_overrides(white_sigma_m=0.0, outlier_rate=0.0,
                                                step_sigma_m=0.0, bias_sigma_m=0.0,
                                                missing_fraction=0.0)
    tab = split_sensitivity(model, CFG, 1000.0, 3, fractions=(0.0, 1.0), windows=(1,))
    yaw = dict(zip(tab.common_fraction, tab.yaw_rmse_deg))
    assert yaw[1.0] < 1e-6          # identical errors on every antenna: exact heading
    assert yaw[0.0] > 20.0


def test_cli_end_to_end(tmp_path):
    out = tmp_path / "st"
    assert main(["--synthetic", "--duration", "400", "--seed", "1", "--out", str(out),
                 "--no-split"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["n"] == 400 - 300             # everything up to the power failure's end (300 s) discarded
    assert {r["scheme"] for r in summary["weighting"]} >= {"none", "huber", "huff", "random"}
    for name in ("fig4_02_xy_vs_time.png", "fig4_03_scatter.png", "fig4_04_06_pairwise_distances.png",
                 "fig4_07_npp_x.png", "fig4_17_23_weighting.png", "fig4_25_33_windows.png"):
        assert (out / name).stat().st_size > 1000
    text = (out / "summary.md").read_text()
    assert "Sliding windows" in text and "Pairwise distances" in text


def test_cli_on_a_real_log(tmp_path, realdata_dir):
    """A real receiver without a known layout: per-sensor sections only, no fits."""
    log = realdata_dir / "hazer/tumbleweed/HOME/20200526/benchmark.csv"
    out = tmp_path / "real"
    assert main(["--session", str(log), "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["weighting"] is None and summary["windows"] is None
    assert summary["meta"]["source"] == "tumbleweed_csv"
    sensors = [r for r in summary["sensors"] if r.get("axis") == "x"]
    assert len(sensors) == 1 and 0.05 < sensors[0]["std_m"] < 5.0
    assert (out / "fig4_09_timeseries_sensorbenchmark.png").stat().st_size > 1000
