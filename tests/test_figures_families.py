"""The all-sensor overlays (Figs 4.34-4.49 and their Path 2 / Huff siblings) and the
sensor-1 lag figures (Figs 4.50-4.53, 4.70-4.73, 4.90-4.93, 4.110-4.113) of issue 28,
drawn from a real small sweep (square20, windows 1 and 10, no / Huff weights, the lag
correction at window 10 with Huff weights, one seed with per-epoch files).

Each figure is captured as drawn (``figures._save`` wrapped): its rows, the tile or panel
of every sensor must hold coloured pixels, its numbers must be the per-epoch files'.
"""

from __future__ import annotations

import pickle

import matplotlib.image as mpimg
import numpy as np
import pytest

from experiments import figures
from experiments.spec import Spec
from experiments.sweep import run

SPEC = {"name": "families", "seed": 5, "seeds": 1,
        "grid": [{"path": "square20", "window": [1, 10], "weighting": ["none", "huff"],
                  "technique": "none"},
                 {"path": "square20", "window": 10, "weighting": "huff", "technique": "lc"}],
        "epochs": {"seeds": [0]}}


@pytest.fixture(scope="module")
def drawn(tmp_path_factory):
    """{file name: (figure, RGB image)} of the "overlay" and "sensor1" groups."""
    out = tmp_path_factory.mktemp("families")
    r = run(Spec.from_dict(SPEC, source="families"), out=out, jobs=1, progress=False,
            figures=False, cache_dir=tmp_path_factory.mktemp("truth"))
    assert r.n_failed == 0, r.errors
    figs, save = {}, figures._save
    # a copy of each figure as saved: a figure group draws its PNGs of one layout on one
    # figure, wiped between them (figures._pooled)
    figures._save = lambda fig, path, written: (save(fig, path, written), figs.__setitem__(
        path.name, pickle.loads(pickle.dumps(fig))))
    try:
        for task in ("overlay", "sensor1"):
            figures.draw_task(out, task)
    finally:
        figures._save = save
    return out, {n: (f, mpimg.imread(out / n)[..., :3]) for n, f in figs.items()}


def _coloured(img: np.ndarray, box) -> int:
    """Pixels in ``box`` (display x0, y0, x1, y1; origin bottom left) that are neither
    white nor grey: drawn tracks, not frames, ticks or text."""
    h = img.shape[0]
    x0, y0, x1, y1 = (int(round(v)) for v in box)
    crop = img[h - y1:h - y0, x0:x1]
    return int(((crop.max(axis=-1) - crop.min(axis=-1)) > 0.15).sum())


def test_the_families_are_drawn_under_their_names(drawn):
    _, figs = drawn
    assert set(figs) == {"fig_overlay_square20.png", "fig_overlay_square20_huff.png",
                         "fig_sensor1_lag_square20.png", "fig_sensor1_lag_square20_huff.png"}
    for fig, _ in figs.values():
        assert "Figs 4." in fig.get_suptitle()
    assert "Huff weights" in figs["fig_overlay_square20_huff.png"][0].get_suptitle()


@pytest.mark.parametrize("name", ["fig_overlay_square20.png", "fig_overlay_square20_huff.png"])
def test_overlay_has_a_tile_per_sensor_and_window(drawn, name):
    out, figs = drawn
    fig, img = figs[name]
    assert len(fig.axes) == 2                           # windows 1 and 10
    ax = fig.axes[0]
    sensors = [t.get_text() for t in ax.texts if t.get_text().startswith("sensor ")]
    assert sensors == [f"sensor {s}" for s in range(1, 9)]
    x0, x1 = ax.get_xlim()
    pitch = (x1 - x0) / (7 + 1 / 1.08)     # xlim: 7 pitches and a tile (pitch 1.08 tiles)
    for row in fig.axes:
        y0, y1 = row.get_ylim()
        for j in range(8):
            a = row.transData.transform([(x0 + j * pitch, y0),
                                         (x0 + j * pitch + pitch / 1.08, y1)])
            assert _coloured(img, (*a[0], *a[1])) > 200, (name, row.get_ylabel(), j)


def test_overlay_numbers_are_the_per_epoch_rms(drawn):
    out, figs = drawn
    fig, _ = figs["fig_overlay_square20.png"]
    texts = [t.get_text() for t in fig.axes[1].texts if " / " in t.get_text()]
    ep = [figures.load_epochs(out, k) for k in figures._Epochs(out).find(
        technique="none", weighting="none", window=10)["key"]][0]
    for s, txt in zip(range(1, 9), texts):
        d = np.hypot(ep[f"x_{s}"] - ep[f"truth_{s}_x"], ep[f"y_{s}"] - ep[f"truth_{s}_y"])
        assert txt.split(" / ")[1] == f"{np.sqrt(np.nanmean(d ** 2)):.2f}"


@pytest.mark.parametrize("name,lc", [("fig_sensor1_lag_square20.png", False),
                                     ("fig_sensor1_lag_square20_huff.png", True)])
def test_lag_figure_rows_and_magnified_slopes(drawn, name, lc):
    _, figs = drawn
    fig, img = figs[name]
    assert len(fig.axes) == 6                           # window 10: x and y, (a)/(b)/(c)
    for ax in fig.axes:
        assert _coloured(img, ax.get_window_extent().extents) > 100, ax.get_title("left")
        # observed, truth, estimate; the lag-corrected estimate only with Huff weights
        assert len(ax.lines) == 3 + lc, ax.get_title("left")
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert any("lag-corrected" in lb for lb in labels) == lc and "CG estimate" not in labels
    for row in (0, 1):
        rise, fall = fig.axes[3 * row + 1], fig.axes[3 * row + 2]
        assert "positive" in rise.get_title("left") and "negative" in fall.get_title("left")
        assert np.diff(rise.lines[1].get_ydata()[[0, -1]])[0] > 0   # the truth rises
        assert np.diff(fall.lines[1].get_ydata()[[0, -1]])[0] < 0   # and falls


def test_pooled_figures_are_the_fresh_ones_byte_for_byte(drawn, monkeypatch):
    """A figure group's second and later PNGs of one layout, drawn on the first one's
    figure wiped (figures._pooled), are byte for byte those of a fresh figure each."""
    out, figs = drawn
    pooled = {n: (out / n).read_bytes() for n in figs}
    monkeypatch.setattr(figures, "_pooled", lambda key, make: make())
    for task in ("overlay", "sensor1"):
        figures.draw_task(out, task)
    for n, data in pooled.items():
        assert (out / n).read_bytes() == data, n
