"""sim.log_timeline: the heaviest increasing subsequence against brute force, the rollover
chain, and the era / week-rollover rules on plain arrays."""

from __future__ import annotations

import itertools

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from sim.log_timeline import (
    DAY_S,
    WEEK_ROLLOVER_S,
    absolute_times,
    continuous_tod,
    heaviest_increasing,
    resolve_times,
)


def _brute(t, w):
    """Best total weight and, among the best, the lexicographically earliest index set."""
    n = len(t)
    best, pick = -1, None
    for r in range(n, -1, -1):
        for comb in itertools.combinations(range(n), r):
            if all(t[a] < t[b] for a, b in itertools.pairwise(comb)):
                v = sum(w[i] for i in comb)
                if v > best:
                    best, pick = v, comb
    return best, pick


@settings(max_examples=150, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 6), st.integers(1, 3)), max_size=9))
def test_heaviest_increasing_matches_brute_force(items):
    t = np.array([a for a, _ in items], dtype=float)
    w = np.array([b for _, b in items], dtype=int)
    keep = heaviest_increasing(t, w)
    kept = np.flatnonzero(keep)
    assert np.all(np.diff(t[kept]) > 0)                      # strictly increasing
    best, _ = _brute(t.tolist(), w.tolist())
    assert int(w[keep].sum()) == max(best, 0)                # and of the largest weight


def test_single_out_of_order_epoch_keeps_the_earlier():
    # telit-he910 pattern: 105153.71 then 105153.408: the second one is dropped
    t = np.array([53.71, 53.408, 54.408, 55.408])
    assert heaviest_increasing(t, np.ones(4, int)).tolist() == [True, False, True, True]


def test_heaviest_increasing_is_fast_on_a_long_log():
    """100,000 epochs with one reversed segment: the O(n log n) path (not the monotone
    shortcut) in a fraction of a second (a quadratic search would take hours)."""
    import time

    t = np.arange(100_000, dtype=float)
    t[1000:1100] -= 5000.0
    t0 = time.perf_counter()
    keep = heaviest_increasing(t, np.ones(t.size, dtype=int))
    assert keep.sum() == t.size - 100
    assert time.perf_counter() - t0 < 20.0


def test_rollover_chain_ignores_default_times_of_no_fix_epochs():
    tod = np.array([86390.0, 86395.0, 5.0, 10.0, 86398.0, 3.0])
    fix = np.array([True, True, False, False, True, True])
    c = continuous_tod(tod, fix)
    # fixes: 86390, 86395, 86398, then 3 s past midnight (next day)
    assert c[[0, 1, 4, 5]].tolist() == [86390.0, 86395.0, 86398.0, DAY_S + 3.0]
    # the no-fix epochs take the day nearest their neighbouring fixes: next day
    assert c[[2, 3]].tolist() == [DAY_S + 5.0, DAY_S + 10.0]


def test_eras_and_week_rollover_on_absolute_times():
    t0 = 1.6e9
    t = np.r_[t0 + np.arange(10.0), t0 + 10 - WEEK_ROLLOVER_S + np.arange(20.0),
              t0 + 400 * DAY_S + np.arange(3.0)]
    fix = np.ones(t.size, dtype=bool)
    out = resolve_times(absolute_times(t), fix)
    assert out.week_rollover.sum() == 20
    assert (out.fate == 2).sum() == 3                        # the step of 400 days
    kept = out.t[out.fate == 0]
    assert np.array_equal(kept, t0 + np.arange(30.0))
