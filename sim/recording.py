"""Real multi-antenna recordings: one GNSS log per antenna, aligned on UTC, as arrays.

A :class:`Recording` is what a platform carrying several receivers gives (the GPS
dissertation's experiment, 000_8f82f8df647bf685.txt, Section 4.1, with real receivers):

- ``t`` (n,) seconds since ``meta["t0_utc"]`` (UTC seconds since 1970), on an even grid;
- ``obs`` (n, m, 2) metres: per-antenna positions, NaN where an antenna has no fix at a
  grid time, in the local metric frame below;
- ``config``: the :class:`~estimator.configuration.SensorConfig` (antenna names = the
  logs' names);
- ``reference`` (optional, :class:`Reference`): per-antenna reference positions (RTK
  receivers, or surveyed positions of a stationary platform) from which the pose (CG and
  heading) follows by a rigid fit of the layout, or a CG track (one RTK receiver at the
  CG: position is scored, heading is not);
- ``height_m`` (n, m) ellipsoidal heights where the logs give them (not used by the planar
  estimators), and ``meta`` (files, per-log counts, frame, grid; plain Python values, so
  ``json.dumps(rec.meta)`` works).

Frame: latitude/longitude (WGS 84) projected with pyproj to the UTM zone of the mean fix
(:func:`sim.nmea.utm_epsg`; the longitudes' circular mean, :func:`sim.nmea.mean_longitude`,
so a recording astride the antimeridian gets the zone of 180 degrees); x = easting - origin,
y = northing - origin, metres (grid north: it differs from true north by the meridian
convergence, < 3 degrees within a zone at mid latitudes, the same for the observations and the
reference). The origin is the mean of the antenna fixes (of the reference when there are no
antenna logs), recorded in ``meta["frame"]`` with the EPSG code.

Alignment on UTC (nothing lost, nothing invented): the grid interval is ``1 / rate_hz``
(default: the median interval between consecutive valid fixes of the antenna logs), its
phase the circular mean of the fix times modulo the interval, and it spans the first to the
last antenna fix. Each valid fix is placed at the nearest grid time when within
``max_offset_s`` (default a quarter interval); per log ``meta["logs"][name]["counts"]`` says
what happened to every valid fix: ``aligned`` + ``off_grid`` (further than max_offset_s from
any grid time) + ``outside_grid`` (before the first or after the last antenna fix: reference
logs) + ``duplicate_on_grid`` (a second fix for one grid time; the nearer one is kept) +
``reacquired`` (a reacquisition transient flagged by the reader, :mod:`sim.nmea`, left out
as stationary sessions leave it out) = the log's valid fixes; the reader's own skip counts
are beside them. Grid times without a fix
are NaN. ``interpolate=True`` (an explicit option) then fills each grid time that has no fix
within ``max_offset_s`` but lies between two consecutive fixes at most 1.5 intervals apart,
by linear interpolation of the projected positions (counted as ``interpolated`` grid
times); it never bridges a gap. For receivers whose fixes are not on a common phase, pass
``max_offset_s=0`` with it. A grid longer than
:data:`MAX_GRID_DAYS` is an error naming the logs' spans (a bogus date in one log), as is a
set of antenna logs that never overlap in time, or dated and undated logs mixed; so is a grid
whose observation array would exceed :data:`MAX_GRID_BYTES` (memory stays bounded).

Logs: NMEA 0183, tumbleweed CSV (:mod:`sim.nmea`) or a plain text / CSV of time, latitude,
longitude and optionally height (:func:`read_text_log`); :func:`read_antenna_log` tells
them apart. A recording file (TOML, ``models/recordings/``) names the logs, the
configuration, the reference and optionally a replay: see :func:`load_recording`.

The recording as truth: with ``[replay]`` the observations are the reference antenna
positions (cm-level RTK, or surveyed) plus a consumer receiver's real error replayed on top
(:func:`sim.gps.observe`; the one-receiver modes of :data:`sim.gps.REPLAY_MODES`), drawn
per seed by :meth:`Recording.observations`, and scored against the reference.
"""

from __future__ import annotations

import hashlib
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from estimator._checks import check_real
from estimator.configuration import SensorConfig, platform_from_table
from estimator.model_files import MODELS_DIR, parse_toml, resolve_model_file
from estimator.platform import PlatformLimits
from sim.gps import REPLAY_MODES, SESSION_REPLAY_KEYS, StationarySession, observe
from sim.nmea import (
    MAX_RATE_HZ,
    LogFixes,
    mean_longitude,
    plausible_fix,
    read_nmea,
    read_tumbleweed_csv,
    utm_epsg,
)
from sim.recording_errors import RecordingError
from sim.truth import Truth

__all__ = [
    "FORMATS",
    "MAX_GRID_BYTES",
    "MAX_GRID_DAYS",
    "RECORDINGS_DIR",
    "Recording",
    "RecordingError",
    "Reference",
    "load_recording",
    "read_antenna_log",
    "read_text_log",
    "recording_digest",
    "recording_files",
    "recording_summary",
]

RECORDINGS_DIR = MODELS_DIR / "recordings"
REPO = MODELS_DIR.parent

#: Log formats of a recording: :func:`read_antenna_log`'s, and "csv" (column-mapped by the
#: recording's ``[csv]`` table, :mod:`sim.csv_logs`).
FORMATS = ("auto", "nmea", "tumbleweed", "text", "csv")

#: Longest grid accepted, days: longer means a bogus date in some log (issue 11: a 1980
#: default date before the first fix laid a 40-year grid).
MAX_GRID_DAYS = 7.0
#: Largest observation array accepted, bytes ((n, m, 2) float64): 1 GiB, e.g. 7 days at
#: 10 Hz for 8 antennas is 0.77 GiB; a higher rate or a longer span is an error naming both
#: instead of an allocation attempt.
MAX_GRID_BYTES = 2**30

#: Earliest plausible fix time: the GPS epoch, 1980-01-06 UTC, in seconds since 1970.
GPS_EPOCH_UTC = 315964800.0

#: Turn flags of a reference (the "controller" flag of a recording): the heading-rate
#: detector of :mod:`estimator.turns` with the thresholds of
#: ``estimator.tracking.DETECTOR_DEFAULTS`` (0.05 / 0.025 rad/s over 8 s).
REFERENCE_TURN_RATE_ON, REFERENCE_TURN_RATE_OFF, REFERENCE_TURN_SPAN_S = 0.05, 0.025, 8.0


# --------------------------------------------------------------------------- readers
_TIME_COLS = ("time", "t", "utc", "timestamp", "time_utc", "unix_time", "time_s", "epoch")
_LAT_COLS = ("lat", "latitude", "lat_deg", "latitude_deg")
_LON_COLS = ("lon", "lng", "long", "longitude", "lon_deg", "longitude_deg")
_H_COLS = ("height", "h", "height_m", "alt", "altitude", "altitude_m", "ellipsoidal_height",
           "hae", "ellipsoid_height_m")
_TEXT_SKIPS = ("comment_lines", "bad_fields", "implausible_time", "duplicate_epochs",
               "time_reversals")


def _parse_time(s: str) -> float:
    """UTC seconds since 1970 from a number or an ISO 8601 string (naive = UTC)."""
    try:
        v = float(s)
    except ValueError:
        txt = s.strip()
        if txt.endswith(("Z", "z")):
            txt = txt[:-1] + "+00:00"
        dt = datetime.fromisoformat(txt)
        if dt.tzinfo is None:
            dt = dt.replace(tzinfo=UTC)
        return dt.timestamp()
    if not math.isfinite(v):
        raise ValueError(f"time {s!r} is not finite")
    return v


def _split(line: str, delim: str | None) -> list[str]:
    return [f.strip() for f in (line.split(delim) if delim else line.split())]


def read_text_log(path: str | Path, name: str | None = None) -> LogFixes:
    """Read a plain text / CSV log of one antenna: time, latitude, longitude[, height].

    Columns are separated by commas, semicolons, tabs or whitespace (taken from the first
    data line). With a header line, columns are found by name (case-insensitive: time /
    t / utc / timestamp / unix_time ..., lat / latitude, lon / lng / longitude, height /
    h / alt / altitude / hae ...; other columns are ignored and listed in
    ``meta["ignored_columns"]``); without one, the order is time, latitude, longitude
    [, height]. Time: UTC seconds since 1970-01-01 or ISO 8601 (``2020-05-26T16:00:46.5Z``;
    without a zone it is UTC). Latitude/longitude: decimal degrees WGS 84; height: metres
    (ellipsoidal, as the file gives it). Lines starting with ``#`` are comments.

    Nothing is dropped silently; ``skipped`` counts ``comment_lines``, ``bad_fields`` (a
    number or time that does not parse, a coordinate out of range or 0, 0, a wrong column
    count; the first line numbers are in ``meta["bad_lines"]``), ``implausible_time``
    (before the GPS epoch 1980-01-06 or more than a day after the file was read),
    ``duplicate_epochs`` (a repeated time, first kept) and ``time_reversals`` (a time
    earlier than the one before, dropped). A file without one valid row raises
    :class:`RecordingError` naming it.
    """
    path = Path(path)
    if not path.is_file():
        raise RecordingError(f"log: no such file {str(path)!r}")
    skipped = dict.fromkeys(_TEXT_SKIPS, 0)
    bad_lines: list[int] = []
    rows: list[tuple[float, float, float, float]] = []
    cols: dict[str, int] | None = None
    header_cols: list[str] = []
    delim: str | None = ""
    ncols = 0
    now = datetime.now(UTC).timestamp() + 86400.0

    def bad(lineno: int, cls: str = "bad_fields") -> None:
        skipped[cls] += 1
        if len(bad_lines) < 10:
            bad_lines.append(lineno)

    with open(path, encoding="utf-8", errors="replace") as fh:
        for lineno, raw in enumerate(fh, start=1):
            line = raw.strip().lstrip("\ufeff")
            if not line:
                continue
            if line.startswith("#"):
                skipped["comment_lines"] += 1
                continue
            if delim == "":
                delim = "," if "," in line else ";" if ";" in line else "\t" if "\t" in line \
                    else None
                fields = _split(line, delim)
                ncols = len(fields)
                try:
                    _parse_time(fields[0])
                    [float(x) for x in fields[1:3]]
                    is_header = ncols < 3
                except ValueError:
                    is_header = True
                if is_header:
                    header_cols = [f.lower().strip('"\' ') for f in fields]
                    cols = {}
                    for key, names in (("t", _TIME_COLS), ("lat", _LAT_COLS),
                                       ("lon", _LON_COLS), ("h", _H_COLS)):
                        hit = [i for i, c in enumerate(header_cols) if c in names]
                        if hit:
                            cols[key] = hit[0]
                    missing = [k for k in ("t", "lat", "lon") if k not in cols]
                    if missing:
                        want = {"t": "time", "lat": "latitude", "lon": "longitude"}
                        raise RecordingError(
                            f"{path}: header {fields!r} has no {[want[k] for k in missing]} "
                            f"column (recognised names: time {list(_TIME_COLS)}, latitude "
                            f"{list(_LAT_COLS)}, longitude {list(_LON_COLS)})")
                    continue
                if ncols > 4:
                    raise RecordingError(
                        f"{path}: line {lineno} has {ncols} columns and the file has no "
                        f"header; without one the columns must be time, latitude, longitude "
                        f"[, height]")
                cols = {"t": 0, "lat": 1, "lon": 2}
                if ncols == 4:
                    cols["h"] = 3
            fields = _split(line, delim)
            if cols is None or len(fields) != ncols:
                bad(lineno)
                continue
            try:
                tv = _parse_time(fields[cols["t"]])
                la = float(fields[cols["lat"]])
                lo = float(fields[cols["lon"]])
                hv = float(fields[cols["h"]]) if "h" in cols and fields[cols["h"]] != "" \
                    else math.nan
            except (ValueError, OverflowError):
                bad(lineno)
                continue
            if not plausible_fix(la, lo, hv):
                bad(lineno)
                continue
            if not GPS_EPOCH_UTC <= tv <= now:
                bad(lineno, "implausible_time")
                continue
            rows.append((tv, la, lo, hv))
    if not rows:
        raise RecordingError(f"{path}: no valid row (time, latitude, longitude); skipped "
                             f"{skipped}, first bad lines {bad_lines}")
    a = np.array(rows, dtype=float)
    keep = np.ones(len(a), dtype=bool)
    last = -math.inf
    seen: set[float] = set()
    for i, tv in enumerate(a[:, 0]):
        if tv < last:
            skipped["time_reversals"] += 1
            keep[i] = False
        elif tv in seen:
            skipped["duplicate_epochs"] += 1
            keep[i] = False
        else:
            seen.add(float(tv))
            last = tv
    a = a[keep]
    ignored = [c for i, c in enumerate(header_cols) if cols and i not in cols.values()]
    return LogFixes(name=name or path.stem, t_utc=a[:, 0], lat=a[:, 1], lon=a[:, 2],
                    quality=np.ones(len(a), dtype=np.int64), date_known=True,
                    skipped=skipped, height_m=a[:, 3],
                    meta={"path": str(path), "format": "text", "bad_lines": bad_lines,
                          "ignored_columns": ignored})


def _sniff(path: Path) -> str:
    with open(path, "rb") as fh:
        head = fh.read(65536)
    if re.search(rb"\$[A-Z]{2}(GGA|RMC),", head):
        return "nmea"
    for raw in head.decode("latin-1").splitlines():
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        up = line.upper()
        if "HOSTNAME" in up and "LATITUDE" in up and "CLOCK" in up:
            return "tumbleweed"
        if re.fullmatch(r"[\x20-\x7e\t]+", line):
            words = {w.lower().strip('"\' ') for w in re.split(r"[,;\s]+", line)}
            if re.search(r"\d", line) or words & set(_LAT_COLS):
                return "text"
        break
    raise RecordingError(f"{path}: cannot tell the log format (no NMEA GGA/RMC, no tumbleweed "
                         f"header, not a text table); pass format= one of {list(FORMATS[1:])}")


def read_antenna_log(path: str | Path, name: str | None = None, format: str = "auto"
                     ) -> LogFixes:
    """Read one antenna's log: ``format`` in :data:`FORMATS` ("auto" looks at the content:
    NMEA GGA/RMC sentences, a tumbleweed CSV header, else a text table)."""
    path = Path(path)
    if format not in FORMATS:
        raise RecordingError(f"format: must be one of {list(FORMATS)}, got {format!r}")
    if not path.is_file():
        raise RecordingError(f"log: no such file {str(path)!r}")
    fmt = _sniff(path) if format == "auto" else format
    if fmt == "csv":
        raise RecordingError(f"{path}: format 'csv' needs a column mapping (a recording's "
                             f"[csv] table; sim.csv_logs.read_csv_log)")
    if fmt == "nmea":
        return read_nmea(path, name)
    if fmt == "tumbleweed":
        return read_tumbleweed_csv(path, name)
    return read_text_log(path, name)


# --------------------------------------------------------------------------- alignment
@dataclass(frozen=True)
class _Grid:
    t0_utc: float
    dt: float
    n: int

    @property
    def t(self) -> np.ndarray:
        return np.arange(self.n) * self.dt


def _grid_from(logs: Sequence[LogFixes], rate_hz: float | None, what: str,
               m_arrays: int | None = None) -> _Grid:
    """The UTC grid spanned by the valid fixes of ``logs`` (module docstring); ``m_arrays``
    antennas (default the number of logs) size the memory check."""
    m_arrays = len(logs) if m_arrays is None else m_arrays
    dated = {lg.date_known for lg in logs}
    if len(dated) > 1:
        undated = [lg.name for lg in logs if not lg.date_known]
        raise RecordingError(f"{what}: log(s) {undated} have no date (NMEA without RMC) and "
                             f"cannot be aligned on UTC with dated logs")
    tv = [lg.t_utc[lg.valid] for lg in logs]
    for lg, t in zip(logs, tv):
        if t.size == 0:
            raise RecordingError(f"{what}: log {lg.name!r} ({lg.meta.get('path', '')}) has no "
                                 f"valid fix; skipped {lg.skipped}")
    if rate_hz is None:
        dts = np.concatenate([np.diff(t) for t in tv])
        dts = dts[dts > 1e-6]
        if dts.size == 0:
            raise RecordingError(f"{what}: fewer than two valid fixes in every log; cannot "
                                 f"infer the sample interval (give rate_hz)")
        dt = float(np.median(dts))
    else:
        dt = 1.0 / _check_rate(rate_hz, "rate_hz")
    spans = {lg.name: (float(t[0]), float(t[-1])) for lg, t in zip(logs, tv)}
    first = min(a for a, _ in spans.values())
    last = max(b for _, b in spans.values())
    if len(logs) > 1:
        overlap = min(b for _, b in spans.values()) - max(a for a, _ in spans.values())
        if overlap < 0:
            raise RecordingError(
                f"{what}: the logs never overlap in UTC (spans {_fmt_spans(spans)}); they "
                f"were not recorded together")
    if (last - first) > MAX_GRID_DAYS * 86400.0:
        raise RecordingError(
            f"{what}: the logs span {(last - first) / 86400.0:.1f} days (> MAX_GRID_DAYS = "
            f"{MAX_GRID_DAYS:g}): spans {_fmt_spans(spans)}; a log with a bogus date?")
    allt = np.concatenate(tv)
    ang = 2.0 * np.pi * np.mod(allt - first, dt) / dt
    phase = float(np.mod(np.arctan2(np.sin(ang).mean(), np.cos(ang).mean()), 2 * np.pi)) \
        * dt / (2 * np.pi)
    t0 = first + phase - dt * round(phase / dt)          # the grid time nearest the first fix
    n = round((last - t0) / dt) + 1
    _check_grid_size(n, m_arrays, dt, what)
    return _Grid(t0_utc=float(t0), dt=dt, n=n)


def _check_rate(rate_hz: object, what: str) -> float:
    """A grid rate, Hz: finite, at most :data:`sim.nmea.MAX_RATE_HZ` (100 Hz, the fastest
    GNSS output) and an interval of at most :data:`MAX_GRID_DAYS`; RecordingError naming
    ``what`` and the value otherwise (1e308 overflowed the grid arithmetic)."""
    try:
        return check_real(rate_hz, what, lo=1.0 / (MAX_GRID_DAYS * 86400.0), hi=MAX_RATE_HZ)
    except ValueError as exc:
        raise RecordingError(f"{exc} Hz (the interval may not exceed MAX_GRID_DAYS = "
                             f"{MAX_GRID_DAYS:g} days; GNSS receivers output at most "
                             f"{MAX_RATE_HZ:g} Hz)") from None


def _plain(obj: object) -> object:
    """``obj`` with numpy scalars and arrays, tuples and paths as plain Python values, so
    ``json.dumps`` takes it (``Recording.meta`` is JSON-ready)."""
    if isinstance(obj, Mapping):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple, np.ndarray)):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.floating):
        return float(obj)
    if isinstance(obj, Path):
        return str(obj)
    return obj


def _check_grid_size(n: int, m: int, dt: float, what: str) -> None:
    """RecordingError when an (n, m, 2) float64 array would exceed MAX_GRID_BYTES."""
    if n * max(m, 1) * 16 > MAX_GRID_BYTES:
        raise RecordingError(
            f"{what}: {n} epochs at {dt:.6g} s for {m} antennas would need "
            f"{n * max(m, 1) * 16 / 2**30:.1f} GiB (> MAX_GRID_BYTES = 1 GiB); lower rate_hz "
            f"or shorten the logs")


def _fmt_spans(spans: Mapping[str, tuple[float, float]]) -> str:
    def iso(v: float) -> str:
        return datetime.fromtimestamp(v, UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    return ", ".join(f"{k}: {iso(a)}..{iso(b)}" for k, (a, b) in spans.items())


def _place(t: np.ndarray, values: np.ndarray, grid: _Grid, max_offset_s: float,
           interpolate: bool) -> tuple[np.ndarray, dict]:
    """Values (k, c) of valid fixes at increasing times t (k,) onto the grid: (n, c),
    NaN-filled, and the counts of the module docstring."""
    n = grid.n
    out = np.full((n, values.shape[1]), np.nan)
    u = (t - grid.t0_utc) / grid.dt
    k = np.rint(u).astype(np.int64)
    off = np.abs(u - k) * grid.dt
    on = off <= max_offset_s
    inside = on & (k >= 0) & (k < n)
    idx = np.flatnonzero(inside)
    idx = idx[np.lexsort((off[idx], k[idx]))]            # by grid time, nearest first
    first = np.ones(idx.size, dtype=bool)
    first[1:] = k[idx][1:] != k[idx][:-1]
    keep = idx[first]
    out[k[keep]] = values[keep]
    counts = {"aligned": int(keep.size), "off_grid": int((~on).sum()),
              "outside_grid": int((on & ~inside).sum()),
              "duplicate_on_grid": int(idx.size - keep.size), "interpolated": 0}
    if interpolate and t.size > 1:
        # grid times without a fix, strictly between two consecutive fixes at most 1.5
        # intervals apart: linear interpolation (never across a gap)
        g = grid.t0_utc + grid.t
        b = np.searchsorted(t, g, side="right")          # t[b - 1] <= g < t[b]
        a = b - 1
        ok = (a >= 0) & (b < t.size)
        ai, bi = np.where(ok, a, 0), np.where(ok, b, 0)
        ta, tb = t[ai], t[bi]
        fill = ok & np.isnan(out[:, 0]) & (ta < g) & (tb - ta <= 1.5 * grid.dt)
        w = np.where(fill, (g - ta) / np.where(fill, tb - ta, 1.0), 0.0)[:, None]
        out[fill] = ((1.0 - w) * values[ai] + w * values[bi])[fill]
        counts["interpolated"] = int(fill.sum())
    return out, counts


class _Frame:
    """UTM projection with a local origin (module docstring)."""

    def __init__(self, lat: np.ndarray, lon: np.ndarray):
        from pyproj import Transformer

        try:
            self.epsg = utm_epsg(float(np.mean(lat)), mean_longitude(lon))
        except ValueError as exc:
            raise RecordingError(f"frame: {exc}") from None
        self._tr = Transformer.from_crs("EPSG:4326", f"EPSG:{self.epsg}", always_xy=True)
        e, nn = self._tr.transform(np.asarray(lon, float), np.asarray(lat, float))
        self.e0, self.n0 = float(np.mean(e)), float(np.mean(nn))

    def xy(self, lat: np.ndarray, lon: np.ndarray) -> np.ndarray:
        e, nn = self._tr.transform(np.asarray(lon, float), np.asarray(lat, float))
        return np.stack([np.asarray(e) - self.e0, np.asarray(nn) - self.n0], axis=-1)

    def to_dict(self) -> dict:
        return {"epsg": self.epsg, "origin_easting_m": self.e0, "origin_northing_m": self.n0,
                "axes": "x = UTM easting - origin, y = UTM northing - origin (grid north), "
                        "metres"}


def _log_info(lg: LogFixes, counts: dict) -> dict:
    v = lg.valid
    info = {"path": lg.meta.get("path"), "format": lg.meta.get("format"),
            "fixes": int(v.sum()), "epochs_without_fix": int((~v).sum()),
            "t_first_utc": float(lg.t_utc[v][0]), "t_last_utc": float(lg.t_utc[v][-1]),
            "counts": counts, "skipped": dict(lg.skipped)}
    return info


def _align(logs: Sequence[LogFixes], grid: _Grid, frame: _Frame, max_offset_s: float,
           interpolate: bool) -> tuple[np.ndarray, np.ndarray, dict]:
    """Project and grid logs: positions (n, k, 2), heights (n, k), per-log info."""
    pos = np.full((grid.n, len(logs), 2), np.nan)
    hgt = np.full((grid.n, len(logs)), np.nan)
    info = {}
    for j, lg in enumerate(logs):
        # reacquisition transients (flagged by the reader, sim.nmea.flag_reacquisitions) are
        # left out as sessions leave them out, and counted
        flagged = (lg.reacquired if lg.reacquired is not None
                   else np.zeros(lg.t_utc.shape, dtype=bool))
        v = lg.valid & ~flagged
        xy = frame.xy(lg.lat[v], lg.lon[v])
        h = lg.height_m[v] if lg.height_m is not None else np.full(int(v.sum()), np.nan)
        vals = np.column_stack([xy, h])
        out, counts = _place(lg.t_utc[v], vals, grid, max_offset_s, interpolate)
        pos[:, j] = out[:, :2]
        hgt[:, j] = np.where(np.isnan(out[:, 0]), np.nan, out[:, 2])
        info[lg.name] = _log_info(lg, {**counts, "reacquired": int((lg.valid & flagged).sum())})
    return pos, hgt, info


# --------------------------------------------------------------------------- reference
@dataclass(frozen=True, eq=False)
class Reference:
    """The reference of a recording (the truth it is scored against).

    kind : "antennas" (per-antenna positions; pose from a rigid fit of the layout to them),
        "cg" (a track of the CG only; heading unknown) or "pose" (CG and heading, e.g. a
        ROS pose / odometry topic, :mod:`sim.ros_bags`).
    cg : (n, 2) metres, NaN where unknown. yaw : (n,) rad (CCW from +x, (-pi, pi]), NaN
        where unknown (always for kind "cg").
    positions : (n, m, 2) metres for kind "antennas" (NaN where an antenna has none).
    residual_m : (n,) RMS distance of the reference antennas from the fitted rigid layout
        (kind "antennas"; NaN where fewer than 2 antennas): how well the layout matches.
    meta : sources and summaries (median residual, and the same for the layout's mirror
        image: a reference that fits the mirror image better says the layout is mirrored).
    """

    kind: str
    cg: np.ndarray
    yaw: np.ndarray
    positions: np.ndarray | None = None
    residual_m: np.ndarray | None = None
    meta: dict = field(default_factory=dict)

    @classmethod
    def from_antennas(cls, positions: np.ndarray, config: SensorConfig, meta: dict | None = None
                      ) -> Reference:
        """Pose from per-antenna reference positions (n, m, 2) by the weighted rigid fit of
        :func:`estimator.window.procrustes_batch` (every present antenna, weight 1)."""
        from estimator.window import procrustes_batch

        cfg = config.planar()
        P = np.asarray(positions, dtype=float)
        if P.ndim != 3 or P.shape[1:] != (cfg.m, 2):
            raise RecordingError(f"reference positions: expected shape (n, {cfg.m}, 2), got "
                                 f"{P.shape}")
        present = ~np.isnan(P[..., 0])
        bf = procrustes_batch(P, present.astype(float), cfg)
        cnt = present.sum(axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            res = np.sqrt(bf.objective / cnt)
            mres = np.sqrt(bf.mirror_objective / cnt)
        med = float(np.nanmedian(res)) if np.isfinite(res).any() else math.nan
        mmed = float(np.nanmedian(mres)) if np.isfinite(mres).any() else math.nan
        m = dict(meta or {})
        m.update({"residual_median_m": med, "mirror_residual_median_m": mmed})
        if mmed < med:
            m["warning"] = (f"the reference antennas fit the MIRROR image of layout "
                            f"{cfg.name!r} better (median RMS {mmed:.3g} m vs {med:.3g} m): "
                            f"the layout is mirrored")
        return cls(kind="antennas", cg=bf.cg, yaw=bf.yaw, positions=P, residual_m=res, meta=m)

    @classmethod
    def from_pose(cls, cg: np.ndarray, yaw: np.ndarray, meta: dict | None = None) -> Reference:
        """A CG track (n, 2) metres with its heading (n,) rad (NaN where unknown)."""
        c, y = np.asarray(cg, dtype=float), np.asarray(yaw, dtype=float)
        if c.ndim != 2 or c.shape[1] != 2 or y.shape != (c.shape[0],):
            raise RecordingError(f"reference pose: expected cg (n, 2) and yaw (n,), got "
                                 f"{c.shape} and {y.shape}")
        return cls(kind="pose", cg=c, yaw=np.angle(np.exp(1j * y)), meta=dict(meta or {}))

    @classmethod
    def from_cg(cls, cg: np.ndarray, meta: dict | None = None) -> Reference:
        """A CG track (n, 2) metres; heading unknown."""
        c = np.asarray(cg, dtype=float)
        if c.ndim != 2 or c.shape[1] != 2:
            raise RecordingError(f"reference cg: expected shape (n, 2), got {c.shape}")
        return cls(kind="cg", cg=c, yaw=np.full(c.shape[0], np.nan), meta=dict(meta or {}))


# --------------------------------------------------------------------------- recording
@dataclass(frozen=True, eq=False)
class Recording:
    """A multi-antenna recording on a UTC grid (module docstring).

    t : (n,) s since ``meta["t0_utc"]``. config : SensorConfig (m antennas).
    obs : (n, m, 2) metres, NaN = no fix; None for a replay recording (observations are
        drawn per seed by :meth:`observations`). reference : :class:`Reference` or None.
    height_m : (n, m) ellipsoidal heights (NaN where none) or None.
    replay : None, or {"session": StationarySession, "noise_overrides": dict} (the
        recording as truth: reference antennas + replayed error).
    name : label. meta : JSON-ready details (files, counts, frame, grid).
    platform : :class:`estimator.platform.PlatformLimits` of the carrier (the recording's
        ``[platform]`` block, else its configuration's) or None (the filter estimates the
        limits from the data); :meth:`truth` passes it on in ``meta["platform"]``.
    """

    t: np.ndarray
    config: SensorConfig
    obs: np.ndarray | None = None
    reference: Reference | None = None
    height_m: np.ndarray | None = None
    replay: dict | None = None
    name: str = "recording"
    meta: dict = field(default_factory=dict)
    platform: PlatformLimits | None = None

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=float)
        if t.ndim != 1 or t.size < 1 or not np.all(np.isfinite(t)) \
                or (t.size > 1 and not np.all(np.diff(t) > 0)):
            raise RecordingError(f"t: must be (n,) finite, strictly increasing seconds, got "
                                 f"shape {t.shape}")
        if not isinstance(self.config, SensorConfig):
            raise TypeError(f"config: expected a SensorConfig, got {type(self.config).__name__}")
        n, m = t.size, self.config.m
        if (self.obs is None) == (self.replay is None):
            raise RecordingError("obs, replay: give measured observations or a replay, "
                                 "exactly one")
        if self.obs is not None:
            o = np.asarray(self.obs, dtype=float)
            if o.shape != (n, m, 2):
                raise RecordingError(f"obs: expected shape ({n}, {m}, 2), got {o.shape}")
            if np.isinf(o).any() or (np.isnan(o[..., 0]) != np.isnan(o[..., 1])).any():
                raise RecordingError("obs: infinite values or a fix NaN in one coordinate only")
            o = o.copy()
            o.setflags(write=False)
            object.__setattr__(self, "obs", o)
        if self.replay is not None:
            if self.reference is None or self.reference.kind != "antennas":
                raise RecordingError("replay: needs a reference of per-antenna positions (the "
                                     "truth the replayed error is added to)")
            if not isinstance(self.replay.get("session"), StationarySession):
                raise RecordingError("replay.session: expected a StationarySession")
        ref = self.reference
        if ref is not None and (ref.cg.shape != (n, 2) or ref.yaw.shape != (n,) or (
                ref.positions is not None and ref.positions.shape != (n, m, 2))):
            raise RecordingError(f"reference: arrays do not match n = {n}, m = {m}")
        if self.height_m is not None and np.asarray(self.height_m).shape != (n, m):
            raise RecordingError(f"height_m: expected shape ({n}, {m})")
        if self.platform is not None and not isinstance(self.platform, PlatformLimits):
            raise RecordingError(f"platform: expected an estimator.platform.PlatformLimits or "
                                 f"None, got {type(self.platform).__name__} {self.platform!r}")
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "meta", _plain(self.meta))

    @property
    def n(self) -> int:
        """Number of grid epochs."""
        return int(self.t.size)

    @property
    def m(self) -> int:
        """Number of antennas."""
        return self.config.m

    def observations(self, rng: np.random.Generator | None = None, *,
                     noise_overrides: Mapping[str, object] | None = None) -> np.ndarray:
        """(n, m, 2) metres, NaN = missing, read-only: the measured observations, or for a
        replay recording the reference antennas plus the replayed error drawn from ``rng``
        (:func:`sim.gps.observe` with the replay's ``noise_overrides``, or with
        ``noise_overrides`` given here in their place, e.g. ``{"replay": "identical"}``)."""
        if self.replay is None:
            if noise_overrides:
                raise RecordingError(f"noise_overrides: recording {self.name!r} has measured "
                                     f"observations, nothing is replayed")
            return self.obs  # type: ignore[return-value]
        if not isinstance(rng, np.random.Generator):
            raise TypeError(f"rng: a replay recording needs a numpy.random.Generator, got "
                            f"{type(rng).__name__}")
        nov = dict(noise_overrides) if noise_overrides else self.replay["noise_overrides"]
        return observe(self.truth(), self.config.planar(), self.replay["session"], rng=rng,
                       noise_overrides=nov)

    def truth(self) -> Truth:
        """The reference as a :class:`sim.truth.Truth` (scored by the sweep like a
        simulation): sensor positions (reference antennas, z = 0; NaN for a CG reference),
        CG, yaw (NaN where unknown), speed and yaw rate by central differences, and turn
        flags from the reference heading (yaw, else the course of the CG) by
        :func:`estimator.turns.detect_turns` (rates in ``REFERENCE_TURN_*``)."""
        cached = self.__dict__.get("_truth_cache")
        if cached is not None:
            return cached
        from estimator.turns import course_heading, detect_turns

        ref = self.reference
        if ref is None:
            raise RecordingError(f"recording {self.name!r}: has no reference (nothing to score "
                                 f"against)")
        n, m = self.n, self.m
        sp = np.full((n, m, 3), np.nan)
        if ref.positions is not None:
            sp[..., :2] = ref.positions
            sp[..., 2] = np.where(np.isnan(ref.positions[..., 0]), np.nan, 0.0)
        cg = np.column_stack([ref.cg, np.where(np.isnan(ref.cg[:, 0]), np.nan, 0.0)])
        if n > 1:
            with np.errstate(invalid="ignore"):
                vel = np.gradient(ref.cg, self.t, axis=0)
                yaw_rate = np.gradient(np.unwrap(np.nan_to_num(ref.yaw)), self.t)
        else:
            vel, yaw_rate = np.zeros((1, 2)), np.zeros(1)
        yaw_rate = np.where(np.isfinite(ref.yaw), yaw_rate, np.nan)
        heading = ref.yaw if np.isfinite(ref.yaw).any() else course_heading(
            self.t, ref.cg, REFERENCE_TURN_SPAN_S)
        turning = detect_turns(self.t, heading, rate_on=REFERENCE_TURN_RATE_ON,
                               rate_off=REFERENCE_TURN_RATE_OFF, span_s=REFERENCE_TURN_SPAN_S)
        truth = Truth(t=self.t, sensor_positions=sp, sensor_names=self.config.names, cg=cg,
                      yaw=ref.yaw, speed=np.hypot(vel[:, 0], vel[:, 1]), yaw_rate=yaw_rate,
                      turning=turning, meta={"recording": self.name, "source": "reference",
                                             "kind": ref.kind, "platform": None if
                                             self.platform is None else
                                             self.platform.to_dict()})
        self.__dict__["_truth_cache"] = truth
        return truth

    def __repr__(self) -> str:
        ref = "none" if self.reference is None else self.reference.kind
        return (f"Recording(name={self.name!r}, n={self.n}, m={self.m}, reference={ref}, "
                f"replay={'yes' if self.replay else 'no'}, config={self.config.name!r})")

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_logs(cls, antennas: Mapping[str, str | Path | LogFixes], config: SensorConfig, *,
                  reference: str | Path | LogFixes | Mapping[str, str | Path | LogFixes]
                  | None = None,
                  reference_positions: Mapping[str, Sequence[float]] | None = None,
                  rate_hz: float | None = None, max_offset_s: float | None = None,
                  interpolate: bool = False, formats: Mapping[str, str] | None = None,
                  name: str = "recording", platform: PlatformLimits | None = None
                  ) -> Recording:
        """A recording from one log per antenna, aligned on UTC (module docstring).

        antennas : antenna name -> log file (or :class:`sim.nmea.LogFixes`); the names must
            be ``config.names`` (an antenna without a log would be invented: error).
        reference : a CG track log, or antenna name -> reference log (RTK), or a pose track
            (:class:`sim.ros_bags.PoseFixes`: CG and heading), or None.
        reference_positions : antenna name -> (latitude, longitude) of a surveyed
            stationary platform (constant over the recording); not with ``reference``.
        rate_hz : grid rate (default from the fixes). max_offset_s : snap tolerance, s
            (default a quarter interval). interpolate : linear interpolation between
            consecutive fixes (named option, counted). formats : name -> log format.
        platform : the carrier's limits (default: ``config.platform``).
        """
        cfg = _check_config(config)
        logs = _read_logs(antennas, cfg, formats or {}, "antennas")
        grid = _grid_from(logs, rate_hz, "antennas", cfg.m)
        off = _max_offset(max_offset_s, grid.dt)
        ref_logs, ref_kind = _reference_logs(reference, cfg, formats or {})
        frame = _Frame(np.concatenate([lg.lat[lg.valid] for lg in logs]),
                       np.concatenate([lg.lon[lg.valid] for lg in logs]))
        pos, hgt, info = _align(logs, grid, frame, off, bool(interpolate))
        ref, ref_info = _make_reference(ref_logs, ref_kind, reference_positions, cfg, grid,
                                        frame, off, bool(interpolate))
        meta = _meta(grid, frame, off, interpolate, info, ref_info)
        heights = hgt if np.isfinite(hgt).any() else None
        return cls(t=grid.t, config=cfg, obs=pos, reference=ref, height_m=heights, name=name,
                   meta=meta, platform=_platform(platform, cfg))

    @classmethod
    def for_replay(cls, config: SensorConfig, session: StationarySession, *,
                   noise_overrides: Mapping[str, object] | None = None,
                   reference: Mapping[str, str | Path | LogFixes] | None = None,
                   reference_positions: Mapping[str, Sequence[float]] | None = None,
                   duration_s: float | None = None, max_offset_s: float | None = None,
                   interpolate: bool = False, formats: Mapping[str, str] | None = None,
                   name: str = "recording", platform: PlatformLimits | None = None
                   ) -> Recording:
        """The recording as truth: per-antenna reference positions (RTK logs, or surveyed
        ``reference_positions`` of a stationary platform) + a session's real error replayed
        on top, drawn per seed (:meth:`observations`; ``noise_overrides`` as in
        :func:`sim.gps.observe`, e.g. ``{"replay": "shifted"}``).

        The grid is the session's sample interval; with reference logs it spans them, with
        surveyed positions it lasts ``duration_s`` (default: the session's length).
        ``platform``: the carrier's limits (default: ``config.platform``).
        """
        cfg = _check_config(config)
        if not isinstance(session, StationarySession):
            raise TypeError(f"session: expected a StationarySession, got "
                            f"{type(session).__name__}")
        nov = dict(noise_overrides or {})
        bad = sorted(set(nov) - set(SESSION_REPLAY_KEYS) - _model_fields())
        if bad:
            raise RecordingError(f"replay: unknown key(s) {bad}; allowed "
                                 f"{sorted(SESSION_REPLAY_KEYS)} and noise-model fields")
        mode = nov.get("replay", "by_receiver")
        if mode not in REPLAY_MODES:
            raise RecordingError(f"replay.mode: unknown {mode!r}; choose one of "
                                 f"{list(REPLAY_MODES)}")
        dt = float(np.median(np.diff(session.t))) if session.n > 1 else 1.0
        ref_logs, kind = _reference_logs(reference, cfg, formats or {})
        if ref_logs is not None and kind != "antennas":
            raise RecordingError("reference: a replay needs per-antenna reference positions "
                                 "(a mapping antenna name -> log), not a CG track")
        if ref_logs is None and reference_positions is None:
            raise RecordingError("reference: a replay needs reference logs per antenna or "
                                 "surveyed reference_positions")
        if ref_logs is not None:
            grid = _grid_from(ref_logs, 1.0 / dt, "reference", cfg.m)
            frame = _Frame(np.concatenate([lg.lat[lg.valid] for lg in ref_logs]),
                           np.concatenate([lg.lon[lg.valid] for lg in ref_logs]))
        else:
            dur = session.n * dt if duration_s is None else check_real(
                duration_s, "duration_s", lo=0.0, lo_open=True)
            n = round(dur / dt)
            if n < 1 or n * dt > MAX_GRID_DAYS * 86400.0:
                raise RecordingError(f"duration_s: gives {n} epochs at {dt:g} s; need 1 .. "
                                     f"{MAX_GRID_DAYS:g} days")
            _check_grid_size(n, cfg.m, dt, "duration_s")
            grid = _Grid(t0_utc=0.0, dt=dt, n=n)
            if not isinstance(reference_positions, Mapping):
                raise TypeError("reference_positions: expected a mapping antenna name -> "
                                "(latitude, longitude)")
            latlon = np.array([_latlon(reference_positions, str(k))
                               for k in reference_positions])
            frame = _Frame(latlon[:, 0], latlon[:, 1])
        off = _max_offset(max_offset_s, grid.dt)
        ref, ref_info = _make_reference(ref_logs, "antennas" if ref_logs else None,
                                        reference_positions, cfg, grid, frame, off,
                                        bool(interpolate))
        meta = _meta(grid, frame, off, interpolate, {}, ref_info)
        if ref_logs is None:
            meta["t0_utc"] = None            # surveyed positions carry no time
        meta["replay"] = {"session": dict(session.meta, names=list(session.names),
                                          n=session.n), "noise_overrides": nov}
        return cls(t=grid.t, config=cfg, reference=ref, name=name, meta=meta,
                   replay={"session": session, "noise_overrides": nov},
                   platform=_platform(platform, cfg))


def _model_fields() -> set[str]:
    import dataclasses

    from sim.gps import GpsNoiseModel

    return {f.name for f in dataclasses.fields(GpsNoiseModel)}


def _platform(platform: object, cfg: SensorConfig) -> PlatformLimits | None:
    """The recording's limits: ``platform`` if given, else the configuration's."""
    return cfg.platform if platform is None else platform


def _check_config(config: object) -> SensorConfig:
    if not isinstance(config, SensorConfig):
        raise TypeError(f"config: expected a SensorConfig, got {type(config).__name__}")
    return config.planar()


def _max_offset(v: float | None, dt: float) -> float:
    if v is None:
        return 0.25 * dt
    off = check_real(v, "max_offset_s", lo=0.0)
    if off >= 0.5 * dt:
        raise RecordingError(f"max_offset_s: {off:g} s must be below half the grid interval "
                             f"({0.5 * dt:g} s), or one fix could serve two grid times")
    return off


def _read_one(value: object, name: str, fmt: str, what: str) -> LogFixes:
    if isinstance(value, LogFixes):
        tv = np.asarray(value.t_utc, dtype=float)
        if tv.ndim != 1 or not np.all(np.isfinite(tv)) or (tv.size > 1 and
                                                            not np.all(np.diff(tv) > 0)):
            raise RecordingError(f"{what}[{name!r}]: LogFixes.t_utc must be finite and "
                                 f"strictly increasing")
        la, lo = np.asarray(value.lat, float), np.asarray(value.lon, float)
        if la.shape != tv.shape or lo.shape != tv.shape:
            raise RecordingError(f"{what}[{name!r}]: LogFixes lat/lon must have the shape of "
                                 f"t_utc {tv.shape}")
        with np.errstate(invalid="ignore"):
            bad = (np.isfinite(la) & np.isfinite(lo)) & ((np.abs(la) > 90) | (np.abs(lo) > 180))
        if bad.any():
            k = int(np.argmax(bad))
            raise RecordingError(f"{what}[{name!r}]: fix {k} at latitude {la[k]!r}, longitude "
                                 f"{lo[k]!r} is outside [-90, 90] x [-180, 180] degrees")
        return LogFixes(name=name, t_utc=value.t_utc, lat=value.lat, lon=value.lon,
                        quality=value.quality, date_known=value.date_known,
                        skipped=dict(value.skipped), meta=dict(value.meta),
                        height_m=value.height_m, reacquired=value.reacquired)
    if not isinstance(value, (str, Path)):
        raise TypeError(f"{what}[{name!r}]: expected a log file path or LogFixes, got "
                        f"{type(value).__name__}")
    try:
        return read_antenna_log(value, name, fmt)
    except RecordingError:
        raise
    except (ValueError, OSError) as exc:
        raise RecordingError(f"{what}[{name!r}]: {value}: {exc}") from None


def _read_logs(mapping: object, cfg: SensorConfig, formats: Mapping[str, str], what: str,
               subset: bool = False) -> list[LogFixes]:
    """Logs named by antenna, in configuration order; ``subset``: some antennas may have
    none (at least 2 must), else every antenna needs one."""
    if not isinstance(mapping, Mapping):
        raise TypeError(f"{what}: expected a mapping antenna name -> log, got "
                        f"{type(mapping).__name__}")
    names = [str(k) for k in mapping]
    unknown = sorted(set(names) - set(cfg.names))
    missing = [k for k in cfg.names if k not in names]
    if unknown or (missing and not subset) or len(set(names)) != len(names):
        raise RecordingError(f"{what}: antenna names must be the configuration's "
                             f"{list(cfg.names)}; unknown {unknown}, without a log {missing}")
    if subset and len(names) < 2:
        raise RecordingError(f"{what}: per-antenna references need at least 2 antennas "
                             f"(the heading needs two), got {names}")
    by = {str(k): v for k, v in mapping.items()}
    return [_read_one(by[k], k, formats.get(k, "auto"), what) for k in cfg.names if k in by]


def _scatter(pos: np.ndarray, logs: Sequence[LogFixes], cfg: SensorConfig) -> np.ndarray:
    """(n, k, 2) positions of the logs (named by antenna) -> (n, m, 2), NaN elsewhere."""
    out = np.full((pos.shape[0], cfg.m, 2), np.nan)
    for j, lg in enumerate(logs):
        out[:, cfg.names.index(lg.name)] = pos[:, j]
    return out


def _reference_logs(reference: object, cfg: SensorConfig, formats: Mapping[str, str]
                    ) -> tuple[list[LogFixes] | None, str | None]:
    if reference is None:
        return None, None
    from sim.ros_bags import PoseFixes

    if isinstance(reference, PoseFixes):
        return [_read_one(reference.track, "cg", "auto", "reference"),
                _read_one(reference.ahead, "ahead", "auto", "reference")], "pose"
    if isinstance(reference, Mapping):
        return _read_logs(reference, cfg, {k: formats.get(f"reference.{k}", "auto")
                                           for k in cfg.names}, "reference", subset=True), \
            "antennas"
    return [_read_one(reference, "cg", formats.get("reference", "auto"), "reference")], "cg"


def _latlon(positions: Mapping[str, Sequence[float]], name: str) -> tuple[float, float]:
    if name not in positions:
        raise RecordingError(f"reference_positions: antenna {name!r} has no position "
                             f"(given for {sorted(positions)})")
    v = positions[name]
    if not isinstance(v, Sequence) or len(v) < 2:
        raise RecordingError(f"reference_positions[{name!r}]: expected (latitude, longitude) "
                             f"degrees, got {v!r}")
    la = check_real(v[0], f"reference_positions[{name!r}].latitude", lo=-90.0, hi=90.0)
    lo = check_real(v[1], f"reference_positions[{name!r}].longitude", lo=-180.0, hi=180.0)
    return la, lo


def _make_reference(ref_logs: list[LogFixes] | None, kind: str | None,
                    positions: Mapping[str, Sequence[float]] | None, cfg: SensorConfig,
                    grid: _Grid, frame: _Frame, off: float, interpolate: bool
                    ) -> tuple[Reference | None, dict]:
    if ref_logs is not None and positions is not None:
        raise RecordingError("reference, reference_positions: give one of them")
    if positions is not None:
        if not isinstance(positions, Mapping):
            raise TypeError("reference_positions: expected a mapping antenna name -> "
                            "(latitude, longitude)")
        names = [str(k) for k in positions]
        extra = sorted(set(names) - set(cfg.names))
        if extra or len(names) < 2:
            raise RecordingError(f"reference_positions: need >= 2 of the configuration's "
                                 f"antennas {list(cfg.names)}; got {names} (unknown {extra})")
        P = np.full((grid.n, cfg.m, 2), np.nan)
        latlon = {k: _latlon(positions, k) for k in cfg.names if k in names}
        ll = np.array(list(latlon.values()))
        xy = frame.xy(ll[:, 0], ll[:, 1])                          # (k, 2)
        for k, name in enumerate(latlon):
            P[:, cfg.names.index(name)] = xy[k]
        info = {"kind": "surveyed", "positions_latlon": {k: list(v) for k, v in latlon.items()}}
        return Reference.from_antennas(P, cfg, {"source": "surveyed positions"}), info
    if ref_logs is None:
        return None, {}
    pos, _, info = _align(ref_logs, grid, frame, off, interpolate)
    meta = {"source": "logs", "logs": {k: v["path"] for k, v in info.items()}}
    if kind == "cg":
        return Reference.from_cg(pos[:, 0], meta), {"kind": "cg", "logs": info}
    if kind == "pose":
        # the heading: from the CG to the point 1 m ahead, both in the recording's frame
        d = pos[:, 1] - pos[:, 0]
        meta.update({k: v for k, v in ref_logs[0].meta.items() if k not in ("path",)})
        return Reference.from_pose(pos[:, 0], np.arctan2(d[:, 1], d[:, 0]), meta), \
            {"kind": "pose", "logs": {"cg": info["cg"]}}
    return Reference.from_antennas(_scatter(pos, ref_logs, cfg), cfg, meta), \
        {"kind": "antennas", "logs": info}


def _meta(grid: _Grid, frame: _Frame, off: float, interpolate: bool, info: dict,
          ref_info: dict) -> dict:
    return {"t0_utc": grid.t0_utc, "rate_hz": 1.0 / grid.dt, "n": grid.n,
            "max_offset_s": off, "interpolate": bool(interpolate), "frame": frame.to_dict(),
            "logs": info, "reference": ref_info}


# --------------------------------------------------------------------------- TOML
_TOP_KEYS = {"name", "description", "config", "rate_hz", "max_offset_s", "interpolate",
             "antenna", "reference", "replay", "platform", "csv", "bag"}
_REFERENCE_KEYS = {"log", "format", "antenna", "topic", "frame", "origin", "epsg",
                   "offset_m", "id"}
_REPLAY_KEYS = {"logs", "session", "mode", "receiver", "shift_s", "model", "overrides",
                "duration_s", "rate_hz"}


def _resolve_file(value: object, base: Path, where: str, folder: Path | None = None) -> Path:
    """A file the recording names, under the one rule of
    :func:`estimator.model_files.resolve_model_file`: relative to the recording's folder,
    then the project, never outside them (or the shared data folder beside the project);
    ``folder``: where a bare name is looked up (configurations, noise models)."""
    return resolve_model_file(value, folder, where, base=base, error=RecordingError)


def _resolve_recording(path_or_name: str | Path) -> Path:
    """A recording: a name in ``models/recordings/`` or a file given by the user."""
    return resolve_model_file(path_or_name, RECORDINGS_DIR, "recording",
                              error=RecordingError).resolve()


def _read_toml(path: Path) -> dict:
    return parse_toml(path.read_bytes(), path, error=RecordingError)


def _parse(path: Path) -> dict:
    """Validated structure of a recording TOML (files resolved), without reading logs."""
    data = _read_toml(path)
    src, base = str(path), path.parent
    unknown = sorted(set(data) - _TOP_KEYS)
    if unknown:
        raise RecordingError(f"{src}: unknown key(s) {unknown}; allowed: {sorted(_TOP_KEYS)}")
    out: dict = {"name": data.get("name", path.stem), "source": src}
    for key in ("name", "description"):
        if key in data and not isinstance(data[key], str):
            raise RecordingError(f"{src}: {key} must be a string, got {data[key]!r}")
    cfgv = data.get("config")
    if not isinstance(cfgv, str) or not cfgv:
        raise RecordingError(f"{src}: config: required, a name in models/configs/ or a file")
    from estimator.configuration import CONFIGS_DIR

    out["config"] = _resolve_file(cfgv, base, f"{src}: config", CONFIGS_DIR)
    for key in ("rate_hz", "max_offset_s"):
        if key in data:
            try:
                out[key] = _check_rate(data[key], key) if key == "rate_hz" else \
                    check_real(data[key], key, lo=0.0)
            except (TypeError, ValueError) as exc:
                raise RecordingError(f"{src}: {exc}") from None
    if "interpolate" in data and not isinstance(data["interpolate"], bool):
        raise RecordingError(f"{src}: interpolate: must be true or false, got "
                             f"{data['interpolate']!r}")
    out["interpolate"] = bool(data.get("interpolate", False))
    try:
        out["platform"] = platform_from_table(data.get("platform"), f"{src}: platform")
    except ValueError as exc:
        raise RecordingError(str(exc)) from None
    out["csv"] = _parse_csv(data.get("csv"), src)
    out["bag"] = _parse_bag(data.get("bag"), base, src)
    ants = data.get("antenna")
    if ants is not None:
        out["antenna"] = _parse_antennas(ants, base, f"{src}: antenna", need_log=True)
    ref = data.get("reference")
    if ref is not None:
        if not isinstance(ref, dict):
            raise RecordingError(f"{src}: reference: must be a table")
        bad = sorted(set(ref) - _REFERENCE_KEYS)
        given = [k for k in ("log", "antenna", "topic") if k in ref]
        if bad or len(given) != 1:
            raise RecordingError(f"{src}: reference: give one of log = <CG track>, "
                                 f"[[reference.antenna]] tables or topic = <pose topic> "
                                 f"(unknown keys {bad})")
        if "topic" in ref:
            out["reference"] = _parse_pose_reference(ref, f"{src}: reference")
        elif "log" in ref:
            out["reference"] = {"log": _resolve_file(ref["log"], base, f"{src}: reference.log"),
                                "format": _fmt(ref.get("format", "auto"),
                                               f"{src}: reference.format")}
            if "id" in ref:
                out["reference"]["id"] = str(ref["id"])
        else:
            out["reference"] = {"antenna": _parse_antennas(
                ref["antenna"], base, f"{src}: reference.antenna", need_log=False)}
    rep = data.get("replay")
    if rep is not None:
        out["replay"] = _parse_replay(rep, base, f"{src}: replay")
        if "antenna" in out:
            raise RecordingError(f"{src}: replay: the observations come from the replay; "
                                 f"remove the [[antenna]] logs (or the [replay] table)")
        if "antenna" not in out.get("reference", {}):
            raise RecordingError(f"{src}: replay: needs [[reference.antenna]] positions (RTK "
                                 f"logs or surveyed latitude/longitude)")
    elif "antenna" not in out:
        raise RecordingError(f"{src}: antenna: at least one [[antenna]] log is required "
                             f"(or a [replay] table)")
    _check_sources(out, src)
    return out


def _parse_csv(table: object, src: str):
    """The ``[csv]`` column mapping (:class:`sim.csv_logs.CsvMapping`) or None."""
    if table is None:
        return None
    from sim.csv_logs import CsvMapping

    return CsvMapping.from_dict(table, f"{src}: csv")


def _parse_bag(table: object, base: Path, src: str) -> dict | None:
    """``[bag]``: ``path`` = a ROS 1 .bag file, a ROS 2 bag folder or its metadata.yaml."""
    if table is None:
        return None
    if not isinstance(table, dict):
        raise RecordingError(f"{src}: bag: must be a table with path = <bag>")
    bad = sorted(set(table) - {"path"})
    if bad or "path" not in table:
        raise RecordingError(f"{src}: bag: needs path = <ROS 1 .bag file or ROS 2 bag folder> "
                             f"(unknown keys {bad})")
    v = table["path"]
    if isinstance(v, str) and (base / v).is_dir():
        v = str(Path(v) / "metadata.yaml")       # a ROS 2 bag folder: its metadata names it
    return {"path": _resolve_file(v, base, f"{src}: bag.path")}


def _parse_pose_reference(ref: dict, where: str) -> dict:
    """``[reference] topic = ...`` (a ROS pose / odometry topic) and its frame."""
    out = {"topic": _topic(ref["topic"], f"{where}.topic"), "frame": ref.get("frame")}
    if out["frame"] not in ("enu", "epsg"):
        raise RecordingError(f"{where}.frame: must be 'enu' (with origin = [lat, lon]) or "
                             f"'epsg' (with epsg = <code>), got {out['frame']!r}")
    try:
        if out["frame"] == "enu":
            o = ref.get("origin")
            if not isinstance(o, list) or len(o) != 2:
                raise RecordingError(f"{where}.origin: required with frame = 'enu': "
                                     f"[latitude, longitude] degrees, got {o!r}")
            out["origin"] = (check_real(o[0], f"{where}.origin[0] (latitude)", lo=-90, hi=90),
                             check_real(o[1], f"{where}.origin[1] (longitude)", lo=-180,
                                        hi=180))
        else:
            e = ref.get("epsg")
            if not isinstance(e, int) or isinstance(e, bool) or e <= 0:
                raise RecordingError(f"{where}.epsg: required with frame = 'epsg': a "
                                     f"projected CRS code (e.g. 32632), got {e!r}")
            out["epsg"] = e
        off = ref.get("offset_m", [0.0, 0.0])
        if not isinstance(off, list) or len(off) != 2:
            raise RecordingError(f"{where}.offset_m: must be [x, y] metres, got {off!r}")
        out["offset_m"] = tuple(check_real(v, f"{where}.offset_m[{i}]", lo=-1e4, hi=1e4)
                                for i, v in enumerate(off))
    except (TypeError, ValueError) as exc:
        raise RecordingError(str(exc)) from None
    return out


def _topic(v: object, where: str) -> str:
    if not isinstance(v, str) or not v.startswith("/"):
        raise RecordingError(f"{where}: must be a ROS topic name ('/...'), got {v!r}")
    return v


def _check_sources(out: dict, src: str) -> None:
    """Every csv log has the [csv] mapping, every topic the [bag], every id a column."""
    entries = [("antenna", e) for e in out.get("antenna", [])]
    entries += [("reference.antenna", e) for e in out.get("reference", {}).get("antenna", [])]
    if "log" in out.get("reference", {}):
        entries.append(("reference", {**out["reference"], "name": "cg"}))
    for where, e in entries:
        if e.get("format") == "csv" and out["csv"] is None:
            raise RecordingError(f"{src}: {where} {e['name']!r}: format 'csv' needs the [csv] "
                                 f"column mapping")
        if "id" in e and (e.get("format") != "csv" or out["csv"].antenna is None):
            raise RecordingError(f"{src}: {where} {e['name']!r}: id: only for a csv log with "
                                 f"an antenna column (csv.antenna)")
        if "topic" in e and out["bag"] is None:
            raise RecordingError(f"{src}: {where} {e['name']!r}: topic needs the [bag] table "
                                 f"(path = <bag>)")
    if "topic" in out.get("reference", {}) and out["bag"] is None:
        raise RecordingError(f"{src}: reference.topic: needs the [bag] table (path = <bag>)")


def _fmt(v: object, where: str) -> str:
    if v not in FORMATS:
        raise RecordingError(f"{where}: must be one of {list(FORMATS)}, got {v!r}")
    return str(v)


def _parse_antennas(items: object, base: Path, where: str, need_log: bool) -> list[dict]:
    if not isinstance(items, list) or not items:
        raise RecordingError(f"{where}: must be a non-empty array of tables")
    out = []
    for k, it in enumerate(items):
        w = f"{where}[{k}]"
        if not isinstance(it, dict):
            raise RecordingError(f"{w}: must be a table")
        allowed = {"name", "log", "format", "id", "topic"} | (
            set() if need_log else {"latitude", "longitude"})
        bad = sorted(set(it) - allowed)
        if bad:
            raise RecordingError(f"{w}: unknown key(s) {bad}; allowed: {sorted(allowed)}")
        if not isinstance(it.get("name"), (str, int)) or isinstance(it.get("name"), bool):
            raise RecordingError(f"{w}.name: required, a sensor name")
        e: dict = {"name": str(it["name"])}
        if sum(k in it for k in ("log", "topic", "latitude")) > 1:
            raise RecordingError(f"{w}: give one of log, topic or latitude/longitude")
        if "id" in it:
            if not isinstance(it["id"], (str, int)) or isinstance(it["id"], bool):
                raise RecordingError(f"{w}.id: must be the antenna's value in the csv antenna "
                                     f"column, got {it['id']!r}")
            e["id"] = str(it["id"])
        if "topic" in it:
            if "format" in it:
                raise RecordingError(f"{w}.format: not with a topic (a bag's NavSatFix)")
            e["topic"] = _topic(it["topic"], f"{w}.topic")
        elif "log" in it:
            e["log"] = _resolve_file(it["log"], base, f"{w}.log")
            e["format"] = _fmt(it.get("format", "auto"), f"{w}.format")
        elif need_log:
            raise RecordingError(f"{w}.log: required (or topic = <NavSatFix topic> with "
                                 f"[bag])")
        else:
            try:
                e["latlon"] = (check_real(it.get("latitude"), f"{w}.latitude", lo=-90, hi=90),
                               check_real(it.get("longitude"), f"{w}.longitude", lo=-180,
                                          hi=180))
            except (TypeError, ValueError) as exc:
                raise RecordingError(str(exc)) from None
        out.append(e)
    names = [e["name"] for e in out]
    if len(set(names)) != len(names):
        raise RecordingError(f"{where}: duplicate antenna names {names}")
    kinds = {"latlon" in e for e in out}
    if len(kinds) > 1:
        raise RecordingError(f"{where}: mix of logs and surveyed positions; use one kind")
    return out


def _parse_replay(rep: object, base: Path, where: str) -> dict:
    if not isinstance(rep, dict):
        raise RecordingError(f"{where}: must be a table")
    bad = sorted(set(rep) - _REPLAY_KEYS)
    if bad:
        raise RecordingError(f"{where}: unknown key(s) {bad}; allowed: {sorted(_REPLAY_KEYS)}")
    if ("logs" in rep) == ("session" in rep):
        raise RecordingError(f"{where}: give logs = [consumer logs] or session = <file.npz>")
    out: dict = {}
    if "logs" in rep:
        logs = rep["logs"]
        if isinstance(logs, str):
            logs = [logs]
        if not isinstance(logs, list) or not logs:
            raise RecordingError(f"{where}.logs: must be a non-empty list of files")
        out["logs"] = [_resolve_file(x, base, f"{where}.logs[{i}]") for i, x in enumerate(logs)]
    else:
        out["session"] = _resolve_file(rep["session"], base, f"{where}.session")
    mode = rep.get("mode", "by_receiver")
    if mode not in REPLAY_MODES:
        raise RecordingError(f"{where}.mode: unknown {mode!r}; choose one of {list(REPLAY_MODES)}")
    nov: dict = {"replay": mode}
    if "receiver" in rep:
        if not isinstance(rep["receiver"], str):
            raise RecordingError(f"{where}.receiver: must be a receiver name")
        nov["receiver"] = rep["receiver"]
    for key in ("shift_s", "duration_s", "rate_hz"):
        if key in rep:
            try:
                v = _check_rate(rep[key], f"{where}.{key}") if key == "rate_hz" else \
                    check_real(rep[key], f"{where}.{key}", lo=0.0, lo_open=True)
            except (TypeError, ValueError) as exc:
                raise RecordingError(str(exc)) from None
            (nov if key == "shift_s" else out)[key] = v
    if "model" in rep:
        if mode != "common_plus_model":
            raise RecordingError(f"{where}.model: only with mode 'common_plus_model'")
        if not isinstance(rep["model"], str):
            raise RecordingError(f"{where}.model: must be a noise-model name or file")
        mp = _resolve_file(rep["model"], base, f"{where}.model", MODELS_DIR / "noise")
        # a bare name stays a name (sim.gps loads it), a file is passed resolved
        nov["model"] = rep["model"] if mp.parent == MODELS_DIR / "noise" and \
            Path(rep["model"]).parent == Path(".") and not Path(rep["model"]).suffix \
            else str(mp)
    elif mode == "common_plus_model":
        raise RecordingError(f"{where}.model: required with mode 'common_plus_model'")
    ov = rep.get("overrides", {})
    if not isinstance(ov, dict):
        raise RecordingError(f"{where}.overrides: must be a table of noise-model fields")
    if ov and mode != "common_plus_model":
        raise RecordingError(f"{where}.overrides: only with mode 'common_plus_model'")
    nov.update(ov)
    out["noise_overrides"] = nov
    return out


def recording_files(path_or_name: str | Path) -> list[Path]:
    """Every file a recording TOML depends on (itself, the configuration, every log and
    session): the sweep hashes them so that editing any invalidates its cells."""
    p = _resolve_recording(path_or_name)
    spec = _parse(p)
    files = [p, Path(spec["config"])]
    if spec["bag"] is not None:
        from sim.ros_bags import bag_files

        files.extend(bag_files(spec["bag"]["path"]))
    for e in spec.get("antenna", []):
        if "log" in e:
            files.append(e["log"])
    ref = spec.get("reference", {})
    if "log" in ref:
        files.append(ref["log"])
    for e in ref.get("antenna", []):
        if "log" in e:
            files.append(e["log"])
    rep = spec.get("replay", {})
    files.extend(rep.get("logs", []))
    if "session" in rep:
        files.append(rep["session"])
    mdl = rep.get("noise_overrides", {}).get("model")
    if mdl and Path(mdl).is_file():
        files.append(Path(mdl))
    return files


def recording_digest(path_or_name: str | Path) -> str:
    """SHA-256 (16 hex digits) of every file of :func:`recording_files`, in order."""
    h = hashlib.sha256()
    for f in recording_files(path_or_name):
        h.update(str(f.name).encode())
        h.update(Path(f).read_bytes())
    return h.hexdigest()[:16]


def recording_summary(path_or_name: str | Path) -> dict:
    """What a recording TOML names, without reading its logs: ``name``, ``config_name``,
    ``config_file``, ``replay_mode`` (None for measured observations), ``has_reference``."""
    p = _resolve_recording(path_or_name)
    spec = _parse(p)
    rep = spec.get("replay")
    return {"name": spec["name"], "config_name": SensorConfig.load(spec["config"]).name,
            "config_file": str(spec["config"]),
            "replay_mode": None if rep is None else rep["noise_overrides"]["replay"],
            "has_reference": "reference" in spec}


def load_recording(path_or_name: str | Path, *, config: SensorConfig | None = None
                   ) -> Recording:
    """Load a recording TOML: a name in ``models/recordings/`` or a file. Format::

        name = "rig"                      # optional, default the file stem
        description = "..."
        config = "rig4"                   # models/configs/ name or file (relative here)
        rate_hz = 1.0                     # optional grid rate (default from the fixes)
        max_offset_s = 0.25               # optional snap tolerance, s
        interpolate = false               # optional, linear between consecutive fixes

        [[antenna]]                       # one per configuration antenna
        name = "1"
        log = "logs/rx1.nmea"             # NMEA, tumbleweed CSV or text (relative here)
        format = "auto"                   # optional: nmea | tumbleweed | text

        [reference]                       # optional
        log = "rtk_cg.csv"                # a CG track (position scored, heading not), or
        [[reference.antenna]]             # per antenna: an RTK log ...
        name = "1"
        log = "rtk/rx1.csv"               # ... or a surveyed position (stationary platform)
        # latitude = 39.79444, longitude = -105.15336

        [replay]                          # optional, instead of [[antenna]]: the recording
        logs = ["consumer.nmea"]          # as truth, reference + replayed real error
        mode = "shifted"                  # sim.gps.REPLAY_MODES
        shift_s = 300                     # optional (shifted)
        receiver = "consumer"             # optional: which receiver of the logs
        model = "gps_stationary"          # common_plus_model: the per-receiver part
        overrides = {common_fraction = 0.5}   # optional model fields
        duration_s = 1200                 # surveyed reference: length of the recording

        [platform]                        # optional: the carrier's limits, SI units
        max_speed_mps = 16.0              # (estimator.platform.PlatformLimits; beside these
        max_accel_mps2 = 5.0              # three: max_yaw_accel_radps2,
        max_turn_rate_radps = 0.6         # max_lateral_accel_mps2, max_jerk_mps3)

    Without ``[platform]`` the configuration's block applies; without either the filter
    estimates the limits from the data.
    Relative paths resolve against the TOML's folder, then the repository. ``config``
    replaces the file's configuration (same antenna names). Errors name file and field.
    """
    p = _resolve_recording(path_or_name)
    spec = _parse(p)
    cfg = config if config is not None else SensorConfig.load(spec["config"])
    if config is not None and set(config.names) != set(SensorConfig.load(spec["config"]).names):
        raise RecordingError(f"config: antenna names {list(config.names)} differ from the "
                             f"recording's configuration")
    kw = {k: spec[k] for k in ("max_offset_s",) if k in spec}
    try:
        reference, positions, formats = _reference_sources(spec)
        if "replay" in spec:
            rep = spec["replay"]
            session = (StationarySession.load(rep["session"]) if "session" in rep
                       else _session_from_logs(rep["logs"], rep.get("rate_hz")))
            rec = Recording.for_replay(
                cfg, session, noise_overrides=rep["noise_overrides"], reference=reference,
                reference_positions=positions, duration_s=rep.get("duration_s"),
                interpolate=spec["interpolate"], formats=formats, name=spec["name"],
                platform=spec["platform"], **kw)
        else:
            antennas = {e["name"]: _log_source(e, spec) for e in spec["antenna"]}
            formats.update({e["name"]: e["format"] for e in spec["antenna"] if "format" in e})
            rec = Recording.from_logs(antennas, cfg, reference=reference,
                                      reference_positions=positions,
                                      rate_hz=spec.get("rate_hz"),
                                      interpolate=spec["interpolate"], formats=formats,
                                      name=spec["name"], platform=spec["platform"], **kw)
    except RecordingError as exc:
        raise RecordingError(f"{p}: {exc}") from None
    rec.meta.update({"source": str(p), "config_file": str(spec["config"]),
                     "platform": None if rec.platform is None else {
                         **rec.platform.to_dict(),
                         "from": "recording" if spec["platform"] is not None else "config"}})
    return rec


def _log_source(e: dict, spec: dict) -> Path | LogFixes:
    """What an antenna entry of a recording TOML names: its log file, or (a csv log, a bag
    topic) the fixes read with the recording's [csv] mapping or from its [bag]."""
    if "topic" in e:
        from sim.ros_bags import read_navsatfix

        return read_navsatfix(spec["bag"]["path"], e["topic"], e["name"])
    if e.get("format") == "csv":
        from sim.csv_logs import read_csv_log

        mp = spec["csv"]
        return read_csv_log(e["log"], mp, name=e["name"],
                            antenna=e.get("id", e["name"]) if mp.antenna else None)
    return e["log"]


def _reference_sources(spec: dict) -> tuple[object, dict | None, dict[str, str]]:
    """(reference for Recording.from_logs / for_replay, surveyed positions, formats)."""
    ref = spec.get("reference", {})
    formats: dict[str, str] = {}
    if "topic" in ref:
        from sim.ros_bags import read_pose_reference

        return read_pose_reference(spec["bag"]["path"], ref["topic"], frame=ref["frame"],
                                   origin=ref.get("origin"), epsg=ref.get("epsg"),
                                   offset_m=ref["offset_m"]), None, formats
    if "log" in ref:
        formats["reference"] = ref["format"]
        return _log_source({**ref, "name": "cg"}, spec), None, formats
    if not ref.get("antenna"):
        return None, None, formats
    if "latlon" in ref["antenna"][0]:
        return None, {e["name"]: e["latlon"] for e in ref["antenna"]}, formats
    formats.update({f"reference.{e['name']}": e["format"] for e in ref["antenna"]
                    if "format" in e})
    return {e["name"]: _log_source(e, spec) for e in ref["antenna"]}, None, formats


def _session_from_logs(paths: Sequence[Path], rate_hz: float | None) -> StationarySession:
    """A StationarySession of consumer logs (one receiver each), aligned on UTC with the
    recording grid rules; each receiver in its own local frame (the replay uses only its
    deviation from its mean)."""
    names = [p.stem if [q.stem for q in paths].count(p.stem) == 1
             else f"{p.parent.name}_{p.stem}" for p in paths]
    logs = [read_antenna_log(p, nm) for p, nm in zip(paths, names)]
    grid = _grid_from(logs, rate_hz, "replay.logs")
    off = 0.25 * grid.dt
    obs = np.full((grid.n, len(logs), 2), np.nan)
    info = {}
    for j, lg in enumerate(logs):
        v = lg.valid
        frame = _Frame(lg.lat[v], lg.lon[v])
        out, counts = _place(lg.t_utc[v], frame.xy(lg.lat[v], lg.lon[v]), grid, off, False)
        obs[:, j] = out
        info[lg.name] = {**_log_info(lg, counts), "frame": frame.to_dict()}
    meta = {"source": "logs", "alignment": "utc", "t0_utc": grid.t0_utc,
            "rate_hz": 1.0 / grid.dt, "receivers": info,
            "frame": "per receiver: x = UTM easting - its mean, y = northing - its mean"}
    return StationarySession(t=grid.t, obs=obs, names=tuple(names), meta=meta)

