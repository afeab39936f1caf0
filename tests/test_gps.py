"""sim.gps: stationary sessions, the generative error model, replay onto a moving truth."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimator.configuration import SensorConfig
from sim.gps import (
    NOISE_DIR,
    GpsModelError,
    GpsNoiseModel,
    StationarySession,
    gauss_markov,
    markov_dropouts,
    replay,
    synthesize_session,
)
from sim.truth import Truth

CFG = SensorConfig.load("rover_gps8")

# A model with every component switched off; tests switch on one component at a time.
QUIET = GpsNoiseModel(sigma_m=0.0, common_fraction=0.0, receiver_sigma_spread=0.0,
                      white_sigma_m=0.0, gm_order=1,
                      bias_sigma_m=0.0, step_rate_per_h=0.0, step_sigma_m=0.0,
                      outlier_rate=0.0, missing_fraction=0.0, power_failure_duration_s=0.0)


def _lag1(x: np.ndarray) -> np.ndarray:
    """Lag-1 autocorrelation along axis 0 (per column)."""
    x = x - x.mean(axis=0)
    return (x[1:] * x[:-1]).sum(axis=0) / (x * x).sum(axis=0)


# --------------------------------------------------------------------------- model / TOML
@pytest.mark.parametrize("path", sorted(NOISE_DIR.glob("gps*.toml")), ids=lambda p: p.stem)
def test_every_shipped_model_loads_and_synthesizes(path):
    model = GpsNoiseModel.load(path)
    s = synthesize_session(model, CFG, 600.0, np.random.default_rng(0))
    assert s.obs.shape == (600, CFG.m, 2)
    assert model.name == path.stem


def test_default_model_split_and_overrides():
    model = GpsNoiseModel.load()
    assert model.name == "gps_stationary"
    assert model.sigma_common_m**2 + model.sigma_receiver_m**2 == pytest.approx(model.sigma_m**2)
    indep = model.with_overrides(common_fraction=0.0)
    assert indep.sigma_common_m == 0.0 and indep.sigma_receiver_m == pytest.approx(model.sigma_m)
    with pytest.raises(GpsModelError, match="nonsense"):
        model.with_overrides(nonsense=1.0)
    with pytest.raises(GpsModelError, match="common_fraction"):
        model.with_overrides(common_fraction=1.5)
    with pytest.raises(GpsModelError, match="receiver_tau_s"):
        model.with_overrides(receiver_tau_s=0.0)


def test_toml_errors_name_the_field(tmp_path):
    p = tmp_path / "bad.toml"
    p.write_text('sigma_m = 1.0\nsigmaa_m = 2.0\n')
    with pytest.raises(GpsModelError, match="sigmaa_m"):
        GpsNoiseModel.load(p)
    p.write_text('sigma_m = -1.0\n')
    with pytest.raises(GpsModelError, match="sigma_m"):
        GpsNoiseModel.load(p)
    with pytest.raises(GpsModelError, match="no such file"):
        GpsNoiseModel.load("does_not_exist")


def test_model_dead_must_exist_in_config():
    with pytest.raises(ValueError, match="'9'"):
        synthesize_session(QUIET.with_overrides(dead=("9",)), CFG, 10.0, np.random.default_rng(0))


# --------------------------------------------------------------------------- recovery
N_LONG = 200_000  # samples (1 Hz): long enough for the tolerances below, ~0.5 s to generate


def test_gauss_markov_recovers_sigma_and_tau():
    sigma, tau = 1.7, 120.0
    x = gauss_markov(N_LONG, (8, 2), sigma, tau, 1.0, np.random.default_rng(1)).reshape(N_LONG, -1)
    # Sample variance of an AR(1): Var(s^2) ~ 2 sigma^4 / n * (1 + phi^2) / (1 - phi^2)
    # (Box-Jenkins); pooled over 16 independent series. Tolerance: 4 standard errors.
    phi = math.exp(-1.0 / tau)
    rel_var_se = math.sqrt(2.0 / N_LONG * (1 + phi**2) / (1 - phi**2) / 16)
    s_hat = math.sqrt(x.var(axis=0).mean())
    assert abs(s_hat / sigma - 1.0) < 4 * 0.5 * rel_var_se  # d(sigma)/sigma = d(var)/(2 var)
    # Lag-1 estimator: Var(phi_hat) ~ (1 - phi^2) / n; tau = -dt / ln(phi), so
    # se(tau) ~ tau^2 / phi * se(phi). Pooled over 16 series; tolerance 4 standard errors.
    phi_hat = _lag1(x).mean()
    tau_hat = -1.0 / math.log(phi_hat)
    se_tau = tau**2 / phi * math.sqrt((1 - phi**2) / N_LONG / 16)
    assert abs(tau_hat - tau) < 4 * se_tau


def _bartlett_var_r(rho: np.ndarray, h: int, n: int) -> float:
    """Bartlett's large-sample variance of the lag-h sample autocorrelation, from the true
    ACF rho[0..K] (zero beyond K); Box, Jenkins & Reinsel, Time Series Analysis, Eq. 2.1.13."""
    K = len(rho) - 1

    def at(k):
        k = np.abs(k)
        return np.where(k <= K, rho[np.minimum(k, K)], 0.0)

    k = np.arange(-K, K + 1)
    rh = rho[h]
    terms = (at(k + h) ** 2 + at(k - h) * at(k + h) + 2 * rh**2 * at(k) ** 2
             - 4 * rh * at(k) * at(k + h))
    return float(terms.sum() / n)


def _acf2(k: np.ndarray | int, tau: float) -> np.ndarray:
    """ACF of the order-2 (double pole) Gauss-Markov process at 1 Hz."""
    phi = math.exp(-1.0 / tau)
    return phi**k * (1 + k * (1 - phi**2) / (1 + phi**2))


def test_second_order_gauss_markov_recovers_sigma_and_tau():
    from scipy.optimize import brentq

    sigma, tau = 1.3, 30.0
    n, series = N_LONG, 16
    x = gauss_markov(n, (series,), sigma, tau, 1.0, np.random.default_rng(11), order=2)
    rho = _acf2(np.arange(0, int(40 * tau)), tau)
    # variance: Var(s^2) ~ 2 sigma^4 / n * sum_k rho(k)^2 (Bartlett), pooled; 4 se
    rel_var_se = math.sqrt(2.0 / n * (2 * (rho**2).sum() - 1) / series)
    assert abs(math.sqrt(x.var(axis=0).mean()) / sigma - 1.0) < 4 * 0.5 * rel_var_se
    # tau from the autocorrelation at lag L = tau (known zero mean: the generator's), solved
    # from the closed-form ACF; se by Bartlett and the delta method; 4 se. (Lag 1 is a poor
    # choice: tau ~ (1 - r1)^(-1/2) magnifies the O(1/n) bias of r1.)
    L = int(tau)
    rL = ((x[L:] * x[:-L]).sum(axis=0) / (x * x).sum(axis=0)).mean()
    tau_hat = brentq(lambda tt: _acf2(L, tt) - rL, 1.0, 1000.0)
    h = 1e-4
    drho_dtau = (_acf2(L, tau + h) - _acf2(L, tau - h)) / (2 * h)
    se_tau = math.sqrt(_bartlett_var_r(rho, L, n) / series) / abs(drho_dtau)
    assert abs(tau_hat - tau) < 4 * se_tau
    # smooth paths: steps far below the order-1 process with the same sigma and tau
    x1 = gauss_markov(n, (series,), sigma, tau, 1.0, np.random.default_rng(12), order=1)
    assert np.diff(x, axis=0).std() < 0.2 * np.diff(x1, axis=0).std()


def test_session_recovers_common_and_receiver_split():
    model = QUIET.with_overrides(sigma_m=2.0, common_fraction=0.5, common_tau_s=60.0,
                                 receiver_tau_s=30.0)
    s = synthesize_session(model, CFG, N_LONG, np.random.default_rng(2))
    e = s.errors()
    alive = [j for j, n in enumerate(s.names) if n not in CFG.dead]
    e = e[:, alive]                                       # (n, 7, 2), no NaN (no dropouts)
    assert not np.isnan(e).any()
    c = e - e.mean(axis=0)
    m = len(alive)
    cov = np.einsum("nia,nja->ija", c, c) / len(c)        # (m, m, 2) cross-covariances
    off = ~np.eye(m, dtype=bool)
    common_var = cov[off].mean()                          # = sigma_common^2
    total_var = np.einsum("iia->ia", cov).mean()          # = sigma_common^2 + sigma_receiver^2
    # se of the common variance ~ that of one AR(1) series' variance (tau 60 s), two axes:
    phi_c = math.exp(-1.0 / 60.0)
    se_c = model.sigma_common_m**2 * math.sqrt(2.0 / N_LONG * (1 + phi_c**2) / (1 - phi_c**2) / 2)
    assert abs(common_var - model.sigma_common_m**2) < 4 * se_c
    assert abs(total_var - model.sigma_m**2) < 4 * 2 * se_c  # dominated by the common part
    # correlation time of the common part from the mean over receivers (independent parts
    # average down by 1/m): lag-1 of the receiver-mean, corrected for the independent share
    assert model.sigma_receiver_m == pytest.approx(math.sqrt(2.0))


def test_dropouts_fraction_and_burst_length():
    f, burst, n, m = 0.1, 5.0, N_LONG, 8
    miss = markov_dropouts(n, m, f, burst, np.random.default_rng(3))
    # Markov-chain fraction: Var ~ f(1-f)/n * (1+lam)/(1-lam), lam = 1 - p - q; 4 se.
    q = 1 / burst
    p = q * f / (1 - f)
    lam = 1 - p - q
    se_f = math.sqrt(f * (1 - f) / (n * m) * (1 + lam) / (1 - lam))
    assert abs(miss.mean() - f) < 4 * se_f
    # burst lengths: geometric with mean 1/q, sd sqrt(1-q)/q; 4 se of the mean
    padded = np.vstack([np.zeros((1, m), bool), miss, np.zeros((1, m), bool)]).astype(np.int8)
    d = np.diff(padded, axis=0)
    lengths = np.flatnonzero(d.T.ravel() == -1) - np.flatnonzero(d.T.ravel() == 1)
    se_b = math.sqrt(1 - q) / q / math.sqrt(lengths.size)
    assert abs(lengths.mean() - burst) < 4 * se_b


def test_outlier_rate_and_plateau_transitions():
    model = QUIET.with_overrides(outlier_rate=0.01, outlier_scale_m=3.0)
    s = synthesize_session(model, CFG, 50_000.0, np.random.default_rng(4))
    e = s.errors()[:, CFG.alive_mask]
    hits = (np.abs(e[..., 0]) > 0).mean()
    se = math.sqrt(0.01 * 0.99 / e[..., 0].size)              # binomial
    assert abs(hits - 0.01) < 4 * se
    model = QUIET.with_overrides(step_rate_per_h=6.0, step_sigma_m=1.0, step_ramp_s=10.0)
    dur = 200 * 3600.0 / 6.0                                  # ~200 transitions per receiver
    s = synthesize_session(model, CFG, dur, np.random.default_rng(5))
    k = np.array(s.meta["drawn"]["plateau_transitions"])
    expected = 6.0 * dur / 3600.0 * CFG.m
    assert abs(k.sum() - expected) < 4 * math.sqrt(expected)  # Poisson
    # plateau levels are redrawn (stationary): per-axis std close to step_sigma_m; each
    # receiver has ~200 nearly independent levels -> se of the pooled std ~ 1/sqrt(2*2*8*200)
    e = s.errors()[:, CFG.alive_mask]
    assert abs(e.std() - 1.0) < 4 * math.sqrt(1 / (2 * 2 * 7 * 200)) + 0.02


def test_dead_receivers_power_failure_and_missing_as_configured():
    model = GpsNoiseModel.load().with_overrides(dead=("1",), power_failure_start_s=100.0,
                                                power_failure_duration_s=50.0)
    s = synthesize_session(model, CFG, 4000.0, np.random.default_rng(6))
    present = s.present
    assert set(s.dead) == {"1", "4"}                          # model's + configuration's dead
    pf = (s.t >= 100.0) & (s.t < 150.0)
    assert not present[pf].any()
    alive = [s.names.index(n) for n in s.names if n not in ("1", "4")]
    frac = 1.0 - present[~pf][:, alive].mean()
    assert 0.01 < frac < 0.06                                 # configured 0.03, bursty
    after = s.after_power_failure()
    assert after.t[0] == 150.0 and after.n == 4000 - 150


def test_save_load_roundtrip_and_seed_determinism(tmp_path):
    model = GpsNoiseModel.load()
    a = synthesize_session(model, CFG, 500.0, np.random.default_rng(7))
    b = synthesize_session(model, CFG, 500.0, np.random.default_rng(7))
    c = synthesize_session(model, CFG, 500.0, np.random.default_rng(8))
    assert np.array_equal(a.obs, b.obs, equal_nan=True)
    assert not np.array_equal(a.obs, c.obs, equal_nan=True)
    path = a.save(tmp_path / "s.npz")
    r = StationarySession.load(path)
    assert np.array_equal(r.obs, a.obs, equal_nan=True) and np.array_equal(r.t, a.t)
    assert r.names == a.names and np.array_equal(r.truth_positions, a.truth_positions)
    assert r.meta["drawn"] == a.meta["drawn"]


def test_session_validation_names_fields():
    with pytest.raises(ValueError, match="obs"):
        StationarySession(np.arange(3.0), np.zeros((3, 2, 3)), ("a", "b"))
    with pytest.raises(ValueError, match="names"):
        StationarySession(np.arange(3.0), np.zeros((3, 2, 2)), ("a", "a"))
    with pytest.raises(ValueError, match="t"):
        StationarySession(np.array([0.0, 0.0, 1.0]), np.zeros((3, 2, 2)), ("a", "b"))
    half = np.zeros((3, 2, 2))
    half[1, 1, 0] = np.nan
    with pytest.raises(ValueError, match="receiver 'b'"):
        StationarySession(np.arange(3.0), half, ("a", "b"))


# --------------------------------------------------------------------------- replay
def _truth(n: int, names=CFG.names, dt: float = 1.0) -> Truth:
    """A platform driving east at 1 m/s with the rover_gps8 layout (z = 0.6 m)."""
    t = np.arange(n) * dt
    cg = np.stack([t * 1.0, np.zeros(n), np.full(n, 0.6)], axis=1)
    body = np.zeros((len(names), 3))
    body[:, :2] = CFG.body_positions[: len(names)]
    sp = cg[:, None, :] + body[None]
    return Truth(t=t, sensor_positions=sp, sensor_names=tuple(names), cg=cg, yaw=np.zeros(n),
                 speed=np.ones(n), yaw_rate=np.zeros(n), turning=np.zeros(n, bool))


def _session(n: int, rng_seed: int = 0, model: GpsNoiseModel | None = None) -> StationarySession:
    return synthesize_session(model or GpsNoiseModel.load(), CFG, float(n),
                              np.random.default_rng(rng_seed))


def test_replay_errors_zero_mean_and_missing_preserved():
    s = _session(1000)
    truth = _truth(1000)
    obs = replay(truth, s)
    err = obs - truth.sensor_positions[..., :2]
    assert np.array_equal(np.isnan(obs), np.isnan(s.obs))     # missing and dead preserved
    mean = np.nanmean(err[:, CFG.alive_mask], axis=0)
    assert np.abs(mean).max() < 1e-12                          # zero-mean over the session
    # the replayed error is the session's deviation from each receiver's mean
    alive = CFG.alive_mask
    dev = s.obs[:, alive] - np.nanmean(s.obs[:, alive], axis=0)
    assert np.allclose(err[:, alive], dev, equal_nan=True, atol=1e-12)
    assert np.isnan(obs[:, CFG.index("4")]).all()


def test_replay_zero_error_session_returns_truth_exactly():
    n = 300
    # constant observations at UTM-sized coordinates: the deviation must be exactly zero
    const = np.array([[512345.678 + j, 4412345.321 - j] for j in range(CFG.m)])
    obs = np.broadcast_to(const, (n, CFG.m, 2)).copy()
    obs[10:20, 2] = np.nan
    s = StationarySession(np.arange(n, dtype=float), obs, CFG.names)
    truth = _truth(n)
    out = replay(truth, s)
    ok = ~np.isnan(out)
    assert np.array_equal(out[ok], truth.sensor_positions[..., :2][ok])
    assert np.isnan(out[10:20, 2]).all()


def test_replay_length_modes_and_determinism():
    s = _session(200)
    truth = _truth(500)
    with pytest.raises(ValueError, match="mode='error'"):
        replay(truth, s)
    w = replay(truth, s, mode="wrap")
    assert np.array_equal(w[200:400], w[0:200], equal_nan=True) is False  # truth moved
    e = w - truth.sensor_positions[..., :2]
    # error repeats (equal up to rounding of truth + error - truth at ~500 m)
    assert np.allclose(e[0:200], e[200:400], equal_nan=True, rtol=0, atol=1e-12)
    a = replay(truth, s, mode="random_offset", rng=np.random.default_rng(3))
    b = replay(truth, s, mode="random_offset", rng=np.random.default_rng(3))
    assert np.array_equal(a, b, equal_nan=True)
    with pytest.raises(ValueError, match="rng"):
        replay(truth, s, mode="random_offset")
    short = _truth(50)
    off = replay(short, s, start=30)
    assert np.allclose(off - short.sensor_positions[..., :2],
                       replay(_truth(80), s)[30:80] - _truth(80).sensor_positions[30:80, :, :2],
                       equal_nan=True, rtol=0, atol=1e-12)


def test_replay_name_and_order_matching():
    s = _session(100)
    # by name: truth sensors in a different order get their own receivers
    names = tuple(reversed(CFG.names))
    truth = Truth(t=np.arange(100.0), sensor_positions=np.zeros((100, CFG.m, 3)),
                  sensor_names=names, cg=np.zeros((100, 3)), yaw=np.zeros(100),
                  speed=np.zeros(100), yaw_rate=np.zeros(100), turning=np.zeros(100, bool))
    out = replay(truth, s)
    ref = replay(_truth_zero(100, CFG.names), s)
    assert np.array_equal(out, ref[:, ::-1], equal_nan=True)
    # partly shared names: error naming the missing one
    bad = names[:-1] + ("zz",)
    with pytest.raises(ValueError, match="zz"):
        replay(_truth_zero(100, bad), s)
    # no shared names: by order
    other = tuple(f"ant{j}" for j in range(CFG.m))
    assert np.array_equal(replay(_truth_zero(100, other), s), ref, equal_nan=True)


def _truth_zero(n: int, names) -> Truth:
    m = len(names)
    return Truth(t=np.arange(float(n)), sensor_positions=np.zeros((n, m, 3)), sensor_names=names,
                 cg=np.zeros((n, 3)), yaw=np.zeros(n), speed=np.zeros(n), yaw_rate=np.zeros(n),
                 turning=np.zeros(n, bool))


def test_replay_rejects_rate_mismatch():
    s = _session(100)
    with pytest.raises(ValueError, match="sample interval"):
        replay(_truth(50, dt=0.1), s)
    replay(_truth(50, dt=0.1), s, check_rate=False)


@settings(max_examples=25, deadline=None)
@given(offset=st.tuples(st.floats(-1e6, 1e6), st.floats(-1e6, 1e6)),
       seed=st.integers(0, 2**31 - 1))
def test_replay_ignores_receiver_offsets(offset, seed):
    """Invariant: adding a constant to a receiver's whole session changes nothing (Section
    4.1.2 uses deviations from the mean); tolerance: float rounding at |offset| <= 1e6 m."""
    s = _session(120, rng_seed=seed % 1000)
    obs = s.obs.copy()
    obs[:, 0] += np.array(offset)
    s2 = StationarySession(s.t, obs, s.names)
    truth = _truth(120)
    a, b = replay(truth, s), replay(truth, s2)
    assert np.allclose(a, b, equal_nan=True, atol=1e-9 * (1 + max(map(abs, offset))))


def test_observe_is_the_sweeps_composition_and_noise_free_is_truth():
    """sim.gps.observe = synthesize (session_s + power failure) -> cut -> random stretch ->
    replay; the same Generator state gives the same array, noise-free gives the truth."""
    from estimator.configuration import SensorConfig
    from sim.gps import GpsNoiseModel, observe, replay, synthesize_session
    from sim.truth import Truth

    cfg = SensorConfig.load("rover_gps8").planar()
    n = 50
    t = np.arange(n, dtype=float)
    pos = np.zeros((n, cfg.m, 3))
    pos[:, :, :2] = cfg.body_positions[None, :, :2] + np.c_[0.2 * t, 0 * t][:, None, :]
    truth = Truth(t=t, sensor_positions=pos, sensor_names=cfg.names,
                  cg=pos[:, :3].mean(axis=1), yaw=np.zeros(n), turning=np.zeros(n, bool),
                  speed=np.full(n, 0.2), yaw_rate=np.zeros(n), meta={})
    clean = observe(truth, cfg, None)
    assert not clean.flags.writeable
    alive = cfg.alive_mask
    assert np.array_equal(clean[:, alive], pos[:, alive, :2])
    assert np.isnan(clean[:, ~alive]).all()
    model = GpsNoiseModel.load("gps_stationary")
    a = observe(truth, cfg, model, rng=np.random.default_rng(5), session_s=600.0)
    rng = np.random.default_rng(5)
    lost = model.power_failure_start_s + model.power_failure_duration_s
    session = synthesize_session(model, cfg, 600.0 + lost, rng).after_power_failure()
    start = int(rng.integers(0, session.n - n + 1))
    b = replay(truth, session, start=start, mode="error")
    assert np.array_equal(a, b, equal_nan=True)
    with pytest.raises(ValueError, match="rng"):
        observe(truth, cfg, model)


# --------------------------------------------------------------------------- one receiver, m
# antennas
def _one_receiver(n: int, seed: int = 0, tau_s: float = 10.0, sigma: float = 1.0,
                  missing: tuple[int, int] | None = None) -> StationarySession:
    """One receiver: an AR(1) error of std ``sigma`` and correlation time ``tau_s`` at a
    UTM-sized position (the replay must use only its deviation from the mean)."""
    rng = np.random.default_rng(seed)
    err = gauss_markov(n, (2,), sigma, tau_s, 1.0, rng, order=1)
    obs = (np.array([512000.0, 4400000.0]) + err)[:, None, :]
    if missing:
        obs[missing[0]:missing[1]] = np.nan
    return StationarySession(np.arange(n, dtype=float), obs, ("rx",))


def _heading_error(truth: Truth, obs: np.ndarray) -> np.ndarray:
    from estimator.window import procrustes_batch

    cfg = CFG.planar()
    present = ~np.isnan(obs[..., 0]) & cfg.alive_mask[None]
    bf = procrustes_batch(np.where(present[..., None], obs, 0.0), present.astype(float), cfg)
    return np.abs(np.angle(np.exp(1j * (bf.yaw - truth.yaw))))


def test_one_receiver_by_receiver_names_the_modes():
    from sim.gps import observe

    with pytest.raises(ValueError, match=r"1 receiver\(s\) for 8 antennas.*shifted.*"
                                         r"common_plus_model.*identical"):
        observe(_truth(100), CFG, _one_receiver(300), rng=np.random.default_rng(0))


def test_identical_mode_is_common_mode_only_and_heading_exact():
    """Every antenna carries the same error at the same time: a translation, so the rigid
    fit's heading equals the truth to round-off (1e-9 rad at 1e6 m coordinates)."""
    from sim.gps import replay_one

    truth, s = _truth(200), _one_receiver(500, missing=(100, 110))
    obs, info = replay_one(truth, s, mode="identical", rng=np.random.default_rng(1), config=CFG)
    assert info["pair_correlation"] == pytest.approx(1.0)
    err = obs - truth.sensor_positions[..., :2]
    alive = CFG.alive_mask
    assert np.allclose(err[:, alive], err[:, alive][:, :1], equal_nan=True, atol=1e-9)
    assert np.isnan(obs[:, ~alive]).all()
    dev = s.obs[:, 0] - np.nanmean(s.obs[:, 0], axis=0)
    assert np.allclose(err[:, 0], dev[info["start"]:info["start"] + 200], equal_nan=True,
                       atol=1e-6)
    he = _heading_error(truth, obs)
    assert np.nanmax(he) < 1e-9


def test_shifted_mode_reads_the_log_at_lags_and_decorrelates():
    """Antenna j gets the log at circular lag j L; with L >> tau the antennas' errors are
    uncorrelated (sample correlation over 2000 samples: |r| < 0.1, about 4.5 sigma for
    independent AR(1) series with tau 10 s, effective n ~ 100), and so is the reported mean
    pair correlation; a short lag keeps them correlated (AR(1): exp(-L / tau))."""
    from sim.gps import replay_one

    n, ns = 2000, 16000
    truth, s = _truth(n), _one_receiver(ns, tau_s=10.0)
    obs, info = replay_one(truth, s, mode="shifted", rng=np.random.default_rng(2))
    L = ns // CFG.m
    assert info["lag_samples"] == L and info["lag_s"] == pytest.approx(L)
    dev = s.obs[:, 0] - s.obs[:, 0].mean(axis=0)
    err = obs - truth.sensor_positions[..., :2]
    for j in range(CFG.m):
        rows = (info["start"] + j * L + np.arange(n)) % ns
        assert np.allclose(err[:, j], dev[rows], atol=1e-6)
    r = np.corrcoef(err[:, 0, 0], err[:, 1, 0])[0, 1]
    assert abs(r) < 0.1
    assert abs(info["pair_correlation"]) < 0.1
    # the heading is no longer exact: independent 1 m errors on a 1.5 m platform
    assert np.median(_heading_error(truth, obs)) > 0.1
    # a short lag keeps the errors correlated, and the report says so
    _, info2 = replay_one(truth, s, mode="shifted", shift_s=1.0, rng=np.random.default_rng(2))
    # pairs at lags 1..7 s: mean of exp(-k / 10) over the 28 pairs' lags = 0.80
    lags = [j - i for i in range(8) for j in range(i + 1, 8)]
    expect = float(np.mean(np.exp(-np.array(lags) / 10.0)))
    assert info2["pair_correlation"] == pytest.approx(expect, abs=0.08)
    with pytest.raises(ValueError, match="shift_s"):
        replay_one(truth, s, mode="shifted", shift_s=ns, rng=np.random.default_rng(2))
    with pytest.raises(ValueError, match="cannot cover"):
        replay_one(_truth(ns + 1), s, mode="shifted", rng=np.random.default_rng(2))


def test_shifted_mode_reports_anticorrelation_of_a_short_session():
    """The documented limit of "shifted": a session only two correlation times long (400 s,
    tau 200 s) cannot give 8 independent segments; its deviation is zero-mean over the
    session, so the phases are anti-correlated (for n = n_session the mean pair correlation
    tends to -1/(m - 1) = -0.14 as tau grows). The report shows it: < -0.05 in each of these
    seeds (-0.10 to -0.13 measured)."""
    from sim.gps import replay_one

    for seed in range(5):
        s = _one_receiver(400, seed=seed, tau_s=200.0)
        _, info = replay_one(_truth(400), s, mode="shifted", rng=np.random.default_rng(seed))
        assert info["pair_correlation"] < -0.05


def test_common_plus_model_adds_only_the_models_per_receiver_part():
    """Differences between antennas come from the model's per-receiver part alone: with a
    model whose per-receiver part is zero the mode equals 'identical' exactly; with
    gps_stationary the antenna-to-antenna spread matches its per-receiver Gauss-Markov
    std sigma sqrt(1 - common_fraction) (plus biases and plateaus)."""
    from sim.gps import replay_one

    truth, s = _truth(300), _one_receiver(600)
    a, ia = replay_one(truth, s, mode="common_plus_model", model=QUIET,
                       rng=np.random.default_rng(3))
    b, _ = replay_one(truth, s, mode="identical", start=ia["start"],
                      rng=np.random.default_rng(3))
    assert np.array_equal(a, b, equal_nan=True)
    model = GpsNoiseModel.load("gps_stationary").with_overrides(missing_fraction=0.0)
    c, ic = replay_one(truth, s, mode="common_plus_model", model=model,
                       rng=np.random.default_rng(4))
    err = c - truth.sensor_positions[..., :2]
    dev = s.obs[:, 0] - s.obs[:, 0].mean(axis=0)
    common = dev[ic["start"]:ic["start"] + 300]
    per = err - common[:, None, :]
    # per-receiver part: GM std 2 sqrt(0.5) = 1.41 m, times a lognormal scale, + 0.5 m bias
    # + 0.5 m plateaus per axis: its spread over 8 receivers lies within [0.5, 5] m
    spread = np.std(per, axis=(0, 1)).mean()
    assert 0.5 < spread < 5.0
    with pytest.raises(ValueError, match="model"):
        replay_one(truth, s, mode="common_plus_model", rng=np.random.default_rng(4))


def test_observe_passes_replay_modes_and_validates_them():
    from sim.gps import observe, replay_one

    truth, s = _truth(100), _one_receiver(400)
    a = observe(truth, CFG, s, rng=np.random.default_rng(7), noise_overrides={"replay": "shifted"})
    b, _ = replay_one(truth, s, mode="shifted", rng=np.random.default_rng(7), config=CFG)
    assert np.array_equal(a, b, equal_nan=True) and not a.flags.writeable
    c = observe(truth, CFG, s, rng=np.random.default_rng(7),
                noise_overrides={"replay": "common_plus_model", "model": "gps_stationary",
                                 "common_fraction": 0.9})
    assert c.shape == (100, CFG.m, 2)
    for bad, match in [({"replay": "mirror"}, "unknown mode"),
                       ({"replay": "shifted", "sigma_m": 1.0}, "do not apply"),
                       ({"replay": "by_receiver", "shift_s": 3.0}, "do not apply"),
                       ({"replay": "identical", "common_fraction": 0.5}, "do not apply")]:
        with pytest.raises(ValueError, match=match):
            observe(truth, CFG, s, rng=np.random.default_rng(7), noise_overrides=bad)


@settings(max_examples=40, deadline=None)
@given(mode=st.sampled_from(["identical", "shifted", "common_plus_model"]),
       shift=st.one_of(st.none(),
                       st.sampled_from([math.nan, math.inf, -1.0, 0.0, 1e300, 1.0, 5.0])),
       start=st.one_of(st.none(), st.integers(-5, 500)),
       receiver=st.sampled_from([None, "rx", "other"]))
def test_replay_one_extremes_raise_or_return_finite(mode, shift, start, receiver):
    """Any argument combination either raises ValueError/TypeError naming an argument or
    returns finite observations where the log has data."""
    from sim.gps import replay_one

    truth, s = _truth(50), _one_receiver(200)
    try:
        obs, _ = replay_one(truth, s, mode=mode, shift_s=shift, start=start,
                               receiver=receiver,
                               model=QUIET if mode == "common_plus_model" else None,
                               rng=np.random.default_rng(0))
    except (ValueError, TypeError) as exc:
        assert any(k in str(exc) for k in ("shift_s", "start", "receiver", "mode", "session"))
        return
    assert obs.shape == (50, CFG.m, 2)
    assert np.isfinite(obs).all()


@pytest.mark.parametrize("engine", ["numba", "numpy"])
@pytest.mark.parametrize("trial", range(6))
def test_first_order_filter_is_lfilter_bit_for_bit(trial, engine):
    """The recursion replaces scipy.signal.lfilter in gauss_markov (to keep scipy.signal out of
    the sweep workers) and must give the same numbers, not merely close ones: the committed
    references were made with lfilter. Both engines: the compiled loop (sim.kernels) and the
    numpy reference."""
    from scipy.signal import lfilter

    from sim.gps import first_order_filter

    rng = np.random.default_rng(100 + trial)
    n, series = int(rng.integers(1, 3000)), int(rng.integers(1, 20))
    phi = math.exp(-rng.uniform(1e-3, 3.0))
    x = rng.standard_normal((n, series, 2)) * 10.0 ** rng.uniform(-3, 3)
    for gain in (1.0, float(rng.uniform(0.01, 2.0))):
        want = lfilter([gain], [1.0, -phi], x, axis=0)
        assert np.array_equal(first_order_filter(x, gain, phi, engine=engine), want)
    assert first_order_filter(np.zeros((0, 3)), 1.0, 0.5, engine=engine).shape == (0, 3)
    with pytest.raises(ValueError, match="engine"):
        first_order_filter(x, 1.0, phi, engine="fortran")
