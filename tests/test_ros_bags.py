"""sim.ros_bags: ROS 1 / ROS 2 bags as recordings (issue 25), on bags the tests write.

The synthetic rig of tests/synth_recording.py (known antenna positions and pose, a 5 s gap
of antenna 2, a late start, an early end) is written as a bag with rosbags' own writers:
one sensor_msgs/NavSatFix topic per antenna (antenna 2's gap as STATUS_NO_FIX messages),
and the pose as nav_msgs/Odometry (ROS 1) or geometry_msgs/PoseStamped (ROS 2) in a local
ENU frame, of a base_link 0.5 m behind the CG. Read back through a recording TOML, the
observations are the written positions and the reference is the written CG and heading
(in the recording's UTM grid: the ENU heading differs by the meridian convergence).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import tomli_w
from pyproj import Transformer
from synth_recording import EPSG, ORIGIN_LATLON, T0_UTC, write_rig

from sim.recording import RecordingError, load_recording, recording_files

rosbags = pytest.importorskip("rosbags")

NAMES = ("1", "2", "3", "4")
#: base_link of the published pose: 0.5 m behind the layout's CG (offset_m = [0.5, 0]).
BASE_BEHIND_M = 0.5


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    return write_rig(tmp_path_factory.mktemp("bagrig"))


def _enu_pose(rig, frame: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The base_link's x, y (metres, ENU at ORIGIN_LATLON or UTM) and yaw in that frame."""
    to_ll = Transformer.from_crs(f"EPSG:{EPSG}", "EPSG:4326", always_xy=True)
    c, s = np.cos(rig.yaw), np.sin(rig.yaw)
    base = rig.cg - BASE_BEHIND_M * np.c_[c, s]            # UTM
    ahead = base + np.c_[c, s]
    if frame == "epsg":
        return base[:, 0], base[:, 1], rig.yaw
    la0, lo0 = ORIGIN_LATLON
    enu = Transformer.from_crs("EPSG:4326", f"+proj=aeqd +lat_0={la0} +lon_0={lo0} "
                               "+datum=WGS84 +units=m", always_xy=True)
    xb, yb = enu.transform(*to_ll.transform(base[:, 0], base[:, 1]))
    xa, ya = enu.transform(*to_ll.transform(ahead[:, 0], ahead[:, 1]))
    return np.asarray(xb), np.asarray(yb), np.arctan2(np.asarray(ya) - yb,
                                                      np.asarray(xa) - xb)


def _write_bag(rig, path: Path, version: int, pose_type: str, frame: str = "enu") -> None:
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC if version == 1 else Stores.ROS2_HUMBLE)
    T = ts.types
    to_ll = Transformer.from_crs(f"EPSG:{EPSG}", "EPSG:4326", always_xy=True)

    def header(t: float, frame_id: str):
        st = T["builtin_interfaces/msg/Time"](sec=int(t), nanosec=round((t % 1) * 1e9))
        kw = {"seq": 0} if version == 1 else {}
        return T["std_msgs/msg/Header"](stamp=st, frame_id=frame_id, **kw)

    def ser(msg, typ):
        return ts.serialize_ros1(msg, typ) if version == 1 else ts.serialize_cdr(msg, typ)

    if version == 1:
        from rosbags.rosbag1 import Writer
        writer = Writer(path)
    else:
        from rosbags.rosbag2 import Writer
        writer = Writer(path, version=9)
    fix_t = "sensor_msgs/msg/NavSatFix"
    with writer:
        for j, name in enumerate(NAMES):
            conn = writer.add_connection(f"/gps{name}/fix", fix_t, typestore=ts)
            for k, tu in enumerate(rig.t_utc):
                ok = np.isfinite(rig.observed[k, j, 0])
                if not ok and name != "2":
                    continue                      # a receiver that did not report
                lo, la = to_ll.transform(*(rig.observed[k, j] if ok else rig.antennas[k, j]))
                status = T["sensor_msgs/msg/NavSatStatus"](status=0 if ok else -1, service=1)
                msg = T[fix_t](header=header(tu, f"gps{name}"), status=status,
                               latitude=float(la) if ok else math.nan,
                               longitude=float(lo) if ok else math.nan, altitude=520.0,
                               position_covariance=np.zeros(9), position_covariance_type=0)
                writer.write(conn, round(tu * 1e9), ser(msg, fix_t))
        x, y, yaw = _enu_pose(rig, frame)
        conn = writer.add_connection("/odom", pose_type, typestore=ts)
        P = T["geometry_msgs/msg/Pose"]
        for k, tu in enumerate(rig.t_utc):
            pose = P(position=T["geometry_msgs/msg/Point"](x=float(x[k]), y=float(y[k]), z=0.0),
                     orientation=T["geometry_msgs/msg/Quaternion"](
                         x=0.0, y=0.0, z=math.sin(yaw[k] / 2), w=math.cos(yaw[k] / 2)))
            if pose_type == "nav_msgs/msg/Odometry":
                tw = T["geometry_msgs/msg/Twist"](linear=T["geometry_msgs/msg/Vector3"](
                    x=0.0, y=0.0, z=0.0), angular=T["geometry_msgs/msg/Vector3"](
                    x=0.0, y=0.0, z=0.0))
                msg = T[pose_type](
                    header=header(tu, "map"), child_frame_id="base_link",
                    pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose,
                                                                   covariance=np.zeros(36)),
                    twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=tw,
                                                                     covariance=np.zeros(36)))
            else:
                msg = T[pose_type](header=header(tu, "map"), pose=pose)
            writer.write(conn, round(tu * 1e9), ser(msg, pose_type))


def _toml(folder: Path, bag: str, frame: str = "enu") -> Path:
    ref = {"topic": "/odom", "frame": frame, "offset_m": [BASE_BEHIND_M, 0.0]}
    ref.update({"origin": list(ORIGIN_LATLON)} if frame == "enu" else {"epsg": EPSG})
    data = {"name": "bagrec", "config": "rover_gps4", "bag": {"path": bag},
            "antenna": [{"name": n, "topic": f"/gps{n}/fix"} for n in NAMES],
            "reference": ref}
    p = folder / f"bag_{frame}.toml"
    p.write_text(tomli_w.dumps(data))
    return p


def _check(rig, rec) -> None:
    fr = rec.meta["frame"]
    origin = np.array([fr["origin_easting_m"], fr["origin_northing_m"]])
    assert fr["epsg"] == EPSG and rec.meta["t0_utc"] == pytest.approx(T0_UTC, abs=1e-6)
    obs = rec.obs + origin
    assert np.array_equal(np.isnan(obs), np.isnan(rig.observed))
    # float64 degrees in the bag: the positions round-trip to well below a millimetre
    assert np.nanmax(np.abs(obs - rig.observed)) < 1e-6
    assert rec.reference.kind == "pose"
    truth = rec.truth()
    # CG of the pose (base_link + 0.5 m forward) and the heading in the UTM grid. The
    # reader applies the 0.5 m in true metres, this test wrote it in UTM grid metres, whose
    # scale here is 1 + 4e-5 (2.4 deg from the central meridian): 2e-5 m apart; 1e-4 m. The
    # heading from a 1 m baseline (conformal projections) to < 1e-6 rad
    assert np.abs(truth.cg[:, :2] + origin - rig.cg).max() < 1e-4
    assert np.abs(np.angle(np.exp(1j * (truth.yaw - rig.yaw)))).max() < 1e-6


@pytest.mark.parametrize("version, pose_type", [(1, "nav_msgs/msg/Odometry"),
                                                (2, "geometry_msgs/msg/PoseStamped")])
def test_bag_recording_reads_back_what_was_written(rig, tmp_path, version, pose_type):
    bag = "drive.bag" if version == 1 else "drive"
    _write_bag(rig, tmp_path / bag, version, pose_type)
    p = _toml(tmp_path, bag)
    rec = load_recording(p)
    _check(rig, rec)
    info = rec.meta["logs"]["2"]
    assert info["fixes"] == 85 and info["skipped"]["no_fix"] == 5     # the 5 s gap
    assert info["format"] == "ros_bag"
    files = recording_files(p)
    assert (tmp_path / bag) in files if version == 1 else \
        (tmp_path / bag / "metadata.yaml") in files
    # the ENU heading differs from the grid heading by the meridian convergence (zone 32:
    # 11.575 E is 2.4 deg east of its central meridian 9 E, at 48 N ~1.9 deg)
    _, _, yaw_enu = _enu_pose(rig, "enu")
    conv = np.degrees(np.angle(np.exp(1j * (yaw_enu - rig.yaw))))
    assert 1.5 < abs(np.median(conv)) < 2.5


def test_pose_in_a_projected_frame(rig, tmp_path):
    _write_bag(rig, tmp_path / "utm.bag", 1, "geometry_msgs/msg/PoseStamped", frame="epsg")
    _check(rig, load_recording(_toml(tmp_path, "utm.bag", frame="epsg")))


def test_bag_errors_name_the_bag_and_topic(rig, tmp_path):
    import tomllib

    _write_bag(rig, tmp_path / "d.bag", 1, "nav_msgs/msg/Odometry")
    p = _toml(tmp_path, "d.bag")
    data = tomllib.loads(p.read_text())
    data["antenna"][0]["topic"] = "/gps9/fix"
    p.write_text(tomli_w.dumps(data))
    with pytest.raises(RecordingError, match=r"d\.bag: topic '/gps9/fix': not in the bag; its "
                                             r"topics: \['/gps1/fix \(sensor_msgs/msg/NavSatF"):
        load_recording(p)
    data["antenna"][0]["topic"] = "/odom"
    p.write_text(tomli_w.dumps(data))
    with pytest.raises(RecordingError, match=r"topic '/odom': message type nav_msgs/msg/"
                                             r"Odometry, expected sensor_msgs/msg/NavSatFix"):
        load_recording(p)
    data["antenna"][0]["topic"] = "/gps1/fix"
    data["reference"]["frame"] = "map"
    p.write_text(tomli_w.dumps(data))
    with pytest.raises(RecordingError, match=r"reference\.frame: must be 'enu'"):
        load_recording(p)
    data["reference"] = {"topic": "/odom", "frame": "enu"}
    p.write_text(tomli_w.dumps(data))
    with pytest.raises(RecordingError, match=r"reference\.origin: required"):
        load_recording(p)
    data.pop("bag")
    data["reference"] = {"topic": "/odom", "frame": "epsg", "epsg": EPSG}
    p.write_text(tomli_w.dumps(data))
    with pytest.raises(RecordingError, match=r"antenna '1': topic needs the \[bag\] table"):
        load_recording(p)
    data["bag"] = {"path": "nothere.bag"}
    p.write_text(tomli_w.dumps(data))
    with pytest.raises(RecordingError, match=r"bag\.path: no such file 'nothere\.bag'"):
        load_recording(p)
    (tmp_path / "junk.bag").write_bytes(b"not a bag at all")
    data["bag"] = {"path": "junk.bag"}
    p.write_text(tomli_w.dumps(data))
    with pytest.raises(RecordingError, match=r"junk\.bag: cannot be read as a ROS 1 or ROS 2 "
                                             r"bag"):
        load_recording(p)
