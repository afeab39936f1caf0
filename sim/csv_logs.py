"""Column-mapped CSV logs: any column order, date and time in separate columns or one,
time formats and zones as the file has them, one file per antenna or one for all.

A recording names the columns in a ``[csv]`` table (:class:`CsvMapping`); every antenna
(or reference) log with ``format = "csv"`` is read with it by :func:`read_csv_log`::

    [csv]
    time = "utc_time"              # column of the time of day, or of the full time
    date = "utc_date"              # optional: a separate date column
    lat = "Latitude"               # decimal degrees WGS 84
    lon = "Longitude"
    alt = "HeightEllipsoid"        # optional, metres (as the file gives it)
    antenna = "receiver"           # optional: one file for several antennas
    time_format = "%H:%M:%S.%f"    # strptime; "auto" (default): see below
    date_format = "%d.%m.%Y"       # strptime; "auto" (default): ISO yyyy-mm-dd
    timezone = "UTC"               # "UTC", an offset "+02:00", or an IANA name
    missing = ["", "NA", "-"]      # markers of a missing value (default below)
    delimiter = ","                # optional: "," ";" "\\t" or " " (default: sniffed)

    [[antenna]]
    name = "1"
    log = "fixes.csv"
    format = "csv"
    id = "rx1"                     # this antenna's value in the antenna column (default: name)

``time_format = "auto"``: with a date column, the time of day as ``HH:MM:SS[.f]``,
``HHMMSS[.f]`` (NMEA style) or seconds of the day; without one, UTC seconds since 1970
(a number; the zone does not apply) or ISO 8601 (``2024-03-01T12:00:00.5``; a zone in the
text wins over ``timezone``). ``"unix"`` / ``"unix_ms"``: seconds / milliseconds since
1970 UTC. Any other value is a :func:`datetime.strptime` format (``%f`` for fractions);
without a date column it must contain the date.

Column names match case-insensitively after stripping spaces and quotes. Nothing is dropped
silently: ``skipped`` counts ``comment_lines`` (``#``), ``missing`` (a missing marker in
the time, date, latitude or longitude), ``bad_fields`` (a value that does not parse, a
coordinate out of range or 0, 0, a wrong column count; first line numbers in
``meta["bad_lines"]``), ``implausible_time`` (before the GPS epoch 1980-01-06 or more than
a day after reading), ``duplicate_epochs`` (a repeated time, first kept) and
``other_antennas`` (rows of the other antennas of a shared file). Rows out of time order are
sorted (``meta["unsorted_rows"]`` says how many were). Errors
(:class:`sim.recording.RecordingError`) name the file, the line and the column.
"""

from __future__ import annotations

import csv
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from datetime import UTC, date, datetime, time, timedelta, timezone, tzinfo
from pathlib import Path

import numpy as np

from sim.nmea import LogFixes, plausible_fix
from sim.recording_errors import RecordingError

__all__ = ["CSV_KEYS", "DEFAULT_MISSING", "CsvMapping", "read_csv_log"]

#: Keys of a ``[csv]`` table.
CSV_KEYS = ("time", "date", "lat", "lon", "alt", "antenna", "time_format", "date_format",
            "timezone", "missing", "delimiter")
#: Missing-value markers by default (compared after stripping spaces, case-insensitive).
DEFAULT_MISSING = ("", "na", "n/a", "nan", "null", "none", "-")
_DELIMS = (",", ";", "\t", " ")
#: Earliest plausible fix time: the GPS epoch, 1980-01-06 UTC, seconds since 1970.
GPS_EPOCH_UTC = 315964800.0
_TOD_FORMATS = ("%H:%M:%S.%f", "%H:%M:%S", "%H%M%S.%f", "%H%M%S")
_OFFSET = re.compile(r"([+-])(\d{2}):?(\d{2})")


def _error(msg: str) -> Exception:
    return RecordingError(msg)


def _zone(value: object, where: str) -> tzinfo:
    """"UTC"/"Z", "+hh:mm" / "-hhmm", or an IANA zone name."""
    if not isinstance(value, str) or not value.strip():
        raise _error(f"{where}: must be 'UTC', an offset like '+02:00' or an IANA zone name, "
                     f"got {value!r}")
    v = value.strip()
    if v.upper() in ("UTC", "Z", "GMT"):
        return UTC
    m = _OFFSET.fullmatch(v)
    if m:
        h, mi = int(m.group(2)), int(m.group(3))
        if h > 14 or mi > 59:
            raise _error(f"{where}: offset {v!r} out of range (at most +/-14:00)")
        sign = 1 if m.group(1) == "+" else -1
        return timezone(sign * timedelta(hours=h, minutes=mi))
    from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

    try:
        return ZoneInfo(v)
    except (ZoneInfoNotFoundError, ValueError):
        raise _error(f"{where}: unknown time zone {v!r} (use 'UTC', an offset like "
                     f"'+02:00' or an IANA name like 'Europe/Berlin')") from None


@dataclass(frozen=True)
class CsvMapping:
    """Which column holds what, and how times read (module docstring). ``time``, ``lat``,
    ``lon`` required; ``date``, ``alt``, ``antenna`` optional column names; formats,
    ``timezone``, ``missing`` markers and ``delimiter`` as the ``[csv]`` table."""

    time: str
    lat: str
    lon: str
    date: str | None = None
    alt: str | None = None
    antenna: str | None = None
    time_format: str = "auto"
    date_format: str = "auto"
    timezone: str = "UTC"
    missing: tuple[str, ...] = DEFAULT_MISSING
    delimiter: str | None = None

    def __post_init__(self) -> None:
        for k in ("time", "lat", "lon", "date", "alt", "antenna"):
            v = getattr(self, k)
            if v is None and k not in ("time", "lat", "lon"):
                continue
            if not isinstance(v, str) or not v.strip():
                raise _error(f"csv.{k}: must be a column name (a non-empty string), got {v!r}")
        cols = [getattr(self, k) for k in ("time", "date", "lat", "lon", "alt", "antenna")
                if getattr(self, k) is not None]
        low = [c.strip().lower() for c in cols]
        dup = sorted({c for c in low if low.count(c) > 1})
        if dup:
            raise _error(f"csv: column {dup[0]!r} named for two fields")
        for k in ("time_format", "date_format"):
            v = getattr(self, k)
            if not isinstance(v, str) or not v:
                raise _error(f"csv.{k}: must be a format string, got {v!r}")
        if self.date is None and self.date_format != "auto":
            raise _error("csv.date_format: given without a date column (csv.date)")
        if self.date is not None and self.time_format in ("unix", "unix_ms"):
            raise _error(f"csv.time_format: {self.time_format!r} is a full time; it takes no "
                         f"date column (remove csv.date)")
        if (self.date is None and self.time_format not in ("auto", "unix", "unix_ms")
                and not any(d in self.time_format for d in ("%Y", "%y", "%j", "%s"))):
            raise _error(f"csv.time_format: {self.time_format!r} has no date (%Y / %y); give "
                         f"the date column (csv.date) or a format with the date")
        _zone(self.timezone, "csv.timezone")
        if (not isinstance(self.missing, tuple)
                or not all(isinstance(m, str) for m in self.missing)):
            raise _error(f"csv.missing: must be a list of strings, got {self.missing!r}")
        if self.delimiter is not None and self.delimiter not in _DELIMS:
            raise _error(f"csv.delimiter: must be one of {list(_DELIMS)}, got "
                         f"{self.delimiter!r}")

    @classmethod
    def from_dict(cls, data: object, where: str = "csv") -> CsvMapping:
        """From the recording's ``[csv]`` table; errors name ``where.<key>``."""
        if not isinstance(data, Mapping):
            raise _error(f"{where}: must be a table")
        bad = sorted(set(data) - set(CSV_KEYS))
        if bad:
            raise _error(f"{where}.{bad[0]}: unknown key (allowed: {list(CSV_KEYS)})")
        for k in ("time", "lat", "lon"):
            if k not in data:
                raise _error(f"{where}.{k}: required (the column's name)")
        kw = dict(data)
        if "missing" in kw:
            m = kw["missing"]
            kw["missing"] = tuple(m) if isinstance(m, list) else m
        try:
            return cls(**kw)
        except ValueError as exc:
            msg = str(exc)
            raise _error(msg.replace("csv", where, 1) if msg.startswith("csv") else msg) \
                from None

    @property
    def zone(self) -> tzinfo:
        return _zone(self.timezone, "csv.timezone")


class _BadValue(ValueError):
    """A field that does not parse (counted per row)."""


def _strptime(text: str, fmt: str) -> datetime:
    try:
        return datetime.strptime(text, fmt)
    except ValueError:
        raise _BadValue(text) from None


def _time_of_day(text: str, fmt: str) -> time | float:
    """A time of day: a ``time`` (formats) or seconds of the day (a number)."""
    if fmt != "auto":
        return _strptime(text, fmt).time()
    for f in _TOD_FORMATS:
        try:
            return datetime.strptime(text, f).time()
        except ValueError:
            continue
    try:
        v = float(text)
    except ValueError:
        raise _BadValue(text) from None
    if not 0.0 <= v < 86400.0:
        raise _BadValue(text)
    return v


def _date(text: str, fmt: str) -> date:
    if fmt == "auto":
        try:
            return date.fromisoformat(text)
        except ValueError:
            raise _BadValue(text) from None
    return _strptime(text, fmt).date()


def _utc(dt: datetime, zone: tzinfo) -> float:
    return (dt if dt.tzinfo is not None else dt.replace(tzinfo=zone)).timestamp()


def _parse_time(tv: str, dv: str | None, mp: CsvMapping, zone: tzinfo) -> float:
    """UTC seconds since 1970 of a row's time (and date) fields."""
    if dv is not None:
        d = _date(dv, mp.date_format)
        tod = _time_of_day(tv, mp.time_format)
        base = datetime(d.year, d.month, d.day)
        dt = base + timedelta(seconds=tod) if isinstance(tod, float) else \
            datetime.combine(d, tod)
        return _utc(dt, zone)
    if mp.time_format in ("unix", "unix_ms"):
        try:
            v = float(tv)
        except ValueError:
            raise _BadValue(tv) from None
        v = v / 1000.0 if mp.time_format == "unix_ms" else v
        if not math.isfinite(v):
            raise _BadValue(tv)
        return v
    if mp.time_format == "auto":
        try:
            v = float(tv)
        except ValueError:
            pass
        else:
            if not math.isfinite(v):
                raise _BadValue(tv)
            return v
        txt = tv[:-1] + "+00:00" if tv.endswith(("Z", "z")) else tv
        try:
            return _utc(datetime.fromisoformat(txt), zone)
        except ValueError:
            raise _BadValue(tv) from None
    return _utc(_strptime(tv, mp.time_format), zone)


def _sniff_delimiter(line: str) -> str:
    for d in (",", ";", "\t"):
        if d in line:
            return d
    return " "


def _split(line: str, delim: str) -> list[str]:
    if delim == " ":
        return line.split()
    return next(csv.reader([line], delimiter=delim))


def _columns(header: list[str], mp: CsvMapping, path: Path) -> dict[str, int]:
    names = [h.strip().strip('"\'').strip().lower() for h in header]
    out = {}
    for key in ("time", "date", "lat", "lon", "alt", "antenna"):
        col = getattr(mp, key)
        if col is None:
            continue
        want = col.strip().lower()
        if want not in names:
            raise _error(f"{path}: csv.{key}: column {col!r} not in the header "
                         f"{[h.strip() for h in header]}")
        out[key] = names.index(want)
    return out


def read_csv_log(path: str | Path, mapping: CsvMapping, *, antenna: str | None = None,
                 name: str | None = None) -> LogFixes:
    """One antenna's fixes from a column-mapped CSV (module docstring). ``antenna``: its
    value in the mapping's antenna column (required with one, refused without)."""
    path = Path(path)
    if not isinstance(mapping, CsvMapping):
        raise TypeError(f"mapping: expected a CsvMapping, got {type(mapping).__name__}")
    if not path.is_file():
        raise _error(f"log: no such file {str(path)!r}")
    if (mapping.antenna is None) != (antenna is None):
        raise _error(f"{path}: antenna: " + (
            f"the file has no antenna column (csv.antenna) to select {antenna!r} by"
            if mapping.antenna is None else
            f"csv.antenna = {mapping.antenna!r} needs the antenna's id in the file"))
    rows, skipped, bad_lines, ids, unsorted = _read_rows(path, mapping, antenna)
    if not rows:
        found = sorted(ids)[:10]
        raise _error(f"{path}: no valid row" + (
            f" for antenna {antenna!r} in column {mapping.antenna!r} (values found: {found})"
            if antenna is not None else "") + f"; skipped {skipped}, first bad lines "
            f"{bad_lines}")
    a = np.array(rows, dtype=float)
    a = a[np.argsort(a[:, 0], kind="stable")]
    first = np.ones(len(a), dtype=bool)
    first[1:] = np.diff(a[:, 0]) > 0
    skipped["duplicate_epochs"] = int((~first).sum())
    a = a[first]
    return LogFixes(name=name or antenna or path.stem, t_utc=a[:, 0], lat=a[:, 1],
                    lon=a[:, 2], quality=np.ones(len(a), dtype=np.int64), date_known=True,
                    skipped=skipped, height_m=a[:, 3],
                    meta={"path": str(path), "format": "csv", "bad_lines": bad_lines,
                          "unsorted_rows": unsorted, "antenna_id": antenna})


def _read_rows(path: Path, mp: CsvMapping, antenna: str | None):
    """(rows (t, lat, lon, h), skipped, bad line numbers, antenna ids seen, unsorted)."""
    skipped = {"comment_lines": 0, "missing": 0, "bad_fields": 0, "implausible_time": 0,
               "duplicate_epochs": 0, "other_antennas": 0}
    bad_lines: list[int] = []
    missing = {m.strip().lower() for m in mp.missing}
    zone = mp.zone
    now = datetime.now(UTC).timestamp() + 86400.0
    rows: list[tuple[float, float, float, float]] = []
    ids: set[str] = set()
    cols: dict[str, int] | None = None
    delim = mp.delimiter
    ncols = 0
    unsorted, last = 0, -math.inf

    def bad(lineno: int, cls: str = "bad_fields") -> None:
        skipped[cls] += 1
        if len(bad_lines) < 10:
            bad_lines.append(lineno)

    with open(path, encoding="utf-8", errors="replace", newline="") as fh:
        for lineno, raw in enumerate(fh, start=1):
            line = raw.strip().lstrip("\ufeff")
            if not line:
                continue
            if line.startswith("#"):
                skipped["comment_lines"] += 1
                continue
            if cols is None:
                delim = delim or _sniff_delimiter(line)
                header = _split(line, delim)
                cols, ncols = _columns(header, mp, path), len(header)
                continue
            f = [v.strip() for v in _split(line, delim)]
            if len(f) != ncols:
                bad(lineno)
                continue
            if antenna is not None:
                aid = f[cols["antenna"]]
                ids.add(aid)
                if aid != antenna:
                    skipped["other_antennas"] += 1
                    continue
            need = [f[cols[k]] for k in ("time", "date", "lat", "lon") if k in cols]
            if any(v.lower() in missing for v in need):
                skipped["missing"] += 1
                continue
            try:
                tv = _parse_time(f[cols["time"]], f[cols["date"]] if "date" in cols else None,
                                 mp, zone)
                la, lo = float(f[cols["lat"]]), float(f[cols["lon"]])
                hv = f[cols["alt"]] if "alt" in cols else ""
                h = math.nan if hv.lower() in missing else float(hv)
            except (ValueError, OverflowError):
                bad(lineno)
                continue
            if not plausible_fix(la, lo, h):
                bad(lineno)
                continue
            if not GPS_EPOCH_UTC <= tv <= now:
                bad(lineno, "implausible_time")
                continue
            unsorted += tv < last
            last = max(last, tv)
            rows.append((tv, la, lo, h))
    if cols is None:
        raise _error(f"{path}: no header line (the [csv] mapping names columns of a header)")
    return rows, skipped, bad_lines, ids, int(unsorted)
