"""Hand-built rigid-platform trajectories for the tracking tests (no simulator).

The platform follows a constant twist per segment (straight lines and circular arcs), so
the truth is known in closed form: CG position, heading and every antenna position.
"""

from __future__ import annotations

import numpy as np

from estimator.configuration import SensorConfig


def rover() -> SensorConfig:
    """The repository's default 8-antenna layout (sensor 4 dead, CG from 2, 3, 6, 7)."""
    return SensorConfig.load("rover_gps8").planar()


def constant_twist(t: np.ndarray, speed: float, yaw0: float, yaw_rate: float = 0.0,
                   start=(0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """CG (n, 2) and yaw (n,) (unwrapped) of a platform moving along its heading at
    ``speed`` with constant ``yaw_rate`` (exact integration), starting at ``start``."""
    t = np.asarray(t, dtype=float) - t[0]
    yaw = yaw0 + yaw_rate * t
    if abs(yaw_rate) < 1e-12:
        xy = np.c_[speed * t * np.cos(yaw0), speed * t * np.sin(yaw0)]
    else:
        r = speed / yaw_rate
        xy = np.c_[r * (np.sin(yaw) - np.sin(yaw0)), r * (np.cos(yaw0) - np.cos(yaw))]
    return xy + np.asarray(start, dtype=float), yaw


def antennas(cfg: SensorConfig, cg: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """(n, m, 2) antenna positions for CG track and yaw; dead sensors are NaN."""
    off = cfg.body_positions[:, :2] - cfg.cg_body[:2]
    c, s = np.cos(yaw), np.sin(yaw)
    rx = c[:, None] * off[None, :, 0] - s[:, None] * off[None, :, 1]
    ry = s[:, None] * off[None, :, 0] + c[:, None] * off[None, :, 1]
    pos = np.stack([cg[:, None, 0] + rx, cg[:, None, 1] + ry], axis=-1)
    pos[:, ~cfg.alive_mask] = np.nan
    return pos


def straight(n: int = 300, speed: float = 1.5, yaw: float = 0.7, dt: float = 1.0):
    """Straight constant-velocity run: t, CG, yaw, observations (noise-free)."""
    cfg = rover()
    t = np.arange(n) * dt
    cg, y = constant_twist(t, speed, yaw)
    return cfg, t, cg, y, antennas(cfg, cg, y)


def corner_path(speed: float = 1.5, dt: float = 1.0, leg_steps: int = 60,
                turn_steps: int = 4):
    """Straight, 90 degree left turn over ``turn_steps`` samples, straight; every segment
    a whole number of samples, so the time stamps are exact. Returns cfg, t, cg, yaw
    (unwrapped), turning flags, noise-free observations."""
    cfg = rover()
    leg_s = leg_steps * dt
    turn_s = turn_steps * dt
    turn_rate = (np.pi / 2) / turn_s
    t1 = np.arange(leg_steps) * dt
    cg1, y1 = constant_twist(np.r_[t1, leg_s], speed, 0.0)
    t2 = np.arange(turn_steps) * dt
    cg2, y2 = constant_twist(np.r_[t2, turn_s], speed, 0.0, turn_rate, start=cg1[-1])
    t3 = np.arange(leg_steps) * dt
    cg3, y3 = constant_twist(t3, speed, np.pi / 2, 0.0, start=cg2[-1])
    cg = np.r_[cg1[:-1], cg2[:-1], cg3]
    yaw = np.r_[y1[:-1], y2[:-1], y3]
    turning = np.r_[np.zeros(t1.size, bool), np.ones(t2.size, bool), np.zeros(t3.size, bool)]
    t = np.arange(cg.shape[0]) * dt
    return cfg, t, cg, yaw, turning, antennas(cfg, cg, yaw)
