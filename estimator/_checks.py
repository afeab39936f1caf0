"""Input checks shared by the estimator modules (DESIGN.md conventions: bad input raises
ValueError naming the field; nothing passes silently)."""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["check_increasing_times"]


def check_increasing_times(t: Any, field: str = "t", n: int | None = None,
                           min_size: int = 0) -> np.ndarray:
    """A time array: ``(n,)`` float seconds, finite and strictly increasing.

    t : array-like of seconds. field : the argument's name, used in every message.
    n : required length (None: any). min_size : smallest allowed length.
    Returns ``t`` as a 1-D float array. Raises ValueError naming ``field`` for a wrong shape
    or length, a NaN or infinite time, or a time not later than the one before it
    (``np.diff(t) <= 0`` alone lets NaN through: every comparison with NaN is False).
    """
    tt = np.asarray(t, dtype=float)
    if tt.ndim != 1 or (n is not None and tt.shape[0] != n) or tt.size < min_size:
        want = f"({n},)" if n is not None else "(n,)"
        more = f" with at least {min_size} samples" if min_size > 0 and n is None else ""
        raise ValueError(f"{field}: expected shape {want} of seconds{more}, got shape {tt.shape}")
    bad = ~np.isfinite(tt)
    if bad.any():
        k = int(np.argmax(bad))
        raise ValueError(f"{field}: times must be finite; {field}[{k}] = {tt[k]!r}")
    if tt.size > 1:
        dec = np.diff(tt) <= 0
        if dec.any():
            k = int(np.argmax(dec))
            raise ValueError(f"{field}: must be strictly increasing; {field}[{k + 1}] = "
                             f"{tt[k + 1]!r} <= {field}[{k}] = {tt[k]!r}")
    return tt
