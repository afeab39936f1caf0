"""The compiled 2-D fast path of fit_window (estimator.window_kernel, issue 27) against the
numpy fast path it replaced (FAST_2D_ENGINE = "numpy", the reference): the same screens
(same inputs declined), positions within 1e-12 m + 2 ulp, objectives within 1e-12 relative
(+1e-12 m^2: the kernel sums in sample order where numpy pairs), yaw within 1e-12 rad."""

import math

import numpy as np
import pytest

import estimator.window as W
from estimator.configuration import SensorConfig
from tests.test_window import _bad_fast_cases, _fast_window, _tol, random_config


def _both(monkeypatch, *args, **kw):
    """(numba engine, numpy engine) results of the fast path; None where it declines."""
    out = []
    for engine in ("numba", "numpy"):
        with monkeypatch.context() as mp:
            mp.setattr(W, "FAST_2D_ENGINE", engine)
            out.append(W._fast_procrustes(*args, **kw))
    return out


@pytest.mark.parametrize("weights", [None, "sm", "smd"])
def test_kernel_matches_the_numpy_fast_path(monkeypatch, weights):
    rng = np.random.default_rng(2027)
    taken = 0
    for k in range(120):
        m = int(rng.integers(2, 9))
        cfg = SensorConfig.load("rover_gps8") if k % 3 == 0 else \
            random_config(rng, m, 2, dead=int(rng.integers(0, 2)) if m > 2 else 0)
        s = int(rng.choice([1, 3, 10, 30]))
        obs, w = _fast_window(rng, cfg, s, utm=bool(k % 2), missing=0.3 * (k % 4 == 1),
                              weights=weights)
        a, b = _both(monkeypatch, obs, cfg, w, 0.01, None, 100)
        assert (a is None) == (b is None), k
        if a is None:
            continue
        taken += 1
        assert (np.abs(a.positions - b.positions) <= _tol(b.positions)).all(), k
        assert (np.abs(a.cg - b.cg) <= _tol(b.cg)).all(), k
        assert abs(math.remainder(a.yaw - b.yaw, 2 * math.pi)) <= 1e-12, k
        for f in ("objective", "mirror_objective"):
            assert getattr(a, f) == pytest.approx(getattr(b, f), rel=1e-12, abs=1e-12), (k, f)
        assert abs(a.max_violation - b.max_violation) <= 1e-12
        assert (a.status, a.solver, a.iterations) == (b.status, b.solver, b.iterations)
    assert taken > 80


def test_kernel_declines_what_the_numpy_fast_path_declines(monkeypatch):
    """Every bad input of the message tests (NaN halves, infinities, coordinates and weights
    out of range, bad shapes and types) is declined by both engines alike."""
    cfg, good, cases = _bad_fast_cases()
    for kw, _field in cases:
        call = {"obs": good, "weights": None, "eps": 0.01, "x0": None, "maxiter": 100, **kw}
        a, b = _both(monkeypatch, call["obs"], cfg, call["weights"], call["eps"], call["x0"],
                     call["maxiter"])
        assert (a is None) == (b is None), kw


@pytest.mark.parametrize("contiguous", [True, False])
def test_weighted_sums_are_the_numpy_reference_bit_for_bit(contiguous):
    """The compiled per-window weighted sums (random weights, Section 3.3) equal the numpy
    loop they replaced exactly (same additions in the same order), with missing samples,
    zero weights, negative and UTM-sized coordinates; the Python function (what
    NUMBA_DISABLE_JIT=1 runs) too."""
    from estimator.trackers._windows import weighted_sums_numpy, weighted_window_means
    from estimator.window_kernel import weighted_sums

    rng = np.random.default_rng(27)
    n, m, w = 300, 5, 7
    obs = rng.normal(scale=3.0, size=(n, m, 2)) + np.array([5e5, -4e6])
    obs[rng.random((n, m)) < 0.2] = np.nan
    ends = np.arange(w - 1, n) if contiguous else np.sort(rng.choice(np.arange(w - 1, n), 90,
                                                                      replace=False))
    wts = rng.random((ends.size, w, m))
    wts[rng.random(wts.shape) < 0.1] = 0.0
    num0, W0 = weighted_sums_numpy(obs, ends, w, wts)
    for fn in (weighted_sums, weighted_sums.py_func):
        num, W = np.zeros_like(num0), np.zeros_like(W0)
        fn(obs, ends.astype(np.int64), wts, num, W)
        np.testing.assert_array_equal(num, num0)
        np.testing.assert_array_equal(W, W0)
    means, sw = weighted_window_means(obs, ends, w, wts)
    with np.errstate(invalid="ignore", divide="ignore"):
        ref = np.where((W0 > 0)[..., None], num0 / W0[..., None], np.nan)
    np.testing.assert_array_equal(means, ref)
    np.testing.assert_array_equal(sw, np.where(W0 > 0, W0, 0.0))
