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
    ``noise_margin + max_speed * (t - t_accepted)``, up to ``max_change``; after
    ``relock_after`` consecutive rejected samples that agree with each other (each within the
    same growing allowance of the previous rejected one) the gate re-locks on the newest one.
    A single spike right after a gap is still rejected (the allowance after a gap of g seconds
    is ``v g``, not "anything"), and a genuine step is followed after ``relock_after`` samples.
    A sample consistent with the value accepted *before* the current reference is accepted
    too (with the same allowance), so a spike small enough to slip through does not make the gate hold it and reject
    the return to the true range.
    Filter 2 allows ``max_sep + noise_margin`` and stops holding after ``relock_after``
    inconsistent pairs in a row.

Initialisation (Appendix C only names ``FilterRawData1/2`` and a 40-sample lead-in,
``Num_Lead_Pts = 40``; the bodies are not printed): the reference value is the median of the
first ``lead_in`` finite samples (robust to a spike inside the lead-in) at the time of the first
of them; every sample, lead-in included, is then gated against it. Appendix C later drops the
lead-in samples before the Kalman filter; that is the caller's choice (the study does it).

Missing samples (NaN, a dropout) stay NaN: a dropout is not a measurement, so the gate does not
invent one; the state is unchanged and, in robust mode, the elapsed time keeps growing.

Both gates accept ``(n,)`` or ``(n, c)`` arrays (c independent channels, gated in parallel; the
time loop is sequential because each decision depends on the last accepted value). Metres and
seconds throughout.
"""

from __future__ import annotations

import numpy as np

__all__ = ["MODES", "separation_gate", "velocity_gate"]

MODES = ("robust", "thesis")


def _check_mode(mode: str) -> str:
    if mode not in MODES:
        raise ValueError(f"mode: must be one of {MODES}, got {mode!r}")
    return mode


def _positive(name: str, value: float, allow_zero: bool = False) -> float:
    v = float(value)
    if not np.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        raise ValueError(f"{name}: must be a {'non-negative' if allow_zero else 'positive'} "
                         f"finite number, got {value!r}")
    return v


def _as_columns(name: str, x: np.ndarray, n: int | None = None) -> tuple[np.ndarray, bool]:
    a = np.asarray(x, dtype=float)
    vec = a.ndim == 1
    if vec:
        a = a[:, None]
    if a.ndim != 2:
        raise ValueError(f"{name}: expected shape (n,) or (n, c), got {np.shape(x)}")
    if n is not None and a.shape[0] != n:
        raise ValueError(f"{name}: expected {n} samples, got {a.shape[0]}")
    if np.any(np.isinf(a)):
        raise ValueError(f"{name}: must be finite or NaN (NaN = missing), got inf")
    return a, vec


def _lead_in_reference(r: np.ndarray, t: np.ndarray, lead_in: int):
    """Median of the first ``lead_in`` finite samples per column, and its reference time."""
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
            t_ref[j] = t[lead[0]] - (t[lead[-1]] - t[lead[0]])
    return ref, t_ref


def velocity_gate(t: np.ndarray, r: np.ndarray, max_speed: float = 10.0, *,
                  mode: str = "robust", sample_interval: float = 0.1,
                  noise_margin: float = 0.05, max_change: float = 2.0,
                  relock_after: int = 5, lead_in: int = 40,
                  return_mask: bool = False):
    """Filter 1 of Section 3.2.2: reject range changes faster than ``max_speed``.

    Parameters
    ----------
    t : (n,) s, strictly increasing (uneven sampling is the normal case).
    r : (n,) or (n, c) m, raw ranges, NaN = missing.
    max_speed : m/s, the platform's top speed (thesis: 10 m/s).
    mode : "robust" (default) or "thesis" (see module docstring).
    sample_interval : s, thesis mode only: the threshold is ``max_speed * sample_interval``
        per sample (thesis: 10 m/s * 0.1 s = 1000 mm).
    noise_margin : m, robust mode: change always allowed (range noise, thesis +/- 15 mm).
    max_change : m, robust mode: cap of the allowance after long gaps.
    relock_after : robust mode: consecutive mutually consistent rejections that re-lock.
    lead_in : samples whose median initialises the reference (Appendix C: 40).
    return_mask : also return ``rejected`` (same shape as r, bool).

    Returns the filtered ranges (same shape as ``r``) [and the rejected mask].
    """
    _check_mode(mode)
    tt = np.asarray(t, dtype=float)
    if tt.ndim != 1:
        raise ValueError(f"t: expected shape (n,), got {tt.shape}")
    if tt.size > 1 and not np.all(np.diff(tt) > 0):
        raise ValueError("t: must be strictly increasing")
    rr, vec = _as_columns("r", r, tt.shape[0])
    vmax = _positive("max_speed", max_speed)
    dt_nom = _positive("sample_interval", sample_interval)
    margin = _positive("noise_margin", noise_margin, allow_zero=True)
    cap = _positive("max_change", max_change)
    if int(relock_after) != relock_after or relock_after < 1:
        raise ValueError(f"relock_after: must be a positive integer, got {relock_after!r}")
    if int(lead_in) != lead_in or lead_in < 1:
        raise ValueError(f"lead_in: must be a positive integer, got {lead_in!r}")
    thesis = mode == "thesis"

    n, c = rr.shape
    out = rr.copy()
    rejected = np.zeros((n, c), dtype=bool)
    ref, t_ref = _lead_in_reference(rr, tt, int(lead_in))
    ref2 = ref.copy()                          # the accepted value before ref (robust mode)
    cand = np.full(c, np.nan)        # newest rejected value (re-lock candidate)
    t_cand = np.full(c, np.nan)
    count = np.zeros(c, dtype=int)
    fixed = vmax * dt_nom
    for i in range(n):
        x = rr[i]
        ok = np.isfinite(x)
        if thesis:
            allow = np.full(c, fixed)
            accept = ok & (np.abs(x - ref) <= allow)
        else:
            allow = np.minimum(margin + vmax * (tt[i] - t_ref), cap)
            # also accept a return to the value accepted before the current reference (same
            # allowance): a spike small enough to pass must not make the gate reject the
            # return to the truth
            accept = ok & ((np.abs(x - ref) <= allow) | (np.abs(x - ref2) <= allow))
        rej = ok & ~accept
        if not thesis and np.any(rej):
            allow_c = np.minimum(margin + vmax * (tt[i] - t_cand), cap)
            consistent = rej & (count > 0) & (np.abs(x - cand) <= allow_c)
            count = np.where(rej, np.where(consistent, count + 1, 1), count)
            cand = np.where(rej, x, cand)
            t_cand = np.where(rej, tt[i], t_cand)
            relock = rej & (count >= relock_after)
            accept |= relock
            rej &= ~relock
        ref2 = np.where(accept, ref, ref2)
        ref = np.where(accept, x, ref)
        t_ref = np.where(accept, tt[i], t_ref)
        count = np.where(accept, 0, count)
        out[i] = np.where(rej, ref, x)
        rejected[i] = rej
    if vec:
        out, rejected = out[:, 0], rejected[:, 0]
    return (out, rejected) if return_mask else out


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
    if int(relock_after) != relock_after or relock_after < 1:
        raise ValueError(f"relock_after: must be a positive integer, got {relock_after!r}")
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
