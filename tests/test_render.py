"""Rendered clips (experiments/render.py): a few frames of the rover and of the quadcopter,
offscreen, in a child process (MuJoCo picks its GL backend once, at import, so the test
process cannot switch it); frame timing and option validation in-process."""

from __future__ import annotations

import ctypes.util
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import given
from hypothesis import strategies as st

from experiments.render import MAX_FRAMES, ClipOptions, main

REPO = Path(__file__).resolve().parents[1]


def _gl_backend() -> str:
    if ctypes.util.find_library("OSMesa"):
        return "osmesa"
    if ctypes.util.find_library("EGL"):
        return "egl"
    pytest.skip("no offscreen GL: install Debian's libosmesa6 (apt-get install libosmesa6; "
                ".ci/run does this) or an EGL driver")


def _rover_cell(folder: Path) -> None:
    """A sweep-shaped folder with one cell: the rover drives 30 m east then turns north at
    1 m/s, the estimate 0.8 m behind with a 10 deg heading error, observations 0.5 m off."""
    n = 60
    t = np.arange(n, dtype=float)
    turn = np.clip(t - 30, 0, None)
    x, y = np.minimum(t, 30.0), turn
    yaw = np.where(t < 30, 0.0, np.pi / 2)
    cols = {"t": t, "cg_x": x - 0.8 * np.cos(yaw), "cg_y": y - 0.8 * np.sin(yaw),
            "yaw": yaw + np.radians(10), "truth_cg_x": x, "truth_cg_y": y, "truth_yaw": yaw}
    cols["cg_x"][:4] = np.nan                            # no estimate until the window fills
    for j, nm in enumerate("12345678"):
        cols[f"obs_{nm}_x"] = x + 0.5 * np.cos(j)
        cols[f"obs_{nm}_y"] = y + 0.5 * np.sin(j)
    (folder / "epochs").mkdir(parents=True)
    pd.DataFrame(cols).to_parquet(folder / "epochs" / "k1.parquet")
    pd.DataFrame([{"key": "k1", "path": "drive", "config": "rover_gps8", "window": 5,
                   "technique": "none", "seed": 0, "mask": "full", "has_epochs": True}]
                 ).to_parquet(folder / "cells.parquet")


_DRIVER = """
import sys
from experiments.render import ClipOptions, render_cell, render_flight
res, out, us = sys.argv[1:4]
o = ClipOptions(fps=10, width=160, height=120, speed=10.0, start_s=20.0, max_frames=3)
render_cell(res, out + "/rover.gif", where={"window": 5}, opts=o, progress=False)
render_flight(us, out + "/flight.mp4", opts=ClipOptions(fps=10, width=161, height=120,
              start_s=10.0, speed=2.0, max_frames=3), progress=False)
print("done")
"""


def test_render_rover_and_flight_frames(tmp_path):
    """3 frames each: files decode to the asked size (H.264 rounds 161 up to even), the
    scenes are lit (not blank), the platform moves between frames, the ghost is red."""
    import imageio.v2 as imageio
    from PIL import Image

    backend = _gl_backend()
    _rover_cell(tmp_path / "run")
    env = {**os.environ, "MUJOCO_GL": backend, "PYTHONPATH": str(REPO)}
    proc = subprocess.run([sys.executable, "-c", _DRIVER, str(tmp_path / "run"), str(tmp_path),
                           str(REPO / "results" / "ultrasonic")], env=env, capture_output=True,
                          text=True, timeout=240)
    assert proc.returncode == 0 and "done" in proc.stdout, proc.stderr[-3000:]
    gif = Image.open(tmp_path / "rover.gif")
    assert gif.n_frames == 3 and gif.size == (160, 120)
    frames = []
    for k in range(3):
        gif.seek(k)
        frames.append(np.asarray(gif.convert("RGB"), dtype=float))
    assert all(f.std() > 10 for f in frames)                  # a lit scene, not a blank frame
    assert np.abs(frames[2] - frames[0]).mean() > 1.0          # 2 s of driving apart
    red = [((f[..., 0] > 150) & (f[..., 1] < 90) & (f[..., 2] < 90)).sum() for f in frames]
    assert min(red) > 10, red                                  # the estimate's ghost
    mp4 = imageio.mimread(tmp_path / "flight.mp4")
    assert len(mp4) == 3 and mp4[0].shape == (120, 162, 3)
    assert np.asarray(mp4[0], float).std() > 10


@given(fps=st.floats(1, 120), speed=st.floats(0.01, 1e4), start=st.floats(0, 50),
       length=st.floats(1, 5000), max_frames=st.one_of(st.none(), st.integers(1, 500)))
def test_frame_times_cover_the_run_at_the_asked_rate(fps, speed, start, length, max_frames):
    o = ClipOptions(fps=fps, speed=speed, start_s=start, max_frames=max_frames)
    if start >= length:
        with pytest.raises(ValueError, match="start_s"):
            o.times(0.0, length)
        return
    full = math.floor((length - start) * fps / speed) + 1
    want = full if max_frames is None else min(full, max_frames)
    if want > MAX_FRAMES:
        with pytest.raises(ValueError, match="speed"):
            o.times(0.0, length)
        return
    ts = o.times(0.0, length)
    assert ts[0] == start and ts[-1] <= length * (1 + 1e-12)
    if len(ts) > 1:   # start + k * step: rounding of 4 ulp of the largest time
        np.testing.assert_allclose(np.diff(ts), speed / fps, rtol=0,
                                   atol=4 * np.spacing(ts[-1]))
    assert len(ts) == want


@pytest.mark.parametrize("kw", [{"fps": 0}, {"fps": math.inf}, {"fps": math.nan},
                                {"fps": True}, {"speed": -1.0}, {"speed": math.inf},
                                {"start_s": -0.5}, {"width": 8}, {"height": 1e300},
                                {"width": 640.0}, {"max_frames": 0}, {"camera": "side"}])
def test_bad_options_are_named(kw):
    with pytest.raises(ValueError, match=next(iter(kw))):
        ClipOptions(**kw)


def test_cli_errors(tmp_path, capsys):
    assert main(["--out", str(tmp_path / "x.mp4")]) == 2          # neither a cell nor --flight
    assert "--flight" in capsys.readouterr().err
    assert main(["--flight", str(tmp_path), "--out", str(tmp_path / "x.mp4")]) == 2
    assert "flight_series.csv not found" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["--flight", str(tmp_path), "--out", "x.gif", "--size", "big"])


# --------------------------------------------------------------------------- what the frames show
_VIEWS = """
import sys
import numpy as np, pandas as pd
from experiments.render import ClipOptions, rover_frames

def cell(L, dx, dyaw, nan_until):
    # L m east, then L m north at 1 m/s; the estimate dx m east of the truth, heading + dyaw
    t = np.arange(2 * L + 1, dtype=float)
    x, y = np.minimum(t, L), np.clip(t - L, 0, None)
    yaw = np.where(t < L, 0.0, np.pi / 2)
    ep = pd.DataFrame({"t": t, "truth_cg_x": x, "truth_cg_y": y, "truth_yaw": yaw,
                       "cg_x": x + dx, "cg_y": y, "yaw": yaw + dyaw})
    ep.loc[ep.t < nan_until, ["cg_x", "cg_y", "yaw"]] = np.nan
    return ep

out = {}
for name, (L, dx, dyaw, nan_until, w, h, t) in eval(sys.argv[1]).items():
    o = ClipOptions(fps=1, width=w, height=h, speed=1.0, start_s=t, max_frames=1, camera="top")
    out[name] = next(rover_frames(cell(L, dx, dyaw, nan_until), "rover_gps8", o))
np.savez(sys.argv[2], **out)
print("done")
"""
#: name: (L m, estimate offset east m, heading offset rad, no estimate before s, width, height,
#: frame time s). All top camera; the truth at the frame time is at (L, t - L) heading north.
_CASES = {"square100": (100, 10.0, 0.0, 0, 640, 480, 150),     # truth (100, 50)
          "ghost": (5, 3.0, math.pi / 2, 3, 320, 240, 8),       # truth (5, 3), estimate (8, 3) W
          "close": (5, 0.01, 0.0, 3, 320, 240, 8),             # the estimate 1 cm off
          "no_estimate": (5, 3.0, 0.0, 3, 320, 240, 2)}         # no estimate yet at t = 2 s
#: rover.xml's hull half sizes (m) and roof height (m); the ghost box adds 0.04 m a side
HULL_HALF, ROOF_Z, GHOST_MARGIN = (0.75, 0.5), 0.55, 0.04


@pytest.fixture(scope="module")
def top_frames(tmp_path_factory) -> dict[str, np.ndarray]:
    backend = _gl_backend()
    out = tmp_path_factory.mktemp("views") / "frames.npz"
    env = {**os.environ, "MUJOCO_GL": backend, "PYTHONPATH": str(REPO)}
    proc = subprocess.run([sys.executable, "-c", _VIEWS, repr(_CASES), str(out)], env=env,
                          capture_output=True, text=True, timeout=240)
    assert proc.returncode == 0 and "done" in proc.stdout, proc.stderr[-3000:]
    with np.load(out) as d:
        return {k: d[k].astype(int) for k in d}


def _pixel(case: str, x: float, y: float, z: float) -> tuple[float, float, float]:
    """(column, row, pixels per metre) of the world point (x, y, z) m in a top frame: a
    pinhole camera straight above the centre that experiments.render._top_view picks (the
    camera is 1 deg off vertical: < 1 px at these sizes, measured 0.8 px on the hull)."""
    from experiments.render import _top_view

    L, *_, w, h, _t = _CASES[case]
    t = np.arange(2 * L + 1.0)
    centre, dist = _top_view(np.minimum(t, L), np.clip(t - L, 0, None), w / h)
    s = (h / 2) / ((dist - z) * math.tan(math.radians(22.5)))      # fovy 45 deg
    return w / 2 + (x - centre[0]) * s, h / 2 - (y - centre[1]) * s, s


def _coverage(mask: np.ndarray, case: str, x: float, y: float, z: float, half_x: float,
              half_y: float) -> float:
    """Fraction of mask pixels in the world rectangle centre (x, y), half sizes (m) at z."""
    c, r, s = _pixel(case, x, y, z)
    rows = slice(round(r - half_y * s), round(r + half_y * s) + 1)
    cols = slice(round(c - half_x * s), round(c + half_x * s) + 1)
    return float(mask[rows, cols].mean())


def _red(f: np.ndarray) -> np.ndarray:
    """Red pixels: the opaque ghost (230, 13, 13)-ish, the translucent box over the ground
    (~(200, 115, 105)) or over the hull (~(145, 55, 65)); ground and hull have r <= g + 15."""
    return f[..., 0] - np.maximum(f[..., 1], f[..., 2]) > 60


def test_top_camera_shows_a_100_m_square_and_the_platform(top_frames):
    """The top camera 139 m above a 100 m square (beyond MuJoCo's default far plane of
    50 x 1.83 m): lit ground, not black; the hull's blue-grey where the truth projects."""
    f = top_frames["square100"]
    below = f[40:]                                                     # under the caption
    assert (below.max(axis=2) < 30).mean() < 0.01                      # was 97 % black
    ground = (below[..., 1] > below[..., 0]) & (below[..., 0] > below[..., 2])
    assert ground.mean() > 0.6
    hull = (f[..., 2] - f[..., 0] >= 5) & (f[..., 0] > 40) & (f[..., 0] < 140)
    c, r, s = _pixel("square100", 100.0, 50.0, ROOF_Z)
    win = hull[round(r - 2 * s):round(r + 2 * s) + 1, round(c - 2 * s):round(c + 2 * s) + 1]
    # the roof is 1.5 x 1.0 m = 26 px at 4.2 px/m, the heading arrow covers ~6 of them
    assert win.sum() >= 10, win.sum()
    rr, cc = np.nonzero(win)
    assert abs(cc.mean() - 2 * s - (c - round(c))) < 2 and abs(rr.mean() - 2 * s) < 2
    assert hull.sum() - win.sum() <= 2                                # nowhere else


def test_ghost_is_drawn_at_the_estimated_pose(top_frames):
    """The estimate 3 m east of the truth, heading west: a red box along x at (8, 3), its
    arrow pointing west; no red on the true hull; nothing red before the first estimate."""
    red = _red(top_frames["ghost"])
    hx, hy = HULL_HALF[0] + GHOST_MARGIN, HULL_HALF[1] + GHOST_MARGIN
    z = ROOF_Z + GHOST_MARGIN
    assert _coverage(red, "ghost", 8.0, 3.0, z, 0.8 * hx, 0.8 * hy) > 0.9
    # beyond the box's short half-size north and south: ground (red if the box faced north)
    for sgn in (1, -1):
        assert _coverage(red, "ghost", 8.0, 3.0 + sgn * 0.5 * (hx + hy), z, 0.3,
                         0.4 * (hx - hy)) < 0.3
    # the 1.6 m arrow west, beyond the box (0.83 m); a 2-3 px wide shaft in a 5 px band
    assert _coverage(red, "ghost", 8.0 - 1.2, 3.0, 1.05, 0.2, 0.1) > 0.25
    assert _coverage(red, "ghost", 8.0 + 1.2, 3.0, 1.05, 0.2, 0.1) == 0.0
    assert _coverage(red, "ghost", 5.0, 3.0, ROOF_Z, 0.6, 0.4) == 0.0       # the true hull
    assert _red(top_frames["no_estimate"])[40:].sum() == 0


def test_ghost_shows_when_the_estimate_is_within_centimetres(top_frames):
    """1 cm off: a ghost the hull's size would be hidden in the opaque hull; the larger
    translucent box tints the whole roof red."""
    red = _red(top_frames["close"])
    assert _coverage(red, "close", 5.01, 3.0, ROOF_Z, 0.8 * HULL_HALF[1], 0.8 * HULL_HALF[0]) \
        > 0.8


def test_render_finds_a_configuration_named_by_path(tmp_path):
    """A configuration named by file path is labelled by its ``name`` (not a file models/
    has), so the clip takes the file the sweep resolved from the run's manifest."""
    from estimator.configuration import SensorConfig
    from experiments.render import _config_file
    from experiments.selection import find_cell
    from experiments.sweep import run

    src = Path(__file__).resolve().parents[1] / "models" / "configs" / "rover_gps4.toml"
    text = src.read_text().replace('name = "rover_gps4"', 'name = "my_roof"')
    assert 'name = "my_roof"' in text
    (tmp_path / "roof.toml").write_text(text)
    (tmp_path / "spec.toml").write_text(
        'name = "roof"\nseeds = 1\nmasks = ["full"]\n[defaults]\npath = "square20"\n'
        'config = "roof.toml"\nnoise = "none"\n[[grid]]\nwindow = [1]\n'
        'technique = ["none"]\n[epochs]\nseeds = [0]\n')
    out = tmp_path / "out"
    run(tmp_path / "spec.toml", out=out, jobs=1, figures=False, progress=False,
        cache_dir=tmp_path / "cache")
    cell = find_cell(out, None, {"window": "1"})
    assert cell["config"] == "my_roof"
    with pytest.raises(ValueError):
        SensorConfig.load(str(cell["config"]))
    f = _config_file(out, cell)
    assert Path(f).resolve() == (tmp_path / "roof.toml").resolve()
    assert SensorConfig.load(f).name == "my_roof"
