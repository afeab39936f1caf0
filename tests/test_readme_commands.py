"""Every shell command the README documents, and every "examples:" line of a CLI's --help,
runs: as written, or (where it is long or needs what a test cannot have) in the quick form
declared in MAPPED below (issue 23). A documented command that is neither in AS_WRITTEN nor
in MAPPED fails test_every_documented_command_is_declared, so a new one cannot go untested.

Where they run: a scratch git clone of the checkout with the working tree's state copied in
(its uncommitted edits and new files), ``../shared`` beside it (the README's real-data
paths), the truth cache copied (no re-simulation). Nothing in the checkout changes.
``/tmp/`` in a command becomes a scratch folder (the same command, its output redirected).
Running them takes 5-10 minutes on the 2-core machine, so the two tests that run them are
marked slow: the README's test command leaves them out, and ``.ci/run`` runs them before it
(``python -m pytest -q -m slow tests/test_readme_commands.py``). The declaration check and
the presets' output folders run in the default suite.

The commands run once, in documented order (README first: later commands read what earlier
ones wrote, e.g. the thesis run), from one module fixture.

After each command ``git status --porcelain`` of the clone must be what it was before, except
under the paths the command names (its arguments, e.g. ``--out clip.mp4`` or the results
folder ``report`` rewrites) and, for the commands asked to regenerate a committed reference
(ASKED_WRITES), that reference: no command writes a tracked file, or leaves an untracked one
git does not ignore, unless asked for.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shlex
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()
PY = Path(sys.executable)

#: Per-command limit (s): the slowest mapped form takes ~30 s on the loaded 2-core machine;
#: a hang must fail, not stall the suite.
TIMEOUT_S = 300

#: A small spec for the mapped forms of the long sweeps (the short square20 path, one window,
#: one seed, two techniques): the option under test (solver, backend, --jobs) is what the
#: command shows.
TINY_SPEC = """\
name = "tiny"
seed = 1
seeds = 1
masks = ["full"]
[defaults]
config = "rover_gps8"
noise = "gps_stationary"
path = "square20"
[[grid]]
window = [10]
weighting = "huff"
technique = ["none", "lc"]
"""
_TINY = "cat > my_spec.toml <<'TOML'\n" + TINY_SPEC + "TOML\n"

#: Documented command (normalized, see _normalize) -> the quick form that runs instead, each
#: with why. ``{tmp}`` is a scratch folder outside the clone.
MAPPED: dict[str, tuple[str, str]] = {
    "pip install -e . && python -m experiments.sweep": (
        "python -m experiments.sweep --seeds 1",
        ("the install is the environment this test runs in; the thesis preset with 1 of its 10 "
        "seeds keeps its whole grid (so the README's selections below are checked against it) "
        "and writes results/thesis/ as the default run does, for the commands that read it")),
    "python -m experiments.sweep": (
        "python -m experiments.sweep --seeds 1", "as the set-up command: the thesis grid, 1 seed"),
    "pip install -e .[test] && python -m pytest -q": (
        "python -m pytest -q -p no:cacheprovider -n 0 tests/test_readme.py -k setup",
        "the suite is what runs this; its check that CI runs this very command stands in"),
    "python -m experiments.sweep --solver elastic": (
        _TINY + "python -m experiments.sweep my_spec.toml --solver elastic --out {tmp}/elastic",
        "the thesis preset takes ~30 s: the batched solver on a tiny spec"),
    "python -m experiments.sweep --solver slsqp": (
        _TINY + "python -m experiments.sweep my_spec.toml --solver slsqp --out {tmp}/slsqp",
        "~25 min on the thesis preset: the SciPy per-window fit on a tiny spec"),
    "python -m experiments.sweep --preset thesis --solver slsqp": (
        _TINY + "python -m experiments.sweep my_spec.toml --solver slsqp --out {tmp}/slsqp",
        "as --solver slsqp"),
    "python -m experiments.sweep --preset thesis --solver elastic": (
        _TINY + "python -m experiments.sweep my_spec.toml --solver elastic --out {tmp}/elastic",
        "as --solver elastic"),
    "python -m experiments.sweep my_spec.toml --jobs 1 --out /tmp/mine": (
        _TINY + "python -m experiments.sweep my_spec.toml --jobs 1 --out {tmp}/mine",
        "my_spec.toml stands for the user's spec: a tiny one"),
    "python -m experiments.sweep my_spec.toml --out /tmp/run --jobs 2": (
        _TINY + "python -m experiments.sweep my_spec.toml --out {tmp}/run --jobs 2",
        "my_spec.toml stands for the user's spec: a tiny one"),
    "python -m experiments.sweep --backend dask --scheduler tcp://127.0.0.1:8786": (
        _TINY + "python -m experiments.sweep my_spec.toml --backend dask --jobs 1 "
        "--out {tmp}/dask",
        ("no scheduler runs at that address here: the same backend on a LocalCluster of one "
        "worker (what the sweep starts without --scheduler), a tiny spec")),
    "python -m experiments.sweep --preset thesis --backend dask --scheduler "
    "tcp://10.0.0.5:8786": (
        _TINY + "python -m experiments.sweep my_spec.toml --backend dask --jobs 1 "
        "--out {tmp}/dask",
        "as --backend dask --scheduler tcp://127.0.0.1:8786"),
    "evo_ape tum results/thesis/tum/<key>_truth.tum results/thesis/tum/<key>_estimate.tum -a": (
        ("python -c \"import glob, numpy as np; f = sorted(glob.glob('results/thesis/tum/*.tum'));"
        " assert len(f) == 2, f; [np.loadtxt(p, ndmin=2)[:, 7] for p in f]\" && "
        "{{ ! command -v evo_ape || evo_ape tum results/thesis/tum/*_truth.tum "
        "results/thesis/tum/*_estimate.tum -a; }}"),
        ("<key> is the exported cell's key: the two files the export wrote, read as TUM (8 "
        "columns), and evo_ape on them where evo is installed (it is no extra of ours)")),
    "python -m experiments.page results/thesis --with results/my_recording": (
        "python -m experiments.page results/thesis --with results/quick",
        "results/my_recording stands for any other run: the quick preset's, run above"),
    "python -m experiments.stationary --session a.nmea b.nmea c.nmea --out /tmp/real": (
        ("python -m experiments.stationary --session ../shared/realdata/gpsd/ublox-8.log "
        "../shared/realdata/gpsd/hemi.log ../shared/realdata/gpsd/rx210.log --out {tmp}/real"),
        "a.nmea b.nmea c.nmea stand for the user's logs: three shared NMEA logs"),
    "python -m experiments.stationary --real-logs DIR": (
        ("python -m experiments.stationary --real-logs ../shared/realdata/gpsd --duration 600 "
        "--no-split"),
        ("DIR stands for a folder of logs: the shared gpsd logs, beside a 600 s synthetic "
        "session without the common_fraction table (what --real-logs adds is the logs)")),
    "python -m experiments.sweep --preset quick --out /tmp/quick": (
        ("cp -r results/quick {tmp}/quick && python -m experiments.sweep --preset quick "
        "--out {tmp}/quick"),
        ("the quick run of the README's command above, again: into its own folder, resumed "
        "from a copy of that run's (the resume path; computing it twice takes ~10 s more)")),
    "python -m experiments.stationary": (
        "python -m experiments.stationary --duration 600",
        ("the default 4300 s synthetic session takes ~15 s (70 s on a loaded machine): a "
        "600 s one, into the same default folder (results/local/stationary)")),
    "python -m experiments.ultrasonic --out /tmp/us --n-mc 20000": (
        "python -m experiments.ultrasonic --out {tmp}/us --n-mc 20000 --quick",
        ("the full flight and identification take ~90 s: the smoke run into the custom folder "
        "(--quick fixes 5000 Monte Carlo points)")),
    "python -m experiments.ultrasonic --reference": (
        "rc=0; python -m experiments.ultrasonic --reference --quick || rc=$?; test $rc -eq 2",
        ("the reference run takes ~90 s (the coordinator's reference regeneration runs it): "
        "here, that --reference refuses any other option (exit 2), so it can only regenerate "
        "the committed folder exactly")),
    "python -m experiments.stationary --reference": (
        "rc=0; python -m experiments.stationary --reference --seed 1 || rc=$?; test $rc -eq 2",
        ("the reference run takes ~35 s (the coordinator's reference regeneration runs it): "
        "here, that --reference refuses any other option (exit 2)")),
    "python -m experiments.render results/thesis --where path=square100 window=100 "
    "technique=none weighting=huff noise_overrides={} seed=0 --out clip.mp4": (
        ("python -m experiments.render results/thesis --where path=square100 window=100 "
        "technique=none weighting=huff 'noise_overrides={{}}' seed=0 --out clip.mp4 --frames 10"),
        "the whole clip is ~500 frames: the same cell and writer, 10 frames"),
    "python -m experiments.render results/thesis --where path=square100 window=100 "
    "technique=lc+dyn weighting=huff dyn_growth=refill noise_overrides={} seed=0 --out clip.mp4": (
        ("python -m experiments.render results/thesis --where path=square100 window=100 "
        "technique=lc+dyn weighting=huff dyn_growth=refill 'noise_overrides={{}}' seed=0 "
        "--out clip.mp4 --frames 10"),
        "the whole clip is ~500 frames: the same cell and writer, 10 frames"),
    "python -m experiments.render --flight results/ultrasonic --out flight.gif --fps 15 "
    "--size 480x360": (
        ("python -m experiments.render --flight results/ultrasonic --out flight.gif --fps 15 "
        "--size 480x360 --frames 10"),
        "the whole flight is ~300 frames: the same writer and size, 10 frames"),
    ("python -m experiments.rigid_ranging ../shared/realdata/uwb_rigid/static_0820/* "
     "../shared/realdata/uwb_rigid/dynamic/fast --out results/local/rigid_ranging"): (
        ("python -m experiments.rigid_ranging "
         "../shared/realdata/uwb_rigid/static_0820/pos1_yaw000 --no-figures "
         "--out results/local/rigid_ranging"),
        ("every static run and the dynamic one take over 5 min here: one static run (~16 s), "
         "same output folder")),
    "python -m experiments.sensitivity": (
        "python -m experiments.sensitivity --quantity sigma --seeds 1",
        ("the full study (18 variants, 5 seeds: 4860 cells) takes ~300 s (~600 s with the path "
         "variants' truths to simulate): one quantity at 1 seed (270 cells, ~12 s), into the "
         "same default folder (results/local/sensitivity)")),
    "python -m experiments.sensitivity --seeds 3 --out /tmp/sens": (
        "python -m experiments.sensitivity --quantity sigma --seeds 1 --out {tmp}/sens",
        "as the default run: one quantity at 1 seed, into the custom folder"),
    "python -m experiments.sensitivity --reference --seeds 5": (
        ("rc=0; python -m experiments.sensitivity --reference --quantity sigma || rc=$?; "
         "test $rc -eq 2 && python -m experiments.sensitivity --quantity sigma --seeds 1 "
         "--out {tmp}/sens_reference"),
        ("the reference run takes ~320 s and rewrites results/sensitivity/ (the coordinator's "
         "reference regeneration runs it): here, that --reference refuses a partial study "
         "(exit 2), and the same pipeline as a non-reference quick run into a scratch folder")),
    "python -m experiments.ranging DIR [DIR ...]": (
        "python -m experiments.ranging ../shared/realdata/uwb_hanyang/LOS/Trajectory_A/Case_1",
        "DIR stands for recordings: the shared LOS case (default output, results/local/ranging)"),
}

#: Documented commands that run exactly as written (normalized; a trailing " ..." matches by
#: prefix, for the multi-line ones).
AS_WRITTEN: set[str] = {
    "python -m experiments.sweep --preset quick",
    "python -m experiments.sweep --help",
    "python -m experiments.report results/thesis",
    ("python -m experiments.export results/thesis --where path=square100 window=100 "
    "technique=lc+dyn weighting=huff dyn_growth=refill noise_overrides={} seed=0"),
    "python -m experiments.page results/thesis",
    "python -m experiments.paths_figure",
    "python -m experiments.paths_figure --reference",
    ("python -m experiments.stationary --session ../shared/realdata/gpsd/quectel-eg25-g.log "
    "--out results/local/quectel"),
    "python -c from sim.nmea import read_log, session_from_fixes as s; import numpy ...",
    "python -m experiments.sweep --preset example_recording",
    "mkdir -p /tmp/rdemo && cat > /tmp/rdemo/replay_demo.toml ...",
    "python -m experiments.sweep /tmp/rdemo/replay_demo.toml --out /tmp/rdemo/out",
    "ls /tmp/rdemo/out/epochs",
    "python -m experiments.export /tmp/rdemo/out --where window=10 technique=lc seed=0",
    "mkdir -p /tmp/hs && python -c ...",
    "cat > /tmp/hs/home_square.toml ...",
    "python -m experiments.sweep /tmp/hs/home_square.toml --out /tmp/hs/out",
    "python -m experiments.ultrasonic --quick",
    ("python -m experiments.ranging ../shared/realdata/uwb_hanyang/LOS/Trajectory_A/Case_1 "
    "--out /tmp/los"),
    "python -m experiments.ranging --reference",
    "python -m experiments.identification --out /tmp/ident",
    "python -m experiments.identification --reference",
    ("python -m experiments.ranging ../shared/realdata/uwb_rigid/dynamic/fast "
    "--out results/local/rigid_ranging_fast"),
    # the --help examples
    "python -m experiments.export /tmp/quick --where window=10 technique=lc seed=0",
    ("python -m experiments.export results/thesis --where path=square100 window=100 "
    "technique=lc+dyn weighting=huff dyn_growth=refill noise_overrides={} seed=0 --out /tmp/tum"),
    "python -m experiments.figures results/thesis",
    # README and --help: one quantity at 1 seed, ~12 s
    "python -m experiments.sensitivity --quantity sigma --seeds 1 --out /tmp/sens_sigma",
}

#: The shared real data beside the checkout (../shared/realdata); commands that read it skip,
#: saying so, where it is absent (e.g. a clone elsewhere).
REALDATA = ROOT.parent / "shared" / "realdata"
NEEDS_REALDATA = {"python -m experiments.ranging --reference"}

#: Commands asked to regenerate a committed reference: what they may rewrite.
ASKED_WRITES: dict[str, tuple[str, ...]] = {
    "python -m experiments.sweep --seeds 1": ("results/thesis/",),
    "python -m experiments.paths_figure --reference": ("results/figures/paths.png",),
    "python -m experiments.stationary --reference": ("results/stationary/",),
    "python -m experiments.ultrasonic --reference": ("results/ultrasonic/",),
    "python -m experiments.ranging --reference": ("results/ranging/",),
    "python -m experiments.identification --reference": ("results/ultrasonic/",),
}


# --------------------------------------------------------------------------- extraction
def split_statements(block: str) -> list[str]:
    """The shell statements of a script: lines joined while a statement goes on (a trailing
    backslash, an open quote, a here-document); comment-only lines dropped."""
    out: list[str] = []
    cur: list[str] = []
    heredoc: str | None = None
    for line in block.splitlines():
        cur.append(line)
        if heredoc is not None:
            if line.strip() != heredoc:
                continue
            heredoc = None
        elif m := re.search(r"<<-?\s*['\"]?(\w+)['\"]?", line):
            heredoc = m.group(1)
            continue
        text = "\n".join(cur)
        if text.rstrip().endswith("\\"):
            continue
        try:
            shlex.split(text, comments=True)
        except ValueError:       # an open quote: the statement goes on
            continue
        if shlex.split(text, comments=True):
            out.append(text)
        cur = []
    assert not cur and heredoc is None, f"unfinished shell statement: {cur}"
    return out


def _normalize(stmt: str) -> str:
    """A statement without comments, continuations and quoting, words joined by one space;
    a here-document is its first line (``cat > FILE ...``), a multi-line ``python -c`` its
    first code line (``python -c CODE...``)."""
    if "<<" in stmt:
        return " ".join(shlex.split(stmt.split("<<", 1)[0], comments=True)) + " ..."
    words = [w.strip() for w in shlex.split(stmt, comments=True)]
    text = " ".join(w for w in words if w)
    if "\n" in text:
        text = text.split("\n")[0].strip() + " ..."
    return text


def readme_statements() -> list[str]:
    """Every statement of the README's ```bash blocks, in order."""
    blocks = re.findall(r"```bash\n(.*?)```", README, re.DOTALL)
    return [s for b in blocks for s in split_statements(b)]


def cli_modules() -> list[str]:
    """``experiments.X`` for every module with a ``__main__`` guard (a CLI)."""
    return sorted(f"experiments.{p.stem}" for p in (ROOT / "experiments").glob("*.py")
                  if re.search(r"^if __name__ == ['\"]__main__['\"]:", p.read_text(), re.MULTILINE))


def example_modules() -> list[str]:
    """The CLIs whose source has an "examples:" help section (only these can print one;
    their --help is what is read)."""
    return [m for m in cli_modules()
            if "examples:" in (ROOT / (m.replace(".", "/") + ".py")).read_text()]


_HELP_SCRIPT = """
import contextlib, io, json, runpy, sys, warnings
warnings.simplefilter("ignore")
out = {}
for mod in sys.argv[1:]:
    buf = io.StringIO()
    sys.argv = [mod, "--help"]
    try:
        with contextlib.redirect_stdout(buf):
            runpy.run_module(mod, run_name="__main__", alter_sys=False)
    except SystemExit:
        pass
    out[mod] = buf.getvalue()
print(json.dumps(out))
"""


def help_texts() -> dict[str, str]:
    """``--help`` of every CLI (one interpreter: the imports are shared, ~3 s in all)."""
    proc = subprocess.run([str(PY), "-c", _HELP_SCRIPT, *example_modules()], cwd=ROOT,
                          capture_output=True, text=True, timeout=TIMEOUT_S, check=False)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


def help_statements(texts: dict[str, str]) -> list[str]:
    """The command lines of the "examples:" section of each help text (up to its first blank
    line), indentation removed."""
    out = []
    for text in texts.values():
        if "\nexamples:\n" not in "\n" + text:
            continue
        section = ("\n" + text).split("\nexamples:\n", 1)[1].split("\n\n", 1)[0]
        out += split_statements("\n".join(ln.strip() for ln in section.splitlines()))
    return out


HELP_TEXTS = help_texts()
DOCUMENTED: list[str] = []     # normalized, each once, README first, in order
STATEMENT: dict[str, str] = {}  # normalized -> the statement as written
for _s in readme_statements() + help_statements(HELP_TEXTS):
    _k = _normalize(_s)
    if _k not in STATEMENT:
        DOCUMENTED.append(_k)
        STATEMENT[_k] = _s


def _declared(key: str) -> bool:
    return key in MAPPED or any(key == w or (w.endswith(" ...") and key.startswith(w[:-4]))
                                for w in AS_WRITTEN)


# --------------------------------------------------------------------------- the runs
def _git(repo: Path, *args: str) -> str:
    return subprocess.run(["git", *args], cwd=repo, capture_output=True, text=True,
                          check=True).stdout


def _status(repo: Path) -> set[str]:
    """``git status --porcelain`` lines (untracked files one by one)."""
    return set(_git(repo, "status", "--porcelain", "--untracked-files=all").splitlines())


def scratch_clone(base: Path) -> Path:
    """``base/main``: a clone of the checkout with its working tree copied over (tracked
    edits, deletions, new unignored files), ``base/shared`` -> the checkout's ``../shared``,
    and the truth cache copied."""
    base.mkdir(parents=True, exist_ok=True)
    repo = base / "main"
    subprocess.run(["git", "clone", "-q", "--no-hardlinks", str(ROOT), str(repo)], check=True)
    for rel in _git(ROOT, "ls-files", "-z", "--cached", "--others",
                    "--exclude-standard").split("\0"):
        if not rel:
            continue
        src, dst = ROOT / rel, repo / rel
        if src.is_file():
            dst.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dst)
        elif dst.exists() and not src.exists():
            dst.unlink()
    if (ROOT / "results" / "cache").is_dir():
        shutil.copytree(ROOT / "results" / "cache", repo / "results" / "cache")
    if (ROOT.parent / "shared").is_dir():
        (base / "shared").symlink_to(ROOT.parent / "shared")
    return repo


def _named_paths(repo: Path, stmt: str) -> list[str]:
    """Paths inside the clone that a command names (its arguments that are paths): what it
    may write because it was asked to."""
    out = []
    for w in shlex.split(stmt, comments=True):
        if "/" not in w and not re.search(r"\.\w+$", w):
            continue
        p = (repo / w).resolve() if not os.path.isabs(w) else Path(w)
        with contextlib.suppress(ValueError):
            out.append(p.relative_to(repo.resolve()).as_posix())
    return out


def _leaked(repo: Path, before: set[str], after: set[str], allowed: list[str]) -> list[str]:
    """Status lines that changed and lie under no allowed path."""
    changed = sorted(before ^ after)
    ok = [a.rstrip("/") for a in allowed]
    return [ln for ln in changed
            if not any(ln[3:] == a or ln[3:].startswith(a + "/") for a in ok)]


#: Commands that read or write the thesis or quick results folders (or the shared spec
#: file my_spec.toml) run in one lane, in order; the others (the side studies) in a second
#: lane, in a clone of their own, at the same time (two lanes: the 2-core machine).
_SWEEP_LANE = re.compile(r"results/(thesis|quick)|/tmp/quick|my_spec|evo_ape"
                         r"|^(pip install -e \. && )?python -m experiments\.sweep"
                         r"( --preset quick)?$")


def _in_sweep_lane(keys: list[str]) -> set[str]:
    """The keys of the sweeps lane: those _SWEEP_LANE matches, and every key that shares a
    ``/tmp/<name>`` folder with one of them (a block's commands depend on each other)."""
    def tmp_dirs(k: str) -> set[str]:
        return set(re.findall(r"/tmp/([\w.-]+)", k))

    lane = {k for k in keys
            if _SWEEP_LANE.search(k) or _SWEEP_LANE.search(MAPPED.get(k, ("",))[0])}
    shared = set().union(*(tmp_dirs(k) for k in lane))
    return lane | {k for k in keys if tmp_dirs(k) & shared}


def _run_lane(base: Path, keys: list[str]) -> dict[str, dict]:
    """Run ``keys`` one after the other in a scratch clone under ``base``; per key its exit
    code, output tail, seconds, the command run and the status lines it changed outside
    what it may write."""
    repo = scratch_clone(base)
    tmp = base / "tmp"
    tmp.mkdir()
    env = dict(os.environ, PATH=f"{PY.parent}{os.pathsep}{os.environ.get('PATH', '')}",
               PYTHONDONTWRITEBYTECODE="1", MPLBACKEND="Agg")
    env.pop("PYTHONPATH", None)
    results: dict[str, dict] = {}
    done: dict[str, dict] = {}      # a quick form shared by two documented commands runs once
    for key in keys:
        form = MAPPED[key][0] if key in MAPPED else STATEMENT[key]
        cmd = re.sub(r"(?<![\w/.])/tmp/", f"{tmp}/", form)   # the README's /tmp, redirected
        cmd = cmd.replace("{tmp}", str(tmp)).replace("{{", "{").replace("}}", "}")
        if cmd in done:
            results[key] = done[cmd]
            continue
        if not REALDATA.is_dir() and ("../shared/" in cmd or key in NEEDS_REALDATA):
            results[key] = {"skip": f"needs the shared real data at {REALDATA}"}
            continue
        before = _status(repo)
        t0 = time.perf_counter()
        try:
            proc = subprocess.run(["bash", "-euo", "pipefail", "-c", cmd], cwd=repo, env=env,
                                  capture_output=True, text=True, timeout=TIMEOUT_S,
                                  check=False)
            code, tail = proc.returncode, (proc.stdout[-1500:] + proc.stderr[-2500:])
        except subprocess.TimeoutExpired:
            code, tail = None, f"timed out after {TIMEOUT_S} s"
        allowed = [*_named_paths(repo, cmd), *ASKED_WRITES.get(key, ()),
                   *ASKED_WRITES.get(form, ())]
        results[key] = done[cmd] = {
            "code": code, "tail": tail, "s": round(time.perf_counter() - t0, 2), "cmd": cmd,
            "leaked": _leaked(repo, before, _status(repo), allowed)}
    return results


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, dict]:
    """Every declared documented command run once (as written or its MAPPED form), in
    documented order within its lane (_SWEEP_LANE), the two lanes side by side."""
    from concurrent.futures import ThreadPoolExecutor

    base = tmp_path_factory.mktemp("commands")
    keys = [k for k in DOCUMENTED if _declared(k)]
    sweeps = _in_sweep_lane(keys)
    lanes = {"sweeps": [k for k in keys if k in sweeps],
             "studies": [k for k in keys if k not in sweeps]}
    with ThreadPoolExecutor(len(lanes)) as pool:
        futures = [pool.submit(_run_lane, base / name, ks) for name, ks in lanes.items()]
        results = {k: v for f in futures for k, v in f.result().items()}
    # what ran, with its seconds: beside the scratch clones, and where
    # CONFIGPOSE_COMMAND_TIMES names a file (to see which command takes the time)
    text = json.dumps(results, indent=1)
    (base / "runs.json").write_text(text)
    if os.environ.get("CONFIGPOSE_COMMAND_TIMES"):
        Path(os.environ["CONFIGPOSE_COMMAND_TIMES"]).write_text(text)
    return results


# --------------------------------------------------------------------------- the tests
def test_commands_are_found():
    """The extraction sees the README's blocks and the --help examples (a regex that finds
    nothing would make every test below vacuous)."""
    assert len(readme_statements()) >= 25
    assert {"experiments.sweep", "experiments.export", "experiments.render"} <= {
        m for m, t in HELP_TEXTS.items() if "\nexamples:\n" in t}
    assert "python -m experiments.sweep --preset quick" in DOCUMENTED


def test_every_documented_command_is_declared():
    """Each documented command is run as written or mapped to a declared quick form, and
    every declared command is still documented (a stale entry hides a changed command)."""
    assert [k for k in DOCUMENTED if not _declared(k)] == []
    assert sorted(set(MAPPED) - set(DOCUMENTED)) == []
    stale = [w for w in AS_WRITTEN if not any(
        k == w or (w.endswith(" ...") and k.startswith(w[:-4])) for k in DOCUMENTED)]
    assert stale == []


def test_statement_splitting():
    """Continuations, open quotes and here-documents make one statement; comments go."""
    block = ("a --x \\\n    --y   # c\n# only a comment\npython -c \"\nprint(1)\"\n"
             "cat > f <<'EOF'\nk = 1 # not a comment\nEOF\nb\n")
    assert split_statements(block) == ["a --x \\\n    --y   # c", "python -c \"\nprint(1)\"",
                                       "cat > f <<'EOF'\nk = 1 # not a comment\nEOF", "b"]
    assert _normalize("a --x \\\n    --y   # c") == "a --x --y"


@pytest.mark.slow
@pytest.mark.parametrize("key", DOCUMENTED)
def test_documented_command_runs(key, runs):
    """Exit code 0 (the quick form where MAPPED says so)."""
    assert _declared(key), f"neither AS_WRITTEN nor MAPPED: {key}"
    r = runs[key]
    if "skip" in r:
        pytest.skip(r["skip"])
    assert r["code"] == 0, f"{r['cmd']}\nexit {r['code']} after {r['s']:.1f} s:\n{r['tail']}"


@pytest.mark.slow
@pytest.mark.parametrize("key", DOCUMENTED)
def test_documented_command_leaves_git_status_alone(key, runs):
    """No tracked file changed, no untracked file git does not ignore, outside what the
    command names or was asked to regenerate (ASKED_WRITES)."""
    r = runs[key]
    if "skip" in r:
        pytest.skip(r["skip"])
    assert r["leaked"] == [], f"{r['cmd']}\nchanged git status: {r['leaked']}"


def test_every_preset_defaults_to_a_committed_or_ignored_folder():
    """Without --out a preset (with or without --solver) writes a committed reference folder
    or one git ignores (results/local/), never a new untracked one (issue 23)."""
    from estimator.window import SOLVERS
    from experiments.spec import PRESETS_DIR
    from experiments.sweep import default_out

    names = [p.stem for p in PRESETS_DIR.glob("*.toml")]
    assert "example_gps4" in names
    folders = {n: default_out(n).resolve().relative_to(ROOT.resolve()).as_posix()
               for n in names + [f"{n}-{s}" for n in names for s in SOLVERS]}
    committed = {"/".join(f.split("/")[:2]) for f in _git(ROOT, "ls-files", "results").split()}
    probe = "\n".join(f"{d}/tables.md" for d in folders.values()) + "\n"
    ignored = subprocess.run(["git", "check-ignore", "--stdin"], cwd=ROOT, input=probe,
                             capture_output=True, text=True, check=False).stdout.split()
    bad = {n: d for n, d in folders.items()
           if d not in committed and f"{d}/tables.md" not in ignored}
    assert bad == {}
