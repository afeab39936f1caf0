"""A non-editable install works: the model files ship as package data (issue 18)."""

from __future__ import annotations

import os
import subprocess
import sys
import zipfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def test_wheel_ships_models_and_presets_and_loads_them(tmp_path):
    """Build the wheel, install it into a bare folder, and load a configuration, a path, a
    noise model and a preset from outside the checkout."""
    wheel_dir = tmp_path / "wheel"
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps",
                    "-q", "-w", str(wheel_dir), str(REPO)], check=True, capture_output=True,
                   timeout=300)
    (whl,) = wheel_dir.glob("configpose-*.whl")
    names = set(zipfile.ZipFile(whl).namelist())
    for f in ("configpose_models/rover.xml", "configpose_models/configs/rover_gps8.toml",
              "configpose_models/paths/square100.toml",
              "configpose_models/noise/gps_stationary.toml",
              "experiments/presets/thesis.toml", "configpose_models/recordings/synthetic_rig.toml",
              "configpose_models/recordings/synthetic_rig/ant1.nmea",
              "experiments/page_assets/page.js"):
        assert f in names, f
    target = tmp_path / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "-q", "--target",
                    str(target), str(whl)], check=True, capture_output=True, timeout=300)
    code = ("from estimator.model_files import MODELS_DIR, SOURCE_CHECKOUT\n"
            "from estimator.configuration import SensorConfig\n"
            "from sim.paths import load_path\n"
            "from sim.gps import GpsNoiseModel\n"
            "from experiments.spec import load_spec, RESULTS_ROOT\n"
            "assert not SOURCE_CHECKOUT, MODELS_DIR\n"
            f"assert str(MODELS_DIR).startswith({str(target)!r}), MODELS_DIR\n"
            "SensorConfig.load('rover_gps8'); load_path('square100')\n"
            "GpsNoiseModel.load('gps_stationary'); load_spec('quick')\n"
            "import pathlib; assert RESULTS_ROOT == pathlib.Path.cwd() / 'results'\n"
            "print('ok')\n")
    env = {**os.environ, "PYTHONPATH": str(target)}
    run = tmp_path / "elsewhere"
    run.mkdir()
    out = subprocess.run([sys.executable, "-c", code], cwd=run, env=env, capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr[-2000:]
