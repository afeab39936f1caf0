"""Per-process memo keyed by content, for estimators a sweep runs many times on the same data.

A sweep evaluates several techniques on identical observations (common random numbers):
the eps-elastic fits of one window size serve the rows None, LC and LC (course)
(:mod:`estimator.tracking`), and the pose filter's forward pass serves the EKF at every
window, its fixed-lag and RTS smoothers and the smoothed heading of the lag correction
(:mod:`estimator.pose_filter`, :mod:`estimator.pose_smoother`). A :class:`ContentMemo`
keeps the last few results, keyed by a digest of the input arrays' bytes (dtype and shape
included) plus the options: a hit is an identical request, so it returns exactly what the
computation would. Least recently used first out.

The values are shared: a caller either returns copies (the elastic fits) or freezes the
arrays (:func:`freeze`, the filter results), so no user can change a memoised value.

Time accounting: each entry remembers what it cost to produce, including the entries it
reused itself (a smoother on a memoised forward pass costs the pass plus the smoothing);
:func:`reused_seconds` is the running total of that cost over the hits of this process, so
a caller can report a result's stand-alone cost (e.g. the time per epoch of an estimator)
as its own time plus the delta of :func:`reused_seconds` over the call.
"""

from __future__ import annotations

import hashlib
import time
from collections import OrderedDict
from collections.abc import Callable, Hashable
from typing import Any, TypeVar

import numpy as np

__all__ = ["ContentMemo", "content_digest", "freeze", "reused_seconds"]

T = TypeVar("T")

_REUSED_S = [0.0]      # stand-alone seconds of every hit in this process


def reused_seconds() -> float:
    """Total stand-alone cost (s) of the memo hits of this process so far (module docstring)."""
    return _REUSED_S[0]


def content_digest(*arrays: np.ndarray) -> str:
    """Hex digest (128 bits, BLAKE2b) of the arrays' dtypes, shapes and bytes (C order)."""
    h = hashlib.blake2b(digest_size=16)
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def freeze(a: np.ndarray) -> np.ndarray:
    """``a`` made read-only (in place) and returned: a memoised array nobody can change."""
    a.flags.writeable = False
    return a


class ContentMemo:
    """Least-recently-used memo of at most ``size`` values, keyed by hashable tuples
    (typically :func:`content_digest` of the inputs plus the options)."""

    def __init__(self, size: int) -> None:
        if isinstance(size, bool) or not isinstance(size, int) or size < 1:
            raise ValueError(f"size: must be an integer >= 1, got {size!r}")
        self.size = size
        self._entries: OrderedDict[Hashable, tuple[Any, float]] = OrderedDict()

    def __len__(self) -> int:
        return len(self._entries)

    def __contains__(self, key: Hashable) -> bool:
        return key in self._entries

    def clear(self) -> None:
        """Forget every entry."""
        self._entries.clear()

    def get(self, key: Hashable, compute: Callable[[], T]) -> T:
        """The memoised value of ``key``, else ``compute()`` stored under it (an exception
        stores nothing). A hit adds the entry's stand-alone cost to :func:`reused_seconds`."""
        hit = self._entries.get(key)
        if hit is not None:
            self._entries.move_to_end(key)
            _REUSED_S[0] += hit[1]
            return hit[0]
        r0, t0 = _REUSED_S[0], time.perf_counter()
        value = compute()
        cost = time.perf_counter() - t0 + (_REUSED_S[0] - r0)
        self._entries[key] = (value, cost)
        while len(self._entries) > self.size:
            self._entries.popitem(last=False)
        return value
