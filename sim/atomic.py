"""Atomic file writes: a reader (or a run killed mid-write) never sees a partial file.

Each write goes to a uniquely named temporary file in the target's folder (so concurrent
writers never share one) and is ``os.replace``-d onto the final name, which is atomic on
POSIX within one filesystem. The temporary file is removed if the write fails.
"""

from __future__ import annotations

import os
import uuid
from collections.abc import Callable
from contextlib import suppress
from pathlib import Path

__all__ = ["atomic_write", "atomic_write_text", "file_stat"]


def atomic_write(path: str | os.PathLike, write: Callable[[Path], object]) -> Path:
    """Call ``write(tmp)`` on a unique temporary path beside ``path``, then move it in place.

    ``write`` receives the temporary :class:`~pathlib.Path` and must create the file there
    (e.g. ``lambda p: df.to_parquet(p)``). The temporary name is hidden and ends in ``.tmp``
    (``.<name>.<pid>.<random>.tmp``), so a torn file left by a killed process never matches
    a glob for finished files such as ``*.json``; writers that pick a format from the suffix
    must be given it explicitly (or write through an open file handle). Returns ``path``.
    """
    final = Path(path)
    tmp = final.with_name(f".{final.name}.{os.getpid()}.{uuid.uuid4().hex[:12]}.tmp")
    try:
        write(tmp)
        os.replace(tmp, final)
    except BaseException:
        with suppress(OSError):
            tmp.unlink()            # absent when ``write`` failed before creating it
        raise
    return final


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically; returns ``path``."""
    return atomic_write(path, lambda p: p.write_text(text, encoding="utf-8"))


def file_stat(path: Path) -> list[int] | None:
    """[size, modification time in ns] of a file (what a writer's "did it change" checks
    compare), None when it does not exist or cannot be read."""
    try:
        st = path.stat()
    except OSError:
        return None
    return [st.st_size, st.st_mtime_ns]
