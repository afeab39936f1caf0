"""experiments.png: the text-caching Agg renderer against matplotlib's own, and the palette
PNG against the drawn pixels.

Tolerances: a cached glyph lands within 1/8 pixel of the stock renderer's position, so only
antialiased glyph edges differ, by at most a fraction of the text's contrast: mean absolute
difference < 1/255 per channel over the figure, no pixel more than 96/255 off and < 0.1 % of
the pixels more than 32/255 off (measured: mean 0.40, max 33, 4 of 240,000 pixels over 32).
The 256-colour palette keeps plain colours exact; antialiased edges within the octree's
error (measured on the thesis figures: mean ~1.2/255, max 48/255).
"""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")

import matplotlib.image as mpimg
import matplotlib.pyplot as plt
import numpy as np
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg

from experiments import png


def _figure():
    fig, ax = plt.subplots(figsize=(6, 4), dpi=100)
    ax.plot([0, 1, 2], [3, 1, 2], color="C3")
    ax.set_title("(a) window 10: sensor 1 x against time", fontsize=9, loc="left")
    ax.set_ylabel("heading (deg)")               # rotated 90 degrees
    ax.set_xlabel("time (s)")
    ax.text(0.5, 2, "0.41 / 0.38", fontsize=7)
    ax.text(1.5, 2.5, "tilted", rotation=30)
    fig.suptitle("Path 1 (square100): CG error by window, Huff weights, seeds 0-4 pooled")
    return fig


def _pixels(canvas) -> np.ndarray:
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].astype(int)


@pytest.fixture(scope="module")
def stock_and_cached():
    stock = _pixels(FigureCanvasAgg(_figure()))
    cached = _pixels(png.canvas(_figure()))
    again = _pixels(png.canvas(_figure()))     # every glyph from the cache now
    plt.close("all")
    return stock, cached, again


def test_cached_text_is_where_the_stock_renderer_draws_it(stock_and_cached):
    stock, cached, again = stock_and_cached
    assert type(png.canvas(plt.figure())).__name__ in ("Canvas", "FigureCanvasAgg")
    d = np.abs(stock - cached).max(axis=-1)
    assert d.mean() < 1.0 and d.max() <= 96 and (d > 32).mean() < 1e-3, (d.mean(), d.max())
    assert (again == cached).all()               # a cache hit draws the same pixels
    assert (d > 0).any() or type(png.canvas(plt.figure())).__name__ == "FigureCanvasAgg"


def test_text_is_drawn_at_all(stock_and_cached):
    """Guards the comparison above: a renderer that drew no text would differ from the
    stock one by far more than the tolerance (here: text pixels exist and match)."""
    stock, cached, _ = stock_and_cached
    blank = _figure()
    for t in [*blank.texts, *blank.axes[0].texts]:
        t.set_visible(False)
    blank.axes[0].set_title("", loc="left")
    blank.axes[0].set_xlabel("")
    blank.axes[0].set_ylabel("")
    no_text = _pixels(FigureCanvasAgg(blank))
    text_px = np.abs(stock - no_text).max(axis=-1) > 32
    assert text_px.sum() > 2000
    assert np.abs(cached - no_text).max(axis=-1)[text_px].mean() > 64


def test_palette_png_reads_back_as_drawn(tmp_path):
    fig = _figure()
    png.save_png(fig, tmp_path / "f.png", dpi=100)
    drawn = np.asarray(fig.canvas.buffer_rgba())[..., :3].astype(int)
    back = (mpimg.imread(tmp_path / "f.png")[..., :3] * 255).round().astype(int)
    plt.close(fig)
    assert back.shape == drawn.shape == (400, 600, 3)
    d = np.abs(back - drawn)
    assert d.mean() < 2.0 and d.max() <= 64, (d.mean(), d.max())
    white = (drawn == 255).all(axis=-1)
    assert (back[white] == 255).all()            # plain colours exact


@pytest.mark.parametrize("size", [7, 9, 10.5, 12])
def test_cached_font_heights_give_the_stock_layout(size):
    """The renderer's font heights (experiments.png._font_heights, cached) lay text out
    exactly as matplotlib does without them: same boxes and line positions, bit for bit."""
    cls = png._classes()[1]
    if not hasattr(cls, "_get_font_height_metrics"):
        pytest.skip("stock renderer (matplotlib before 3.11)")
    fig = plt.figure(figsize=(4, 3), dpi=100)
    t = fig.text(0.1, 0.5, "window 10\nsensor 1 y (m)\nlp", fontsize=size, rotation=30)
    stock = t._get_layout(FigureCanvasAgg(fig).get_renderer())
    fig2 = plt.figure(figsize=(4, 3), dpi=100)
    t2 = fig2.text(0.1, 0.5, t.get_text(), fontsize=size, rotation=30)
    cached = t2._get_layout(png.canvas(fig2).get_renderer())
    plt.close("all")
    assert np.array_equal(stock[0].get_points(), cached[0].get_points())
    assert stock[1] == cached[1] and np.array_equal(stock[2], cached[2])
