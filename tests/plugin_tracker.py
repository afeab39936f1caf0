"""A user's tracker as a plug-in would write it (the protocol of estimator.trackers.base):
no base class, its own options, ``track(t, obs, config) -> DataFrame``.

Per epoch: the CG is the mean of the observed antennas (no configuration knowledge beyond
which antennas there are), the yaw the direction from antenna ``rear`` to antenna ``front``
minus that side's angle in the body frame.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import pandas as pd


@dataclass(frozen=True, kw_only=True)
class MeanTracker:
    """Per-epoch mean of the antennas; yaw from antennas ``rear`` -> ``front`` (0-based
    indices into the configuration's sensors)."""

    rear: int = 0
    front: int = 1

    def __post_init__(self) -> None:
        for name in ("rear", "front"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 0:
                raise ValueError(f"{name}: must be a sensor index >= 0, got {v!r}")
        if self.rear == self.front:
            raise ValueError(f"front: must differ from rear, both {self.rear}")

    def track(self, t, obs, config) -> pd.DataFrame:
        o = np.asarray(obs, dtype=float)[..., :2]
        B = config.body_positions[:, :2]
        d = o[:, self.front] - o[:, self.rear]
        side = B[self.front] - B[self.rear]
        yaw = np.arctan2(d[:, 1], d[:, 0]) - np.arctan2(side[1], side[0])
        yaw = np.arctan2(np.sin(yaw), np.cos(yaw))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)     # epochs with no antenna
            cg = np.nanmean(o, axis=1)
        return pd.DataFrame({"t": np.asarray(t, dtype=float), "cg_x": cg[:, 0],
                             "cg_y": cg[:, 1], "yaw": yaw})


class NotATracker:
    """A class without a track method (for the loader's errors)."""


def not_a_class(t, obs, config):
    """A function, not a class (for the loader's errors)."""
    return


class BadSignature:
    """track takes too few arguments (for the loader's errors)."""

    def track(self, t):
        return None
