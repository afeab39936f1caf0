"""The README's examples run as written (docs that rot are worse than none)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()


def test_readme_has_exactly_two_setup_commands():
    setup = README.split("## Set-up", 1)[1].split("\n## ", 1)[0]
    commands = re.findall(r"```bash\n(.*?)```", setup, re.DOTALL)
    assert [c.strip() for c in commands] == [
        "pip install -e . && python -m experiments.sweep",
        "pip install -e '.[test]' && python -m pytest -q",
    ]
    ci_lines = [ln.strip() for ln in (ROOT / ".ci" / "run").read_text().splitlines()]
    # CI runs the README's test command as written, as its last line (so pytest's exit code
    # is the script's), inside a virtual environment it has just created and activated
    assert ci_lines[-1] == commands[1].strip()
    venv = next(i for i, ln in enumerate(ci_lines) if ln.startswith("python3 -m venv "))
    activate = next(i for i, ln in enumerate(ci_lines) if ln.startswith("source ")
                    and ln.endswith("/bin/activate\""))
    assert venv < activate < len(ci_lines) - 1


BLOCKS = re.findall(r"```python\n(.*?)```", README, re.DOTALL)
#: Runs every block in one fresh interpreter (numpy, pandas and MuJoCo are imported once
#: instead of once per block, ~1 s each), each block as a script of its own: a new
#: ``__main__`` namespace and its own empty working folder; stdout and any exception per
#: block go to results.json.
_RUNNER = """
import contextlib, io, json, os, pathlib, sys, traceback
blocks = json.loads(pathlib.Path("blocks.json").read_text())
results = []
for i, code in enumerate(blocks):
    work = pathlib.Path(f"block{i}").resolve()
    work.mkdir()
    os.chdir(work)
    out = io.StringIO()
    try:
        with contextlib.redirect_stdout(out):
            exec(compile(code, f"README.md python block {i}", "exec"), {"__name__": "__main__"})
        results.append({"ok": True, "stdout": out.getvalue(), "error": ""})
    except BaseException:
        results.append({"ok": False, "stdout": out.getvalue(), "error": traceback.format_exc()})
    os.chdir(work.parent)
pathlib.Path("results.json").write_text(json.dumps(results))
"""


@pytest.fixture(scope="module")
def block_results(tmp_path_factory) -> list[dict]:
    """The outcome of every Python block of the README, run as described in _RUNNER."""
    import json

    work = tmp_path_factory.mktemp("readme")
    (work / "blocks.json").write_text(json.dumps(BLOCKS))
    (work / "runner.py").write_text(_RUNNER)
    proc = subprocess.run([sys.executable, "runner.py"], check=False, cwd=work,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads((work / "results.json").read_text())


@pytest.mark.parametrize("index", range(len(BLOCKS)))
def test_readme_python_block_runs(index, block_results):
    res = block_results[index]
    assert res["ok"], res["error"][-3000:]
    assert res["stdout"].strip()


def test_readme_presets_and_modules_exist():
    from experiments.spec import available_presets

    for name in re.findall(r"--preset (\w+)", README):
        assert name in available_presets(), name
    for mod in set(re.findall(r"python -m (experiments\.\w+)", README)):
        assert (ROOT / (mod.replace(".", "/") + ".py")).exists(), mod


def test_design_notes_name_every_module():
    """docs/DESIGN-notes.md maps every module of estimator/, sim/ and experiments/ (a module
    added without a line there fails here), and names no module that does not exist."""
    notes = (ROOT / "docs" / "DESIGN-notes.md").read_text()
    for pkg in ("estimator", "sim", "experiments"):
        section = notes.split(f"`{pkg}/` (", 1)[1].split("\n\n`", 1)[0].split("\n## ", 1)[0]
        named = set(re.findall(r"`(\w+)\.py`", section))
        # modules of subpackages (estimator/trackers/, experiments/runner/) count too
        files = {p.stem for p in (ROOT / pkg).rglob("*.py") if p.stem != "__init__"}
        assert files == named, (pkg, sorted(files - named), sorted(named - files))
