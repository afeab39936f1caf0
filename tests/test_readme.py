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
    ci = (ROOT / ".ci" / "run").read_text()
    assert "pip install -q -e '.[test]' && python -m pytest -q" in ci


@pytest.mark.parametrize("index", range(len(re.findall(r"```python\n", README))))
def test_readme_python_block_runs(index, tmp_path):
    block = re.findall(r"```python\n(.*?)```", README, re.DOTALL)[index]
    script = tmp_path / "example.py"
    script.write_text(block)
    proc = subprocess.run([sys.executable, str(script)], check=False, cwd=tmp_path,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stdout.strip()


def test_readme_presets_and_modules_exist():
    from experiments.spec import available_presets

    for name in re.findall(r"--preset (\w+)", README):
        assert name in available_presets(), name
    for mod in set(re.findall(r"python -m (experiments\.\w+)", README)):
        assert (ROOT / (mod.replace(".", "/") + ".py")).exists(), mod
