"""track's option objects (estimator.track_options) and the weighting vocabulary
(estimator.weights.Weighting): each checks itself where it is built, the text forms round
trip, extreme values raise errors that name the field, and the objects select exactly what
the plain arguments select."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from synth_tracks import straight

from estimator.configuration import SensorConfig
from estimator.tracking import (
    DynamicWindow,
    FitOptions,
    LagCorrection,
    MotionOptions,
    track,
)
from estimator.weights import (
    THRESHOLD_WEIGHTINGS,
    WEIGHTINGS,
    Weighting,
    huber_weights,
    huff_huber_weights,
    huff_weights,
    random_weights,
    weights_for,
)

XY = ["cg_x", "cg_y"]
EXTREMES = [math.nan, math.inf, -math.inf, -1.0, 0.0, True, "1", None, [1.0]]


# ----------------------------------------------------------------------------- Weighting
@settings(max_examples=100, deadline=None)
@given(st.sampled_from(THRESHOLD_WEIGHTINGS),
       st.floats(min_value=1e-300, max_value=1e300, allow_nan=False, allow_infinity=False))
def test_weighting_text_round_trips(scheme, threshold):
    """str() writes what parse() reads back to the same object, for any threshold from
    1e-300 m to 1e300 m (the text is repr's shortest round-trip form)."""
    w = Weighting(scheme, huff_threshold=threshold)
    assert Weighting.parse(str(w)) == w
    assert Weighting.parse(w) is w


@pytest.mark.parametrize("text", [*WEIGHTINGS, "huff:3.5", "huff_huber:2", "huff:1e3"])
def test_weighting_names_parse(text):
    w = Weighting.parse(text)
    assert w.scheme == text.split(":")[0]
    assert (w.huff_threshold is None) == (":" not in text)


@pytest.mark.parametrize("text", ["tukey", "huff:", "huff:0", "huff:-1", "huff:nan", "huff:inf",
                                  "huff:1e400", "huff: 3", "huff:3m", "huber:3", "none:1",
                                  "random:2", "", ":3"])
def test_bad_weighting_text_names_the_field(text):
    with pytest.raises(ValueError, match="weighting"):
        Weighting.parse(text)


@pytest.mark.parametrize("kwargs, field", [
    ({"scheme": "huff", "huff_threshold": v}, "huff_threshold") for v in EXTREMES[:5]
] + [
    ({"scheme": "none", "huff_threshold": 3.0}, "huff_threshold"),
    ({"scheme": "huber", "huber_c": 0.0}, "huber_c"),
    ({"scheme": "huber", "huber_c": math.inf}, "huber_c"),
    ({"scheme": "huff", "huber_c": 2.0}, "huber_c"),        # huff does not use it
])
def test_bad_weighting_fields_are_named(kwargs, field):
    with pytest.raises((ValueError, TypeError), match=field):
        Weighting(**kwargs)


def test_weights_for_is_each_weight_function():
    """The one dispatcher returns exactly the weight function of the scheme (same arrays,
    the same random draws from the same generator)."""
    cfg = SensorConfig.load("rover_gps8").planar()
    rng = np.random.default_rng(3)
    obs = cfg.body_positions + rng.normal(0.0, 0.5, (4, 6, cfg.m, 2))
    obs[0, 2, 3] = np.nan
    assert weights_for(obs, cfg, "none") is None
    np.testing.assert_array_equal(weights_for(obs, cfg, "huff:3.5"), huff_weights(obs, cfg, 3.5))
    np.testing.assert_array_equal(weights_for(obs, cfg, "huber"), huber_weights(obs))
    np.testing.assert_array_equal(weights_for(obs, cfg, Weighting("huff_huber", 2.0, 1.5)),
                                  huff_huber_weights(obs, cfg, 2.0, 1.5))
    np.testing.assert_array_equal(weights_for(obs, cfg, "random", np.random.default_rng(9)),
                                  random_weights(obs.shape[:-1], np.random.default_rng(9)))
    with pytest.raises(ValueError, match="rng"):
        weights_for(obs, cfg, "random")


# ----------------------------------------------------------------------------- options
@pytest.mark.parametrize("make, field", [
    *[(lambda v=v: FitOptions(eps=v), "fit.eps") for v in EXTREMES[:5]],
    (lambda: FitOptions(warm_start=1), "fit.warm_start"),
    (lambda: FitOptions(maxiter=0), "fit.maxiter"),
    (lambda: FitOptions(maxiter=2.0), "fit.maxiter"),
    *[(lambda v=v: MotionOptions(omega_max=v), "motion.omega_max") for v in EXTREMES[:5]],
    (lambda: MotionOptions(yaw_rate="yes"), "motion.yaw_rate"),
    (lambda: DynamicWindow(0), "dynamic_window"),
    (lambda: DynamicWindow(1.0), "dynamic_window"),
    (lambda: DynamicWindow(True), "dynamic_window"),
    (lambda: DynamicWindow(1, "fifo"), "window_growth"),
    (lambda: DynamicWindow(1, detector=[("window", 3)]), "detector"),
    (lambda: LagCorrection("both"), "lag_correction.mode"),
    (lambda: LagCorrection(velocity_span=0), "velocity_span"),
    (lambda: LagCorrection(heading=np.array([0.0, np.inf])), r"lag_heading\[1\]"),
    (lambda: LagCorrection(heading=np.zeros(3, int)), "lag_heading"),
    (lambda: LagCorrection("course", heading=np.zeros(3)), "lag_heading"),
])
def test_bad_options_name_the_field(make, field):
    with pytest.raises((ValueError, TypeError), match=field):
        make()


def test_extreme_but_valid_options_are_kept():
    assert FitOptions(eps=1e-300).eps == 1e-300
    assert FitOptions(maxiter=np.int64(10**9)).maxiter == 10**9
    assert MotionOptions(omega_max=1e300).omega_max == 1e300
    assert DynamicWindow(10**12).small == 10**12
    h = LagCorrection(heading=np.array([np.nan, 1e300, -1e300]))
    assert np.isnan(h.heading[0]) and h.heading[1] == 1e300


@pytest.mark.parametrize("value", [False, True, "pose", "course"])
def test_lag_correction_shorthands_are_the_objects(value):
    """lag_correction=True / "pose" / "course" is LagCorrection(mode), False is none: the
    same track, bit for bit."""
    cfg, t, _cg, _yaw, obs = straight(n=40)
    obs = obs + np.random.default_rng(5).normal(0, 0.3, obs.shape)
    obj = LagCorrection.coerce(value)
    assert (obj is None) == (value is False)
    a = track(t, obs, cfg, window=5, lag_correction=value, layout_check=False)
    b = track(t, obs, cfg, window=5, lag_correction=obj or False, layout_check=False)
    assert a.equals(b)


def test_dynamic_window_shorthand_and_fit_defaults_are_the_objects():
    cfg, t, _cg, _yaw, obs = straight(n=40)
    obs = obs + np.random.default_rng(6).normal(0, 0.3, obs.shape)
    flags = np.zeros(40, bool)
    flags[[12, 13, 30]] = True
    a = track(t, obs, cfg, window=6, dynamic_window=2, turning=flags, layout_check=False)
    b = track(t, obs, cfg, window=6, dynamic_window=DynamicWindow(2, "jump"), turning=flags,
              fit=FitOptions(), layout_check=False)
    assert a.equals(b)
    c = track(t, obs, cfg, window=6, weighting="huff:3.5", layout_check=False)
    d = track(t, obs, cfg, window=6, weighting=Weighting("huff", 3.5), layout_check=False)
    assert c.equals(d) and c.attrs["settings"]["huff_threshold"] == 3.5
