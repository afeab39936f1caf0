"""The outputs phase of a sweep: tables, REPORT.md, figures and the run's page, written side
by side and only where their inputs changed (issue 16).

:func:`write_outputs` is what :func:`experiments.sweep.run` calls once the cells are done.
The outputs fall into units, each with known inputs:

- ``tables``: tables.md and the table CSVs (:mod:`experiments.tables`) and the Tables
  4.1/4.2 chart drawn from the CSVs (``fig_tables.png``). Inputs: the cell table (every
  column, timings included: the heading table and timings.local.csv show them).
- ``report``: REPORT.md and claims.csv (:mod:`experiments.report`). Inputs: the cell
  table, the spec, manifest.json and the CSVs of the sensitivity study the spec declared
  (``[report] sensitivity``; the Cause lines quote them).
- one unit per figure group of :mod:`experiments.figures` (box plots, orientation,
  overlays, ...). Inputs: the sweep's layout (the cell table's key, axis, seed and mask
  columns and which cells kept per-epoch estimates; not their statistics) and the
  per-epoch files the group read when it was last drawn (a figure draws those files only).
- ``page``: index.html (:mod:`experiments.page`). Inputs: the cell table, every per-epoch
  file, REPORT.md, tables.md, claims.csv, the figures, manifest.json and the flight series
  the spec declared (``[page] flight``).

Every unit also depends on the code of ``experiments/`` (any change there redraws all).
``outputs.local.json`` (git-ignored, like every ``*.local.json``) records each unit's input
digest and the size and modification time of the files it wrote; a unit whose inputs are
unchanged and whose files are all still there as written is skipped. So a resumed run with
nothing to compute re-reads and writes nothing, and a run that recomputed cells without
per-epoch files redraws the tables, the report, their chart and the page but no other
figure.

With ``jobs > 1`` the tables, the report and the figure groups run in worker processes
(joblib loky: the sweep's workers, already started), the largest first, beside the page's
replay (handed out after the tables and the report); the page is written last in this
process (it lists the figures and shows the report).
"""

from __future__ import annotations

import contextlib
import gc
import hashlib
import json
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pandas as pd

from sim.atomic import atomic_write_text, file_stat

__all__ = ["STATE_FILE", "code_digest", "frame_digest", "n_steps", "write_outputs"]

#: The record of what each unit last wrote, in the results folder (git-ignored).
STATE_FILE = "outputs.local.json"
#: The figure group drawn with the tables (it reads the table CSVs).
CHART_TASK = "tables"
#: The figure groups by typical cost (thesis preset, CPU-s measured in one process at load
#: ~6: sensor1 1.6-2.0, overlay 1.4-1.7, weighting 0.95, oracle 0.4-0.7, the others 0.2-0.45),
#: largest first: the order in which they are handed to the workers after the tables and the
#: report (1.3-2 s each), so the last to finish are short.
_FIGURE_ORDER = ("sensor1", "overlay", "weighting", "oracle", "lag_correction", "beyond",
                 "orientation", "dynamic", "lc_dyn")

_EXPERIMENTS = Path(__file__).resolve().parent


def code_digest() -> str:
    """Digest of the code that writes the outputs: every module of ``experiments/`` and the
    page's assets (a change anywhere there redraws every output)."""
    from sim.cache import source_digest

    files = [*_EXPERIMENTS.glob("*.py"), *(_EXPERIMENTS / "page_assets").glob("*")]
    return source_digest(tuple(f for f in files if f.is_file()))[:24]


def frame_digest(df: pd.DataFrame, columns: list[str] | None = None) -> str:
    """Digest of a DataFrame's contents (column names, dtypes and values; ``columns``: only
    those), independent of its index."""
    if columns is not None:
        df = df[[c for c in columns if c in df.columns]]
    h = hashlib.blake2b(digest_size=16)
    h.update(json.dumps([[str(c), str(t)] for c, t in df.dtypes.items()]).encode())
    h.update(pd.util.hash_pandas_object(df, index=False).to_numpy().tobytes())
    return h.hexdigest()


def _digest(*parts: Any) -> str:
    return hashlib.blake2b(json.dumps(parts, sort_keys=True, default=str).encode(),
                           digest_size=16).hexdigest()


def _manifest_inputs(path: Path) -> str:
    """What of ``manifest.json`` the report and the page show: everything but ``status``
    (the outputs are written while it says "running"; the run marks it "complete" after
    them, so with the status a resumed run redrew both although nothing they show had
    changed). "" without a manifest, the text itself when it is not a JSON object."""
    try:
        text = path.read_text()
    except OSError:
        return ""
    try:
        man = json.loads(text)
    except ValueError:
        return text
    if not isinstance(man, dict):
        return text
    man.pop("status", None)
    return json.dumps(man, sort_keys=True)


def _sensitivity_inputs(out: Path, spec: Any) -> list | None:
    """[declared value, {csv name: content digest}] of the sensitivity study the run declared
    (:func:`experiments.causes.declared_sensitivity`), None when it declared none or the
    value is bad (the report unit raises the error)."""
    from experiments.causes import declared_sensitivity

    try:
        sens = declared_sensitivity(out, spec)
    except ValueError:
        return None
    if sens.value is None:
        return None
    files = sorted(sens.path.glob("*.csv")) if sens.path is not None else []
    return [sens.value, {f.name: hashlib.blake2b(f.read_bytes(), digest_size=16).hexdigest()
                         for f in files}]


def _stats(out: Path, names: list[str]) -> dict[str, list[int] | None]:
    return {n: file_stat(out / n) for n in names}


def _layout_columns(table: pd.DataFrame) -> list[str]:
    """The columns that say which cells exist (key, axes, seed, mask, has_epochs), not what
    they measured: the inputs of the figures besides their per-epoch files."""
    from experiments.page import _axis_columns

    return ["key", *_axis_columns(table), "mask", "has_epochs"]


def _epoch_keys(table: pd.DataFrame) -> list[str]:
    if "has_epochs" not in table or "key" not in table:
        return []
    return sorted(set(table.loc[table["has_epochs"].astype(bool), "key"]))


def _epoch_stats(out: Path, keys: list[str]) -> dict[str, list[int] | None]:
    return _stats(out / "epochs", [f"{k}.parquet" for k in keys])


# --------------------------------------------------------------------------- units
@contextlib.contextmanager
def _young_gc() -> Iterator[None]:
    """Collect only what the unit makes: the objects alive before it (a worker's modules,
    tables and caches, ~130-190 thousand) are frozen out of the collector's full passes
    for its duration, which otherwise scanned them all a few times per unit (0.4-0.6 CPU-s
    of the thesis preset's outputs, measured with gc.callbacks); unfrozen after, so
    nothing is kept that a collection would free."""
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()


def _tables_unit(table: pd.DataFrame, out: Path, figures: bool) -> dict:
    """tables.md, the table CSVs and (with ``figures``) the Tables 4.1/4.2 chart; returns
    the files written (the .md/.csv files of the folder that changed, REPORT.md and
    claims.csv aside: the report unit writes those meanwhile, plus the chart) and seconds."""
    from experiments import tables

    def snapshot() -> dict[str, list[int] | None]:
        return {p.name: file_stat(p) for p in (*out.glob("*.md"), *out.glob("*.csv"))
                if p.name not in _REPORT_FILES}

    t0 = time.perf_counter()
    before = snapshot()
    with _young_gc():
        tables.write_tables(table, out)
    files = sorted(n for n, st in snapshot().items() if before.get(n) != st)
    t1 = time.perf_counter()
    if figures:
        from experiments import figures as figs

        with _young_gc():
            written, _ = figs.draw_task(out, CHART_TASK)
        files += [p.name for p in written]
    return {"files": files, "tables_s": t1 - t0, "chart_s": time.perf_counter() - t1}


#: What :func:`experiments.report.write_report` writes.
_REPORT_FILES = ("REPORT.md", "claims.csv")


def _report_unit(table: pd.DataFrame, out: Path, spec: Any) -> dict:
    """REPORT.md and claims.csv; returns the files written and seconds."""
    from experiments import report

    t0 = time.perf_counter()
    with _young_gc():
        report.write_report(table, out, spec=spec)
    return {"files": list(_REPORT_FILES), "report_s": time.perf_counter() - t0}


def _figure_unit(out: Path, task: str) -> dict:
    """One figure group: the files written, the per-epoch files read, seconds."""
    from experiments import figures as figs

    t0 = time.perf_counter()
    with _young_gc():
        written, loaded = figs.draw_task(out, task)
    return {"files": [p.name for p in written], "loaded": loaded,
            "seconds": time.perf_counter() - t0}


def _replay_unit(out: Path) -> dict:
    """The page's replay of the folder's cells (the page's largest part), made beside the
    figures; the page itself is written last."""
    from experiments import page

    t0 = time.perf_counter()
    return {"replay": page.own_replay(out), "seconds": time.perf_counter() - t0}


def _run_unit(kind: str, *args: Any) -> tuple[str, dict]:
    name = args[-1] if kind == "figure" else kind
    fn = {"tables": _tables_unit, "report": _report_unit, "figure": _figure_unit,
          "replay": _replay_unit}[kind]
    from experiments.runner.worker import release_memos, timeline, trim_heap

    release_memos()             # the cells are done: a worker's memos go (loky's leak check)
    with timeline(f"output {name}"):
        res = fn(*args)
        trim_heap()             # what the unit freed, back to the OS before loky measures
    return name, res


def n_steps(figures: bool = True) -> int:
    """Progress steps of :func:`write_outputs`: the tables, the report, each figure group and
    the page."""
    from experiments.figures import figure_tasks

    return 3 + (sum(t != CHART_TASK for t in figure_tasks()) if figures else 0)


def write_outputs(table: pd.DataFrame, out_dir: str | Path, *, spec: Any = None,
                  jobs: int = 1, figures: bool = True,
                  on_step: Callable[[str], object] | None = None) -> dict:
    """Write the outputs of a sweep's results folder whose inputs changed (module docstring).

    table : the cell table (``cells.parquet``, which must already be written: the figures
        and the page read it). spec : the run's :class:`experiments.spec.Spec` (for the
        report; None: what the folder says). jobs : worker processes for the tables, the
        report and the figure groups (1: all in this process). figures : draw the PNG
        figures.
    on_step : called with each unit's name as it finishes or is skipped (progress).

    Returns ``{"written": [...], "skipped": [...], "seconds": {unit: s}, "wall_s": s}``.
    """
    from experiments import figures as figs

    t_start = time.perf_counter()
    out = Path(out_dir)
    step = on_step or (lambda _name: None)
    state_path = out / STATE_FILE
    try:
        state_text = state_path.read_text()
        state = json.loads(state_text)
        units = state.get("units", {}) if isinstance(state, dict) else {}
    except (OSError, ValueError):
        state_text, units = None, {}
    code = code_digest()
    manifest = _manifest_inputs(out / "manifest.json")
    table_d = frame_digest(table)
    spec_d = _digest(getattr(spec, "raw", None))
    layout_d = frame_digest(table, _layout_columns(table))
    new: dict[str, dict] = {}

    def unchanged(name: str, inputs: str, extra_ok: bool = True) -> bool:
        rec = units.get(name)
        return bool(rec and extra_ok and rec.get("inputs") == inputs
                    and rec.get("files") is not None
                    and all(file_stat(out / f) == s for f, s in rec["files"].items()))

    # what needs writing
    todo: list[tuple] = []
    unit_in = {"tables": _digest(code, table_d, figures),
               "report": _digest(code, table_d, spec_d, manifest,
                                 _sensitivity_inputs(out, spec))}
    for name, args in (("tables", (table, out, figures)), ("report", (table, out, spec))):
        if unchanged(name, unit_in[name]):
            new[name] = units[name]
        else:
            todo.append((name, *args))
    fig_in = {}
    if figures:
        order = {t: i for i, t in enumerate(_FIGURE_ORDER)}
        for task in sorted((t for t in figs.figure_tasks() if t != CHART_TASK),
                           key=lambda t: order.get(t, -1)):
            fig_in[task] = _digest(code, layout_d)
            rec = units.get(task, {})
            same_epochs = rec.get("epochs") == _epoch_stats(out, rec.get("loaded", []))
            if rec.get("loaded") is not None and unchanged(task, fig_in[task], same_epochs):
                new[task] = rec
            else:
                todo.append(("figure", out, task))

    for name in new:               # skipped: unchanged since they were written
        step(name)

    # the tables, the report and the figure groups, side by side; when any of them is
    # rewritten the page is too (it shows them), so its replay is made beside them, handed
    # out after the tables and the report, before the figure groups: it costs about as much
    # as the larger groups (thesis preset: 0.36-0.41 CPU-s, growing with the cells), and
    # queued last it was the last unit to finish, 0.4 s after the other worker's last
    seconds: dict[str, float] = {}
    replay = None
    if todo:
        todo.insert(sum(u[0] in unit_in for u in todo), ("replay", out))
        if jobs > 1 and len(todo) > 1:
            from joblib import Parallel, delayed

            it = Parallel(n_jobs=min(jobs, len(todo)), backend="loky",
                          return_as="generator_unordered")(
                delayed(_run_unit)(*u) for u in todo)
        else:
            it = (_run_unit(*u) for u in todo)
        for name, res in it:
            if name == "replay":
                replay = res["replay"]
                seconds["replay_s"] = res["seconds"]
                continue
            if name in unit_in:
                new[name] = {"inputs": unit_in[name], "files": _stats(out, res["files"])}
                seconds.update({k: v for k, v in res.items() if k.endswith("_s")})
            else:
                new[name] = {"inputs": fig_in[name], "files": _stats(out, res["files"]),
                             "loaded": res["loaded"],
                             "epochs": _epoch_stats(out, res["loaded"])}
                seconds[name] = res["seconds"]
            step(name)

    # the page, last: it shows the report and lists the figures
    from experiments import page

    pngs = sorted(p.name for p in out.glob("*.png"))
    fdir = page.flight_dir(out)       # the flight series the spec declared, if any
    page_in = _digest(code, table_d, manifest, _epoch_stats(out, _epoch_keys(table)),
                      _stats(out, ["REPORT.md", "tables.md", "claims.csv", *pngs]),
                      _stats(fdir, ["flight_series.csv"]) if fdir else None)
    if unchanged("page", page_in):
        new["page"] = units["page"]
    else:
        t0 = time.perf_counter()
        from experiments.runner.worker import timeline

        with timeline("main page"):
            page.write_page(out, replay=replay)      # index.html: replay, claims, tables, figs
        seconds["page_s"] = time.perf_counter() - t0
        new["page"] = {"inputs": page_in, "files": _stats(out, ["index.html"])}
    step("page")
    units.update(new)
    text = json.dumps({"units": units}, indent=1, sort_keys=True)
    if text != state_text:          # unchanged: not rewritten (a read-only finished run reruns)
        atomic_write_text(state_path, text)
    written = [u[0] if u[0] in unit_in else u[-1] for u in todo if u[0] != "replay"] \
        + (["page"] if "page_s" in seconds else [])
    return {"written": written, "skipped": sorted(set(new) - set(written)),
            "seconds": seconds, "wall_s": time.perf_counter() - t_start}
