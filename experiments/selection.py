"""Choosing one cell of a results folder by ``--key`` or ``--where AXIS=VALUE`` terms: the
one selection of :mod:`experiments.export` and :mod:`experiments.render`.

A term's value is read in the type of its column in ``cells.parquet`` (``window=100`` is an
integer, ``path=square100`` a string); a value of a JSON column (``noise_overrides``,
``path_overrides``) is compared as JSON, so ``noise_overrides={"common_fraction": 0.9}``
matches the stored ``{"common_fraction":0.9}``. When several cells match, the error names
the axes whose values differ among them and, for each, the terms to add (ready to paste
into a shell); when none matches, it names the first term that matches nothing and the
values that axis takes there.
"""

from __future__ import annotations

import json
import shlex
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["AmbiguousSelection", "axis_columns", "find_cell", "parse_where", "select_cell"]

#: Candidates listed in an ambiguity error (the differing axes are always listed in full).
MAX_LISTED = 10


class AmbiguousSelection(ValueError):
    """Several cells match: ``.differing`` maps each axis whose values differ among them to
    those values."""

    def __init__(self, message: str, differing: dict[str, list]):
        super().__init__(message)
        self.differing = differing


def parse_where(items: Sequence[str]) -> dict[str, str]:
    """``["window=100", "path=square100"]`` -> ``{"window": "100", "path": "square100"}``.

    Values stay text here: :func:`select_cell` reads each in its column's type.
    """
    out: dict[str, str] = {}
    for it in items:
        k, sep, v = str(it).partition("=")
        if not sep or not k.strip():
            raise ValueError(f"--where: expected AXIS=VALUE, got {it!r}")
        k = k.strip()
        if k in out and out[k] != v:
            raise ValueError(f"--where: {k} given twice ({k}={out[k]} and {it})")
        out[k] = v
    return out


def axis_columns(cells: pd.DataFrame) -> list[str]:
    """The columns that say which cell a row is: those between ``key`` and ``mask`` (the
    sweep's layout), else the spec's axes and ``seed`` present."""
    cols = list(cells.columns)
    if "key" in cols and "mask" in cols and cols.index("mask") > cols.index("key") + 1:
        return cols[cols.index("key") + 1:cols.index("mask")]
    from experiments.spec import AXES

    return [a for a in (*AXES, "seed") if a in cols]


def _term(axis: str, value) -> str:
    """``axis=value`` as a shell word (quoted when it has to be)."""
    return shlex.quote(f"{axis}={value}")


def _is_json_column(col: pd.Series) -> bool:
    vals = col.dropna().astype(str)
    return not vals.empty and bool(vals.str.startswith("{").all())


def _coerce(cells: pd.DataFrame, axis: str, value):
    """``value`` (text or a Python value) in the type of column ``axis``."""
    col = cells[axis]
    if not isinstance(value, str):
        return value
    kind = col.dtype.kind
    try:
        if kind in "iu":
            return int(value)
        if kind == "f":
            return float(value)
        if kind == "b":
            low = value.strip().lower()
            if low not in ("true", "false"):
                raise ValueError(value)
            return low == "true"
    except ValueError:
        expected = {"i": "an integer", "u": "an integer", "f": "a number",
                    "b": "true or false"}[kind]
        raise ValueError(f"--where {axis}={value}: {axis} takes {expected}, got "
                         f"{value!r}") from None
    return value


def _match(cells: pd.DataFrame, axis: str, value) -> np.ndarray:
    col = cells[axis]
    if isinstance(value, str) and _is_json_column(col):
        try:
            want = json.loads(value)
        except json.JSONDecodeError:
            raise ValueError(f"--where {axis}={value}: {axis} takes a JSON object such as "
                             f"{col.iloc[0]}, got {value!r}") from None
        return np.array([json.loads(v) == want for v in col.astype(str)], dtype=bool)
    if isinstance(value, str) and col.dtype.kind not in "iufb":
        return (col.astype(str) == value).to_numpy()
    return (col == value).to_numpy()


def _values(col: pd.Series) -> list:
    """The distinct values of ``col``: numbers sorted, text in the folder's (spec's) order."""
    vals = list(dict.fromkeys(col.tolist()))
    return sorted(vals) if col.dtype.kind in "iufb" else vals


def _ambiguous(sel: pd.DataFrame) -> AmbiguousSelection:
    axes = [a for a in axis_columns(sel) if sel[a].nunique(dropna=False) > 1]
    differing = {a: _values(sel[a]) for a in axes}
    lines = [(f"expected exactly one matching cell, found {len(sel)}; they differ in "
              f"{', '.join(axes) or 'no axis (duplicate keys?)'}. Add one term per axis to "
              "--where:")]
    lines += [f"  {a}: " + " / ".join(_term(a, v) for v in vals)
              for a, vals in differing.items()]
    shown = sel[["key", *axes]].head(MAX_LISTED)
    lines += ["the matching cells" + (f" (first {MAX_LISTED})" if len(sel) > MAX_LISTED else "")
              + ":", shown.to_string(index=False)]
    return AmbiguousSelection("\n".join(lines), differing)


def _none_match(cells: pd.DataFrame, where: dict) -> ValueError:
    """No cell matches: name the first term that empties the selection and the values its
    axis takes among the cells the earlier terms select."""
    sel, earlier = cells, []
    for k, v in where.items():
        nxt = sel[_match(sel, k, _coerce(sel, k, v))]
        if nxt.empty:
            among = f" with {' '.join(earlier)}" if earlier else ""
            vals = " / ".join(_term(k, x) for x in _values(sel[k]))
            return ValueError(f"--where {k}={v}: no cell{among} has it; {k} takes {vals}")
        sel, earlier = nxt, [*earlier, f"{k}={v}"]
    return ValueError("--where: no cell matches")


def select_cell(cells: pd.DataFrame, key: str | None = None, where: dict | None = None
                ) -> pd.Series:
    """The one row of ``cells`` (one row per cell, or per cell x mask) with ``key``, or
    matching every ``where`` term (values as text or in the column's type).

    Raises ValueError naming the unknown axis or bad value, :class:`AmbiguousSelection`
    (a ValueError) listing the differing axes and their terms when several cells match.
    """
    if "key" not in cells.columns:
        raise ValueError("cells: no 'key' column (not a sweep's cells.parquet?)")
    cells = cells.drop_duplicates("key")
    where = dict(where or {})
    if key is not None:
        sel = cells[cells["key"].astype(str) == str(key)]
        if sel.empty:
            raise ValueError(f"key: no cell has key {key!r}")
    else:
        known = axis_columns(cells)
        for k in where:
            if k not in cells.columns:
                raise ValueError(f"--where {k}=...: unknown axis {k!r}; the axes are "
                                 f"{', '.join(known)}")
        mk = np.ones(len(cells), dtype=bool)
        for k, v in where.items():
            mk &= _match(cells, k, _coerce(cells, k, v))
        sel = cells[mk]
        if sel.empty:
            raise _none_match(cells, where)
    if len(sel) != 1:
        raise _ambiguous(sel)
    return sel.iloc[0]


def find_cell(results: str | Path, key: str | None = None, where: dict | None = None
              ) -> pd.Series:
    """The one cell of the results folder ``results`` (its ``cells.parquet``) matching
    ``key`` or every ``where`` term (:func:`select_cell`)."""

    import pandas as pd

    f = Path(results) / "cells.parquet"
    if not f.exists():
        raise ValueError(f"results: {f} not found (run the sweep into {results} first)")
    return select_cell(pd.read_parquet(f), key, where)
