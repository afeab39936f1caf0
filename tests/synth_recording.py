"""A synthetic multi-antenna recording with a reference, written as real log files.

A platform with the rover_gps4 layout (four antennas, 1.5 m x 1.0 m) drives a known path
at 1 m/s: 30 s east, a 90-degree left turn over 10 s, then north. Every antenna position is
known in closed form. The observed antennas get independent Gaussian errors and write one
log each in a different format (NMEA GGA+RMC, tumbleweed CSV, CSV with ISO times and a
header, whitespace text without header), with gaps, a late start and an early end; an RTK
reference log per antenna holds the exact positions. The files read back through
:mod:`sim.recording` must give the written positions, so the loader, the alignment, the
reference pose and the scoring are all checked against a known truth.

``python tests/synth_recording.py DIR [TOML]`` writes the files to DIR (and the recording
file to TOML, default DIR/rig.toml). ``models/recordings/synthetic_rig.toml`` with its logs
in ``models/recordings/synthetic_rig/`` (the example of the README and of
``experiments/presets/example_recording.toml``) is this function's output with the
defaults (``python tests/synth_recording.py models/recordings/synthetic_rig
models/recordings/synthetic_rig.toml``), and ``tests/test_recording.py`` checks that it
still is.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
from pyproj import Transformer

T0_UTC = datetime(2024, 3, 1, 12, 0, 0, tzinfo=UTC).timestamp()
ORIGIN_LATLON = (48.137, 11.575)     # UTM zone 32 N
EPSG = 32632
LAYOUT = {"1": (0.75, 0.5), "2": (0.75, -0.5), "3": (-0.75, 0.5), "4": (-0.75, -0.5)}
HEIGHT_M = 520.0


@dataclass
class Rig:
    """What was written: times (n,) UTC s, CG (n, 2) and antenna positions (n, 4, 2) in
    UTM metres (EPSG 32632), yaw (n,) rad, observed positions with NaN where not logged,
    and the files."""

    t_utc: np.ndarray
    cg: np.ndarray
    yaw: np.ndarray
    antennas: np.ndarray
    observed: np.ndarray
    files: dict


def trajectory(t: np.ndarray, speed: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """CG (n, 2) metres relative to the start and yaw (n,) rad: east for 30 s, a left turn
    of pi/2 over 10 s at constant rate (an arc of radius 20/pi m), then north."""
    w = (math.pi / 2) / 10.0
    r = speed / w
    x = np.empty_like(t)
    y = np.empty_like(t)
    yaw = np.empty_like(t)
    a = t < 30
    x[a], y[a], yaw[a] = speed * t[a], 0.0, 0.0
    b = (t >= 30) & (t < 40)
    psi = w * (t[b] - 30)
    x[b], y[b], yaw[b] = 30 * speed + r * np.sin(psi), r * (1 - np.cos(psi)), psi
    c = t >= 40
    x[c], y[c], yaw[c] = 30 * speed + r, r + speed * (t[c] - 40), math.pi / 2
    return np.stack([x, y], axis=1), yaw


def _nmea(body: str) -> str:
    cs = 0
    for ch in body:
        cs ^= ord(ch)
    return f"${body}*{cs:02X}"


def _ddmm(v: float, lat: bool) -> tuple[str, str]:
    hemi = ("N" if v >= 0 else "S") if lat else ("E" if v >= 0 else "W")
    v = abs(v)
    deg = int(v)
    minutes = (v - deg) * 60.0
    return (f"{deg:02d}{minutes:010.7f}" if lat else f"{deg:03d}{minutes:010.7f}"), hemi


def write_rig(folder: str | Path, *, seed: int = 0, noise_m: float = 0.1, n: int = 90,
              toml: str | Path | None = None) -> Rig:
    """Write the logs and the reference to ``folder`` and the recording TOML to ``toml``
    (default ``folder/rig.toml``; log paths in it are relative to its folder); returns what
    was written."""
    folder = Path(folder)
    toml_path = Path(toml) if toml is not None else folder / "rig.toml"
    rel = Path(__import__("os").path.relpath(folder.resolve(), toml_path.resolve().parent))
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    to_utm = Transformer.from_crs("EPSG:4326", f"EPSG:{EPSG}", always_xy=True)
    to_ll = Transformer.from_crs(f"EPSG:{EPSG}", "EPSG:4326", always_xy=True)
    e0, n0 = to_utm.transform(ORIGIN_LATLON[1], ORIGIN_LATLON[0])
    t = np.arange(n, dtype=float)
    cg, yaw = trajectory(t)
    cg = cg + np.array([e0, n0])
    B = np.array(list(LAYOUT.values()))
    c, s = np.cos(yaw), np.sin(yaw)
    R = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)        # (n, 2, 2)
    ant = cg[:, None, :] + np.einsum("nab,mb->nma", R, B)                   # (n, 4, 2)
    obs = ant + rng.normal(0.0, noise_m, ant.shape)
    logged = np.ones((n, 4), dtype=bool)
    logged[50:55, 1] = False        # antenna 2: a 5 s gap
    logged[:3, 2] = False           # antenna 3: starts late
    logged[n - 3:, 3] = False       # antenna 4: ends early
    observed = np.where(logged[..., None], obs, np.nan)
    tu = T0_UTC + t
    files = {}

    def latlon(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        lo, la = to_ll.transform(xy[:, 0], xy[:, 1])
        return np.asarray(la), np.asarray(lo)

    # antenna 1: NMEA GGA + RMC, plus a comment, a bad checksum and a truncated line
    la, lo = latlon(obs[:, 0])
    lines = ["# synthetic NMEA log, antenna 1"]
    for k in np.flatnonzero(logged[:, 0]):
        d = datetime.fromtimestamp(tu[k], UTC)
        hms = d.strftime("%H%M%S") + ".00"
        lat_s, ns = _ddmm(la[k], True)
        lon_s, ew = _ddmm(lo[k], False)
        lines.append(_nmea(f"GPGGA,{hms},{lat_s},{ns},{lon_s},{ew},1,12,0.8,{HEIGHT_M:.3f},M,"
                           f"0.000,M,,"))
        lines.append(_nmea(f"GPRMC,{hms},A,{lat_s},{ns},{lon_s},{ew},1.94,0.0,"
                           f"{d.strftime('%d%m%y')},,,A"))
    lines.insert(5, "$GPGGA,120001.00,4808.2200000,N,01134.5000000,E,1,12,0.8,1.0,M,0,M,,*00")
    lines.insert(9, "$GPRMC,120002.00,A,4808.22")
    (folder / "ant1.nmea").write_text("\r\n".join(lines) + "\r\n")
    files["1"] = "ant1.nmea"
    # antenna 2: tumbleweed CSV (TIME whole seconds, CLOCK 50 ms later)
    la, lo = latlon(obs[:, 1])
    rows = [("HOSTNAME, OBSERVATION, CLOCK, TIME, LATITUDE, LONGITUDE, HORIZONTAL, MSL, "
             "WGS84, VERTICAL, SPEED, COURSE")]
    for i, k in enumerate(np.flatnonzero(logged[:, 1])):
        rows.append(f'"synth", {i + 1}, {tu[k] + 0.05:.9f}, {tu[k]:.9f}, {la[k]:.9f}, '
                    f"{lo[k]:.9f}, 0.1000, {HEIGHT_M:.4f}, {HEIGHT_M:.4f}, 0.1500, 1.000000, "
                    f"0.000000000")
    (folder / "ant2.csv").write_text("\n".join(rows) + "\n")
    files["2"] = "ant2.csv"
    # antenna 3: CSV with a header and ISO 8601 times
    la, lo = latlon(obs[:, 2])
    rows = ["time,latitude,longitude,height"]
    for k in np.flatnonzero(logged[:, 2]):
        iso = datetime.fromtimestamp(tu[k], UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")
        rows.append(f"{iso},{la[k]:.10f},{lo[k]:.10f},{HEIGHT_M:.3f}")
    (folder / "ant3.csv").write_text("\n".join(rows) + "\n")
    files["3"] = "ant3.csv"
    # antenna 4: whitespace text, no header, unix seconds
    la, lo = latlon(obs[:, 3])
    rows = [f"{tu[k]:.3f} {la[k]:.10f} {lo[k]:.10f} {HEIGHT_M:.3f}"
            for k in np.flatnonzero(logged[:, 3])]
    (folder / "ant4.txt").write_text("\n".join(rows) + "\n")
    files["4"] = "ant4.txt"
    # reference: exact positions per antenna (RTK), text with header
    for j, name in enumerate(LAYOUT):
        la, lo = latlon(ant[:, j])
        rows = ["time,lat,lon"] + [f"{tu[k]:.3f},{la[k]:.10f},{lo[k]:.10f}" for k in range(n)]
        (folder / f"rtk{name}.csv").write_text("\n".join(rows) + "\n")
        files[f"rtk{name}"] = f"rtk{name}.csv"
    description = ("Synthetic 4-antenna rig (rover_gps4) driving 30 s east, a 10 s left "
                   "turn, then north at 1 m/s; 0.1 m errors per axis; one log per antenna in "
                   "four formats, RTK reference per antenna. Written by "
                   "tests/synth_recording.py.")
    lines_t = ['name = "synthetic_rig"', f'description = "{description}"',
               'config = "rover_gps4"', ""]
    for name in LAYOUT:
        lines_t += ["[[antenna]]", f'name = "{name}"', f'log = "{(rel / files[name]).as_posix()}"',
                    ""]
    for name in LAYOUT:
        lines_t += ["[[reference.antenna]]", f'name = "{name}"',
                    f'log = "{(rel / files["rtk" + name]).as_posix()}"', ""]
    toml_path.write_text("\n".join(lines_t))
    out = {k: folder / v for k, v in files.items()}
    out["toml"] = toml_path
    return Rig(t_utc=tu, cg=cg, yaw=yaw, antennas=ant, observed=observed, files=out)


if __name__ == "__main__":
    out = Path(sys.argv[1]) if len(sys.argv) > 1 else Path("synthetic_rig")
    rig = write_rig(out, toml=sys.argv[2] if len(sys.argv) > 2 else None)
    print(f"wrote {len(rig.files)} files: {sorted(str(p) for p in rig.files.values())}")
