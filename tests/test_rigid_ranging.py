"""Rigid-body pose from ranges (issue 26): estimator.rigid_ranging (joint fit, filter,
smoother), sim.range_recording (the setup.toml reader) and experiments.rigid_ranging (scoring).

Simulated rigid bodies: 8 anchors around a 7 x 6 m room at about 1 m, three tags 0.3 m
apart (the shared 08-14 layout's size); nothing here is read from the shared runs except in
the tests marked as such, which skip when ../shared/realdata is absent.
"""

from __future__ import annotations

import gzip
import math

import numpy as np
import pytest
from scipy import stats

from estimator import rigid_ranging as rr
from experiments import rigid_ranging as score
from sim.range_recording import (
    RangeRecordingError,
    StaticReference,
    TrajectoryReference,
    load_range_recording,
)

ANCHORS = np.array([[-3.4, 3.0, 1.04], [0.0, 3.0, 1.10], [3.6, 3.0, 0.98], [3.6, 0.0, 1.06],
                    [3.5, -3.0, 1.00], [0.0, -3.0, 1.12], [-3.4, -3.0, 1.02],
                    [-3.5, 0.0, 1.05]])
BODY = np.array([[-0.07, -0.14, 0.0], [-0.075, 0.14, 0.0], [0.20, 0.145, 0.0]])
Z0 = 0.97


def ranges_at(pose, body=BODY, anchors=ANCHORS, z0=Z0):
    """(E, N, M) exact 3-D ranges for planar poses (E, 3) x, y, yaw."""
    pose = np.atleast_2d(pose)
    R = rr._rz(pose[:, 2])
    b = np.column_stack([body, np.zeros(len(body))]) if body.shape[1] == 2 else body
    tags = np.einsum("eij,nj->eni", R, b) + np.column_stack(
        [pose[:, :2], np.full(len(pose), z0)])[:, None]
    return np.linalg.norm(tags[:, :, None] - anchors[None, None], axis=3)


# ------------------------------------------------------------------------ exact recovery
def test_exact_pose_closed_form_and_joint_fit_2d():
    pose = np.array([[0.5, -1.2, 0.7], [-2.0, 1.5, -2.9], [1.0, 2.0, 3.1]])
    D = ranges_at(pose)
    pos, R, ok = rr.closed_form_start(ANCHORS, BODY, D, origin_z_m=Z0)
    assert ok.all()
    # damped_ls's tolerance is 1e-10 relative: 1e-7 m covers its stop on exact ranges
    np.testing.assert_allclose(pos[:, :2], pose[:, :2], atol=1e-7)
    np.testing.assert_allclose(np.arctan2(R[:, 1, 0], R[:, 0, 0]), pose[:, 2], atol=1e-7)
    for robust in ("none", "huber", "cauchy"):
        f = rr.fit_pose(ANCHORS, BODY, D, origin_z_m=Z0, robust=robust)
        assert list(f.status) == ["ok"] * 3
        np.testing.assert_allclose(f.pose, pose, atol=1e-9)   # Gauss-Newton to rounding
        assert np.all(f.rms_residual_m < 1e-9)


def test_exact_pose_3d():
    A = ANCHORS.copy()
    A[1::2, 2] = 2.6                                  # anchors at two heights: z observable
    body = np.vstack([BODY, [0.05, 0.0, 0.3]])        # four tags, not coplanar
    R = rr._rotvec(np.array([[0.1, -0.2, 0.9]]))[0]
    t = np.array([0.4, -0.8, 1.2])
    D = np.linalg.norm(((R @ body.T).T + t)[:, None] - A[None], axis=2)
    pos, _R0, ok = rr.closed_form_start(A, body, D, dim=3)
    assert ok.all()
    np.testing.assert_allclose(pos[0], t, atol=1e-6)
    f = rr.fit_pose(A, body, D, dim=3, robust="none")
    assert f.status[0] == "ok"
    np.testing.assert_allclose(f.position[0], t, atol=1e-9)
    np.testing.assert_allclose(f.rotation[0], R, atol=1e-9)


def test_any_subset_of_ranges_and_too_few():
    pose = np.array([0.3, 0.4, 1.0])
    D = ranges_at(pose)[0]
    D[0, [1, 4, 6]] = np.nan          # tag 0 keeps 5 anchors, tag 2 only two
    D[2, 2:] = np.nan
    f = rr.fit_pose(ANCHORS, BODY, D, origin_z_m=Z0, robust="none")
    assert f.status[0] == "ok"
    np.testing.assert_allclose(f.pose[0], pose, atol=1e-9)
    D2 = np.full_like(D, np.nan)
    D2[0, :2] = D[0, :2]
    D2[1, 0] = ranges_at(pose)[0][1, 0]
    f = rr.fit_pose(ANCHORS, BODY, D2, origin_z_m=Z0)
    assert f.status[0] == "insufficient_data" and np.isnan(f.pose).all()


# ----------------------------------------------------------------------- noise: the CRB
def numeric_jacobian(pose, h=1e-6):
    """(K, 3) d ranges / d (x, y, yaw) at ``pose`` by central differences (independent of
    the estimator's analytic Jacobian)."""
    cols = []
    for i in range(3):
        d = np.zeros(3)
        d[i] = h
        cols.append(((ranges_at(pose + d) - ranges_at(pose - d)) / (2 * h)).ravel())
    return np.column_stack(cols)


def numeric_crb(pose, sigma):
    J = numeric_jacobian(pose)
    return sigma ** 2 * np.linalg.inv(J.T @ J)


def test_monte_carlo_spread_matches_the_fisher_information():
    """Plain least squares is efficient here: the sample covariance of 400 fits of noisy
    ranges matches sigma^2 (J'J)^-1 at the true pose. A sample variance of n Gaussian draws
    has relative standard deviation sqrt(2 / (n - 1)) = 0.071; the tolerance is 4 of them."""
    rng = np.random.default_rng(7)
    n, sigma = 400, 0.02
    pose = np.array([0.8, -0.6, 0.4])
    D = ranges_at(pose)[0] + rng.normal(0, sigma, (n, 3, 8))
    f = rr.fit_pose(ANCHORS, BODY, D, origin_z_m=Z0, robust="none", sigma_m=sigma,
                    mirror_check=False)
    crb = numeric_crb(pose, sigma)
    fitted = rr.fit_pose(ANCHORS, BODY, ranges_at(pose)[0], origin_z_m=Z0, robust="none",
                         sigma_m=sigma).covariance[0]
    # the fit's covariance is the CRB (its Jacobian is right): central differences carry
    # O(h^2) = 1e-12 relative error, far below 1e-6
    np.testing.assert_allclose(fitted, crb, rtol=1e-6, atol=1e-15)
    err = f.pose - pose
    err[:, 2] = rr.wrap_angle(err[:, 2])
    var = err.var(axis=0, ddof=1)
    tol = 4 * math.sqrt(2 / (n - 1))
    np.testing.assert_allclose(var / np.diag(crb), 1.0, atol=tol)
    # no bias beyond 4 standard errors of the mean
    assert np.all(np.abs(err.mean(axis=0)) < 4 * np.sqrt(np.diag(crb) / n))
    # Huber (95 % efficiency at Gaussian noise): variance at most 1 / 0.95 x CRB + tolerance
    fh = rr.fit_pose(ANCHORS, BODY, D, origin_z_m=Z0, robust="huber", sigma_m=sigma,
                     mirror_check=False)
    eh = fh.pose - pose
    eh[:, 2] = rr.wrap_angle(eh[:, 2])
    assert np.all(eh.var(axis=0, ddof=1) / np.diag(crb) < 1 / 0.95 + tol)


def test_robust_fit_ignores_a_spike_that_moves_the_baseline():
    rng = np.random.default_rng(2)
    pose = np.array([1.0, 0.5, -0.3])
    D = ranges_at(pose)[0] + rng.normal(0, 0.02, (3, 8))
    D[1, 3] += 1.5                                     # one spike of 1.5 m
    base = rr.fit_pose(ANCHORS, BODY, D, origin_z_m=Z0, robust="none", sigma_m=0.02)
    rob = rr.fit_pose(ANCHORS, BODY, D, origin_z_m=Z0, robust="huber", sigma_m=0.02)
    eb = np.hypot(*(base.pose[0, :2] - pose[:2]))
    er = np.hypot(*(rob.pose[0, :2] - pose[:2]))
    assert eb > 0.05 and er < 0.5 * eb


# -------------------------------------------------------------------------- bias state
@pytest.mark.parametrize("mode", ["common", "anchor"])
def test_bias_state_recovered_exactly(mode):
    pose = np.array([-0.4, 1.1, 2.0])
    bias = 0.17 if mode == "common" else np.linspace(0.05, 0.25, 8)
    D = ranges_at(pose)[0] + bias
    f = rr.fit_pose(ANCHORS, BODY, D, origin_z_m=Z0, bias=mode, robust="none")
    assert f.status[0] == "ok"
    np.testing.assert_allclose(f.pose[0], pose, atol=1e-8)
    np.testing.assert_allclose(f.bias[0], np.broadcast_to(bias, f.bias[0].shape), atol=1e-8)
    # without the state the same ranges leave a pose error
    g = rr.fit_pose(ANCHORS, BODY, D, origin_z_m=Z0, robust="none")
    assert np.hypot(*(g.pose[0, :2] - pose[:2])) > 1e-3


def test_bias_state_noisy_within_its_covariance():
    rng = np.random.default_rng(5)
    n, sigma = 300, 0.02
    pose = np.array([0.2, -0.3, 0.5])
    D = ranges_at(pose)[0] + 0.15 + rng.normal(0, sigma, (n, 3, 8))
    f = rr.fit_pose(ANCHORS, BODY, D, origin_z_m=Z0, bias="common", robust="none",
                    sigma_m=sigma, mirror_check=False)
    sd = np.sqrt(f.covariance[:, 3, 3])
    z = (f.bias[:, 0] - 0.15) / sd
    # standardised errors: mean 0 within 4 / sqrt(n), variance 1 within 4 sqrt(2 / n)
    assert abs(z.mean()) < 4 / math.sqrt(n)
    assert abs(z.var() - 1) < 4 * math.sqrt(2 / n)


# ------------------------------------------------------------------------ mirror checks
def test_mirror_pose_reported_for_collinear_anchors():
    line = np.array([[-3.0, 0, 1.0], [0.0, 0, 1.2], [3.0, 0, 0.8], [5.0, 0, 1.1]])
    two = np.array([[0.0, -0.2], [0.0, 0.2]])
    pose = np.array([0.5, 2.0, 0.3])
    f = rr.fit_pose(line, two, ranges_at(pose, two, line)[0], origin_z_m=Z0, robust="none")
    assert f.status[0] == "ambiguous"
    got = {tuple(np.round(f.pose[0], 6)), tuple(np.round(f.alternative[0], 6))}
    mirror = (0.5, -2.0, round(float(rr.wrap_angle(math.pi - 0.3)), 6))
    assert got == {tuple(np.round(pose, 6)), mirror}
    # three tags: the proper pose is unique, but the mirrored layout fits as well
    f3 = rr.fit_pose(line, BODY, ranges_at(pose, BODY, line)[0], origin_z_m=Z0, robust="none")
    assert f3.status[0] == "mirror_ambiguous"
    np.testing.assert_allclose(f3.pose[0], pose, atol=1e-8)


def test_mirrored_layout_detected_and_good_geometry_ok():
    pose = np.array([0.5, 1.0, 0.3])
    D = ranges_at(pose)[0]
    assert rr.fit_pose(ANCHORS, BODY, D, origin_z_m=Z0).status[0] == "ok"
    wrong = BODY * [1, -1, 1]                          # tags given with the wrong handedness
    assert rr.fit_pose(ANCHORS, wrong, D, origin_z_m=Z0, robust="none").status[0] == "mirrored"


@pytest.mark.parametrize("kw, field", [
    ({"anchors": np.zeros((2, 3))}, "anchors"),
    ({"body": np.zeros((1, 2))}, "body"),
    ({"ranges": np.ones((3, 7))}, "ranges"),
    ({"ranges": -np.ones((3, 8))}, "ranges"),
    ({"robust": "l1"}, "robust"),
    ({"bias": "pair"}, "bias"),
    ({"dim": 4}, "dim"),
    ({"sigma_m": 0.0}, "sigma_m"),
])
def test_fit_pose_validation_names_the_field(kw, field):
    args = {"anchors": ANCHORS, "body": BODY, "ranges": np.ones((3, 8))}
    args.update({k: v for k, v in kw.items() if k in args})
    rest = {k: v for k, v in kw.items() if k not in args}
    with pytest.raises(ValueError, match=field):
        rr.fit_pose(args["anchors"], args["body"], args["ranges"], **rest)


# ---------------------------------------------------------------------------- the filter
CFG = rr.FilterConfig(sigma_range_m=0.05, q_accel=0.5, q_yaw_accel=0.5, q_bias=0.0,
                      init_sigma_bias_m=0.3)


def driven_body(rng, seconds=4.0, rate=50.0, cfg=CFG, bias=0.1):
    """A rigid body driven by white acceleration of the filter's own spectral densities
    (the model the filter assumes), ranges at ``rate`` Hz with the filter's noise."""
    dt = 1 / rate
    n = int(seconds * rate)
    t = np.arange(n) * dt
    x = np.zeros((n, 6))
    x[0] = [0.5, -0.5, 0.3, 0.4, 0.2, 0.3]
    for k in range(1, n):      # exact discretisation of the white-acceleration model
        for p, v, q in ((0, 3, cfg.q_accel), (1, 4, cfg.q_accel), (2, 5, cfg.q_yaw_accel)):
            Q = q * np.array([[dt ** 3 / 3, dt ** 2 / 2], [dt ** 2 / 2, dt]])
            w = rng.multivariate_normal([0, 0], Q)
            x[k, p] = x[k - 1, p] + dt * x[k - 1, v] + w[0]
            x[k, v] = x[k - 1, v] + w[1]
    D = ranges_at(x[:, :3]) + bias + rng.normal(0, cfg.sigma_range_m, (n, 3, 8))
    return t, x[:, :3], D


def run_filter(t, D, cfg=CFG):
    f = rr.fit_pose(ANCHORS, BODY, D, origin_z_m=Z0, bias="common", sigma_m=0.05,
                    mirror_check=False)
    ts, tag, anc, r = rr.grid_to_stream(t, D)
    return rr.track(ANCHORS, BODY, ts, tag, anc, r, t, f.pose, init_bias=f.bias[:, 0],
                    origin_z_m=Z0, config=cfg)


def test_filter_nees_and_nis_in_chi_square_band():
    """30 independent runs; NEES (3 dof) at the last epoch of each run: the sum over runs is
    chi-square(90) if the filter is consistent (two-sided 99 % band). NIS of every accepted
    update: mean 1 within 4 standard errors of the run's NIS values (each chi-square(1))."""
    rng = np.random.default_rng(11)
    runs, last, nis = 30, [], []
    for _ in range(runs):
        t, truth, D = driven_body(rng)
        res = run_filter(t, D)
        assert res.segment.max() == 0                  # never re-initialised
        last.append(rr.nees(res, t, truth)[-1])
        nis.append(res.nis[res.accepted])
    lo, hi = stats.chi2.ppf([0.005, 0.995], 3 * runs)
    assert lo < np.sum(last) < hi
    allnis = np.concatenate(nis)
    assert abs(allnis.mean() - 1) < 4 * math.sqrt(2 / allnis.size) + 0.02
    # the 0.02: the EKF's linearisation of ranges at ~3 m over 5 cm noise (measured 0.99-1.01)


def test_filter_recovers_from_a_jump_and_smoother_improves():
    rng = np.random.default_rng(4)
    t, truth, D = driven_body(rng, seconds=6.0)
    jumped = truth.copy()
    jumped[150:, 0] += 1.5                             # the body is carried 1.5 m at 3 s
    D2 = ranges_at(jumped) + 0.1 + rng.normal(0, 0.05, D.shape)
    res = run_filter(t, D2)
    assert res.segment.max() >= 1                      # re-initialised after the jump
    e = np.hypot(*(res.pose[:, :2] - jumped[:, :2]).T)
    assert np.all(e[200:] < 0.1)                       # back on track 1 s after the jump
    # a 5 s gap in the ranges: re-initialised at the first epoch after it
    t3, D3 = np.concatenate([t[t < 2.0], t[t >= 2.0] + 5.0]), D
    res = run_filter(t3, D3)
    assert res.reinit[np.searchsorted(res.times, 7.0)] and res.segment.max() == 1
    # smoother: lower RMSE than the filter on the un-jumped run
    res = run_filter(t, D)
    sm = rr.smooth(res)
    ef = np.hypot(*(res.pose[:, :2] - truth[:, :2]).T)[25:]
    es = np.hypot(*(sm.pose[:, :2] - truth[:, :2]).T)[25:]
    assert np.sqrt(np.mean(es ** 2)) < 0.8 * np.sqrt(np.mean(ef ** 2))


def test_filter_one_update_and_one_predict_match_a_numpy_ekf():
    """Two epochs with one range each against a plain numpy EKF with a numerical range
    Jacobian (central differences, error ~1e-12): the unrolled scalar code must agree to
    1e-9."""
    cfg = rr.FilterConfig(sigma_range_m=0.05, q_accel=0.7, q_yaw_accel=0.4, q_bias=1e-4,
                          init_sigma_bias_m=0.2)
    x0 = np.array([0.5, -0.3, 0.8, 0.0, 0.0, 0.0, 0.1])
    t = np.array([0.0, 0.25])
    tag, anc, r = np.array([2, 1]), np.array([3, 6]), np.array([3.9, 4.4])
    res = rr.track(ANCHORS, BODY, t, tag, anc, r, [0.0], [x0[:3]], init_bias=[x0[6]],
                   origin_z_m=Z0, config=cfg)

    def h(x, n, m):
        return ranges_at(x[:3])[0][n, m] + x[6]

    def update(x, P, n, m, z):
        H = np.zeros(7)
        for i in range(7):
            d = np.zeros(7)
            d[i] = 1e-6
            H[i] = (h(x + d, n, m) - h(x - d, n, m)) / 2e-6
        S = H @ P @ H + cfg.sigma_range_m ** 2
        K = P @ H / S
        return x + K * (z - h(x, n, m)), P - np.outer(K, H @ P)

    P = np.diag([0.1 ** 2, 0.1 ** 2, 0.1 ** 2, 1.0, 1.0, 1.0, 0.2 ** 2])
    x, P = update(x0, P, 2, 3, 3.9)
    np.testing.assert_allclose(res.state_post[0], x, atol=1e-9)
    np.testing.assert_allclose(res.cov_post[0], P, atol=1e-9)
    dt = 0.25
    F = np.eye(7)
    F[0, 3] = F[1, 4] = F[2, 5] = dt
    Q = np.zeros((7, 7))
    for p, v, q in ((0, 3, cfg.q_accel), (1, 4, cfg.q_accel), (2, 5, cfg.q_yaw_accel)):
        Q[np.ix_([p, v], [p, v])] = q * np.array([[dt ** 3 / 3, dt ** 2 / 2], [dt ** 2 / 2, dt]])
    Q[6, 6] = cfg.q_bias * dt
    x, P = F @ x, F @ P @ F.T + Q
    np.testing.assert_allclose(res.state_pred[1], x, atol=1e-9)
    np.testing.assert_allclose(res.cov_pred[1], P, atol=1e-9)
    x, P = update(x, P, 1, 6, 4.4)
    np.testing.assert_allclose(res.state_post[1], x, atol=1e-9)
    np.testing.assert_allclose(res.cov_post[1], P, atol=1e-9)


def test_filter_update_time():
    """Written for speed (scalar locals, no per-update allocation): on an idle core one update
    takes ~6 us; the bound 20 us is issue 26's target, x3 for the shared 2-core machine."""
    rng = np.random.default_rng(1)
    t, _, D = driven_body(rng, seconds=4.0, rate=100.0)
    best = min(run_filter(t, D).seconds / D.size for _ in range(3))
    assert best < 60e-6


def test_filter_input_validation():
    with pytest.raises(ValueError, match="t: must be non-decreasing"):
        rr.track(ANCHORS, BODY, [1.0, 0.5], [0, 0], [0, 1], [1.0, 1.0], [0.0],
                 [[0.0, 0.0, 0.0]])
    with pytest.raises(ValueError, match="anchor"):
        rr.track(ANCHORS, BODY, [0.0], [0], [8], [1.0], [0.0], [[0.0, 0.0, 0.0]])
    with pytest.raises(ValueError, match="gate_sigma"):
        rr.FilterConfig(gate_sigma=0.0)


# ---------------------------------------------------------------------------- the reader
SETUP = """
[body]
origin_z_m = 0.97
[anchors]
a0 = [0.0, 0.0, 1.0]
a1 = [4.0, 0.0, 1.0]
a2 = [0.0, 4.0, 1.0]
[tags]
t0 = [0.1, 0.0, 0.0]
t1 = [-0.1, 0.0, 0.0]
[ranges]
file = "ranges.csv"
header_rows = 0
time_column = 0
time_format = "%Y-%m-%d %H:%M:%S.%f"
missing = "empty field"
columns = [["a0", "t0"], ["a0", "t1"], ["a1", "t0"], ["a1", "t1"], ["a2", "t0"], ["a2", "t1"]]
[calibration]
bias_m = [0.1, 0.1, 0.2, 0.2, 0.0, 0.0]
slope = [0.0, 0.0, 0.0, 0.0, 1.0, 1.0]
"""
STATIC = '[reference]\nkind = "static"\nx_m = 1.0\ny_m = 2.0\nyaw_deg = 90.0\n'
ROWS = ["2022-08-15 9:42:24.766,1,2,3,4,5,6,",
        "2022-08-15 9:42:24.776,1.5,2,3,4,,,",      # last anchor block empty: left-shifted
        "2022-08-15 9:42:24.786,1,,3,4,5,6,"]


def write_run(tmp_path, setup=SETUP + STATIC, rows=ROWS):
    (tmp_path / "setup.toml").write_text(setup)
    (tmp_path / "ranges.csv").write_text("\n".join(rows) + "\n")
    return tmp_path


def test_reader_arrays(tmp_path):
    rec = load_range_recording(write_run(tmp_path))
    np.testing.assert_allclose(np.diff(rec.times), [0.01, 0.01], atol=1e-6)
    assert rec.ranges.shape == (3, 2, 3) and rec.tag_names == ("t0", "t1")
    np.testing.assert_array_equal(rec.ranges[0], [[1, 3, 5], [2, 4, 6]])
    assert rec.dropped_rows.tolist() == [False, True, False]
    assert np.isnan(rec.ranges[1]).all()
    assert np.isnan(rec.ranges[2, 1, 0]) and rec.ranges[2, 0, 0] == 1     # mid-row missing
    assert rec.reference == StaticReference(1.0, 2.0, math.pi / 2)
    cal = load_range_recording(tmp_path, calibrate=True)
    np.testing.assert_allclose(cal.ranges[0], [[0.9, 2.8, 2.5], [1.9, 3.8, 3.0]])
    keep = load_range_recording(tmp_path, trailing_missing="keep")
    assert keep.ranges[1, 0, 0] == 1.5 and not keep.dropped_rows.any()


def test_reader_trajectory_quaternion_and_gzip(tmp_path):
    yaw_x = np.radians([10.0, 20.0])
    # motion-capture body frame = tag frame turned 180 deg about x: q = q_z(yaw) * q_x(pi)
    q = [(0.0 * math.cos(a / 2), math.cos(a / 2), math.sin(a / 2), 0.0) for a in yaw_x]
    lines = ["time,x,y,z,rotation,,,"] + [
        f"2022-08-15 9:42:2{4 + k}.000,{k},0,0.97,{qq[0]},{qq[1]},{qq[2]},{qq[3]}"
        for k, qq in enumerate(q)]
    with gzip.open(tmp_path / "ref.csv.gz", "wt") as fh:
        fh.write("\n".join(lines) + "\n")
    ref = ('[reference]\nkind = "trajectory"\nfile = "ref.csv.gz"\nheader_rows = 1\n'
           'time_column = 0\ntime_format = "%Y-%m-%d %H:%M:%S.%f"\n'
           'columns = ["time", "x", "y", "z", "qw", "qx", "qy", "qz"]\nyaw_offset_deg = 7.0\n')
    rec = load_range_recording(write_run(tmp_path, SETUP + ref))
    assert isinstance(rec.reference, TrajectoryReference)
    np.testing.assert_allclose(np.degrees(rec.reference.yaw), [17.0, 27.0], atol=1e-9)
    np.testing.assert_allclose(rec.reference.xyz[:, 0], [0, 1])


@pytest.mark.parametrize("edit, field", [
    (lambda s: s.replace('file = "ranges.csv"', 'file = "../ranges.csv"'), "file"),
    (lambda s: s.replace('file = "ranges.csv"', 'file = "/etc/passwd"'), "file"),
    (lambda s: s.replace('["a2", "t1"]', '["a9", "t1"]'), r"columns\[5\]"),
    (lambda s: s.replace('time_format = "%Y-%m-%d %H:%M:%S.%f"', 'time_format = "%H:%M"'),
     "time_format"),
    (lambda s: s.replace("origin_z_m = 0.97", 'origin_z_m = "high"'), "origin_z_m"),
    (lambda s: s.replace("a2 = [0.0, 4.0, 1.0]", "a2 = [0.0, 4.0]"), "a2"),
    (lambda s: s.replace("slope = [0.0, 0.0, 0.0, 0.0, 1.0, 1.0]", "slope = [0.0]"), "slope"),
    (lambda s: s.replace('kind = "static"', 'kind = "moving"'), "kind"),
    (lambda s: s.replace("yaw_deg = 90.0", ""), "yaw_deg"),
    (lambda s: s.replace("[tags]\nt0 = [0.1, 0.0, 0.0]\n", "[tags]\n"), r"\[tags\]"),
])
def test_reader_validation_names_the_field(tmp_path, edit, field):
    write_run(tmp_path, edit(SETUP + STATIC))
    with pytest.raises(RangeRecordingError, match=field):
        load_range_recording(tmp_path)


def test_reader_rejects_bad_rows(tmp_path):
    write_run(tmp_path, rows=ROWS + ["2022-08-15 9:42:24.796,1,2,3,4,5,6,7"])
    with pytest.raises(RangeRecordingError, match="columns"):          # 7th data column
        load_range_recording(tmp_path)
    write_run(tmp_path, rows=ROWS + ["2022-08-15 9:42:24.796,1,x,3,4,5,6"])
    with pytest.raises(RangeRecordingError, match="not a number"):
        load_range_recording(tmp_path)
    write_run(tmp_path, rows=ROWS[::-1])
    with pytest.raises(RangeRecordingError, match="time_column"):
        load_range_recording(tmp_path)


# ----------------------------------------------------------------------------- scoring
def test_clock_offset_recovered():
    rng = np.random.default_rng(3)
    t = np.arange(0, 20, 0.01)
    truth = np.column_stack([np.cos(0.5 * t), np.sin(0.7 * t), 0.5 * t])
    ref = TrajectoryReference(t + 0.137, np.column_stack([truth[:, :2], np.zeros(t.size)]),
                              rr.wrap_angle(truth[:, 2]))
    est = truth + rng.normal(0, 0.01, truth.shape)
    fields, _ = score.score_trajectory(t, est, ref)
    # 1 cm noise on 2000 epochs at ~0.7 m/s: the offset is fixed to well under 1 ms
    assert abs(fields["clock_offset_s"] - 0.137) < 1e-3
    assert fields["rmse_2d_m"] < 0.02 and fields["coverage"] > 0.98


def test_cli_end_to_end_on_a_simulated_static_run(tmp_path):
    rng = np.random.default_rng(9)
    pose = np.array([0.4, -0.2, 0.6])
    D = ranges_at(pose, anchors=ANCHORS)[0] + 0.15
    names = [f"a{m}" for m in range(8)]
    setup = ["[body]", f"origin_z_m = {Z0}", "[anchors]"]
    setup += [f"a{m} = [{a[0]}, {a[1]}, {a[2]}]" for m, a in enumerate(ANCHORS)]
    setup += ["[tags]"] + [f"t{n} = [{b[0]}, {b[1]}, {b[2]}]" for n, b in enumerate(BODY)]
    cols = [[a, f"t{n}"] for a in names for n in range(3)]
    setup += ["[ranges]", 'file = "r.csv"', 'time_format = "seconds"',
              "columns = " + str(cols).replace("'", '"'),
              '[reference]', 'kind = "static"', f"x_m = {pose[0]}", f"y_m = {pose[1]}",
              f"yaw_deg = {math.degrees(pose[2])}"]
    run = tmp_path / "run"
    run.mkdir()
    (run / "setup.toml").write_text("\n".join(setup) + "\n")
    rows = [",".join([f"{0.01 * k:.2f}"] + [f"{D[n, m] + rng.normal(0, 0.03):.3f}"
                                           for m in range(8) for n in range(3)])
            for k in range(200)]
    (run / "r.csv").write_text("\n".join(rows) + "\n")
    assert score.main([str(run), "--out", str(tmp_path / "out")]) == 0
    import pandas as pd
    tab = pd.read_csv(tmp_path / "out" / "summary.csv")
    assert tuple(tab.columns) == score.COLUMNS
    assert list(tab.method) == list(score.METHODS)
    by = tab.set_index("method")
    # the bias state removes the 0.15 m offset the baseline cannot
    assert by.loc["robust_bias", "rmse_2d_m"] < by.loc["baseline", "rmse_2d_m"]
    assert {p.name for p in (tmp_path / "out").rglob("*.png")} == {"errors.png",
                                                                    "trajectory.png"}
    assert score.main([str(tmp_path / "nothing"), "--out", str(tmp_path / "o2")]) == 2
    # the ranging CLI hands a folder with a setup.toml to this scorer
    from experiments import ranging
    assert ranging.main([str(run), "--out", str(tmp_path / "o3"), "--no-figures"]) == 0
    assert (tmp_path / "o3" / "summary.csv").is_file()


# ------------------------------------------------------------------- the shared runs
def test_shared_runs_read(realdata_dir):
    root = realdata_dir / "uwb_rigid"
    if not root.is_dir():
        pytest.skip("../shared/realdata/uwb_rigid is absent")
    runs = sorted(p.parent for p in root.glob("*/*/setup.toml"))
    assert len(runs) == 13
    for d in runs:
        rec = load_range_recording(d)
        assert rec.ranges.shape[1:] == (3, 8)
        assert rec.dropped_rows.sum() <= 10             # left-shifted rows, counted in all 13


@pytest.mark.slow
def test_shared_runs_targets(realdata_dir, tmp_path):
    """Issue 26's targets on the 13 shared runs (about 15 min on the shared machine): the
    named method (``smoother``) below the baseline in position and yaw RMSE on >= 80 % of
    runs, and no static run with a 2-D error over 1 m at any epoch (every method but the
    baseline)."""
    root = realdata_dir / "uwb_rigid"
    if not root.is_dir():
        pytest.skip("../shared/realdata/uwb_rigid is absent")
    runs = sorted(p.parent for p in root.glob("*/*/setup.toml"))
    tab = score.run(runs, tmp_path, figures=False)
    wins = 0
    for _, g in tab.groupby("run"):
        by = g.set_index("method")
        wins += (by.loc["smoother", "rmse_2d_m"] < by.loc["baseline", "rmse_2d_m"]) and (
            by.loc["smoother", "yaw_rmse_deg"] < by.loc["baseline", "yaw_rmse_deg"])
    assert wins >= 0.8 * tab.run.nunique()
    static = tab[tab.run.str.startswith("static") & (tab.method != "baseline")]
    assert (static.max_error_2d_m <= 1.0).all()
