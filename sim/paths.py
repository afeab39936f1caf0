"""Experiment paths as data: waypoint lists with target areas, loaded from TOML, plus geometry.

The GPS dissertation (000_8f82f8df647bf685.txt, Section 4.9) drives its platform around two
squares, Path 1 (0,0)->(100,0)->(100,100)->(0,100)->(0,0) and Path 2 (the 200 m square), with
"target areas of a certain diameter around the target points", so the platform "does not
necessarily move in a straight line to the target points and may take a curved path". A
:class:`Path` holds exactly that: the ordered target points, the target-area radius, the
cruise speed, the sensor sample rate, and optional platform limits. The quadcopter (thesis 003)
uses the same record with 3-D waypoints or ``altitude_m``.

TOML schema (``models/paths/<name>.toml``; every key validated, unknown keys rejected, errors
name the file and the field)::

    name = "square100"                 # required, must equal the file's stem
    description = "..."                # optional free text
    waypoints = [[0, 0], [100, 0], [100, 100], [0, 100]]   # >= 2 points, [x, y] or [x, y, z] m
    closed = true                      # required: after the last waypoint return to the first
    target_radius_m = 3.0              # required, > 0: radius of the target area around a point
    cruise_speed_mps = 1.5             # required, > 0
    sample_rate_hz = 1.0               # optional, > 0, sensor (GPS) rate; default 1 Hz
    # optional platform-specific limits (> 0 where given; absent = the simulator's default)
    max_turn_rate_radps = 0.8
    max_lateral_accel_mps2 = 0.8
    max_accel_mps2 = 0.5
    lookahead_m = 3.0                  # pure-pursuit lookahead distance
    altitude_m = 1.5                   # quadcopter: flight altitude for 2-D waypoints (finite)
    corner_speed_mps = 5.0             # optional, > 0: brake before each corner to this speed
                                       # (a driver's anticipation; absent = no anticipation)
    vehicle = "car"                    # optional: MuJoCo model models/<vehicle>.xml that
                                       # drives the path (absent = models/rover.xml)

Conventions: the first waypoint is the start. With ``closed = true`` the route returns to the
first waypoint at the end (do not repeat it; a repeated start point is rejected as ambiguous).
The *polyline* is the route's vertices (start, targets..., and the start again when closed).
*Corners* are the polyline's interior vertices, where the route changes direction; the route's
end point is not a corner (the platform stops there).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path as FsPath
from typing import Any

import numpy as np

from estimator.model_files import MODELS_DIR, read_model_toml

__all__ = [
    "PATHS_DIR",
    "Path",
    "PathError",
    "PathErrors",
    "available_paths",
    "load_path",
    "path_errors",
    "project_to_polyline",
]

PATHS_DIR = MODELS_DIR / "paths"

_REQUIRED = ("name", "waypoints", "closed", "target_radius_m", "cruise_speed_mps")
_POSITIVE_OPTIONAL = ("max_turn_rate_radps", "max_lateral_accel_mps2", "max_accel_mps2",
                      "lookahead_m", "corner_speed_mps")
#: Physical ranges of the numeric fields (units in the names). A value outside is a typo
#: (km/h for m/s, ms for s) and would make a simulation run for days or never move.
_RANGES = {
    "target_radius_m": (1e-3, 1e4),
    "cruise_speed_mps": (1e-2, 100.0),          # 1 cm/s .. 360 km/h
    "sample_rate_hz": (1e-2, 1e3),
    "max_turn_rate_radps": (1e-3, 100.0),
    "max_lateral_accel_mps2": (1e-3, 100.0),    # 10 g
    "max_accel_mps2": (1e-3, 100.0),
    "lookahead_m": (1e-2, 1e4),
    "corner_speed_mps": (1e-2, 100.0),
}
#: Longest route a path may describe at its cruise speed (simulated time, s): 7 days.
MAX_ROUTE_S = 7 * 86400.0
_ALLOWED = set(_REQUIRED) | set(_POSITIVE_OPTIONAL) | {"description", "sample_rate_hz",
                                                        "altitude_m", "vehicle"}


class PathError(ValueError):
    """A path (or its TOML file) is invalid; the message names the file and the field."""


def _is_number(v: object) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


@dataclass(frozen=True, eq=False)
class Path:
    """An experiment path: ordered target points with target areas (Section 4.9).

    Attributes
    ----------
    name : str
    waypoints : (k, d) float64, metres, d in {2, 3}; ``waypoints[0]`` is the start.
    closed : bool, return to ``waypoints[0]`` after the last waypoint.
    target_radius_m : float, radius of the target area around each target point.
    cruise_speed_mps : float
    sample_rate_hz : float, sensor rate of the logged truth (GPS: 1 Hz).
    description : str
    altitude_m, max_turn_rate_radps, max_lateral_accel_mps2, max_accel_mps2, lookahead_m :
        float or None (None = the simulator's own default).
    corner_speed_mps : float or None, speed to brake to before each corner (None = none).
    vehicle : str or None, the MuJoCo model ``models/<vehicle>.xml`` driving the path
        (None = the rover).
    source : str, the file the path was read from (or "<dict>").
    """

    name: str
    waypoints: np.ndarray
    closed: bool
    target_radius_m: float
    cruise_speed_mps: float
    sample_rate_hz: float = 1.0
    description: str = ""
    altitude_m: float | None = None
    max_turn_rate_radps: float | None = None
    max_lateral_accel_mps2: float | None = None
    max_accel_mps2: float | None = None
    lookahead_m: float | None = None
    corner_speed_mps: float | None = None
    vehicle: str | None = None
    source: str = field(default="<dict>", compare=False)

    def __post_init__(self) -> None:
        src = self.source
        if not isinstance(self.name, str) or not self.name:
            raise PathError(f"{src}: name must be a non-empty string, got {self.name!r}")
        wp = np.array(self.waypoints, dtype=float)
        if wp.ndim != 2 or wp.shape[0] < 2 or wp.shape[1] not in (2, 3):
            raise PathError(
                f"{src}: waypoints must be >= 2 points of [x, y] or [x, y, z], got shape "
                f"{wp.shape}")
        if not np.all(np.isfinite(wp)):
            bad = int(np.argwhere(~np.isfinite(wp))[0, 0])
            raise PathError(f"{src}: waypoints[{bad}] has a non-finite coordinate: "
                            f"{wp[bad].tolist()}")
        if not isinstance(self.closed, (bool, np.bool_)):
            raise PathError(f"{src}: closed must be true or false, got {self.closed!r}")
        closed = bool(self.closed)
        if closed and wp.shape[0] < 3:
            raise PathError(f"{src}: waypoints: a closed path needs >= 3 points, got {wp.shape[0]}")
        if closed and np.allclose(wp[0], wp[-1]):
            raise PathError(
                f"{src}: waypoints: the last point {wp[-1].tolist()} repeats the start while "
                "closed = true; drop it (closed already returns to the start)")
        for key in ("target_radius_m", "cruise_speed_mps", "sample_rate_hz", *_POSITIVE_OPTIONAL):
            v = getattr(self, key)
            if v is None and key in _POSITIVE_OPTIONAL:
                continue
            if not _is_number(v) or not math.isfinite(v) or v <= 0:
                raise PathError(f"{src}: {key} must be a finite number > 0, got {v!r}")
            lo, hi = _RANGES[key]
            if not lo <= v <= hi:
                raise PathError(f"{src}: {key} = {v!r} is outside its physical range "
                                f"[{lo:g}, {hi:g}]")
            object.__setattr__(self, key, float(v))
        if self.vehicle is not None and not (isinstance(self.vehicle, str)
                                             and self.vehicle.isidentifier()):
            raise PathError(f"{src}: vehicle must be a model name such as \"car\" "
                            f"(models/<vehicle>.xml), got {self.vehicle!r}")
        if self.altitude_m is not None:
            if not _is_number(self.altitude_m) or not math.isfinite(self.altitude_m):
                raise PathError(f"{src}: altitude_m must be a finite number, got "
                                f"{self.altitude_m!r}")
            object.__setattr__(self, "altitude_m", float(self.altitude_m))
        verts = np.vstack([wp, wp[:1]]) if closed else wp
        seg = np.linalg.norm(np.diff(verts, axis=0), axis=1)
        if seg.min() <= 1e-9:
            i = int(np.argmin(seg))
            raise PathError(f"{src}: waypoints[{i}] and the next point coincide: "
                            f"{verts[i].tolist()}")
        if self.target_radius_m >= 0.5 * seg.min():
            raise PathError(
                f"{src}: target_radius_m = {self.target_radius_m} must be less than half the "
                f"shortest segment ({seg.min():.6g} m), or neighbouring target areas overlap")
        if not isinstance(self.description, str):
            raise PathError(f"{src}: description must be a string, got {self.description!r}")
        if seg.sum() / self.cruise_speed_mps > MAX_ROUTE_S:
            raise PathError(f"{src}: the route is {seg.sum():.6g} m long at "
                            f"{self.cruise_speed_mps:g} m/s, more than 7 days of simulation")
        wp.setflags(write=False)
        object.__setattr__(self, "waypoints", wp)
        object.__setattr__(self, "closed", closed)

    # ------------------------------------------------------------------ geometry views
    @property
    def d(self) -> int:
        """Dimension of the waypoints (2 or 3)."""
        return int(self.waypoints.shape[1])

    @property
    def start(self) -> np.ndarray:
        """(d,) the start point, ``waypoints[0]``."""
        return self.waypoints[0]

    @property
    def polyline(self) -> np.ndarray:
        """(k + closed, d) route vertices: the waypoints, plus the start again when closed."""
        wp = self.waypoints
        return np.vstack([wp, wp[:1]]) if self.closed else wp.copy()

    @property
    def targets(self) -> np.ndarray:
        """(k - 1 + closed, d) the target points visited after the start, in order."""
        return self.polyline[1:]

    @property
    def corner_indices(self) -> np.ndarray:
        """(c,) int, indices into :attr:`polyline` of the interior vertices (the turns)."""
        return np.arange(1, self.polyline.shape[0] - 1)

    @property
    def corners(self) -> np.ndarray:
        """(c, d) the corner points (interior vertices of the polyline)."""
        return self.polyline[self.corner_indices]

    @property
    def length_m(self) -> float:
        """Total polyline length, metres."""
        return float(np.linalg.norm(np.diff(self.polyline, axis=0), axis=1).sum())

    def to_dict(self) -> dict[str, Any]:
        """JSON/TOML-serialisable dict of every field (the inverse of :meth:`from_dict`)."""
        out: dict[str, Any] = {
            "name": self.name, "description": self.description,
            "waypoints": self.waypoints.tolist(), "closed": self.closed,
            "target_radius_m": self.target_radius_m, "cruise_speed_mps": self.cruise_speed_mps,
            "sample_rate_hz": self.sample_rate_hz,
        }
        for key in ("altitude_m", *_POSITIVE_OPTIONAL, "vehicle"):
            v = getattr(self, key)
            if v is not None:
                out[key] = v
        return out

    @classmethod
    def from_dict(cls, data: dict, *, source: str = "<dict>") -> Path:
        """Build from the TOML table structure in the module docstring (validated)."""
        if not isinstance(data, dict):
            raise PathError(f"{source}: expected a table, got {type(data).__name__}")
        unknown = sorted(set(data) - _ALLOWED)
        if unknown:
            raise PathError(f"{source}: unknown key(s) {unknown}; allowed: {sorted(_ALLOWED)}")
        missing = [k for k in _REQUIRED if k not in data]
        if missing:
            raise PathError(f"{source}: missing required key(s) {missing}")
        wps = data["waypoints"]
        if not isinstance(wps, list):
            raise PathError(f"{source}: waypoints must be a list of [x, y] or [x, y, z], got "
                            f"{wps!r}")
        for i, p in enumerate(wps):
            if (not isinstance(p, list) or len(p) not in (2, 3)
                    or not all(_is_number(v) for v in p)):
                raise PathError(f"{source}: waypoints[{i}] must be 2 or 3 numbers (metres), got "
                                f"{p!r}")
            if len(p) != len(wps[0]):
                raise PathError(
                    f"{source}: waypoints[{i}] has {len(p)} coordinates, waypoints[0] has "
                    f"{len(wps[0])}")
        if not isinstance(data["closed"], bool):
            raise PathError(f"{source}: closed must be true or false, got {data['closed']!r}")
        kw = {k: data[k] for k in data if k != "waypoints"}
        return cls(waypoints=np.array(wps, dtype=float).reshape(len(wps), -1) if wps
                   else np.zeros((0, 2)), source=source, **kw)


def available_paths() -> list[str]:
    """Names of the shipped paths in ``models/paths/``."""
    return sorted(p.stem for p in PATHS_DIR.glob("*.toml"))


def load_path(name_or_path: str | FsPath | Path) -> Path:
    """Load a path: a :class:`Path` (returned as is), a file path, or a name in models/paths/.

    A bare name (no suffix, no directory) resolves to ``models/paths/<name>.toml``. The file's
    ``name`` must equal its stem. Raises :class:`PathError` naming the file and field.
    """
    if isinstance(name_or_path, Path):
        return name_or_path
    data, p = read_model_toml(name_or_path, PATHS_DIR, "path", error=PathError)
    if "name" in data and data["name"] != p.stem:
        raise PathError(f"{p}: name {data['name']!r} must equal the file name's stem {p.stem!r}")
    return Path.from_dict(data, source=str(p))


# ---------------------------------------------------------------------- geometry helpers
def project_to_polyline(points: np.ndarray, vertices: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Nearest point on a polyline for each query point (vectorised over points x segments).

    Parameters
    ----------
    points : (n, d) metres. vertices : (k, d) metres, k >= 2, same d.

    Returns
    -------
    dist : (n,) distance to the polyline, metres.
    segment : (n,) int, index i of the nearest segment vertices[i] -> vertices[i+1]
        (ties go to the lower index).
    foot : (n, d) nearest point on the polyline.
    arclength : (n,) distance along the polyline from vertices[0] to ``foot``, metres.
    """
    P = np.asarray(points, dtype=float)
    V = np.asarray(vertices, dtype=float)
    if P.ndim != 2 or V.ndim != 2 or P.shape[1] != V.shape[1] or V.shape[0] < 2:
        raise ValueError(f"points/vertices: expected (n, d) and (k>=2, d), got {P.shape}, "
                         f"{V.shape}")
    A, B = V[:-1], V[1:]
    AB = B - A                                               # (s, d)
    L2 = (AB**2).sum(-1)                                     # (s,)
    AP = P[:, None, :] - A[None, :, :]                       # (n, s, d)
    u = np.clip((AP * AB).sum(-1) / np.where(L2 > 0, L2, 1.0), 0.0, 1.0)   # (n, s)
    F = A[None] + u[..., None] * AB[None]                    # (n, s, d)
    d2 = ((P[:, None, :] - F) ** 2).sum(-1)
    seg = np.argmin(d2, axis=1)
    rows = np.arange(P.shape[0])
    L = np.sqrt(L2)
    cum = np.concatenate([[0.0], np.cumsum(L)])
    return (np.sqrt(d2[rows, seg]), seg, F[rows, seg], cum[seg] + u[rows, seg] * L[seg])


@dataclass(frozen=True)
class PathErrors:
    """How well a trajectory follows a path (see :func:`path_errors`). Distances in metres.

    cut_in_m : (c,) per corner, the trajectory's closest approach to the corner point: how far
        the platform stays from the target point when it turns inside the target area.
    corner_max_m : (c,) per corner, the largest distance from the polyline within
        ``corner_zone_m`` (arclength) of the corner.
    straight_max_m, straight_rms_m, straight_mean_m : distance from the polyline over the
        samples on the straights (farther than ``corner_zone_m`` from every corner).
    n_straight : number of samples counted as on the straights.
    closure_m : distance from the last sample to the route's end point (the start when closed).
    corner_zone_m : the zone used.
    """

    cut_in_m: np.ndarray
    corner_max_m: np.ndarray
    straight_max_m: float
    straight_rms_m: float
    straight_mean_m: float
    n_straight: int
    closure_m: float
    corner_zone_m: float

    def as_dict(self) -> dict[str, Any]:
        """Plain dict (lists for arrays) for tables and JSON."""
        return {k: (v.tolist() if isinstance(v, np.ndarray) else v)
                for k, v in self.__dict__.items()}


def path_errors(xy: np.ndarray, path: Path, *, corner_zone_m: float | None = None) -> PathErrors:
    """Tracking errors of a trajectory against a path's polyline (horizontal plane).

    Parameters
    ----------
    xy : (n, 2) (or (n, 3); only x, y are used) trajectory of the point that follows the path
        (the rover's body origin), metres, in time order.
    path : the path followed.
    corner_zone_m : samples whose nearest polyline point lies within this arclength of a
        corner belong to that corner's zone, the others are "straights". Default
        ``3 * target_radius_m + lookahead`` where lookahead = ``lookahead_m`` or
        ``target_radius_m``: the controller leaves a segment ``target_radius_m`` before its
        corner and aims ``lookahead`` ahead, so the turn and its settling stay within about
        that distance of the corner.
    """
    xy = np.asarray(xy, dtype=float)
    if xy.ndim != 2 or xy.shape[1] not in (2, 3) or xy.shape[0] < 1:
        raise ValueError(f"xy: expected shape (n, 2) or (n, 3), got {xy.shape}")
    xy = xy[:, :2]
    if corner_zone_m is None:
        look = path.lookahead_m if path.lookahead_m is not None else path.target_radius_m
        corner_zone_m = 3.0 * path.target_radius_m + look
    if not (math.isfinite(corner_zone_m) and corner_zone_m >= 0):
        raise ValueError(f"corner_zone_m: must be a finite number >= 0, got {corner_zone_m!r}")
    V = path.polyline[:, :2]
    dist, _, _, s = project_to_polyline(xy, V)
    seglen = np.linalg.norm(np.diff(V, axis=0), axis=1)
    s_vert = np.concatenate([[0.0], np.cumsum(seglen)])
    ci = path.corner_indices
    s_corner = s_vert[ci]                                     # (c,)
    near = np.abs(s[:, None] - s_corner[None, :]) <= corner_zone_m   # (n, c)
    straight = ~near.any(axis=1)
    corners = V[ci]
    to_corner = np.linalg.norm(xy[:, None, :] - corners[None, :, :], axis=-1)   # (n, c)
    cut_in = to_corner.min(axis=0) if xy.shape[0] else np.full(len(ci), np.nan)
    corner_max = np.array([dist[near[:, j]].max() if near[:, j].any() else np.nan
                           for j in range(len(ci))])
    ds = dist[straight]
    return PathErrors(
        cut_in_m=cut_in, corner_max_m=corner_max,
        straight_max_m=float(ds.max()) if ds.size else float("nan"),
        straight_rms_m=float(np.sqrt(np.mean(ds**2))) if ds.size else float("nan"),
        straight_mean_m=float(ds.mean()) if ds.size else float("nan"),
        n_straight=int(ds.size),
        closure_m=float(np.linalg.norm(xy[-1] - V[-1])),
        corner_zone_m=float(corner_zone_m),
    )
