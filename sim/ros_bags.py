"""ROS 1 / ROS 2 bags as recordings: NavSatFix per antenna, a pose or odometry reference.

Read with the pure-Python ``rosbags`` package (optional extra ``[ros]``; no ROS
installation): :class:`rosbags.highlevel.AnyReader` opens a ROS 1 ``.bag`` file or a ROS 2
bag folder (sqlite3 or mcap), message definitions from the bag (a ROS 2 bag without them
falls back to the Humble type store).

- Antennas: one ``sensor_msgs/NavSatFix`` topic per antenna (:func:`read_navsatfix`):
  time = ``header.stamp`` (UTC; the bag's receive time where the stamp is 0), latitude /
  longitude in degrees WGS 84, altitude (ellipsoidal, as NavSatFix defines it). A message
  with ``status.status < 0`` (STATUS_NO_FIX) or a non-finite latitude / longitude is a
  no-fix epoch (NaN), counted in ``skipped["no_fix"]``; a repeated or earlier stamp is
  dropped and counted (``duplicate_epochs``, ``time_reversals``), as the text reader does.
- Reference: a ``geometry_msgs/PoseStamped`` or ``nav_msgs/Odometry`` topic
  (:func:`read_pose_reference`): the pose's position and heading (yaw of its orientation
  quaternion, CCW from the frame's x axis) in a metric frame given by the recording:
  ``frame = "enu"`` with ``origin = [lat, lon]`` (x east, y north of a local tangent plane
  at the origin: the azimuthal equidistant projection, exact in distance and direction from
  the origin), or ``frame = "epsg"`` with ``epsg = <code>`` (a projected CRS, e.g. a UTM
  zone, as robot_localization's ``utm`` frame). ``offset_m`` = the layout's CG in the
  pose's body frame (x forward, y left; default the pose's own point). The track becomes
  two :class:`sim.nmea.LogFixes` (the CG, and a point 1 m ahead along the pose's x axis),
  which :class:`sim.recording.Recording` aligns on its UTC grid like any log, so the
  heading comes out in the recording's own UTM grid (the meridian convergence and the
  projection included).

Errors (:class:`sim.recording.RecordingError`) name the bag and the topic: no such topic
(listing the bag's topics), a topic of another message type, a topic without messages.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sim.nmea import LogFixes
from sim.recording_errors import RecordingError

__all__ = ["NAVSATFIX", "POSE_TYPES", "PoseFixes", "bag_files", "bag_topics",
           "read_navsatfix", "read_pose_reference"]

NAVSATFIX = "sensor_msgs/msg/NavSatFix"
POSE_TYPES = ("geometry_msgs/msg/PoseStamped", "nav_msgs/msg/Odometry")
#: Distance of the heading point ahead of the pose, m (any length works: the projection is
#: conformal; 1 m keeps it far above the float resolution of projected coordinates).
AHEAD_M = 1.0


@dataclass(frozen=True)
class PoseFixes:
    """A pose reference as two position logs on one clock: ``track`` (the CG) and
    ``ahead`` (a point :data:`AHEAD_M` ahead along the pose's x axis); ``meta`` source."""

    track: LogFixes
    ahead: LogFixes
    meta: dict


def _error(msg: str) -> Exception:
    return RecordingError(msg)


def _rosbags():
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ImportError as exc:
        raise ImportError("reading ROS bags needs the optional dependency rosbags: "
                          "pip install -e '.[ros]'") from exc
    return AnyReader, get_typestore(Stores.ROS2_HUMBLE)


def bag_files(path: str | Path) -> list[Path]:
    """The files of a bag: a ROS 1 ``.bag`` file itself, or every file of a ROS 2 bag
    folder (named by the folder or its ``metadata.yaml``)."""
    p = Path(path)
    folder = p.parent if p.name == "metadata.yaml" else p
    if folder.is_dir():
        return sorted(f for f in folder.iterdir() if f.is_file())
    return [p]


def _bag_path(path: str | Path) -> Path:
    p = Path(path)
    if p.name == "metadata.yaml":
        p = p.parent
    if not p.exists():
        raise _error(f"bag: no such file or folder {str(p)!r}")
    return p


def _messages(path: str | Path, topic: str, types: Sequence[str]):
    """(receive time ns, message) of ``topic`` in the bag, checked to be one of ``types``."""
    AnyReader, default = _rosbags()
    bag = _bag_path(path)
    try:
        reader = AnyReader([bag], default_typestore=default)
        reader.open()
    except Exception as exc:  # noqa: BLE001 - rosbags raises its own classes per format
        raise _error(f"bag {bag}: cannot be read as a ROS 1 or ROS 2 bag: "
                     f"{type(exc).__name__}: {exc}") from None
    try:
        conns = [c for c in reader.connections if c.topic == topic]
        if not conns:
            known = sorted({f"{c.topic} ({c.msgtype})" for c in reader.connections})
            raise _error(f"bag {bag}: topic {topic!r}: not in the bag; its topics: {known}")
        bad = sorted({c.msgtype for c in conns} - set(types))
        if bad:
            raise _error(f"bag {bag}: topic {topic!r}: message type {bad[0]}, expected "
                         f"{' or '.join(types)}")
        out = [(ts, reader.deserialize(raw, c.msgtype))
               for c, ts, raw in reader.messages(connections=conns)]
    finally:
        reader.close()
    if not out:
        raise _error(f"bag {bag}: topic {topic!r}: no messages")
    return out


def bag_topics(path: str | Path) -> dict[str, str]:
    """Topic -> message type of every connection in the bag."""
    AnyReader, default = _rosbags()
    with AnyReader([_bag_path(path)], default_typestore=default) as reader:
        return {c.topic: c.msgtype for c in reader.connections}


def _stamp(msg, ts_ns: int) -> float:
    """UTC seconds of a message: its header stamp, else (stamp 0) the bag's receive time."""
    st = msg.header.stamp
    v = st.sec + st.nanosec * 1e-9
    return float(v) if v > 0 else ts_ns * 1e-9


def _ordered(t: np.ndarray) -> tuple[np.ndarray, dict]:
    """Rows to keep of times in bag order (first of a repeated time; no step backwards)."""
    keep = np.ones(t.size, dtype=bool)
    skipped = {"duplicate_epochs": 0, "time_reversals": 0}
    last = -math.inf
    for i, v in enumerate(t):
        if v < last:
            keep[i] = False
            skipped["time_reversals"] += 1
        elif v == last:
            keep[i] = False
            skipped["duplicate_epochs"] += 1
        else:
            last = v
    return keep, skipped


def read_navsatfix(path: str | Path, topic: str, name: str | None = None) -> LogFixes:
    """One antenna's fixes from a ``sensor_msgs/NavSatFix`` topic (module docstring)."""
    msgs = _messages(path, topic, (NAVSATFIX,))
    t = np.array([_stamp(m, ts) for ts, m in msgs])
    lat = np.array([float(m.latitude) for _, m in msgs])
    lon = np.array([float(m.longitude) for _, m in msgs])
    alt = np.array([float(m.altitude) for _, m in msgs])
    status = np.array([int(m.status.status) for _, m in msgs])
    with np.errstate(invalid="ignore"):
        fix = (status >= 0) & np.isfinite(lat) & np.isfinite(lon) & (np.abs(lat) <= 90) \
            & (np.abs(lon) <= 180)
    keep, skipped = _ordered(t)
    skipped["no_fix"] = int((~fix & keep).sum())
    lat, lon = np.where(fix, lat, np.nan), np.where(fix, lon, np.nan)
    return LogFixes(name=name or topic, t_utc=t[keep], lat=lat[keep], lon=lon[keep],
                    quality=np.where(fix, 1, 0)[keep].astype(np.int64), date_known=True,
                    skipped=skipped, height_m=np.where(fix, alt, np.nan)[keep],
                    meta={"path": str(path), "format": "ros_bag", "topic": topic,
                          "messages": len(msgs)})


def _yaw(q) -> float:
    """Yaw (rad) of an orientation quaternion (ZYX convention, as tf2's getYaw)."""
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def _to_latlon(frame: str, origin: Sequence[float] | None, epsg: int | None):
    """Callable (x (k,), y (k,)) metres -> (lat (k,), lon (k,)) degrees for the frame."""
    from pyproj import Transformer

    if frame == "enu":
        la0, lo0 = float(origin[0]), float(origin[1])
        crs = f"+proj=aeqd +lat_0={la0!r} +lon_0={lo0!r} +datum=WGS84 +units=m"
    else:
        crs = f"EPSG:{int(epsg)}"
    tr = Transformer.from_crs(crs, "EPSG:4326", always_xy=True)

    def f(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        lo, la = tr.transform(np.asarray(x, float), np.asarray(y, float))
        return np.asarray(la), np.asarray(lo)

    return f


def read_pose_reference(path: str | Path, topic: str, *, frame: str,
                        origin: Sequence[float] | None = None, epsg: int | None = None,
                        offset_m: Sequence[float] = (0.0, 0.0)) -> PoseFixes:
    """The reference track of a PoseStamped / Odometry topic (module docstring): frame
    "enu" (``origin`` = (lat, lon) degrees) or "epsg" (``epsg`` a projected CRS code);
    ``offset_m`` the layout's CG in the pose's body frame, m."""
    if frame not in ("enu", "epsg"):
        raise _error(f"reference.frame: must be 'enu' or 'epsg', got {frame!r}")
    if frame == "enu" and origin is None:
        raise _error("reference.origin: required with frame = 'enu' ([latitude, longitude])")
    if frame == "epsg" and epsg is None:
        raise _error("reference.epsg: required with frame = 'epsg' (a projected CRS code)")
    msgs = _messages(path, topic, POSE_TYPES)
    t = np.array([_stamp(m, ts) for ts, m in msgs])
    poses = [m.pose.pose if hasattr(m, "child_frame_id") else m.pose for _, m in msgs]
    x = np.array([p.position.x for p in poses], dtype=float)
    y = np.array([p.position.y for p in poses], dtype=float)
    yaw = np.array([_yaw(p.orientation) for p in poses])
    c, s = np.cos(yaw), np.sin(yaw)
    ox, oy = float(offset_m[0]), float(offset_m[1])
    cx, cy = x + c * ox - s * oy, y + s * ox + c * oy
    keep, skipped = _ordered(t)
    try:
        f = _to_latlon(frame, origin, epsg)
    except Exception as exc:  # noqa: BLE001 - pyproj's CRSError for a bad code
        raise _error(f"reference.{'origin' if frame == 'enu' else 'epsg'}: not usable: "
                     f"{exc}") from None
    la, lo = f(cx[keep], cy[keep])
    la2, lo2 = f(cx[keep] + AHEAD_M * c[keep], cy[keep] + AHEAD_M * s[keep])
    meta = {"path": str(path), "format": "ros_bag", "topic": topic, "frame": frame,
            "origin": None if origin is None else [float(v) for v in origin],
            "epsg": epsg, "offset_m": [ox, oy], "messages": len(msgs)}
    q = np.ones(int(keep.sum()), dtype=np.int64)

    def log(name: str, la_: np.ndarray, lo_: np.ndarray) -> LogFixes:
        return LogFixes(name=name, t_utc=t[keep], lat=la_, lon=lo_, quality=q,
                        date_known=True, skipped=dict(skipped), meta=dict(meta))

    return PoseFixes(track=log("cg", la, lo), ahead=log("ahead", la2, lo2), meta=meta)

