"""``python -m experiments.X --help`` and a mistyped option answer before the heavy imports.

A CLI module's top level runs before ``main`` parses the arguments, so whatever it imports
there is paid by ``--help`` and by every usage error (pandas ~0.4 CPU-s, numba ~0.5 through
the compiled range kernels, scipy, matplotlib). Each case runs the module as ``__main__`` in
a fresh interpreter (runpy, as ``python -m`` does), catches argparse's SystemExit and lists
the heavy packages then in ``sys.modules``: none of them is needed to parse arguments.
Correctness, not speed: no timing threshold (the machine is shared).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

#: Packages no CLI needs to parse its arguments (numpy is allowed: the sweep loads it too).
HEAVY = ("numba", "llvmlite", "scipy", "pandas", "pyarrow", "matplotlib", "mujoco", "cvxpy",
         "gtsam", "sklearn")

#: The CLIs held to it, with the positional argument each requires (so that the mistyped
#: option, not a missing argument, is the error).
CLIS = {"sweep": [], "ranging": [], "rigid_ranging": ["some_folder"], "ultrasonic": [],
        "stationary": [], "sensitivity": [], "identification": [], "export": ["some_folder"],
        "bench": [], "paths_figure": []}

_DRIVER = f"""
import json, runpy, sys
module, args = sys.argv[1], sys.argv[2:]
sys.argv = [module, *args]
try:
    runpy.run_module(module, run_name="__main__", alter_sys=True)
    code = "returned"
except SystemExit as exc:
    code = exc.code
sys.stdout.flush()
print("\\nRESULT " + json.dumps({{"exit": code,
      "heavy": sorted(m for m in {HEAVY!r} if m in sys.modules)}}))
"""


def _parse_only(module: str, args: list[str]) -> tuple[dict, str, str]:
    """({"exit": code, "heavy": [...]}, stdout before the result line, stderr)."""
    r = subprocess.run([sys.executable, "-c", _DRIVER, f"experiments.{module}", *args],
                       cwd=REPO, capture_output=True, text=True, check=False, timeout=120)
    out, sep, result = r.stdout.rpartition("\nRESULT ")
    assert sep, f"no result line; stdout={r.stdout!r} stderr={r.stderr!r}"
    return json.loads(result), out, r.stderr


@pytest.mark.parametrize("module", sorted(CLIS))
def test_help_imports_no_heavy_package(module):
    res, out, err = _parse_only(module, ["--help"])
    assert res["exit"] == 0, err
    assert out.lstrip().startswith(f"usage: python -m experiments.{module}"), out[:200]
    assert res["heavy"] == [], f"--help of experiments.{module} imported {res['heavy']}"


@pytest.mark.parametrize("module", sorted(CLIS))
def test_bad_option_imports_no_heavy_package(module):
    res, _, err = _parse_only(module, [*CLIS[module], "--no-such-option"])
    lines = err.strip().splitlines()
    assert res["exit"] == 2 and len(lines) == 1, err
    assert f"python -m experiments.{module}: error:" in lines[0], lines
    assert "--no-such-option" in lines[0], lines
    assert res["heavy"] == [], f"a usage error of experiments.{module} imported {res['heavy']}"


def test_deferred_names_stay_importable():
    """The names the CLI modules imported at their top are still their attributes
    (``from experiments.identification_chain import kalman_steady_state``, ...)."""
    from estimator import kalman, ranging, sysid
    from experiments import identification, identification_chain, ultrasonic
    from experiments import ranging as ranging_cli

    assert identification_chain.kalman_steady_state is kalman.kalman_steady_state
    assert identification.AxisIdentification is sysid.AxisIdentification
    assert ranging_cli.localize is ranging.localize
    import pandas

    assert ultrasonic.pd is pandas
    with pytest.raises(AttributeError, match="no_such_name"):
        _ = ranging_cli.no_such_name
