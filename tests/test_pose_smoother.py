"""Smoothers (estimator.pose_smoother) against FilterPy's rts_smoother and a batch solution.

A linear-Gaussian system run through FilterPy's KalmanFilter gives the forward pass; the
clone quantities the smoother reads (the previous state re-estimated with each epoch's
data and the cross-covariance) come from the textbook joint update of (x_k, x_{k-1}),
written out here. rts_smooth must equal FilterPy's rts_smoother; the fixed-lag smoother
must equal FilterPy's rts_smoother run on the data up to each epoch's lag end. On the pose
filter itself: lag 0 is the filter, an unbounded lag the RTS smoother, segments are not
crossed.
"""

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter, rts_smoother
from hypothesis import given, settings
from hypothesis import strategies as st
from pose_scenes import kinematic_truth, noisy

from estimator.metrics import heading_error
from estimator.pose_filter import NX, PoseFilterParams, PoseFilterResult, run_pose_filter
from estimator.pose_smoother import fixed_lag_smooth, rts_smooth, smoothed_heading


def _linear_system(n=60, seed=0):
    """A 6-state linear system (constant acceleration in x and y, a slowly turning 'yaw'
    channel kept small so that wrapping never acts) observed in 4 of its states."""
    rng = np.random.default_rng(seed)
    dt = 0.5
    F = np.eye(NX)
    F[0, 3], F[0, 4], F[3, 4] = dt, 0.5 * dt * dt, dt
    F[1, 5] = dt
    G = rng.normal(0, 0.3, (NX, 3))
    G[2] *= 0.01                      # the heading channel stays within (-pi, pi]
    Q = G @ G.T + 1e-3 * np.eye(NX)
    Q[2, 2] = 1e-6 + G[2] @ G[2]
    H = np.zeros((4, NX))
    H[0, 0], H[1, 1], H[2, 2], H[3, 3] = 1, 1, 1, 1
    R = np.diag([0.5, 0.4, 0.0004, 0.3])
    x = np.zeros(NX)
    zs = []
    for _ in range(n):
        x = F @ x + rng.multivariate_normal(np.zeros(NX), Q)
        zs.append(H @ x + rng.multivariate_normal(np.zeros(4), R))
    return F, Q, H, R, np.array(zs)


def _forward(F, Q, H, R, zs, x0, P0):
    """FilterPy forward pass plus the clone quantities of each epoch (joint update)."""
    kf = KalmanFilter(dim_x=NX, dim_z=4)
    kf.F, kf.Q, kf.H, kf.R = F, Q, H, R
    kf.x, kf.P = x0.copy(), P0.copy()
    n = len(zs)
    X = np.empty((n, NX))
    P = np.empty((n, NX, NX))
    XC = np.full((n, NX), np.nan)
    PC = np.full((n, NX, NX), np.nan)
    B = np.full((n, NX, NX), np.nan)
    for k, z in enumerate(zs):
        xprev, Pprev = kf.x.copy(), kf.P.copy()
        kf.predict()
        # the joint of (x_k, x_{k-1}) before and after this epoch's measurement
        Y = np.block([[kf.P, F @ Pprev], [Pprev @ F.T, Pprev]])
        yv = np.r_[kf.x, xprev]
        Hy = np.c_[H, np.zeros((4, NX))]
        S = Hy @ Y @ Hy.T + R
        K = Y @ Hy.T @ np.linalg.inv(S)
        yv = yv + K @ (z - Hy @ yv)
        Y = Y - K @ S @ K.T
        kf.update(z)
        X[k], P[k] = kf.x, kf.P
        np.testing.assert_allclose(yv[:NX], kf.x, atol=1e-10)
        if k:
            XC[k], PC[k], B[k] = yv[NX:], Y[NX:, NX:], Y[:NX, NX:]
    seg = np.zeros(n, dtype=bool)
    seg[0] = True
    res = PoseFilterResult(states=X, covariances=P, prev_states=XC, prev_covariances=PC,
                           cross_covariances=B, segment_start=seg, status=np.full(n, "ok"),
                           n_used=np.zeros(n, int), n_gated=np.zeros(n, int),
                           n_steps=np.zeros(n, int), sigma_abs_m=1.0, sigma_step_m=1.0)
    return res, kf


def test_rts_matches_filterpy_rts_smoother():
    F, Q, H, R, zs = _linear_system()
    x0, P0 = np.zeros(NX), np.eye(NX)
    res, _ = _forward(F, Q, H, R, zs, x0, P0)
    assert np.abs(res.states[:, 2]).max() < 1.0          # no wrapping in this check
    xs, Ps, _, _ = rts_smoother(res.states, res.covariances, Fs=[F] * len(zs),
                                Qs=[Q] * len(zs))
    sm = rts_smooth(res, reverse=True)
    # the same recursion in two algebraic forms: agreement to rounding (values O(1-10))
    np.testing.assert_allclose(sm.states, xs, rtol=0, atol=1e-9)
    np.testing.assert_allclose(sm.covariances, Ps, rtol=0, atol=1e-9)


@pytest.mark.parametrize("lag_s", [0.0, 1.0, 2.6, 10.0, 1e9])
def test_fixed_lag_matches_rts_on_the_data_up_to_the_lag(lag_s):
    """Epoch k's fixed-lag estimate = FilterPy's rts_smoother on epochs 0..j, at k, with j
    the last epoch within lag_s of k (dt = 0.5 s)."""
    F, Q, H, R, zs = _linear_system(n=40, seed=1)
    x0, P0 = np.zeros(NX), np.eye(NX)
    res, _ = _forward(F, Q, H, R, zs, x0, P0)
    t = 0.5 * np.arange(40)
    fl = fixed_lag_smooth(res, t, lag_s, reverse=True).states
    for k in range(40):
        j = int(np.searchsorted(t, t[k] + lag_s, side="right")) - 1
        xs, _, _, _ = rts_smoother(res.states[:j + 1], res.covariances[:j + 1],
                                   Fs=[F] * (j + 1), Qs=[Q] * (j + 1))
        np.testing.assert_allclose(fl[k], xs[k], rtol=0, atol=1e-9)


def test_smoothers_do_not_cross_a_segment_start():
    F, Q, H, R, zs = _linear_system(n=30, seed=2)
    res, _ = _forward(F, Q, H, R, zs, np.zeros(NX), np.eye(NX))
    seg = res.segment_start.copy()
    seg[15] = True
    cut = PoseFilterResult(**{**res.__dict__, "segment_start": seg})
    sm = rts_smooth(cut, reverse=True).states
    first, _ = _forward(F, Q, H, R, zs[:15], np.zeros(NX), np.eye(NX))
    np.testing.assert_allclose(sm[:15], rts_smooth(first, reverse=True).states, atol=1e-12)
    fl = fixed_lag_smooth(cut, 0.5 * np.arange(30), 100.0, reverse=True).states
    np.testing.assert_allclose(fl[:15], sm[:15], atol=1e-12)
    assert np.array_equal(sm[29], res.states[29])        # the last epoch is the filter's


def test_a_row_without_output_does_not_blank_the_rows_before_it():
    """Issue 23: a forward row that is NaN although the next row holds a clone (what the
    filter wrote at a lost track) used to turn every earlier row of the segment NaN (a NaN
    gain). The rows before it are smoothed with their own data, exactly as a pass that ends
    there; the rows after it are the next stretch's (here the filter's: no segment start,
    no link back)."""
    F, Q, H, R, zs = _linear_system(n=30, seed=4)
    res, _ = _forward(F, Q, H, R, zs, np.zeros(NX), np.eye(NX))
    X, Pc = res.states.copy(), res.covariances.copy()
    X[15], Pc[15] = np.nan, np.nan                 # row 15 lost; row 16 keeps its clone
    lost = PoseFilterResult(**{**res.__dict__, "states": X, "covariances": Pc})
    first, _ = _forward(F, Q, H, R, zs[:15], np.zeros(NX), np.eye(NX))
    want = rts_smooth(first, reverse=True)
    for sm in (rts_smooth(lost, reverse=True).states,
               fixed_lag_smooth(lost, 0.5 * np.arange(30), 1e6, reverse=True).states):
        assert np.isfinite(sm[:15]).all() and np.isnan(sm[15]).all()
        np.testing.assert_allclose(sm[:15], want.states, rtol=0, atol=1e-12)
    np.testing.assert_allclose(rts_smooth(lost, reverse=True).covariances[:15],
                               want.covariances, rtol=0, atol=1e-12)


def test_a_singular_covariance_ends_the_stretch_instead_of_failing():
    """A singular P_{k+1} (no gain) cuts the recursion there; nothing raises."""
    F, Q, H, R, zs = _linear_system(n=20, seed=5)
    res, _ = _forward(F, Q, H, R, zs, np.zeros(NX), np.eye(NX))
    Pc = res.covariances.copy()
    Pc[10] = 0.0
    cut = PoseFilterResult(**{**res.__dict__, "covariances": Pc})
    sm = rts_smooth(cut, reverse=True)
    assert np.isfinite(sm.states).all()
    first, _ = _forward(F, Q, H, R, zs[:10], np.zeros(NX), np.eye(NX))
    np.testing.assert_allclose(sm.states[:10], rts_smooth(first, reverse=True).states,
                               rtol=0, atol=1e-12)


# ---------------------------------------------------------------- on the pose filter
@pytest.fixture(scope="module")
def car_pass():
    truth, cfg, limits = kinematic_truth("car_block", "car_rtk4", cg_ahead_m=1.3)
    n = 300
    obs = noisy(truth, cfg, "gps_rtk", 5)[:n]
    p = PoseFilterParams.from_limits(limits, no_slip_point_m=(-1.3, 0.0))
    res = run_pose_filter(truth.t[:n], obs, cfg.body_positions - cfg.cg_body, p)
    return truth, cfg, obs, res, p


def test_fixed_lag_limits_are_the_filter_and_the_rts_smoother(car_pass):
    """Lag 0 is the filter; a lag beyond the recording is the RTS smoother, to 1e-10: the
    fixed-lag smoother sums each 6-term product with numpy's einsum, the compiled RTS
    recursion in a plain loop, and the rounding is carried back over ~300 epochs (measured
    1.9e-12 on the acceleration, 1e-12 against the numpy RTS loop)."""
    truth, _, _, res, _ = car_pass
    t = truth.t[:300]
    np.testing.assert_array_equal(fixed_lag_smooth(res, t, 0.0).states, res.states)
    for engine in ("numpy", "numba"):
        np.testing.assert_allclose(fixed_lag_smooth(res, t, 1e6).states,
                                   rts_smooth(res, engine=engine).states, rtol=0, atol=1e-10)


def test_smoothing_improves_the_heading_on_the_car(car_pass):
    """RTS uses both sides of every epoch: its heading RMS must be below the filter's
    (measured 0.09 vs 0.16 degrees over the whole car run)."""
    truth, _, _, res, _ = car_pass
    n = 300
    e_f = heading_error(res.states[1:, 2], truth.yaw[1:n])
    e_s = heading_error(rts_smooth(res).states[1:, 2], truth.yaw[1:n])
    assert np.sqrt(np.mean(e_s ** 2)) < np.sqrt(np.mean(e_f ** 2))


def test_smoothed_heading_one_call(car_pass):
    truth, cfg, obs, res, p = car_pass
    t = truth.t[:300]
    yaw = smoothed_heading(t, obs, cfg, p)
    np.testing.assert_array_equal(yaw, rts_smooth(res).states[:, 2])
    assert yaw.shape == (300,) and np.isnan(yaw[0]) and np.isfinite(yaw[1:]).all()
    assert ((yaw[1:] > -np.pi) & (yaw[1:] <= np.pi)).all()
    assert np.degrees(heading_error(yaw[1:], truth.yaw[1:300])).max() < 1.0
    lag = smoothed_heading(t, obs, cfg, p, lag_s=2.0)
    assert np.degrees(heading_error(lag[1:], truth.yaw[1:300])).max() < 1.0
    with pytest.raises(TypeError, match="config"):
        smoothed_heading(t, obs, "car_rtk4")


@settings(max_examples=25, deadline=None)
@given(st.one_of(st.floats(allow_nan=True, allow_infinity=True),
                 st.sampled_from([-1.0, -1e-300, np.inf, np.nan, 1e300])))
def test_fixed_lag_rejects_a_bad_lag_naming_it(lag):
    F, Q, H, R, zs = _linear_system(n=5)
    res, _ = _forward(F, Q, H, R, zs, np.zeros(NX), np.eye(NX))
    if np.isfinite(lag) and lag >= 0:
        assert fixed_lag_smooth(res, np.arange(5.0), lag).states.shape == (5, NX)
    else:
        with pytest.raises((ValueError, TypeError), match="lag_s"):
            fixed_lag_smooth(res, np.arange(5.0), lag)


def test_smoothers_reject_a_wrong_result_or_time_axis():
    F, Q, H, R, zs = _linear_system(n=5)
    res, _ = _forward(F, Q, H, R, zs, np.zeros(NX), np.eye(NX))
    with pytest.raises(TypeError, match="res"):
        rts_smooth(res.states)
    with pytest.raises(ValueError, match="^t:"):
        fixed_lag_smooth(res, np.arange(4.0), 1.0)


def _lost_then_restarted():
    """The rover layout (0.05 m white fixes, 1 Hz) rolling back, then driving forward,
    with a 30 s all-antenna outage from epoch 30: the filter predicts into it, loses the
    track (heading sd past 45 degrees) and restarts after it."""
    from estimator.configuration import SensorConfig

    cfg = SensorConfig.load("rover_gps8").planar()
    v = np.r_[np.full(8, -0.5), np.zeros(2), np.full(60, 1.0)]
    t = np.arange(v.size + 1.0)
    x = np.r_[0.0, np.cumsum(v)]
    off = cfg.body_positions - cfg.cg_body
    pos = np.c_[x, np.zeros_like(x)][:, None, :] + off[None]
    obs = pos + np.random.default_rng(4).normal(0, 0.05, pos.shape)
    obs[:, ~cfg.alive_mask] = np.nan
    obs[30:60] = np.nan
    p = PoseFilterParams(sigma_abs_m=0.05, sigma_step_m=0.07)
    return t, obs, off, p


def test_smoothers_keep_every_row_the_filter_outputs_across_a_lost_track():
    """Issue 23 / issue 25 ("RTS and fixed-lag bridge NaN epochs and outages"): both
    smoothers used to blank every earlier row of the segment that ended in a lost track
    (here 20 of them). Now: a smoothed row wherever the filter has one; the epochs the
    filter predicted through (status "predicted") are smoothed across; the stretch before
    the loss equals the smoother on a pass that ends there (the filter is causal); after
    the restart the smoothing resumes."""
    t, obs, off, p = _lost_then_restarted()
    res = run_pose_filter(t, obs, off, p)
    lost = int(np.flatnonzero((res.status == "waiting") & (np.arange(t.size) > 20))[0])
    assert 30 <= lost < 40 and res.status[lost - 1] == "predicted"
    out = np.isfinite(res.states[:, 0])
    cut = run_pose_filter(t[:lost], obs[:lost], off, res.params)   # the same resolved limits
    want = rts_smooth(cut).states
    start = int(np.flatnonzero(res.segment_start[:lost])[-1])
    for sm in (rts_smooth(res).states, fixed_lag_smooth(res, t, 1e6).states):
        assert np.array_equal(np.isfinite(sm[:, 0]), out)
        np.testing.assert_allclose(sm[start:lost], want[start:], rtol=0, atol=1e-12)
    restart = 60 + int(np.flatnonzero(res.status[60:] == "reset")[0])
    sm = rts_smooth(res).states
    assert np.isfinite(sm[restart:]).all() and (sm[restart:-1] != res.states[restart:-1]).any()


def test_an_outage_the_filter_predicts_through_is_smoothed_across():
    """0.5 s without any fix at 10 Hz on the car (5 "predicted" rows inside one segment):
    the smoothed rows there are finite and, using the data on both sides, at least twice
    as close to the truth as the filter's predictions (measured: 1.3 cm for RTS and the
    2 s fixed lag vs 5.3 cm mean CG error; 2x leaves room for other seeds). This already
    held before issue 23; it guards issue 25's "bridge outages" against a regression."""
    truth, cfg, limits = kinematic_truth("car_block", "car_rtk4", cg_ahead_m=1.3)
    n = 300
    obs = noisy(truth, cfg, "gps_rtk", 5)[:n]
    obs[150:155] = np.nan
    p = PoseFilterParams.from_limits(limits, no_slip_point_m=(-1.3, 0.0))
    res = run_pose_filter(truth.t[:n], obs, cfg.body_positions - cfg.cg_body, p)
    assert (res.status[150:155] == "predicted").all() and not res.segment_start[150:156].any()
    sm = rts_smooth(res).states
    fl = fixed_lag_smooth(res, truth.t[:n], 2.0).states
    gap = slice(150, 155)
    e_f = np.hypot(*(res.cg()[gap] - truth.cg[gap, :2]).T).mean()
    for s_ in (sm, fl):
        assert np.isfinite(s_[gap]).all()
        assert np.hypot(*(res.cg(s_)[gap] - truth.cg[gap, :2]).T).mean() < 0.5 * e_f
