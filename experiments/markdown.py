"""Markdown tables from DataFrames: the one writer of the reports' tables (tables.md,
the stationary, ultrasonic and ranging summaries)."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import pandas as pd

__all__ = ["markdown_table"]

#: A column of :func:`markdown_table`: (header, column name or function of the row -> text).
Column = tuple[str, "str | Callable[[pd.Series], str]"]


def markdown_table(df: pd.DataFrame, columns: Sequence[Column] | None = None, *,
                   floatfmt: str | None = ".4g", nan: str | None = "-") -> str:
    """``df`` as a Markdown table, one line per row.

    columns : None (every column, headed by its name) or (header, column) pairs, where a
        column is a name or a function of the row (a Series) returning the cell's text.
    floatfmt : format of float cells (None: ``str``). nan : text of a NaN float cell (None:
        formatted like any float, e.g. "nan"). Other values print with ``str``; values are
        read per column, so an integer column stays integer.
    """
    cols: list[Column] = ([(str(c), c) for c in df.columns] if columns is None
                          else list(columns))
    lines = ["| " + " | ".join(h for h, _ in cols) + " |",
             "|" + "|".join("---" for _ in cols) + "|"]
    values = {c: df[c].to_numpy(dtype=object) for _, c in cols if not callable(c)}
    rows = [r for _, r in df.iterrows()] if any(callable(c) for _, c in cols) else None
    for i in range(len(df)):
        cells = []
        for _, c in cols:
            if callable(c):
                cells.append(c(rows[i]))
                continue
            v = values[c][i]
            if isinstance(v, (float, np.floating)):
                if nan is not None and np.isnan(v):
                    cells.append(nan)
                else:
                    cells.append(str(v) if floatfmt is None else format(v, floatfmt))
            else:
                cells.append(str(v))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)
