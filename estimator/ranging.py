"""Range localization: the Appendix C pipeline over asynchronous range streams, and a tightly
coupled range filter (thesis 003, Sections 3.2.2-3.2.3 and Appendix C; beyond the thesis for
real ranging data such as outdoor UWB).

:func:`localize` runs every stage and returns all of them (:class:`RangingResult`):

1. **Gates** (:mod:`estimator.range_filters`): Filter 1 (velocity) on every transmitter/receiver
   channel on its own clock; Filter 2 (separation) on the epoch ranges of two transmitters.
2. **Epochs** (:func:`epoch_ranges`): the asynchronous channels brought to common epoch times:
   ``"sample"`` (synchronous streams: the samples are the epochs, as the thesis's DAQ),
   ``"interpolate"`` (linear between the accepted samples bracketing the epoch, if they are
   at most ``max_gap_s`` apart; uses one future sample) or ``"latest"`` (the newest accepted
   sample at most ``max_gap_s`` old; causal).
3. **Fixes** (:func:`trilaterate_epochs`): one trilateration per epoch and transmitter, with
   any :mod:`estimator.trilateration` method. The default ``damped_ls`` uses whichever
   receivers reported (>= 3), an optional known height, and picks the mirror minimum nearest
   the previous fix (``mirror="continuity"``). Each fix carries its geometric standard
   deviation per axis, ``sigma_range * sqrt(diag((J'J)^-1))`` (first-order propagation of
   the range noise; grows with the dilution of precision far from a small array).
4. **Kalman** (:func:`filter_fixes`): Appendix C's PV Kalman filter per axis and transmitter
   (:func:`estimator.kalman.pv_kalman`), with the per-fix standard deviations (or a fixed
   one, as the thesis) and an innovation gate with re-initialisation.
5. **Heading** (two transmitters): atan2 of the two fixes, unwrapped, PV Kalman filtered
   (Appendix C), wrapped back.
6. **Tightly coupled filter** (:class:`RangeFilter`, :func:`tight_filter`): an extended Kalman
   filter on a constant-velocity state (plus yaw and yaw rate when transmitters sit on lever
   arms) updated with every range as it arrives, each gated on its normalised innovation;
   it needs no trilateration (one damped fix initialises it) and no complete epoch. This is
   what the authors of the outdoor UWB dataset do with an IMU (an error-state filter); here
   without one.

Ranges are given as :class:`RangeStreams` (long format: one row per sample with its time,
receiver and transmitter). SI units throughout; ``RangingConfig`` holds every setting, each a
physical quantity with a documented default (:meth:`RangingConfig.appendix_c` for the
thesis's ultrasonic quadcopter, :meth:`RangingConfig.uwb_ground_tag` for a UWB tag on a
pedestrian or small ground robot).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from itertools import combinations
from typing import Any, cast

import numpy as np

from estimator import range_kernels
from estimator import trilateration as tri
from estimator._checks import check_array, check_increasing_times, check_int, check_real
from estimator.kalman import PVKalman, pv_kalman
from estimator.orientation import heading_from_points, unwrap_angle, wrap_angle
from estimator.range_filters import MODES as GATE_MODES
from estimator.range_filters import check_units, separation_gate, velocity_gate

__all__ = [
    "MIRROR_MODES",
    "SYNC_MODES",
    "Fixes",
    "RangeFilter",
    "RangeStreams",
    "RangingConfig",
    "RangingResult",
    "TightResult",
    "best_triple",
    "check_range_geometry",
    "epoch_ranges",
    "filter_fixes",
    "gate_streams",
    "height_bounds",
    "localize",
    "nominal_interval",
    "tight_filter",
    "transmitter_heading",
    "trilaterate_epochs",
]

SYNC_MODES = ("sample", "interpolate", "latest")
MIRROR_MODES = ("continuity", "side")
#: largest accepted |time| (s) and range (m) in a stream (times as seconds since an epoch are
#: ~2e9; nanoseconds would be ~2e18 and are refused by the unit check)
_MAX_T = 1e12
_THREE = ("simple", "closed_form", "cayley_menger")
#: argument types of RangeFilter.update's fast path (checked by type, not isinstance)
_FLOATS = frozenset({float, np.float64, int})
_INTS = frozenset({int, np.int64, np.intp})


# =============================================================================================
# data: range streams and settings
# =============================================================================================


@dataclass(frozen=True)
class RangeStreams:
    """Asynchronous range samples in long format, sorted by time.

    t (N,) s; r (N,) m (NaN = the sample carries no range); receiver (N,) int in
    [0, n_receivers); transmitter (N,) int in [0, n_transmitters). Within each channel (one
    transmitter/receiver pair) times are strictly increasing. Validated on construction
    (``ValueError``/``TypeError`` naming the field); ranges that look like millimetres warn
    and times that look like nanoseconds raise (:func:`estimator.range_filters.check_units`).
    """

    t: np.ndarray
    r: np.ndarray
    receiver: np.ndarray
    transmitter: np.ndarray
    n_receivers: int
    n_transmitters: int = 1

    def __post_init__(self) -> None:
        k = check_int(self.n_receivers, "n_receivers", lo=1, hi=10_000)
        nt = check_int(self.n_transmitters, "n_transmitters", lo=1, hi=100)
        t = check_array(self.t, "t", max_abs=_MAX_T)
        r = check_array(self.r, "r", allow_nan=True, max_abs=tri.MAX_ABS_M)
        if t.ndim != 1:
            raise ValueError(f"t: expected shape (N,), got {t.shape}")
        n = t.shape[0]
        if r.shape != (n,):
            raise ValueError(f"r: expected shape ({n},), got {r.shape}")
        with np.errstate(invalid="ignore"):
            if np.any(r < 0):
                raise ValueError(f"r: ranges must be >= 0 m, got min {np.nanmin(r)!r}")
        rx = self._index(self.receiver, "receiver", n, k)
        tx = self._index(self.transmitter, "transmitter", n, nt)
        if n > 1 and np.any(np.diff(t) < 0):
            i = int(np.argmax(np.diff(t) < 0))
            raise ValueError(f"t: must be sorted; t[{i + 1}] = {t[i + 1]!r} < t[{i}] = {t[i]!r}")
        ch = tx * k + rx
        order = np.lexsort((t, ch))
        same = (np.diff(ch[order]) == 0) & (np.diff(t[order]) <= 0)
        if same.any():
            i = order[int(np.argmax(same)) + 1]
            raise ValueError(f"t: times of channel (transmitter {tx[i]}, receiver {rx[i]}) must "
                             f"be strictly increasing; t[{i}] = {t[i]!r} repeats")
        check_units(t, r)
        for name, val in (("t", t), ("r", r), ("receiver", rx), ("transmitter", tx),
                          ("n_receivers", k), ("n_transmitters", nt)):
            object.__setattr__(self, name, val)

    @staticmethod
    def _index(a, name: str, n: int, hi: int) -> np.ndarray:
        arr = np.asarray(a)
        if arr.shape != (n,) or not (np.issubdtype(arr.dtype, np.integer) or arr.size == 0):
            raise TypeError(f"{name}: expected an integer array of shape ({n},), got "
                            f"{arr.dtype} {arr.shape}")
        arr = arr.astype(int)
        if arr.size and (arr.min() < 0 or arr.max() >= hi):
            bad = int(arr[(arr < 0) | (arr >= hi)][0])
            raise ValueError(f"{name}: indices must be in [0, {hi}), got {bad}")
        return arr

    @property
    def n_channels(self) -> int:
        """Transmitter/receiver pairs: channel c = transmitter * n_receivers + receiver."""
        return self.n_transmitters * self.n_receivers

    @property
    def channel(self) -> np.ndarray:
        """(N,) channel index of every sample."""
        return self.transmitter * self.n_receivers + self.receiver

    @classmethod
    def from_synchronous(cls, t: np.ndarray, ranges: np.ndarray) -> RangeStreams:
        """Streams from ranges sampled together: t (n,) s, ranges (n, T, k) or (n, k) m."""
        tt = check_array(t, "t", max_abs=_MAX_T)
        rr = check_array(ranges, "ranges", allow_nan=True, max_abs=tri.MAX_ABS_M)
        if rr.ndim == 2:
            rr = rr[:, None, :]
        if tt.ndim != 1 or rr.ndim != 3 or rr.shape[0] != tt.shape[0]:
            raise ValueError(f"ranges: expected shape (n, T, k) or (n, k) with n = len(t) = "
                             f"{tt.shape[0] if tt.ndim == 1 else tt.shape}, got {rr.shape}")
        n, nt, k = rr.shape
        return cls(np.repeat(tt, nt * k), rr.reshape(-1),
                   np.tile(np.arange(k), n * nt), np.tile(np.repeat(np.arange(nt), k), n),
                   k, nt)

    @classmethod
    def from_channels(cls, channels: Mapping, n_receivers: int,
                      n_transmitters: int = 1) -> RangeStreams:
        """Streams from per-channel arrays: ``{receiver: (t, r)}`` or
        ``{(transmitter, receiver): (t, r)}``, each t (n_c,) s and r (n_c,) m."""
        ts, rs, rxs, txs = [], [], [], []
        for key, value in channels.items():
            tx, rx = (0, key) if not isinstance(key, tuple) else key
            tc = check_array(value[0], f"channels[{key!r}].t", max_abs=_MAX_T).reshape(-1)
            rc = check_array(value[1], f"channels[{key!r}].r", allow_nan=True,
                             max_abs=tri.MAX_ABS_M).reshape(-1)
            if tc.shape != rc.shape:
                raise ValueError(f"channels[{key!r}]: t and r differ in length "
                                 f"({tc.size} vs {rc.size})")
            ts.append(tc)
            rs.append(rc)
            rxs.append(np.full(tc.size, check_int(rx, f"channels[{key!r}] receiver")))
            txs.append(np.full(tc.size, check_int(tx, f"channels[{key!r}] transmitter")))
        if not ts:
            raise ValueError("channels: no channel given")
        t = np.concatenate(ts)
        order = np.argsort(t, kind="stable")
        return cls(t[order], np.concatenate(rs)[order], np.concatenate(rxs)[order],
                   np.concatenate(txs)[order], n_receivers, n_transmitters)

    def is_synchronous(self) -> bool:
        """Every channel sampled at the same times (the thesis's DAQ)."""
        if self.t.size == 0 or self.t.size % self.n_channels:
            return False
        times = np.unique(self.t)
        return times.size * self.n_channels == self.t.size and bool(np.all(
            np.bincount(self.channel, minlength=self.n_channels) == times.size))

    def padded(self, values: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray,
                                                                  np.ndarray]:
        """Per-channel columns for the gates: times (n_max, C), values (n_max, C) (NaN
        padded) and the (N,) row of each sample in its column."""
        ch = self.channel
        counts = np.bincount(ch, minlength=self.n_channels)
        n_max = int(counts.max()) if counts.size else 0
        order = np.argsort(ch, kind="stable")
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        row = np.empty(self.t.size, dtype=int)
        row[order] = np.arange(self.t.size) - starts[ch[order]]
        tp = np.full((n_max, self.n_channels), np.nan)
        vp = np.full((n_max, self.n_channels), np.nan)
        tp[row, ch] = self.t
        vp[row, ch] = self.r if values is None else values
        return tp, vp, row


@dataclass(frozen=True)
class RangingConfig:
    """Settings of :func:`localize`; each is a physical quantity or a documented choice.

    Platform and sensor:
    sigma_range_m : range noise standard deviation of the sensor class (m).
    max_speed_mps : the platform's top speed (m/s): Filter 1's allowance.
    accel_std_mps2 : standard deviation of the platform's accelerations (m/s^2): the process
        noise of both filters (PV Kalman: per-step white acceleration; tightly coupled filter:
        white-acceleration spectral density ``accel_std^2 x 1 s``).
    Gates (Filter 1 / Filter 2, :mod:`estimator.range_filters`):
    gate_mode : "robust" or "thesis". noise_margin_m : None = 3 sigma_range.
    max_change_m : largest jump accepted without re-locking; None = noise_margin + the motion
        over two nominal sample intervals at max_speed.
    relock_after : consecutive consistent samples that re-lock Filter 1 and re-initialise the
        Kalman filters (longer than a spike run: real UWB spikes come in runs of 2-4).
    lead_in : samples whose median initialises Filter 1 (Appendix C ``Num_Lead_Pts``).
    sample_interval_s : the nominal sample interval (s) of Filter 1 (thesis mode: threshold =
        max_speed x interval) and of ``max_change``; None = the median interval of the data.
    tx_separation_m : Filter 2's transmitter separation (None: no Filter 2).
    Geometry:
    lever_arms_m : (T, 3) transmitter positions in the body frame (x forward, y left, z up);
        None = every transmitter at the body origin. The platform is taken as level (yaw only).
    height_m : the body origin's known z (m; None = solve z): known-height (2-D) mode.
    height_bounds_m : (lo, hi) m, the plausible z interval of the body origin for free-height
        ``damped_ls`` fixes (declared, e.g. from a recording's metadata); None = from the
        receivers' heights when ``height_margin_m`` is set (:func:`height_bounds`), else
        unbounded. A fix whose z falls outside is re-solved at the nearest bound; a fix whose
        geometric z std exceeds half the interval's width (the geometry cannot resolve z,
        e.g. receivers nearly coplanar seen from afar) is re-solved at
        ``fallback_height_m`` (known-height fallback); the PV Kalman z is held inside too.
    height_margin_m : margin (m) of the bounds from the geometry: the receivers' lowest z
        minus it to their highest z plus it. fallback_height_m : None = the bounds' middle.
    Fixes:
    method : a :mod:`estimator.trilateration` method name. receivers_used : indices of the
        receivers used by the fixes (None: all; for a three-receiver method the largest
        triangle, :func:`best_triple`). side : mirror side when nothing else decides.
    mirror : "continuity" (damped_ls: the mirror minimum nearest the previous fix) or "side".
    sync : epoch assembly (``SYNC_MODES``); None = "sample" for synchronous streams, else
        "interpolate". max_gap_s : longest gap bridged by interpolation / oldest sample used;
        None = ``sqrt(8 sigma_range / accel_std)``, where the chord error of a range under
        acceleration a over a gap g, a g^2 / 8, equals the range noise.
    Kalman on fixes:
    kalman_sigma_process : None = accel_std. kalman_sigma_measurement : None = each fix's own
        geometric standard deviation; a number = fixed (the thesis). kalman_gate : innovation
        gate in standard deviations (None: off). kalman_lead_in : epochs dropped before the
        filter (Appendix C drops ``Num_Lead_Pts``). heading_sigma_process /
        heading_sigma_measurement : the heading filter (rad/s^2, rad; Appendix C 1 deg).
    Tightly coupled filter:
    tight_gate : normalised-innovation gate in standard deviations (a Gaussian range passes
        with probability 1 - 6e-7 at 5). yaw_accel_std : yaw acceleration std (rad/s^2) when
        lever arms make yaw a state. tight_uses_gate1 : also skip samples Filter 1 rejected.
    """

    sigma_range_m: float
    max_speed_mps: float
    accel_std_mps2: float
    gate_mode: str = "robust"
    noise_margin_m: float | None = None
    max_change_m: float | None = None
    relock_after: int = 5
    lead_in: int = 40
    sample_interval_s: float | None = None
    tx_separation_m: float | None = None
    lever_arms_m: tuple | None = None
    height_m: float | None = None
    height_bounds_m: tuple | None = None
    height_margin_m: float | None = None
    fallback_height_m: float | None = None
    method: str = "damped_ls"
    receivers_used: tuple | None = None
    side: int = 1
    mirror: str = "continuity"
    sync: str | None = None
    max_gap_s: float | None = None
    kalman_sigma_process: float | None = None
    kalman_sigma_measurement: float | None = None
    kalman_gate: float | None = 5.0
    kalman_lead_in: int = 0
    heading_sigma_process: float = math.radians(1.0)
    heading_sigma_measurement: float = math.radians(1.0)
    tight_gate: float = 5.0
    yaw_accel_std: float = 1.0
    tight_uses_gate1: bool = True

    def __post_init__(self) -> None:
        big = 1e8
        for f in ("sigma_range_m", "max_speed_mps", "accel_std_mps2", "heading_sigma_process",
                  "heading_sigma_measurement", "tight_gate", "yaw_accel_std"):
            check_real(getattr(self, f), f, lo=0.0, lo_open=True, hi=big)
        for f in ("noise_margin_m", "max_change_m", "sample_interval_s", "tx_separation_m",
                  "max_gap_s",
                  "kalman_sigma_process", "kalman_sigma_measurement", "kalman_gate"):
            if getattr(self, f) is not None:
                check_real(getattr(self, f), f, lo=0.0, lo_open=f != "noise_margin_m", hi=big)
        if self.height_m is not None:
            check_real(self.height_m, "height_m", lo=-tri.MAX_ABS_M, hi=tri.MAX_ABS_M)
        self._check_height_bounds()
        check_int(self.relock_after, "relock_after", lo=1, hi=10_000)
        check_int(self.lead_in, "lead_in", lo=1, hi=10_000_000)
        check_int(self.kalman_lead_in, "kalman_lead_in", lo=0, hi=10_000_000)
        if self.gate_mode not in GATE_MODES:
            raise ValueError(f"gate_mode: must be one of {GATE_MODES}, got {self.gate_mode!r}")
        if self.method not in tri.METHODS:
            raise ValueError(f"method: must be one of {tuple(tri.METHODS)}, got {self.method!r}")
        if self.mirror not in MIRROR_MODES:
            raise ValueError(f"mirror: must be one of {MIRROR_MODES}, got {self.mirror!r}")
        if self.sync is not None and self.sync not in SYNC_MODES:
            raise ValueError(f"sync: must be one of {SYNC_MODES} or None, got {self.sync!r}")
        if self.side not in (1, -1) or isinstance(self.side, bool):
            raise ValueError(f"side: must be +1 or -1, got {self.side!r}")
        if not isinstance(self.tight_uses_gate1, bool):
            raise TypeError(f"tight_uses_gate1: must be a bool, got {self.tight_uses_gate1!r}")
        if self.lever_arms_m is not None:
            lev = check_array(self.lever_arms_m, "lever_arms_m", max_abs=1e3)
            if lev.ndim != 2 or lev.shape[1] != 3 or lev.shape[0] < 1:
                raise ValueError(f"lever_arms_m: expected shape (T, 3), got {lev.shape}")
            object.__setattr__(self, "lever_arms_m", tuple(map(tuple, lev.tolist())))
        if self.receivers_used is not None:
            idx = tuple(check_int(i, "receivers_used[]", lo=0) for i in self.receivers_used)
            if len(set(idx)) != len(idx) or len(idx) < 3:
                raise ValueError(f"receivers_used: need >= 3 distinct indices, got {idx}")
            object.__setattr__(self, "receivers_used", idx)

    def _check_height_bounds(self) -> None:
        """Validate height_bounds_m / height_margin_m / fallback_height_m (ValueError naming
        the field and the value)."""
        if self.height_bounds_m is not None:
            b = check_array(self.height_bounds_m, "height_bounds_m", max_abs=tri.MAX_ABS_M)
            if b.shape != (2,) or not b[0] < b[1]:
                raise ValueError("height_bounds_m: expected (lo, hi) m with lo < hi, got "
                                 f"{self.height_bounds_m!r}")
            object.__setattr__(self, "height_bounds_m", (float(b[0]), float(b[1])))
        if self.height_margin_m is not None:
            check_real(self.height_margin_m, "height_margin_m", lo=0.0, hi=tri.MAX_ABS_M)
        if self.fallback_height_m is not None:
            check_real(self.fallback_height_m, "fallback_height_m", lo=-tri.MAX_ABS_M,
                       hi=tri.MAX_ABS_M)
        bounded = self.height_bounds_m is not None or self.height_margin_m is not None
        if bounded and self.method != "damped_ls":
            raise ValueError("height_bounds_m / height_margin_m: free-height bounds apply to "
                             f"method 'damped_ls' only, got method {self.method!r}")

    # ---- presets (documented physics, never fitted to data) ----
    @classmethod
    def appendix_c(cls, **changes) -> RangingConfig:
        """Thesis 003 Appendix C (HX19 ultrasonic, F450 quadcopter): range noise 5 mm
        (Appendix B: +/- 15 mm as 3 sigma), Filter 1 at 10 m/s (1000 mm per 0.1 s sample;
        robust mode: 0.05 m margin, 2 m largest unconfirmed change),
        Filter 2 at the 0.5 m transmitter separation with the transmitters 0.25 m ahead of and
        behind the centre, CMD on receivers chosen by the caller, ``side=+1`` (the quadcopter
        flies above the array), Appendix C's Kalman sigmas (3 mm/s^2, 2 mm) after a 40-sample
        lead-in, heading filter 1 deg/s^2, 1 deg; accelerations 1 m/s^2 (the simulated
        square's lateral limit)."""
        base: dict[str, Any] = {"sigma_range_m": 0.005, "max_speed_mps": 10.0,
                                "accel_std_mps2": 1.0,
                    "noise_margin_m": 0.05, "max_change_m": 2.0, "sample_interval_s": 0.1,
                    "tx_separation_m": 0.5,
                    "lever_arms_m": ((0.25, 0.0, 0.0), (-0.25, 0.0, 0.0)),
                    "method": "cayley_menger", "mirror": "side", "kalman_sigma_process": 0.003,
                    "kalman_sigma_measurement": 0.002,
                    "kalman_gate": None, "kalman_lead_in": 40}
        base.update(changes)
        return cls(**base)

    @classmethod
    def uwb_ground_tag(cls, **changes) -> RangingConfig:
        """A UWB tag (DW1000 class) on a pedestrian or a small ground robot.

        sigma_range_m 0.1: the DW1000's specified ranging accuracy (+/- 10 cm). max_speed_mps
        3.0: a jogging person; small ground robots are slower (Clearpath Jackal 2.0 m/s,
        Husky 1.0 m/s). accel_std_mps2 1.0: walking and small-robot accelerations (peaks of
        2-3 m/s^2). Gates: noise margin 3 sigma = 0.3 m; re-lock after 5 samples (longer than
        the 2-4 sample spike runs of this sensor class). height_margin_m 2.0: a free-height
        fix keeps the tag within 2 m of the anchors' height span (anchors on tripods or
        posts, the tag 0-2 m above the same ground; :func:`height_bounds`). Everything else:
        the defaults (damped least squares with mirror continuity, per-fix Kalman sigmas,
        5-sigma gates).
        """
        base: dict[str, Any] = {"sigma_range_m": 0.1, "max_speed_mps": 3.0,
                                "accel_std_mps2": 1.0, "height_margin_m": 2.0}
        base.update(changes)
        return cls(**base)

    def replace(self, **changes) -> RangingConfig:
        """A validated copy with some fields changed."""
        return replace(self, **changes)

    # ---- derived values ----
    @property
    def noise_margin(self) -> float:
        return 3.0 * self.sigma_range_m if self.noise_margin_m is None else self.noise_margin_m

    def max_change(self, interval_s: float) -> float:
        if self.max_change_m is not None:
            return self.max_change_m
        return self.noise_margin + 2.0 * self.max_speed_mps * interval_s

    @property
    def max_gap(self) -> float:
        if self.max_gap_s is not None:
            return self.max_gap_s
        return math.sqrt(8.0 * self.sigma_range_m / self.accel_std_mps2)

    def height_interval(self, receivers: np.ndarray) -> tuple[float, float] | None:
        """The free-height z interval of the body origin (m): the declared
        ``height_bounds_m``, else :func:`height_bounds` with ``height_margin_m``, else None
        (also None in known-height mode)."""
        if self.height_m is not None:
            return None
        if self.height_bounds_m is not None:
            return self.height_bounds_m
        if self.height_margin_m is None:
            return None
        return height_bounds(receivers, self.height_margin_m)

    def levers(self, n_transmitters: int) -> np.ndarray:
        if self.lever_arms_m is None:
            return np.zeros((n_transmitters, 3))
        lev = np.asarray(self.lever_arms_m, dtype=float)
        if lev.shape[0] != n_transmitters:
            raise ValueError(f"lever_arms_m: {lev.shape[0]} lever arms for {n_transmitters} "
                             "transmitters")
        return lev


def height_bounds(receivers: np.ndarray, margin_m: float) -> tuple[float, float]:
    """Plausible z interval (m) of a platform among receivers (k, 3) m: from the lowest
    receiver's z minus ``margin_m`` to the highest one's plus ``margin_m`` (a platform on the
    ground the receivers stand on)."""
    rec = check_array(receivers, "receivers", max_abs=tri.MAX_ABS_M)
    if rec.ndim != 2 or rec.shape[1] != 3 or rec.shape[0] < 1:
        raise ValueError(f"receivers: expected shape (k, 3), got {rec.shape}")
    m = check_real(margin_m, "margin_m", lo=0.0, hi=tri.MAX_ABS_M)
    return float(rec[:, 2].min() - m), float(rec[:, 2].max() + m)


def nominal_interval(streams: RangeStreams) -> float:
    """Median sample interval over all channels (s); 0.1 s when no channel has two samples."""
    dts = []
    ch = streams.channel
    for c in range(streams.n_channels):
        tc = streams.t[(ch == c) & np.isfinite(streams.r)]
        if tc.size > 1:
            dts.append(np.diff(tc))
    return float(np.median(np.concatenate(dts))) if dts else 0.1


def best_triple(rec: np.ndarray) -> tuple[int, int, int]:
    """The receiver triple with the largest triangle area (best geometry for points far above
    a near-planar array: the in-plane position error scales with 1 / baseline)."""
    rec = check_array(rec, "receivers", max_abs=tri.MAX_ABS_M)
    if rec.ndim != 2 or rec.shape[1] != 3 or rec.shape[0] < 3:
        raise ValueError(f"receivers: expected shape (k, 3) with k >= 3, got {rec.shape}")
    best, area = (0, 1, 2), -1.0
    for c in combinations(range(rec.shape[0]), 3):
        a = float(np.linalg.norm(np.cross(rec[c[1]] - rec[c[0]], rec[c[2]] - rec[c[0]])))
        if a > area:
            best, area = (c[0], c[1], c[2]), a
    return best


def _check_types(streams=None, config=None) -> None:
    if streams is not None and not isinstance(streams, RangeStreams):
        raise TypeError(f"streams: expected RangeStreams, got {type(streams).__name__}")
    if config is not None and not isinstance(config, RangingConfig):
        raise TypeError(f"config: expected RangingConfig, got {type(config).__name__}")


def _check_epochs(epochs) -> np.ndarray:
    te = check_array(epochs, "epochs", max_abs=_MAX_T)
    if te.ndim != 1 or (te.size > 1 and np.any(np.diff(te) <= 0)):
        raise ValueError(f"epochs: expected a strictly increasing (n,) array of seconds, got "
                         f"shape {te.shape}")
    return te


# =============================================================================================
# stages 1-2: gates and epochs
# =============================================================================================


@dataclass(frozen=True)
class GateStage:
    """Filter 1 output per sample: ``r`` (N,) m (a rejected sample holds the last accepted
    value of its channel, as the thesis) and ``rejected`` (N,) bool."""

    r: np.ndarray
    rejected: np.ndarray


def gate_streams(streams: RangeStreams, config: RangingConfig) -> GateStage:
    """Filter 1 (:func:`estimator.range_filters.velocity_gate`) on every channel at once, each
    on its own clock (asynchronous receivers)."""
    _check_types(streams, config)
    tp, rp, row = streams.padded()
    ch = streams.channel
    if tp.shape[0] == 0:
        return GateStage(streams.r.copy(), np.zeros(0, dtype=bool))
    dt = config.sample_interval_s or nominal_interval(streams)
    out, rej = velocity_gate(tp, rp, config.max_speed_mps, mode=config.gate_mode,
                             sample_interval=dt, noise_margin=config.noise_margin,
                             max_change=config.max_change(dt),
                             relock_after=config.relock_after, lead_in=config.lead_in,
                             return_mask=True)
    return GateStage(out[row, ch], rej[row, ch])


def _default_epochs(streams: RangeStreams, sync: str) -> np.ndarray:
    if sync == "sample":
        return np.unique(streams.t)
    fin = np.isfinite(streams.r)
    if not fin.any():
        return np.zeros(0)
    t0, t1 = streams.t[fin][0], streams.t[fin][-1]
    dt = nominal_interval(streams)
    return t0 + dt * np.arange(int(np.floor((t1 - t0) / dt)) + 1)


def epoch_ranges(streams: RangeStreams, values: np.ndarray, epochs: np.ndarray, *, sync: str,
                 max_gap_s: float, valid: np.ndarray | None = None) -> np.ndarray:
    """Ranges of every channel at the epoch times: (n, T, k) m, NaN = none.

    values (N,) per-sample ranges (raw or gated); valid (N,) bool, samples allowed to
    contribute (default: finite). ``sync``: "sample" (each epoch takes the sample at exactly
    its time; ``values`` as given, held gate outputs included), "interpolate" (linear between
    the valid samples bracketing the epoch when they are at most ``max_gap_s`` apart; a
    sample exactly at the epoch is used as is), "latest" (the newest valid sample at most
    ``max_gap_s`` old).
    """
    _check_types(streams)
    if sync not in SYNC_MODES:
        raise ValueError(f"sync: must be one of {SYNC_MODES}, got {sync!r}")
    te = _check_epochs(epochs)
    max_gap_s = check_real(max_gap_s, "max_gap_s", lo=0.0, hi=_MAX_T)
    values = check_array(values, "values", allow_nan=True, shape=(streams.t.size,),
                         max_abs=tri.MAX_ABS_M)
    if valid is not None:
        valid = np.asarray(valid)
        if valid.shape != (streams.t.size,) or valid.dtype != bool:
            raise ValueError(f"valid: expected a bool array of shape ({streams.t.size},), "
                             f"got {valid.dtype} {valid.shape}")
    k, nt = streams.n_receivers, streams.n_transmitters
    out = np.full((te.size, nt, k), np.nan)
    ch = streams.channel
    ok = np.isfinite(values) if valid is None else (valid & np.isfinite(values))
    for c in range(streams.n_channels):
        tx, rx = divmod(c, k)
        sel = (ch == c) & (ok if sync != "sample" else np.ones_like(ok))
        tc, vc = streams.t[sel], values[sel]
        if tc.size == 0:
            continue
        if sync == "sample":
            i = np.searchsorted(te, tc)
            hit = (i < te.size) & (te[np.minimum(i, te.size - 1)] == tc)
            if not hit.all():
                raise ValueError("epochs: sync='sample' needs every sample time among the "
                                 f"epochs (channel {c} at t = {tc[~hit][0]!r} is not)")
            out[i, tx, rx] = vc
            continue
        j = np.searchsorted(tc, te, side="right")          # first sample after the epoch
        before = j - 1
        has_b = before >= 0
        bb = np.maximum(before, 0)
        exact = has_b & (tc[bb] == te)
        if sync == "latest":
            use = has_b & (te - tc[bb] <= max_gap_s)
            out[use, tx, rx] = vc[bb[use]]
            continue
        has_a = j < tc.size
        aa = np.minimum(j, tc.size - 1)
        bracket = has_b & has_a & (tc[aa] - tc[bb] <= max_gap_s)
        w = np.where(bracket, (te - tc[bb]) / np.where(bracket, tc[aa] - tc[bb], 1.0), 0.0)
        val = np.where(bracket, vc[bb] + w * (vc[aa] - vc[bb]), np.nan)
        val = np.where(exact, vc[bb], val)
        out[:, tx, rx] = val
    return out


# =============================================================================================
# stage 3: fixes
# =============================================================================================


@dataclass(frozen=True)
class Fixes:
    """Trilateration per epoch and transmitter.

    position (n, T, 3) m (NaN: no fix); sigma (n, T, 3) m, first-order standard deviation per
    axis (0 for a known height, NaN without a fix); ok (n, T) bool, a usable fix (finite, not
    missing, bounded or degenerate, converged); info: one
    :class:`estimator.trilateration.TrilaterationInfo` per transmitter; receivers (k_used,)
    indices of the receivers used; height_bounds (lo, hi) m, the body origin's free-height
    interval the fixes were held in (None: unbounded); height_held (n, T) bool, fixes
    re-solved at a bound or at the fallback height (all False when unbounded).
    """

    position: np.ndarray
    sigma: np.ndarray
    ok: np.ndarray
    info: tuple
    receivers: tuple
    height_bounds: tuple | None = None
    height_held: np.ndarray | None = None


def _fix_sigma(rec: np.ndarray, pos: np.ndarray, r: np.ndarray, sigma: float,
               known_z: bool) -> np.ndarray:
    """sigma sqrt(diag((J'J)^-1)) per fix, (n, 3) m; J the unit range Jacobian of the used
    receivers (known z: x, y only, z std 0). NaN where the fix or J'J is not usable."""
    d = 2 if known_z else 3
    diff = pos[:, None, :] - rec[None, :, :]
    dist = np.linalg.norm(diff, axis=2)
    use = np.isfinite(r) & np.isfinite(dist) & (dist > 0)
    J = np.where(use[:, :, None], diff[:, :, :d] / np.where(use, dist, 1.0)[:, :, None], 0.0)
    A = np.einsum("nki,nkj->nij", J, J)
    out = np.full((pos.shape[0], 3), np.nan)
    good = tri._well_conditioned(A) if A.shape[0] else np.zeros(0, dtype=bool)
    if good.any():
        cov = np.linalg.inv(A[good])
        out[good, :d] = sigma * np.sqrt(np.maximum(np.diagonal(cov, axis1=1, axis2=2), 0.0))
        if known_z:
            out[good, 2] = 0.0
    return out


def _continuity(pos: np.ndarray, info) -> np.ndarray:
    """Sequential mirror choice: at an ambiguous row take whichever of the returned point and
    ``info.alternative`` is nearer the previous usable fix."""
    out = pos.copy()
    alt = info.alternative
    amb = np.flatnonzero(info.ambiguous & np.all(np.isfinite(alt), axis=1))
    if amb.size == 0:
        return out
    fin = np.all(np.isfinite(out), axis=1)
    # the previous usable fix of row i: the last finite row before it (as returned, or as
    # swapped when it was ambiguous itself: rows are visited in order)
    prev = np.maximum.accumulate(np.where(fin, np.arange(out.shape[0]), -1))
    for i in amb.tolist():
        j = int(prev[i - 1]) if i > 0 else -1
        if j >= 0 and np.linalg.norm(alt[i] - out[j]) < np.linalg.norm(out[i] - out[j]):
            out[i] = alt[i]
    return out


def _held_heights(p: np.ndarray, sz: np.ndarray, usable: np.ndarray, lo: float, hi: float,
                  fallback: float) -> np.ndarray:
    """Known heights (n,) m for the free-height fixes p (n, 3) m that leave [lo, hi] (the
    nearest bound) or whose z the geometry cannot resolve (geometric z std sz (n,) m >
    (hi - lo) / 2, or NaN: J'J singular; ``fallback``); NaN where the free fix stands or is
    not usable."""
    z = p[:, 2]
    out = np.full(z.shape, np.nan)
    unresolved = usable & ~(sz <= 0.5 * (hi - lo))
    outside = usable & ~unresolved & ((z < lo) | (z > hi))
    out[outside] = np.clip(z[outside], lo, hi)
    out[unresolved] = fallback
    return out


def _merge_info(info, sub, rows: np.ndarray):
    """``info`` with the rows ``rows`` of every per-row field taken from ``sub``."""
    fields = {}
    for name in info.__dataclass_fields__:
        a = np.array(getattr(info, name), copy=True)
        a[rows] = getattr(sub, name)
        fields[name] = a
    return type(info)(**fields)


def _memo_rows(reuse: dict | None, key: tuple, inp: Callable[[], np.ndarray],
               rows: np.ndarray, compute: Callable) -> tuple:
    """``compute(sel)`` (a tuple of per-row arrays for the rows ``sel`` of this call) for
    every row, reusing the previous call's rows under ``key`` whose epoch (``rows`` (m,),
    increasing) and inputs (``inp()`` (m, c) float) are bitwise equal; this call is then
    stored under ``key``. ``reuse`` None: compute everything. Bit-identical to computing all
    when ``compute`` treats each row on its own (damped_ls and :func:`_fix_sigma` do, tested).
    """
    if reuse is None:
        return compute(slice(None))
    x = np.ascontiguousarray(inp(), dtype=float)
    m = x.shape[0]
    same, at = np.zeros(m, dtype=bool), np.zeros(m, dtype=np.intp)
    old = reuse.get(key)
    if old is not None and old[0].size:
        o_rows, o_x, o_out = old
        at = np.minimum(np.searchsorted(o_rows, rows), o_rows.size - 1)
        same = (o_rows[at] == rows) & np.all(o_x[at].view(np.int64) == x.view(np.int64), axis=1)
    todo = np.flatnonzero(~same)
    if todo.size == m:
        out = tuple(compute(slice(None)))
    else:
        out = tuple(a[at] for a in o_out)
        if todo.size:
            for a, b in zip(out, compute(todo), strict=True):
                a[todo] = b
    reuse[key] = (rows, x, out)
    return tuple(a.copy() for a in out)


def _damped(reuse: dict | None, key: tuple, ru: np.ndarray, r: np.ndarray, h, prior,
            config: RangingConfig, rows: np.ndarray | None = None):
    """``tri.damped_ls(ru, r, height_m=h, prior=prior, return_info=True)`` (side and sigma
    from ``config``) for the epoch rows ``rows`` (default all) of r (m, k) m; h None, a scalar
    or (m,) m; prior None or (m, 3) m. ``reuse``: :func:`_memo_rows` (the raw and the gated
    epoch ranges of :func:`localize` differ in a few rows, 0.3 % of the bench's epochs, so
    the second trilateration solves only those)."""
    m = r.shape[0]
    names = tuple(tri.TrilaterationInfo.__dataclass_fields__)

    def solve(sel):
        hs = h if h is None or np.ndim(h) == 0 else h[sel]
        p, info = tri.damped_ls(ru, r[sel], height_m=hs, prior=None if prior is None else
                                prior[sel], side=config.side, sigma_m=config.sigma_range_m,
                                return_info=True)
        return (p, *(getattr(info, f) for f in names))

    def inputs():
        hz = np.broadcast_to(np.nan if h is None else np.asarray(h, dtype=float), (m,))
        return np.column_stack([r, hz, np.full((m, 3), np.nan) if prior is None else prior])
    p, *info = _memo_rows(reuse, key, inputs, np.arange(m) if rows is None else rows, solve)
    return p, tri.TrilaterationInfo(**dict(zip(names, info, strict=True)))


def _sigma_rows(reuse: dict | None, key: tuple, ru: np.ndarray, p: np.ndarray, r: np.ndarray,
                sigma: float, known_z: bool, rows: np.ndarray | None = None) -> np.ndarray:
    """:func:`_fix_sigma` (n, 3) m through :func:`_memo_rows` (``reuse``, ``key``)."""
    return _memo_rows(reuse, key, lambda: np.column_stack([p, r]),
                      np.arange(p.shape[0]) if rows is None else rows,
                      lambda sel: (_fix_sigma(ru, p[sel], r[sel], sigma, known_z),))[0]


def _bounded_fix(ru, rj, p, info, good, config, lo, hi, lz, reuse=None, j=0):
    """Hold the free-height damped fixes of one transmitter j (lever z ``lz``) in [lo, hi]
    (body origin): re-solve the rows :func:`_held_heights` names in known-height mode, the
    free fix as the mirror prior (``reuse``: :func:`_memo_rows`). Returns (positions, info,
    held (n,) bool, the free fixes' geometric stds (n, 3) m)."""
    mid = 0.5 * (lo + hi) if config.fallback_height_m is None else config.fallback_height_m
    s_free = _sigma_rows(reuse, ("sigma free", j), ru, p, rj, config.sigma_range_m, False)
    h = _held_heights(p, s_free[:, 2], good, lo + lz, hi + lz, mid + lz)
    rows = np.flatnonzero(np.isfinite(h))
    held = np.zeros(p.shape[0], dtype=bool)
    if rows.size == 0:
        return p, info, held, s_free
    pk, ik = _damped(reuse, ("held", j), ru, rj[rows], h[rows], p[rows], config, rows)
    out = p.copy()
    out[rows] = pk
    held[rows] = True
    return out, _merge_info(info, ik, rows), held, s_free


def _check_epoch_ranges(ranges: np.ndarray, rec: np.ndarray) -> np.ndarray:
    rr = check_array(ranges, "ranges", allow_nan=True, max_abs=tri.MAX_ABS_M)
    if rr.ndim != 3 or rec.ndim != 2 or rr.shape[2] != rec.shape[0]:
        raise ValueError(f"ranges: expected shape (n, T, {rec.shape[0] if rec.ndim == 2 else 'k'})"
                         f", got {rr.shape}")
    return rr


def trilaterate_epochs(ranges: np.ndarray, receivers: np.ndarray,
                       config: RangingConfig, *, reuse: dict | None = None) -> Fixes:
    """One fix per epoch and transmitter from epoch ranges (n, T, k) m (Appendix C: CMD per
    transmitter; default here: ``damped_ls``). Returns :class:`Fixes`.

    reuse : a dict shared by calls on the same epochs (:func:`localize` passes one to its raw
    and gated fixes): ``damped_ls`` rows and fix stds whose inputs equal the previous call's
    are taken from it, not computed again (bit-identical; :func:`_memo_rows`). It is cleared
    when the receivers, the config or the epoch count differ from the call that filled it.
    """
    rec = check_array(receivers, "receivers", max_abs=tri.MAX_ABS_M)
    rr = _check_epoch_ranges(ranges, rec)
    n, nt, _ = rr.shape
    idx = config.receivers_used
    if idx is None and config.method in _THREE:
        idx = best_triple(rec)
    idx = tuple(range(rec.shape[0])) if idx is None else idx
    if max(idx) >= rec.shape[0]:
        raise ValueError(f"receivers_used: index {max(idx)} for {rec.shape[0]} receivers")
    ru = rec[list(idx)]
    if reuse is not None and reuse.get("context") != (config, ru.tobytes(), n):
        reuse.clear()
        reuse["context"] = (config, ru.tobytes(), n)
    levers = config.levers(nt)
    fn: Callable[..., Any] = tri.METHODS[config.method]
    pos = np.full((n, nt, 3), np.nan)
    sig = np.full((n, nt, 3), np.nan)
    ok = np.zeros((n, nt), dtype=bool)
    infos = []
    known = config.height_m is not None and config.method == "damped_ls"
    bounds = config.height_interval(rec)
    held = np.zeros((n, nt), dtype=bool)
    sm = config.sigma_range_m
    for j in range(nt):
        rj = rr[:, j, list(idx)]
        s_free = None
        if config.method == "damped_ls":
            h = None if not known else config.height_m + levers[j, 2]
            p, info = _damped(reuse, ("free", j), ru, rj, h, None, config)
            if config.mirror == "continuity":
                p = _continuity(p, info)
            good = ~(info.missing | info.bounded | info.degenerate) & info.converged
            if bounds is not None:
                good &= np.all(np.isfinite(p), axis=1)
                p, info, held[:, j], s_free = _bounded_fix(ru, rj, p, info, good, config,
                                                           *bounds, levers[j, 2], reuse, j)
                good = ~(info.missing | info.bounded | info.degenerate) & info.converged
        else:
            p, info = fn(ru, rj, side=config.side, return_info=True)
            good = ~info.missing & info.converged & ~info.degenerate
        good &= np.all(np.isfinite(p), axis=1)
        pos[:, j] = p
        ok[:, j] = good
        hj = held[:, j]
        # a fix left free keeps the std computed for the bound test (same point and ranges)
        sig[:, j] = s_free if s_free is not None else _sigma_rows(
            reuse, ("sigma", j), ru, p, rj, sm, known)
        if bounds is not None and hj.any():    # z held: the bounds' uniform spread
            rows = np.flatnonzero(hj)
            sig[rows, j] = _sigma_rows(reuse, ("sigma held", j), ru, p[rows], rj[rows], sm,
                                       True, rows)
            sig[rows, j, 2] = (bounds[1] - bounds[0]) / math.sqrt(12.0)
        infos.append(info)
    return Fixes(pos, sig, ok, tuple(infos), idx, bounds, held)


# =============================================================================================
# stages 4-5: Kalman on fixes, heading
# =============================================================================================


def filter_fixes(t: np.ndarray, fixes: Fixes, config: RangingConfig, *,
                 sigma_process: float | None = None,
                 sigma_measurement: float | None = None) -> np.ndarray:
    """PV Kalman filter (Appendix C ``RangeKalmanFilter``) per transmitter and axis of the
    usable fixes. t (n,) s; returns (n, T, 3) m, NaN for the first ``kalman_lead_in`` epochs
    (dropped, as Appendix C) and where an axis has no usable fix at all. ``sigma_process``
    and ``sigma_measurement`` override the config (None: config; the config's None: the
    acceleration std and the per-fix geometric stds). An axis whose fixes all have std 0
    (a known height) is passed through. Fixes with ``height_bounds``: the filtered z is
    clipped to them (plus each transmitter's lever z)."""
    if not isinstance(fixes, Fixes):
        raise TypeError(f"fixes: expected Fixes, got {type(fixes).__name__}")
    _check_types(None, config)
    n, nt, _ = fixes.position.shape
    tt = check_increasing_times(t, "t", n=n) if n else np.zeros(0)
    sp = sigma_process if sigma_process is not None else (
        config.kalman_sigma_process if config.kalman_sigma_process is not None
        else config.accel_std_mps2)
    sm_fixed = sigma_measurement if sigma_measurement is not None else \
        config.kalman_sigma_measurement
    lead = config.kalman_lead_in
    out = np.full((n, nt, 3), np.nan)
    if n <= lead:
        return out
    tl = tt[lead:]
    sm: np.ndarray | float
    for j in range(nt):
        z = np.where(fixes.ok[lead:, j, None], fixes.position[lead:, j], np.nan)
        s = fixes.sigma[lead:, j]
        for a in range(3):
            za = z[:, a]
            if not np.isfinite(za).any():
                continue
            if sm_fixed is None:
                sa = np.where(np.isfinite(za), s[:, a], np.nan)
                if np.all(sa[np.isfinite(za)] == 0.0):      # a known coordinate
                    out[lead:, j, a] = np.where(np.isfinite(za), za, np.nanmedian(za))
                    continue
                za = np.where(sa > 0, za, np.nan)
                if not np.isfinite(za).any():
                    continue
                sm = np.where(np.isfinite(za), sa, np.nan)
            else:
                sm = sm_fixed
            out[lead:, j, a] = _pv_kalman(tl, za, sp, sm, config.kalman_gate,
                                          config.relock_after)
    if fixes.height_bounds is not None:      # the filter's z stays where the fixes are held
        lz = config.levers(nt)[:, 2]
        lo, hi = fixes.height_bounds
        out[..., 2] = np.clip(out[..., 2], lo + lz[None, :], hi + lz[None, :])
    return out


def _pv_kalman(t: np.ndarray, z: np.ndarray, sp: float, sm: np.ndarray | float,
               gate: float | None, reinit_after: int) -> np.ndarray:
    """:func:`estimator.kalman.pv_kalman` (the reference, same arguments) with its loop in
    :func:`estimator.range_kernels.pv_run`: the checks and the Appendix C initial state
    (``PVKalman.from_thesis``) once, then the compiled loop. Returns (n,)."""
    if np.ndim(sm) == 0:
        s = np.full(t.size, float(sm))
        s0 = float(sm)
    else:
        s = np.asarray(sm, dtype=float)
        s0 = float(np.nanmedian(s)) if np.isfinite(s).any() else 1.0
        bad = np.isfinite(z) & ~(s > 0)
        if bad.any():
            raise ValueError(f"sigma_measurement: must be > 0 where z is finite, got "
                             f"{s[bad][0]!r}")
    kf = PVKalman.from_thesis(t, z, sp, s0)
    return range_kernels.pv_run(np.asarray(t, float), np.asarray(z, float), s, kf.x[0],
                                kf.x[1], kf.P, kf.sigma_process,
                                math.nan if gate is None else float(gate), int(reinit_after))


def transmitter_heading(front: np.ndarray, rear: np.ndarray, levers: np.ndarray | None = None
                        ) -> np.ndarray:
    """Yaw (rad, (-pi, pi]) of the body from two transmitter positions (..., 3) m: atan2 of
    front - rear (Appendix C) minus the body-frame angle of lever 0 - lever 1 (0 for a front
    and a rear transmitter on the x axis)."""
    yaw = heading_from_points(front, rear)
    if levers is not None:
        d = np.asarray(levers[0], dtype=float) - np.asarray(levers[1], dtype=float)
        yaw = wrap_angle(yaw - math.atan2(d[1], d[0]))
    return yaw


def _body_position(tx_pos: np.ndarray, levers: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Body origin from transmitter positions (n, T, 3): mean over T of p_j - Rz(yaw) l_j."""
    mean_tx = tx_pos.mean(axis=1)                 # NaN if any transmitter is missing
    lm = levers.mean(axis=0)
    if not np.any(lm):
        return mean_tx
    c, s = np.cos(yaw), np.sin(yaw)
    off = np.stack([c * lm[0] - s * lm[1], s * lm[0] + c * lm[1], np.full_like(c, lm[2])], 1)
    return mean_tx - off


# =============================================================================================
# stage 6: tightly coupled range filter
# =============================================================================================


class RangeFilter:
    """Extended Kalman filter updated with one range at a time (not in the thesis).

    State: position (d = 3, or d = 2 with a known height), velocity (d), and, when the
    transmitters sit on lever arms, yaw and yaw rate. Constant-velocity model with continuous
    white acceleration of spectral density ``q = accel_std^2 x 1 s`` per axis (and
    ``yaw_accel_std^2 x 1 s`` for yaw): over dt,
    ``Q = q [[dt^3/3, dt^2/2], [dt^2/2, dt]]`` (Bar-Shalom, Li and Kirubarajan 2001,
    Sec. 6.2.2). Measurement of transmitter j by receiver i: ``h = |p + Rz(yaw) l_j - p_i|``
    (level platform), noise ``sigma_range^2``. A range whose normalised innovation exceeds
    ``gate`` standard deviations is not used (:meth:`update` returns False).

    receivers (k, 3) m; levers (T, 3) m body frame or None; height_m: known z of the body
    origin or None. height_bounds (lo, hi) m and fallback_height_m (None: the middle), free
    z only: the body origin's plausible z interval (:meth:`RangingConfig.height_interval`);
    after every range and at initialisation z is held in it, with the known-height fallback
    where the ranges do not resolve z (:func:`estimator.range_kernels.rf_hold_height`).
    Streaming use: :meth:`initialise`, then :meth:`update` per range in time
    order (a range before the filter's time raises ValueError; equal times are fine);
    :meth:`state_at` extrapolates without changing the filter. Predict and update run in the
    compiled kernels of :mod:`estimator.range_kernels`; ``reference=True`` uses the numpy
    reference (``_predict_reference`` / ``_update_reference``; same results to rounding).
    """

    def __init__(self, receivers: np.ndarray, *, sigma_range_m: float, accel_std_mps2: float,
                 height_m: float | None = None, levers: np.ndarray | None = None,
                 yaw_accel_std: float = 1.0, gate: float = 5.0,
                 height_bounds: tuple[float, float] | None = None,
                 fallback_height_m: float | None = None, reference: bool = False) -> None:
        self.rec = check_array(receivers, "receivers", max_abs=tri.MAX_ABS_M)
        if self.rec.ndim != 2 or self.rec.shape[1] != 3:
            raise ValueError(f"receivers: expected shape (k, 3), got {self.rec.shape}")
        self.R = check_real(sigma_range_m, "sigma_range_m", lo=0.0, lo_open=True, hi=1e8) ** 2
        self.q = check_real(accel_std_mps2, "accel_std_mps2", lo=0.0, lo_open=True, hi=1e8) ** 2
        self.q_yaw = check_real(yaw_accel_std, "yaw_accel_std", lo=0.0, lo_open=True,
                                hi=1e8) ** 2
        self.gate2 = check_real(gate, "gate", lo=0.0, lo_open=True, hi=1e8) ** 2
        self.height = None if height_m is None else check_real(height_m, "height_m",
                                                               lo=-1e8, hi=1e8)
        self.d = 3 if self.height is None else 2
        lev = None if levers is None else check_array(levers, "levers", max_abs=1e3)
        self.levers = lev if lev is not None and np.any(lev) else None
        self.yaw = self.levers is not None
        self.n = 2 * self.d + (2 if self.yaw else 0)
        self.x = np.zeros(self.n)
        self.P = np.eye(self.n)
        self.t = -math.inf
        self.initialised = False
        # constant pieces of F(dt) = I + dt Fd and Q(dt) = a Qa + b Qb + c Qc
        n, d = self.n, self.d
        self._I = np.eye(n)
        self._Fd = np.zeros((n, n))
        self._Qa, self._Qb, self._Qc = np.zeros((n, n)), np.zeros((n, n)), np.zeros((n, n))
        pairs = [(i, i + d, self.q) for i in range(d)]
        if self.yaw:
            pairs.append((2 * d, 2 * d + 1, self.q_yaw))
        for i, j, qq in pairs:
            self._Fd[i, j] = 1.0
            self._Qa[i, i] = qq
            self._Qb[i, j] = self._Qb[j, i] = qq
            self._Qc[j, j] = qq
        self._H = np.zeros(n)
        self._PH = np.zeros(n)
        self._ntx = 1 if self.levers is None else self.levers.shape[0]
        self._lev = np.zeros((self._ntx, 3)) if self.levers is None else \
            np.ascontiguousarray(self.levers, dtype=float)
        self._z = math.nan if self.height is None else self.height
        self._zb = self._height_bounds(height_bounds, fallback_height_m)
        self._reference = bool(reference)

    def _height_bounds(self, bounds, fallback) -> np.ndarray:
        """(lo, hi, fallback z, fallback variance) m, m^2 for free z (NaN: unbounded); the
        fallback variance is the interval's uniform spread (hi - lo)^2 / 12."""
        if bounds is None or self.height is not None:
            return np.full(4, np.nan)
        b = check_array(bounds, "height_bounds", shape=(2,), max_abs=tri.MAX_ABS_M)
        if not b[0] < b[1]:
            raise ValueError(f"height_bounds: expected (lo, hi) m with lo < hi, got {bounds!r}")
        mid = 0.5 * (b[0] + b[1]) if fallback is None else check_real(
            fallback, "fallback_height_m", lo=-tri.MAX_ABS_M, hi=tri.MAX_ABS_M)
        return np.array([b[0], b[1], mid, (b[1] - b[0]) ** 2 / 12.0])

    def initialise(self, t: float, position: np.ndarray, *, position_std: float,
                   speed_std: float, yaw: float = 0.0, yaw_std: float = math.pi) -> None:
        """Start at time t (s) from a position (3,) m with isotropic stds (m, m/s, rad)."""
        t = check_real(t, "t", lo=-_MAX_T, hi=_MAX_T)
        position = check_array(position, "position", shape=(3,), max_abs=tri.MAX_ABS_M)
        for name, v in (("position_std", position_std), ("speed_std", speed_std),
                        ("yaw_std", yaw_std)):
            check_real(v, name, lo=0.0, lo_open=True, hi=1e8)
        yaw = check_real(yaw, "yaw", lo=-1e3, hi=1e3)
        d = self.d
        self.x = np.zeros(self.n)
        self.x[:d] = np.asarray(position, dtype=float)[:d]
        var = [position_std ** 2] * d + [speed_std ** 2] * d
        if self.yaw:
            self.x[2 * d] = yaw
            var += [yaw_std ** 2, 1.0]
        self.P = np.diag(np.asarray(var, dtype=float))
        self.t = float(t)
        self.initialised = True
        if self._reference:
            self._hold_reference()
        else:
            range_kernels.rf_hold_height(self.x, self.P, self._zb)

    def predict(self, t: float) -> None:
        """Propagate the state to time t (s; no-op for t equal to the filter's time).
        ValueError naming ``t`` and the filter's time for a t before it, or before
        :meth:`initialise`."""
        if not self.initialised:
            raise ValueError("predict: the filter is not initialised (call initialise first)")
        self._predict(self._check_time(t))

    def _check_time(self, t: float) -> float:
        """t (s) as a float, not before the filter's time :attr:`t`: a filter cannot go back
        (a range older than the state would be applied as if it were new). Equal times are
        accepted: several ranges measured at one instant (receivers sampled together) are
        applied one after another with no prediction between them."""
        t = check_real(t, "t", lo=-_MAX_T, hi=_MAX_T)
        if t < self.t:
            raise ValueError(f"t: {t!r} s is before the filter's time {self.t!r} s; ranges "
                             "must come in time order (equal times are fine)")
        return t

    def _predict(self, t: float) -> None:
        if self._reference:
            self._predict_reference(t)
            return
        if t > self.t:
            range_kernels.rf_predict(self.x, self.P, t - self.t, self.d, self.yaw, self.q,
                                     self.q_yaw)
            self.t = t

    def _predict_reference(self, t: float) -> None:
        dt = t - self.t
        if dt <= 0:
            return
        F = self._I + dt * self._Fd
        self.x = F @ self.x
        dt2 = dt * dt
        self.P = F @ self.P @ F.T + (dt2 * dt / 3.0) * self._Qa + (dt2 / 2.0) * self._Qb \
            + dt * self._Qc
        self.t = t

    def _tx_point(self, x: np.ndarray, tx: int) -> tuple[np.ndarray, np.ndarray | None]:
        d = self.d
        p = np.empty(3)
        p[:d] = x[:d]
        if d == 2:
            p[2] = self.height
        if not self.yaw:
            return p, None
        lx, ly, lz = self._lev[tx]
        c, s = math.cos(x[2 * d]), math.sin(x[2 * d])
        p[0] += c * lx - s * ly
        p[1] += s * lx + c * ly
        p[2] += lz
        return p, np.array([-s * lx - c * ly, c * lx - s * ly])

    def update(self, t: float, receiver: int, transmitter: int, r: float) -> bool:
        """Predict to t (s, not before the filter's time; equal is fine), then update with
        range r (m, NaN: predict only) of (transmitter, receiver). Returns True if the range
        was used, False if the gate rejected it (or r is NaN). Before :meth:`initialise`, or
        a t before the filter's time: ValueError. Plain float/int arguments in range take a
        fast path; anything else gets the full checks (the same errors)."""
        if not self.initialised:
            raise ValueError("update: the filter is not initialised (call initialise first)")
        if (type(t) in _FLOATS and type(r) in _FLOATS and type(receiver) in _INTS
                and type(transmitter) in _INTS and self.t <= t <= _MAX_T
                and 0.0 <= r <= tri.MAX_ABS_M and 0 <= receiver < self.rec.shape[0]
                and 0 <= transmitter < self._ntx):
            return self._update(float(t), receiver, transmitter, float(r))
        t = self._check_time(t)
        check_int(receiver, "receiver", lo=0, hi=self.rec.shape[0] - 1)
        ntx = 1 if self.levers is None else self.levers.shape[0]
        check_int(transmitter, "transmitter", lo=0, hi=max(ntx - 1, 0))
        if isinstance(r, (float, np.floating)) and math.isnan(r):
            self._predict(t)
            return False
        r = check_real(r, "r", lo=0.0, hi=tri.MAX_ABS_M)
        return self._update(t, int(receiver), int(transmitter), r)

    def _update(self, t: float, receiver: int, transmitter: int, r: float) -> bool:
        if self._reference:
            return self._update_reference(t, receiver, transmitter, r)
        if math.isnan(r):
            self._predict(t)
            return False
        ok = range_kernels.rf_step(self.x, self.P, t - self.t, self.rec, self._lev, receiver,
                                   transmitter, r, self.d, self.yaw, self._z, self.q,
                                   self.q_yaw, self.R, self.gate2, self._H, self._PH, self._zb)
        self.t = max(self.t, t)
        return bool(ok)

    def _update_reference(self, t: float, receiver: int, transmitter: int, r: float) -> bool:
        """numpy reference of the kernel path: predict, range update, height hold."""
        if math.isnan(r):
            self._predict_reference(t)
            return False
        ok = self._range_update_reference(t, receiver, transmitter, r)
        self._hold_reference()
        return ok

    def _hold_reference(self) -> None:
        """numpy reference of :func:`estimator.range_kernels.rf_hold_height`."""
        lo, hi, mid, var = self._zb
        if math.isnan(lo):
            return
        if self.P[2, 2] > (0.5 * (hi - lo)) ** 2:
            g = self.P[2].copy()
            S = self.P[2, 2] + var
            self.x += g / S * (mid - self.x[2])
            self.P -= np.outer(g / S, g)
        z = self.x[2]
        if z < lo or z > hi:
            self.x[2] = lo if z < lo else hi
            if (z < lo and self.x[5] < 0.0) or (z > hi and self.x[5] > 0.0):
                self.x[5] = 0.0

    def _range_update_reference(self, t: float, receiver: int, transmitter: int,
                                r: float) -> bool:
        self._predict_reference(t)
        if math.isnan(r):
            return False
        d = self.d
        p, dyaw = self._tx_point(self.x, transmitter)
        diff = p - self.rec[receiver]
        dist = math.sqrt(diff[0] * diff[0] + diff[1] * diff[1] + diff[2] * diff[2])
        if dist == 0.0:
            return False
        H = self._H
        H[:d] = diff[:d] / dist
        if dyaw is not None:
            H[2 * d] = (diff[0] * dyaw[0] + diff[1] * dyaw[1]) / dist
        PH = self.P @ H
        S = H @ PH + self.R
        nu = r - dist
        if nu * nu > self.gate2 * S:
            return False
        K = PH / S
        self.x += K * nu
        # Joseph-free symmetric update: P - K S K' (= (I - K H) P for the optimal gain)
        self.P -= np.outer(K, PH)
        return True

    def state_at(self, t: float) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
        """(position (3,), velocity (3,), yaw, position std (3,)) extrapolated to time t (s);
        NaN before :meth:`initialise`."""
        if not self.initialised:
            nan3 = np.full(3, np.nan)
            return nan3, nan3.copy(), math.nan, nan3.copy()
        d = self.d
        dt = max(t - self.t, 0.0)
        pos = np.empty(3)
        vel = np.zeros(3)
        pos[:d] = self.x[:d] + dt * self.x[d:2 * d]
        vel[:d] = self.x[d:2 * d]
        std = np.zeros(3)
        i = np.arange(d)
        var = (self.P[i, i] + 2 * dt * self.P[i, i + d] + dt * dt * self.P[i + d, i + d]
               + self.q * dt ** 3 / 3.0)
        std[:d] = np.sqrt(np.maximum(var, 0.0))
        if d == 2:
            pos[2] = self.height
        elif not math.isnan(self._zb[0]):
            pos[2] = min(max(pos[2], self._zb[0]), self._zb[1])
        yaw = float(wrap_angle(self.x[2 * d] + dt * self.x[2 * d + 1])) if self.yaw else math.nan
        return pos, vel, yaw, std


@dataclass(frozen=True)
class TightResult:
    """Output of :func:`tight_filter`.

    t (n,) epoch times s; position (n, 3) m of the body origin (NaN before initialisation),
    velocity (n, 3) m/s, yaw (n,) rad (NaN without lever arms), std (n, 3) m (filter's
    position standard deviation); per stream sample (N,) bool: used (the range updated or
    initialised the filter), gated (rejected by the innovation gate), skipped (not offered:
    Filter 1 rejected it); reinitialised (times s); n_updates (finite ranges in the streams).
    """

    t: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    yaw: np.ndarray
    std: np.ndarray
    used: np.ndarray
    gated: np.ndarray
    skipped: np.ndarray
    reinitialised: tuple
    n_updates: int


#: Consecutive failed initial fixes of :func:`tight_filter` before its attempts are
#: throttled to one per ``max_gap_s``.
_FREE_FIX_ATTEMPTS = 20


def _enough_fresh(latest_t, latest_r, t, max_gap) -> bool:
    """Every transmitter has >= 3 channels with a range at most max_gap (s) old at t."""
    fresh = np.isfinite(latest_r) & (t - latest_t <= max_gap)
    return bool(np.all(fresh.sum(axis=1) >= 3))


def _initial_fix(rec, levers, height, latest_t, latest_r, t, max_gap, sigma, prior=None):
    """A damped fix per transmitter from each channel's newest range at most max_gap old;
    returns (body position (3,), yaw, position std) or None when too few channels report or
    the fix is not usable (degenerate, bounded, or mirror-ambiguous without a prior)."""
    nt = latest_r.shape[0]
    if not _enough_fresh(latest_t, latest_r, t, max_gap):
        return None
    fresh = np.isfinite(latest_r) & (t - latest_t <= max_gap)
    pts = np.full((nt, 3), np.nan)
    stds = []
    for j in range(nt):
        rj = np.where(fresh[j], latest_r[j], np.nan)
        h = None if height is None else height + levers[j, 2]
        p, info = tri.damped_ls(rec, rj, height_m=h, prior=prior, sigma_m=sigma,
                                return_info=True)
        if info.missing or info.degenerate or info.bounded or not np.all(np.isfinite(p)):
            return None
        if info.ambiguous and prior is None:
            return None                      # two mirror points fit: wait for more receivers
        pts[j] = p
        s = _fix_sigma(rec, p[None], rj[None], sigma, height is not None)[0]
        if not np.all(np.isfinite(s)):
            return None
        stds.append(float(np.max(s)))
    yaw = transmitter_heading(pts[0], pts[1], levers) if nt == 2 else 0.0
    body = _body_position(pts[None], levers, np.array([yaw]))[0]
    if height is not None:
        body[2] = height
    return body, float(yaw), max(stds)


#: Fewest range pairs for a verdict of :func:`check_range_geometry`.
_MIN_GEOMETRY_PAIRS = 20


def _geometry_excess(streams: RangeStreams, rec: np.ndarray, config: RangingConfig
                     ) -> np.ndarray:
    """Triangle-inequality excess (m) of each pair of consecutive finite ranges to one
    transmitter from two different receivers i, j at most ``max_gap_s`` apart (dt):
    ``max(|r_i - r_j| - d_ij, d_ij - (r_i + r_j)) - (2 noise_margin + max_speed dt)``,
    d_ij the receivers' distance; <= 0 for ranges of one point in the receivers' unit."""
    fin = np.isfinite(streams.r)
    out = []
    for j in range(streams.n_transmitters):
        idx = np.flatnonzero(fin & (streams.transmitter == j))
        a, b = idx[:-1], idx[1:]
        ra, rb = streams.receiver[a], streams.receiver[b]
        dt = streams.t[b] - streams.t[a]
        keep = (ra != rb) & (dt <= config.max_gap)
        a, b, dt = a[keep], b[keep], dt[keep]
        d = np.linalg.norm(rec[streams.receiver[a]] - rec[streams.receiver[b]], axis=1)
        r1, r2 = streams.r[a], streams.r[b]
        worst = np.maximum(np.abs(r1 - r2) - d, d - (r1 + r2))
        out.append(worst - (2.0 * config.noise_margin + config.max_speed_mps * dt))
    return np.concatenate(out) if out else np.zeros(0)


def check_range_geometry(streams: RangeStreams, receivers: np.ndarray,
                         config: RangingConfig) -> None:
    """Ranges that fit the receivers' geometry, or a ValueError naming ``r``.

    The ranges of one point to receivers i and j obey the triangle inequality,
    ``|r_i - r_j| <= d_ij <= r_i + r_j`` (d_ij the receivers' distance), up to the noise
    (``2 noise_margin``) and the motion between the two samples (``max_speed dt``). Tested
    on each pair of consecutive ranges to one transmitter from two receivers at most
    ``max_gap_s`` apart (:func:`_geometry_excess`): when more than half of at least
    :data:`_MIN_GEOMETRY_PAIRS` pairs break it, the ranges and the receivers are not in
    one unit (millimetre ranges against metre receivers make the range differences ~1000x
    the separations; a filter on them never initialises and tries a fix at every sample).
    Spikes and NLOS ranges are a minority and pass; fewer pairs give no verdict.
    streams : :class:`RangeStreams`; receivers (k, 3) m; config : its noise margin,
    top speed and ``max_gap_s``.
    """
    rec = np.asarray(receivers, dtype=float)
    ex = _geometry_excess(streams, rec, config)
    if ex.size < _MIN_GEOMETRY_PAIRS:
        return
    bad = int(np.count_nonzero(ex > 0))
    if 2 * bad > ex.size:
        raise ValueError(
            f"r: the ranges do not fit the receivers' geometry: {bad} of {ex.size} pairs of "
            "near-simultaneous ranges to one transmitter break the triangle inequality "
            f"(median excess {np.median(ex):.4g} m beyond noise and motion; receivers span "
            f"{_span(rec):.4g} m); are the ranges in millimetres? pass metres "
            "(r_mm * 1e-3), and the receivers in metres too")


def _span(rec: np.ndarray) -> float:
    """Largest distance between two receivers (k, 3), m."""
    d = rec[:, None, :] - rec[None, :, :]
    return float(np.sqrt((d * d).sum(-1)).max()) if rec.size else 0.0


def tight_filter(streams: RangeStreams, receivers: np.ndarray, config: RangingConfig,
                 epochs: np.ndarray, *, rejected: np.ndarray | None = None,
                 reference: bool = False) -> TightResult:
    """Run :class:`RangeFilter` over the streams in time order; report it at the epochs.

    Initialisation: at the first sample when every transmitter has >= 3 receivers with a range
    at most ``max_gap_s`` old and an unambiguous :func:`estimator.trilateration.damped_ls`
    fix per transmitter (position std = twice the fix's geometric std, speed std =
    max_speed).
    Re-initialisation: when ``relock_after`` x (channels) consecutive finite ranges were all
    rejected, the filter has lost the platform and restarts from a fresh damped fix (prior:
    its own position). ``rejected`` (N,): samples to skip (Filter 1's mask when
    ``tight_uses_gate1``). Epoch outputs are causal: the state after every sample at or before
    the epoch, extrapolated to it. Ranges that do not fit the receivers' geometry (e.g.
    millimetres) raise ValueError (:func:`check_range_geometry`). Bounded work: one pass
    over the N samples; an initialisation attempt is one damped fix per transmitter (capped
    at :data:`estimator.trilateration.DLS_MAX_ITER` iterations, ~13 ms when it fails); after
    :data:`_FREE_FIX_ATTEMPTS` consecutive failed fixes, at most one attempt per
    ``max_gap_s`` (the ranges' freshness window) until one succeeds (normal data fail at
    most 2 in a row, measured on the synthetic scenes, so they are never throttled).
    The sample loop runs in :func:`estimator.range_kernels.tight_run` while the filter is
    initialised and not lost (the fixes in Python); ``reference=True``: all in Python with
    the numpy filter (the same results to rounding).
    """
    _check_types(streams, config)
    rec = check_array(receivers, "receivers", max_abs=tri.MAX_ABS_M)
    if rec.ndim != 2 or rec.shape != (streams.n_receivers, 3):
        raise ValueError(f"receivers: expected shape ({streams.n_receivers}, 3), got {rec.shape}")
    check_range_geometry(streams, rec, config)
    te = _check_epochs(epochs)
    nt, k = streams.n_transmitters, streams.n_receivers
    levers = config.levers(nt)
    height = config.height_m
    filt = RangeFilter(rec, sigma_range_m=config.sigma_range_m,
                       accel_std_mps2=config.accel_std_mps2, height_m=height, levers=levers,
                       yaw_accel_std=config.yaw_accel_std, gate=config.tight_gate,
                       height_bounds=config.height_interval(rec),
                       fallback_height_m=config.fallback_height_m, reference=reference)
    n = te.size
    pos = np.full((n, 3), np.nan)
    vel = np.full((n, 3), np.nan)
    yaw = np.full(n, np.nan)
    std = np.full((n, 3), np.nan)
    N = streams.t.size
    used = np.zeros(N, dtype=bool)
    gated = np.zeros(N, dtype=bool)
    latest_t = np.full((nt, k), -np.inf)
    latest_r = np.full((nt, k), np.nan)
    skip = np.zeros(N, dtype=bool) if rejected is None else np.asarray(rejected, dtype=bool)
    if skip.shape != (N,):
        raise ValueError(f"rejected: expected shape ({N},), got {skip.shape}")
    lost_after = config.relock_after * streams.n_channels
    max_gap = config.max_gap
    reinit: list[float] = []
    run = 0
    failed, next_try = 0, -math.inf      # consecutive failed fixes; next allowed attempt (s)
    e = 0
    ts, rs, rxs, txs = streams.t, streams.r, streams.receiver, streams.transmitter
    s = 0
    while s < N:
        if filt.initialised and run < lost_after and not reference:
            # the compiled loop, until the end or a lost filter (see range_kernels.tight_run)
            s, e, run, filt.t = range_kernels.tight_run(
                s, e, ts, rs, rxs, txs, skip, te, filt.x, filt.P, filt.t, filt.rec, filt._lev,
                filt.d, filt.yaw, filt._z, filt.q, filt.q_yaw, filt.R, filt.gate2, filt._zb, run,
                lost_after, latest_t, latest_r, pos, vel, yaw, std, used, gated, filt._H,
                filt._PH)
            if s >= N:
                break
        ti = ts[s]
        while e < n and te[e] < ti:
            if filt.initialised:
                pos[e], vel[e], yaw[e], std[e] = filt.state_at(te[e])
            e += 1
        ri = rs[s]
        s += 1
        if math.isnan(ri):
            continue
        tx, rx = txs[s - 1], rxs[s - 1]
        if skip[s - 1]:
            continue
        latest_t[tx, rx], latest_r[tx, rx] = ti, ri
        if not filt.initialised or run >= lost_after:
            if failed >= _FREE_FIX_ATTEMPTS and ti < next_try:
                continue                          # throttled: see the docstring
            prior = filt.state_at(ti)[0] if filt.initialised else None
            fix = _initial_fix(rec, levers, height, latest_t, latest_r, ti, max_gap,
                               config.sigma_range_m, prior)
            if fix is None:
                if _enough_fresh(latest_t, latest_r, ti, max_gap):   # a fix was tried
                    failed, next_try = failed + 1, ti + max_gap
                continue
            failed = 0
            if filt.initialised:
                reinit.append(float(ti))
            filt.initialise(ti, fix[0], position_std=max(2.0 * fix[2], 1e-6),
                            speed_std=config.max_speed_mps, yaw=fix[1])
            run = 0
            used[s - 1] = True
            continue
        if filt._update(ti, rx, tx, ri):
            used[s - 1] = True
            run = 0
        else:
            gated[s - 1] = True
            run += 1
    while e < n:
        if filt.initialised:
            pos[e], vel[e], yaw[e], std[e] = filt.state_at(te[e])
        e += 1
    yaw = wrap_angle(yaw)                     # the compiled loop leaves yaw unwrapped
    if not filt.yaw:
        yaw[:] = np.nan
    return TightResult(te, pos, vel, yaw, std, used, gated, skip & np.isfinite(rs),
                       tuple(reinit), int(np.isfinite(rs).sum()))


# =============================================================================================
# the whole pipeline
# =============================================================================================


@dataclass(frozen=True)
class RangingResult:
    """Every stage of :func:`localize`.

    config; epochs (n,) s; gate (:class:`GateStage`, per sample); ranges_raw, ranges_gate1,
    ranges (n, T, k) m: epoch ranges before the gates, after Filter 1, after both gates;
    separation_rejected (n, k) bool (Filter 2; all False without it); fixes_raw,
    fixes_gate1, fixes (:class:`Fixes`) from those ranges; kalman (n, T, 3) m per transmitter;
    position (n, 3) m, the body origin from the Kalman-filtered transmitters; heading_fix and
    heading (n,) rad from two transmitters' fixes, raw and Kalman-filtered (NaN with one
    transmitter); tight (:class:`TightResult`).
    """

    config: RangingConfig
    epochs: np.ndarray
    gate: GateStage
    ranges_raw: np.ndarray
    ranges_gate1: np.ndarray
    ranges: np.ndarray
    separation_rejected: np.ndarray
    fixes_raw: Fixes
    fixes_gate1: Fixes
    fixes: Fixes
    kalman: np.ndarray
    position: np.ndarray
    heading_fix: np.ndarray
    heading: np.ndarray
    tight: TightResult
    extra: dict = field(default_factory=dict)


def localize(streams: RangeStreams, receivers: np.ndarray, config: RangingConfig, *,
             epochs: np.ndarray | None = None, tight: bool = True) -> RangingResult:
    """The Appendix C pipeline (gates -> trilateration -> Kalman -> heading) and the tightly
    coupled filter over asynchronous range streams; every stage is returned.

    streams : :class:`RangeStreams` (T transmitters, k receivers); receivers (k, 3) m;
    config : :class:`RangingConfig`; epochs (n,) s, the output times (default: the sample
    times of synchronous streams, else a grid at the median sample interval over the data);
    tight : run the tightly coupled filter (else ``tight`` holds NaN).
    """
    _check_types(streams, config)
    rec = check_array(receivers, "receivers", max_abs=tri.MAX_ABS_M)
    if rec.shape != (streams.n_receivers, 3):
        raise ValueError(f"receivers: expected shape ({streams.n_receivers}, 3), got {rec.shape}")
    check_range_geometry(streams, rec, config)       # before any stage: fail fast
    nt = streams.n_transmitters
    levers = config.levers(nt)
    sync = config.sync or ("sample" if streams.is_synchronous() else "interpolate")
    te = _default_epochs(streams, sync) if epochs is None else _check_epochs(epochs)
    gate = gate_streams(streams, config)
    gap = config.max_gap
    fin = np.isfinite(streams.r)
    raw = epoch_ranges(streams, streams.r, te, sync=sync, max_gap_s=gap)
    if sync == "sample":
        g1 = epoch_ranges(streams, gate.r, te, sync=sync, max_gap_s=gap)
    else:
        g1 = epoch_ranges(streams, streams.r, te, sync=sync, max_gap_s=gap,
                          valid=fin & ~gate.rejected)
    g2 = g1
    sep_rej = np.zeros((te.size, streams.n_receivers), dtype=bool)
    if nt == 2 and config.tx_separation_m is not None and te.size:
        a, b, sep_rej = separation_gate(g1[:, 0, :], g1[:, 1, :], config.tx_separation_m,
                                        mode=config.gate_mode, return_mask=True)
        g2 = np.stack([a, b], axis=1)
    solved: dict = {}          # the gates change few epochs: solve only those again
    fixes_raw = trilaterate_epochs(raw, rec, config, reuse=solved)
    fixes_g1 = trilaterate_epochs(g1, rec, config, reuse=solved)
    fixes = fixes_g1 if g2 is g1 else trilaterate_epochs(g2, rec, config, reuse=solved)
    kal = filter_fixes(te, fixes, config)
    if nt == 2:
        yaw_fix = transmitter_heading(fixes.position[:, 0], fixes.position[:, 1], levers)
        yaw_fix = np.where(fixes.ok.all(axis=1), yaw_fix, np.nan) if config.method == \
            "damped_ls" else yaw_fix
        if np.isfinite(yaw_fix).any() and te.size:
            yaw_f = wrap_angle(cast(np.ndarray, pv_kalman(te, unwrap_angle(yaw_fix),
                                                          config.heading_sigma_process,
                                                          config.heading_sigma_measurement)))
        else:
            yaw_f = np.full(te.size, np.nan)
    else:
        yaw_fix = np.full(te.size, np.nan)
        yaw_f = yaw_fix.copy()
    position = _body_position(kal, levers, np.where(np.isfinite(yaw_f), yaw_f, 0.0)) \
        if te.size else np.zeros((0, 3))
    if tight:
        tr = tight_filter(streams, rec, config, te,
                          rejected=gate.rejected if config.tight_uses_gate1 else None)
    else:
        nan3 = np.full((te.size, 3), np.nan)
        none = np.zeros(streams.t.size, dtype=bool)
        tr = TightResult(te, nan3, nan3.copy(), np.full(te.size, np.nan), nan3.copy(),
                         none, none.copy(), none.copy(), (), 0)
    extra = {"sync": sync, "max_gap_s": gap, "nominal_interval_s": nominal_interval(streams)}
    return RangingResult(config, te, gate, raw, g1, g2, sep_rej, fixes_raw, fixes_g1, fixes,
                         kal, position, yaw_fix, yaw_f, tr, extra)
