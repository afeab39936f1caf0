"""Plug-in trackers that fail inside a sweep's cell (tests/test_plugin_sweep.py): one
raises, one returns a table without the protocol's columns."""

from __future__ import annotations

import pandas as pd


class RaisingTracker:
    """Builds fine, fails on every track (a user's estimator that diverges)."""

    def track(self, t, obs, config) -> pd.DataFrame:
        raise RuntimeError("diverged at epoch 3")


class NoYawTracker:
    """Returns a table without the ``yaw`` column the protocol requires."""

    def track(self, t, obs, config) -> pd.DataFrame:
        return pd.DataFrame({"t": t, "cg_x": obs[:, 0, 0], "cg_y": obs[:, 0, 1]})
