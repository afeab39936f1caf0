"""Compiled range-filter kernels (estimator.range_kernels, issues 26/27) against the plain
numpy / Python references kept in estimator.rigid_ranging and estimator.ranging.

Tolerance: the kernels do the same floating-point operations in the same order as the
references, so results agree to rounding; the bound 1e-9 (relative to 1 + |value|) leaves
room for libm differences in cos/sin (measured: bit-identical filters, <= 1e-14 smoother).
Discrete outputs (gating, segments, re-initialisations) must be identical.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from synth_ranges import UWB_ANCHORS, scenario
from test_rigid_ranging import ANCHORS, BODY, CFG, Z0, driven_body, ranges_at

from estimator import rigid_ranging as rr
from estimator.ranging import RangeFilter, RangeStreams, RangingConfig, tight_filter

TOL = 1e-9


def close(a, b, tol=TOL):
    a, b = np.asarray(a, float), np.asarray(b, float)
    assert a.shape == b.shape
    np.testing.assert_array_equal(np.isfinite(a), np.isfinite(b))
    m = np.isfinite(b)
    assert np.all(np.abs(a[m] - b[m]) <= tol * (1 + np.abs(b[m])))


def rigid_case(seed, cfg=CFG, jump=True):
    """A driven body with a 1.5 m jump at 3 s (re-initialisation), a 5 s gap and spikes
    (gated updates): every branch of the filter loop."""
    rng = np.random.default_rng(seed)
    t, truth, _ = driven_body(rng, seconds=6.0, cfg=cfg)
    if jump:
        truth[150:, 0] += 1.5
    D = ranges_at(truth) + 0.1 + rng.normal(0, 0.05, (t.size, 3, 8))
    D[rng.random(D.shape) < 0.03] += 2.0                      # spikes: gated
    D[rng.random(D.shape) < 0.1] = np.nan                      # missing ranges
    t = np.where(t >= 4.0, t + 5.0, t)                         # a 5 s gap
    f = rr.fit_pose(ANCHORS, BODY, D, origin_z_m=Z0, bias="common", sigma_m=0.05,
                    mirror_check=False)
    ts, tag, anc, r = rr.grid_to_stream(t, D)
    return (ANCHORS, BODY, ts, tag, anc, r, t, f.pose), dict(init_bias=f.bias[:, 0],
                                                             origin_z_m=Z0, config=cfg)


@pytest.mark.parametrize("cfg", [CFG, rr.FilterConfig(q_bias=0.0, init_sigma_bias_m=0.0)])
def test_rigid_filter_and_smoother_kernels_match_the_references(cfg):
    """The second config switches the bias state off: singular predictions, the smoother's
    pseudo-inverse branch."""
    args, kw = rigid_case(3, cfg)
    a = rr.track(*args, **kw)
    b = rr.track(*args, reference=True, **kw)
    assert a.segment.max() >= 2 and (~a.accepted).sum() > 10    # re-inits and gating seen
    for f in ("state_pred", "cov_pred", "state_post", "cov_post", "nis"):
        close(getattr(a, f), getattr(b, f))
    for f in ("segment", "reinit", "n_accepted", "n_gated", "accepted"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
    from estimator.range_kernels import rigid_rts

    assert rigid_rts(a.times, a.segment, a.state_pred, a.cov_pred, a.state_post,
                     a.cov_post)[2]                         # no fallback to the reference
    sa, sb = rr.smooth(a), rr.smooth(a, reference=True)
    close(sa.state_post, sb.state_post)
    close(sa.cov_post, sb.cov_post)
    assert not np.allclose(sa.state_post, a.state_post)          # it did smooth


# ------------------------------------------------------------- single-tag range filter


LEV = [[0.25, 0.1, 0.0], [-0.25, 0.0, 0.05]]


@pytest.mark.parametrize("height, lev, bounds", [
    (1.0, None, None), (None, None, None), (1.0, LEV, None), (None, LEV, None),
    (None, None, (1.1, 1.3)), (None, LEV, (0.0, 0.9))])
def test_range_filter_kernel_matches_the_numpy_reference(height, lev, bounds):
    """500 ranges at uneven steps (some repeated times, 5 % spikes the gate rejects, a few
    NaN) through the kernel filter and the numpy reference: every return value identical,
    state and covariance within TOL after each update. Bounds (free z): the second holds z
    below the truth (1.0 m) at its upper bound, the first is narrower than the initial z std
    (the fallback pseudo-measurement)."""
    rng = np.random.default_rng(5)
    lev = None if lev is None else np.array(lev)
    kw = dict(sigma_range_m=0.1, accel_std_mps2=0.8, height_m=height, levers=lev,
              yaw_accel_std=0.5, gate=4.0, height_bounds=bounds)
    a, b = RangeFilter(UWB_ANCHORS, **kw), RangeFilter(UWB_ANCHORS, **kw, reference=True)
    for f in (a, b):
        f.initialise(0.0, [12.0, -1.0, 1.0], position_std=1.5, speed_std=2.0, yaw=0.3,
                     yaw_std=0.5)
    t = np.cumsum(np.where(rng.random(500) < 0.2, 0.0, rng.uniform(0.005, 0.05, 500)))
    ntx = 1 if lev is None else 2
    rejected = 0
    for ti in t:
        p = np.array([12.0 + 0.5 * ti, -1.0, 1.0])
        rx, tx = int(rng.integers(4)), int(rng.integers(ntx))
        r = float(np.linalg.norm(p - UWB_ANCHORS[rx]) + rng.normal(0, 0.1))
        r = r + 3.0 if rng.random() < 0.05 else (math.nan if rng.random() < 0.02 else r)
        ua, ub = a.update(float(ti), rx, tx, r), b.update(float(ti), rx, tx, r)
        assert ua == ub
        rejected += not ua
        close(a.x, b.x)
        close(a.P, b.P)
        assert a.t == b.t
    assert rejected > 10
    for x, y in zip(a.state_at(t[-1] + 0.3), b.state_at(t[-1] + 0.3)):
        close(x, y)
    if bounds is not None:
        assert bounds[0] <= a.x[2] <= bounds[1]


def test_range_filter_fast_path_keeps_the_checks():
    f = RangeFilter(UWB_ANCHORS, sigma_range_m=0.1, accel_std_mps2=1.0, height_m=1.0)
    f.initialise(1.0, [5.0, 0.0, 1.0], position_std=1.0, speed_std=1.0)
    for args, field in (((0.5, 0, 0, 3.0), "t"), ((2.0, 4, 0, 3.0), "receiver"),
                        ((2.0, 0, 1, 3.0), "transmitter"), ((2.0, 0, 0, -1.0), "r"),
                        ((math.inf, 0, 0, 3.0), "t")):
        with pytest.raises(ValueError, match=field):
            f.update(*args)
    with pytest.raises(TypeError, match="receiver"):
        f.update(2.0, True, 0, 3.0)
    assert f.t == 1.0


@pytest.mark.parametrize("height", [1.0, None])
def test_tight_filter_kernel_matches_the_reference_through_reinitialisations(height):
    """The synthetic UWB scene with spikes, a dropout and NLOS, plus a 3 s blackout of every
    receiver and a 6 m jump of the ranges (the filter is lost and re-initialised): the
    compiled loop and the all-Python reference agree (sample flags and re-initialisation
    times identical, states within TOL)."""
    sc = scenario(4, duration_s=60.0)
    s = sc.streams
    r = np.where((s.t > 20) & (s.t < 23), np.nan, s.r)
    r = np.where(s.t > 40, r + 6.0, r)
    st = RangeStreams(s.t, r, s.receiver, s.transmitter, s.n_receivers)
    cfg = RangingConfig.uwb_ground_tag(height_m=height)
    te = np.arange(0.0, 60.0, 0.1)
    a = tight_filter(st, sc.anchors, cfg, te)
    b = tight_filter(st, sc.anchors, cfg, te, reference=True)
    assert len(a.reinitialised) >= 1 and a.gated.sum() > 10
    assert a.reinitialised == b.reinitialised
    for f in ("used", "gated", "skipped"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
    for f in ("position", "velocity", "std"):
        close(getattr(a, f), getattr(b, f))


# ----------------------------------------------------------- Filter 1, PV Kalman on fixes
@pytest.mark.parametrize("mode", ["robust", "thesis"])
@pytest.mark.parametrize("seed", [0, 1])
def test_velocity_gate_kernel_matches_the_numpy_loop(mode, seed):
    """The synthetic UWB scene's channels (spike runs, a dropout, per-channel clocks with NaN
    padding): identical outputs and masks (bit for bit: the same comparisons)."""
    from estimator.range_filters import velocity_gate

    tp, rp, _ = scenario(seed).streams.padded()
    kw = dict(mode=mode, return_mask=True, max_change=1.0, noise_margin=0.3)
    a = velocity_gate(tp, rp, 3.0, **kw)
    b = velocity_gate(tp, rp, 3.0, reference=True, **kw)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    assert a[1].sum() > 50


@pytest.mark.parametrize("gate", [None, 3.0])
@pytest.mark.parametrize("per_sample", [False, True])
def test_pv_kalman_kernel_matches_the_reference(gate, per_sample):
    """estimator.kalman.pv_kalman against the compiled loop used by filter_fixes, on uneven
    samples with 5 % spikes (gated, re-initialisations) and 5 % NaN."""
    from estimator.kalman import pv_kalman
    from estimator.ranging import _pv_kalman

    rng = np.random.default_rng(2)
    t = np.cumsum(rng.uniform(0.05, 0.15, 2000))
    z = 10 * np.sin(t / 5) + rng.normal(0, 0.1, t.size)
    z[rng.random(t.size) < 0.05] += 5.0
    z[rng.random(t.size) < 0.05] = np.nan
    sm = np.where(np.isfinite(z), rng.uniform(0.05, 0.2, t.size), np.nan) if per_sample \
        else 0.1
    close(_pv_kalman(t, z, 1.0, sm, gate, 5), pv_kalman(t, z, 1.0, sm, gate=gate,
                                                        reinit_after=5))


# ------------------------------------------------------------------ damped least squares
@pytest.mark.parametrize("height", [None, 1.0])
def test_damped_ls_kernel_matches_the_batched_numpy_lm(height, monkeypatch):
    """damped_ls with the compiled per-row LM against the batched numpy reference on 800
    epochs of the synthetic UWB scene (spikes, a dropout, NLOS; tag out to 40 m). The two
    sum J'J in different orders, so an iterate can stop one step apart: positions agree to
    1e-6 m (the stopping tests are relative, tol 1e-10 of the ~40 m scale; measured 1.6e-7 m
    on the LOS run), every status flag identically."""
    from estimator import trilateration as tri
    from estimator.ranging import epoch_ranges

    sc = scenario(1)
    te = np.arange(0.0, 80.0, 0.1)
    R = epoch_ranges(sc.streams, sc.streams.r, te, sync="interpolate", max_gap_s=0.5)[:, 0]
    a, ia = tri.damped_ls(sc.anchors, R, height_m=height, return_info=True)
    monkeypatch.setattr(tri, "_levenberg_marquardt", tri._levenberg_marquardt_reference)
    b, ib = tri.damped_ls(sc.anchors, R, height_m=height, return_info=True)
    np.testing.assert_array_equal(np.isfinite(a), np.isfinite(b))
    assert np.isfinite(b).sum() > 0.9 * b.size
    np.testing.assert_allclose(a, b, atol=1e-6, rtol=0)
    for f in ("missing", "converged", "degenerate", "bounded", "ambiguous"):
        np.testing.assert_array_equal(getattr(ia, f), getattr(ib, f))
