"""The shared command-line wrapper (experiments/cli.py, issue 23): one-line errors with exit
2, Ctrl-C 130 and SIGTERM 143 in one line, bugs in one line with the --debug hint, --debug
tracebacks; every CLI goes through it; --jobs validation; page --with."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from experiments import cli

REPO = Path(__file__).resolve().parents[1]
#: Every module of experiments/ with a command line (python -m experiments.X).
CLI_MODULES = sorted(p.stem for p in (REPO / "experiments").glob("*.py")
                     if re.search(r"^def main\(", p.read_text(), re.MULTILINE))


def _err_lines(capsys) -> list[str]:
    return capsys.readouterr().err.strip().splitlines()


# --------------------------------------------------------------------------- the wrapper
@pytest.mark.parametrize("exc, code, expect", [
    (ValueError("--where window: must be an integer, got 'abc'"), 2, "--where window"),
    (FileNotFoundError(2, "No such file or directory", "/no/such.toml"), 2,
     "/no/such.toml: No such file or directory"),
    (PermissionError(13, "Permission denied", "/ro/out"), 2, "/ro/out: Permission denied"),
    (ValueError("line one\nline two"), 2, "line one line two"),
    (KeyboardInterrupt(), 130, "interrupted (SIGINT)"),
    (cli.Terminated(signal.SIGTERM, "3 of 9 cells kept"), 143,
     "interrupted (SIGTERM): 3 of 9 cells kept"),
    (ZeroDivisionError("division by zero"), 1,
     "internal error (a bug): ZeroDivisionError: division by zero; run with --debug"),
])
def test_each_outcome_is_one_line_with_its_exit_code(exc, code, expect, capsys):
    def main(argv):
        raise exc

    assert cli.call(main, [], prog="prog") == code
    err = _err_lines(capsys)
    assert len(err) == 1 and err[0].startswith("prog: ") and expect in err[0], err


def test_debug_prints_the_traceback_first(capsys):
    def main(argv):
        raise ValueError("bad value")

    assert cli.call(main, ["--debug"], prog="prog") == 2
    err = capsys.readouterr().err
    assert "Traceback (most recent call last)" in err and err.strip().endswith(
        "prog: error: bad value")


def test_return_codes_pass_through_and_non_int_is_success():
    assert cli.call(lambda argv: 3, []) == 3
    assert cli.call(lambda argv: Path("x.png"), []) == 0        # paths_figure returns a path


def test_usage_errors_are_one_line_exit_2_and_debug_is_accepted(capsys):
    p = cli.ArgumentParser(prog="prog")
    p.add_argument("--jobs", type=cli.jobs_arg)
    assert p.parse_args(["--jobs", "3", "--debug"]).debug is True
    for bad, shown in (("0", "got 0"), ("-3", "got -3"), ("abc", "got 'abc'")):
        with pytest.raises(SystemExit) as ex:
            p.parse_args(["--jobs", bad])
        assert ex.value.code == 2
        err = _err_lines(capsys)
        assert len(err) == 1 and "--jobs" in err[0] and shown in err[0], err
    with pytest.raises(SystemExit):
        p.parse_args(["--nope"])
    err = _err_lines(capsys)
    assert len(err) == 1 and "unrecognized arguments: --nope" in err[0]


def test_sigterm_raises_keyboard_interrupt_in_the_main_thread_and_is_restored():
    """SIGTERM inside the wrapper: a Terminated (a KeyboardInterrupt), exit 143; the old
    handler is back afterwards. Without the handler the default action would end pytest."""
    seen = []

    def main(argv):
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(5)                       # the handler interrupts this
        except KeyboardInterrupt as exc:
            seen.append(type(exc))
            raise
        return 0

    before = signal.getsignal(signal.SIGTERM)
    t0 = time.perf_counter()
    assert cli.call(main, [], prog="prog") == 143
    assert time.perf_counter() - t0 < 4
    assert seen == [cli.Terminated]
    assert signal.getsignal(signal.SIGTERM) is before


# --------------------------------------------------------------------------- every CLI
def test_the_cli_list_is_complete():
    assert {"sweep", "export", "render", "page", "figures", "report", "stationary",
            "ultrasonic", "ranging", "identification", "bench", "paths_figure"} \
        <= set(CLI_MODULES)


@pytest.mark.parametrize("module", CLI_MODULES)
def test_every_cli_goes_through_the_wrapper(module):
    """Each module's parser is cli.ArgumentParser (--debug in its help, a one-line usage
    error) and its __main__ runs through experiments.cli."""
    src = (REPO / "experiments" / f"{module}.py").read_text()
    main_part = src[src.index("\ndef main("):]
    assert "argparse.ArgumentParser(" not in main_part
    tail = main_part[main_part.index('if __name__ == "__main__":'):]
    assert "run_cli(main)" in tail or "cli.run(main)" in tail, module


@pytest.mark.parametrize("module", ["sweep", "stationary", "ranging", "page"])
def test_cli_bad_option_is_one_line_exit_2(module):
    """A subprocess per CLI (import cost ~1-2 s each, so only a few): an unknown option is
    one line on stderr, exit 2, no traceback."""
    args = ["some_folder"] if module == "page" else []        # its one required argument
    r = subprocess.run([sys.executable, "-m", f"experiments.{module}", *args,
                        "--no-such-option"],
                       cwd=REPO, capture_output=True, text=True, check=False, timeout=120)
    err = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(err) == 1, r.stderr
    assert f"python -m experiments.{module}: error:" in err[0] and "--no-such-option" in err[0]


@pytest.mark.parametrize("jobs", ["0", "-3", "two"])
def test_sweep_jobs_must_be_a_positive_integer(jobs, capsys):
    """--jobs 0 silently meant all cores, --jobs -3 was a 15-line traceback."""
    from experiments.sweep import main

    with pytest.raises(SystemExit) as ex:
        main(["--preset", "quick", "--jobs", jobs])
    assert ex.value.code == 2
    err = _err_lines(capsys)
    assert len(err) == 1 and "--jobs" in err[0] and jobs in err[0], err


# --------------------------------------------------------------------------- page --with
@pytest.fixture
def results_folder(tmp_path):
    """A finished (fake) sweep folder with cells.parquet."""
    from test_sweep import TINY, fake_cell, fake_truth

    from experiments.spec import Spec
    from experiments.sweep import run

    spec = Spec.from_dict({**TINY, "defaults": {"noise": "none"}}, source="fake")
    run(spec, out=tmp_path / "res", jobs=1, progress=False, outputs=False,
        truth_fn=fake_truth, cell_fn=fake_cell)
    return tmp_path / "res"


def test_page_with_a_missing_folder_exits_2_and_writes_no_page(results_folder, tmp_path,
                                                             capsys):
    """It printed an error, exited 0 and wrote the error into the page."""
    from experiments import page

    out = tmp_path / "page.html"
    for extra, why in ((tmp_path / "MISSING", "no cells.parquet there"),
                       (results_folder, "no cell kept its per-epoch estimates")):
        code = cli.call(page.main, [str(results_folder), "--with", str(extra), "--out",
                                    str(out), "--ultrasonic", "none"])
        err = _err_lines(capsys)
        assert code == 2 and len(err) == 1, err
        assert f"--with {extra}: {why}" in err[0]
        assert not out.exists()


@pytest.mark.parametrize("module, option, bad", [
    ("identification", "--noise-m", "-1"), ("identification", "--seed", "-1"),
    ("ultrasonic", "--z-plane", "nan"), ("stationary", "--duration", "-5"),
    ("stationary", "--duration", "inf"), ("stationary", "--seed", "x")])
def test_numeric_options_name_the_option_not_the_parameter(module, option, bad, capsys):
    """These named the function parameter ('noise_m', 'duration_s') or an internal array
    ('tx_positions/receivers' for --z-plane nan); now argparse names the option."""
    import importlib

    main = importlib.import_module(f"experiments.{module}").main
    with pytest.raises(SystemExit) as ex:
        main([option, bad])
    err = _err_lines(capsys)
    assert ex.value.code == 2 and len(err) == 1, err
    assert f"argument {option}: must be" in err[0] and repr(bad) in err[0]


def test_number_types_accept_valid_values():
    assert cli.finite_float("-2.5") == -2.5 and cli.positive_float("1e-3") == 1e-3
    assert cli.nonnegative_float("0") == 0.0 and cli.seed_arg("7") == 7


def test_run_exits_with_the_code_after_the_exit_handlers_without_the_teardown():
    """cli.run ends the process after every other exit handler (registered later, run
    first) with main's code and its output flushed, but skips the interpreter's teardown
    (issue 27: 0.3-0.6 s after a sweep's last line): an object's __del__ at teardown does
    not run."""
    code = ("import atexit, sys\n"
            "from experiments import cli\n"
            "class Late:\n"
            "    def __del__(self): print('teardown', flush=True)\n"
            "KEEP = Late()\n"
            "def main(argv):\n"
            "    atexit.register(lambda: print('handler'))\n"
            "    print('out', end='')\n"
            "    sys.stderr.write('err')\n"
            "    return 3\n"
            "cli.run(main, [])\n")
    r = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True,
                       text=True, check=False, timeout=60)
    assert r.returncode == 3, r.stderr
    assert r.stdout == "outhandler\n" and r.stderr == "err"
