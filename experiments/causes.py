"""Why a claim does not reproduce: the ``Cause:`` lines and the evidence sections of REPORT.md.

A verdict of "mixed" or "not reproduced" (:mod:`experiments.report`) is only useful with its
measured cause. For every such claim this module writes one line beginning ``Cause:`` that
names the cause and points to the rows or the study that show it, with the numbers read
from the same sweep; nothing is typed by hand. The causes, each shown by rows of the sweep:

- heading observability: the lag correction of Section 3.4.2 shifts each estimate along
  the estimated heading; re-evaluating the claim with the oracle rows (the same correction
  fed the simulator's heading, :data:`experiments.spec.ORACLE_TECHNIQUES`) shows whether a
  right heading would make it hold; the side study over the GPS error's common fraction
  shows how good the heading is under each noise split (:func:`observability_section`);
- step 2 of Section 3.4.2: its distance is Euclidean, so >= 0, and biased upward by
  single-epoch noise when the trail is small; shown by the oracle (right heading, still
  worse) against the course variant (signed along-track distance);
- noise autocorrelation: averaging a window of an error correlated over minutes barely
  shrinks it; shown by the motion-compensated rows (the same window without its lag) and
  by the heading error on the straights;
- shared noise and single runs: conditions that differ only on the few estimates whose
  window holds a turn cannot differ by much on shared noise; the published rows differ by
  more than our "None" rows vary from seed to seed (:func:`seed_spread_section`);
- speed and path: a window's trail is ``(s - 1) v / (2 rate)`` on a straight, whatever the
  path; the dissertation does not state its speed;
- the turns: a long window's trail swings round each corner;
- the growth rule of the dynamic window: Dyn SW under the other rule.

Each function returns text only where its numbers are present; a sweep that lacks the rows
(e.g. no oracle rows) gets a line saying which rows would show the cause.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from experiments.claims import (
    P1,
    ClaimResult,
    _derived,
    _per_seed,
    _straight,
    _wlabel,
    evaluate_claims,
    swap_techniques,
)
from experiments.markdown import md_row, md_separator
from experiments.spec import REPO, sensitivity_folder
from experiments.tables import (
    THESIS_TABLES,
    THESIS_WINDOWS,
    faithful,
    seed_ci,
    select,
)
from experiments.techniques import oracle_pairs

__all__ = ["ORACLE_SWAP", "SENSITIVITY_TABLES", "Evidence", "Sensitivity", "cause_line",
           "declared_sensitivity", "evidence", "observability_section", "seed_spread_section"]

#: The estimated-heading lag correction -> its oracle (the simulator's heading).
ORACLE_SWAP = oracle_pairs()
#: Below this median heading error (deg) the estimated orientation "matches" (claim C9).
MATCH_DEG = 10.0
#: The sensitivity study's tables (``python -m experiments.sensitivity``) a declared folder
#: must hold for C2, C8 and the small-window claims to quote its re-measurements (mask.csv
#: and turns.csv are optional: without them their sentences are left out).
SENSITIVITY_TABLES = ("sensitivity", "comparisons", "shipped")


@dataclass(frozen=True)
class Sensitivity:
    """The sensitivity study the run's spec declared (``[report] sensitivity``): ``value`` as
    written (None: none declared), ``path`` its folder resolved (None: not declared or no
    sensitivity.csv there, :func:`experiments.spec.sensitivity_folder`)."""

    value: str | None = None
    path: Path | None = None

    @property
    def folder(self) -> Path | None:
        """``path`` when it holds every one of :data:`SENSITIVITY_TABLES`, else None."""
        ok = self.path is not None and all((self.path / f"{n}.csv").is_file()
                                           for n in SENSITIVITY_TABLES)
        return self.path if ok else None

    def table(self, name: str) -> pd.DataFrame:
        """``<folder>/<name>.csv``, empty when there is no folder or no such file."""
        f = None if self.folder is None else self.folder / f"{name}.csv"
        return pd.read_csv(f) if f is not None and f.is_file() else pd.DataFrame()

    def shipped(self, quantity: str) -> float:
        """The shipped value of ``quantity`` (SI units, the study's shipped.csv)."""
        t = self.table("shipped")
        return float(t.loc[t["quantity"] == quantity, "value"].iloc[0])

    def missing(self, what: str = "") -> str:
        """The sentence that stands where the study's numbers would (``what``: with what)."""
        if self.value is None:
            return (f" Not re-measured{what}: the spec declares no sensitivity study "
                    "([report] sensitivity).")
        return (f" Not re-measured{what}: {self.value} ([report] sensitivity) lacks the "
                f"sensitivity study's {', '.join(f'{n}.csv' for n in SENSITIVITY_TABLES)} "
                "(python -m experiments.sensitivity writes them).")


def declared_sensitivity(results: str | Path, spec=None) -> Sensitivity:
    """The sensitivity study of a run: ``spec``'s ``[report] sensitivity`` or, without a
    spec, what the run's manifest.json recorded, resolved against the spec's folder by
    :func:`experiments.spec.sensitivity_folder`. A bad value raises SpecError naming the
    field; a missing or damaged manifest declares none."""
    if spec is not None:
        value = (spec.report or {}).get("sensitivity")
        base, where = (None if spec.direct_paths else spec.base_dir), \
            f"{spec.source}: report.sensitivity"
    else:
        try:
            man = json.loads((Path(results) / "manifest.json").read_text())
        except (OSError, ValueError):
            man = {}
        sp = man.get("spec") if isinstance(man, dict) else None
        tab = sp.get("report") if isinstance(sp, dict) else None
        value = tab.get("sensitivity") if isinstance(tab, dict) else None
        b = Path(str(man.get("spec_base_dir", "."))) if isinstance(man, dict) else Path(".")
        base = b if b.is_absolute() else REPO / b
        where = "manifest.json: spec.report.sensitivity"
    if value is None:
        return Sensitivity()
    return Sensitivity(value, sensitivity_folder(value, base, where))


@dataclass
class Evidence:
    """What the Cause lines are measured from.

    cells : one variant's cells with every reading and oracle row (pseudo-conditions of
    :func:`experiments.claims._derived` added). main : the cells the claims were evaluated
    on (the faithful readings). studies : the side studies of the whole sweep
    (:func:`experiments.tables.side_studies`). sensitivity : the sensitivity study the
    spec declared (:func:`declared_sensitivity`; default none).
    """

    cells: pd.DataFrame
    main: pd.DataFrame
    studies: pd.DataFrame
    sensitivity: Sensitivity = field(default_factory=Sensitivity)


# --------------------------------------------------------------------------- helpers
def _m(cells: pd.DataFrame, metric: str, **where) -> float:
    """Mean over seeds of ``metric`` for the condition (NaN when absent)."""
    v = _per_seed(cells, where, metric)
    v = v[np.isfinite(v.to_numpy())] if len(v) else v
    return float(v.mean()) if len(v) else math.nan


def _ok(*vals: float) -> bool:
    return all(np.isfinite(v) for v in vals)


def _tw(cells: pd.DataFrame) -> str:
    ws = set(select(cells, technique=["lc", "dyn", "lc+dyn"])["weighting"])
    return "huff" if "huff" in ws or not ws else min(ws)


def _failing(r: ClaimResult) -> list:
    return [o for o in r.outcomes if o.result not in ("supports", "missing")]


def _windows_of(outcomes) -> list[int]:
    return sorted({int(o.comparison.a["window"]) for o in outcomes
                   if isinstance(o.comparison.a, dict) and "window" in o.comparison.a})


def _probe(ev: Evidence, r: ClaimResult, mapping: dict, cells: pd.DataFrame | None = None,
           windows: list[int] | None = None) -> tuple[int, int, str] | None:
    """Re-evaluate the claim with ``mapping`` applied to its techniques (its comparisons at
    ``windows`` only, default all): (supports, evaluated, verdict), or None when the sweep
    lacks the substituted rows."""
    sw = swap_techniques(r.claim, mapping, "", lambda s: s, keep_unchanged=not mapping)
    res = evaluate_claims(ev.main if cells is None else cells, [sw])[0]
    outs = [o for o in res.outcomes if o.result != "missing" and (
        windows is None or (isinstance(o.comparison.a, dict)
                            and o.comparison.a.get("window") in windows))]
    if not outs:
        return None
    k = sum(o.result == "supports" for o in outs)
    return k, len(outs), "reproduced" if k == len(outs) else \
        "not reproduced" if k == 0 else "mixed"


def _oracle_text(ev: Evidence, r: ClaimResult, windows: list[int] | None = None
                 ) -> str | None:
    """'fed the simulator's heading ... k/n' for a claim on the lag correction."""
    oracle_cells = _derived(pd.concat([ev.main, select(ev.cells, technique=list(
        ORACLE_SWAP.values()))]).drop_duplicates(["key", "mask"]))
    pr = _probe(ev, r, ORACLE_SWAP, faithful(oracle_cells), windows)
    if pr is None:
        return None
    k, n, v = pr
    at = f" at window {', '.join(map(str, windows))}" if windows else ""
    return (f"fed the simulator's heading instead (oracle rows \"Oracle: LC (simulator "
            f"heading)\" in Tables 4.1/4.2), the same comparisons{at} give {k}/{n} supports "
            f"(**{v}**)")


def _turn_share(ev: Evidence, windows: list[int], technique: str = "none") -> str | None:
    """'x % / y % of the estimates at windows ...' whose window holds a turning epoch."""
    if "no_turns_window" not in set(ev.main["mask"]):
        return None
    parts = []
    for w in windows:
        full = _m(ev.main, "n_epochs", path=P1, window=w, weighting=_tw(ev.main),
                  technique=technique, mask="full")
        free = _m(ev.main, "n_epochs", path=P1, window=w, weighting=_tw(ev.main),
                  technique=technique, mask="no_turns_window")
        if not _ok(full, free) or full <= 0:
            return None
        parts.append(f"{100 * (1 - free / full):.0f} % at w={w}")
    return ", ".join(parts)


def _published_too(outcomes) -> str:
    """Labels of failing comparisons the dissertation's own tables do not support either."""
    bad = [o.comparison.label for o in outcomes
           if o.thesis_result is not None and o.thesis_result != "supports"]
    if not bad:
        return ""
    return (" The dissertation's own Tables 4.1/4.2 do not support "
            + ("it" if len(bad) == 1 else f"{len(bad)} of them") + " either ("
            + "; ".join(bad[:3]) + ("; ..." if len(bad) > 3 else "") + ").")


def _path_speed(cells: pd.DataFrame, path: str) -> tuple[float, float] | None:
    """(cruise speed m/s, sample rate Hz) of a path as the variant ran it."""
    try:
        from sim.paths import load_path

        d = load_path(path).to_dict()
    except (ImportError, ValueError, OSError):
        return None
    ovs = set(cells.loc[cells["path"] == path, "path_overrides"]) \
        if "path_overrides" in cells else {"{}"}
    if len(ovs) == 1:
        d.update(json.loads(next(iter(ovs))))
    return float(d["cruise_speed_mps"]), float(d["sample_rate_hz"])


def _noise_model(cells: pd.DataFrame, overrides: str = "{}"):
    """The GPS noise model of the cells (None for sessions, several models or no simulator)."""
    names = set(cells["noise"]) if "noise" in cells else set()
    if len(names) != 1:
        return None
    name = next(iter(names))
    if name == "none" or name.startswith("session:"):
        return None
    try:
        from sim.gps import GpsNoiseModel

        model = GpsNoiseModel.load(name)
        ov = json.loads(overrides)
        return model.with_overrides(**ov) if ov else model
    except (ImportError, ValueError, TypeError, OSError):
        return None


def _baseline_m(cells: pd.DataFrame) -> float | None:
    """Longest distance between two alive sensors of the variant's configuration."""
    names = set(cells["config"]) if "config" in cells else set()
    if len(names) != 1:
        return None
    try:
        from estimator.configuration import SensorConfig

        cfg = SensorConfig.load(next(iter(names)))
    except (ValueError, OSError):
        return None
    alive = cfg.alive_mask
    return float(cfg.distances()[np.ix_(alive, alive)].max())


def _deg(rad: float) -> float:
    return math.degrees(rad) if np.isfinite(rad) else math.nan


# --------------------------------------------------------------------------- sensitivity
def _sens_rows(sens: Sensitivity, cid: str, quantity: str, unit: str
               ) -> list[tuple[str, str, pd.DataFrame]]:
    """[(label, "**verdict** (k/n)", comparisons)] of claim ``cid`` in the sensitivity
    study: the shipped setting, then each value of ``quantity``."""
    s, c = sens.table("sensitivity"), sens.table("comparisons")
    if s.empty or c.empty:
        return []
    ship, out = f"{sens.shipped(quantity):g}{unit} (shipped)", []
    for r in s[(s["claim"] == cid) & s["quantity"].isin(["shipped", quantity])].itertuples():
        same = (c["claim"] == cid) & (c["quantity"] == r.quantity)
        same &= c["value"].isna() if r.quantity == "shipped" else np.isclose(c["value"], r.value)
        out.append((ship if r.quantity == "shipped" else f"{r.value:g}{unit}",
                    f"**{r.verdict}** ({r.supports}/{r.evaluated})", c[same]))
    return out


def _sens_intro(sens: Sensitivity, rows: list, what: str) -> str:
    n = int(max(int(c["n_seeds"].max()) for _, _, c in rows if not c.empty))
    return (f" Re-measured with {what} (sensitivity study, {str(sens.value).rstrip('/')}/, "
            f"{n} seeds, its own shipped run beside): ")


def _speed_text(sens: Sensitivity) -> str:
    """C2 at other speeds: verdict and the Path 1 window-10 trail against the noise level."""
    rows = _sens_rows(sens, "C2", "speed", " m/s")
    if not rows:
        return sens.missing()
    parts = []
    for lab, vd, c in rows:
        o = c[c["comparison"].str.startswith("Path 1 w=10: trail")]
        parts.append(f"{lab} {vd}" + (f", w=10 along-track error {o['mean_a'].iloc[0]:+.2f} m "
                                      f"vs noise level {-o['mean_b'].iloc[0]:.2f} m"
                                      if len(o) else ""))
    return _sens_intro(sens, rows, "slower and faster speeds") + "; ".join(parts) + "."


def _fraction_gains(sens: Sensitivity) -> list[tuple[str, str, float]]:
    """[(common fraction, "**verdict** (k/n)", Huff's gain in the Path 1 w=1 mean |x|)] of
    C8 in the sensitivity study (gain NaN where the comparison is absent)."""
    out = []
    for lab, vd, c in _sens_rows(sens, "C8", "common_fraction", ""):
        o = c[c["comparison"] == "Path 1 w=1 mean |x|: huff < none"]
        out.append((lab, vd, 1 - o["mean_a"].iloc[0] / o["mean_b"].iloc[0] if len(o)
                    else math.nan))
    return out


def _fraction_text(sens: Sensitivity, gains: list[tuple[str, str, float]]) -> str:
    if not gains:
        return sens.missing()
    return (_sens_intro(sens, _sens_rows(sens, "C8", "common_fraction", ""),
                        "the common fraction varied")
            + "; ".join(f"common_fraction {lab} {vd}, Huff lowers the w=1 mean |x| by "
                        f"{100 * g:.1f} %" for lab, vd, g in gains) + ".")


def _mask_text(sens: Sensitivity) -> str:
    """C14 under a widened no-turns mask (sensitivity study, mask.csv)."""
    m = sens.table("mask")
    if m.empty:
        return ""
    return ("; with the no-turns mask widened instead (every estimate dropped whose window, "
            "widened on both sides, holds a turning epoch): " + "; ".join(
                f"{r.dilate_s:g} s, {100 * r.dropped_w5:.0f} % of the w=5 estimates dropped: "
                f"{r.small_supports}/{r.small_evaluated} supports (w=5 std |x| full minus no "
                f"turns {r.diff_w5_x:+.3f} m)" for r in m.itertuples()))


def _wide_text(sens: Sensitivity, cid: str) -> str:
    """Small-window comparisons of a turn claim with wider turns (larger target areas)."""
    rows = _sens_rows(sens, cid, "turn_width", " m")
    t = sens.table("turns")
    if not rows or t.empty:
        return "." + sens.missing(" with wider turns").rstrip(".")
    parts = []
    for lab, _, c in rows:
        small = c[(c["window"] > 0) & (c["window"] < 100)]
        k = int((small["result"] == "supports").sum())
        base = "shipped" in lab
        tt = t[(t["window"] == 5) & (t["quantity"] == ("shipped" if base else "turn_width"))]
        if not base:
            tt = tt[np.isclose(tt["value"], float(lab.split()[0]))]
        share = f", {100 * tt['turn_share'].iloc[0]:.0f} % of the w=5 estimates" if len(tt) else ""
        parts.append(f"target radius {lab}{share}: {k}/{len(small)} supports")
    return ("." + _sens_intro(sens, rows, "wider turns (larger target areas, so a wider "
                              "turning flag and no-turns mask)").rstrip(": ")
            + " below window 100: " + "; ".join(parts)
            + (_mask_text(sens) if cid == "C14" else ""))


# --------------------------------------------------------------------------- per claim
def _c1(ev: Evidence, r: ClaimResult) -> str | None:
    nt = _straight(ev.main)
    if nt == "no_turns":
        return None
    parts, holds = [], True
    for o in _failing(r):
        p = o.comparison.a["path"]
        w1, w0 = o.comparison.a["window"], o.comparison.b["window"]
        a = _m(ev.main, "jitter_rms", path=p, window=w1, technique="none", weighting="none",
               mask=nt)
        b = _m(ev.main, "jitter_rms", path=p, window=w0, technique="none", weighting="none",
               mask=nt)
        if not _ok(a, b):
            return None
        holds &= a < b
        parts.append(f"{_wlabel(p)} {a:.3f} m at w={w1} vs {b:.3f} m at w={w0} "
                     f"(full path {o.mean_a:.3f} vs {o.mean_b:.3f})")
    if not holds:
        return ("not the turns alone: on the straights too the larger window jitters more ("
                + "; ".join(parts) + "; `jitter_rms` per mask in by_cell.csv).")
    return ("the turns. A long window trails far behind, and at each corner the trail "
            "swings round, so the error changes fast there; on the straights (estimates whose "
            "window holds no turning epoch) the jitter falls with the window as claimed: "
            + "; ".join(parts) + ". Rows: `jitter_rms` per mask in by_cell.csv.")


def _c2(ev: Evidence, r: ClaimResult) -> str | None:
    nt = _straight(ev.main)
    parts = []
    for o in _failing(r):
        p, w = o.comparison.a["path"], int(o.comparison.a["window"])
        sp = _path_speed(ev.main, p)
        trail = -_m(ev.main, "along_mean", path=p, window=w, technique="none",
                    weighting="none", mask=nt)
        noise = -o.mean_b
        if sp is None or not _ok(trail, noise):
            return None
        expect = (w - 1) * sp[0] / (2 * sp[1])
        parts.append(f"{_wlabel(p)} w={w}: trail {trail:.2f} m (expected (s - 1) v / (2 rate) "
                     f"= {expect:.2f} m at {sp[0]:g} m/s) against a noise level of "
                     f"{noise:.2f} m, paired difference [{o.lo:.2f}, {o.hi:.2f}]")
    return ("speed. How apparent a trail is depends on the platform's speed, which the "
            "dissertation does not state (Set-up): " + "; ".join(parts) + "."
            + _speed_text(ev.sensitivity) + " `experiments/presets/speed.toml` re-checks the "
            "claims at 0.5 and 1.5 m/s.")


def _c3(ev: Evidence, r: ClaimResult) -> str | None:
    o = r.outcomes[0]
    sp1, sp2 = _path_speed(ev.main, P1), _path_speed(ev.main, "square200")
    if sp1 is None or sp2 is None:
        return None
    expect = [99 * v / (2 * rate) for v, rate in (sp1, sp2)]
    return (f"speed, not path. On a straight a window of s epochs trails by (s - 1) v / "
            f"(2 rate) whatever the path's length: {expect[0]:.1f} m on Path 1 ({sp1[0]:g} "
            f"m/s) and {expect[1]:.1f} m on Path 2 ({sp2[0]:g} m/s) at window 100; measured on "
            f"the straights {-o.mean_b:.2f} m and {-o.mean_a:.2f} m. A longer trail on Path 2 "
            "needs Path 2 driven faster (or sampled slower), which the dissertation does not "
            "state (Set-up).")


def _c4(ev: Evidence, r: ClaimResult) -> str | None:
    parts = []
    for p in dict.fromkeys(o.comparison.a["path"] for o in _failing(r)):
        w8 = "huff"
        mc = {w: _m(ev.cells, "ex_p95", path=p, window=w, technique="motion_compensated",
                    weighting=w8, mask="full") for w in (1, 10)}
        plain = _m(ev.main, "ex_p95", path=p, window=10, technique="none", weighting=w8,
                   mask="full")
        if not _ok(mc[1], mc[10], plain):
            return None
        parts.append(f"{_wlabel(p)}: p95 |x| {mc[10]:.2f} m at w=10 vs {mc[1]:.2f} m at "
                     f"w=1 without the lag (motion-compensated window, Huff), {plain:.2f} m "
                     "with it")
    model = _noise_model(ev.main)
    tau = (f" (per-receiver Gauss-Markov time constant {model.receiver_tau_s:g} s, common "
           f"part {model.common_tau_s:g} s, order {model.gm_order})") if model else ""
    return ("noise autocorrelation. The GPS error is correlated over minutes" + tau + ", so "
            "the 10 epochs of a window carry nearly the same error and averaging them does "
            "not shrink its tails; what the window adds is its trail. " + "; ".join(parts)
            + ". Rows: \"Motion-compensated\" (beyond rows of Table 4.1).")


def _c8(ev: Evidence, r: ClaimResult) -> str | None:
    w = min(_windows_of(r.outcomes), default=1)
    h = _m(ev.main, "ex_mean", path=P1, window=w, technique="none", weighting="huff",
           mask="full")
    n = _m(ev.main, "ex_mean", path=P1, window=w, technique="none", weighting="none",
           mask="full")
    if not _ok(h, n):
        return None
    model = _noise_model(ev.main)
    cf = (f" ({100 * model.common_fraction:.0f} % of the error variance here, "
          "common_fraction in the noise model)") if model else ""
    k, gains = len(_failing(r)), _fraction_gains(ev.sensitivity)
    moved = [(float(lab), g) for lab, _, g in gains if "shipped" not in lab]
    g0 = min(moved)[1] if moved else math.nan          # at the smallest common fraction
    why = ("not the common part of the error: with none of it common the gain stays small "
           "(below), so it is the per-receiver part, spread over all receivers rather than "
           "concentrated in a bad one, that leaves Huff (which down-weights a receiver whose "
           "distances disagree with the configuration, Section 3.3.3) little to act on"
           if np.isfinite(g0) and g0 < 0.05 else
           "the error common to all receivers" + cf + " moves them alike, so no weighting "
           "removes it, and the per-receiver part is spread over all receivers rather than "
           "concentrated in a bad one")
    return ("the error leaves the weights little to act on: " + why + ". Measured: Huff "
            f"lowers the mean |x| error "
            f"by {100 * (n - h) / n:.1f} % at window {w} on Path 1 ({h:.3f} vs {n:.3f} m), and "
            f"{k} of {len(r.outcomes)} comparisons are within seed noise (weighting table in "
            "tables.md)." + _fraction_text(ev.sensitivity, gains))


def _heading_by_fraction(ev: Evidence, window: int) -> list[tuple[str, float]]:
    """[(common fraction label, median heading error rad)] at ``window``, Path 1, Huff: the
    shipped noise and each side-study value."""
    out = []
    base = _m(ev.main, "eh_median", path=P1, window=window, technique="none",
              weighting="huff", mask="full")
    model = _noise_model(ev.main)
    if np.isfinite(base):
        out.append((f"{model.common_fraction:g} (shipped)" if model else "shipped", base))
    for ov in _study_fractions(ev):
        v = _m(ev.studies, "eh_median", path=P1, window=window, technique="none",
               weighting="huff", mask="full", noise_overrides=ov)
        if np.isfinite(v):
            out.append((f"{json.loads(ov)['common_fraction']:g}", v))
    return out


def _study_fractions(ev: Evidence) -> list[str]:
    """noise_overrides values of the side studies that set only the common fraction."""
    if ev.studies.empty or "noise_overrides" not in ev.studies:
        return []
    vals = [v for v in dict.fromkeys(ev.studies["noise_overrides"])
            if set(json.loads(v)) == {"common_fraction"}]
    return sorted(vals, key=lambda v: json.loads(v)["common_fraction"])


def _c9(ev: Evidence, r: ClaimResult) -> str | None:
    rows = _heading_by_fraction(ev, 1)
    if not rows:
        return None
    L = _baseline_m(ev.main)
    size = f"a {L:.1f} m platform" if L else "the platform"
    txt = ", ".join(f"{_deg(v):.1f} deg at common_fraction {lab}" for lab, v in rows)
    ok = [lab for lab, v in rows if _deg(v) < MATCH_DEG]
    end = (f"below {MATCH_DEG:g} deg only at {', '.join(ok)}" if ok else
           f"above {MATCH_DEG:g} deg in every setting of this sweep")
    return ("heading observability. The heading comes from the per-receiver part of the GPS "
            f"error across {size}; the part common to all receivers does not change it. Median "
            f"heading error at window 1 (Path 1, Huff): {txt}; {end}. See \"Heading "
            "observability\" below.")


def _c10(ev: Evidence, r: ClaimResult) -> str | None:
    nt = _straight(ev.main)
    if nt == "no_turns":
        return None
    v = {(w, m): _m(ev.main, "eh_median", path=P1, window=w, technique="none",
                    weighting="none", mask=m) for w in (1, 100) for m in ("full", nt)}
    if not _ok(*v.values()):
        return None
    return ("noise autocorrelation and the turns. On the straights (estimates whose window "
            f"holds no turning epoch) the median heading error is {_deg(v[100, nt]):.1f} deg at "
            f"w=100 vs {_deg(v[1, nt]):.1f} deg at w=1: 100 epochs of an error correlated over "
            "minutes average out little of it; over the full path the corners, where the "
            f"100-epoch window still holds the old heading, raise w=100 to "
            f"{_deg(v[100, 'full']):.1f} deg ({_deg(v[1, 'full']):.1f} at w=1). Rows: "
            "`eh_median` per mask in by_cell.csv; Figure 4.119.")


def _step2_text(ev: Evidence, windows: list[int]) -> str | None:
    """The lag correction at small windows: worse with the right heading too, not with a
    signed distance (course variant)."""
    w8 = _tw(ev.main)
    parts, oracle_worse, course_ok = [], True, True
    for w in windows:
        none = _m(ev.main, "ex_median", path=P1, window=w, weighting=w8, technique="none",
                  mask="full")
        lc = _m(ev.main, "ex_median", path=P1, window=w, weighting=w8, technique="lc",
                mask="full")
        orc = _m(ev.cells, "ex_median", path=P1, window=w, weighting=w8,
                 technique="lc_sim_heading", mask="full")
        crs = _m(ev.main, "ex_median", path=P1, window=w, weighting=w8, technique="lc_course",
                 mask="full")
        if not _ok(none, lc, orc, crs):
            return None
        oracle_worse &= orc > none
        course_ok &= crs <= none
        parts.append(f"w={w}: None {none:.3f}, LC {lc:.3f}, LC with the simulator's heading "
                     f"{orc:.3f}, LC (course) {crs:.3f} m")
    nums = "median |x| on Path 1, " + "; ".join(parts)
    if oracle_worse and course_ok:
        return ("at small windows, step 2 of Section 3.4.2, not the heading: the correction "
                "is worse than None even with the simulator's heading, and the course variant, "
                "which takes step 2's distance signed along the track, is not. Step 2's "
                "Euclidean distance is >= 0, so single-epoch noise biases it upward when the "
                f"trail is small, and the shift it produces is noise ({nums}; rows \"Oracle: LC "
                "(simulator heading)\" and \"LC (course)\" in Table 4.1)")
    return f"at small windows neither the heading nor step 2 alone ({nums})"


def _lc_claim(step2: bool, heading: bool) -> Callable[[Evidence, ClaimResult], str | None]:
    """Cause of a claim on the lag correction: step 2 at small windows and/or the heading."""

    def f(ev: Evidence, r: ClaimResult) -> str | None:
        bad = _failing(r)
        small = [w for w in _windows_of(bad) if w < 100]
        large = [w for w in _windows_of(bad) if w >= 100]
        parts = []
        if step2 and small:
            s2 = _step2_text(ev, small)
            if s2 is None:
                return None
            parts.append(s2)
        if heading and large:
            o = _oracle_text(ev, r, large)
            if o is None:
                return None
            parts.append("at window 100, heading observability: the correction shifts each "
                         "estimate by up to the trail (about 10 m) along the estimated heading, "
                         "so the heading error turns into a position error (see \"Heading "
                         "observability\"); " + o)
        if not parts:
            return None
        return "; ".join(parts) + "." + _published_too(bad)
    return f


def _turns_and_heading(what: str, heading: str
                       ) -> Callable[[Evidence, ClaimResult], str | None]:
    """Cause of a claim about the turns: few turn estimates at small windows, the heading at
    window 100. ``what``: what differs only on those estimates; ``heading``: how the heading
    error hides the claimed effect at window 100."""

    def f(ev: Evidence, r: ClaimResult) -> str | None:
        bad = _failing(r)
        small = [w for w in _windows_of(bad) if w < 100]
        large = [w for w in _windows_of(bad) if w >= 100]
        parts = []
        if small:
            share = _turn_share(ev, small, "lc")
            if share is None:
                return None
            at = f"at windows {', '.join(map(str, small))}"
            lead = (f"{at} few turn estimates: {what} only on the estimates with a turn in "
                    f"their window ({share}), too few to move these statistics beyond the seed "
                    "noise")
            m = ev.sensitivity.table("mask") if r.claim.cid == "C14" else pd.DataFrame()
            if not m.empty and (m["small_supports"] == 0).all():
                w = m.iloc[-1]
                lead = (f"{at} not the few turn estimates ({share}) alone: with the no-turns "
                        f"mask widened by {w.dilate_s:g} s ({100 * w.dropped_w5:.0f} % of the "
                        f"w=5 estimates dropped) the full path's spread still exceeds the "
                        f"straights' by only {w.diff_w5_x:+.3f} m (w=5, std |x|), so at small "
                        "windows the turns add no outliers to the lag-corrected error")
            parts.append(lead + _wide_text(ev.sensitivity, r.claim.cid))
        if large:
            o = _oracle_text(ev, r, large)
            if o is None:
                return None
            parts.append(f"at window 100, heading observability: {heading}; " + o)
        return ("; ".join(parts) + "." + _published_too(bad)) if parts else None
    return f


def _shared_noise_text(ev: Evidence, windows: list[int]) -> str | None:
    """Dyn SW vs None at small windows: shared noise, single runs."""
    share = _turn_share(ev, windows)
    if share is None:
        return None
    w8 = _tw(ev.main)
    w = windows[0]
    d = (_per_seed(ev.main, {"path": P1, "window": w, "weighting": w8, "technique": "dyn",
                                 "mask": "full"}, "ex_mean")
         - _per_seed(ev.main, {"path": P1, "window": w, "weighting": w8, "technique": "none",
                                   "mask": "full"}, "ex_mean")).dropna()
    pub = THESIS_TABLES["x"].get((w, "Dyn SW"), {}).get("mean", math.nan) \
        - THESIS_TABLES["x"].get((w, "None"), {}).get("mean", math.nan)
    if d.empty or not np.isfinite(pub):
        return None
    return (f"Dyn SW against None at windows {', '.join(map(str, windows))}: shared noise and "
            f"single runs. The two differ only on the estimates whose window holds a turn "
            f"({share}); on the same noise their mean |x| differs by {d.min():+.3f} to "
            f"{d.max():+.3f} m per seed at w={w}, while the published rows differ by "
            f"{pub:+.3f} m, more than our None rows vary from seed to seed (\"Single runs and "
            "seed spread\" below): the published rows look like separate single runs")


def _c18(ev: Evidence, r: ClaimResult) -> str | None:
    bad = _failing(r)
    parts = []
    lc_small = [w for w in _windows_of([o for o in bad if "LC" in o.comparison.label])
                if w < 100]
    if lc_small:
        s2 = _step2_text(ev, lc_small)
        if s2 is None:
            return None
        parts.append("LC and LC + Dyn SW " + s2)
    dyn_small = [w for w in _windows_of([o for o in bad if o.comparison.label.split(": ")[-1]
                                         .startswith("Dyn SW")]) if w < 100]
    if dyn_small:
        sn = _shared_noise_text(ev, dyn_small)
        if sn is None:
            return None
        parts.append(sn)
    large = [o for o in bad if o.comparison.a.get("window") == 100]
    if large:
        parts.append("at window 100 the dynamic window shortens only the estimates near the "
                     "turns and keeps the trail on the straights, which does not narrow the "
                     "spread of the error: " + "; ".join(
                         f"{o.comparison.label} ({o.mean_a:.3f} vs {o.mean_b:.3f} m"
                         + (f"; published {o.comparison.thesis[0]:.3f} vs "
                            f"{o.comparison.thesis[1]:.3f}, {o.thesis_result}"
                            if o.comparison.thesis else "") + ")" for o in large))
    if not parts:
        return None
    return "; ".join(parts) + "." + _published_too(bad)




def _course_small(ev: Evidence, r: ClaimResult) -> str | None:
    """Course-variant claims at small windows: the trail it removes is small."""
    bad = _failing(r)
    nt = _straight(ev.main)
    parts = []
    small = [w for w in _windows_of(bad) if w < 100]
    w8 = _tw(ev.main)
    for w in small:
        a0 = _m(ev.main, "along_mean", path=P1, window=w, weighting=w8, technique="none",
                mask=nt)
        a1 = _m(ev.main, "along_mean", path=P1, window=w, weighting=w8, technique="lc_course",
                mask=nt)
        e = _m(ev.main, "ex_mean", path=P1, window=w, weighting=w8, technique="none",
               mask="full")
        if not _ok(a0, a1, e):
            return None
        parts.append(f"w={w}: mean along-track error on the straights {a0:+.2f} m without, "
                     f"{a1:+.2f} m with it, against a mean |x| error of {e:.2f} m")
    out = []
    if parts:
        out.append("at windows " + ", ".join(map(str, small)) + " the trail is small: the "
                   "course correction removes it, but it is a small part of the error, and "
                   "the paired differences straddle 0 over the seeds (" + "; ".join(parts) + ")")
    for o in (o for o in bad if o.comparison.a.get("window") == 100):
        t = _refill_text(ev, o)
        if t is None:
            return None
        out.append(t)
    return ("; ".join(out) + ".") if out else None


def _refill_text(ev: Evidence, o) -> str | None:
    """A comparison against Dyn SW at window 100 that the refill rule makes close."""
    b = o.comparison.b
    if not isinstance(b, dict) or b.get("technique") != "dyn" or "dyn_growth" not in ev.cells:
        return None
    metric = o.comparison.metric
    jump = _m(ev.cells, metric, **{**b, "dyn_growth": "jump"})
    if not np.isfinite(jump):
        return None
    return (f"at window 100 the refilling dynamic window is strong: its estimates after each "
            f"turn keep short windows while the queue refills, which lowers Dyn SW's "
            f"`{metric}` to {o.mean_b:.3f} m (jump rule: {jump:.3f} m); {o.comparison.label}: "
            f"{o.mean_a:.3f} vs {o.mean_b:.3f} m, within seed noise [{o.lo:.3f}, {o.hi:.3f}]")


def _course_turns(ev: Evidence, r: ClaimResult) -> str | None:
    """Course-variant claims about turns at small windows: few turn estimates."""
    bad = _failing(r)
    small = [w for w in _windows_of(bad) if w < 100]
    share = _turn_share(ev, small, "lc_course") if small else None
    if share is None or len(small) < len(_windows_of(bad)):
        return None
    return (f"few turn estimates: at windows {', '.join(map(str, small))} only the estimates "
            f"with a turn in their window ({share}) can differ between the compared "
            "conditions, which moves these statistics by less than the seed noise.")


_CAUSES: dict[str, Callable[[Evidence, ClaimResult], str | None]] = {
    "C1": _c1, "C2": _c2, "C3": _c3, "C4": _c4, "C8": _c8, "C9": _c9, "C10": _c10,
    "C13": _lc_claim(step2=True, heading=True),
    "C14": _turns_and_heading(
        "the full path and the no-turns mask differ",
        "with the estimated heading the corrected error is as large on the straights as in "
        "the turns"),
    "C17": _turns_and_heading(
        "LC and LC + Dyn SW differ",
        "with the estimated heading the corrected error is large on the straights too, where "
        "the dynamic window changes nothing"),
    "C18": _c18,
    "C19": _turns_and_heading(
        "LC and LC + Dyn SW differ",
        "with the estimated heading the corrected error is large on the straights too, where "
        "the dynamic window changes nothing"),
    "C21": _lc_claim(step2=False, heading=True),
    "C22": _lc_claim(step2=True, heading=True),
    "C13c": _course_small, "C18c": _course_small, "C22c": _course_small, "C21c": _course_small,
    "C14c": _course_turns, "C17c": _course_turns, "C19c": _course_turns,
}


def cause_line(result: ClaimResult, ev: Evidence) -> str | None:
    """The ``Cause:`` line of a mixed or not-reproduced claim (None for the others)."""
    if result.verdict not in ("mixed", "not reproduced"):
        return None
    fn = _CAUSES.get(result.claim.cid)
    text = fn(ev, result) if fn is not None else None
    if text is None:
        return ("Cause: not measured by this sweep: it lacks the rows that would show it "
                "(the thesis preset has them: oracle rows, the straights mask, the "
                "motion-compensated and course rows, the heading-observability study).")
    return "Cause: " + text


# --------------------------------------------------------------------------- sections
def seed_spread_section(cells: pd.DataFrame) -> list[str]:
    """REPORT.md section: the per-seed spread of the "None" rows beside the published
    single-run values (Tables 4.1/4.2, Path 1), and how far apart Dyn SW and None can be on
    shared noise."""
    w8 = _tw(cells)
    lines = ["## Single runs and seed spread", "",
             ("The dissertation reports one run per row; we report the mean over seeds. How far "
              "one run can land from that mean is the spread of the per-seed values: for the "
              "\"None\" rows (Path 1, " + w8 + " weights, full path) the smallest and largest "
              "per-seed value beside the published one. Two rows computed on the same noise "
              "(common random numbers) differ only where their estimates differ (Dyn SW and "
              "None below: only where a turn is in the window)."), "",
             md_row(["Window", "Axis", "Statistic", "Published (one run)",
                     "Ours: mean [95 % CI]", "Ours: per-seed min - max", "Published inside?"]),
             md_separator(7)]
    n_rows = 0
    for w in THESIS_WINDOWS:
        for ax in ("x", "y"):
            for st in ("mean", "median", "std"):
                v = _per_seed(cells, {"path": P1, "window": w, "weighting": w8, "technique": "none",
                                          "mask": "full"}, f"e{ax}_{st}").dropna()
                if v.empty:
                    continue
                pub = THESIS_TABLES[ax][(w, "None")][st]
                m, lo, hi, _ = seed_ci(v, lower=0.0)        # |error| statistics >= 0
                inside = "yes" if v.min() <= pub <= v.max() else "no"
                lines.append(md_row([w, ax, st, f"{pub:.3f}", f"{m:.3f} [{lo:.3f}, {hi:.3f}]",
                                     f"{v.min():.3f} - {v.max():.3f}", inside]))
                n_rows += 1
    if not n_rows:
        return []
    lines.append("")
    d_lines = []
    for w in THESIS_WINDOWS:
        d = (_per_seed(cells, {"path": P1, "window": w, "weighting": w8, "technique": "dyn",
                                   "mask": "full"}, "ex_mean")
             - _per_seed(cells, {"path": P1, "window": w, "weighting": w8, "technique": "none",
                                     "mask": "full"}, "ex_mean")).dropna()
        if d.empty:
            continue
        pub = THESIS_TABLES["x"][(w, "Dyn SW")]["mean"] - THESIS_TABLES["x"][(w, "None")]["mean"]
        d_lines.append(md_row([w, f"{pub:+.3f}", f"{d.mean():+.3f}",
                               f"{d.min():+.3f} - {d.max():+.3f}"]))
    if d_lines:
        lines += [("Dyn SW minus None, mean |x| (m): on shared noise the two differ only where a "
                   "turn is in the window; the published difference is that of two runs."), "",
                  md_row(["Window", "Published", "Ours: mean over seeds",
                          "Ours: per-seed min - max"]), md_separator(4), *d_lines, ""]
    return lines


def sensitivity_section(sens: Sensitivity) -> list[str]:
    """REPORT.md's "Sensitivity of the verdicts": per claim, the values of each quantity at
    which the declared sensitivity study's verdict differs from its shipped run's
    (``sensitivity.csv``); nothing when the spec declares no study or its files are missing."""
    s = sens.table("sensitivity")
    if s.empty:
        return []
    moved = [q for q in dict.fromkeys(s["quantity"]) if q != "shipped"]
    base = s[s["quantity"] == "shipped"].set_index("claim")
    flips = s[s["flipped"].astype(bool) & (s["quantity"] != "shipped")]
    n = int(flips["claim"].nunique())
    lines = ["## Sensitivity of the verdicts", "",
             (f"Each verdict re-judged with one quantity of the noise model or the path moved "
              f"at a time (the declared sensitivity study, `{sens.value}`, its own seeds and "
              f"shipped run; ranges and their bounds from the dissertation in its REPORT.md): "
              f"{n} of {len(base)} verdicts flip somewhere. Values at which a verdict differs "
              "from the shipped setting's (supports / comparisons):"), "",
             md_row(["Claim", "Shipped", *moved]), md_separator(2 + len(moved))]
    for cid in (c for c in base.index if c in set(flips["claim"])):
        f, b = flips[flips["claim"] == cid], base.loc[cid]
        lines.append(md_row([cid, f"{b.verdict} ({b.supports}/{b.evaluated})", *[
            "; ".join(f"{r.value:g}: **{r.verdict}** ({r.supports}/{r.evaluated})"
                      for r in f[f["quantity"] == q].itertuples()) or "-" for q in moved]]))
    return [*lines, ""]


def observability_section(main: pd.DataFrame, studies: pd.DataFrame) -> list[str]:
    """REPORT.md section of the heading-observability side study: per common fraction of the
    GPS error, the per-receiver error, the median heading error at windows 1 and 100, the lag
    correction at window 100 with the estimated and with the simulator's heading, and the
    setting the dissertation's numbers imply."""
    ev = Evidence(main, main, studies)
    fracs = _study_fractions(ev)
    if not fracs:
        return []
    model = _noise_model(main)
    L = _baseline_m(main)
    settings = [("{}", main)] + [(ov, studies) for ov in fracs]
    lines = ["## Heading observability", "",
             ("Side study: Path 1, Huff weights, the shipped noise model with a larger share "
              "of the error variance common to all receivers (`noise_overrides` "
              "common_fraction). The common part moves every antenna alike and leaves the "
              "heading alone; the per-receiver part, across "
              + (f"a {L:.1f} m platform" if L else "the platform") + ", decides how well the "
              "heading is observed. The lag correction of Section 3.4.2 shifts each estimate "
              "along that heading. Mean |x| / |y| CG error (m) at window 100; median "
              "heading error (deg, Eq. 4.2) technique None."), "",
             md_row(["common_fraction", "per-receiver Gauss-Markov sigma (m)",
                     "heading error w=1 / 100 (deg)", "LC Full Path", "LC + Dyn SW",
                     "Oracle: LC (simulator heading)"]),
             md_separator(6)]
    res = []
    for ov, src in settings:
        cf = json.loads(ov).get("common_fraction", model.common_fraction if model else None)
        mdl = _noise_model(main, ov)
        sig = f"{mdl.sigma_m * math.sqrt(1 - mdl.common_fraction):.2f}" if mdl else "n/a"
        where = {"path": P1, "weighting": "huff", "noise_overrides": ov, "mask": "full"}
        eh = [_deg(_m(src, "eh_median", window=w, technique="none", **where))
              for w in (1, 100)]
        row = {t: (_m(src, "ex_mean", window=100, technique=t, **where),
                   _m(src, "ey_mean", window=100, technique=t, **where))
               for t in ("lc", "lc+dyn", "lc_sim_heading")}
        res.append((cf, eh[0] if np.isfinite(eh[0]) else math.nan, row))
        cells_txt = [f"{row[t][0]:.3f} / {row[t][1]:.3f}" if _ok(*row[t]) else "n/a"
                     for t in ("lc", "lc+dyn", "lc_sim_heading")]
        label = f"{cf:g}" + (" (shipped)" if ov == "{}" else "") if cf is not None else ov
        lines.append(md_row([label, sig, " / ".join(f"{v:.1f}" for v in eh), *cells_txt]))
    pub = (THESIS_TABLES["x"][(100, "LC Full Path")]["mean"],
           THESIS_TABLES["y"][(100, "LC Full Path")]["mean"])
    pub_dyn = (THESIS_TABLES["x"][(100, "LC + Dyn SW")]["mean"],
               THESIS_TABLES["y"][(100, "LC + Dyn SW")]["mean"])
    lines += [md_row(["published (one run)", "", "", f"{pub[0]:.3f} / {pub[1]:.3f}",
                      f"{pub_dyn[0]:.3f} / {pub_dyn[1]:.3f}", ""]), ""]
    lines += [_implied_setting(res, pub), ""]
    return lines


def _implied_setting(res: list, pub: tuple[float, float]) -> str:
    """The sentence naming the noise split the dissertation's numbers imply."""
    valid = [(cf, eh1, row) for cf, eh1, row in res if cf is not None and _ok(*row["lc"])]
    if not valid:
        return ""
    reach = [cf for cf, _, row in valid if row["lc"][0] <= pub[0] and row["lc"][1] <= pub[1]]
    match = [cf for cf, eh1, _ in valid if np.isfinite(eh1) and eh1 < MATCH_DEG]
    closest = min(valid, key=lambda x: abs(x[2]["lc"][0] - pub[0]))
    orc = [(cf, row["lc_sim_heading"]) for cf, _, row in valid if _ok(*row["lc_sim_heading"])]
    txt = ("Which setting the dissertation's numbers imply: its LC Full Path at window 100 "
           f"({pub[0]:.3f} / {pub[1]:.3f} m) ")
    if reach:
        txt += (f"is reached with the estimated heading from common_fraction {min(reach):g} "
                "on")
    else:
        txt += (f"is reached with the estimated heading in none of these settings (closest: "
                f"common_fraction {closest[0]:g}, {closest[2]['lc'][0]:.3f} / "
                f"{closest[2]['lc'][1]:.3f} m)")
    if orc:
        cf0, (ox, oy) = orc[0]
        txt += (f", and with the simulator's heading at common_fraction {cf0:g} "
                f"({ox:.3f} / {oy:.3f} m)")
    txt += (f"; its orientation \"matches the actual heading\" (median error below "
            f"{MATCH_DEG:g} deg, claim C9) ")
    txt += (f"from common_fraction {min(match):g} on." if match else
            "in none of these settings.")
    top = max(valid, key=lambda x: x[0])
    if not reach:
        txt += (f" Its numbers therefore imply a heading better than ours at common_fraction "
                f"{top[0]:g} (median error {top[1]:.1f} deg at window 1): in this noise model "
                f"more than {100 * top[0]:g} % of the Gauss-Markov error common to the "
                "receivers, or a heading not estimated from these antennas at all; Section "
                "4.12.1 says its orientation \"matches the actual heading of the vehicle "
                "calculated by the simulation\".")
    return txt


def evidence(cells: pd.DataFrame, main: pd.DataFrame, studies: pd.DataFrame,
             sensitivity: Sensitivity | None = None) -> Evidence:
    """The :class:`Evidence` of one variant (``main`` = the evaluated cells; ``sensitivity``:
    the declared study, default none)."""
    return Evidence(_derived(cells), main, studies, sensitivity or Sensitivity())

