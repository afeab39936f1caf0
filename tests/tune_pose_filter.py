"""One-off tuning of the EKF defaults (estimator.pose_filter), kept for reproducibility.

Not a test (pytest does not collect it). Run: ``python tests/tune_pose_filter.py``.
Data: Path 1 (square100) driven by the MuJoCo rover, GPS errors from the default stationary
noise model (models/noise/gps_stationary.toml) built exactly as the sweep builds them
(sim.gps.observe: 4000 s sessions cut after the power failure, a random stretch replayed), four sessions spawned from seed 20261122, which no test and no
sweep preset uses. Criterion: mean Euclidean CG error over the whole path.
"""

from __future__ import annotations

import itertools
import time

import numpy as np

from estimator.configuration import SensorConfig
from estimator.metrics import cg_errors
from estimator.pose_filter import PoseFilterParams
from estimator.tracking import track
from sim.gps import observe
from sim.rover import simulate_rover

SEED = 20261122
N_SESSIONS = 4


def main() -> None:
    cfg = SensorConfig.load("rover_gps8")
    truth = simulate_rover("square100", cfg)
    t = truth.t
    cg = truth.cg[:, :2]
    runs = []
    for child in np.random.SeedSequence(SEED).spawn(N_SESSIONS):
        rng = np.random.default_rng(child)
        # the sweep's observations (sim.gps.observe): a ~4000 s session cut after its power
        # failure, a random stretch replayed onto the truth
        runs.append(observe(truth, cfg, "gps_stationary", rng=rng, session_s=4000.0))

    def score(**kw):
        errs = []
        for obs in runs:
            df = track(t, obs, cfg, **kw)
            k = np.searchsorted(t, df["t"].to_numpy())
            errs.append(np.nanmean(cg_errors(df[["cg_x", "cg_y"]].to_numpy(), cg[k])["euclid"]))
        return float(np.mean(errs))

    print(f"{t.size} epochs x {N_SESSIONS} sessions; mean Euclidean CG error (m) of references:")
    for kw in ({"window": 1}, {"window": 10},
               {"window": 10, "method": "motion_compensated", "yaw_rate": True},
               {"window": 10, "method": "naive"}):
        print(f"  {kw}: {score(**kw):.3f}")
    grids = [
        ("first", [0.5, 1.0, 2.0, 3.0], [0.2, 0.5, 1.0, 2.0], [0.02, 0.05, 0.1, 0.2]),
        ("second (edges extended)", [2.0, 3.0, 4.0, 6.0], [0.5, 1.0, 2.0],
         [0.005, 0.01, 0.02, 0.05]),
    ]
    for name, sms, sas, sys_ in grids:
        rows = []
        t0 = time.perf_counter()
        for sm, sa, sy in itertools.product(sms, sas, sys_):
            p = PoseFilterParams(sigma_meas=sm, sigma_accel=sa, sigma_yaw_accel=sy)
            rows.append((round(score(window=10, method="ekf", filter_params=p), 4), sm, sa, sy))
        rows.sort()
        print(f"{name} grid, {len(rows)} points in {time.perf_counter() - t0:.1f} s; best 5 "
              "(error m, sigma_meas, sigma_accel, sigma_yaw_accel):")
        for r in rows[:5]:
            print("  ", r)
        print("   worst:", rows[-1])

if __name__ == "__main__":
    main()
