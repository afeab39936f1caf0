"""sim.recording: multi-antenna recordings from real log files, scored against a reference.

The synthetic rig of tests/synth_recording.py is written as NMEA, tumbleweed CSV and text
logs from a closed-form trajectory, so every number read back has a known value.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from synth_recording import EPSG, LAYOUT, T0_UTC, write_rig

from estimator.configuration import LayoutWarning, SensorConfig
from estimator.metrics import evaluate_track
from estimator.tracking import track
from sim.nmea import LogFixes
from sim.recording import (
    Recording,
    RecordingError,
    load_recording,
    read_antenna_log,
    read_text_log,
    recording_files,
)

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    folder = tmp_path_factory.mktemp("rig")
    return write_rig(folder)


@pytest.fixture(scope="module")
def rec(rig):
    return load_recording(rig.files["toml"])


def _origin(rec: Recording) -> np.ndarray:
    fr = rec.meta["frame"]
    assert fr["epsg"] == EPSG
    return np.array([fr["origin_easting_m"], fr["origin_northing_m"]])


def _mirrored(cfg: SensorConfig) -> SensorConfig:
    B = cfg.body_positions.copy()
    B[:, 1] = -B[:, 1]
    return SensorConfig(cfg.names, B, cfg.cg_members, cfg.dead, name=f"{cfg.name}_mirror")


# --------------------------------------------------------------------------- loading
def test_shipped_synthetic_rig_is_the_generators_output(tmp_path):
    rig = write_rig(tmp_path / "synthetic_rig", toml=tmp_path / "synthetic_rig.toml")
    shipped = REPO / "models" / "recordings"
    for p in rig.files.values():
        rel = p.relative_to(tmp_path)
        assert (shipped / rel).read_bytes() == p.read_bytes(), rel


def test_recording_reads_back_what_was_written(rig, rec):
    """Positions equal the written ones to the logs' precision (NMEA: 1e-7 arc-minutes =
    0.19 mm; text 1e-9..1e-10 degrees), missing fixes stay NaN (no interpolation), and
    every valid fix of every log is accounted for."""
    assert rec.n == 90 and rec.m == 4 and rec.meta["t0_utc"] == T0_UTC
    np.testing.assert_array_equal(rec.t, np.arange(90.0))
    obs = rec.obs + _origin(rec)
    assert np.array_equal(np.isnan(obs), np.isnan(rig.observed))
    assert np.nanmax(np.abs(obs - rig.observed)) < 3e-4
    for name, info in rec.meta["logs"].items():
        c = info["counts"]
        assert c["aligned"] + c["off_grid"] + c["outside_grid"] + c["duplicate_on_grid"] \
            + c["reacquired"] == info["fixes"], name
        assert c["interpolated"] == 0
    assert rec.meta["logs"]["1"]["skipped"]["bad_checksum"] == 1
    assert rec.meta["logs"]["1"]["skipped"]["truncated"] == 1
    assert rec.meta["logs"]["1"]["skipped"]["comment_lines"] == 1
    assert rec.meta["logs"]["2"]["fixes"] == 85            # the 5 s gap
    assert rec.meta["logs"]["2"]["format"] == "tumbleweed_csv"
    assert rec.meta["logs"]["3"]["format"] == "text" and rec.meta["logs"]["4"]["format"] == "text"
    # heights from the text logs (the NMEA and tumbleweed readers give none yet)
    assert np.nanmax(np.abs(rec.height_m[:, 2:] - 520.0)) < 1e-9


def test_reference_pose_is_the_trajectory(rig, rec):
    """Pose of the reference antennas by the rigid fit: CG and yaw equal the closed-form
    trajectory (text positions at 1e-10 degrees: < 1e-4 m, yaw < 1e-5 rad); the layout
    fits the reference to 1e-4 m and its mirror image by ~1 m (the rig's width)."""
    truth = rec.truth()
    assert np.abs(truth.cg[:, :2] + _origin(rec) - rig.cg).max() < 1e-4
    assert np.abs(np.angle(np.exp(1j * (truth.yaw - rig.yaw)))).max() < 1e-5
    assert rec.reference.meta["residual_median_m"] < 1e-4
    assert rec.reference.meta["mirror_residual_median_m"] > 0.5
    assert "warning" not in rec.reference.meta
    # the turn (t = 30..40 s) is flagged, delayed by the detector's half span (4 s)
    turning = np.flatnonzero(truth.turning)
    assert 30 <= turning.min() <= 36 and 40 <= turning.max() <= 48


def test_track_and_metrics_on_the_recording(rig, rec):
    """window 1, 0.1 m independent errors per axis on 4 antennas (3 at the ends): the CG
    error per axis has std 0.1 / sqrt(4) = 0.05 m, Euclidean mean 0.05 sqrt(pi / 2) =
    0.063 m; heading std 0.1 / sqrt(sum |b_i - b|^2) = 0.1 / 1.80 = 0.055 rad. Bounds
    0.1 m and 0.09 rad leave ~60 % margin (90 samples: the means vary by ~5 %)."""
    truth = rec.truth()
    est = track(rec.t, rec.obs, rec.config, window=1)
    assert est.attrs["layout_check"]["mirror_verdict"] == "consistent"
    assert est.attrs["layout_check"]["forward_verdict"] == "consistent"
    assert est.attrs["warnings"] == []
    scores = evaluate_track(est, truth.t, truth.cg, truth.yaw, truth.turning)
    full = scores[scores["mask"] == "full"].set_index("quantity")
    assert full.loc["euclid", "mean"] < 0.1
    assert full.loc["yaw", "mean"] < 0.09
    assert full.loc["euclid", "n"] == 90 and full.loc["euclid", "n_nan"] == 0


def test_tiny_sweep_on_a_recording_writes_the_same_tables(rig, rec, tmp_path):
    """The sweep scores a recording cell with estimator.metrics: its numbers equal a direct
    track + evaluate_track on the recording, to round-off."""
    from experiments.spec import Spec
    from experiments.sweep import run

    spec = Spec.from_dict({"name": "rec", "seeds": 1, "grid": [
        {"recording": str(rig.files["toml"]), "window": [1, 5],
         "technique": ["none", "lc", "ekf"]}]}, source="test")
    cells = spec.expand()
    assert {c.path for c in cells} == {"recording-rig"}
    assert {c.config for c in cells} == {"rover_gps4"} and {c.noise for c in cells} == {"recording"}
    res = run(spec, out=tmp_path / "out", jobs=1, progress=False, outputs=False)
    assert res.n_failed == 0, res.errors
    df = res.cells
    from experiments.tables import write_tables

    md = write_tables(df, tmp_path / "out").read_text()    # the sweep's tables, unchanged
    assert "recording-rig" in md and "Table 4.1" in md
    row = df[(df.window == 1) & (df.technique == "none") & (df["mask"] == "full")].iloc[0]
    truth = rec.truth()
    est = track(rec.t, rec.obs, rec.config, window=1)
    s = evaluate_track(est, truth.t, truth.cg, truth.yaw).set_index("quantity")
    assert row["eu_mean"] == pytest.approx(s.loc["euclid", "mean"], rel=1e-12)
    assert row["eh_mean"] == pytest.approx(s.loc["yaw", "mean"], rel=1e-12)
    assert row["n_reference"] == 90
    assert set(df["layout_mirror_verdict"]) == {"consistent"}
    assert np.isfinite(df["ex_mean"]).all()


def test_recording_without_reference_gets_coverage_rows(rig, tmp_path):
    from experiments.spec import Spec
    from experiments.sweep import run

    text = rig.files["toml"].read_text().split("[[reference.antenna]]")[0]
    noref = rig.files["toml"].parent / "noref.toml"     # beside the logs it names
    noref.write_text(text)
    rec = load_recording(noref)
    assert rec.reference is None
    with pytest.raises(RecordingError, match="no reference"):
        rec.truth()
    spec = Spec.from_dict({"name": "noref", "seeds": 1, "masks": ["full"], "grid": [
        {"recording": str(noref), "window": 3, "technique": ["none", "naive"]}],
        "epochs": {"seeds": [0]}}, source="t")
    res = run(spec, out=tmp_path / "out", jobs=1, progress=False, outputs=False)
    assert res.n_failed == 0, res.errors
    df = res.cells
    assert list(df["mask"]) == ["full", "full"]
    from experiments.tables import write_tables

    write_tables(df, tmp_path / "out")        # NaN error statistics keep the tables' shape
    assert (df["n_epochs"] == 88).all() and (df["n_reference"] == 0).all()
    assert df["ex_mean"].isna().all() and df["eh_p95"].isna().all()
    assert (df["n_valid"] + df["n_nan"] == df["n_epochs"]).all()
    assert not df["has_epochs"].any()      # per-epoch files need a reference (figures)


# --------------------------------------------------------------------------- mirror / handedness
def test_mirrored_layout_is_reported_by_track_the_reference_and_the_sweep(rig, rec, tmp_path):
    """The mirror image of rover_gps4 has the same distances: the fit cannot refuse it,
    but with 0.1 m errors on a 1.5 m x 1 m layout the data prefer the real hand by far."""
    mir = _mirrored(rec.config)
    with pytest.warns(LayoutWarning, match="layout may be mirrored"):
        est = track(rec.t, rec.obs, mir, window=1)
    lc = est.attrs["layout_check"]
    assert lc["mirror_verdict"] == "mirrored" and lc["mirror_fraction"] > 0.5
    assert lc["mirror_objective_ratio"] < 0.5
    mrec = load_recording(rig.files["toml"], config=mir)
    assert "MIRROR" in mrec.reference.meta["warning"]
    # a config override in a sweep block: same recording, mirrored layout
    cfg_file = tmp_path / "mirror4.toml"
    import tomli_w

    cfg_file.write_text(tomli_w.dumps(mir.to_dict()))
    from experiments.spec import Spec
    from experiments.sweep import run

    spec = Spec.from_dict({"name": "mir", "seeds": 1, "masks": ["full"], "grid": [
        {"recording": str(rig.files["toml"]), "window": 1, "config": str(cfg_file)}]},
        source="t")
    res = run(spec, out=tmp_path / "out", jobs=1, progress=False, outputs=False)
    assert res.n_failed == 0, res.errors
    assert list(res.cells["layout_mirror_verdict"]) == ["mirrored"]
    assert res.cells["config"].iloc[0] == mir.name     # a file is labelled by its model's name


def test_from_distances_with_an_observed_snapshot_recovers_the_real_hand(rig, rec):
    """Distances measured to 1 cm give the layout up to a reflection; one epoch of the RTK
    reference on the first straight (heading east, 0 rad) fixes hand and forward axis."""
    cfg = rec.config
    rng = np.random.default_rng(5)
    E = np.triu(rng.normal(0.0, 0.01, (4, 4)), 1)
    D = cfg.distances() + E + E.T
    k = 10
    observed = rec.reference.positions[k]
    got = SensorConfig.from_distances(cfg.names, D, observed=observed,
                                      heading=float(rec.truth().yaw[k]),
                                      cg_members=cfg.cg_members)
    assert np.abs(got.body_positions - cfg.body_positions).max() < 0.03
    est = track(rec.t, rec.obs, got, window=1)
    assert est.attrs["layout_check"]["mirror_verdict"] == "consistent"


# --------------------------------------------------------------------------- replay as truth
def _consumer_log(path: Path, n: int, seed: int = 0) -> Path:
    """A one-receiver text log with a 1 m AR(1) error (tau 20 s) around a fixed point."""
    from sim.gps import gauss_markov

    rng = np.random.default_rng(seed)
    err = gauss_markov(n, (2,), 1.0, 20.0, 1.0, rng)
    lat = 48.0 + err[:, 1] / 111_200.0
    lon = 11.0 + err[:, 0] / (111_200.0 * math.cos(math.radians(48.0)))
    rows = [f"{1_700_000_000 + k},{lat[k]:.10f},{lon[k]:.10f}" for k in range(n)]
    path.write_text("\n".join(rows) + "\n")
    return path


def test_replay_recording_is_reference_plus_replayed_error(rig, tmp_path):
    """Surveyed reference positions (a stationary rig) + one consumer log replayed as
    decorrelated segments: each seed draws other segments; the reference stays."""
    log = _consumer_log(tmp_path / "consumer.csv", 1200)
    ll = {}
    from pyproj import Transformer

    tr = Transformer.from_crs(f"EPSG:{EPSG}", "EPSG:4326", always_xy=True)
    for j, name in enumerate(LAYOUT):
        lo, la = tr.transform(*rig.antennas[0, j])
        ll[name] = (la, lo)
    lines = ['name = "survey"', 'config = "rover_gps4"', "",
             "[replay]", f'logs = ["{log}"]', 'mode = "shifted"', "duration_s = 200", ""]
    for name, (la, lo) in ll.items():
        lines += ["[[reference.antenna]]", f'name = "{name}"', f"latitude = {la!r}",
                  f"longitude = {lo!r}", ""]
    toml = tmp_path / "survey.toml"
    toml.write_text("\n".join(lines))
    rec = load_recording(toml)
    assert rec.obs is None and rec.n == 200 and rec.meta["t0_utc"] is None
    a = rec.observations(np.random.default_rng(1))
    b = rec.observations(np.random.default_rng(2))
    assert not np.allclose(a, b)
    ref = rec.reference.positions
    err = a - ref
    assert 0.2 < np.nanstd(err) < 3.0                      # the log's 1 m error
    assert rec.reference.meta["residual_median_m"] < 1e-6  # the survey is rigid
    with pytest.raises(TypeError, match="rng"):
        rec.observations()
    from experiments.spec import Spec
    from experiments.sweep import run

    spec = Spec.from_dict({"name": "rt", "seeds": 2, "masks": ["full"], "grid": [
        {"recording": str(toml), "window": 10}]}, source="t")
    assert {c.noise for c in spec.expand()} == {"replay:shifted"}
    res = run(spec, out=tmp_path / "out", jobs=1, progress=False, outputs=False)
    assert res.n_failed == 0, res.errors
    assert res.cells["eu_mean"].nunique() == 2                 # the seeds differ
    assert str(log) in {str(p) for p in recording_files(toml)}


# --------------------------------------------------------------------------- alignment
def _fixes(name: str, t: np.ndarray, xy_m: np.ndarray, date_known: bool = True) -> LogFixes:
    lat = 48.0 + xy_m[:, 1] / 111_200.0
    lon = 11.0 + xy_m[:, 0] / 74_400.0
    return LogFixes(name=name, t_utc=np.asarray(t, float), lat=lat, lon=lon,
                    quality=np.ones(len(t), np.int64), date_known=date_known)


def _two(t1, t2, **kw) -> Recording:
    cfg = SensorConfig(["a", "b"], [[0.5, 0.0], [-0.5, 0.0]])
    z1 = np.zeros((len(t1), 2))
    z2 = np.zeros((len(t2), 2)) + [1.0, 0.0]
    return Recording.from_logs({"a": _fixes("a", t1, z1), "b": _fixes("b", t2, z2)}, cfg, **kw)


def test_alignment_counts_off_grid_duplicates_and_gaps():
    base = 1.7e9 + np.arange(20.0)
    t2 = np.r_[base[:5], base[5] + 0.4, base[6] + 0.1, base[6] + 0.2, base[7:10], base[14:]]
    rec = _two(base, t2)
    c = rec.meta["logs"]["b"]["counts"]
    assert c == {"aligned": 15, "off_grid": 1, "outside_grid": 0, "duplicate_on_grid": 1,
                 "interpolated": 0, "reacquired": 0}
    assert rec.meta["logs"]["b"]["fixes"] == sum(c.values())
    present = ~np.isnan(rec.obs[:, 1, 0])
    assert not present[5] and present[6] and not present[10:14].any()
    # the explicit interpolation option fills the 0.4 s-off epoch, never the 4 s gap
    rec2 = _two(base, t2, interpolate=True)
    p2 = ~np.isnan(rec2.obs[:, 1, 0])
    assert p2[5] and not p2[10:14].any()
    assert rec2.meta["logs"]["b"]["counts"]["interpolated"] == 1


@pytest.mark.parametrize("t1, t2, kw, match", [
    (1.7e9 + np.arange(5.0), 3.2e8 + np.arange(5.0), {}, "never overlap"),
    (1.7e9 + np.arange(5.0), 1.7e9 + np.r_[0.0, 1.0, 9e5], {}, "MAX_GRID_DAYS"),
    (1.7e9 + np.arange(5.0), 1.7e9 + np.arange(5.0), {"max_offset_s": 0.6}, "max_offset_s"),
    (1.7e9 + np.arange(5.0), 1.7e9 + np.arange(5.0), {"rate_hz": 0.0}, "rate_hz"),
    (1.7e9 + np.arange(5.0), 1.7e9 + np.arange(5.0), {"rate_hz": 1e9}, "rate_hz: must be"),
    # 5.8 days at the largest rate, 100 Hz, 2 antennas: 1.6 GB
    (1.7e9 + np.r_[0.0, 1.0, 5e5], 1.7e9 + np.r_[0.0, 1.0, 5e5], {"rate_hz": 100.0},
     "MAX_GRID_BYTES"),
])
def test_alignment_errors_name_the_cause(t1, t2, kw, match):
    with pytest.raises((RecordingError, ValueError), match=match):
        _two(t1, t2, **kw)


def test_dated_and_undated_logs_do_not_mix():
    cfg = SensorConfig(["a", "b"], [[0.5, 0.0], [-0.5, 0.0]])
    t = 1.7e9 + np.arange(5.0)
    z = np.zeros((5, 2))
    with pytest.raises(RecordingError, match=r"\['b'\] have no date"):
        Recording.from_logs({"a": _fixes("a", t, z), "b": _fixes("b", t, z, False)}, cfg)
    with pytest.raises(RecordingError, match=r"without a log \['b'\]"):
        Recording.from_logs({"a": _fixes("a", t, z)}, cfg)


# --------------------------------------------------------------------------- text reader
def test_text_reader_variants_and_counts(tmp_path):
    p = tmp_path / "a.txt"
    p.write_text("# comment\n"
                 "Latitude; Longitude; UTC; quality\n"
                 "48.1; 11.5; 2024-03-01T12:00:00+01:00; 4\n"
                 "48.1; 11.5; 2024-03-01T11:00:01Z; 4\n"
                 "48.1; 11.5; 2024-03-01T11:00:01Z; 4\n"      # duplicate
                 "48.1; 11.5; 2024-03-01T11:00:00.5Z; 4\n"    # reversal
                 "91.0; 11.5; 2024-03-01T11:00:02Z; 4\n"      # latitude out of range
                 "48.1; 11.5; 1975-01-01T00:00:00Z; 4\n"      # before the GPS epoch
                 "48.1; eleven; 2024-03-01T11:00:03Z; 4\n"    # not a number
                 "48.1; 11.5; 2024-03-01T11:00:04Z\n")        # column missing
    lf = read_text_log(p)
    t0 = 1709290800.0
    np.testing.assert_array_equal(lf.t_utc, [t0, t0 + 1])
    assert lf.skipped == {"comment_lines": 1, "bad_fields": 3, "implausible_time": 1,
                          "duplicate_epochs": 1, "time_reversals": 1}
    assert lf.meta["ignored_columns"] == ["quality"] and lf.meta["bad_lines"] == [7, 8, 9, 10]
    assert np.isnan(lf.height_m).all()
    assert read_antenna_log(p).name == "a"


@pytest.mark.parametrize("text, match", [
    ("", "no valid row"),
    ("time,lat\n1,2\n", r"no \['longitude'\] column"),
    ("1 2 3 4 5\n", "5 columns and the file has no header"),
    ("# only comments\n", "no valid row"),
])
def test_text_reader_errors_name_the_file(tmp_path, text, match):
    p = tmp_path / "bad.txt"
    p.write_text(text)
    with pytest.raises(RecordingError, match=match) as info:
        read_text_log(p)
    assert "bad.txt" in str(info.value)


@settings(max_examples=60, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.lists(st.text(alphabet=st.characters(codec="utf-8", exclude_categories=("Cs",)),
                        max_size=40), max_size=8),
       st.sampled_from([",", ";", " ", "\t"]))
def test_text_reader_never_crashes(tmp_path, lines, sep):
    p = tmp_path / "fuzz.txt"
    p.write_text("\n".join([sep.join(["1.7e9", "48", "11"])] + lines) + "\n")
    try:
        lf = read_text_log(p)
    except RecordingError:
        return
    assert np.isfinite(lf.t_utc).all() and np.all(np.diff(lf.t_utc) > 0)
    assert (np.abs(lf.lat) <= 90).all() and (np.abs(lf.lon) <= 180).all()


@settings(max_examples=40, deadline=None)
@given(n=st.integers(1, 6), m=st.integers(2, 4),
       fill=st.sampled_from([0.0, math.nan, math.inf, 1e300, -1e300]))
def test_recording_constructor_validates(n, m, fill):
    cfg = SensorConfig([str(k) for k in range(m)], np.c_[np.arange(m), np.zeros(m)])
    obs = np.full((n, m, 2), fill)
    try:
        rec = Recording(t=np.arange(float(n)), config=cfg, obs=obs)
    except (RecordingError, TypeError) as exc:
        assert "obs" in str(exc)
        assert math.isinf(fill)
        return
    assert rec.observations().shape == (n, m, 2)


_EXT = st.sampled_from([0.0, -0.0, 1.0, -1.0, 89.9, 90.0, 91.0, 180.0, -181.0, 1e300, -1e300,
                        math.nan, math.inf, -math.inf])


@settings(max_examples=60, deadline=None)
@given(lat=_EXT, lon=_EXT, dt=st.sampled_from([1.0, 0.5, 1e-9, 86400.0 * 30, -1.0]),
       k=st.integers(0, 4))
def test_from_logs_extremes_raise_recording_errors_or_give_finite_arrays(lat, lon, dt, k):
    cfg = SensorConfig(["a", "b"], [[0.5, 0.0], [-0.5, 0.0]])
    t = 1.7e9 + np.arange(5.0)
    z = np.zeros((5, 2))
    fa = _fixes("a", t, z)
    fb = _fixes("b", t, z)
    fb.lat = fb.lat.copy()
    fb.lon = fb.lon.copy()
    fb.lat[k], fb.lon[k] = lat, lon
    fb.t_utc = fb.t_utc.copy()
    fb.t_utc[k:] += dt - 1.0 if k else 0.0
    try:
        rec = Recording.from_logs({"a": fa, "b": fb}, cfg)
    except (RecordingError, TypeError) as exc:
        assert str(exc)
        return
    assert np.isfinite(rec.obs[~np.isnan(rec.obs)]).all() and rec.n <= 7 * 86400 * 2 + 1


@pytest.mark.parametrize("change, match", [
    ({"colour": "red"}, "unknown key"),
    ({"config": None}, "config: required"),
    ({"interpolate": "yes"}, "interpolate"),
    ({"rate_hz": -1}, "rate_hz"),
    ({"antenna": [{"name": "1"}]}, r"antenna\[0\].log: required"),
    ({"antenna": [{"name": "1", "log": "nope.nmea"}]}, "no such file"),
    ({"replay": {"logs": ["x"], "mode": "mirror"}}, "no such file|replay"),
])
def test_recording_toml_errors_name_the_field(rig, tmp_path, change, match):
    import tomllib

    import tomli_w

    data = tomllib.loads(rig.files["toml"].read_text())
    for k, v in change.items():
        if v is None:
            data.pop(k)
        else:
            data[k] = v
    p = rig.files["toml"].parent / f"bad_{tmp_path.name}.toml"    # beside the logs
    p.write_text(tomli_w.dumps(data))
    with pytest.raises(RecordingError, match=match):
        load_recording(p)


_TVAL = st.one_of(st.booleans(), st.integers(-5, 5), st.floats(allow_nan=False),
                  st.text(max_size=4), st.lists(st.integers(0, 3), max_size=2))


@settings(max_examples=80, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(top=st.dictionaries(st.sampled_from(["name", "config", "rate_hz", "max_offset_s",
                                            "interpolate", "bogus"]), _TVAL, max_size=4),
       ants=st.lists(st.dictionaries(st.sampled_from(["name", "log", "format", "latitude"]),
                                     _TVAL, max_size=3), max_size=3),
       replay=st.one_of(st.none(), st.dictionaries(
           st.sampled_from(["logs", "mode", "shift_s", "model", "duration_s"]), _TVAL,
           max_size=3)))
def test_load_recording_fuzz_raises_recording_errors(tmp_path, top, ants, replay):
    import tomli_w

    data = dict(top)
    if ants:
        data["antenna"] = ants
    if replay is not None:
        data["replay"] = replay
    p = tmp_path / "fuzz.toml"
    p.write_text(tomli_w.dumps(data))
    with pytest.raises((RecordingError, TypeError)):
        load_recording(p)


def test_unknown_recording_name_lists_known():
    with pytest.raises(RecordingError, match="known names: .*synthetic_rig"):
        load_recording("no_such_recording")


def test_example_recording_preset_loads():
    from experiments.spec import load_spec

    spec = load_spec("example_recording")
    cells = spec.expand()
    assert {c.recording for c in cells} == {"synthetic_rig"}
    assert {c.path for c in cells} == {"recording-synthetic_rig"}
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rec = load_recording("synthetic_rig")
    assert rec.reference is not None and rec.reference.kind == "antennas"


# --------------------------------------------------------------------------- real logs
def test_worked_example_on_real_logs(realdata_dir, tmp_path):
    """The README's worked example, one seed, window 1: RTK error replayed onto the
    surveyed 1 m square. Duplicated error leaves heading exact (round-off); decorrelated
    mm-level error leaves it within a degree (0.17 deg measured); the mirrored layout
    (wrong antenna named left) is reported and costs more than 90 degrees (128 measured)."""
    import tomli_w

    from experiments.spec import Spec
    from experiments.sweep import run

    c = SensorConfig.load("home_square4")
    bad = SensorConfig.from_distances(c.names, c.distances(), forward=("SW", "NW"), left="NE",
                                      cg_members=c.cg_members, name="wrong_left")
    (tmp_path / "wrong_left.toml").write_text(tomli_w.dumps(bad.to_dict()))
    spec = Spec.from_dict({"name": "hs", "seed": 7, "seeds": 1, "masks": ["full"], "grid": [
        {"recording": "home_square_rtk", "window": 1,
         "noise_overrides": [{"replay": "shifted"}, {"replay": "identical"}]},
        {"recording": "home_square_rtk", "window": 1, "config": "wrong_left.toml"}]},
        source="t", base_dir=tmp_path)
    res = run(spec, out=tmp_path / "out", jobs=1, progress=False, outputs=False)
    assert res.n_failed == 0, res.errors
    df = res.cells.set_index(["config", "noise"])
    assert df.loc[("home_square4", "replay:identical"), "eh_max"] < 1e-9
    right = df.loc[("home_square4", "replay:shifted")]
    assert right["eh_mean"] < math.radians(1.0) and right["layout_mirror_verdict"] == "consistent"
    wrong = df.loc[("wrong_left", "replay:shifted")]
    assert wrong["eh_mean"] > math.radians(90.0) and wrong["layout_mirror_verdict"] == "mirrored"


def test_spec_rejects_path_or_noise_beside_a_recording():
    from experiments.spec import Spec, SpecError

    for extra in ({"path": "square20"}, {"noise": "gps_stationary"},
                  {"noise_overrides": {"replay": "identical"}}):
        with pytest.raises(SpecError, match="path|noise"):
            Spec.from_dict({"name": "x", "grid": [{"recording": "synthetic_rig", "window": 1,
                                                   **extra}]}, source="t")


def test_sweep_replays_one_session_onto_every_antenna(tmp_path):
    """``noise = "session:<file>"`` with a one-receiver session: by receiver it fails naming
    the modes (recorded as the cell's error); ``noise_overrides = {replay = ...}`` runs."""
    from experiments.spec import Spec, SpecError
    from experiments.sweep import run
    from sim.gps import StationarySession
    from sim.truth import Truth

    cfg = SensorConfig.load("rover_gps4")
    n = 60

    def truth_fn(path_file, path_overrides, config_file, sim_seed, cache_dir=None):
        t = np.arange(float(n))
        sp = np.zeros((n, 4, 3))
        sp[..., :2] = cfg.body_positions[None] + np.c_[t, 0 * t][:, None, :]
        return Truth(t=t, sensor_positions=sp, sensor_names=cfg.names, cg=sp.mean(axis=1),
                     yaw=np.zeros(n), speed=np.ones(n), yaw_rate=np.zeros(n),
                     turning=np.zeros(n, bool))

    rng = np.random.default_rng(0)
    sess = StationarySession(np.arange(400.0), rng.normal(0, 1.0, (400, 1, 2)), ("rx",))
    sess.save(tmp_path / "one.npz")
    grid = {"path": "square20", "config": "rover_gps4", "noise": "session:one.npz",
            "window": 1}
    spec = Spec.from_dict({"name": "one", "seeds": 1, "masks": ["full"], "grid": [
        dict(grid, noise_overrides=[{}, {"replay": "shifted"}, {"replay": "identical"}])]},
        source="t", base_dir=tmp_path)
    res = run(spec, out=tmp_path / "out", jobs=1, progress=False, outputs=False,
              truth_fn=truth_fn)
    assert res.n_failed == 1 and "1 receiver(s) for 4 antennas" in res.errors[0]["error"]
    eh = res.cells.set_index("noise_overrides")["eh_mean"]
    assert eh['{"replay":"identical"}'] < 1e-9 < eh['{"replay":"shifted"}']
    with pytest.raises(SpecError, match="noise_overrides.replay"):
        Spec.from_dict({"name": "one", "grid": [dict(grid, noise_overrides={"replay": "x"})]},
                       source="t", base_dir=tmp_path)


def test_reacquisition_transients_are_left_out_and_counted():
    """A fix the reader flags as a reacquisition transient (sim.nmea.flag_reacquisitions) is
    not placed on the grid; it is counted, so every valid fix is still accounted for."""
    from estimator.configuration import SensorConfig
    from sim.nmea import LogFixes
    from sim.recording import Recording

    t = 1.7e9 + np.arange(30.0)
    lat = np.full(30, 40.0) + 1e-7 * np.arange(30)
    lon = np.full(30, -105.0)
    flags = np.zeros(30, bool)
    flags[10] = True
    lat_b = lat.copy()
    lat_b[10] += 0.002                                   # ~220 m off: the transient
    logs = {"a": LogFixes("a", t, lat, lon, np.ones(30, np.int64), True),
            "b": LogFixes("b", t, lat_b, lon, np.ones(30, np.int64), True, reacquired=flags)}
    cfg = SensorConfig(("a", "b"), np.array([[0.5, 0.0], [-0.5, 0.0]]))
    rec = Recording.from_logs(logs, cfg)
    c = rec.meta["logs"]["b"]["counts"]
    assert c["reacquired"] == 1 and c["aligned"] == 29
    assert rec.meta["logs"]["b"]["fixes"] == sum(v for k, v in c.items() if k != "interpolated")
    assert np.isnan(rec.obs[10, 1]).all() and np.isfinite(rec.obs[10, 0]).all()


# --------------------------------------------------------------------------- path rule (issue
# 23/24)
@pytest.mark.parametrize("key, value", [
    ("config", "/etc/hostname"),
    ("config", "../../../../../../../../../etc/hostname"),
    ("log", "/etc/hostname"),
    ("log", "../../../../../../../../../etc/hostname"),
])
def test_recording_files_follow_the_path_rule(rig, tmp_path, key, value):
    import tomllib

    import tomli_w

    data = tomllib.loads(rig.files["toml"].read_text())
    if key == "config":
        data["config"] = value
    else:
        data["antenna"][0]["log"] = value
    p = rig.files["toml"].parent / f"esc_{tmp_path.name}.toml"
    p.write_text(tomli_w.dumps(data))
    with pytest.raises(RecordingError, match=r"leaves the folder of the file naming it"):
        load_recording(p)


def test_deeply_nested_recording_toml_is_a_one_line_error(tmp_path):
    p = tmp_path / "deep.toml"
    p.write_text('config = "rover_gps4"\nx = ' + "[" * 3000 + "]" * 3000 + "\n")
    with pytest.raises(RecordingError, match=r"deep\.toml: not usable TOML") as ei:
        load_recording(p)
    assert "\n" not in str(ei.value)


def test_shipped_recordings_resolve_under_the_rule():
    # the shipped recordings name ../shared/realdata logs: inside the allowed roots
    from sim.recording import RECORDINGS_DIR, _parse

    for toml in sorted(RECORDINGS_DIR.glob("*.toml")):
        try:
            _parse(toml)
        except RecordingError as exc:
            assert "no such file" in str(exc), exc      # realdata absent: not a rule error


# --------------------------------------------------------------------------- issue 23 grid / frame
# / meta
@pytest.mark.parametrize("rate", [1e308, float("inf"), float("nan"), 0.0, -1.0, 1e3, 1e-9])
def test_rate_hz_is_validated(rate):
    # 1e308 overflowed the grid arithmetic (OverflowError); now a RecordingError naming it
    base = 1.7e9 + np.arange(20.0)
    with pytest.raises(RecordingError, match="rate_hz: must be"):
        _two(base, base, rate_hz=rate)


def test_rate_hz_at_the_bounds_is_accepted():
    base = 1.7e9 + np.arange(20.0)
    assert _two(base, base, rate_hz=1.0).n == 20
    assert _two(base, base, rate_hz=100.0).n == 1901


def test_utm_zone_of_a_recording_astride_the_antimeridian():
    # the arithmetic mean of 179.9995 E and 179.9995 W is 0 (zone 31, ~20,000 km away)
    from sim.nmea import mean_longitude, utm_epsg

    cfg = SensorConfig(["a", "b"], [[0.5, 0.0], [-0.5, 0.0]])
    t = 1.7e9 + np.arange(10.0)
    one = np.ones(10)
    a = LogFixes(name="a", t_utc=t, lat=-17.0 * one, lon=179.9995 * one,
                 quality=np.ones(10, np.int64), date_known=True)
    b = LogFixes(name="b", t_utc=t, lat=-17.0 * one, lon=-179.9995 * one,
                 quality=np.ones(10, np.int64), date_known=True)
    rec = Recording.from_logs({"a": a, "b": b}, cfg)
    assert rec.meta["frame"]["epsg"] in (32701, 32760)          # zone 1 or 60, south
    assert mean_longitude([179.9995, -179.9995]) in (180.0, -180.0)
    assert utm_epsg(-17.0, mean_longitude([10.0, 20.0])) == 32733
    # the two antennas lie ~106 m apart (0.001 degree of longitude at 17 S), not 1e7 m
    d = np.linalg.norm(rec.obs[0, 0] - rec.obs[0, 1])
    assert 100.0 < d < 112.0


def test_recording_meta_is_json_ready(rig, rec):
    import json

    # skip counts were numpy integers: json.dumps raised TypeError
    json.dumps(rec.meta)
    base = 1.7e9 + np.arange(20.0)
    json.dumps(_two(base, base).meta)


# --------------------------------------------------------------------------- [platform]
def test_recording_platform_block_overrides_the_configurations(rig, tmp_path):
    import tomllib

    import tomli_w

    data = tomllib.loads(rig.files["toml"].read_text())
    rec0 = load_recording(rig.files["toml"])
    # without a block of its own the recording takes its configuration's (rover_gps4)
    assert rec0.platform == SensorConfig.load("rover_gps4").platform
    assert rec0.meta["platform"]["from"] == "config"
    data["platform"] = {"max_speed_mps": 16.0, "max_accel_mps2": 5.0,
                        "max_turn_rate_radps": 0.6}
    p = rig.files["toml"].parent / f"plat_{tmp_path.name}.toml"
    p.write_text(tomli_w.dumps(data))
    rec = load_recording(p)
    assert (rec.platform.max_speed_mps, rec.platform.max_turn_rate_radps) == (16.0, 0.6)
    assert rec.meta["platform"]["from"] == "recording"
    # the sweep reads the limits from the truth (experiments filter_params_for)
    from estimator.platform import PlatformLimits

    assert PlatformLimits.from_dict(rec.truth().meta["platform"]) == rec.platform
    data["platform"] = {"max_speed_mps": 16.0, "max_accel_mps2": 0.0,
                        "max_turn_rate_radps": 0.6}
    p.write_text(tomli_w.dumps(data))
    with pytest.raises(RecordingError, match=r"platform\.max_accel_mps2: must be in .*got 0"):
        load_recording(p)


def test_recording_without_any_platform_leaves_the_limits_to_the_data(rig):
    cfg = SensorConfig(list(LAYOUT), list(LAYOUT.values()), name="bare")
    logs = {k: rig.files[f"rtk{k}"] for k in LAYOUT}
    rec = Recording.from_logs(logs, cfg, reference=logs)
    assert rec.platform is None and rec.truth().meta["platform"] is None
    with pytest.raises(RecordingError, match="platform: expected"):
        Recording(t=rec.t, config=cfg, obs=rec.obs, platform={"max_speed_mps": 1.0})
