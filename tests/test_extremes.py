"""Extreme inputs through the public functions not covered by a module's own property tests
(issue 13): every call returns a documented result (NaN where undefined) or raises
ValueError/TypeError naming the argument; nothing else escapes, memory stays bounded."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from estimator import lag, metrics, orientation, turns
from estimator.configuration import SensorConfig

EXTREME = st.sampled_from([np.nan, np.inf, -np.inf, 1e300, -1e300, 0.0, 1e-300, -1e-300,
                           5e7, 1.0])
SETTINGS = settings(max_examples=60, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow])


def _arr(n, extra_shape, special, pos, seed):
    a = np.random.default_rng(seed).normal(size=(n, *extra_shape)) * 3.0
    if a.size:
        a.reshape(-1)[pos % a.size] = special
    return a


def _ok(fn, *args, **kw):
    """Call; allowed outcomes: a result, or ValueError/TypeError with a message."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        try:
            return fn(*args, **kw)
        except (ValueError, TypeError) as exc:
            assert str(exc), f"{fn.__name__}: empty error message"
            return None


@SETTINGS
@given(n=st.integers(0, 40), special=EXTREME, pos=st.integers(0, 10**6),
       seed=st.integers(0, 2**16))
def test_orientation_and_metrics_survive_extremes(n, special, pos, seed):
    a1 = _arr(n, (), special, pos, seed)
    a2 = _arr(n, (2,), special, pos, seed)
    b2 = _arr(n, (2,), 0.0, 0, seed + 1)
    w = _ok(orientation.wrap_angle, a1)
    if w is not None:
        fin = np.isfinite(a1)
        assert np.all((w[fin] > -np.pi) & (w[fin] <= np.pi))   # (-pi, pi] where defined
    _ok(orientation.unwrap_angle, a1)
    _ok(orientation.heading_from_points, a2, b2)
    _ok(orientation.law_of_cosines_heading, a2, 0.3)
    _ok(orientation.law_of_cosines_bearing, a2)
    _ok(orientation.law_of_cosines_angle, np.abs(a1), np.abs(a1) + 1, np.abs(a1) + 2)
    e = _ok(metrics.cg_errors, a2, b2)
    if e is not None:
        assert set(e) == {"x", "y", "euclid"}
    h = _ok(metrics.heading_error, a1, np.zeros(n))
    if h is not None:
        fin = np.isfinite(a1)
        assert np.all((h[fin] >= 0) & (h[fin] <= np.pi))
    _ok(metrics.along_cross_errors, a2, b2, a1)
    s = _ok(metrics.summarize, a1)
    if s is not None:
        assert s["n"] + s["n_nan"] == n or "n" not in s


@SETTINGS
@given(n=st.integers(0, 40), special=EXTREME, pos=st.integers(0, 10**6),
       seed=st.integers(0, 2**16), span=st.sampled_from([1e-300, 0.5, 4.0, 1e300, np.inf,
                                                         np.nan, -1.0]))
def test_turn_detection_and_lag_survive_extremes(n, special, pos, seed, span):
    t = np.arange(n, dtype=float)
    h = _arr(n, (), special, pos, seed)
    xy = _arr(n, (2,), special, pos, seed)
    r = _ok(turns.heading_rate, t, h, span)
    if r is not None:
        assert r.shape == (n,)
    _ok(turns.course_heading, t, xy, span)
    f = _ok(turns.detect_turns, t, h, span_s=span)
    if f is not None:
        assert f.dtype == bool and f.shape == (n,)
    _ok(turns.hysteresis, h, 0.05, 0.02)
    _ok(lag.estimate_velocity, t, xy, 3)


@pytest.mark.parametrize("bad", ["1", None, True, [1.0]])
def test_turn_detector_numbers_name_the_argument(bad):
    with pytest.raises((ValueError, TypeError), match="span_s"):
        turns.heading_rate(np.arange(5.0), np.zeros(5), bad)


def test_huge_session_is_refused_before_allocation():
    from sim.gps import GpsNoiseModel, synthesize_session

    cfg = SensorConfig.load("rover_gps8")
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="receiver-samples"):
        synthesize_session(GpsNoiseModel.load("gps_stationary"), cfg, 1e15, rng)
    with pytest.raises(ValueError, match="receiver-samples"):
        synthesize_session(GpsNoiseModel.load("gps_stationary"), cfg, 100.0, rng, rate_hz=1e300)


# ------------------------------------------------------------------ sim helpers (issue 13)
@SETTINGS
@given(v=st.one_of(EXTREME, st.sampled_from(["x", None, True])),
       n=st.integers(0, 6), seed=st.integers(0, 2**16))
def test_sim_helpers_survive_extremes(v, n, seed):
    from sim import controllers, gps, rover, ultrasonic
    from sim.paths import load_path

    rng = np.random.default_rng(seed)
    pp = controllers.PurePursuitParams.from_path(load_path("square20"))
    _ok(controllers.rate_limit, v, 0.0, 1.0, 0.1)
    _ok(controllers.pure_pursuit_curvature, v, 0.0, 0.0, 1.0, 1.0)
    _ok(controllers.speed_limit, v, pp)
    _ok(controllers.diff_drive_wheel_speeds, 1.0, 0.1, v, 0.2)
    steps = _ok(rover.default_control_steps, v, 0.005)
    if steps is not None:
        assert steps >= 1
    model = ultrasonic.UltrasonicNoiseModel.load()
    t = _ok(ultrasonic.sample_times, v, model, rng)
    if t is not None:
        assert np.all(np.diff(t) > 0)
    tx = rng.normal(size=(n, 2, 3))
    if n and isinstance(v, float):
        tx[0, 0, 0] = v
    r = _ok(ultrasonic.simulate_ranges, np.arange(n, dtype=float), tx, rng.normal(size=(6, 3)),
            model, rng)
    if r is not None:
        assert r.shape == (n, 2, 6)
    e = _ok(gps.receiver_errors, gps.GpsNoiseModel.load("gps_stationary"), 3, n, 1.0, rng)
    if e is not None:
        assert e[0].shape == (n, 3, 2)


@SETTINGS
@given(n=st.integers(1, 40), special=EXTREME, pos=st.integers(0, 10**6),
       seed=st.integers(0, 2**16))
def test_turn_flags_and_first_observations_survive_extremes(n, special, pos, seed):
    from estimator.tracking import detect_turning

    cfg = SensorConfig.load("rover_gps4").planar()
    o = _arr(n, (cfg.m, 2), special, pos, seed)
    t = np.arange(n, dtype=float)
    f = _ok(detect_turning, t, o, cfg)
    if f is not None:
        assert f.dtype == bool and f.shape == (n,)
    first, idx = lag.first_observations(np.where(np.isfinite(o), o, np.nan), np.array([0]),
                                        np.array([n - 1]))
    assert first.shape == (1, cfg.m, 2) and idx.shape == (1, cfg.m)


# ------------------------------------------------------ pose filter and smoothers (issue 23)
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(n=st.integers(2, 30), step=st.sampled_from([1e-300, 1e-9, 1e-3, 1.0, 1e4, 1e10]),
       speed=st.sampled_from([0.0, -1.0, 1.0, 1e3, 1e7]),
       noise=st.sampled_from([0.0, 1e-3, 0.3, 1e4]),
       sigma=st.sampled_from([None, 1e-6, 0.05, 1e6, 1e300]),
       gap=st.sampled_from([0.0, 3600.0, 1e11]), miss=st.floats(0.0, 0.9),
       reverse=st.booleans(), seed=st.integers(0, 2**16))
def test_pose_filter_and_smoothers_never_fail_or_give_inf(n, step, speed, noise, sigma, gap,
                                                          miss, reverse, seed):
    """Generated inputs as in issue 23's attack (tiny and huge steps, an hour's or 3000
    years' gap, noise-free to 10 km noise, absurd noise levels, missing fixes, both speed
    modes): a named ValueError/TypeError, or a pass whose every row is all finite or all
    NaN (states and covariances, never inf), forward-mode speeds >= 0, and smoothers with
    a finite row exactly where the filter has one (no NaN carried back)."""
    from estimator.pose_filter import PoseFilterParams, run_pose_filter
    from estimator.pose_smoother import fixed_lag_smooth, rts_smooth

    rng = np.random.default_rng(seed)
    off = np.array([[0.75, 0.5], [0.75, 0.0], [-0.75, 0.5], [-0.75, -0.5]])
    t = np.cumsum(rng.uniform(0.5, 1.5, n)) * step
    t[n // 2:] += gap
    obs = np.c_[speed * t, np.zeros(n)][:, None, :] + off[None]
    obs = obs + rng.normal(0, 1.0, obs.shape) * noise
    obs[rng.random((n, 4)) < miss] = np.nan

    def run():
        p = PoseFilterParams(reverse=reverse, **(
            {} if sigma is None else {"sigma_abs_m": sigma, "sigma_step_m": sigma}))
        return run_pose_filter(t, obs, off, p)

    res = _ok(run)
    if res is None:
        return
    out = np.isfinite(res.states[:, 0])
    assert np.array_equal(np.isfinite(res.states).all(1), out)
    assert not np.isinf(res.states).any() and not np.isinf(res.covariances).any()
    assert np.isfinite(res.covariances[out]).all()
    if not reverse:
        assert (res.states[out, 3] >= 0).all()
    for sm in (rts_smooth(res, reverse).states, fixed_lag_smooth(res, t, 5.0, reverse).states):
        assert np.array_equal(np.isfinite(sm).all(1), out)
