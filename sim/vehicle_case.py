"""A simulated real vehicle: a car with four RTK antennas on a slanted roof frame (issue 25).

The character of the recording issue 25 describes (a car kept back from the project): 1 Hz,
~1500 epochs; four antennas on a 0.8 m rigid frame whose forward axis is 3.4 deg off the
direction of travel, the frame's centre 1.3 m ahead of the rear axle (the no-slip point);
per-antenna presence 63-97 % (all four in ~43 % of epochs, three in ~46 %, one or none in
~3 %), one antenna missing for 333 s, an all-antenna outage of 34 s, a 150 s stop; speed
median ~6, max 16 m/s; yaw rate p95 ~18, max ~31 deg/s; acceleration p99 ~4.7 m/s^2.

Pure numpy, every draw from the caller's Generator. The trajectory is a kinematic car
(the rear axle's midpoint moves along the car's heading: no slip), driven by random speed
and turn commands with acceleration, jerk, curvature and lateral-acceleration limits,
integrated at ``SUBSTEP_S`` and sampled at ``rate_hz``. :func:`vehicle_observations` puts
the project's error models on the antennas: ``"rtk"`` (network RTK on one vehicle,
models/noise/gps_rtk_network.toml: cm level common to all antennas, ~1.8 mm per antenna, the
recording's stated 0.11 deg window-1 heading), ``"rtk_independent"`` (models/noise/gps_rtk.toml:
1.5 cm per receiver, independent) or a consumer session (models/noise/gps_stationary.toml,
synthesized) replayed from one receiver by :func:`sim.gps.replay_one` in mode ``"shifted"``
or ``"common_plus_model"``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from estimator._checks import check_real
from estimator.configuration import SensorConfig
from sim.gps import (
    GpsNoiseModel,
    markov_dropouts,
    receiver_errors,
    replay_one,
    synthesize_session,
)
from sim.truth import Truth

__all__ = ["NOISES", "RTK_MODELS", "VehicleCase", "simulate_vehicle_case", "vehicle_observations"]

#: Integration step of the kinematic car, s.
SUBSTEP_S = 0.02
#: The frame's forward axis relative to the direction of travel, rad (issue 25: 3.4 deg).
MOUNT_YAW_RAD = math.radians(3.4)
#: Frame centre ahead of the rear axle, m (models/configs/car_rtk4.toml: 1.3 m).
FRAME_AHEAD_M = 1.3
#: Half side of the square frame, m (0.8 m frame).
HALF_SIDE_M = 0.4
#: Absence fraction per antenna from random bursts (the fourth also loses a 333 s block):
#: presence ~97, 91, 86 and 63 %, all four ~43 %, three ~46 % (independent bursts).
ABSENT = (0.03, 0.10, 0.16, 0.2)
#: Mean dropout burst, s.
BURST_S = 6.0
#: Error models of :func:`vehicle_observations`.
NOISES = ("none", "rtk", "rtk_independent", "shifted", "common_plus_model")
#: Noise model files of the RTK error models of :data:`NOISES`.
RTK_MODELS = {"rtk": "gps_rtk_network", "rtk_independent": "gps_rtk"}


@dataclass(frozen=True, eq=False)
class VehicleCase:
    """One simulated drive: ``truth`` (antenna positions (n, 4, 3) m, CG = frame centre,
    yaw = the frame's forward axis, rad), ``config`` (planar layout, names 1-4), ``present``
    (n, 4) bool (which antennas report), ``no_slip_point_m`` (rear axle midpoint in the
    layout's body frame relative to the CG, m), ``mount_yaw_rad`` (frame axis minus
    direction of travel, rad) and ``limits`` (the generator's own speed, acceleration,
    turn-rate and lateral-acceleration limits, SI)."""

    truth: Truth
    config: SensorConfig
    present: np.ndarray
    no_slip_point_m: tuple[float, float]
    mount_yaw_rad: float
    limits: dict


def _layout() -> SensorConfig:
    h = HALF_SIDE_M
    return SensorConfig.from_dict({
        "name": "car_rtk4_slanted", "description": "0.8 m roof frame (issue 25)",
        "cg_sensors": ["1", "2", "3", "4"],
        "sensor": [{"name": "1", "position_m": [h, h]}, {"name": "2", "position_m": [h, -h]},
                   {"name": "3", "position_m": [-h, h]}, {"name": "4", "position_m": [-h, -h]}]})


def _speed_targets(rng: np.random.Generator, duration: float, v_max: float, stop: tuple
                   ) -> list[tuple[float, float, float]]:
    """(start s, target speed m/s, accel limit m/s^2) segments; one at v_max, the stop."""
    seg, t = [(0.0, 0.0, 2.0)], 8.0                 # start at rest (a standstill start)
    scale = v_max / 16.0
    top = rng.uniform(0.05, 0.4) * duration
    while t < duration:
        if stop[0] <= t < stop[1]:
            t = stop[1]
            continue
        v = float(np.clip(rng.lognormal(math.log(6.2), 0.45), 1.0, 14.0))
        if rng.random() < 0.1:
            v = rng.uniform(0.5, 2.5)
        hard = rng.random() < 0.25                  # firm braking / acceleration
        seg.append((t, v * scale, rng.uniform(4.5, 6.5) if hard else rng.uniform(1.5, 3.5)))
        seg[-1] = (seg[-1][0], seg[-1][1], seg[-1][2] * scale)
        t += rng.uniform(8.0, 35.0)
        if seg[-1][0] < top <= t:
            seg.append((top, v_max, 3.0 * scale))
            t = top + 30.0
    seg.append((stop[0], 0.0, 3.0 * scale))
    seg.append((stop[1], 6.0 * scale, 2.5 * scale))
    return sorted(seg)


def _turn_targets(rng: np.random.Generator, duration: float) -> list[tuple[float, float]]:
    """(start s, yaw-rate command rad/s) segments: straights and turns of 20-150 deg."""
    seg, t = [], 0.0
    while t < duration:
        straight = rng.uniform(3.0, 25.0)
        seg.append((t, 0.0))
        t += straight
        rate = math.radians(rng.uniform(5.0, 30.5)) * (1 if rng.random() < 0.5 else -1)
        turn = math.radians(rng.uniform(20.0, 150.0))
        seg.append((t, rate))
        t += turn / abs(rate)
    return seg


def _command(seg: list, t: np.ndarray, col: int) -> np.ndarray:
    starts = np.array([s[0] for s in seg])
    idx = np.searchsorted(starts, t, side="right") - 1
    return np.array([s[col] for s in seg])[np.maximum(idx, 0)]


def _drive(rng: np.random.Generator, duration: float, v_max: float, stop: tuple
           ) -> tuple[np.ndarray, ...]:
    """Kinematic car at SUBSTEP_S: t, rear-axle xy (N, 2), travel heading, speed, yaw rate,
    accel (N,). Limits: the segments' accel (<= 6.5 m/s^2), jerk 6 m/s^3, curvature 1/4.5 m, lateral
    acceleration 4.5 m/s^2 (scaled with v_max), yaw acceleration 0.6 rad/s^2."""
    t = np.arange(0.0, duration + 1e-9, SUBSTEP_S)
    sp = _speed_targets(rng, duration, v_max, stop)
    v_cmd, a_lim = _command(sp, t, 1), _command(sp, t, 2)
    w_cmd = _command(_turn_targets(rng, duration), t, 1)
    scale = v_max / 16.0
    jerk, alat, kappa, yacc = 6.0 * scale, 4.5 * scale, 1 / 4.5, 0.6
    n = t.size
    v = np.zeros(n)
    a = np.zeros(n)
    w = np.zeros(n)
    dt = SUBSTEP_S
    vk = ak = wk = 0.0
    for k in range(1, n):
        a_want = min(max(2.0 * (v_cmd[k] - vk), -a_lim[k]), a_lim[k])
        ak += min(max(a_want - ak, -jerk * dt), jerk * dt)
        vk = max(vk + ak * dt, 0.0)
        if vk == 0.0:
            ak = max(ak, 0.0)
        lim = min(kappa * vk, alat / vk) if vk > 1e-9 else 0.0
        w_want = min(max(w_cmd[k], -lim), lim)
        wk += min(max(w_want - wk, -yacc * dt), yacc * dt)
        wk = min(max(wk, -lim), lim)
        v[k], a[k], w[k] = vk, ak, wk
    psi = np.concatenate(([0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) * dt)))
    psi += rng.uniform(-math.pi, math.pi)
    vm = 0.5 * (v[1:] + v[:-1])
    pm = 0.5 * (psi[1:] + psi[:-1])
    xy = np.zeros((n, 2))
    xy[1:] = np.cumsum(np.c_[vm * np.cos(pm), vm * np.sin(pm)] * dt, axis=0)
    return t, xy, psi, v, w, a


def _availability(rng: np.random.Generator, n: int, rate_hz: float, outage: tuple,
                  block: tuple) -> np.ndarray:
    """(n, 4) bool presence: bursty dropouts per antenna, antenna 4's block, the outage."""
    burst = max(BURST_S * rate_hz, 1.0)
    missing = np.concatenate([markov_dropouts(n, 1, f, burst, rng) for f in ABSENT], axis=1)
    k = np.arange(n) / rate_hz
    missing[(k >= block[0]) & (k < block[1]), 3] = True
    missing[(k >= outage[0]) & (k < outage[1])] = True
    return ~missing


def simulate_vehicle_case(rng: np.random.Generator, *, rate_hz: float = 1.0,
                          duration_s: float = 1514.0, max_speed_mps: float = 16.0
                          ) -> VehicleCase:
    """Draw one drive of the issue-25 car (module docstring).

    rng : the Generator of every draw. rate_hz : GNSS rate, 0.5-20 Hz. duration_s : length,
    s (>= 600: the stop, the block and the outage sit at fixed fractions of it).
    max_speed_mps : top speed (0.1-30 m/s); speeds and accelerations scale with it.
    """
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng: must be a numpy.random.Generator, got {type(rng).__name__}")
    rate = check_real(rate_hz, "rate_hz", lo=0.5, hi=20.0)
    dur = check_real(duration_s, "duration_s", lo=600.0, hi=1e5)
    vmax = check_real(max_speed_mps, "max_speed_mps", lo=0.1, hi=30.0)
    stop = (0.45 * dur, 0.45 * dur + 150.0)
    outage = (0.8 * dur, 0.8 * dur + 34.0)
    block = (0.15 * dur, 0.15 * dur + 333.0)
    ts, xy, psi, v, w, _ = _drive(rng, dur, vmax, stop)
    step = max(round(1.0 / (rate * SUBSTEP_S)), 1)
    ts, xy, psi, v, w = ts[::step], xy[::step], psi[::step], v[::step], w[::step]
    cfg = _layout()
    yaw = psi + MOUNT_YAW_RAD
    c, s = np.cos(psi), np.sin(psi)
    centre = xy + FRAME_AHEAD_M * np.c_[c, s]
    off = cfg.body_positions - cfg.cg_body
    cy, sy = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    pos = np.stack([centre[:, None, 0] + cy * off[:, 0] - sy * off[:, 1],
                    centre[:, None, 1] + sy * off[:, 0] + cy * off[:, 1],
                    np.zeros((ts.size, cfg.m))], -1)
    cm, sm = math.cos(MOUNT_YAW_RAD), math.sin(MOUNT_YAW_RAD)
    ns = (-FRAME_AHEAD_M * cm, FRAME_AHEAD_M * sm)       # R(-mount) (-L, 0)
    vel = np.c_[v * c - w * FRAME_AHEAD_M * s, v * s + w * FRAME_AHEAD_M * c]
    yw = np.angle(np.exp(1j * yaw))
    truth = Truth(t=ts - ts[0], sensor_positions=pos, sensor_names=cfg.names,
                  cg=np.c_[centre, np.zeros(ts.size)], yaw=np.where(yw == -np.pi, np.pi, yw),
                  speed=np.hypot(*vel.T), yaw_rate=w, turning=np.abs(w) > math.radians(3),
                  meta={"model": "vehicle_case", "no_slip_point_m": list(ns),
                        "mount_yaw_rad": MOUNT_YAW_RAD, "rate_hz": rate})
    present = _availability(rng, ts.size, rate, outage, block)
    limits = {"max_speed_mps": vmax, "max_accel_mps2": 6.5 * vmax / 16.0,
              "max_turn_rate_radps": math.radians(30.5),
              "max_lateral_accel_mps2": 4.5 * vmax / 16.0, "max_yaw_accel_radps2": 0.6}
    return VehicleCase(truth=truth, config=cfg, present=present, no_slip_point_m=ns,
                       mount_yaw_rad=MOUNT_YAW_RAD, limits=limits)


def vehicle_observations(case: VehicleCase, noise: str, rng: np.random.Generator
                         ) -> np.ndarray:
    """Antenna fixes (n, 4, 2) m of ``case`` with an error model of :data:`NOISES`, NaN
    where the case's antenna is absent. "rtk": gps_rtk_network (cm common to the antennas,
    ~1.8 mm per antenna); "rtk_independent": gps_rtk per antenna (1.5 cm). "shifted" /
    "common_plus_model": one receiver of a synthesized gps_stationary session (4 n s long)
    replayed by :func:`sim.gps.replay_one` (the latter adds gps_stationary's per-receiver
    part; its own dropouts add to the case's)."""
    if noise not in NOISES:
        raise ValueError(f"noise: must be one of {NOISES}, got {noise!r}")
    tr, n = case.truth, case.truth.n
    if noise == "none":
        obs = tr.sensor_positions[..., :2].copy()
    elif noise in RTK_MODELS:
        dt = float(np.median(np.diff(tr.t)))
        model = GpsNoiseModel.load(RTK_MODELS[noise])
        err, _ = receiver_errors(model, case.config.m, n, dt, rng)
        obs = tr.sensor_positions[..., :2] + err
    else:
        rate = float(tr.meta["rate_hz"])
        model = GpsNoiseModel.load("gps_stationary")
        session = synthesize_session(model, case.config, 4.0 * n / rate + 400.0, rng,
                                     rate_hz=rate).after_power_failure()
        obs, _ = replay_one(tr, session, mode=noise, rng=rng, receiver="1",
                            model=model if noise == "common_plus_model" else None)
    obs[~case.present] = np.nan
    return obs
