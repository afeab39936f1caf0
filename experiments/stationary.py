"""Stationary analysis report: the GPS dissertation's Chapter 4.2-4.8 on any session.

``python -m experiments.stationary [--synthetic | --session PATH [PATH ...]] [--out DIR]
[--real-logs DIR]``, and ``python -m experiments.stationary --reference`` to regenerate the
committed reference ``results/stationary`` (synthetic session, seed 0, plus the real logs of
``../shared/realdata``). Other runs write to ``--out`` (default ``results/local/stationary``,
ignored by git) and never into ``results/stationary``.

Regenerates, for a :class:`sim.gps.StationarySession` (synthetic by default, or a saved
``.npz`` session, or NMEA / tumbleweed CSV logs, one per receiver):

- Fig 4.2  per-sensor x and y against time;           Fig 4.3 y-vs-x scatter per sensor;
- Figs 4.4-4.6  every pairwise distance against time with its configured value;
- Figs 4.7-4.8  normal probability plots of x and y;
- Figs 4.9-4.15 per sensor: series, ACF, ACF of AR(1) residuals (Eq. 2.2), with the
  +-1.96/sqrt(n) significance bounds the dissertation used (Section 4.3);
- Figs 4.17-4.24 the whole-recording estimate (Eq. 3.7; SLSQP, eps = 0.01 m) under each
  weighting scheme: none, Huber (Eq. 3.12), Huff (3.13), Huber with only sensors 1+5 and
  1+8 (Figs 4.20-4.21), Huff x Huber (3.14), deleted residuals (3.3.2), random;
- Figs 4.25-4.33 sliding-window estimates (closed-form procrustes per window, Section 3.4.1)
  for windows 1..10 with no weights, Huff without threshold and Huff with threshold 3.5,
  and the spread of the estimates per window size;

each scored against the true antenna positions when the session has them (synthetic; the
dissertation could not, Section 4.6). Per sensor and axis the std comes with robust
statistics (MAD, p95 of |deviation|) and the outliers that drive it (modified z-score > 3.5,
:mod:`estimator.noise_stats`), with std and AR(1) phi recomputed without them. Figures (PNG)
and ``summary.md`` / ``summary.json`` go to the output folder; tables are saved as CSV first
and the figures drawn from them and from the saved session, so re-plotting never
re-simulates. Like the dissertation (Section 4.1), data before the power failure are
discarded. Provenance (code version, command, paths, wall time) goes to ``run_info.json``
beside them, which git ignores, so a rerun of the reference leaves git clean.

Synthetic runs also write ``claims.md`` (with ``claims_seeds.csv`` / ``claims_variants.csv``):
the claims of Sections 4.3-4.8 judged over 20 seeds by the moving claims' rule, with a
``Cause:`` line for each claim not reproduced (:mod:`experiments.stationary_claims`;
``--no-claims`` skips it).

``--real-logs DIR`` additionally writes ``real_logs.md`` / ``real_logs.csv``: import counts
and per-axis statistics of every NMEA or tumbleweed CSV log found under DIR (recursive; any
folder layout), the evidence behind the default noise model.
"""

from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from estimator.configuration import SensorConfig
from estimator.noise_stats import acf, ar1_fit, noise_summary, tau_from_phi
from experiments.deferred import deferred_attributes
from experiments.markdown import markdown_table
from experiments.provenance import code_version
from experiments.stationary_analysis import (
    WINDOW_SCHEMES,
    Scored,
    weighting_estimates,
    window_estimates,
    window_spreads,
)
from sim.gps import GpsNoiseModel, StationarySession, synthesize_session

if TYPE_CHECKING:
    import pandas as pd

#: imported where used, not here, so that --help and argument errors answer before
#: pandas / numba / scipy / matplotlib load; still importable from this module
__getattr__ = deferred_attributes(__name__, {
    "pd": ("pandas", None),
    "figs": ("experiments.stationary_figures", None),
})

__all__ = ["REFERENCE_OUT", "WINDOW_SCHEMES", "analyse", "main", "real_log_tables", "sensor_table",
           "split_sensitivity", "weighting_estimates", "window_estimates", "window_spreads",
           "write_claims"]

REPO = Path(__file__).resolve().parents[1]
#: The committed reference; written only by ``--reference``.
REFERENCE_OUT = REPO / "results" / "stationary"
#: Default output of every other run (``results/local/`` is ignored by git).
DEFAULT_OUT = REPO / "results" / "local" / "stationary"
#: Real logs of the reference run, where CI has them.
REFERENCE_REAL_LOGS = REPO.parent / "shared" / "realdata"
#: Tables and summary.json keep 12 significant digits: far below any effect, and above the
#: last-bit differences of reductions (BLAS, summation order) that would otherwise make a
#: rerun of the reference differ in the 16th digit.
FLOAT_FORMAT = "%.12g"
#: Columns of the robust-statistics tables and their legend.
ROBUST_COLUMNS = ("std_m", "mad_sigma_m", "p95_m", "outliers", "std_inliers_m", "worst_m",
                  "worst_t_s", "ar1_phi", "ar1_phi_inliers")
ROBUST_LEGEND = (
    "mad_sigma_m = 1.4826 x median |x - median| (the std of a normal sample); p95_m = 95th "
    "percentile of |x - median|; outliers = samples with modified z-score "
    "0.6745 |x - median| / MAD > 3.5 (Iglewicz & Hoaglin); std_inliers_m and "
    "ar1_phi_inliers = std and AR(1) phi with them set missing; worst_m / worst_t_s = the "
    "largest |x - median| and when (s from the start). A std far above std_inliers, or a "
    "phi far from phi_inliers, is driven by the flagged samples.")


# --------------------------------------------------------------------------- estimates


def split_sensitivity(model: GpsNoiseModel, config: SensorConfig, duration_s: float, seed: int,
                      fractions: tuple[float, ...] = (0.0, 0.25, 0.5, 0.75, 0.9, 1.0),
                      windows: tuple[int, ...] = (1, 10)) -> pd.DataFrame:
    """Heading/CG accuracy of unweighted sliding windows against ``common_fraction``.

    For each fraction, a session from ``model.with_overrides(common_fraction=f)`` (same seed,
    so the same random draws feed a different split; data after the power failure) is fitted
    per window by procrustes. Columns: common_fraction, sigma_receiver_m, window,
    yaw_rmse_deg, cg_rmse_m, rmse_m. This is the parameter that decides whether heading is
    observable (../shared/notes/window-solvers.md).
    """
    import pandas as pd

    rows = []
    for f in fractions:
        m = model.with_overrides(common_fraction=f)
        s = synthesize_session(m, config, duration_s,
                               np.random.default_rng(seed)).after_power_failure()
        tab, _ = window_spreads(s, config, sizes=windows, schemes=("none",))
        for _, r in tab.iterrows():
            rows.append({"common_fraction": f, "sigma_receiver_m": m.sigma_receiver_m,
                         "window": int(r.window), "yaw_rmse_deg": r.yaw_rmse_deg,
                         "cg_rmse_m": r.cg_rmse_m, "rmse_m": r.rmse_m})
    return pd.DataFrame(rows)


# --------------------------------------------------------------------------- analysis
def _pairs(names: tuple[str, ...], alive: np.ndarray) -> list[tuple[int, int]]:
    idx = [j for j in range(len(names)) if alive[j]]
    return [(a, b) for k, a in enumerate(idx) for b in idx[k + 1:]]


def _axis_stats(v: np.ndarray, t: np.ndarray, dt: float) -> dict:
    """Spread, robust spread, outliers and AR(1) of one coordinate series (n,) on times t."""
    ns = noise_summary(v)
    return {"n": ns.n, "std_m": ns.std, "mad_sigma_m": ns.mad_sigma, "p95_m": ns.p95,
            "outliers": ns.outliers, "std_inliers_m": ns.std_inliers,
            "worst_m": ns.worst_abs_dev,
            "worst_t_s": float(t[ns.worst_index] - t[0]) if ns.worst_index >= 0 else math.nan,
            "npp_r": ns.npp_r, "ar1_phi": ns.ar1_phi, "ar1_phi_inliers": ns.ar1_phi_inliers,
            "tau_s": tau_from_phi(ns.ar1_phi, dt),
            "tau_inliers_s": tau_from_phi(ns.ar1_phi_inliers, dt)}


def sensor_table(session: StationarySession, nlags: int = 50) -> pd.DataFrame:
    """Per receiver and axis: std beside its robust counterparts (1.4826 MAD, p95 of
    |deviation|), the flagged outliers (modified z > 3.5) and std / AR(1) phi without them,
    NPP r, excess kurtosis, lag-1 ACF, AR(1) phi, sigma and correlation time, share of ACF
    lags 1..nlags outside +-1.96/sqrt(n) for the series and for its AR(1) residuals
    (Section 4.3), missing fraction."""
    import pandas as pd
    from scipy import stats

    dt = float(np.median(np.diff(session.t))) if session.n > 1 else 1.0
    lags = min(nlags, session.n - 1)
    rows = []
    for j, name in enumerate(session.names):
        x = session.obs[:, j]
        ok = np.isfinite(x[:, 0])
        if ok.sum() < 10:
            rows.append({"sensor": name, "missing": 1.0 - ok.mean()})
            continue
        for a, ax in enumerate("xy"):
            v = x[:, a]
            n = int(ok.sum())
            bound = 1.96 / math.sqrt(n)
            r = acf(v, lags)
            _, _, sw, res = ar1_fit(v)
            rr = acf(res, lags)
            rows.append({
                "sensor": name, "axis": ax, "n": n, "missing": float(1 - ok.mean()),
                **_axis_stats(v, session.t, dt),
                "excess_kurtosis": float(stats.kurtosis(v[ok])),
                "acf1": float(r[1]), "ar1_sigma_m": sw,
                "acf_outside": float((np.abs(r[1:]) > bound).mean()),
                "resid_acf_outside": float((np.abs(rr[1:]) > bound).mean()),
            })
    return pd.DataFrame(rows)


def pair_table(session: StationarySession, config: SensorConfig | None) -> pd.DataFrame:
    """Per pair of alive receivers: configured distance and observed distance statistics."""
    import pandas as pd

    alive = session.present.any(axis=0)
    D = config.distances() if config is not None else None
    rows = []
    for a, b in _pairs(session.names, alive):
        d = np.linalg.norm(session.obs[:, a] - session.obs[:, b], axis=-1)
        rows.append({"pair": f"{session.names[a]}-{session.names[b]}",
                     "configured_m": float(D[a, b]) if D is not None else math.nan,
                     "mean_m": float(np.nanmean(d)), "std_m": float(np.nanstd(d)),
                     "min_m": float(np.nanmin(d)), "max_m": float(np.nanmax(d)),
                     "mean_abs_dev_m": (float(np.nanmean(np.abs(d - D[a, b])))
                                        if D is not None else math.nan)})
    return pd.DataFrame(rows)


def analyse(session: StationarySession, config: SensorConfig | None, out: Path,
            rng: np.random.Generator, *, nlags: int = 100) -> dict:
    """Run every section, write CSV tables, figures and summary.md/json to ``out``."""
    import pandas as pd

    from experiments import stationary_figures as figs

    out.mkdir(parents=True, exist_ok=True)
    session.save(out / "session.npz")
    s_tab = sensor_table(session, nlags=50)
    s_tab.to_csv(out / "sensors.csv", index=False, float_format=FLOAT_FORMAT)
    match = config is not None and set(session.names) <= set(config.names) \
        and tuple(session.names) == tuple(config.names)
    # pairwise distances only mean something for co-located receivers of a known layout
    p_tab = pair_table(session, config) if match else pd.DataFrame()
    if match:
        p_tab.to_csv(out / "pairs.csv", index=False, float_format=FLOAT_FORMAT)
    w_est = win_tab = None
    if match:
        w_est = weighting_estimates(session, config, rng)
        pd.DataFrame([{"scheme": e.scheme, "status": e.status, "pos_rmse_m": e.pos_rmse_m,
                       "cg_err_m": e.cg_err_m, "yaw_err_deg": e.yaw_err_deg} for e in w_est]
                     ).to_csv(out / "weighting.csv", index=False, float_format=FLOAT_FORMAT)
        win_tab, win_est = window_spreads(session, config)
        win_tab.to_csv(out / "windows.csv", index=False, float_format=FLOAT_FORMAT)
    # figures (drawn from the saved session and tables)
    figs.plot_all(out, session, config if match else None, nlags=nlags,
                  weighting=w_est, windows=win_est if match else None)
    summary = _write_summary(out, session, config if match else None, s_tab, p_tab, w_est, win_tab)
    return summary


def _md(df: pd.DataFrame, floatfmt: str = ".3f") -> str:
    """The summaries' tables: floats with ``floatfmt``, NaN as "nan"."""
    return markdown_table(df, floatfmt=floatfmt, nan=None)


def _write_summary(out: Path, session: StationarySession, config: SensorConfig | None,
                   s_tab: pd.DataFrame, p_tab: pd.DataFrame, w_est: list[Scored] | None,
                   win_tab: pd.DataFrame | None) -> dict:
    import pandas as pd

    meta = session.meta
    lines = [f"# Stationary analysis ({meta.get('source', 'session')})", ""]
    span_s = session.t[-1] - session.t[0] + (session.t[1] - session.t[0] if session.n > 1 else 0)
    lines.append(f"Session: {session.n} samples "
                 f"({span_s:.0f} s), "
                 f"{session.m} receivers {list(session.names)}, dead {list(session.dead)}, "
                 f"missing {1 - session.present.mean():.1%} of all samples, "
                 f"alignment {meta.get('alignment')!r}.")
    if meta.get("model"):
        mdl = meta["model"]
        lines.append(f"Noise model `{mdl.get('name')}`: sigma_m {mdl['sigma_m']} m, "
                     f"common_fraction {mdl['common_fraction']}, "
                     f"taus {mdl['common_tau_s']} / {mdl['receiver_tau_s']} s, "
                     f"seed {meta.get('seed')}. Data before the power failure "
                     f"({meta.get('power_failure_s')}) discarded, as in Section 4.1.")
    if meta.get("skipped"):
        nz = {k: v for k, v in meta["skipped"].items() if v}
        lines.append(f"Import skips: {nz}.")
    lines += ["", "## Per sensor (Figs 4.2, 4.3, 4.7-4.15)", "",
              ("std: per-axis standard deviation; npp_r: normal-probability-plot correlation (1 = "
               "normal); tau_s: correlation time implied by the AR(1) phi (Eq. 2.2); acf_outside / "
               f"resid_acf_outside: share of lags 1-{min(50, session.n - 1)} whose ACF exceeds "
               "+-1.96/sqrt(n) for the "
               "coordinates / the AR(1) residuals (the dissertation found both mostly outside)."),
              ""]
    cols = [c for c in ["sensor", "axis", "missing", "std_m", "npp_r", "excess_kurtosis", "ar1_phi",
                        "tau_s", "acf_outside", "resid_acf_outside"] if c in s_tab.columns]
    per_axis = s_tab.dropna(subset=["axis"]) if "axis" in s_tab else s_tab
    per_axis = per_axis.astype({c: int for c in ("n", "outliers") if c in per_axis})
    lines.append(_md(per_axis[cols]))
    rob = [c for c in ROBUST_COLUMNS if c in per_axis.columns]
    if len(rob) > 2:
        lines += ["", "Robust spread and outliers: " + ROBUST_LEGEND, ""]
        lines.append(_md(per_axis[["sensor", "axis", *rob]]))
    if len(p_tab):
        lines += ["", "## Pairwise distances (Figs 4.4-4.6)", ""]
        lines.append(_md(p_tab))
    if w_est is not None:
        lines += ["", "## Whole-recording estimate per weighting scheme (Figs 4.17-4.24)", "",
                  ("Eq. 3.7 by SLSQP (eps = 0.01 m); `means` is the per-sensor mean without the "
                   "configuration. Scores against the true antenna positions: RMS position error "
                   "over alive sensors, CG error (Eq. 3.8 members), heading error."), ""]
        lines.append(_md(pd.DataFrame([{"scheme": e.scheme, "status": e.status,
                                        "pos_rmse_m": e.pos_rmse_m, "cg_err_m": e.cg_err_m,
                                        "yaw_err_deg": e.yaw_err_deg} for e in w_est])))
    if win_tab is not None:
        lines += ["", "## Sliding windows (Figs 4.25-4.33)", "",
                  ("Closed-form procrustes per window. spread_m: RMS distance of the window "
                   "estimates from their own mean (the cluster size the dissertation compared); "
                   "rmse_m / cg_rmse_m / yaw_rmse_deg: against the truth."), ""]
        lines.append(_md(win_tab))
    reading = _reading(session, s_tab, w_est, win_tab)
    if reading:
        lines += (["", "## Reading (computed from the tables above)", ""]
                  + [f"- {r}" for r in reading])
    lines += ["", "## Figures", ""]
    for p in sorted(out.glob("*.png")):
        lines.append(f"- [{p.name}]({p.name})")
    (out / "summary.md").write_text("\n".join(lines) + "\n")
    summary = {"n": session.n, "m": session.m,
               "names": list(session.names), "meta": meta,
               "sensors": s_tab.to_dict(orient="records"), "pairs": p_tab.to_dict(orient="records"),
               "weighting": None if w_est is None else [
                   {"scheme": e.scheme, "status": e.status, "pos_rmse_m": e.pos_rmse_m,
                    "cg_err_m": e.cg_err_m, "yaw_err_deg": e.yaw_err_deg} for e in w_est],
               "windows": None if win_tab is None else win_tab.to_dict(orient="records")}
    (out / "summary.json").write_text(json.dumps(_rounded(summary), indent=1,
                                                 default=_json_default) + "\n")
    return summary


def _reading(session: StationarySession, s_tab: pd.DataFrame, w_est: list[Scored] | None,
             win_tab: pd.DataFrame | None) -> list[str]:
    """Plain statements derived from the tables (no hand-written numbers)."""
    out = []
    if "axis" in s_tab:
        t = s_tab.dropna(subset=["axis"])
        if len(t):
            out.append(f"Per-axis std {t.std_m.min():.2f}-{t.std_m.max():.2f} m; NPP r "
                       f"{t.npp_r.min():.3f}-{t.npp_r.max():.3f} (1 = normal); "
                       f"ACF beyond the bounds "
                       f"at {t.acf_outside.min():.0%}-{t.acf_outside.max():.0%} "
                       f"of lags 1-{min(50, session.n - 1)}, AR(1) "
                       f"residual ACF at "
                       f"{t.resid_acf_outside.min():.0%}-{t.resid_acf_outside.max():.0%} "
                       f"(Section 4.3 reports both mostly beyond).")
            for r in _outlier_driven(t).itertuples():
                out.append(f"Sensor {r.sensor} {r.axis}: {_driven_text(r)}.")
            for r in _heavy(t).itertuples():
                out.append(f"Sensor {r.sensor} {r.axis}: {r.outliers / r.n:.0%} of the samples "
                           f"beyond the outlier cut-off (heavy tails or plateaus, not a few "
                           f"outliers).")
    if w_est is not None and session.truth_positions is not None:
        fits = [e for e in w_est if e.scheme != "means" and np.isfinite(e.pos_rmse_m)]
        best = min(fits, key=lambda e: e.pos_rmse_m)
        none = next(e for e in fits if e.scheme == "none")
        means = next(e for e in w_est if e.scheme == "means")
        out.append(f"Whole recording: the configuration fit (none) has "
                   f"{none.pos_rmse_m:.2f} m RMS "
                   f"position error vs {means.pos_rmse_m:.2f} m for the per-sensor means; "
                   f"best scheme "
                   f"{best.scheme!r} at {best.pos_rmse_m:.2f} m; "
                   f"CG error of the fit {none.cg_err_m:.2f} m "
                   f"(the common-mode error averaged over the session cannot be removed).")
    if win_tab is not None and len(win_tab):
        for sch in win_tab.scheme.unique():
            w = win_tab[win_tab.scheme == sch].set_index("window")
            lo, hi = w.index.min(), w.index.max()
            msg = (f"Windows {sch}: spread {w.spread_m[lo]:.2f} m at window {lo} -> "
                   f"{w.spread_m[hi]:.2f} m at {hi} ({w.spread_m[hi] / w.spread_m[lo] - 1:+.1%})")
            if np.isfinite(w.yaw_rmse_deg[lo]):
                msg += f"; heading RMS {w.yaw_rmse_deg[lo]:.0f} -> {w.yaw_rmse_deg[hi]:.0f} deg"
            out.append(msg + ".")
    return out


def _rounded(o: object) -> object:
    """Floats (also in nested dicts / lists / numpy scalars) to FLOAT_FORMAT's 12 digits."""
    if isinstance(o, dict):
        return {k: _rounded(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_rounded(v) for v in o]
    if isinstance(o, (float, np.floating)):
        v = float(o)
        return float(FLOAT_FORMAT % v) if math.isfinite(v) else v
    if isinstance(o, np.integer):
        return int(o)
    return o


def _json_default(o: object) -> object:
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


#: When a statistic counts as driven by the flagged outliers (a reporting cut, stated in the
#: reports): the flagged samples are a small minority (at most 5 % of the series; a normal
#: sample has 0.05 % beyond the cut-off) and leaving them out moves the std by more than a
#: sixth (std > 1.2 x std without them) or AR(1) phi by more than 0.1. More than 5 % beyond
#: the cut-off is not a few outliers but a heavy-tailed or multimodal series (plateaus),
#: listed separately.
OUTLIER_SHARE_MAX = 0.05
DRIVEN_RULE = ("Series where at most 5 % of the samples are flagged and leaving them out "
               "moves the std by more than a sixth (std > 1.2 std_inliers) or the AR(1) phi "
               "by more than 0.1")
HEAVY_RULE = ("Series with more than 5 % of the samples beyond the cut-off (a normal sample "
              "has 0.05 %): heavy tails or plateaus, where the robust and the classical "
              "spread describe different things")


def _outlier_driven(tab: pd.DataFrame) -> pd.DataFrame:
    """Rows (series) whose std or AR(1) phi is driven by a few flagged outliers (DRIVEN_RULE)."""
    if "outliers" not in tab or not len(tab):
        return tab.iloc[:0]
    few = (tab.outliers > 0) & (tab.outliers <= OUTLIER_SHARE_MAX * tab.n)
    return tab[few & ((tab.std_m > 1.2 * tab.std_inliers_m)
                      | ((tab.ar1_phi - tab.ar1_phi_inliers).abs() > 0.1))]


def _heavy(tab: pd.DataFrame) -> pd.DataFrame:
    """Rows with more than OUTLIER_SHARE_MAX of their samples flagged (HEAVY_RULE)."""
    if "outliers" not in tab or not len(tab):
        return tab.iloc[:0]
    return tab[tab.outliers > OUTLIER_SHARE_MAX * tab.n]


def _driven_text(r) -> str:
    return (f"std {r.std_m:.2f} m -> {r.std_inliers_m:.2f} m and AR(1) phi {r.ar1_phi:.2f} -> "
            f"{r.ar1_phi_inliers:.2f} without {int(r.outliers)} flagged sample(s); the worst is "
            f"{r.worst_m:.1f} m from the median at t = {r.worst_t_s:.0f} s")


# --------------------------------------------------------------------------- real logs
def real_log_tables(root: Path) -> tuple[pd.DataFrame, pd.DataFrame, list[str]]:
    """Every NMEA / tumbleweed CSV log under ``root`` (recursive, any layout; see
    :func:`sim.nmea.find_logs`), each imported alone and gridded at its own rate.

    Returns ``(imports, stats, other)``: ``imports`` one row per log (format, time base,
    fixes, grid epochs, duration, missing share, reacquisition fixes dropped, an error if
    it could not be gridded, and one column per skip class); ``stats`` one row per log and
    axis (east, north in the local UTM frame) with the columns of :data:`ROBUST_COLUMNS`
    and the AR(1) correlation times; ``other`` the files under root that are not logs
    (relative paths).
    """
    import pandas as pd

    from sim.nmea import SKIP_CLASSES, find_logs, read_log, session_from_fixes

    logs, other = find_logs(root)
    imports, stats = [], []
    for f in logs:
        rel = f.relative_to(root).as_posix()
        row: dict = {"log": rel, "format": None, "time_base": None, "fixes": 0, "epochs": 0,
                     "duration_s": math.nan, "missing": math.nan, "reacquired": 0, "error": ""}
        try:
            fx = read_log(f)
        except ValueError as exc:
            imports.append({**row, "error": str(exc).replace(str(f), rel)})
            continue
        row.update({"format": fx.meta.get("format"), "time_base": fx.meta.get("time_base"),
                    "fixes": int(fx.valid.sum()), "reacquired": fx.skipped["reacquisition"],
                    **{c: fx.skipped[c] for c in SKIP_CLASSES}})
        try:
            s = session_from_fixes([fx])
        except ValueError as exc:
            # first clause only, and no machine path in a table that may be committed
            imports.append({**row, "error": str(exc).split(";")[0].replace(str(f), rel)})
            continue
        dt = 1.0 / s.meta["rate_hz"]
        row.update({"epochs": s.n, "duration_s": float(s.t[-1] - s.t[0] + dt),
                    "missing": float(1 - s.present.mean()),
                    "off_grid": s.meta["skipped"]["off_grid"],
                    "duplicate_epochs": s.meta["skipped"]["duplicate_epochs"]})
        imports.append(row)
        for a, ax in enumerate(("east", "north")):
            stats.append({"log": rel, "axis": ax, **_axis_stats(s.obs[:, 0, a], s.t, dt)})
    imp = pd.DataFrame(imports)
    for c in SKIP_CLASSES:
        imp[c] = imp[c].fillna(0).astype(int) if c in imp else 0
    return imp, pd.DataFrame(stats), [p.relative_to(root).as_posix() for p in other]


def _real_logs_md(label: str, imp: pd.DataFrame, st: pd.DataFrame, other: list[str]) -> str:
    """real_logs.md from the tables of :func:`real_log_tables`."""
    import pandas as pd

    from sim.nmea import SKIP_CLASSES

    def skips(r: pd.Series) -> str:
        return ", ".join(f"{c} {int(r[c])}" for c in SKIP_CLASSES
                         if r[c] and c not in ("other_sentences", "reacquisition"))

    cols = ["log", "format", "time_base", "fixes", "epochs", "duration_s", "missing",
            "reacquired"]
    show = imp[cols].copy()
    show["skipped / error"] = [r["error"] or skips(r) for _, r in imp.iterrows()]
    totals = pd.DataFrame({"class": list(SKIP_CLASSES),
                           "count": [int(imp[c].sum()) for c in SKIP_CLASSES],
                           "logs": [int((imp[c] > 0).sum()) for c in SKIP_CLASSES]})
    text = [f"# Real receiver logs under `{label}`, imported with sim.nmea", "",
            (f"{len(imp)} logs (NMEA or tumbleweed CSV, found recursively), each imported alone "
             "and gridded at its own median fix interval from its first to its last fix; "
             "reacquisition transients dropped (`reacquired`); `missing` = grid epochs without "
             "a fix. Skip classes: `sim/nmea.py` module docstring."), "",
            "## Import", "", _md(show, ".2f"), "",
            "## Skip classes over all logs", "",
            "`count` summed over the logs, `logs` = how many logs have the class.", "",
            _md(totals), "",
            "## Spread, robust spread and outliers per axis", "",
            ("East / north in the log's local UTM frame, metres. " + ROBUST_LEGEND + " tau_s = "
             "AR(1) correlation time -dt / ln(phi) (short logs bias it low and cannot show "
             "slower components)."), "",
            _md(st[["log", "axis", "n", *ROBUST_COLUMNS, "tau_s", "tau_inliers_s"]], ".2f")]
    text += ["", "## Statistics driven by outliers", "", DRIVEN_RULE + ":", ""]
    text += [f"- {r.log} {r.axis}: {_driven_text(r)}" for r in _outlier_driven(st).itertuples()] \
        or ["- none"]
    text += ["", "## Heavy tails and plateaus", "", HEAVY_RULE + ":", ""]
    text += [f"- {r.log} {r.axis}: {int(r.outliers)} of {int(r.n)} samples "
             f"({r.outliers / r.n:.0%}); std {r.std_m:.2f} m, 1.4826 MAD {r.mad_sigma_m:.2f} m, "
             f"p95 {r.p95_m:.2f} m" for r in _heavy(st).itertuples()] or ["- none"]
    if other:
        text += ["", f"## Other files under `{label}` (not NMEA or tumbleweed CSV): {len(other)}",
                 "", ", ".join(f"`{o}`" for o in other)]
    return "\n".join(text) + "\n"


# --------------------------------------------------------------------------- claims
def write_claims(out: Path, model: GpsNoiseModel, config: SensorConfig, duration_s: float,
                 real_logs: Path | None) -> list:
    """claims.md, claims_seeds.csv and claims_variants.csv (:mod:`experiments.stationary_claims`)
    and a verdict table appended to summary.md. Returns the claim results."""
    import pandas as pd

    from experiments import stationary_claims as sc

    cells = sc.seed_table(model, config, duration_s)
    cells.to_csv(out / "claims_seeds.csv", index=False, float_format=FLOAT_FORMAT)
    variants = {k: sc.seed_table(model.with_overrides(**v), config, duration_s, sc.VARIANT_SEEDS)
                for k, v in sc.VARIANTS.items()}
    pd.concat([v.assign(variant=k) for k, v in variants.items()]).to_csv(
        out / "claims_variants.csv", index=False, float_format=FLOAT_FORMAT)
    real = sc.real_log_shares(real_logs) if real_logs is not None else None
    results = sc.evaluate(cells)
    causes = sc.cause_lines(results, cells, variants, real)
    (out / "claims.md").write_text(sc.claims_markdown(results, causes, len(sc.SEEDS), model.name))
    with open(out / "summary.md", "a") as fh:
        fh.write("\n## Claims of Sections 4.3-4.8 ([claims.md](claims.md))\n\n"
                 f"Judged over {len(sc.SEEDS)} seeds by the moving claims' rule; causes for "
                 "every claim not reproduced in claims.md.\n\n| claim | verdict | text |\n"
                 "|---|---|---|\n" + "".join(f"| {r.claim.cid} | {r.verdict} | {r.claim.text} |\n"
                                               for r in results))
    return results


# --------------------------------------------------------------------------- CLI
class SessionFileError(ValueError):
    """A ``--session`` file that is missing or is not a session: the message names it."""


def load_session(paths: list[str]) -> StationarySession:
    """A saved ``.npz`` session, or NMEA / CSV logs (one per receiver) via sim.nmea.

    Raises :class:`SessionFileError` (one line naming the file and what is wrong) for a
    missing file, a folder, an ``.npz`` that is not a saved session (random bytes, other
    arrays) and a log without a usable fix (a README, random bytes, a foreign CSV)."""
    for p in paths:
        if not Path(p).is_file():
            why = "a folder, not a file" if Path(p).is_dir() else "no such file"
            raise SessionFileError(f"--session {p}: {why}")
    if len(paths) == 1 and paths[0].endswith(".npz"):
        return _load_npz(paths[0])
    from sim.nmea import import_session

    try:
        return import_session(paths)
    except (ValueError, OSError) as exc:       # OSError: e.g. unreadable (permissions)
        raise SessionFileError(f"--session {' '.join(paths)}: {_short(exc)}") from exc


def _load_npz(path: str) -> StationarySession:
    """A session saved by ``StationarySession.save``; anything else is a SessionFileError."""
    import zipfile

    try:
        return StationarySession.load(path)
    except (ValueError, OSError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        raise SessionFileError(f"--session {path}: not a session saved by "
                               f"StationarySession.save ({_short(exc)})") from exc


def _short(exc: BaseException, limit: int = 300) -> str:
    """``exc``'s message on one line, at most ``limit`` characters."""
    text = " ".join(str(exc).strip("'\"").split()) or type(exc).__name__
    return text if len(text) <= limit else text[:limit - 3] + "..."


def _rel(p: Path) -> str:
    """``p`` relative to the repository when inside it (for messages)."""
    try:
        return str(p.resolve().relative_to(REPO))
    except ValueError:
        return str(p)


def main(argv: list[str] | None = None) -> int:
    raw = sys.argv[1:] if argv is None else list(argv)
    from experiments.cli import ArgumentParser, positive_float, seed_arg

    ap = ArgumentParser(prog="python -m experiments.stationary",
                        description=__doc__.split("\n\n")[0])
    ap.add_argument("--reference", action="store_true",
                    help=f"regenerate the committed reference {_rel(REFERENCE_OUT)}: the synthetic "
                         "session with every default below and the real logs of "
                         "../shared/realdata; takes no other option")
    src = ap.add_mutually_exclusive_group()
    src.add_argument("--synthetic", action="store_true", help="synthetic session (default)")
    src.add_argument("--session", nargs="+", metavar="PATH",
                     help="a saved session .npz, or NMEA/CSV logs (one per receiver)")
    ap.add_argument("--model", default="gps_stationary", help="noise model name or TOML path")
    ap.add_argument("--config", default="rover_gps8", help="sensor configuration name or TOML path")
    ap.add_argument("--duration", type=positive_float, default=4300.0,
                    help="synthetic session length in s, before discarding the power failure")
    ap.add_argument("--seed", type=seed_arg, default=0)
    ap.add_argument("--out", type=Path, default=None,
                    help=f"output folder (default {_rel(DEFAULT_OUT)}, ignored by git; "
                         f"{_rel(REFERENCE_OUT)} only through --reference)")
    ap.add_argument("--keep-before-power-failure", action="store_true",
                    help="analyse the whole recording "
                         "(default: discard up to the power failure's end)")
    ap.add_argument("--no-split", action="store_true",
                    help="skip the common_fraction sensitivity table (synthetic sessions only)")
    ap.add_argument("--no-claims", action="store_true",
                    help="skip claims.md, the Sections 4.3-4.8 claims judged over 20 seeds and "
                         "their model variants (synthetic sessions only)")
    ap.add_argument("--real-logs", type=Path, metavar="DIR",
                    help="also write real_logs.md / real_logs.csv: every NMEA or tumbleweed CSV "
                         "log found under DIR (recursive, any layout)")
    args = ap.parse_args(raw)
    if args.reference:
        if len([a for a in raw if a != "--debug"]) > 1:
            ap.error("--reference takes no other option (it regenerates the committed "
                     "reference exactly); write custom runs with --out")
        if not REFERENCE_REAL_LOGS.is_dir():
            ap.error(f"--reference needs the real logs at {REFERENCE_REAL_LOGS} "
                     f"(../shared/realdata beside the checkout)")
        out, real_logs, label = REFERENCE_OUT, REFERENCE_REAL_LOGS, "../shared/realdata"
    else:
        out = args.out if args.out is not None else DEFAULT_OUT
        ref = REFERENCE_OUT.resolve()
        if out.resolve() == ref or ref in out.resolve().parents:
            ap.error(f"--out {args.out}: {_rel(REFERENCE_OUT)} is the committed reference; "
                     "regenerate it with --reference, write other runs elsewhere")
        real_logs, label = args.real_logs, str(args.real_logs)
    if real_logs is not None:
        from sim.nmea import find_logs

        if not real_logs.is_dir():
            ap.error(f"--real-logs {real_logs}: not a folder")
        if not find_logs(real_logs)[0]:
            ap.error(f"--real-logs {real_logs}: no NMEA or tumbleweed CSV log found (recursive)")
    t_start = time.time()
    rng = np.random.default_rng(args.seed)
    config = SensorConfig.load(args.config)
    if args.session:
        print(f"importing {len(args.session)} file(s)", flush=True)
        session = load_session(args.session)
    else:
        print(f"synthesizing a {args.duration:g} s session ({args.model}, seed {args.seed})",
              flush=True)
        model = GpsNoiseModel.load(args.model)
        session = synthesize_session(model, config, args.duration, rng)
        session.meta["seed"] = args.seed
    if not args.keep_before_power_failure:
        session = session.after_power_failure()
    match = tuple(session.names) == tuple(config.names)
    if not match:
        print(f"receivers {list(session.names)} do not match configuration {config.name!r} "
              f"{list(config.names)}: configuration sections (distances, fits) skipped",
              file=sys.stderr)
    print("statistics, fits and figures", flush=True)
    analyse(session, config if match else None, out, rng)
    if not args.session and not args.no_split:
        print("common-mode split sensitivity", flush=True)
        split = split_sensitivity(GpsNoiseModel.load(args.model), config, args.duration, args.seed)
        split.to_csv(out / "split.csv", index=False, float_format=FLOAT_FORMAT)
        with open(out / "summary.md", "a") as fh:
            fh.write("\n## Common-mode share vs heading (model sweep, same seed)\n\n"
                     "Unweighted sliding windows, procrustes, scored against the truth; "
                     "`common_fraction` overridden on the model above, total sigma fixed.\n\n"
                     + _md(split) + "\n")
    if not args.session and not args.no_claims:
        print("stationary claims over seeds and model variants", flush=True)
        write_claims(out, GpsNoiseModel.load(args.model), config, args.duration, real_logs)
    if real_logs is not None:
        print(f"real logs under {label}", flush=True)
        imp, st, other = real_log_tables(real_logs)
        imp.to_csv(out / "real_logs.csv", index=False, float_format=FLOAT_FORMAT)
        st.to_csv(out / "real_logs_stats.csv", index=False, float_format=FLOAT_FORMAT)
        (out / "real_logs.md").write_text(_real_logs_md(label, imp, st, other))
    # provenance: machine paths and wall time stay out of the tracked files
    info = {"code": code_version(), "argv": raw, "out": str(out.resolve()),
            "real_logs": None if real_logs is None else str(real_logs.resolve()),
            "started_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(t_start)),
            "wall_s": round(time.time() - t_start, 1)}
    (out / "run_info.json").write_text(json.dumps(info, indent=1) + "\n")
    print(f"wrote {_rel(out)}/summary.md ({info['wall_s']:.0f} s)")
    return 0


if __name__ == "__main__":
    from experiments.cli import run as run_cli

    run_cli(main)
