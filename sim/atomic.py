"""Atomic file writes: a reader (or a run killed mid-write) never sees a partial file.

Each write goes to a uniquely named temporary file in the target's folder (so concurrent
writers never share one) and is ``os.replace``-d onto the final name, which is atomic on
POSIX within one filesystem. The temporary file is removed if the write fails.
"""

from __future__ import annotations

import os
import uuid
from collections.abc import Callable
from pathlib import Path

__all__ = ["atomic_write", "atomic_write_text"]


def atomic_write(path: str | os.PathLike, write: Callable[[Path], object]) -> Path:
    """Call ``write(tmp)`` on a unique temporary path beside ``path``, then move it in place.

    ``write`` receives the temporary :class:`~pathlib.Path` and must create the file there
    (e.g. ``lambda p: df.to_parquet(p)``). The temporary name keeps ``path``'s suffixes, for
    writers that choose a format by suffix (``np.savez`` appends ``.npz`` otherwise).
    Returns ``path``.
    """
    final = Path(path)
    tmp = final.with_name(f".{final.stem}.{os.getpid()}.{uuid.uuid4().hex[:12]}.tmp"
                          f"{''.join(final.suffixes) or ''}")
    try:
        write(tmp)
        os.replace(tmp, final)
    finally:
        if tmp.exists():
            tmp.unlink()
    return final


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically; returns ``path``."""
    return atomic_write(path, lambda p: p.write_text(text, encoding="utf-8"))
