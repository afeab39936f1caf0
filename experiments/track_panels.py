"""The panels of the per-sensor figures of the GPS dissertation's Sections 4.10-4.11
(000_8f82f8df647bf685.txt), drawn by :mod:`experiments.figures`: a row of overlay tiles
(every sensor's observed, fitted and true track, Figs 4.34-4.49 style) and a row of the
sensor-1 lag figure (a coordinate against time, its steepest rise and fall magnified,
Figs 4.50-4.53 style). ``ep`` is a cell's per-epoch columns (``ep[name]``: a float array).
"""

from __future__ import annotations

import numpy as np

__all__ = ["CG", "EST", "OBS", "TRUE", "extent", "lag_row", "legend", "overlay_row",
           "rms_txt", "steepest_stretch"]

#: Colours of Sections 4.10-4.11: observed purple, sensor estimate blue, CG estimate green,
#: truth red (here the lag-corrected estimate, which those figures lack, is green dashed).
OBS, EST, CG, TRUE = "#9467bd", "C0", "C2", "C3"


def rms_txt(ep, x: str, y: str, s: str) -> str:
    """RMS horizontal distance of columns (x, y) to sensor s's truth over the epochs where
    both are known, as text ("none" without such epochs: a dead receiver, a gappy truth)."""
    d = np.hypot(np.asarray(ep[x], float) - np.asarray(ep[f"truth_{s}_x"], float),
                 np.asarray(ep[y], float) - np.asarray(ep[f"truth_{s}_y"], float))
    d = d[np.isfinite(d)]
    return f"{np.sqrt(np.mean(d ** 2)):.2f}" if d.size else "none"


def legend(fig, lc: bool | None = None) -> None:
    """The tracks' legend, top right; ``lc``: a lag figure (no CG estimate), with (True)
    or without the lag-corrected estimate."""
    from matplotlib.lines import Line2D

    spec = [("observed", OBS, ".", "none"), ("sensor estimate", EST, "", "-"),
            ("CG estimate", CG, "", "-"), ("sensor truth", TRUE, "", "-")]
    if lc is not None:
        spec[2:3] = [("lag-corrected estimate (LC, Section 3.4.2)", CG, "", "--")] * lc
    fig.legend(handles=[Line2D([], [], color=c, marker=m, ls=ls, label=lb)
                        for lb, c, m, ls in spec], loc="upper right", ncol=4, fontsize=9,
               bbox_to_anchor=(0.995, 1 - 0.45 / fig.get_figheight()), frameon=False)


def extent(*cols: np.ndarray) -> tuple[float, float]:
    """(lo, hi) of the finite values of ``cols`` with a margin, (0, 1) without any."""
    v = np.concatenate([np.asarray(c, float) for c in cols])
    v = v[np.isfinite(v)]
    pad = 0.04 * (v.max() - v.min()) + 1.0 if v.size else 0.0
    return (v.min() - pad, v.max() + pad) if v.size else (0.0, 1.0)


def overlay_row(ax, ep, sensors: list[str], top: bool) -> None:
    """One window's row: a tile per sensor side by side on one axes, each kind of track one
    line across the tiles (a figure's cost is its axes and artists), the x ticks under the
    first tile (every tile spans the same metres)."""
    from matplotlib.ticker import MaxNLocator

    (x0, x1), (y0, y1) = (extent(ep[f"truth_cg_{a}"], ep[f"cg_{a}"]) for a in "xy")
    half = max(x1 - x0, y1 - y0) / 2            # square tiles, whatever the path's shape
    (x0, x1), (y0, y1) = ((c - half, c + half) for c in ((x0 + x1) / 2, (y0 + y1) / 2))
    pitch, mid = 1.08 * (x1 - x0), (x0 + x1) / 2
    ep.prefetch([f"{p}{s}{a}" for s in sensors for p, a in (("obs_", "_x"), ("obs_", "_y"),
                ("truth_", "_x"), ("truth_", "_y"), ("x_", ""), ("y_", ""))])
    for cols, kw in (("obs_{}_x obs_{}_y", {"ls": "none", "marker": ".", "ms": 1,
                                             "color": OBS}),
                     ("truth_{}_x truth_{}_y", {"color": TRUE, "lw": 1.2}),
                     ("cg_x cg_y", {"color": CG, "lw": 0.6}),
                     ("x_{} y_{}", {"color": EST, "lw": 0.6})):
        xs, ys = [], []
        for j, s in enumerate(sensors):       # a tile's track, then NaN: the line breaks
            cx, cy = cols.format(s, s).split()
            x = np.asarray(ep[cx], float)
            xs += [np.where((x >= x0) & (x <= x1), x, np.nan) + j * pitch, [np.nan]]
            ys += [np.asarray(ep[cy], float), [np.nan]]
        ax.plot(np.concatenate(xs), np.concatenate(ys), **kw)
    # the tiles' frames: one line, NaN between tiles (a patch per tile cost more to add)
    fx = np.array([0, 1, 1, 0, 0, np.nan]) * (x1 - x0) + x0
    fy = np.array([0, 0, 1, 1, 0, np.nan]) * (y1 - y0) + y0
    ax.plot(np.concatenate([fx + j * pitch for j in range(len(sensors))]),
            np.tile(fy, len(sensors)), color="k", lw=0.6, clip_on=False, zorder=1)
    for j, s in enumerate(sensors):
        ax.text(mid + j * pitch, (y0 + y1) / 2, f"{rms_txt(ep, f'obs_{s}_x', f'obs_{s}_y', s)}"
                f" / {rms_txt(ep, f'x_{s}', f'y_{s}', s)}", ha="center", va="center", fontsize=7)
        if top:
            ax.text(mid + j * pitch, y1, f"sensor {s}", ha="center", va="bottom", fontsize=9)
    ax.set_xticks([t for t in MaxNLocator(3).tick_values(x0, x1) if x0 <= t <= x1])
    ax.yaxis.set_major_locator(MaxNLocator(3))
    ax.tick_params(labelsize=7)
    ax.set(xlim=(x0, x1 + (len(sensors) - 1) * pitch), ylim=(y0, y1), aspect="equal")
    ax.set_frame_on(False)


def steepest_stretch(truth: np.ndarray, sign: int = 0) -> slice | None:
    """The stretch of ``max(10, n // 7)`` epochs (n > 20) where the truth (n,) changes
    fastest on average (sign 0: |slope|; +1 / -1: the steepest rise / fall, None if it
    never rises / falls), counting only epochs whose slope is known (a gappy reference:
    NaN rows); at least half of the stretch must be known. None when no stretch qualifies
    (too short, or the reference is missing almost everywhere)."""
    k = truth.size
    if k <= 20:
        return None
    span = max(10, k // 7)
    g = np.gradient(truth)
    slope = np.abs(g) if sign == 0 else sign * g
    known = np.isfinite(slope)
    # the mean over the known epochs: the plain moving mean (as before gaps were handled,
    # so a complete reference picks the same stretch bit for bit) times span / known count
    mean = np.convolve(np.where(known, slope, 0.0), np.ones(span) / span, mode="valid")
    count = np.convolve(known.astype(float), np.ones(span), mode="valid")
    score = np.where(count >= 0.5 * span, mean * (span / np.maximum(count, 1.0)), -np.inf)
    i0 = int(np.argmax(score))
    return slice(i0, i0 + span) if score[i0] > (0 if sign else -np.inf) else None


def lag_row(axes, ep, lc, s: str, axis: str) -> None:
    """One row of the lag figure: sensor s's ``axis`` coordinate against time, (a) the
    whole run, (b)/(c) the steepest rising/falling stretch magnified (blank if none)."""
    t = np.asarray(ep["t"], float)
    truth = np.asarray(ep[f"truth_{s}_{axis}"], float)
    series = [(t, np.asarray(ep[f"obs_{s}_{axis}"], float), {"ls": "none", "marker": ".",
                                                          "ms": 2, "color": OBS}),
              (t, truth, {"color": TRUE, "lw": 1.5}),
              (t, np.asarray(ep[f"{axis}_{s}"], float), {"color": EST, "lw": 1.0})]
    if lc is not None:
        series.append((np.asarray(lc["t"], float), np.asarray(lc[f"{axis}_{s}"], float),
                       {"color": CG, "lw": 1.0, "ls": "--"}))
    spans = [(t[0], t[-1])] + [None if sl is None else (t[sl][0], t[sl][-1]) for sl in
                               (steepest_stretch(truth, 1), steepest_stretch(truth, -1))]
    for ax, span in zip(axes, spans):
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=7)
        ax.locator_params(nbins=4)
        if span is None:
            ax.text(0.5, 0.5, "no such stretch in the reference", ha="center",
                    transform=ax.transAxes, fontsize=8)
            continue
        for tt, v, kw in series:
            m = (tt >= span[0]) & (tt <= span[1])
            ax.plot(tt[m], v[m], **kw)
