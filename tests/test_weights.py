"""Tests of estimator.weights (dissertation Section 3.3): hand-computed Huff cases, Huber
against statsmodels, deleted residuals on a worked example, batching and bad input."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from statsmodels.robust.norms import HuberT
from statsmodels.robust.scale import mad as sm_mad

from estimator.configuration import SensorConfig
from estimator.weights import (
    deleted_residual_mask,
    huber_weights,
    huff_huber_weights,
    huff_weights,
    random_weights,
)
from estimator.window import fit_window

NAN = np.nan


# ----------------------------------------------------------------------------- Huff
@pytest.fixture
def line4() -> SensorConfig:
    """Four sensors on a line, 1 m apart: a_01 = 1, a_02 = 2, a_03 = 3, a_12 = 1, ..."""
    return SensorConfig(list("ABCD"), [[0, 0], [1, 0], [2, 0], [3, 0]])


def _line_obs(xs):
    return np.array([[[x, 0.0] for x in xs]])


def test_huff_hand_case_all_reporting(line4):
    # B observed 0.1 m too far forward: pair errors |AB| 1.1 (0.1), |AC| 2 (0), |AD| 3 (0),
    # |BC| 0.9 (0.1), |BD| 1.9 (0.1), |CD| 1 (0).
    # relative errors (step 6, 3 relationships each): A 0.1/3, B 0.3/3, C 0.1/3, D 0.1/3
    # step 8: w = 1/r * 3/(m-1) = 1/r  ->  A 30, B 10, C 30, D 30
    obs = _line_obs([0.0, 1.1, 2.0, 3.0])
    np.testing.assert_allclose(huff_weights(obs, line4), [[30, 10, 30, 30]], rtol=1e-9)
    # step 4: average error = 0.3 / 6 pairs = 0.05 m
    # threshold 0.05: step 5 excludes the whole time step
    np.testing.assert_array_equal(huff_weights(obs, line4, threshold=0.05), [[0, 0, 0, 0]])
    # threshold 0.06: step 5 passes; step 7 excludes B (0.1 >= 0.06), keeps the others
    np.testing.assert_allclose(huff_weights(obs, line4, threshold=0.06), [[30, 0, 30, 30]],
                               rtol=1e-9)


def test_huff_hand_case_missing_sensors(line4):
    # D missing: pairs AB (0.1), AC (0), BC (0.1); 2 relationships each, factor 2/3
    # A: r = 0.05 -> 20 * 2/3; B: r = 0.1 -> 10 * 2/3; C: r = 0.05 -> 20 * 2/3; D: 0
    obs = _line_obs([0.0, 1.1, 2.0, NAN])
    np.testing.assert_allclose(huff_weights(obs, line4), [[40 / 3, 20 / 3, 40 / 3, 0]],
                               rtol=1e-9)
    # a lone sensor has no relationship: weight 0 (no evidence, and n_i/(m-1) = 0)
    lone = _line_obs([0.0, NAN, NAN, NAN])
    np.testing.assert_array_equal(huff_weights(lone, line4), [[0, 0, 0, 0]])
    np.testing.assert_array_equal(huff_weights(lone, line4, threshold=1.0), [[0, 0, 0, 0]])


def test_huff_zero_error_floor(line4):
    exact = _line_obs([5.0, 6.0, 7.0, 8.0])
    # r = 0 is floored at min_error (1 mm): w = 1/0.001 = 1000 for every sensor
    np.testing.assert_allclose(huff_weights(exact, line4), [[1000.0] * 4], rtol=1e-12)
    np.testing.assert_allclose(huff_weights(exact, line4, min_error=0.01), [[100.0] * 4])


def test_huff_dead_sensors_count_in_m():
    # m = 3 with C dead: A and B have 1 relationship of m - 1 = 2 possible -> factor 1/2
    cfg = SensorConfig(list("ABC"), [[0, 0], [3, 0], [0, 4]], dead=["C"])
    obs = np.array([[[0.0, 0.0], [3.2, 0.0], [NAN, NAN]]])  # |AB| error 0.2 m
    np.testing.assert_allclose(huff_weights(obs, cfg), [[0.5 / 0.2, 0.5 / 0.2, 0.0]])


def test_huff_batched_and_3d(line4):
    rng = np.random.default_rng(0)
    obs = rng.normal(size=(3, 5, 4, 2))
    obs[0, 1, 2] = NAN
    stacked = huff_weights(obs, line4, threshold=2.0)
    assert stacked.shape == (3, 5, 4)
    for k in range(3):
        np.testing.assert_array_equal(stacked[k], huff_weights(obs[k], line4, threshold=2.0))
    assert stacked[0, 1, 2] == 0 and np.isfinite(stacked).all()
    cfg3 = SensorConfig(list("ABCD"), [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    obs3 = np.array([[[0, 0, 0], [1.2, 0, 0], [0, 1, 0], [0, 0, 1]]], float)
    # errors: AB 0.2, BC |(1.2,0)-(0,1)| = sqrt(2.44) vs sqrt(2), BD the same, others 0
    e = np.sqrt(2.44) - np.sqrt(2)
    r = np.array([0.2, 0.2 + 2 * e, e, e]) / 3
    np.testing.assert_allclose(huff_weights(obs3, cfg3), [1 / r], rtol=1e-9)


def test_huff_huber_product(line4):
    rng = np.random.default_rng(1)
    obs = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [3.0, 0.0]]) + \
        rng.normal(scale=0.1, size=(6, 4, 2))
    prod = huff_huber_weights(obs, line4, threshold=1.0)
    np.testing.assert_allclose(
        prod, huff_weights(obs, line4, threshold=1.0)[..., None] * huber_weights(obs))


# ----------------------------------------------------------------------------- Huber
@settings(deadline=None, max_examples=60)
@given(seed=st.integers(0, 2**32 - 1), s=st.integers(2, 60), c=st.sampled_from([1.0, 1.345, 2.5]))
def test_huber_equals_statsmodels(seed, s, c):
    rng = np.random.default_rng(seed)
    obs = rng.standard_t(df=2, size=(s, 3, 2)) * 2.0 + 1e5
    obs[rng.random((s, 3)) < 0.2] = NAN
    w = huber_weights(obs, c=c)
    norm = HuberT(t=c)
    for i in range(3):
        for a in range(2):
            x = obs[:, i, a]
            ok = ~np.isnan(x)
            if ok.sum() == 0:
                assert (w[:, i, a] == 0).all()
                continue
            e = x[ok] - np.median(x[ok])                       # Eq. 3.11
            # the dissertation's constant 0.6745; statsmodels' mad divides by the exact
            # Phi^-1(3/4) = 0.67449..., 1.5e-5 relative apart
            scale = np.median(np.abs(e)) / 0.6745
            assert sm_mad(e, center=0.0) == pytest.approx(scale * 0.6745 / 0.6744897501960817,
                                                          rel=1e-12)
            if scale == 0:
                continue  # limit case, tested separately
            np.testing.assert_allclose(w[ok, i, a], norm.weights(e / scale), rtol=1e-12)
            assert (w[~ok, i, a] == 0).all()


def test_huber_limits():
    # MAD = 0 (most samples equal): weight 1 at the median, 0 elsewhere (limit MAD -> 0)
    obs = np.zeros((5, 1, 2))
    obs[4, 0] = [3.0, 0.0]
    w = huber_weights(obs)
    np.testing.assert_array_equal(w[:, 0, 0], [1, 1, 1, 1, 0])
    np.testing.assert_array_equal(w[:, 0, 1], [1, 1, 1, 1, 1])
    # one sample: its own median, weight 1
    np.testing.assert_array_equal(huber_weights(np.ones((1, 2, 2))), np.ones((1, 2, 2)))
    # huge c: every weight 1 (ordinary least squares)
    rng = np.random.default_rng(0)
    assert (huber_weights(rng.normal(size=(30, 4, 2)), c=1e9) == 1).all()


def test_huber_batched():
    rng = np.random.default_rng(2)
    obs = rng.normal(size=(4, 12, 3, 2))
    obs[1, :, 1] = NAN  # a sensor without data in one window
    w = huber_weights(obs)
    for k in range(4):
        np.testing.assert_array_equal(w[k], huber_weights(obs[k]))
    assert (w[1, :, 1] == 0).all() and np.isfinite(w).all()


# ----------------------------------------------------------------------------- deleted residuals
def test_deleted_residual_worked_example():
    # x = 1, 2, 3, 4, 100: median 3, e = -2, -1, 0, 1, 97, median|e| = 1,
    # sigma = 1/0.6745, h = 1/5, d* = e / (sigma sqrt(0.8)) = e * 0.6745 / 0.894427
    x = np.array([1.0, 2.0, 3.0, 4.0, 100.0])
    obs = np.stack([x, np.zeros(5)], axis=-1)[:, None, :]
    dstar = (x - 3.0) * 0.6745 / np.sqrt(0.8)  # -1.508, -0.754, 0, 0.754, 73.1
    keep = deleted_residual_mask(obs)[:, 0, 0]
    np.testing.assert_array_equal(keep, np.abs(dstar) <= 3.0)
    np.testing.assert_array_equal(keep, [True, True, True, True, False])
    keep14 = deleted_residual_mask(obs, threshold=1.4)[:, 0, 0]
    np.testing.assert_array_equal(keep14, [False, True, True, True, False])
    # absolute rule: |d| = |e| / (1 - h) = 2.5, 1.25, 0, 1.25, 121.25 > 1.0 m flagged
    keep_abs = deleted_residual_mask(obs, rule="absolute")[:, 0, 0]
    np.testing.assert_array_equal(keep_abs, [False, False, True, False, False])
    # y: all zero -> MAD 0, nothing flagged
    assert deleted_residual_mask(obs)[:, 0, 1].all()


def test_deleted_residual_missing_and_single_sample():
    obs = np.array([[[1.0, 1.0]], [[NAN, NAN]], [[50.0, 2.0]]])
    keep = deleted_residual_mask(obs)
    assert not keep[1].any()  # missing: never kept
    one = deleted_residual_mask(np.array([[[7.0, 8.0]]]))
    assert one.all()  # n = 1, h = 1: cannot be judged, kept


def test_deleted_residual_mask_feeds_fit_window():
    cfg = SensorConfig.load("rover_gps8")
    rng = np.random.default_rng(3)
    obs = cfg.body_positions[None] + rng.normal(scale=0.05, size=(40, 8, 2))
    obs[:, 3] = NAN
    obs[5, 0] += [30.0, -30.0]  # a gross outlier
    keep = deleted_residual_mask(obs)
    assert not keep[5, 0].any()
    fit = fit_window(obs, cfg, weights=keep)
    assert fit.status == "ok"
    assert np.abs(fit.positions - cfg.body_positions).max() < 0.05


# ----------------------------------------------------------------------------- random + fit
def test_random_weights_reproducible():
    a = random_weights((5, 8), np.random.default_rng(42))
    b = random_weights((5, 8), np.random.default_rng(42))
    np.testing.assert_array_equal(a, b)
    assert a.shape == (5, 8) and (a >= 0).all() and (a < 1).all()
    assert random_weights(3, np.random.default_rng(0)).shape == (3,)


def test_weights_feed_fit_window_unchanged():
    cfg = SensorConfig.load("rover_gps8")
    rng = np.random.default_rng(4)
    obs = cfg.body_positions[None] + rng.normal(size=(10, 8, 2))
    obs[:, 3] = NAN
    obs[rng.random((10, 8)) < 0.1] = NAN
    for w in (huber_weights(obs), huff_weights(obs, cfg), huff_weights(obs, cfg, 3.5),
              huff_huber_weights(obs, cfg), deleted_residual_mask(obs),
              random_weights(obs.shape[:2], rng)):
        assert np.isfinite(w).all()
        for solver in ("procrustes", "slsqp"):
            assert fit_window(obs, cfg, weights=w, solver=solver).status in (
                "ok", "insufficient_data")


# ----------------------------------------------------------------------------- bad input
def test_bad_input(line4):
    good = _line_obs([0.0, 1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="obs"):
        huff_weights(good[:, :3], line4)
    with pytest.raises(ValueError, match="obs"):
        huff_weights(np.zeros((4, 2)), line4)
    with pytest.raises(ValueError, match="obs"):
        huber_weights(np.full((3, 2, 2), np.inf))
    with pytest.raises(ValueError, match="threshold"):
        huff_weights(good, line4, threshold=-1.0)
    with pytest.raises(ValueError, match="min_error"):
        huff_weights(good, line4, min_error=0.0)
    with pytest.raises(ValueError, match="config"):
        huff_weights(good, "line4")
    with pytest.raises(ValueError, match="c"):
        huber_weights(good, c=0.0)
    with pytest.raises(ValueError, match="rule"):
        deleted_residual_mask(good, rule="literal")
    with pytest.raises(ValueError, match="threshold"):
        deleted_residual_mask(good, threshold=float("nan"))
    with pytest.raises(ValueError, match="rng"):
        random_weights((2, 2), 42)
    with pytest.raises(ValueError, match="shape"):
        random_weights((2, -1), np.random.default_rng(0))


# --------------------------------------------------------------- fast median vs np.nanmedian
def _ref_robust_residuals(arr):
    """The implementation before the sort-based median (np.nanmedian twice)."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        med = np.nanmedian(arr, axis=-3, keepdims=True)
        e = arr - med
        mad = np.nanmedian(np.abs(e), axis=-3, keepdims=True) / 0.6745
    return e, mad


@pytest.mark.parametrize("seed", range(6))
def test_robust_residuals_equal_nanmedian_reference(seed):
    """Sort-based window medians give np.nanmedian's numbers bit for bit (the same two
    middle values averaged the same way): odd/even counts, NaN dropouts, all-NaN sensors,
    ties (MAD = 0), batch dimensions, d = 2 and 3."""
    from estimator.weights import _robust_residuals

    rng = np.random.default_rng(seed)
    s = int(rng.integers(1, 30))
    shape = (int(rng.integers(1, 6)), 3, s, 4, 2 + seed % 2)
    arr = rng.normal(0, 5, shape)
    if seed % 3 == 0:
        arr = np.round(arr)  # ties: many MAD = 0 windows
    arr[rng.random(shape[:-1]) < 0.25] = np.nan
    arr[..., 1, :] = np.nan  # a dead sensor
    e, mad, _ = _robust_residuals(arr, np.isnan(arr))
    e0, mad0 = _ref_robust_residuals(arr)
    np.testing.assert_array_equal(e, e0)
    np.testing.assert_array_equal(mad, mad0)
    w = huber_weights(arr)
    with np.errstate(divide="ignore", invalid="ignore"):
        w0 = np.where(np.abs(e0) <= 1.345 * mad0, 1.0, 1.345 * mad0 / np.abs(e0))
    np.testing.assert_array_equal(w, np.where(np.isnan(arr), 0.0, w0))


def _ref_huff(obs, config, threshold, min_error=1e-3):
    """Section 3.3.3 steps 1-9 written per time step with Python loops (the docstring's
    reading), as an independent reference for the vectorized huff_weights."""
    n_t, m = obs.shape[0], config.m
    a = config.distances()
    w = np.zeros((n_t, m))
    for t in range(n_t):
        rep = [i for i in range(m) if np.isfinite(obs[t, i]).all()]
        e = {}
        for i in rep:
            for j in rep:
                if i != j:
                    e[i, j] = abs(float(np.sqrt(((obs[t, i] - obs[t, j]) ** 2).sum())) - a[i, j])
        pairs = [(i, j) for i in rep for j in rep if i < j]
        if threshold is not None and pairs and sum(e[p] for p in pairs) / len(pairs) >= threshold:
            continue  # step 5
        for i in rep:
            ni = len(rep) - 1
            if ni == 0:
                continue
            r = sum(e[i, j] for j in rep if j != i) / ni
            if threshold is not None and r >= threshold:
                continue  # step 7
            w[t, i] = (1.0 / max(r, min_error)) * ni / (m - 1)
    return w


@pytest.mark.parametrize("d", [2, 3])
@pytest.mark.parametrize("threshold", [None, 1.5])
def test_huff_equals_per_time_step_reference(d, threshold):
    """Vectorized Huff weights against the loop reference: dropouts, a dead sensor, lone
    reporters; 1e-12 relative (the reference adds the errors in another order)."""
    rng = np.random.default_rng(d)
    body = rng.normal(0, 1.0, (6, d))
    cfg = SensorConfig(list("ABCDEF"), body)
    obs = body[None] + rng.normal(0, 0.5, (200, 6, d))
    obs[rng.random((200, 6)) < 0.3] = NAN
    obs[:, 2] = NAN
    obs[0, 1:] = NAN  # one lone reporter
    np.testing.assert_allclose(huff_weights(obs, cfg, threshold), _ref_huff(obs, cfg, threshold),
                               rtol=1e-12, atol=0)


# ----------------------------------------------------------------------------- extremes
#: inf, nan, 1e300, subnormals, the coordinate bound and just beyond (issue 13)
EXTREME = st.sampled_from([0.0, 1.0, -2.5, 1e-300, 5e-324, 1e9, -1e9, 1.0000001e9, 1e300,
                           -1e300, np.inf, -np.inf, np.nan])
NUMBER_ARGS = st.one_of(EXTREME, st.sampled_from([1.345, 3.0, 1e-3, "1", None, True, [1.0]]))


def _named(exc: Exception, *names: str) -> bool:
    return any(n in str(exc) for n in names)


def _inject(rng, arr, vals):
    if arr.size and vals:
        arr.flat[rng.integers(0, arr.size, len(vals))] = vals
    return arr


@settings(deadline=None, max_examples=60)
@given(seed=st.integers(0, 2**32 - 1), s=st.integers(0, 7), vals=st.lists(EXTREME, max_size=5),
       c=NUMBER_ARGS, thr=st.one_of(st.none(), NUMBER_ARGS), rule=st.sampled_from(
           ["standardized", "absolute", "literal"]), min_error=NUMBER_ARGS)
def test_weights_extreme_values_flagged_or_named(seed, s, vals, c, thr, rule, min_error):
    """Every public weight function on observations with inf / nan / 1e300 / subnormals, empty
    windows and bad scalars: a documented result (finite, in range, zero at missing samples)
    or ValueError/TypeError naming the argument."""
    rng = np.random.default_rng(seed)
    cfg = SensorConfig.load("rover_gps8")
    obs = _inject(rng, cfg.body_positions + rng.normal(size=(s, cfg.m, 2)), vals)
    calls = {
        "huber": (lambda: huber_weights(obs, c), ("obs", "c")),
        "deleted": (lambda: deleted_residual_mask(obs, thr, rule=rule),
                    ("obs", "threshold", "rule")),
        "huff": (lambda: huff_weights(obs, cfg, thr, min_error=min_error),
                 ("obs", "threshold", "min_error")),
        "huff_huber": (lambda: huff_huber_weights(obs, cfg, thr, c, min_error=min_error),
                       ("obs", "threshold", "min_error", "c")),
    }
    for name, (fn, args) in calls.items():
        try:
            w = fn()
        except (ValueError, TypeError) as exc:
            assert _named(exc, *args), (name, exc)
            continue
        missing = np.isnan(obs)
        if name == "deleted":
            assert w.dtype == bool and w.shape == obs.shape and not w[missing].any()
            continue
        assert np.isfinite(w).all() and (w >= 0).all(), name
        if name == "huber":
            assert w.shape == obs.shape and (w <= 1).all() and (w[missing] == 0).all()
        elif name == "huff":
            assert w.shape == obs.shape[:2]
            assert (w[missing.any(axis=-1)] == 0).all()


@settings(deadline=None, max_examples=40)
@given(shape=st.one_of(st.integers(-2, 5), st.tuples(st.integers(-1, 4), st.integers(0, 3)),
                       st.sampled_from([(10**9, 10**9), (2**62,), 2.0, "3", None, (True,),
                                        (3.0, 2)])))
def test_random_weights_shapes(shape):
    """Shapes: non-negative integers give uniform [0, 1) weights; negative, non-integer and
    unallocatable sizes (10^18 weights) raise at once naming ``shape``, allocating nothing."""
    rng = np.random.default_rng(0)
    try:
        w = random_weights(shape, rng)
    except (ValueError, TypeError) as exc:
        assert "shape" in str(exc)
        return
    assert ((w >= 0) & (w < 1)).all()
    assert w.shape == ((shape,) if isinstance(shape, int) else tuple(shape))


def test_weights_memory_is_linear_in_the_input():
    """Huber, deleted residuals and Huff on 20,000 x 8 x 2 observations: the peak memory is a
    bounded multiple of the input: a few copies for the sorts of the window medians (measured
    4.3x and 3.3x, bound 8x); Huff works on (n, m, m) pair arrays, each m / 2 = 4 times the
    input, a handful alive at once (measured 22x, bound 32x)."""
    import tracemalloc

    rng = np.random.default_rng(1)
    cfg = SensorConfig.load("rover_gps8")
    obs = cfg.body_positions + rng.normal(size=(20_000, cfg.m, 2))
    size = obs.nbytes
    for fn, bound in ((lambda: huber_weights(obs[None]), 8),
                      (lambda: deleted_residual_mask(obs[None]), 8),
                      (lambda: huff_weights(obs, cfg), 32)):
        tracemalloc.start()
        fn()
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        assert peak < bound * size, (peak / size, bound)
