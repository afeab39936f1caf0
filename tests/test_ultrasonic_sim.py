"""Ultrasonic range model (sim.ultrasonic): layouts, validation, fault rates, determinism."""

import numpy as np
import pytest

from sim.ultrasonic import (
    CLEAN,
    DROPOUT,
    HELD,
    SPIKE,
    UltrasonicNoiseModel,
    load_receivers,
    sample_times,
    simulate_ranges,
    true_ranges,
)


def test_layouts_in_metres_and_centred():
    names, mc = load_receivers("montecarlo")
    assert names == ("R40", "R41", "R42", "R43", "R44", "R45")
    # Appendix B: Rx44 = [0, 0, 0] mm translated by T_RCM = [-650, -375.278, 0] mm
    np.testing.assert_allclose(mc[4], [-0.65, -0.375278, 0.0])
    _, raw = load_receivers("montecarlo", translate=False)
    np.testing.assert_allclose(raw[5], [1.3, 0.0, 0.0])
    _, fl = load_receivers("flight", translate=False)
    np.testing.assert_allclose(fl[1], [0.9873615, 0.54026, 0.022])   # Appendix C Rx41
    _, flc = load_receivers("flight")
    np.testing.assert_allclose(np.ptp(flc[:, :2], axis=0) / 2 + flc[:, :2].min(axis=0), 0,
                               atol=1e-12)


def test_model_validation_names_field(tmp_path):
    with pytest.raises(ValueError, match="spike_rate"):
        UltrasonicNoiseModel(spike_rate=1.5)
    with pytest.raises(ValueError, match="spike_max_m"):
        UltrasonicNoiseModel(spike_min_m=2.0, spike_max_m=1.0)
    with pytest.raises(ValueError, match="dropout_mean_length"):
        UltrasonicNoiseModel(dropout_mean_length=0.5)
    p = tmp_path / "bad.toml"
    p.write_text('sigma_m = 0.005\nspike_size = 3\n')
    with pytest.raises(ValueError, match="spike_size"):
        UltrasonicNoiseModel.load(p)
    assert UltrasonicNoiseModel.load("ultrasonic").sigma_m == 0.005


def _long_run(model, n=40000, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.05
    tx = np.zeros((n, 2, 3))
    tx[:, :, 2] = 3.0
    tx[:, 1, 0] = 0.5
    _, rec = load_receivers("flight")
    r, codes = simulate_ranges(t, tx, rec, model, rng, return_faults=True)
    return r, codes, true_ranges(tx, rec)


def test_fault_rates_match_configuration():
    model = UltrasonicNoiseModel.load().replace(dropout_mean_length=1.0)
    r, codes, truth = _long_run(model)
    N = codes.size                                   # 480k independent Bernoulli trials
    z = 5.0                                          # 5 sigma binomial band: false-fail ~1e-6

    def within(k, n, p):
        return abs(k - n * p) <= z * np.sqrt(n * p * (1 - p))

    dropped = codes == DROPOUT
    assert within(dropped.sum(), N, model.dropout_rate)
    held = codes == HELD
    assert within(held.sum(), (~dropped).sum(), model.hold_rate)
    fresh = ~dropped & ~held
    assert within((codes == SPIKE).sum(), fresh.sum(), model.spike_rate)
    # the codes describe the data
    assert np.isnan(r[dropped]).all() and not np.isnan(r[~dropped]).any()
    err = r - truth
    assert np.all(np.abs(err[codes == CLEAN]) <= model.max_error_m)
    # a Gaussian truncated at +/-3 sigma has std 0.9866 sigma; 2 % covers sampling error
    assert np.std(err[codes == CLEAN]) == pytest.approx(model.sigma_m * 0.9866, rel=0.02)
    sp = np.abs(err[codes == SPIKE])
    assert sp.min() >= model.spike_min_m - model.max_error_m
    assert sp.max() <= model.spike_max_m + model.max_error_m


def test_dropout_bursts_rate_and_length():
    model = UltrasonicNoiseModel.load().replace(dropout_rate=0.05, dropout_mean_length=4.0)
    _, codes, _ = _long_run(model, n=40000, seed=1)
    d = (codes == DROPOUT).reshape(codes.shape[0], -1)
    # Markov chain: correlated samples inflate the variance of the fraction by
    # (1 + rho) / (1 - rho), rho = 1 - p_in - p_out; 5 sigma band.
    rho = 1 - model.dropout_enter_prob - model.dropout_exit_prob
    n = d.size
    sd = np.sqrt(model.dropout_rate * (1 - model.dropout_rate) / n * (1 + rho) / (1 - rho))
    assert abs(d.mean() - model.dropout_rate) <= 5 * sd
    # mean burst length = 1 / p_exit
    starts = (d[1:] & ~d[:-1]).sum()
    ends = (~d[1:] & d[:-1]).sum()
    mean_len = d[1:].sum() / ((starts + ends) / 2)
    assert mean_len == pytest.approx(model.dropout_mean_length, rel=0.05)


def test_held_values_repeat_last_fresh_and_seed_reproduces():
    model = UltrasonicNoiseModel.load()
    r, codes, _ = _long_run(model, n=3000, seed=7)
    flat_r, flat_c = r.reshape(3000, -1), codes.reshape(3000, -1)
    for j in range(flat_r.shape[1]):
        last = None
        for i in range(3000):
            if flat_c[i, j] == HELD:
                assert flat_r[i, j] == last
            elif flat_c[i, j] != DROPOUT:
                last = flat_r[i, j]
    r2, codes2, _ = _long_run(model, n=3000, seed=7)
    np.testing.assert_array_equal(r, r2)
    np.testing.assert_array_equal(codes, codes2)


def test_sample_times_uneven_within_bounds():
    model = UltrasonicNoiseModel.load()
    t = sample_times(60.0, model, np.random.default_rng(0))
    dt = np.diff(t)
    assert dt.min() >= model.min_interval_s and dt.max() <= model.max_interval_s
    assert t[0] == 0.0 and t[-1] <= 60.0 and t[-1] > 60.0 - model.max_interval_s


def test_simulate_validates():
    model = UltrasonicNoiseModel.load()
    rng = np.random.default_rng(0)
    _, rec = load_receivers("flight")
    with pytest.raises(ValueError, match="tx_positions"):
        simulate_ranges(np.arange(3.0), np.zeros((3, 2)), rec, model, rng)
    with pytest.raises(ValueError, match="rng"):
        simulate_ranges(np.arange(3.0), np.zeros((3, 2, 3)), rec, model, 0)
    with pytest.raises(ValueError, match="t:"):
        simulate_ranges(np.zeros(3), np.zeros((3, 2, 3)), rec, model, rng)


@pytest.mark.parametrize("field, value, exc", [
    ("sigma_m", True, TypeError),            # a bool is not a number (one rule, _checks)
    ("spike_rate", "0.1", TypeError),
    ("hold_rate", None, TypeError),
    ("min_interval_s", 0.0, ValueError),
    ("max_interval_s", float("inf"), ValueError),
    ("dropout_rate", float("nan"), ValueError),
    ("hold_rate", 1.0, ValueError),
])
def test_every_numeric_field_is_checked_one_way(field, value, exc):
    with pytest.raises(exc, match=field):
        UltrasonicNoiseModel(**{field: value})
    # and a valid number comes back as a float
    assert isinstance(UltrasonicNoiseModel(spike_rate=0).spike_rate, float)
