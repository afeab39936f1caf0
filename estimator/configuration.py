"""Sensor configurations: names, body-frame mounting positions, dead sensors, CG members.

The configuration is the "known sensor configuration" of the GPS dissertation
(000_8f82f8df647bf685.txt, Section 3.1.1): the pairwise distances a_ij between sensors
are what the window fit constrains (Eq. 3.7, 3.9), and the centre of gravity is the mean
of a chosen subset of sensors (Eq. 3.8).

Body frame: x forward, y left, z up, metres. "Forward" is a physical promise, not a
convention of the file: the lag correction (Section 3.4.2, ``lag_correction="pose"``
shifts along the body +x axis), the EKF's motion model (velocity along body +x, started
from the course) and the turn detector read the body +x axis as the direction of travel.
A layout whose +x points sideways or backwards, or a mirror image of the real one, fits
the window (distances are the same) but corrupts heading and every forward-based step;
:func:`estimator.layout_check.check_layout` (run by ``track``) tests both on the data.

TOML format (see models/configs/)::

    name = "rover_gps8"
    description = "..."
    mount_height_m = 0.9          # optional, height of 2-D sensors above ground (simulation)
    cg_sensors = ["2", "3", "6", "7"]   # optional, default: all sensors
    dead = ["4"]                  # optional, sensors that never report

    [platform]                    # optional: the carrier's limits (SI units), see below
    max_speed_mps = 2.0
    max_accel_mps2 = 0.5
    max_turn_rate_radps = 0.8

    [[sensor]]
    name = "1"
    position_m = [0.75, 0.5]      # 2 or 3 numbers, the same count for every sensor

``[platform]``: speed (m/s), longitudinal acceleration (m/s^2) and turn-rate (rad/s)
limits of the vehicle carrying the layout, required when the block is given, and
optionally ``max_yaw_accel_radps2``, ``max_lateral_accel_mps2``, ``max_jerk_mps3``
(:class:`estimator.platform.PlatformLimits`, which validates them). The pose filter takes
its process noise and gates from them; absent (``config.platform is None``), the filter
estimates them from the data (issue 25). A recording's own ``[platform]`` block
(:func:`sim.recording.load_recording`) takes precedence over the configuration's.

Layouts known only by measured pairwise distances: :meth:`SensorConfig.from_distances`
(tolerance in metres, forward axis and handedness from named antennas or from one observed
set of positions with a known heading); :meth:`SensorConfig.to_dict` writes the result in
the TOML structure above.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np

from estimator._checks import check_int, check_real
from estimator.model_files import MODELS_DIR, read_model_toml
from estimator.platform import PlatformLimits

__all__ = [
    "CONFIGS_DIR",
    "DISTANCE_TOL_M",
    "MAX_BODY_M",
    "MAX_DISTANCE_SENSORS",
    "MODELS_DIR",
    "ConfigError",
    "LayoutWarning",
    "SensorConfig",
    "platform_from_table",
]

CONFIGS_DIR = MODELS_DIR / "configs"

#: Largest body-frame coordinate and pairwise distance accepted, metres. A rigid platform
#: larger than 1000 km is not a platform; the bound keeps squared coordinates (<= 1e12 m^2)
#: far from float overflow, so distances, MDS and every fit stay finite.
MAX_BODY_M = 1e6

#: Default tolerance of :meth:`SensorConfig.from_distances`, metres: the largest accepted
#: asymmetry, diagonal entry and embedding residual (triangle excess: 3x). Measured antenna
#: distances carry centimetre errors: distances between RTK-fixed positions (the u-blox
#: ZED-F9P reports 0.0141 m horizontal accuracy in ../shared/realdata/hazer/tumbleweed, and
#: its repeat fixes of one surveyed corner differ by 5-10 mm, HOME/20200526/notes.txt) have
#: a standard deviation of about 1-1.5 cm. With 1.0 / 1.5 / 2.0 cm independent errors on every
#: distance of rover_gps8, the least-squares embedding residual exceeded 0.05 m in 0 / 0 / 11
#: of 500 draws (largest accepted 0.029 / 0.044 / 0.049 m); rover_gps4 (fewer redundant distances)
#: never did. A wrong entry (swapped pair, a typo, a centimetre / inch mix-up) is usually
#: decimetres: one rover_gps8 distance 0.1 m off is rejected. Pass ``tol_m`` for other
#: instruments (e.g. 0.005 for a total station).
DISTANCE_TOL_M = 0.05

#: Most sensors :meth:`SensorConfig.from_distances` accepts. Its triangle-inequality check
#: looks at every (i, j, k) triple, m^3 operations in O(m^2) memory: 0.4 s at m = 500 on one
#: core (3.4 s at 1000); an antenna array of a vehicle has a few dozen at most.
MAX_DISTANCE_SENSORS = 500


class ConfigError(ValueError):
    """A sensor configuration (or its TOML file) is invalid; the message names the field."""


class LayoutWarning(UserWarning):
    """A layout's forward axis or handedness was not fixed by the input (see
    :meth:`SensorConfig.from_distances`), or the data suggest it is wrong."""


def _as_names(names: Iterable[object], field_name: str) -> tuple[str, ...]:
    if isinstance(names, (str, bytes)) or not isinstance(names, Iterable):
        raise TypeError(f"{field_name}: must be a sequence of sensor names, got "
                        f"{type(names).__name__} {names!r}")
    out = tuple(str(n) for n in names)
    if any(n == "" for n in out):
        raise ConfigError(f"{field_name}: sensor names must be non-empty strings, got {out!r}")
    seen: set[str] = set()
    for n in out:
        if n in seen:
            raise ConfigError(f"{field_name}: duplicate sensor name {n!r}")
        seen.add(n)
    return out


def _check_distance_matrix(names: tuple[str, ...], D: object, tol: float) -> np.ndarray:
    """Validate a measured distance matrix (see ``from_distances``); returns it symmetrized."""
    m = len(names)
    Dm = _as_float_array(D, "D")
    if Dm.shape != (m, m):
        raise ConfigError(f"D: expected shape ({m}, {m}) for {m} names, got {Dm.shape}")
    if not np.all(np.isfinite(Dm)):
        i, j = np.argwhere(~np.isfinite(Dm))[0]
        raise ConfigError(f"D: entry ({names[i]!r}, {names[j]!r}) is not finite: {Dm[i, j]!r}")
    if np.abs(Dm).max() > MAX_BODY_M:
        i, j = np.unravel_index(np.argmax(np.abs(Dm)), Dm.shape)
        raise ConfigError(f"D: entry ({names[i]!r}, {names[j]!r}) = {Dm[i, j]!r} m exceeds "
                          f"MAX_BODY_M = {MAX_BODY_M:g} m")
    if np.any(np.abs(np.diag(Dm)) > tol):
        i = int(np.argmax(np.abs(np.diag(Dm))))
        raise ConfigError(f"D: diagonal entry for {names[i]!r} is {Dm[i, i]!r}, must be 0 "
                          f"(within tol_m = {tol:g} m)")
    asym = np.abs(Dm - Dm.T)
    if asym.max() > tol:
        i, j = np.unravel_index(np.argmax(asym), asym.shape)
        raise ConfigError(
            f"D: not symmetric within tol_m = {tol:g} m, worst pair ({names[i]!r}, "
            f"{names[j]!r}): {Dm[i, j]!r} vs {Dm[j, i]!r}")
    if Dm.min() < 0:
        i, j = np.unravel_index(np.argmin(Dm), Dm.shape)
        raise ConfigError(f"D: negative distance for pair ({names[i]!r}, {names[j]!r}): "
                          f"{Dm[i, j]!r}")
    Dm = 0.5 * (Dm + Dm.T)
    np.fill_diagonal(Dm, 0.0)
    off = np.where(np.eye(m, dtype=bool), np.inf, Dm)
    if off.min() <= 1e-9:
        i, j = np.unravel_index(np.argmin(off), off.shape)
        raise ConfigError(f"D: pair ({names[i]!r}, {names[j]!r}) has distance {Dm[i, j]!r}; "
                          f"distinct sensors cannot coincide")
    _check_triangles(names, Dm, tol)
    return Dm


def _check_triangles(names: tuple[str, ...], Dm: np.ndarray, tol: float) -> None:
    """Triangle inequality: excess[i, j, k] = D[i,j] - D[i,k] - D[k,j] over all k, one k at
    a time (O(m^2) memory). Three measured distances, each within tol of the truth, can
    exceed it by up to 3 tol (three collinear antennas); the embedding residual check then
    judges the whole matrix."""
    worst = -np.inf
    at: tuple = (0, 0, 0)  # (i, j, k) of the worst excess
    for k in range(Dm.shape[0]):
        excess = Dm - Dm[:, k, None] - Dm[None, k, :]
        flat = int(np.argmax(excess))
        if excess.flat[flat] > worst:
            worst = float(excess.flat[flat])
            at = (*np.unravel_index(flat, excess.shape), k)
    if worst > 3.0 * tol:
        i, j, k = at
        raise ConfigError(
            f"D: triangle inequality violated by {worst:.6g} m (> 3 tol_m = "
            f"{3 * tol:g} m) for pair ({names[i]!r}, {names[j]!r}) via {names[k]!r}")


def _embed(D: np.ndarray, d: int) -> np.ndarray:
    """Classical MDS: B = -1/2 J D^2 J, X = V_d sqrt(max(L_d, 0)); (m, d), centroid at 0."""
    m = D.shape[0]
    D2 = D**2
    row = D2.mean(axis=1)                    # J D^2 J without the (m, m) products
    B = -0.5 * (D2 - row[:, None] - row[None, :] + row.mean())
    evals, evecs = np.linalg.eigh(B)
    order = np.argsort(evals)[::-1]
    evals, evecs = evals[order], evecs[:, order]
    X = np.zeros((m, d))
    k = min(d, m)
    X[:, :k] = evecs[:, :k] * np.sqrt(np.clip(evals[:k], 0.0, None))
    return X


def _residuals(X: np.ndarray, D: np.ndarray) -> np.ndarray:
    """(m, m) | |x_i - x_j| - D_ij |, metres."""
    diff = X[:, None, :] - X[None, :, :]
    return np.abs(np.sqrt((diff**2).sum(-1)) - D)


def _refine_embedding(X0: np.ndarray, D: np.ndarray) -> np.ndarray:
    """Least-squares embedding: minimize sum_{i<j} (|x_i - x_j| - D_ij)^2 from X0 (scipy
    least_squares, trust-region with LSMR on the sparse analytic Jacobian, 2d non-zeros per
    pair: O(m^2) memory; in units of max(D) so tolerances are relative). Tolerances 1e-12:
    the cost agrees with a dense exact solve to 12 digits. Returns the refined positions,
    centred, or X0 if refinement did not lower the cost."""
    from scipy import sparse
    from scipy.optimize import least_squares

    m, d = X0.shape
    I, J = np.triu_indices(m, 1)
    s = float(D.max())
    target = D[I, J] / s
    rows = np.repeat(np.arange(I.size), 2 * d)
    cols = np.concatenate([I[:, None] * d + np.arange(d), J[:, None] * d + np.arange(d)],
                          axis=1).ravel()

    def fun(x: np.ndarray) -> np.ndarray:
        X = x.reshape(m, d)
        return np.sqrt(((X[I] - X[J]) ** 2).sum(1)) - target

    def jac(x: np.ndarray) -> sparse.csr_matrix:
        X = x.reshape(m, d)
        diff = X[I] - X[J]
        u = diff / np.maximum(np.sqrt((diff**2).sum(1)), 1e-300)[:, None]
        vals = np.concatenate([u, -u], axis=1).ravel()
        return sparse.csr_matrix((vals, (rows, cols)), shape=(I.size, m * d))

    x0 = (X0 / s).ravel()
    sol = least_squares(fun, x0, jac=jac, method="trf", tr_solver="lsmr", xtol=1e-12,
                        ftol=1e-12, gtol=1e-12, max_nfev=100)
    if not np.all(np.isfinite(sol.x)) or sol.cost > 0.5 * float((fun(x0) ** 2).sum()):
        return X0
    X = sol.x.reshape(m, d) * s
    return X - X.mean(axis=0)


def _name_index(cfg: SensorConfig, value: object, field_name: str) -> int:
    if not isinstance(value, (str, int, np.integer)) or isinstance(value, bool):
        raise TypeError(f"{field_name}: must be a sensor name, got {type(value).__name__} "
                        f"{value!r}")
    try:
        return cfg.index(value if isinstance(value, (int, np.integer)) else str(value))
    except ConfigError as exc:
        raise ConfigError(f"{field_name}: {exc}") from None


def _frame_from_names(cfg: SensorConfig, forward: object, left: object, tol_m: float
                      ) -> tuple[np.ndarray, str]:
    """Body positions with +x along ``forward`` and ``left`` at y > 0 (d = 2), CG origin."""
    if forward is None:
        raise ConfigError("left: needs forward (a sensor name or a (rear, front) pair)")
    if cfg.d != 2:
        raise ConfigError("forward/left: fix the frame of a 2-D layout only (in 3-D named "
                          "antennas cannot tell which side is up); pass observed and heading")
    X = cfg.body_positions
    cg = cfg.cg_body
    if isinstance(forward, (tuple, list)):
        if len(forward) != 2:
            raise ConfigError(f"forward: a (rear, front) pair needs 2 names, got {forward!r}")
        a = _name_index(cfg, forward[0], "forward[0]")
        b = _name_index(cfg, forward[1], "forward[1]")
        axis_names: tuple[int, ...] = (a, b)
        vec, what = X[b] - X[a], f"{cfg.names[a]!r} -> {cfg.names[b]!r}"
    else:
        b = _name_index(cfg, forward, "forward")
        vec, what, axis_names = X[b] - cg, f"CG -> {cfg.names[b]!r}", (b,)
    norm = float(np.hypot(vec[0], vec[1]))
    if norm <= tol_m:
        raise ConfigError(f"forward: {what} is {norm:.3g} m long, within tol_m = {tol_m:g} m "
                          f"of zero; it cannot define the forward axis")
    ux = vec / norm
    uy = np.array([-ux[1], ux[0]])
    B = np.stack([(X - cg) @ ux, (X - cg) @ uy], axis=1)
    note = f"frame: +x along {what}"
    if left is None:
        warnings.warn("from_distances: forward is fixed but not the handedness (pass left= "
                      "a sensor on the left of the forward axis); the layout may be a mirror "
                      "image", LayoutWarning, stacklevel=3)
        return B, note + "; handedness arbitrary"
    k = _name_index(cfg, left, "left")
    if k in axis_names:
        # a sensor that names the forward axis lies on it; with a (rear, front) pair off
        # the CG its body y is the CG's offset, and the hand would follow where the CG is
        raise ConfigError(f"left: sensor {cfg.names[k]!r} lies on the forward axis {what} "
                          f"(it names it); name a sensor to one side of it")
    if abs(B[k, 1]) <= tol_m:
        raise ConfigError(f"left: sensor {cfg.names[k]!r} lies {B[k, 1]:.3g} m from the "
                          f"forward axis (within tol_m = {tol_m:g} m); name a sensor clearly "
                          f"to one side")
    if B[k, 1] < 0:
        B[:, 1] = -B[:, 1]        # the mirror image is the real layout
    return B, note + f"; {cfg.names[k]!r} on the left"


def _rigid_fit(X: np.ndarray, P: np.ndarray, proper: bool) -> tuple[np.ndarray, float]:
    """Best rigid (det +1, ``proper``) or improper (det -1) orthogonal fit of X (k, d) onto
    P (k, d) (Kabsch): returns (R (d, d), t (d,)) with ``P ~ X @ R.T + t``."""
    xc, pc = X.mean(axis=0), P.mean(axis=0)
    M = (P - pc).T @ (X - xc)
    U, _, Vt = np.linalg.svd(M)
    Dg = np.ones(X.shape[1])
    det = np.linalg.det(U @ Vt)
    Dg[-1] = (1.0 if det > 0 else -1.0) * (1.0 if proper else -1.0)
    R = (U * Dg) @ Vt
    return R, pc - R @ xc


def _frame_from_observed(cfg: SensorConfig, observed: object, heading: object
                         ) -> tuple[np.ndarray, str]:
    """Body positions from the hand that fits ``observed`` world positions better, rotated
    so that ``heading`` (rad, CCW from east) is body +x; CG origin."""
    if observed is None or heading is None:
        raise ConfigError("observed and heading: both are needed (world positions of the "
                          "antennas and the platform's heading at that moment)")
    yaw = check_real(heading, "heading")
    P = _as_float_array(observed, "observed")
    m, d = cfg.m, cfg.d
    if P.ndim != 2 or P.shape[0] != m or P.shape[1] not in ((2, 3) if d == 2 else (3,)):
        want = f"({m}, 2) or ({m}, 3)" if d == 2 else f"({m}, 3)"
        raise ConfigError(f"observed: expected shape {want} (x east, y north[, z up], metres), "
                          f"got {P.shape}")
    P = P[:, :d]
    if np.isinf(P).any():
        raise ConfigError("observed: contains an infinite coordinate (use NaN rows for "
                          "unobserved antennas)")
    rows = ~np.isnan(P).any(axis=1)
    if np.isnan(P[rows]).any() or (np.isnan(P).any(axis=1) & ~np.isnan(P).all(axis=1)).any():
        raise ConfigError("observed: a partly NaN row; an unobserved antenna is NaN in every "
                          "coordinate")
    X = cfg.body_positions
    if rows.sum() < d + 1:
        raise ConfigError(f"observed: {int(rows.sum())} observed antennas; at least {d + 1} "
                          f"not all on one line are needed to tell the hands apart")
    Xo, Po = X[rows], P[rows]
    if np.abs(Po).max() > 1e7:
        raise ConfigError("observed: coordinates above 1e7 m; use a local metric frame")
    out = {}
    for proper in (True, False):
        R, t = _rigid_fit(Xo, Po, proper)
        W = X @ R.T + t
        out[proper] = (W, float(np.sqrt(np.mean(((W[rows] - Po) ** 2).sum(1)))))
    sv = np.linalg.svd(Xo - Xo.mean(axis=0), compute_uv=False)
    if sv[d - 1] <= 1e-9 * max(sv[0], 1e-300):
        raise ConfigError("observed: the observed antennas lie on one line (one plane in "
                          "3-D); they cannot tell the hands apart")
    proper = out[True][1] <= out[False][1]
    W, rms = out[proper]
    other = out[not proper][1]
    if other < 2.0 * rms:
        warnings.warn(
            f"from_distances: the observed positions barely prefer one hand (RMS residual "
            f"{rms:.3g} m vs {other:.3g} m for the mirror image); the layout may be mirrored",
            LayoutWarning, stacklevel=3)
    cg = W[cfg.cg_mask].mean(axis=0)
    c, s_ = math.cos(yaw), math.sin(yaw)
    Rz = np.eye(d)
    Rz[:2, :2] = [[c, -s_], [s_, c]]
    B = (W - cg) @ Rz          # row-wise Rz^T (w - cg): world -> body
    note = (f"frame: observed positions with heading {yaw:.4g} rad; RMS residual "
            f"{rms:.3g} m ({'proper' if proper else 'mirror image of the distances'}; the "
            f"other hand {other:.3g} m)")
    return B, note


def platform_from_table(table: object, where: str = "platform") -> PlatformLimits | None:
    """A TOML ``[platform]`` table as :class:`PlatformLimits` (None when absent); a bad
    key or value raises ConfigError naming ``where.<key>`` and the value."""
    if table is None:
        return None
    try:
        return PlatformLimits.from_dict(table, where=where)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None


def _check_platform(platform: object) -> PlatformLimits | None:
    if platform is not None and not isinstance(platform, PlatformLimits):
        raise ConfigError(f"platform: expected an estimator.platform.PlatformLimits or None, "
                          f"got {type(platform).__name__} {platform!r}")
    return platform


def _as_float_array(a: object, field_name: str) -> np.ndarray:
    """``a`` as a float64 array; TypeError naming the field when it is not numeric."""
    try:
        return np.array(a, dtype=float)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{field_name}: must be a numeric array, got {type(a).__name__} "
                        f"({exc})") from None


@dataclass(frozen=True, eq=False)
class PairGeometry:
    """Constants of a layout that the window fits use on every call, computed once per
    configuration (:attr:`SensorConfig.pair_geometry`); every array is read-only.

    I, J : (P,) int, the pairs i < j in ``np.triu_indices(m, 1)`` order, P = m (m - 1) / 2.
    a : (P,) metres, their distances a_ij (Section 3.1.1). min_distance : min a_ij, metres.
    difference : (P, m) float, +1 at (k, I[k]) and -1 at (k, J[k]): ``difference @ p`` is
        ``p[I] - p[J]`` (exactly: every product is by 1, -1 or 0).
    cg_mask : (m,) bool, the CG members (Eq. 3.8); cg_index : their indices (ints).
    body1 : (m, d + 1), the body positions less their centroid, with a column of ones
        (a rigid fit's moments in one product; centring keeps them free of cancellation).
    """

    I: np.ndarray
    J: np.ndarray
    a: np.ndarray
    min_distance: float
    difference: np.ndarray
    cg_mask: np.ndarray
    cg_index: tuple[int, ...]
    body1: np.ndarray


@dataclass(frozen=True, eq=False)
class SensorConfig:
    """A rigid sensor layout in the platform's body frame.

    Parameters
    ----------
    names : sequence of str, length m
        Sensor names (unique). The dissertation numbers its antennas "1".."8".
    body_positions : array_like, shape (m, d), d in {2, 3}, metres
        Mounting positions in the body frame (x forward, y left, z up), finite, at most
        :data:`MAX_BODY_M` from the origin, no two coinciding (m >= 2).
    cg_members : sequence of str or int, optional
        Sensors whose mean defines the centre of gravity (Eq. 3.8). Default: all sensors.
    dead : sequence of str or int, optional
        Sensors that never report (the dissertation's sensor 4). They stay in the layout
        (their distances still constrain nothing, because they have no observations).
    mount_height_m : float, optional
        Height (>= 0, metres) of a 2-D layout above the ground, used only by the simulator.
    name, description : str
        Free text for reports.
    platform : :class:`estimator.platform.PlatformLimits`, optional
        Speed, acceleration and turn-rate limits of the carrier (the TOML ``[platform]``
        block); None (default): the pose filter estimates them from the data.
    """

    names: tuple[str, ...]
    body_positions: np.ndarray
    cg_members: tuple[str, ...] = ()
    dead: tuple[str, ...] = ()
    mount_height_m: float = 0.0
    name: str = "config"
    description: str = ""
    platform: PlatformLimits | None = None
    _index: dict = field(default_factory=dict, repr=False, compare=False)

    def __init__(
        self,
        names: Sequence[object],
        body_positions: object,
        cg_members: Sequence[object] | None = None,
        dead: Sequence[object] = (),
        *,
        mount_height_m: float = 0.0,
        name: str = "config",
        description: str = "",
        platform: PlatformLimits | None = None,
    ) -> None:
        names_t = _as_names(names, "names")
        pos = _as_float_array(body_positions, "body_positions")
        if pos.ndim != 2:
            raise ConfigError(
                f"body_positions: expected shape (m, d), got {pos.shape}")
        if pos.shape[0] != len(names_t):
            raise ConfigError(
                f"body_positions: {pos.shape[0]} rows for {len(names_t)} names")
        if len(names_t) < 2:
            raise ConfigError("names: a configuration needs at least 2 sensors, got "
                              f"{len(names_t)}")
        if pos.shape[1] not in (2, 3):
            raise ConfigError(f"body_positions: dimension d must be 2 or 3, got {pos.shape[1]}")
        if not np.all(np.isfinite(pos)):
            bad = int(np.argwhere(~np.isfinite(pos))[0, 0])
            raise ConfigError(f"body_positions: sensor {names_t[bad]!r} has a non-finite "
                              "coordinate")
        if np.abs(pos).max() > MAX_BODY_M:
            bad = int(np.argmax(np.abs(pos).max(axis=1)))
            raise ConfigError(
                f"body_positions: sensor {names_t[bad]!r} at {pos[bad].tolist()!r} m is more "
                f"than MAX_BODY_M = {MAX_BODY_M:g} m from the body origin")
        diff = pos[:, None, :] - pos[None, :, :]
        dist = np.sqrt((diff**2).sum(-1))
        np.fill_diagonal(dist, np.inf)
        if dist.min() <= 1e-9:
            i, j = np.unravel_index(np.argmin(dist), dist.shape)
            raise ConfigError(
                f"body_positions: sensors {names_t[i]!r} and {names_t[j]!r} coincide")
        try:
            mh = check_real(mount_height_m, "mount_height_m", lo=0.0)
        except ValueError as exc:
            raise ConfigError(f"{exc} (metres above ground, >= 0)") from None
        index = {n: k for k, n in enumerate(names_t)}

        def resolve(items: Sequence[object], field_name: str) -> tuple[str, ...]:
            if isinstance(items, (str, bytes)) or not isinstance(items, Iterable):
                raise TypeError(f"{field_name}: must be a sequence of sensor names or "
                                f"indices, got {type(items).__name__} {items!r}")
            out = []
            for it in items:
                if isinstance(it, (int, np.integer)) and not isinstance(it, bool):
                    if not 0 <= int(it) < len(names_t):
                        raise ConfigError(f"{field_name}: index {it} out of range "
                                          f"0..{len(names_t)-1}")
                    out.append(names_t[int(it)])
                elif str(it) in index:
                    out.append(str(it))
                else:
                    raise ConfigError(f"{field_name}: unknown sensor {it!r}; known: "
                                      f"{list(names_t)}")
            if len(set(out)) != len(out):
                raise ConfigError(f"{field_name}: duplicate entries {out!r}")
            return tuple(out)

        dead_t = resolve(dead, "dead")
        cg_t = resolve(cg_members if cg_members is not None else names_t, "cg_members")
        if not cg_t:
            raise ConfigError("cg_members: must name at least one sensor")
        if len(dead_t) > len(names_t) - 2:
            raise ConfigError(f"dead: at most m - 2 = {len(names_t) - 2} sensors may be dead, got "
                              f"{len(dead_t)}")
        pos.setflags(write=False)
        object.__setattr__(self, "names", names_t)
        object.__setattr__(self, "body_positions", pos)
        object.__setattr__(self, "cg_members", cg_t)
        object.__setattr__(self, "dead", dead_t)
        object.__setattr__(self, "mount_height_m", mh)
        object.__setattr__(self, "name", str(name))
        object.__setattr__(self, "description", str(description))
        object.__setattr__(self, "platform", _check_platform(platform))
        object.__setattr__(self, "_index", index)

    # ------------------------------------------------------------------ basic views
    @property
    def m(self) -> int:
        """Number of sensors."""
        return len(self.names)

    @property
    def d(self) -> int:
        """Spatial dimension of the layout (2 or 3)."""
        return int(self.body_positions.shape[1])

    def index(self, name: str | int | np.integer) -> int:
        """Index of a sensor by name (or pass-through of a valid index)."""
        if isinstance(name, (int, np.integer)) and not isinstance(name, bool):
            if 0 <= int(name) < self.m:
                return int(name)
            raise ConfigError(f"sensor index {name} out of range 0..{self.m - 1}")
        try:
            return self._index[str(name)]
        except KeyError:
            raise ConfigError(f"unknown sensor {name!r}; known: {list(self.names)}") from None

    @property
    def alive_mask(self) -> np.ndarray:
        """(m,) bool, False for dead sensors."""
        mask = np.ones(self.m, dtype=bool)
        for n in self.dead:
            mask[self._index[n]] = False
        return mask

    @property
    def cg_mask(self) -> np.ndarray:
        """(m,) bool, True for the sensors that define the CG (Eq. 3.8)."""
        mask = np.zeros(self.m, dtype=bool)
        for n in self.cg_members:
            mask[self._index[n]] = True
        return mask

    @property
    def cg_body(self) -> np.ndarray:
        """(d,) body-frame CG: mean of the CG members' positions (Eq. 3.8), metres."""
        return self.body_positions[self.cg_mask].mean(axis=0)

    def distances(self) -> np.ndarray:
        """(m, m) pairwise distances a_ij in metres (Section 3.1.1), zero diagonal."""
        diff = self.body_positions[:, None, :] - self.body_positions[None, :, :]
        return np.sqrt((diff**2).sum(-1))

    @cached_property
    def pair_geometry(self) -> PairGeometry:
        """The pairs, their distances and the CG members as arrays (:class:`PairGeometry`),
        computed on first use and kept on this object (the layout is immutable)."""
        I, J = np.triu_indices(self.m, 1)
        E = np.zeros((I.size, self.m))
        E[np.arange(I.size), I] = 1.0
        E[np.arange(I.size), J] = -1.0
        a = self.distances()[I, J]
        cg = self.cg_mask
        B = self.body_positions
        B1 = np.hstack([B - B.mean(axis=0), np.ones((self.m, 1))])
        arrays = (I, J, a, E, cg, B1)
        for arr in arrays:
            arr.setflags(write=False)
        return PairGeometry(I=I, J=J, a=a, min_distance=float(a.min()), difference=E,
                            cg_mask=cg,
                            cg_index=tuple(np.flatnonzero(cg).tolist()), body1=B1)

    def cg_from_positions(self, positions: np.ndarray) -> np.ndarray:
        """CG of estimated sensor positions, Eq. 3.8: mean over the CG members.

        positions: (..., m, d) -> (..., d).
        """
        positions = np.asarray(positions, dtype=float)
        return positions[..., self.cg_mask, :].mean(axis=-2)

    def planar(self) -> SensorConfig:
        """The same layout projected to the xy-plane (d = 2); a 2-D config returns itself."""
        if self.d == 2:
            return self
        return SensorConfig(self.names, self.body_positions[:, :2], self.cg_members, self.dead,
                            mount_height_m=self.mount_height_m, name=self.name,
                            description=self.description, platform=self.platform)

    def __repr__(self) -> str:
        return (f"SensorConfig(name={self.name!r}, m={self.m}, d={self.d}, "
                f"dead={list(self.dead)}, cg_members={list(self.cg_members)})")

    def to_dict(self) -> dict:
        """The configuration as the TOML table structure of the module docstring (the
        inverse of :meth:`from_dict`; write it with ``tomli_w.dumps``)."""
        out: dict = {"name": self.name}
        if self.description:
            out["description"] = self.description
        out["mount_height_m"] = self.mount_height_m
        out["cg_sensors"] = list(self.cg_members)
        if self.dead:
            out["dead"] = list(self.dead)
        if self.platform is not None:
            out["platform"] = {k: v for k, v in self.platform.to_dict().items()
                               if v is not None}
        out["sensor"] = [{"name": n, "position_m": [float(v) for v in p]}
                         for n, p in zip(self.names, self.body_positions)]
        return out

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_distances(
        cls,
        names: Sequence[object],
        D: object,
        *,
        d: int = 2,
        tol_m: float = DISTANCE_TOL_M,
        forward: object = None,
        left: object = None,
        observed: object = None,
        heading: float | None = None,
        **kwargs: object,
    ) -> SensorConfig:
        """A body frame from measured pairwise distances (Section 3.1.1: the fit needs only
        the distances a_ij; the frame matters for heading, lag correction and the EKF).

        names : 2 <= m <= :data:`MAX_DISTANCE_SENSORS` sensor names. D : (m, m) metres,
            finite, <= :data:`MAX_BODY_M`. Memory O(m^2); time O(m^3) (0.1-0.3 s at m = 250).
        d : 2 or 3, the dimension of the layout.
        tol_m : metres (default :data:`DISTANCE_TOL_M`, reasoning there): the largest
            accepted asymmetry |D_ij - D_ji|, diagonal entry, triangle-inequality excess
            and embedding residual. Otherwise ``ConfigError`` names the worst pair.

        The layout is the least-squares embedding of the distances: classical MDS
        (B = -1/2 J D^2 J, X = V_d sqrt(L_d)) refined by Gauss-Newton on
        sum_{i<j} (|x_i - x_j| - D_ij)^2 (exact data are returned as MDS gives them).

        Distances cannot tell a layout from its mirror image, nor which way is forward. Fix
        them with one of (otherwise the frame is the principal axes of the layout centred
        on its centroid, and a :class:`LayoutWarning` says that forward and handedness are
        arbitrary; a mirrored layout cost 0.7 m of antenna error and 36-145 degrees of
        heading on a real 4-antenna frame):

        - ``forward`` = a sensor name (body +x points from the CG to it) or a pair
          ``(rear, front)`` (+x along rear -> front), and ``left`` = a sensor name that
          lies to the left of that axis (body y > 0; within ``tol_m`` of the axis, or one
          of the sensors naming it, is an error: it fixes no hand). d = 2 only: in 3-D,
          named antennas cannot tell which side is up.
        - ``observed`` = (m, 2|3) world positions of the antennas at one moment (x east,
          y north, z up, metres; NaN rows for unobserved antennas; e.g. RTK fixes or a
          long stationary average) and ``heading`` = the yaw of the platform's forward
          direction then (rad, CCW from east, e.g. the direction of travel while driving
          forward). The hand whose rigid fit to ``observed`` has the smaller residual is
          taken; both RMS residuals go into ``description``, and a LayoutWarning is
          raised when they differ by less than a factor 2 (the observation is then too
          noisy for the layout's size to decide). A 3-D layout is assumed level then.

        The body origin is then the CG (mean of ``cg_members``), as in models/configs/.
        ``kwargs`` (cg_members, dead, mount_height_m, name, description) pass to the
        constructor; ``description`` gets a note saying how the frame was fixed.
        """
        names_t = _as_names(names, "names")
        m = len(names_t)
        if m < 2:
            raise ConfigError(f"names: a configuration needs at least 2 sensors, got {m}")
        if m > MAX_DISTANCE_SENSORS:
            raise ConfigError(f"names: from_distances takes at most MAX_DISTANCE_SENSORS = "
                              f"{MAX_DISTANCE_SENSORS} sensors, got {m}")
        d = check_int(d, "d")
        if d not in (2, 3):
            raise ConfigError(f"d: must be 2 or 3, got {d!r}")
        tol_m = check_real(tol_m, "tol_m", lo=0.0)
        Dm = _check_distance_matrix(names_t, D, tol_m)
        scale = float(Dm.max())
        tol = tol_m + 1e-9 * scale + 1e-12      # plus float round-off of the embedding
        X = _embed(Dm, d)
        resid = _residuals(X, Dm)
        if resid.max() > 1e-9 * scale:
            X = _refine_embedding(X, Dm)
            resid = _residuals(X, Dm)
        if resid.max() > tol:
            i, j = np.unravel_index(np.argmax(resid), resid.shape)
            raise ConfigError(
                f"D: not realizable in {d} dimensions within tol_m = {tol_m:g} m; worst pair "
                f"({names_t[i]!r}, {names_t[j]!r}) is off by {resid[i, j]:.6g} m after the "
                f"least-squares embedding")
        # validate kwargs (cg_members, dead, ...) once, on the raw embedding
        raw = cls(names_t, X, **kwargs)  # type: ignore[arg-type]
        if observed is not None or heading is not None:
            if forward is not None or left is not None:
                raise ConfigError("forward/left and observed/heading: give one way to fix "
                                  "the frame, not both")
            B, note = _frame_from_observed(raw, observed, heading)
        elif forward is not None or left is not None:
            B, note = _frame_from_names(raw, forward, left, tol_m)
        else:
            B = X - X.mean(axis=0)      # principal axes about the centroid (MDS order)
            note = ("frame: principal axes of the distances; forward axis and handedness "
                    "arbitrary")
            warnings.warn(
                "from_distances: without forward/left or observed/heading the body +x axis "
                "and the handedness are arbitrary (the layout may be a mirror image); lag "
                "correction and the EKF assume +x is forward", LayoutWarning, stacklevel=2)
        desc = str(kwargs.get("description", "") or "")
        kw = {k: v for k, v in kwargs.items() if k != "description"}
        return cls(names_t, B, description=f"{desc}; {note}" if desc else note,
                   **kw)  # type: ignore[arg-type]

    @classmethod
    def load(cls, path_or_name: str | Path) -> SensorConfig:
        """Load a configuration TOML: a path, or a name looked up in ``models/configs/``.

        Every field is validated; unknown keys are rejected. Errors name the file and field.
        """
        data, path = read_model_toml(path_or_name, CONFIGS_DIR, "config", error=ConfigError)
        return cls.from_dict(data, source=str(path))

    @classmethod
    def from_dict(cls, data: dict, *, source: str = "<dict>") -> SensorConfig:
        """Build from the TOML table structure documented in the module docstring."""
        allowed = {"name", "description", "mount_height_m", "cg_sensors", "dead", "sensor",
                   "platform"}
        unknown = sorted(set(data) - allowed)
        if unknown:
            raise ConfigError(f"{source}: unknown key(s) {unknown}; allowed: {sorted(allowed)}")
        sensors = data.get("sensor")
        if not isinstance(sensors, list) or not sensors:
            raise ConfigError(f"{source}: 'sensor' must be a non-empty array of tables "
                              "([[sensor]])")
        names: list[str] = []
        positions: list[list[float]] = []
        for k, s in enumerate(sensors):
            where = f"{source}: sensor[{k}]"
            if not isinstance(s, dict):
                raise ConfigError(f"{where}: must be a table with 'name' and 'position_m'")
            extra = sorted(set(s) - {"name", "position_m"})
            if extra:
                raise ConfigError(f"{where}: unknown key(s) {extra}; allowed: ['name', "
                                  "'position_m']")
            if "name" not in s:
                raise ConfigError(f"{where}.name: missing")
            if not isinstance(s["name"], (str, int)) or isinstance(s["name"], bool):
                raise ConfigError(f"{where}.name: must be a string, got {s['name']!r}")
            p = s.get("position_m")
            if (not isinstance(p, list) or len(p) not in (2, 3)
                    or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in p)):
                raise ConfigError(f"{where}.position_m: must be 2 or 3 numbers (metres), got {p!r}")
            if positions and len(p) != len(positions[0]):
                raise ConfigError(
                    f"{where}.position_m: has {len(p)} coordinates, sensor[0] has "
                    f"{len(positions[0])}")
            names.append(str(s["name"]))
            positions.append([float(v) for v in p])
        for key in ("cg_sensors", "dead"):
            if key in data and not isinstance(data[key], list):
                raise ConfigError(f"{source}: {key} must be a list of sensor names, got "
                                  f"{data[key]!r}")
        mh = data.get("mount_height_m", 0.0)
        if (not isinstance(mh, (int, float)) or isinstance(mh, bool) or not math.isfinite(mh)
                or mh < 0):
            raise ConfigError(f"{source}: mount_height_m must be a number >= 0 (metres), got "
                              f"{mh!r}")
        for key in ("name", "description"):
            if key in data and not isinstance(data[key], str):
                raise ConfigError(f"{source}: {key} must be a string, got {data[key]!r}")
        platform = platform_from_table(data.get("platform"), f"{source}: platform")
        try:
            return cls(
                names, positions,
                cg_members=[str(x) for x in data["cg_sensors"]] if "cg_sensors" in data else None,
                dead=[str(x) for x in data.get("dead", [])],
                mount_height_m=float(mh),
                name=data.get("name", Path(source).stem),
                description=data.get("description", ""),
                platform=platform,
            )
        except ConfigError as exc:
            raise ConfigError(f"{source}: {exc}") from None
