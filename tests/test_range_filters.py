"""Spike gates of thesis 003 Section 3.2.2 (Filter 1 velocity, Filter 2 separation)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimator.range_filters import separation_gate, velocity_gate


def _track(n=600, seed=0, dt_range=(0.03, 0.1)):
    """A smooth range (1 m/s swings) with 5 mm noise on uneven times."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(*dt_range, n))
    r = 5.0 + 1.0 * np.sin(0.8 * t) + rng.normal(0, 0.005, n)
    return t, r


@pytest.mark.parametrize("mode", ["robust", "thesis"])
def test_clean_data_untouched(mode):
    t, r = _track()
    out, rej = velocity_gate(t, r, 10.0, mode=mode, return_mask=True)
    np.testing.assert_array_equal(out, r)
    assert not rej.any()
    a, b, rej2 = separation_gate(r, r + 0.3, 0.5, mode=mode, return_mask=True)
    np.testing.assert_array_equal(a, r)
    np.testing.assert_array_equal(b, r + 0.3)
    assert not rej2.any()


@pytest.mark.parametrize("mode", ["robust", "thesis"])
def test_injected_spikes_removed(mode):
    t, r = _track(seed=1)
    rng = np.random.default_rng(2)
    # isolated spikes (>= 7 samples apart) larger than the one-sample allowance of both gates
    # (thesis: 10 m/s x 0.1 s = 1 m; robust: 0.05 m + 10 m/s x dt <= 1.05 m). Back-to-back
    # spikes widen the robust allowance by design (it grows with the time since the last
    # accepted sample), see test_gap_then_spike...
    spikes = rng.choice(np.arange(50, len(r), 7), 30, replace=False)
    raw = r.copy()
    raw[spikes] += rng.uniform(1.2, 5.0, spikes.size) * rng.choice([-1, 1], spikes.size)
    out, rej = velocity_gate(t, raw, 10.0, mode=mode, return_mask=True)
    assert set(np.flatnonzero(rej)) == set(spikes)
    # a rejected sample is replaced by the previous accepted value (thesis: "the previous
    # range measurement is simply adopted"); the clean ones pass bit for bit
    clean = np.setdiff1d(np.arange(len(r)), spikes)
    np.testing.assert_array_equal(out[clean], r[clean])
    for i in spikes:
        j = max(k for k in range(i) if not rej[k])
        assert out[i] == r[j]
    # the worst deviation left is the motion between a spike and its held sample
    assert np.max(np.abs(out - r)) < 0.2


def test_gap_then_spike_rejected_in_both_modes_but_gap_then_motion_differs():
    t = np.arange(200) * 0.05
    r = np.full(200, 4.0)
    # dropout for 2 s, during which the platform moves 1.5 m at 0.75 m/s
    r[100:140] = np.nan
    r[140:] = 5.5
    spiky = r.copy()
    spiky[140] = 9.5                       # a spike as the first sample after the gap
    for mode in ("robust", "thesis"):
        out, rej = velocity_gate(t, spiky, 10.0, mode=mode, return_mask=True)
        assert rej[140], mode
        assert np.isnan(out[100:140]).all()          # a dropout stays a dropout
    # genuine 1.5 m change over a 2 s gap: robust accepts (allowance grows with elapsed time),
    # the literal thesis gate (1 m per sample) holds 4.0 for ever
    out, rej = velocity_gate(t, r, 10.0, mode="robust", return_mask=True)
    assert not rej.any()
    out_t, rej_t = velocity_gate(t, r, 10.0, mode="thesis", return_mask=True)
    assert rej_t[140:].all() and np.all(out_t[140:] == 4.0)


def test_genuine_step_relocks_only_in_robust_mode():
    t = np.arange(300) * 0.05
    r = np.where(t < 5.0, 3.0, 6.0)        # e.g. a receiver occluded then re-acquired
    out, rej = velocity_gate(t, r, 10.0, mode="robust", relock_after=5, return_mask=True)
    k = int(np.argmax(t >= 5.0))
    assert rej[k:k + 4].all() and not rej[k + 4:].any()
    np.testing.assert_array_equal(out[k + 4:], 6.0)
    out_t = velocity_gate(t, r, 10.0, mode="thesis")
    np.testing.assert_array_equal(out_t[k:], 3.0)       # stuck: the documented failure


def test_relock_needs_consistent_rejections():
    # a burst of random spikes must not re-lock the robust gate
    t = np.arange(100) * 0.05
    r = np.full(100, 3.0)
    r[50:60] = [8, 12, 7.5, 15, 9, 13.2, 7.1, 11, 14.5, 8.3]
    out, rej = velocity_gate(t, r, 10.0, mode="robust", relock_after=3, max_change=1.0,
                             return_mask=True)
    assert rej[50:60].all()
    np.testing.assert_array_equal(out, 3.0)


def test_lead_in_spike_is_not_the_reference():
    t = np.arange(100) * 0.05
    r = np.full(100, 2.0)
    r[0] = 7.0                              # spike on the very first sample
    out, rej = velocity_gate(t, r, 10.0, mode="thesis", return_mask=True)
    assert rej[0] and not rej[1:].any()
    np.testing.assert_array_equal(out[1:], 2.0)


def test_columns_are_independent():
    t, r = _track(seed=3)
    r2 = r.copy()
    r2[100] += 3.0
    both = velocity_gate(t, np.c_[r, r2], 10.0)
    np.testing.assert_array_equal(both[:, 0], velocity_gate(t, r, 10.0))
    np.testing.assert_array_equal(both[:, 1], velocity_gate(t, r2, 10.0))


@pytest.mark.parametrize("mode", ["robust", "thesis"])
def test_separation_gate_holds_previous_pair(mode):
    n = 50
    a = np.linspace(5.0, 5.5, n)
    b = a + 0.4
    b_bad = b.copy()
    b_bad[[10, 30]] += 2.0
    oa, ob, rej = separation_gate(a, b_bad, 0.5, mode=mode, return_mask=True)
    assert np.flatnonzero(rej).tolist() == [10, 30]
    assert oa[10] == a[9] and ob[10] == b[9]
    assert oa[30] == a[29] and ob[30] == b[29]
    np.testing.assert_array_equal(np.delete(ob, [10, 30]), np.delete(b, [10, 30]))


def test_separation_gate_relock_and_margin():
    a = np.full(40, 5.0)
    b = np.full(40, 5.51)                   # 0.51 m: radially aligned pair plus noise
    _, _, rej = separation_gate(a, b, 0.5, mode="robust", return_mask=True)
    assert not rej.any()
    _, _, rej_t = separation_gate(a, b, 0.5, mode="thesis", return_mask=True)
    assert rej_t.all()                      # nothing accepted yet: stays as is, flagged
    b2 = np.r_[np.full(20, 5.3), np.full(20, 6.5)]
    _, _, rej = separation_gate(a, b2, 0.5, mode="robust", relock_after=4, return_mask=True)
    assert rej[20:23].all() and not rej[23:].any()
    _, ob_t = separation_gate(a, b2, 0.5, mode="thesis")
    np.testing.assert_array_equal(ob_t[20:], 5.3)


def test_nan_pairs_pass_through():
    a = np.array([5.0, np.nan, 5.0, 5.0])
    b = np.array([5.2, 5.2, np.nan, 9.0])
    oa, ob, rej = separation_gate(a, b, 0.5, return_mask=True)
    assert np.isnan(oa[1]) and ob[1] == 5.2 and np.isnan(ob[2])
    assert rej.tolist() == [False, False, False, True]
    assert oa[3] == 5.0 and ob[3] == 5.2


def test_validation_names_fields():
    t = np.arange(5.0)
    with pytest.raises(ValueError, match="mode"):
        velocity_gate(t, np.ones(5), mode="literal")
    with pytest.raises(ValueError, match="max_speed"):
        velocity_gate(t, np.ones(5), -1.0)
    with pytest.raises(ValueError, match="t:"):
        velocity_gate(t[::-1], np.ones(5))
    with pytest.raises(ValueError, match="r:"):
        velocity_gate(t, np.ones(4))
    with pytest.raises(ValueError, match="r_b"):
        separation_gate(np.ones(5), np.ones(4))
    with pytest.raises(ValueError, match="max_sep"):
        separation_gate(np.ones(5), np.ones(5), 0.0)


def test_robust_accepts_return_after_a_spike_that_slipped_through():
    # a 0.9 m spike passes both gates at dt = 0.1 s; the return to the truth 0.03 s later is a
    # 0.9 m change the robust allowance (0.05 + 10 * 0.03 = 0.35 m) would reject, but it is
    # consistent with the value accepted before the spike, so it is accepted
    t = np.r_[np.arange(51) * 0.1, 5.0 + 0.03 + np.arange(50) * 0.1]
    r = np.full(t.size, 3.0)
    r[50] = 3.9
    out, rej = velocity_gate(t, r, 10.0, mode="robust", return_mask=True)
    assert not rej.any()
    np.testing.assert_array_equal(out, r)


# ---------------------------------------------------------------------------------------------
# real-data behaviours (issue 12): spike runs, long dropouts, asynchronous receivers, units
# ---------------------------------------------------------------------------------------------


def _walk(n=1200, dt=0.1, seed=0, speed=1.2):
    """A range changing at up to `speed` m/s with 0.08 m noise, 10 Hz."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt + rng.normal(0, 0.004, n)
    t.sort()
    r = 20.0 + 15.0 * np.sin(speed / 15.0 * t) + rng.normal(0, 0.08, n)
    return t, r


@pytest.mark.parametrize("after_gap", [False, True])
def test_consistent_spike_runs_of_2_to_4_samples_are_rejected_whole(after_gap):
    """Real UWB spikes: runs of 2-4 samples with the same negative offset (1-19 m), sometimes
    right after a dropout. Every sample of every run is rejected, not only the first (the
    allowance grows with the time since the last accepted sample; a sample continuing the
    rejected run stays rejected). Gate sized for a 3 m/s platform and 0.1 m ranges."""
    t, r = _walk(seed=3)
    rng = np.random.default_rng(4)
    raw = r.copy()
    spike = np.zeros(r.size, dtype=bool)
    for s0 in range(60, r.size - 10, 37):
        if after_gap:
            raw[s0 - 8:s0] = np.nan                     # 0.8 s dropout, then the spike run
        run = rng.integers(2, 5)
        raw[s0:s0 + run] = r[s0:s0 + run] - rng.uniform(1.0, 19.0)
        spike[s0:s0 + run] = True
    kw = {"noise_margin": 0.3, "max_change": 0.9, "relock_after": 5}
    _, rej = velocity_gate(t, raw, 3.0, return_mask=True, **kw)
    assert rej[spike].all()
    # clean samples pass, except the re-lock: after a dropout (or the moving lead-in) whose
    # motion exceeds max_change, relock_after - 1 = 4 samples are held before the re-lock
    gaps = 1 + (len(range(60, r.size - 10, 37)) if after_gap else 0)
    assert rej[~spike & np.isfinite(raw)].sum() <= 4 * gaps


def test_true_change_across_a_long_dropout_is_reacquired_in_relock_after_samples():
    t = np.arange(400) * 0.1
    r = 10.0 + 1.5 * t                                 # receding at 1.5 m/s
    r[100:150] = np.nan                                # 5 s dropout: the range moved 7.5 m
    out, rej = velocity_gate(t, r, 3.0, noise_margin=0.3, max_change=0.9, relock_after=5,
                             return_mask=True)
    assert rej[150:154].all() and not rej[154:].any()  # 4 held, re-locked on the 5th
    np.testing.assert_array_equal(out[154:], r[154:])
    # the thesis gate never re-acquires
    _, rej_t = velocity_gate(t, r, 3.0, mode="thesis", return_mask=True)
    assert rej_t[150:].all()


def test_per_channel_times_equal_gating_each_channel_on_its_own_clock():
    ta, ra = _walk(seed=5)
    tb, rb = _walk(n=900, seed=6)
    tb = tb + 0.037                                    # another receiver, its own clock
    rb[[100, 101, 400]] -= 7.0
    T = np.full((1200, 2), np.nan)
    R = np.full((1200, 2), np.nan)
    T[:, 0], R[:, 0] = ta, ra
    T[:900, 1], R[:900, 1] = tb, rb                    # shorter channel: NaN padded
    both, rej = velocity_gate(T, R, 3.0, return_mask=True)
    a, rej_a = velocity_gate(ta, ra, 3.0, return_mask=True)
    b, rej_b = velocity_gate(tb, rb, 3.0, return_mask=True)
    np.testing.assert_array_equal(rej[:, 0], rej_a)
    np.testing.assert_array_equal(both[:, 0], a)
    np.testing.assert_array_equal(both[:900, 1], b)
    np.testing.assert_array_equal(rej[:900, 1], rej_b)
    assert np.isnan(both[900:, 1]).all() and not rej[900:, 1].any()
    with pytest.raises(ValueError, match=r"t\[:, 1\]: must be strictly increasing"):
        bad = T.copy()
        bad[5, 1] = bad[4, 1]
        velocity_gate(bad, R, 3.0)
    with pytest.raises(ValueError, match="t:"):
        bad = T.copy()
        bad[3, 0] = np.nan                             # a range without a time
        velocity_gate(bad, R, 3.0)


def test_unit_mistakes_are_caught():
    from estimator.range_filters import UnitWarning

    t, r = _walk(n=100)
    with pytest.warns(UnitWarning, match="millimetres"):
        velocity_gate(t, r * 1000.0, 3.0)
    with pytest.raises(ValueError, match="nanoseconds"):
        velocity_gate(t * 1e9, r, 3.0)


@pytest.mark.parametrize("kwargs, field, exc", [
    ({"relock_after": np.inf}, "relock_after", TypeError),
    ({"relock_after": 2.0}, "relock_after", TypeError),
    ({"noise_margin": "0.1"}, "noise_margin", TypeError),
    ({"noise_margin": None}, "noise_margin", TypeError),
    ({"max_sep": 1e300}, "max_sep", ValueError),
])
def test_separation_gate_bad_numbers_named(kwargs, field, exc):
    with pytest.raises(exc, match=field):
        separation_gate(np.ones(5), np.ones(5), **kwargs)


@pytest.mark.parametrize("kwargs, field, exc", [
    ({"relock_after": np.inf}, "relock_after", TypeError),
    ({"lead_in": 0}, "lead_in", ValueError),
    ({"max_change": np.nan}, "max_change", ValueError),
    ({"max_speed": "fast"}, "max_speed", TypeError),
    ({"sample_interval": None}, "sample_interval", TypeError),
])
def test_velocity_gate_bad_numbers_named(kwargs, field, exc):
    with pytest.raises(exc, match=field):
        velocity_gate(np.arange(5.0), np.ones(5), **kwargs)


@pytest.mark.filterwarnings("ignore::estimator.range_filters.UnitWarning")
@settings(max_examples=40, deadline=None)
@given(value=st.sampled_from([0.0, 5e-324, 1e11, 1e300, np.inf, np.nan]),
       n=st.sampled_from([0, 1, 2, 3000]), mode=st.sampled_from(["robust", "thesis"]))
def test_extremes_never_crash_silently(value, n, mode):
    """Extreme ranges (0, subnormal, 1e11 m, 1e300, inf, NaN), empty to long series: a named
    ValueError (inf and anything beyond 1e12) or a filtered series of the same shape whose
    finite outputs are input values."""
    t = np.arange(n) * 0.1
    r = np.full(n, 5.0)
    r[n // 2:n // 2 + 1] = value
    try:
        out, rej = velocity_gate(t, r, 3.0, mode=mode, return_mask=True)
        a, _, rej2 = separation_gate(r, r, 0.5, mode=mode, return_mask=True)
    except ValueError as exc:
        assert str(exc).startswith(("r:", "r_a:")), exc
        assert not (np.isfinite(value) and abs(value) <= 1e12)
        return
    assert out.shape == r.shape == rej.shape == a.shape
    # missing stays missing, accepted samples pass bit for bit, everything else is finite
    np.testing.assert_array_equal(np.isnan(out), np.isnan(r))
    np.testing.assert_array_equal(out[~rej], r[~rej])
    np.testing.assert_array_equal(a[~rej2], r[~rej2])
