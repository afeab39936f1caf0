"""Tests for experiments.identification (thesis 003 Section 3.3 study, part 3 of the
ultrasonic study). Synthetic responses keep the default tests fast and independent of the
simulator: the whole run (fits, table, report, figures) happens once, in a module fixture;
the other tests call the pure layers (identify, identification_table) on small inputs. The
run on sim.quadcopter is marked slow; the pitch evidence runs once on a small budget."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from estimator.sysid import FORMS, simulate, step_response
from experiments.identification import (
    AXIS_FORMS,
    THESIS,
    identification_table,
    identify,
    main,
    pitch_evidence,
    run_identification,
    thesis_window_study,
)

# Plants of the three forms with the simulator's rough scale (sim/quadcopter.py docstring).
TRUE = {
    "thrust": {"K": 4.1, "Tp1": 0.3, "Tp2": 0.6, "Td": 0.66},
    "pitch": {"K": 14.3, "Tw": 1.2, "zeta": 0.21, "Td": 0.38},
    "yaw_rate": {"K": 1.0, "Tp1": 1.85, "Td": 0.12},
}
AMP = {"thrust": (0.2, 0.5), "pitch": (0.1, 0.5), "yaw_rate": (0.5, 1.0)}


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


def _lag(form: str, p: dict) -> float:
    """Independent of sysid.total_lag: the ramp asymptote's lag read off a long simulated
    step response, t - y(t) / K at t = 400 s. The slowest transient here (the thesis's
    pitch, Tw / zeta = 13.5 s) is down to e^-29 of its size, below 1e-10 s."""
    t = np.arange(0.0, 400.0 + 1e-9, 0.05)
    return float(t[-1] - step_response(t, form, {**p, "K": 1.0})[-1])


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
    # synthetic data: no simulator, so no pitch evidence and no simulator constants
    assert not (out / "identification_pitch_evidence.csv").exists()
    assert table.simulator.isna().all()
    md = (out / "identification.md").read_text()
    for axis in AXIS_FORMS:
        assert f"## {axis}" in md
    assert "0.6858" in md  # the thesis's inconsistent thrust delay is reported
    assert "## Summary" in md


def test_table_rows_and_thesis_lags(quick_run):
    _, table = quick_run
    assert len(table) == sum(len(FORMS[f]) + 1 for f in AXIS_FORMS.values())
    for axis, form in AXIS_FORMS.items():
        sub = table[table.axis == axis].set_index("parameter")
        assert list(sub.index) == [*FORMS[form], "lag"]
        # the thesis's total lag is the ramp lag of the thesis's own model (behaviour, read
        # off its step response; 1e-6 s: the 400 s response has fully settled)
        assert sub.loc["lag", "thesis"] == pytest.approx(
            _lag(form, THESIS[axis]["params"]), abs=1e-6)


def test_clean_fit_recovers_synthetic_truth(quick_run):
    _, table = quick_run
    for axis, form in AXIS_FORMS.items():
        sub = table[table.axis == axis].set_index("parameter")
        for k, v in {**TRUE[axis], "lag": _lag(form, TRUE[axis])}.items():
            # noise-free data of the exact model form: recovered to solver tolerance; 1e-4
            # leaves room for the multi-start optimum's stopping tolerance
            assert sub.loc[k, "clean"] == pytest.approx(v, rel=1e-4), (axis, k)
        assert (sub.clean_fit_pct > 99.99).all()
        assert (sub.step_fit_pct > 99.99).all()
        assert (sub.noisy_fit_pct < sub.clean_fit_pct).all()
        assert (sub.noisy_ci_low <= sub.noisy_ci_high).all()


def test_thesis_in_ci_column_agrees_with_the_intervals(quick_run):
    _, table = quick_run
    k_rows = table.parameter == "K"
    assert table.loc[k_rows, "thesis_in_noisy_ci"].isna().all()   # units differ
    rest = table[~k_rows]
    inside = (rest.noisy_ci_low <= rest.thesis) & (rest.thesis <= rest.noisy_ci_high)
    assert (rest.thesis_in_noisy_ci.astype(bool) == inside).all()
    # the synthetic pitch (Tw 1.2 s) is far from the thesis's 5.44 s with tight intervals
    pitch = rest[rest.axis == "pitch"].set_index("parameter")
    assert not pitch.loc["Tw", "thesis_in_noisy_ci"]


def _small(step: bool = False) -> dict:
    return synthetic(step=step)


def test_same_seed_same_results():
    a = identification_table(identify(_small(), seed=3, n_mc=1, n_starts=2), noise_m=0.01)
    b = identification_table(identify(_small(), seed=3, n_mc=1, n_starts=2), noise_m=0.01)
    cols = [c for c in a.columns if not c.endswith("time_s")]
    pd.testing.assert_frame_equal(a[cols], b[cols])
    c = identification_table(identify(_small(), seed=4, n_mc=0, n_starts=2), noise_m=0.01)
    assert not np.array_equal(a.noisy.to_numpy(), c.noisy.to_numpy())


def test_noise_free_skips_noisy_fits():
    results = identify(_small(), noise_m=0.0, n_mc=5, n_starts=2)
    table = identification_table(results, noise_m=0.0)
    assert table.noisy.isna().all() and (table.n_mc == 0).all()
    assert table.step_fit_pct.isna().all() and table.thesis_in_noisy_ci.isna().all()
    assert all(r.noisy is None and r.mc == () for r in results.values())


def _never_called():
    raise AssertionError("responses were produced although an argument is invalid")


@pytest.mark.parametrize("kw,field,exc", [({"noise_m": -1.0}, "noise_m", ValueError),
                                          ({"noise_m": float("nan")}, "noise_m", ValueError),
                                          ({"noise_m": math.inf}, "noise_m", ValueError),
                                          ({"seed": -2}, "seed", ValueError),
                                          ({"seed": 1.5}, "seed", TypeError),
                                          ({"n_mc": -1}, "n_mc", ValueError),
                                          ({"n_starts": 0}, "n_starts", ValueError),
                                          ({"quick": "yes"}, "quick", TypeError)])
def test_bad_arguments_raise_before_any_work(tmp_path, kw, field, exc):
    with pytest.raises(exc, match=rf"^{field}"):
        run_identification(tmp_path / "out", responses=_never_called, **kw)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("mutate", [
    lambda d: d.pop(("pitch", "impulse")),
    lambda d: d.__setitem__(("thrust", "impulse"), (np.zeros(3), np.zeros(4), np.zeros(3))),
    lambda d: d.__setitem__(("thrust", "step"), "not a triple"),
])
def test_bad_responses_raise_before_fitting(tmp_path, mutate):
    data = synthetic(step=False)
    mutate(data)
    with pytest.raises(ValueError, match=r"^responses"):
        run_identification(tmp_path / "out", quick=True, responses=data)
    assert not (tmp_path / "out").exists()


@pytest.fixture(scope="module")
def evidence():
    pytest.importorskip("mujoco")
    return pitch_evidence(seed=0, noise_m=0.0, n_starts=2)


def test_pitch_evidence_rows(evidence):
    rows, window = evidence
    assert window is None            # noise_m = 0: no thesis-window study
    r = rows.set_index("case")
    rate, angle = r.loc["default plant, rate mode"], r.loc["default plant, angle mode"]
    assert rate.in_f450_ranges and angle.in_f450_ranges
    # rate mode underdamped, angle mode overdamped (fit and linear chain agree on it)
    assert rate.fit_zeta < 1 and rate.chain_zeta < 1
    assert angle.fit_zeta > 1 and angle.chain_zeta > 1
    # the F450 corners bound the rate-mode Tw below the thesis's 5.44 s
    slow = r.loc["F450 ranges: slowest corner"]
    assert slow.chain_Tw > rate.chain_Tw > r.loc["F450 ranges: fastest corner"].chain_Tw
    assert slow.chain_Tw < THESIS["pitch"]["params"]["Tw"]
    # the implied values lie outside the ranges, and MuJoCo with them reproduces the
    # thesis: the chain to 1 % (its inversion neglects the motor lag), the fit to 2 % / 3 %
    # (fit vs chain measured at the default plant: Tw 0.3 %, zeta 3.4 %)
    imp = r.loc["values the thesis's Tw, zeta imply"]
    th = THESIS["pitch"]["params"]
    assert not imp.in_f450_ranges
    assert imp.chain_Tw == pytest.approx(th["Tw"], rel=0.01)
    assert imp.chain_zeta == pytest.approx(th["zeta"], rel=0.01)
    assert imp.fit_Tw == pytest.approx(th["Tw"], rel=0.02)
    assert imp.fit_zeta == pytest.approx(th["zeta"], rel=0.03)


def test_thesis_window_study():
    """At 1 cm the thesis's own window leaves Tw and zeta undetermined (the study's finding:
    0 % identifiable over 10 runs in results/ultrasonic); at 1 um the same fit recovers
    them with intervals that cover the thesis's values, so the "undetermined" is the
    window and the noise, not a broken fit. 2 runs of 1 start each: ~0.2 s per call."""
    w = thesis_window_study(seed=0, noise_m=0.01, n_runs=2, n_starts=1)
    assert w["n_runs"] == 2 and w["t_end_s"] == pytest.approx(5.0)
    sharp = thesis_window_study(seed=0, noise_m=1e-6, n_runs=2, n_starts=1)
    th = THESIS["pitch"]["params"]
    for k in ("Tw", "zeta"):
        assert w[f"frac_identifiable_{k}"] == 0.0
        lo, hi = w[f"median_ci_{k}"]
        assert hi - lo > th[k]                      # wider than the value itself
        assert sharp[f"frac_identifiable_{k}"] == 1.0 and sharp[f"frac_ci_covers_{k}"] == 1.0
        lo, hi = sharp[f"median_ci_{k}"]
        assert lo < th[k] < hi and hi - lo < 0.01 * th[k]
    # the thesis's model in its own window: 0.5 s of unit stick, K 3.4259 m/s, y(5 s) as
    # sysid.simulate gives it (the study adds noise only)
    assert w["y_end_m"] == pytest.approx(0.274, abs=0.001)
    with pytest.raises(ValueError, match="^noise_m"):
        thesis_window_study(noise_m=0.0)
    with pytest.raises(ValueError, match="^n_runs"):
        thesis_window_study(n_runs=0)


@pytest.mark.slow
def test_cli_on_simulator(tmp_path, capsys):
    """The real run: the simulator's impulse responses (a few seconds of MuJoCo each)."""
    pytest.importorskip("mujoco")
    assert main(["--out", str(tmp_path), "--quick"]) == 0
    table = pd.read_csv(tmp_path / "identification.csv")
    assert (table.clean_fit_pct > 95).all()
    assert table.simulator.notna().any()
    assert (tmp_path / "identification_pitch_evidence.csv").exists()
    assert "identification.md" in capsys.readouterr().out
