"""The simulated real vehicle of issue 25 and the pose filter on it: the generator's
character, the platform limits and travel axis estimated from the data, a standstill start,
recovery from a gate lock-out, and heading bounds on the RTK and consumer-error cases."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from pose_scenes import square_layout, vehicle_scene
from scipy.stats import binom, chi2
from test_pose_filter_monitor import P_GATE, WINDOW, status_follows_the_rule

import estimator.pose_filter as pf
from estimator.metrics import heading_error
from estimator.platform import PlatformLimits, estimate_limits, estimate_travel_axis
from estimator.pose_filter import PoseFilterParams, estimate_noise, run_pose_filter
from estimator.pose_smoother import fixed_lag_smooth, rts_smooth
from sim.vehicle_case import MOUNT_YAW_RAD, simulate_vehicle_case, vehicle_observations

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def rtk():
    """Seed 0 with RTK errors, and the filter's pass with defaults (everything estimated)."""
    case, t, obs, off = vehicle_scene(0, "rtk")
    return case, t, obs, off, run_pose_filter(t, obs, off)


def _rms_deg(yaw, truth, mask):
    e = np.degrees(heading_error(yaw, truth))
    return float(np.sqrt(np.mean(e[mask & np.isfinite(e)] ** 2)))


def test_the_case_has_the_recordings_character():
    """Issue 25's recording: 1 Hz, ~1500 epochs, presence 63-97 % per antenna, all four in
    ~43 %, three in ~46 %, one or none in ~3 %, a 34 s outage, a 150 s stop, speed median
    ~6 and max 16 m/s, yaw rate p95 ~18 and max ~31 deg/s, the frame 3.4 deg off the
    travel. Bounds: the ranges seen over seeds 0-4 (all four 41-47 %, three 39-47 %, median
    speed 5.3-6.2, yaw-rate p95 17.7-22.7 deg/s) widened by a few points; the acceleration's
    p99 is 2.3-3.2 m/s^2 here, below the recording's 4.7 (the generator's accelerations are
    jerk-limited; see the README)."""
    case = simulate_vehicle_case(np.random.default_rng(0))
    tr, p = case.truth, case.present
    k = p.sum(1)
    assert tr.n == 1515 and np.allclose(np.diff(tr.t), 1.0)
    assert p.mean(0).min() >= 0.55 and p.mean(0).max() <= 0.99
    assert 0.35 <= (k == 4).mean() <= 0.52 and 0.35 <= (k == 3).mean() <= 0.52
    assert 0.015 <= (k <= 1).mean() <= 0.06
    outage = ~p.any(1)
    assert outage.sum() >= 34 and (tr.speed < 0.01).sum() >= 150
    assert 4.5 <= np.median(tr.speed) <= 7.0 and 15.0 <= tr.speed.max() <= 16.5
    w = np.degrees(np.abs(tr.yaw_rate))
    assert 15.0 <= np.percentile(w, 95) <= 25.0 and w.max() <= 31.0
    # the antenna missing for 333 s
    gap = np.diff(np.flatnonzero(np.diff(np.r_[1, p[:, 3].astype(int), 1]) != 0))
    assert gap.max() >= 333
    # the layout's forward axis vs the rear axle's travel: 3.4 deg (noise-free fixes)
    assert case.mount_yaw_rad == pytest.approx(math.radians(3.4))
    with pytest.raises(ValueError, match="rate_hz"):
        simulate_vehicle_case(np.random.default_rng(0), rate_hz=50.0)
    with pytest.raises(ValueError, match="noise"):
        vehicle_observations(case, "gps", np.random.default_rng(0))


def test_limits_and_travel_axis_are_estimated_from_the_data(rtk):
    """From the RTK fixes alone: the speed limit covers the 16 m/s top speed (p99 x 1.25:
    ~20), the acceleration limit is of the drive's p99 (2.5-4.5 m/s^2 measured, the
    generator's 6.5 m/s^2 reached only in short bursts), the turn rate covers the 30 deg/s
    the drive reaches (x 1.25 margin, within 30 %); the travel axis is the frame's
    -3.4 deg to 0.3 deg (measured 0.06-0.13 deg off over seeds 0-1) and the CG 1.3 m
    ahead of the rear axle to 0.15 m (measured 1.25-1.28 m)."""
    case, t, obs, off, res = rtk
    sa, _ = estimate_noise(obs, off)
    lim = estimate_limits(t, obs, off, sa)
    assert lim.source == "data"
    assert 16.0 <= lim.max_speed_mps <= 25.0
    assert 2.0 <= lim.max_accel_mps2 <= 8.0
    top = np.abs(case.truth.yaw_rate).max()
    assert top <= lim.max_turn_rate_radps <= 1.3 * 1.25 * top
    ax = estimate_travel_axis(t, obs, off, sa)
    assert ax.known and math.degrees(abs(ax.offset_rad + MOUNT_YAW_RAD)) < 0.3
    assert abs(ax.lever_m - 1.3) < 0.15
    # the filter used exactly these (its parameters resolved from the same data)
    assert res.params.travel_offset_rad == ax.offset_rad
    assert res.params.max_speed_mps == lim.max_speed_mps
    # a platform standing still all the time: the floors, never zero or NaN
    still = np.broadcast_to(obs[:1], obs.shape).copy()
    lim0 = estimate_limits(t, still, off, sa)
    assert lim0.max_accel_mps2 == 0.5 and lim0.max_turn_rate_radps == 0.3
    assert not estimate_travel_axis(t, still, off, sa).known


def test_platform_limits_are_validated_and_reach_the_filter():
    lim = PlatformLimits.from_dict({"max_speed_mps": 16.0, "max_accel_mps2": 4.7,
                                    "max_turn_rate_radps": 0.55})
    assert lim.max_yaw_accel_radps2 == 0.55 and lim.max_lateral_accel_mps2 == 4.7
    p = PoseFilterParams.from_platform(lim, lag_s=5.0)
    assert (p.max_speed_mps, p.max_accel_mps2, p.lag_s) == (16.0, 4.7, 5.0)
    assert p.no_slip_point_m is None and not p.resolved
    assert PoseFilterParams.from_platform(None) == PoseFilterParams()
    with pytest.raises(ValueError, match=r"platform\.max_speed_mps.*-1"):
        PlatformLimits.from_dict({"max_speed_mps": -1, "max_accel_mps2": 1,
                                  "max_turn_rate_radps": 1})
    with pytest.raises(ValueError, match=r"platform\.max_turn_rate_radps: required"):
        PlatformLimits.from_dict({"max_speed_mps": 1, "max_accel_mps2": 1})
    with pytest.raises(ValueError, match=r"platform\.top_speed: unknown key"):
        PlatformLimits.from_dict({"top_speed": 1})
    with pytest.raises(ValueError, match="travel_offset_rad"):
        PoseFilterParams(travel_offset_rad=1.0)
    with pytest.raises(ValueError, match="max_accel_mps2: None"):
        _ = PoseFilterParams().sigma_accel_step


def test_rtk_car_heading_with_defaults(rtk):
    """Defaults, nothing given, network RTK (gps_rtk_network): EKF, fixed-lag and RTS
    heading on the epochs with two or more antennas. Measured on seed 0: EKF 0.13,
    fixed-lag 0.10, RTS 0.10 deg RMS (window 1: 0.10 deg); over the seeds 0-9 that do
    not fail at a hard acceleration (7 of 10, see tests/test_vehicle_case_rtk.py) EKF
    0.13-0.22 and RTS 0.10-0.21 deg; bounds 0.3 / 0.3 / 0.3 deg (the seeds' largest plus
    40 %), no flip (no error beyond 90 deg), finite on >= 99 % of those epochs (measured
    99.9 %). Every row carries its NIS with 2 dof per measurement."""
    case, t, obs, _, res = rtk
    two = np.isfinite(obs[..., 0]).sum(1) >= 2
    rows = {"ekf": res.states, "fixed_lag": fixed_lag_smooth(res, t, res.params.lag_s).states,
            "rts": rts_smooth(res).states}
    for name, bound in (("ekf", 0.3), ("fixed_lag", 0.3), ("rts", 0.3)):
        X = rows[name]
        assert _rms_deg(X[:, 2], case.truth.yaw, two) < bound, name
        e = np.degrees(heading_error(X[:, 2], case.truth.yaw))
        assert not (np.abs(e[np.isfinite(e)]) > 90).any(), name
        assert np.isfinite(X[two, 2]).mean() >= 0.99, name
    # smoothers bridge the outage and single-antenna epochs: a row wherever the filter has
    for X in (rows["fixed_lag"], rows["rts"]):
        assert np.array_equal(np.isfinite(X[:, 0]), np.isfinite(res.states[:, 0]))
    data = (np.isfinite(res.states[:, 0]) & np.isfinite(obs[..., 0]).any(1)
            & ~res.segment_start)                      # a start row has no prediction
    assert np.isfinite(res.nis[data]).all()
    nfix = np.isfinite(obs[data, :, 0]).sum(1)
    assert (res.nis_dof[data] % 2 == 0).all() and (res.nis_dof[data] >= 2 * nfix).all()


def _standstill_scene(jump_deg: float = 123.0, n: int = 60, k_jump: int = 30):
    """A car standing still with four antennas (0.8 m square, 1 cm white noise, 1 Hz) whose
    layout reads ``jump_deg`` off for the first ``k_jump`` epochs, rotated about antenna 1
    (so antenna 1 agrees with both headings): the filter starts on the wrong heading and,
    once the layout shows the true one, the three other antennas fail its gates while
    antenna 1 keeps passing (the issue's lock-out: "2 of 3 gated for minutes")."""
    h = 0.4
    off = np.array([[h, h], [h, -h], [-h, h], [-h, -h]])
    yaw = 0.3
    rng = np.random.default_rng(7)
    t = np.arange(float(n))

    def place(a):
        c, s = math.cos(a), math.sin(a)
        return off @ np.array([[c, s], [-s, c]])

    true = place(yaw)
    wrong = place(yaw + math.radians(jump_deg))
    wrong += true[0] - wrong[0]                       # pivot on antenna 1
    obs = np.where(np.arange(n)[:, None, None] < k_jump, wrong[None], true[None])
    obs = obs + rng.normal(0, 0.01, obs.shape) + np.array([500.0, -300.0])
    return t, obs, off, yaw, k_jump


def test_standstill_start_takes_the_layouts_heading_and_a_lock_out_is_recovered():
    """At a standstill the start is the layout's heading (no motion needed); when the layout
    then contradicts the state by 123 deg the filter re-initialises from the epoch's rigid
    fit within REINIT_EPOCHS (3) epochs, reported "reinit" (the epochs before it
    "inconsistent", not "ok"), and holds the true heading to 1 deg afterwards. Without the
    monitor (REINIT_EPOCHS beyond the run) the first epoch whose fixes all fail their gates
    while its fit agrees with the layout re-initialises (FilterStart.motion_miss, issue 25;
    before it: max_rejects all-gated epochs, then a restart, >= 90 deg off for 5 epochs)."""
    t, obs, off, yaw, kj = _standstill_scene()
    res = run_pose_filter(t, obs, off)
    init = int(np.flatnonzero(res.status == "init")[0])
    assert init <= 1
    assert math.degrees(heading_error(res.states[init, 2], yaw + math.radians(123))) < 1.0
    re = np.flatnonzero(res.status == "reinit")
    assert re.size and kj <= re[0] <= kj + pf.REINIT_EPOCHS
    assert set(res.status[kj:re[0]]) <= {"inconsistent"}
    after = np.arange(t.size) >= re[0]
    assert np.degrees(heading_error(res.states[after, 2], np.full(after.sum(), yaw))).max() < 1
    import unittest.mock as um

    with um.patch.object(pf, "REINIT_EPOCHS", 10 ** 9):
        locked = run_pose_filter(t, obs, off)
    err = np.degrees(heading_error(locked.states[:, 2], np.full(t.size, yaw)))
    miss = np.flatnonzero(locked.status == "reinit")
    assert miss.size and locked.n_used[miss[0]] == 0 and miss[0] <= kj + 2
    assert err[miss[0]:].max() < 1.0


def _standstill_gap_scene(jump_m: float = 0.0, seed: int = 3):
    """A car on the 0.8 m square (1 Hz, heading 0.3 rad) driving at 3 m/s, braking at 1
    m/s^2 from t = 25 s to rest at 28 s, standing to 80 s, with consumer-like errors (a
    common random walk of 3 cm per epoch, one of 1.5 cm per antenna, constant 0.4 m biases:
    metre-level, the frame cannot give the heading) and an all-antenna gap at epochs 50-51;
    ``jump_m``: every fix from epoch 52 on moved by that much along x (the car moved in the
    gap). Returns (t, obs, offsets, true heading, params): sigma 0.5 m, step 5 cm, curvature
    limit 0.2 1/m, acceleration limit 4 m/s^2 (the car's: the speed's sd grows by it in the
    gap)."""
    n = 80
    t = np.arange(float(n))
    v = np.where(t < 25, 3.0, np.maximum(3.0 - (t - 25), 0.0))
    s = np.r_[0.0, np.cumsum(0.5 * (v[1:] + v[:-1]))]
    yaw = np.full(n, 0.3)
    off, obs = square_layout(np.c_[s * math.cos(0.3), s * math.sin(0.3)], yaw)
    rng = np.random.default_rng(seed)
    obs = obs + (np.cumsum(rng.normal(0, 0.03, (n, 1, 2)), axis=0)
                 + np.cumsum(rng.normal(0, 0.015, (n, 4, 2)), axis=0)
                 + rng.normal(0, 0.4, (1, 4, 2))) + np.array([300.0, -200.0])
    obs[50:52] = np.nan
    obs[52:, :, 0] += jump_m
    p = PoseFilterParams(sigma_abs_m=0.5, sigma_step_m=0.05, max_curvature_1pm=0.2,
                         max_accel_mps2=4.0)
    return t, obs, off, yaw, p


def test_a_car_that_stood_through_a_gap_keeps_its_heading(monkeypatch):
    """A car that did not move cannot have turned (issue 25, cpm drive 14: a 2 s gap at the
    stop grew the heading sd from 4 to 42 deg, and the returning drifting fixes turned the
    heading 50 deg before the car moved off). Predicted through the gap the heading's sd
    grows (here 1.7 -> 34 deg); when the fixes return where they were (``_standstill_gap``:
    every antenna within INIT_MOTION_SIGMAS sigma_step sqrt(k - j) of its fix at j, the last
    epoch with one), the heading's variance at the return is at most that at j plus
    (kappa x that travel)^2, and the heading then stays within 3 of its sd of the truth
    (consistent). Without the bound (patched out) the sd is 32 deg at the return and the
    heading drifts to 20 deg off at 4 sd (measured). A gap after which the fixes moved by 1
    m is not bounded."""
    t, obs, off, yaw, p = _standstill_gap_scene()
    res = run_pose_filter(t, obs, off, p, engine="numpy")
    assert list(res.status[50:52]) == ["predicted", "predicted"]
    su = pf._setup(*pf._check_run_args(t, obs, off, res.params), res.params)
    j, thr = pf._standstill_gap(su.starter, 52)
    assert j == 49 and thr == pytest.approx(5 * 0.05 * math.sqrt(3))
    assert pf._standstill_gap(su.starter, 51) is None        # no fix at 51
    assert pf._standstill_gap(su.starter, 53) is None        # no gap before 53
    var = res.covariances[:, 2, 2]
    assert math.degrees(math.sqrt(var[51])) > 20.0           # the gap grew it
    assert var[52] <= (var[49] + (0.2 * thr) ** 2) * (1 + 1e-9)
    e = heading_error(res.states[52:, 2], yaw[52:])
    assert (np.abs(e) <= 3.0 * np.sqrt(var[52:])).all()
    monkeypatch.setattr(pf, "_bound_after_standstill_gap", lambda *args: None)
    old = run_pose_filter(t, obs, off, p, engine="numpy")
    e_old = heading_error(old.states[52:, 2], yaw[52:])
    assert np.abs(e_old).max() > 3.0 * np.abs(e).max()
    t, moved, off, _, p = _standstill_gap_scene(jump_m=1.0)
    su = pf._setup(*pf._check_run_args(t, moved, off, res.params), res.params)
    assert pf._standstill_gap(su.starter, 52) is None


def test_consumer_errors_replayed_onto_the_car():
    """Consumer errors (a gps_stationary receiver replayed 'shifted': metre-level, no
    common part; heading from the motion only, the 0.8 m frame cannot give it): the RTS row
    on seed 0, measured 4.8 deg RMS with 96.7 % output on the >= 2-antenna epochs
    (window 1: 86 deg). Bounds 7 deg and 95 % (target 5 deg: met in the mean of 10 seeds,
    see the README). The 150 s stop holds its heading (standstill hold): within 10 deg
    RMS there (measured 3.8 deg; 65 deg without the hold)."""
    case, t, obs, off = vehicle_scene(0, "shifted")
    res = run_pose_filter(t, obs, off)
    sm = rts_smooth(res).states
    two = np.isfinite(obs[..., 0]).sum(1) >= 2
    assert _rms_deg(sm[:, 2], case.truth.yaw, two) < 7.0
    assert np.isfinite(sm[two, 2]).mean() >= 0.95
    stop = case.truth.speed < 0.01
    stop[:20] = False                                  # the start at rest: no heading yet
    assert _rms_deg(sm[:, 2], case.truth.yaw, stop) < 10.0


def test_rtk_car_is_flagged_at_its_per_epoch_rate_and_a_mis_modelled_noise_is_not_hidden(rtk):
    """The RTK car (defaults) flags rows by the rule (both tests reproduced from
    scipy.stats.chi2, row by row) and no more often than its per-epoch alarm rate allows: a
    row is flagged by its own test (the share e of epochs above their quantile, the
    manoeuvres' spikes) or by its window. A window whose epochs are consistent but for
    one saturated epoch fails with probability <= 1 - gate_prob (the winsorised sum is at
    most the chi-square one), and it takes 3 saturated epochs of 10 with the others at
    their mean (the _Monitor docstring; 2 here, to leave room for the others above it);
    with spikes independent at rate e a window holds 2 or more with probability
    P(Bin(10, e) >= 2). Bound: e + P(Bin(10, e) >= 2) + (1 - gate_prob). Measured, seed 0:
    e 7.85 %, bound 26.1 %, flagged 8.9 % (before the winsorised window 39.1 %). The same
    drive with sigma_abs and sigma_step given 3x too small (the innovations 3x their model)
    is mostly flagged (measured 80 %)."""
    case, t, obs, off, res = rtk
    status_follows_the_rule(res)
    two = np.isfinite(obs[..., 0]).sum(1) >= 2
    data = (res.nis_dof > 0) & np.isfinite(res.nis)
    q = chi2.ppf(P_GATE, np.maximum(res.nis_dof, 1))
    e = float((res.nis[data] > q[data]).mean())
    bound = e + binom.sf(1, WINDOW, e) + (1.0 - P_GATE)
    assert (res.status[two] == "inconsistent").mean() <= bound
    sa, ss = estimate_noise(obs, off)
    small = run_pose_filter(t, obs, off, PoseFilterParams(sigma_abs_m=sa / 3, sigma_step_m=ss / 3))
    status_follows_the_rule(small)
    assert (small.status[two] == "inconsistent").mean() > 0.5


@pytest.mark.parametrize(("rate", "vmax", "bound"), [
    (0.5, 30.0, 4.0),
    pytest.param(20.0, 0.1, 1.0, marks=pytest.mark.slow)])   # 12000 epochs: ~15 s
def test_rates_and_speeds_at_the_ends_of_the_range(rate, vmax, bound):
    """0.5 Hz at up to 30 m/s and 20 Hz creeping at up to 0.1 m/s (600 s drives with the
    case's stop, outage and dropouts; noise-free fixes at the 1 mm floor): never an
    exception, finite output on >= 95 % of the >= 2-antenna epochs, heading RMS there below
    the bound. Measured: 0.5 Hz 2.7 deg (the 30 m/s car turns up to 60 deg and brakes at
    12 m/s^2 between two samples: bound 4 deg), 20 Hz 0.12 deg (the layout gives the
    heading: bound 1 deg)."""
    case, t, obs, off = vehicle_scene(3, "none", rate_hz=rate, duration_s=600.0,
                                      max_speed_mps=vmax)
    res = run_pose_filter(t, obs, off)
    two = np.isfinite(obs[..., 0]).sum(1) >= 2
    assert np.isfinite(res.states[two, 2]).mean() >= 0.95
    assert _rms_deg(res.states[:, 2], case.truth.yaw, two) < bound


# --------------------------------------------------------------------------- the car preset
def test_shipped_car_recordings_are_the_generators_output(tmp_path):
    """models/recordings/car_case*: tests/synth_vehicle_recording.py's output with its
    defaults (logs and TOMLs byte for byte; the session's arrays exactly, its .npz holds
    zip time stamps)."""
    from synth_vehicle_recording import write_car_recordings

    from sim.gps import StationarySession

    shipped = REPO / "models" / "recordings"
    w = write_car_recordings(tmp_path)
    for key, p in w.files.items():
        rel = p.relative_to(tmp_path)
        if key == "session":
            a, b = StationarySession.load(p), StationarySession.load(shipped / rel)
            assert np.array_equal(a.t, b.t) and np.array_equal(a.obs, b.obs, equal_nan=True)
            assert a.names == b.names and a.meta == b.meta
        else:
            assert (shipped / rel).read_bytes() == p.read_bytes(), rel


def test_car_recording_reads_back_the_case():
    """The RTK recording gives the written fixes (1e-9 deg: 0.1 mm; bound 0.3 mm), NaN
    where the case's antenna is absent; its reference pose is the case's truth on the
    epochs with two or more antennas (the rigid fit of exact positions written to 0.1 mm
    on a 0.8 m frame: ~2e-4 rad; bound 1e-3 rad, 1 mm) and NaN elsewhere. The replay
    recording's observations inherit the case's dropouts."""
    from synth_vehicle_recording import DRIVE_SEED, NOISE_SEED

    from sim.recording import load_recording

    case = simulate_vehicle_case(np.random.default_rng(DRIVE_SEED))
    rtk = vehicle_observations(case, "rtk", np.random.default_rng(NOISE_SEED))
    rec = load_recording("car_case_rtk")
    assert rec.n == case.truth.n and rec.config.name == "car_rtk4"
    d = rec.obs - rtk
    assert np.array_equal(np.isnan(rec.obs[..., 0]), ~case.present)
    shift = np.nanmedian(d.reshape(-1, 2), axis=0)        # the recording's own origin
    assert np.nanmax(np.abs(d - shift)) < 3e-4
    tr, two = rec.truth(), case.present.sum(1) >= 2
    assert np.array_equal(np.isfinite(tr.yaw), two)
    assert np.max(heading_error(tr.yaw[two], case.truth.yaw[two])) < 1e-3
    cg_err = tr.cg[two, :2] - shift - case.truth.cg[two, :2]
    assert np.max(np.abs(cg_err)) < 1e-3
    rep = load_recording("car_case_replay")
    obs = rep.observations(np.random.default_rng(0))
    assert np.isnan(obs[~case.present]).all()


def test_car_preset_loads_and_expands():
    from experiments.runner.run import RESULTS_DIR, default_out
    from experiments.spec import available_presets, load_spec

    assert "car" in available_presets()
    spec = load_spec("car")
    cells = spec.expand()
    assert len(cells) == 3 * 4 * 10
    assert {c.noise for c in cells} == {"recording", "replay:shifted",
                                        "replay:common_plus_model"}
    # no optional extra needed (the GTSAM peer is added by hand where gtsam is installed)
    assert {c.technique for c in cells} == {"none", "ekf", "ekf_fixed_lag", "ekf_smoother"}
    assert {c.window for c in cells} == {1}
    assert default_out(spec.name) == RESULTS_DIR / "local" / "car"     # git-ignored


def test_car_preset_tiny_run(tmp_path):
    """One seed of the RTK grid, window 1 and the causal filter, through the sweep: the
    filter row carries NEES and NIS, the window fit NaN there, and the filter ran with the
    recording's [platform] limits (its heading RMS is the direct run's with them, not the
    one with limits estimated from the data); heading bound 0.5 deg RMS, the RTK target
    (network RTK: window 1 measured 0.13 deg, EKF 0.14 deg)."""
    import pandas as pd

    from experiments.runner.run import run
    from experiments.spec import Spec, load_spec

    raw = load_spec("car").to_dict()
    raw.update(seeds=1, grid=[{**raw["grid"][0], "technique": ["none", "ekf"]}])
    for k in ("epochs", "source"):
        raw.pop(k, None)
    res = run(Spec.from_dict(raw), out=tmp_path, jobs=1, progress=False, figures=False)
    assert res.n_failed == 0
    cells = pd.read_parquet(tmp_path / "cells.parquet").set_index("technique")
    assert np.degrees(cells["eh_rmse"]).max() < 0.5
    assert np.isfinite(cells.loc["ekf", ["nees_mean", "nis_per_dof", "status_not_ok"]]).all()
    assert np.isnan(cells.loc["none", ["nees_mean", "nis_per_dof"]].astype(float)).all()
    ht = pd.read_csv(tmp_path / "heading.csv")
    assert {"nees_mean", "nis_in_band", "status_inconsistent"} <= set(ht.columns)
    # the recording's [platform] block (car_rtk4's) reaches the filter of a recording cell
    from sim.recording import load_recording

    rec = load_recording("car_case_rtk")
    tr, off = rec.truth(), rec.config.planar().body_positions - rec.config.planar().cg_body
    two = np.isfinite(tr.yaw)
    for fp, same in ((PoseFilterParams.from_platform(rec.platform), True),
                     (PoseFilterParams(), False)):
        e = heading_error(run_pose_filter(rec.t, rec.obs, off, fp).states[two, 2], tr.yaw[two])
        rms = float(np.sqrt(np.nanmean(e ** 2)))
        assert bool(rms == pytest.approx(cells.loc["ekf", "eh_rmse"], rel=1e-9)) is same
