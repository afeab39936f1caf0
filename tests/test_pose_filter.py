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


# --------------------------------------------------------------- equivalence with the reference
def _scene(seed, n=400, outliers=True):
    """Random antenna fixes around a CTRV-like track: NaN dropouts, a dead antenna, uneven
    time steps and (optionally) bursts of gross errors that trigger gating and resets."""
    import _ref_pose_filter  # noqa: F401  (import check: tests/ is on sys.path)

    rng = np.random.default_rng(seed)
    off = np.array([[0.75, 0.5], [0.75, 0.0], [-0.75, 0.5], [-0.75, -0.5], [0.0, 0.3]])
    t = np.cumsum(rng.uniform(0.3, 2.0, n))
    yaw = 0.3 + np.cumsum(rng.normal(0, 0.05, n))
    cg = np.cumsum(np.c_[np.cos(yaw), np.sin(yaw)] * 0.5, axis=0)
    c, s = np.cos(yaw), np.sin(yaw)
    obs = np.stack([cg[:, None, 0] + c[:, None] * off[:, 0] - s[:, None] * off[:, 1],
                    cg[:, None, 1] + s[:, None] * off[:, 0] + c[:, None] * off[:, 1]], -1)
    obs += rng.normal(0, 1.0, obs.shape)
    obs[rng.random((n, 5)) < 0.1] = np.nan
    obs[:, 4] = np.nan  # dead antenna
    if outliers:
        obs[150:160] += 80.0  # every antenna off: gated, then reset
        obs[rng.random((n, 5)) < 0.03] += 30.0
    x0 = np.array([cg[0, 0], cg[0, 1], yaw[0], 0.5, 0.0])
    P0 = np.diag([4.0, 4.0, 0.25, 1.0, 0.25])
    return t, obs, off, x0, P0


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("gate_prob", [0.999, 1.0])
def test_run_matches_reference_implementation(seed, gate_prob):
    """The scalar-math loop reproduces the numpy implementation it replaced (kept in
    tests/_ref_pose_filter.py). Same algebra, except that the covariance update goes
    through a closed-form 3x3 inverse instead of two 5x5 inverses (rounding differs);
    1e-9 absolute on states and covariances (values are O(1-100); measured differences
    ~3e-12 over 2000 epochs). Without gating the gross errors are left out of the scene: an
    ungated filter fed 30-80 m outliers is so sensitive that the two implementations'
    last-bit differences grow to metres (measured 5 m on seed 1), for either one against
    any reordering of its own arithmetic."""
    import _ref_pose_filter as ref

    t, obs, off, x0, P0 = _scene(seed, outliers=gate_prob < 1)
    params = PoseFilterParams(sigma_meas=1.5, gate_prob=gate_prob, max_rejects=3)
    new = run_pose_filter(t, obs, off, x0, P0, 2, params)
    old = ref.run_pose_filter(t, obs, off, x0, P0, 2, params)
    np.testing.assert_array_equal(new.status, old.status)
    np.testing.assert_array_equal(new.n_used, old.n_used)
    np.testing.assert_array_equal(new.n_gated, old.n_gated)
    if gate_prob < 1:
        assert (new.status == "reset").any()
    np.testing.assert_allclose(new.states, old.states, rtol=0, atol=1e-9)
    np.testing.assert_allclose(new.covariances, old.covariances, rtol=0, atol=1e-9)


def test_public_steps_match_reference_implementation():
    import _ref_pose_filter as ref

    rng = np.random.default_rng(5)
    for _ in range(20):
        x = rng.normal(size=5) * [10, 10, 2, 1, 0.5]
        A = rng.normal(size=(5, 5))
        P = A @ A.T + 0.1 * np.eye(5)
        dt = rng.uniform(0.1, 3)
        a, b = ctrv_predict(x, P, dt, 0.7, 0.05), ref.ctrv_predict(x, P, dt, 0.7, 0.05)
        np.testing.assert_allclose(a[0], b[0], rtol=0, atol=1e-12)
        np.testing.assert_allclose(a[1], b[1], rtol=1e-13, atol=1e-12)
        z = rng.normal(size=(4, 2)) * 3 + x[:2]
        for gate in (np.inf, 5.0):
            a = antenna_update(x, P, z, OFFSETS, 0.9, gate)
            b = ref.antenna_update(x, P, z, OFFSETS, 0.9, gate)
            np.testing.assert_array_equal(a[2], b[2])
            np.testing.assert_allclose(a[0], b[0], rtol=0, atol=1e-10)
            np.testing.assert_allclose(a[1], b[1], rtol=1e-12, atol=1e-12)


def _valid_args():
    n = 6
    t = np.arange(float(n))
    obs = np.c_[t, np.zeros(n)][:, None, :] + OFFSETS[None]
    x0 = np.array([0.0, 0.0, 0.0, 1.0, 0.0])
    P0 = np.diag([1.0, 1.0, 0.1, 0.1, 0.01])
    return {"t": t, "obs": obs, "offsets": OFFSETS, "x0": x0, "P0": P0, "k0": 0}


@pytest.mark.parametrize("field, bad", [
    ("x0", np.zeros(4)),                       # used to run with a 4-element state
    ("x0", np.zeros((5, 1))),
    ("x0", np.array([0.0, 0.0, np.nan, 1.0, 0.0])),
    ("P0", np.eye(4)),
    ("P0", np.eye(5)[:, :, None]),
    ("P0", np.diag([1.0, 1.0, np.inf, 1.0, 1.0])),
    ("offsets", OFFSETS[:, :1]),
    ("offsets", OFFSETS[:-1]),
    ("obs", np.zeros((6, 4))),
    ("t", np.arange(5.0)),                    # wrong length
    ("t", np.r_[0.0, 1.0, np.nan, 3.0, 4.0, 5.0]),
    ("k0", 6),
    ("k0", -1),
    ("k0", 1.0),
])
def test_run_pose_filter_rejects_bad_arguments_naming_the_field(field, bad):
    args = {**_valid_args(), field: bad}
    with pytest.raises(ValueError, match=rf"^{field}:"):
        run_pose_filter(**args)


def test_run_pose_filter_docstring_states_the_arguments():
    doc = run_pose_filter.__doc__
    for text in ("x0 : (5,)", "P0 : (5, 5)", "offsets : (m, 2)", "obs : (n, m, 2)",
                 "t : (n,)", "k0 :", "params :"):
        assert text in doc, text
