"""Motion-compensated window fit: the pose at the newest epoch of a window, not mid-window.

Beyond the dissertation (000_8f82f8df647bf685.txt, Sections 3.4.2 and 5.2): its window fit
(Eq. 3.9) holds the platform still for the whole window, so the estimate sits mid-window
((s-1) v dt / 2 behind) and, with missing samples, each antenna's mean refers to a
different time. Here the platform moves with a constant twist over the window: constant
body-frame velocity and constant yaw rate omega. Writing planar points as complex numbers,
with tau = t_w - t_end <= 0 the time of a sample relative to the newest epoch,

    p_i(tau) = c + s(tau) v + z exp(i omega tau) b_i,
    s(tau)   = (exp(i omega tau) - 1) / (i omega)      (-> tau as omega -> 0),

where ``c`` is the body origin at the newest epoch, ``v`` its world velocity there,
``z = exp(i yaw)`` and ``b_i`` the body-frame sensor positions. (Integrating
``R(yaw + omega sigma) u_body`` gives ``s(tau) R(yaw) u_body``, and ``s`` commutes with
rotations, so v = R(yaw) u_body.) For fixed omega the model is complex-linear in (c, v, z);
minimizing the weighted squared residuals over c and v in closed form leaves
``alpha |z|^2 - 2 Re(conj(z) g) + const`` with real ``alpha``, so under ``|z| = 1`` the
optimum is ``z = g / |g|``: the rigid, exact-distance (procrustes) solution, with every
sample at its own time. Omega is found by a grid over ``[-omega_max, omega_max]`` refined by
golden-section search, all windows at once (range limited to half a turn per window); with
``yaw_rate=False`` omega = 0 and the fit is one closed form (constant velocity, constant
heading).

Weights are per sample and sensor ``(s, m)``; per-axis weights ``(s, m, 2)`` (Huber) are
reduced to their mean over the axes (the complex closed form needs isotropic weights).

A window whose samples all share one time cannot tell velocity from position: the velocity
is then set to 0 (the fit reduces to the ordinary window fit). Fewer than two sensors with
data: status "insufficient_data", NaN pose.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimator.configuration import SensorConfig
from estimator.orientation import wrap_angle

__all__ = ["MotionFit", "motion_compensated_batch", "motion_compensated_series"]

_GOLDEN = (np.sqrt(5.0) - 1.0) / 2.0


@dataclass(frozen=True)
class MotionFit:
    """Batched motion-compensated fits of N windows (planar).

    positions (N, m, 2) metres at each window's newest epoch, cg (N, 2), yaw (N,) rad,
    velocity (N, 2) m/s (world, body origin), yaw_rate (N,) rad/s, objective (N,) m^2
    (weighted squared residuals), status (N,) str ("ok" | "insufficient_data").
    """

    positions: np.ndarray
    cg: np.ndarray
    yaw: np.ndarray
    velocity: np.ndarray
    yaw_rate: np.ndarray
    objective: np.ndarray
    status: np.ndarray


def _s_of(x: np.ndarray) -> np.ndarray:
    """(exp(ix) - 1) / (ix), stable at x = 0: sin(x)/x + i (1 - cos x)/x."""
    re = np.sinc(x / np.pi)
    im = np.sin(x / 2.0) * np.sinc(x / (2.0 * np.pi))
    return re + 1j * im


class _Sums:
    """Per-window, per-epoch sums over sensors (omega-independent), (N, s) arrays."""

    def __init__(self, tau, Wt, Bt, Ot, EOt, BB, OO, o=None, wt=None, b=None):
        self.tau = tau  # (N, s)
        self.Wt, self.Bt, self.Ot, self.EOt = Wt, Bt, Ot, EOt
        self.BB, self.OO = BB, OO  # (N,)
        self.W = Wt.sum(axis=1)
        self.o, self.wt, self.b = o, wt, b  # stacked samples, for exact_objective only

    @classmethod
    def from_stacked(cls, tau: np.ndarray, o: np.ndarray, wt: np.ndarray, b: np.ndarray):
        """From stacked windows: o (N, s, m) complex, wt (N, s, m), b (m,) complex."""
        return cls(tau, wt.sum(axis=2), (wt * b[None, None, :]).sum(axis=2),
                   (wt * o).sum(axis=2), (wt * np.conj(b)[None, None, :] * o).sum(axis=2),
                   (wt * (np.abs(b) ** 2)[None, None, :]).sum(axis=(1, 2)),
                   (wt * np.abs(o) ** 2).sum(axis=(1, 2)), o, wt, b)

    def exact_objective(self, omega: np.ndarray) -> np.ndarray:
        """Objective from explicit residuals (no cancellation; O(N s m))."""
        c, v, z, _ = self.solve(omega)
        x = omega[:, None] * self.tau
        ph = np.exp(1j * x)
        s = self.tau * _s_of(x)
        q = c[:, None] + s * v[:, None]  # (N, s)
        r = self.o - q[:, :, None] - (ph * z[:, None])[:, :, None] * self.b[None, None, :]
        return (self.wt * (r.real**2 + r.imag**2)).sum(axis=(1, 2))

    def solve(self, omega: np.ndarray):
        """Closed-form (c, v, z, objective) for each window at yaw rate omega (N,)."""
        tau = self.tau
        x = omega[:, None] * tau
        ph = np.exp(1j * x)
        s = tau * _s_of(x)
        Wt = self.Wt
        S1 = (Wt * s).sum(axis=1)
        S2 = (Wt * np.abs(s) ** 2).sum(axis=1)
        E1 = (ph * self.Bt).sum(axis=1)
        SE = (np.conj(s) * ph * self.Bt).sum(axis=1)
        rc = self.Ot.sum(axis=1)
        rw = (np.conj(s) * self.Ot).sum(axis=1)
        rz = (np.conj(ph) * self.EOt).sum(axis=1)
        return _closed_form(self.W, S1, S2, E1, SE, rc, rw, rz, self.BB, self.OO)


def _closed_form(W, S1, S2, E1, SE, rc, rw, rz, BB, OO):
    """(c, v, z, objective) (N,) from the window sums of the normal equations at one yaw
    rate: W = sum w, S1 = sum w s, S2 = sum w |s|^2, E1 = sum e B, SE = sum conj(s) e B,
    rc = sum O, rw = sum conj(s) O, rz = sum conj(e) EO (e = exp(i omega tau), B = w b,
    O = w o, EO = w conj(b) o, all centred), BB = sum w |b|^2, OO = sum w |o|^2."""
    det = W * S2 - np.abs(S1) ** 2  # real, >= 0
    moving = det > 1e-12 * np.maximum(W * S2, 1e-300)
    safe_det = np.where(moving, det, 1.0)
    safe_W = np.where(W > 0, W, 1.0)
    # A11^{-1} = [[S2, -S1], [-conj(S1), W]] / det  (Hermitian 2x2)
    # alpha = a22 - a12^H A11^{-1} a12 ; g = rz - a12^H A11^{-1} r1
    a12 = (E1, SE)
    r1 = (rc, rw)

    def quad(u, v):  # u^H A11^{-1} v
        return (np.conj(u[0]) * (S2 * v[0] - S1 * v[1])
                + np.conj(u[1]) * (-np.conj(S1) * v[0] + W * v[1])) / safe_det

    alpha_m = BB - quad(a12, a12).real
    g_m = rz - quad(a12, r1)
    base_m = OO - quad(r1, r1).real
    # not moving (all samples at one time): v = 0, only c
    alpha_s = BB - np.abs(E1) ** 2 / safe_W
    g_s = rz - np.conj(E1) * rc / safe_W
    base_s = OO - np.abs(rc) ** 2 / safe_W
    alpha = np.where(moving, alpha_m, alpha_s)
    g = np.where(moving, g_m, g_s)
    base = np.where(moving, base_m, base_s)
    ag = np.abs(g)
    z = np.where(ag > 0, g / np.where(ag > 0, ag, 1.0), np.nan)
    obj = np.maximum(base + alpha - 2.0 * ag, 0.0)
    # back-substitute y = A11^{-1} (r1 - a12 z)
    q0 = rc - E1 * z
    q1 = rw - SE * z
    c_m = (S2 * q0 - S1 * q1) / safe_det
    v_m = (-np.conj(S1) * q0 + W * q1) / safe_det
    c = np.where(moving, c_m, q0 / safe_W)
    v = np.where(moving, v_m, 0.0)
    return c, v, z, obj


def motion_compensated_batch(tau: np.ndarray, obs: np.ndarray, config: SensorConfig,
                             weights: np.ndarray | None = None, *, yaw_rate: bool = True,
                             omega_max: float = 1.0, grid_points: int = 17,
                             iterations: int = 24) -> MotionFit:
    """Fit the constant-twist model (module docstring) to N windows at once.

    tau : (N, s) seconds relative to each window's newest epoch (<= 0; padding rows may
        have any value if their observations are NaN).
    obs : (N, s, m, 2) metres, NaN = missing. config : planar layout with m sensors.
    weights : None, (N, s, m) or (N, s, m, 2) >= 0 (per-axis weights averaged over axes).
    yaw_rate : estimate omega (grid + golden section) or fix it at 0.
    omega_max : bound on |omega|, rad/s. The search range of each window is further limited
        to ``|omega| T <= pi`` (T its time span): a constant yaw rate that turns the platform
        by more than half a turn inside one window is not a model of any window worth
        fitting, and the limit keeps the grid fine in phase. grid_points : grid over that
        range (17 points: the phase ``omega * T`` moves by pi/8 between them).
        iterations : golden-section steps on the bracket around the best grid point.
    """
    obs = np.asarray(obs, dtype=float)
    tau = np.asarray(tau, dtype=float)
    if config.d != 2:
        config = config.planar()
    N, s, m = obs.shape[:3]
    if obs.ndim != 4 or obs.shape[3] != 2 or m != config.m:
        raise ValueError(f"obs: expected shape (N, s, {config.m}, 2), got {obs.shape}")
    if tau.shape != (N, s):
        raise ValueError(f"tau: expected shape ({N}, {s}), got {tau.shape}")
    present = np.all(np.isfinite(obs), axis=-1)
    if weights is None:
        wt = present.astype(float)
    else:
        w = np.asarray(weights, dtype=float)
        if w.shape == obs.shape:
            w = w.mean(axis=-1)
        if w.shape != obs.shape[:3]:
            raise ValueError(
                f"weights: expected shape {obs.shape[:3]} or {obs.shape}, got {w.shape}")
        if not np.all(np.isfinite(w)) or np.any(w < 0):
            raise ValueError("weights: must be finite and >= 0")
        wt = np.where(present, w, 0.0)
    tau = np.where(present.any(axis=2), tau, 0.0)
    if not np.all(np.isfinite(tau)):
        raise ValueError("tau: must be finite where observations are present")
    oc = np.where(present, obs[..., 0] + 1j * obs[..., 1], 0.0)
    # centre each window (translation-invariant model) so the objective does not cancel
    W = wt.sum(axis=(1, 2))
    ref = np.where(W > 0, (wt * oc).sum(axis=(1, 2)) / np.where(W > 0, W, 1.0), 0.0)
    oc = np.where(present, oc - ref[:, None, None], 0.0)
    B = config.body_positions
    b = B[:, 0] + 1j * B[:, 1]
    sums = _Sums.from_stacked(tau, oc, wt, b)
    omega = np.zeros(N)
    if yaw_rate:
        if not np.isfinite(omega_max) or omega_max <= 0:
            raise ValueError(f"omega_max: must be a positive number (rad/s), got {omega_max!r}")
        if int(grid_points) != grid_points or grid_points < 3:
            raise ValueError(f"grid_points: must be an integer >= 3, got {grid_points!r}")
        # per-window search range: |omega| * T <= pi (at most half a turn within the window)
        T = np.max(np.where(wt.sum(axis=2) > 0, -tau, 0.0), axis=1)
        rng_k = np.minimum(omega_max, np.pi / np.maximum(T, 1e-9))
        K = int(grid_points)
        best = np.full(N, np.inf)
        for u in np.linspace(-1.0, 1.0, K):
            om = u * rng_k
            obj = sums.solve(om)[3]
            obj = np.where(np.isfinite(obj), obj, np.inf)
            better = obj < best
            omega = np.where(better, om, omega)
            best = np.where(better, obj, best)
        h = 2.0 * rng_k / (K - 1)
        lo = np.maximum(omega - h, -rng_k)
        hi = np.minimum(omega + h, rng_k)
        x1 = hi - _GOLDEN * (hi - lo)
        x2 = lo + _GOLDEN * (hi - lo)
        f1 = sums.solve(x1)[3]
        f2 = sums.solve(x2)[3]
        for _ in range(iterations):
            left = f1 <= f2  # the minimum lies in [lo, x2], else in [x1, hi]
            hi = np.where(left, x2, hi)
            lo = np.where(left, lo, x1)
            new_x = np.where(left, hi - _GOLDEN * (hi - lo), lo + _GOLDEN * (hi - lo))
            fx = sums.solve(new_x)[3]
            x1, x2, f1, f2 = (np.where(left, new_x, x2), np.where(left, x1, new_x),
                              np.where(left, fx, f2), np.where(left, f1, fx))
        cand = 0.5 * (lo + hi)
        fc = sums.solve(cand)[3]
        omega = np.where(fc <= best, cand, omega)
        # polish: the closed-form objective is a difference of large sums, so near a perfect
        # fit its rounding (~1e-16 of the data's spread squared) hides the last digits of
        # omega; one parabolic step on the objective from explicit residuals recovers them
        d = 1e-5 * rng_k
        j0 = sums.exact_objective(omega)
        jm = sums.exact_objective(omega - d)
        jp = sums.exact_objective(omega + d)
        curv = jp - 2.0 * j0 + jm
        with np.errstate(invalid="ignore", divide="ignore"):
            step = np.where(curv > 0, -0.5 * d * (jp - jm) / curv, 0.0)
        step = np.clip(np.nan_to_num(step), -10.0 * d, 10.0 * d)
        cand = np.clip(omega + step, -rng_k, rng_k)
        omega = np.where(sums.exact_objective(cand) <= j0, cand, omega)
    return _finish(sums.solve(omega), omega, ref, b, (wt.sum(axis=1) > 0).sum(axis=1),
                   config)


def _finish(solved: tuple, omega: np.ndarray, ref: np.ndarray, b: np.ndarray,
            n_sensors: np.ndarray, config: SensorConfig) -> MotionFit:
    """Pose at the newest epoch from the closed form (c, v, z, objective) at yaw rate
    omega (N,); ``ref`` (N,) complex is added back to c (the windows were centred)."""
    c, v, z, obj = solved
    ok = (n_sensors >= 2) & np.isfinite(z)
    c = c + ref
    pos_c = c[:, None] + z[:, None] * b[None, :]
    pos = np.stack([pos_c.real, pos_c.imag], axis=-1)
    vel = np.stack([v.real, v.imag], axis=-1)
    bad = ~ok
    pos[bad] = np.nan
    vel[bad] = np.nan
    return MotionFit(positions=pos, cg=config.cg_from_positions(pos),
                     # np.angle gives -pi for z = -x - 0j; the convention is (-pi, pi]
                     yaw=np.where(ok, wrap_angle(np.angle(z)), np.nan), velocity=vel,
                     yaw_rate=np.where(ok, omega, np.nan), objective=np.where(ok, obj, np.nan),
                     status=np.where(ok, "ok", "insufficient_data"))


def _block_sums(vals: np.ndarray, a: np.ndarray, e: np.ndarray, L: int
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sums of ``vals`` (n, k) over the index ranges a..e (inclusive, e - a < L), split at
    the boundary of blocks of L samples: returns (head, tail, split) where head is the sum
    over a..min(e, end of a's block), tail over the rest (0 when the range lies in one
    block) and split (N,) bool. The prefix sums restart in every block, so their round-off
    is that of sums over at most L samples, not over the whole recording."""
    n, k = vals.shape
    nb = -(-n // L)
    pad = np.zeros((nb * L, k), dtype=vals.dtype)
    pad[:n] = vals
    C = np.cumsum(pad.reshape(nb, L, k), axis=1).reshape(nb * L, k)
    ba, be = a // L, e // L
    split = be != ba
    prev = np.where((a % L != 0)[:, None], C[np.maximum(a - 1, 0)], 0.0)
    head_end = np.where(split, ba * L + L - 1, e)
    head = C[head_end] - prev
    tail = np.where(split[:, None], C[e], 0.0)
    return head, tail, split


def motion_compensated_series(t: np.ndarray, obs: np.ndarray, config: SensorConfig,
                              ends: np.ndarray, window: int,
                              sample_weights: np.ndarray | None = None) -> MotionFit:
    """Constant-velocity fits (omega = 0) of the windows ``ends - window + 1 .. ends`` of one
    recording in O(n + N), independent of the window size: the same closed form as
    :func:`motion_compensated_batch` with ``yaw_rate=False``, from window sums of per-epoch
    sums over the sensors. With omega = 0 every sum the closed form needs is a sum over the
    window of a per-epoch quantity times 1, tau or tau^2 (tau = t - t_end); these are taken
    from prefix sums that restart every ``window`` samples, with time measured from each
    block's first epoch and shifted to t_end afterwards (sum w tau = sum w u + d sum w,
    sum w tau^2 = sum w u^2 + 2 d sum w u + d^2 sum w, u = t - t_block, d = t_block - t_end),
    so the round-off stays that of window-length sums.

    t : (n,) s. obs : (n, m, 2) metres, NaN = missing. ends : (N,) int. window : s >= 1.
    sample_weights : None or (n, m) >= 0, weights that belong to a sample whatever its
    window (e.g. Huff weights).
    """
    obs = np.asarray(obs, dtype=float)
    tt = np.asarray(t, dtype=float)
    if config.d != 2:
        config = config.planar()
    n, m = obs.shape[:2]
    present = np.all(np.isfinite(obs), axis=-1)
    wt = present.astype(float)
    if sample_weights is not None:
        sw = np.asarray(sample_weights, dtype=float)
        if sw.shape != (n, m) or not np.all(np.isfinite(sw)) or np.any(sw < 0):
            raise ValueError(f"sample_weights: expected finite values >= 0 of shape ({n}, {m})")
        wt = np.where(present, sw, 0.0)
    ref0 = np.nanmean(obs.reshape(-1, 2), axis=0) if present.any() else np.zeros(2)
    o = np.where(present, (obs[..., 0] - ref0[0]) + 1j * (obs[..., 1] - ref0[1]), 0.0)
    B = config.body_positions
    b = B[:, 0] + 1j * B[:, 1]
    L = int(window)
    ends = np.asarray(ends, dtype=int)
    starts = ends - (L - 1)
    # per-epoch sums over sensors, time from the first epoch of each block of L samples
    Wt = wt.sum(axis=1)
    Bt = wt @ b
    Ot = (wt * o).sum(axis=1)
    u = tt - tt[(np.arange(n) // L) * L]
    vals = np.stack([Wt, Wt * u, Wt * u * u, Bt, Bt * u, Ot, Ot * u, (wt * o) @ np.conj(b),
                     wt @ (np.abs(b) ** 2), (wt * np.abs(o) ** 2).sum(axis=1)], axis=1)
    head, tail, split = _block_sums(vals, starts, ends, L)
    t_end = tt[ends]
    d_head = tt[(starts // L) * L] - t_end
    d_tail = np.where(split, tt[np.minimum((ends // L) * L, n - 1)] - t_end, 0.0)

    def shifted(part, d):  # sums over one part with tau = u + d
        w0, w1, w2 = part[:, 0].real, part[:, 1].real, part[:, 2].real
        return (w0, w1 + d * w0, w2 + 2.0 * d * w1 + d * d * w0,
                part[:, 3], part[:, 4] + d * part[:, 3], part[:, 5], part[:, 6] + d * part[:, 5])

    hs, ts_ = shifted(head, d_head), shifted(tail, d_tail)
    W, S1, S2, E1, SE, Osum, Otau = (x + y for x, y in zip(hs, ts_))
    EO = head[:, 7] + tail[:, 7]
    BB = (head[:, 8] + tail[:, 8]).real
    OO = (head[:, 9] + tail[:, 9]).real
    # centre each window on its weighted mean (as motion_compensated_batch does)
    ref = np.where(W > 0, Osum / np.where(W > 0, W, 1.0), 0.0)
    rc = Osum - ref * W
    rw = Otau - ref * S1
    rz = EO - ref * np.conj(E1)
    OOc = OO - 2.0 * (np.conj(ref) * Osum).real + np.abs(ref) ** 2 * W
    solved = _closed_form(W, S1, S2, E1, SE, rc, rw, rz, BB, OOc)
    cnt = np.zeros((n + 1, m))
    np.cumsum(wt > 0, axis=0, out=cnt[1:])
    n_sensors = ((cnt[ends + 1] - cnt[ends + 1 - L]) > 0).sum(axis=1)
    return _finish(solved, np.zeros(ends.size), ref + (ref0[0] + 1j * ref0[1]), b, n_sensors,
                   config)
