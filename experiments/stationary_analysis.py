"""The stationary analysis of Sections 4.5-4.8: whole-recording and sliding-window estimates
of a stationary session under each weighting scheme, scored against the truth.

Source: 000_8f82f8df647bf685.txt (GPS dissertation), Sections 4.5-4.8 (Eq. 3.7, Figs
4.17-4.33). :mod:`experiments.stationary` (the report) and :mod:`experiments.stationary_claims`
(the claims' verdicts) both use these; neither imports the other.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from estimator.configuration import SensorConfig
from estimator.metrics import cg_errors, heading_error, summarize
from estimator.weights import Weighting, deleted_residual_mask, huber_weights, weights_for
from estimator.window import fit_stationary, procrustes_batch, sliding_window_means
from sim.gps import StationarySession

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["WINDOW_SCHEMES", "Scored", "weighting_estimates", "window_estimates",
           "window_spreads"]


#: Sliding-window schemes of Figs 4.25-4.33 (weightings of estimator.weights): no weights,
#: Huff without threshold, Huff with a 3.5 m threshold. Only per-sample weights (none, Huff):
#: they are computed once on the recording and every window shares them.
WINDOW_SCHEMES = ("none", "huff", "huff:3.5")


@dataclass
class Scored:
    """One estimate of the antenna positions and its score against the truth (if known)."""

    scheme: str
    positions: np.ndarray          # (m, 2)
    status: str
    pos_rmse_m: float              # RMS over alive sensors of |p_i - truth_i|
    cg_err_m: float
    yaw_err_deg: float


def _score(positions: np.ndarray, truth: np.ndarray | None, config: SensorConfig,
           alive: np.ndarray) -> tuple[float, float, float]:
    """RMS position error over alive sensors, CG error (Eq. 4.1, Euclidean) and heading
    error (Eq. 4.2, degrees) of one estimate of the antenna positions (estimator.metrics)."""
    if truth is None or not np.isfinite(positions[alive]).all():
        return math.nan, math.nan, math.nan
    e = cg_errors(positions[alive], truth[alive])["euclid"]
    cg = cg_errors(config.cg_from_positions(positions)[None],
                   config.cg_from_positions(truth)[None])["euclid"][0]
    yaw = procrustes_batch(np.stack([positions, truth]), np.tile(alive.astype(float), (2, 1)),
                           config).yaw
    return (summarize(e)["rmse"], float(cg), float(np.degrees(heading_error(yaw[:1], yaw[1:])[0])))


def weighting_estimates(session: StationarySession, config: SensorConfig,
                        rng: np.random.Generator, *, eps: float = 0.01,
                        solver: str = "slsqp") -> list[Scored]:
    """Whole-recording estimate (Eq. 3.7) under each weighting scheme of Section 4.6.

    Schemes: "means" (per-sensor means, no configuration: the baseline), "none" (4.17),
    "huber" (4.18), "huff" (4.19, no threshold), "huber_1_5" / "huber_1_8" (4.20 / 4.21:
    only those two sensors' data), "huff_huber" (4.22, Eq. 3.14), "deleted_residuals"
    (4.23), "random" (control); the weightings' names are those of
    :class:`estimator.weights.Weighting`. obs (n, m, 2) are the session's.
    """
    obs = session.obs
    truth = session.truth_positions
    alive = session.present.any(axis=0)
    out: list[Scored] = []
    means = np.nanmean(np.where(alive[None, :, None], obs, 0.0), axis=0)
    means[~alive] = np.nan
    out.append(Scored("means", means, "ok", *_score(means, truth, config, alive)))

    def only(names: tuple[str, ...]) -> np.ndarray:
        o = obs.copy()
        keep = np.array([n in names for n in session.names])
        o[:, ~keep] = np.nan
        return o

    schemes = {
        "none": (obs, None),
        "huber": (obs, weights_for(obs, config, "huber")),
        "huff": (obs, weights_for(obs, config, "huff")),
        "huber_1_5": (only(("1", "5")), huber_weights(only(("1", "5")))),
        "huber_1_8": (only(("1", "8")), huber_weights(only(("1", "8")))),
        "huff_huber": (obs, weights_for(obs, config, "huff_huber")),
        "deleted_residuals": (obs, deleted_residual_mask(obs).astype(float)),
        "random": (obs, weights_for(obs, config, "random", rng)),
    }
    for name, (o, w) in schemes.items():
        if name.startswith("huber_1") and not {"1", "5", "8"} <= set(session.names):
            continue
        fit = fit_stationary(o, config, weights=w, eps=eps, solver=solver)
        out.append(Scored(name, fit.positions, fit.status,
                          *_score(fit.positions, truth, config, alive)))
    return out


def window_estimates(obs: np.ndarray, config: SensorConfig, s: int, scheme: str
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Sliding-window estimates (Section 3.4.1): window k holds samples k-s+1..k, k >= s-1.

    scheme : a weighting without per-window statistics, "none" or "huff" with or without a
    threshold (e.g. "huff:3.5", :class:`estimator.weights.Weighting`).
    Closed-form procrustes per window on the weighted window means (exact distances; the
    eps slack changes positions by about 1.3 eps, ../shared/notes/window-solvers.md). Huff
    weights (Section 3.3.3) depend on their own sample only, so they are computed once on
    the recording and the windows summed by :func:`estimator.window.sliding_window_means`.
    Returns positions (n-s+1, m, 2) (NaN where a window has insufficient data) and the
    status array.
    """
    if Weighting.parse(scheme).scheme not in ("none", "huff"):
        raise ValueError(f"scheme: {scheme!r} weighs each window by its own statistics; "
                         f"choose 'none' or 'huff[:<threshold>]', e.g. {list(WINDOW_SCHEMES)}")
    w = weights_for(obs, config, scheme)
    means, sw = sliding_window_means(obs, s, w)
    fit = procrustes_batch(means, sw, config)
    return fit.positions, fit.status


def window_spreads(session: StationarySession, config: SensorConfig,
                   sizes: tuple[int, ...] = tuple(range(1, 11)),
                   schemes: tuple[str, ...] = tuple(WINDOW_SCHEMES)) -> tuple[pd.DataFrame, dict]:
    """Spread and accuracy of sliding-window estimates per window size and scheme.

    Per row: ``spread_m`` = RMS over alive sensors and windows of the distance of each
    window estimate from that sensor's mean estimate (the "cluster" of Figs 4.25-4.33);
    ``rmse_m`` = RMS distance from the true position (NaN without truth); ``cg_rmse_m``,
    ``yaw_rmse_deg`` (wrapped), ``insufficient`` = fraction of windows without a fit.
    Also returns the estimates {(scheme, s): positions} for the figures.
    """
    import pandas as pd

    alive = session.present.any(axis=0)
    truth = session.truth_positions
    rows, est = [], {}
    if truth is not None:
        yaw_true = float(procrustes_batch(truth[None], alive[None].astype(float), config).yaw[0])
        cg_true = config.cg_from_positions(truth)
    for scheme in schemes:
        for s in sizes:
            pos, status = window_estimates(session.obs, config, s, scheme)
            est[(scheme, s)] = pos
            ok = status == "ok"
            p = pos[ok][:, alive]
            centre = p.mean(axis=0)
            spread = float(np.sqrt(((p - centre) ** 2).sum(-1).mean()))
            row = {"scheme": scheme, "window": s, "estimates": int(ok.sum()),
                   "insufficient": float(1 - ok.mean()), "spread_m": spread,
                   "rmse_m": math.nan, "cg_rmse_m": math.nan, "yaw_rmse_deg": math.nan}
            if truth is not None:
                d = p - truth[alive]
                row["rmse_m"] = summarize(np.hypot(d[..., 0], d[..., 1]).ravel())["rmse"]
                cg = config.cg_from_positions(pos[ok])
                row["cg_rmse_m"] = summarize(cg_errors(cg, np.broadcast_to(cg_true, cg.shape))
                                             ["euclid"])["rmse"]
                yaw = procrustes_batch(pos[ok], np.tile(alive.astype(float), (ok.sum(), 1)),
                                       config).yaw
                row["yaw_rmse_deg"] = float(np.degrees(summarize(
                    heading_error(yaw, np.full(yaw.shape, yaw_true)))["rmse"]))
            rows.append(row)
    return pd.DataFrame(rows), est
