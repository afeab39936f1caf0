"""Input checks shared by every module (DESIGN.md conventions: bad input raises ValueError or
TypeError naming the argument and its value; nothing passes silently).

One place for the checks that used to be copied per module (and disagreed, e.g. ``True``
accepted as a sigma in one module and rejected in another): booleans are never numbers,
NaN and infinities are rejected unless asked for, and every message names the field.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Iterable
from typing import Any

import numpy as np

__all__ = [
    "check_array",
    "check_fields",
    "check_increasing_times",
    "check_int",
    "check_real",
]


def check_real(value: Any, name: str, *, lo: float | None = None, hi: float | None = None,
               lo_open: bool = False, hi_open: bool = False, finite: bool = True) -> float:
    """A real number (``int``/``float``/numpy scalar, never ``bool``) as a Python float.

    lo, hi : bounds (None: unbounded); ``lo_open``/``hi_open`` make them strict.
    finite : reject NaN and +-inf (default). NaN is always rejected.
    Raises TypeError naming ``name`` for a non-number (str, None, bool, array) and ValueError
    naming ``name`` and the value for NaN, an infinity or a value out of range.
    """
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name}: must be a real number, got {type(value).__name__} {value!r}")
    v = float(value)
    if math.isnan(v) or (finite and math.isinf(v)):
        raise ValueError(f"{name}: must be a finite number, got {value!r}")
    if lo is not None and (v < lo or (lo_open and v == lo)):
        raise ValueError(f"{name}: must be {'>' if lo_open else '>='} {lo:g}, got {value!r}")
    if hi is not None and (v > hi or (hi_open and v == hi)):
        raise ValueError(f"{name}: must be {'<' if hi_open else '<='} {hi:g}, got {value!r}")
    return v


def check_int(value: Any, name: str, lo: int | None = None, hi: int | None = None) -> int:
    """An integer (``int`` or numpy integer, never ``bool`` or a float such as ``2.0``).

    Raises TypeError naming ``name`` for a non-integer and ValueError for a value outside
    ``[lo, hi]`` (None: unbounded).
    """
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
        raise TypeError(f"{name}: must be an integer, got {type(value).__name__} {value!r}")
    v = int(value)
    if (lo is not None and v < lo) or (hi is not None and v > hi):
        rng = f"[{'-inf' if lo is None else lo}, {'inf' if hi is None else hi}]"
        raise ValueError(f"{name}: must be an integer in {rng}, got {value!r}")
    return v


def check_fields(obj: Any, fields: Iterable[str], *, prefix: str = "", lo: float = 0.0,
                 lo_open: bool = True) -> None:
    """Check that each attribute in ``fields`` of ``obj`` is a finite real number > ``lo``
    (``>= lo`` with ``lo_open=False``); the message names ``prefix + field``.

    For parameter dataclasses (sigmas, gains, time constants): one rule for all of them.
    """
    for f in fields:
        check_real(getattr(obj, f), f"{prefix}{f}", lo=lo, lo_open=lo_open)


def check_array(a: Any, name: str, *, shape: tuple[int | None, ...] | None = None,
                allow_nan: bool = False, max_abs: float | None = None) -> np.ndarray:
    """A float64 array with an optional shape (None entries match any length).

    allow_nan : NaN allowed (missing data); infinities never are.
    max_abs : largest allowed magnitude of a finite entry (e.g. 1e7 m keeps squares of
        coordinates far from overflow); None = no bound.
    Raises TypeError naming ``name`` if it is not numeric, ValueError for a wrong shape, a
    NaN (unless allowed), an infinity or an entry above ``max_abs`` (naming its index).
    """
    try:
        arr = np.asarray(a, dtype=float)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{name}: must be a numeric array, got {type(a).__name__}") from exc
    if shape is not None and (arr.ndim != len(shape) or any(
            s is not None and s != n for s, n in zip(shape, arr.shape))):
        want = "(" + ", ".join("n" if s is None else str(s) for s in shape) + \
            ("," if len(shape) == 1 else "") + ")"
        raise ValueError(f"{name}: expected shape {want}, got {arr.shape}")
    bad = np.isinf(arr) if allow_nan else ~np.isfinite(arr)
    if bad.any():
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        what = "finite or NaN" if allow_nan else "finite"
        raise ValueError(f"{name}: values must be {what}; {name}{list(idx)} = {arr[idx]!r}")
    if max_abs is not None:
        with np.errstate(invalid="ignore"):
            big = np.abs(arr) > max_abs
        if big.any():
            idx = tuple(int(i) for i in np.argwhere(big)[0])
            raise ValueError(f"{name}: |value| must be <= {max_abs:g}; "
                             f"{name}{list(idx)} = {arr[idx]!r}")
    return arr


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
