"""Sensitivity of the pose filter to its derived parameters, kept for reproducibility.

Not a test (pytest does not collect it) and not a tuning: every parameter of the filter is
derived (process noise from the platform's limits, noise levels from the data through the
configuration, estimator.pose_filter), and nothing here feeds back into a default. It
shows how far each derived value is from the best multiple of itself on data no test or
preset uses, so a reader can judge the derivations. Run: ``python tests/tune_pose_filter.py``
(about a minute per path on this 2-core machine).

Data: Path 1 (square100) and the car-like case (car_block), observations built exactly as
the sweep builds them (sim.gps.observe: 4000 s sessions cut after the power failure, a
random stretch replayed), four sessions spawned from seed 20261122. For each derived
quantity (the acceleration and yaw-acceleration limits behind the process noise, the fix
and displacement noise levels) the filter runs with that quantity times 0.5, 1 and 2, the
others as derived; criterion printed: heading RMS (degrees) of the causal filter and of the
RTS smoother, and the mean Euclidean CG error (m).
"""

from __future__ import annotations

import time

import numpy as np

from estimator.configuration import SensorConfig
from estimator.metrics import cg_errors, heading_error, summarize
from estimator.pose_filter import PoseFilterParams, estimate_noise, run_pose_filter
from estimator.pose_smoother import rts_smooth
from sim.gps import observe
from sim.rover import simulate_rover

SEED = 20261122
N_SESSIONS = 4
CASES = (("square100", "rover_gps8", "gps_stationary"), ("car_block", "car_rtk4", "gps_rtk"))


def _score(truth, runs, off, params):
    """Heading RMS (degrees) of the causal filter and of the RTS smoother and the mean
    Euclidean CG error (m) over every session's epochs with a state (estimator.metrics)."""
    hf, hs, eu = [], [], []
    for obs in runs:
        res = run_pose_filter(truth.t, obs, off, params)
        ok = np.isfinite(res.states[:, 0])
        sm = rts_smooth(res, params.reverse).states
        hf.append(heading_error(res.states[ok, 2], truth.yaw[ok]))
        hs.append(heading_error(sm[ok, 2], truth.yaw[ok]))
        eu.append(cg_errors(res.cg()[ok], truth.cg[ok, :2])["euclid"])
    return (float(np.degrees(summarize(np.concatenate(hf))["rmse"])),
            float(np.degrees(summarize(np.concatenate(hs))["rmse"])),
            summarize(np.concatenate(eu))["mean"])


def main() -> None:
    for path, config, noise in CASES:
        cfg = SensorConfig.load(config).planar()
        truth = simulate_rover(path, cfg)
        off = cfg.body_positions - cfg.cg_body
        runs = [np.array(observe(truth, cfg, noise, rng=np.random.default_rng(child),
                                 session_s=4000.0))
                for child in np.random.SeedSequence(SEED).spawn(N_SESSIONS)]
        sa, ss = (float(np.median(v)) for v in zip(*(estimate_noise(o, off) for o in runs)))
        base = PoseFilterParams.from_limits(
            truth.meta["params"]["controller"],
            no_slip_point_m=tuple(truth.meta.get("no_slip_point_m", (0.0, 0.0))))
        print(f"{path} ({config}, {noise}): {truth.n} epochs x {N_SESSIONS} sessions; "
              f"derived: a_max {base.max_accel_mps2}, alpha_max "
              f"{base.max_yaw_accel_radps2}, sigma_abs ~{sa:.4f} m, sigma_step ~{ss:.4f} m")
        t0 = time.perf_counter()
        for field, value in (("max_accel_mps2", base.max_accel_mps2),
                             ("max_yaw_accel_radps2", base.max_yaw_accel_radps2),
                             ("sigma_abs_m", sa), ("sigma_step_m", ss)):
            for f in (0.5, 1.0, 2.0):
                kw = {field: value * f}
                if field.startswith("sigma"):
                    kw = {"sigma_abs_m": sa, "sigma_step_m": ss, **kw}
                p = PoseFilterParams(**{**base.__dict__, **kw})
                h_f, h_s, e = _score(truth, runs, off, p)
                print(f"  {field} x {f:<3}: heading RMS causal {h_f:6.2f} deg, RTS "
                      f"{h_s:6.2f} deg, CG error {e:.3f} m")
        print(f"  ({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
