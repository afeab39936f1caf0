"""Tests for experiments.identification (thesis 003 Section 3.3 study, part 3 of the
ultrasonic study). Synthetic responses keep the default tests fast and independent of the
simulator; the run on sim.quadcopter is marked slow."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from estimator.sysid import FORMS, simulate
from experiments.identification import AXIS_FORMS, THESIS, main, run_identification

# Plants of the three forms with the simulator's rough scale (sim/quadcopter.py docstring).
TRUE = {
    "thrust": {"K": 4.1, "Tp1": 0.3, "Tp2": 0.6, "Td": 0.66},
    "pitch": {"K": 28.0, "Tw": 0.66, "zeta": 0.8, "Td": 0.35},
    "yaw_rate": {"K": 1.0, "Tp1": 1.85, "Td": 0.12},
}
AMP = {"thrust": (0.2, 0.5), "pitch": (0.05, 0.5), "yaw_rate": (0.5, 1.0)}


def synthetic(step: bool = True) -> dict:
    t = np.arange(0.0, 8.0 + 1e-9, 0.05)
    out = {}
    for axis, form in AXIS_FORMS.items():
        amp, width = AMP[axis]
        u = amp * ((t >= 1.0 - 1e-9) & (t < 1.0 + width - 1e-9))
        out[(axis, "impulse")] = (t, u, simulate(t, u, form, TRUE[axis]))
        if step:
            us = amp * (t >= 1.0 - 1e-9)
            out[(axis, "step")] = (t, us, simulate(t, us, form, TRUE[axis]))
    return out


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("ident")
    table = run_identification(out, seed=3, noise_m=0.01, quick=True, n_mc=3,
                               responses=synthetic)
    return out, table


def test_outputs_written(quick_run):
    out, table = quick_run
    for name in ("identification.md", "identification.csv", "identification_series.csv",
                 *(f"identification_{a}.png" for a in AXIS_FORMS)):
        assert (out / name).stat().st_size > 0, name
    assert pd.read_csv(out / "identification.csv").shape == table.shape
    md = (out / "identification.md").read_text()
    for axis in AXIS_FORMS:
        assert f"## {axis}" in md
    assert "0.6858" in md  # the thesis's inconsistent thrust delay is reported
    assert "## Summary" in md


def test_table_rows_and_thesis_values(quick_run):
    _, table = quick_run
    assert len(table) == sum(len(FORMS[f]) + 1 for f in AXIS_FORMS.values())
    for axis, form in AXIS_FORMS.items():
        sub = table[table.axis == axis].set_index("parameter")
        assert list(sub.index) == [*FORMS[form], "lag"]
        th = THESIS[axis]["params"]
        for k, v in th.items():
            assert sub.loc[k, "thesis"] == v
        extra = 2 * th["zeta"] * th["Tw"] if form == "second_order" else (
            th["Tp1"] + th.get("Tp2", 0.0))
        assert sub.loc["lag", "thesis"] == pytest.approx(th["Td"] + extra, rel=1e-12)
        # synthetic responses: no simulator constants
        assert sub.simulator.isna().all()


def test_clean_fit_recovers_synthetic_truth(quick_run):
    _, table = quick_run
    for axis in AXIS_FORMS:
        sub = table[table.axis == axis].set_index("parameter")
        lag = TRUE[axis]["Td"] + (2 * TRUE[axis]["zeta"] * TRUE[axis]["Tw"] if axis == "pitch"
                                  else TRUE[axis]["Tp1"] + TRUE[axis].get("Tp2", 0.0))
        for k, v in {**TRUE[axis], "lag": lag}.items():
            # noise-free data of the exact model form: recovered to solver tolerance; 1e-4
            # leaves room for the multi-start optimum's stopping tolerance
            assert sub.loc[k, "clean"] == pytest.approx(v, rel=1e-4), (axis, k)
        assert (sub.clean_fit_pct > 99.99).all()
        assert (sub.step_fit_pct > 99.99).all()
        assert (sub.noisy_fit_pct < sub.clean_fit_pct).all()
        assert (sub.noisy_ci_low <= sub.noisy_ci_high).all()


def test_same_seed_same_table(tmp_path, quick_run):
    _, table = quick_run
    again = run_identification(tmp_path, seed=3, noise_m=0.01, quick=True, n_mc=3,
                               responses=synthetic)
    cols = [c for c in table.columns if not c.endswith("time_s")]
    pd.testing.assert_frame_equal(table[cols], again[cols])


def test_noise_free_option_skips_noisy_fits(tmp_path):
    table = run_identification(tmp_path, noise_m=0.0, quick=True,
                               responses=lambda: synthetic(step=False))
    assert table.noisy.isna().all() and (table.n_mc == 0).all()
    assert table.step_fit_pct.isna().all()
    assert (tmp_path / "identification_pitch.png").exists()


@pytest.mark.parametrize("kw,field", [({"noise_m": -1.0}, "noise_m"),
                                      ({"noise_m": float("nan")}, "noise_m"),
                                      ({"seed": -2}, "seed"),
                                      ({"n_mc": -1}, "n_mc")])
def test_bad_arguments(tmp_path, kw, field):
    with pytest.raises(ValueError, match=rf"^{field}"):
        run_identification(tmp_path, responses=synthetic, **kw)


def test_missing_axis_raises(tmp_path):
    data = synthetic(step=False)
    del data[("pitch", "impulse")]
    with pytest.raises(ValueError, match=r"^responses"):
        run_identification(tmp_path, quick=True, responses=data)


@pytest.mark.slow
def test_cli_on_simulator(tmp_path, capsys):
    """The real run: the simulator's impulse responses (a few seconds of MuJoCo each)."""
    pytest.importorskip("mujoco")
    assert main(["--out", str(tmp_path), "--quick"]) == 0
    table = pd.read_csv(tmp_path / "identification.csv")
    assert (table.clean_fit_pct > 95).all()
    assert "identification.md" in capsys.readouterr().out
