"""GTSAM peer (estimator.gtsam_peer): skips cleanly without the optional gtsam package,
except the test that the missing dependency is reported with the install command."""

import builtins

import numpy as np
import pytest
from pose_scenes import kinematic_truth, noisy

from estimator.metrics import heading_error
from estimator.pose_filter import PoseFilterParams, run_pose_filter
from estimator.pose_smoother import fixed_lag_smooth


def test_missing_gtsam_is_reported_with_the_install_command(monkeypatch):
    import estimator.gtsam_peer as peer

    real_import = builtins.__import__

    def no_gtsam(name, *a, **k):
        if name == "gtsam" or name.startswith("gtsam."):
            raise ImportError("No module named 'gtsam'")
        return real_import(name, *a, **k)

    monkeypatch.setattr(builtins, "__import__", no_gtsam)
    assert not peer.gtsam_available()
    with pytest.raises(ImportError, match=r"pip install -e '\.\[gtsam\]'"):
        peer.run_gtsam_peer(np.arange(3.0), np.zeros((3, 2, 2)), np.eye(2))


@pytest.fixture(scope="module")
def gtsam():
    return pytest.importorskip("gtsam")


def test_lever_arm_factor_is_the_antenna_residual(gtsam):
    """The peer's fix factor is GTSAM's KnownLandmarkFactorPose2 with the fix as the
    'landmark' and the lever arm as the 'measurement': its error R^T (z - p) - r has the
    norm of the antenna residual z - (p + R r) (R is a rotation), so with an isotropic noise
    model it is the lever-arm GPS factor exactly."""
    key = gtsam.symbol("x", 0)
    pose = gtsam.Pose2(3.0, -1.0, 0.7)
    vals = gtsam.Values()
    vals.insert(key, pose)
    r = np.array([0.75, 0.5])
    z = np.array([4.1, 0.2])
    f = gtsam.KnownLandmarkFactorPose2(key, z, r, gtsam.noiseModel.Isotropic.Sigma(2, 1.0))
    c, s = np.cos(0.7), np.sin(0.7)
    resid = z - (np.array([3.0, -1.0]) + np.array([c * r[0] - s * r[1], s * r[0] + c * r[1]]))
    assert np.linalg.norm(f.unwhitenedError(vals)) == pytest.approx(np.linalg.norm(resid),
                                                                     rel=1e-12)


def test_displacement_factor_jacobians_match_finite_differences(gtsam):
    from estimator.gtsam_peer import _displacement_factor

    ka, kb = gtsam.symbol("x", 0), gtsam.symbol("x", 1)
    r = np.array([0.4, -0.3])
    f = _displacement_factor(gtsam, gtsam.noiseModel.Isotropic.Sigma(2, 1.0), ka, kb, r,
                             np.array([1.0, 0.2]))
    pa, pb = gtsam.Pose2(1.0, 2.0, 0.3), gtsam.Pose2(2.1, 2.3, 0.5)
    vals = gtsam.Values()
    vals.insert(ka, pa)
    vals.insert(kb, pb)
    lin = f.linearize(vals)
    A = np.asarray(lin.jacobian()[0])
    h = 1e-6
    num = np.zeros((2, 6))
    for j in range(6):
        for sign in (1, -1):
            xi = np.zeros(3)
            xi[j % 3] = sign * h
            v2 = gtsam.Values()
            v2.insert(ka, pa.retract(xi) if j < 3 else pa)
            v2.insert(kb, pb.retract(xi) if j >= 3 else pb)
            num[:, j] += sign * f.unwhitenedError(v2) / (2 * h)
    np.testing.assert_allclose(A, num, atol=1e-7)


@pytest.fixture(scope="module")
def car_scene(gtsam):
    truth, cfg, limits = kinematic_truth("car_block", "car_rtk4", cg_ahead_m=1.3)
    n = 250
    obs = noisy(truth, cfg, "gps_rtk", 7)[:n]
    p = PoseFilterParams.from_limits(limits, no_slip_point_m=(-1.3, 0.0), lag_s=2.0)
    return truth, cfg, obs, p, n


def test_peer_agrees_with_the_ekf_on_the_car(car_scene):
    """Two independent estimators on the same data and model: the GTSAM fixed-lag peer and
    the EKF fixed-lag smoother. Both within 0.5 degrees RMS of the truth (centimetre fixes
    on a 0.8 m frame) and within 2x of each other (measured 0.08 vs 0.09 degrees)."""
    from estimator.gtsam_peer import run_gtsam_peer

    truth, cfg, obs, p, n = car_scene
    t = truth.t[:n]
    off = cfg.body_positions - cfg.cg_body
    g = run_gtsam_peer(t, obs, off, p)
    ekf = fixed_lag_smooth(run_pose_filter(t, obs, off, p), t, p.lag_s).states
    start = int(np.flatnonzero(np.isfinite(g.fixed_lag[:, 0]))[0])
    assert np.isfinite(g.fixed_lag[start:, :3]).all() and np.isfinite(g.causal[start:]).sum()
    rms = {}
    for name, X in (("gtsam", g.fixed_lag), ("ekf", ekf)):
        e = np.degrees(heading_error(X[start:, 2], truth.yaw[start:n]))
        rms[name] = float(np.sqrt(np.mean(e ** 2)))
    assert max(rms.values()) < 0.5
    assert 0.5 < rms["gtsam"] / rms["ekf"] < 2.0
    assert g.update_s > 0 and set(g.status[start:]) <= {"ok", "predicted"}


def test_textbook_peer_runs_without_displacements(car_scene):
    from estimator.gtsam_peer import run_gtsam_peer

    truth, cfg, obs, p, n = car_scene
    g = run_gtsam_peer(truth.t[:80], obs[:80], cfg.body_positions - cfg.cg_body, p,
                       displacements=False)
    start = int(np.flatnonzero(np.isfinite(g.fixed_lag[:, 0]))[0])
    assert np.isfinite(g.fixed_lag[start:, :3]).all()
    # centimetre fixes: the lever-arm factors alone fix the heading to a degree
    assert np.degrees(heading_error(g.fixed_lag[start:, 2], truth.yaw[start:80])).max() < 1.0
