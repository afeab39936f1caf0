"""Issue 14 wiring: techniques in specs and the sweep, the heading table and eh_rmse, the
filter's vehicle parameters, and the car-like case's simulation pieces (path fields, braking
before corners, the car model)."""

import json
import math

import numpy as np
import pandas as pd
import pytest
from pose_scenes import kinematic_truth

from experiments.spec import NO_SOLVER, NO_WEIGHTS, TECHNIQUES, Spec, SpecError
from sim.controllers import PurePursuitParams, simulate_unicycle
from sim.paths import Path, PathError, load_path


# --------------------------------------------------------------------------- specs
def _spec(technique, **extra):
    return Spec.from_dict({"name": "t", "seeds": 1, "grid": [
        {"path": "square20", "window": [1, 5], "technique": technique, **extra}]})


def test_new_techniques_take_no_solver_and_no_weights():
    for tech in ("ekf_fixed_lag", "ekf_smoother"):
        assert tech in TECHNIQUES and tech in NO_SOLVER and tech in NO_WEIGHTS
        cells = _spec(tech, weighting=["none", "huff"], solver=["slsqp", "ccp"]).expand()
        assert {c.solver for c in cells} == {"-"} and {c.weighting for c in cells} == {"-"}
        assert len(cells) == 2            # one per window, not per weighting x solver


def test_gtsam_technique_without_gtsam_fails_on_load_with_the_install_command(monkeypatch):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "gtsam" else real(name, *a))
    with pytest.raises(SpecError, match=r"gtsam.*pip install -e '\.\[gtsam\]'"):
        _spec("gtsam")


def test_peer_preset_loads_when_gtsam_is_installed():
    pytest.importorskip("gtsam")
    from experiments.spec import load_spec

    spec = load_spec("peer")
    cells = spec.expand()
    assert len(spec.seeds) == 10
    techs = {(c.path, c.technique) for c in cells}
    for path in ("square100", "square200", "car_block"):
        for tech in ("ekf", "ekf_fixed_lag", "ekf_smoother", "gtsam", "none"):
            assert (path, tech) in techs


# --------------------------------------------------------------------------- sweep
def test_filter_params_come_from_the_vehicle():
    from experiments.sweep import filter_params_for

    truth, _, limits = kinematic_truth("car_block", "car_rtk4", cg_ahead_m=1.3)
    truth.meta["params"] = {"controller": {**limits, "cruise_speed_mps": 15.0}}
    p = filter_params_for(truth)
    for field in ("max_accel_mps2", "max_lateral_accel_mps2", "max_turn_rate_radps",
                  "max_yaw_accel_radps2"):                  # the path's limits, by name
        assert getattr(p, field) == limits[field], field
    assert p.no_slip_point_m == (-1.3, 0.0)
    del truth.meta["no_slip_point_m"]                   # truths simulated before issue 14
    assert filter_params_for(truth).no_slip_point_m == (0.0, 0.0)


def test_sweep_scores_the_filter_family_with_eh_rmse(tmp_path):
    """A tiny sweep on a kinematic square (no MuJoCo): eh_rmse in cells.parquet and
    by_cell.csv, the heading table written, the estimator's time per epoch there."""
    from experiments.sweep import run

    def truth_fn(path_file, overrides, config_file, seed, cache_dir):
        truth, _, limits = kinematic_truth("square20", "rover_gps8")
        truth.meta["params"] = {"controller": limits}
        return truth

    spec = Spec.from_dict({"name": "heading", "seeds": 2, "masks": ["full"], "grid": [
        {"path": "square20", "window": 1, "noise": "gps_rtk",
         "technique": ["ekf", "ekf_fixed_lag", "ekf_smoother", "none"]}]})
    res = run(spec, out=tmp_path, jobs=1, progress=False, figures=False, truth_fn=truth_fn)
    assert res.n_failed == 0
    cells = pd.read_parquet(tmp_path / "cells.parquet")
    assert cells["eh_rmse"].notna().all()
    by = pd.read_csv(tmp_path / "by_cell.csv")
    assert {"eh_rmse", "eh_rmse_lo", "eh_rmse_hi"} <= set(by.columns)
    ht = pd.read_csv(tmp_path / "heading.csv")
    assert set(ht["technique"]) == {"ekf", "ekf_fixed_lag", "ekf_smoother", "none"}
    # centimetre fixes on the 1.5 m rover: every filter row within a degree
    assert (ht.loc[ht["technique"] != "none", "eh_rmse_deg"] < 1.0).all()
    assert "## Heading" in (tmp_path / "tables.md").read_text()
    # wall times stay out of the tracked files: the time per epoch is in a *.local.csv
    assert not any(c.startswith("us_per_epoch") for c in ht.columns)
    tm = pd.read_csv(tmp_path / "heading_timings.local.csv")
    assert (tm["us_per_epoch"] > 0).all() and len(tm) == len(ht)


# --------------------------------------------------------------------------- tables
def test_heading_table_by_hand():
    from experiments.tables import heading_table

    rows = []
    for seed, (rmse, mx, eu, t_s, n) in enumerate([(0.01, 0.05, 1.0, 0.2, 100),
                                                     (0.03, 2.0, 1.2, 0.4, 100)]):
        rows.append({"path": "square100", "technique": "ekf", "weighting": "-", "window": 1,
                     "mask": "full", "seed": seed, "eh_rmse": rmse, "eh_p95": rmse,
                     "eh_max": mx, "eu_mean": eu, "t_track_s": t_s, "n_epochs": n})
    rows.append({**rows[0], "technique": "none", "weighting": "huff", "seed": 0})
    rows.append({**rows[0], "technique": "none", "weighting": "none", "seed": 0,
                 "eh_rmse": 9.0})
    rows.append({**rows[0], "mask": "no_turns", "eh_rmse": 9.0})
    ht = heading_table(pd.DataFrame(rows))
    ekf = ht[ht["technique"] == "ekf"].iloc[0]
    assert ekf["eh_rmse_deg"] == pytest.approx(math.degrees(0.02))
    assert ekf["us_per_epoch"] == pytest.approx(3000.0)     # (2000 + 4000) us / 2
    assert ekf["eu_mean"] == pytest.approx(1.1) and ekf["flip_seeds"] == 1
    assert ekf["n_seeds"] == 2
    fit = ht[ht["technique"] == "none"]
    assert len(fit) == 1 and fit.iloc[0]["weighting"] == "huff"   # Huff preferred
    assert ht.iloc[0]["estimator"] == "EKF (causal)"


# --------------------------------------------------------------------------- sim
def test_path_vehicle_and_corner_speed_fields():
    p = load_path("car_block")
    assert p.vehicle == "car" and p.corner_speed_mps == 5.0
    d = p.to_dict()
    assert d["vehicle"] == "car" and d["corner_speed_mps"] == 5.0
    assert Path.from_dict(d).to_dict() == d
    rover = load_path("square100").to_dict()
    assert "vehicle" not in rover and "corner_speed_mps" not in rover
    for bad in ("car.xml", "../car", 3, ""):
        with pytest.raises(PathError, match="vehicle"):
            Path.from_dict({**d, "vehicle": bad})
    for bad in (0.0, -5.0, math.inf, math.nan, True):
        with pytest.raises(PathError, match="corner_speed_mps"):
            Path.from_dict({**d, "corner_speed_mps": bad})


def _entry_speeds(p):
    """Speed of the unicycle as it enters each corner's target area (first sample within
    target_radius_m of a corner point after being outside)."""
    t, xy, _ = simulate_unicycle(p, dt=0.02)
    v = np.hypot(*np.gradient(xy, t, axis=0).T)
    c = p.corners[:, :2]
    near = np.min(np.hypot(xy[:, None, 0] - c[None, :, 0], xy[:, None, 1] - c[None, :, 1]),
                  axis=1)
    inside = near < p.target_radius_m
    first = np.flatnonzero(inside[1:] & ~inside[:-1]) + 1
    return v[first], v


def test_braking_before_corners():
    """With corner_speed_mps the platform brakes (at 0.8 of its acceleration limit) so
    that it enters each corner's target area at that speed; without it, it enters near
    cruise speed and only the lateral-acceleration limit slows the turn."""
    p = load_path("car_block")
    entry, v = _entry_speeds(p)
    # 11 corners (2 laps x 6 - the end point), then the final approach (stopping law)
    assert entry.size == 12
    # the law's corner speed (5 m/s) at the area's edge; 0.1 m/s for 0.02 s samples and the
    # central difference (measured 4.98-5.01)
    np.testing.assert_allclose(entry[:-1], p.corner_speed_mps, atol=0.1)
    assert v.max() == pytest.approx(p.cruise_speed_mps, abs=0.05)
    free = Path.from_dict({k: w for k, w in p.to_dict().items() if k != "corner_speed_mps"})
    # without the braking law it enters closer to the cruise speed than to the corner speed
    assert _entry_speeds(free)[0].max() > (p.corner_speed_mps + p.cruise_speed_mps) / 2
    assert PurePursuitParams.from_path(load_path("square100")).corner_speed_mps is None


@pytest.mark.slow
def test_car_model_drives_the_block_with_a_no_slip_rear_axle():
    """models/car.xml on car_block: the controlled point is the rear axle (1.3 m behind the
    chassis origin, read from the model), whose sideways speed stays near 0 (soft contacts
    creep by millimetres per second), while the antenna frame's centre moves sideways in the
    turns; speeds 0-15 m/s."""
    from estimator.configuration import SensorConfig
    from sim.rover import simulate_rover

    tr = simulate_rover("car_block", SensorConfig.load("car_rtk4"), cache_dir=False)
    assert tr.meta["no_slip_point_m"] == [-1.3, 0.0]
    c, s = np.cos(tr.yaw), np.sin(tr.yaw)
    axle = tr.cg[:, :2] - 1.3 * np.c_[c, s]
    va = np.gradient(axle, tr.t, axis=0)
    vc = np.gradient(tr.cg[:, :2], tr.t, axis=0)
    lat_axle = -s * va[:, 0] + c * va[:, 1]
    lat_cg = -s * vc[:, 0] + c * vc[:, 1]
    assert np.abs(lat_axle).max() < 0.05 and np.abs(lat_cg).max() > 0.5
    assert tr.speed.max() < 15.2 and np.abs(tr.speed * tr.yaw_rate).max() < 4.2
    assert json.loads(json.dumps(tr.meta["path"]))["vehicle"] == "car"
