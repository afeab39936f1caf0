"""The stationary claims of the GPS dissertation (000_8f82f8df647bf685.txt Sections 4.3-4.8)
judged on simulated sessions by the moving claims' rule (:data:`experiments.claims.RULE`).

Each claim is a list of :class:`experiments.claims.Comparison` on a per-seed table (one row
per seed and condition, :func:`seed_table`); :func:`experiments.claims.evaluate_claims`
pairs the seeds, takes the 95 % Student-t interval of the mean difference and gives
supports / contradicts / inconclusive per comparison and reproduced / not reproduced /
mixed per claim. Section 4.9 describes the moving set-up and makes no stationary claim.

Conditions of the table: ``session`` (series and layout statistics of the whole session),
each weighting scheme of :func:`experiments.stationary_analysis.weighting_estimates` (``none``,
``huber``, ...) and ``window:<scheme>`` (sliding windows). Every claim not reproduced gets a
``Cause:`` line from :func:`cause_lines`: the same claim re-evaluated on model variants
(:data:`VARIANTS`) and, for the residual claim, on the real receiver logs, i.e. measurements
that could have come out either way.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

from estimator.configuration import SensorConfig
from estimator.noise_stats import acf, ar1_fit
from experiments.claims import RULE, Claim, ClaimResult, Comparison, evaluate_claims
from experiments.stationary_analysis import weighting_estimates, window_spreads
from sim.gps import GpsNoiseModel, StationarySession, synthesize_session

__all__ = ["STATIONARY_CLAIMS", "VARIANTS", "cause_lines", "claims_markdown", "evaluate",
           "seed_table", "series_shares", "session_rows"]

#: Seeds of the main evaluation (seed 0 is the reference session) and of each variant.
SEEDS = tuple(range(20))
VARIANT_SEEDS = tuple(range(10))
#: ACF lags judged (Section 4.3's figures show lags up to about 40-50).
NLAGS = 50
#: "Mostly exceed": more than half of the lags outside +-1.96/sqrt(n).
MOSTLY = 0.5
#: "No sharp jagged-ness": lag-1 autocorrelation above 0.9, i.e. the step-to-step change has
#: a std below sqrt(2 (1 - 0.9)) = 0.45 of the series' own std (white noise has r1 = 0).
SMOOTH_R1 = 0.9
#: "Form the configuration": every pairwise distance of the fit within 2 eps of the layout
#: (Eq. 3.7 allows eps = 0.01 m of slack; 2 eps leaves room for SLSQP's tolerance).
LAYOUT_TOL_M = 0.02
#: "Within the area of the observed values": inside the 5-95 % range of x and of y.
AREA_Q = (0.05, 0.95)
#: "A definite decrease in the spread": window 10's spread at least 10 % below window 1's
#: (a scatter plot shows a 10 % smaller cluster; a few per cent are invisible in Fig 4.27).
DEFINITE = -0.10
WEIGHTED = ("huber", "huff", "huff_huber", "deleted_residuals")
WINDOW_SCHEMES = ("none", "huff", "huff:3.5")
#: Model variants the causes measure (overrides of the session's noise model).
VARIANTS = {
    "short correlation (taus 1 s, no plateaus)": {"common_tau_s": 1.0, "receiver_tau_s": 1.0,
                                                 "step_rate_per_h": 0.0},
    "first-order Gauss-Markov (gm_order 1)": {"gm_order": 1},
    "common_fraction 0.9": {"common_fraction": 0.9},
    "30 % missing (5 s bursts)": {"missing_fraction": 0.3},
}


# --------------------------------------------------------------------------- measurements
def series_shares(v: np.ndarray, nlags: int = NLAGS) -> tuple[float, float, float]:
    """Share of lags 1..nlags with |ACF| > 1.96/sqrt(n) for the series and for its AR(1)
    residuals (Eq. 2.2), and the lag-1 ACF. v (n,) metres, NaN = missing."""
    n = int(np.isfinite(v).sum())
    if n < 10:
        raise ValueError(f"v: needs at least 10 present samples, got {n}")
    lags = min(nlags, n // 2)
    bound = 1.96 / math.sqrt(n)
    r = acf(v, lags)
    rr = acf(ar1_fit(v)[3], lags)
    return (float((np.abs(r[1:]) > bound).mean()), float((np.abs(rr[1:]) > bound).mean()),
            float(r[1]))


def _series_rows(session: StationarySession) -> dict:
    alive = np.flatnonzero(session.present.any(axis=0))
    coord = [series_shares(session.obs[:, j, a]) for j in alive for a in (0, 1)]
    dist = [series_shares(np.linalg.norm(session.obs[:, a] - session.obs[:, b], axis=-1))
            for k, a in enumerate(alive) for b in alive[k + 1:]]
    c, d = np.array(coord), np.array(dist)
    return {"acf_min": c[:, 0].min(), "resid_median": float(np.median(c[:, 1])),
            "resid_max": c[:, 1].max(), "acf1_min": c[:, 2].min(),
            "dist_acf_min": d[:, 0].min(), "dist_resid_median": float(np.median(d[:, 1]))}


def _layout_rows(session: StationarySession, config: SensorConfig, positions: np.ndarray) -> dict:
    """Largest layout violation of the unweighted fit and the share of alive sensors whose
    estimate lies inside the AREA_Q range of its observations on both axes."""
    alive = session.present.any(axis=0)
    p = positions[alive]
    d = np.linalg.norm(p[:, None] - p[None], axis=-1)
    D = config.distances()[np.ix_(alive, alive)]
    lo, hi = np.nanquantile(session.obs[:, alive], AREA_Q, axis=0)
    inside = ((p >= lo) & (p <= hi)).all(axis=1)
    return {"layout_err_max_m": float(np.abs(d - D).max()), "inside_share": float(inside.mean())}


def session_rows(session: StationarySession, config: SensorConfig, seed: int,
                 rng: np.random.Generator) -> list[dict]:
    """The per-seed rows of one session (conditions: module docstring)."""

    est = weighting_estimates(session, config, rng)
    none = next(e for e in est if e.scheme == "none")
    rows = [{"seed": seed, "condition": "session", **_series_rows(session),
             **_layout_rows(session, config, none.positions)}]
    rows += [{"seed": seed, "condition": e.scheme, "pos_rmse_m": e.pos_rmse_m,
              "yaw_err_deg": e.yaw_err_deg} for e in est]
    tab, _ = window_spreads(session, config, sizes=(1, 10), schemes=WINDOW_SCHEMES)
    for sch, g in tab.groupby("scheme", sort=False):
        s = g.set_index("window").spread_m
        rows.append({"seed": seed, "condition": f"window:{sch}", "spread_1_m": s[1],
                     "spread_10_m": s[10], "spread_change": s[10] / s[1] - 1})
    return rows


def seed_table(model: GpsNoiseModel, config: SensorConfig, duration_s: float,
               seeds: tuple[int, ...] = SEEDS) -> pd.DataFrame:
    """One row per seed and condition; the session of seed s is the one the stationary report
    draws with ``--seed s`` (same generator, data after the power failure)."""
    rows = []
    for s in seeds:
        rng = np.random.default_rng(s)
        session = synthesize_session(model, config, duration_s, rng).after_power_failure()
        rows += session_rows(session, config, s, rng)
    return pd.DataFrame(rows)


# --------------------------------------------------------------------------- claims
S = {"condition": "session"}


def _c(cond: str) -> dict:
    return {"condition": cond}


def _weighted(rel: str, metric: str = "pos_rmse_m") -> list[Comparison]:
    return [Comparison(_c(w), rel, _c("none"), metric, f"{w} {rel} none ({metric})")
            for w in WEIGHTED]


def _window(scheme: str) -> Claim:
    sec = {"none": "4.7", "huff": "4.8.1", "huff:3.5": "4.8.2"}[scheme]
    return Claim(
        f"S{sec}", sec,
        f"Sliding windows ({scheme}): a definite decrease in the spread of the estimates as "
        f"the window grows from 1 to 10 samples (judged: spread(10)/spread(1) - 1 < "
        f"{DEFINITE:+.0%}).",
        lambda cells, c=f"window:{scheme}": [Comparison(
            _c(c), "<", DEFINITE, "spread_change", f"{c}: spread(10)/spread(1) - 1 < {DEFINITE}")])


STATIONARY_CLAIMS: list[Claim] = [
    Claim("S4.3a", "4.3",
          "The ACF of the coordinates exceeds the significance bounds for all sensors (judged: "
          f"in every series more than {MOSTLY:.0%} of lags 1-{NLAGS} outside +-1.96/sqrt(n)).",
          lambda cells: [Comparison(S, ">", MOSTLY, "acf_min", "min over series of the share")]),
    Claim("S4.3b", "4.3",
          "The ACF of the AR(1) residuals mostly exceeds the bounds: significant residual "
          f"autocorrelation (judged: median over series of the share of lags 1-{NLAGS} "
          f"outside > {MOSTLY:.0%}).",
          lambda cells: [Comparison(S, ">", MOSTLY, "resid_median",
                                    "median share, AR(1) residuals")]),
    Claim("S4.3c", "4.3",
          "Similar results for the distances between sensors: their ACF and their AR(1) "
          "residuals' ACF exceed the bounds (same judgement on every pairwise distance).",
          lambda cells: [Comparison(S, ">", MOSTLY, "dist_acf_min", "min share, distances"),
                         Comparison(S, ">", MOSTLY, "dist_resid_median",
                                    "median share, distances' AR(1) residuals")]),
    Claim("S4.3d", "4.3",
          "The coordinates follow a trend without the sharp jagged-ness of time series data "
          f"(judged: lag-1 ACF > {SMOOTH_R1} in every series).",
          lambda cells: [Comparison(S, ">", SMOOTH_R1, "acf1_min", "min lag-1 ACF")]),
    Claim("S4.5a", "4.5",
          "The unweighted estimates form the configuration of Fig 4.1 (judged: every pairwise "
          f"distance of the fit within {LAYOUT_TOL_M} m of the layout).",
          lambda cells: [Comparison(S, "<", LAYOUT_TOL_M, "layout_err_max_m", "max |d - a| (m)")]),
    Claim("S4.5b", "4.5",
          "The unweighted estimates lie within the area of the observed values (judged: every "
          f"alive sensor's estimate inside the {AREA_Q[0]:.0%}-{AREA_Q[1]:.0%} range of its "
          "x and of its y observations).",
          lambda cells: [Comparison(S, ">=", 1.0, "inside_share", "share of sensors inside")]),
    Claim("S4.5c", "4.5",
          "The unweighted fit is the worst case: outlier removal and weighting can only improve "
          "it (judged: position RMSE of Huber, Huff, Huff x Huber, deleted residuals <= none).",
          lambda cells: _weighted("<=")),
    Claim("S4.6a", "4.6",
          "With only sensors 1+5 or 1+8 (Huber) the orientation straightens: more erroneous "
          "data may not help (judged: heading error of huber_1_5 and huber_1_8 < Huber on all "
          "sensors).",
          lambda cells: [Comparison(_c(s), "<", _c("huber"), "yaw_err_deg", f"{s} < huber (deg)")
                         for s in ("huber_1_5", "huber_1_8")]),
    Claim("S4.6b", "4.6",
          "The weighting techniques have slight advantages and seem to produce more accurate "
          "estimates (judged: position RMSE of each weighted scheme < none).",
          lambda cells: _weighted("<")),
    _window("none"), _window("huff"), _window("huff:3.5"),
]


def evaluate(cells: pd.DataFrame) -> list[ClaimResult]:
    """The stationary claims on a per-seed table (the moving claims' evaluation and rule)."""
    return evaluate_claims(cells, STATIONARY_CLAIMS)


# --------------------------------------------------------------------------- causes
def _mean(cells: pd.DataFrame, cond: str, metric: str) -> float:
    v = cells.loc[cells.condition == cond, metric]
    return float(v.mean()) if len(v) else math.nan


def _variant_text(r: ClaimResult, variants: dict[str, pd.DataFrame]) -> str:
    """The claim's verdict under each variant, with how many comparisons support it and the
    first comparison's means."""
    parts = []
    for name, cells in variants.items():
        vr = evaluate_claims(cells, [r.claim])[0]
        o = vr.outcomes[0]
        k = sum(x.result == "supports" for x in vr.outcomes)
        parts.append(f"{name}: {vr.verdict} ({k}/{len(vr.outcomes)} support; first: "
                     f"{o.comparison.metric} {o.mean_a:.3g} vs {o.mean_b:.3g})")
    return "; ".join(parts)


def _specific(cid: str, cells: pd.DataFrame, real: pd.DataFrame | None) -> str:
    """The claim-specific part of a Cause line, numbers from the tables."""
    if cid == "S4.3b":
        txt = ("the AR(1) residuals of the simulated Gauss-Markov errors are nearly white "
               f"(median share {_mean(cells, 'session', 'resid_median'):.0%}, at most "
               f"{cells.resid_max.max():.0%} of lags in any series); the thesis's real session, "
               "or residuals of a model other than Eq. 2.2, would show more")
        if real is not None and len(real):
            txt += (f"; on the {len(real)} real log axes of ../shared/realdata the AR(1) residual "
                    f"share is {real.resid_share.median():.0%} median, "
                    f"{real.resid_share.max():.0%} "
                    f"max (logs of {int(real.n.min())}-{int(real.n.max())} fixes, lags 1-n/2)")
        return txt
    if cid == "S4.3c":
        return ("the distance between two receivers is a smooth function of their Gauss-Markov "
                "errors and is whitened by Eq. 2.2 like the coordinates (median share "
                f"{_mean(cells, 'session', 'dist_resid_median'):.0%}); real logs of one receiver "
                "each give no distance to measure")
    if cid in ("S4.5c", "S4.6b"):
        d = {w: _mean(cells, w, "pos_rmse_m") for w in ("none", *WEIGHTED)}
        return ("the weights scale each receiver's residuals by its whole-session MAD, so slow "
                "plateaus (correlation times 120-600 s) are down-weighted like outliers and the "
                "common-mode error no longer cancels across receivers (if so, the short-"
                "correlation variant below should remove the penalty); mean position RMSE "
                + ", ".join(f"{k} {v:.3f} m" for k, v in d.items()))
    if cid == "S4.6a":
        d = {s: _mean(cells, s, "yaw_err_deg") for s in ("huber", "huber_1_5", "huber_1_8")}
        return ("one baseline of 1.25 / 1.80 m carries the heading with two receivers' "
                "per-receiver error, where seven receivers average theirs; the thesis judged the "
                "straightening by eye without the true heading (Section 4.6); mean heading "
                "error " + ", ".join(
                    f"{k} {v:.1f} deg" for k, v in d.items()))
    if cid.startswith(("S4.7", "S4.8")):
        return ("10 samples at 1 Hz are far shorter than the errors' correlation times "
                "(120-600 s), so a window of 10 averages almost one error value; the thesis's "
                "reading (less effect of missing data) is measured by the 30 % missing variant")
    return _specific_rest(cid, cells)


def _specific_rest(cid: str, cells: pd.DataFrame) -> str:
    """Cause readings of the claims the reference reproduces (they can fail on other runs)."""
    if cid == "S4.3a":
        return (f"the least series has {_mean(cells, 'session', 'acf_min'):.0%} of lags outside; "
                "the errors' correlation times (120-600 s) set how many lags of 1-50 s stay "
                "significant")
    if cid == "S4.3d":
        return (f"lowest lag-1 ACF {_mean(cells, 'session', 'acf1_min'):.3f}: white jitter and "
                "outliers on top of the Gauss-Markov error roughen a short or low-variance series")
    if cid == "S4.5a":
        return (f"largest layout violation {_mean(cells, 'session', 'layout_err_max_m'):.3f} m "
                "(Eq. 3.7's eps slack plus SLSQP's tolerance)")
    if cid == "S4.5b":
        return (f"share of sensors inside {_mean(cells, 'session', 'inside_share'):.0%}: the "
                "rigid fit moves each receiver to the layout around the common centre, so a "
                "receiver whose error mean is off (biases of 0.5 m, short sessions) falls outside "
                "its own 5-95 % box")
    raise ValueError(f"cid: no cause reading for claim {cid!r}")


def cause_lines(results: list[ClaimResult], cells: pd.DataFrame,
                variants: dict[str, pd.DataFrame], real: pd.DataFrame | None = None
                ) -> dict[str, str]:
    """``Cause:`` per claim not reproduced (or mixed): the claim-specific reading and the
    claim re-evaluated on each model variant (measurements that could have come out
    otherwise)."""
    out = {}
    for r in results:
        if r.verdict in ("reproduced", "not evaluated"):
            continue
        out[r.claim.cid] = (f"Cause: {_specific(r.claim.cid, cells, real)}. Measured under "
                            f"model variants ({len(VARIANT_SEEDS)} seeds each): "
                            f"{_variant_text(r, variants)}.")
    return out


def real_log_shares(root: Path) -> pd.DataFrame:
    """Per real log and axis (sim.nmea import, as real_logs.md): n and the AR(1) residual
    ACF share (lags 1..min(50, n/2)); logs with fewer than 20 fixes are left out."""
    from sim.nmea import find_logs, read_log, session_from_fixes

    rows = []
    for f in find_logs(root)[0]:
        try:
            s = session_from_fixes([read_log(f)])
        except ValueError:
            continue
        for a, ax in enumerate(("east", "north")):
            v = s.obs[:, 0, a]
            if np.isfinite(v).sum() >= 20:
                _, res, _ = series_shares(v)
                rows.append({"log": f.relative_to(root).as_posix(), "axis": ax,
                             "n": int(np.isfinite(v).sum()), "resid_share": res})
    return pd.DataFrame(rows, columns=["log", "axis", "n", "resid_share"])


# --------------------------------------------------------------------------- report
def claims_markdown(results: list[ClaimResult], causes: dict[str, str], n_seeds: int,
                    model_name: str) -> str:
    """claims.md: the rule, one section per claim with its comparisons and verdict."""
    from collections import Counter

    counts = Counter(r.verdict for r in results)
    lines = ["# Stationary claims (dissertation Sections 4.3-4.8)", "",
             f"Each claim judged on {n_seeds} simulated sessions (noise model `{model_name}`, "
             "seeds 0.., seed 0 = the session of summary.md), paired by seed. " + RULE, "",
             ("Section 4.9 describes the moving set-up (paths, Huff as the only moving "
              "weighting) and makes no stationary claim."), "",
             "Verdicts: " + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())), "",
             "| claim | section | verdict |", "|---|---|---|"]
    lines += [f"| {r.claim.cid} | {r.claim.section} | {r.verdict} |" for r in results]
    for r in results:
        lines += ["", f"## {r.claim.cid} (Section {r.claim.section}): {r.verdict}", "",
                  r.claim.text, ""]
        lines += [f"- {o.comparison.label}: A = {o.mean_a:.4g}, B = {o.mean_b:.4g}, mean A - B = "
                  f"{o.diff:.3g} [{o.lo:.3g}, {o.hi:.3g}] over {o.n} seeds: {o.result}"
                  for o in r.outcomes]
        if r.claim.cid in causes:
            lines += ["", causes[r.claim.cid]]
    return "\n".join(lines) + "\n"
