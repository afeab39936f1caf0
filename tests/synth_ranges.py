"""Synthetic asynchronous range recordings with the behaviours of real UWB data (for tests).

Each behaviour is a switch of :func:`scenario`, sized like the outdoor UWB recordings in
``../shared/realdata/uwb_hanyang`` (see its README), never fitted to them: negative spike runs
of 2-4 mutually consistent samples (1-19 m), a multi-second dropout on one receiver, a positive
NLOS bias, unsynchronised receivers (own clock offset and jitter), a range lag, and a small
array (about 2 m) with the tag up to ~40 m away.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimator.ranging import RangeStreams

#: anchors like the outdoor UWB array (x, y, z in m): 2 m wide, 1.5 m tall
UWB_ANCHORS = np.array([[2.5775, 0.87, 1.97], [2.5775, -0.87, 1.97], [2.5775, -0.87, 0.5],
                        [0.69, 0.87, 0.5]])
#: a nearly coplanar array: the same footprint, heights within 4 cm
FLAT_ANCHORS = np.array([[2.5775, 0.87, 1.00], [2.5775, -0.87, 1.02], [0.69, -0.87, 0.98],
                         [0.69, 0.87, 1.01]])


@dataclass
class Scenario:
    """A recording: streams, anchors, the truth at any time and what was injected."""

    streams: RangeStreams
    anchors: np.ndarray
    height_m: float
    duration_s: float
    spike: np.ndarray          # (N,) bool: the sample is a spike
    lag_s: float

    x_max_m: float = 40.0

    def truth(self, t: np.ndarray) -> np.ndarray:
        return path(t, self.height_m, self.x_max_m)


def path(t: np.ndarray, height_m: float = 1.0, x_max_m: float = 40.0) -> np.ndarray:
    """A ground tag driving from x = 2 m out to ``x_max_m`` and back in 80 s with lateral
    swings of +/- 4 m: speed <= 1.6 m/s, acceleration <= 0.4 m/s^2 (x_max 40). (n, 3) m."""
    t = np.asarray(t, dtype=float)
    x = 2.0 + 0.5 * (x_max_m - 2.0) * (1.0 - np.cos(2.0 * np.pi * t / 80.0))
    y = 4.0 * np.sin(2.0 * np.pi * t / 20.0)
    return np.stack([x, y, np.full_like(x, height_m)], axis=1)


def scenario(seed: int = 0, *, duration_s: float = 80.0, anchors: np.ndarray = UWB_ANCHORS,
             sigma_m: float = 0.08, rate_hz: float = 10.0, spikes: bool = True,
             dropout: tuple[int, float, float] | None = (2, 30.0, 3.5),
             nlos: tuple[int, float, float, float] | None = (1, 40.0, 55.0, 0.4),
             lag_s: float = 0.2, async_receivers: bool = True,
             height_m: float = 1.0, x_max_m: float = 40.0) -> Scenario:
    """Draw one recording. dropout = (receiver, start s, length s); nlos = (receiver, start s,
    end s, positive bias m); spikes: about one run of 2-4 samples per receiver every 8 s."""
    rng = np.random.default_rng(seed)
    k = anchors.shape[0]
    chans, spike_flags = {}, []
    for j in range(k):
        off = rng.uniform(0.0, 1.0 / rate_hz) if async_receivers else 0.0
        t = off + np.arange(0.0, duration_s, 1.0 / rate_hz)
        if async_receivers:
            t = t + rng.normal(0.0, 0.005, t.size)          # receive jitter
            t = np.sort(t)
        keep = rng.random(t.size) > 0.03                     # scattered single losses
        if dropout is not None and dropout[0] == j:
            keep &= ~((t >= dropout[1]) & (t < dropout[1] + dropout[2]))
        t = t[keep]
        r = np.linalg.norm(path(t - lag_s, height_m, x_max_m) - anchors[j], axis=1)
        r = r + rng.normal(0.0, sigma_m, t.size)
        if nlos is not None and nlos[0] == j:
            r = r + np.where((t >= nlos[1]) & (t < nlos[2]), nlos[3], 0.0)
        flag = np.zeros(t.size, dtype=bool)
        if spikes:
            starts = rng.choice(np.arange(45, t.size - 5), size=max(1, int(duration_s / 8)),
                                replace=False)
            for s0 in starts:
                run = rng.integers(2, 5)
                offset = rng.uniform(1.0, 19.0)
                sl = slice(s0, s0 + run)
                r[sl] = np.maximum(r[sl] - offset, 0.1)      # a consistent negative run
                flag[sl] = True
        chans[j] = (t, np.maximum(r, 0.0))
        spike_flags.append(flag)
    streams = RangeStreams.from_channels(chans, n_receivers=k)
    # from_channels sorts by time (stable): reorder the flags the same way
    order = np.argsort(np.concatenate([c[0] for c in chans.values()]), kind="stable")
    spike = np.concatenate(spike_flags)[order]
    return Scenario(streams, anchors, height_m, duration_s, spike, lag_s, x_max_m)
