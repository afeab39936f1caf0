"""Synthetic scenes for the pose-filter tests: fast (no MuJoCo), with the project's noise.

A path file is driven by the project's own pure-pursuit controller on an ideal kinematic
unicycle (:func:`sim.controllers.simulate_unicycle`: the controlled point is the no-slip
point, exactly), sampled at the path's rate; the antennas sit at their body offsets from the
CG, which is ``cg_ahead_m`` ahead of the no-slip point. Observations come from
:func:`sim.gps.observe` with a noise model of ``models/noise/`` (or none).
"""

from __future__ import annotations

import numpy as np

from estimator.configuration import SensorConfig
from sim.controllers import PurePursuitParams, simulate_unicycle
from sim.gps import observe
from sim.paths import load_path
from sim.truth import Truth


def kinematic_truth(path: str, config: str, cg_ahead_m: float = 0.0,
                    overrides: dict | None = None) -> tuple[Truth, SensorConfig, dict]:
    """Truth of ``config`` driven along ``path`` (a models/paths name) by the unicycle.

    Returns (truth, planar config, limits) where limits are the controller's parameters
    (the platform limits the pose filter takes).
    """
    p = load_path(path)
    if overrides:
        from sim.paths import Path

        p = Path.from_dict({**p.to_dict(), **overrides})
    cfg = SensorConfig.load(config).planar()
    params = PurePursuitParams.from_path(p)
    t, xy, yaw = simulate_unicycle(p, params, dt=0.01)
    step = int(round(1.0 / (p.sample_rate_hz * 0.01)))
    t, xy, yaw = t[::step], xy[::step], yaw[::step]
    c, s = np.cos(yaw), np.sin(yaw)
    cg = xy + cg_ahead_m * np.c_[c, s]
    off = cfg.body_positions - cfg.cg_body
    pos = np.stack([cg[:, None, 0] + c[:, None] * off[:, 0] - s[:, None] * off[:, 1],
                    cg[:, None, 1] + s[:, None] * off[:, 0] + c[:, None] * off[:, 1],
                    np.zeros((t.size, cfg.m))], axis=-1)
    n = t.size
    vel = np.gradient(cg, t, axis=0)
    yaw_w = np.angle(np.exp(1j * yaw))
    yaw_w = np.where(yaw_w == -np.pi, np.pi, yaw_w)
    truth = Truth(t=t - t[0], sensor_positions=pos, sensor_names=cfg.names,
                  cg=np.c_[cg, np.zeros(n)], yaw=yaw_w, speed=np.hypot(*vel.T),
                  yaw_rate=np.gradient(np.unwrap(yaw), t), turning=np.zeros(n, bool),
                  meta={"no_slip_point_m": [-cg_ahead_m, 0.0]})
    limits = {k: getattr(params, k) for k in ("max_accel_mps2", "max_yaw_accel_radps2",
                                              "max_turn_rate_radps", "max_lateral_accel_mps2")}
    return truth, cfg, limits


def noisy(truth: Truth, cfg: SensorConfig, noise: str, seed: int) -> np.ndarray:
    """The scene's observations (n, m, 2) with a noise model, the sweep's way."""
    return np.array(observe(truth, cfg, noise, rng=np.random.default_rng(seed),
                            session_s=4000.0))


def vehicle_scene(seed: int, noise: str = "rtk", **kw):
    """The issue-25 car (:func:`sim.vehicle_case.simulate_vehicle_case`, drive seed ``seed``,
    keywords passed on) with an error model of :data:`sim.vehicle_case.NOISES` (noise seed
    1000 + seed): (case, t (n,) s, obs (n, 4, 2) m, offsets (4, 2) m from the CG)."""
    from sim.vehicle_case import simulate_vehicle_case, vehicle_observations

    case = simulate_vehicle_case(np.random.default_rng(seed), **kw)
    obs = vehicle_observations(case, noise, np.random.default_rng(1000 + seed))
    off = case.config.body_positions - case.config.cg_body
    return case, case.truth.t, obs, off


def square_layout(pos: np.ndarray, yaw: np.ndarray, half_m: float = 0.4
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Four antennas on a square of half-side ``half_m`` (m) about the CG, body frame
    (forward, left): (offsets (4, 2), noise-free observations (n, 4, 2)) of a CG at ``pos``
    (n, 2) m with heading ``yaw`` (n,) rad."""
    h = half_m
    off = np.array([[h, h], [h, -h], [-h, h], [-h, -h]])
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    obs = np.stack((pos[:, None, 0] + c * off[:, 0] - s * off[:, 1],
                    pos[:, None, 1] + s * off[:, 0] + c * off[:, 1]), axis=-1)
    return off, obs
