"""The content memo (estimator.memo), the TrackCache a runner passes to the trackers, and
the pose-filter pass and smoothers through it: a hit returns exactly what the computation
returns, shared values cannot be changed, the reused cost is accounted for, and nothing is
cached without a cache (no module-level memos in estimator/)."""

import math

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from estimator import memo
from estimator.configuration import SensorConfig
from estimator.memo import ContentMemo, TrackCache, content_digest, freeze, ledger
from estimator.pose_filter import PoseFilterParams, memo_pose_filter, run_pose_filter
from estimator.pose_smoother import (
    fixed_lag_smooth,
    memo_smoothed_states,
    rts_smooth,
    smoothed_heading,
)
from estimator.tracking import track


# --------------------------------------------------------------------------- ContentMemo
def test_lru_order_hits_and_failures():
    m = ContentMemo(2)
    calls = []

    def make(v):
        def f():
            calls.append(v)
            return v
        return f

    assert m.get("a", make(1)) == 1 and m.get("b", make(2)) == 2
    assert m.get("a", make(99)) == 1                  # hit: not recomputed, now most recent
    assert m.get("c", make(3)) == 3                   # evicts "b", the least recently used
    assert "b" not in m and "a" in m and len(m) == 2
    assert calls == [1, 2, 3]

    def boom():
        raise RuntimeError("no")

    with pytest.raises(RuntimeError):
        m.get("d", boom)
    assert "d" not in m and len(m) == 2               # a failure stores nothing
    m.clear()
    assert len(m) == 0


@pytest.mark.parametrize("size", [0, -1, 1.5, True, "3", None])
def test_size_is_validated(size):
    with pytest.raises(ValueError, match="size"):
        ContentMemo(size)


def test_ledger_counts_each_reused_entry_once_at_its_own_cost(monkeypatch):
    """A sweep's cells: the forward pass (3 s) and a smoother on it (1 s more). What a cell
    reuses is counted at the cost the entries had when computed, each entry once (the pass
    reached directly and through the smoother), and nothing the cell computed itself."""
    clock = [0.0]
    monkeypatch.setattr(memo, "_clock", lambda: clock[0])
    passes, smooth = ContentMemo(2), ContentMemo(2)

    def forward():
        clock[0] += 3.0
        return "pass"

    def smoother():
        p = passes.get("p", forward)
        clock[0] += 1.0
        return p + "+rts"

    with ledger() as a:                       # computes both: nothing reused
        assert smooth.get("s", smoother) == "pass+rts"
    assert a.seconds == 0.0 and len(a.computed) == 2
    with ledger() as b:                       # the pass alone, a hit
        passes.get("p", forward)
    assert b.seconds == 3.0
    with ledger() as c:                       # the pass and the smoother on it: 3 + 1
        passes.get("p", forward)
        smooth.get("s", smoother)
    assert c.seconds == 4.0
    with ledger() as outer:                   # a new smoother on the memoised pass: 3
        passes.get("p", forward)
        with ledger() as inner:               # nested measurements see the same
            smooth.get("s2", smoother)
    assert outer.seconds == inner.seconds == 3.0
    with ledger() as d:                       # the new smoother, now memoised: 3 + 1
        smooth.get("s2", smoother)
    assert d.seconds == 4.0
    assert clock[0] == 5.0                    # the pass and each smoother ran once


@settings(max_examples=60, deadline=None)
@given(hnp.arrays(dtype=st.sampled_from([np.float64, np.float32, np.int64]),
                  shape=hnp.array_shapes(min_dims=1, max_dims=3, min_side=0, max_side=5)))
def test_digest_depends_on_dtype_shape_and_bytes(a):
    assert content_digest(a) == content_digest(a.copy())
    assert content_digest(a) != content_digest(a.astype(np.complex128))
    flat = a.reshape(1, -1)
    if flat.shape != a.shape:
        assert content_digest(a) != content_digest(flat)
    if a.size:
        b = a.copy()
        b.flat[0] = 1 if a.flat[0] != 1 else 2
        assert content_digest(a) != content_digest(b)
    # non-contiguous views digest like their contiguous copies
    assert content_digest(a.T) == content_digest(np.ascontiguousarray(a.T))


def test_digest_extreme_values():
    big = np.array([1e300, -1e300, np.inf, -np.inf, np.nan, 0.0, -0.0])
    assert content_digest(big) == content_digest(big.copy())
    assert content_digest(big[:0]) != content_digest(np.zeros((0, 1)))   # shape counts
    assert content_digest(np.zeros(10**6)) != content_digest(np.ones(10**6))
    assert content_digest(np.array([0.0])) != content_digest(np.array([-0.0]))  # bytes


def test_freeze_makes_read_only():
    a = freeze(np.zeros(3))
    with pytest.raises(ValueError):
        a[0] = 1.0


# --------------------------------------------------------------------------- pose filter
@pytest.fixture(scope="module")
def drive():
    """A short noisy straight-and-turn drive of the eight-antenna rover (no simulator)."""
    cfg = SensorConfig.load("rover_gps8").planar()
    rng = np.random.default_rng(5)
    n = 120
    t = np.arange(n, dtype=float)
    yaw = np.where(t < 60, 0.0, 0.03 * (t - 60))
    xy = np.cumsum(0.2 * np.c_[np.cos(yaw), np.sin(yaw)], axis=0)
    off = cfg.body_positions - cfg.cg_body
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    obs = np.stack([xy[:, None, 0] + c * off[:, 0] - s * off[:, 1],
                    xy[:, None, 1] + s * off[:, 0] + c * off[:, 1]], -1)
    obs = obs + rng.normal(0, 0.3, obs.shape)
    obs[rng.random((n, cfg.m)) < 0.1] = np.nan
    obs[:, ~cfg.alive_mask] = np.nan
    return t, obs, cfg, off


def test_memoised_pass_is_the_direct_pass_and_shared_read_only(drive):
    t, obs, _cfg, off = drive
    p = PoseFilterParams()
    direct = run_pose_filter(t, obs, off, p)
    cache = TrackCache()
    a = memo_pose_filter(t, obs, off, p, cache)
    b = memo_pose_filter(t.copy(), obs.copy(), off.copy(), p, cache)     # equal content: a hit
    assert b is a
    assert memo_pose_filter(t, obs, off, p) is not a                     # no cache: computed
    for name, v in vars(direct).items():
        if isinstance(v, np.ndarray):
            np.testing.assert_array_equal(getattr(a, name), v)
            assert not getattr(a, name).flags.writeable, name
    other = memo_pose_filter(t, obs, off, PoseFilterParams(max_accel_mps2=1.0), cache)
    assert other is not a                                          # params are in the key
    with pytest.raises(ValueError, match="obs"):
        memo_pose_filter(t, obs[:, :, :1], off, p, cache)
    with pytest.raises(TypeError, match="cache"):
        memo_pose_filter(t, obs, off, p, {})


@pytest.mark.parametrize("lag_s", [None, 0.0, 5.0])
def test_memoised_smoothers_equal_the_direct_ones(drive, lag_s):
    t, obs, cfg, off = drive
    p = PoseFilterParams()
    res = run_pose_filter(t, obs, off, p)
    want = (rts_smooth(res, p.reverse).states if lag_s is None
            else fixed_lag_smooth(res, t, lag_s, p.reverse).states)
    cache = TrackCache()
    got = memo_smoothed_states(t, obs, off, p, lag_s, cache)
    np.testing.assert_array_equal(got, want)
    assert not got.flags.writeable
    assert memo_smoothed_states(t, obs, off, p, lag_s, cache) is got
    assert len(cache.filter_pass) == 1 and len(cache.smoothed) == 1
    np.testing.assert_array_equal(memo_smoothed_states(t, obs, off, p, lag_s), want)
    if lag_s is None:
        np.testing.assert_array_equal(smoothed_heading(t, obs, cfg, p), want[:, 2])
        np.testing.assert_array_equal(smoothed_heading(t, obs, cfg, p, cache=cache),
                                      want[:, 2])
        assert len(cache.smoothed) == 1                            # the heading was a hit


@pytest.mark.parametrize("lag_s", [-1.0, math.nan, math.inf, "1"])
def test_memoised_smoother_rejects_bad_lag(drive, lag_s):
    t, obs, _cfg, off = drive
    with pytest.raises((ValueError, TypeError), match="lag_s"):
        memo_smoothed_states(t, obs, off, PoseFilterParams(), lag_s)


def test_track_rows_are_copies_not_the_memo(drive):
    """The filter rows of a track share one memoised pass; changing a track's output in
    place must not change what the next track returns."""
    t, obs, cfg, _ = drive
    kw = {"window": 5, "method": "ekf_smoother", "layout_check": False, "cache": TrackCache()}
    first = track(t, obs, cfg, **kw)
    again = track(t, obs, cfg, **kw)
    first.loc[:, ["speed", "yaw_rate", "n_used", "cg_x"]] = -1
    third = track(t, obs, cfg, **kw)
    pd.testing.assert_frame_equal(third, again)       # NaN cells (e.g. nis) compare equal
    ekf1 = track(t, obs, cfg, window=1, method="ekf", layout_check=False, cache=kw["cache"])
    ekf5 = track(t, obs, cfg, window=5, method="ekf", layout_check=False, cache=kw["cache"])
    pd.testing.assert_frame_equal(ekf5.drop(columns="window").reset_index(drop=True),
                                  ekf1.iloc[4:].drop(columns="window").reset_index(drop=True))


def test_cache_memos_are_bounded(drive):
    t, obs, _cfg, off = drive
    cache = TrackCache(filter_pass=2, smoothed=3)
    for i in range(4):
        memo_smoothed_states(t, obs, off, PoseFilterParams(lag_s=1.0 + i), None, cache)
    assert len(cache.filter_pass) == 2 and len(cache.smoothed) == 3
    cache.clear()
    assert not any(len(m) for m in cache.memos().values())


def test_no_module_level_memos_in_the_estimators():
    """Caching is the runner's (issue 24): no module of estimator/ holds a ContentMemo or a
    TrackCache at import, and a track without a cache leaves no memo behind."""
    import importlib
    import pkgutil

    import estimator

    for info in pkgutil.walk_packages(estimator.__path__, "estimator."):
        if info.name == "estimator.gtsam_peer" or info.name.endswith(".peer"):
            continue                      # imports nothing optional at import, but skip
        mod = importlib.import_module(info.name)
        for name, value in vars(mod).items():
            assert not isinstance(value, (ContentMemo, TrackCache)), (info.name, name)
    before = {id(m): len(m) for m in list(memo._MEMOS)}
    cfg, t, obs = _small_track_inputs()
    for kw in ({"weighting": "huff"}, {"solver": "elastic"}, {"method": "ekf_smoother"}):
        track(t, obs, cfg, window=5, layout_check=False, **kw)
    assert {id(m): len(m) for m in list(memo._MEMOS)} == before


def _small_track_inputs():
    cfg = SensorConfig.load("rover_gps8").planar()
    rng = np.random.default_rng(3)
    n = 60
    t = np.arange(n, dtype=float)
    off = cfg.body_positions[:, :2] - cfg.cg_body[:2]
    xy = np.c_[0.5 * t, 0.1 * t]
    obs = xy[:, None, :] + off[None] + rng.normal(0, 0.05, (n, cfg.m, 2))
    obs[:, ~cfg.alive_mask] = np.nan
    return cfg, t, obs


def test_clear_all_empties_every_memo():
    from estimator.memo import ContentMemo, clear_all

    a, b = ContentMemo(2), ContentMemo(3)
    a.get("x", lambda: 1)
    b.get("y", lambda: 2)
    clear_all()
    assert len(a) == 0 and len(b) == 0
    calls = []
    assert a.get("x", lambda: calls.append(1) or 5) == 5 and calls == [1]


def test_digest_of_a_frozen_array_is_remembered_while_it_lives():
    """A frozen array that owns its data is hashed once (the sweep keys every fit of a noise
    key by its observations); the digest is the one of its bytes, a writeable or viewed
    array is hashed every time, and the entry goes with the array."""
    import gc

    from estimator import memo

    a = np.arange(12.0).reshape(3, 4).copy()          # owns its data
    d = content_digest(a)
    freeze(a)
    assert content_digest(a) == d and id(a) in memo._FROZEN_DIGESTS
    assert len(memo._FROZEN_DIGESTS[id(a)][1]) == 1
    view = np.asarray(a, dtype=float)[1:]              # a read-only view: remembered by a
    assert content_digest(view) == content_digest(view.copy())
    assert len(memo._FROZEN_DIGESTS[id(a)][1]) == 2
    assert content_digest(a[::2]) == content_digest(a[::2].copy())   # another view
    b = np.zeros(3)
    content_digest(b)
    assert id(b) not in memo._FROZEN_DIGESTS          # writeable: hashed every time
    w = np.zeros(4)
    v = w[1:]
    v.flags.writeable = False
    content_digest(v)
    assert id(w) not in memo._FROZEN_DIGESTS          # its owner is writeable
    key = id(a)
    del a, view
    gc.collect()
    assert key not in memo._FROZEN_DIGESTS


def test_cumsum_means_share_a_recordings_prefix_sums():
    """cumsum_means through cache.prefix: one set of cumulative sums per (observations,
    weights) serves every window size and row set, with the numbers of an uncached call."""
    from estimator.trackers._windows import cumsum_means

    rng = np.random.default_rng(5)
    obs = rng.normal(0, 3, (300, 4, 2))
    obs[rng.random((300, 4)) < 0.1] = np.nan
    wts = rng.uniform(0, 2, (300, 4))
    cache = TrackCache()
    for w in (1, 5, 40):
        ends = np.arange(w - 1, 300)
        for sw in (None, wts):
            got = cumsum_means(obs, ends, w, sw, cache)
            want = cumsum_means(obs, ends, w, sw)
            assert all(np.array_equal(a, b, equal_nan=True) for a, b in zip(got, want))
    assert len(cache.prefix) == 2          # counts and the weights: two sets of sums
