"""PNG files of matplotlib figures, drawn with cached text and written as palette images
(issue 27).

Text: matplotlib 3.11's Agg backend shapes every string (libraqm) and loads, hints and
renders every glyph on every draw (a Python loop per glyph), ~60-70 % of the drawing of
these figures (measured: the overlay figures redraw in 0.92 CPU-s, 0.36 without text). The
renderer here keeps, for the life of the process, each string's size and glyph layout and
each glyph's bitmap at a quarter-pixel origin; a glyph is then one blit. Glyphs land within
1/8 pixel of where the stock renderer puts them (``tests/test_png.py`` bounds the pixel
difference). Where matplotlib lacks the private calls this uses (before 3.11) the stock
renderer draws.

File: a figure of lines, markers and text holds a few hundred distinct colours (its
antialiased edges); quantized to a 256-colour palette (Pillow's fast octree, each entry then
the mean of its pixels) its PNG is ~3x smaller and encodes in half the CPU time of the RGBA
file ``savefig`` writes (the 18 thesis figures: 0.90 MB against 2.90 MB, 0.46 against 0.94
CPU-s at load ~7), with a mean colour error of 0.4/255 per channel, at antialiased edges;
white stays white.
"""

from __future__ import annotations

import math
from pathlib import Path

__all__ = ["canvas", "save_png"]

#: Sub-pixel steps of a cached glyph's origin per pixel (4: within 1/8 pixel).
STEPS = 4
#: Entries a cache may hold before it is emptied (a bound for long-lived processes: the
#: thesis preset's figures need ~3,000 glyphs and ~5,000 strings).
MAX_ENTRIES = 100_000
_METRICS: dict[tuple, tuple[float, float, float]] = {}
_LAYOUTS: dict[tuple, list[tuple]] = {}
_GLYPHS: dict[tuple, tuple] = {}
_HEIGHTS: dict[tuple, tuple] = {}
_CLASSES: list = []


def _bounded(cache: dict) -> dict:
    """``cache``, emptied first if it holds :data:`MAX_ENTRIES` entries."""
    if len(cache) >= MAX_ENTRIES:
        cache.clear()
    return cache


def _prop_key(prop) -> tuple:
    return (tuple(prop.get_family()), prop.get_style(), prop.get_variant(), prop.get_weight(),
            prop.get_stretch(), prop.get_size_in_points(), prop.get_file())


def _font_heights(prop, dpi: float) -> tuple:
    """matplotlib 3.11's ``Text._get_layout`` font heights (ascent, descent, line gap) of
    ``prop`` at ``dpi``; (None, None, None) where the font has neither table (it then
    measures "lp")."""
    from matplotlib.font_manager import fontManager, get_font

    font = get_font(fontManager._find_fonts_by_props(prop))
    for table_name, linegap_key, ascent_key, descent_key in (
            ("OS/2", "sTypoLineGap", "sTypoAscender", "sTypoDescender"),
            ("hhea", "lineGap", "ascent", "descent")):
        table = font.get_sfnt_table(table_name)
        if table is None:
            continue
        fontsize = prop.get_size_in_points()
        units_per_em = font.get_sfnt_table("head")["unitsPerEm"]
        scale = 1 / units_per_em * fontsize * dpi / 72
        return table[ascent_key] * scale, -table[descent_key] * scale, table[linegap_key] * scale
    return None, None, None


def _classes():
    """(canvas class, renderer class) with the text cache, or the stock Agg ones."""
    if _CLASSES:
        return _CLASSES[0]
    from matplotlib.backends import backend_agg as agg
    from matplotlib.ft2font import FT2Font

    if not (hasattr(FT2Font, "_layout") and hasattr(FT2Font, "_render_glyph")
            and hasattr(FT2Font, "_set_transform")):
        _CLASSES.append((agg.FigureCanvasAgg, agg.RendererAgg))
        return _CLASSES[0]

    class Renderer(agg.RendererAgg):
        def _get_font_height_metrics(self, prop):
            """(ascent, descent, line gap) in pixels of ``prop``'s font, as
            ``Text._get_layout`` computes them without this method (the same operations
            on the font's OS/2 or hhea table), once per font, size and dpi instead of at
            every layout (each a font look-up and three table reads)."""
            key = (_prop_key(prop), self.dpi)
            if key not in _HEIGHTS:
                _bounded(_HEIGHTS)[key] = _font_heights(prop, self.dpi)
            return _HEIGHTS[key]

        def get_text_width_height_descent(self, s, prop, ismath):
            if ismath:
                return super().get_text_width_height_descent(s, prop, ismath)
            key = (s, _prop_key(prop), self.dpi, agg.get_hinting_flag())
            if key not in _METRICS:
                _bounded(_METRICS)[key] = super().get_text_width_height_descent(s, prop, ismath)
            return _METRICS[key]

        def draw_text(self, gc, x, y, s, prop, angle, ismath=False, mtext=None):
            if ismath or not gc.get_antialiased() or (mtext is not None and (
                    mtext.get_fontfeatures() or mtext.get_language())):
                return super().draw_text(gc, x, y, s, prop, angle, ismath, mtext)
            flags = agg.get_hinting_flag()
            size = prop.get_size_in_points()
            key = (s, _prop_key(prop), self.dpi, flags)
            if key not in _LAYOUTS:
                font = self._prepare_font(prop)
                _bounded(_LAYOUTS)[key] = [(i.ft_object, i.glyph_index, i.x, i.y)
                                 for i in font._layout(s, flags=flags)]
            cos, sin = math.cos(math.radians(angle)), math.sin(math.radians(angle))
            for ft, glyph, dx, dy in _LAYOUTS[key]:
                # the origin in FreeType's pixels (y up), split into whole pixels and steps
                ox = round(STEPS * (x + dx * cos - dy * sin))
                oy = round(STEPS * (self.height - y + dx * sin + dy * cos))
                (ix, qx), (iy, qy) = divmod(ox, STEPS), divmod(oy, STEPS)
                buf, left, top = self._glyph(ft, size, glyph, angle, qx, qy, flags)
                self._renderer.draw_text_image(buf, left + ix, int(self.height) - top - iy
                                               + buf.shape[0], 0, gc)

        def _glyph(self, ft, size, glyph, angle, qx, qy, flags):
            """The bitmap of ``glyph`` with its origin at (qx, qy) steps and its left and top
            pixel there, rendered once per process."""
            import numpy as np
            from matplotlib.ft2font import RenderMode

            key = (ft.fname, size, self.dpi, glyph, angle, qx, qy, flags)
            if key not in _GLYPHS:
                cos, sin = math.cos(math.radians(angle)), math.sin(math.radians(angle))
                ft.set_size(size, self.dpi)
                ft._set_transform(
                    (0x10000 * np.array([[cos, -sin], [sin, cos]])).round().astype(int),
                    [64 * qx // STEPS, 64 * qy // STEPS])
                bm = ft._render_glyph(glyph, flags, RenderMode.NORMAL)
                _bounded(_GLYPHS)[key] = (np.array(bm.buffer), bm.left, bm.top)
            return _GLYPHS[key]

    class Canvas(agg.FigureCanvasAgg):
        def get_renderer(self):
            w, h = self.get_width_height(physical=True)
            key = w, h, self.figure.dpi
            if self._lastKey != key:
                self.renderer = Renderer(w, h, self.figure.dpi)
                self._lastKey = key
            return self.renderer

    _CLASSES.append((Canvas, Renderer))
    return _CLASSES[0]


def canvas(fig):
    """Attach the text-caching Agg canvas to ``fig`` (before it is drawn); returns it."""
    cls = _classes()[0]
    return fig.canvas if type(fig.canvas) is cls else cls(fig)


def save_png(fig, path: str | Path, dpi: float = 100) -> None:
    """Draw ``fig`` at ``dpi`` (its text through the cache) and write it to ``path`` as a
    256-colour palette PNG."""
    import numpy as np
    from PIL import Image

    fig.set_dpi(dpi)
    cv = canvas(fig)
    cv.draw()
    rgb = Image.fromarray(np.asarray(cv.buffer_rgba())).convert("RGB")
    q = rgb.quantize(256, method=Image.Quantize.FASTOCTREE)
    # the octree's colours are its cells' centres (white came out 254): each palette entry
    # becomes the mean of the pixels it stands for (every 13th pixel: the same to < 1/255)
    idx = np.asarray(q).ravel()[::13]
    px = np.asarray(rgb).reshape(-1, 3)[::13]
    n = np.bincount(idx, minlength=256)[:, None]
    mean = np.stack([np.bincount(idx, weights=px[:, c], minlength=256) for c in range(3)], 1)
    old = np.zeros((256, 3))
    given = np.asarray(q.getpalette()[:768], float).reshape(-1, 3)
    old[:len(given)] = given
    pal = np.where(n > 0, mean / np.maximum(n, 1), old)
    q.putpalette(np.round(pal).astype(np.uint8).ravel().tolist())
    q.save(path, format="png", compress_level=6, dpi=(dpi, dpi))
