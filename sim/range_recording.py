"""Reader of a recorded rigid-body ranging run described by a ``setup.toml`` (issue 26).

The format is the one of ``../shared/realdata/uwb_rigid/*/setup.toml`` (its README): a run
folder holds ``setup.toml`` and the files it names, by paths relative to the folder (never
leaving it). Keys read (everything else, e.g. notes and checksums, is ignored):

* ``[body] origin_z_m``: world height of the tag-frame origin (m);
* ``[anchors] <name> = [x, y, z]`` (m, world, >= 3); ``[tags] <name> = [x, y(, z)]`` (m, body
  frame, >= 2);
* ``[ranges]``: ``file`` (CSV, optionally gzip: ``.gz``), ``delimiter`` (default ``,``),
  ``header_rows`` (default 0), ``time_column`` (default 0), ``time_format`` (a strftime
  format of naive wall-clock times, or ``"seconds"`` for numbers), ``missing`` (``"empty
  field"`` or a literal marker such as ``"nan"``), ``columns``: one ``[anchor, tag]`` pair per
  data column (the CSV columns other than the time column, in order; further columns must be
  empty);
* optional ``[calibration]``: ``bias_m``, ``slope`` (and ``sigma_m``) in ``columns`` order;
  applied on request as ``d_true = (d_raw - bias) / (1 + slope)``;
* ``[reference]``: ``kind = "static"`` with ``x_m``, ``y_m``, ``yaw_deg``; or ``kind =
  "trajectory"`` with ``file``, ``delimiter``, ``header_rows``, ``time_column``,
  ``time_format``, ``columns`` (names incl. ``time, x, y, z, qw, qx, qy, qz``: scalar-first
  Hamilton quaternion, body -> world) and ``yaw_offset_deg``: tag-frame yaw = yaw of the
  body x axis + offset.

Times are seconds since 1970-01-01 of the naive clock (as if UTC); the UWB and reference
clocks may differ by an unknown constant, estimated at scoring.

Rows shifted left. In the shared runs every row with a missing range misses a whole trailing
block of columns (the last anchor or two), and its values are those of the other anchors
moved left by one block (found here: the ranges of a0..a6 sit under a1..a7). Such a row
cannot be re-aligned without knowing which anchor dropped, so by default
(``trailing_missing="drop"``) rows whose missing fields are exactly the trailing columns are
dropped (all NaN, flagged in ``dropped_rows``); ``"keep"`` keeps them as read.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

__all__ = [
    "Calibration",
    "RangeRecording",
    "RangeRecordingError",
    "StaticReference",
    "TrajectoryReference",
    "load_range_recording",
]

_QUAT = ("qw", "qx", "qy", "qz")


class RangeRecordingError(ValueError):
    """A setup.toml field or a file it names is malformed; the message names it."""


@dataclass(frozen=True)
class StaticReference:
    """Known pose for the whole run: x, y (m), yaw (rad)."""

    x_m: float
    y_m: float
    yaw: float


@dataclass(frozen=True)
class TrajectoryReference:
    """Reference trajectory: times (L,) s (own clock), xyz (L, 3) m, yaw (L,) rad (tag frame,
    offset applied, wrapped)."""

    times: np.ndarray
    xyz: np.ndarray
    yaw: np.ndarray


@dataclass(frozen=True)
class Calibration:
    """Per-pair calibration (N, M) arrays: bias (m), slope (-), sigma (m, NaN if absent)."""

    bias_m: np.ndarray
    slope: np.ndarray
    sigma_m: np.ndarray


@dataclass(frozen=True)
class RangeRecording:
    """One run: times (n,) s; ranges (n, N, M) m (NaN missing); anchors (M, 3) m; body (N, 3) m;
    names; origin_z_m; reference; calibration (or None); calibrated (applied?);
    dropped_rows (n,) bool (left-shifted rows, see the module docstring); folder."""

    folder: Path
    times: np.ndarray
    ranges: np.ndarray
    anchors: np.ndarray
    anchor_names: tuple[str, ...]
    body: np.ndarray
    tag_names: tuple[str, ...]
    origin_z_m: float
    reference: StaticReference | TrajectoryReference
    calibration: Calibration | None
    calibrated: bool
    dropped_rows: np.ndarray


def _err(where: str, msg: str) -> RangeRecordingError:
    return RangeRecordingError(f"setup.toml {where}: {msg}")


def _get(table: dict, key: str, where: str, kind, default=None, required=True):
    if key not in table:
        if required:
            raise _err(f"{where} {key}", "missing")
        return default
    v = table[key]
    ok = isinstance(v, kind) and not (kind in (int, float, (int, float)) and isinstance(v, bool))
    if not ok:
        raise _err(f"{where} {key}", f"expected {getattr(kind, '__name__', kind)}, got "
                                     f"{type(v).__name__} {v!r}")
    if isinstance(v, float) and not math.isfinite(v):
        raise _err(f"{where} {key}", f"must be finite, got {v!r}")
    return v


def _table(setup: dict, name: str, required=True) -> dict:
    t = setup.get(name)
    if t is None and not required:
        return {}
    if not isinstance(t, dict):
        raise _err(f"[{name}]", "missing section" if t is None else f"not a table: {t!r}")
    return t


def _points(setup: dict, name: str, dims: tuple[int, ...], minimum: int):
    t = _table(setup, name)
    names, pts = [], []
    for k, v in t.items():
        if not (isinstance(v, list) and len(v) in dims and all(
                isinstance(c, (int, float)) and not isinstance(c, bool) and math.isfinite(c)
                for c in v)):
            raise _err(f"[{name}] {k}", f"expected {' or '.join(map(str, dims))} finite "
                                        f"numbers (m), got {v!r}")
        names.append(k)
        pts.append(list(map(float, v)) + [0.0] * (3 - len(v)))
    if len(names) < minimum:
        raise _err(f"[{name}]", f"needs >= {minimum} entries, got {len(names)}")
    return tuple(names), np.array(pts)


def _inside(folder: Path, rel: str, where: str) -> Path:
    p = Path(rel)
    if p.is_absolute():
        raise _err(where, f"must be a path relative to the run folder, got {rel!r}")
    full = (folder / p).resolve()
    if not full.is_relative_to(folder.resolve()):
        raise _err(where, f"leaves the run folder: {rel!r}")
    if not full.is_file():
        raise _err(where, f"file not found: {rel!r} (in {folder})")
    return full


def _read_table(folder: Path, t: dict, sect: str) -> pd.DataFrame:
    path = _inside(folder, _get(t, "file", sect, str), f"{sect} file")
    delim = _get(t, "delimiter", sect, str, ",", required=False)
    header = _get(t, "header_rows", sect, int, 0, required=False)
    if header < 0:
        raise _err(f"{sect} header_rows", f"must be >= 0, got {header}")
    missing = _get(t, "missing", sect, str, "empty field", required=False)
    na = [""] if missing == "empty field" else ["", missing]
    try:
        return pd.read_csv(path, sep=delim, header=None, skiprows=header, dtype=str,
                           keep_default_na=False, na_values=na, compression="infer")
    except (pd.errors.ParserError, UnicodeDecodeError, OSError, EOFError) as exc:
        raise _err(f"{sect} file", f"cannot read {path.name}: {exc}") from exc


def _times(col: pd.Series, fmt: str, sect: str) -> np.ndarray:
    if col.isna().any():
        raise _err(f"{sect} time_column", f"empty time in data row {int(col.isna().argmax())}")
    if fmt == "seconds":
        v = pd.to_numeric(col, errors="coerce").to_numpy(float)
    else:
        dt = pd.to_datetime(col, format=fmt, errors="coerce")
        v = (dt - pd.Timestamp("1970-01-01")).dt.total_seconds().to_numpy(float)
    bad = ~np.isfinite(v)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise _err(f"{sect} time_format", f"{fmt!r} does not parse data row {i}: "
                                          f"{col.iloc[i]!r}")
    if np.any(np.diff(v) < 0):
        i = int(np.flatnonzero(np.diff(v) < 0)[0]) + 1
        raise _err(f"{sect} time_column", f"times decrease at data row {i}")
    return v


def _numbers(df: pd.DataFrame, sect: str) -> np.ndarray:
    out = df.apply(pd.to_numeric, errors="coerce")
    bad = out.isna() & df.notna()
    if bad.to_numpy().any():
        i, j = np.argwhere(bad.to_numpy())[0]
        raise _err(f"{sect} file", f"not a number in data row {i}, column {df.columns[j]}: "
                                   f"{df.iat[i, j]!r}")
    return out.to_numpy(float, copy=True)


def _read_ranges(folder, setup, anchors, tags, trailing_missing):
    sect = "[ranges]"
    t = _table(setup, "ranges")
    df = _read_table(folder, t, sect)
    tcol = _get(t, "time_column", sect, int, 0, required=False)
    fmt = _get(t, "time_format", sect, str)
    cols = _get(t, "columns", sect, list)
    pairs = []
    for k, c in enumerate(cols):
        if not (isinstance(c, list) and len(c) == 2 and c[0] in anchors and c[1] in tags):
            raise _err(f"{sect} columns[{k}]", f"expected [anchor, tag] with anchor in "
                                               f"{list(anchors)} and tag in {list(tags)}, "
                                               f"got {c!r}")
        pairs.append((tags.index(c[1]), anchors.index(c[0])))
    if len(set(pairs)) != len(pairs):
        raise _err(f"{sect} columns", "an [anchor, tag] pair appears twice")
    if not 0 <= tcol < df.shape[1]:
        raise _err(f"{sect} time_column", f"{tcol} outside the file's {df.shape[1]} columns")
    data = df.drop(columns=df.columns[tcol])
    if data.shape[1] < len(pairs):
        raise _err(f"{sect} columns", f"{len(pairs)} pairs but the file has only "
                                      f"{data.shape[1]} data columns")
    extra = data.iloc[:, len(pairs):]
    if extra.notna().to_numpy().any():
        raise _err(f"{sect} columns", f"{len(pairs)} pairs but data column {len(pairs) + 1} "
                                      f"holds values")
    times = _times(df.iloc[:, tcol], fmt, sect)
    v = _numbers(data.iloc[:, :len(pairs)], sect)
    if (v < 0).any():
        raise _err(f"{sect} file", f"negative range {np.nanmin(v)!r} m")
    miss = np.isnan(v)
    nmiss = miss.sum(axis=1)
    # the missing fields are exactly the last nmiss ones: the first missing is at k - nmiss
    trailing = (nmiss > 0) & (np.argmax(miss, axis=1) == v.shape[1] - nmiss)
    if trailing_missing == "drop":
        v[trailing] = np.nan
    D = np.full((v.shape[0], len(tags), len(anchors)), np.nan)
    for j, (n, m) in enumerate(pairs):
        D[:, n, m] = v[:, j]
    return times, D, pairs, trailing if trailing_missing == "drop" else np.zeros_like(trailing)


def _calibration(setup, pairs, N, M):
    t = _table(setup, "calibration", required=False)
    if not t:
        return None
    arrs = {}
    for key, req in (("bias_m", True), ("slope", True), ("sigma_m", False)):
        v = _get(t, key, "[calibration]", list, None, required=req)
        if v is None:
            arrs[key] = np.full((N, M), np.nan)
            continue
        if len(v) != len(pairs) or not all(isinstance(x, (int, float)) and not
                                           isinstance(x, bool) and math.isfinite(x) for x in v):
            raise _err(f"[calibration] {key}", f"expected {len(pairs)} finite numbers (one "
                                               f"per [ranges] column), got {v!r}")
        a = np.full((N, M), np.nan)
        for x, (n, m) in zip(v, pairs):
            a[n, m] = float(x)
        arrs[key] = a
    if np.any(arrs["slope"] <= -1):
        raise _err("[calibration] slope", "must be > -1")
    return Calibration(arrs["bias_m"], arrs["slope"], arrs["sigma_m"])


def _reference(folder, setup):
    sect = "[reference]"
    t = _table(setup, "reference")
    kind = _get(t, "kind", sect, str)
    if kind == "static":
        x, y, yaw = (float(_get(t, k, sect, (int, float))) for k in ("x_m", "y_m", "yaw_deg"))
        return StaticReference(x, y, math.radians(yaw))
    if kind != "trajectory":
        raise _err(f"{sect} kind", f"must be 'static' or 'trajectory', got {kind!r}")
    df = _read_table(folder, t, sect)
    names = _get(t, "columns", sect, list)
    need = ("time", "x", "y", "z") + _QUAT
    lacking = [c for c in need if c not in names]
    if lacking or len(names) > df.shape[1]:
        raise _err(f"{sect} columns", f"needs {list(need)} within the file's {df.shape[1]} "
                                      f"columns, got {names!r}")
    tcol = _get(t, "time_column", sect, int, names.index("time"), required=False)
    if names.index("time") != tcol:
        raise _err(f"{sect} time_column", f"{tcol} but columns names 'time' at "
                                          f"{names.index('time')}")
    offset = math.radians(float(_get(t, "yaw_offset_deg", sect, (int, float), 0.0,
                                     required=False)))
    times = _times(df.iloc[:, tcol], _get(t, "time_format", sect, str), sect)
    v = _numbers(df.iloc[:, [names.index(c) for c in need[1:]]], sect)
    good = np.all(np.isfinite(v), axis=1)
    qw, qx, qy, qz = v[:, 3:7].T
    norm = np.sqrt(qw ** 2 + qx ** 2 + qy ** 2 + qz ** 2)
    if np.any(np.abs(norm[good] - 1) > 0.01):
        raise _err(f"{sect} columns", "quaternions are not unit (|q| differs from 1 by > 0.01)")
    yaw = np.arctan2(2 * (qx * qy + qw * qz), 1 - 2 * (qy ** 2 + qz ** 2)) + offset
    yaw = np.pi - np.mod(np.pi - yaw, 2 * np.pi)
    return TrajectoryReference(times[good], v[good, :3], yaw[good])


def load_range_recording(folder, *, calibrate: bool = False,
                         trailing_missing: str = "drop") -> RangeRecording:
    """Read the run in ``folder`` (a directory holding ``setup.toml``; module docstring).

    calibrate : apply ``[calibration]`` (RangeRecordingError if the run has none).
    trailing_missing : ``"drop"`` (default) or ``"keep"`` the left-shifted rows.
    Raises RangeRecordingError (a ValueError) naming the field or file for malformed input.
    """
    if trailing_missing not in ("drop", "keep"):
        raise ValueError(f"trailing_missing: must be 'drop' or 'keep', got {trailing_missing!r}")
    folder = Path(folder)
    path = folder / "setup.toml"
    if not path.is_file():
        raise RangeRecordingError(f"setup.toml: not found in {folder}")
    try:
        setup = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise RangeRecordingError(f"setup.toml: not valid TOML: {exc}") from exc
    z0 = float(_get(_table(setup, "body"), "origin_z_m", "[body]", (int, float)))
    anames, A = _points(setup, "anchors", (3,), 3)
    tnames, B = _points(setup, "tags", (2, 3), 2)
    times, D, pairs, dropped = _read_ranges(folder, setup, anames, tnames, trailing_missing)
    cal = _calibration(setup, pairs, len(tnames), len(anames))
    if calibrate:
        if cal is None:
            raise RangeRecordingError(f"setup.toml [calibration]: calibrate=True but {folder} "
                                      f"has no calibration")
        D = (D - np.nan_to_num(cal.bias_m)) / (1 + np.nan_to_num(cal.slope))
    return RangeRecording(folder=folder, times=times, ranges=D, anchors=A, anchor_names=anames,
                          body=B, tag_names=tnames, origin_z_m=z0,
                          reference=_reference(folder, setup), calibration=cal,
                          calibrated=calibrate, dropped_rows=dropped)
