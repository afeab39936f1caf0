"""Compiled range-filter kernels (estimator.range_kernels, issues 26/27) against the plain
numpy / Python references kept in estimator.rigid_ranging and estimator.ranging.

Tolerance: the kernels do the same floating-point operations in the same order as the
references, so results agree to rounding; the bound 1e-9 (relative to 1 + |value|) leaves
room for libm differences in cos/sin (measured: bit-identical filters, <= 1e-14 smoother).
Discrete outputs (gating, segments, re-initialisations) must be identical.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_rigid_ranging import ANCHORS, BODY, CFG, Z0, driven_body, ranges_at

from estimator import rigid_ranging as rr

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
    sa, sb = rr.smooth(a), rr.smooth(a, reference=True)
    close(sa.state_post, sb.state_post)
    close(sa.cov_post, sb.cov_post)
    assert not np.allclose(sa.state_post, a.state_post)          # it did smooth
