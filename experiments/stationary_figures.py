"""Figures of the stationary report (experiments.stationary), one PNG per dissertation figure
group. Pure plotting: everything plotted is computed in experiments.stationary."""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from estimator.configuration import SensorConfig
from sim.gps import StationarySession

DPI = 60


def _grid(k: int, ncols: int = 4, size: tuple[float, float] = (3.2, 2.4)):
    nrows = max(1, math.ceil(k / ncols))
    fig, axes = plt.subplots(nrows, ncols, figsize=(size[0] * ncols, size[1] * nrows), squeeze=False)
    for ax in axes.ravel()[k:]:
        ax.set_visible(False)
    return fig, axes.ravel()


def _save(fig, path: Path, dpi: int = DPI) -> None:
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)


def plot_all(out: Path, session: StationarySession, config: SensorConfig | None, *, nlags: int,
             weighting=None, windows=None) -> None:
    from experiments.stationary import acf, ar1_fit

    alive = [j for j in range(session.m) if session.present[:, j].any()]
    names = session.names
    t = session.t - session.t[0]
    truth = session.truth_positions

    # Fig 4.2: x (green) and y (blue) against time
    fig, axs = _grid(len(alive))
    for ax, j in zip(axs, alive):
        x = session.obs[:, j]
        ax.plot(t, x[:, 0] - np.nanmean(x[:, 0]), color="green", lw=0.6, label="x - mean")
        ax.plot(t, x[:, 1] - np.nanmean(x[:, 1]), color="blue", lw=0.6, label="y - mean")
        ax.set_title(f"sensor {names[j]}")
        ax.set_xlabel("t [s]")
        ax.set_ylabel("m")
    axs[0].legend(fontsize=7)
    fig.suptitle("Fig 4.2: x and y against time (deviation from the sensor's mean)")
    _save(fig, out / "fig4_02_xy_vs_time.png")

    # Fig 4.3: y vs x scatter
    fig, axs = _grid(len(alive), size=(2.8, 2.8))
    for ax, j in zip(axs, alive):
        x = session.obs[:, j]
        ax.plot(x[::2, 0], x[::2, 1], ".", ms=1, alpha=0.4, rasterized=True)
        if truth is not None:
            ax.plot(*truth[j], "kx", ms=8, mew=2)
        ax.set_aspect("equal", "datalim")
        ax.set_title(f"sensor {names[j]}")
    fig.suptitle("Fig 4.3: y vs x (x = truth)")
    _save(fig, out / "fig4_03_scatter.png")

    # Figs 4.4-4.6: pairwise distances with configured values
    if config is not None:
        D = config.distances()
        pairs = [(a, b) for k, a in enumerate(alive) for b in alive[k + 1:]]
        fig, axs = _grid(len(pairs), ncols=6, size=(2.6, 1.9))
        for ax, (a, b) in zip(axs, pairs):
            d = np.linalg.norm(session.obs[:, a] - session.obs[:, b], axis=-1)
            ax.plot(t[::3], d[::3], lw=0.4)
            ax.axhline(D[a, b], color="red", lw=1)
            ax.set_title(f"{names[a]}-{names[b]} (a={D[a, b]:.2f} m)", fontsize=8)
            ax.tick_params(labelsize=6)
        fig.suptitle("Figs 4.4-4.6: distance between two sensors vs time (red: configured)")
        _save(fig, out / "fig4_04_06_pairwise_distances.png", dpi=45)

    # Figs 4.7-4.8: normal probability plots
    from scipy import stats

    for a, ax_name, fig_no in ((0, "x", "07"), (1, "y", "08")):
        fig, axs = _grid(len(alive), size=(2.8, 2.4))
        for ax, j in zip(axs, alive):
            v = session.obs[:, j, a]
            v = v[np.isfinite(v)]
            (osm, osr), (slope, icpt, r) = stats.probplot(v, dist="norm")
            ax.plot(osm, osr, ".", ms=1.5)
            ax.plot(osm, slope * osm + icpt, "r-", lw=0.8)
            ax.set_title(f"sensor {names[j]} (r={r:.3f})", fontsize=9)
            ax.set_xlabel("normal quantile", fontsize=7)
        fig.suptitle(f"Fig 4.{int(fig_no)}: normal probability plots, {ax_name}")
        _save(fig, out / f"fig4_{fig_no}_npp_{ax_name}.png")

    # Figs 4.9-4.15: time series, ACF, ACF of AR(1) residuals, per sensor
    lags = np.arange(nlags + 1)
    for k, j in enumerate(alive):
        fig, axs = plt.subplots(2, 3, figsize=(10, 4.6))
        for a, ax_name in enumerate("xy"):
            v = session.obs[:, j, a]
            n = int(np.isfinite(v).sum())
            bound = 1.96 / math.sqrt(max(n, 1))
            _, phi, _, res = ar1_fit(v)
            axs[a, 0].plot(t, v, lw=0.5)
            axs[a, 0].set_title(f"{ax_name} series", fontsize=9)
            for col, series, title in ((1, v, "ACF"), (2, res, f"ACF of AR(1) residuals (phi={phi:.3f})")):
                r = acf(series, nlags)
                axs[a, col].vlines(lags, 0, r, lw=0.8)
                axs[a, col].axhline(bound, color="b", ls="--", lw=0.7)
                axs[a, col].axhline(-bound, color="b", ls="--", lw=0.7)
                axs[a, col].set_title(f"{ax_name}: {title}", fontsize=9)
                axs[a, col].set_xlabel("lag [samples]", fontsize=7)
        fig.suptitle(f"Fig 4.{9 + k}-style time series analysis, sensor {names[j]}")
        _save(fig, out / f"fig4_{9 + k:02d}_timeseries_sensor{names[j]}.png")

    # Figs 4.17-4.24: whole-recording estimates per weighting scheme
    if weighting is not None and config is not None:
        est = [e for e in weighting if e.scheme != "means"]
        fig, axs = _grid(len(est), ncols=4, size=(3.0, 3.0))
        for ax, e in zip(axs, est):
            for j in alive:
                ax.plot(*session.obs[::10, j].T, ".", ms=0.5, alpha=0.15, color="grey")
            _config_poly(ax, e.positions, alive, "C1", "estimate")
            if truth is not None:
                _config_poly(ax, truth, alive, "k", "truth")
            ax.set_aspect("equal", "datalim")
            score = "" if math.isnan(e.pos_rmse_m) else f"\nrmse {e.pos_rmse_m:.2f} m, yaw {e.yaw_err_deg:.0f} deg"
            ax.set_title(f"{e.scheme}{score}", fontsize=8)
        fig.suptitle("Figs 4.17-4.23: observed (grey) and estimated stationary locations")
        _save(fig, out / "fig4_17_23_weighting.png")
        fig, ax = plt.subplots(figsize=(5.5, 5))
        for k, e in enumerate(est):
            _config_poly(ax, e.positions, alive, f"C{k}", e.scheme)
        if truth is not None:
            _config_poly(ax, truth, alive, "k", "truth")
        ax.set_aspect("equal", "datalim")
        ax.legend(fontsize=7)
        ax.set_title("Fig 4.24: summary of weighted and unweighted estimates")
        _save(fig, out / "fig4_24_weighting_summary.png")

    # Figs 4.25-4.33: sliding windows
    if windows is not None:
        schemes = sorted({k[0] for k in windows}, key=["none", "huff", "huff3.5"].index)
        sizes = sorted({k[1] for k in windows})
        show = [s for s in (1, 2, 5, 10) if s in sizes]
        fig, axs = plt.subplots(len(schemes), len(show), figsize=(2.9 * len(show), 2.9 * len(schemes)),
                                squeeze=False)
        for r_, sch in enumerate(schemes):
            for c_, s in enumerate(show):
                ax = axs[r_, c_]
                pos = windows[(sch, s)]
                for j in alive:
                    ax.plot(*pos[::10, j].T, ".", ms=0.8, alpha=0.3)
                if truth is not None:
                    ax.plot(*truth[alive].T, "kx", ms=5)
                ax.set_aspect("equal", "datalim")
                ax.set_title(f"{sch}, window {s}", fontsize=8)
        fig.suptitle("Figs 4.25-4.33: sliding-window estimates (x = truth)")
        _save(fig, out / "fig4_25_33_windows.png", dpi=45)


def _config_poly(ax, pos: np.ndarray, alive: list[int], color: str, label: str) -> None:
    p = pos[alive]
    if not np.isfinite(p).all():
        return
    c = p.mean(axis=0)
    order = np.argsort(np.arctan2(p[:, 1] - c[1], p[:, 0] - c[0]))
    q = p[np.r_[order, order[0]]]
    ax.plot(q[:, 0], q[:, 1], "-o", color=color, ms=3, lw=1, label=label)
