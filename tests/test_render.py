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
