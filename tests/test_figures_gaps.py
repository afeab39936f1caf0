"""experiments.figures on gappy references (issue 25): a recording's reference with NaN
stretches, or missing everywhere, must give figures of what exists, never a traceback
(``ValueError: All-NaN slice encountered`` in the sensor-1 lag figure's magnified inset).

The results folder is written by hand: a cell table naming four per-epoch files (windows
1 and 10 of technique "none", plus "lc" and "ekf" at window 10) whose truth columns are
NaN on stretches or on every row.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from experiments import figures
from experiments.figures import _flag, draw_task, figure_tasks
from experiments.track_panels import steepest_stretch as _steepest_stretch

N = 120


def _epochs(truth_nan: np.ndarray, seed: int = 0) -> pd.DataFrame:
    """A straight east-west drive at 1 m/s with 0.5 m noise; truth columns NaN where
    ``truth_nan`` (N,) is True (the estimate and observations stay)."""
    rng = np.random.default_rng(seed)
    t = np.arange(N, dtype=float)
    x = np.where(t < 60, t, 120.0 - t)            # out and back: a steep and a flat part
    y = np.zeros(N)
    cols = {"t": t}
    for s, dy in (("1", 0.5), ("2", -0.5)):
        tx, ty = x, y + dy
        cols[f"truth_{s}_x"] = np.where(truth_nan, np.nan, tx)
        cols[f"truth_{s}_y"] = np.where(truth_nan, np.nan, ty)
        cols[f"obs_{s}_x"] = tx + rng.normal(0, 0.5, N)
        cols[f"obs_{s}_y"] = ty + rng.normal(0, 0.5, N)
        cols[f"x_{s}"] = tx + 0.1
        cols[f"y_{s}"] = ty
    cols["cg_x"], cols["cg_y"] = x + 0.1, y
    cols["truth_cg_x"] = np.where(truth_nan, np.nan, x)
    cols["truth_cg_y"] = np.where(truth_nan, np.nan, y)
    yaw = np.where(t < 60, 0.0, np.pi)
    cols["truth_yaw"] = np.where(truth_nan, np.nan, yaw)
    cols["yaw"] = yaw
    cols["err_x"] = np.where(truth_nan, np.nan, 0.1)
    cols["err_y"] = np.where(truth_nan, np.nan, 0.0)
    cols["err_yaw"] = np.where(truth_nan, np.nan, 0.01)
    # the turning flag of a gappy reference: unknown (NA) where the reference is missing
    cols["truth_turning"] = pd.array(np.where(truth_nan, None, (t > 55) & (t < 65)),
                                     dtype="boolean")
    return pd.DataFrame(cols)


def _results(tmp_path, truth_nan: np.ndarray):
    (tmp_path / "epochs").mkdir()
    rows = []
    for k, (tech, w) in enumerate((("none", 1), ("none", 10), ("lc", 10), ("ekf", 10))):
        key = f"cell{k}"
        _epochs(truth_nan, seed=k).to_parquet(tmp_path / "epochs" / f"{key}.parquet")
        rows.append({"key": key, "path": "rec", "technique": tech, "weighting": "none",
                     "window": w, "seed": 0, "has_epochs": True})
    pd.DataFrame(rows).to_parquet(tmp_path / "cells.parquet")
    figures._INDEX_CACHE.clear()
    return tmp_path


@pytest.mark.parametrize("gaps", ["stretches", "all"])
def test_every_figure_group_draws_a_gappy_reference(tmp_path, gaps):
    nan = np.zeros(N, dtype=bool)
    if gaps == "stretches":
        nan[5:40] = True                          # 35 s with no reference (issue 25: 34 s)
        nan[70:75] = True
        nan[::3] = True                           # and every third epoch besides
    else:
        nan[:] = True                             # a reference missing everywhere
    out = _results(tmp_path, nan)
    written = []
    for task in figure_tasks():
        files, _ = draw_task(out, task)
        written += files
    names = {p.name for p in written}
    # the groups whose data the folder holds are drawn, gaps or not
    assert {"fig_sensor1_lag_rec.png", "fig_overlay_rec.png", "fig_weights_rec.png",
            "fig_beyond.png"} <= names
    assert all(p.stat().st_size > 0 for p in written)


def test_steepest_stretch_skips_unknown_epochs():
    truth = np.r_[np.zeros(30), np.arange(30.0) * 2.0, np.full(40, 60.0)]   # steep at 30-59
    sl = _steepest_stretch(truth)
    assert sl.stop - sl.start == 14 and 28 <= sl.start <= 48
    gappy = truth.copy()
    gappy[25:60] = np.nan                          # the steep part unknown: the next best
    sl2 = _steepest_stretch(gappy)
    assert sl2 is not None and np.isfinite(gappy[sl2]).mean() >= 0.5
    assert _steepest_stretch(np.full(100, np.nan)) is None      # all NaN: no inset
    assert _steepest_stretch(np.arange(15.0)) is None           # too short for an inset
    # the signed stretches of the lag figures (positive / negative slope magnified)
    assert 28 <= _steepest_stretch(truth, 1).start <= 48
    assert _steepest_stretch(truth, -1) is None                 # it never falls
    assert _steepest_stretch(60.0 - truth, -1).start == _steepest_stretch(truth, 1).start
    assert _steepest_stretch(gappy, 1) is None                  # its only rise unknown
    # a complete reference picks what the moving mean alone picked (figures unchanged)
    rng = np.random.default_rng(1)
    z = np.cumsum(rng.normal(size=200))
    span = max(10, 200 // 7)
    old = int(np.argmax(np.convolve(np.abs(np.gradient(z)), np.ones(span) / span, "valid")))
    assert _steepest_stretch(z).start == old


def test_flags_with_unknown_rows():
    col = pd.Series([True, False, None], dtype="boolean")
    assert _flag(col, True).tolist() == [True, False, True]
    assert _flag(pd.Series([1.0, 0.0, np.nan]), False).tolist() == [True, False, False]
