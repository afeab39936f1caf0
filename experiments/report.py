"""REPORT.md: every performance claim of the GPS dissertation, checked against a sweep's data.

The claims and the verdict rule are :mod:`experiments.claims`; the measured causes of the
claims that are not reproduced are :mod:`experiments.causes`. This module writes them out.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from experiments import causes
from experiments.claims import (
    _COLUMNS,
    CLAIMS,
    COURSE_CLAIMS,
    P1,
    RULE,
    ClaimResult,
    _cond,
    _derived,
    _per_seed,
    _tw,
    evaluate_claims,
)
from experiments.markdown import md_row, md_separator
from experiments.spec import RESULTS_ROOT
from experiments.tables import PATH_LABELS, THESIS_TABLES, faithful, numpy_strings, thesis_row
from sim.atomic import atomic_write, atomic_write_text

__all__ = ["agreement", "main", "verdict_counts", "write_report"]

#: The stationary claims' per-seed table (experiments.stationary, results/stationary).
STATIONARY_SEEDS = RESULTS_ROOT / "stationary" / "claims_seeds.csv"


# --------------------------------------------------------------------------- counts
def agreement(main: pd.DataFrame) -> dict[str, int]:
    """Published cells of Tables 4.1/4.2 (Path 1: 5 rows x 3 windows x 3 statistics x 2
    axes) against our mean over seeds of the same row: ``cells`` compared, ``within10`` /
    ``within25`` (|ours / published - 1| <= 0.10 / 0.25), ``beyond2x`` (ratio > 2 or < 0.5),
    ``misses`` (beyond 25 %) and ``high`` (misses with ours above the published value)."""
    w8, n = _tw(main), dict.fromkeys(("cells", "within10", "within25", "beyond2x", "misses",
                                      "high"), 0)
    for ax, tab in THESIS_TABLES.items():
        for (w, row), stats in tab.items():
            tech, mask = thesis_row(main, row)
            for st, pub in stats.items():
                v = _per_seed(main, _cond(P1, w, w8, tech, mask), f"e{ax}_{st}").dropna()
                if v.empty:
                    continue
                r = float(v.mean()) / pub
                n["cells"] += 1
                n["within10"] += abs(r - 1) <= 0.10
                n["within25"] += abs(r - 1) <= 0.25
                n["beyond2x"] += not 0.5 <= r <= 2.0
                n["misses"] += abs(r - 1) > 0.25
                n["high"] += r > 1.25
    return n


def verdict_counts(results: list[ClaimResult]) -> str:
    """"reproduced a, mixed b, not reproduced c" (and "not evaluated d" when any)."""
    vs = [r.verdict for r in results]
    order = ("reproduced", "mixed", "not reproduced", "not evaluated")
    return ", ".join(f"{k} {vs.count(k)}" for k in order if vs.count(k) or k != order[-1])


def _counts_lines(main: pd.DataFrame, res: list[ClaimResult]) -> list[str]:
    """The Summary's agreement and verdict counts (issue 28), computed from the data."""
    a = agreement(main)
    ids = {c.cid for c in CLAIMS}
    thesis = [r for r in res if r.claim.cid in ids]
    course = [r for r in res if r.claim.cid not in ids]
    lines = [(f"Verdicts of the thesis claims C1-C22: {verdict_counts(thesis)}; of the "
              f"course variants: {verdict_counts(course)}.")]
    if STATIONARY_SEEDS.exists():
        from experiments.stationary_claims import evaluate as stationary_evaluate

        st = stationary_evaluate(pd.read_csv(STATIONARY_SEEDS))
        lines.append(f"Verdicts of the stationary claims (Sections 4.3-4.8, "
                     f"results/stationary/claims.md): {verdict_counts(st)}.")
    if a["cells"]:
        lines.append(
            f"Agreement with the published cells of Tables 4.1/4.2 (Path 1, {a['cells']} "
            f"cells: 5 rows x windows 5/10/100 x mean/median/std x |x|/|y|; ours = the mean "
            f"over seeds of the same row): {a['within10']} within 10 %, {a['within25']} within "
            f"25 %, {a['beyond2x']} off by more than 2x; of the {a['misses']} beyond 25 %, "
            f"{a['high']} are ours too high.")
    return ["", *(x for line in lines for x in (line, ""))]


# --------------------------------------------------------------------------- writing
def _f(v: float, digits: int = 3) -> str:
    return "n/a" if not np.isfinite(v) else f"{v:.{digits}f}"


def _claim_section(r: ClaimResult, rows: list, vlabel: str, cause: str | None = None
                   ) -> list[str]:
    lines = [f"## {r.claim.cid} ({r.claim.section}): {r.claim.text}"
             + (f" [{vlabel}]" if vlabel else ""), "",
             f"Verdict: **{r.verdict}**. {r.claim.note}", ""]
    if cause:
        lines += [cause, ""]
    if not r.outcomes:
        return lines + ["The sweep has none of the cells this claim needs.", ""]
    lines += [md_row(["Comparison", "seeds", "A", "B", "A - B [95 % CI]", "result", "thesis"]),
              md_separator(7)]
    for o in r.outcomes:
        c = o.comparison
        th = ""
        if c.thesis is not None:
            th = f"{c.thesis[0]:.3f} vs {c.thesis[1]:.3f}: {o.thesis_result}"
        b = _f(o.mean_b) if isinstance(c.b, dict) else f"{c.b:.3f} (const)"
        lines.append(md_row([f"{c.label} (`{c.metric}`)", o.n, _f(o.mean_a), b,
                             f"{_f(o.diff)} [{_f(o.lo)}, {_f(o.hi)}]", o.result, th]))
        rows.append({"variant": vlabel, "claim": r.claim.cid, "comparison": c.label,
                     "metric": c.metric, "relation": c.rel, "n_seeds": o.n,
                     "mean_a": o.mean_a, "mean_b": o.mean_b, "diff": o.diff, "lo": o.lo,
                     "hi": o.hi, "result": o.result,
                     "thesis_a": c.thesis[0] if c.thesis else np.nan,
                     "thesis_b": c.thesis[1] if c.thesis else np.nan,
                     "thesis_result": o.thesis_result, "verdict": r.verdict})
    return lines + [""]


def _setup(cells: pd.DataFrame, out: Path) -> list[str]:
    """The experimental set-up, read from the files the cells name (never typed by hand)."""
    import json

    lines = ["## Set-up", ""]
    try:
        from sim.paths import load_path
    except ImportError:          # report on a machine without the simulator: skip
        return []
    for p in dict.fromkeys(cells["path"]):
        try:
            path = load_path(p)
        except ValueError:
            continue
        ovs = sorted(set(cells.loc[cells["path"] == p, "path_overrides"])) \
            if "path_overrides" in cells else ["{}"]
        for ov in ovs:
            d = {**path.to_dict(), **json.loads(ov)}
            lines.append(f"- {PATH_LABELS.get(p, p)} (`{p}`{', ' + ov if ov != '{}' else ''}): "
                         f"{path.length_m:.0f} m, cruise {d['cruise_speed_mps']} m/s, samples "
                         f"at {d['sample_rate_hz']} Hz, target radius {d['target_radius_m']} m; "
                         f"a 100-sample window trails (s - 1) v / (2 rate) = "
                         f"{99 * d['cruise_speed_mps'] / (2 * d['sample_rate_hz']):.1f} m "
                         "on a straight.")
    for col in ("config", "noise", "noise_overrides"):
        if col in cells:
            vals = sorted(set(cells[col]))
            lines.append(f"- {col}: {', '.join(f'`{v}`' for v in vals)}")
    man = out / "manifest.json"
    if man.exists():
        m = json.loads(man.read_text())
        code = m.get("code", {})
        lines.append(f"- spec seed {m.get('spec_seed')}, seeds {m.get('seeds')}, code "
                     f"{code.get('git_describe') or code.get('git_commit')} (package "
                     f"{code.get('package')}); see `manifest.json` and `spec.toml`.")
    lines += [("- The dissertation does not state its vehicle's speed; the shipped paths use the "
              "speed its Table 4.1 implies (see the comments in models/paths/). "
              "`experiments/presets/speed.toml` checks the claims at other speeds."), ""]
    return lines


def write_report(cells: pd.DataFrame, out_dir: str | Path, spec=None) -> Path:
    """Write REPORT.md (claims, our numbers, verdicts) and claims.csv to ``out_dir``.

    When the sweep has several variants (e.g. two configurations or noise models, see
    :func:`experiments.tables.variants`), every claim is evaluated on each variant.
    """
    from experiments.tables import plugin_section, run_name, side_studies, variants

    _COLUMNS.clear()
    cells = numpy_strings(cells)
    out = Path(out_dir)
    studies = side_studies(cells)
    sens = causes.declared_sensitivity(out, spec)       # [report] sensitivity, if declared
    per_variant, evidence = [], {}
    for lab, sub in variants(cells):
        main = _derived(faithful(sub))
        per_variant.append((lab, evaluate_claims(main, CLAIMS + COURSE_CLAIMS)))
        evidence[lab] = causes.evidence(sub, main, studies, sens)
    n_seeds = int(cells["seed"].nunique())
    solvers = sorted(set(cells["solver"]) - {"-"})
    lines = [f"# Claim-by-claim check of the GPS dissertation ({run_name(out, spec)})", "",
             ("Source: 000_8f82f8df647bf685.txt, Sections 3.4, 4.10-4.12 and 5.1 (moving "
             f"platform). Data: `cells.parquet` of this folder, {n_seeds} seed(s), solver(s) "
             f"{', '.join(solvers) or '-'}. Generated by `experiments/report.py` from the data; "
             "nothing here is written by hand. The per-comparison numbers are also in "
             "`claims.csv`."), "",
             *_setup(cells, out),
             "## Rule", "", RULE, "",
             ("Metric names: `ex_*`/`ey_*` absolute x/y CG error (Eq. 4.1, m), `eh_*` heading "
             "error (Eq. 4.2, rad), `along_mean` signed along-track CG error (m), `jitter_rms` "
             "epoch-to-epoch change of the error (m), `*_outliers` fraction above Q3 + 1.5 IQR."),
             "", "## Summary", ""]
    head = ["Claim", "Section"]
    for lab, _ in per_variant:
        head += [f"Verdict{' (' + lab + ')' if lab else ''}", "supports / comparisons"]
    head.append("Dissertation's own tables")
    lines += [md_row(head), md_separator(len(head))]
    for i, cl in enumerate(per_variant[0][1]):
        row = [f"{cl.claim.cid}: {cl.claim.text}", cl.claim.section]
        for _, res in per_variant:
            r = res[i]
            s = sum(o.result == "supports" for o in r.outcomes)
            n = sum(o.result != "missing" for o in r.outcomes)
            row += [f"**{r.verdict}**", f"{s}/{n}"]
        r0 = per_variant[0][1][i]
        tv = ""
        if r0.thesis_verdict:
            ts = sum(o.thesis_result == "supports" for o in r0.outcomes)
            tv = f"{r0.thesis_verdict} ({ts}/{len(r0.outcomes)})"
        lines.append(md_row([*row, tv]))
    lines += ["", ("Rows C13c-C22c repeat the lag-correction claims with the course-based lag "
              "correction (our variant, beyond the dissertation) in place of the as-written one.")]
    for lab, res in per_variant:
        counts: dict[str, int] = {}
        for r in res:
            counts[r.verdict] = counts.get(r.verdict, 0) + 1
        lines += ["", (f"Totals ({lab}): " if lab else "Totals: ")
                  + ", ".join(f"{k}: {v}" for k, v in sorted(counts.items()))]
    lines += _counts_lines(evidence[per_variant[0][0]].main, per_variant[0][1])
    lines += [("Every mixed or not-reproduced claim has a line beginning `Cause:` in its "
              "section: the measured cause and the rows or study that show it "
              "(`experiments/causes.py`)."), ""]
    first = per_variant[0][0]
    lines += causes.seed_spread_section(evidence[first].main)
    lines += causes.observability_section(evidence[first].main, studies)
    lines += causes.sensitivity_section(sens)
    lines += plugin_section(cells, out, spec)      # the spec's plug-in trackers, if any
    rows: list[dict] = []
    for lab, res in per_variant:
        for r in res:
            lines += _claim_section(r, rows, lab, causes.cause_line(r, evidence[lab]))
    atomic_write(out / "claims.csv", lambda p: pd.DataFrame(rows).to_csv(p, index=False))
    path = out / "REPORT.md"
    atomic_write_text(path, "\n".join(lines))
    return path


def main(argv: list[str] | None = None) -> int:
    """``python -m experiments.report results/thesis``: rewrite tables, REPORT.md and the
    page (index.html) from the folder's cells.parquet (no simulation, no estimation)."""
    import sys

    from experiments.cli import ArgumentParser
    from experiments.tables import write_tables

    p = ArgumentParser(
        prog="python -m experiments.report",
        description="Rewrite tables.md, the table CSVs, REPORT.md, claims.csv and index.html "
                    "of a sweep results folder from its cells.parquet. Example: "
                    "python -m experiments.report results/thesis")
    p.add_argument("results", help="results folder, e.g. results/thesis")
    args = p.parse_args(argv)
    out = Path(args.results)
    if not (out / "cells.parquet").exists():
        print(f"error: {out}/cells.parquet not found", file=sys.stderr)
        return 2
    cells = pd.read_parquet(out / "cells.parquet")
    print(write_tables(cells, out))
    print(write_report(cells, out))
    from experiments.page import write_page

    print(write_page(out))
    return 0


if __name__ == "__main__":
    from experiments.cli import run as run_cli

    run_cli(main)
