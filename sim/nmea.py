"""Import real GNSS logs (NMEA 0183, tumbleweed CSV) into a :class:`sim.gps.StationarySession`.

NMEA: GGA and RMC sentences from any talker (``$GP``, ``$GN``, ``$GL``, ``$GA``, ``$GB``,
...) are read field by field with strict number formats (a coordinate is unsigned
``ddmm.mmmm``; ``nan``, ``inf``, exponents, signs and out-of-range values are malformed);
other sentence types are classified with pynmea2. Everything that is not a kept fix is
counted, never silently dropped; the counts per class are in ``LogFixes.skipped`` and, summed
over receivers, in the session's ``meta["skipped"]``. Classes (dropped unless marked kept):

- ``long_lines``: lines longer than :data:`MAX_LINE_CHARS` (1 MiB), not read: no log holds
  such lines (a sentence has at most 82 characters). Parsing is linear in the input
  (sentences are found by a regular expression that never rescans), so even a line just
  below the bound parses in milliseconds and Ctrl-C interrupts between lines and sentences.
- ``comment_lines``: lines starting with ``#`` (gpsd regression-log headers).
- ``host_prefixes`` (kept): lines that start with the logging host's timestamp, e.g.
  ``2017-05-25T16:04:28 -->> $GNGGA,...`` (ISO 8601 date and time, optional fraction, ``Z``
  or ``+hh:mm`` zone, optional ``[ ]``, then separators); the sentence after it is read.
- ``timestamp_lines`` (kept): lines holding only such a timestamp; it times the sentences
  that follow. A timestamp without a zone is taken as UTC (``meta["host_time"]``).
- ``binary_segments``: runs of non-NMEA bytes (UBX/RTCM binary, line noise) before, between
  or instead of sentences.
- ``truncated``: a ``$`` fragment without a ``*hh`` checksum terminator before the next
  ``$`` (cut-off lines; ``$`` and ``*`` are reserved in NMEA 0183 and never inside a
  sentence, so a complete sentence after a cut-off one on the same line is still read; a
  sentence whose checksum cannot be verified is not trusted).
- ``bad_checksum``: checksum present but wrong.
- ``parse_error``: checksum fine but pynmea2 cannot parse a sentence of another type.
- ``bad_fields``: a GGA/RMC with a malformed or out-of-range time, date, coordinate,
  hemisphere, fix quality, altitude or geoid separation, or the position 0,0.
- ``no_fix`` (kept as a missing epoch when timed): a GGA with fix quality 0 or an RMC with
  status ``V``. Untimed ones (``$GPGGA,,,,,,0,...``, what many receivers send before a fix)
  cannot be placed and are also counted in ``meta["untimed_sentences"]``.
- ``empty_position`` (kept as a missing epoch): a GGA/RMC that claims a fix but has empty
  latitude/longitude fields.
- ``no_date`` (kept): GGA sentences of epochs without an RMC dated from a later RMC (the
  nearer one in time; e.g. before the first RMC of the log).
- ``implausible_date``: epochs dated before 1983 or after tomorrow (receiver default dates
  such as ``050180`` / ``100180``), see :mod:`sim.log_timeline`.
- ``time_jump``: epochs separated from the log's main era by more than ``max_span_s``
  (a step of years).
- ``week_rollover`` (kept, corrected): epochs shifted by k x 1024 weeks (GPS week-number
  rollover bug).
- ``duplicate_epochs``: a second fix for an epoch already seen (GGA and RMC of the same
  time are merged: the GGA position wins; only genuine repeats count here).
- ``time_reversals``: a single epoch out of time order (dropped).
- ``reversed_segments``: epochs of a run of two or more out of time order (a whole segment
  whose time went back, e.g. after a restart).
- ``no_host_time``: with ``time_base="host"``, epochs without a plausible host timestamp.
- ``reacquisition`` (kept in ``LogFixes``, flagged in ``reacquired``; dropped from sessions by
  default): fixes of a reacquisition transient, see :func:`flag_reacquisitions`.
- ``off_grid``: fixes that do not fall within a quarter interval of the session's sample
  grid (e.g. 5 Hz fixes when a 1 Hz grid was asked for; session level).
- ``other_sentences``: valid sentences of other types (GSA, GSV, VTG, TXT, proprietary);
  not errors, reported for completeness.

Accounting: every checksum-valid GGA/RMC sentence (``meta["fix_sentences"]``) ends in exactly
one of: an epoch of the output (``len(t_utc)``), ``meta["merged_sentences"]`` (another sentence
of an epoch already counted, e.g. the RMC beside the GGA), ``meta["untimed_sentences"]``, or
one of ``bad_fields``, ``duplicate_epochs``, ``time_reversals``, ``reversed_segments``,
``implausible_date``, ``time_jump``, ``no_host_time`` (:data:`DROP_CLASSES`).

Time base (``time_base=``, details in :mod:`sim.log_timeline`): ``"auto"`` (default) uses the
receiver's RMC dates when a fix carries a plausible date; else the host timestamps of the
log, when present and plausible, supply the date and the receiver its time of day; else the
time of day counts from day 0 (1970-01-01, ``date_known = False``, as for a log without
RMC). ``"receiver"`` never uses host time, ``"host"`` takes the host timestamps as the epoch
times (1 s resolution on many loggers; the receiver's time only groups sentences).
Implausible dates, steps of years, repeated and out-of-order epochs are removed so that
only plausible times remain; a cold restart in the middle of a log therefore leaves two
segments on one time line, joined when their dates are consistent. A midnight without an
RMC date (time of day back by more than 12 h) advances the date by one day.

Reacquisition: after a gap (no fix for longer than 1.5 fix intervals, or no-fix epochs) a
receiver's first fixes can be hundreds of metres off (and fractional-second times, which the
grid handles as ``off_grid`` when they miss a grid point by more than a quarter interval).
:func:`flag_reacquisitions` flags them; sessions drop them by default.

Frame: latitude/longitude (WGS 84) are projected with pyproj to UTM; the zone is chosen
from the mean fix of the data (the circular mean of the longitudes, :func:`mean_longitude`,
so fixes astride the antimeridian get the zone of 180 degrees; with the Norway/Svalbard
exceptions), EPSG 326zz north /
327zz south. The local frame is x = UTM easting - origin, y = UTM northing - origin
(grid north, as the dissertation's UTM plots; it differs from true north by the meridian
convergence, under 3 degrees within a zone at mid latitudes). The origin is the mean of all
valid fixes (``origin="common"``, used when receivers are co-located / time-aligned) or each
receiver's own mean (``origin="per_receiver"``, used for independent series recorded at
different places), recorded in ``meta["frame"]``. Heights (``LogFixes.height_m``) are metres
above the WGS 84 ellipsoid: GGA altitude (above mean sea level) + geoid separation, NaN when
either field is empty.

Tumbleweed CSV (com-diag-hazer ``benchmark.csv`` / ``mobile.csv``): columns HOSTNAME,
OBSERVATION, CLOCK, TIME, LATITUDE, LONGITUDE, HORIZONTAL, MSL, WGS84, VERTICAL, SPEED,
COURSE; TIME is the fix time in UTC seconds since 1970, LATITUDE/LONGITUDE decimal degrees,
WGS84 the height above the ellipsoid in metres.

Memory is bounded: a session grid longer than ``max_span_s`` (default 7 days) or faster than
``max_rate_hz`` (default 100 Hz) raises a ValueError naming the logs and their time span
before anything is allocated.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from datetime import UTC, date, datetime, timedelta, timezone
from pathlib import Path
from typing import Literal

import numpy as np
import pynmea2

from estimator._checks import check_array, check_int, check_real
from sim.gps import StationarySession
from sim.log_timeline import (
    DAY_S,
    FATES,
    MAX_SPAN_S,
    absolute_times,
    assemble_times,
    plausible_bounds,
    resolve_times,
    span_text,
)

__all__ = [
    "DROP_CLASSES",
    "MAX_LINE_CHARS",
    "MAX_RATE_HZ",
    "MAX_SPAN_S",
    "REACQ_FLOOR_M",
    "REACQ_LOOKAHEAD",
    "REACQ_SIGMAS",
    "SKIP_CLASSES",
    "LogFixes",
    "find_logs",
    "flag_reacquisitions",
    "import_session",
    "log_format",
    "mean_longitude",
    "parse_nmea",
    "plausible_fix",
    "read_log",
    "read_nmea",
    "read_tumbleweed_csv",
    "session_from_fixes",
    "utm_epsg",
]

SKIP_CLASSES = (
    "long_lines", "comment_lines", "host_prefixes", "timestamp_lines", "binary_segments",
    "truncated",
    "bad_checksum", "parse_error", "bad_fields", "no_fix", "empty_position", "no_date",
    "implausible_date", "time_jump", "week_rollover", "duplicate_epochs", "time_reversals",
    "reversed_segments", "no_host_time", "reacquisition", "off_grid", "other_sentences",
)
#: Classes that drop a GGA/RMC epoch or sentence (the accounting identity, module docstring).
DROP_CLASSES = ("bad_fields", "duplicate_epochs", "time_reversals", "reversed_segments",
                "implausible_date", "time_jump", "no_host_time")

#: Fastest grid a session may have: GNSS receivers output at most 20-100 Hz.
MAX_RATE_HZ = 100.0
#: A fix after a gap is a reacquisition transient when it lies farther than
#: max(REACQ_SIGMAS x the log's robust horizontal spread, REACQ_FLOOR_M) from the median
#: of the next REACQ_LOOKAHEAD fixes (see flag_reacquisitions for the reasoning).
REACQ_SIGMAS = 5.0
REACQ_FLOOR_M = 1.0
REACQ_LOOKAHEAD = 5

# A sentence: "$", talker + type, ",", printable fields without the reserved "$" and "*"
# (NMEA 0183), "*hh". Excluding "$" / "*" from the fields and matching them possessively
# makes every match attempt stop at the next "$": a line is scanned in linear time (the
# former lazy "[\x20-\x7e]*?" rescanned the rest of the line from every "$" fragment).
_SENTENCE = re.compile(r"\$([A-Z0-9]{2,5}),[\x20-\x23\x25-\x29\x2b-\x7e]*+\*[0-9A-Fa-f]{2}")
_SENTENCE_B = re.compile(rb"\$[A-Z][A-Z0-9]{1,4},[\x20-\x23\x25-\x29\x2b-\x7e]*+\*[0-9A-Fa-f]{2}")
#: Lines longer than this (characters, after decoding) are skipped and counted as
#: ``long_lines``: a sentence has at most 82 characters and a line of a real log a host
#: timestamp and a few sentences, or the bytes of a binary message between two newline
#: bytes (0x0a comes every 256 bytes on average in binary data); the bound keeps the work
#: and memory of one line small.
MAX_LINE_CHARS = 1 << 20
_LITERAL_ENDS = ("\\r\\n", "\\n", "\\r")
_FIX_TYPES = {"GGA", "RMC"}
_WS = " \t\r\n\x0b\x0c"   # ASCII whitespace only: latin-1 bytes such as 0x85 or 0xa0 are binary
_HOST_TS = re.compile(
    r"[ \t]*\[?(\d{4})-(\d{2})-(\d{2})[T ](\d{2}):(\d{2}):(\d{2})(?:[.,](\d{1,9}))?"
    r"(Z|[+-]\d{2}:?\d{2})?\]?[ \t:|>=,;\-]*", re.ASCII)
# strict field formats: unsigned ddmm.mmmm / dddmm.mmmm, hhmmss(.s), ddmmyy, one-digit
# fix quality, signed decimal metres (no exponent, no nan/inf)
_COORD = re.compile(r"\d{1,5}(?:\.\d{0,12})?", re.ASCII)
_TOD = re.compile(r"(\d{2})(\d{2})(\d{2}(?:\.\d{1,9})?)", re.ASCII)
_DATE = re.compile(r"(\d{2})(\d{2})(\d{2})", re.ASCII)
_QUAL = re.compile(r"\d", re.ASCII)
_METRES = re.compile(r"[+-]?\d{1,9}(?:\.\d{0,9})?", re.ASCII)
#: |GGA altitude| above this is malformed: COCOM limits civil receivers to 18 km; 100 km
#: keeps any platform a NMEA log can come from.
_MAX_ALTITUDE_M = 1e5
#: |geoid separation| above this is malformed: the geoid departs from the WGS 84
#: ellipsoid by -107 .. +86 m (EGM96).
_MAX_GEOID_SEP_M = 200.0


@dataclass
class LogFixes:
    """Fixes read from one log (one receiver), before gridding.

    t_utc : (k,) seconds since 1970-01-01 UTC (or since day 0 when ``date_known`` is False),
    strictly increasing; includes no-fix epochs, whose lat/lon are NaN. lat, lon : (k,)
    degrees WGS 84. quality : (k,) int, GGA fix quality (RMC-only epochs: 1 for 'A', 0 for
    'V'). skipped : counts per class (module docstring). meta : source details (time base,
    accounting, host clock, flagged reacquisitions).
    height_m : (k,) metres above the WGS 84 ellipsoid, NaN where the log has none, or None
        when the reader does not provide heights at all.
    reacquired : (k,) bool, fixes flagged as a reacquisition transient
        (:func:`flag_reacquisitions`), or None when not computed.
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
    reacquired: np.ndarray | None = None

    @property
    def valid(self) -> np.ndarray:
        """(k,) bool, epochs with a usable position."""
        return np.isfinite(self.lat) & np.isfinite(self.lon)



def plausible_fix(lat_deg: float, lon_deg: float, alt_m: float) -> bool:
    """A fix a log may hold: finite latitude and longitude in range (degrees), not the
    (0, 0) "null island" receivers report without a fix, and a height (m) that is not
    infinite (NaN means absent)."""
    return (math.isfinite(lat_deg) and math.isfinite(lon_deg) and abs(lat_deg) <= 90.0
            and abs(lon_deg) <= 180.0 and not (lat_deg == 0.0 and lon_deg == 0.0)
            and not math.isinf(alt_m))

def _zero_skips() -> dict:
    return dict.fromkeys(SKIP_CLASSES, 0)


# --------------------------------------------------------------------------- fields
def _tod(s: str) -> float | None:
    """hhmmss(.s) -> seconds of day, or None when malformed (hh < 24, mm < 60, ss < 60)."""
    m = _TOD.fullmatch(s)
    if not m:
        return None
    h, mi, se = int(m.group(1)), int(m.group(2)), float(m.group(3))
    if h > 23 or mi > 59 or se >= 60.0:
        return None
    return h * 3600.0 + mi * 60.0 + se


def _date(s: str) -> date | None:
    """ddmmyy -> date (yy 80-99: 19yy, 00-79: 20yy, GPS era), None when not a calendar date."""
    m = _DATE.fullmatch(s)
    if not m:
        return None
    d, mo, y = (int(g) for g in m.groups())
    try:
        return date(1900 + y if y >= 80 else 2000 + y, mo, d)
    except ValueError:
        return None


def _coord(value: str, hemi: str, is_lat: bool) -> float | None:
    """ddmm.mmmm / dddmm.mmmm + hemisphere -> signed degrees, or None when malformed."""
    if hemi not in (("N", "S") if is_lat else ("E", "W")) or not _COORD.fullmatch(value):
        return None
    v = float(value)
    deg = math.floor(v / 100.0)
    minutes = v - 100.0 * deg
    if not (0.0 <= minutes < 60.0):
        return None
    out = deg + minutes / 60.0
    if out > (90.0 if is_lat else 180.0):
        return None
    return -out if hemi in ("S", "W") else out


def _metres(s: str, bound: float) -> float | None:
    """Signed decimal metres with |v| <= bound, NaN when empty, None when malformed."""
    if not s:
        return math.nan
    if not _METRES.fullmatch(s):
        return None
    v = float(s)
    return v if abs(v) <= bound else None


def _checksum_ok(sentence: str) -> bool:
    body, cs = sentence[1:-3], sentence[-2:]
    x = 0
    for ch in body.encode("latin-1"):
        x ^= ch
    return x == int(cs, 16)


def _host_seconds(m: re.Match) -> float | None:
    """UTC seconds of a host timestamp match, None when not a valid date-time."""
    y, mo, d, h, mi, se, frac, tz = m.groups()
    try:
        tzinfo = UTC
        if tz and tz != "Z":
            sign = 1 if tz[0] == "+" else -1
            hh, mm = int(tz[1:3]), int(tz[-2:])
            tzinfo = timezone(sign * timedelta(hours=hh, minutes=mm))
        dt = datetime(int(y), int(mo), int(d), int(h), int(mi), int(se), tzinfo=tzinfo)
        return dt.timestamp() + (float("0." + frac) if frac else 0.0)
    except (ValueError, OverflowError):
        return None


# --------------------------------------------------------------------------- NMEA
def parse_nmea(lines: Iterable[bytes | str], name: str = "receiver", *,
               time_base: Literal["auto", "receiver", "host"] = "auto",
               max_span_s: float = MAX_SPAN_S, latest_date: date | None = None) -> LogFixes:
    """Parse NMEA 0183 text (an iterable of lines, bytes or str) into fixes of one receiver.

    GGA and RMC of the same epoch are merged (GGA position, height and quality win; RMC
    supplies the date). Skips are counted per class, times put on one plausible time line
    (module docstring; :mod:`sim.log_timeline`), reacquisition transients flagged.
    time_base : "auto" | "receiver" | "host"; max_span_s : longest time line (s) before a
    step counts as ``time_jump``; latest_date : latest plausible date (default: tomorrow,
    UTC). Never raises on malformed input: every sentence is counted.
    """
    if time_base not in ("auto", "receiver", "host"):
        raise ValueError(f"time_base: must be 'auto', 'receiver' or 'host', got {time_base!r}")
    max_span_s = check_real(max_span_s, "max_span_s", lo=0.0, lo_open=True)
    if latest_date is not None and not isinstance(latest_date, date):
        raise TypeError(f"latest_date: must be a datetime.date or None, got {latest_date!r}")
    if isinstance(lines, (str, bytes)):
        raise TypeError("lines: expected an iterable of lines (bytes or str), got one "
                        f"{type(lines).__name__}; split it first (e.g. text.splitlines())")
    skipped = _zero_skips()
    acct = {"fix_sentences": 0, "untimed_sentences": 0}
    talkers: dict[str, int] = {}
    records: list[dict] = []
    host_now = math.nan
    host_naive = False
    for raw in lines:
        if not isinstance(raw, (bytes, str)):
            raise TypeError(f"lines: each line must be bytes or str, got {type(raw).__name__}")
        if len(raw) > MAX_LINE_CHARS:
            skipped["long_lines"] += 1
            continue
        text = _line_text(raw)
        if text.lstrip(_WS).startswith("#"):
            skipped["comment_lines"] += 1
            continue
        if not text.strip(_WS):
            continue
        mh = _HOST_TS.match(text)
        if mh is not None and (hs := _host_seconds(mh)) is not None:
            host_now = hs
            host_naive = host_naive or mh.group(8) is None
            text = text[mh.end():]
            if not text.strip(_WS):
                skipped["timestamp_lines"] += 1
                continue
            skipped["host_prefixes"] += 1
        pos = 0
        for mt in _SENTENCE.finditer(text):
            if mt.start() > pos:
                _count_gap(text[pos:mt.start()], skipped)
            pos = mt.end()
            _handle_sentence(mt.group(0), skipped, talkers, records, host_now, acct)
        if pos < len(text):
            _count_gap(text[pos:], skipped)
    fx = _epochs(records, skipped, time_base=time_base, max_span_s=max_span_s,
                 latest_date=latest_date)
    fx.name = name
    n_host = skipped["host_prefixes"] + skipped["timestamp_lines"]
    fx.meta.update(acct)
    fx.meta.update({"talkers": talkers, "host_time": {
        "lines": n_host, "zone": ("unspecified (taken as UTC)" if host_naive else "given")
        if n_host else None}})
    return fx


def _line_text(raw: bytes | str) -> str:
    """One line as text without its line end; some captures store the line end as the
    literal characters "\\r\\n" (stripped too, in time linear in the line)."""
    text = raw.decode("latin-1") if isinstance(raw, bytes) else raw
    text = text.rstrip("\r\n")
    end = len(text)
    while text.endswith(_LITERAL_ENDS, 0, end):
        end = text.rfind("\\", 0, end)
    return text[:end]


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


def _handle_sentence(sentence: str, skipped: dict, talkers: dict, records: list[dict],
                     host: float, acct: dict) -> None:
    head = sentence[1:sentence.index(",")]
    stype = head[-3:]
    if not _checksum_ok(sentence):
        skipped["bad_checksum"] += 1
        return
    if stype not in _FIX_TYPES or len(head) != 5:
        try:
            pynmea2.parse(sentence, check=True)
        except pynmea2.SentenceTypeError:
            pass
        except Exception:  # noqa: BLE001 - a third-party parser's failure on any other type is counted
            skipped["parse_error"] += 1
            return
        skipped["other_sentences"] += 1
        return
    acct["fix_sentences"] += 1
    talkers[head[:2]] = talkers.get(head[:2], 0) + 1
    f = [x.strip() for x in sentence[7:-3].split(",")]
    f += [""] * (12 - len(f))
    gga = stype == "GGA"
    if gga:
        tod_s, lat_s, ns, lon_s, ew, qual_s = f[0], f[1], f[2], f[3], f[4], f[5]
        no_fix = qual_s in ("", "0")
    else:
        tod_s, status, lat_s, ns, lon_s, ew, date_s = f[0], f[1], f[2], f[3], f[4], f[5], f[8]
        no_fix = status != "A"
    if not tod_s:
        # an empty time field is what receivers without a fix send (e.g. $GPGGA,,,,,,0,...)
        if no_fix:
            skipped["no_fix"] += 1
            acct["untimed_sentences"] += 1
        else:
            skipped["bad_fields"] += 1
        return
    tod = _tod(tod_s)
    if tod is None:
        skipped["bad_fields"] += 1
        return
    rec_date = None
    if gga:
        if qual_s and not _QUAL.fullmatch(qual_s):
            skipped["bad_fields"] += 1
            return
        quality = int(qual_s) if qual_s else 0
    else:
        quality = 0 if no_fix else 1
        if date_s:
            rec_date = _date(date_s)
            if rec_date is None:
                skipped["bad_fields"] += 1
                return
    lat = lon = height = math.nan
    if no_fix:
        skipped["no_fix"] += 1
    elif not (lat_s and lon_s):
        skipped["empty_position"] += 1
        quality = 0
    else:
        la = _coord(lat_s, ns, True)
        lo = _coord(lon_s, ew, False)
        if la is None or lo is None or (la == 0.0 and lo == 0.0):
            skipped["bad_fields"] += 1
            return
        if gga:
            alt, sep = _metres(f[8], _MAX_ALTITUDE_M), _metres(f[10], _MAX_GEOID_SEP_M)
            if alt is None or sep is None:
                skipped["bad_fields"] += 1
                return
            height = alt + sep
        lat, lon = la, lo
    records.append({"tod": tod, "date": rec_date, "lat": lat, "lon": lon, "height": height,
                    "quality": quality, "type": head, "host": host})


def _epochs(records: list[dict], skipped: dict, *, time_base: str, max_span_s: float,
            latest_date: date | None) -> LogFixes:
    """Records (log order) -> epochs on one plausible time line, merged, counted."""
    k = len(records)
    tod = np.array([r["tod"] for r in records], dtype=float)
    # epochs: consecutive records with the same time of day (GGA + RMC of one fix)
    starts = np.r_[0, np.flatnonzero(np.abs(np.diff(tod)) >= 1e-6) + 1] if k else np.zeros(0, int)
    stops = np.r_[starts[1:], k] if k else np.zeros(0, int)
    G = starts.size
    day = np.full(G, np.nan)
    host = np.full(G, np.nan)
    fix = np.zeros(G, dtype=bool)
    merged = 0
    for g, (a, b) in enumerate(zip(starts, stops)):
        grp = records[a:b]
        d = next((r["date"] for r in grp if r["date"] is not None), None)
        if d is not None:
            day[g] = float((d - date(1970, 1, 1)).days)
        host[g] = next((r["host"] for r in grp if math.isfinite(r["host"])), math.nan)
        fix[g] = any(math.isfinite(r["lat"]) for r in grp)
        # a second GGA (or RMC) of the same talker in one epoch is a repeat
        # (GPGGA + GLGGA + GNGGA of one epoch, as SiRFstarV sends, are not)
        n_types = len({r["type"] for r in grp})
        skipped["duplicate_epochs"] += (b - a) - n_types
        merged += n_types - 1
    times = assemble_times(tod[starts] if G else tod, day, host, fix, time_base=time_base,
                           latest=latest_date)
    times = resolve_times(times, fix, host, max_span_s=max_span_s, latest=latest_date)
    for code, cls in FATES.items():
        skipped[cls] += int((times.fate == code).sum())
    keep = np.flatnonzero(times.fate == 0)
    t = times.t[keep]
    lat = np.full(keep.size, np.nan)
    lon = np.full(keep.size, np.nan)
    hgt = np.full(keep.size, np.nan)
    q = np.zeros(keep.size, dtype=np.int64)
    for i, g in enumerate(keep):
        grp = records[starts[g]:stops[g]]
        ok = [r for r in grp if math.isfinite(r["lat"])]
        if ok:
            best = next((r for r in ok if r["type"].endswith("GGA")), ok[0])
            lat[i], lon[i], hgt[i] = best["lat"], best["lon"], best["height"]
            q[i] = max(r["quality"] for r in ok)
    skipped["no_date"] = int(sum(stops[g] - starts[g] for g in keep if times.back_dated[g]))
    skipped["week_rollover"] = int(times.week_rollover[keep].sum())
    fx = LogFixes(name="receiver", t_utc=t, lat=lat, lon=lon, quality=q,
                  date_known=times.date_known, skipped=skipped, height_m=hgt,
                  meta={"time_base": times.time_base, "time_notes": times.notes,
                        "merged_sentences": merged})
    _flag(fx)
    return fx


def _flag(fx: LogFixes) -> None:
    """Set ``reacquired``, its count and the list of flagged fixes on a LogFixes."""
    flags, offset = flag_reacquisitions(fx.t_utc, fx.lat, fx.lon)
    fx.reacquired = flags
    fx.skipped["reacquisition"] = int(flags.sum())
    fx.meta["reacquisitions"] = [{"t_utc": float(fx.t_utc[i]), "offset_m": float(offset[i])}
                                 for i in np.flatnonzero(flags)]


# --------------------------------------------------------------------------- reacquisition
def flag_reacquisitions(t: np.ndarray, lat: np.ndarray, lon: np.ndarray, *,
                        sigmas: float = REACQ_SIGMAS, floor_m: float = REACQ_FLOOR_M,
                        lookahead: int = REACQ_LOOKAHEAD) -> tuple[np.ndarray, np.ndarray]:
    """Flag the fixes of reacquisition transients in one receiver's epochs.

    t : (k,) s, increasing; lat, lon : (k,) degrees, NaN = no fix. Returns ``flags (k,)``
    bool and ``offset_m (k,)`` (distance of each flagged fix from the median of the next
    ``lookahead`` fixes; NaN elsewhere).

    A fix starts an acquisition when it is the first of the log or follows a gap: no-fix
    epochs, or more than 1.5 median fix intervals without a fix. From there, each fix
    farther than ``max(sigmas * sigma_h, floor_m)`` from the median of the next
    ``lookahead`` fixes is flagged, until the first one that is not (settled); sigma_h is
    the log's horizontal robust spread, ``hypot`` of the per-axis 1.4826 x MAD of all its
    fixes (a reacquisition fix hundreds of metres off barely moves it). Reasoning: for a
    stationary receiver with normal errors of sigma per axis, a fix's distance from the
    median of 5 others has a per-axis spread of at most 1.15 sigma, and 5 sigma_h = 7.1
    sigma per axis is exceeded with probability < 1e-8; a gradual convergence after the
    first fix (metres over tens of seconds) stays within the receiver's own spread and is
    not flagged. Below ``floor_m`` = 1 m an offset is within the accuracy of any autonomous
    (non-RTK) fix. On a moving receiver the spread is that of its path, so only jumps much
    larger than the path are flagged: the rule is built for stationary logs. Distances use
    a local equirectangular approximation (relative error < 1e-3 over a few km).
    """
    t = check_array(t, "t", shape=(None,))
    k = t.size
    lat = check_array(lat, "lat", shape=(k,), allow_nan=True, max_abs=90.0)
    lon = check_array(lon, "lon", shape=(k,), allow_nan=True, max_abs=180.0)
    if k > 1 and not np.all(np.diff(t) > 0):
        raise ValueError("t: must be strictly increasing")
    sigmas = check_real(sigmas, "sigmas", lo=0.0, lo_open=True)
    floor_m = check_real(floor_m, "floor_m", lo=0.0)
    lookahead = check_int(lookahead, "lookahead", 3, 1000)
    flags = np.zeros(k, dtype=bool)
    offset = np.full(k, np.nan)
    idx = np.flatnonzero(np.isfinite(lat) & np.isfinite(lon))
    if idx.size < 4:
        return flags, offset
    la0 = math.radians(float(np.median(lat[idx])))
    lon0 = float(np.median(lon[idx]))
    r = 6371008.8                                        # mean Earth radius, m
    x = r * math.cos(la0) * np.radians(((lon[idx] - lon0 + 180.0) % 360.0) - 180.0)
    y = r * np.radians(lat[idx] - float(np.median(lat[idx])))
    dtv = np.diff(t[idx])
    gap = np.r_[True, (np.diff(idx) > 1) | (dtv > 1.5 * float(np.median(dtv)))]
    mad = 1.482602218505602
    sigma_h = math.hypot(mad * float(np.median(np.abs(x - np.median(x)))),
                         mad * float(np.median(np.abs(y - np.median(y)))))
    thr = max(sigmas * sigma_h, floor_m)
    n = idx.size
    for j in np.flatnonzero(gap):
        i = j
        while i + 3 <= n - 1 and (i == j or not gap[i]):
            nxt = slice(i + 1, min(i + 1 + lookahead, n))
            off = math.hypot(x[i] - float(np.median(x[nxt])), y[i] - float(np.median(y[nxt])))
            if off <= thr:
                break
            flags[idx[i]] = True
            offset[idx[i]] = off
            i += 1
    return flags, offset


# --------------------------------------------------------------------------- readers
def read_nmea(path: str | Path, name: str | None = None, **options) -> LogFixes:
    """Read an NMEA log file (binary bytes tolerated). ``name`` defaults to the file stem;
    keyword ``options`` pass to :func:`parse_nmea` (time_base, max_span_s, latest_date)."""
    path = Path(path)
    with open(path, "rb") as fh:
        data = fh.read()
    lines = re.split(rb"\r\n|\n|\r", data)
    fixes = parse_nmea(lines, name=name or path.stem, **options)
    fixes.meta.update({"path": str(path), "format": "nmea"})
    return fixes


def read_tumbleweed_csv(path: str | Path, name: str | None = None, *,
                        max_span_s: float = MAX_SPAN_S, latest_date: date | None = None
                        ) -> LogFixes:
    """Read a com-diag-hazer tumbleweed CSV (``benchmark.csv``); columns in the module docstring.

    Rows with unparseable or non-finite numbers count as ``bad_fields``; the rows' times go
    through the same plausibility checks as NMEA epochs (:mod:`sim.log_timeline`: implausible
    dates, steps of years, repeated TIME values as ``duplicate_epochs`` (first kept), rows out
    of order as ``time_reversals`` / ``reversed_segments``). Height: the WGS84 column.
    """
    import pandas as pd

    path = Path(path)
    df = pd.read_csv(path, skipinitialspace=True)
    df.columns = [str(c).strip().upper() for c in df.columns]
    need = ("TIME", "LATITUDE", "LONGITUDE")
    for c in need:
        if c not in df.columns:
            raise ValueError(f"{path}: column {c!r} missing; found {list(df.columns)}")
    skipped = _zero_skips()

    def col(c: str) -> np.ndarray:
        if c not in df.columns:
            return np.full(len(df), np.nan)
        return pd.to_numeric(df[c], errors="coerce").to_numpy(dtype=float)

    t, lat, lon, clock, hgt = col("TIME"), col("LATITUDE"), col("LONGITUDE"), col("CLOCK"), \
        col("WGS84")
    ok = np.isfinite(t) & np.isfinite(lat) & np.isfinite(lon) & (np.abs(lat) <= 90) \
        & (np.abs(lon) <= 180)
    skipped["bad_fields"] = int((~ok).sum())
    t, lat, lon, clock, hgt = t[ok], lat[ok], lon[ok], clock[ok], hgt[ok]
    hgt = np.where(np.abs(hgt) <= _MAX_ALTITUDE_M, hgt, np.nan)
    stale = 0
    lo, hi = plausible_bounds(latest_date)
    good = (t >= lo) & (t < hi)
    if np.all(np.isfinite(clock)) and clock.size > 1 and good.any():
        # In these logs TIME repeats the previous second in about a quarter of the rows while
        # the position has changed (a new fix), and CLOCK (host time at output) advances
        # evenly. Epoch = CLOCK - median(CLOCK - TIME) over rows with a plausible TIME,
        # rounded to 1 ms; rows whose TIME is more than 0.5 s off that epoch are counted in
        # meta["stale_time_rows"].
        latency = float(np.median(clock[good] - t[good]))
        epoch = np.round(clock - latency, 3)
        stale = int((np.abs(epoch - t) > 0.5).sum())
        t = epoch
    times = resolve_times(absolute_times(t, latest=latest_date), np.ones(t.size, dtype=bool),
                          max_span_s=max_span_s,
                          latest=latest_date)
    for code, cls in FATES.items():
        skipped[cls] += int((times.fate == code).sum())
    keep = times.fate == 0
    host = str(df["HOSTNAME"].iloc[0]).strip('" ') if "HOSTNAME" in df.columns and len(df) else ""
    fx = LogFixes(name=name or f"{path.parent.name}_{path.stem}", t_utc=times.t[keep],
                  lat=lat[keep], lon=lon[keep], quality=np.ones(int(keep.sum()), dtype=np.int64),
                  date_known=True, skipped=skipped, height_m=hgt[keep],
                  meta={"path": str(path), "format": "tumbleweed_csv", "hostname": host,
                        "stale_time_rows": stale, "time_base": "receiver",
                        "time_notes": times.notes})
    skipped["week_rollover"] = int(times.week_rollover[keep].sum())
    _flag(fx)
    return fx


def read_log(path: str | Path, name: str | None = None, **options) -> LogFixes:
    """Read one receiver log: ``.csv`` as tumbleweed CSV, anything else as NMEA. Keyword
    ``options`` pass to the reader (``max_span_s``, ``latest_date``; NMEA also ``time_base``)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"path: no such file {str(path)!r}")
    if path.suffix.lower() == ".csv":
        return read_tumbleweed_csv(path, name, **options)
    return read_nmea(path, name, **options)


def log_format(path: str | Path) -> str | None:
    """``"tumbleweed_csv"``, ``"nmea"`` or None (not a log this module reads).

    A ``.csv`` whose header names TIME, LATITUDE and LONGITUDE is tumbleweed CSV; any other
    file holding at least one complete NMEA sentence (``$`` talker+type, fields, ``*hh``) is
    NMEA. Files are scanned in 1 MiB chunks until a sentence is found.
    """
    path = Path(path)
    if path.suffix.lower() == ".csv":
        try:
            with open(path, encoding="utf-8", errors="replace") as fh:
                header = fh.readline()
        except OSError:
            return None
        cols = {c.strip().strip('"').upper() for c in header.split(",")}
        return "tumbleweed_csv" if {"TIME", "LATITUDE", "LONGITUDE"} <= cols else None
    tail = b""
    try:
        with open(path, "rb") as fh:
            while chunk := fh.read(1 << 20):
                if _SENTENCE_B.search(tail + chunk):
                    return "nmea"
                tail = chunk[-200:]
    except OSError:
        return None
    return None


def find_logs(root: str | Path) -> tuple[list[Path], list[Path]]:
    """Recursive scan of ``root``: (logs this module reads, other files), both sorted.

    See :func:`log_format` for what counts as a log. Hidden files and folders (``.git``, ...)
    are not scanned. Raises ValueError naming ``root`` when it is not a folder.
    """
    root = Path(root)
    if not root.is_dir():
        raise ValueError(f"root: not a folder: {str(root)!r}")
    logs, other = [], []
    for p in sorted(root.rglob("*")):
        if any(part.startswith(".") for part in p.relative_to(root).parts) or not p.is_file():
            continue
        (logs if log_format(p) else other).append(p)
    return logs, other


# --------------------------------------------------------------------------- frame
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


def mean_longitude(lon: np.ndarray) -> float:
    """Circular mean of longitudes, degrees in [-180, 180) (NaN ignored): the zone of fixes
    astride the antimeridian (179.9 E and 179.9 W) is that of 180, not of 0 as the
    arithmetic mean would give. ValueError when no longitude is finite."""
    a = np.radians(np.asarray(lon, dtype=float).ravel())
    a = a[np.isfinite(a)]
    if a.size == 0:
        raise ValueError("lon: no finite longitude to average")
    mean = math.degrees(math.atan2(float(np.sin(a).mean()), float(np.cos(a).mean())))
    return ((mean + 180.0) % 360.0) - 180.0


def _project(lat: np.ndarray, lon: np.ndarray, epsg: int) -> tuple[np.ndarray, np.ndarray]:
    from pyproj import Transformer

    tr = Transformer.from_crs("EPSG:4326", f"EPSG:{epsg}", always_xy=True)
    e, nn = tr.transform(lon, lat)
    return np.asarray(e, dtype=float), np.asarray(nn, dtype=float)


# --------------------------------------------------------------------------- session
def _anchor(t_valid: np.ndarray, t_first: float, dt: float) -> float:
    """Grid origin: the first grid point at or before ``t_first`` whose phase (time modulo
    dt) is the circular mean phase of the valid fixes, so fixes land on grid points."""
    ang = 2.0 * np.pi * np.mod(t_valid, dt) / dt
    phase = (float(np.mod(np.arctan2(np.sin(ang).mean(), np.cos(ang).mean()), 2 * np.pi))
             * dt / (2 * np.pi))
    return math.floor((t_first - phase) / dt + 0.25) * dt + phase


def _check_span(names: list[str], t0: float, t1: float, dt: float, max_span_s: float) -> int:
    """Number of grid epochs from t0 to t1; ValueError naming the logs when the span exceeds
    ``max_span_s`` (checked before any allocation)."""
    span = t1 - t0
    if not (span <= max_span_s):
        raise ValueError(
            f"logs {names!r}: the fixes span {span:.0f} s ({span / DAY_S:.1f} days, "
            f"{span / dt:.3g} epochs at {1.0 / dt:g} Hz), {span_text(t0, t1)}, more than "
            f"max_span_s={max_span_s:.0f} s ({max_span_s / DAY_S:g} days): a time jump the "
            f"importer kept, logs recorded far apart aligned on UTC (alignment='utc'), or a "
            f"recording longer than the limit; split it or pass a larger max_span_s")
    return math.floor(span / dt + 0.25) + 1


def session_from_fixes(
    logs: Sequence[LogFixes],
    *,
    rate_hz: float | None = None,
    alignment: Literal["auto", "utc", "independent"] = "auto",
    origin: Literal["auto", "common", "per_receiver"] = "auto",
    reacquisition: Literal["drop", "keep"] = "drop",
    max_span_s: float = MAX_SPAN_S,
    max_rate_hz: float = MAX_RATE_HZ,
) -> StationarySession:
    """Grid one or several receivers' fixes into a StationarySession.

    Grid: interval ``1/rate_hz`` (default: the median interval between valid fixes of the
    logs, at most ``max_rate_hz``), laid from the first to the last position fix (no-fix
    epochs never extend it); fixes are snapped to the nearest grid point when within a
    quarter interval, else counted ``off_grid``; grid points without a fix are NaN (missing
    epochs). A grid spanning more than ``max_span_s`` (default 7 days) raises ValueError
    naming the logs and the span, before anything is allocated.

    Reacquisition transients (``LogFixes.reacquired``) are set missing with
    ``reacquisition="drop"`` (default) or kept with ``"keep"``; either way they are counted
    (``reacquisition``) and listed per receiver in ``meta["receivers"][j]["reacquisitions"]``.

    Alignment: ``"utc"`` puts all logs on one UTC grid (t = 0 at the earliest fix);
    ``"independent"`` starts every log at t = 0 (recorded at different times: replay then
    treats them as simultaneous antennas, which keeps each receiver's own error character
    but not the common-mode part). ``"auto"`` picks "utc" when all dated logs share a time
    interval at least half as long as the shortest log (undated logs, without RMC, align on
    time of day with each other), else "independent".
    Origin ``"auto"``: common for "utc", per receiver for "independent".
    """
    if isinstance(logs, LogFixes) or not logs:
        raise ValueError("logs: need a non-empty sequence of LogFixes (one per receiver)")
    bad = [type(lg).__name__ for lg in logs if not isinstance(lg, LogFixes)]
    if bad:
        raise TypeError(f"logs: every element must be a LogFixes, got {bad}")
    names = [lg.name for lg in logs]
    if len(set(names)) != len(names):
        raise ValueError(f"logs: duplicate receiver names {names!r}; pass distinct names")
    if reacquisition not in ("drop", "keep"):
        raise ValueError(f"reacquisition: must be 'drop' or 'keep', got {reacquisition!r}")
    max_span_s = check_real(max_span_s, "max_span_s", lo=0.0, lo_open=True)
    max_rate_hz = check_real(max_rate_hz, "max_rate_hz", lo=0.0, lo_open=True)
    use = []
    for lg in logs:
        if not lg.valid.any():
            raise ValueError(f"log {lg.name!r}: no valid fix ({lg.meta.get('path', '')}); "
                             f"skipped counts {lg.skipped}")
        u = lg.valid.copy()
        if reacquisition == "drop" and lg.reacquired is not None:
            u &= ~lg.reacquired
        if not u.any():
            raise ValueError(f"log {lg.name!r}: every fix is flagged as a reacquisition "
                             f"transient; pass reacquisition='keep'")
        use.append(u)
    # interval
    if rate_hz is None:
        dts = np.concatenate([np.diff(lg.t_utc[u]) for lg, u in zip(logs, use)])
        dts = dts[dts > 1e-6]
        if dts.size == 0:
            raise ValueError("logs: fewer than two valid fixes; cannot infer the sample rate "
                             "(pass rate_hz)")
        dt = float(np.median(dts))
        if 1.0 / dt > max_rate_hz:
            raise ValueError(f"logs {names!r}: median interval between fixes {dt:.3g} s "
                             f"({1.0 / dt:.3g} Hz) is faster than max_rate_hz={max_rate_hz:g}; "
                             f"pass rate_hz")
    else:
        dt = 1.0 / check_real(rate_hz, "rate_hz", lo=0.0, lo_open=True, hi=max_rate_hz)
    # alignment
    starts = np.array([lg.t_utc[u][0] for lg, u in zip(logs, use)])
    stops = np.array([lg.t_utc[u][-1] for lg, u in zip(logs, use)])
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
    # time offsets per log: anchor every log to a grid; size checked before allocating
    if alignment == "utc":
        t0 = _anchor(np.concatenate([lg.t_utc[u] for lg, u in zip(logs, use)]),
                     float(starts.min()), dt)
        offs = [t0] * len(logs)
        n = _check_span(names, t0, float(stops.max()), dt, max_span_s)
    else:
        offs = [_anchor(lg.t_utc[u], float(s0), dt) for lg, u, s0 in zip(logs, use, starts)]
        n = max(_check_span([lg.name], o, float(s1), dt, max_span_s)
                for lg, o, s1 in zip(logs, offs, stops))
    idx_per_log, keep_per_log = [], []
    skipped_tot = _zero_skips()
    receivers = []
    for lg, u, off in zip(logs, use, offs):
        g = (lg.t_utc - off) / dt
        k = np.rint(g).astype(np.int64)
        # epochs before the first / after the last used fix (no-fix, or dropped) are off
        # the grid's span: not gridded
        inside = (k >= 0) & (k < n) & (lg.valid <= u)
        on_grid = inside & (np.abs(g - k) <= 0.25)
        sk = dict(lg.skipped)
        sk["off_grid"] = sk.get("off_grid", 0) + int((inside & ~on_grid & u).sum())
        # two epochs snapped to one grid point: keep a fix over a no-fix epoch, else the
        # first in time; count the others
        cand = np.flatnonzero(on_grid)
        order = np.lexsort((cand, ~u[cand], k[cand]))
        kk = k[cand][order]
        first = np.r_[True, kk[1:] != kk[:-1]] if kk.size else np.zeros(0, dtype=bool)
        sk["duplicate_epochs"] = sk.get("duplicate_epochs", 0) + int((~first).sum())
        sel = np.sort(cand[order][first])
        idx_per_log.append(k[sel])
        keep_per_log.append(sel)
        for c, v in sk.items():
            skipped_tot[c] = skipped_tot.get(c, 0) + v
        flagged = np.flatnonzero(lg.reacquired) if lg.reacquired is not None else []
        rq = lg.meta.get("reacquisitions") or []
        offm = [d.get("offset_m", math.nan) for d in rq] if len(rq) == len(flagged) \
            else [math.nan] * len(flagged)
        receivers.append({
            "name": lg.name, "skipped": sk, "date_known": lg.date_known,
            "fixes": int(lg.valid.sum()), "epochs": int(lg.t_utc.size),
            "t_first_utc": float(lg.t_utc[u][0]), "t_last_utc": float(lg.t_utc[u][-1]),
            "reacquisitions": [{"t_s": float(lg.t_utc[i] - off), "offset_m": float(o),
                                "dropped": reacquisition == "drop"}
                               for i, o in zip(flagged, offm)],
            **{k2: v2 for k2, v2 in lg.meta.items()
               if k2 in ("path", "format", "talkers", "hostname", "stale_time_rows", "time_base")}})
    m = len(logs)
    lat = np.full((n, m), np.nan)
    lon = np.full((n, m), np.nan)
    for j, (lg, gi, sel) in enumerate(zip(logs, idx_per_log, keep_per_log)):
        lat[gi, j] = lg.lat[sel]
        lon[gi, j] = lg.lon[sel]
    obs = np.full((n, m, 2), np.nan)
    frame: dict = {"axes": "x = UTM easting - origin, y = UTM northing - origin (grid north), "
                           "metres",
                   "origin_mode": origin}
    valid = np.isfinite(lat)
    if origin == "common":
        epsg = utm_epsg(float(np.nanmean(lat)), mean_longitude(lon[valid]))
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
            epsg = utm_epsg(float(np.mean(lat[v, j])), mean_longitude(lon[v, j]))
            e, nn = _project(lat[v, j], lon[v, j], epsg)
            e0, n0 = float(e.mean()), float(nn.mean())
            obs[v, j, 0] = e - e0
            obs[v, j, 1] = nn - n0
            receivers[j].update({"epsg": epsg, "origin_easting_m": e0, "origin_northing_m": n0})
    t = np.arange(n) * dt
    meta = {
        "source": ("tumbleweed_csv"
                   if all(r.get("format") == "tumbleweed_csv" for r in receivers) else "nmea"),
        "alignment": alignment,
        "t0_utc": offs[0] if alignment == "utc" else None,
        "rate_hz": 1.0 / dt,
        "frame": frame,
        "receivers": receivers,
        "skipped": skipped_tot,
        "reacquisition": reacquisition,
        "power_failure_s": None,
    }
    for j, r in enumerate(receivers):
        pts = obs[:, j]
        ok = ~np.isnan(pts[:, 0])
        r["std_east_m"] = float(np.std(pts[ok, 0])) if ok.sum() > 1 else None
        r["std_north_m"] = float(np.std(pts[ok, 1])) if ok.sum() > 1 else None
        r["missing_fraction"] = float(1.0 - ok.mean())
    return StationarySession(t=t, obs=obs, names=tuple(names), truth_positions=None, meta=meta)


def import_session(paths: Sequence[str | Path] | str | Path, *, names: Sequence[str] | None = None,
                   rate_hz: float | None = None,
                   alignment: Literal["auto", "utc", "independent"] = "auto",
                   origin: Literal["auto", "common", "per_receiver"] = "auto",
                   reacquisition: Literal["drop", "keep"] = "drop",
                   max_span_s: float = MAX_SPAN_S,
                   time_base: Literal["auto", "receiver", "host"] = "auto") -> StationarySession:
    """Read one log or several (one per receiver) and grid them into one session.

    ``.csv`` files are tumbleweed CSV, others NMEA. Receiver names default to the file stems
    (made unique with the parent folder when stems repeat, e.g. ``20200519B_benchmark``).
    See :func:`parse_nmea` for ``time_base`` and :func:`session_from_fixes` for the grid,
    alignment, frame, reacquisition and ``max_span_s``.
    """
    if isinstance(paths, (str, Path)):
        paths = [paths]
    paths = [Path(p) for p in paths]
    if names is not None and len(names) != len(paths):
        raise ValueError(f"names: {len(names)} names for {len(paths)} logs")
    if names is None:
        stems = [p.stem for p in paths]
        names = [f"{p.parent.name}_{p.stem}" if stems.count(p.stem) > 1 else p.stem for p in paths]
    logs = [read_log(p, nm, max_span_s=max_span_s,
                     **({} if p.suffix.lower() == ".csv" else {"time_base": time_base}))
            for p, nm in zip(paths, names)]
    return session_from_fixes(logs, rate_hz=rate_hz, alignment=alignment, origin=origin,
                              reacquisition=reacquisition, max_span_s=max_span_s)
