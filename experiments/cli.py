"""The one way in and out of every command line (``python -m experiments.X``), issue 23.

Every CLI builds its parser with :class:`ArgumentParser` and ends with
``cli.run(main)``; ``main(argv) -> int`` stays callable from tests. The contract:

* exit 0: done; 1: the command ran but reports failures (e.g. failed sweep cells);
* exit 2: bad input, ONE line on stderr naming the argument or file and the value:
  an argparse error, a ``ValueError`` (which includes parse errors of a user's file:
  ``tomllib.TOMLDecodeError``, ``json.JSONDecodeError``, ``UnicodeDecodeError``, pandas'
  ``ParserError``) or an ``OSError`` on a file (missing, unreadable, not writable);
* exit 130 on Ctrl-C (SIGINT), 143 on SIGTERM: one line. SIGTERM is handled like Ctrl-C
  (:func:`sigterm_as_interrupt` raises :class:`Terminated`, a ``KeyboardInterrupt``, in the
  main thread, so every ``except KeyboardInterrupt``/``finally`` cleans up the same way);
  the code is 128 + the signal's number, as a shell reports a process that signal ended,
  so a caller can tell the two apart. A second SIGTERM during the clean-up ends the process
  at once (the default action is restored when the first arrives);
* exit 1 on an unexpected exception (a bug): one line with its type and message and the
  hint to rerun with ``--debug``;
* ``--debug`` (added to every parser): the traceback of any of the above is printed before
  the line.
"""

from __future__ import annotations

import argparse
import atexit
import math
import os
import signal
import sys
import threading
import traceback
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager, suppress
from typing import NoReturn

__all__ = ["ArgumentParser", "Terminated", "call", "finite_float", "jobs_arg",
           "nonnegative_float", "positive_float", "positive_int", "run", "seed_arg",
           "sigterm_as_interrupt"]

EXIT_USAGE = 2
EXIT_BUG = 1


class Terminated(KeyboardInterrupt):
    """A termination signal (SIGTERM) turned into a ``KeyboardInterrupt``; ``signum`` is the
    signal's number."""

    def __init__(self, signum: int, *args: object):
        super().__init__(*args)
        self.signum = signum


class ArgumentParser(argparse.ArgumentParser):
    """``argparse.ArgumentParser`` with ``--debug`` and a one-line usage error (exit 2)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.add_argument("--debug", action="store_true",
                          help="print the traceback of an error (default: one line)")

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_USAGE, f"{self.prog}: error: {_one_line(message)} (see --help)\n")


def jobs_arg(text: str) -> int:
    """argparse type of ``--jobs``: a positive integer (0 and negatives are rejected)."""
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text!r}") from None
    if n < 1:
        raise argparse.ArgumentTypeError(f"must be a positive integer (1 = in this process), "
                                         f"got {n}")
    return n


def _number(convert: Callable[[str], float], ok: Callable[[float], bool], what: str
            ) -> Callable[[str], float]:
    """An argparse type: ``convert(text)`` that must satisfy ``ok`` (else "must be WHAT")."""
    def parse(text: str):
        try:
            value = convert(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be {what}, got {text!r}") from None
        if not ok(value):
            raise argparse.ArgumentTypeError(f"must be {what}, got {text!r}")
        return value

    parse.__name__ = what.replace(" ", "_")             # argparse names the type by it
    return parse


#: argparse types for numbers: finite floats (m, s), seeds (numpy needs them >= 0).
finite_float = _number(float, math.isfinite, "a finite number")
positive_float = _number(float, lambda v: math.isfinite(v) and v > 0, "a finite number > 0")
nonnegative_float = _number(float, lambda v: math.isfinite(v) and v >= 0,
                            "a finite number >= 0")
seed_arg = _number(int, lambda v: v >= 0, "an integer >= 0")
positive_int = _number(int, lambda v: v >= 1, "an integer >= 1")


@contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """While the block runs, SIGTERM raises :class:`Terminated` in the main thread (nothing
    is installed off the main thread, where Python allows no signal handlers)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum: int, _frame) -> None:
        signal.signal(signum, signal.SIG_DFL)          # a second one ends the process
        raise Terminated(signum)

    old = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


def call(main: Callable[[list[str]], int | None], argv: Sequence[str] | None = None,
         prog: str | None = None) -> int:
    """Run ``main(argv)`` under the contract above; returns the exit code (argparse's
    ``SystemExit`` for --help or a usage error passes through)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    prog = prog or _prog(main)
    debug = "--debug" in argv
    try:
        with sigterm_as_interrupt():
            code = main(argv)
    except KeyboardInterrupt as exc:
        signum = getattr(exc, "signum", signal.SIGINT)
        why = f": {_one_line(str(exc))}" if str(exc) else ""
        return _fail(debug, f"{prog}: interrupted ({signal.Signals(signum).name}){why}",
                     128 + signum)
    except (ValueError, OSError) as exc:
        return _fail(debug, f"{prog}: error: {describe(exc)}", EXIT_USAGE)
    except Exception as exc:  # noqa: BLE001 - a bug: one line and the way to its traceback
        return _fail(debug, f"{prog}: internal error (a bug): {type(exc).__name__}: "
                            f"{_one_line(str(exc))}"
                            + ("" if debug else "; run with --debug for the traceback"), EXIT_BUG)
    return code if isinstance(code, int) else 0


def run(main: Callable[[list[str]], int | None], argv: Sequence[str] | None = None,
        prog: str | None = None) -> NoReturn:
    """:func:`call`, then exit with its code (a module's ``if __name__ == "__main__"``),
    without the interpreter's teardown (:func:`_exit_after_atexit`)."""
    exit_code: list[int] = []
    atexit.register(_exit_after_atexit, exit_code)
    exit_code.append(call(main, argv, prog))
    sys.exit(exit_code[0])


def _exit_after_atexit(exit_code: list[int]) -> None:
    """The last exit handler (registered before any other: they run last in, first out):
    once every other one ran (loky's workers stopped, joblib's temporary folders removed,
    logging flushed), flush stdout and stderr and end the process with ``exit_code[0]``,
    skipping the teardown of every module, which costs a sweep 0.3-0.6 s of wall time after
    its last line (pandas, matplotlib and numba's objects freed one by one; issue 27).
    Nothing when no code was recorded (argparse's --help, an escaped exception) or under
    coverage or a tracer (their data is saved by exit handlers registered before this)."""
    if not exit_code or sys.gettrace() is not None or "coverage" in sys.modules:
        return
    for stream in (sys.stdout, sys.stderr):
        with suppress(Exception):
            stream.flush()
    os._exit(exit_code[0])


def describe(exc: BaseException) -> str:
    """One line for a user-input error: an ``OSError`` names its file and the reason."""
    if isinstance(exc, OSError) and exc.filename is not None:
        return f"{exc.filename}: {exc.strerror or exc}"
    return _one_line(str(exc)) or type(exc).__name__


def _fail(debug: bool, line: str, code: int) -> int:
    if debug:
        traceback.print_exc()
    print(line, file=sys.stderr, flush=True)
    return code


def _one_line(text: str) -> str:
    return " ".join(text.split())


def _prog(main: Callable) -> str:
    """``python -m experiments.X`` for ``main``'s module, also when it runs as ``__main__``."""
    mod = sys.modules.get(main.__module__)
    spec = getattr(mod, "__spec__", None)
    name = spec.name if spec is not None else main.__module__
    return f"python -m {name}"
