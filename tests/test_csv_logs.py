"""sim.csv_logs: column-mapped CSV logs read into a recording (issue 25).

The synthetic rig of tests/synth_recording.py (known positions, a 5 s gap, a late start, an
early end) is written again as CSV in several layouts: columns in other orders, date and
time in separate columns (day-first dates, NMEA-style times, a local time zone), one file
for all antennas with an antenna column (rows shuffled), missing markers. Read back through
a recording TOML, every layout must give the positions written (lat/lon at 1e-10 degrees:
< 1e-4 m) on the same UTC grid.
"""

from __future__ import annotations

import tomllib
from datetime import UTC, datetime, timedelta, timezone
from pathlib import Path

import numpy as np
import pytest
import tomli_w
from pyproj import Transformer
from synth_recording import EPSG, T0_UTC, write_rig

from sim.csv_logs import CsvMapping, read_csv_log
from sim.recording import RecordingError, load_recording, read_antenna_log, recording_files

NAMES = ("1", "2", "3", "4")


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    return write_rig(tmp_path_factory.mktemp("csvrig"))


def _latlon(rig, j: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows written for antenna j: (indices, lat, lon) of its logged epochs."""
    to_ll = Transformer.from_crs(f"EPSG:{EPSG}", "EPSG:4326", always_xy=True)
    k = np.flatnonzero(np.isfinite(rig.observed[:, j, 0]))
    lo, la = to_ll.transform(rig.observed[k, j, 0], rig.observed[k, j, 1])
    return k, np.asarray(la), np.asarray(lo)


def _toml(folder: Path, name: str, csv_table: dict, antennas: list[dict]) -> Path:
    data = {"name": name, "config": "rover_gps4", "csv": csv_table, "antenna": antennas}
    p = folder / f"{name}.toml"
    p.write_text(tomli_w.dumps(data))
    return p


def _check(rig, rec) -> None:
    fr = rec.meta["frame"]
    assert fr["epsg"] == EPSG and rec.meta["t0_utc"] == pytest.approx(T0_UTC, abs=1e-6)
    obs = rec.obs + np.array([fr["origin_easting_m"], fr["origin_northing_m"]])
    assert np.array_equal(np.isnan(obs), np.isnan(rig.observed))
    # 1e-10 degrees of latitude/longitude: ~1e-5 m; 1e-4 m leaves room for the projection
    assert np.nanmax(np.abs(obs - rig.observed)) < 1e-4


def test_per_antenna_files_with_date_and_time_columns_in_any_order(rig, tmp_path):
    """Columns lon, Date, height, lat, Time; dates day-first, times of day in local time
    (UTC+01:00); a missing height ('-'); rows with a missing time or latitude ('NA') are
    counted, not read."""
    zone = timezone(timedelta(hours=1))
    ants = []
    for j, name in enumerate(NAMES):
        k, la, lo = _latlon(rig, j)
        rows = ["# exported by a logger", "lon,Date,height,lat,Time"]
        for i, kk in enumerate(k):
            d = datetime.fromtimestamp(rig.t_utc[kk], UTC).astimezone(zone)
            h = "-" if i == 3 else "520.000"
            rows.append(f"{lo[i]:.10f},{d:%d.%m.%Y},{h},{la[i]:.10f},{d:%H:%M:%S.%f}")
        rows += ["NA,01.03.2024,520,48.1,13:00:00", "11.5,01.03.2024,520,48.1,NA"]
        (tmp_path / f"a{name}.csv").write_text("\n".join(rows) + "\n")
        ants.append({"name": name, "log": f"a{name}.csv", "format": "csv"})
    p = _toml(tmp_path, "cols", {"time": "Time", "date": "Date", "lat": "lat", "lon": "lon",
                                 "alt": "height", "date_format": "%d.%m.%Y",
                                 "timezone": "+01:00", "missing": ["NA", "-"]}, ants)
    rec = load_recording(p)
    _check(rig, rec)
    sk = rec.meta["logs"]["1"]["skipped"]
    assert sk["missing"] == 2 and sk["comment_lines"] == 1 and sk["bad_fields"] == 0
    assert rec.meta["logs"]["1"]["format"] == "csv"
    assert np.isnan(rec.height_m[3, 0]) and rec.height_m[4, 0] == pytest.approx(520.0)


def test_one_shared_file_with_an_antenna_column_and_shuffled_rows(rig, tmp_path):
    """Semicolon-separated, columns antenna;lat;lon;t_ms (UNIX milliseconds), all antennas
    in one file in random order; the recording picks each antenna's rows by its id."""
    rows = []
    for j, name in enumerate(NAMES):
        k, la, lo = _latlon(rig, j)
        rows += [f"rx{name};{la[i]:.10f};{lo[i]:.10f};{rig.t_utc[kk] * 1000:.0f}"
                 for i, kk in enumerate(k)]
    order = np.random.default_rng(3).permutation(len(rows))
    text = "RX;Lat;Lon;t_ms\n" + "\n".join(rows[i] for i in order) + "\n"
    (tmp_path / "all.csv").write_text(text)
    ants = [{"name": n, "log": "all.csv", "format": "csv", "id": f"rx{n}"} for n in NAMES]
    p = _toml(tmp_path, "shared", {"time": "t_ms", "lat": "Lat", "lon": "Lon",
                                   "antenna": "RX", "time_format": "unix_ms"}, ants)
    rec = load_recording(p)
    _check(rig, rec)
    info = rec.meta["logs"]["2"]
    assert info["skipped"]["other_antennas"] == len(rows) - 85 and info["fixes"] == 85
    assert recording_files(p).count(tmp_path / "all.csv") == 4


def test_nmea_style_times_iso_dates_and_an_iana_zone(rig, tmp_path):
    """Tab-separated; date ISO (auto), time HHMMSS.ss (auto), zone Europe/Berlin (CET in
    March: UTC+1)."""
    from zoneinfo import ZoneInfo

    zone = ZoneInfo("Europe/Berlin")
    ants = []
    for j, name in enumerate(NAMES):
        k, la, lo = _latlon(rig, j)
        rows = ["utc_time\tlatitude\tdate\tlongitude"]
        for i, kk in enumerate(k):
            d = datetime.fromtimestamp(rig.t_utc[kk], UTC).astimezone(zone)
            rows.append(f"{d:%H%M%S}.{d.microsecond // 10000:02d}\t{la[i]:.10f}\t{d:%Y-%m-%d}"
                        f"\t{lo[i]:.10f}")
        (tmp_path / f"n{name}.tsv").write_text("\n".join(rows) + "\n")
        ants.append({"name": name, "log": f"n{name}.tsv", "format": "csv"})
    p = _toml(tmp_path, "nmea_style", {"time": "UTC_TIME", "date": "Date", "lat": "Latitude",
                                       "lon": "longitude", "timezone": "Europe/Berlin"}, ants)
    _check(rig, load_recording(p))


def test_iso_times_with_a_zone_in_the_text_and_a_csv_reference(rig, tmp_path):
    """ISO 8601 times with their own offset (they win over csv.timezone); the RTK reference
    as csv too: the reference pose is the written trajectory."""
    ants, refs = [], []
    for j, name in enumerate(NAMES):
        k, la, lo = _latlon(rig, j)
        rows = ["lat,when,lon"]
        for i, kk in enumerate(k):
            d = datetime.fromtimestamp(rig.t_utc[kk], UTC).astimezone(
                timezone(timedelta(hours=-5)))
            rows.append(f"{la[i]:.10f},{d.isoformat()},{lo[i]:.10f}")
        (tmp_path / f"i{name}.csv").write_text("\n".join(rows) + "\n")
        ants.append({"name": name, "log": f"i{name}.csv", "format": "csv"})
        refs.append({"name": name, "log": str(rig.files[f"rtk{name}"])})
    data = {"name": "iso", "config": "rover_gps4",
            "csv": {"time": "when", "lat": "lat", "lon": "lon", "timezone": "Asia/Tokyo"},
            "antenna": ants, "reference": {"antenna": refs}}
    (tmp_path / "iso.toml").write_text(tomli_w.dumps(data))
    # the reference logs lie outside this folder: copy them in (files named in a recording
    # must come with it)
    for r in refs:
        q = tmp_path / Path(r["log"]).name
        q.write_text(Path(r["log"]).read_text())
        r["log"] = q.name
    (tmp_path / "iso.toml").write_text(tomli_w.dumps(data))
    rec = load_recording(tmp_path / "iso.toml")
    _check(rig, rec)
    assert np.abs(np.angle(np.exp(1j * (rec.truth().yaw - rig.yaw)))).max() < 1e-5


@pytest.mark.parametrize("table, match", [
    ({"lat": "a", "lon": "b"}, r"csv\.time: required"),
    ({"time": "t", "lat": "a", "lon": "b", "colour": 1}, r"csv\.colour: unknown key"),
    ({"time": "t", "lat": "t", "lon": "b"}, r"column 't' named for two fields"),
    ({"time": "t", "lat": "a", "lon": "b", "timezone": "Mars/Olympus"},
     r"csv\.timezone: unknown time zone 'Mars/Olympus'"),
    ({"time": "t", "lat": "a", "lon": "b", "timezone": "+25:00"}, r"offset '\+25:00'"),
    ({"time": "t", "lat": "a", "lon": "b", "time_format": "%H:%M:%S"},
     r"csv\.time_format: '%H:%M:%S' has no date"),
    ({"time": "t", "lat": "a", "lon": "b", "date_format": "%d.%m.%Y"},
     r"csv\.date_format: given without a date column"),
    ({"time": "t", "lat": "a", "lon": "b", "delimiter": "|"}, r"csv\.delimiter"),
    ({"time": "t", "lat": "a", "lon": "b", "missing": "NA"}, r"csv\.missing"),
])
def test_mapping_errors_name_the_key(table, match):
    with pytest.raises(RecordingError, match=match):
        CsvMapping.from_dict(table)


def test_reader_errors_name_the_file_and_column(tmp_path):
    f = tmp_path / "x.csv"
    f.write_text("time,lat,lon\n2024-03-01T12:00:00Z,48.1,11.5\n")
    with pytest.raises(RecordingError, match=r"x\.csv: csv\.lon: column 'Longitude' not in "
                                             r"the header \['time', 'lat', 'lon'\]"):
        read_csv_log(f, CsvMapping(time="time", lat="lat", lon="Longitude"))
    mp = CsvMapping(time="time", lat="lat", lon="lon", antenna="rx")
    f.write_text("time,lat,lon,rx\n2024-03-01T12:00:00Z,48.1,11.5,a\n")
    with pytest.raises(RecordingError, match=r"no valid row for antenna 'b' in column 'rx' "
                                             r"\(values found: \['a'\]\)"):
        read_csv_log(f, mp, antenna="b")
    with pytest.raises(RecordingError, match="needs the antenna's id"):
        read_csv_log(f, mp)
    f.write_text("time,lat,lon\nnoon,48.1,11.5\n2024-03-01T12:00:01Z,48.1,11.5\n")
    lg = read_csv_log(f, CsvMapping(time="time", lat="lat", lon="lon"))
    assert lg.skipped["bad_fields"] == 1 and lg.meta["bad_lines"] == [2] and lg.t_utc.size == 1
    with pytest.raises(RecordingError, match="format 'csv' needs a column mapping"):
        read_antenna_log(f, format="csv")


def test_recording_toml_checks_the_csv_wiring(rig, tmp_path):
    f = tmp_path / "a.csv"
    f.write_text("time,lat,lon\n2024-03-01T12:00:00Z,48.1,11.5\n")
    base = {"name": "w", "config": "rover_gps4",
            "antenna": [{"name": n, "log": "a.csv", "format": "csv"} for n in NAMES]}
    p = tmp_path / "w.toml"
    p.write_text(tomli_w.dumps(base))
    with pytest.raises(RecordingError, match=r"antenna '1': format 'csv' needs the \[csv\]"):
        load_recording(p)
    data = tomllib.loads(p.read_text())
    data["csv"] = {"time": "time", "lat": "lat", "lon": "lon"}
    data["antenna"][0]["id"] = "rx1"
    p.write_text(tomli_w.dumps(data))
    with pytest.raises(RecordingError, match=r"antenna '1': id: only for a csv log with an "
                                             r"antenna column"):
        load_recording(p)
