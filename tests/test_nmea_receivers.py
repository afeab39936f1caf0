"""sim.nmea on synthetic logs with what real receivers do: default dates and times before the
first fix, a cold restart mid-log, host-timestamp prefixes and bare timestamp lines,
reacquisition jumps with fractional-second times, midnight and GPS week rollover, steps of
years; the bounded grid; and arbitrary checksum-valid GGA/RMC sentences (property test).

Each test writes sentences from a list of epochs it knows, imports them and checks the
imported fixes / session against what was written."""

from __future__ import annotations

import functools
import math
import operator
from datetime import UTC, datetime, timedelta

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sim.log_timeline import WEEK_ROLLOVER_S
from sim.nmea import (
    DROP_CLASSES,
    SKIP_CLASSES,
    find_logs,
    flag_reacquisitions,
    import_session,
    log_format,
    parse_nmea,
    read_log,
    session_from_fixes,
)

LAT0, LON0 = 39.79422, -105.15337          # a place; positions are metres around it
M_PER_DEG_LAT = 111_034.0                  # at 39.8 deg (WGS 84 meridian arc, 0.1 % is ample)


def _cs(body: str) -> str:
    return f"${body}*{functools.reduce(operator.xor, body.encode(), 0):02X}"


def _dm(v: float, width: int) -> str:
    a = abs(v)
    d = int(a)
    return f"{d:0{width}d}{(a - d) * 60:010.7f}"


def _pos(north_m: float = 0.0, east_m: float = 0.0) -> tuple[float, float]:
    return (LAT0 + north_m / M_PER_DEG_LAT,
            LON0 + east_m / (M_PER_DEG_LAT * math.cos(math.radians(LAT0))))


def epoch(t: datetime | None, *, fix: bool = True, north_m: float = 0.0, east_m: float = 0.0,
          date: str | None = None, tod: str | None = None, rmc: bool = True, alt: str = "1708.6",
          sep: str = "-21.5", prefix: str = "") -> list[str]:
    """GGA (+ RMC) of one epoch at UTC ``t``; ``date`` / ``tod`` override the written fields
    (receiver defaults), ``prefix`` is prepended to each line (host timestamp)."""
    la, lo = _pos(north_m, east_m)
    ts = tod if tod is not None else (t.strftime("%H%M%S.") + f"{t.microsecond // 10000:02d}"
                                      if t else "")
    ds = date if date is not None else (t.strftime("%d%m%y") if t else "")
    if fix:
        pos = f"{_dm(la, 2)},N,{_dm(lo, 3)},W"
        g = f"GPGGA,{ts},{pos},1,08,0.9,{alt},M,{sep},M,,"
        r = f"GPRMC,{ts},A,{pos},0.02,,{ds},,,A"
    else:
        g = f"GPGGA,{ts},,,,,0,00,99.9,,,,,,"
        r = f"GPRMC,{ts},V,,,,,,,{ds},,,N"
    return [prefix + _cs(g)] + ([prefix + _cs(r)] if rmc else [])


def run(t0: datetime, n: int, **kw) -> list[str]:
    return [ln for k in range(n) for ln in epoch(t0 + timedelta(seconds=k), **kw)]


T0 = datetime(2021, 8, 20, 18, 49, 26, tzinfo=UTC)


def _utc(t: datetime) -> float:
    return t.timestamp()


def _counts_add_up(fx) -> None:
    """The accounting identity of the module docstring."""
    total = len(fx.t_utc) + fx.meta["merged_sentences"] + fx.meta["untimed_sentences"] + \
        sum(fx.skipped[c] for c in DROP_CLASSES)
    assert total == fx.meta["fix_sentences"], (total, fx.meta, fx.skipped)


# --------------------------------------------------------------------------- cold start
def test_cold_start_default_dates_never_define_the_grid():
    """A receiver's first minute: RMC dated 050180 with times counting from 235942.800, no
    fix; then the real date with fixes. Only the real epochs are kept, the defaults are
    counted, the session starts at the first real fix."""
    default = [ln for k in range(40) for ln in epoch(None, fix=False, date="050180",
                                                      tod=f"2359{42 + k // 5:02d}.{(k % 5) * 2}00")]
    lines = default + run(T0, 30)
    fx = parse_nmea(lines)
    assert fx.date_known and fx.meta["time_base"] == "receiver"
    assert fx.skipped["implausible_date"] == 40
    assert np.array_equal(fx.t_utc, _utc(T0) + np.arange(30))
    assert fx.valid.all()
    _counts_add_up(fx)
    s = session_from_fixes([fx])
    assert s.n == 30 and s.present.all() and s.meta["t0_utc"] == _utc(T0)


def test_cold_start_other_default_date():
    lines = [ln for k in range(10) for ln in epoch(None, fix=False, date="100180",
                                                    tod=f"0000{k:02d}.00")] + run(T0, 20)
    fx = parse_nmea(lines)
    assert fx.skipped["implausible_date"] == 10 and fx.valid.sum() == 20
    assert fx.t_utc[0] == _utc(T0)


def test_cold_start_without_rmc_default_times_are_a_reversed_segment():
    """GGA only (undated): default times 23:59:42.8.. before the real 18:49:26. The default
    run is later in the day than the fixes that follow it: off the time line, counted."""
    default = [ln for k in range(12) for ln in epoch(None, fix=False, rmc=False,
                                                      tod=f"2359{42 + k:02d}.800")]
    fx = parse_nmea(default + run(T0, 25, rmc=False))
    assert not fx.date_known
    assert fx.skipped["reversed_segments"] == 12
    assert fx.valid.sum() == 25 and fx.t_utc.size == 25
    assert np.allclose(np.diff(fx.t_utc), 1.0)
    _counts_add_up(fx)


def test_mid_log_cold_restart_joins_segments_on_one_grid():
    """Fixes, then a restart (1980 dates, no fix, 20 epochs), then fixes again 60 s after
    the last fix before the restart: both fix segments on one grid, the gap missing."""
    a = run(T0, 50, north_m=1.0)
    restart = [ln for k in range(20) for ln in epoch(None, fix=False, date="060180",
                                                      tod=f"0000{k:02d}.00")]
    b = run(T0 + timedelta(seconds=110), 40, north_m=-1.0)
    fx = parse_nmea(a + restart + b)
    assert fx.skipped["implausible_date"] == 20
    assert fx.valid.sum() == 90
    s = session_from_fixes([fx])
    assert s.n == 150 and s.present[:, 0].sum() == 90
    assert not s.present[50:110, 0].any()
    # what was written: 1 m north, then 1 m south of the same point (frame origin = mean)
    y = s.obs[:, 0, 1]
    assert np.allclose(y[:50] - y[110:].mean(), 2.0, atol=0.01)
    _counts_add_up(fx)


def test_mid_log_restart_counting_from_a_default_time_of_day_is_dropped():
    """Undated restart that counts from 00:00:00 (earlier in the day than the fixes): the
    whole no-fix segment goes back in time and is counted as reversed_segments."""
    a = run(T0, 30, rmc=False)
    restart = [ln for k in range(15) for ln in epoch(None, fix=False, rmc=False,
                                                      tod=f"0000{k:02d}.00")]
    b = run(T0 + timedelta(seconds=60), 30, rmc=False)
    fx = parse_nmea(a + restart + b)
    assert fx.skipped["reversed_segments"] == 15
    assert fx.valid.sum() == 60
    _counts_add_up(fx)


def test_fixes_with_default_dates_are_dropped_when_real_dates_exist():
    """Some receivers output positions before the week number is known: fixes dated 1980
    among fixes with the real date. The 1980 ones are implausible, the rest kept."""
    bad = run(datetime(1980, 1, 6, 0, 0, 0, tzinfo=UTC), 5)
    fx = parse_nmea(bad + run(T0, 20))
    assert fx.skipped["implausible_date"] == 5 and fx.valid.sum() == 20
    assert fx.t_utc[0] == _utc(T0)


def test_only_default_dated_fixes_keep_time_of_day_without_a_date():
    """A short log whose fixes all carry 1980 dates and no host clock: the fixes are kept
    on the receiver's time of day, the date dropped (date_known False), noted in meta."""
    fx = parse_nmea(run(datetime(1980, 1, 6, 12, 0, 0, tzinfo=UTC), 10))
    assert fx.valid.sum() == 10 and not fx.date_known
    assert fx.meta["time_base"] == "receiver_undated"
    assert np.array_equal(fx.t_utc, 43200.0 + np.arange(10))
    with pytest.raises(ValueError, match="implausible|no valid fix"):
        session_from_fixes([parse_nmea(run(datetime(1980, 1, 6, tzinfo=UTC), 10),
                                       time_base="receiver")])


def test_step_of_years_forward_is_a_time_jump():
    """Ten fixes dated 18 years early (a firmware default with a fix), then the real date:
    a step of years, counted time_jump; the grid is the real segment only."""
    fx = parse_nmea(run(T0.replace(year=2003), 10) + run(T0, 40))
    assert fx.skipped["time_jump"] == 10 and fx.skipped["week_rollover"] == 0
    assert fx.valid.sum() == 40 and fx.t_utc[0] == _utc(T0)
    _counts_add_up(fx)


def test_future_dates_are_implausible():
    fx = parse_nmea(run(T0, 10) + run(datetime(2060, 1, 1, tzinfo=UTC), 3),
                    latest_date=datetime(2022, 1, 1).date())
    assert fx.skipped["implausible_date"] == 3 and fx.valid.sum() == 10


# --------------------------------------------------------------------------- host clock
def _host(t: datetime, zone: str = "") -> str:
    return t.strftime("%Y-%m-%dT%H:%M:%S") + zone + " -->> "


def test_host_prefixes_are_recognised_and_counted():
    lines = [ln for k in range(30)
             for ln in epoch(T0 + timedelta(seconds=k),
                             prefix=_host(T0 + timedelta(seconds=k, milliseconds=300)))]
    fx = parse_nmea(lines)
    assert fx.skipped["host_prefixes"] == 60
    assert fx.skipped["binary_segments"] == 0 and fx.skipped["truncated"] == 0
    assert fx.meta["time_base"] == "receiver"           # receiver dates plausible: not used
    assert np.array_equal(fx.t_utc, _utc(T0) + np.arange(30))
    assert fx.meta["host_time"]["zone"].startswith("unspecified")
    _counts_add_up(fx)


def test_host_clock_dates_a_log_without_rmc():
    """GGA-only log with host prefixes: the host supplies the date, the receiver the time
    of day (host 2 s late, in UTC+02:00, still the same UTC day)."""
    lines = [ln for k in range(20) for ln in epoch(
        T0 + timedelta(seconds=k), rmc=False,
        prefix=_host(T0 + timedelta(seconds=k + 2, hours=2), "+02:00"))]
    fx = parse_nmea(lines)
    assert fx.date_known and fx.meta["time_base"] == "host_date"
    assert np.array_equal(fx.t_utc, _utc(T0) + np.arange(20))


def test_host_clock_rescues_default_dated_fixes():
    """Every RMC dated 1980 (the receiver never learned the week), host prefixes plausible:
    dates from the host, time of day from the receiver."""
    lines = [ln for k in range(15) for ln in epoch(
        T0 + timedelta(seconds=k), date="060180", prefix=_host(T0 + timedelta(seconds=k), "Z"))]
    fx = parse_nmea(lines)
    assert fx.meta["time_base"] == "host_date" and fx.valid.sum() == 15
    assert fx.t_utc[0] == _utc(T0)
    assert fx.skipped["implausible_date"] == 0


def test_bare_timestamp_lines_time_the_following_sentences():
    lines = []
    for k in range(10):
        lines.append((T0 + timedelta(seconds=k)).strftime("%Y-%m-%d %H:%M:%S.250"))
        lines += epoch(T0 + timedelta(seconds=k), rmc=False)
    fx = parse_nmea(lines)
    assert fx.skipped["timestamp_lines"] == 10 and fx.skipped["binary_segments"] == 0
    assert fx.meta["time_base"] == "host_date"
    assert np.array_equal(fx.t_utc, _utc(T0) + np.arange(10))
    # the host clock as the time base: the host's times (0.25 s after the fixes)
    fh = parse_nmea(lines, time_base="host")
    assert np.allclose(fh.t_utc, _utc(T0) + 0.25 + np.arange(10))


def test_host_clock_corrects_a_week_rollover_receiver():
    """Receiver dates 1024 weeks behind (the rollover bug), host clock right."""
    t_bug = T0 - timedelta(seconds=WEEK_ROLLOVER_S)
    lines = [ln for k in range(10) for ln in epoch(
        t_bug + timedelta(seconds=k), prefix=_host(T0 + timedelta(seconds=k), "Z"))]
    fx = parse_nmea(lines)
    assert fx.skipped["week_rollover"] == 10
    assert fx.t_utc[0] == _utc(T0)


# --------------------------------------------------------------------------- rollovers
def test_week_rollover_bug_mid_log_is_corrected():
    """A receiver crossing the 2019-04-06 rollover with the bug: its date jumps back 1024
    weeks (to 1999-08-22) and time runs on. Both parts on one time line, counted."""
    t_roll = datetime(2019, 4, 6, 23, 59, 30, tzinfo=UTC)
    before = run(t_roll, 30)
    after = run(t_roll + timedelta(seconds=30) - timedelta(seconds=WEEK_ROLLOVER_S), 50)
    fx = parse_nmea(before + after)
    # the bug only goes back in time: the 1999 part (the larger) is moved forward
    assert fx.skipped["week_rollover"] == 50
    assert np.array_equal(fx.t_utc, _utc(t_roll) + np.arange(80))


def test_correct_receiver_across_the_gps_week_rollover_date():
    t_roll = datetime(2019, 4, 6, 23, 59, 50, tzinfo=UTC)
    fx = parse_nmea(run(t_roll, 20))
    assert np.array_equal(fx.t_utc, _utc(t_roll) + np.arange(20))
    assert fx.skipped["week_rollover"] == 0


def test_midnight_rollover_gga_only_and_with_rmc_every_10_s():
    t = datetime(2021, 12, 31, 23, 59, 40, tzinfo=UTC)
    lines = [ln for k in range(40) for ln in epoch(t + timedelta(seconds=k), rmc=k % 10 == 0)]
    fx = parse_nmea(lines)
    assert np.array_equal(fx.t_utc, _utc(t) + np.arange(40))


# --------------------------------------------------------------------------- reacquisition
def test_reacquisition_jump_is_flagged_and_dropped_from_the_session():
    """Stationary receiver with 0.5 m jitter; after 10 s without a fix the first fix is
    300 m off at a fractional second, the next 60 m off; then it settles on whole seconds."""
    rng = np.random.default_rng(1)
    lines = []
    for k in range(60):
        lines += epoch(T0 + timedelta(seconds=k), north_m=rng.normal(0, 0.5),
                       east_m=rng.normal(0, 0.5))
    lines += [ln for k in range(10) for ln in epoch(None, fix=False)]
    t1 = T0 + timedelta(seconds=70, milliseconds=350)
    lines += epoch(t1, north_m=300.0)
    lines += epoch(T0 + timedelta(seconds=71), north_m=60.0)
    for k in range(72, 130):
        lines += epoch(T0 + timedelta(seconds=k), north_m=rng.normal(0, 0.5),
                       east_m=rng.normal(0, 0.5))
    fx = parse_nmea(lines)
    assert fx.skipped["reacquisition"] == 2
    flagged = fx.t_utc[fx.reacquired]
    assert np.allclose(flagged, [_utc(t1), _utc(T0) + 71])
    off = [d["offset_m"] for d in fx.meta["reacquisitions"]]
    assert off[0] == pytest.approx(300.0, abs=3.0) and off[1] == pytest.approx(60.0, abs=3.0)
    s = session_from_fixes([fx])
    assert s.meta["skipped"]["reacquisition"] == 2
    assert np.nanmax(np.abs(s.obs)) < 5.0               # the jump is not in the data
    assert [r["dropped"] for r in s.meta["receivers"][0]["reacquisitions"]] == [True, True]
    kept = session_from_fixes([fx], reacquisition="keep")
    assert np.nanmax(kept.obs[:, 0, 1]) > 50.0
    # 70.35 s is 0.35 s off the whole-second grid: counted off_grid, not snapped
    assert kept.meta["skipped"]["off_grid"] == 1


def test_slow_convergence_after_the_first_fix_is_not_flagged():
    """A receiver that converges from 8 m to its settled spread (3 m, AR(1) wander) over
    the first 20 s: part of its own error, not a reacquisition jump."""
    rng = np.random.default_rng(2)
    x = np.zeros(400)
    for k in range(1, 400):
        x[k] = 0.98 * x[k - 1] + rng.normal(0, 3.0 * math.sqrt(1 - 0.98 ** 2))
    x[:20] += np.linspace(8.0, 0.0, 20)
    lines = [ln for k in range(400) for ln in epoch(T0 + timedelta(seconds=k), north_m=x[k])]
    assert parse_nmea(lines).skipped["reacquisition"] == 0


# --------------------------------------------------------------------------- heights, fields
def test_height_is_altitude_plus_geoid_separation():
    lines = epoch(T0) + epoch(T0 + timedelta(seconds=1), sep="") + \
        epoch(T0 + timedelta(seconds=2), alt="12.5", sep="+30.25")
    fx = parse_nmea(lines)
    assert fx.height_m[0] == pytest.approx(1708.6 - 21.5, abs=1e-9)
    assert math.isnan(fx.height_m[1])
    assert fx.height_m[2] == pytest.approx(42.75, abs=1e-9)


@pytest.mark.parametrize("field,value", [
    ("lat", "nan"), ("lat", "inf"), ("lon", "-inf"), ("lat", "1e400"), ("lon", "1e3"),
    ("lat", "99999999999999999999999999"), ("lat", "-3947.6"), ("lon", "+10509.2"),
    ("lat", "NaN"), ("alt", "nan"), ("alt", "1e400"), ("alt", "123456789"), ("sep", "inf"),
    ("q", "-1"), ("q", "nan"), ("time", "nan"), ("time", "1e5"), ("time", "246060"),
])
def test_non_numeric_and_huge_fields_are_bad_fields_not_crashes(field, value):
    """The crash class of issue 13: checksum-valid GGA with nan / inf / 1e400 / huge / signed
    numbers used to raise (cannot convert float NaN to integer, OverflowError)."""
    f = {"time": "120000.00", "lat": "3947.65338", "lon": "10509.20216", "q": "1",
         "alt": "1708.6", "sep": "-21.5"}
    f[field] = value
    bad = _cs(f"GPGGA,{f['time']},{f['lat']},N,{f['lon']},W,{f['q']},12,0.67,{f['alt']},M,"
              f"{f['sep']},M,,")
    fx = parse_nmea(run(T0, 3, rmc=False) + [bad])
    assert fx.skipped["bad_fields"] == 1 and fx.valid.sum() == 3
    _counts_add_up(fx)


_FIELD = st.one_of(
    st.sampled_from(["", "nan", "NaN", "inf", "-inf", "1e400", "-0", "+1", "0", "00",
                     "99999999999999999999", "3947.65338", "10509.20216", "120000.00",
                     "235959.99", "240000", "050180", "311299", "290222", "A", "V", "N", "S",
                     "E", "W", "1", "4", "9", "-21.5", "1708.6", "M", "0.1e-3", "..", " 1"]),
    st.text(st.characters(min_codepoint=0x20, max_codepoint=0x7e,
                          blacklist_characters="$*,"), max_size=12))


@settings(max_examples=150, deadline=None)
@given(st.lists(st.tuples(st.sampled_from(["GPGGA", "GNRMC", "GLGGA", "GPRMC"]),
                          st.lists(_FIELD, min_size=0, max_size=15)), min_size=0, max_size=25),
       st.sampled_from(["auto", "receiver", "host"]))
def test_property_arbitrary_checksum_valid_fix_sentences(sentences, time_base):
    """parse_nmea never raises on checksum-valid GGA/RMC with arbitrary fields, and every
    sentence is accounted for exactly once (module docstring identity)."""
    lines = [_cs(head + "," + ",".join(fields)) for head, fields in sentences]
    fx = parse_nmea(lines, time_base=time_base)
    assert fx.meta["fix_sentences"] == len(lines)
    _counts_add_up(fx)
    assert set(fx.skipped) == set(SKIP_CLASSES)
    assert all(v >= 0 for v in fx.skipped.values())
    assert fx.t_utc.size == fx.lat.size == fx.height_m.size == fx.reacquired.size
    assert np.all(np.diff(fx.t_utc) > 0)
    ok = fx.valid
    assert np.all(np.abs(fx.lat[ok]) <= 90) and np.all(np.abs(fx.lon[ok]) <= 180)
    assert not np.isinf(fx.height_m).any()


# --------------------------------------------------------------------------- bounded grid
def test_grid_longer_than_the_limit_is_an_error_not_an_allocation():
    """Fixes every 6 h for 8 days (no step exceeds the era limit, the span does): the
    session refuses before allocating, naming the log and its span."""
    lines = [ln for k in range(33) for ln in epoch(T0 + timedelta(hours=6 * k))]
    fx = parse_nmea(lines, name="long")
    assert fx.valid.sum() == 33
    with pytest.raises(ValueError, match=r"'long'.*8\.0 days.*max_span_s"):
        session_from_fixes([fx], rate_hz=1.0)
    s = session_from_fixes([fx], rate_hz=1 / 3600, max_span_s=9 * 86400)
    assert s.n == 8 * 24 + 1


def test_logs_far_apart_forced_onto_one_utc_grid_are_refused():
    a = parse_nmea(run(T0, 10), name="a")
    b = parse_nmea(run(T0.replace(year=2022), 10), name="b")
    assert session_from_fixes([a, b]).meta["alignment"] == "independent"
    with pytest.raises(ValueError, match="max_span_s"):
        session_from_fixes([a, b], alignment="utc")


def test_rate_above_the_limit_is_refused():
    fx = parse_nmea(run(T0, 10))
    with pytest.raises(ValueError, match="rate_hz"):
        session_from_fixes([fx], rate_hz=1e6)
    with pytest.raises(ValueError, match="rate_hz"):
        session_from_fixes([fx], rate_hz=math.inf)


# --------------------------------------------------------------------------- files
def test_find_logs_scans_any_folder(tmp_path):
    (tmp_path / "a" / "b").mkdir(parents=True)
    (tmp_path / "a" / "b" / "rx.nmea").write_text("\n".join(run(T0, 5)) + "\n")
    (tmp_path / "top.txt").write_text("2017-05-25T16:04:28 -->> " + run(T0, 1)[0] + "\n")
    (tmp_path / "notes.md").write_text("no sentences here, $ only\n")
    (tmp_path / "uwb.csv").write_text("t,x,y\n0,1,2\n")
    (tmp_path / "run.csv").write_text("HOSTNAME, CLOCK, TIME, LATITUDE, LONGITUDE, WGS84\n")
    (tmp_path / ".git").mkdir()
    (tmp_path / ".git" / "x.log").write_text(run(T0, 1)[0])
    logs, other = find_logs(tmp_path)
    assert [p.name for p in logs] == ["rx.nmea", "run.csv", "top.txt"]
    assert sorted(p.name for p in other) == ["notes.md", "uwb.csv"]
    assert log_format(tmp_path / "run.csv") == "tumbleweed_csv"
    with pytest.raises(ValueError, match="root"):
        find_logs(tmp_path / "missing")


def test_tumbleweed_heights_and_implausible_rows(tmp_path):
    rows = [("HOSTNAME, OBSERVATION, CLOCK, TIME, LATITUDE, LONGITUDE, HORIZONTAL, MSL, WGS84, "
             "VERTICAL, SPEED, COURSE")]
    t0 = _utc(T0)
    for k in range(8):
        tt = 315964800 + k if k < 2 else t0 + k          # two rows at the 1980 GPS epoch
        rows.append(f'"gold", {k}, {t0 + k + 0.05:.6f}, {tt:.9f}, 39.79, -105.15, 1.1, '
                    f"1702.6, {'nan' if k == 7 else '1681.1'}, 2.0, 0.0, 0.0")
    p = tmp_path / "benchmark.csv"
    p.write_text("\n".join(rows) + "\n")
    fx = read_log(p)
    # CLOCK (host time) is plausible for every row: the 1980 TIME rows are stale, re-timed
    assert fx.meta["stale_time_rows"] == 2
    assert np.allclose(fx.t_utc, t0 + np.arange(8), atol=1e-3)
    assert np.allclose(fx.height_m[:7], 1681.1) and math.isnan(fx.height_m[7])
    s = import_session([p])
    assert s.n == 8 and s.present.all()


_EPOCH = st.tuples(
    st.integers(0, 86399),                                   # time of day, s
    st.sampled_from([None, "050180", "100180", "200821", "210821", "200803", "040100",
                     "070419", "220899"]),                   # RMC date (None: GGA only)
    st.booleans(),                                           # fix
    st.sampled_from(["", "2021-08-20T18:49:26 -->> ", "1970-01-01T00:00:05Z ",
                     "2021-08-21 03:00:00+02:00: "]),        # host prefix
    st.integers(0, 3))                                       # repeats of the epoch


@settings(max_examples=100, deadline=None)
@given(st.lists(_EPOCH, max_size=40), st.sampled_from(["auto", "receiver", "host"]))
def test_property_arbitrary_time_lines(epochs, time_base):
    """Any sequence of epochs with default, real, rolled-over or missing dates and times,
    fixes or not, host prefixes or not, repeated: no exception; the output time line is
    strictly increasing, dated times are plausible, every sentence is accounted for, and a
    session either grids it within the span limit or refuses with a ValueError."""
    lines = []
    for tod, d, fix, prefix, rep in epochs:
        ts = f"{tod // 3600:02d}{tod // 60 % 60:02d}{tod % 60:02d}.00"
        for _ in range(1 + rep % 2):
            lines += epoch(None, fix=fix, tod=ts, date=d or "", rmc=d is not None, prefix=prefix)
    fx = parse_nmea(lines, time_base=time_base, latest_date=datetime(2030, 1, 1).date())
    _counts_add_up(fx)
    assert np.all(np.diff(fx.t_utc) > 0)
    if fx.date_known and fx.t_utc.size:
        assert fx.t_utc.min() >= datetime(1983, 1, 1, tzinfo=UTC).timestamp()
    if fx.valid.any():
        try:
            s = session_from_fixes([fx])
        except ValueError as exc:
            assert "max_span_s" in str(exc) or "rate" in str(exc) or "reacquisition" in str(exc)
        else:
            assert s.t[-1] - s.t[0] <= 7 * 86400


# --------------------------------------------------------------------------- bad arguments
def test_bad_arguments_name_the_argument():
    fx = parse_nmea(run(T0, 5))
    with pytest.raises(TypeError, match="lines"):
        parse_nmea("$GPGGA,...")
    with pytest.raises(TypeError, match="lines"):
        parse_nmea([1, 2])
    with pytest.raises(ValueError, match="time_base"):
        parse_nmea([], time_base="gps")
    with pytest.raises(ValueError, match="max_span_s"):
        parse_nmea([], max_span_s=math.nan)
    with pytest.raises(TypeError, match="latest_date"):
        parse_nmea([], latest_date="2021-01-01")
    with pytest.raises(TypeError, match="logs"):
        session_from_fixes([fx, "rx2"])
    with pytest.raises(ValueError, match="logs"):
        session_from_fixes(fx)
    with pytest.raises(ValueError, match="max_span_s"):
        session_from_fixes([fx], max_span_s=-1.0)
    with pytest.raises(ValueError, match="max_span_s"):
        session_from_fixes([fx], max_span_s=math.inf)      # memory must stay bounded
    with pytest.raises(TypeError, match="rate_hz"):
        session_from_fixes([fx], rate_hz="1")
    with pytest.raises(ValueError, match="reacquisition"):
        session_from_fixes([fx], reacquisition="maybe")


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.floats(-90, 90) | st.just(math.nan),
                          st.floats(-180, 180) | st.just(math.nan)), max_size=40),
       st.floats(1e-3, 1e3), st.floats(0, 1e6))
def test_property_flag_reacquisitions_never_raises(points, sigmas, floor_m):
    """Any positions in range (and NaN), any positive threshold: flags only fixes, offsets
    only where flagged and above the threshold's floor."""
    t = np.arange(len(points), dtype=float)
    lat = np.array([p[0] for p in points]) if points else np.zeros(0)
    lon = np.array([p[1] for p in points]) if points else np.zeros(0)
    flags, off = flag_reacquisitions(t, lat, lon, sigmas=sigmas, floor_m=floor_m)
    assert flags.shape == t.shape and not flags[~(np.isfinite(lat) & np.isfinite(lon))].any()
    assert np.all(off[flags] > floor_m) and np.isnan(off[~flags]).all()


def test_flag_reacquisitions_bad_inputs():
    t = np.arange(5.0)
    with pytest.raises(ValueError, match="lat"):
        flag_reacquisitions(t, np.full(5, 95.0), np.zeros(5))
    with pytest.raises(ValueError, match="lon"):
        flag_reacquisitions(t, np.zeros(5), np.zeros(4))
    with pytest.raises(ValueError, match="t"):
        flag_reacquisitions(t[::-1], np.zeros(5), np.zeros(5))
    with pytest.raises(ValueError, match="lookahead"):
        flag_reacquisitions(t, np.zeros(5), np.zeros(5), lookahead=1)
