"""The naive baseline: no configuration knowledge, the CG as the mean of the CG antennas'
own window means (Eq. 3.8 on raw means), no heading.

Source: 000_8f82f8df647bf685.txt (GPS dissertation), Eq. 3.8 and Section 3.4.1 (windows);
described in :mod:`estimator.tracking` (``method="naive"``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import pandas as pd

from estimator.memo import TrackCache
from estimator.trackers._common import cg_and_heading, frame, settings
from estimator.trackers._windows import DynamicOptions, cumsum_means

__all__ = ["NaiveTracker"]


@dataclass(frozen=True, kw_only=True, eq=False)
class NaiveTracker(DynamicOptions):
    """Naive CG mean (``method="naive"``): a row needs every CG antenna observed at least once
    in its window, else it is NaN with status "insufficient_data" (the mean of a subset is a
    different point of the platform). Options: :class:`DynamicOptions`, :class:`TrackerOptions`.
    """

    name: ClassVar[str] = "naive"

    def track(self, t: Any, obs: Any, config: Any, *, cache: TrackCache | None = None
              ) -> pd.DataFrame:
        """Track a recording: t (n,) s, obs (n, m, 2) m (NaN missing), config a
        :class:`estimator.configuration.SensorConfig`; ``cache``: the recording's cumulative
        sums (``cache.prefix``, shared with the window fits of the same observations)."""
        tt, o, cfg = self._start(t, obs, config)
        rows = self._rows(tt, o, cfg)
        means, cnt = cumsum_means(o, rows.ends, rows.wsize, cache=cache)
        full = np.all(cnt[:, cfg.cg_mask] > 0, axis=1)
        pos = np.where(full[:, None, None], means, np.nan)
        status = np.where(full, "ok", "insufficient_data").astype(object)
        cg, yaw_loc = cg_and_heading(cfg, pos, naive=True)
        st = settings(self.name, self.window, cfg, dyn=self._dynamic, turning=self.turning)
        return frame(tt, o, cfg, rows, pos=pos, cg=cg, yaw=np.full(rows.ends.size, np.nan),
                     yaw_loc=yaw_loc, status=status, extra={}, settings=st,
                     layout_check=self.layout_check)
