"""Markdown tables: the one writer of the reports' tables (tables.md, REPORT.md, the
stationary, ultrasonic, ranging and identification summaries) and the one escaping rule.

A GFM table row is split at every unescaped ``|``, so a header such as ``mean |x|`` or a
value such as ``{replay = "a|b"}`` would add columns. :func:`escape_cell` writes ``|`` as
``\\|`` (GFM's escape, also inside code spans) and a line break as a space (a row is one
line); :func:`md_row` and :func:`markdown_table` apply it to every header and cell.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # pandas only in annotations: importing this module stays light (a CLI's --help)
    import pandas as pd

__all__ = ["escape_cell", "markdown_table", "md_row", "md_separator", "split_row"]

#: A column of :func:`markdown_table`: (header, column name or function of the row -> text).
Column = tuple[str, "str | Callable[[pd.Series], str]"]


def escape_cell(text: object) -> str:
    """``text`` as one Markdown table cell: ``|`` -> ``\\|``, line breaks -> spaces.

    An already escaped ``\\|`` is kept as it is (not doubled), so escaping twice is harmless.
    """
    s = str(text).replace("\r\n", " ").replace("\n", " ").replace("\r", " ")
    out = []
    for i, ch in enumerate(s):
        if ch == "|" and not (i > 0 and s[i - 1] == "\\"):
            out.append("\\|")
        else:
            out.append(ch)
    return "".join(out)


def md_row(cells: Iterable[object]) -> str:
    """One table line ``| a | b |``, each cell escaped (:func:`escape_cell`)."""
    return "| " + " | ".join(escape_cell(c) for c in cells) + " |"


def md_separator(n: int) -> str:
    """The header/body separator line of an ``n``-column table (``|---|---|``)."""
    if n < 1:
        raise ValueError(f"n: a table has at least one column, got {n}")
    return "|" + "|".join("---" for _ in range(n)) + "|"


def split_row(line: str) -> list[str]:
    """The cells of a table line, split at unescaped ``|`` (GFM's rule; the inverse of
    :func:`md_row` up to the escapes). Used by the tests that parse the written tables."""
    s = line.strip()
    if not (s.startswith("|") and s.endswith("|")) or len(s) < 2:
        raise ValueError(f"line: not a Markdown table row, got {line!r}")
    cells, cur, i = [], [], 1
    while i < len(s) - 1:
        ch = s[i]
        if ch == "\\" and s[i + 1] == "|" and i + 1 < len(s) - 1:
            cur.append("|")
            i += 2
            continue
        if ch == "|":
            cells.append("".join(cur).strip())
            cur = []
        else:
            cur.append(ch)
        i += 1
    cells.append("".join(cur).strip())
    return cells


def _fmt(v: object, floatfmt: str | None, nan: str | None) -> str:
    if isinstance(v, (float, np.floating)):
        if nan is not None and np.isnan(v):
            return nan
        return str(v) if floatfmt is None else format(v, floatfmt)
    return str(v)


def markdown_table(df: pd.DataFrame, columns: Sequence[Column] | None = None, *,
                   floatfmt: str | None = ".4g", nan: str | None = "-") -> str:
    """``df`` as a Markdown table, one line per row; headers and cells escaped.

    columns : None (every column, headed by its name) or (header, column) pairs, where a
        column is a name or a function of the row (a Series) returning the cell's text.
    floatfmt : format of float cells (None: ``str``). nan : text of a NaN float cell (None:
        formatted like any float, e.g. "nan"). Other values print with ``str``; values are
        read per column, so an integer column stays integer.
    """
    cols: list[Column] = ([(str(c), c) for c in df.columns] if columns is None
                          else list(columns))
    lines = [md_row(h for h, _ in cols), md_separator(len(cols))]
    values = {c: df[c].to_numpy(dtype=object) for _, c in cols if not callable(c)}
    rows = [r for _, r in df.iterrows()] if any(callable(c) for _, c in cols) else None
    for i in range(len(df)):
        lines.append(md_row(c(rows[i]) if callable(c) else _fmt(values[c][i], floatfmt, nan)
                            for _, c in cols))
    return "\n".join(lines)
