"""Consistency columns of the sweep (issue 25): heading NEES and NIS summaries per cell
(estimator.scoring) and in the heading table (experiments.tables), on hand-built tracks
whose covariance is known."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from estimator.scoring import CONSISTENCY_COLUMNS, consistency, coverage_rows, score_track

N = 20000


def _truth(n: int = N) -> SimpleNamespace:
    """A straight drive at 1 m/s, heading 0.3 rad, two antennas 1 m apart, 1 Hz."""
    t = np.arange(n, dtype=float)
    cg = np.stack([t, np.zeros(n)], 1)
    pos = np.stack([cg + [0.5, 0.0], cg - [0.5, 0.0]], 1)
    return SimpleNamespace(t=t, cg=cg, yaw=np.full(n, 0.3), turning=np.zeros(n, bool),
                           sensor_positions=pos, sensor_names=("a", "b"), n=n)


def _track(truth, yaw_err, yaw_sd, nis=None, dof=None, status=None) -> pd.DataFrame:
    df = pd.DataFrame({"t": truth.t, "cg_x": truth.cg[:, 0], "cg_y": truth.cg[:, 1],
                       "yaw": truth.yaw + yaw_err, "window": 1, "yaw_sd": yaw_sd})
    if nis is not None:
        df["nis"], df["nis_dof"] = nis, dof
    if status is not None:
        df["solver_status"] = status
    return df


def test_nees_and_nis_of_a_consistent_track_are_one_and_95_percent():
    rng = np.random.default_rng(7)
    truth = _truth()
    sd = rng.uniform(0.005, 0.05, N)                   # known, varying heading sd (rad)
    dof = rng.choice([2, 4, 8], N).astype(float)
    status = np.where(np.arange(N) % 10 == 0, "inconsistent", "ok")
    df = _track(truth, rng.normal(0.0, sd), sd, rng.chisquare(dof), dof, status)
    rows, _ = score_track(df, truth, truth.sensor_positions[..., :2], None, ["full"],
                          epochs=False)
    r = rows[0]
    # mean of N chi-square(1) / N: sd sqrt(2 / N) = 0.01; 5 sd
    assert r["nees_mean"] == pytest.approx(1.0, abs=0.05)
    # a share of N rows: binomial sd sqrt(0.95 * 0.05 / N) = 0.0015; 5 sd
    assert r["nees_in_band"] == pytest.approx(0.95, abs=0.008)
    # sum of chi-square(dof) over the summed dof: sd sqrt(2 / sum dof) < 0.005
    assert r["nis_per_dof"] == pytest.approx(1.0, abs=0.025)
    assert r["nis_in_band"] == pytest.approx(0.95, abs=0.008)
    assert r["status_not_ok"] == pytest.approx(0.1) and r["status_inconsistent"] == 0.1


def test_an_overconfident_track_shows_in_nees_and_the_band():
    rng = np.random.default_rng(8)
    truth = _truth()
    sd = np.full(N, 0.01)
    # the error is twice the sd the estimate claims: NEES mean 4, inside the band only
    # where |z| < sqrt(5.024) / 2 = 1.121, P = 0.738
    df = _track(truth, rng.normal(0.0, 2 * sd), sd)
    rows, _ = score_track(df, truth, truth.sensor_positions[..., :2], None, ["full"],
                          epochs=False)
    assert rows[0]["nees_mean"] == pytest.approx(4.0, abs=0.2)      # 5 sd of 4 sqrt(2/N)
    assert rows[0]["nees_in_band"] == pytest.approx(0.738, abs=0.02)
    # no nis / nis_dof / status columns: NaN, not 0
    for c in ("nis_per_dof", "nis_in_band", "status_not_ok", "status_inconsistent"):
        assert math.isnan(rows[0][c])


def test_exact_nees_and_missing_values_are_left_out():
    truth = _truth(4)
    sd = np.array([0.1, 0.1, np.nan, 0.2])
    err = np.array([0.2, 0.1, 0.3, 0.0])              # NEES 4, 1, -, 0
    df = _track(truth, err, sd, nis=np.array([2.0, np.nan, 6.0, 4.0]),
                dof=np.array([2.0, 0.0, 2.0, 4.0]),
                status=np.array(["ok", "waiting", "ok", "reinit"], dtype=object))
    out = consistency(df, err, np.ones(4, bool))
    assert out["nees_mean"] == pytest.approx(5.0 / 3.0)
    # chi-square(1) 95 % band [0.00098, 5.02]: 4 and 1 inside, 0 below
    assert out["nees_in_band"] == pytest.approx(2.0 / 3.0)
    assert out["nis_per_dof"] == pytest.approx(12.0 / 8.0)
    assert out["status_not_ok"] == 0.5 and out["status_inconsistent"] == 0.0
    # a mask picks rows
    out = consistency(df, err, np.array([True, False, False, False]))
    assert out["nees_mean"] == pytest.approx(4.0) and out["status_not_ok"] == 0.0


def test_window_fit_track_has_nan_consistency_and_coverage_rows_keep_nis():
    truth = _truth(50)
    df = _track(truth, np.zeros(50), np.zeros(50)).drop(columns="yaw_sd")
    rows, _ = score_track(df, truth, truth.sensor_positions[..., :2], None, ["full"],
                          epochs=False)
    assert all(math.isnan(rows[0][c]) for c in CONSISTENCY_COLUMNS)
    df = _track(truth, np.zeros(50), np.full(50, 0.1), nis=np.full(50, 2.0),
                dof=np.full(50, 2.0), status=np.array(["ok"] * 50, dtype=object))
    row = coverage_rows(df)[0]                          # no reference: no NEES
    assert math.isnan(row["nees_mean"]) and row["nis_per_dof"] == 1.0
    assert row["status_not_ok"] == 0.0


def test_heading_table_carries_the_consistency_columns():
    from experiments.tables import heading_table

    rows = []
    for seed, nees in enumerate((0.8, 1.2)):
        base = {"path": "square100", "weighting": "-", "window": 1, "mask": "full",
                "seed": seed, "eh_rmse": 0.01, "eh_p95": 0.02, "eh_max": 0.05,
                "eu_mean": 1.0, "t_track_s": 0.2, "n_epochs": 100}
        rows.append({**base, "technique": "ekf", "nees_mean": nees, "nees_in_band": 0.9,
                     "nis_per_dof": 2.0, "nis_in_band": 0.5, "status_not_ok": 0.1,
                     "status_inconsistent": 0.05})
        rows.append({**base, "technique": "none", "weighting": "huff",
                     **dict.fromkeys(CONSISTENCY_COLUMNS, np.nan)})
    ht = heading_table(pd.DataFrame(rows))
    for c in CONSISTENCY_COLUMNS:
        assert {c, f"{c}_lo", f"{c}_hi"} <= set(ht.columns)
    ekf = ht[ht["technique"] == "ekf"].iloc[0]
    assert ekf["nees_mean"] == pytest.approx(1.0) and ekf["nees_mean_lo"] >= 0.0
    assert ekf["nis_per_dof"] == 2.0 and ekf["status_inconsistent"] == 0.05
    fit = ht[ht["technique"] == "none"].iloc[0]
    assert all(math.isnan(fit[c]) for c in CONSISTENCY_COLUMNS)   # NaN, not 0
    # a cell table from before issue 25 (no such columns) still gives the table, NaN there
    old = pd.DataFrame(rows).drop(columns=list(CONSISTENCY_COLUMNS))
    assert heading_table(old)["nees_mean"].isna().all()


def test_tables_md_heading_section_has_the_consistency_columns(tmp_path):
    from experiments.tables import _variant_tables

    rows = []
    for seed in (0, 1):
        rows.append({"path": "square100", "technique": "ekf", "weighting": "-", "window": 1,
                     "mask": "full", "seed": seed, "eh_rmse": 0.01, "eh_p95": 0.02,
                     "eh_max": 0.05, "eu_mean": 1.0, "t_track_s": 0.2, "n_epochs": 100,
                     "nees_mean": 1.1, "nees_in_band": 0.93, "nis_per_dof": 1.4,
                     "nis_in_band": 0.8, "status_not_ok": 0.02, "status_inconsistent": 0.01,
                     "dyn_growth": "-",
                     **{f"{a}_{s}": 0.5 for a in ("ex", "ey") for s in ("mean", "median", "std")}})
    md = "\n".join(_variant_tables(pd.DataFrame(rows), tmp_path, ""))
    head = next(line for line in md.splitlines() if line.startswith("| Path | Estimator"))
    for name in ("NEES", "NEES in band", "NIS/dof", "NIS in band", "not ok", "inconsistent"):
        assert f"| {name} |" in head
    ht = pd.read_csv(tmp_path / "heading.csv")
    assert ht.loc[0, "nis_per_dof"] == pytest.approx(1.4)
