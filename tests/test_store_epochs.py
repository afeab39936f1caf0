"""The per-epoch parquet writer (experiments.runner.store.write_epochs): what pandas'
``to_parquet(index=False, use_dictionary=False)`` wrote, read back as the same frame."""

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest

from experiments.runner import store
from experiments.runner.store import epoch_table, write_epochs
from sim.atomic import atomic_write


def _frame(n: int, seed: int, status_dtype="str") -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    f64 = rng.normal(size=n)
    f64[::7] = np.nan                           # NaN (null in arrow, NaN again on read)
    f32 = rng.normal(size=n).astype(np.float32)
    f32[3::11] = np.nan
    df = pd.DataFrame({"t": np.arange(n) * 0.1, "x": f64, "ok": rng.random(n) > 0.5,
                       "solver_status": rng.choice(["ok", "held", "lost"], n),
                       "n": rng.integers(0, 9, n)}).astype({"solver_status": status_dtype})
    ep = pd.DataFrame({"e_1": f32, "e_2": -f32, "gated": rng.random(n) > 0.9})
    return pd.concat([df, ep], axis=1)


@pytest.mark.parametrize("status_dtype", ["str", object])
def test_write_epochs_reads_back_as_to_parquet(tmp_path, status_dtype):
    store._EPOCH_SCHEMAS.clear()
    for seed, n in [(0, 50), (1, 37), (2, 0)]:    # first frame: schema; then cached
        df = _frame(n, seed, status_dtype)
        new, old = tmp_path / f"new{seed}.parquet", tmp_path / f"old{seed}.parquet"
        write_epochs(df, new)
        df.to_parquet(old, index=False, use_dictionary=False)
        a, b = pd.read_parquet(new), pd.read_parquet(old)
        assert a.equals(b) and a.dtypes.equals(b.dtypes) and a.index.equals(b.index)
        assert pq.read_table(new).equals(pq.read_table(old))
        assert pq.read_schema(new).equals(pq.read_schema(old), check_metadata=True)
    assert len(store._EPOCH_SCHEMAS) == (status_dtype == "str")  # object: from_pandas


def test_epoch_table_falls_back_when_string_type_changes():
    store._EPOCH_SCHEMAS.clear()
    df = _frame(20, 0)
    epoch_table(df)
    other = df.assign(solver_status=pd.array(["a"] * 20, dtype=pd.StringDtype("python")))
    got = epoch_table(other.astype({"solver_status": "str"}))
    assert got.column("solver_status").to_pylist() == ["a"] * 20


def test_atomic_write_leaves_no_temporary_file_on_failure(tmp_path):
    def boom(p):
        p.write_text("part")
        raise RuntimeError("disk full")

    with pytest.raises(RuntimeError):
        atomic_write(tmp_path / "a.json", boom)
    assert list(tmp_path.iterdir()) == []
    atomic_write(tmp_path / "b.json", lambda p: p.write_text("x"))
    assert [p.name for p in tmp_path.iterdir()] == ["b.json"]
