"""The main job's command line: run an experiment spec as a reproducible, parallel,
resumable sweep (``python -m experiments.sweep``, or the console script ``configpose-sweep``,
:mod:`experiments.console`).

``python -m experiments.sweep`` regenerates the GPS dissertation's moving-platform
performance results (000_8f82f8df647bf685.txt, Sections 4.10-4.12, Tables 4.1 and 4.2) from
the ``thesis`` preset; any spec (see :mod:`experiments.spec`) runs the same way. This module
parses the command line, runs the spec and prints the summary; the work is
:mod:`experiments.runner`: ``run`` (:mod:`~experiments.runner.run`), one cell's observe ->
track -> score (:mod:`~experiments.runner.cell`, scores by :mod:`estimator.scoring`), the
results folder (:mod:`~experiments.runner.store`), the executors (loky, Dask,
in-process: :mod:`~experiments.runner.backends`) and what a worker runs
(:mod:`~experiments.runner.worker`). Their public names are re-exported here.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import warnings
from pathlib import Path

from estimator.scoring import SERIES_COLUMNS, score_track
from estimator.window import SOLVERS
from experiments import cli
from experiments.provenance import code_version
from experiments.runner.backends import (
    PASS_COST_CELLS,
    batches,
    check_scheduler,
    prestart,
    stop_workers,
    uses_pose_filter,
)
from experiments.runner.cell import (
    CELL_SOURCES,
    STREAM_ESTIMATOR,
    STREAM_NOISE,
    CellContext,
    CellFn,
    CellOutput,
    _observations,
    _track_cell,
    cell_code_digest,
    cell_rng,
    evaluate_cell,
    evaluate_recording_cell,
    filter_params_for,
    simulate_truth,
)
from experiments.runner.run import (
    RESULTS_DIR,
    TOP_LEVEL_RUNS,
    Results,
    default_out,
    discard_code_version,
    import_for_outputs,
    run,
    start_code_version,
)
from experiments.runner.store import LOCK_FILE, CellStore, SweepError, folder_lock
from experiments.runner.worker import CellJob, mark, process_started, run_batch, timeline
from experiments.spec import SpecError, available_presets, load_spec

__all__ = [
    "CELL_SOURCES",
    "LOCK_FILE",
    "PASS_COST_CELLS",
    "RESULTS_DIR",
    "SERIES_COLUMNS",
    "STREAM_ESTIMATOR",
    "STREAM_NOISE",
    "TOP_LEVEL_RUNS",
    "CellContext",
    "CellFn",
    "CellJob",
    "CellOutput",
    "CellStore",
    "Results",
    "SweepError",
    "batches",
    "build_parser",
    "cell_code_digest",
    "cell_rng",
    "check_scheduler",
    "code_version",
    "default_out",
    "evaluate_cell",
    "evaluate_recording_cell",
    "filter_params_for",
    "folder_lock",
    "import_for_outputs",
    "main",
    "run",
    "run_batch",
    "score_track",
    "simulate_truth",
    "uses_pose_filter",
]
#: Re-exported for the tests of the cell code (tests/test_techniques.py, test_sweep.py).
_PRIVATE_REEXPORTS = (_observations, _track_cell)


# --------------------------------------------------------------------------- CLI
_EPILOG = """examples:
  python -m experiments.sweep                      # the default preset (thesis), all cores
  python -m experiments.sweep --preset quick       # one path, 2 seeds, a few seconds
  python -m experiments.sweep my_spec.toml --out /tmp/run --jobs 2
  python -m experiments.sweep --preset thesis --solver slsqp   # faithful solver, slow
                                          # -> results/local/thesis-slsqp/
  python -m experiments.sweep --preset thesis --solver elastic # the same fit, batched
                                          # -> results/thesis-elastic/
  python -m experiments.sweep --preset thesis --backend dask --scheduler tcp://10.0.0.5:8786
  python -m experiments.figures results/thesis     # re-plot from saved files, no simulation

A rerun of the same spec resumes: finished cells are skipped (--force recomputes).
One run per results folder at a time (its lock.local.json names the holder's pid; a lock
left by a dead process is taken over). Ctrl-C / SIGTERM: exit 130 / 143 in one line, the
manifest says "interrupted", no worker is left running, the rerun resumes. --debug shows
the traceback of an error.
presets: {presets}

{axes}
"""


def _epilog() -> str:
    """The help's epilog: examples, presets and the values of the spec's named axes (from
    the technique registry and the estimators' vocabularies, experiments.spec.axis_help)."""
    from experiments.spec import axis_help

    return _EPILOG.format(presets=", ".join(available_presets()), axes=axis_help())


DEFAULT_PRESET = "thesis"


def build_parser() -> argparse.ArgumentParser:
    p = cli.ArgumentParser(
        prog="python -m experiments.sweep",
        description="Run an experiment spec (TOML) as a parallel, resumable sweep and write "
                    "cells.parquet, tables.md/CSV, REPORT.md and figures to results/<name>/.",
        epilog=_epilog(),
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("spec", nargs="?", help="spec TOML file (default: --preset thesis)")
    p.add_argument("--preset", metavar="NAME",
                   help="run a shipped preset from experiments/presets/ (default "
                        f"{DEFAULT_PRESET!r}); "
                        "e.g. --preset quick")
    p.add_argument("--out", metavar="DIR",
                   help="results folder (default results/<spec name>/ for "
                        f"{', '.join(sorted(TOP_LEVEL_RUNS))}, else the ignored "
                        "results/local/<spec name>/), e.g. --out /tmp/thesis")
    p.add_argument("--jobs", type=cli.jobs_arg, metavar="N",
                   help=f"worker processes (default all cores = {os.cpu_count()}); 1 = in-process")
    p.add_argument("--backend", choices=("loky", "dask"), default="loky",
                   help="loky: joblib processes on this machine (default); dask: a Dask cluster")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="Dask scheduler address for --backend dask, e.g. tcp://127.0.0.1:8786 "
                        "(default: start a LocalCluster of --jobs workers)")
    p.add_argument("--force", action="store_true", help="recompute finished cells")
    p.add_argument("--solver", choices=SOLVERS,
                   help="override every cell's solver; results go to results/<name>-<solver>/, "
                        "e.g. --solver slsqp")
    p.add_argument("--seeds", type=cli.positive_int, metavar="N",
                   help="override the number of seeds (seeds 0..N-1), e.g. --seeds 3")
    p.add_argument("--cache-dir", metavar="DIR",
                   help="simulated-truth cache (default results/cache/truth), e.g. "
                        "--cache-dir /tmp/empty to time a cold run")
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return p




def _likely_work(args: argparse.Namespace) -> bool:
    """Whether the run will probably compute cells (so starting the workers early pays):
    --force, or a results folder without finished cells. For a spec file without --out the
    folder is not known before the spec is read: yes."""
    if args.force:
        return True
    if args.out is None and args.spec:
        return True
    name = (args.preset or DEFAULT_PRESET) + (f"-{args.solver}" if args.solver else "")
    cells = (Path(args.out) if args.out is not None else default_out(name)) / "cells"
    return not (cells.is_dir() and any(cells.glob("*.json")))


def main(argv: list[str] | None = None) -> int:
    """CLI entry point; returns the exit code (0 ok, 1 some cells failed, 2 bad spec or
    option, 3 the run could not go on: unreachable scheduler, unwritable results folder,
    the folder in use by another run). Through :mod:`experiments.cli` (``python -m``):
    130 on Ctrl-C, 143 on SIGTERM, the manifest marked ``interrupted``, no worker left."""
    mark("main start-up", process_started())     # the interpreter and the imports
    args = build_parser().parse_args(argv)
    if args.spec and args.preset:
        print("error: give a spec file or --preset, not both", file=sys.stderr)
        return 2
    start_code_version()        # git's processes beside the workers' start and the plan
    # joblib warns on an interrupt that it cancelled the workers' tasks: the CLI reports the
    # interrupt in one line (experiments.cli)
    warnings.filterwarnings("ignore", message=r"\d+ tasks (which were still|have been "
                                              r"successfully)",
                            category=UserWarning)
    jobs = args.jobs or (os.cpu_count() or 1)
    with timeline("main prestart"):
        started = (prestart(jobs) if args.backend == "loky" and jobs > 1 and _likely_work(args)
                   else iter(()))
    try:
        code = _main(args)
    except BaseException:
        _stop_workers()        # interrupted: the workers' tasks are not waited for
        raise
    finally:
        discard_code_version()  # not taken when the spec was bad: no later run takes it
    for _ in started:           # (long done)
        pass
    with timeline("main stop workers"):
        _stop_workers()
    return code


def _stop_workers() -> None:
    """:func:`stop_workers` when this process may have started loky workers (it imported
    loky's executor); else nothing (creating one to stop it cost a resumed run 0.3 s)."""
    if "joblib.externals.loky.reusable_executor" in sys.modules:
        stop_workers()



def _main(args: argparse.Namespace) -> int:
    try:
        with timeline("main spec"):
            spec = load_spec(args.spec or args.preset or DEFAULT_PRESET)
        if args.solver:
            spec = spec.with_solver(args.solver)
        if args.seeds is not None:
            spec = spec.with_seeds(range(args.seeds))
    except SpecError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    try:
        res = run(spec, out=args.out, jobs=args.jobs, backend=args.backend,
                  scheduler=args.scheduler, force=args.force, progress=not args.quiet,
                  figures=not args.no_figures, cache_dir=args.cache_dir)
    except SweepError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 3
    except OSError as exc:  # e.g. the results folder cannot even be created
        print(f"error: cannot write {exc.filename or args.out or 'the results folder'}: "
              f"{exc.strerror or exc}", file=sys.stderr)
        return 3
    for e in res.errors[:10]:
        print(f"FAILED cell {e['key']} {json.dumps(e['params'])}: {e['error']}", file=sys.stderr)
    if len(res.errors) > 10:
        print(f"... and {len(res.errors) - 10} more failed cells, see {res.out_dir}/errors.json",
              file=sys.stderr)
    print(res.summary())
    return 1 if res.errors else 0


if __name__ == "__main__":
    cli.run(main)
