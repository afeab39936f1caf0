"""How the thesis claims' verdicts move with the noise model's calibrated and assumed
quantities (issue 28): ``python -m experiments.sensitivity [--reference] [--seeds N]
[--quantity NAME ...]``.

The noise model is partly calibrated from the tables it is scored against (``sigma_m`` from
the CG errors, the cruise speed from the window-100 "None" row, models/paths/square100.toml)
and partly assumed (``common_fraction``, the Gauss-Markov time constants, the 3 m target
area that sets how wide the turns and so the turning flag are). Each :data:`QUANTITIES`
entry is moved over a range, one at a time, on the thesis preset's claim grids
(:data:`GRIDS`, experiments/presets/thesis.toml) through the normal runner
(:func:`experiments.runner.run.run`; the variants are spec overrides). Every claim of
:mod:`experiments.claims` is evaluated per variant by the fixed rule, against the shipped
setting run with the same seeds (``--quantity``: only the named quantities' variants, e.g.
to rerun one; not with ``--reference``, which is always the full study). Writes to ``--out``
(``--reference``: results/sensitivity/, default results/local/sensitivity/):
``sensitivity.csv`` (claim x variant -> verdict, supports, key comparison),
``comparisons.csv`` (every comparison of :data:`CAUSE_CLAIMS`, read by the ``Cause:`` lines
of :mod:`experiments.causes`), ``turns.csv`` (share of the estimates with a turn in their
window), ``mask.csv`` (C14 under a widened no-turns mask), ``shipped.csv`` (the shipped
value of every quantity, which the ``Cause:`` lines label "(shipped)") and ``REPORT.md``.
The cells themselves stay in results/local/sensitivity/sweep and .../mask (resumable).
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from experiments.deferred import deferred_attributes
from experiments.markdown import md_row, md_separator
from experiments.spec import PRESETS_DIR, RESULTS_ROOT, Spec, load_spec
from sim.atomic import atomic_write, atomic_write_text

if TYPE_CHECKING:
    import pandas as pd

#: imported where used, not here, so that --help and argument errors answer before
#: pandas / numba / scipy / matplotlib load; still importable from this module
__getattr__ = deferred_attributes(__name__, {
    "pd": ("pandas", None),
    "brentq": ("scipy.optimize", "brentq"),
    "CLAIMS": ("experiments.claims", "CLAIMS"),
    "COURSE_CLAIMS": ("experiments.claims", "COURSE_CLAIMS"),
    "P1": ("experiments.claims", "P1"),
    "evaluate_claims": ("experiments.claims", "evaluate_claims"),
    "THESIS_TABLES": ("experiments.tables", "THESIS_TABLES"),
    "faithful": ("experiments.tables", "faithful"),
    "numpy_strings": ("experiments.tables", "numpy_strings"),
})

__all__ = ["CAUSE_CLAIMS", "DILATE_S", "GRIDS", "QUANTITIES", "Quantity", "evaluate_mask",
           "evaluate_variants", "main", "mask_cells", "mask_spec", "wide_mask",
           "sensitivity_spec", "shipped", "shipped_table", "speed_bound", "tau_bounds",
           "variants", "write_tables"]

#: The thesis preset's grid blocks the claims read (the beyond, oracle and side-study rows
#: only feed the Cause lines); "LC, smoothed heading" is dropped (no claim reads it).
GRIDS = ("weighting", "techniques", "beyond_lc")
DROP = ("lc_smoothed_heading",)
#: Claims whose per-comparison numbers the thesis REPORT's Cause lines quote.
CAUSE_CLAIMS = ("C2", "C8", "C14", "C17", "C19")
REFERENCE = RESULTS_ROOT / "sensitivity"
LOCAL = RESULTS_ROOT / "local" / "sensitivity"
#: Ratio of the common to the per-receiver Gauss-Markov time constant, kept when "tau" moves.
TAU_RATIO = 5.0


@dataclass(frozen=True)
class Quantity:
    """One quantity moved: ``field`` of the noise model or path file (``axis``), its tried
    ``values`` (SI units ``unit``), and how the shipped value was set (``kind``)."""

    name: str
    field: str
    axis: str          # "noise" or "path"
    unit: str
    values: tuple[float, ...]
    kind: str
    why: str = ""

    def overrides(self, v: float) -> dict:
        if self.field == "receiver_tau_s":
            return {"receiver_tau_s": v, "common_tau_s": TAU_RATIO * v}
        return {self.field: v}


QUANTITIES = (
    Quantity("sigma", "sigma_m", "noise", "m", (1.5, 2.5, 3.0, 3.5),
             "calibrated on the CG errors",
             "25 % below the shipped value up to past the top of the bound"),
    Quantity("speed", "cruise_speed_mps", "path", "m/s", (0.1, 0.15, 0.3),
             "calibrated on the window-100 None row",
             "the bound's low end, half the shipped speed (C2 asks for slower), and above it"),
    Quantity("common_fraction", "common_fraction", "noise", "-", (0.0, 0.25, 0.75, 0.9),
             "assumed", "independent receivers up to 0.9 (0.99: the thesis side study)"),
    Quantity("tau", "receiver_tau_s", "noise", "s", (15.0, 30.0, 60.0, 240.0),
             f"assumed (common_tau_s = {TAU_RATIO:g} x receiver_tau_s throughout)",
             "from the text's bound (15 s) to twice the shipped value"),
    Quantity("turn_width", "target_radius_m", "path", "m", (6.0, 10.0),
             "assumed (the target-area size is not printed)",
             "a turn of radius ~r is flagged while 1/r > 1/15 1/m (sim.controllers), so "
             "r < 15 m; 10 m is the widest clearly flagged"),
)


def variants(quantities=QUANTITIES) -> list[tuple[str, float | None, str | None, dict]]:
    """[(quantity, value, axis, overrides)]: the shipped setting first (quantity "shipped")."""
    out: list[tuple[str, float | None, str | None, dict]] = [("shipped", None, None, {})]
    return out + [(q.name, v, q.axis, q.overrides(v)) for q in quantities for v in q.values]


def sensitivity_spec(seeds: int, quantities=QUANTITIES) -> Spec:
    """The thesis preset's :data:`GRIDS` once per variant (overrides on the block)."""
    raw = load_spec("thesis").raw
    blocks = [b for b in raw["grid"] if b["name"] in GRIDS]
    grid = []
    for q, v, axis, ov in variants(quantities):
        for b in blocks:
            nb = copy.deepcopy(b)
            nb["name"] = f"{b['name']}:{q}={v}"
            techs = nb["technique"] if isinstance(nb["technique"], list) else [nb["technique"]]
            nb["technique"] = [t for t in techs if t not in DROP]
            if axis:
                nb[f"{axis}_overrides"] = ov
            grid.append(nb)
    data = {"name": "sensitivity", "seed": raw["seed"], "seeds": int(seeds),
            "masks": raw["masks"], "session_s": raw.get("session_s", 4000.0),
            "defaults": raw["defaults"], "grid": grid,
            "description": "thesis claim grids under each sensitivity variant (issue 28)"}
    return Spec.from_dict(data, source="sensitivity (thesis preset grids)", base_dir=PRESETS_DIR)


# --------------------------------------------------------------------------- evaluation
def _subset(cells: pd.DataFrame, axis: str | None, ov: dict) -> pd.DataFrame:
    want = {"noise": {}, "path": {}}
    if axis:
        want[axis] = ov
    mk = np.ones(len(cells), dtype=bool)
    for a, w in want.items():
        col = cells[f"{a}_overrides"]
        mk &= col.map({s: json.loads(s) == w for s in set(col)}).to_numpy(dtype=bool)
    return cells[mk]


def _key(outs, base_outs) -> tuple[str, float, float, float]:
    """The comparison to quote: the first whose result differs from the shipped setting's,
    else the first that does not support the claim, else the first."""
    pick = next((o for o, b in zip(outs, base_outs) if o.result != b.result), None)
    pick = pick or next((o for o in outs if o.result != "supports"), None) or outs[0]
    return pick.comparison.label, pick.diff, pick.lo, pick.hi


def _turn_shares(main: pd.DataFrame) -> dict[int, float]:
    """{window: share of the LC estimates on Path 1 whose window holds a turning epoch}."""
    from experiments.claims import P1, _per_seed

    out = {}
    for w in (5, 10, 100):
        n = [_per_seed(main, {"path": P1, "window": w, "weighting": "huff", "technique": "lc",
                              "mask": m}, "n_epochs").mean() for m in ("full", "no_turns_window")]
        if np.isfinite(n).all() and n[0] > 0:
            out[w] = float(1 - n[1] / n[0])
    return out


def evaluate_variants(cells: pd.DataFrame, quantities=QUANTITIES
                      ) -> tuple[pd.DataFrame, pd.DataFrame, pd.DataFrame]:
    """(sensitivity, comparisons, turns) tables of a sensitivity sweep's cells."""
    import pandas as pd

    from experiments.claims import CLAIMS, COURSE_CLAIMS, _derived, evaluate_claims
    from experiments.tables import faithful, numpy_strings

    cells = numpy_strings(cells)
    rows, comps, turns, base = [], [], [], None
    for q, v, axis, ov in variants(quantities):
        main = _derived(faithful(_subset(cells, axis, ov)))
        if main.empty:
            raise ValueError(f"cells: no cells of variant {q} = {v} ({ov}); run the sweep")
        res = evaluate_claims(main, CLAIMS + COURSE_CLAIMS)
        base = base or res
        for r, b in zip(res, base):
            k = sum(o.result == "supports" for o in r.outcomes)
            n = sum(o.result != "missing" for o in r.outcomes)
            lab, d, lo, hi = _key(r.outcomes, b.outcomes) if r.outcomes else ("", *[math.nan] * 3)
            rows.append({"quantity": q, "value": v, "claim": r.claim.cid, "verdict": r.verdict,
                         "supports": k, "evaluated": n, "key_comparison": lab, "key_diff": d,
                         "key_lo": lo, "key_hi": hi, "shipped_verdict": b.verdict,
                         "flipped": r.verdict != b.verdict})
            if r.claim.cid in CAUSE_CLAIMS:
                comps += [{"quantity": q, "value": v, "claim": r.claim.cid,
                           "window": o.comparison.a.get("window", -1),
                           "comparison": o.comparison.label, "n_seeds": o.n, "mean_a": o.mean_a,
                           "mean_b": o.mean_b, "diff": o.diff, "lo": o.lo, "hi": o.hi,
                           "result": o.result} for o in r.outcomes]
        turns += [{"quantity": q, "value": v, "window": w, "turn_share": s}
                  for w, s in _turn_shares(main).items()]
    return pd.DataFrame(rows), pd.DataFrame(comps), pd.DataFrame(turns)


# --------------------------------------------------------------------------- wider mask
#: Widenings (s) of the no-turns mask for C14: each estimate is dropped whose window,
#: widened by this much on both sides, holds a turning epoch (the "wider mask", issue 28).
DILATE_S = (0.0, 10.0, 30.0, 60.0)


def mask_spec(seeds: int) -> Spec:
    """LC on Path 1 (Huff, windows 5/10/100) with every seed's per-epoch errors kept."""
    from experiments.claims import P1

    raw = load_spec("thesis").raw
    grid = [{"name": "lc", "path": P1, "window": [5, 10, 100], "weighting": "huff",
             "technique": "lc"}]
    data = {"name": "sensitivity-mask", "seed": raw["seed"], "seeds": int(seeds),
            "masks": ["full", "no_turns_window"], "session_s": raw.get("session_s", 4000.0),
            "defaults": raw["defaults"], "grid": grid, "epochs": {"seeds": "all"}}
    return Spec.from_dict(data, source="sensitivity (wider no-turns mask)", base_dir=PRESETS_DIR)


def wide_mask(turning: np.ndarray, window: np.ndarray, d: int) -> np.ndarray:
    """(n,) bool: estimates (one per epoch, in order) whose window of ``window`` epochs
    ending at them, widened by ``d`` epochs on both sides, holds no turning epoch."""
    c = np.concatenate([[0], np.cumsum(np.asarray(turning, dtype=int))])
    k, n = np.arange(len(c) - 1), len(c) - 1
    return c[np.clip(k + d + 1, 0, n)] - c[np.clip(k - np.asarray(window) + 1 - d, 0, n)] == 0


def mask_cells(cells: pd.DataFrame, out: Path, rate_hz: float = 1.0) -> pd.DataFrame:
    """Per seed and widening: std of |x|, |y| of LC on the full path and under the widened
    no-turns mask (ddof 1, as estimator.metrics), as claim-table rows with ``dilate_s``."""
    import pandas as pd

    from experiments.claims import P1

    rows = []
    for r in cells[cells["mask"] == "full"].itertuples():
        e = pd.read_parquet(out / "epochs" / f"{r.key}.parquet")
        ok = np.isfinite(e["err_x"].to_numpy())
        for d in DILATE_S:
            keep = ok & wide_mask(e["truth_turning"].to_numpy(bool), e["window"].to_numpy(int),
                                  int(round(d * rate_hz)))
            for mask, mk in (("full", ok), ("no_turns_window", keep)):
                rows.append({"path": P1, "window": r.window, "weighting": "huff",
                             "technique": "lc", "mask": mask, "seed": r.seed, "dilate_s": d,
                             "dropped": 1 - mk.sum() / ok.sum(), **{
                                 f"e{a}_std": float(np.abs(e[f"err_{a}"][mk]).std(ddof=1))
                                 for a in "xy"}})
    return pd.DataFrame(rows)


def evaluate_mask(rows: pd.DataFrame) -> pd.DataFrame:
    """C14 (LC full path std > LC no turns std) per widening: verdict, supports below
    window 100, and the share of the w=5 estimates the widened mask drops."""
    import pandas as pd

    from experiments.claims import CLAIMS, evaluate_claims

    c14 = next(c for c in CLAIMS if c.cid == "C14")
    out = []
    for d, g in rows.groupby("dilate_s"):
        res = evaluate_claims(g.drop(columns="dilate_s"), [c14])[0]
        outs = [o for o in res.outcomes if o.result != "missing"]
        small = [o for o in outs if o.comparison.a["window"] < 100]
        drop5 = g[(g["window"] == 5) & (g["mask"] == "no_turns_window")]["dropped"].mean()
        out.append({"dilate_s": d, "verdict": res.verdict, "supports": sum(
            o.result == "supports" for o in outs), "evaluated": len(outs),
            "small_supports": sum(o.result == "supports" for o in small),
            "small_evaluated": len(small), "dropped_w5": drop5,
            "diff_w5_x": small[0].diff if small else math.nan})
    return pd.DataFrame(out)


# --------------------------------------------------------------------------- bounds
def speed_bound(rate_hz: float = 1.0, window: int = 100) -> tuple[float, float]:
    """(low, high) cruise speed (m/s) the published Path 1 "None" rows allow: on a straight
    a window of s samples trails by (s - 1) v / (2 rate), along x on half of the path, so
    mean |x| ~ (s - 1) v / (4 rate) + noise; the noise adds at most the window-10 value
    (low: published w=100 minus w=10, high: all of w=100; both axes)."""
    from experiments.tables import THESIS_TABLES

    k = (window - 1) / (4 * rate_hz)
    pub = {ax: (THESIS_TABLES[ax][(window, "None")]["mean"],
                THESIS_TABLES[ax][(10, "None")]["mean"]) for ax in ("x", "y")}
    return (min((a - b) / k for a, b in pub.values()), max(a / k for a, _ in pub.values()))


def _acf(k, tau: float, order: int):
    """Gauss-Markov ACF at lag k (samples) for pole time constant ``tau`` (samples)."""
    u = np.asarray(k, dtype=float) / tau
    return np.exp(-u) * (1 + u) if order == 2 else np.exp(-u)


def tau_bounds(n: int, order: int, s: int = 10, shrink: float = 0.10) -> tuple[float, float]:
    """(low, high) time constant (s at 1 Hz) the stationary text allows for a Gauss-Markov
    error of ``order``. Low: Section 4.3, the ACF of every sensor's coordinates exceeds the
    bounds 1.96 / sqrt(n) at every lag of R's default plot (lag.max = 10 log10 n). High:
    Section 4.7, a "definite decrease in the spread" from window 1 to ``s`` (read, as in
    experiments.stationary_claims, as at least ``shrink``): the std of an s-sample mean is
    sqrt((1 + 2 sum_k (1 - k/s) r(k)) / s) times the one-sample std."""
    from scipy.optimize import brentq

    lag = int(10 * math.log10(n))
    lo = brentq(lambda t: _acf(lag, t, order) - 1.96 / math.sqrt(n), 1e-2, 1e5)
    k = np.arange(1, s)

    def ratio(t: float) -> float:
        return math.sqrt((1 + 2 * np.sum((1 - k / s) * _acf(k, t, order))) / s)

    return lo, brentq(lambda t: ratio(t) - (1 - shrink), 1e-2, 1e5)


def sigma_bound(main: pd.DataFrame, sigma: float) -> tuple[float, float]:
    """(low, high) sigma_m (m) that would bring our Path 1 "None" mean |x|, |y| at windows 5
    and 10 onto the published ones, if the CG error scaled with sigma (the Gauss-Markov
    part dominates it): sigma times the smallest and largest published / ours ratio."""
    from experiments.claims import P1, _per_seed
    from experiments.tables import THESIS_TABLES

    r = [THESIS_TABLES[ax][(w, "None")]["mean"] / _per_seed(main, {
        "path": P1, "window": w, "weighting": "huff", "technique": "none", "mask": "full"},
        f"e{ax}_mean").mean() for w in (5, 10) for ax in ("x", "y")]
    return sigma * min(r), sigma * max(r)


def shipped() -> dict[str, float]:
    """The shipped value of every quantity, read from its model / path file."""
    from experiments.claims import P1
    from sim.gps import GpsNoiseModel
    from sim.paths import load_path

    m, p = GpsNoiseModel.load("gps_stationary"), load_path(P1).to_dict()
    return {q.name: float(getattr(m, q.field) if q.axis == "noise" else p[q.field])
            for q in QUANTITIES}


def shipped_table(ship: dict[str, float]) -> pd.DataFrame:
    """``shipped.csv``: one row per :data:`QUANTITIES` entry (quantity, field, axis, unit,
    value: the shipped value in SI units ``unit``, from :func:`shipped`)."""
    import pandas as pd

    return pd.DataFrame([{"quantity": q.name, "field": q.field, "axis": q.axis, "unit": q.unit,
                          "value": ship[q.name]} for q in QUANTITIES])


def write_tables(out: Path, tables: dict[str, pd.DataFrame]) -> None:
    """Write each table as ``out/<name>.csv`` (6 significant digits, atomically)."""
    for name, df in tables.items():
        atomic_write(out / f"{name}.csv",
                     lambda f, df=df: df.to_csv(f, index=False, float_format="%.6g"))


# --------------------------------------------------------------------------- report
def _bounds_text(main: pd.DataFrame, ship: dict[str, float], n_session: int) -> dict[str, str]:
    s_lo, s_hi = sigma_bound(main, ship["sigma"])
    v_lo, v_hi = speed_bound()
    t1, t2 = tau_bounds(n_session, 1), tau_bounds(n_session, 2)
    return {
        "sigma": (f"no number in the stationary text (Sections 4.1.1-4.8 print none; the "
                  f"figures are images). From Tables 4.1/4.2: the published None means at "
                  f"windows 5/10 are {s_lo / ship['sigma']:.2f}-{s_hi / ship['sigma']:.2f} x "
                  f"ours, i.e. sigma_m {s_lo:.2f}-{s_hi:.2f} m if the CG error scaled with it"),
        "speed": (f"not stationary. Tables 4.1/4.2 window-100 None (mean |x| ~ 99 v / 4 + "
                  f"noise, noise at most the window-10 value): {v_lo:.3f}-{v_hi:.3f} m/s"),
        "common_fraction": ("Section 4.2 (Figs 4.4-4.6): the pairwise distances vary over "
                            "time, so the per-receiver part is not 0 (< 1); no number. The "
                            "published orientation (claim C9, thesis REPORT 'Heading "
                            "observability') needs >= 0.99"),
        "tau": (f"Section 4.3: the coordinates' ACF exceeds 1.96/sqrt(n) at every lag of R's "
                f"default plot (n = {n_session}, lag {int(10 * math.log10(n_session))}): "
                f"tau >= {t1[0]:.1f} s (order 1) / {t2[0]:.1f} s (order 2). Section 4.7: a "
                f"'definite decrease' (>= 10 %) of the spread from window 1 to 10: tau <= "
                f"{t1[1]:.1f} s (order 1) / {t2[1]:.1f} s (order 2). Together: {t1[0]:.0f}-"
                f"{t1[1]:.0f} s for an AR(1) error, and no order-2 (shipped) time constant "
                "satisfies both: the text implies a faster error than the shipped one"),
        "turn_width": ("Section 4.9: 'target areas of a certain diameter', not printed; "
                       "the turning flag marks the curve the target area makes"),
    }


def _cell(r: pd.Series) -> str:
    return f"{r.value:g}: **{r.verdict}** ({r.supports}/{r.evaluated})"


def write_report(sens: pd.DataFrame, turns: pd.DataFrame, out: Path, bounds: dict[str, str],
                 ship: dict[str, float], seeds: int, mask: pd.DataFrame | None = None,
                 quantities=QUANTITIES, command: str | None = None) -> Path:
    """REPORT.md: ranges and their derivation, the flips table, the full verdict matrix, for
    ``quantities`` (those ``sens`` holds); ``command`` is the one named as its generator
    (default: the reference command at ``seeds``)."""
    command = command or f"python -m experiments.sensitivity --reference --seeds {seeds}"
    lines = ["# Sensitivity of the thesis claims' verdicts (issue 28)", "",
             (f"Every claim of the thesis REPORT.md (experiments/claims.py, the same rule) "
              f"re-evaluated with one quantity moved at a time, on the thesis preset's grids "
              f"{', '.join(GRIDS)} (Path 1 and 2; without LC, smoothed heading), {seeds} seeds "
              f"(the thesis preset: 10), against the shipped setting run with the same seeds. "
              f"Generated by `{command}` "
              "(its wall time is in run.local.json); nothing typed by hand."), "",
             "## Quantities and ranges", "",
             md_row(["Quantity", "Field", "Shipped", "Tried", "Why these", "Shipped value is",
                     "Bound from the dissertation"]), md_separator(7)]
    for q in quantities:
        lines.append(md_row([q.name, f"`{q.field}` ({q.axis}, {q.unit})", f"{ship[q.name]:g}",
                             ", ".join(f"{v:g}" for v in q.values), q.why, q.kind,
                             bounds[q.name]]))
    flips = sens[sens.flipped & (sens.quantity != "shipped")]
    lines += ["", "## Verdicts that flip", "",
              ("Per claim, the values at which its verdict differs from the shipped "
               "setting's (supports / comparisons in brackets)."), "",
              md_row(["Claim", "Shipped", *[q.name for q in quantities]]),
              md_separator(2 + len(quantities))]
    base = sens[sens.quantity == "shipped"].set_index("claim")
    for cid in (c for c in dict.fromkeys(sens.claim) if c in set(flips.claim)):
        f = flips[flips.claim == cid]
        b = base.loc[cid]
        lines.append(md_row([cid, f"{b.verdict} ({b.supports}/{b.evaluated})", *[
            "; ".join(_cell(r) for r in f[f.quantity == q.name].itertuples()) or "-"
            for q in quantities]]))
    steady = [c for c in base.index if c not in set(flips.claim)]
    lines += ["", f"No flip anywhere: {', '.join(steady) or 'none'}.", "",
              "Flips per quantity: " + ", ".join(
                  f"{q.name} {int((flips.quantity == q.name).sum())}" for q in quantities), ""]
    lines += _seed_check(sens, seeds) + _mask_md(mask) + _matrix(sens) + _turns_md(turns)
    path = out / "REPORT.md"
    atomic_write_text(path, "\n".join(lines))
    return path


def _label(r) -> str:
    return "shipped" if r.quantity == "shipped" else f"{r.quantity} {r.value:g}"


def _seed_check(sens: pd.DataFrame, seeds: int) -> list[str]:
    """The shipped setting at ``seeds`` seeds against the committed thesis run (10 seeds):
    the claims whose verdict differs, i.e. those the reduced seed count alone decides."""
    import pandas as pd

    f = RESULTS_ROOT / "thesis" / "claims.csv"
    if not f.exists():
        return []
    ref = pd.read_csv(f).drop_duplicates("claim").set_index("claim")["verdict"]
    base = sens[sens.quantity == "shipped"].set_index("claim")
    diff = [f"{c} ({ref[c]} with 10, {base.loc[c, 'verdict']} with {seeds})"
            for c in base.index if c in ref.index and ref[c] != base.loc[c, "verdict"]]
    return ["## Seeds", "", (f"The shipped setting with {seeds} seeds against the committed "
            f"thesis run (results/thesis/claims.csv, 10 seeds): "
            + (f"{len(diff)} verdicts differ: {'; '.join(diff)}. A flip of these claims "
               "above may be seed noise as much as the quantity." if diff
               else "every verdict is the same.")), ""]


def _mask_md(mask: pd.DataFrame | None) -> list[str]:
    if mask is None or mask.empty:
        return []
    lines = ["## C14 under a wider no-turns mask", "",
             ("LC Full Path std > LC No Turns std (Path 1, Huff), with every estimate dropped "
              "whose window, widened by the given time on both sides, holds a turning epoch "
              "(per-epoch errors of the shipped setting; widening 0 = the sweep's mask)."), "",
             md_row(["Widening (s)", "w=5 estimates dropped", "Verdict", "supports below w=100",
                     "w=5 std |x| full - no turns (m)"]), md_separator(5)]
    for r in mask.itertuples():
        lines.append(md_row([f"{r.dilate_s:g}", f"{100 * r.dropped_w5:.1f} %", r.verdict,
                             f"{r.small_supports}/{r.small_evaluated}", f"{r.diff_w5_x:+.4f}"]))
    return lines + [""]


def _matrix(sens: pd.DataFrame) -> list[str]:
    short = {"reproduced": "R", "mixed": "M", "not reproduced": "N", "not evaluated": "-"}
    cols = list(dict.fromkeys(_label(r) for r in sens.itertuples()))
    lines = ["## All verdicts", "", "R reproduced, M mixed, N not reproduced; k/n supports.",
             "", md_row(["Claim", *cols]), md_separator(1 + len(cols))]
    for cid, g in sens.groupby("claim", sort=False):
        lines.append(md_row([cid, *[f"{short[r.verdict]} {r.supports}/{r.evaluated}"
                                    for r in g.itertuples()]]))
    return lines + [""]


def _turns_md(turns: pd.DataFrame) -> list[str]:
    if turns.empty:
        return []
    ws = sorted(set(turns.window))
    lines = ["## Estimates with a turn in their window", "",
             "Share of the LC estimates (Path 1, Huff) whose window holds a turning epoch.", "",
             md_row(["Variant", *[f"w={w}" for w in ws]]), md_separator(1 + len(ws))]
    by = {}
    for r in turns.itertuples():
        by.setdefault(_label(r), {})[r.window] = r.turn_share
    for lab, d in by.items():
        lines.append(md_row([lab, *[f"{100 * d[w]:.1f} %" if w in d else "n/a" for w in ws]]))
    return lines + [""]


# --------------------------------------------------------------------------- CLI
_EPILOG = """examples:
  python -m experiments.sensitivity --seeds 3 --out /tmp/sens
  python -m experiments.sensitivity --quantity sigma --seeds 1 --out /tmp/sens_sigma"""


def _parse(argv: list[str] | None):
    """The options; ``a.quantities``: the selected :data:`QUANTITIES`, in their order."""
    from experiments.cli import ArgumentParser, jobs_arg, positive_int

    p = ArgumentParser(prog="python -m experiments.sensitivity", epilog=_EPILOG,
                       description=__doc__.split("\n\n")[0],
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--reference", action="store_true",
                   help="write the committed reference results/sensitivity/ (the full study)")
    p.add_argument("--out", type=Path, help=f"output folder (default {LOCAL})")
    p.add_argument("--seeds", type=positive_int, default=5, help="seeds per variant (default 5)")
    p.add_argument("--quantity", action="append", metavar="NAME",
                   choices=[q.name for q in QUANTITIES],
                   help=("vary only this quantity (repeatable; default all: "
                         f"{', '.join(q.name for q in QUANTITIES)})"))
    p.add_argument("--jobs", type=jobs_arg, help="worker processes (default: all cores)")
    a = p.parse_args(argv)
    if a.reference and a.out:
        p.error("--out: not with --reference (the reference folder is fixed)")
    if a.reference and a.quantity:
        p.error(f"--quantity {a.quantity[0]}: not with --reference (the reference is the "
                "full study of every quantity)")
    a.quantities = tuple(q for q in QUANTITIES if not a.quantity or q.name in a.quantity)
    return a


def _command(a) -> str:
    """The command line that reproduces this run's REPORT (without --out / --jobs)."""
    return " ".join(["python -m experiments.sensitivity", *(["--reference"] * a.reference),
                     f"--seeds {a.seeds}", *(f"--quantity {n}" for n in a.quantity or ())])


def _run_cells(spec: Spec, folder: Path, jobs: int | None):
    """The runner's results of ``spec`` in ``folder`` (cells resumed or computed); None
    (said on stderr) if any cell failed."""
    from experiments.runner.run import run

    res = run(spec, out=folder, jobs=jobs, outputs=False)
    if res.n_failed:
        print(f"error: {res.n_failed} cells failed (see {res.out_dir}/errors.json)",
              file=sys.stderr)
        return None
    return res


def main(argv: list[str] | None = None) -> int:
    """Run the variants through the runner, evaluate, write the outputs (module docstring)."""
    a = _parse(argv)   # first: --help and usage errors need none of the imports below
    from experiments.claims import _derived
    from experiments.tables import faithful, numpy_strings

    qs = a.quantities
    out = REFERENCE if a.reference else (a.out or LOCAL)
    t0 = time.perf_counter()
    spec = sensitivity_spec(a.seeds, qs)
    print(f"sensitivity: {len(variants(qs))} variants x {len(GRIDS)} grids, {a.seeds} seeds, "
          f"{len(spec.expand())} cells", file=sys.stderr)
    res = _run_cells(spec, LOCAL / "sweep", a.jobs)
    if res is None:
        return 1
    print("sensitivity: C14 under a widened no-turns mask", file=sys.stderr)
    mres = _run_cells(mask_spec(a.seeds), LOCAL / "mask", a.jobs)
    if mres is None:
        return 1
    mask = evaluate_mask(mask_cells(numpy_strings(mres.cells), mres.out_dir))
    print("sensitivity: evaluating the claims per variant", file=sys.stderr)
    sens, comps, turns = evaluate_variants(res.cells, qs)
    ship = shipped()
    main_cells = _derived(faithful(_subset(numpy_strings(res.cells), None, {})))
    bounds = _bounds_text(main_cells, ship, n_session=_session_samples(spec))
    out.mkdir(parents=True, exist_ok=True)
    write_tables(out, {"sensitivity": sens, "comparisons": comps, "turns": turns, "mask": mask,
                       "shipped": shipped_table(ship)})
    wall = time.perf_counter() - t0
    print(write_report(sens, turns, out, bounds, ship, a.seeds, mask, qs, _command(a)))
    atomic_write_text(out / "run.local.json", json.dumps(
        {"wall_s": wall, "run": res.summary(), "seeds": a.seeds,
         "quantities": [q.name for q in qs]}, indent=1))
    print(f"sensitivity: done in {wall:.1f} s", file=sys.stderr)
    return 0


def _session_samples(spec: Spec) -> int:
    """Samples of the stationary session after the power failure (Section 4.1.1), at 1 Hz."""
    from sim.gps import GpsNoiseModel

    m = GpsNoiseModel.load("gps_stationary")
    return int(spec.session_s - m.power_failure_start_s - m.power_failure_duration_s)


if __name__ == "__main__":
    from experiments.cli import run as run_cli

    run_cli(main)
