"""PV Kalman filter of thesis 003 Appendix C (RangeKalmanFilter) against filterpy."""

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter
from hypothesis import given, settings
from hypothesis import strategies as st

from estimator.kalman import N_INIT, PVKalman, process_noise, pv_kalman


def _data(n=400, seed=0):
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.02, 0.1, n))            # uneven, as the HX19 log
    truth = 2.0 * np.sin(0.5 * t) + 0.3 * t
    return t, truth + rng.normal(0, 0.02, n)


def _filterpy_reference(t, z, sp, sm):
    """Appendix C's loop written with filterpy's KalmanFilter (independent implementation)."""
    kf = KalmanFilter(dim_x=2, dim_z=1)
    kf.x = np.array([[np.mean(z[:N_INIT])], [0.0]])
    dt_avg = np.mean(np.diff(t))
    def q(dt):
        return sp**2 * np.array([[dt**4 / 4, dt**3 / 2], [dt**3 / 2, dt**2]])

    kf.P = q(dt_avg)
    kf.H = np.array([[1.0, 0.0]])
    kf.R = np.array([[sm**2]])
    out = [kf.x[0, 0]]
    for i in range(1, len(t)):
        dt = t[i] - t[i - 1]
        kf.F = np.array([[1.0, dt], [0.0, 1.0]])
        kf.Q = q(dt)
        kf.predict()
        if np.isfinite(z[i]):
            kf.update(np.array([[z[i]]]))
        out.append(kf.x[0, 0])
    return np.array(out)


@pytest.mark.parametrize("sp, sm", [(3.0, 2.0), (0.5, 0.05), (1.0, 1.0)])
def test_equals_filterpy_on_uneven_steps(sp, sm):
    t, z = _data()
    ours = pv_kalman(t, z, sp, sm)
    ref = _filterpy_reference(t, z, sp, sm)
    # Same arithmetic up to the covariance update form (filterpy uses the Joseph form, the
    # thesis P = (I - K C) P): both exact for the optimal gain, so they differ by rounding
    # only; 1e-12 relative to the signal scale (a few metres) bounds that.
    np.testing.assert_allclose(ours, ref, rtol=0, atol=1e-12 * np.max(np.abs(z)))


def test_first_output_is_initial_state_and_class_equals_function():
    t, z = _data(seed=1)
    out = pv_kalman(t, z, 1.0, 0.1)
    assert out[0] == np.mean(z[:10])
    kf = PVKalman.from_thesis(t, z, 1.0, 0.1)
    np.testing.assert_array_equal(kf.P, process_noise(np.mean(np.diff(t)), 1.0))
    stream = [kf.x[0]]
    for i in range(1, len(t)):
        kf.predict(t[i] - t[i - 1])
        kf.update(z[i])
        stream.append(kf.x[0])
    np.testing.assert_array_equal(out, np.array(stream))      # bit for bit


def test_nan_is_predict_only():
    t, z = _data(seed=2)
    z[[50, 51, 52, 200]] = np.nan
    ours = pv_kalman(t, z, 1.0, 0.1)
    assert np.all(np.isfinite(ours))
    np.testing.assert_allclose(ours, _filterpy_reference(t, z, 1.0, 0.1), rtol=0, atol=1e-11)
    # predict only: across the gap the estimate moves on the constant-rate line
    kf = PVKalman.from_thesis(t, z, 1.0, 0.1)
    for i in range(1, 50):
        kf.predict(t[i] - t[i - 1])
        kf.update(z[i])
    x49 = kf.x.copy()
    assert ours[50] == pytest.approx(x49[0] + x49[1] * (t[50] - t[49]), abs=1e-12)


def test_steady_noise_reduction():
    # a constant signal: the filter's output scatter is well below the measurement noise
    rng = np.random.default_rng(4)
    t = np.cumsum(rng.uniform(0.03, 0.1, 3000))
    z = 1.0 + rng.normal(0, 0.05, t.size)
    out = pv_kalman(t, z, 0.01, 0.05)
    assert np.std(out[500:] - 1.0) < 0.2 * 0.05


def test_validation():
    t = np.arange(20.0)
    with pytest.raises(ValueError, match="sigma_measurement"):
        pv_kalman(t, t, 1.0, 0.0)
    with pytest.raises(ValueError, match="t:"):
        pv_kalman(t[::-1], t, 1.0, 1.0)
    with pytest.raises(ValueError, match="z:"):
        pv_kalman(t, t[:5], 1.0, 1.0)
    with pytest.raises(ValueError, match="dt"):
        PVKalman([0, 0], np.eye(2), 1.0, 1.0).predict(0.0)


# ---------------------------------------------------------------------------------------------
# SI defaults, per-sample sigmas, the innovation gate, bad input (issues 12, 13)
# ---------------------------------------------------------------------------------------------


def test_defaults_are_appendix_c_values_in_si():
    t, z = _data(seed=5)
    np.testing.assert_array_equal(pv_kalman(t, z), pv_kalman(t, z, 0.003, 0.002))
    np.testing.assert_allclose(pv_kalman(t, z), _filterpy_reference(t, z, 0.003, 0.002),
                               rtol=0, atol=1e-12 * np.max(np.abs(z)))


def test_per_sample_sigma_equals_filterpy_with_per_step_R():
    t, z = _data(seed=6)
    rng = np.random.default_rng(7)
    sm = rng.uniform(0.01, 0.5, t.size)
    ours = pv_kalman(t, z, 0.5, sm)
    kf = KalmanFilter(dim_x=2, dim_z=1)
    kf.x = np.array([[np.mean(z[:N_INIT])], [0.0]])
    def q(dt):
        return 0.25 * np.array([[dt**4 / 4, dt**3 / 2], [dt**3 / 2, dt**2]])

    kf.P = q(np.mean(np.diff(t)))
    kf.H = np.array([[1.0, 0.0]])
    ref = [kf.x[0, 0]]
    for i in range(1, t.size):
        dt = t[i] - t[i - 1]
        kf.F = np.array([[1.0, dt], [0.0, 1.0]])
        kf.Q = q(dt)
        kf.predict()
        kf.update(np.array([[z[i]]]), R=np.array([[sm[i] ** 2]]))
        ref.append(kf.x[0, 0])
    # same algebra, Joseph vs short covariance update: rounding only (see above)
    np.testing.assert_allclose(ours, ref, rtol=0, atol=1e-11)


def test_innovation_gate_rejects_spikes_and_reinitialises_on_a_new_level():
    rng = np.random.default_rng(8)
    t = np.arange(600) * 0.1
    z = 2.0 + rng.normal(0, 0.05, 600)
    spikes = np.arange(100, 500, 40)
    z[spikes] -= 3.0
    z[550:] += 4.0                                   # a lasting step: a new level
    out, info = pv_kalman(t, z, 0.5, 0.05, gate=5.0, reinit_after=5, return_info=True)
    assert info.gated[spikes].all()
    assert np.max(np.abs(out[100:549] - 2.0)) < 0.1  # the spikes never reached the estimate
    assert info.reinitialised[550:556].sum() == 1 and info.reinitialised[554]
    assert abs(out[-1] - 6.0) < 0.1
    # gate=None is the thesis filter (no rejection at all)
    plain, info0 = pv_kalman(t, z, 0.5, 0.05, return_info=True)
    assert not info0.gated.any() and np.max(np.abs(plain[100:549] - 2.0)) > 0.5
    # a gate wider than any innovation changes nothing
    np.testing.assert_array_equal(pv_kalman(t, z, 0.5, 0.05, gate=1e9), plain)


@pytest.mark.parametrize("call, field, exc", [
    (lambda t, z: pv_kalman(t, z, 1.0, 1e300), "sigma_measurement", ValueError),
    (lambda t, z: pv_kalman(t, z, 1e-300, 1e-300), "sigma_process", ValueError),
    (lambda t, z: pv_kalman(t, z, "1", 1.0), "sigma_process", TypeError),
    (lambda t, z: pv_kalman(t, z, 1.0, None), "sigma_measurement", TypeError),
    (lambda t, z: pv_kalman(t, z, 1.0, 1.0, gate=np.inf), "gate", ValueError),
    (lambda t, z: pv_kalman(t, z, 1.0, 1.0, reinit_after=np.inf), "reinit_after", TypeError),
    (lambda t, z: pv_kalman(t, np.full(t.size, 1e300), 1.0, 1.0), "z", ValueError),
    (lambda t, z: pv_kalman(t * 1e9, z, 1.0, 1.0), "t", ValueError),
    (lambda t, z: pv_kalman(t, ["a"] * t.size, 1.0, 1.0), "z", TypeError),
    (lambda t, z: pv_kalman(t, z, 1.0, np.zeros(t.size)), "sigma_measurement", ValueError),
    (lambda t, z: PVKalman([0, 0], np.eye(2), 1.0, 1.0).predict(1e200), "dt", ValueError),
    (lambda t, z: PVKalman([0, 0], np.eye(2), 1.0, 1.0).predict("1"), "dt", TypeError),
    (lambda t, z: PVKalman([0, 0], np.eye(2), 1.0, 1.0).update("a"), "z", TypeError),
    (lambda t, z: PVKalman([0, 0], np.eye(2) * 1e300, 1.0, 1.0), "P0", ValueError),
    (lambda t, z: pv_kalman(t, z, 1.0, 1e-300), "sigma_measurement", ValueError),
])
def test_overflowing_and_wrong_type_arguments_are_named(call, field, exc):
    t, z = _data(n=30)
    with pytest.raises(exc, match=field):
        call(t, z)


@settings(max_examples=40, deadline=None)
@given(sp=st.sampled_from([0.0, 1e-50, 1e-3, 1.0, 1e50]),
       sm=st.sampled_from([1e-50, 1e-3, 1.0, 1e50]),
       zval=st.sampled_from([0.0, 1e-300, 1e100, -1e100, np.nan]),
       n=st.sampled_from([1, 2, 11, 1500]), gate=st.sampled_from([None, 3.0]))
def test_extremes_give_finite_output(sp, sm, zval, n, gate):
    """Any accepted sigma pair (1e-50 .. 1e50), extreme measurements (+-1e100, 1e-300,
    NaN), one to 1500 samples: the output is finite (the filter never produces NaN
    from finite input) or the call is a named ValueError (all-NaN input has no start)."""
    t = np.arange(n) * 0.1
    z = np.sin(t)
    z[n // 2] = zval
    try:
        out = pv_kalman(t, z, sp, sm, gate=gate)
    except ValueError as exc:
        assert str(exc).startswith("z:") and not np.isfinite(z).any()
        return
    assert out.shape == (n,) and np.all(np.isfinite(out))
