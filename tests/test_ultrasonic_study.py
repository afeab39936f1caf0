"""Smoke test of the ultrasonic study (python -m experiments.ultrasonic) at tiny sizes."""

import json

import numpy as np
import pytest

from experiments import ultrasonic as study


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("ultrasonic")
    spec = study.StudySpec(n_mc=3000, flight_duration_s=12.0)
    res = study.run(out, spec, identification=False, figures=True)
    return out, res


def test_outputs_written(quick_run):
    out, _res = quick_run
    for name in ("mc_table.csv", "mc_table.md", "mc_pixels.csv", "flight_stages.csv",
                 "flight_stages.md", "flight_series.csv", "README.md", "run_info.json",
                 "mc_mse_maps.png", "flight_ranges.png", "flight_position.png",
                 "flight_heading.png"):
        assert (out / name).stat().st_size > 0, name
    info = json.loads((out / "run_info.json").read_text())
    assert info["spec"]["n_mc"] == 3000
    assert "Part 3 not run" in (out / "README.md").read_text()


def test_monte_carlo_table_is_sane(quick_run):
    _, res = quick_run
    mc = res["mc"].set_index("method")
    cfp, cmd = mc.loc["CFP (Rx 43, 44, 45)"], mc.loc["CMD (Rx 43, 44, 45)"]
    # the same three-sphere solution: identical totals up to rounding
    assert cfp["mse_total_mm2"] == pytest.approx(cmd["mse_total_mm2"], rel=1e-9)
    # x/y MSE of every method is of the order of (sigma * GDOP)^2: 5 mm noise, GDOP ~10
    assert np.all(mc["mse_x_mm2"] < 1e5) and np.all(mc["mse_x_mm2"] > 25)


def test_flight_filters_reduce_error(quick_run):
    _, res = quick_run
    fl = res["flight"]
    for gates in fl["gates"].unique():
        d = fl[fl["gates"] == gates].set_index("stage")
        assert d.loc["filter1+2 -> CMD", "rmse_3d_m"] <= d.loc["raw -> CMD", "rmse_3d_m"]
    assert np.isfinite(fl["heading_rmse_deg"]).all()


def test_same_seed_same_numbers(tmp_path):
    spec = study.StudySpec(n_mc=500, flight_duration_s=6.0)
    a = study.run(tmp_path / "a", spec, identification=False, figures=False)
    b = study.run(tmp_path / "b", spec, identification=False, figures=False)
    assert a["mc"].drop(columns="time_s").equals(b["mc"].drop(columns="time_s"))
    assert a["flight"].equals(b["flight"])


def test_cli_rejects_bad_args():
    with pytest.raises(SystemExit):
        study.main(["--n-mc", "0"])


def test_best_triple_is_the_largest_triangle():
    from sim.ultrasonic import load_receivers

    names, rec = load_receivers("flight")
    i, j, k = study.best_triple(rec)
    area = 0.5 * np.linalg.norm(np.cross(rec[j] - rec[i], rec[k] - rec[i]))
    assert {names[i], names[j], names[k]} == {"R43", "R44", "R45"}
    assert area == pytest.approx(0.5 * 1.2954 * 1.08052, rel=1e-3)
