"""Import real GNSS logs (NMEA 0183, tumbleweed CSV) into a :class:`sim.gps.StationarySession`.

NMEA: GGA and RMC sentences are parsed with pynmea2 from any talker (``$GP``, ``$GN``,
``$GL``, ``$GA``, ``$GB``, ...). Everything else in a log is counted, never silently
dropped; the counts per class are in ``meta["skipped"]`` (session) and ``LogFixes.skipped``:

- ``comment_lines``: lines starting with ``#`` (gpsd regression-log headers).
- ``binary_segments``: runs of non-NMEA bytes (UBX/RTCM binary, line noise) before, between
  or instead of sentences.
- ``truncated``: a ``$`` fragment without a ``*hh`` checksum terminator (cut-off lines; a
  sentence whose checksum cannot be verified is not trusted).
- ``bad_checksum``: checksum present but wrong.
- ``parse_error``: checksum fine but pynmea2 cannot parse the sentence.
- ``bad_fields``: a GGA/RMC with a malformed time, coordinate or hemisphere, or 0,0.
- ``no_fix``: a GGA with fix quality 0 or an RMC with status ``V`` (the epoch becomes a
  missing sample, as a receiver without a fix reports nothing useful).
- ``empty_position``: a GGA/RMC that claims a fix but has empty latitude/longitude fields.
- ``no_date``: GGA epochs before the first RMC date of the log (they are dated by
  back-propagating the first RMC date; counted, not dropped).
- ``duplicate_epochs``: a second fix for an epoch already seen (GGA and RMC of the same
  second are merged first: the GGA position wins; only genuine repeats count here).
- ``time_reversals``: a fix whose time is earlier than the previous one by less than 12 h
  (out of order; dropped and counted; larger backward jumps are a midnight rollover).
- ``off_grid``: fixes that do not fall within a quarter interval of the session's sample
  grid (e.g. 5 Hz fixes when a 1 Hz grid was asked for).
- ``other_sentences``: valid sentences of other types (GSA, GSV, VTG, TXT, proprietary);
  not errors, reported for completeness.

Dates: RMC carries the date; GGA only the time of day. The running date is taken from the
latest RMC; when the time of day jumps back by more than 12 h without a new RMC date, the
date advances by one day (midnight rollover). A log without any RMC gets day 0 = 1970-01-01
and ``date_known = False``; its times are still monotone across midnight.

Frame: latitude/longitude (WGS 84) are projected with pyproj to UTM; the zone is chosen
from the mean fix of the data (with the Norway/Svalbard exceptions), EPSG 326zz north /
327zz south. The local frame is x = UTM easting - origin, y = UTM northing - origin
(grid north, as the dissertation's UTM plots; it differs from true north by the meridian
convergence, under 3 degrees within a zone at mid latitudes). The origin is the mean of all
valid fixes (``origin="common"``, used when receivers are co-located / time-aligned) or each
receiver's own mean (``origin="per_receiver"``, used for independent series recorded at
different places), recorded in ``meta["frame"]``.

Tumbleweed CSV (com-diag-hazer ``benchmark.csv`` / ``mobile.csv``): columns HOSTNAME,
OBSERVATION, CLOCK, TIME, LATITUDE, LONGITUDE, HORIZONTAL, MSL, WGS84, VERTICAL, SPEED,
COURSE; TIME is the fix time in UTC seconds since 1970, LATITUDE/LONGITUDE decimal degrees.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from datetime import UTC, date, datetime
from datetime import time as dtime
from pathlib import Path
from typing import Literal

import numpy as np
import pynmea2

from sim.gps import StationarySession

__all__ = [
    "SKIP_CLASSES",
    "LogFixes",
    "import_session",
    "parse_nmea",
    "read_log",
    "read_nmea",
    "read_tumbleweed_csv",
    "session_from_fixes",
    "utm_epsg",
]

SKIP_CLASSES = (
    "comment_lines", "binary_segments", "truncated", "bad_checksum", "parse_error",
    "bad_fields", "no_fix", "empty_position", "no_date", "duplicate_epochs",
    "time_reversals", "off_grid", "other_sentences",
)

_SENTENCE = re.compile(r"\$([A-Z0-9]{2,5}),[\x20-\x7e]*?\*[0-9A-Fa-f]{2}")
_FIX_TYPES = {"GGA", "RMC"}
_DAY = 86400.0
_WS = " \t\r\n\x0b\x0c"   # ASCII whitespace only: latin-1 bytes such as 0x85 or 0xa0 are binary


@dataclass
class LogFixes:
    """Fixes read from one log (one receiver), before gridding.

    t_utc : (k,) seconds since 1970-01-01 UTC (or since day 0 when ``date_known`` is False);
    includes no-fix epochs, whose lat/lon are NaN. lat, lon : (k,) degrees WGS 84.
    quality : (k,) int, GGA fix quality (RMC-only epochs: 1 for 'A', 0 for 'V').
    skipped : counts per class (see module docstring). meta : source details.
    height_m : (k,) metres above the WGS 84 ellipsoid, NaN where the log has none, or None
        when the reader does not provide heights at all.
    """

    name: str
    t_utc: np.ndarray
    lat: np.ndarray
    lon: np.ndarray
    quality: np.ndarray
    date_known: bool
    skipped: dict = field(default_factory=dict)
    meta: dict = field(default_factory=dict)
    height_m: np.ndarray | None = None

    @property
    def valid(self) -> np.ndarray:
        """(k,) bool, epochs with a usable position."""
        return np.isfinite(self.lat) & np.isfinite(self.lon)


def _zero_skips() -> dict:
    return {k: 0 for k in SKIP_CLASSES}


def _tod(ts: object) -> float | None:
    if not isinstance(ts, dtime):
        return None
    return ts.hour * 3600.0 + ts.minute * 60.0 + ts.second + ts.microsecond * 1e-6


def _coord(value: str, hemi: str, is_lat: bool) -> float | None:
    """ddmm.mmmm / dddmm.mmmm + hemisphere -> signed degrees, or None when malformed."""
    if hemi not in (("N", "S") if is_lat else ("E", "W")):
        return None
    try:
        v = float(value)
    except ValueError:
        return None
    deg = math.floor(v / 100.0)
    minutes = v - 100.0 * deg
    if not (0.0 <= minutes < 60.0) or deg < 0:
        return None
    out = deg + minutes / 60.0
    if out > (90.0 if is_lat else 180.0):
        return None
    return -out if hemi in ("S", "W") else out


def parse_nmea(lines: Iterable[bytes | str], name: str = "receiver") -> LogFixes:
    """Parse NMEA 0183 text (an iterable of lines, bytes or str) into fixes of one receiver.

    GGA and RMC of the same epoch are merged (GGA position and quality win; RMC supplies
    the date). Skips are counted per class (module docstring). Times are UTC seconds.
    """
    skipped = _zero_skips()
    talkers: dict[str, int] = {}
    # raw epochs: (day_index_or_date, tod) -> record
    records: list[dict] = []
    for raw in lines:
        if isinstance(raw, bytes):
            text = raw.decode("latin-1")
        else:
            text = raw
        text = text.rstrip("\r\n")
        # some captures store the line end as the literal characters "\r\n"
        while text.endswith(("\\r\\n", "\\n", "\\r")):
            text = text[: text.rfind("\\")]
        if text.lstrip(_WS).startswith("#"):
            skipped["comment_lines"] += 1
            continue
        if not text.strip(_WS):
            continue
        pos = 0
        for mt in _SENTENCE.finditer(text):
            if mt.start() > pos:
                _count_gap(text[pos:mt.start()], skipped)
            pos = mt.end()
            sentence = mt.group(0)
            _handle_sentence(sentence, skipped, talkers, records)
        if pos < len(text):
            _count_gap(text[pos:], skipped)
    # dates: continuous log time c = tod + 86400 * (midnight rollovers so far); each RMC date
    # fixes the offset abs - c, which holds until the next RMC (records before the first
    # RMC take the first RMC's offset and are counted as no_date)
    date_known = any(r["date"] is not None for r in records)
    base = datetime(1970, 1, 1, tzinfo=UTC)
    cont = np.empty(len(records))
    rollovers = 0
    last_tod: float | None = None
    for i, r in enumerate(records):
        if last_tod is not None and r["tod"] < last_tod - _DAY / 2:
            rollovers += 1
        last_tod = r["tod"]
        cont[i] = r["tod"] + rollovers * _DAY
    offset = 0.0
    if date_known:
        i0 = next(i for i, r in enumerate(records) if r["date"] is not None)
        d0 = records[i0]["date"]
        offset = (datetime.combine(d0, dtime(0), tzinfo=UTC) - base).total_seconds() \
            + records[i0]["tod"] - cont[i0]
        skipped["no_date"] = sum(1 for r in records[:i0] if r["date"] is None)
    t_list, lat_l, lon_l, q_l = [], [], [], []
    for i, r in enumerate(records):
        if r["date"] is not None:
            offset = (datetime.combine(r["date"], dtime(0), tzinfo=UTC) - base).total_seconds() \
                + r["tod"] - cont[i]
        t_list.append(cont[i] + offset)
        lat_l.append(r["lat"])
        lon_l.append(r["lon"])
        q_l.append(r["quality"])
    t = np.array(t_list, dtype=float)
    lat = np.array(lat_l, dtype=float)
    lon = np.array(lon_l, dtype=float)
    q = np.array(q_l, dtype=np.int64)
    types = [r["type"] for r in records]
    t, lat, lon, q = _merge_epochs(t, lat, lon, q, types, skipped)
    return LogFixes(name=name, t_utc=t, lat=lat, lon=lon, quality=q, date_known=date_known,
                    skipped=skipped, meta={"talkers": talkers})


def _count_gap(gap: str, skipped: dict) -> None:
    """Classify text outside valid sentences: a '$' fragment is truncated, else binary."""
    if not gap.strip(_WS):
        return
    parts = gap.split("$")
    head = parts[0].strip(_WS)
    if head:
        # printable text without '$' is the tail of a cut-off sentence; else binary bytes
        printable = re.fullmatch(r"[\x20-\x7e]*", head) is not None
        skipped["truncated" if printable and "," in head else "binary_segments"] += 1
    for frag in parts[1:]:
        if not frag.strip(_WS):
            continue
        # a fragment with a checksum field is a sentence whose checksum did not match the
        # regex (non-printable bytes inside) -> binary noise within a sentence
        if re.fullmatch(r"[A-Z0-9]{2,5},[\x20-\x7e]*", frag.rstrip(_WS)):
            skipped["truncated"] += 1
        else:
            skipped["binary_segments"] += 1


def _handle_sentence(sentence: str, skipped: dict, talkers: dict, records: list[dict]) -> None:
    head = sentence[1:sentence.index(",")]
    stype = head[-3:]
    try:
        msg = pynmea2.parse(sentence, check=True)
    except pynmea2.ChecksumError:
        skipped["bad_checksum"] += 1
        return
    except pynmea2.SentenceTypeError:
        skipped["other_sentences"] += 1
        return
    except (pynmea2.ParseError, ValueError, TypeError, IndexError):
        skipped["parse_error"] += 1
        return
    if stype not in _FIX_TYPES or len(head) != 5:
        skipped["other_sentences"] += 1
        return
    talkers[head[:2]] = talkers.get(head[:2], 0) + 1
    try:
        tod = _tod(msg.timestamp)
    except (ValueError, TypeError, AttributeError):
        tod = None
    if tod is None:
        # an empty time field is what receivers without a fix send (e.g. $GPGGA,,,,,,0,...)
        empty = not (msg.data[0] if msg.data else "").strip()
        no_fix = (stype == "GGA" and str(msg.gps_qual).strip() in ("", "0")) or \
            (stype == "RMC" and (msg.status or "").strip() != "A")
        skipped["no_fix" if (empty and no_fix) else "bad_fields"] += 1
        return
    rec_date = None
    if stype == "GGA":
        try:
            quality = int(msg.gps_qual) if str(msg.gps_qual).strip() != "" else 0
        except (ValueError, TypeError):
            skipped["bad_fields"] += 1
            return
        has_fix = quality > 0
    else:
        status = (msg.status or "").strip()
        has_fix = status == "A"
        quality = 1 if has_fix else 0
        try:
            ds = msg.datestamp
        except (ValueError, TypeError):
            ds = None
        if isinstance(ds, date):
            rec_date = ds
        elif (msg.data[8] if len(msg.data) > 8 else "").strip():
            skipped["bad_fields"] += 1
            return
    lat = lon = math.nan
    if not has_fix:
        skipped["no_fix"] += 1
    elif not (msg.lat.strip() and msg.lon.strip()):
        skipped["empty_position"] += 1
        quality = 0
    else:
        la = _coord(msg.lat, msg.lat_dir, True)
        lo = _coord(msg.lon, msg.lon_dir, False)
        if la is None or lo is None or (la == 0.0 and lo == 0.0):
            skipped["bad_fields"] += 1
            return
        lat, lon = la, lo
    records.append({"tod": tod, "date": rec_date, "lat": lat, "lon": lon, "quality": quality,
                    "type": head})


def _merge_epochs(t: np.ndarray, lat: np.ndarray, lon: np.ndarray, q: np.ndarray,
                  types: list[str], skipped: dict) -> tuple[np.ndarray, ...]:
    """Merge records of the same epoch (GGA + RMC), drop out-of-order ones (counted)."""
    if t.size == 0:
        return t, lat, lon, q
    keep_t, keep_lat, keep_lon, keep_q = [], [], [], []
    # records arrive grouped by epoch; a new epoch starts when the time changes
    i = 0
    k = t.size
    last = -math.inf
    seen_epochs: set[float] = set()
    while i < k:
        j = i
        while j + 1 < k and abs(t[j + 1] - t[i]) < 1e-6:
            j += 1
        ti = t[i]
        group = slice(i, j + 1)
        valid = np.isfinite(lat[group])
        if ti < last - 1e-6:
            skipped["time_reversals"] += 1
        elif round(ti, 6) in seen_epochs:
            skipped["duplicate_epochs"] += 1
        else:
            # a second GGA (or RMC) of the same talker in one epoch group is a repeat
            # (GPGGA + GLGGA + GNGGA of one epoch, as SiRFstarV sends, are not)
            skipped["duplicate_epochs"] += (j - i + 1) - len(set(types[i:j + 1]))
            seen_epochs.add(round(ti, 6))
            if valid.any():
                first = i + int(np.argmax(valid))   # log order: GGA usually first; prefer GGA
                gq = q[group]
                la, lo, qq = lat[first], lon[first], int(gq[valid].max())
            else:
                la = lo = math.nan
                qq = 0
            keep_t.append(ti)
            keep_lat.append(la)
            keep_lon.append(lo)
            keep_q.append(qq)
            last = ti
        i = j + 1
    return (np.array(keep_t), np.array(keep_lat), np.array(keep_lon),
            np.array(keep_q, dtype=np.int64))


def read_nmea(path: str | Path, name: str | None = None) -> LogFixes:
    """Read an NMEA log file (binary bytes tolerated). ``name`` defaults to the file stem."""
    path = Path(path)
    with open(path, "rb") as fh:
        data = fh.read()
    lines = re.split(rb"\r\n|\n|\r", data)
    fixes = parse_nmea(lines, name=name or path.stem)
    fixes.meta.update({"path": str(path), "format": "nmea"})
    return fixes


def read_tumbleweed_csv(path: str | Path, name: str | None = None) -> LogFixes:
    """Read a com-diag-hazer tumbleweed CSV (``benchmark.csv``); columns in the module docstring.

    Rows with unparseable numbers count as ``bad_fields``; repeated TIME values (the same fix
    logged twice) count as ``duplicate_epochs`` (first kept); backward TIME steps as
    ``time_reversals``.
    """
    import pandas as pd

    path = Path(path)
    df = pd.read_csv(path, skipinitialspace=True)
    df.columns = [c.strip().upper() for c in df.columns]
    need = ("TIME", "LATITUDE", "LONGITUDE")
    for c in need:
        if c not in df.columns:
            raise ValueError(f"{path}: column {c!r} missing; found {list(df.columns)}")
    skipped = _zero_skips()
    t = pd.to_numeric(df["TIME"], errors="coerce").to_numpy(dtype=float)
    lat = pd.to_numeric(df["LATITUDE"], errors="coerce").to_numpy(dtype=float)
    lon = pd.to_numeric(df["LONGITUDE"], errors="coerce").to_numpy(dtype=float)
    clock = (pd.to_numeric(df["CLOCK"], errors="coerce").to_numpy(dtype=float)
             if "CLOCK" in df.columns else np.full(t.shape, np.nan))
    ok = np.isfinite(t) & np.isfinite(lat) & np.isfinite(lon) & (np.abs(lat) <= 90) & (np.abs(lon) <= 180)
    skipped["bad_fields"] = int((~ok).sum())
    t, lat, lon, clock = t[ok], lat[ok], lon[ok], clock[ok]
    stale = 0
    if np.all(np.isfinite(clock)) and clock.size > 1:
        # In these logs TIME repeats the previous second in about a quarter of the rows while
        # the position has changed (a new fix), and CLOCK (host time at output) advances
        # evenly. Epoch = CLOCK - median(CLOCK - TIME), rounded to 1 ms; rows whose TIME is
        # more than 0.5 s off that epoch are counted in meta["stale_time_rows"].
        latency = float(np.median(clock - t))
        epoch = np.round(clock - latency, 3)
        stale = int((np.abs(epoch - t) > 0.5).sum())
        t = epoch
    q = np.ones(t.size, dtype=np.int64)
    keep = np.ones(t.size, dtype=bool)
    last = -math.inf
    seen: set[float] = set()
    for i, ti in enumerate(t):
        key = round(float(ti), 6)
        if ti < last - 1e-6:
            skipped["time_reversals"] += 1
            keep[i] = False
        elif key in seen:
            skipped["duplicate_epochs"] += 1
            keep[i] = False
        else:
            seen.add(key)
            last = ti
    host = str(df["HOSTNAME"].iloc[0]).strip('" ') if "HOSTNAME" in df.columns and len(df) else ""
    return LogFixes(name=name or f"{path.parent.name}_{path.stem}", t_utc=t[keep], lat=lat[keep],
                    lon=lon[keep], quality=q[keep], date_known=True, skipped=skipped,
                    meta={"path": str(path), "format": "tumbleweed_csv", "hostname": host,
                          "stale_time_rows": stale})


def read_log(path: str | Path, name: str | None = None) -> LogFixes:
    """Read one receiver log: ``.csv`` as tumbleweed CSV, anything else as NMEA."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"path: no such file {str(path)!r}")
    if path.suffix.lower() == ".csv":
        return read_tumbleweed_csv(path, name)
    return read_nmea(path, name)


def utm_epsg(lat: float, lon: float) -> int:
    """EPSG code of the WGS 84 / UTM zone containing (lat, lon) degrees.

    Standard 6-degree zones, with the Norway (32V) and Svalbard (31X-37X) exceptions.
    """
    if not (-80.0 <= lat <= 84.0):
        raise ValueError(f"lat: {lat!r} is outside UTM coverage (-80..84 degrees); use UPS")
    lon = ((lon + 180.0) % 360.0) - 180.0
    zone = int((lon + 180.0) // 6.0) + 1
    zone = min(zone, 60)
    if 56.0 <= lat < 64.0 and 3.0 <= lon < 12.0:
        zone = 32
    if 72.0 <= lat <= 84.0 and lon >= 0.0:
        if lon < 9.0:
            zone = 31
        elif lon < 21.0:
            zone = 33
        elif lon < 33.0:
            zone = 35
        elif lon < 42.0:
            zone = 37
    return (32600 if lat >= 0 else 32700) + zone


def _project(lat: np.ndarray, lon: np.ndarray, epsg: int) -> tuple[np.ndarray, np.ndarray]:
    from pyproj import Transformer

    tr = Transformer.from_crs("EPSG:4326", f"EPSG:{epsg}", always_xy=True)
    e, nn = tr.transform(lon, lat)
    return np.asarray(e, dtype=float), np.asarray(nn, dtype=float)


def _anchor(t_valid: np.ndarray, t_first: float, dt: float) -> float:
    """Grid origin: the first grid point at or before ``t_first`` whose phase (time modulo
    dt) is the circular mean phase of the valid fixes, so fixes land on grid points."""
    ang = 2.0 * np.pi * np.mod(t_valid, dt) / dt
    phase = float(np.mod(np.arctan2(np.sin(ang).mean(), np.cos(ang).mean()), 2 * np.pi)) * dt / (2 * np.pi)
    return math.floor((t_first - phase) / dt + 0.25) * dt + phase


def session_from_fixes(
    logs: Sequence[LogFixes],
    *,
    rate_hz: float | None = None,
    alignment: Literal["auto", "utc", "independent"] = "auto",
    origin: Literal["auto", "common", "per_receiver"] = "auto",
) -> StationarySession:
    """Grid one or several receivers' fixes into a StationarySession.

    Grid: interval ``1/rate_hz`` (default: the median interval between valid fixes of the
    logs); fixes are snapped to the nearest grid point when within a quarter interval, else
    counted ``off_grid``; grid points without a fix are NaN (missing epochs).

    Alignment: ``"utc"`` puts all logs on one UTC grid (t = 0 at the earliest fix);
    ``"independent"`` starts every log at t = 0 (recorded at different times: replay then
    treats them as simultaneous antennas, which keeps each receiver's own error character
    but not the common-mode part). ``"auto"`` picks "utc" when all dated logs share a time
    interval at least half as long as the shortest log (undated logs, without RMC, align on
    time of day with each other), else "independent".
    Origin ``"auto"``: common for "utc", per receiver for "independent".
    """
    if not logs:
        raise ValueError("logs: need at least one receiver log")
    names = [lg.name for lg in logs]
    if len(set(names)) != len(names):
        raise ValueError(f"logs: duplicate receiver names {names!r}; pass distinct names")
    for lg in logs:
        if not lg.valid.any():
            raise ValueError(f"log {lg.name!r}: no valid fix ({lg.meta.get('path', '')}); "
                             f"skipped counts {lg.skipped}")
    # interval
    if rate_hz is None:
        dts = np.concatenate([np.diff(lg.t_utc[lg.valid]) for lg in logs])
        dts = dts[dts > 1e-6]
        if dts.size == 0:
            raise ValueError("logs: fewer than two valid fixes; cannot infer the sample rate (pass rate_hz)")
        dt = float(np.median(dts))
    else:
        if not (rate_hz > 0 and math.isfinite(rate_hz)):
            raise ValueError(f"rate_hz: must be a positive number, got {rate_hz!r}")
        dt = 1.0 / float(rate_hz)
    # alignment
    starts = np.array([lg.t_utc[lg.valid][0] for lg in logs])
    stops = np.array([lg.t_utc[lg.valid][-1] for lg in logs])
    overlap = float(stops.min() - starts.max())
    shortest = float((stops - starts).min())
    # undated logs (no RMC) count from day 0: they align on time of day with each other,
    # never with dated logs
    same_dating = len({lg.date_known for lg in logs}) == 1
    if alignment == "auto":
        alignment = "utc" if (len(logs) == 1 or (same_dating and overlap >= 0.5 * shortest)) \
            else "independent"
    if alignment not in ("utc", "independent"):
        raise ValueError(f"alignment: must be 'auto', 'utc' or 'independent', got {alignment!r}")
    if origin == "auto":
        origin = "common" if alignment == "utc" else "per_receiver"
    if origin not in ("common", "per_receiver"):
        raise ValueError(f"origin: must be 'auto', 'common' or 'per_receiver', got {origin!r}")
    # time offsets per log: anchor every log to a grid
    if alignment == "utc":
        t0 = _anchor(np.concatenate([lg.t_utc[lg.valid] for lg in logs]),
                     float(min(lg.t_utc[0] for lg in logs)), dt)
        offs = [t0] * len(logs)
    else:
        offs = [_anchor(lg.t_utc[lg.valid], float(lg.t_utc[0]), dt) for lg in logs]
    idx_per_log, keep_per_log = [], []
    n = 0
    skipped_tot = _zero_skips()
    receivers = []
    for lg, off in zip(logs, offs):
        u = (lg.t_utc - off) / dt
        k = np.rint(u).astype(np.int64)
        on_grid = np.abs(u - k) <= 0.25
        sk = dict(lg.skipped)
        sk["off_grid"] = sk.get("off_grid", 0) + int((~on_grid & lg.valid).sum())
        # two fixes snapped to one grid point: keep the first, count it
        kk = k[on_grid]
        _, first_idx = np.unique(kk, return_index=True)
        dup = kk.size - first_idx.size
        sk["duplicate_epochs"] = sk.get("duplicate_epochs", 0) + int(dup)
        sel = np.flatnonzero(on_grid)[np.sort(first_idx)]
        idx_per_log.append(k[sel])
        keep_per_log.append(sel)
        n = max(n, int(k[sel].max()) + 1 if sel.size else 0)
        for c, v in sk.items():
            skipped_tot[c] = skipped_tot.get(c, 0) + v
        receivers.append({"name": lg.name, "skipped": sk, "date_known": lg.date_known,
                          "fixes": int(lg.valid.sum()), "epochs": int(lg.t_utc.size),
                          "t_first_utc": float(lg.t_utc[0]), "t_last_utc": float(lg.t_utc[-1]),
                          **{k2: v2 for k2, v2 in lg.meta.items() if k2 in ("path", "format", "talkers", "hostname", "stale_time_rows")}})
    m = len(logs)
    lat = np.full((n, m), np.nan)
    lon = np.full((n, m), np.nan)
    for j, (lg, gi, sel) in enumerate(zip(logs, idx_per_log, keep_per_log)):
        lat[gi, j] = lg.lat[sel]
        lon[gi, j] = lg.lon[sel]
    obs = np.full((n, m, 2), np.nan)
    frame: dict = {"axes": "x = UTM easting - origin, y = UTM northing - origin (grid north), metres",
                   "origin_mode": origin}
    valid = np.isfinite(lat)
    if origin == "common":
        epsg = utm_epsg(float(np.nanmean(lat)), float(np.nanmean(lon)))
        e, nn = _project(np.where(valid, lat, 0.0), np.where(valid, lon, 0.0), epsg)
        e0, n0 = float(np.mean(e[valid])), float(np.mean(nn[valid]))
        obs[..., 0] = np.where(valid, e - e0, np.nan)
        obs[..., 1] = np.where(valid, nn - n0, np.nan)
        frame.update({"epsg": epsg, "origin_easting_m": e0, "origin_northing_m": n0})
        for r in receivers:
            r.update({"epsg": epsg})
    else:
        for j in range(m):
            v = valid[:, j]
            epsg = utm_epsg(float(np.mean(lat[v, j])), float(np.mean(lon[v, j])))
            e, nn = _project(lat[v, j], lon[v, j], epsg)
            e0, n0 = float(e.mean()), float(nn.mean())
            obs[v, j, 0] = e - e0
            obs[v, j, 1] = nn - n0
            receivers[j].update({"epsg": epsg, "origin_easting_m": e0, "origin_northing_m": n0})
    t = np.arange(n) * dt
    meta = {
        "source": "tumbleweed_csv" if all(r.get("format") == "tumbleweed_csv" for r in receivers) else "nmea",
        "alignment": alignment,
        "t0_utc": offs[0] if alignment == "utc" else None,
        "rate_hz": 1.0 / dt,
        "frame": frame,
        "receivers": receivers,
        "skipped": skipped_tot,
        "power_failure_s": None,
    }
    for r in receivers:
        pts = obs[:, receivers.index(r)]
        ok = ~np.isnan(pts[:, 0])
        r["std_east_m"] = float(np.std(pts[ok, 0])) if ok.sum() > 1 else None
        r["std_north_m"] = float(np.std(pts[ok, 1])) if ok.sum() > 1 else None
        r["missing_fraction"] = float(1.0 - ok.mean())
    return StationarySession(t=t, obs=obs, names=tuple(names), truth_positions=None, meta=meta)


def import_session(paths: Sequence[str | Path] | str | Path, *, names: Sequence[str] | None = None,
                   rate_hz: float | None = None,
                   alignment: Literal["auto", "utc", "independent"] = "auto",
                   origin: Literal["auto", "common", "per_receiver"] = "auto") -> StationarySession:
    """Read one log or several (one per receiver) and grid them into one session.

    ``.csv`` files are tumbleweed CSV, others NMEA. Receiver names default to the file stems
    (made unique with the parent folder when stems repeat, e.g. ``20200519B_benchmark``).
    See :func:`session_from_fixes` for the grid, alignment and frame.
    """
    if isinstance(paths, (str, Path)):
        paths = [paths]
    paths = [Path(p) for p in paths]
    if names is not None and len(names) != len(paths):
        raise ValueError(f"names: {len(names)} names for {len(paths)} logs")
    if names is None:
        stems = [p.stem for p in paths]
        names = [f"{p.parent.name}_{p.stem}" if stems.count(p.stem) > 1 else p.stem for p in paths]
    logs = [read_log(p, nm) for p, nm in zip(paths, names)]
    return session_from_fixes(logs, rate_hz=rate_hz, alignment=alignment, origin=origin)
