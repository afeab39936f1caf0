"""Stationary analysis report: the GPS dissertation's Chapter 4.2-4.8 on any session.

``python -m experiments.stationary [--synthetic | --session PATH [PATH ...]] [--out DIR]``

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
dissertation could not, Section 4.6). Figures (PNG) and ``summary.md`` / ``summary.json``
go to ``--out`` (default ``results/stationary``); tables are saved as CSV first and the
figures drawn from them and from the saved session, so re-plotting never re-simulates.
Like the dissertation (Section 4.1), data before the power failure are discarded.

``--real-logs DIR`` additionally writes ``real_logs.md``: per-log statistics of every real
receiver log under DIR (e.g. ../shared/realdata), the evidence behind the default noise model.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from estimator.configuration import SensorConfig
from estimator.orientation import wrap_angle
from estimator.weights import (
    deleted_residual_mask,
    huber_weights,
    huff_huber_weights,
    huff_weights,
    random_weights,
)
from estimator.window import fit_stationary, procrustes_batch, window_means
from experiments.provenance import git_describe
from sim.gps import GpsNoiseModel, StationarySession, synthesize_session

__all__ = [
    "acf",
    "analyse",
    "ar1_fit",
    "main",
    "npp_r",
    "real_log_table",
    "weighting_estimates",
    "window_spreads",
]

REPO = Path(__file__).resolve().parents[1]
DEFAULT_OUT = REPO / "results" / "stationary"
WINDOW_SCHEMES = ("none", "huff", "huff3.5")


# --------------------------------------------------------------------------- statistics
def acf(x: np.ndarray, nlags: int) -> np.ndarray:
    """Sample autocorrelation r_0..r_nlags of a series with NaN = missing.

    ``r_k = sum_t d_t d_{t+k} / sum_t d_t^2`` with ``d = x - mean(x)`` over present samples
    and products only where both samples are present (Box-Jenkins estimator; for a series
    without gaps it equals statsmodels ``acf(x, adjusted=False)``). x (n,) -> (nlags+1,).
    """
    x = np.asarray(x, dtype=float)
    ok = np.isfinite(x)
    if ok.sum() < 2:
        return np.full(nlags + 1, np.nan)
    d = np.where(ok, x - x[ok].mean(), 0.0)
    den = float((d * d).sum())
    if den == 0.0:
        return np.full(nlags + 1, np.nan)
    n = x.size
    nl = min(nlags, n - 1)
    # all lags at once via FFT of the zero-filled deviations (missing contribute 0)
    nfft = 1 << math.ceil(math.log2(2 * n))
    f = np.fft.rfft(d, nfft)
    r = np.fft.irfft(f * np.conj(f), nfft)[: nl + 1] / den
    out = np.full(nlags + 1, np.nan)
    out[: nl + 1] = r
    return out


def ar1_fit(x: np.ndarray) -> tuple[float, float, float, np.ndarray]:
    """AR(1) of Eq. 2.2, x_t = delta + phi x_{t-1} + w_t, by least squares on present pairs.

    Returns ``(delta, phi, sigma_w, residuals (n,))`` with residuals NaN where x_t or
    x_{t-1} is missing (and at t = 0). Equals statsmodels ``AutoReg(x, 1, trend="c")``
    (conditional least squares) for a series without gaps.
    """
    x = np.asarray(x, dtype=float)
    prev, cur = x[:-1], x[1:]
    ok = np.isfinite(prev) & np.isfinite(cur)
    res = np.full(x.shape, np.nan)
    if ok.sum() < 3:
        return math.nan, math.nan, math.nan, res
    A = np.column_stack([np.ones(ok.sum()), prev[ok]])
    (delta, phi), *_ = np.linalg.lstsq(A, cur[ok], rcond=None)
    r = cur[ok] - (delta + phi * prev[ok])
    res[1:][ok] = r
    sigma = float(np.sqrt((r * r).sum() / max(ok.sum() - 2, 1)))
    return float(delta), float(phi), sigma, res


def npp_r(x: np.ndarray) -> float:
    """Correlation coefficient of the normal probability plot (scipy.stats.probplot's r);
    1 for a perfect normal sample (Figs 4.7-4.8)."""
    from scipy import stats

    v = np.asarray(x, dtype=float)
    v = v[np.isfinite(v)]
    if v.size < 3 or np.ptp(v) == 0:
        return math.nan
    (_, _), (_, _, r) = stats.probplot(v, dist="norm")
    return float(r)


# --------------------------------------------------------------------------- estimates
@dataclass
class Scored:
    """One estimate of the antenna positions and its score against the truth (if known)."""

    scheme: str
    positions: np.ndarray          # (m, 2)
    status: str
    pos_rmse_m: float              # RMS over alive sensors of |p_i - truth_i|
    cg_err_m: float
    yaw_err_deg: float


def _score(positions: np.ndarray, truth: np.ndarray | None, config: SensorConfig,
           alive: np.ndarray) -> tuple[float, float, float]:
    if truth is None or not np.isfinite(positions[alive]).all():
        return math.nan, math.nan, math.nan
    e = np.linalg.norm(positions[alive] - truth[alive], axis=-1)
    cg = config.cg_from_positions(positions) - config.cg_from_positions(truth)
    yaw = procrustes_batch(np.stack([positions, truth]), np.tile(alive.astype(float), (2, 1)),
                           config).yaw
    return (float(np.sqrt((e * e).mean())), float(np.linalg.norm(cg)),
            float(np.degrees(abs(wrap_angle(yaw[0] - yaw[1])))))


def weighting_estimates(session: StationarySession, config: SensorConfig,
                        rng: np.random.Generator, *, eps: float = 0.01,
                        solver: str = "slsqp") -> list[Scored]:
    """Whole-recording estimate (Eq. 3.7) under each weighting scheme of Section 4.6.

    Schemes: "means" (per-sensor means, no configuration: the baseline), "none" (4.17),
    "huber" (4.18), "huff" (4.19, no threshold), "huber_1_5" / "huber_1_8" (4.20 / 4.21:
    only those two sensors' data), "huff_x_huber" (4.22), "deleted_residuals" (4.23),
    "random" (control). obs (n, m, 2) are the session's; weights per estimator.weights.
    """
    obs = session.obs
    truth = session.truth_positions
    alive = session.present.any(axis=0)
    out: list[Scored] = []
    means = np.nanmean(np.where(alive[None, :, None], obs, 0.0), axis=0)
    means[~alive] = np.nan
    out.append(Scored("means", means, "ok", *_score(means, truth, config, alive)))

    def only(names: tuple[str, ...]) -> np.ndarray:
        o = obs.copy()
        keep = np.array([n in names for n in session.names])
        o[:, ~keep] = np.nan
        return o

    schemes = {
        "none": (obs, None),
        "huber": (obs, huber_weights(obs)),
        "huff": (obs, huff_weights(obs, config)),
        "huber_1_5": (only(("1", "5")), huber_weights(only(("1", "5")))),
        "huber_1_8": (only(("1", "8")), huber_weights(only(("1", "8")))),
        "huff_x_huber": (obs, huff_huber_weights(obs, config)),
        "deleted_residuals": (obs, deleted_residual_mask(obs).astype(float)),
        "random": (obs, random_weights(obs.shape[:2], rng)),
    }
    for name, (o, w) in schemes.items():
        if name.startswith("huber_1") and not {"1", "5", "8"} <= set(session.names):
            continue
        fit = fit_stationary(o, config, weights=w, eps=eps, solver=solver)
        out.append(Scored(name, fit.positions, fit.status, *_score(fit.positions, truth, config, alive)))
    return out


def _window_weights(scheme: str, win: np.ndarray, config: SensorConfig) -> np.ndarray | None:
    if scheme == "none":
        return None
    if scheme == "huff":
        return huff_weights(win, config)
    if scheme == "huff3.5":
        return huff_weights(win, config, threshold=3.5)
    raise ValueError(f"scheme: unknown {scheme!r}; choose one of {list(WINDOW_SCHEMES)}")


def window_estimates(obs: np.ndarray, config: SensorConfig, s: int, scheme: str) -> tuple[np.ndarray, np.ndarray]:
    """Sliding-window estimates (Section 3.4.1): window k holds samples k-s+1..k, k >= s-1.

    Closed-form procrustes per window on the weighted window means (exact distances; the
    eps slack changes positions by about 1.3 eps, ../shared/notes/window-solvers.md).
    Returns positions (n-s+1, m, 2) (NaN where a window has insufficient data) and the
    status array.
    """
    win = np.lib.stride_tricks.sliding_window_view(obs, s, axis=0)   # (N, m, 2, s)
    win = np.moveaxis(win, -1, 1)                                    # (N, s, m, 2)
    w = _window_weights(scheme, win, config)
    means, sw = window_means(win, w)
    fit = procrustes_batch(means, sw, config)
    return fit.positions, fit.status


def window_spreads(session: StationarySession, config: SensorConfig,
                   sizes: tuple[int, ...] = tuple(range(1, 11)),
                   schemes: tuple[str, ...] = WINDOW_SCHEMES) -> tuple[pd.DataFrame, dict]:
    """Spread and accuracy of sliding-window estimates per window size and scheme.

    Per row: ``spread_m`` = RMS over alive sensors and windows of the distance of each
    window estimate from that sensor's mean estimate (the "cluster" of Figs 4.25-4.33);
    ``rmse_m`` = RMS distance from the true position (NaN without truth); ``cg_rmse_m``,
    ``yaw_rmse_deg`` (wrapped), ``insufficient`` = fraction of windows without a fit.
    Also returns the estimates {(scheme, s): positions} for the figures.
    """
    alive = session.present.any(axis=0)
    truth = session.truth_positions
    rows, est = [], {}
    if truth is not None:
        yaw_true = float(procrustes_batch(truth[None], alive[None].astype(float), config).yaw[0])
        cg_true = config.cg_from_positions(truth)
    for scheme in schemes:
        for s in sizes:
            pos, status = window_estimates(session.obs, config, s, scheme)
            est[(scheme, s)] = pos
            ok = status == "ok"
            p = pos[ok][:, alive]
            centre = p.mean(axis=0)
            spread = float(np.sqrt(((p - centre) ** 2).sum(-1).mean()))
            row = {"scheme": scheme, "window": s, "estimates": int(ok.sum()),
                   "insufficient": float(1 - ok.mean()), "spread_m": spread,
                   "rmse_m": math.nan, "cg_rmse_m": math.nan, "yaw_rmse_deg": math.nan}
            if truth is not None:
                row["rmse_m"] = float(np.sqrt(((p - truth[alive]) ** 2).sum(-1).mean()))
                cg = config.cg_from_positions(pos[ok]) - cg_true
                row["cg_rmse_m"] = float(np.sqrt((cg ** 2).sum(-1).mean()))
                yaw = procrustes_batch(pos[ok], np.tile(alive.astype(float), (ok.sum(), 1)), config).yaw
                row["yaw_rmse_deg"] = float(np.degrees(np.sqrt((wrap_angle(yaw - yaw_true) ** 2).mean())))
            rows.append(row)
    return pd.DataFrame(rows), est


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
    rows = []
    for f in fractions:
        m = model.with_overrides(common_fraction=f)
        s = synthesize_session(m, config, duration_s, np.random.default_rng(seed)).after_power_failure()
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


def sensor_table(session: StationarySession, nlags: int = 50) -> pd.DataFrame:
    """Per receiver and axis: std, NPP r, excess kurtosis, lag-1 ACF, AR(1) phi and implied
    correlation time, share of ACF lags 1..nlags outside +-1.96/sqrt(n) for the series and
    for its AR(1) residuals (Section 4.3), missing fraction."""
    from scipy import stats

    dt = float(np.median(np.diff(session.t))) if session.n > 1 else 1.0
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
            r = acf(v, nlags)
            _, phi, sw, res = ar1_fit(v)
            rr = acf(res, nlags)
            rows.append({
                "sensor": name, "axis": ax, "n": n, "missing": float(1 - ok.mean()),
                "std_m": float(np.nanstd(v)), "npp_r": npp_r(v),
                "excess_kurtosis": float(stats.kurtosis(v[ok])),
                "acf1": float(r[1]), "ar1_phi": phi, "ar1_sigma_m": sw,
                "tau_s": float(-dt / math.log(phi)) if 0 < phi < 1 else math.nan,
                "acf_outside": float((np.abs(r[1:]) > bound).mean()),
                "resid_acf_outside": float((np.abs(rr[1:]) > bound).mean()),
            })
    return pd.DataFrame(rows)


def pair_table(session: StationarySession, config: SensorConfig | None) -> pd.DataFrame:
    """Per pair of alive receivers: configured distance and observed distance statistics."""
    alive = session.present.any(axis=0)
    D = config.distances() if config is not None else None
    rows = []
    for a, b in _pairs(session.names, alive):
        d = np.linalg.norm(session.obs[:, a] - session.obs[:, b], axis=-1)
        rows.append({"pair": f"{session.names[a]}-{session.names[b]}",
                     "configured_m": float(D[a, b]) if D is not None else math.nan,
                     "mean_m": float(np.nanmean(d)), "std_m": float(np.nanstd(d)),
                     "min_m": float(np.nanmin(d)), "max_m": float(np.nanmax(d)),
                     "mean_abs_dev_m": float(np.nanmean(np.abs(d - D[a, b]))) if D is not None else math.nan})
    return pd.DataFrame(rows)


def analyse(session: StationarySession, config: SensorConfig | None, out: Path,
            rng: np.random.Generator, *, nlags: int = 100) -> dict:
    """Run every section, write CSV tables, figures and summary.md/json to ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    session.save(out / "session.npz")
    s_tab = sensor_table(session, nlags=50)
    s_tab.to_csv(out / "sensors.csv", index=False)
    match = config is not None and set(session.names) <= set(config.names) \
        and tuple(session.names) == tuple(config.names)
    # pairwise distances only mean something for co-located receivers of a known layout
    p_tab = pair_table(session, config) if match else pd.DataFrame()
    if match:
        p_tab.to_csv(out / "pairs.csv", index=False)
    w_est = win_tab = None
    if match:
        w_est = weighting_estimates(session, config, rng)
        pd.DataFrame([{"scheme": e.scheme, "status": e.status, "pos_rmse_m": e.pos_rmse_m,
                       "cg_err_m": e.cg_err_m, "yaw_err_deg": e.yaw_err_deg} for e in w_est]
                     ).to_csv(out / "weighting.csv", index=False)
        win_tab, win_est = window_spreads(session, config)
        win_tab.to_csv(out / "windows.csv", index=False)
    # figures (drawn from the saved session and tables)
    from experiments import stationary_figures as figs

    figs.plot_all(out, session, config if match else None, nlags=nlags,
                  weighting=w_est, windows=win_est if match else None)
    summary = _write_summary(out, session, config if match else None, s_tab, p_tab, w_est, win_tab)
    return summary


def _md(df: pd.DataFrame, floatfmt: str = ".3f") -> str:
    cols = list(df.columns)
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for i in range(len(df)):
        cells = []
        for c in cols:
            v = df[c].iloc[i]          # per column, so integer columns stay integers
            cells.append(format(v, floatfmt) if isinstance(v, (float, np.floating)) else str(v))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _write_summary(out: Path, session: StationarySession, config: SensorConfig | None,
                   s_tab: pd.DataFrame, p_tab: pd.DataFrame, w_est: list[Scored] | None,
                   win_tab: pd.DataFrame | None) -> dict:
    meta = session.meta
    lines = [f"# Stationary analysis ({meta.get('source', 'session')})", ""]
    lines.append(f"Code version {git_describe()}. Session: {session.n} samples "
                 f"({session.t[-1] - session.t[0] + (session.t[1] - session.t[0] if session.n > 1 else 0):.0f} s), "
                 f"{session.m} receivers {list(session.names)}, dead {list(session.dead)}, "
                 f"missing {1 - session.present.mean():.1%} of all samples, "
                 f"alignment {meta.get('alignment')!r}.")
    if meta.get("model"):
        mdl = meta["model"]
        lines.append(f"Noise model `{mdl.get('name')}`: sigma_m {mdl['sigma_m']} m, common_fraction "
                     f"{mdl['common_fraction']}, taus {mdl['common_tau_s']} / {mdl['receiver_tau_s']} s, "
                     f"seed {meta.get('seed')}. Data before the power failure "
                     f"({meta.get('power_failure_s')}) discarded, as in Section 4.1.")
    if meta.get("skipped"):
        nz = {k: v for k, v in meta["skipped"].items() if v}
        lines.append(f"Import skips: {nz}.")
    lines += ["", "## Per sensor (Figs 4.2, 4.3, 4.7-4.15)", "",
              "std: per-axis standard deviation; npp_r: normal-probability-plot correlation (1 = "
              "normal); tau_s: correlation time implied by the AR(1) phi (Eq. 2.2); acf_outside / "
              "resid_acf_outside: share of lags 1-50 whose ACF exceeds +-1.96/sqrt(n) for the "
              "coordinates / the AR(1) residuals (the dissertation found both mostly outside).", ""]
    cols = [c for c in ["sensor", "axis", "missing", "std_m", "npp_r", "excess_kurtosis", "ar1_phi",
                        "tau_s", "acf_outside", "resid_acf_outside"] if c in s_tab.columns]
    lines.append(_md(s_tab[cols].dropna(subset=["axis"]) if "axis" in s_tab else s_tab[cols]))
    if len(p_tab):
        lines += ["", "## Pairwise distances (Figs 4.4-4.6)", ""]
        lines.append(_md(p_tab))
    if w_est is not None:
        lines += ["", "## Whole-recording estimate per weighting scheme (Figs 4.17-4.24)", "",
                  "Eq. 3.7 by SLSQP (eps = 0.01 m); `means` is the per-sensor mean without the "
                  "configuration. Scores against the true antenna positions: RMS position error "
                  "over alive sensors, CG error (Eq. 3.8 members), heading error.", ""]
        lines.append(_md(pd.DataFrame([{"scheme": e.scheme, "status": e.status,
                                        "pos_rmse_m": e.pos_rmse_m, "cg_err_m": e.cg_err_m,
                                        "yaw_err_deg": e.yaw_err_deg} for e in w_est])))
    if win_tab is not None:
        lines += ["", "## Sliding windows (Figs 4.25-4.33)", "",
                  "Closed-form procrustes per window. spread_m: RMS distance of the window "
                  "estimates from their own mean (the cluster size the dissertation compared); "
                  "rmse_m / cg_rmse_m / yaw_rmse_deg: against the truth.", ""]
        lines.append(_md(win_tab))
    reading = _reading(session, s_tab, w_est, win_tab)
    if reading:
        lines += ["", "## Reading (computed from the tables above)", ""] + [f"- {r}" for r in reading]
    lines += ["", "## Figures", ""]
    for p in sorted(out.glob("*.png")):
        lines.append(f"- [{p.name}]({p.name})")
    (out / "summary.md").write_text("\n".join(lines) + "\n")
    summary = {"code_version": git_describe(), "n": session.n, "m": session.m,
               "names": list(session.names), "meta": meta,
               "sensors": s_tab.to_dict(orient="records"), "pairs": p_tab.to_dict(orient="records"),
               "weighting": None if w_est is None else [
                   {"scheme": e.scheme, "status": e.status, "pos_rmse_m": e.pos_rmse_m,
                    "cg_err_m": e.cg_err_m, "yaw_err_deg": e.yaw_err_deg} for e in w_est],
               "windows": None if win_tab is None else win_tab.to_dict(orient="records")}
    (out / "summary.json").write_text(json.dumps(summary, indent=1, default=_json_default) + "\n")
    return summary


def _reading(session: StationarySession, s_tab: pd.DataFrame, w_est: list[Scored] | None,
             win_tab: pd.DataFrame | None) -> list[str]:
    """Plain statements derived from the tables (no hand-written numbers)."""
    out = []
    if "axis" in s_tab:
        t = s_tab.dropna(subset=["axis"])
        if len(t):
            out.append(f"Per-axis std {t.std_m.min():.2f}-{t.std_m.max():.2f} m; NPP r "
                       f"{t.npp_r.min():.3f}-{t.npp_r.max():.3f} (1 = normal); ACF beyond the bounds "
                       f"at {t.acf_outside.min():.0%}-{t.acf_outside.max():.0%} of lags 1-50, AR(1) "
                       f"residual ACF at {t.resid_acf_outside.min():.0%}-{t.resid_acf_outside.max():.0%} "
                       f"(Section 4.3 reports both mostly beyond).")
    if w_est is not None and session.truth_positions is not None:
        fits = [e for e in w_est if e.scheme != "means" and np.isfinite(e.pos_rmse_m)]
        best = min(fits, key=lambda e: e.pos_rmse_m)
        none = next(e for e in fits if e.scheme == "none")
        means = next(e for e in w_est if e.scheme == "means")
        out.append(f"Whole recording: the configuration fit (none) has {none.pos_rmse_m:.2f} m RMS "
                   f"position error vs {means.pos_rmse_m:.2f} m for the per-sensor means; best scheme "
                   f"{best.scheme!r} at {best.pos_rmse_m:.2f} m; CG error of the fit {none.cg_err_m:.2f} m "
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


def _json_default(o: object) -> object:
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


# --------------------------------------------------------------------------- real logs
def real_log_table(root: Path) -> pd.DataFrame:
    """Per real log under ``root`` (gpsd/*.log, hazer/nmea/*, hazer/tumbleweed/**/*.csv):
    fixes, grid epochs, missing share, std east/north, AR(1) correlation time (from the lag-1
    coefficient of each axis), and the skip counts."""
    from sim.nmea import read_log, session_from_fixes

    files = (sorted((root / "gpsd").glob("*.log")) + sorted((root / "hazer/nmea").glob("*.dat"))
             + sorted((root / "hazer/nmea").glob("*.lst"))
             + sorted((root / "hazer/tumbleweed").glob("**/*.csv")))
    rows = []
    for f in files:
        fx = read_log(f)
        skips = {k: v for k, v in fx.skipped.items() if v and k != "other_sentences"}
        row = {"log": str(f.relative_to(root)), "fixes": int(fx.valid.sum()), "epochs": pd.NA,
               "duration_s": math.nan, "missing": math.nan, "std_east_m": math.nan,
               "std_north_m": math.nan, "tau_east_s": math.nan, "tau_north_s": math.nan,
               "skipped": ", ".join(f"{k} {v}" for k, v in skips.items())}
        if fx.valid.sum() >= 3:
            s = session_from_fixes([fx])
            x = s.obs[:, 0]
            dt = 1.0 / s.meta["rate_hz"]
            row.update({"epochs": s.n, "duration_s": float(s.t[-1] - s.t[0] + dt),
                        "missing": float(1 - s.present.mean()),
                        "std_east_m": float(np.nanstd(x[:, 0])), "std_north_m": float(np.nanstd(x[:, 1]))})
            for a, ax in enumerate(("east", "north")):
                phi = ar1_fit(x[:, a])[1]
                row[f"tau_{ax}_s"] = float(-dt / math.log(phi)) if 0 < phi < 1 else math.nan
        rows.append(row)
    tab = pd.DataFrame(rows)
    tab["epochs"] = tab["epochs"].astype("Int64")
    return tab


# --------------------------------------------------------------------------- CLI
def load_session(paths: list[str]) -> StationarySession:
    """A saved ``.npz`` session, or NMEA / CSV logs (one per receiver) via sim.nmea."""
    if len(paths) == 1 and paths[0].endswith(".npz"):
        return StationarySession.load(paths[0])
    from sim.nmea import import_session

    return import_session(paths)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m experiments.stationary", description=__doc__.split("\n\n")[0])
    src = ap.add_mutually_exclusive_group()
    src.add_argument("--synthetic", action="store_true", help="synthetic session (default)")
    src.add_argument("--session", nargs="+", metavar="PATH",
                     help="a saved session .npz, or NMEA/CSV logs (one per receiver)")
    ap.add_argument("--model", default="gps_stationary", help="noise model name or TOML path")
    ap.add_argument("--config", default="rover_gps8", help="sensor configuration name or TOML path")
    ap.add_argument("--duration", type=float, default=4300.0,
                    help="synthetic session length in s, before discarding the power failure")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    ap.add_argument("--keep-before-power-failure", action="store_true",
                    help="analyse the whole recording (default: discard up to the power failure's end)")
    ap.add_argument("--no-split", action="store_true",
                    help="skip the common_fraction sensitivity table (synthetic sessions only)")
    ap.add_argument("--real-logs", type=Path, metavar="DIR",
                    help="also write real_logs.md with statistics of every log under DIR")
    args = ap.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    config = SensorConfig.load(args.config)
    if args.session:
        session = load_session(args.session)
    else:
        model = GpsNoiseModel.load(args.model)
        session = synthesize_session(model, config, args.duration, rng)
        session.meta["seed"] = args.seed
    if not args.keep_before_power_failure:
        session = session.after_power_failure()
    match = tuple(session.names) == tuple(config.names)
    if not match:
        print(f"receivers {list(session.names)} do not match configuration {config.name!r} "
              f"{list(config.names)}: configuration sections (distances, fits) skipped", file=sys.stderr)
    analyse(session, config if match else None, args.out, rng)
    if not args.session and not args.no_split:
        split = split_sensitivity(GpsNoiseModel.load(args.model), config, args.duration, args.seed)
        split.to_csv(args.out / "split.csv", index=False)
        with open(args.out / "summary.md", "a") as fh:
            fh.write("\n## Common-mode share vs heading (model sweep, same seed)\n\n"
                     "Unweighted sliding windows, procrustes, scored against the truth; "
                     "`common_fraction` overridden on the model above, total sigma fixed.\n\n"
                     + _md(split) + "\n")
    if args.real_logs:
        tab = real_log_table(args.real_logs)
        tab.to_csv(args.out / "real_logs.csv", index=False)
        text = ["# Real receiver logs (../shared/realdata), imported with sim.nmea", "",
                "One row per log: valid fixes, grid epochs (missing = no-fix or absent epochs), "
                "per-axis std in the local UTM frame, AR(1) correlation time from the lag-1 "
                "coefficient (short logs bias it low and cannot show slower components), and the "
                "skip counts (other sentence types omitted).", "", _md(tab, ".2f")]
        (args.out / "real_logs.md").write_text("\n".join(text) + "\n")
    print(f"wrote {args.out}/summary.md")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
