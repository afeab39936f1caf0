"""sim.cache: content-hash keys, store/load round trip, corrupt files, concurrent writers."""

from __future__ import annotations

import multiprocessing as mp
import time
import warnings

import numpy as np
import pytest

from sim.cache import cached, canonical, key_hash, truth_key
from sim.paths import load_path
from sim.truth import Truth


def make_truth(value: float = 1.0, n: int = 5) -> Truth:
    t = np.arange(n, dtype=float)
    return Truth(t=t, sensor_positions=np.full((n, 2, 3), value), sensor_names=("a", "b"),
                 cg=np.zeros((n, 3)), yaw=np.zeros(n), speed=np.ones(n), yaw_rate=np.zeros(n),
                 turning=np.zeros(n, bool), meta={"value": value})


def base_key(**changes):
    kw = {"simulator": "rover", "model_xml": "<mujoco/>", "path": load_path("square20"),
              "params": {"a": 1.0, "b": [1, 2]}, "seed": 0}
    kw.update(changes)
    return truth_key(**kw)


def test_hash_is_order_independent_and_sensitive_to_every_input():
    k = base_key()
    assert key_hash(k) == key_hash(dict(reversed(list(k.items()))))
    assert key_hash(base_key(params={"b": [1, 2], "a": 1.0})) == key_hash(k)
    others = [base_key(seed=1), base_key(model_xml="<mujoco />"),
              base_key(params={"a": 1.0000000000000002, "b": [1, 2]}),
              base_key(path=load_path("square100"))]
    hashes = {key_hash(o) for o in others}
    assert key_hash(k) not in hashes and len(hashes) == len(others)
    assert {"mujoco", "numpy"} <= set(k["versions"]) and k["code_salt"]


def test_canonical_rejects_what_cannot_hash_reliably():
    with pytest.raises(ValueError, match="non-finite"):
        canonical({"x": float("nan")})
    with pytest.raises(ValueError, match="type"):
        canonical({"x": object()})
    assert canonical({"a": np.arange(2), "b": (np.float32(0.5), np.bool_(True))}) == \
        {"a": [0, 1], "b": [0.5, True]}


def test_computes_once_then_loads(tmp_path):
    calls = []

    def compute():
        calls.append(1)
        return make_truth(2.0)

    k = base_key()
    a = cached(k, compute, tmp_path)
    b = cached(k, compute, tmp_path)
    assert len(calls) == 1
    np.testing.assert_array_equal(a.sensor_positions, b.sensor_positions)
    assert a.meta["hash"] == b.meta["hash"] == key_hash(k)
    assert b.meta["value"] == 2.0
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"{key_hash(k)}.npz"]


def test_corrupt_file_is_recomputed_loudly(tmp_path):
    k = base_key()
    (tmp_path / f"{key_hash(k)}.npz").write_bytes(b"not a zip file")
    with pytest.warns(UserWarning, match="unusable"):
        t = cached(k, lambda: make_truth(3.0), tmp_path)
    assert t.meta["value"] == 3.0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert cached(k, lambda: make_truth(4.0), tmp_path).meta["value"] == 3.0


def _worker(args):
    cache_dir, _value = args
    k = base_key()

    def compute():
        time.sleep(0.05)             # widen the race window
        return make_truth(1.0, n=20000)   # ~1 MB: writes take measurable time

    t = cached(k, compute, cache_dir)
    return float(t.sensor_positions.sum()), t.meta["hash"]


def test_concurrent_writers_never_expose_partial_files(tmp_path):
    ctx = mp.get_context("fork")
    with ctx.Pool(4) as pool:
        out = pool.map(_worker, [(tmp_path, i) for i in range(8)])
    assert len(set(out)) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"{key_hash(base_key())}.npz"]


def test_truth_key_follows_the_simulator_sources(tmp_path):
    from sim.cache import SIMULATOR_SOURCES, source_digest

    assert {p.name for p in SIMULATOR_SOURCES} >= {"rover.py", "quadcopter.py", "controllers.py"}
    a, b = tmp_path / "a.py", tmp_path / "b.py"
    a.write_text("x = 1\n")
    b.write_text("y = 2\n")
    d1 = source_digest((a, b))
    c = tmp_path / "c"
    c.mkdir()
    a2 = c / "a.py"
    a2.write_text("x = 2\n")  # one character of one file changed
    assert source_digest((a2, b)) != d1
    assert source_digest((b, a)) == d1  # order-free


def test_atomic_write_leaves_nothing_behind_on_failure(tmp_path):
    from sim.atomic import atomic_write, atomic_write_text

    target = tmp_path / "out.csv"
    atomic_write_text(target, "old")

    def broken(p):
        p.write_text("partial")
        raise RuntimeError("disk full")

    with pytest.raises(RuntimeError, match="disk full"):
        atomic_write(target, broken)
    assert target.read_text() == "old"
    assert sorted(f.name for f in tmp_path.iterdir()) == ["out.csv"]
