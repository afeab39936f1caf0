"""Spike filters for raw ultrasonic ranges (thesis 003, Section 3.2.2 and Appendix C).

Filter 1, :func:`velocity_gate`: a Tx/Rx range cannot change faster than the platform can
move ("1000 mm per sample at a maximum sampling interval of roughly 0.1 s", i.e. 10 m/s);
a rejected sample is replaced by the previous accepted value.

Filter 2, :func:`separation_gate`: the ranges from one receiver to the two transmitters
(0.5 m apart) cannot differ by more than that separation; otherwise both are replaced by the
previous values.

Two behaviours (``mode``):

``"thesis"``
    The literal rule: a fixed threshold per sample (``max_speed * sample_interval`` =
    1.0 m for the thesis's 10 m/s and 0.1 s), compared with the last accepted value, never
    re-locking; Filter 2 with the bare ``max_sep``. It holds a stale value forever after a
    genuine jump larger than the threshold (e.g. after a long dropout).
``"robust"`` (default)
    The allowed change grows with the time since the last accepted sample,
    ``noise_margin + max_speed * (t - t_accepted)``, up to ``max_change`` (the largest jump
    accepted without confirmation). A rejected sample starts a *run*; a later sample that is
    consistent with the run (within the same growing allowance of its newest member) and
    nearer to it than to the reference continues the run and is rejected too, however long
    the elapsed time has made the reference's allowance: the second, third and fourth samples
    of a spike run stay rejected (real UWB spikes come in runs of 2-4 mutually consistent
    samples). A run of ``relock_after`` consistent samples is not a spike: the gate re-locks on
    its newest sample. So a true change across a long dropout (larger than ``max_change``) is
    re-acquired after ``relock_after`` samples, and a single spike right after a gap is still
    rejected (the allowance after a gap of g seconds is ``min(v g, max_change)``, not
    "anything").
    A sample consistent with the value accepted *before* the current reference is accepted
    too (with the same allowance), so a spike small enough to slip through does not make the
    gate hold it and reject the return to the true range.
    Filter 2 allows ``max_sep + noise_margin`` and stops holding after ``relock_after``
    inconsistent pairs in a row.

Asynchronous receivers. ``t`` may be ``(n,)`` (all channels sampled together, the thesis's DAQ)
or ``(n, c)``: one time column per channel, each strictly increasing over its finite entries;
shorter channels are padded at the end with NaN times and NaN ranges. Each channel is gated
on its own clock in the same call.

Units. Metres and seconds: ranges whose median exceeds 1000 m (millimetres?) raise a
:class:`UnitWarning`; times whose median interval exceeds 1e6 s (11 days: nanoseconds?) raise a
``ValueError`` (every allowance would be unlimited).

Initialisation (Appendix C only names ``FilterRawData1/2`` and a 40-sample lead-in,
``Num_Lead_Pts = 40``; the bodies are not printed): the reference value is the median of the
first ``lead_in`` finite samples (robust to a spike inside the lead-in) at the time of the first
of them; every sample, lead-in included, is then gated against it. Appendix C later drops the
lead-in samples before the Kalman filter; that is the caller's choice (the study does it).

Missing samples (NaN, a dropout) stay NaN: a dropout is not a measurement, so the gate does not
invent one; the state is unchanged and, in robust mode, the elapsed time keeps growing.

Both gates accept ``(n,)`` or ``(n, c)`` arrays (c independent channels, gated in parallel; the
time loop is sequential because each decision depends on the last accepted value). Metres and
seconds throughout. Numbers are validated by :mod:`estimator._checks` (a bad value raises
``ValueError``/``TypeError`` naming the argument); ranges and times are limited to
``|value| <= MAX_ABS`` (1e12) so that no allowance overflows.
"""

from __future__ import annotations

import warnings

import numpy as np

from estimator import range_kernels
from estimator._checks import check_array, check_increasing_times, check_int, check_real

__all__ = ["MAX_ABS", "MODES", "UnitWarning", "check_units", "separation_gate", "velocity_gate"]

MODES = ("robust", "thesis")
#: largest accepted |range| (m) and |time| (s): 1e12 keeps every product and square finite
MAX_ABS = 1e12
#: a median range above this (m) looks like millimetres
_MM_LIKE_M = 1e3
#: a median sample interval above this (s) looks like nanoseconds (10 Hz in ns is 1e8)
_NS_LIKE_S = 1e6


class UnitWarning(UserWarning):
    """Ranges or times that look like the wrong unit (millimetres, nanoseconds)."""


def _check_mode(mode: str) -> str:
    if mode not in MODES:
        raise ValueError(f"mode: must be one of {MODES}, got {mode!r}")
    return mode


def check_units(t: np.ndarray | None, r: np.ndarray, *, t_name: str = "t",
                r_name: str = "r") -> None:
    """Unit sanity of range data (SI expected): a median range above 1000 m warns
    (:class:`UnitWarning`, millimetres?); a median positive time step above 1e6 s raises
    ``ValueError`` naming ``t_name`` (nanoseconds? 10 Hz in ns is 1e8 per step)."""
    rr = np.asarray(r, dtype=float)
    fin = rr[np.isfinite(rr)]
    if fin.size and np.median(fin) > _MM_LIKE_M:
        warnings.warn(f"{r_name}: median range {np.median(fin):.6g} m looks like millimetres; "
                      "pass metres (r_mm * 1e-3)", UnitWarning, stacklevel=3)
    if t is None:
        return
    tt = np.asarray(t, dtype=float)
    if tt.size < 2:
        return
    steps = np.diff(tt.reshape(tt.shape[0], -1), axis=0)
    steps = steps[np.isfinite(steps) & (steps > 0)]
    if steps.size and np.median(steps) > _NS_LIKE_S:
        raise ValueError(f"{t_name}: median sample interval {np.median(steps):.6g} s looks like "
                         "nanoseconds; pass seconds (t_ns * 1e-9)")


def _positive(name: str, value: float, allow_zero: bool = False) -> float:
    return check_real(value, name, lo=0.0, lo_open=not allow_zero, hi=MAX_ABS)


def _as_columns(name: str, x: np.ndarray, n: int | None = None) -> tuple[np.ndarray, bool]:
    a = check_array(x, name, allow_nan=True, max_abs=MAX_ABS)
    vec = a.ndim == 1
    if vec:
        a = a[:, None]
    if a.ndim != 2:
        raise ValueError(f"{name}: expected shape (n,) or (n, c), got {np.shape(x)}")
    if n is not None and a.shape[0] != n:
        raise ValueError(f"{name}: expected {n} samples, got {a.shape[0]}")
    return a, vec


def _channel_times(t: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Validated times as (n, c): a shared (n,) column or per-channel (n, c) columns, each
    strictly increasing over its finite entries, NaN only where the range is NaN too."""
    tt = check_array(t, "t", allow_nan=True, max_abs=MAX_ABS)
    n, c = r.shape
    if tt.ndim == 1:
        if tt.shape[0] != n:
            raise ValueError(f"r: expected {tt.shape[0]} samples (one per time in t), got {n}")
        return np.repeat(check_increasing_times(tt, "t")[:, None], c, axis=1)
    elif tt.shape != (n, c):
        raise ValueError(f"t: expected shape ({n},) or ({n}, {c}), got {tt.shape}")
    bad = np.isnan(tt) & np.isfinite(r)
    if bad.any():
        i, j = (int(v) for v in np.argwhere(bad)[0])
        raise ValueError(f"t: a finite range has no time; t[{i}, {j}] = nan, r = {r[i, j]!r}")
    for j in range(c):                     # each channel on its own clock; NaN = padding
        check_increasing_times(tt[:, j][np.isfinite(tt[:, j])], f"t[:, {j}]")
    return tt


def _lead_in_reference(r: np.ndarray, t: np.ndarray, lead_in: int):
    """Median of the first ``lead_in`` finite samples per column, and its reference time.
    t (n, c) per-channel times."""
    c = r.shape[1]
    ref = np.full(c, np.nan)
    t_ref = np.full(c, np.nan)
    for j in range(c):
        idx = np.flatnonzero(np.isfinite(r[:, j]))
        if idx.size:
            lead = idx[:lead_in]
            ref[j] = np.median(r[lead, j])
            # the median stands for the whole lead-in: treat it as accepted one lead-in span
            # before the first sample, so the allowance covers motion during the lead-in
            t_ref[j] = t[lead[0], j] - (t[lead[-1], j] - t[lead[0], j])
    return ref, t_ref


def velocity_gate(t: np.ndarray, r: np.ndarray, max_speed: float = 10.0, *,
                  mode: str = "robust", sample_interval: float = 0.1,
                  noise_margin: float = 0.05, max_change: float = 2.0,
                  relock_after: int = 5, lead_in: int = 40,
                  return_mask: bool = False, reference: bool = False):
    """Filter 1 of Section 3.2.2: reject range changes faster than ``max_speed``.

    Parameters
    ----------
    t : (n,) s strictly increasing (uneven sampling is the normal case), or (n, c) per-channel
        times for asynchronous receivers (NaN padding where ``r`` is NaN).
    r : (n,) or (n, c) m, raw ranges, NaN = missing.
    max_speed : m/s, the platform's top speed (thesis: 10 m/s).
    mode : "robust" (default) or "thesis" (see module docstring).
    sample_interval : s, thesis mode only: the threshold is ``max_speed * sample_interval``
        per sample (thesis: 10 m/s * 0.1 s = 1000 mm).
    noise_margin : m, robust mode: change always allowed (range noise, thesis +/- 15 mm).
    max_change : m, robust mode: the largest change accepted without ``relock_after``
        consistent samples (caps the allowance after long gaps).
    relock_after : robust mode: consecutive mutually consistent rejections that re-lock.
    lead_in : samples whose median initialises the reference (Appendix C: 40).
    return_mask : also return ``rejected`` (same shape as r, bool).
    reference : run the numpy loop instead of the compiled one
        (:func:`estimator.range_kernels.velocity_gate_run`; the same results).

    Returns the filtered ranges (same shape as ``r``) [and the rejected mask].
    """
    _check_mode(mode)
    rr, vec = _as_columns("r", r)
    tt = _channel_times(t, rr)
    vmax = _positive("max_speed", max_speed)
    dt_nom = _positive("sample_interval", sample_interval)
    margin = _positive("noise_margin", noise_margin, allow_zero=True)
    cap = _positive("max_change", max_change)
    relock_after = check_int(relock_after, "relock_after", lo=1, hi=2**31 - 1)
    lead_in = check_int(lead_in, "lead_in", lo=1, hi=2**31 - 1)
    check_units(tt, rr)
    thesis = mode == "thesis"

    ref, t_ref = _lead_in_reference(rr, tt, lead_in)
    loop = _gate_loop_reference if reference else range_kernels.velocity_gate_run
    out, rejected = loop(rr, tt, ref, t_ref, thesis, vmax * dt_nom, margin, vmax, cap,
                         relock_after)
    if vec:
        out, rejected = out[:, 0], rejected[:, 0]
    return (out, rejected) if return_mask else out


def _gate_loop_reference(rr, tt, ref, t_ref, thesis, fixed, margin, vmax, cap, relock_after):
    """The numpy time loop of :func:`velocity_gate` (all channels per row), the reference of
    :func:`estimator.range_kernels.velocity_gate_run` (same arguments and results)."""
    n, c = rr.shape
    out = rr.copy()
    rejected = np.zeros((n, c), dtype=bool)
    ref, t_ref = ref.copy(), t_ref.copy()
    ref2 = ref.copy()                # the accepted value before ref (robust mode)
    cand = np.full(c, np.nan)        # newest sample of the current rejected run
    t_cand = np.full(c, np.nan)
    count = np.zeros(c, dtype=int)   # length of the current run of consistent rejections
    for i in range(n):
        x = rr[i]
        ok = np.isfinite(x)
        if thesis:
            accept = ok & (np.abs(x - ref) <= fixed)
        else:
            ti = tt[i]
            allow = np.minimum(margin + vmax * (ti - t_ref), cap)
            d_ref = np.abs(x - ref)
            # also accept a return to the value accepted before the current reference (same
            # allowance): a spike small enough to pass must not make the gate reject the
            # return to the truth
            accept = ok & ((d_ref <= allow) | (np.abs(x - ref2) <= allow))
            # a sample continuing the current rejected run (consistent with its newest member
            # and nearer to it than to the reference) stays rejected, however far the elapsed
            # time has opened the reference's allowance
            allow_c = np.minimum(margin + vmax * (ti - t_cand), cap)
            d_c = np.abs(x - cand)
            cont = ok & (count > 0) & (d_c <= allow_c) & (d_c < d_ref)
            accept &= ~cont
            rej = ok & ~accept
            count = np.where(rej, np.where(cont, count + 1, 1), count)
            cand = np.where(rej, x, cand)
            t_cand = np.where(rej, ti, t_cand)
            relock = rej & (count >= relock_after)
            accept |= relock
            t_ref = np.where(accept, ti, t_ref)
            count = np.where(accept, 0, count)
        rej = ok & ~accept
        ref2 = np.where(accept, ref, ref2)
        ref = np.where(accept, x, ref)
        out[i] = np.where(rej, ref, x)
        rejected[i] = rej
    return out, rejected


def separation_gate(r_a: np.ndarray, r_b: np.ndarray, max_sep: float = 0.5, *,
                    mode: str = "robust", noise_margin: float = 0.03,
                    relock_after: int = 5, return_mask: bool = False):
    """Filter 2 of Section 3.2.2: ranges from one receiver to the two transmitters may not
    differ by more than the transmitters' separation (thesis: 500 mm).

    Parameters
    ----------
    r_a, r_b : (n,) or (n, c) m, ranges from the same receiver(s) to transmitters a and b
        (normally after :func:`velocity_gate`), NaN = missing.
    max_sep : m, transmitter separation (thesis: 0.5 m, tape-measured).
    mode : "robust" allows ``max_sep + noise_margin`` (two noisy ranges can legitimately
        differ by slightly more than the separation when the pair is radially aligned) and
        re-locks: from the ``relock_after``-th inconsistent pair in a row on, pairs pass
        through unchanged (a persistent disagreement is not a spike, and holding would freeze
        the range for ever) until a consistent pair restarts the count; "thesis" uses
        ``max_sep`` and holds for as long as the disagreement lasts.
    return_mask : also return ``rejected`` (bool, same shape).

    A rejected pair is replaced by the previous accepted pair; before the first accepted pair
    there is nothing to hold, so a rejected pair stays NaN there (reported in the mask). A pair
    with a NaN member cannot be checked: it passes through unchanged and does not update the
    held pair.

    Returns ``(filtered_a, filtered_b)`` [and the rejected mask].
    """
    _check_mode(mode)
    a, vec = _as_columns("r_a", r_a)
    b, _ = _as_columns("r_b", r_b, a.shape[0])
    if b.shape != a.shape:
        raise ValueError(f"r_b: expected shape {a.shape}, got {b.shape}")
    sep = _positive("max_sep", max_sep)
    margin = _positive("noise_margin", noise_margin, allow_zero=True)
    relock_after = check_int(relock_after, "relock_after", lo=1, hi=2**31 - 1)
    check_units(None, a, r_name="r_a")
    thesis = mode == "thesis"
    allow = sep if thesis else sep + margin

    n, c = a.shape
    out_a, out_b = a.copy(), b.copy()
    rejected = np.zeros((n, c), dtype=bool)
    prev_a = np.full(c, np.nan)
    prev_b = np.full(c, np.nan)
    count = np.zeros(c, dtype=int)
    for i in range(n):
        ok = np.isfinite(a[i]) & np.isfinite(b[i])
        accept = ok & (np.abs(a[i] - b[i]) <= allow)
        rej = ok & ~accept
        if not thesis:
            # a pair inconsistent for relock_after samples in a row is not a spike: stop
            # holding and pass the raw pairs through until they agree again
            count = np.where(rej, count + 1, np.where(ok, 0, count))
            rej &= count < relock_after
        prev_a = np.where(accept, a[i], prev_a)
        prev_b = np.where(accept, b[i], prev_b)
        out_a[i] = np.where(rej, prev_a, a[i])
        out_b[i] = np.where(rej, prev_b, b[i])
        rejected[i] = rej
    if vec:
        out_a, out_b, rejected = out_a[:, 0], out_b[:, 0], rejected[:, 0]
    return (out_a, out_b, rejected) if return_mask else (out_a, out_b)
