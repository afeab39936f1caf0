"""CellStore.prefetch (issue 27): the run reads each cell file as its batch finishes, so
the cell table at the end is assembled from rows already read; the same table as reading
the files then, and a file changed after it was read is read again."""

import os

from experiments.runner.store import CellStore
from experiments.spec import load_spec


def _record(i: int) -> dict:
    return {"ok": True, "rows": [{"mask": "all", "rmse_m": 0.1 * i},
                                 {"mask": "no_turns", "rmse_m": 0.2 * i}],
            "timings": {"t_cell_s": 0.01}, "status_counts": {"ok": 5, "few": i},
            "epochs": None}


def test_prefetched_rows_give_the_table_of_the_files_and_changes_are_reread(tmp_path):
    cells = load_spec("quick").expand()[:4]
    store = CellStore(tmp_path)
    for i, c in enumerate(cells[:3]):
        store.write(c, _record(i))
    keys = [c.key for c in cells]             # the fourth has no file: left out
    fresh = CellStore(tmp_path).read_cells(keys)
    store.prefetch(keys)
    assert store.read_cells(keys).equals(fresh) and len(fresh) == 6
    store.write(cells[1], _record(7))           # rewritten after it was read
    path = tmp_path / "cells" / f"{cells[1].key}.json"
    os.utime(path, ns=(1, 1))                   # another stat than the prefetched one
    got = store.read_cells(keys)
    assert got.equals(CellStore(tmp_path).read_cells(keys))
    assert list(got.loc[got["key"] == cells[1].key, "n_status_other"]) == [7, 7]
