"""The ultrasonic quadcopter study of thesis 003 (``python -m experiments.ultrasonic``).

Parts (each writes Markdown + CSV tables and PNG figures to ``--out``, default
``results/local/ultrasonic/``, an untracked folder; only ``--reference`` writes the committed
reference run ``results/ultrasonic/``, with the default spec):

1. Monte Carlo trilateration error analysis (Appendix B): ``--n-mc`` random positions with
   x, y ~ U[-8, 8] m on the plane z = ``--z-plane`` (5 m), the Appendix B receivers centred by
   its T_RCM translation, range noise N(0, 5 mm) (Appendix B: randn * 15 mm / 3); linear and
   nonlinear least squares on all six receivers, CFP and CMD on receivers 43, 44, 45. Per-method
   mean-error and MSE maps on 1 m pixels (Appendix B's FindBIN: positions rounded to the nearest
   bin centre, 17 x 17 pixels) and the thesis's totals (``MSE_Error_Total`` = mean over pixels
   of the per-pixel MSE, per axis and overall).
2. Flight pipeline on the simulated quadcopter (Sections 3.2.2-3.2.3, Appendix C): truth from
   :func:`sim.quadcopter.simulate_quadcopter` on ``quad_square6`` (nose along the path),
   ranges from :mod:`sim.ultrasonic` on the Appendix C layout (centred), then
   raw -> Filter 1 -> Filter 2 -> CMD per transmitter (receivers 41, 42, 45 as Appendix C, or the
   largest-area triple with ``--triple best``) -> PV Kalman per axis (Appendix C's sigmas,
   40-sample lead-in dropped) -> average of the two transmitters -> heading (atan2 of front -
   rear, unwrapped, PV Kalman with 1 deg/s^2, 1 deg as Appendix C), all by
   :func:`estimator.ranging.localize` with :meth:`RangingConfig.appendix_c`; plus its tightly
   coupled range filter and the joint two-transmitter pose under the layout (both not in the
   thesis). Position RMSE per axis and heading RMSE at every
   stage, for the robust gates and the literal thesis gates.
3. Transfer-function identification (Section 3.3) via
   :func:`experiments.identification.run_identification`.

Figures are drawn from the saved tables (``mc_pixels.csv``, ``flight_series.csv``), so
re-plotting never re-simulates. Wall times go to ``timings.json`` (git-ignored), never to the
tracked files, so a rerun of the same code does not dirty the checkout. ``run(...)`` is the
callable entry point; ``main`` parses arguments only.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from estimator.metrics import heading_error, summarize
from estimator.orientation import heading_from_points, unwrap_angle
from experiments.deferred import deferred_attributes
from experiments.markdown import markdown_table
from experiments.provenance import git_describe
from sim.ultrasonic import UltrasonicNoiseModel, load_receivers, simulate_ranges, true_ranges

if TYPE_CHECKING:
    import pandas as pd

    from estimator.ranging import RangingConfig, RangingResult

#: imported where used, not here, so that --help and argument errors answer before
#: pandas / numba / scipy / matplotlib load; still importable from this module
__getattr__ = deferred_attributes(__name__, {
    "pd": ("pandas", None),
    "tri": ("estimator.trilateration", None),
    "RangeStreams": ("estimator.ranging", "RangeStreams"),
    "RangingConfig": ("estimator.ranging", "RangingConfig"),
    "RangingResult": ("estimator.ranging", "RangingResult"),
    "best_triple": ("estimator.ranging", "best_triple"),
    "filter_fixes": ("estimator.ranging", "filter_fixes"),
    "localize": ("estimator.ranging", "localize"),
    "fit_pose": ("estimator.rigid_ranging", "fit_pose"),
    "ufig": ("experiments.ultrasonic_figures", None),
})

REPO = Path(__file__).resolve().parents[1]
#: the committed reference run (written only by ``--reference``)
REFERENCE_OUT = REPO / "results" / "ultrasonic"
#: default output of every other run (git-ignored)
DEFAULT_OUT = REPO / "results" / "local" / "ultrasonic"

MC_METHODS = ("linear_ls", "nonlinear_ls", "nonlinear_ls_reflect", "closed_form",
              "cayley_menger")
MC_LABEL = {"linear_ls": "LS (6 Rx)", "nonlinear_ls": "NLS (6 Rx)",
            "nonlinear_ls_reflect": "NLS (6 Rx), start reflected to z > 0 [not in thesis]",
            "closed_form": "CFP (Rx 43, 44, 45)", "cayley_menger": "CMD (Rx 43, 44, 45)"}
MC_SHORT = {"linear_ls": "LS (6 Rx)", "nonlinear_ls": "NLS (6 Rx)",
            "nonlinear_ls_reflect": "NLS, reflected start*", "closed_form": "CFP (43-45)",
            "cayley_menger": "CMD (43-45)"}
MC_TRIPLE = ("R43", "R44", "R45")           # Appendix B RCM_3
FLIGHT_TRIPLE = ("R41", "R42", "R45")       # Appendix C RCM_3
MM2 = 1e6                                   # m^2 -> mm^2
TIGHT_STAGE = "tightly coupled filter (6 Rx, yaw state) [not in thesis]"
JOINT_STAGE = ("joint 2-Tx pose per epoch (6 Rx, 0.5 m layout; z from the Kalman fixes) "
               "[not in thesis]")
#: height step (m) of the joint fit's epoch groups (one fit_pose call per step, at the group's
#: mean height; 1 mm steps cost 4x the time): a height error moves the planar pose ~2-3x as
#: far (exact ranges, tests), but the steps are small against the Kalman z errors (~2 cm):
#: 1 cm against 1 mm changed the x, y RMSE by 0.06 mm on the default flight
JOINT_Z_STEP_M = 0.01


@dataclass(frozen=True)
class StudySpec:
    """Everything that determines the study's numbers (written to ``spec.json``)."""

    seed: int = 0
    n_mc: int = 100_000
    z_plane_m: float = 5.0                  # Appendix B Z_Plane_Value = 5000 mm
    extent_m: float = 8.0                   # Appendix B Xmin..Xmax = -8000..8000 mm
    bin_m: float = 1.0                      # Appendix B BIN_Size = 1000 mm
    mc_sigma_m: float = 0.005               # Appendix B Sigma = 15 mm / 3
    path: str = "quad_square6"
    yaw_mode: str = "along_path"
    flight_duration_s: float | None = None  # None = the whole path
    noise_model: str = "ultrasonic"
    triple: str = "appendix_c"              # or "best" (largest receiver triangle)
    max_speed_mps: float = 10.0             # Filter 1: 1000 mm per <= 0.1 s sample
    alt_max_speed_mps: float = 2.0          # Filter 1 sized to this flight (cruise 0.5 m/s)
    tx_separation_m: float = 0.5            # Filter 2
    lead_in: int = 40                       # Appendix C Num_Lead_Pts
    kf_sigma_process: float = 0.003         # Appendix C Sigma_Process = 3 (mm)
    kf_sigma_measurement: float = 0.002     # Appendix C Sigma_Measurement = 2 (mm)
    # second Kalman setting sized from physics, not from the truth: the path's acceleration
    # limit (quad_square6 max_lateral_accel_mps2 = 1) and the CMD scatter of a 3-receiver
    # triple from the Monte Carlo (x, y RMSE about 45 mm at 5 m)
    kf2_sigma_process: float = 1.0
    kf2_sigma_measurement: float = 0.05
    heading_sigma_process_deg: float = 1.0  # Appendix C heading filter
    heading_sigma_measurement_deg: float = 1.0


# =============================================================================================
# Part 1: Monte Carlo (Appendix B)
# =============================================================================================


def run_monte_carlo(spec: StudySpec, rng: np.random.Generator) -> dict:
    """Appendix B. Returns {"table": DataFrame, "pixels": DataFrame, "extra": dict}."""
    import pandas as pd

    from estimator import trilateration as tri
    from experiments import ultrasonic_figures as ufig

    names, rec = load_receivers("montecarlo")
    idx3 = [names.index(n) for n in MC_TRIPLE]
    n = spec.n_mc
    P = np.empty((n, 3))
    P[:, :2] = rng.uniform(-spec.extent_m, spec.extent_m, size=(n, 2))
    P[:, 2] = spec.z_plane_m
    noise = rng.normal(0.0, spec.mc_sigma_m, (n, 6))
    R = true_ranges(P[:, None, :], rec)[:, 0, :] + noise
    est, infos, secs = {}, {}, {}
    for m in MC_METHODS:
        kw = {}
        if m == "nonlinear_ls_reflect":
            f, kw = tri.nonlinear_ls, {"reflect_start": True}
        else:
            f = tri.METHODS[m]
        rr, rw = (rec[idx3], R[:, idx3]) if m in ("closed_form", "cayley_menger") else (rec, R)
        t0 = time.perf_counter()
        est[m], infos[m] = f(rr, rw, side=1, return_info=True, **kw)
        secs[m] = time.perf_counter() - t0

    # Appendix B pixels: FindBIN rounds to the nearest BIN_Size -> centres -8..8 (17 x 17)
    nb = round(2 * spec.extent_m / spec.bin_m) + 1
    ix = np.clip(np.rint((P[:, 0] + spec.extent_m) / spec.bin_m).astype(int), 0, nb - 1)
    iy = np.clip(np.rint((P[:, 1] + spec.extent_m) / spec.bin_m).astype(int), 0, nb - 1)
    flat = ix * nb + iy
    count = np.bincount(flat, minlength=nb * nb)
    rows, pix = [], []
    for m in MC_METHODS:
        e = est[m] - P
        sums = np.stack([np.bincount(flat, e[:, a], nb * nb) for a in range(3)], 1)
        sq = np.stack([np.bincount(flat, e[:, a] ** 2, nb * nb) for a in range(3)], 1)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean_e = sums / count[:, None]
            mse = sq / count[:, None]
        # thesis total: sum over pixels of the per-pixel MSE / Num_Pixels (all pixels filled)
        total_axes = np.nanmean(mse, axis=0) * MM2
        info = infos[m]
        rows.append({
            "method": MC_LABEL[m],
            "mse_x_mm2": total_axes[0], "mse_y_mm2": total_axes[1], "mse_z_mm2": total_axes[2],
            "mse_total_mm2": total_axes.sum(),
            "rmse_3d_mm": np.sqrt(np.mean(np.sum(e ** 2, axis=1))) * 1e3,
            "median_err_3d_mm": np.median(np.linalg.norm(e, axis=1)) * 1e3,
            # Appendix B Metric_*_ErrorAvg: mean over pixels of the per-pixel mean error
            "bias_x_mm": np.nanmean(mean_e[:, 0]) * 1e3,
            "bias_y_mm": np.nanmean(mean_e[:, 1]) * 1e3,
            "bias_z_mm": np.nanmean(mean_e[:, 2]) * 1e3,
            "no_intersection_pct": 100.0 * np.mean(info.no_intersection),
            "mirror_side_pct": 100.0 * np.mean(est[m][:, 2] < 0),
            "mean_iterations": float(np.mean(info.iterations)),
            "time_s": secs[m],
        })
        cx = -spec.extent_m + spec.bin_m * (np.arange(nb * nb) // nb)
        cy = -spec.extent_m + spec.bin_m * (np.arange(nb * nb) % nb)
        pix.append(pd.DataFrame({
            "method": m, "x_m": cx, "y_m": cy, "n": count,
            "mean_err_x_mm": mean_e[:, 0] * 1e3, "mean_err_y_mm": mean_e[:, 1] * 1e3,
            "mean_err_z_mm": mean_e[:, 2] * 1e3,
            "mse_x_mm2": mse[:, 0] * MM2, "mse_y_mm2": mse[:, 1] * MM2,
            "mse_z_mm2": mse[:, 2] * MM2, "mse_mm2": mse.sum(axis=1) * MM2}))
    table = pd.DataFrame(rows)
    table["mse_normalized"] = table["mse_total_mm2"] / table["mse_total_mm2"].min()
    extra = {
        "cfp_vs_cmd_max_diff_m": float(np.max(np.abs(est["closed_form"] - est["cayley_menger"]))),
        "receivers_m": rec.tolist(), "names": list(names),
    }
    return {"table": table, "pixels": pd.concat(pix, ignore_index=True), "extra": extra,
            "range_errors": ufig.range_error_counts(noise, list(names))}


# =============================================================================================
# Part 2: flight pipeline (Sections 3.2.2-3.2.3, Appendix C)
# =============================================================================================


def flight_config(spec: StudySpec, triple: tuple[int, ...], mode: str = "robust",
                  max_speed: float | None = None) -> RangingConfig:
    """The Appendix C settings of :meth:`RangingConfig.appendix_c` with this study's values."""
    from estimator.ranging import RangingConfig

    return RangingConfig.appendix_c(
        gate_mode=mode, max_speed_mps=spec.max_speed_mps if max_speed is None else max_speed,
        tx_separation_m=spec.tx_separation_m, lead_in=spec.lead_in,
        kalman_lead_in=spec.lead_in, receivers_used=tuple(triple),
        kalman_sigma_process=spec.kf_sigma_process,
        kalman_sigma_measurement=spec.kf_sigma_measurement,
        heading_sigma_process=np.radians(spec.heading_sigma_process_deg),
        heading_sigma_measurement=np.radians(spec.heading_sigma_measurement_deg))


def _heading(front, rear):
    return heading_from_points(front[..., :2], rear[..., :2])


def _score(stage, gate_mode, est, truth, yaw_est, yaw_true, flags=None):
    """RMSE per axis (m) and of the 3-D error (RMSE, median, max) over the rows with every
    coordinate finite; heading RMSE and max (deg) of the wrapped differences (Eq. 4.2):
    :func:`estimator.metrics.summarize` and :func:`estimator.metrics.heading_error`.
    est, truth : (n, 3) or (n, k, 3) metres (every transmitter's rows pooled)."""
    e = (est - truth).reshape(-1, 3)
    ok = np.all(np.isfinite(e), axis=-1)
    axes = [summarize(np.abs(e[:, a]), ok) for a in range(3)]
    e3 = summarize(np.linalg.norm(np.where(ok[:, None], e, 0.0), axis=1), ok)
    h = summarize(heading_error(yaw_est, yaw_true))
    return {
        "gates": gate_mode, "stage": stage,
        "rmse_x_m": axes[0]["rmse"], "rmse_y_m": axes[1]["rmse"], "rmse_z_m": axes[2]["rmse"],
        "rmse_3d_m": e3["rmse"], "median_3d_m": e3["median"], "max_3d_m": e3["max"],
        "heading_rmse_deg": np.degrees(h["rmse"]), "heading_max_deg": np.degrees(h["max"]),
        "missing_pct": 100.0 * (1 - ok.mean()),
        "no_intersection_pct": np.nan if flags is None else 100.0 * np.mean(flags),
    }


def joint_pose(res: RangingResult, receivers: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Not in the thesis: the pose of the two-transmitter body from all twelve gated epoch
    ranges at once, under the layout (``lever_arms_m``; issue 26), by
    :func:`estimator.rigid_ranging.fit_pose` in its planar mode (x, y, yaw; robust Huber LM,
    mirror checks). Two transmitters fix no roll, so z is not solved jointly: each epoch's
    body height is the mean of the two transmitters' Appendix C Kalman z (``res.kalman``),
    epochs grouped by height in :data:`JOINT_Z_STEP_M` steps (one fit per group at the
    group's mean height). receivers (k, 3) m. Returns position (n, 3) m and yaw (n,) rad, NaN
    where a Kalman z is missing or the fit has no usable pose (status not ``ok``,
    ``mirror_ambiguous`` or ``ambiguous``)."""
    from estimator.rigid_ranging import fit_pose

    n = res.epochs.size
    body = np.asarray(res.config.levers(2), dtype=float)[:, :2]
    z = res.kalman[:, :, 2].mean(axis=1)
    pos, yaw = np.full((n, 3), np.nan), np.full(n, np.nan)
    key = np.round(z / JOINT_Z_STEP_M)
    for k in np.unique(key[np.isfinite(key)]):
        rows = np.flatnonzero(key == k)
        f = fit_pose(receivers, body, res.ranges[rows], origin_z_m=float(z[rows].mean()),
                     dim=2, sigma_m=res.config.sigma_range_m)
        good = np.isin(f.status, ("ok", "mirror_ambiguous", "ambiguous"))
        pos[rows[good], :2] = f.position[good, :2]
        pos[rows[good], 2] = z[rows[good]]
        yaw[rows[good]] = f.yaw[good]
    return pos, yaw


def run_flight(spec: StudySpec, rng: np.random.Generator) -> dict:
    """Appendix C pipeline on the simulated flight. Returns {"table", "series", "extra"}."""
    import pandas as pd

    from estimator.ranging import RangeStreams, best_triple, filter_fixes, localize
    from sim.quadcopter import simulate_quadcopter

    truth = simulate_quadcopter(spec.path, seed=spec.seed, yaw_mode=spec.yaw_mode,
                                duration_s=spec.flight_duration_s)
    t = truth.t
    tx = truth.sensor_positions                      # (n, 2, 3): front, rear
    if tuple(truth.sensor_names) != ("front", "rear"):
        raise ValueError(f"truth.sensor_names: expected ('front', 'rear'), "
                         f"got {truth.sensor_names}")
    names, rec = load_receivers("flight")
    if spec.triple == "appendix_c":
        tri_idx = tuple(names.index(x) for x in FLIGHT_TRIPLE)
    elif spec.triple == "best":
        tri_idx = best_triple(rec)
    else:
        raise ValueError(f"triple: expected 'appendix_c' or 'best', got {spec.triple!r}")
    model = UltrasonicNoiseModel.load(spec.noise_model)
    raw, faults = simulate_ranges(t, tx, rec, model, rng, return_faults=True)
    streams = RangeStreams.from_synchronous(t, raw)
    yaw_true = truth.yaw
    mid_true = tx.mean(axis=1)
    lead = slice(spec.lead_in, None)                 # Appendix C drops Num_Lead_Pts samples

    rows, series = [], {"t": t, "yaw_true": yaw_true}
    for a, ax in enumerate("xyz"):
        series[f"front_true_{ax}"] = tx[:, 0, a]
        series[f"mid_true_{ax}"] = mid_true[:, a]
    for j in range(rec.shape[0]):
        for k, side in enumerate(("front", "rear")):     # T20, T21
            series[f"range_true_{side}_{names[j]}"] = true_ranges(tx, rec)[:, k, j]
            series[f"range_raw_{side}_{names[j]}"] = raw[:, k, j]
    gate_configs = (("robust", spec.max_speed_mps), ("thesis", spec.max_speed_mps),
                    ("robust", spec.alt_max_speed_mps))
    for mode, vmax in gate_configs:
        label = f"{mode}, {vmax:g} m/s"
        cfg = flight_config(spec, tri_idx, mode, vmax)
        res = localize(streams, rec, cfg)
        stages = {"raw": res.fixes_raw, "filter1": res.fixes_gate1, "filter1+2": res.fixes}
        for stage, fx in stages.items():
            pos = fx.position
            flag = np.stack([info.no_intersection for info in fx.info], axis=1)
            yaw = _heading(pos[:, 0], pos[:, 1])
            rows.append(_score(f"{stage} -> CMD", label, pos[lead], tx[lead], yaw[lead],
                               yaw_true[lead], flag[lead]))
            if stage == "filter1":
                rows[-1]["rejected_pct"] = 100.0 * res.gate.rejected.mean()
            if stage == "filter1+2":
                rows[-1]["rejected_pct"] = 100.0 * res.separation_rejected.mean()
        # PV Kalman per axis per transmitter after the lead-in (Appendix C); heading: atan2 of
        # the unfiltered CMD positions, unwrapped, PV Kalman (Appendix C), wrapped back
        yaw_filt = res.heading
        for tag, kal in (("Appendix C sigmas", res.kalman),
                         ("physical sigmas", filter_fixes(
                             t, res.fixes, cfg, sigma_process=spec.kf2_sigma_process,
                             sigma_measurement=spec.kf2_sigma_measurement))):
            kf = kal[lead]
            yaw_kf_pos = _heading(kf[:, 0], kf[:, 1])
            rows.append(_score(f"Kalman per Tx ({tag})", label, kf, tx[lead], yaw_kf_pos,
                               yaw_true[lead]))
            mid = kf.mean(axis=1)
            rows.append(_score(f"mean of 2 Tx ({tag}) + filtered heading", label, mid,
                               mid_true[lead], yaw_filt[lead], yaw_true[lead]))
            if tag == "Appendix C sigmas":
                kf_c, mid_c = kf, mid
        # not in the thesis: every range of all six receivers as it arrives, lever arms of the
        # two transmitters, yaw in the state (estimator.ranging.RangeFilter)
        rows.append(_score(TIGHT_STAGE, label,
                           res.tight.position[lead], mid_true[lead], res.tight.yaw[lead],
                           yaw_true[lead]))
        # not in the thesis: both transmitters' ranges solved jointly under their layout
        jpos, jyaw = joint_pose(res, rec)
        rows.append(_score(JOINT_STAGE, label, jpos[lead], mid_true[lead], jyaw[lead],
                           yaw_true[lead]))
        kf, mid = kf_c, mid_c
        if vmax != spec.max_speed_mps:
            continue
        for j in range(rec.shape[0]):
            series[f"range_{mode}_front_{names[j]}"] = res.ranges[:, 0, j]
        if mode == "robust":
            cmd_pos = res.fixes.position
            for a, ax in enumerate("xyz"):
                series[f"front_cmd_{ax}"] = cmd_pos[:, 0, a]
                series[f"front_kf_{ax}"] = np.r_[np.full(spec.lead_in, np.nan), kf[:, 0, a]]
                series[f"mid_kf_{ax}"] = np.r_[np.full(spec.lead_in, np.nan), mid[:, a]]
            series["yaw_cmd"] = _heading(cmd_pos[:, 0], cmd_pos[:, 1])
            series["yaw_filtered"] = yaw_filt
    table = pd.DataFrame(rows)
    extra = {
        "n_samples": int(t.size), "duration_s": float(t[-1] - t[0]),
        "dt_min_s": float(np.diff(t).min()), "dt_max_s": float(np.diff(t).max()),
        "triple": [names[i] for i in tri_idx],
        "fault_pct": {k: float(100.0 * np.mean(faults == c))
                      for k, c in (("clean", 0), ("spike", 1), ("held", 2), ("dropout", 3))},
        "noise_model": asdict(model),
        "truth_meta_hash": truth.meta.get("hash"),
    }
    return {"table": table, "series": pd.DataFrame(series), "extra": extra}


# =============================================================================================
# figures (from the saved tables only)
# =============================================================================================


def plot_monte_carlo(pixels: pd.DataFrame, out: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    files = []
    methods = list(dict.fromkeys(pixels["method"]))
    for col, title, fname, log in (
            ("mse_mm2", "MSE per 1 m pixel (mm$^2$)", "mc_mse_maps.png", True),
            ("mse_x_mm2", "x MSE per pixel (mm$^2$)", "mc_mse_x_maps.png", True),
            ("mse_z_mm2", "z MSE per pixel (mm$^2$)", "mc_mse_z_maps.png", True),
            ("mean_err_z_mm", "mean z error per pixel (mm)", "mc_mean_err_z_maps.png", False)):
        fig, axes = plt.subplots(1, len(methods), figsize=(4.0 * len(methods), 4.8),
                                 layout="constrained")
        vals = pixels[col].to_numpy()
        if log:
            pos = vals[vals > 0]
            norm = LogNorm(vmin=pos.min(), vmax=pos.max())
        else:
            lim = np.nanmax(np.abs(vals))
            norm = matplotlib.colors.Normalize(vmin=-lim, vmax=lim)
        for ax, m in zip(np.atleast_1d(axes), methods, strict=True):
            d = pixels[pixels["method"] == m]
            xs, ys = np.unique(d["x_m"]), np.unique(d["y_m"])
            grid = d.pivot(index="y_m", columns="x_m", values=col).to_numpy()
            step = xs[1] - xs[0] if xs.size > 1 else 1.0
            im = ax.imshow(grid, origin="lower", norm=norm,
                           cmap="viridis" if log else "RdBu_r",
                           extent=(xs[0] - step / 2, xs[-1] + step / 2,
                                   ys[0] - step / 2, ys[-1] + step / 2))
            ax.set_title(MC_SHORT.get(m, m))
            ax.set_xlabel("x (m)")
            ax.set_ylabel("y (m)")
        fig.colorbar(im, ax=axes, shrink=0.8, label=title)
        fig.suptitle(f"Appendix B Monte Carlo: {title}   (* not in the thesis)")
        p = out / fname
        fig.savefig(p, dpi=110)
        plt.close(fig)
        files.append(p)
    return files


def plot_flight(series: pd.DataFrame, out: Path, receiver_names: list[str]) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = series["t"].to_numpy()
    files = []
    # Fig 3.8: raw vs filtered ranges, front transmitter, six receivers
    fig, axes = plt.subplots(3, 2, figsize=(11, 8), sharex=True, constrained_layout=True)
    for ax, nm in zip(axes.ravel(), receiver_names, strict=True):
        ax.plot(t, series[f"range_raw_front_{nm}"], lw=0.6, color="0.6", label="raw")
        ax.plot(t, series[f"range_thesis_front_{nm}"], lw=0.8, label="filtered (thesis gates)")
        ax.plot(t, series[f"range_robust_front_{nm}"], lw=0.8, label="filtered (robust gates)")
        ax.plot(t, series[f"range_true_front_{nm}"], "k--", lw=0.6, label="truth")
        ax.set_title(f"front Tx - {nm}")
        ax.set_ylabel("range (m)")
    axes[0, 0].legend(fontsize=7)
    for ax in axes[-1]:
        ax.set_xlabel("time (s)")
    fig.suptitle("Ranges before and after Filters 1 and 2 (cf. thesis Fig. 3.8)")
    files.append(out / "flight_ranges.png")
    fig.savefig(files[-1], dpi=110)
    plt.close(fig)
    # Figs 3.9-3.12: position before / after the Kalman filter
    fig, axes = plt.subplots(3, 1, figsize=(10, 8), sharex=True, constrained_layout=True)
    for ax, a in zip(axes, "xyz", strict=True):
        ax.plot(t, series[f"front_cmd_{a}"], lw=0.6, color="0.55", label="CMD (after filters)")
        ax.plot(t, series[f"front_kf_{a}"], lw=1.0, label="after Kalman filter")
        ax.plot(t, series[f"front_true_{a}"], "k--", lw=0.7, label="truth")
        ax.set_ylabel(f"{a} (m)")
        lo, hi = np.nanpercentile(series[f"front_true_{a}"], [0, 100])
        pad = max(0.5, 0.2 * (hi - lo))
        ax.set_ylim(lo - pad, hi + pad)
    axes[0].legend(fontsize=8)
    axes[-1].set_xlabel("time (s)")
    fig.suptitle("Front transmitter position before/after the PV Kalman filter "
                 "(cf. Figs. 3.9-3.12)")
    files.append(out / "flight_position.png")
    fig.savefig(files[-1], dpi=110)
    plt.close(fig)
    # top view
    fig, ax = plt.subplots(figsize=(6, 6), constrained_layout=True)
    ax.plot(series["front_cmd_x"], series["front_cmd_y"], ".", ms=2, color="0.6",
            label="CMD (after filters)")
    ax.plot(series["mid_kf_x"], series["mid_kf_y"], lw=1.0, label="Kalman, mean of 2 Tx")
    ax.plot(series["mid_true_x"], series["mid_true_y"], "k--", lw=0.8, label="truth")
    ax.set_aspect("equal")
    ax.set_xlim(-5, 5)
    ax.set_ylim(-5, 5)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.legend(fontsize=8)
    files.append(out / "flight_xy.png")
    fig.savefig(files[-1], dpi=110)
    plt.close(fig)
    # heading
    fig, ax = plt.subplots(figsize=(10, 4), constrained_layout=True)
    # unwrapped for display (each series from its first sample; all start near 0 here)
    ax.plot(t, np.degrees(unwrap_angle(series["yaw_cmd"].to_numpy())), ".", ms=2,
            color="0.6", label="atan2 of CMD Tx")
    ax.plot(t, np.degrees(unwrap_angle(series["yaw_filtered"].to_numpy())), lw=1.0,
            label="PV Kalman of the unwrapped heading")
    ax.plot(t, np.degrees(unwrap_angle(series["yaw_true"].to_numpy())), "k--", lw=0.8,
            label="truth")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("heading (deg, unwrapped)")
    ax.legend(fontsize=8)
    fig.suptitle("Heading from the two transmitters (Appendix C)")
    files.append(out / "flight_heading.png")
    fig.savefig(files[-1], dpi=110)
    plt.close(fig)
    return files


# =============================================================================================
# driver
# =============================================================================================


def _identification(out: Path, seed: int) -> tuple[pd.DataFrame | None, str]:
    """Part 3: :mod:`experiments.identification` writes its own identification.md/csv,
    series and figures into ``out``; the table is returned for the README."""
    from experiments.identification import run_identification

    return run_identification(out, seed=seed), "ok"


IDENT_COLS = ("axis", "form", "parameter", "unit", "thesis", "thesis_unit", "clean", "noisy",
              "noisy_ci_low", "noisy_ci_high", "noisy_identifiable", "noisy_fit_pct")


def run(out_dir: str | Path = DEFAULT_OUT, spec: StudySpec | None = None, *,
        identification: bool = True, figures: bool = True) -> dict:
    """Run parts 1-3, write tables/figures/README to ``out_dir``; returns the DataFrames and
    timings."""
    import pandas as pd

    from experiments import ultrasonic_figures as ufig

    spec = spec or StudySpec()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    ss = np.random.SeedSequence(spec.seed)
    rng_mc, rng_flight = (np.random.default_rng(s) for s in ss.spawn(2))
    timings = {}

    t0 = time.perf_counter()
    mc = run_monte_carlo(spec, rng_mc)
    timings["monte_carlo_s"] = time.perf_counter() - t0
    mc["table"].drop(columns=["time_s"]).to_csv(out / "mc_table.csv", index=False)
    mc["pixels"].to_csv(out / "mc_pixels.csv", index=False)
    mc["range_errors"].to_csv(out / "mc_range_errors.csv", index=False)

    t0 = time.perf_counter()
    fl = run_flight(spec, rng_flight)
    timings["flight_s"] = time.perf_counter() - t0
    fl["table"].to_csv(out / "flight_stages.csv", index=False)
    fl["series"].to_csv(out / "flight_series.csv", index=False)

    ident, ident_status = (None, "not run (identification=False)")
    if identification:
        t0 = time.perf_counter()
        ident, ident_status = _identification(out, spec.seed)
        timings["identification_s"] = time.perf_counter() - t0

    if figures:
        t0 = time.perf_counter()
        plot_monte_carlo(pd.read_csv(out / "mc_pixels.csv"), out)
        plot_flight(pd.read_csv(out / "flight_series.csv"), out, mc["extra"]["names"])
        ufig.plot_all(out, mc["extra"]["names"], np.asarray(mc["extra"]["receivers_m"]), MC_SHORT)
        timings["figures_s"] = time.perf_counter() - t0

    info = {"spec": asdict(spec), "code_version": git_describe(),
            "monte_carlo": mc["extra"], "flight": fl["extra"],
            "identification": ident_status, "python": sys.version.split()[0],
            "numpy": np.__version__}
    (out / "run_info.json").write_text(json.dumps(info, indent=2, default=float) + "\n")
    timings["monte_carlo_by_method_s"] = dict(zip(mc["table"]["method"], mc["table"]["time_s"]))
    (out / "timings.json").write_text(json.dumps(timings, indent=2, default=float) + "\n")
    _write_markdown(out, spec, mc, fl, ident, ident_status)
    return {"mc": mc["table"], "flight": fl["table"], "identification": ident,
            "timings": timings, "info": info}


def _write_markdown(out, spec, mc, fl, ident, ident_status) -> None:
    mct = mc["table"].drop(columns=["time_s"])
    flt = fl["table"].copy()
    (out / "mc_table.md").write_text(markdown_table(mct) + "\n")
    (out / "flight_stages.md").write_text(markdown_table(flt) + "\n")
    ex = fl["extra"]
    best = mct.loc[mct["mse_total_mm2"].idxmin(), "method"]
    lines = [
        "# Ultrasonic quadcopter study (thesis 003)",
        "",
        ("Generated by `python -m experiments.ultrasonic` "
        f"(code at commit `{git_describe()}`, seed {spec.seed}); every number below is "
        "measured by that run (wall times are in the untracked `timings.json`)."),
        "",
        (f"## 1. Monte Carlo trilateration (Appendix B), {spec.n_mc} points, z = "
        f"{spec.z_plane_m} m, sigma = {spec.mc_sigma_m * 1e3:g} mm"),
        "",
        ("Totals as Appendix B computes them: mean over the 1 m pixels of the per-pixel MSE "
        "(mm^2), per axis and summed. `mirror_side_pct`: estimates below the receivers' plane "
        "(z < 0, the wrong mirror solution)."),
        "",
        markdown_table(mct),
        "",
        (f"Lowest total MSE: **{best}**. CFP and CMD solve the same three sphere equations; "
        f"their estimates differ by at most {mc['extra']['cfp_vs_cmd_max_diff_m']:.2e} m "
        "(rounding)."),
        "",
        ("Thesis comparison: the thesis text available here prints no numeric MSE values for "
        "the Monte Carlo (its Chapter 2 results are not in the extract); it states that the "
        "CMD method was \"determined to be the most accurate and robust\" (Section 3.2.3, "
        "Chapter 4). See the discussion below."),
        "",
        ("Figures: `mc_mse_maps.png`, `mc_mse_x_maps.png`, `mc_mse_z_maps.png`, "
        "`mc_mean_err_z_maps.png`; Appendix B's own figures: `appB_bias_quiver.png` (x+y MSE "
        "contour with the per-pixel mean x/y error as arrows), `appB_mse_normalized.png` (total "
        "MSE / smallest per method), `appB_range_error_hist.png` (simulated range errors per "
        "receiver, counts in `mc_range_errors.csv`)."),
        "",
        (f"## 2. Flight pipeline on the simulated quadcopter ({spec.path}, "
        f"{ex['n_samples']} samples over {ex['duration_s']:.1f} s, intervals "
        f"{ex['dt_min_s']:.3f}-{ex['dt_max_s']:.3f} s)"),
        "",
        f"Receivers {', '.join(ex['triple'])} (CMD), Appendix C flight layout centred under "
        f"the square. Range faults in this run (% of samples): "
        + ", ".join(f"{k} {v:.2f}" for k, v in ex["fault_pct"].items())
        + f". Filter 1 {spec.max_speed_mps:g} m/s, Filter 2 {spec.tx_separation_m:g} m; Kalman "
        f"sigma_process {spec.kf_sigma_process * 1e3:g} mm/s^2, sigma_measurement "
        f"{spec.kf_sigma_measurement * 1e3:g} mm (Appendix C); heading filter "
        f"{spec.heading_sigma_process_deg:g} deg/s^2, {spec.heading_sigma_measurement_deg:g} "
        f"deg. The first {spec.lead_in} samples (Appendix C lead-in) are excluded from all "
        "scores. Positions in metres, headings in degrees.",
        "",
        markdown_table(flt),
        "",
        ("Figures: `flight_ranges.png` (Fig. 3.8), `flight_position.png` (Figs. 3.9-3.12), "
        "`flight_xy.png`, `flight_heading.png`, `fig3_07_range_change_T20.png` / `_T21.png` "
        "(Fig. 3.7: change in consecutive raw ranges, Filter 1's 1000 mm cut-off), "
        "`fig3_2_2_tx_difference.png` (raw T20 - T21 range per receiver, Filter 2's 500 mm)."),
        "",
        "## 3. Transfer-function identification (Section 3.3)",
        "",
    ]
    if ident is not None:
        cols = [c for c in IDENT_COLS if c in ident.columns]
        lines += [("From `experiments.identification.run_identification` (full report in "
                  "`identification.md`, figures `identification_<axis>.png`). The simulator's "
                  "units differ from the thesis's (mm and normalised stick), so gains are not "
                  "comparable in value; time constants and delays are."), "",
                  markdown_table(ident[cols]), ""]
    else:
        lines += [f"Part 3 {ident_status}.", ""]
    lines += _discussion(spec, mct, flt)
    (out / "README.md").write_text("\n".join(lines) + "\n")


def _discussion(spec: StudySpec, mct: pd.DataFrame, flt: pd.DataFrame) -> list[str]:
    """Comparison with the thesis; every number is read from this run's tables."""
    m = mct.set_index("method")
    ls, nls = m.loc[MC_LABEL["linear_ls"]], m.loc[MC_LABEL["nonlinear_ls"]]
    nlr, cmd = m.loc[MC_LABEL["nonlinear_ls_reflect"]], m.loc[MC_LABEL["cayley_menger"]]

    def row(gates, stage):
        d = flt[(flt["gates"] == gates) & (flt["stage"] == stage)]
        return d.iloc[0]

    g10 = f"robust, {spec.max_speed_mps:g} m/s"
    gth = f"thesis, {spec.max_speed_mps:g} m/s"
    g2 = f"robust, {spec.alt_max_speed_mps:g} m/s"
    raw = row(g10, "raw -> CMD")
    out = [
        "## Discussion: what matches the thesis and what does not",
        "",
        ("**Monte Carlo ranking.** The thesis judged CMD the most accurate and robust method "
        "and used it for the flights. This run agrees among the thesis's four methods: "
        f"CMD/CFP total MSE {cmd['mse_total_mm2']:.4g} mm^2 against "
        f"{nls['mse_total_mm2']:.4g} (NLS) and {ls['mse_total_mm2']:.4g} (LS). The reason is "
        "geometric, not numerical: the Appendix B receivers differ in height by only 22 mm, "
        "so the linear least-squares z is nearly unobservable (LS z MSE "
        f"{ls['mse_z_mm2']:.4g} mm^2, {ls['mirror_side_pct']:.2f} % of its estimates below "
        "the array), and Gauss-Newton started there converges to the mirror solution for "
        f"{nls['mirror_side_pct']:.2f} % of the points, whose ~10 m errors dominate its MSE. "
        "CFP and CMD are the same three-sphere solution (they agree to rounding, see above); "
        "any CFP/CMD difference in the thesis must come from its implementation (complex "
        "intermediates, the Lambda/zeta re-expression), not from the method."),
        "",
        ("**Not in the thesis.** Mirroring the linear start to the platform side before "
        "Gauss-Newton (`nonlinear_ls(..., reflect_start=True)`) removes every mirror solution "
        f"and makes the six-receiver NLS the best estimator: total "
        f"{nlr['mse_total_mm2']:.4g} mm^2, "
        f"{100 * (1 - nlr['mse_total_mm2'] / cmd['mse_total_mm2']):.0f} % "
        "below CMD. The thesis's conclusion holds for its NLS implementation, not for "
        "least squares as such."),
        "",
        ("**Flight pipeline.** The thesis shows the filters and Kalman filter only as figures "
        "(3.8-3.12), with no error numbers (its flights had no ground truth), so the table "
        f"above is new. Raw ranges with spikes give CMD positions with a 3-D RMSE of "
        f"{raw['rmse_3d_m']:.3g} m (max {raw['max_3d_m']:.3g} m): three receivers about 1 m "
        "apart seen from 2.5 m amplify range errors by an order of magnitude (median 3-D "
        f"error {raw['median_3d_m']:.3g} m from 5 mm range noise). With the thesis's "
        f"10 m/s Filter 1 and 0.5 m Filter 2 the RMSE drops to "
        f"{row(gth, 'filter1+2 -> CMD')['rmse_3d_m']:.3g} m (literal gates) and "
        f"{row(g10, 'filter1+2 -> CMD')['rmse_3d_m']:.3g} m (robust gates); with Filter 1 sized "
        f"to this flight ({spec.alt_max_speed_mps:g} m/s) to "
        f"{row(g2, 'filter1+2 -> CMD')['rmse_3d_m']:.3g} m. 10 m/s lets spikes of up to 1 m "
        "per 0.1 s through, and every one is amplified by CMD."),
        "",
        ("**Receivers.** Appendix C sets RCM_3 = [Rx41; Rx42; Rx45] and builds T20's ranges "
         "from R41, R42, R45, but T21's from [T21R42, T21R42, T21R45] (R42 twice), which "
         "would place T21 with a wrong range; that looks like a typo and both transmitters "
         "use R41, R42, R45 here."),
        "",
        ("**Kalman filter.** Appendix C's sigmas (3 mm/s^2 process, 2 mm measurement) make a "
        "very stiff constant-velocity filter; on this 0.5 m/s square it lags at the corners "
        "(x RMSE "
        f"{row(g2, 'Kalman per Tx (Appendix C sigmas)')['rmse_x_m']:.3g} m vs "
        f"{row(g2, 'filter1+2 -> CMD')['rmse_x_m']:.3g} m before the filter) while it removes "
        "most of the z noise. Sigmas sized from physics (process = the path's 1 m/s^2 "
        "acceleration limit, measurement = the Monte Carlo's ~50 mm CMD scatter) give "
        f"{row(g2, 'mean of 2 Tx (physical sigmas) + filtered heading')['rmse_3d_m']:.3g} m "
        "3-D RMSE for the mean of the two transmitters."),
        "",
        ("**Heading.** atan2 of two transmitters only 0.5 m apart turns their few-cm position "
        "errors into a heading RMSE of "
        f"{row(g2, 'filter1+2 -> CMD')['heading_rmse_deg']:.3g} deg (filtered ranges, CMD); "
        "the Appendix C heading Kalman filter (1 deg/s^2, 1 deg, on the unwrapped angle) gives "
        f"{row(g2, 'mean of 2 Tx (Appendix C sigmas) + filtered heading')['heading_rmse_deg']:.3g}"
        " deg RMSE; the heading of the Kalman-filtered transmitter positions (physical "
        f"sigmas) {row(g2, 'Kalman per Tx (physical sigmas)')['heading_rmse_deg']:.3g} deg. "
        "The thesis filtered the raw (wrapped) heading in degrees, which jumps by 360 deg "
        "when the heading crosses +/-180 deg; here it is unwrapped first."),
        "",
        ("**Tightly coupled filter (not in the thesis).** Updating one constant-velocity state "
        "with every range of all six receivers as it arrives (lever arms of the two "
        "transmitters, yaw in the state, each range gated on its innovation; "
        "`estimator.ranging.RangeFilter`) gives "
        f"{row(g10, TIGHT_STAGE)['rmse_3d_m']:.3g} m 3-D RMSE and "
        f"{row(g10, TIGHT_STAGE)['heading_rmse_deg']:.3g} deg heading RMSE, against "
        f"{row(g10, 'mean of 2 Tx (physical sigmas) + filtered heading')['rmse_3d_m']:.3g} m "
        "and "
        f"{row(g10, 'mean of 2 Tx (Appendix C sigmas) + filtered heading')['heading_rmse_deg']:.3g}"
        " deg for the Appendix C chain behind the same gates: it uses six receivers instead of "
        "three, and the "
        "heading comes from the geometry of all twelve ranges rather than from the difference "
        "of two noisy fixes 0.5 m apart."),
        "",
        ("**Joint two-transmitter pose (not in the thesis).** Both transmitters' gated ranges "
        "to all six receivers solved at once for (x, y, yaw) under the 0.5 m layout "
        "(`estimator.rigid_ranging.fit_pose`, robust Huber Levenberg-Marquardt, per epoch, "
        "no filter; the height from the Appendix C Kalman z, since two transmitters fix no "
        "roll) gives "
        f"{row(g10, JOINT_STAGE)['rmse_3d_m']:.3g} m 3-D RMSE and "
        f"{row(g10, JOINT_STAGE)['heading_rmse_deg']:.3g} deg heading RMSE (max "
        f"{row(g10, JOINT_STAGE)['heading_max_deg']:.3g} deg), against the thesis's "
        "per-transmitter fixes + heading behind the same gates, "
        f"{row(g10, 'filter1+2 -> CMD')['rmse_3d_m']:.3g} m and "
        f"{row(g10, 'filter1+2 -> CMD')['heading_rmse_deg']:.3g} deg unfiltered, "
        f"{row(g10, 'mean of 2 Tx (Appendix C sigmas) + filtered heading')['heading_rmse_deg']:.3g}"
        " deg with the heading filter; the tightly coupled filter, which also carries the "
        "motion between epochs, stays best. A range spike that passes the gates still throws "
        "a single epoch's joint heading (the max); the filter's innovation gate stops it."),
        "",
        ("**Assumptions.** The range fault rates (spikes 1 %, stale 3 %, dropouts 2 % in "
        "bursts) are not given in the thesis (see `models/noise/ultrasonic.toml`); the flight "
        "layout is Appendix C's, centred under the square; the truth is the MuJoCo quadcopter "
        "of `sim.quadcopter`, not the F450 flights."),
        "",
    ]
    return out


def main(argv: list[str] | None = None) -> int:
    from experiments.cli import ArgumentParser, finite_float, seed_arg

    ap = ArgumentParser(prog="python -m experiments.ultrasonic", description=__doc__,
                        formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default=None,
                    help="output folder (default results/local/ultrasonic/, untracked)")
    ap.add_argument("--reference", action="store_true",
                    help="regenerate the committed reference run results/ultrasonic/ "
                         "(default spec only)")
    ap.add_argument("--n-mc", type=int, default=StudySpec.n_mc)
    ap.add_argument("--z-plane", type=finite_float, default=StudySpec.z_plane_m,
                    help="height (m) of the Monte Carlo slice (Appendix B: 5 m)")
    ap.add_argument("--seed", type=seed_arg, default=0)
    ap.add_argument("--triple", choices=("appendix_c", "best"), default="appendix_c")
    ap.add_argument("--quick", action="store_true",
                    help="smoke run: 5000 Monte Carlo points, 20 s of flight, no identification")
    ap.add_argument("--no-identification", action="store_true")
    args = ap.parse_args(argv)
    if args.n_mc < 1:
        ap.error(f"--n-mc: must be >= 1, got {args.n_mc}")
    spec = StudySpec(seed=args.seed, n_mc=5000 if args.quick else args.n_mc,
                     z_plane_m=args.z_plane, triple=args.triple,
                     flight_duration_s=20.0 if args.quick else None)
    if args.reference:
        if spec != StudySpec() or args.no_identification or args.out is not None:
            ap.error("--reference regenerates results/ultrasonic/ with the default spec; it "
                     "takes no --out, --quick, --n-mc, --z-plane, --seed, --triple or "
                     "--no-identification")
        out = REFERENCE_OUT
    else:
        out = Path(args.out) if args.out is not None else DEFAULT_OUT
    res = run(out, spec, identification=not (args.quick or args.no_identification))
    import pandas as pd

    pd.set_option("display.width", 200)
    print(res["mc"].to_string(index=False))
    print(res["flight"].to_string(index=False))
    print("timings:", {k: round(v, 2) for k, v in res["timings"].items()
                       if isinstance(v, float)})
    print(f"written to {out}")
    return 0


if __name__ == "__main__":
    from experiments.cli import run as run_cli

    run_cli(main)
