"""The ultrasonic study's range and Appendix B figure families (thesis 003), drawn from the
study's saved tables only (:mod:`experiments.ultrasonic` writes them):

- ``fig3_07_range_change_T20.png`` / ``_T21.png``: Fig 3.7, histograms of the change in
  consecutive raw range values per receiver, bins of 1000 mm from -10000 to 10000 mm (the
  thesis's ``XValues``), with the Filter 1 cut-off of 1000 mm per sample (Section 3.2.2);
  from ``flight_series.csv`` (``range_raw_front_*`` = T20, ``range_raw_rear_*`` = T21).
- ``fig3_2_2_tx_difference.png``: the T20 - T21 range difference per receiver (20 bins, as
  the thesis's script), with Filter 2's 500 mm transmitter separation (Section 3.2.2).
- ``appB_bias_quiver.png``: per method, contour of the x + y MSE per 1 m pixel with the
  per-pixel mean x/y error as arrows and the receivers as dots (Appendix B figures 12-15,
  "XY MSE and XY Error Biasing"); from ``mc_pixels.csv``.
- ``appB_mse_normalized.png``: bar chart of each method's total MSE over the smallest
  (Appendix B ``MSE_Error_Normalized_All``); from ``mc_table.csv``.
- ``appB_range_error_hist.png``: histograms of the simulated range errors per receiver,
  -30..30 mm (Appendix B figure 1); from ``mc_range_errors.csv`` (counts per 1 mm bin).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

__all__ = ["ERROR_EDGES_MM", "plot_all", "range_error_counts"]

#: Appendix B plots its error histograms on -30..30 mm; 1 mm bins.
ERROR_EDGES_MM = np.arange(-30.0, 31.0, 1.0)
#: Fig 3.7's bins (thesis XValues = -10000:1000:10000 mm, used as bin centres).
CHANGE_CENTRES_MM = np.arange(-10000.0, 10001.0, 1000.0)
FILTER1_MM = 1000.0       # Section 3.2.2: 1000 mm per sample (~10 m/s at 0.1 s)
FILTER2_MM = 500.0        # Section 3.2.2: 0.5 m transmitter separation
TX = {"front": "T20", "rear": "T21"}


def range_error_counts(errors_m: np.ndarray, names: list[str]) -> pd.DataFrame:
    """Counts of range errors (n, k) metres per receiver in the ERROR_EDGES_MM bins; errors
    outside -30..30 mm are counted in ``below`` / ``above``. Columns: receiver, lo_mm, hi_mm,
    count (one row per bin) plus rows with lo_mm = -inf / hi_mm = +inf for the tails."""
    e = np.asarray(errors_m, dtype=float)
    if e.ndim != 2 or e.shape[1] != len(names):
        raise ValueError(f"errors_m: expected shape (n, {len(names)}), got {e.shape}")
    rows = []
    for j, nm in enumerate(names):
        mm = e[:, j] * 1e3
        c, _ = np.histogram(mm, ERROR_EDGES_MM)
        lo, hi = ERROR_EDGES_MM[:-1], ERROR_EDGES_MM[1:]
        rows.append(pd.DataFrame({"receiver": nm, "lo_mm": lo, "hi_mm": hi, "count": c}))
        rows.append(pd.DataFrame({"receiver": nm, "lo_mm": [-np.inf, ERROR_EDGES_MM[-1]],
                                  "hi_mm": [ERROR_EDGES_MM[0], np.inf],
                                  "count": [(mm < ERROR_EDGES_MM[0]).sum(),
                                            (mm >= ERROR_EDGES_MM[-1]).sum()]}))
    return pd.concat(rows, ignore_index=True)


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _grid(plt, n: int, title: str):
    fig, axes = plt.subplots(3, 2, figsize=(10, 8), constrained_layout=True)
    fig.suptitle(title)
    return fig, axes.ravel()[:n]


def _save(fig, path: Path, plt) -> Path:
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def plot_range_change(series: pd.DataFrame, names: list[str], out: Path) -> list[Path]:
    """Fig 3.7 per transmitter: histogram of diff(raw range) in mm, log counts."""
    plt = _plt()
    edges = np.r_[CHANGE_CENTRES_MM - 500.0, CHANGE_CENTRES_MM[-1] + 500.0]
    files = []
    for side, tx in TX.items():
        fig, axes = _grid(plt, len(names), f"Change in consecutive raw range values, {tx} "
                          "(cf. thesis Fig. 3.7); red: Filter 1 cut-off +-1000 mm")
        for ax, nm in zip(axes, names, strict=True):
            d = np.diff(series[f"range_raw_{side}_{nm}"].to_numpy()) * 1e3
            _log_hist(ax, np.clip(d[np.isfinite(d)], edges[0], edges[-1]), edges, "tab:blue",
                      FILTER1_MM, f"{tx}{nm}", "change in range (mm)")
        files.append(_save(fig, out / f"fig3_07_range_change_{tx}.png", plt))
    return files


def _log_hist(ax, d: np.ndarray, bins, color: str, limit_mm: float, title: str,
              xlabel: str) -> None:
    """One panel: a log-count histogram of ``d`` (mm) with a filter's +-limit in red."""
    ax.hist(d, bins=bins, color=color)
    ax.set_yscale("log")
    for s in (-1, 1):
        ax.axvline(s * limit_mm, color="tab:red", lw=0.8)
    ax.set_title(title)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("count")


def plot_tx_difference(series: pd.DataFrame, names: list[str], out: Path) -> Path:
    """Histogram of the raw T20 - T21 range per receiver (20 bins), Filter 2's +-500 mm."""
    plt = _plt()
    fig, axes = _grid(plt, len(names), "Raw range difference T20 - T21 per receiver "
                      "(thesis Section 3.2.2); red: Filter 2 limit +-500 mm")
    for ax, nm in zip(axes, names, strict=True):
        d = (series[f"range_raw_front_{nm}"] - series[f"range_raw_rear_{nm}"]).to_numpy() * 1e3
        _log_hist(ax, d[np.isfinite(d)], 20, "tab:green", FILTER2_MM, f"T20{nm} - T21{nm}",
                  "difference (mm)")
    return _save(fig, out / "fig3_2_2_tx_difference.png", plt)


def plot_bias_quiver(pixels: pd.DataFrame, receivers_m: np.ndarray, out: Path,
                     labels: dict[str, str] | None = None) -> Path:
    """Appendix B "XY MSE and XY Error Biasing": per method, log10 contour of the x + y MSE
    per pixel (mm^2) and arrows of the per-pixel mean x/y error (mm; one common scale)."""
    plt = _plt()
    methods = list(dict.fromkeys(pixels["method"]))
    fig, axes = plt.subplots(1, len(methods), figsize=(4.2 * len(methods), 4.6),
                             constrained_layout=True, squeeze=False)
    scale = np.nanmax(np.hypot(pixels.mean_err_x_mm, pixels.mean_err_y_mm))
    for ax, m in zip(axes[0], methods, strict=True):
        d = pixels[pixels["method"] == m]
        g = {c: d.pivot(index="y_m", columns="x_m", values=c)
             for c in ("mse_x_mm2", "mse_y_mm2", "mean_err_x_mm", "mean_err_y_mm")}
        xy = g["mse_x_mm2"] + g["mse_y_mm2"]
        X, Y = np.meshgrid(xy.columns.to_numpy(), xy.index.to_numpy())
        cs = ax.contourf(X, Y, np.log10(xy.to_numpy()), levels=12, cmap="viridis")
        ax.quiver(X, Y, g["mean_err_x_mm"].to_numpy(), g["mean_err_y_mm"].to_numpy(),
                  angles="xy", scale=scale * 12, scale_units="width", color="white")
        ax.plot(receivers_m[:, 0], receivers_m[:, 1], "k.", ms=10)
        ax.set_title((labels or {}).get(m, m), fontsize=9)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.set_aspect("equal")
    fig.colorbar(cs, ax=axes[0].tolist(), shrink=0.8, label="log10 x+y MSE per pixel (mm$^2$)")
    fig.suptitle(f"XY MSE and XY error bias (Appendix B); longest arrow {scale:.1f} mm")
    return _save(fig, out / "appB_bias_quiver.png", plt)


def plot_mse_normalized(table: pd.DataFrame, out: Path) -> Path:
    """Appendix B's bar chart: total MSE of each method / the smallest (log scale)."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(8, 4.5), constrained_layout=True)
    y = table["mse_total_mm2"] / table["mse_total_mm2"].min()
    ax.bar(range(len(y)), y, color="tab:purple")
    ax.set_xticks(range(len(y)), [str(m)[:28] for m in table["method"]], rotation=20,
                  ha="right", fontsize=8)
    ax.set_yscale("log")
    for i, v in enumerate(y):
        ax.text(i, v, f"{v:.3g}", ha="center", va="bottom", fontsize=8)
    ax.set_ylabel("total MSE / smallest")
    ax.set_title("Comparison of normalised MSE for all methods (Appendix B)")
    return _save(fig, out / "appB_mse_normalized.png", plt)


def plot_range_errors(counts: pd.DataFrame, out: Path) -> Path:
    """Appendix B figure 1: histogram of the range errors per receiver, -30..30 mm."""
    plt = _plt()
    names = list(dict.fromkeys(counts["receiver"]))
    fig, axes = _grid(plt, len(names), "Histogram of simulated range errors per receiver "
                      "(Appendix B figure 1)")
    for ax, nm in zip(axes, names, strict=True):
        c = counts[(counts.receiver == nm) & np.isfinite(counts.lo_mm) & np.isfinite(counts.hi_mm)]
        ax.bar(c.lo_mm, c["count"], width=c.hi_mm - c.lo_mm, align="edge", color="tab:orange")
        tails = counts[(counts.receiver == nm)]["count"].sum() - c["count"].sum()
        ax.set_title(f"{nm} ({tails} beyond +-30 mm)")
        ax.set_xlim(ERROR_EDGES_MM[0], ERROR_EDGES_MM[-1])
        ax.set_xlabel("error (mm)")
        ax.set_ylabel("count")
    return _save(fig, out / "appB_range_error_hist.png", plt)


def plot_all(out: Path, names: list[str], receivers_m: np.ndarray,
             labels: dict[str, str] | None = None) -> list[Path]:
    """Every figure of this module from the tables saved in ``out``."""
    series = pd.read_csv(out / "flight_series.csv")
    files = plot_range_change(series, names, out)
    files.append(plot_tx_difference(series, names, out))
    files.append(plot_bias_quiver(pd.read_csv(out / "mc_pixels.csv"), receivers_m, out, labels))
    files.append(plot_mse_normalized(pd.read_csv(out / "mc_table.csv"), out))
    files.append(plot_range_errors(pd.read_csv(out / "mc_range_errors.csv"), out))
    return files
