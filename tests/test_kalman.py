"""PV Kalman filter of thesis 003 Appendix C (RangeKalmanFilter) against filterpy."""

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter

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
    q = lambda dt: sp**2 * np.array([[dt**4 / 4, dt**3 / 2], [dt**3 / 2, dt**2]])
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
