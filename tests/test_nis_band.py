"""nis_summary computes the chi-square band once per distinct dof (issue 27: it was ~4 of the
thesis preset's cell CPU-s per row): the same numbers as the band per row."""

import math

import numpy as np
from scipy.special import chdtri

from estimator.pose_filter import nis_summary


def _per_row(nis, dof, band=0.95):
    ok = np.isfinite(nis) & (dof > 0)
    lo, hi = chdtri(dof[ok], 0.5 + 0.5 * band), chdtri(dof[ok], 0.5 - 0.5 * band)
    inside = (nis[ok] >= lo) & (nis[ok] <= hi)
    return {"mean_nis_per_dof": float(nis[ok].sum() / dof[ok].sum()),
            "share_in_band": float(inside.mean()), "n": int(ok.sum())}


def test_band_per_distinct_dof_is_the_band_per_row():
    rng = np.random.default_rng(27)
    for band in (0.95, 0.5, 0.99):
        dof = rng.choice([0.0, 1.0, 2.0, 3.5, 14.0, 16.0], size=4000)
        nis = rng.chisquare(np.maximum(dof, 1.0))
        nis[rng.random(4000) < 0.05] = np.nan
        # values on the band's edges: a comparison against a band off by one ulp would flip
        edge = rng.random(4000) < 0.1
        nis[edge & (dof > 0)] = chdtri(dof[edge & (dof > 0)], 0.5 + 0.5 * band)
        assert nis_summary(nis, dof, band) == _per_row(nis, dof, band)
    empty = nis_summary(np.full(3, np.nan), np.ones(3))
    assert empty["n"] == 0 and math.isnan(empty["share_in_band"])
