"""Network RTK on the issue-25 car (models/noise/gps_rtk_network.toml): the model's numbers
follow from the two facts its file states, the simulated car reproduces the recording's
window-1 heading, and the pose filter stays within bounds on it (issue 25)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from pose_scenes import vehicle_scene

from estimator.configuration import SensorConfig
from estimator.epoch_fit import epoch_rigid_fits
from estimator.metrics import heading_error
from estimator.pose_filter import PoseFilterParams, run_pose_filter
from estimator.pose_smoother import rts_smooth
from sim.gps import GpsNoiseModel, receiver_errors

#: The recording's stated character (issue 25): window-1 heading RMS, deg, and the share of
#: epochs with 4, 3 and 2 antennas (one or none: 3 %).
RECORDING_W1_DEG = 0.11
RECORDING_MIX = {4: 0.43, 3: 0.46, 2: 0.08}


def _inverse_spread(k: int, half_side: float = 0.4) -> float:
    """Mean over the k-antenna subsets of the 0.8 m square of 1 / sum |r_i - c|^2, m^-2:
    the rigid fit's heading variance per unit per-axis noise variance."""
    sq = np.array(list(itertools.product((half_side, -half_side), repeat=2)))
    return float(np.mean([1.0 / ((sq[list(c)] - sq[list(c)].mean(0)) ** 2).sum()
                          for c in itertools.combinations(range(4), k)]))


def _per_antenna_sd(m: GpsNoiseModel) -> float:
    """Per-axis sd of one antenna's error relative to the others, m (receiver scale
    lognormal: E[s^2] = exp(2 spread^2))."""
    return math.sqrt(m.sigma_receiver_m ** 2 * math.exp(2 * m.receiver_sigma_spread ** 2)
                     + m.white_sigma_m ** 2 + m.bias_sigma_m ** 2)


def test_network_rtk_model_follows_from_its_stated_facts():
    """[A] the absolute per-axis sd is gps_rtk's single receiver (median scale: GM 15 mm,
    bias 5 mm, white 2 mm = 15.94 mm), nearly all of it common; [R] the per-antenna sd is
    0.11 deg / sqrt(E[1 / sum |r - c|^2]) over the recording's mix (1.82 mm). Tolerance 1 %:
    the file's numbers have 3-4 digits (the exact ones: 15.90 mm, 0.99160)."""
    net, ind = GpsNoiseModel.load("gps_rtk_network"), GpsNoiseModel.load("gps_rtk")
    factor = sum(w * _inverse_spread(k) for k, w in RECORDING_MIX.items()) / sum(
        RECORDING_MIX.values())
    assert factor == pytest.approx(1.117, abs=1e-3)
    rel = _per_antenna_sd(net)
    assert rel == pytest.approx(math.radians(RECORDING_W1_DEG) / math.sqrt(factor), rel=0.01)
    absolute = math.hypot(net.sigma_common_m, rel)
    single = math.sqrt(ind.sigma_m ** 2 + ind.bias_sigma_m ** 2 + ind.white_sigma_m ** 2)
    assert absolute == pytest.approx(single, rel=0.01)
    assert net.sigma_common_m > 8 * rel                   # common mode dominant


def test_network_rtk_errors_move_the_antennas_together():
    """Drawn errors (40 antennas, 5000 s, 1 Hz): the deviation from the antennas' mean has
    the stated 1.82 mm per axis (within 10 %: 40 lognormal receiver scales and 30 s
    correlation; measured 1.78-1.85 mm over seeds 0-2) and two antennas' errors correlate
    above 0.98 (expected 0.987 at median scale; measured 0.987-0.991)."""
    net = GpsNoiseModel.load("gps_rtk_network")
    err, _ = receiver_errors(net, 40, 5000, 1.0, np.random.default_rng(0))
    dev = (err - err.mean(1, keepdims=True)) * math.sqrt(40 / 39)
    assert float(np.sqrt(np.mean(dev ** 2))) == pytest.approx(_per_antenna_sd(net), rel=0.1)
    assert np.corrcoef(err[:, 0, 0], err[:, 1, 0])[0, 1] > 0.98


def test_simulated_car_reproduces_the_recordings_window1_heading():
    """The car case with "rtk" (network RTK): the rigid fit per epoch gives the recording's
    0.11 deg on the >= 2-antenna epochs. Measured over seeds 0-9: 0.097-0.140 deg, mean
    0.115, sd 0.014 (the case's antenna mix varies by seed: all four 36-52 %). Bounds:
    each of seeds 0-2 in [0.08, 0.17] deg (the seed range widened by 2 sd) and their mean
    within 0.11 +- 0.03 deg; the independent-receiver model (gps_rtk) gives ~8x that."""
    rms = []
    for seed in range(3):
        case, _, obs, off = vehicle_scene(seed, "rtk")
        two = np.isfinite(obs[..., 0]).sum(1) >= 2
        e = heading_error(epoch_rigid_fits(obs, off)[1], case.truth.yaw)[two]
        rms.append(math.degrees(float(np.sqrt(np.mean(e ** 2)))))
    assert all(0.08 <= r <= 0.17 for r in rms), rms
    assert abs(np.mean(rms) - RECORDING_W1_DEG) < 0.03
    case, _, obs, off = vehicle_scene(0, "rtk_independent")
    two = np.isfinite(obs[..., 0]).sum(1) >= 2
    e = heading_error(epoch_rigid_fits(obs, off)[1], case.truth.yaw)[two]
    assert math.degrees(float(np.sqrt(np.mean(e ** 2)))) > 5 * rms[0]


def _run(seed: int, params: PoseFilterParams) -> tuple[np.ndarray, np.ndarray]:
    """EKF and RTS heading errors (deg) on the >= 2-antenna epochs of drive ``seed``."""
    case, t, obs, off = vehicle_scene(seed, "rtk")
    two = np.isfinite(obs[..., 0]).sum(1) >= 2
    res = run_pose_filter(t, obs, off, params)
    return tuple(np.degrees(heading_error(X[two, 2], case.truth.yaw[two]))
                 for X in (res.states, rts_smooth(res).states))


@pytest.mark.parametrize("seed", [3, 7, 9])
def test_network_rtk_target_with_the_platform_block(seed):
    """With car_rtk4's [platform] limits (the car preset's) the RTK target holds on the
    three seeds where the limits estimated from the data failed before issue 25's
    motion-miss fix (below): EKF and RTS RMS
    <= 0.5 deg (measured EKF 0.14-0.15, RTS 0.10-0.11 deg; bound 0.3 deg, twice the
    measured), no error above 5 deg (measured max: EKF 1.8-3.3, RTS 0.4-0.5 deg) and finite
    output on >= 99 % of the >= 2-antenna epochs (measured 99.8 %). With the defaults
    each of these seeds has an error above 5 deg (30-95 deg), so the test fails there."""
    par = PoseFilterParams.from_platform(SensorConfig.load("car_rtk4").platform)
    for e in _run(seed, par):
        assert np.isfinite(e).mean() >= 0.99
        assert float(np.sqrt(np.nanmean(e ** 2))) < 0.3
        assert np.nanmax(e) < 5.0


@pytest.mark.parametrize("seed", [3, 7, 9])
def test_network_rtk_defaults_survive_a_hard_acceleration(seed):
    """Defaults (limits estimated from the data) on the seeds with hard acceleration onsets
    (seed 3: the speed changes by 4.3 m/s in 1 s against estimated limits of ~3 m/s^2):
    no error above 5 deg, finite output on >= 99 % of the >= 2-antenna epochs. Before
    issue 25's motion-miss re-initialisation (every fix gated while the epoch's fit agrees
    with the layout) and the fit-consistent yaw rate of a re-initialisation: seed 3 EKF
    3.0 deg RMS, max 95 deg (30-95 deg on the three). Measured now: EKF 0.15-0.19 deg RMS,
    max 3.5-4.1 deg; RTS 0.10-0.11, max 0.5-0.7 deg; output 99.86 %."""
    for e in _run(seed, PoseFilterParams()):
        assert np.isfinite(e).mean() >= 0.99
        assert np.nanmax(e) < 5.0
