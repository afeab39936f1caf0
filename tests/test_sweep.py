"""Sweep runner: resume, force, error capture, determinism, parallel backends, SIGKILL, CLI.

Tiny specs only (square20 path, 2 seeds, windows 1 and 5) so the file stays well under a
minute on the shared 2-core machine.
"""

import contextlib
import json
import os
import re
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from experiments.spec import Spec
from experiments.sweep import CellOutput, build_parser, cell_rng, main, run

REPO = Path(__file__).resolve().parents[1]

TINY = {
    "name": "tiny",
    "seed": 11,
    "seeds": 2,
    "grid": [
        {"path": "square20", "window": [1, 5], "weighting": ["none", "huff"],
         "technique": "none"},
        {"path": "square20", "window": 5, "weighting": "huff",
         "technique": ["lc", "dyn", "lc+dyn", "motion_compensated", "ekf", "naive"]},
    ],
    "epochs": {"seeds": [0]},
}
# numbers that must agree bit for bit between runs (timings are excluded)
_TIMING = ("t_noise_s", "t_track_s", "t_score_s", "t_cell_s", "t_reused_s")


def _numbers(df: pd.DataFrame) -> pd.DataFrame:
    cols = [c for c in df.columns if c not in _TIMING]
    return df[cols].sort_values(["key", "mask"]).reset_index(drop=True)


# --------------------------------------------------------------------------- fakes
def fake_truth(path_file, path_overrides, config_file, sim_seed, cache_dir=None):
    return {"path": Path(path_file).stem}


def fake_cell(cell, truth, ctx):
    rng = cell_rng(ctx.spec_seed, cell.seed, 0)
    v = float(rng.normal()) + cell.window
    return CellOutput(rows=[{"mask": m, "ex_mean": v, "n_epochs": 3} for m in ctx.masks],
                      status_counts={"ok": 3})


def failing_cell(cell, truth, ctx):
    if cell.window == 5 and cell.weighting == "huff":
        raise RuntimeError("solver exploded")
    return fake_cell(cell, truth, ctx)


def _fake_spec(**kw):
    return Spec.from_dict({**TINY, "defaults": {"noise": "none"}, **kw}, source="fake")


def _fake_run(spec, out, **kw):
    return run(spec, out=out, jobs=1, progress=False, outputs=False, truth_fn=fake_truth, **kw)


def test_resume_skips_finished_cells_and_force_recomputes(tmp_path):
    spec = _fake_spec()
    n = len(spec.expand())
    r1 = _fake_run(spec, tmp_path, cell_fn=fake_cell)
    assert (r1.n_cells, r1.n_computed, r1.n_resumed, r1.n_failed) == (n, n, 0, 0)
    assert len(r1.cells) == n * len(spec.masks)
    assert len(list((tmp_path / "cells").glob("*.json"))) == n
    r2 = _fake_run(spec, tmp_path, cell_fn=fake_cell)
    assert (r2.n_computed, r2.n_resumed) == (0, n)
    pd.testing.assert_frame_equal(_numbers(r1.cells), _numbers(r2.cells))
    r3 = _fake_run(spec, tmp_path, cell_fn=fake_cell, force=True)
    assert (r3.n_computed, r3.n_resumed) == (n, 0)
    man = json.loads((tmp_path / "manifest.json").read_text())
    assert man["status"] == "complete" and man["spec_seed"] == 11 and man["seeds"] == [0, 1]
    assert man["spec"]["name"] == "tiny" and "git_commit" in man["code"]
    assert "package" in man["code"]
    assert f"tiny: {n} cells ({n} computed, 0 resumed, 0 failed)" in r3.summary()


def test_errors_are_recorded_with_parameters_and_do_not_stop_the_sweep(tmp_path):
    spec = _fake_spec()
    n = len(spec.expand())
    bad = [c for c in spec.expand() if c.window == 5 and c.weighting == "huff"]
    r = _fake_run(spec, tmp_path, cell_fn=failing_cell)
    assert r.n_failed == len(bad) and r.n_computed == n - len(bad)
    assert len(r.cells) == (n - len(bad)) * 2
    e = r.errors[0]
    assert e["error"] == "RuntimeError: solver exploded" and "Traceback" in e["traceback"]
    assert e["params"]["window"] == 5 and e["params"]["weighting"] == "huff"
    assert json.loads((tmp_path / "errors.json").read_text())[0]["key"] in {c.key for c in bad}
    # the rerun retries only the failed cells; when they succeed the error files go away
    r2 = _fake_run(spec, tmp_path, cell_fn=fake_cell)
    assert (r2.n_computed, r2.n_resumed, r2.n_failed) == (len(bad), n - len(bad), 0)
    assert not list((tmp_path / "errors").glob("*.json"))


def test_cli_help_documents_every_option(capsys):
    with pytest.raises(SystemExit):
        build_parser().parse_args(["--help"])
    text = capsys.readouterr().out
    for opt in ("--preset", "--out", "--jobs", "--backend", "--scheduler", "--force",
                "--solver", "--seeds", "--cache-dir", "examples:"):
        assert opt in text
    assert main(["--preset", "nope"]) == 2
    assert "preset 'nope'" in capsys.readouterr().err


# --------------------------------------------------------------------------- real pipeline
@pytest.fixture(scope="module")
def truth_cache(tmp_path_factory):
    return tmp_path_factory.mktemp("truth_cache")


@pytest.fixture(scope="module")
def real_run(tmp_path_factory, truth_cache):
    out = tmp_path_factory.mktemp("real")
    spec = Spec.from_dict(TINY, source="tiny")
    return run(spec, out=out, jobs=1, progress=False, figures=False, cache_dir=truth_cache)


def test_real_run_outputs(real_run):
    r = real_run
    assert r.n_failed == 0, r.errors
    out = r.out_dir
    for f in ("cells.parquet", "tables.md", "REPORT.md", "claims.csv", "manifest.json",
              "table_4_1_square20.csv", "weighting.csv", "orientation.csv"):
        assert (out / f).exists(), f
    c = r.cells
    assert set(c["mask"]) == {"full", "no_turns"}
    for col in ("ex_mean", "ex_median", "ex_std", "ex_rmse", "ex_p95", "ex_max", "ey_mean",
                "eu_mean", "eh_median", "along_mean", "jitter_rms", "t_track_s",
                "status_counts", "n_status_ok", "path", "window", "weighting", "technique",
                "solver", "seed"):
        assert col in c.columns, col
    full = c[c["mask"] == "full"]
    # the full path has at least as many epochs as the no-turns subset
    nt = c[c["mask"] == "no_turns"].set_index("key")["n_epochs"]
    assert (full.set_index("key")["n_epochs"] >= nt).all()
    # per-epoch files for seed 0 only, and they agree with the summary row
    ep_keys = {p.stem for p in (out / "epochs").glob("*.parquet")}
    assert ep_keys == set(c.loc[c["seed"] == 0, "key"])
    row = full[full["key"] == min(ep_keys)].iloc[0]
    ep = pd.read_parquet(out / "epochs" / f"{row['key']}.parquet")
    # Eq. 4.1 mean |x| recomputed from the per-epoch file (same floats, same order)
    assert np.nanmean(np.abs(ep["err_x"])) == pytest.approx(row["ex_mean"], rel=1e-12)


def test_same_spec_gives_identical_cells_serial_and_parallel(real_run, tmp_path, truth_cache):
    spec = real_run.spec
    again = run(spec, out=tmp_path / "again", jobs=1, progress=False, outputs=False,
                cache_dir=truth_cache)
    pd.testing.assert_frame_equal(_numbers(real_run.cells), _numbers(again.cells))
    par = run(spec, out=tmp_path / "par", jobs=2, progress=False, outputs=False,
              cache_dir=truth_cache)
    pd.testing.assert_frame_equal(_numbers(real_run.cells), _numbers(par.cells))


def test_dask_local_cluster_backend(real_run, tmp_path, truth_cache):
    from distributed import LocalCluster

    spec = Spec.from_dict({**TINY, "grid": [TINY["grid"][0]]}, source="tiny")
    with LocalCluster(n_workers=1, threads_per_worker=2, processes=False,
                      dashboard_address=None) as cluster:
        r = run(spec, out=tmp_path, backend="dask", scheduler=cluster.scheduler_address,
                progress=False, outputs=False, cache_dir=truth_cache)
    assert r.n_failed == 0 and r.n_computed == len(spec.expand())
    ref = real_run.cells[real_run.cells["key"].isin(r.cells["key"])]
    pd.testing.assert_frame_equal(_numbers(ref), _numbers(r.cells))


def _sweep_killed_mid_run(spec_file: Path, out: Path, truth_cache) -> tuple[int, int]:
    """Start the sweep on ``spec_file`` in its own session, SIGKILL the whole group once a
    first cell is on disk; returns (cells seen before the kill, cells on disk after it)."""
    cmd = [sys.executable, "-m", "experiments.sweep", str(spec_file), "--out", str(out),
           "--jobs", "2", "--quiet", "--no-figures", "--cache-dir", str(truth_cache)]
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    proc = subprocess.Popen(cmd, cwd=REPO, env=env, start_new_session=True,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 60
    n_before = 0
    while time.time() < deadline and proc.poll() is None:
        n_before = len(list((out / "cells").glob("*.json"))) if (out / "cells").exists() else 0
        if n_before >= 1:
            break
        time.sleep(0.01)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    n_after = len(list((out / "cells").glob("*.json"))) if (out / "cells").exists() else 0
    return n_before, n_after


def test_sigkill_mid_run_loses_and_duplicates_nothing(real_run, tmp_path, truth_cache):
    spec_file = tmp_path / "tiny.toml"
    spec_file.write_text(_toml(TINY))
    n_total = len(real_run.spec.expand())
    # Landing the kill mid-run is a precondition, not the property under test: on a loaded
    # machine the last batch can finish between the poll and the kill (seen once at load
    # ~10), so a kill that came too late is retried in a fresh folder.
    tries = []
    for attempt in range(4):
        out = tmp_path / f"killed{attempt}"
        n_before, n_after_kill = _sweep_killed_mid_run(spec_file, out, truth_cache)
        tries.append((n_before, n_after_kill))
        if 0 < n_after_kill < n_total and n_before <= n_after_kill:
            break
    else:
        pytest.fail(f"no kill landed mid-run in 4 tries (cells before/after, of {n_total}): "
                    f"{tries}")
    # a torn write leaves at most a temp file whose name never matches the store's '*.json'
    for p in (out / "cells").iterdir():
        assert p.suffix in (".json", ".tmp"), p.name
    # finished cells are complete JSON documents (atomic writes)
    for p in (out / "cells").glob("*.json"):
        json.loads(p.read_text())
    r = run(spec_file, out=out, jobs=1, progress=False, outputs=False, cache_dir=truth_cache)
    assert r.n_resumed == n_after_kill and r.n_computed == n_total - n_after_kill
    assert len(list((out / "cells").glob("*.json"))) == n_total
    assert r.cells["key"].nunique() == n_total and len(r.cells) == 2 * n_total
    pd.testing.assert_frame_equal(_numbers(real_run.cells), _numbers(r.cells))


def test_readme_example_user_added_configuration(tmp_path, truth_cache):
    """README walkthrough: models/configs/rover_gps4.toml named in a spec runs end to end."""
    r = run("example_gps4", out=tmp_path, jobs=1, progress=False, figures=False,
            cache_dir=truth_cache)
    assert r.n_failed == 0, r.errors
    assert set(r.cells["config"]) == {"rover_gps8", "rover_gps4"}
    assert "config=rover_gps4" in (tmp_path / "REPORT.md").read_text()


def test_models_named_by_file_are_shown_by_their_name(tmp_path, truth_cache):
    """Tables and file names use a model's ``name``, not its file name (issue 13)."""
    cfg = (REPO / "models" / "configs" / "rover_gps4.toml").read_text()
    (tmp_path / "layouts").mkdir()
    (tmp_path / "layouts" / "my_roof.toml").write_text(
        cfg.replace('name = "rover_gps4"', 'name = "roof4"', 1))
    spec = tmp_path / "s.toml"
    spec.write_text('name = "named"\nseeds = 1\n[defaults]\nnoise = "none"\n[[grid]]\n'
                    'path = "square20"\nwindow = 5\nweighting = "huff"\n'
                    'technique = ["none", "lc"]\nconfig = ["rover_gps8", "layouts/my_roof.toml"]\n')
    r = run(spec, out=tmp_path / "out", jobs=1, progress=False, figures=False,
            cache_dir=truth_cache)
    assert r.n_failed == 0, r.errors
    names = {p.name for p in (tmp_path / "out").glob("table_4_1*.csv")}
    assert "table_4_1_square20_config_roof4.csv" in names, names
    assert not any("toml" in n for n in names)
    assert "config=roof4" in (tmp_path / "out" / "tables.md").read_text()


def test_figures_redraw_and_tum_export_from_saved_files(real_run, tmp_path):
    from experiments import export, figures

    out = real_run.out_dir
    files = figures.draw_all(out)
    names = {f.name for f in files}
    assert {"fig_4_118_orientation.png", "fig_weights_square20.png",
            "fig_sensor1_lag_square20.png", "fig_4_123_lc_dyn.png"} <= names, names
    # palette PNGs (experiments.png): empty axes of the smallest figure are ~4.3 kB, the
    # smallest drawn figure here ~7 kB
    assert len(files) >= 5 and all(f.stat().st_size > 6_000 for f in files)
    est, tru = export.export_tum(out, where={"window": 5, "technique": "lc", "seed": 0},
                                 out=tmp_path)
    a = np.loadtxt(est)
    b = np.loadtxt(tru)
    assert a.shape[1] == 8 and b.shape == a.shape
    # unit quaternions about +z; the truth's yaw is recovered from qz, qw
    np.testing.assert_allclose(np.linalg.norm(a[:, 4:], axis=1), 1.0, atol=1e-6)
    key = export.find_cell(out, where={"window": 5, "technique": "lc", "seed": 0})["key"]
    ep = pd.read_parquet(next((out / "epochs").glob(f"{key}.parquet")))
    np.testing.assert_allclose(2 * np.arctan2(b[:, 6], b[:, 7]),
                               np.angle(np.exp(1j * ep["truth_yaw"])), atol=1e-5)
    with pytest.raises(ValueError, match="exactly one"):
        export.find_cell(out, where={"window": 5})


def _toml(d: dict) -> str:
    """Minimal TOML writer for the test spec (tables, arrays of tables, scalars, lists)."""
    def val(v):
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, list):
            return "[" + ", ".join(val(x) for x in v) + "]"
        return str(v).lower() if isinstance(v, bool) else str(v)
    lines = [f"{k} = {val(v)}" for k, v in d.items() if not isinstance(v, (dict, list))
             or (isinstance(v, list) and not (v and isinstance(v[0], dict)))]
    for k, v in d.items():
        if isinstance(v, dict):
            lines.append(f"[{k}]")
            lines += [f"{kk} = {val(vv)}" for kk, vv in v.items()]
        elif isinstance(v, list) and v and isinstance(v[0], dict):
            for block in v:
                lines.append(f"[[{k}]]")
                lines += [f"{kk} = {val(vv)}" for kk, vv in block.items()]
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------- provenance
def test_cells_computed_by_other_code_are_recomputed(tmp_path, monkeypatch, capsys):
    import experiments.runner.run
    import experiments.runner.store
    import experiments.sweep as sweep

    spec = _fake_spec()
    n = len(spec.expand())
    _fake_run(spec, tmp_path, cell_fn=fake_cell)
    rec = json.loads(next((tmp_path / "cells").glob("*.json")).read_text())
    assert rec["code"] == sweep.cell_code_digest()
    # same code: everything resumes; changed sources: nothing old is mixed in
    assert _fake_run(spec, tmp_path, cell_fn=fake_cell).n_resumed == n
    for module in (experiments.runner.run, experiments.runner.store):   # its users
        monkeypatch.setattr(module, "cell_code_digest", lambda: "other-code")
    r = _fake_run(spec, tmp_path, cell_fn=fake_cell)
    assert (r.n_computed, r.n_resumed) == (n, 0)
    assert f"{n} of {n} finished cells were computed by other code" in capsys.readouterr().err
    assert json.loads((tmp_path / "run.local.json").read_text())["n_stale"] == n


def test_spec_toml_records_the_overrides_and_reloads_to_the_same_cells(tmp_path):
    from experiments.spec import load_spec

    spec = _fake_spec().with_solver("slsqp").with_seeds([3, 4])
    _fake_run(spec, tmp_path, cell_fn=fake_cell)
    again = load_spec(tmp_path / "spec.toml")
    assert again.name == "tiny-slsqp" and again.seeds == (3, 4)
    assert [c.key for c in again.expand()] == [c.key for c in spec.expand()]
    assert {c.solver for c in again.expand()} <= {"slsqp", "-"}


def test_worker_memo_does_not_outlive_a_run_or_ignore_the_session_length():
    import experiments.sweep as sweep

    calls = []

    def cell_fn(cell, truth, ctx):
        key = ("obs", ctx.session_s)
        if key not in ctx.memo:
            calls.append(ctx.session_s)
            ctx.memo[key] = object()
        return CellOutput(rows=[{"mask": "full", "ex_mean": 0.0}])

    from experiments.runner.worker import WORKER

    cells = _fake_spec().expand()[:2]
    for run_id in ("a", "a", "b"):
        job = sweep.CellJob(spec_seed=0, masks=("full",), session_s=100.0, run_id=run_id,
                            cell_fn=cell_fn)
        sweep.run_batch(cells, None, [False, False], job)
    assert calls == [100.0, 100.0]  # memo reused within run "a", cleared for run "b"
    WORKER.memo.clear()


def test_observations_memo_keys_on_the_session_length(truth_cache):
    from collections import OrderedDict

    import experiments.sweep as sweep
    from estimator.configuration import SensorConfig

    cell = Spec.from_dict({**TINY, "defaults": {"noise": "gps_stationary"}}).expand()[0]
    truth = sweep.simulate_truth(cell.file("path"), cell.path_overrides, cell.file("config"), 0,
                                 str(truth_cache))
    config = SensorConfig.load(cell.file("config")).planar()
    memo = OrderedDict()

    def obs(session_s):
        ctx = sweep.CellContext(spec_seed=1, masks=("full",), session_s=session_s,
                                want_epochs=False, memo=memo)
        return sweep._observations(cell, truth, config, ctx)

    a, b = obs(4000.0), obs(1000.0)
    assert not np.array_equal(a, b, equal_nan=True)  # a shorter session: other errors
    assert obs(4000.0) is a  # memoised


@pytest.mark.parametrize("n", ["0", "-1"])
def test_cli_rejects_zero_seeds(n, capsys):
    """--seeds -1 said 'seeds: must be non-negative integers, got ()'."""
    with pytest.raises(SystemExit) as ex:
        main(["--preset", "quick", "--seeds", n, "--out", "/nonexistent/never"])
    err = capsys.readouterr().err.strip().splitlines()
    assert ex.value.code == 2 and len(err) == 1
    assert f"argument --seeds: must be an integer >= 1, got '{n}'" in err[0]


def test_spec_rejects_a_noise_file_that_is_not_a_gps_model():
    from experiments.spec import SpecError

    with pytest.raises(SpecError, match=r"grid\[0\]\.noise: 'ultrasonic' is not a GPS noise model"):
        Spec.from_dict({"name": "x", "defaults": {"path": "square20", "noise": "ultrasonic"},
                        "grid": [{"window": [1]}]})


# --------------------------------------------------------------------------- faults (issue 13)
def epochs_cell(cell, truth, ctx):
    out = fake_cell(cell, truth, ctx)
    if ctx.want_epochs:
        out.epochs = pd.DataFrame({"t": np.arange(50.0), "cg_x": np.arange(50.0)})
    return out


def test_disk_full_mid_run_is_one_line_and_the_rerun_resumes(tmp_path, monkeypatch):
    import errno

    from experiments import sweep
    from experiments.sweep import SweepError

    spec = _fake_spec()
    n = len(spec.expand())
    real_write = sweep.CellStore.write
    calls = {"n": 0}

    def full_disk(self, cell, res):
        calls["n"] += 1
        if calls["n"] > 3:
            raise OSError(errno.ENOSPC, "No space left on device", str(self.cells_dir / "x.tmp"))
        real_write(self, cell, res)

    monkeypatch.setattr(sweep.CellStore, "write", full_disk)
    with pytest.raises(SweepError) as exc:
        _fake_run(spec, tmp_path, cell_fn=fake_cell)
    msg = str(exc.value)
    assert "\n" not in msg and "No space left on device" in msg and "x.tmp" in msg
    assert "rerun the same command to resume" in msg
    assert json.loads((tmp_path / "manifest.json").read_text())["status"] == "interrupted"
    monkeypatch.setattr(sweep.CellStore, "write", real_write)
    r = _fake_run(spec, tmp_path, cell_fn=fake_cell)
    assert (r.n_resumed, r.n_computed, r.n_failed) == (3, n - 3, 0)
    assert json.loads((tmp_path / "manifest.json").read_text())["status"] == "complete"


def test_cli_unwritable_results_is_one_line_exit_3(tmp_path, capsys, monkeypatch):
    import experiments.runner.run

    def refuse(path, obj):
        raise PermissionError(13, "Permission denied", str(path))

    monkeypatch.setattr(experiments.runner.run, "write_json", refuse)
    spec = tmp_path / "s.toml"
    spec.write_text('name = "ro"\n[defaults]\nnoise = "none"\n[[grid]]\npath = "square20"\n'
                    'window = 1\n')
    assert main([str(spec), "--out", str(tmp_path / "out"), "--quiet", "--jobs", "1"]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Permission denied" in err[0] and "manifest.json" in err[0]


def test_unreachable_dask_scheduler_fails_fast_naming_the_address(tmp_path):
    import socket

    from experiments.sweep import SweepError

    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    addr = f"tcp://127.0.0.1:{port}"
    t0 = time.perf_counter()
    with pytest.raises(SweepError, match=rf"{addr}.*dask scheduler --port"):
        run(_fake_spec(), out=tmp_path, backend="dask", scheduler=addr, progress=False,
            outputs=False, truth_fn=fake_truth, cell_fn=fake_cell)
    assert time.perf_counter() - t0 < 10.0     # was a 30 s hang and a 61-line OSError


def test_damaged_cell_files_are_detected_reported_and_recomputed(tmp_path, capsys):
    spec = _fake_spec()
    n = len(spec.expand())
    _fake_run(spec, tmp_path, cell_fn=epochs_cell)
    parquets = sorted((tmp_path / "epochs").glob("*.parquet"))
    jsons = sorted((tmp_path / "cells").glob("*.json"))
    assert parquets
    p = parquets[0]
    p.write_bytes(p.read_bytes()[: p.stat().st_size // 2])        # truncated parquet
    victim = next(j for j in jsons if j.stem != p.stem)
    victim.write_text("")                                          # empty cell record
    capsys.readouterr()
    r = _fake_run(spec, tmp_path, cell_fn=epochs_cell)
    err = capsys.readouterr().err
    assert "2 of" in err and "damaged files" in err and "other code" not in err
    assert (r.n_computed, r.n_resumed) == (2, n - 2)
    pd.read_parquet(p)                                             # readable again
    assert json.loads((tmp_path / "run.local.json").read_text())["n_damaged"] == 2


def test_rerun_leaves_the_manifest_byte_identical(tmp_path):
    spec = _fake_spec()
    _fake_run(spec, tmp_path, cell_fn=fake_cell)
    first = (tmp_path / "manifest.json").read_bytes()
    _fake_run(spec, tmp_path, cell_fn=fake_cell)
    assert (tmp_path / "manifest.json").read_bytes() == first
    man = json.loads(first)
    assert not any(k in man for k in ("started_utc", "timings_s", "cpu_count"))
    assert str(REPO) not in first.decode()


def test_spec_without_epochs_says_which_figures_it_cannot_draw(tmp_path, capsys, truth_cache):
    spec = tmp_path / "s.toml"
    spec.write_text('name = "noep"\nseeds = 1\n[defaults]\nnoise = "none"\n[[grid]]\n'
                    'path = "square20"\nwindow = 5\nweighting = "huff"\n'
                    'technique = ["none", "lc"]\n')
    run(spec, out=tmp_path / "out", jobs=1, progress=False, cache_dir=truth_cache)
    err = capsys.readouterr().err
    assert "no cell kept per-epoch estimates" in err and "[epochs]" in err


def test_lc_with_smoothed_heading_is_an_estimator_row(tmp_path, truth_cache):
    """Issue 14's "LC, smoothed heading": the pose filter's RTS heading from the same
    observations feeds step 5 of the lag correction. It uses no truth (not an oracle) and,
    on square20, its heading is closer to the truth than the law-of-cosines heading LC uses."""
    spec = tmp_path / "s.toml"
    spec.write_text('name = "lcs"\nseeds = 1\n[defaults]\nnoise = "gps_stationary"\n'
                    '[[grid]]\npath = "square20"\nwindow = 10\nweighting = "huff"\n'
                    'technique = ["lc", "lc_smoothed_heading"]\n[epochs]\nseeds = [0]\n')
    r = run(spec, out=tmp_path / "out", jobs=1, progress=False, figures=False,
            cache_dir=truth_cache)
    assert r.n_failed == 0, r.errors
    from experiments.spec import ORACLE_TECHNIQUES

    assert "lc_smoothed_heading" not in ORACLE_TECHNIQUES
    by = pd.read_csv(tmp_path / "out" / "by_cell.csv")
    assert not by.loc[by["technique"] == "lc_smoothed_heading", "oracle"].any()
    ep = {t: pd.read_parquet(next((tmp_path / "out" / "epochs").glob(f"{k}.parquet")))
          for t, k in r.cells.drop_duplicates("technique")[["technique", "key"]].values}
    # the shift's direction follows the heading it is given: compare it with the truth's
    shift = {t: e[["lag_dx", "lag_dy"]].to_numpy() for t, e in ep.items()}
    assert np.isfinite(shift["lc_smoothed_heading"]).all(axis=1).mean() > 0.9
    err = {}
    for t, d in shift.items():
        e = ep[t]
        ang = np.arctan2(d[:, 1], d[:, 0])
        off = np.angle(np.exp(1j * (ang - e["truth_yaw"].to_numpy())))
        ok = np.isfinite(off) & (np.hypot(d[:, 0], d[:, 1]) > 0.5)
        err[t] = np.sqrt(np.mean(np.minimum(np.abs(off[ok]), np.pi - np.abs(off[ok])) ** 2))
    assert err["lc_smoothed_heading"] < 0.5 * err["lc"], err


# --------------------------------------------------------------------------- scheduling
@pytest.mark.parametrize("preset", ["tiny", "thesis", "quick"])
@pytest.mark.parametrize("jobs", [1, 2, 7, 64])
def test_batches_partition_cells_and_keep_a_noise_keys_filter_cells_together(preset, jobs):
    """Every cell in exactly one task; a task holds one noise key (shared observations);
    the pose-filter cells of a noise key share a task (one forward pass through the memo);
    tasks come largest first."""
    from experiments.spec import load_spec
    from experiments.sweep import PASS_COST_CELLS as _PASS_COST_CELLS
    from experiments.sweep import batches as _batches
    from experiments.sweep import uses_pose_filter as _uses_pose_filter

    cells = (Spec.from_dict(TINY, source="tiny") if preset == "tiny"
             else load_spec(preset)).expand()
    epochs = {c.truth_key: 100 + 17 * i for i, c in enumerate(cells)}
    batches = _batches(cells, jobs, lambda c: epochs[c.truth_key])
    keys = [c.key for b in batches for c in b]
    assert sorted(keys) == sorted(c.key for c in cells)
    where: dict = {}
    for i, b in enumerate(batches):
        assert len({c.noise_key for c in b}) == 1
        for c in b:
            if _uses_pose_filter(c):
                where.setdefault(c.noise_key, set()).add(i)
    assert all(len(v) == 1 for v in where.values())
    cost = [(len(b) + _PASS_COST_CELLS * any(map(_uses_pose_filter, b)))
            * epochs[b[0].truth_key] for b in batches]
    assert cost == sorted(cost, reverse=True)


def test_outputs_unchanged_are_not_rewritten(real_run):
    """The real units on a small sweep: a second pass over unchanged inputs rewrites
    nothing and says so in the run's summary line."""
    from experiments.outputs import write_outputs

    out = real_run.out_dir
    write_outputs(real_run.cells, out, spec=real_run.spec, figures=False)
    before = {p.name: p.stat().st_mtime_ns for p in out.iterdir() if p.is_file()}
    res = write_outputs(real_run.cells, out, spec=real_run.spec, figures=False)
    assert res["written"] == [] and set(res["skipped"]) == {"tables", "report", "page"}
    after = {p.name: p.stat().st_mtime_ns for p in out.iterdir() if p.is_file()}
    changed = {k for k in after if before.get(k) != after[k]}
    assert changed <= {"outputs.local.json"}, changed


def test_workers_are_started_early_only_when_cells_are_likely_to_run(tmp_path):
    from experiments.sweep import _likely_work

    def args(*a):
        return build_parser().parse_args([*a])

    out = tmp_path / "run"
    assert _likely_work(args("--out", str(out)))                 # nothing there yet
    (out / "cells").mkdir(parents=True)
    assert _likely_work(args("--out", str(out)))                 # a folder, no finished cell
    (out / "cells" / "abc.json").write_text("{}")
    assert not _likely_work(args("--out", str(out)))             # a resumed run
    assert _likely_work(args("--out", str(out), "--force"))
    assert _likely_work(args("my_spec.toml"))                    # folder unknown before reading


def test_warm_up_lock_lets_one_worker_at_a_time(tmp_path):
    """While one worker warms up (the lock held), another process cannot take the lock; it
    can once the first is done (the lock file stays usable)."""
    from experiments.runner.worker import _exclusive

    lock = tmp_path / "warm.lock"
    probe = ("import fcntl, sys\n"
             f"fh = open({str(lock)!r}, 'a')\n"
             "try:\n"
             "    fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)\n"
             "except BlockingIOError:\n"
             "    sys.exit(7)\n")

    def other_takes_it() -> bool:
        rc = subprocess.run([sys.executable, "-c", probe], check=False).returncode
        assert rc in (0, 7), rc
        return rc == 0

    with _exclusive(str(lock)):
        assert not other_takes_it()
    assert other_takes_it()
    with _exclusive(None):                 # no path: no lock, the block still runs
        assert other_takes_it()
    ran = []
    with _exclusive(str(tmp_path / "no-such-folder" / "warm.lock")):   # cannot be created
        ran.append(True)                   # the work runs anyway, without a lock
    assert ran


def test_a_worker_skips_its_warm_up_while_another_holds_the_lock(tmp_path, monkeypatch):
    """warm_up does not wait for another worker's warm-up (it would idle with cells queued,
    issue 27): with the lock held it returns at once and writes no warm-up line; a lock
    asked for without waiting is not taken while held, and is once free."""
    from experiments.runner.worker import TIMELINE_ENV, _exclusive, warm_up

    lock, line = str(tmp_path / "warm.lock"), tmp_path / "timeline.jsonl"
    monkeypatch.setenv(TIMELINE_ENV, str(line))
    with _exclusive(lock) as mine:
        assert mine
        with _exclusive(lock, wait=False) as other:
            assert other is False
        assert warm_up(False, lock) == os.getpid()
    assert not line.exists()
    with _exclusive(lock, wait=False) as free:
        assert free


def test_cli_exit_codes_and_no_leftover_temporary_folders(tmp_path):
    """The command line ends through experiments.cli after stopping its workers
    (experiments.runner.backends.stop_workers): the exit code is main()'s, the summary line
    is printed, and joblib's shared-memory folders of the run's workers are removed (those
    named by the run's pid: other processes on the machine make and remove their own
    meanwhile)."""
    spec_file = tmp_path / "tiny.toml"
    spec_file.write_text(_toml({**TINY, "grid": [TINY["grid"][0]], "seeds": 1}))
    shm = Path("/dev/shm")
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    proc = subprocess.Popen([sys.executable, "-m", "experiments.sweep", str(spec_file),
                             "--out", str(tmp_path / "out"), "--jobs", "2", "--quiet",
                             "--no-figures", "--cache-dir", str(tmp_path / "cache")],
                            cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    stdout, stderr = proc.communicate(timeout=300)
    assert proc.returncode == 0, stderr
    assert "tiny: 4 cells (4 computed, 0 resumed, 0 failed)" in stdout
    assert "leaked" not in stderr
    left = sorted(shm.glob(f"joblib_memmapping_folder_{proc.pid}_*")) if shm.is_dir() else []
    assert not left, left
    bad = subprocess.run([sys.executable, "-m", "experiments.sweep", "--preset", "nope"],
                         cwd=REPO, env=env, capture_output=True, text=True, check=False)
    assert bad.returncode == 2 and "nope" in bad.stderr


def test_end_of_run_imports_leave_matplotlib_to_the_workers():
    """The main process imports what the outputs phase needs while the workers compute the
    cells (experiments.runner.run.import_for_outputs); that includes experiments.figures for the
    figure groups' names, and must not include matplotlib (the workers draw)."""
    code = ("import sys\n"
            "import experiments.sweep as s\n"
            "s.import_for_outputs()\n"
            "assert 'pandas' in sys.modules and 'experiments.page' in sys.modules\n"
            "assert 'experiments.causes' in sys.modules\n"    # the report unit's inputs
            "import experiments.figures as f\n"
            "assert f.figure_tasks()\n"
            "print('matplotlib' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True,
                         text=True, check=True).stdout.strip()
    assert out == "False"


# --------------------------------------------------------------------------- interrupts, locks
def _descendants(pid: int) -> set[int]:
    """Every live descendant of ``pid`` (Linux /proc)."""
    out, todo = set(), [pid]
    while todo:
        p = todo.pop()
        for task in Path(f"/proc/{p}/task").glob("*"):
            with contextlib.suppress(OSError):
                kids = {int(k) for k in (task / "children").read_text().split()}
                todo.extend(kids - out)
                out |= kids
    return out


def _default_sigint() -> None:
    """In the child before exec: SIGINT back to its default disposition."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _alive(pid: int) -> bool:
    """Whether ``pid`` still runs (a zombie waiting to be reaped does not)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    return "\nState:\tZ" not in status


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="needs Linux /proc")
@pytest.mark.parametrize("sig, code, group", [(signal.SIGINT, 130, False),
                                              (signal.SIGINT, 130, True),
                                              (signal.SIGTERM, 143, False)])
def test_interrupt_is_one_line_marks_the_manifest_and_leaves_no_worker(sig, code, group,
                                                                      tmp_path):
    """Ctrl-C (SIGINT) and SIGTERM mid-run: exit 130 / 143, ONE line on stderr (no traceback,
    no joblib warning), manifest.json "interrupted", no child process of the run survives it
    (the loky workers ran on for minutes after SIGTERM), and the rerun resumes the finished
    cells. The signal lands once the first cell is written (the workers are computing);
    ``group``: to the whole process group, workers included, as a terminal's Ctrl-C does."""
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "experiments.sweep", "--preset", "quick", "--seeds", "6",
           "--out", str(out), "--jobs", "2", "--quiet", "--no-figures"]
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    # A terminal starts the command with SIGINT at its default; a pytest-xdist worker may
    # have it ignored (SIG_IGN is inherited across exec, and then Python installs no
    # KeyboardInterrupt handler: the run ignores Ctrl-C and exits 0), so restore it here.
    proc = subprocess.Popen(cmd, cwd=REPO, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=_default_sigint)
    deadline = time.time() + 120
    while time.time() < deadline and proc.poll() is None:
        if (out / "cells").is_dir() and any((out / "cells").glob("*.json")):
            break
        time.sleep(0.02)
    kids = _descendants(proc.pid)
    assert proc.poll() is None and kids, "the run ended before it could be interrupted"
    if group:
        os.killpg(proc.pid, sig)
    else:
        proc.send_signal(sig)
    try:
        _stdout, stderr = proc.communicate(timeout=60)
    except subprocess.TimeoutExpired:            # a worker kept the pipes open
        for k in kids | {proc.pid}:
            with contextlib.suppress(OSError):
                os.kill(k, signal.SIGKILL)
        raise
    err = stderr.strip().splitlines()
    assert proc.returncode == code, stderr
    assert len(err) == 1 and "interrupted" in err[0], stderr
    assert "rerun the same command to resume" in err[0]
    assert json.loads((out / "manifest.json").read_text())["status"] == "interrupted"
    t_end = time.time() + 10                     # killed workers are gone within moments
    while time.time() < t_end and any(_alive(k) for k in kids):
        time.sleep(0.1)
    assert not [k for k in kids if _alive(k)]
    assert not (out / sweep_module().LOCK_FILE).exists()
    if group:                                    # the rerun resumes (once: it costs ~10 s)
        n_kept = len(list((out / "cells").glob("*.json")))
        r = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True,
                           check=False, timeout=300)
        assert r.returncode == 0, r.stderr
        m = re.search(r"(\d+) computed, (\d+) resumed", r.stdout)
        assert m and int(m.group(2)) in (n_kept, 0), r.stdout   # 0: others changed the code
        assert json.loads((out / "manifest.json").read_text())["status"] == "complete"


def sweep_module():
    from experiments import sweep

    return sweep


def test_in_process_interrupt_marks_the_manifest_and_keeps_the_cells(tmp_path):
    """A KeyboardInterrupt inside the cells (jobs=1): manifest "interrupted", the message
    counts the finished cells, the lock is released, and the rerun resumes them."""
    spec = _fake_spec()
    n = len(spec.expand())
    seen = []

    def interrupting(cell, truth, ctx):
        if len(seen) == 3:
            raise KeyboardInterrupt
        seen.append(cell.key)
        return fake_cell(cell, truth, ctx)

    with pytest.raises(KeyboardInterrupt) as exc:
        _fake_run(spec, tmp_path, cell_fn=interrupting)
    assert f"3 of {n} cells are finished" in str(exc.value)
    assert json.loads((tmp_path / "manifest.json").read_text())["status"] == "interrupted"
    assert not (tmp_path / sweep_module().LOCK_FILE).exists()
    r = _fake_run(spec, tmp_path, cell_fn=fake_cell)
    assert (r.n_resumed, r.n_computed) == (3, n - 3)
    assert json.loads((tmp_path / "manifest.json").read_text())["status"] == "complete"


_HOLD_LOCK = ("import sys, time\n"
              "from pathlib import Path\n"
              "from experiments.sweep import folder_lock\n"
              "with folder_lock(Path(sys.argv[1])) as why:\n"
              "    assert why is None\n"
              "    print('held', flush=True)\n"
              "    time.sleep(60)\n")


def test_second_run_into_one_folder_fails_at_once_naming_folder_and_pid(tmp_path, capsys):
    """Two sweeps into one --out both computed every cell; now the second fails at once
    (exit 3, one line naming the folder and the holder's pid) and computes nothing."""
    out = tmp_path / "out"
    out.mkdir()
    holder = subprocess.Popen([sys.executable, "-c", _HOLD_LOCK, str(out)], cwd=REPO,
                              stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        spec = tmp_path / "s.toml"
        spec.write_text(_toml({**TINY, "defaults": {"noise": "none"}}))
        t0 = time.perf_counter()
        assert main([str(spec), "--out", str(out), "--quiet", "--jobs", "1"]) == 3
        assert time.perf_counter() - t0 < 20           # no cell computed
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and str(out) in err[0] and f"pid {holder.pid}" in err[0], err
        assert not (out / "cells").exists() or not any((out / "cells").iterdir())
    finally:
        holder.kill()
        holder.wait()
    # the holder died without releasing: its stale lock is taken over
    lock = out / sweep_module().LOCK_FILE
    assert json.loads(lock.read_text())["pid"] == holder.pid
    r = _fake_run(_fake_spec(), out, cell_fn=fake_cell)
    assert r.n_failed == 0 and r.n_computed == len(_fake_spec().expand())
    assert not lock.exists()                         # released at the end


def test_stale_lock_of_a_dead_pid_is_taken_over(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)
    pid = int(dead.stdout)
    (tmp_path / sweep_module().LOCK_FILE).write_text(json.dumps({"pid": pid}) + "\n")
    r = _fake_run(_fake_spec(), tmp_path, cell_fn=fake_cell)
    assert r.n_failed == 0 and not (tmp_path / sweep_module().LOCK_FILE).exists()


def test_rerun_with_nothing_to_compute_writes_nothing(tmp_path):
    """A finished run rerun with nothing to compute rewrites no file (only the git-ignored
    run.local.json sidecar, where the folder allows it), so a read-only folder reruns."""
    spec = _fake_spec()
    _fake_run(spec, tmp_path, cell_fn=fake_cell)
    _fake_run(spec, tmp_path, cell_fn=fake_cell)      # (settles what the first one left)

    def stamps():
        return {p: p.stat().st_mtime_ns for p in tmp_path.rglob("*")
                if p.is_file() and p.name != "run.local.json"}

    before = stamps()
    time.sleep(0.01)
    r = _fake_run(spec, tmp_path, cell_fn=fake_cell)
    assert r.n_computed == 0 and stamps() == before


def _read_only_run(out: Path, cmd: list[str]) -> subprocess.CompletedProcess:
    """``cmd`` with ``out`` bind-mounted read-only in a private mount namespace."""
    q = shlex.quote(str(out))
    script = f"mount --bind {q} {q} && mount -o remount,ro,bind {q} && {shlex.join(cmd)}"
    return subprocess.run(["unshare", "-m", "sh", "-c", script], cwd=REPO,
                          capture_output=True, text=True, check=False, timeout=300)


def _can_mount_read_only(tmp_path: Path) -> bool:
    import shutil

    if shutil.which("unshare") is None:
        return False
    d = tmp_path / "probe"
    d.mkdir()
    r = _read_only_run(d, ["touch", str(d / "x")])
    return r.returncode != 0 and "Read-only file system" in r.stderr


def test_finished_run_on_a_read_only_folder_reruns(tmp_path):
    """A finished run on a read-only folder could not be rerun even with nothing to compute;
    now it reruns (exit 0), and one with cells to compute says it cannot write, in one line.
    The folder is made read-only by a bind mount (root ignores file permissions)."""
    if not _can_mount_read_only(tmp_path):
        pytest.skip("needs unshare and mount permissions for a read-only bind mount")
    spec = tmp_path / "s.toml"
    spec.write_text(_toml({**TINY, "defaults": {"noise": "none"}, "seeds": 1}))
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "experiments.sweep", str(spec), "--out", str(out), "--jobs",
           "1", "--quiet", "--no-figures"]
    for _attempt in range(3):   # others editing this tree change the code between the runs
        subprocess.run(cmd, cwd=REPO, check=True, capture_output=True, timeout=300)
        subprocess.run(cmd, cwd=REPO, check=True, capture_output=True, timeout=300)
        ro = _read_only_run(out, cmd)
        if ro.returncode == 0:
            break
    assert ro.returncode == 0, ro.stderr
    assert "0 computed" in ro.stdout
    (out / "cells" / next((out / "cells").iterdir()).name).unlink()    # a cell to compute
    ro = _read_only_run(out, cmd)
    err = ro.stderr.strip().splitlines()
    assert ro.returncode == 3 and len(err) == 1 and "Read-only file system" in err[0], ro.stderr


def test_cell_digest_covers_only_the_code_that_computes_a_cell():
    """CELL_SOURCES: estimator/ (subpackages too), sim/, the spec and its registry and the
    cell module; not the CLI, the store, the workers' scheduling or run (a help-text typo
    must not recompute every cell)."""
    from experiments.sweep import CELL_SOURCES

    rel = {p.relative_to(REPO).as_posix() for p in CELL_SOURCES}
    assert {"experiments/runner/cell.py", "experiments/spec.py", "experiments/techniques.py",
            "estimator/scoring.py", "estimator/trackers/base.py", "sim/gps.py"} <= rel
    assert not rel & {"experiments/sweep.py", "experiments/runner/store.py",
                      "experiments/runner/run.py", "experiments/runner/backends.py",
                      "experiments/runner/worker.py", "experiments/cli.py"}
    assert {r.split("/")[0] for r in rel} == {"estimator", "sim", "experiments"}
