"""Metrics (Eq. 4.1, 4.2, summaries, masks, alignment) against hand-computed values."""

import math

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimator.metrics import (
    STATISTICS,
    align_to_truth,
    along_cross_errors,
    cg_errors,
    evaluate_track,
    evaluation_masks,
    heading_error,
    jitter_rms,
    summarize,
    track_errors,
    travel_direction,
)


def test_cg_errors_hand_values():
    est = np.array([[1.0, 2.0], [0.0, 0.0], [np.nan, np.nan]])
    true = np.array([[4.0, 6.0], [-1.0, 1.0], [0.0, 0.0]])
    e = cg_errors(est, true)
    np.testing.assert_array_equal(e["x"][:2], [3.0, 1.0])
    np.testing.assert_array_equal(e["y"][:2], [4.0, 1.0])
    np.testing.assert_allclose(e["euclid"][:2], [5.0, math.sqrt(2)])
    assert np.isnan(e["x"][2]) and np.isnan(e["euclid"][2])
    with pytest.raises(ValueError, match="shapes differ"):
        cg_errors(est, true[:2])
    with pytest.raises(ValueError, match="est_xy"):
        cg_errors(np.zeros(3), true)


def test_heading_error_wraps():
    # 3.1 vs -3.1: 0.083 rad apart across +/-pi, not 6.2
    e = heading_error(np.array([3.1, 0.5, -math.pi]), np.array([-3.1, 0.2, math.pi]))
    np.testing.assert_allclose(e, [2 * math.pi - 6.2, 0.3, 0.0], atol=1e-12)


def test_along_cross_hand_values():
    # travelling north (yaw pi/2): an estimate 2 m south and 1 m east lags 2 m, is 1 m right
    a, c = along_cross_errors(np.array([[1.0, -2.0]]), np.zeros((1, 2)), np.array([math.pi / 2]))
    assert a[0] == pytest.approx(-2.0) and c[0] == pytest.approx(-1.0)


def test_summarize_hand_values():
    e = np.array([1.0, 2.0, 3.0, 4.0, np.nan])
    s = summarize(e)
    assert s["n"] == 4 and s["n_nan"] == 1
    assert s["mean"] == pytest.approx(2.5)
    assert s["median"] == pytest.approx(2.5)
    assert s["std"] == pytest.approx(math.sqrt(5.0 / 3.0))  # ddof = 1: sum sq dev 5 / 3
    assert s["rmse"] == pytest.approx(math.sqrt(30.0 / 4.0))
    assert s["p95"] == pytest.approx(3.85)  # linear interpolation at rank 0.95 * 3 = 2.85
    assert s["max"] == 4.0
    m = summarize(e, np.array([True, False, True, False, True]))
    assert m["n"] == 2 and m["n_nan"] == 1 and m["mean"] == pytest.approx(2.0)
    empty = summarize(np.array([np.nan]))
    assert empty["n"] == 0 and all(math.isnan(empty[k]) for k in STATISTICS)
    with pytest.raises(ValueError, match="mask"):
        summarize(e, np.ones(5))


def test_evaluation_masks_margin():
    tr = np.zeros(10, bool)
    tr[5] = True
    t = np.arange(10.0)
    m0 = evaluation_masks(tr)
    assert m0["full"].all() and m0["no_turns"].sum() == 9 and not m0["no_turns"][5]
    m1 = evaluation_masks(tr, t, margin_s=1.0)
    np.testing.assert_array_equal(np.flatnonzero(~m1["no_turns"]), [4, 5, 6])
    with pytest.raises(ValueError, match="t: required"):
        evaluation_masks(tr, margin_s=1.0)
    with pytest.raises(ValueError, match="turning"):
        evaluation_masks(np.zeros(3))


def _window_mask_reference(turning, t, window, margin_s):
    """Brute force: an estimate is kept when no epoch of its window is within margin_s of
    a turning epoch."""
    tt = t[turning]
    out = np.zeros(turning.size, bool)
    for k, w in enumerate(window):
        if w == 0:
            continue
        win = t[k - w + 1:k + 1]
        near = tt.size and (np.abs(win[:, None] - tt[None, :]) <= margin_s).any()
        out[k] = not near
    return out


def test_no_turns_window_hand_example():
    """Issue 15: "LC No Turns" drops every estimate whose window still holds a turning
    epoch. A turn at epoch 5, windows of 3: estimates at 5, 6, 7 hold it; with a 1 s margin
    epochs 4-6 count as turning, so 4-8 go; no estimate at epochs 0-1 (window 0)."""
    tr = np.zeros(12, bool)
    tr[5] = True
    t = np.arange(12.0)
    win = np.r_[0, 0, np.full(10, 3)]
    m = evaluation_masks(tr, window=win)
    np.testing.assert_array_equal(np.flatnonzero(~m["no_turns_window"]), [0, 1, 5, 6, 7])
    np.testing.assert_array_equal(np.flatnonzero(~m["no_turns"]), [5])
    m1 = evaluation_masks(tr, t, margin_s=1.0, window=win)
    np.testing.assert_array_equal(np.flatnonzero(~m1["no_turns_window"]), [0, 1, 4, 5, 6, 7, 8])
    assert "no_turns_window" not in evaluation_masks(tr)
    with pytest.raises(ValueError, match=r"window\[2\]"):
        evaluation_masks(tr, window=np.r_[0, 0, 4, np.full(9, 3)])
    with pytest.raises(ValueError, match="window"):
        evaluation_masks(tr, window=np.full(12, 1.0))
    with pytest.raises(ValueError, match="window"):
        evaluation_masks(tr, window=np.full(11, 1))


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.booleans(), st.integers(0, 50)), max_size=120),
       st.sampled_from([0.0, 0.5, 2.0, 1e300]))
def test_no_turns_window_matches_brute_force(rows, margin):
    """Random turning flags and window sizes (clipped to the epochs available), margins up
    to 1e300 s: the cumulative-count mask equals the brute-force definition."""
    tr = np.array([r[0] for r in rows], dtype=bool)
    win = np.array([min(r[1], k + 1) for k, r in enumerate(rows)], dtype=np.int64)
    t = np.arange(tr.size) * 0.7
    got = evaluation_masks(tr, t, margin_s=margin, window=win)["no_turns_window"]
    np.testing.assert_array_equal(got, _window_mask_reference(tr, t, win, margin))
    assert not (got & ~evaluation_masks(tr, t, margin_s=margin)["no_turns"]).any()


def test_evaluate_track_scores_the_window_mask():
    tt = np.arange(8.0)
    cg = np.c_[tt, np.zeros(8)]
    turning = np.zeros(8, bool)
    turning[2] = True
    df = pd.DataFrame({"t": tt[2:], "cg_x": tt[2:], "cg_y": np.ones(6), "yaw": np.zeros(6),
                       "window": np.full(6, 3)})
    ev = evaluate_track(df, tt, cg, np.zeros(8), turning).set_index(["mask", "quantity"])
    assert ev.loc[("no_turns", "x"), "n"] == 5          # epoch 2 only
    assert ev.loc[("no_turns_window", "x"), "n"] == 3   # epochs 2, 3, 4 hold epoch 2


def test_align_to_truth():
    tt = np.array([0.0, 0.5, 1.0, 2.0])
    np.testing.assert_array_equal(align_to_truth(np.array([0.5, 2.0, 0.0]), tt), [1, 3, 0])
    with pytest.raises(ValueError, match="1.5"):
        align_to_truth(np.array([1.5]), tt)
    with pytest.raises(ValueError, match="strictly increasing"):
        align_to_truth(np.array([0.0]), np.array([1.0, 0.0]))


def test_evaluate_track_hand_example():
    # truth moves east at 1 m/s, yaw 0; the estimate lags 2 m and is 1 m north, yaw 0.1
    tt = np.arange(6.0)
    cg = np.c_[tt, np.zeros(6)]
    yaw = np.zeros(6)
    rows = np.arange(2, 6)
    df = pd.DataFrame({"t": tt[rows], "cg_x": tt[rows] - 2.0, "cg_y": np.ones(4),
                       "yaw": np.full(4, 0.1), "yaw_loc": np.full(4, -0.2)})
    turning = np.zeros(6, bool)
    turning[3] = True
    ev = evaluate_track(df, tt, cg, yaw, turning).set_index(["mask", "quantity"])
    assert ev.loc[("full", "x"), "mean"] == pytest.approx(2.0)
    assert ev.loc[("full", "y"), "mean"] == pytest.approx(1.0)
    assert ev.loc[("full", "euclid"), "max"] == pytest.approx(math.sqrt(5.0))
    assert ev.loc[("full", "along"), "mean"] == pytest.approx(-2.0)  # lag is negative
    assert ev.loc[("full", "along"), "max"] == pytest.approx(2.0)  # magnitude
    assert ev.loc[("full", "yaw"), "mean"] == pytest.approx(0.1)
    assert ev.loc[("full", "yaw_loc"), "mean"] == pytest.approx(0.2)
    assert ev.loc[("no_turns", "x"), "n"] == 3
    with pytest.raises(ValueError, match="cg_x"):
        evaluate_track(df.drop(columns="cg_x"), tt, cg, yaw)


@pytest.mark.parametrize("bad", [np.nan, 0.5], ids=["nan", "repeated"])
def test_align_to_truth_rejects_nan_or_repeated_truth_time(bad):
    tt = np.array([0.0, 0.5, 1.0, 2.0])
    tt[2] = bad
    with pytest.raises(ValueError, match=r"^truth_t: .*truth_t\[2\]"):
        align_to_truth(np.array([0.0]), tt)


def test_align_to_truth_rejects_nan_estimate_time():
    # a NaN estimate time used to be matched silently to the last truth sample
    with pytest.raises(ValueError, match=r"^est_t: .*est_t\[1\]"):
        align_to_truth(np.array([0.0, np.nan]), np.array([0.0, 0.5, 1.0]))



# ----------------------------------------------------------------------------- issue 18
def test_summarize_outliers_and_signed_hand_values():
    """Box-plot outliers: 1..8 and 40: Q1 = 3, Q3 = 7 (linear ranks 2 and 6), whisker
    7 + 1.5 * 4 = 13, so 40 is the one outlier of 9. Signed: mean -1 of (-3, 1) but p95 /
    max / outliers of the magnitudes (3, 1)."""
    s = summarize(np.r_[np.arange(1.0, 9.0), 40.0])
    assert s["outliers"] == pytest.approx(1 / 9)
    assert math.isnan(summarize(np.array([1.0, 2.0, 50.0]))["outliers"])   # < 4 values
    a = summarize(np.array([-3.0, 1.0]), signed=True)
    assert a["mean"] == -1.0 and a["median"] == -1.0 and a["max"] == 3.0
    assert a["p95"] == pytest.approx(1 + 0.95 * 2) and a["rmse"] == pytest.approx(math.sqrt(5))
    inf = summarize(np.array([1.0, np.inf, 3.0]))
    assert inf["n"] == 2 and inf["n_nan"] == 1 and inf["max"] == 3.0  # inf: no estimate


@settings(max_examples=150, deadline=None)
@given(st.lists(st.one_of(st.floats(-1e300, 1e300, allow_nan=False),
                          st.sampled_from([0.0, -0.0, 1e-300, np.nan, np.inf])),
                max_size=60),
       st.booleans())
def test_summarize_equals_numpy_statistics(values, signed):
    """One partition serves the median, p95 and quartiles: the same floats as numpy's median /
    percentile (linear) and the Tukey fraction by definition, for any values (1e300, signed
    zeros, NaN and inf counted as missing)."""
    e = np.array(values, dtype=float)
    with np.errstate(over="ignore"):     # the mean / rmse of 1e300s overflow, as in numpy
        s = summarize(e, signed=signed)
    fin = e[np.isfinite(e)]
    assert s["n"] == fin.size and s["n_nan"] == e.size - fin.size
    if not fin.size:
        assert all(math.isnan(s[k]) for k in (*STATISTICS, "outliers"))
        return
    mag = np.abs(fin) if signed else fin
    with np.errstate(over="ignore", invalid="ignore"):
        assert s["mean"] == fin.mean() or (math.isnan(s["mean"]) and np.isnan(fin.mean()))
        assert s["median"] == np.median(fin)
        assert s["p95"] == np.percentile(mag, 95) and s["max"] == mag.max()
        if fin.size >= 4:
            q1, q3 = np.percentile(mag, [25, 75])
            assert s["outliers"] == np.mean(mag > q3 + 1.5 * (q3 - q1))


def test_jitter_rms_hand_values():
    """Errors (0,0), (3,4), (3,4), (NaN): steps 5, 0, NaN -> RMS sqrt(25/2); a mask that
    drops row 1 leaves no consecutive pair inside it but (2, 3), which is NaN."""
    d = np.array([[0.0, 0.0], [3.0, 4.0], [3.0, 4.0], [np.nan, np.nan]])
    assert jitter_rms(d) == pytest.approx(math.sqrt(12.5))
    assert math.isnan(jitter_rms(d, np.array([True, False, True, True])))
    assert math.isnan(jitter_rms(d[:1]))
    with pytest.raises(ValueError, match="mask"):
        jitter_rms(d, np.ones(3, bool))


def test_travel_direction_is_the_course_with_the_heading_at_rest():
    """A platform driving north-east while facing east (side-slip, yaw 0): the direction of
    travel is pi/4, not the heading; at rest (repeated positions) the heading; without a
    heading NaN; a speed floor turns slow epochs over to the heading."""
    t = np.arange(5.0)
    cg = np.array([[0, 0], [1, 1], [2, 2], [2, 2], [2, 2]], dtype=float)
    yaw = np.zeros(5)
    d = travel_direction(t, cg, yaw)
    np.testing.assert_allclose(d[:3], math.pi / 4, atol=1e-15)
    # central differences: epoch 3 sees (2,2) -> (2,2) on both sides: at rest
    np.testing.assert_array_equal(d[3:], 0.0)
    assert np.isnan(travel_direction(t, cg)[3:]).all()
    slow = travel_direction(t, cg * 0.1, yaw, min_speed_mps=0.2)   # 0.14 m/s < 0.2
    np.testing.assert_array_equal(slow, 0.0)
    assert travel_direction(t[:1], cg[:1], yaw[:1])[0] == 0.0      # one sample: the heading
    with pytest.raises(ValueError, match="min_speed_mps"):
        travel_direction(t, cg, yaw, min_speed_mps=-1.0)
    with pytest.raises(ValueError, match="cg"):
        travel_direction(t, cg[:4], yaw)


def test_track_errors_hand_example_reversing():
    """The truth drives backwards (west) facing east: a window estimate 2 m east of it has
    trailed along the direction of travel, along = -2 (along the heading it would read +2);
    1 m north is 1 m to the right of travel (cross -1); heading error 0.1 rad."""
    tt = np.arange(6.0)
    cg = np.c_[-tt, np.zeros(6)]
    yaw = np.zeros(6)
    e = track_errors(tt[2:], cg[2:] + [2.0, 1.0], np.full(4, 0.1), tt, cg, yaw)
    np.testing.assert_array_equal(e.index, [2, 3, 4, 5])
    np.testing.assert_allclose(e.along, -2.0, atol=1e-12)
    np.testing.assert_allclose(e.cross, -1.0, atol=1e-12)
    np.testing.assert_allclose(e.heading, 0.1, atol=1e-12)
    np.testing.assert_array_equal(e.euclid, math.sqrt(5.0))
    np.testing.assert_array_equal(e.dxy, [[2.0, 1.0]] * 4)
    assert np.isnan(track_errors(tt[2:], cg[2:], None, tt, cg, yaw).heading).all()
    with pytest.raises(ValueError, match="est_t"):
        track_errors(tt[2:] + 0.5, cg[2:], None, tt, cg, yaw)
    with pytest.raises(ValueError, match="est_xy"):
        track_errors(tt[2:], cg[3:], None, tt, cg, yaw)


def test_sweep_and_evaluate_track_are_one_scorer():
    """The sweep's score_track and evaluate_track give the same numbers for the same track
    (both are estimator.metrics): per-axis and Euclidean errors, heading, along-track (on a
    platform whose CG is 0.5 m ahead of its no-slip axle, so course and heading differ in
    the turns), and the sweep's outlier share and jitter agree with their definitions."""
    from pose_scenes import kinematic_truth

    from estimator.tracking import track
    from experiments.sweep import score_track
    from sim.gps import observe

    truth, cfg, _ = kinematic_truth("square20", "rover_gps4", cg_ahead_m=0.5)
    truth.turning[::7] = True                               # some epochs to leave out
    obs = observe(truth, cfg, "gps_stationary", rng=np.random.default_rng(2), session_s=600.0)
    df = track(truth.t, obs, cfg, window=5, layout_check=False)
    rows, _ = score_track(df, truth, obs, cfg, ("full", "no_turns"), epochs=False)
    ev = evaluate_track(df, truth.t, truth.cg, truth.yaw, truth.turning,
                        heading_columns=("yaw",)).set_index(["mask", "quantity"])
    for row in rows:
        for col, q in (("ex", "x"), ("ey", "y"), ("eu", "euclid"), ("eh", "yaw")):
            for stat in (*STATISTICS, "outliers"):
                assert row[f"{col}_{stat}"] == ev.loc[(row["mask"], q), stat], (col, stat)
        assert row["along_mean"] == ev.loc[(row["mask"], "along"), "mean"]
        assert row["along_median"] == ev.loc[(row["mask"], "along"), "median"]
    e = track_errors(df["t"], df[["cg_x", "cg_y"]].to_numpy(), None, truth.t, truth.cg,
                     truth.yaw)
    slip = np.abs(np.angle(np.exp(1j * (travel_direction(truth.t, truth.cg, truth.yaw)
                                         - truth.yaw))))
    assert slip.max() > 0.05                                # the course is not the heading
    d = np.diff(e.dxy, axis=0)
    assert rows[0]["jitter_rms"] == pytest.approx(np.sqrt(np.mean(np.sum(d * d, axis=1))),
                                                  rel=1e-12)


@settings(max_examples=120, deadline=None)
@given(st.integers(0, 70), st.integers(0, 2**32 - 1), st.sampled_from(["none", "rows", "mixed"]))
def test_summaries_equal_summarize_bit_for_bit(k, seed, nans):
    """summaries (issue 27: every series of a mask at once, joint pairwise sums and one
    partition) gives summarize's numbers exactly, and its types, for any size (0-3 values:
    NaN std / outliers), NaN rows shared by the series or not, ties and infinities."""
    from estimator.metrics import summaries

    rng = np.random.default_rng(seed)
    ser = {"x": np.abs(rng.normal(size=k)), "y": np.round(np.abs(rng.normal(size=k)), 1),
           "h": np.abs(rng.standard_cauchy(size=k)), "a": rng.normal(size=k) * 3}
    if nans != "none" and k:
        gone = rng.random(k) < 0.2
        for v in ser.values():
            v[gone] = np.nan
        if nans == "mixed":
            ser["h"][rng.random(k) < 0.2] = np.nan
            ser["y"][0] = np.inf
    masks = {"all": None, "some": rng.random(k) < 0.6, "none": np.zeros(k, bool),
             "every": np.ones(k, bool)}
    got = summaries(ser, masks, signed={"a"})
    for mname, mk in masks.items():
        for name, e in ser.items():
            want = summarize(e, mk, signed=name == "a")
            have = got[mname][name]
            assert list(have) == list(want)
            for q, w in want.items():
                assert type(have[q]) is type(w), (mname, name, q)
                assert have[q] == w or (math.isnan(w) and math.isnan(have[q])), (mname, name, q)


def test_summaries_rejects_bad_shapes_naming_the_argument():
    from estimator.metrics import summaries

    with pytest.raises(ValueError, match=r"series\['y'\]"):
        summaries({"x": np.zeros(3), "y": np.zeros(4)}, {"all": None})
    with pytest.raises(ValueError, match=r"masks\['m'\]"):
        summaries({"x": np.zeros(3)}, {"m": np.array([1, 0, 1])})


def test_index_rows_and_nearest_samples_fast_paths():
    """A run of consecutive epochs becomes a slice (a view, the same values); estimates at
    the truth's own times take the exact-match path, others the nearest sample as before."""
    from estimator.metrics import index_rows, nearest_samples

    assert index_rows(np.arange(3, 9)) == slice(3, 9)
    for idx in (np.array([3, 5, 6]), np.array([4, 4, 5]), np.array([], dtype=int)):
        assert index_rows(idx) is idx
    tt = np.array([0.0, 0.1, 0.25, 0.4, 0.6])
    assert nearest_samples(tt[1:4], tt, 1e-6).tolist() == [1, 2, 3]
    assert nearest_samples(np.array([0.0999999, 0.6000001]), tt, 1e-6).tolist() == [1, 4]
    assert align_to_truth([0.25, 0.25], tt).tolist() == [2, 2]
    with pytest.raises(ValueError, match="est_t"):
        nearest_samples(np.array([0.7]), tt, 1e-6)
