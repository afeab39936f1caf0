"""Memos keyed by content, for estimators a runner calls many times on the same data.

The estimators keep no caches of their own (no module-level state): a runner that wants
reuse makes a :class:`TrackCache` (one :class:`ContentMemo` per kind of intermediate result)
and passes it in (``track(..., cache=...)``, ``Tracker.track(..., cache=...)``); ``None``
computes everything. The sweep keeps one per worker process and run.

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

Time accounting: each entry remembers what it cost to produce, its own computation and,
separately, the entries it used (a smoother on a memoised forward pass costs the pass plus
the smoothing). :func:`ledger` measures what a piece of work took from the memos: the cost of
every entry it hit, each counted once (the pass reached directly and through the smoother
counts once) and none it computed itself (that time is in its own), so a caller can report a
result's stand-alone cost (e.g. the time per epoch of an estimator) as its own time plus
``ledger.seconds``.
"""

from __future__ import annotations

import hashlib
import itertools
import time
import weakref
from collections import OrderedDict
from collections.abc import Callable, Hashable, Iterator
from contextlib import contextmanager
from typing import Any, TypeVar

import numpy as np

__all__ = ["ContentMemo", "Ledger", "TrackCache", "array_digest", "clear_all",
           "content_digest", "freeze", "ledger", "memo_get"]

T = TypeVar("T")


def content_digest(*arrays: np.ndarray) -> str:
    """Hex digest (128 bits, BLAKE2b) of the arrays' dtypes, shapes and bytes (C order): the
    digest of the arrays' own digests (:func:`array_digest`), in order."""
    h = hashlib.blake2b(digest_size=16)
    for a in arrays:
        h.update(array_digest(a))
    return h.hexdigest()


#: id of a frozen array -> (weak reference to it, {view of it: digest}); see
#: :func:`array_digest`.
_FROZEN_DIGESTS: dict[int, tuple[weakref.ref, dict[tuple, bytes]]] = {}


def array_digest(a: np.ndarray) -> bytes:
    """16-byte BLAKE2b digest of one array's dtype, shape and bytes (C order). A read-only
    array whose data belong to an array :func:`freeze` made read-only (itself or a view of
    it: ``np.asarray(obs, dtype=float)`` of a frozen array is a view) is hashed once while
    that array lives: a sweep's worker keys every fit of a noise key's observations
    (0.5 MB) by them."""
    root = _frozen_root(a)
    if root is None:
        return _hash(a)
    view = (a.__array_interface__["data"][0], a.shape, a.strides, a.dtype.str)
    hit = _FROZEN_DIGESTS.get(id(root))
    if hit is None or hit[0]() is not root:
        hit = (weakref.ref(root, _forget(id(root))), {})
        _FROZEN_DIGESTS[id(root)] = hit
    d = hit[1].get(view)
    if d is None:
        d = hit[1][view] = _hash(a)
    return d


def _hash(a: np.ndarray) -> bytes:
    c = np.ascontiguousarray(a)
    h = hashlib.blake2b(digest_size=16)
    h.update(f"{c.dtype.str}{c.shape}".encode())
    h.update(c.tobytes())
    return h.digest()


def _frozen_root(a: Any) -> np.ndarray | None:
    """The frozen array that owns ``a``'s data (``a`` itself or its base), if ``a`` is
    read-only and that array is read-only and owns its data; else None."""
    if not isinstance(a, np.ndarray) or a.flags.writeable:
        return None
    b = a
    while isinstance(b.base, np.ndarray):
        b = b.base
    if b.base is not None or not b.flags.owndata or b.flags.writeable:
        return None
    return b


def _forget(key: int) -> Callable[[weakref.ref], None]:
    """The callback that drops the digests of a frozen array that is gone (unless its id
    was reused since)."""
    def drop(ref: weakref.ref) -> None:
        hit = _FROZEN_DIGESTS.get(key)
        if hit is not None and hit[0] is ref:
            del _FROZEN_DIGESTS[key]
    return drop


def freeze(a: np.ndarray) -> np.ndarray:
    """``a`` made read-only (in place) and returned: a memoised array nobody can change
    (never make it writeable again: :func:`array_digest` remembers its digest)."""
    a.flags.writeable = False
    return a


class Ledger:
    """What a piece of work took from the memos (see :func:`ledger`): ``hits`` maps each
    entry it reached, directly or through another entry, to that entry's own cost (s);
    ``computed`` holds the entries it computed itself."""

    def __init__(self) -> None:
        self.hits: dict[tuple, float] = {}
        self.computed: set[tuple] = set()

    @property
    def seconds(self) -> float:
        """The stand-alone cost of what was reused: the own costs of the entries reached,
        each once, less those computed within the measurement."""
        return float(sum(s for k, s in self.hits.items() if k not in self.computed))


_clock = time.perf_counter           # (replaceable in tests)
_LEDGERS: list[Ledger] = []          # measurements in progress
_FRAMES: list[dict] = []             # computations in progress: {"cover", "nested_s"}
_IDS = itertools.count()


@contextmanager
def ledger() -> Iterator[Ledger]:
    """Measure what the enclosed work takes from every :class:`ContentMemo` of this process::

        with ledger() as led:
            work()
        stand_alone_s = own_time + led.seconds
    """
    led = Ledger()
    _LEDGERS.append(led)
    try:
        yield led
    finally:
        _LEDGERS.remove(led)


#: Every :class:`ContentMemo` of this process (for :func:`clear_all`).
_MEMOS: weakref.WeakSet = weakref.WeakSet()


def clear_all() -> None:
    """Forget every entry of every :class:`ContentMemo` of this process (a benchmark that
    repeats a call times the computation, not the look-up)."""
    for memo in list(_MEMOS):
        memo.clear()


class ContentMemo:
    """Least-recently-used memo of at most ``size`` values, keyed by hashable tuples
    (typically :func:`content_digest` of the inputs plus the options)."""

    def __init__(self, size: int) -> None:
        if isinstance(size, bool) or not isinstance(size, int) or size < 1:
            raise ValueError(f"size: must be an integer >= 1, got {size!r}")
        self.size = size
        self._id = next(_IDS)
        # key -> (value, cover: {(memo id, key): own seconds} of the entry and what it used)
        self._entries: OrderedDict[Hashable, tuple[Any, dict]] = OrderedDict()
        _MEMOS.add(self)

    def __len__(self) -> int:
        return len(self._entries)

    def __contains__(self, key: Hashable) -> bool:
        return key in self._entries

    def clear(self) -> None:
        """Forget every entry."""
        self._entries.clear()

    def get(self, key: Hashable, compute: Callable[[], T]) -> T:
        """The memoised value of ``key``, else ``compute()`` stored under it (an exception
        stores nothing). Hits and computations are recorded in every active :func:`ledger`."""
        hit = self._entries.get(key)
        if hit is not None:
            self._entries.move_to_end(key)
            value, cover = hit
            if _FRAMES:
                _FRAMES[-1]["cover"].update(cover)
            for led in _LEDGERS:
                led.hits.update(cover)
            return value
        frame: dict = {"cover": {}, "nested_s": 0.0}
        _FRAMES.append(frame)
        t0 = _clock()
        try:
            value = compute()
        finally:
            _FRAMES.pop()
        total = _clock() - t0
        full = (self._id, key)
        cover = {**frame["cover"], full: total - frame["nested_s"]}   # own: nested computed apart
        if _FRAMES:
            _FRAMES[-1]["cover"].update(cover)
            _FRAMES[-1]["nested_s"] += total
        for led in _LEDGERS:
            led.computed.add(full)
        self._entries[key] = (value, cover)
        while len(self._entries) > self.size:
            self._entries.popitem(last=False)
        return value


class TrackCache:
    """The memos a tracker may use, one :class:`ContentMemo` per kind of result (sizes in
    entries; what one entry holds, for 4000 epochs of 8 sensors):

    huff : per-sample Huff weights of a recording (Section 3.3.3), (n, m) floats;
    procrustes / elastic : window fits of one window size (positions, yaw, status), ~0.5 MB;
    filter_pass : pose-filter forward passes (:mod:`estimator.pose_filter`), ~3.8 MB;
    smoothed : smoothed filter states (:mod:`estimator.pose_smoother`), (n, 6) floats;
    poses : a track's rows before its lag correction (positions, CG, law-of-cosines
        heading, ...: the rows the techniques of one fit or filter state share), ~0.6 MB;
    lag : the lag correction's inputs that do not depend on its mode or heading (first
        observations of each window, the velocity), (N, m) and (N, 2) floats;
    prefix : a recording's cumulative sums of observations and weights (the window means
        of every window size come from them), (n, m, 2) and (n, m) floats, ~0.4 MB.

    Sizes: what the per-process memos they replace kept (8, 16, 16, 4, 8; poses and lag
    16; prefix 8: the counts and the Huff weights of a few noise keys). A hit is an
    identical request (keys digest the input arrays' bytes plus every
    option), so a cached and an uncached call give the same numbers.
    """

    def __init__(self, *, huff: int = 8, procrustes: int = 16, elastic: int = 16,
                 filter_pass: int = 4, smoothed: int = 8, poses: int = 16, lag: int = 16,
                 prefix: int = 8) -> None:
        self.huff = ContentMemo(huff)
        self.procrustes = ContentMemo(procrustes)
        self.elastic = ContentMemo(elastic)
        self.filter_pass = ContentMemo(filter_pass)
        self.smoothed = ContentMemo(smoothed)
        self.poses = ContentMemo(poses)
        self.lag = ContentMemo(lag)
        self.prefix = ContentMemo(prefix)

    def memos(self) -> dict[str, ContentMemo]:
        """The memos by name."""
        return {"huff": self.huff, "procrustes": self.procrustes, "elastic": self.elastic,
                "filter_pass": self.filter_pass, "smoothed": self.smoothed,
                "poses": self.poses, "lag": self.lag, "prefix": self.prefix}

    def clear(self) -> None:
        """Forget every entry of every memo."""
        for memo in self.memos().values():
            memo.clear()


def memo_get(cache: TrackCache | None, kind: str, key: Callable[[], Hashable],
             compute: Callable[[], T]) -> T:
    """``compute()`` through memo ``kind`` of ``cache`` (keyed by ``key()``, which is only
    evaluated with a cache), or directly when ``cache`` is None."""
    if cache is None:
        return compute()
    if not isinstance(cache, TrackCache):
        raise TypeError(f"cache: expected a TrackCache or None, got {type(cache).__name__}")
    return cache.memos()[kind].get(key(), compute)
