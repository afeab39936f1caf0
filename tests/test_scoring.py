"""The sweep's cell scorer (estimator.scoring, issue 27): score_track's fast path against
an independent, straightforward computation of every column on a small hand-built case
(loops and numpy's own statistics), the optional per-(truth, observations) reference, and
the helpers' edge cases (missing statuses, missing observations, bad input)."""

from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
from scipy.stats import chi2

from estimator.scoring import (
    CONSISTENCY_COLUMNS,
    ScoringReference,
    _nanmean_rows,
    _status_flags,
    score_track,
)

MASKS = ("full", "no_turns", "no_turns_window")
#: relative tolerance of the straightforward computation: the same statistics by other
#: formulas (np.median / np.percentile / np.std, a Python loop per window, scipy's chi2
#: band): equal up to the last bits of their own rounding (1e-12 is ~4500 ulp)
RTOL = 1e-12


def _case(seed: int = 4, n: int = 80, m: int = 3):
    """A truth on an uneven time line with a turn, observations with a dead sensor at some
    epochs and none at one epoch, and a track from epoch 5 on with NaN estimates, a
    varying window, heading standard deviations, NIS and statuses (one missing)."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.08, 0.12, n))
    yaw = np.where(np.arange(n) < 40, 0.0, np.minimum((np.arange(n) - 40) * 0.2, np.pi / 2))
    v = np.column_stack((np.cos(yaw), np.sin(yaw))) * 1.5
    cg = np.column_stack((np.cumsum(v[:, 0] * 0.1), np.cumsum(v[:, 1] * 0.1), np.zeros(n)))
    turning = (np.arange(n) >= 40) & (np.arange(n) < 49)
    off = rng.normal(0, 0.5, (m, 3))
    sp = cg[:, None, :] + off[None]
    truth = SimpleNamespace(t=t, cg=cg, yaw=yaw, turning=turning, sensor_positions=sp,
                            sensor_names=tuple(f"s{j}" for j in range(m)), n=n)
    obs = sp[..., :2] + rng.normal(0, 0.3, (n, m, 2))
    obs[10:20, 1] = np.nan
    obs[30] = np.nan
    rows = np.arange(5, n)
    k = rows.size
    est = cg[rows, :2] + rng.normal(0, 0.2, (k, 2))
    est[[3, 4, 50]] = np.nan
    eyaw = yaw[rows] + rng.normal(0, 0.05, k)
    eyaw[7] = np.nan
    status = np.array(rng.choice(["ok", "ok", "inconsistent", "waiting"], k), dtype=object)
    status[2] = None
    df = pd.DataFrame({"t": t[rows], "cg_x": est[:, 0], "cg_y": est[:, 1], "yaw": eyaw,
                       "window": rng.integers(1, 6, k), "yaw_sd": rng.uniform(0.02, 0.1, k),
                       "nis": rng.chisquare(2, k), "nis_dof": rng.choice([0, 2, 4], k),
                       "solver_status": status})
    return df, truth, obs, rows


def _stats(e: np.ndarray, mk: np.ndarray, signed: bool = False) -> dict:
    fin = e[mk & np.isfinite(e)]
    if not fin.size:
        return {}
    mag = np.abs(fin) if signed else fin
    q1, q3 = np.percentile(mag, [25, 75])
    return {"mean": np.mean(fin), "median": np.median(fin), "std": np.std(fin, ddof=1),
            "rmse": np.sqrt(np.mean(fin ** 2)), "p95": np.percentile(mag, 95),
            "max": np.max(mag), "outliers": np.mean(mag > q3 + 1.5 * (q3 - q1))}


def _band_share(v: np.ndarray, dof: np.ndarray) -> tuple[float, float]:
    """(sum v / sum dof, share inside the central 95 % chi-square band) of the rows with a
    finite value and dof > 0."""
    ok = np.isfinite(v) & (dof > 0)
    lo, hi = chi2.ppf(0.025, dof[ok]), chi2.ppf(0.975, dof[ok])
    return v[ok].sum() / dof[ok].sum(), np.mean((v[ok] >= lo) & (v[ok] <= hi))


def _straightforward(df, truth, obs, rows) -> tuple[dict[str, dict], dict[str, np.ndarray]]:
    """Every column of score_track's rows, computed the plain way, by mask; and the masks."""
    cg, t = truth.cg[:, :2], truth.t
    d = df[["cg_x", "cg_y"]].to_numpy() - cg[rows]
    vel = np.gradient(cg, t, axis=0)
    course = np.arctan2(vel[:, 1], vel[:, 0])[rows]
    along = d[:, 0] * np.cos(course) + d[:, 1] * np.sin(course)
    dyaw = df["yaw"].to_numpy() - truth.yaw[rows]
    series = {"ex": np.abs(d[:, 0]), "ey": np.abs(d[:, 1]), "eu": np.hypot(d[:, 0], d[:, 1]),
              "eh": np.abs(np.angle(np.exp(1j * dyaw)))}
    win = df["window"].to_numpy()
    masks = {"full": np.ones(rows.size, bool), "no_turns": ~truth.turning[rows],
             "no_turns_window": np.array([not truth.turning[r - w + 1:r + 1].any()
                                          for r, w in zip(rows, win)])}
    with np.errstate(invalid="ignore"), pytest.warns(RuntimeWarning):
        obs_e = np.nanmean(np.abs(obs - truth.sensor_positions[..., :2]), axis=1)[rows]
    status = df["solver_status"].to_numpy(dtype=object)
    nees = (series["eh"] / df["yaw_sd"].to_numpy()) ** 2
    out = {}
    for name, mk in masks.items():
        row: dict = {"n_epochs": int(mk.sum())}
        for s, e in series.items():
            row.update({f"{s}_{k}": v for k, v in _stats(e, mk).items()})
        sa = _stats(along, mk, signed=True)
        row["along_mean"], row["along_median"] = sa["mean"], sa["median"]
        steps = [np.hypot(*(d[j] - d[j - 1])) for j in range(1, rows.size)
                 if mk[j] and mk[j - 1]]
        steps = np.array([s for s in steps if np.isfinite(s)])
        row["jitter_rms"] = np.sqrt(np.mean(steps ** 2))
        row["obs_ex_mean"], row["obs_ey_mean"] = np.nanmean(obs_e[mk], axis=0)
        row["nees_mean"], row["nees_in_band"] = _band_share(nees[mk], np.ones(mk.sum()))
        row["nis_per_dof"], row["nis_in_band"] = _band_share(
            df["nis"].to_numpy()[mk], df["nis_dof"].to_numpy(float)[mk])
        row["status_not_ok"] = np.mean([s != "ok" for s in status[mk]])
        row["status_inconsistent"] = np.mean([s == "inconsistent" for s in status[mk]])
        out[name] = row
    return out, masks


def test_score_track_equals_a_straightforward_computation():
    """Each statistic of each mask, the jitter, the observations' own error and the
    consistency columns equal the plain computation (RTOL); a wrong mask, a wrong window
    reach or a dropped NaN row would move several of them by far more."""
    df, truth, obs, rows = _case()
    got, ep = score_track(df, truth, obs, None, MASKS)
    want, masks = _straightforward(df, truth, obs, rows)
    assert [r["mask"] for r in got] == list(MASKS)
    for row in got:
        w = want[row["mask"]]
        assert row["n_epochs"] == w["n_epochs"]
        assert 0 < w["n_epochs"] < rows.size or row["mask"] == "full"
        for key, value in w.items():
            assert row[key] == pytest.approx(value, rel=RTOL, abs=1e-15), (row["mask"], key)
        assert row["n_valid"] + row["n_nan"] == row["n_epochs"] and row["n_nan"] > 0
    assert ep["no_turns_window"].tolist() == masks["no_turns_window"].tolist()
    assert len(ep) == rows.size and ep["err_x"].isna().sum() == 3


def test_reference_gives_the_same_numbers_bit_for_bit():
    """ScoringReference (built once per truth and observations, for a caller that scores
    many tracks of them) changes no number, not even in the last bit, nor the epoch table."""
    df, truth, obs, _ = _case(seed=9)
    ref = ScoringReference.of(truth, obs)
    for track in (df, df.iloc[::2].reset_index(drop=True), df.drop(columns="window")):
        a, ea = score_track(track, truth, obs, None, MASKS)
        b, eb = score_track(track, truth, obs, None, MASKS, reference=ref)
        assert [list(x) for x in a] == [list(y) for y in b]
        for x, y in zip(a, b):
            assert all(x[c] == y[c] or (x[c] != x[c] and y[c] != y[c]) for c in x)
        pd.testing.assert_frame_equal(ea, eb, check_exact=True)


def test_reference_of_other_inputs_is_refused():
    df, truth, obs, _ = _case()
    ref = ScoringReference.of(truth, obs)
    with pytest.raises(ValueError, match="reference"):
        score_track(df, truth, obs.copy(), None, MASKS, reference=ref)
    with pytest.raises(ValueError, match="reference"):
        score_track(df, truth, obs, None, MASKS, reference=ScoringReference.of(truth))
    with pytest.raises(ValueError, match="obs"):
        ScoringReference.of(truth, obs[:-1])


def test_missing_columns_and_bad_windows_name_the_field():
    df, truth, obs, _ = _case()
    with pytest.raises(ValueError, match="'cg_y'"):
        score_track(df.drop(columns="cg_y"), truth, obs, None, MASKS)
    bad = df.copy()
    bad.loc[0, "window"] = 7                       # epoch 5 cannot have a window of 7
    with pytest.raises(ValueError, match=r"window\[5\] = 7"):
        score_track(bad, truth, obs, None, MASKS)
    late = df.copy()
    late.loc[3, "t"] = 99.0
    with pytest.raises(ValueError, match="est_t"):
        score_track(late, truth, obs, None, MASKS)


@pytest.mark.parametrize("dtype", [object, "str", pd.StringDtype("python"),
                                   pd.StringDtype("pyarrow")])
def test_status_flags_of_every_string_column_kind(dtype):
    """A missing status is not ok and not inconsistent, as comparing the object array."""
    s = pd.Series(["ok", None, "inconsistent", "waiting"], dtype=dtype).array
    not_ok, inc = _status_flags(s)
    assert not_ok.dtype == bool and inc.dtype == bool
    assert not_ok.tolist() == [False, True, True, True]
    assert inc.tolist() == [False, False, True, False]


def test_nanmean_rows_is_numpys_nanmean_exactly():
    rng = np.random.default_rng(2)
    a = np.abs(rng.standard_cauchy((500, 8)))
    a[rng.random(a.shape) < 0.2] = np.nan
    a[7] = np.nan
    with pytest.warns(RuntimeWarning):
        want = np.nanmean(a, axis=1)
    assert np.array_equal(_nanmean_rows(a.copy()), want, equal_nan=True)
    b = a[~np.isnan(a).any(axis=1)]
    assert np.array_equal(_nanmean_rows(b.copy()), np.nanmean(b, axis=1))


def test_consistency_columns_are_nan_without_their_inputs():
    df, truth, obs, _ = _case()
    rows, _ = score_track(df[["t", "cg_x", "cg_y", "yaw"]], truth, obs, None, MASKS,
                          epochs=False)
    assert all(np.isnan(r[c]) for r in rows for c in CONSISTENCY_COLUMNS)


def test_band_equals_nis_summary_bit_for_bit():
    """The consistency shares take nis_summary's per-row band once per track and mask the
    rows after: the same two numbers, exactly, for any mask (values on the band's edges
    included)."""
    from estimator.pose_filter import _chdtri, nis_summary
    from estimator.scoring import _Band

    rng = np.random.default_rng(6)
    dof = rng.choice([0.0, 1.0, 2.0, 3.0], 400)
    v = rng.chisquare(np.maximum(dof, 1))
    v[rng.random(400) < 0.1] = np.nan
    v[:8] = _chdtri(np.maximum(dof[:8], 1), 0.5 + 0.5 * 0.95)          # on the edges
    v[8:16] = _chdtri(np.maximum(dof[8:16], 1), 0.5 - 0.5 * 0.95)
    band = _Band.of(v, dof)
    for mk in (np.ones(400, bool), rng.random(400) < 0.3, np.zeros(400, bool)):
        s = nis_summary(v[mk], dof[mk])
        got = band.at(mk)
        want = (s["mean_nis_per_dof"], s["share_in_band"])
        assert got == want or (np.isnan(got).all() and np.isnan(want).all())


@pytest.mark.parametrize("dtype", [object, "str"])
def test_status_counts_are_value_counts(dtype):
    from estimator.scoring import status_counts

    vals = ["ok"] * 5 + ["insufficient_data"] * 7 + [None] + ["inconsistent"] * 2
    df = pd.DataFrame({"solver_status": pd.array(vals, dtype=dtype), "t": np.arange(15.0)})
    want = {str(k): int(v) for k, v in df["solver_status"].value_counts().items()}
    got = status_counts(df)
    assert list(got.items()) == list(want.items())
    assert status_counts(df[["t"]]) == {}
