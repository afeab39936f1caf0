"""The run page (experiments/page.py): its payload against the files it reads, the file
contract on a synthetic recording folder, the ultrasonic flight, bad input, the CLIs.

The browser check (headless Chromium) is in test_page_browser.py. Tolerances: the page
stores float32 relative to a rounded origin; at |value| <= 200 m float32 resolves 1.5e-5 m,
so positions are compared to 1e-4 m, times (<= 2000 s) to 1e-3 s.
"""

from __future__ import annotations

import base64
import json
import math
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from experiments import page
from experiments.outline import is_simple_polygon, layout_outline
from experiments.spec import Spec, SpecError, load_spec
from experiments.sweep import run

REPO = Path(__file__).resolve().parents[1]

TINY = {
    "name": "tinypage", "seed": 3, "seeds": 1,
    "grid": [
        {"path": "square20", "window": [1, 5], "weighting": ["none", "huff"],
         "technique": "none"},
        {"path": "square20", "window": 5, "weighting": "huff", "technique": ["lc", "ekf"]},
    ],
    "epochs": {"seeds": [0]},
}


def decode(s: str, dtype: str = "<f4") -> np.ndarray:
    return np.frombuffer(base64.b64decode(s), dtype=dtype).astype(float)


def payload(html: str) -> dict:
    m = re.search(r'<script type="application/json" id="cp-data">(.*?)</script>', html, re.S)
    return json.loads(m.group(1))


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory) -> Path:
    """A real tiny sweep (square20, one seed) with per-epoch files; writes index.html. The
    truth comes from the shared, content-addressed cache (simulated on the first run)."""
    out = tmp_path_factory.mktemp("tinypage")
    r = run(Spec.from_dict(TINY, source="tiny"), out=out, jobs=1, progress=False,
            figures=False)
    assert r.n_failed == 0, r.errors
    return out


# --------------------------------------------------------------------------- synthetic recordings
BODY = np.array([[0.8, 0.4], [0.8, -0.4], [-0.7, 0.45], [-0.7, -0.45]])   # m, x fwd, y left
#: An antenna at the reference point on the layout's rear edge: ordered by angle round the
#: origin (as the page did), the outline crossed itself (issue 23).
EDGE_ORIGIN = np.array([[0.0, 0.0], [1.0, 1.0], [1.0, -1.0], [2.0, 0.2], [2.0, -0.2]])


def _pose_track(n: int, x0: float, y0: float, t0: float, rng) -> dict:
    """A circle of 40 m radius driven at 2 m/s, UTM-sized coordinates, epoch-second times."""
    t = t0 + 0.2 * np.arange(n)
    phi = 2.0 * (t - t0) / 40.0
    cx, cy = x0 + 40 * np.cos(phi), y0 + 40 * np.sin(phi)
    yaw = np.angle(np.exp(1j * (phi + np.pi / 2)))
    return {"t": t, "cx": cx, "cy": cy, "yaw": yaw}


def _antennas(cx, cy, yaw, body=BODY) -> tuple[np.ndarray, np.ndarray]:
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    return (cx[:, None] + c * body[:, 0] - s * body[:, 1],
            cy[:, None] + s * body[:, 0] + c * body[:, 1])


def write_recording_folder(folder: Path, n: int = 300, seed: int = 0, body=BODY) -> dict:
    """The page's file contract, as a recording run would write it: two recordings (one with
    an RTK-like reference, one without), two techniques each, UTM coordinates; antennas
    "a", "b", ... at ``body`` (m, x forward, y left)."""
    rng = np.random.default_rng(seed)
    names = [chr(ord("a") + j) for j in range(len(body))]
    (folder / "epochs").mkdir(parents=True, exist_ok=True)
    recs, truths = [], {}
    for rec_name, ref in (("drive_a", True), ("drive_b", False)):
        tr = _pose_track(n, 500_123.0, 4_100_456.0, 1.7e9 + (0 if ref else 1e4), rng)
        ax, ay = _antennas(tr["cx"], tr["cy"], tr["yaw"], body)
        obs_x, obs_y = ax + rng.normal(0, 1, ax.shape), ay + rng.normal(0, 1, ay.shape)
        obs_x[rng.random(ax.shape) < 0.1] = np.nan
        truths[rec_name] = {**tr, "ref": ref, "obs_x": obs_x}
        for tech, off in (("none", 1.0), ("ekf", 0.3)):
            k = f"{rec_name}_{tech}"
            ex, ey = tr["cx"] + off * np.sin(tr["yaw"]), tr["cy"] - off * np.cos(tr["yaw"])
            eyaw = np.angle(np.exp(1j * (tr["yaw"] + 0.05)))
            ebx, eby = _antennas(ex, ey, eyaw, body)
            cols = {"t": tr["t"], "cg_x": ex, "cg_y": ey, "yaw": eyaw}
            for j, nm in enumerate(names):
                cols[f"x_{nm}"], cols[f"y_{nm}"] = ebx[:, j], eby[:, j]
                cols[f"obs_{nm}_x"] = obs_x[:, j].astype(np.float32)
                cols[f"obs_{nm}_y"] = obs_y[:, j].astype(np.float32)
            if ref:
                cols.update({"truth_cg_x": tr["cx"], "truth_cg_y": tr["cy"],
                             "truth_yaw": tr["yaw"],
                             "truth_turning": (np.arange(n) % 100) > 80})
                for j, nm in enumerate(names):
                    cols[f"truth_{nm}_x"], cols[f"truth_{nm}_y"] = ax[:, j], ay[:, j]
            pd.DataFrame(cols).to_parquet(folder / "epochs" / f"{k}.parquet", index=False)
            for mask in ("full", "no_turns"):
                recs.append({"key": k, "recording": rec_name, "technique": tech, "seed": 0,
                             "mask": mask, "ex_mean": off if ref else np.nan,
                             "has_epochs": True})
    pd.DataFrame(recs).to_parquet(folder / "cells.parquet", index=False)
    return truths


# --------------------------------------------------------------------------- tests
def test_sweep_writes_page_whose_replay_equals_the_epoch_files(tiny_run):
    out = tiny_run
    html = (out / "index.html").read_text()
    assert "Claims and verdicts" in html and "Tables" in html
    data = payload(html)
    src = data["gps"][0]
    assert {"window", "weighting", "technique"} <= set(src["axes"])
    assert src["fixed"]["path"] == "square20" and "path" not in src["axes"]
    cells = pd.read_parquet(out / "cells.parquet")
    keys = set(cells.loc[cells["has_epochs"], "key"])
    assert {c["key"] for c in src["cells"]} == keys
    assert len(src["tracks"]) == 1                           # one truth: square20, rover_gps8
    tr = src["tracks"][0]
    t = decode(tr["t"])
    for c in src["cells"]:
        ep = pd.read_parquet(out / "epochs" / f"{c['key']}.parquet")
        pos = np.searchsorted(t, ep["t"].to_numpy())
        np.testing.assert_allclose(t[pos], ep["t"], atol=1e-3)
        for col, name in (("cg_x", "x"), ("cg_y", "y"), ("yaw", "yaw")):
            got = decode(c[name])
            np.testing.assert_allclose(got[pos], ep[col], atol=1e-4)
            assert np.isnan(np.delete(got, pos)).all()       # no estimate before the window fills
        np.testing.assert_allclose(decode(tr["truth"]["x"])[pos], ep["truth_cg_x"], atol=1e-4)
    # the antenna layout recovered from the truth is the configuration file's (the rover tilts
    # < 1e-4 rad with antennas 0.6 m up: < 0.1 mm)
    from estimator.configuration import SensorConfig

    cfg = SensorConfig.load("rover_gps8").planar()
    body = cfg.body_positions[:, :2] - cfg.cg_body[:2]
    assert tr["names"] == list(cfg.names)
    np.testing.assert_allclose(tr["body"], body, atol=1e-3)
    # the dead antenna (sensor 4) has no observations
    dead = dict(zip(tr["names"], src["noise"][0]["dead"]))
    assert dead == {n: n in cfg.dead for n in cfg.names}


def test_decimation_picks_every_kth_epoch(tiny_run):
    full = page.replay_source(tiny_run, max_points=10_000)
    small = page.replay_source(tiny_run, max_points=7)
    n = full["tracks"][0]["n_full"]
    k = math.ceil(n / 7)
    assert small["tracks"][0]["step"] == k and full["tracks"][0]["step"] == 1
    np.testing.assert_array_equal(decode(small["tracks"][0]["t"]),
                                  decode(full["tracks"][0]["t"])[::k])
    for a, b in zip(full["cells"], small["cells"]):
        np.testing.assert_array_equal(decode(b["x"]), decode(a["x"])[::k])   # picked, not averaged


def test_recording_folder_contract(tmp_path):
    truths = write_recording_folder(tmp_path)
    src = page.replay_source(tmp_path)
    assert src["axes"] == ["recording", "technique"]
    assert len(src["tracks"]) == 2 and len(src["noise"]) == 2     # one per recording
    by_rec = {c["axes"]["recording"]: src["tracks"][c["track"]] for c in src["cells"]}
    a, b = by_rec["drive_a"], by_rec["drive_b"]
    ta = truths["drive_a"]
    # UTM-sized values: stored relative to a rounded origin, decoded back to 1e-4 m
    assert a["origin"][0] != 0 and abs(a["origin"][0] - 500_123) < 100
    np.testing.assert_allclose(decode(a["truth"]["x"]) + a["origin"][0], ta["cx"], atol=1e-4)
    np.testing.assert_allclose(decode(a["truth"]["y"]) + a["origin"][1], ta["cy"], atol=1e-4)
    np.testing.assert_allclose(decode(a["t"]) + a["t0"], ta["t"], atol=1e-3)
    np.testing.assert_array_equal(decode(a["turning"], "u1").astype(bool),
                                  (np.arange(len(ta["t"])) % 100) > 80)
    # layouts: from the reference antennas (a) and from the estimated ones (b, no reference)
    np.testing.assert_allclose(a["body"], BODY, atol=1e-4)
    np.testing.assert_allclose(b["body"], BODY, atol=1e-4)
    assert b["truth"] is None and b["turning"] is None
    obs = decode(src["noise"][0]["obs"]).reshape(len(ta["t"]), 4, 2)
    np.testing.assert_allclose(obs[:, :, 0] + a["origin"][0], ta["obs_x"], atol=1e-1,
                               equal_nan=True)      # float32 in the file: 0.06 m at 5e5 m
    html = page.build_page(tmp_path, ultrasonic=None)
    assert payload(html)["gps"][0]["cells"][0]["axes"]["recording"] in ("drive_a", "drive_b")


def test_layout_outline_is_the_convex_hull(tmp_path):
    """The payload's outline: the hull's indices (page.js draws exactly these), simple, with
    the antenna at the origin as a corner; the rover_gps8-like layout without one inside."""
    write_recording_folder(tmp_path, n=120, body=EDGE_ORIGIN)
    for tr in page.replay_source(tmp_path)["tracks"]:
        body = np.asarray(tr["body"])
        np.testing.assert_allclose(body, EDGE_ORIGIN, atol=1e-4)
        assert tr["outline"] == layout_outline(EDGE_ORIGIN) == [0, 2, 4, 3, 1]
        assert is_simple_polygon(body[tr["outline"]])


def test_extra_folders_are_replayed_beside_the_run(tiny_run, tmp_path):
    write_recording_folder(tmp_path / "rec")
    data = payload(page.build_page(tiny_run, ultrasonic=None, extra=(tmp_path / "rec",)))
    assert [len(s["cells"]) for s in data["gps"]] == [6, 4]
    assert data["flight"] is None


def test_page_is_reproducible(tiny_run, tmp_path):
    """The same folder gives the same page, byte for byte (no clock time, no run status):
    a rerun of a committed reference leaves its index.html unchanged."""
    a, b = tmp_path / "a.html", tmp_path / "b.html"
    page.write_page(tiny_run, out=a)
    page.write_page(tiny_run, out=b)
    assert a.read_bytes() == b.read_bytes()
    assert "status running" not in a.read_text()


def test_missing_required_column_is_named_and_reported_in_the_page(tmp_path, capsys):
    write_recording_folder(tmp_path)
    f = tmp_path / "epochs" / "drive_a_none.parquet"
    pd.read_parquet(f).drop(columns=["yaw"]).to_parquet(f)
    with pytest.raises(ValueError, match=r"drive_a_none\.parquet: missing columns \['yaw'\]"):
        page.replay_source(tmp_path)
    html = page.build_page(tmp_path, ultrasonic=None)
    assert "error-box" in html and "missing columns" in html
    assert "missing columns ['yaw']" in capsys.readouterr().err


def test_folder_without_epochs_says_so(tmp_path):
    pd.DataFrame([{"key": "k", "path": "p", "seed": 0, "mask": "full", "has_epochs": False}]
                 ).to_parquet(tmp_path / "cells.parquet")
    assert page.replay_source(tmp_path) is None
    html = page.build_page(tmp_path, ultrasonic=None)
    assert "nothing to replay" in html and payload(html)["gps"] == []


@pytest.mark.parametrize("bad", [0, 1, -3, 2.5, True, None, "10"])
def test_max_points_is_validated(tiny_run, bad):
    with pytest.raises(ValueError, match="max_points"):
        page.replay_source(tiny_run, max_points=bad)


_VALUES = st.one_of(st.floats(allow_nan=True, allow_infinity=True),
                    st.sampled_from([0.0, 1e300, -1e300, np.nan, np.inf, 5e5, 4e6]))


@settings(max_examples=25, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(n=st.integers(1, 40), max_points=st.integers(2, 60), data=st.data())
def test_any_finite_or_not_values_give_strict_json(tmp_path_factory, n, max_points, data):
    """Extreme values (inf, nan, 1e300, UTM-sized, a single epoch) never break the page: the
    payload is strict JSON (no NaN/Infinity literals) and has one value per kept epoch."""
    folder = tmp_path_factory.mktemp("hyp")
    (folder / "epochs").mkdir()
    col = lambda: np.array(data.draw(st.lists(_VALUES, min_size=n, max_size=n)))  # noqa: E731
    cols = {"t": np.arange(n) * 0.5, "cg_x": col(), "cg_y": col(), "yaw": col(),
            "truth_cg_x": col(), "truth_cg_y": col(), "truth_yaw": col()}
    pd.DataFrame(cols).to_parquet(folder / "epochs" / "k.parquet")
    pd.DataFrame([{"key": "k", "recording": "r", "seed": 0, "mask": "full", "ex_mean": np.inf,
                   "has_epochs": True}]).to_parquet(folder / "cells.parquet")
    src = page.replay_source(folder, max_points=max_points)
    json.dumps(src, allow_nan=False)
    kept = math.ceil(n / math.ceil(n / max_points))
    assert len(decode(src["cells"][0]["x"])) == kept == len(decode(src["tracks"][0]["t"]))


def test_flight_replay_matches_the_ultrasonic_study():
    us = REPO / "results" / "ultrasonic"
    f = page.flight_source(us)
    s = pd.read_csv(us / "flight_series.csv")
    front = np.stack([decode(f["truth"]["front"][a]) for a in "xyz"], 1)
    rear = np.stack([decode(f["truth"]["rear"][a]) for a in "xyz"], 1)
    np.testing.assert_allclose(front[:, 0], s["front_true_x"], atol=1e-5)
    # both transmitters: 0.5 m apart on the airframe (thesis 003 Section 3.2.2)
    np.testing.assert_allclose(np.linalg.norm(front - rear, axis=1), 0.5, atol=1e-5)
    from sim.ultrasonic import load_receivers

    names, rec = load_receivers("flight")
    assert f["receivers"]["names"] == list(names)
    np.testing.assert_allclose(f["receivers"]["xyz"], rec, atol=1e-5)
    info = json.loads((us / "run_info.json").read_text())
    assert f["receivers"]["used"] == info["flight"]["triple"]
    assert set(f["ranges"]["raw"]) == set(names) and f["gated_kind"] == "robust"
    np.testing.assert_allclose(decode(f["ranges"]["raw"]["R41"]), s["range_raw_front_R41"],
                               atol=1e-5, equal_nan=True)
    assert page.flight_source(REPO / "no_such_folder") is None


def test_cli_and_report_write_the_page(tiny_run, tmp_path, capsys):
    out = tmp_path / "p.html"
    assert page.main([str(tiny_run), "--out", str(out)]) == 0
    assert "MB)" in capsys.readouterr().out and payload(out.read_text())["flight"] is None
    assert page.main([str(tiny_run), "--out", str(out), "--ultrasonic",
                      str(REPO / "results" / "ultrasonic")]) == 0
    assert payload(out.read_text())["flight"]["title"] == "ultrasonic flight"
    with pytest.raises(ValueError, match=r"--ultrasonic .*nowhere: no flight_series.csv there"):
        page.main([str(tiny_run), "--out", str(out), "--ultrasonic", str(tmp_path / "nowhere")])
    assert page.main([str(tmp_path / "nope")]) == 2
    assert page.main([str(tiny_run), "--max-points", "1"]) == 2
    assert "--max-points" in capsys.readouterr().err
    from experiments import report

    (tiny_run / "index.html").unlink()
    assert report.main([str(tiny_run)]) == 0
    assert (tiny_run / "index.html").exists()


# --------------------------------------------------------------------------- [page] flight
def _declaring(run_dir: Path, dest: Path, flight: str) -> Path:
    """A copy of a run's cells.parquet and manifest whose spec declares ``[page] flight``
    (what a sweep of such a spec records), relative to the project."""
    dest.mkdir()
    (dest / "cells.parquet").write_bytes((run_dir / "cells.parquet").read_bytes())
    man = json.loads((run_dir / "manifest.json").read_text())
    man["spec"]["page"] = {"flight": flight}
    man["spec_base_dir"] = "experiments/presets"
    (dest / "manifest.json").write_text(json.dumps(man))
    return dest


def test_a_spec_without_a_flight_source_reads_no_other_study(tiny_run, monkeypatch):
    """No ``[page] flight``: no flight section, and nothing under results/ultrasonic is
    read (the page used to read it for every run)."""
    def reads(*a, **k):
        raise AssertionError(f"flight_source{a} read without a declared source")

    monkeypatch.setattr(page, "flight_source", reads)
    assert "page" not in json.loads((tiny_run / "manifest.json").read_text())["spec"]
    html = page.build_page(tiny_run)
    assert payload(html)["flight"] is None and 'id="flight"' not in html
    assert page.flight_dir(tiny_run) is None


def test_a_declared_flight_source_is_replayed(tiny_run, tmp_path):
    run_dir = _declaring(tiny_run, tmp_path / "run", "results/ultrasonic")
    assert page.declared_flight(run_dir) == ("results/ultrasonic", REPO / "results" / "ultrasonic")
    html = page.build_page(run_dir)
    assert payload(html)["flight"]["title"] == "ultrasonic flight"
    assert "From <code>results/ultrasonic/flight_series.csv</code>" in html
    # declared but not written yet: the page says so, no replay
    empty = _declaring(tiny_run, tmp_path / "empty", "results/no-such-study")
    html = page.build_page(empty)
    assert payload(html)["flight"] is None and "holds no flight_series.csv yet" in html
    assert page.flight_dir(empty) is None


def test_the_thesis_preset_declares_its_flight_source():
    spec = load_spec("thesis")
    assert spec.page == {"flight": "results/ultrasonic"}
    assert spec.to_dict()["page"] == spec.with_solver("elastic").to_dict()["page"]
    assert "page" not in load_spec("quick").to_dict()


@pytest.mark.parametrize("table, match", [
    ({"flight": 3}, r"page\.flight: must be a folder path \(string\).*got 3"),
    ({"flight": ""}, r"page\.flight: must be a folder path"),
    ({"flight": "../../../etc"}, r"page\.flight: '\.\./\.\./\.\./etc' must be named relative"),
    ({"flight": "/etc"}, r"page\.flight: '/etc' must be named relative"),
    ({"flights": "results/ultrasonic"}, r"page: unknown key\(s\) \['flights'\]"),
    ("results/ultrasonic", r"page: must be a table"),
])
def test_a_bad_page_table_is_a_one_line_spec_error(tmp_path, table, match):
    with pytest.raises(SpecError, match=match) as ei:
        Spec.from_dict({**TINY, "page": table}, source="s.toml", base_dir=tmp_path)
    assert "\n" not in str(ei.value)


def test_a_flight_source_outside_the_project_is_refused(tmp_path):
    """A folder that holds the file but lies outside the spec's folder and the project: the
    one path rule of every file a spec names refuses it, naming the field."""
    outside = tmp_path / "elsewhere"
    outside.mkdir()
    (outside / "flight_series.csv").write_text("t\n0\n")
    spec_dir = tmp_path / "specs"
    spec_dir.mkdir()
    (spec_dir / "s.toml").write_text(
        'name = "s"\n[page]\nflight = "../elsewhere"\n'
        '[[grid]]\npath = "square20"\nwindow = 1\n')
    with pytest.raises(SpecError, match=r"page\.flight: .*leaves the folder of the file"):
        load_spec(spec_dir / "s.toml")


def test_tables_figure_grows_with_its_rows(tmp_path):
    """fig_tables.png: one level row per (window, technique), so more rows make it taller
    instead of crowding the labels."""
    from PIL import Image

    from experiments.figures import _draw

    def table(rows: list[tuple[int, str]]) -> pd.DataFrame:
        return pd.DataFrame([{"path": "square100", "weighting": "huff", "window": w,
                              "technique": t, "thesis_row": t == "None", "mean": 1.0,
                              "mean_lo": 0.8, "mean_hi": 1.2, "mean_thesis": 1.1}
                             for w, t in rows])

    heights = []
    for rows in ([(5, "None"), (10, "None")], [(w, t) for w in (5, 10, 100)
                                               for t in ("None", "LC", "Dyn SW", "EKF")]):
        for n in (1, 2):
            table(rows).to_csv(tmp_path / f"table_4_{n}.csv", index=False)
        assert _draw(tmp_path, "tables") == [tmp_path / "fig_tables.png"]
        heights.append(Image.open(tmp_path / "fig_tables.png").size)
    assert heights[0][0] == heights[1][0] and heights[1][1] > heights[0][1] + 200


# --------------------------------------------------------------------------- real browser
CHROMIUM = "/usr/bin/chromium"      # Debian package `chromium` (.ci/run installs it)
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu",
                 "--disable-background-networking", "--disable-component-update",
                 "--disable-sync", "--no-first-run"]


@pytest.fixture
def browser_page(tmp_path):
    """A fresh headless Chromium (own --user-data-dir) page that records console errors;
    skips with the reason when Playwright or Debian's Chromium is missing."""
    sync_api = pytest.importorskip(
        "playwright.sync_api", reason="playwright not installed (pip install -e '.[test]')")
    if not Path(CHROMIUM).exists():
        pytest.skip(f"{CHROMIUM} not found: install Debian's chromium (apt-get install "
                    "chromium; .ci/run does this)")
    errors: list[str] = []
    with sync_api.sync_playwright() as p:
        ctx = p.chromium.launch_persistent_context(
            str(tmp_path / "chromium-profile"), executable_path=CHROMIUM, headless=True,
            args=CHROMIUM_ARGS, viewport={"width": 1300, "height": 1000})
        pg = ctx.new_page()
        pg.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
        pg.on("pageerror", lambda e: errors.append(str(e)))
        pg.errors = errors
        yield pg
        ctx.close()


def _state(pg, which: str) -> dict:
    return pg.evaluate(f"window.configpose.{which}.state()")


def test_page_in_headless_chromium(tiny_run, tmp_path, browser_page):
    """Open the page from disk: no console error; the slider moves the drawn pose; switching
    cells and sources redraws; the flight plays; screenshots go to the test's tmp dir."""
    write_recording_folder(tmp_path / "rec", n=200)
    html = tmp_path / "index.html"
    page.write_page(tiny_run, out=html, extra=(tmp_path / "rec",),
                    ultrasonic=REPO / "results" / "ultrasonic")
    pg = browser_page
    pg.goto(html.as_uri())
    pg.wait_for_function("window.configpose && window.configpose.ready", timeout=10_000)
    assert pg.evaluate("window.configpose.gps.length") == 2
    assert pg.evaluate("window.configpose.flight !== null")

    # the slider moves the pose (keyboard on the slider, as a user would)
    s0 = _state(pg, "gps[0]")
    shot0 = pg.locator("#replay-0 canvas.overview").screenshot()
    pg.locator("#replay-0 .slider").focus()
    for _ in range(5):                         # PageUp: a tenth of the range; half way round
        pg.keyboard.press("PageUp")
    s1 = _state(pg, "gps[0]")
    assert 0.4 * s0["n"] < s1["index"] < 0.6 * s0["n"] and s1["t"] > s0["t"]
    assert math.dist(s0["overviewPx"], s1["overviewPx"]) > 20           # pixels on screen
    assert math.dist(s0["truth"][:2], s1["truth"][:2]) > 5               # metres in the data
    assert pg.locator("#replay-0 canvas.overview").screenshot() != shot0

    # switch cells: another window; same epoch, another estimate
    pg.select_option("#replay-0 select[data-axis=window]", "5")
    s2 = _state(pg, "gps[0]")
    assert s2["axes"]["window"] == "5" and s2["key"] != s1["key"] and s2["index"] == s1["index"]
    assert s2["est"] != s1["est"] and s2["truth"] == s1["truth"]
    pg.select_option("#replay-0 select[data-axis=technique]", "ekf")
    s3 = _state(pg, "gps[0]")
    assert s3["axes"]["technique"] == "ekf" and s3["key"] != s2["key"]

    # the recording source: the one without a reference has no truth drawn
    pg.select_option("#replay-1 select[data-axis=recording]", "drive_b")
    r0 = _state(pg, "gps[1]")
    assert r0["truth"] is None and r0["truthPx"] is None and r0["estPx"] is not None
    pg.locator("#replay-1 .slider").focus()
    for _ in range(3):
        pg.keyboard.press("ArrowRight")
    pg.keyboard.press("PageUp")
    r1 = _state(pg, "gps[1]")
    assert r1["index"] > 3 and math.dist(r0["overviewPx"], r1["overviewPx"]) > 5

    # the flight: play for a moment, then drag to the end
    f0 = _state(pg, "flight")
    pg.click("#flight-replay button.play")
    pg.wait_for_timeout(600)
    pg.click("#flight-replay button.play")
    f1 = _state(pg, "flight")
    assert f1["index"] > f0["index"]
    pg.locator("#flight-replay .slider").focus()
    pg.keyboard.press("End")
    f2 = _state(pg, "flight")
    assert math.dist(f1["truthPx"], f2["truthPx"]) > 5 and f2["front"] != f1["front"]

    for sel, name in (("#replay-0", "replay"), ("#replay-1", "recording"),
                      ("#flight-replay", "flight")):
        pg.locator(sel).screenshot(path=str(tmp_path / f"page_{name}.png"))
    pg.screenshot(path=str(tmp_path / "page.png"))
    assert all((tmp_path / f"page{s}.png").stat().st_size > 20_000
               for s in ("", "_replay", "_recording", "_flight"))
    assert pg.errors == []


def test_page_draws_the_layout_hull_in_chromium(tmp_path, browser_page):
    """The drawn outline (canvas pixels, from state()) of both poses, for a layout with an
    antenna at the origin: a simple polygon through the hull's antennas, in the hull's order
    (by angle round the origin it was a bow-tie)."""
    write_recording_folder(tmp_path / "rec", n=120, body=EDGE_ORIGIN)
    html = tmp_path / "index.html"
    page.write_page(tmp_path / "rec", out=html, ultrasonic=None)
    pg = browser_page
    pg.goto(html.as_uri())
    pg.wait_for_function("window.configpose && window.configpose.ready", timeout=10_000)
    pg.locator("#replay-0 .slider").focus()
    pg.keyboard.press("PageUp")
    st = _state(pg, "gps[0]")
    assert st["truth"] is not None
    hull = layout_outline(EDGE_ORIGIN)
    for which, (_x, _y, yaw) in (("estOutlinePx", st["est"]), ("truthOutlinePx", st["truth"])):
        poly = np.asarray(st[which], float)
        assert poly.shape == (len(hull), 2) and is_simple_polygon(poly), (which, poly)
        # the same corners as the layout's hull at that pose (screen y points down: flip)
        c, s = np.cos(yaw), np.sin(yaw)
        world = np.stack([c * EDGE_ORIGIN[:, 0] - s * EDGE_ORIGIN[:, 1],
                          s * EDGE_ORIGIN[:, 0] + c * EDGE_ORIGIN[:, 1]], 1)
        scale = np.linalg.norm(poly[1] - poly[0]) / np.linalg.norm(world[hull[1]] - world[hull[0]])
        want = (world[hull] - world[hull[0]]) * [scale, -scale] + poly[0]
        # 1 px: positions are float32 (1e-5 m, < 0.01 px at the close-up scale); margin only
        np.testing.assert_allclose(poly, want, atol=1.0)
    assert pg.errors == []
