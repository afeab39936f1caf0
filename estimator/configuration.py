"""Sensor configurations: names, body-frame mounting positions, dead sensors, CG members.

The configuration is the "known sensor configuration" of the GPS dissertation
(000_8f82f8df647bf685.txt, Section 3.1.1): the pairwise distances a_ij between sensors
are what the window fit constrains (Eq. 3.7, 3.9), and the centre of gravity is the mean
of a chosen subset of sensors (Eq. 3.8).

Body frame: x forward, y left, z up, metres. TOML format (see models/configs/)::

    name = "rover_gps8"
    description = "..."
    mount_height_m = 0.9          # optional, height of 2-D sensors above ground (simulation)
    cg_sensors = ["2", "3", "6", "7"]   # optional, default: all sensors
    dead = ["4"]                  # optional, sensors that never report

    [[sensor]]
    name = "1"
    position_m = [0.75, 0.5]      # 2 or 3 numbers, the same count for every sensor
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from estimator.model_files import MODELS_DIR, read_model_toml

__all__ = ["SensorConfig", "ConfigError", "MODELS_DIR", "CONFIGS_DIR"]

CONFIGS_DIR = MODELS_DIR / "configs"


class ConfigError(ValueError):
    """A sensor configuration (or its TOML file) is invalid; the message names the field."""


def _as_names(names: Iterable[object], field_name: str) -> tuple[str, ...]:
    out = tuple(str(n) for n in names)
    if any(n == "" for n in out):
        raise ConfigError(f"{field_name}: sensor names must be non-empty strings, got {out!r}")
    seen: set[str] = set()
    for n in out:
        if n in seen:
            raise ConfigError(f"{field_name}: duplicate sensor name {n!r}")
        seen.add(n)
    return out


@dataclass(frozen=True, eq=False)
class SensorConfig:
    """A rigid sensor layout in the platform's body frame.

    Parameters
    ----------
    names : sequence of str, length m
        Sensor names (unique). The dissertation numbers its antennas "1".."8".
    body_positions : array_like, shape (m, d), d in {2, 3}, metres
        Mounting positions in the body frame (x forward, y left, z up).
    cg_members : sequence of str or int, optional
        Sensors whose mean defines the centre of gravity (Eq. 3.8). Default: all sensors.
    dead : sequence of str or int, optional
        Sensors that never report (the dissertation's sensor 4). They stay in the layout
        (their distances still constrain nothing, because they have no observations).
    mount_height_m : float, optional
        Height of a 2-D layout above the ground, used only by the simulator.
    name, description : str
        Free text for reports.
    """

    names: tuple[str, ...]
    body_positions: np.ndarray
    cg_members: tuple[str, ...] = ()
    dead: tuple[str, ...] = ()
    mount_height_m: float = 0.0
    name: str = "config"
    description: str = ""
    _index: dict = field(default_factory=dict, repr=False, compare=False)

    def __init__(
        self,
        names: Sequence[object],
        body_positions: object,
        cg_members: Sequence[object] | None = None,
        dead: Sequence[object] = (),
        *,
        mount_height_m: float = 0.0,
        name: str = "config",
        description: str = "",
    ) -> None:
        names_t = _as_names(names, "names")
        pos = np.array(body_positions, dtype=float)
        if pos.ndim != 2:
            raise ConfigError(
                f"body_positions: expected shape (m, d), got {pos.shape}")
        if pos.shape[0] != len(names_t):
            raise ConfigError(
                f"body_positions: {pos.shape[0]} rows for {len(names_t)} names")
        if pos.shape[1] not in (2, 3):
            raise ConfigError(f"body_positions: dimension d must be 2 or 3, got {pos.shape[1]}")
        if len(names_t) < 2:
            raise ConfigError(f"names: a configuration needs at least 2 sensors, got {len(names_t)}")
        if not np.all(np.isfinite(pos)):
            bad = int(np.argwhere(~np.isfinite(pos))[0, 0])
            raise ConfigError(f"body_positions: sensor {names_t[bad]!r} has a non-finite coordinate")
        diff = pos[:, None, :] - pos[None, :, :]
        dist = np.sqrt((diff**2).sum(-1))
        np.fill_diagonal(dist, np.inf)
        if dist.min() <= 1e-9:
            i, j = np.unravel_index(np.argmin(dist), dist.shape)
            raise ConfigError(
                f"body_positions: sensors {names_t[i]!r} and {names_t[j]!r} coincide")
        if not (isinstance(mount_height_m, (int, float)) and math.isfinite(mount_height_m)):
            raise ConfigError(f"mount_height_m: must be a finite number, got {mount_height_m!r}")
        index = {n: k for k, n in enumerate(names_t)}

        def resolve(items: Sequence[object], field_name: str) -> tuple[str, ...]:
            out = []
            for it in items:
                if isinstance(it, (int, np.integer)) and not isinstance(it, bool):
                    if not 0 <= int(it) < len(names_t):
                        raise ConfigError(f"{field_name}: index {it} out of range 0..{len(names_t)-1}")
                    out.append(names_t[int(it)])
                elif str(it) in index:
                    out.append(str(it))
                else:
                    raise ConfigError(f"{field_name}: unknown sensor {it!r}; known: {list(names_t)}")
            if len(set(out)) != len(out):
                raise ConfigError(f"{field_name}: duplicate entries {out!r}")
            return tuple(out)

        dead_t = resolve(dead, "dead")
        cg_t = resolve(cg_members if cg_members is not None else names_t, "cg_members")
        if not cg_t:
            raise ConfigError("cg_members: must name at least one sensor")
        if len(dead_t) > len(names_t) - 2:
            raise ConfigError(f"dead: at most m - 2 = {len(names_t) - 2} sensors may be dead, got {len(dead_t)}")
        pos.setflags(write=False)
        object.__setattr__(self, "names", names_t)
        object.__setattr__(self, "body_positions", pos)
        object.__setattr__(self, "cg_members", cg_t)
        object.__setattr__(self, "dead", dead_t)
        object.__setattr__(self, "mount_height_m", float(mount_height_m))
        object.__setattr__(self, "name", str(name))
        object.__setattr__(self, "description", str(description))
        object.__setattr__(self, "_index", index)

    # ------------------------------------------------------------------ basic views
    @property
    def m(self) -> int:
        """Number of sensors."""
        return len(self.names)

    @property
    def d(self) -> int:
        """Spatial dimension of the layout (2 or 3)."""
        return int(self.body_positions.shape[1])

    def index(self, name: str | int) -> int:
        """Index of a sensor by name (or pass-through of a valid index)."""
        if isinstance(name, (int, np.integer)) and not isinstance(name, bool):
            if 0 <= int(name) < self.m:
                return int(name)
            raise ConfigError(f"sensor index {name} out of range 0..{self.m - 1}")
        try:
            return self._index[str(name)]
        except KeyError:
            raise ConfigError(f"unknown sensor {name!r}; known: {list(self.names)}") from None

    @property
    def alive_mask(self) -> np.ndarray:
        """(m,) bool, False for dead sensors."""
        mask = np.ones(self.m, dtype=bool)
        for n in self.dead:
            mask[self._index[n]] = False
        return mask

    @property
    def cg_mask(self) -> np.ndarray:
        """(m,) bool, True for the sensors that define the CG (Eq. 3.8)."""
        mask = np.zeros(self.m, dtype=bool)
        for n in self.cg_members:
            mask[self._index[n]] = True
        return mask

    @property
    def cg_body(self) -> np.ndarray:
        """(d,) body-frame CG: mean of the CG members' positions (Eq. 3.8), metres."""
        return self.body_positions[self.cg_mask].mean(axis=0)

    def distances(self) -> np.ndarray:
        """(m, m) pairwise distances a_ij in metres (Section 3.1.1), zero diagonal."""
        diff = self.body_positions[:, None, :] - self.body_positions[None, :, :]
        return np.sqrt((diff**2).sum(-1))

    def cg_from_positions(self, positions: np.ndarray) -> np.ndarray:
        """CG of estimated sensor positions, Eq. 3.8: mean over the CG members.

        positions: (..., m, d) -> (..., d).
        """
        positions = np.asarray(positions, dtype=float)
        return positions[..., self.cg_mask, :].mean(axis=-2)

    def planar(self) -> "SensorConfig":
        """The same layout projected to the xy-plane (d = 2); a 2-D config returns itself."""
        if self.d == 2:
            return self
        return SensorConfig(self.names, self.body_positions[:, :2], self.cg_members, self.dead,
                            mount_height_m=self.mount_height_m, name=self.name,
                            description=self.description)

    def __repr__(self) -> str:
        return (f"SensorConfig(name={self.name!r}, m={self.m}, d={self.d}, "
                f"dead={list(self.dead)}, cg_members={list(self.cg_members)})")

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_distances(
        cls,
        names: Sequence[object],
        D: object,
        *,
        d: int = 2,
        rtol: float = 1e-6,
        **kwargs: object,
    ) -> "SensorConfig":
        """Recover a body frame from a pairwise distance matrix by classical MDS.

        ``D`` is (m, m), metres. It must be finite, symmetric, non-negative with a zero
        diagonal, satisfy the triangle inequality, and embed in ``d`` dimensions with a
        residual at most ``rtol * max(D)`` (plus 1e-9 m). Otherwise ``ConfigError`` names
        the worst pair. The recovered frame is centred on the sensors' centroid, with its
        axes along the principal directions; distances are what matter to the fit
        (Section 3.1.1), not the frame.
        """
        names_t = _as_names(names, "names")
        D = np.array(D, dtype=float)
        m = len(names_t)
        if D.shape != (m, m):
            raise ConfigError(f"D: expected shape ({m}, {m}) for {m} names, got {D.shape}")
        if d not in (2, 3):
            raise ConfigError(f"d: must be 2 or 3, got {d!r}")
        if not np.all(np.isfinite(D)):
            i, j = np.argwhere(~np.isfinite(D))[0]
            raise ConfigError(f"D: entry ({names_t[i]!r}, {names_t[j]!r}) is not finite")
        scale = float(np.max(np.abs(D))) if m else 0.0
        tol = rtol * scale + 1e-9
        if np.any(np.abs(np.diag(D)) > tol):
            i = int(np.argmax(np.abs(np.diag(D))))
            raise ConfigError(f"D: diagonal entry for {names_t[i]!r} is {D[i, i]!r}, must be 0")
        asym = np.abs(D - D.T)
        if asym.max() > tol:
            i, j = np.unravel_index(np.argmax(asym), asym.shape)
            raise ConfigError(
                f"D: not symmetric, worst pair ({names_t[i]!r}, {names_t[j]!r}): "
                f"{D[i, j]!r} vs {D[j, i]!r}")
        if D.min() < 0:
            i, j = np.unravel_index(np.argmin(D), D.shape)
            raise ConfigError(f"D: negative distance for pair ({names_t[i]!r}, {names_t[j]!r}): {D[i, j]!r}")
        D = 0.5 * (D + D.T)
        # triangle inequality: D[i,j] <= D[i,k] + D[k,j] for all k
        # excess[i, j, k] = D[i,j] - D[i,k] - D[k,j]
        excess = D[:, :, None] - D[:, None, :] - D.T[None, :, :]
        if excess.max() > tol:
            i, j, k = np.unravel_index(np.argmax(excess), excess.shape)
            raise ConfigError(
                f"D: triangle inequality violated by {excess[i, j, k]:.6g} m for pair "
                f"({names_t[i]!r}, {names_t[j]!r}) via {names_t[k]!r}")
        # classical MDS: B = -1/2 J D^2 J, X = V_d sqrt(L_d)
        J = np.eye(m) - 1.0 / m
        B = -0.5 * J @ (D**2) @ J
        evals, evecs = np.linalg.eigh(B)
        order = np.argsort(evals)[::-1]
        evals, evecs = evals[order], evecs[:, order]
        top = np.clip(evals[:d], 0.0, None)
        X = evecs[:, :d] * np.sqrt(top)
        diff = X[:, None, :] - X[None, :, :]
        resid = np.abs(np.sqrt((diff**2).sum(-1)) - D)
        if resid.max() > tol:
            i, j = np.unravel_index(np.argmax(resid), resid.shape)
            raise ConfigError(
                f"D: not realizable in {d} dimensions; worst pair ({names_t[i]!r}, "
                f"{names_t[j]!r}) is off by {resid[i, j]:.6g} m after embedding")
        return cls(names_t, X, **kwargs)  # type: ignore[arg-type]

    @classmethod
    def load(cls, path_or_name: str | Path) -> "SensorConfig":
        """Load a configuration TOML: a path, or a name looked up in ``models/configs/``.

        Every field is validated; unknown keys are rejected. Errors name the file and field.
        """
        data, path = read_model_toml(path_or_name, CONFIGS_DIR, "config", error=ConfigError)
        return cls.from_dict(data, source=str(path))

    @classmethod
    def from_dict(cls, data: dict, *, source: str = "<dict>") -> "SensorConfig":
        """Build from the TOML table structure documented in the module docstring."""
        allowed = {"name", "description", "mount_height_m", "cg_sensors", "dead", "sensor"}
        unknown = sorted(set(data) - allowed)
        if unknown:
            raise ConfigError(f"{source}: unknown key(s) {unknown}; allowed: {sorted(allowed)}")
        sensors = data.get("sensor")
        if not isinstance(sensors, list) or not sensors:
            raise ConfigError(f"{source}: 'sensor' must be a non-empty array of tables ([[sensor]])")
        names, positions = [], []
        for k, s in enumerate(sensors):
            where = f"{source}: sensor[{k}]"
            if not isinstance(s, dict):
                raise ConfigError(f"{where}: must be a table with 'name' and 'position_m'")
            extra = sorted(set(s) - {"name", "position_m"})
            if extra:
                raise ConfigError(f"{where}: unknown key(s) {extra}; allowed: ['name', 'position_m']")
            if "name" not in s:
                raise ConfigError(f"{where}.name: missing")
            if not isinstance(s["name"], (str, int)) or isinstance(s["name"], bool):
                raise ConfigError(f"{where}.name: must be a string, got {s['name']!r}")
            p = s.get("position_m")
            if (not isinstance(p, list) or len(p) not in (2, 3)
                    or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in p)):
                raise ConfigError(f"{where}.position_m: must be 2 or 3 numbers (metres), got {p!r}")
            if positions and len(p) != len(positions[0]):
                raise ConfigError(
                    f"{where}.position_m: has {len(p)} coordinates, sensor[0] has {len(positions[0])}")
            names.append(str(s["name"]))
            positions.append([float(v) for v in p])
        for key in ("cg_sensors", "dead"):
            if key in data and not isinstance(data[key], list):
                raise ConfigError(f"{source}: {key} must be a list of sensor names, got {data[key]!r}")
        mh = data.get("mount_height_m", 0.0)
        if not isinstance(mh, (int, float)) or isinstance(mh, bool) or not math.isfinite(mh) or mh < 0:
            raise ConfigError(f"{source}: mount_height_m must be a number >= 0 (metres), got {mh!r}")
        for key in ("name", "description"):
            if key in data and not isinstance(data[key], str):
                raise ConfigError(f"{source}: {key} must be a string, got {data[key]!r}")
        try:
            return cls(
                names, positions,
                cg_members=[str(x) for x in data["cg_sensors"]] if "cg_sensors" in data else None,
                dead=[str(x) for x in data.get("dead", [])],
                mount_height_m=float(mh),
                name=data.get("name", Path(source).stem),
                description=data.get("description", ""),
            )
        except ConfigError as exc:
            raise ConfigError(f"{source}: {exc}") from None
