"""The time line of a receiver log: which epochs carry a plausible time, and what that time is.

Real receivers do not write a clean monotone clock. Before their first fix many send RMC/GGA
with a default date and time (dates in 1980 around the GPS epoch, such as ``050180`` or
``100180``; times such as ``235942.800``) and jump to the real date once they have a fix;
a cold restart in the middle of a log does it again; a receiver with the GPS week-number
rollover bug jumps back by 1024 weeks; single sentences arrive out of order. This module
turns the epochs of one log (groups of sentences with the same time of day, in log order)
into times and a fate per epoch, so that only plausible times define a session's grid.

Steps (:func:`assemble_times`, then :func:`resolve_times`):

1. Time of day -> continuous log time ``c``: a step back by more than 12 h is a midnight
   rollover (+1 day); smaller backward steps stay backward (out-of-order or restarted).
2. Date. ``time_base="receiver"``: every epoch with an RMC date is a source, ``t = date +
   time of day``; an undated epoch (GGA only) takes the date of the nearer (in ``c``) of the
   previous and the next source, so the GGA of the first real fix after a run of default
   dates is dated by the real RMC that follows it, not by the bogus one before it.
   ``"host"``: ``t`` is the host clock (a logger's timestamp prefix). ``"auto"`` (default):
   the receiver's dates when at least one epoch with a position fix (any epoch, in a log
   without fixes) has a plausible date;
   otherwise, when the log has plausible host timestamps, the host clock dates each epoch
   (the day that puts the receiver's time of day nearest the host time, so a host clock
   within +-12 h of UTC dates correctly) and the receiver keeps its precise time of day
   (``"host_date"``); otherwise the receiver's time of day counted from day 0
   (``"receiver_undated"``, ``date_known = False``; any RMC dates were implausible).
3. Implausible dates (``implausible_date``): before :data:`EARLIEST_PLAUSIBLE_DATE` (NMEA
   0183 was first published in 1983: an earlier date is a receiver default) or after
   ``latest`` (default: tomorrow, UTC; a log cannot come from the future).
4. GPS week rollover (``week_rollover``, kept and corrected): an era (below) whose times
   come within ``max_span_s`` of the main era when shifted by k x 1024 weeks (|k| <= 3) is
   a receiver with the rollover bug; the earlier of the two is moved forward (the bug only
   ever goes back in time). With plausible host timestamps, a receiver time that differs
   from the host clock by k x 1024 weeks (within a day) is corrected the same way.
5. Eras (``time_jump``): the times sorted and split wherever consecutive ones are more than
   ``max_span_s`` apart (default 7 days, the grid limit: nothing farther apart can share a
   grid anyway); the era with the most position fixes is the log, the others are a step of
   years (e.g. 1980 defaults when the limit check above cannot apply, a default date of a
   later GPS era, ...).
6. Repeats (``duplicate_epochs``): an epoch whose time equals that of an earlier one.
7. Order: the log is written in time order, so the kept epochs are the heaviest strictly
   increasing subsequence of times in log order (position fixes weigh more than any number
   of no-fix epochs; ties keep the earlier epochs). Epochs off it are out of order: alone,
   ``time_reversals``; two or more in a row, ``reversed_segments`` (a whole segment whose
   time went back, e.g. a restart counting from a default time of the same day).

No-fix epochs never decide anything: they can only lose against fixes in steps 5 and 7, and
a session's grid is laid from position fixes alone (``sim.nmea.session_from_fixes``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import UTC, date, datetime, timedelta
from typing import Literal

import numpy as np

__all__ = [
    "DAY_S",
    "EARLIEST_PLAUSIBLE_DATE",
    "FATES",
    "MAX_SPAN_S",
    "WEEK_ROLLOVER_S",
    "Times",
    "absolute_times",
    "assemble_times",
    "heaviest_increasing",
    "resolve_times",
]

DAY_S = 86400.0
#: Dates before this are receiver defaults (NMEA 0183 was first published in 1983).
EARLIEST_PLAUSIBLE_DATE = date(1983, 1, 1)
#: GPS week-number rollover: the 10-bit week counter wraps every 1024 weeks.
WEEK_ROLLOVER_S = 1024 * 7 * DAY_S
#: Longest time line a log (and a session's grid) may span: 7 days.
MAX_SPAN_S = 7 * DAY_S

KEEP = 0
#: Fate codes of dropped epochs -> the skip class that counts them.
FATES = {1: "implausible_date", 2: "time_jump", 3: "duplicate_epochs", 4: "time_reversals",
         5: "reversed_segments", 6: "no_host_time"}
_IMPLAUSIBLE, _JUMP, _DUP, _REV, _REVSEG, _NOHOST = 1, 2, 3, 4, 5, 6
_TIME_EPS = 1e-6


def _days(d: date) -> float:
    return float((d - date(1970, 1, 1)).days)


def plausible_bounds(latest: date | None) -> tuple[float, float]:
    """[earliest, latest + 1 day) as seconds since 1970 (latest default: tomorrow, UTC)."""
    hi = latest if latest is not None else datetime.now(UTC).date() + timedelta(days=1)
    return _days(EARLIEST_PLAUSIBLE_DATE) * DAY_S, (_days(hi) + 1.0) * DAY_S


def _chain(tod: np.ndarray) -> np.ndarray:
    """+1 day at each step back by more than 12 h (midnight rollover)."""
    if tod.size == 0:
        return tod.astype(float)
    return tod + DAY_S * np.r_[0, np.cumsum(np.diff(tod) < -DAY_S / 2)]


def continuous_tod(tod: np.ndarray, fix: np.ndarray | None = None) -> np.ndarray:
    """Time of day (s) in log order -> continuous time ``c`` (step 1).

    The rollover chain runs over the epochs with a position fix only (a fix implies a
    known time; no-fix epochs may carry default times, and a default time after a restart
    would otherwise count as a midnight); every other epoch takes the day that puts it
    nearest (within 12 h) to the nearer of the previous and the next fix epoch. Without
    any fix the chain runs over all epochs.
    """
    if fix is None or not fix.any() or fix.all():
        return _chain(tod)
    n = tod.size
    c = np.empty(n)
    fi = np.flatnonzero(fix)
    c[fi] = _chain(tod[fi])
    prev = np.maximum.accumulate(np.where(fix, np.arange(n), -1))
    nxt = np.minimum.accumulate(np.where(fix, np.arange(n), n)[::-1])[::-1]
    best = np.full(n, np.inf)
    for ref in (prev, nxt):
        # only epochs without a fix that have this neighbour (ref is then a fix epoch, whose
        # c is set; the others' c is still unset and never read)
        i = np.flatnonzero((ref >= 0) & (ref < n) & ~fix)
        r = ref[i]
        cand = tod[i] + DAY_S * np.round((c[r] - tod[i]) / DAY_S)
        d = np.abs(cand - c[r])
        take = d < best[i]
        c[i[take]] = cand[take]
        best[i[take]] = d[take]
    return c


def _nearest_source(c: np.ndarray, src: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For every element, the index of the nearer (in c) of the previous and the next
    source in log order, and whether that source comes later (back-dated). src: bool."""
    n = c.size
    idx = np.arange(n)
    prev = np.maximum.accumulate(np.where(src, idx, -1))
    nxt = np.minimum.accumulate(np.where(src, idx, n)[::-1])[::-1]
    dp = np.where(prev >= 0, np.abs(c - c[np.clip(prev, 0, n - 1)]), np.inf)
    dn = np.where(nxt < n, np.abs(c[np.clip(nxt, 0, n - 1)] - c), np.inf)
    use_next = dn < dp
    return np.where(use_next, nxt, prev), use_next & ~src


def _date_from_sources(c: np.ndarray, tod: np.ndarray, day: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Absolute times from dated sources (``day`` finite): t = c + offset of the nearest source."""
    src = np.isfinite(day)
    offset = np.where(src, day * DAY_S + tod - c, 0.0)
    which, back = _nearest_source(c, src)
    return c + offset[which], back


@dataclass
class Times:
    """Times and fates of a log's epochs (G,), from :func:`assemble_times` / :func:`resolve_times`.

    t : seconds since 1970-01-01 UTC (since day 0 when ``date_known`` is False).
    fate : 0 = kept, else a key of :data:`FATES`. back_dated : undated epochs dated from a
    later RMC (``no_date``). week_rollover : epochs shifted by k x 1024 weeks.
    time_base : "receiver", "host_date", "host" or "receiver_undated". notes : why.
    """

    t: np.ndarray
    fate: np.ndarray
    date_known: bool
    time_base: str
    back_dated: np.ndarray
    week_rollover: np.ndarray
    notes: list[str]


def assemble_times(tod: np.ndarray, day: np.ndarray, host: np.ndarray, fix: np.ndarray, *,
                   time_base: Literal["auto", "receiver", "host"] = "auto",
                   latest: date | None = None) -> Times:
    """Steps 1-3 of the module docstring: times of day + dates (+ host clock) -> times.

    tod : (G,) seconds of day; day : (G,) days since 1970 of the epoch's RMC date, NaN when
    undated; host : (G,) host-clock seconds since 1970, NaN when none; fix : (G,) bool,
    epoch has a position fix. Returns :class:`Times` with implausible dates marked.
    """
    G = tod.size
    fate = np.zeros(G, dtype=np.int8)
    back = np.zeros(G, dtype=bool)
    notes: list[str] = []
    lo, hi = plausible_bounds(latest)
    c = continuous_tod(tod, fix)
    host_ok = np.isfinite(host) & (host >= lo) & (host < hi)
    if np.isfinite(host).any() and not host_ok.all() and host_ok.any():
        notes.append(f"{int((np.isfinite(host) & ~host_ok).sum())} epochs with an implausible "
                     f"host time (ignored)")
    if time_base == "host":
        fate[~host_ok] = _NOHOST
        return Times(np.where(host_ok, host, 0.0), fate, True, "host", back,
                     np.zeros(G, dtype=bool), notes)
    dated = np.isfinite(day)
    day_ok = dated & (day * DAY_S >= lo) & (day * DAY_S < hi)
    # the epochs whose dates decide: those with a position fix (all, in a log without any)
    decide = fix if fix.any() else np.ones(G, dtype=bool)
    if time_base == "receiver" or (decide & day_ok).any():
        if not dated.any():
            return Times(c, fate, False, "receiver_undated", back, np.zeros(G, dtype=bool),
                         notes + ["no RMC date in the log"])
        t, back = _date_from_sources(c, tod, day)
        fate[(t < lo) | (t >= hi)] = _IMPLAUSIBLE
        return Times(t, fate, True, "receiver", back, np.zeros(G, dtype=bool), notes)
    if (decide & host_ok).any():
        hday = np.where(host_ok, np.round((host - tod) / DAY_S), np.nan)
        t, _ = _date_from_sources(c, tod, hday)
        why = "no RMC date" if not dated.any() else "no fix with a plausible RMC date"
        return Times(t, fate, True, "host_date", back, np.zeros(G, dtype=bool),
                     notes + [f"{why}: dates from the host clock, time of day from the receiver"])
    why = "no RMC date in the log" if not dated.any() else \
        "no fix with a plausible RMC date and no host clock: dates dropped"
    return Times(c, fate, False, "receiver_undated", back, np.zeros(G, dtype=bool), notes + [why])


def absolute_times(t: np.ndarray, *, latest: date | None = None) -> Times:
    """Step 3 for times that are already absolute (seconds since 1970, e.g. a CSV's TIME):
    implausible ones marked, ready for :func:`resolve_times`."""
    lo, hi = plausible_bounds(latest)
    fate = np.where((t < lo) | (t >= hi), _IMPLAUSIBLE, KEEP).astype(np.int8)
    return Times(t.astype(float).copy(), fate, True, "receiver", np.zeros(t.size, dtype=bool),
                 np.zeros(t.size, dtype=bool), [])


def _eras(t: np.ndarray, max_span_s: float) -> np.ndarray:
    """Era label per element: sorted times split at gaps > max_span_s."""
    order = np.argsort(t, kind="stable")
    cut = np.r_[0, np.cumsum(np.diff(t[order]) > max_span_s)]
    lab = np.empty(t.size, dtype=np.int64)
    lab[order] = cut
    return lab


def _era_stats(lab: np.ndarray, t: np.ndarray, fix: np.ndarray) -> tuple[np.ndarray, ...]:
    """Per era label: fixes, epochs, first index in log order, min and max time."""
    E = int(lab.max()) + 1
    fixes = np.bincount(lab, weights=fix.astype(float), minlength=E)
    sizes = np.bincount(lab, minlength=E)
    first = np.full(E, lab.size)
    np.minimum.at(first, lab, np.arange(lab.size))
    lo = np.full(E, np.inf)
    hi = np.full(E, -np.inf)
    np.minimum.at(lo, lab, t)
    np.maximum.at(hi, lab, t)
    return fixes, sizes, first, lo, hi


def _main_era(fixes: np.ndarray, sizes: np.ndarray, first: np.ndarray) -> int:
    """The era with the most fixes, then the most epochs, then the first in log order."""
    return int(np.lexsort((first, -sizes, -fixes))[0])


def heaviest_increasing(t: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """(G,) bool: the strictly increasing subsequence of ``t`` (log order) of largest total
    ``weight`` (positive integers); ties keep earlier elements. O(G log G) with a Fenwick
    tree of prefix maxima over the ranks of t; a strictly increasing t is returned whole."""
    G = t.size
    if G == 0 or bool(np.all(np.diff(t) > 0)):
        return np.ones(G, dtype=bool)
    ranks = np.unique(t, return_inverse=True)[1] + 1          # 1..R, equal t -> equal rank
    R = int(ranks.max())
    tree_v = [0] * (R + 1)
    tree_i = [-1] * (R + 1)
    best = [0] * G
    prev = [-1] * G
    w = [int(v) for v in weight]
    rk = [int(v) for v in ranks]
    for i in range(G):
        # best chain ending at a rank < rk[i] (strictly smaller time); ties -> smaller index
        r, bv, bi = rk[i] - 1, 0, -1
        while r > 0:
            v, j = tree_v[r], tree_i[r]
            if v > bv or (v == bv and v > 0 and j < bi):
                bv, bi = v, j
            r -= r & -r
        best[i] = bv + w[i]
        prev[i] = bi
        r = rk[i]
        while r <= R:
            if best[i] > tree_v[r] or (best[i] == tree_v[r] and i < tree_i[r]):
                tree_v[r], tree_i[r] = best[i], i
            r += r & -r
    top = max(best)
    i = best.index(top)                                        # first chain end of top weight
    keep = np.zeros(G, dtype=bool)
    while i >= 0:
        keep[i] = True
        i = prev[i]
    return keep


def _runs_of(mask: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) of the runs of True in a bool array."""
    d = np.diff(np.r_[0, mask.astype(np.int8), 0])
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist()))


def resolve_times(times: Times, fix: np.ndarray, host: np.ndarray | None = None, *,
                  max_span_s: float = MAX_SPAN_S, latest: date | None = None) -> Times:
    """Steps 4-7 of the module docstring on the epochs still kept by :func:`assemble_times`.

    fix : (G,) bool, epoch has a position fix; host : (G,) host seconds (NaN = none) or
    None, used for the week-rollover check of a receiver time base; latest : as in
    :func:`assemble_times`. Returns ``times``, updated in place.
    """
    t, fate = times.t, times.fate
    wr = times.week_rollover
    live = np.flatnonzero(fate == KEEP)
    if live.size == 0:
        return times
    dated = times.date_known and times.time_base in ("receiver", "host_date")
    if dated and times.time_base == "receiver" and host is not None:
        lo, hi = plausible_bounds(latest)
        hsel = live[fix[live] & np.isfinite(host[live]) & (host[live] >= lo) & (host[live] < hi)]
        if hsel.size:
            off = float(np.median(host[hsel] - t[hsel]))
            k = round(off / WEEK_ROLLOVER_S)
            if k != 0 and abs(off - k * WEEK_ROLLOVER_S) < DAY_S:
                t[live] += k * WEEK_ROLLOVER_S
                wr[live] = True
                times.notes.append(f"receiver dates {k} x 1024 weeks behind the host clock "
                                   f"(GPS week rollover): corrected")
    # week-rollover merging of dated eras (step 4): an era with fixes that lands within
    # max_span_s of the main era when shifted by k x 1024 weeks; one merge per pass
    for _ in range(8 if dated else 0):
        lab = _eras(t[live], max_span_s)
        fixes, sizes, first, lo_e, hi_e = _era_stats(lab, t[live], fix[live])
        main = _main_era(fixes, sizes, first)
        moved = False
        for e in np.flatnonzero(fixes > 0):
            if e == main:
                continue
            for k in (1, -1, 2, -2, 3, -3):
                s = k * WEEK_ROLLOVER_S
                if (lo_e[e] + s <= hi_e[main] + max_span_s
                        and hi_e[e] + s >= lo_e[main] - max_span_s):
                    # the bug only goes back in time: move the earlier of the two forward
                    grp = live[lab == (e if k > 0 else main)]
                    t[grp] += abs(s)
                    wr[grp] = True
                    times.notes.append(f"{grp.size} epochs shifted by {abs(k)} x 1024 weeks "
                                       f"(GPS week rollover)")
                    moved = True
                    break
            if moved:
                break
        if not moved:
            break
    # eras (step 5)
    lab = _eras(t[live], max_span_s)
    sel = lab == _main_era(*_era_stats(lab, t[live], fix[live])[:3])
    fate[live[~sel]] = _JUMP
    live = live[sel]
    # repeats (step 6): same time as an earlier epoch
    key = np.round(t[live] / _TIME_EPS)
    _, first = np.unique(key, return_index=True)
    rep = np.ones(live.size, dtype=bool)
    rep[first] = False
    fate[live[rep]] = _DUP
    live = live[~rep]
    # order (step 7)
    w = np.where(fix[live], live.size + 1, 1)
    on = heaviest_increasing(t[live], w)
    for a, b in _runs_of(~on):
        fate[live[a:b]] = _REV if b - a == 1 else _REVSEG
    return times


def span_text(t0: float, t1: float) -> str:
    """'2020-05-19T16:04:28Z .. 2020-05-26T...' for messages (seconds since 1970)."""
    def iso(v: float) -> str:
        if not math.isfinite(v) or abs(v) > 1e11:
            return repr(v)
        return datetime.fromtimestamp(v, UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    return f"{iso(t0)} .. {iso(t1)}"
