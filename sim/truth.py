"""Ground-truth trajectories logged by the simulators.

A :class:`Truth` is what the dissertation's Simulink model provided as the "perfect" case
(000_8f82f8df647bf685.txt, Section 4.1.2): exact sensor positions, CG and heading at the
sensor sample times, plus the controller's turning flag (the "control information" of
Section 3.4.2.1). The quadcopter uses the same record with its two ultrasonic transmitters
as the sensors.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sim.atomic import atomic_write

__all__ = ["Truth"]

_ARRAYS = ("t", "sensor_positions", "cg", "yaw", "speed", "yaw_rate", "turning")


@dataclass(frozen=True, eq=False)
class Truth:
    """Exact trajectory of a simulated platform, sampled at the sensor rate.

    Attributes
    ----------
    t : (n,) float64, seconds, strictly increasing (uneven for ultrasonic sampling).
    sensor_positions : (n, m, 3) float64, metres, world frame (x east, y north, z up).
    sensor_names : tuple of m str, matching the sensor configuration's names.
    cg : (n, 3) float64, metres, the platform's centre of gravity / body origin.
    yaw : (n,) float64, radians, counter-clockwise from +x, wrapped to (-pi, pi].
    speed : (n,) float64, m/s, horizontal speed of the CG.
    yaw_rate : (n,) float64, rad/s.
    turning : (n,) bool, the controller's own "turning" flag (Section 3.4.2.1).
    meta : dict, JSON-serialisable: model, path, parameters, seed, versions, hash.
    """

    t: np.ndarray
    sensor_positions: np.ndarray
    sensor_names: tuple[str, ...]
    cg: np.ndarray
    yaw: np.ndarray
    speed: np.ndarray
    yaw_rate: np.ndarray
    turning: np.ndarray
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=float)
        n = t.shape[0] if t.ndim == 1 else -1
        if t.ndim != 1 or n < 1:
            raise ValueError(f"t: expected shape (n,), got {t.shape}")
        if n > 1 and not np.all(np.diff(t) > 0):
            raise ValueError("t: must be strictly increasing")
        sp = np.asarray(self.sensor_positions, dtype=float)
        if sp.ndim != 3 or sp.shape[0] != n or sp.shape[2] != 3:
            raise ValueError(f"sensor_positions: expected shape ({n}, m, 3), got {sp.shape}")
        if len(self.sensor_names) != sp.shape[1]:
            raise ValueError(
                f"sensor_names: {len(self.sensor_names)} names for {sp.shape[1]} sensors")
        checks = {"cg": (n, 3), "yaw": (n,), "speed": (n,), "yaw_rate": (n,), "turning": (n,)}
        for name, shape in checks.items():
            arr = np.asarray(getattr(self, name))
            if arr.shape != shape:
                raise ValueError(f"{name}: expected shape {shape}, got {arr.shape}")
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "sensor_positions", sp)
        object.__setattr__(self, "sensor_names", tuple(str(s) for s in self.sensor_names))
        object.__setattr__(self, "cg", np.asarray(self.cg, dtype=float))
        object.__setattr__(self, "yaw", np.asarray(self.yaw, dtype=float))
        object.__setattr__(self, "speed", np.asarray(self.speed, dtype=float))
        object.__setattr__(self, "yaw_rate", np.asarray(self.yaw_rate, dtype=float))
        object.__setattr__(self, "turning", np.asarray(self.turning, dtype=bool))

    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.t.shape[0])

    @property
    def m(self) -> int:
        """Number of sensors."""
        return int(self.sensor_positions.shape[1])

    def save(self, path: str | Path) -> Path:
        """Write to a single ``.npz`` file (atomically: temp file then rename)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)

        def write(tmp: Path) -> None:
            with open(tmp, "wb") as fh:
                np.savez(fh, **{k: getattr(self, k) for k in _ARRAYS},
                         sensor_names=np.array(self.sensor_names),
                         meta=np.array(json.dumps(self.meta, sort_keys=True, default=str)))

        return atomic_write(path, write)

    @classmethod
    def load(cls, path: str | Path) -> Truth:
        """Read a file written by :meth:`save`."""
        with np.load(Path(path), allow_pickle=False) as z:
            kw = {k: z[k] for k in _ARRAYS}
            return cls(sensor_names=tuple(str(s) for s in z["sensor_names"]),
                       meta=json.loads(str(z["meta"])), **kw)
