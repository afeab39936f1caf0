"""The simulated issue-25 car (:mod:`sim.vehicle_case`) written as a shipped recording.

One drive of :func:`sim.vehicle_case.simulate_vehicle_case` (1 Hz, 1514 s, four antennas on
the 0.8 m ``car_rtk4`` frame slanted 3.4 deg off the direction of travel, per-antenna
dropouts, one antenna missing for 333 s, a 34 s outage, a 150 s stop) becomes three
recordings that share one reference:

- ``car_case_rtk``: the four antennas' RTK fixes (``vehicle_observations(case, "rtk")``,
  models/noise/gps_rtk_network.toml) as one whitespace text log per antenna (unix s, lat, lon,
  height), only where the case's antenna reports;
- ``car_case_replay`` and ``car_case_replay_cpm``: ``[replay]`` recordings: the reference
  plus one receiver of a synthesized ``gps_stationary`` session
  (``car_case/consumer_session.npz``) replayed per seed, mode ``shifted`` and
  ``common_plus_model`` (+ gps_stationary's per-receiver part) respectively.

The reference is the exact antenna positions per antenna (RTK CSV logs) at the epochs where
the case's antenna reports, so the reference pose (the rigid fit of the layout) exists on
the epochs with two or more antennas and nowhere else: the sweep scores those epochs, the
measure of the README's car table, and the replayed observations inherit the case's
dropouts (an antenna without a reference position has no observation). The layout is the
shipped ``car_rtk4`` (same antennas as the case's) and the recordings carry no
``[platform]`` block, so ``car_rtk4``'s road-car limits apply.

``python tests/synth_vehicle_recording.py [DIR]`` writes ``DIR/car_case/`` and the three TOMLs
into DIR (default models/recordings); the shipped files are its output with the defaults
and ``tests/test_vehicle_case.py`` checks that they still are.
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pyproj import Transformer
from synth_recording import EPSG, HEIGHT_M, ORIGIN_LATLON, T0_UTC

from sim.gps import GpsNoiseModel, StationarySession, synthesize_session
from sim.vehicle_case import VehicleCase, simulate_vehicle_case, vehicle_observations

#: Seeds of the drive and of the RTK errors / the consumer session (fixed: one recording).
DRIVE_SEED, NOISE_SEED = 25, 1025
NAMES = ("1", "2", "3", "4")


@dataclass
class CarRecording:
    """What was written: the case, its RTK fixes (n, 4, 2) m in the case's frame (NaN where
    absent), the consumer session, the UTM offset of the case's origin, and the files."""

    case: VehicleCase
    rtk: np.ndarray
    session: StationarySession
    origin_utm: np.ndarray
    files: dict


def _rows_latlon(to_ll: Transformer, xy: np.ndarray, tu: np.ndarray, keep: np.ndarray,
                 sep: str, height: bool) -> list[str]:
    """One text row per kept epoch: unix time, lat, lon (1e-9 deg = 0.1 mm), [height]."""
    lo, la = to_ll.transform(xy[keep, 0], xy[keep, 1])
    tail = f"{sep}{HEIGHT_M:.1f}" if height else ""
    return [f"{t:.1f}{sep}{a:.9f}{sep}{b:.9f}{tail}"
            for t, a, b in zip(tu[keep], np.asarray(la), np.asarray(lo), strict=True)]


def _consumer_session(case: VehicleCase, rng: np.random.Generator) -> StationarySession:
    """Receiver "1" of a gps_stationary session of 4 n s + 400 s (as vehicle_observations
    draws it), after its power failure: enough for the shifted replay of four antennas."""
    s = synthesize_session(GpsNoiseModel.load("gps_stationary"), case.config,
                           4.0 * case.truth.n + 400.0, rng, rate_hz=1.0).after_power_failure()
    return StationarySession(t=s.t - s.t[0], obs=s.obs[:, :1].copy(), names=("1",),
                             truth_positions=None if s.truth_positions is None
                             else s.truth_positions[:1].copy(),
                             meta={"source": "synthetic", "model": "gps_stationary",
                                   "alignment": "synthetic", "power_failure_s": None,
                                   "written_by": "tests/synth_vehicle_recording.py"})


def _toml(name: str, description: str, body: list[str], rel: Path) -> str:
    lines = [f'name = "{name}"', f'description = "{description}"', 'config = "car_rtk4"', "",
             *body]
    for nm in NAMES:
        lines += ["[[reference.antenna]]", f'name = "{nm}"',
                  f'log = "{(rel / f"ref{nm}.csv").as_posix()}"', ""]
    return "\n".join(lines)


def write_car_recordings(out_dir: str | Path = "models/recordings") -> CarRecording:
    """Write ``out_dir/car_case/`` (logs, reference, session) and, in ``out_dir``,
    ``car_case_rtk.toml``, ``car_case_replay.toml``, ``car_case_replay_cpm.toml``; returns
    what was written (module docstring)."""
    out = Path(out_dir)
    folder = out / "car_case"
    folder.mkdir(parents=True, exist_ok=True)
    rel = Path(os.path.relpath(folder.resolve(), out.resolve()))
    case = simulate_vehicle_case(np.random.default_rng(DRIVE_SEED))
    rng = np.random.default_rng(NOISE_SEED)
    rtk = vehicle_observations(case, "rtk", rng)
    session = _consumer_session(case, rng)
    to_utm = Transformer.from_crs("EPSG:4326", f"EPSG:{EPSG}", always_xy=True)
    to_ll = Transformer.from_crs(f"EPSG:{EPSG}", "EPSG:4326", always_xy=True)
    origin = np.array(to_utm.transform(ORIGIN_LATLON[1], ORIGIN_LATLON[0]))
    tu = T0_UTC + case.truth.t
    truth_xy = case.truth.sensor_positions[..., :2] + origin
    files = {}
    for j, nm in enumerate(NAMES):
        keep = case.present[:, j]
        rows = _rows_latlon(to_ll, rtk[:, j] + origin, tu, keep, " ", True)
        (folder / f"ant{nm}.txt").write_text("\n".join(rows) + "\n")
        rows = ["time,lat,lon", *_rows_latlon(to_ll, truth_xy[:, j], tu, keep, ",", False)]
        (folder / f"ref{nm}.csv").write_text("\n".join(rows) + "\n")
        files[f"ant{nm}"], files[f"ref{nm}"] = folder / f"ant{nm}.txt", folder / f"ref{nm}.csv"
    files["session"] = session.save(folder / "consumer_session.npz")
    what = ("Simulated issue-25 car (sim.vehicle_case, drive seed 25): 1 Hz, 1514 s, four "
            "antennas on the car_rtk4 0.8 m frame slanted 3.4 deg, per-antenna dropouts, a "
            "333 s missing antenna, a 34 s outage, a 150 s stop; reference = exact antenna "
            "positions where the antenna reports. Written by tests/synth_vehicle_recording.py.")
    body = []
    for nm in NAMES:
        body += ["[[antenna]]", f'name = "{nm}"', f'log = "{(rel / f"ant{nm}.txt").as_posix()}"',
                 'format = "text"', ""]
    files["toml_rtk"] = out / "car_case_rtk.toml"
    files["toml_rtk"].write_text(_toml(
        "car_case_rtk", what + " Observations: gps_rtk_network fixes.", body, rel))
    for name, mode, extra in (("car_case_replay", "shifted", []),
                              ("car_case_replay_cpm", "common_plus_model",
                               ['model = "gps_stationary"'])):
        body = ["[replay]", f'session = "{(rel / "consumer_session.npz").as_posix()}"',
                f'mode = "{mode}"', 'receiver = "1"', *extra, ""]
        files[f"toml_{name}"] = out / f"{name}.toml"
        files[f"toml_{name}"].write_text(_toml(
            name, what + f" Observations: a gps_stationary consumer receiver replayed per "
            f"seed, mode {mode}.", body, rel))
    return CarRecording(case=case, rtk=rtk, session=session, origin_utm=origin, files=files)


if __name__ == "__main__":
    rec = write_car_recordings(sys.argv[1] if len(sys.argv) > 1 else "models/recordings")
    print(f"wrote {len(rec.files)} files: {sorted(str(p) for p in rec.files.values())}")
