"""Figures of the stationary report (experiments.stationary), one PNG per dissertation figure
group. Pure plotting of what experiments.stationary computed and the session it analysed;
the statistics themselves come from :mod:`estimator.noise_stats`.

Every figure has labelled axes with units, legends at 9-10 pt and a size for a report page
(about 1100-1400 px wide at :data:`DPI`)."""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.lines import Line2D

from estimator.configuration import SensorConfig
from estimator.noise_stats import acf, ar1_fit
from experiments.outline import layout_outline
from sim.gps import StationarySession

__all__ = ["DPI", "plot_all"]

DPI = 110
_STYLE = {"font.size": 10, "axes.titlesize": 10, "axes.labelsize": 10, "legend.fontsize": 9,
          "xtick.labelsize": 9, "ytick.labelsize": 9, "figure.titlesize": 12}
_SCHEME_ORDER = ["none", "huff", "huff:3.5"]


def _grid(k: int, ncols: int = 4, size: tuple[float, float] = (3.4, 2.7), **kw):
    """A grid of k panels, ncols wide at most, each ``size`` inches; extra panels hidden."""
    ncols = max(1, min(ncols, k))
    nrows = max(1, math.ceil(k / ncols))
    if k <= 2:                       # one or two receivers (a real log): report-page width
        size = (7.5 / ncols, 7.5 / ncols * size[1] / size[0])
    fig, axes = plt.subplots(nrows, ncols, figsize=(size[0] * ncols, size[1] * nrows + 0.6),
                             squeeze=False, layout="constrained", **kw)
    for ax in axes.ravel()[k:]:
        ax.set_visible(False)
    return fig, axes.ravel()


def _save(fig, path: Path, **kw) -> None:
    fig.savefig(path, dpi=DPI, **kw)
    plt.close(fig)


def _finish(fig, ax, title: str, *, ncols: int = 3) -> None:
    """Title above the panels and the legend of ``ax``'s artists in one row below them
    (constrained layout places all three when the figure is saved). Legend markers are
    drawn opaque at 6 pt or more, however small and faint the plotted points are."""
    fig.suptitle(title)
    handles, labels = ax.get_legend_handles_labels()
    proxies = [Line2D([], [], color=h.get_color(), marker=h.get_marker(),
                      linestyle=h.get_linestyle(), lw=max(h.get_linewidth(), 1.0),
                      ms=max(h.get_markersize(), 6.0), mew=h.get_markeredgewidth())
               if isinstance(h, Line2D) else h for h in handles]
    if handles:
        fig.legend(proxies, labels, loc="outside lower center", ncols=ncols, frameon=False)


def plot_all(out: Path, session: StationarySession, config: SensorConfig | None, *, nlags: int,
             weighting=None, windows=None) -> None:
    """Every figure of the report into ``out``: Figs 4.2-4.15 for any session; 4.4-4.6,
    4.17-4.24 and 4.25-4.33 when the configuration matches (``weighting``: the Scored list
    of experiments.stationary_analysis.weighting_estimates; ``windows``:
    {(scheme, s): positions})."""
    with plt.rc_context(_STYLE):
        _plot_all(out, session, config, nlags=nlags, weighting=weighting, windows=windows)


def _plot_all(out: Path, session: StationarySession, config: SensorConfig | None, *,
              nlags: int, weighting, windows) -> None:
    alive = [j for j in range(session.m) if session.present[:, j].any()]
    names = session.names
    t = session.t - session.t[0]
    dt = float(np.median(np.diff(session.t))) if session.n > 1 else 1.0
    truth = session.truth_positions

    # Fig 4.2: x (green) and y (blue) against time
    fig, axs = _grid(len(alive))
    for ax, j in zip(axs, alive):
        x = session.obs[:, j]
        ax.plot(t, x[:, 0] - np.nanmean(x[:, 0]), color="green", lw=0.6, label="x (east)")
        ax.plot(t, x[:, 1] - np.nanmean(x[:, 1]), color="blue", lw=0.6, label="y (north)")
        ax.set_title(f"sensor {names[j]}")
        ax.set_xlabel("t [s]")
        ax.set_ylabel("deviation from mean [m]")
        ax.grid(alpha=0.3)
    _finish(fig, axs[0], "Fig 4.2: x and y against time (deviation from each sensor's mean)",
            ncols=2)
    _save(fig, out / "fig4_02_xy_vs_time.png")

    # Fig 4.3: y vs x scatter
    fig, axs = _grid(len(alive), size=(3.2, 3.2))
    for ax, j in zip(axs, alive):
        x = session.obs[:, j]
        few = np.isfinite(x[:, 0]).sum() < 500          # short real logs: visible dots
        ax.plot(x[:, 0], x[:, 1], ".", ms=5 if few else 1.5, alpha=0.8 if few else 0.35,
                rasterized=True, label="fixes")
        if truth is not None:
            ax.plot(*truth[j], "kx", ms=9, mew=2, label="true position")
        ax.set_aspect("equal", "datalim")
        ax.set_title(f"sensor {names[j]}")
        ax.set_xlabel("x east [m]")
        ax.set_ylabel("y north [m]")
        ax.grid(alpha=0.3)
    _finish(fig, axs[0], "Fig 4.3: y against x per sensor", ncols=2)
    _save(fig, out / "fig4_03_scatter.png")

    # Figs 4.4-4.6: pairwise distances with configured values
    if config is not None:
        D = config.distances()
        pairs = [(a, b) for k, a in enumerate(alive) for b in alive[k + 1:]]
        fig, axs = _grid(len(pairs), ncols=5, size=(2.8, 2.1))
        for ax, (a, b) in zip(axs, pairs):
            d = np.linalg.norm(session.obs[:, a] - session.obs[:, b], axis=-1)
            ax.plot(t, d, lw=0.4, label="observed")
            ax.axhline(D[a, b], color="red", lw=1.2, label="configured")
            ax.set_title(f"sensors {names[a]}-{names[b]} ({D[a, b]:.2f} m)")
            ax.grid(alpha=0.3)
        for ax in axs[: len(pairs)]:
            ax.set_xlabel("t [s]")
            ax.set_ylabel("distance [m]")
        _finish(fig, axs[0], "Figs 4.4-4.6: distance between two sensors against time", ncols=2)
        _save(fig, out / "fig4_04_06_pairwise_distances.png")

    # Figs 4.7-4.8: normal probability plots
    from scipy import stats

    for a, ax_name, fig_no in ((0, "x", "07"), (1, "y", "08")):
        fig, axs = _grid(len(alive), size=(3.2, 2.8))
        for ax, j in zip(axs, alive):
            v = session.obs[:, j, a]
            v = v[np.isfinite(v)]
            (osm, osr), (slope, icpt, r) = stats.probplot(v, dist="norm")
            ax.plot(osm, osr, ".", ms=5 if v.size < 500 else 2, label="ordered samples")
            ax.plot(osm, slope * osm + icpt, "r-", lw=1, label="normal fit")
            ax.set_title(f"sensor {names[j]} (r = {r:.3f})")
            ax.set_xlabel("standard normal quantile [-]")
            ax.set_ylabel(f"{ax_name} [m]")
            ax.grid(alpha=0.3)
        _finish(fig, axs[0], f"Fig 4.{int(fig_no)}: normal probability plots of {ax_name}",
                ncols=2)
        _save(fig, out / f"fig4_{fig_no}_npp_{ax_name}.png")

    # Figs 4.9-4.15: time series, ACF, ACF of AR(1) residuals, per sensor
    lags = min(nlags, session.n - 1)
    lag_s = np.arange(lags + 1) * dt
    for k, j in enumerate(alive):
        fig, axs = plt.subplots(2, 3, figsize=(13, 6.2), layout="constrained")
        for a, ax_name in enumerate(("x (east)", "y (north)")):
            v = session.obs[:, j, a]
            n = int(np.isfinite(v).sum())
            bound = 1.96 / math.sqrt(max(n, 1))
            _, phi, _, res = ar1_fit(v)
            axs[a, 0].plot(t, v, lw=0.5)
            axs[a, 0].set_title(f"{ax_name} series")
            axs[a, 0].set_xlabel("t [s]")
            axs[a, 0].set_ylabel(f"{ax_name[0]} [m]")
            for col, series, title in ((1, v, "ACF"),
                                       (2, res, f"ACF of AR(1) residuals (phi = {phi:.3f})")):
                r = acf(series, lags)
                axs[a, col].vlines(lag_s, 0, r, lw=1.0, label="sample ACF")
                axs[a, col].axhline(bound, color="b", ls="--", lw=0.8,
                                    label="+-1.96/sqrt(n) bounds")
                axs[a, col].axhline(-bound, color="b", ls="--", lw=0.8)
                axs[a, col].axhline(0, color="k", lw=0.5)
                axs[a, col].set_title(f"{ax_name}: {title}")
                axs[a, col].set_xlabel("lag [s]")
                axs[a, col].set_ylabel("autocorrelation [-]")
        for ax in axs.ravel():
            ax.grid(alpha=0.3)
        _finish(fig, axs[0, 1], f"Fig 4.{9 + k}-style time series analysis, sensor {names[j]}",
                ncols=2)
        _save(fig, out / f"fig4_{9 + k:02d}_timeseries_sensor{names[j]}.png")

    # Figs 4.17-4.24: whole-recording estimates per weighting scheme
    if weighting is not None and config is not None:
        est = [e for e in weighting if e.scheme != "means"]
        fig, axs = _grid(len(est), ncols=4, size=(3.3, 3.3))
        for ax, e in zip(axs, est):
            for i, j in enumerate(alive):
                ax.plot(*session.obs[::10, j].T, ".", ms=1, alpha=0.2, color="grey",
                        rasterized=True, label="observations (every 10th)" if i == 0 else None)
            _config_poly(ax, e.positions, alive, "C1", "estimate")
            if truth is not None:
                _config_poly(ax, truth, alive, "k", "truth")
            ax.set_aspect("equal", "datalim")
            score = "" if math.isnan(e.pos_rmse_m) else \
                f"\nRMSE {e.pos_rmse_m:.2f} m, heading error {e.yaw_err_deg:.0f} deg"
            ax.set_title(f"{e.scheme}{score}")
            ax.set_xlabel("x east [m]")
            ax.set_ylabel("y north [m]")
        _finish(fig, axs[0], "Figs 4.17-4.23: observed and estimated stationary antenna locations",
                ncols=3)
        _save(fig, out / "fig4_17_23_weighting.png")
        fig, ax = plt.subplots(figsize=(9.5, 7.0), layout="constrained")
        for k, e in enumerate(est):
            _config_poly(ax, e.positions, alive, f"C{k}", e.scheme)
        if truth is not None:
            _config_poly(ax, truth, alive, "k", "truth", lw=2.2)
        ax.set_aspect("equal", "datalim")
        ax.set_xlabel("x east [m]")
        ax.set_ylabel("y north [m]")
        ax.grid(alpha=0.3)
        fig.legend(*ax.get_legend_handles_labels(), title="weighting scheme",
                   loc="outside right upper", fontsize=10, title_fontsize=10)
        ax.set_title("Fig 4.24: whole-recording estimates of the antenna layout per "
                     "weighting scheme")
        _save(fig, out / "fig4_24_weighting_summary.png")

    # Figs 4.25-4.33: sliding windows
    if windows is not None:
        schemes = sorted({k[0] for k in windows}, key=_SCHEME_ORDER.index)
        sizes = sorted({k[1] for k in windows})
        show = [s for s in (1, 2, 5, 10) if s in sizes]
        fig, axs = plt.subplots(len(schemes), len(show), figsize=(3.3 * len(show),
                                                                    3.3 * len(schemes) + 0.6),
                                squeeze=False, layout="constrained")
        for r_, sch in enumerate(schemes):
            for c_, s in enumerate(show):
                ax = axs[r_, c_]
                pos = windows[(sch, s)]
                for j in alive:
                    ax.plot(*pos[::10, j].T, ".", ms=1.2, alpha=0.3, rasterized=True,
                            label=f"sensor {names[j]}")
                if truth is not None:
                    ax.plot(*truth[alive].T, "kx", ms=7, mew=1.5, label="truth")
                ax.set_aspect("equal", "datalim")
                ax.set_title(f"{sch}, window s = {s} ({s * dt:g} s)")
                ax.set_xlabel("x east [m]")
                ax.set_ylabel("y north [m]")
        _finish(fig, axs[0, 0], "Figs 4.25-4.33: sliding-window estimates of each antenna "
                "(every 10th window)", ncols=min(9, len(alive) + 1))
        _save(fig, out / "fig4_25_33_windows.png")


def _config_poly(ax, pos: np.ndarray, alive: list[int], color: str, label: str,
                 lw: float = 1.4) -> None:
    p = pos[alive]
    if not np.isfinite(p).all():
        return
    hull = layout_outline(p)            # not by angle round the mean: that can cross itself
    q = p[hull + hull[:1]]
    ax.plot(q[:, 0], q[:, 1], "-o", color=color, ms=4, lw=lw, label=label)
    ax.plot(p[:, 0], p[:, 1], "o", color=color, ms=4)     # every antenna, inside ones too
