"""EKF on the antennas: update against FilterPy, Jacobian against finite differences,
gating and reset."""

import numpy as np
import pytest
from filterpy.kalman import ExtendedKalmanFilter

from estimator.pose_filter import (
    PoseFilterParams,
    _h,
    antenna_update,
    ctrv_predict,
    run_pose_filter,
)

OFFSETS = np.array([[0.75, 0.5], [0.75, 0.0], [-0.75, 0.5], [-0.75, -0.5]])


def test_update_matches_filterpy():
    rng = np.random.default_rng(0)
    x = np.array([3.0, -2.0, 0.4, 1.2, 0.1])
    A = rng.normal(size=(5, 5))
    P = A @ A.T + np.eye(5)
    z = _h(x, OFFSETS)[0] + rng.normal(0, 0.5, (4, 2))
    xn, Pn, acc = antenna_update(x, P, z, OFFSETS, sigma_meas=0.7)
    ekf = ExtendedKalmanFilter(dim_x=5, dim_z=8)
    ekf.x = x.copy()
    ekf.P = P.copy()
    ekf.update(z.reshape(-1), lambda s: _h(s, OFFSETS)[1], lambda s: _h(s, OFFSETS)[0].reshape(-1),
               R=0.49 * np.eye(8))
    assert acc.all()
    # 1e-12 relative: the same algebra in a different order (solve vs inverse)
    np.testing.assert_allclose(xn, ekf.x, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(Pn, ekf.P, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("om", [0.3, -0.8, 1e-9, 0.0])
def test_predict_jacobian_matches_finite_differences(om):
    x = np.array([1.0, 2.0, 0.7, 1.5, om])
    dt = 0.8
    P = np.eye(5)
    _, Pn = ctrv_predict(x, P, dt, 1e-12, 1e-12)  # Q ~ 0: Pn = F F^T
    h = 1e-6
    F = np.empty((5, 5))
    for j in range(5):
        e = np.zeros(5)
        e[j] = h
        a = ctrv_predict(x + e, P, dt, 1, 1)[0]
        b = ctrv_predict(x - e, P, dt, 1, 1)[0]
        F[:, j] = (a - b) / (2 * h)
    # central differences: error O(h^2) plus rounding O(eps / h) ~ 1e-10
    np.testing.assert_allclose(Pn, F @ F.T, atol=1e-6)


def test_predict_continuous_at_zero_yaw_rate():
    x0 = np.array([0.0, 0.0, 1.0, 2.0, 0.0])
    a = ctrv_predict(x0, np.eye(5), 1.0, 0.1, 0.1)[0]
    b = ctrv_predict(x0 + np.array([0, 0, 0, 0, 1e-5]), np.eye(5), 1.0, 0.1, 0.1)[0]
    np.testing.assert_allclose(a[:2], b[:2], atol=1e-4)


def test_gating_and_reset():
    n = 30
    t = np.arange(float(n))
    x_true = np.c_[t, np.zeros(n)]
    obs = x_true[:, None, :] + OFFSETS[None]
    obs[20:] += 100.0  # the platform "teleports": every antenna fails the gate
    x0 = np.array([0.0, 0.0, 0.0, 1.0, 0.0])
    P0 = np.diag([1.0, 1.0, 0.1, 0.1, 0.01])
    params = PoseFilterParams(sigma_meas=0.5, max_rejects=3)
    res = run_pose_filter(t, obs, OFFSETS, x0, P0, 0, params)
    assert res.status[0] == "init"
    assert (res.status[1:20] == "ok").all()
    np.testing.assert_array_equal(res.n_gated[20:22], [4, 4])
    assert res.status[22] == "reset"  # third rejected epoch in a row
    assert res.n_used[22] == 4


def test_params_validation():
    with pytest.raises(ValueError, match="sigma_meas"):
        PoseFilterParams(sigma_meas=0)
    with pytest.raises(ValueError, match="gate_prob"):
        PoseFilterParams(gate_prob=1.5)
    with pytest.raises(ValueError, match="max_rejects"):
        PoseFilterParams(max_rejects=0)
