"""Pose of a rigid body carrying N >= 2 tags in a known layout, from anchor-tag ranges (issue 26).

The two sources meet here: the ultrasonic thesis (003, Appendix A) trilaterates each tag
alone; the GPS dissertation (000, Section 3.1) fits all sensors jointly under their known
layout and checks the mirror image of the layout. :func:`fit_pose` does the joint fit on the
ranges themselves (the rigid-body localisation problem; Jiang et al., ICRA 2023, GN-ULS):

1. **closed-form start** (:func:`closed_form_start`): each tag trilaterated alone by
   :func:`estimator.trilateration.damped_ls` (known tag height in the planar mode), then the
   weighted Procrustes fit of the layout to the fixes
   (:func:`estimator.rigid_fit.procrustes_batch`);
2. **joint refinement**: Levenberg-Marquardt on all ranges of the epoch at once, with robust
   IRLS weights (``robust="huber"`` k = 1.345 or ``"cauchy"`` c = 2.385, the 95 %-efficiency
   constants; scale = 1.4826 MAD of the residuals, floored at ``sigma_m``) or none (plain
   least squares: the independent baseline);
3. an optional **range-bias state** (``bias="common"``: one offset added to every range;
   ``"anchor"``: one per anchor), solved with the pose;
4. **mirror checks** like the GPS layout fit: the layout mirrored (body y -> -y) is fitted
   too (``mirror_objective``), and the pose reflected in the anchors' best-fit line in x-y is
   used as a second start; statuses in :data:`STATUSES`;
5. everything vectorised over epochs (one numpy pass per iteration for all epochs).

Modes. ``dim=2`` (planar): pose ``(x, y, yaw)``, tag world height = ``origin_z_m`` + tag z,
ranges are 3-D distances. ``dim=3``: position ``(x, y, z)`` and a rotation matrix, needs
three non-collinear tags and anchors that are not coplanar with the tags' possible positions
(a flat anchor array leaves the mirror in its plane: ``side`` picks it for the start).

Shapes: anchors ``(M, 3)`` m (world: x east, y north, z up); body ``(N, 2)`` or ``(N, 3)`` m
(tag frame; 2 columns = tag z 0); ranges ``(N, M)`` (one epoch) or ``(E, N, M)`` m, NaN =
missing (any subset per epoch). The covariance is ``sigma_m^2 (J' W J)^-1`` at the solution
(W the final robust weights, 1 for plain least squares): the Cramer-Rao bound for Gaussian
range noise of standard deviation ``sigma_m`` when W = 1.

The tightly coupled filter (:func:`track`) and its RTS smoother (:func:`smooth`) are further
down, with their own docstrings.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from estimator import range_kernels
from estimator import trilateration as tri
from estimator._checks import check_array, check_int, check_real
from estimator.configuration import SensorConfig
from estimator.orientation import wrap_angle
from estimator.rigid_fit import procrustes_batch

__all__ = [
    "BIAS_MODES",
    "ROBUST",
    "STATE",
    "STATUSES",
    "FilterConfig",
    "RigidPoseFit",
    "TrackResult",
    "closed_form_start",
    "fit_pose",
    "grid_to_stream",
    "nees",
    "smooth",
    "track",
]

#: name -> tuning constant of the robust loss (95 % efficiency at Gaussian noise)
ROBUST = {"none": None, "huber": 1.345, "cauchy": 2.385}
BIAS_MODES = ("none", "common", "anchor")

#: Status vocabulary of :class:`RigidPoseFit` (as :data:`estimator.window.STATUSES`).
STATUSES = {
    "ok": "joint fit converged at a well-determined pose",
    "insufficient_data": "fewer finite ranges than unknowns + 1, or no start (fewer than 2 "
                         "tags trilaterated, 3 non-collinear in 3-D): NaN pose",
    "degenerate": "J'W J singular at the solution (condition number >= 1e12): the ranges do "
                  "not fix the pose; the last iterate is returned",
    "maxiter": "iteration limit reached before the step test was met; last iterate returned",
    "ambiguous": "a second proper pose (from the start reflected in the anchors' line) fits "
                 "within 9 scale^2 of the best: the mirror pose fits nearly as well",
    "mirror_ambiguous": "the mirrored layout fits within 9 scale^2 of the proper one: the "
                        "ranges do not fix the layout's handedness (a swapped tag would pass)",
    "mirrored": "the mirrored layout fits better by more than 9 scale^2: the layout or the tag "
                "assignment is probably mirrored; the proper fit is returned",
}

_MAX_ABS_M = 1e7
_SINGULAR_REL = 1e-12
#: cost tie band of the mirror checks, in units of scale^2 (as damped_ls's 9 sigma^2)
_TIE = 9.0
#: iteration cap of the two mirror-check fits: their costs are upper bounds of the minima, so
#: a capped check can miss a tie (never invent one); 10 iterations reach the exact mirror of
#: a collinear array from its reflected start in 3-5 (measured) and cap the cost of the
#: checks at about that of the main fit
_CHECK_ITER = 10
#: iterations during which the robust scale is re-estimated from the residuals (then frozen)
_SCALE_ITER = 5


@dataclass(frozen=True)
class RigidPoseFit:
    """Per-epoch joint fit (E epochs; P parameters = 3 + n_bias in 2-D, 6 + n_bias in 3-D).

    position (E, 2|3) m; yaw (E,) rad (wrapped); rotation (E, 3, 3) body -> world;
    bias (E, n_bias) m; covariance (E, P, P) over (x, y, yaw, biases) in 2-D or
    (x, y, z, rotation increment about world x, y, z, biases) in 3-D (m, rad);
    rms_residual_m (E,); scale_m (E,) robust scale; n_ranges (E,); iterations (E,);
    objective (E,) robust cost; mirror_objective (E,) of the mirrored layout (NaN if not
    checked); alternative (E, 3) the other proper pose (x, y, yaw) when ``ambiguous``;
    status (E,) str from :data:`STATUSES`.
    """

    position: np.ndarray
    yaw: np.ndarray
    rotation: np.ndarray
    bias: np.ndarray
    covariance: np.ndarray
    rms_residual_m: np.ndarray
    scale_m: np.ndarray
    n_ranges: np.ndarray
    iterations: np.ndarray
    objective: np.ndarray
    mirror_objective: np.ndarray
    alternative: np.ndarray
    status: np.ndarray

    @property
    def pose(self) -> np.ndarray:
        """(E, 3): x, y (m), yaw (rad)."""
        return np.column_stack([self.position[:, 0], self.position[:, 1], self.yaw])


# ------------------------------------------------------------------------------ checks
def _check_geometry(anchors, body, ranges):
    A = check_array(anchors, "anchors", max_abs=_MAX_ABS_M)
    if A.ndim != 2 or A.shape[1] != 3 or A.shape[0] < 3:
        raise ValueError(f"anchors: expected shape (M, 3) with M >= 3, got {A.shape}")
    B = check_array(body, "body", max_abs=_MAX_ABS_M)
    if B.ndim != 2 or B.shape[1] not in (2, 3) or B.shape[0] < 2:
        raise ValueError(f"body: expected shape (N, 2) or (N, 3) with N >= 2, got {B.shape}")
    if B.shape[1] == 2:
        B = np.column_stack([B, np.zeros(B.shape[0])])
    D = check_array(ranges, "ranges", allow_nan=True, max_abs=_MAX_ABS_M)
    single = D.ndim == 2
    if single:
        D = D[None]
    if D.ndim != 3 or D.shape[1:] != (B.shape[0], A.shape[0]):
        raise ValueError(f"ranges: expected shape ({B.shape[0]}, {A.shape[0]}) or "
                         f"(E, {B.shape[0]}, {A.shape[0]}), got {np.shape(ranges)}")
    if (D < 0).any():
        raise ValueError(f"ranges: must be >= 0 m, found {np.nanmin(D)!r}")
    return A, B, D, single


def _choice(value, name, allowed):
    if value not in allowed:
        raise ValueError(f"{name}: must be one of {tuple(allowed)}, got {value!r}")
    return value


# ------------------------------------------------------------------------- closed form
def _rz(yaw: np.ndarray) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    R = np.zeros(yaw.shape + (3, 3))
    R[..., 0, 0], R[..., 0, 1], R[..., 1, 0], R[..., 1, 1] = c, -s, s, c
    R[..., 2, 2] = 1.0
    return R


def _tag_fixes(A, B, D, dim, origin_z, sigma, side):
    """Per-tag damped trilateration: (E, N, 3) world points (NaN where a tag has < 3 ranges)."""
    E, N = D.shape[0], B.shape[0]
    fix = np.full((E, N, 3), np.nan)
    for n in range(N):
        kw = {} if dim == 3 else {"height_m": origin_z + B[n, 2]}
        fix[:, n] = tri.damped_ls(A, D[:, n], sigma_m=sigma, side=side, **kw)
    return fix


def _procrustes(fix, B, dim):
    """Weighted Procrustes of the layout to the tag fixes: (E, 3) position, (E, 3, 3) R, ok."""
    E, N = fix.shape[:2]
    cols = slice(0, dim)
    w = np.all(np.isfinite(fix[..., cols]), axis=2).astype(float)
    cfg = SensorConfig([f"t{i}" for i in range(N)], B[:, cols])
    fit = procrustes_batch(np.where(w[..., None] > 0, fix[..., cols], np.nan), w, cfg)
    ok = fit.status == "ok"
    pos = np.full((E, 3), np.nan)
    R = np.full((E, 3, 3), np.nan)
    if dim == 2:
        pos[:, :2] = fit.translation
        R = _rz(fit.yaw)
    else:
        pos, R = fit.translation, fit.rotation
    return pos, R, ok


def closed_form_start(anchors, body, ranges, *, origin_z_m: float = 0.0, dim: int = 2,
                      sigma_m: float = 0.05, side: int = 1):
    """Per-tag trilateration + weighted Procrustes (thesis Appendix A + dissertation 3.1).

    Returns position (E, 3) m (2-D: z = origin_z_m), rotation (E, 3, 3) and ok (E,) bool
    (False: fewer than 2 tags fixed, or 3 non-collinear in 3-D; NaN pose). Single epoch in:
    leading axis of length 1.
    """
    dim = _choice(dim, "dim", (2, 3))
    A, B, D, _ = _check_geometry(anchors, body, ranges)
    z0 = check_real(origin_z_m, "origin_z_m", lo=-_MAX_ABS_M, hi=_MAX_ABS_M)
    sig = check_real(sigma_m, "sigma_m", lo=0.0, lo_open=True, hi=1e3)
    fix = _tag_fixes(A, B, D, dim, z0, sig, side)
    pos, R, ok = _procrustes(fix, B, dim)
    if dim == 2:
        pos[:, 2] = z0
    return pos, R, ok


# --------------------------------------------------------------------------- the model
class _Model:
    """Residuals and Jacobian of all ranges of E epochs (K = N M ranges per epoch)."""

    def __init__(self, A, B, D, dim, origin_z, bias):
        self.A, self.B, self.dim, self.z0 = A, B, dim, origin_z
        N, M = B.shape[0], A.shape[0]
        self.D = D.reshape(D.shape[0], N * M)
        self.mask = np.isfinite(self.D)
        self.D0 = np.where(self.mask, self.D, 0.0)
        self.tag = np.repeat(np.arange(N), M)
        self.anc = np.tile(np.arange(M), N)
        self.nb = {"none": 0, "common": 1, "anchor": M}[bias]
        self.bias = bias
        self.npose = 3 if dim == 2 else 6
        self.p = self.npose + self.nb

    def bias_columns(self, E):
        K = self.tag.size
        if self.bias == "none":
            return np.zeros((E, K, 0))
        if self.bias == "common":
            return np.ones((E, K, 1))
        Jb = np.zeros((K, self.nb))
        Jb[np.arange(K), self.anc] = 1.0
        return np.broadcast_to(Jb, (E, K, self.nb))

    def evaluate(self, pos, R, b, rows=None):
        """r (E, K) = predicted - measured (0 where missing), J (E, K, P); ``rows`` selects
        the epochs (default all)."""
        mask = self.mask if rows is None else self.mask[rows]
        D0 = self.D0 if rows is None else self.D0[rows]
        Rb = np.einsum("eij,nj->eni", R, self.B)[:, self.tag]          # (E, K, 3)
        diff = pos[:, None, :] + Rb - self.A[self.anc][None]
        if self.dim == 2:
            diff[..., 2] = self.z0 + self.B[self.tag, 2] - self.A[self.anc, 2]
        rho = np.linalg.norm(diff, axis=2)
        u = diff / np.where(rho > 0, rho, 1.0)[..., None]
        bias = np.zeros_like(rho) if self.nb == 0 else np.einsum(
            "ekb,eb->ek", self.bias_columns(rho.shape[0]), b)
        r = np.where(mask, rho + bias - D0, 0.0)
        E, K = r.shape
        J = np.zeros((E, K, self.p))
        if self.dim == 2:
            J[..., 0], J[..., 1] = u[..., 0], u[..., 1]
            J[..., 2] = u[..., 1] * Rb[..., 0] - u[..., 0] * Rb[..., 1]
        else:
            J[..., 0:3] = u
            J[..., 3:6] = np.cross(Rb, u)
        J[..., self.npose:] = self.bias_columns(E)
        J *= mask[..., None]
        return r, J


def _masked_median(x, mask):
    """Row medians (E,) of x (E, K) over mask (NaN for an empty row); sort-based, fast."""
    mask = mask & np.isfinite(x)
    n = mask.sum(axis=1)
    xs = np.sort(np.where(mask, x, np.inf), axis=1)
    lo = np.clip((n - 1) // 2, 0, None)
    hi = np.clip(n // 2, 0, None)
    rows = np.arange(x.shape[0])
    med = 0.5 * (xs[rows, lo] + xs[rows, hi])
    return np.where(n > 0, med, np.nan)


def _normal(J, w, r=None):
    """J' W J (E, P, P) and, with r, J' W r (E, P), by batched matmul."""
    Jw = J * w[..., None]
    H = np.matmul(Jw.transpose(0, 2, 1), J)
    return H if r is None else (H, np.matmul(Jw.transpose(0, 2, 1), r[..., None])[..., 0])


def _robust_weights(r, mask, kind, floor, scale=None):
    """IRLS weights (E, K) and scale (E,): ``scale`` if given, else 1.4826 MAD of the used
    residuals, >= floor."""
    k = ROBUST[kind]
    if scale is None:
        med = _masked_median(r, mask)
        mad = 1.4826 * _masked_median(np.abs(r - med[:, None]), mask)
        s = np.maximum(np.nan_to_num(mad, nan=floor, posinf=floor), floor)
    else:
        s = scale
    if k is None:
        return mask.astype(float), s
    a = np.abs(r) / (k * s[:, None])
    w = np.minimum(1.0, 1.0 / np.maximum(a, 1e-300)) if kind == "huber" else 1.0 / (1.0 + a * a)
    return w * mask, s


def _rho(r, mask, kind, s):
    """Robust cost sum_k s^2 rho(r_k / s) (E,), with the least-squares rho = r^2 / 2 x 2."""
    k = ROBUST[kind]
    if k is None:
        return np.sum(np.where(mask, r * r, 0.0), axis=1)
    a = np.abs(r) / (k * s[:, None])
    if kind == "huber":
        c = np.where(a <= 1, a * a, 2 * a - 1)
    else:
        c = np.log1p(a * a)
    return np.sum(np.where(mask, c, 0.0), axis=1) * (k * s) ** 2


def _apply_step(pos, R, b, step, model):
    pos = pos.copy()
    if model.dim == 2:
        pos[:, :2] += step[:, :2]
        yaw = np.arctan2(R[:, 1, 0], R[:, 0, 0]) + step[:, 2]
        R = _rz(yaw)
    else:
        pos += step[:, :3]
        R = np.einsum("eij,ejk->eik", _rotvec(step[:, 3:6]), R)
    return pos, R, b + step[:, model.npose:]


def _rotvec(w):
    """Rodrigues: (E, 3) rotation vectors -> (E, 3, 3)."""
    th = np.linalg.norm(w, axis=1)
    k = w / np.where(th > 0, th, 1.0)[:, None]
    Kx = np.zeros((w.shape[0], 3, 3))
    Kx[:, 0, 1], Kx[:, 0, 2], Kx[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    Kx[:, 1, 0], Kx[:, 2, 0], Kx[:, 2, 1] = k[:, 2], -k[:, 1], k[:, 0]
    s, c = np.sin(th)[:, None, None], np.cos(th)[:, None, None]
    return np.eye(3) + s * Kx + (1 - c) * (Kx @ Kx)


def _solve_lm(model, pos, R, b, robust, floor, max_iter, tol):
    """Batched IRLS Levenberg-Marquardt; returns pos, R, b, iterations, converged, w, s."""
    E = pos.shape[0]
    lam = np.full(E, 1e-3)
    it = np.zeros(E, dtype=int)
    done = ~np.all(np.isfinite(pos), axis=1)
    r, J = model.evaluate(pos, R, b)
    w, s = _robust_weights(r, model.mask, robust, floor)
    eye = np.eye(model.p)
    for _ in range(max_iter):
        live = np.flatnonzero(~done)
        if live.size == 0:
            break
        rl, Jl, wl, sl = r[live], J[live], w[live], s[live]
        H, g = _normal(Jl, wl, rl)
        Hd = H + lam[live, None, None] * (np.einsum("epp->ep", H)[:, :, None] * eye + 1e-12 * eye)
        ok = np.all(np.isfinite(Hd), axis=(1, 2)) & (np.abs(np.linalg.det(Hd)) > 0)
        step = np.zeros((live.size, model.p))
        if ok.any():
            step[ok] = -np.linalg.solve(Hd[ok], g[ok][..., None])[..., 0]
        p2, R2, b2 = _apply_step(pos[live], R[live], b[live], step, model)
        r2, J2 = model.evaluate(p2, R2, b2, live)
        ml = model.mask[live]
        better = _rho(r2, ml, robust, sl) <= _rho(rl, ml, robust, sl)
        it[live] += 1
        acc = live[better & ok]
        pos[acc], R[acc], b[acc], r[acc], J[acc] = p2[better & ok], R2[better & ok], \
            b2[better & ok], r2[better & ok], J2[better & ok]
        lam[live] = np.where(better, np.maximum(lam[live] / 3, 1e-9), lam[live] * 4)
        small = np.linalg.norm(step, axis=1) <= tol * (1.0 + np.linalg.norm(pos[live], axis=1))
        done[live[(small & better) | ~ok | (lam[live] > 1e8)]] = True
        if acc.size:
            w_new, s_new = _robust_weights(r[acc], model.mask[acc], robust, floor)
            # the scale follows the residuals for the first _SCALE_ITER iterations, then is
            # frozen: IRLS then minimises one fixed robust cost and the step test can be met
            s[acc] = np.where(it[acc] <= _SCALE_ITER, s_new, s[acc])
            if ROBUST[robust] is not None:
                w_new = _robust_weights(r[acc], model.mask[acc], robust, floor, s[acc])[0]
            w[acc] = w_new
    return pos, R, b, it, done, w, s, r, J


def _covariance(J, w, sigma):
    H = _normal(J, w)
    fin = np.flatnonzero(np.isfinite(H).all(axis=(1, 2)))
    good = np.zeros(H.shape[0], dtype=bool)
    if fin.size:
        ev = np.linalg.eigvalsh(H[fin])
        good[fin] = ev[:, 0] > _SINGULAR_REL * ev[:, -1]
    cov = np.full_like(H, np.nan)
    if good.any():
        cov[good] = sigma ** 2 * np.linalg.inv(H[good])
    return cov, good


def _anchor_line(A):
    """Anchors' best-fit line in x-y: centroid (2,), unit normal (2,)."""
    c = A[:, :2].mean(axis=0)
    _, _, vt = np.linalg.svd(A[:, :2] - c)
    return c, vt[1]


def _reflect_start(pos, R, B, A):
    """The pose whose tags are the given pose's tags reflected in the anchors' x-y line."""
    c, nrm = _anchor_line(A)
    pts = np.einsum("eij,nj->eni", R, B)[..., :2] + pos[:, None, :2]
    h = (pts - c) @ nrm
    refl = pts - 2 * h[..., None] * nrm
    cfg = SensorConfig([f"t{i}" for i in range(B.shape[0])], B[:, :2])
    fin = np.all(np.isfinite(refl), axis=2)
    fit = procrustes_batch(np.where(fin[..., None], refl, np.nan), fin.astype(float), cfg)
    p2 = pos.copy()
    p2[:, :2] = fit.translation
    return p2, _rz(fit.yaw)


def fit_pose(anchors, body, ranges, *, origin_z_m: float = 0.0, dim: int = 2,
             robust: str = "huber", bias: str = "none", sigma_m: float = 0.05,
             mirror_check: bool = True, side: int = 1, x0=None, max_iter: int = 50,
             tol: float = 1e-8) -> RigidPoseFit:
    """Joint robust fit of the rigid pose to all ranges of each epoch (module docstring).

    anchors (M, 3) m; body (N, 2|3) m (tag frame); ranges (N, M) or (E, N, M) m, NaN missing.
    origin_z_m : 2-D mode: world height of the tag-frame origin (tag z = origin + body z).
    dim : 2 (x, y, yaw) or 3 (x, y, z, rotation). robust : key of :data:`ROBUST`.
    bias : :data:`BIAS_MODES` (range offset state). sigma_m : range noise std (m): floor of the
    robust scale, scale of the covariance and of the start's mirror tests.
    mirror_check : fit the mirrored layout and the reflected pose (2-D only; 2-3x the cost).
    x0 : optional start pose (E, 3) x, y, yaw (2-D) for every epoch instead of the closed form.
    Returns :class:`RigidPoseFit` (leading axis E; E = 1 for one epoch).
    """
    dim = _choice(dim, "dim", (2, 3))
    _choice(robust, "robust", ROBUST)
    _choice(bias, "bias", BIAS_MODES)
    A, B, D, _ = _check_geometry(anchors, body, ranges)
    z0 = check_real(origin_z_m, "origin_z_m", lo=-_MAX_ABS_M, hi=_MAX_ABS_M)
    sig = check_real(sigma_m, "sigma_m", lo=0.0, lo_open=True, hi=1e3)
    max_iter = check_int(max_iter, "max_iter", lo=1, hi=100_000)
    tol = check_real(tol, "tol", lo=0.0, lo_open=True, hi=1e-2)
    model = _Model(A, B, D, dim, z0, bias)
    E = D.shape[0]
    if x0 is None:
        pos, R, ok = closed_form_start(A, B, D, origin_z_m=z0, dim=dim, sigma_m=sig, side=side)
    else:
        if dim != 2:
            raise ValueError("x0: only for dim=2 (x, y, yaw)")
        X = check_array(x0, "x0", max_abs=_MAX_ABS_M).reshape(-1, 3)
        if X.shape[0] not in (1, E):
            raise ValueError(f"x0: expected shape (3,) or ({E}, 3), got {np.shape(x0)}")
        X = np.broadcast_to(X, (E, 3))
        pos = np.column_stack([X[:, :2], np.full(E, z0)])
        R, ok = _rz(X[:, 2]), np.ones(E, dtype=bool)
    nr = model.mask.sum(axis=1)
    ok &= nr >= model.p + 1
    pos[~ok] = np.nan
    b = np.zeros((E, model.nb))
    sol = _solve_lm(model, pos, R, b, robust, sig, max_iter, tol)
    return _finish(model, sol, ok, nr, A, B, robust, sig, mirror_check, max_iter, tol)


def _finish(model, sol, ok, nr, A, B, robust, sig, mirror_check, max_iter, tol):
    """Mirror checks, covariance, statuses and the result object of :func:`fit_pose`."""
    pos, R, b, it, conv, w, s, r, J = sol
    E = pos.shape[0]
    obj = _rho(r, model.mask, robust, s)
    alt = np.full((E, 3), np.nan)
    mobj = np.full(E, np.nan)
    status = np.where(ok, "ok", "insufficient_data").astype(object)
    if mirror_check and model.dim == 2 and ok.any():
        status, pos, R, b, r, J, w, obj, alt = _reflected(model, pos, R, b, r, J, w, s, obj,
                                                          ok, status, A, B, robust, sig,
                                                          max_iter, tol)
        mobj = _mirror_layout(model, pos, R, ok, robust, sig, s, max_iter, tol, B)
        span = np.linalg.matrix_rank(B[:, :2] - B[:, :2].mean(axis=0)) == 2
        if span:
            tie = ok & (status == "ok") & (mobj <= obj + _TIE * s ** 2)
            mirror_better = ok & (status == "ok") & (mobj < obj - _TIE * s ** 2)
            status[tie & ~mirror_better] = "mirror_ambiguous"
            status[mirror_better] = "mirrored"
    cov, good = _covariance(J, w, sig)
    status[ok & ~good] = "degenerate"
    status[ok & good & ~conv & (status == "ok")] = "maxiter"
    rms = np.sqrt(np.sum(r * r * model.mask, axis=1) / np.maximum(nr, 1))
    rms[~ok] = np.nan
    yaw = wrap_angle(np.arctan2(R[:, 1, 0], R[:, 0, 0]))
    p_out = pos[:, :model.dim].copy()
    for arr in (p_out, yaw, b, rms, obj):
        arr[~ok] = np.nan
    return RigidPoseFit(position=p_out, yaw=yaw, rotation=R, bias=b, covariance=cov,
                        rms_residual_m=rms, scale_m=s, n_ranges=nr, iterations=it,
                        objective=obj, mirror_objective=mobj, alternative=alt,
                        status=status.astype(str))


def _reflected(model, pos, R, b, r, J, w, s, obj, ok, status, A, B, robust, sig, max_iter,
               tol):
    """Second start: the pose reflected in the anchors' x-y line; keep the better minimum.
    Two minima are distinct when their positions differ by > 10 sigma_m or yaws by > 0.05
    rad (far beyond the spread of one minimum at sigma_m); a tie is within 9 scale^2."""
    p2, R2 = _reflect_start(pos, R, B, A)
    p2[~ok] = np.nan
    pb, Rb, bb, _, _, wb, _, rb, Jb = _solve_lm(model, p2, R2, b.copy(), robust, sig,
                                                min(max_iter, _CHECK_ITER), tol)
    objb = _rho(rb, model.mask, robust, s)
    yaw_a = np.arctan2(R[:, 1, 0], R[:, 0, 0])
    yaw_b = np.arctan2(Rb[:, 1, 0], Rb[:, 0, 0])
    distinct = ok & np.isfinite(objb) & ((np.linalg.norm(pb[:, :2] - pos[:, :2], axis=1)
                                          > 10 * sig) | (np.abs(wrap_angle(yaw_a - yaw_b))
                                                         > 0.05))
    better = distinct & (objb < obj - _TIE * s ** 2)
    tie = distinct & ~better & (objb <= obj + _TIE * s ** 2)
    other = np.column_stack([pb[:, 0], pb[:, 1], yaw_b])
    sel = better
    pos, R, b = np.where(sel[:, None], pb, pos), np.where(sel[:, None, None], Rb, R), \
        np.where(sel[:, None], bb, b)
    r, J, w = np.where(sel[:, None], rb, r), np.where(sel[:, None, None], Jb, J), \
        np.where(sel[:, None], wb, w)
    obj = np.where(sel, objb, obj)
    alt = np.full((pos.shape[0], 3), np.nan)
    alt[tie] = other[tie]
    status = status.copy()
    status[tie] = "ambiguous"
    return status, pos, R, b, r, J, w, obj, alt


def _mirror_layout(model, pos, R, ok, robust, sig, s, max_iter, tol, B):
    """Robust cost (E,) of the mirrored layout (body y -> -y), the better of two starts fitted
    in one batch: the proper fit's tag points and those points reflected in the anchors' x-y
    line (exact for collinear anchors), each Procrustes-fitted with the mirrored layout."""
    E, N, M = pos.shape[0], B.shape[0], model.A.shape[0]
    Bm = B * np.array([1.0, -1.0, 1.0])
    D = model.D.reshape(E, N, M)
    mm = _Model(model.A, Bm, np.concatenate([D, D]), 2, model.z0, model.bias)
    pts = np.einsum("eij,nj->eni", R, B)[..., :2] + pos[:, None, :2]
    c, nrm = _anchor_line(model.A)
    refl = pts - 2 * ((pts - c) @ nrm)[..., None] * nrm
    both = np.concatenate([pts, refl])
    okk = np.concatenate([ok, ok]) & np.all(np.isfinite(both), axis=(1, 2))
    cfg = SensorConfig([f"t{i}" for i in range(N)], Bm[:, :2])
    fit = procrustes_batch(np.where(okk[:, None, None], both, np.nan),
                           np.where(okk, 1.0, 0.0)[:, None] * np.ones(both.shape[:2]), cfg)
    p0 = np.concatenate([pos, pos])
    p0[:, :2] = fit.translation
    p0[~okk] = np.nan
    out = _solve_lm(mm, p0, _rz(np.nan_to_num(fit.yaw)), np.zeros((2 * E, mm.nb)),
                    robust, sig, min(max_iter, _CHECK_ITER), tol)
    cost = _rho(out[7], mm.mask, robust, np.concatenate([s, s]))
    mobj = np.fmin(cost[:E], cost[E:])
    mobj[~ok] = np.nan
    return mobj


# ============================================================ tightly coupled filter
@dataclass(frozen=True)
class FilterConfig:
    """Settings of :func:`track` (SI units; physical defaults for a hand-pushed trolley or a
    small ground robot with UWB tags, not fitted to any recording).

    sigma_range_m : range noise std (m). q_accel : white-acceleration spectral density of x
    and y (m^2/s^3). q_yaw_accel : same for yaw (rad^2/s^3). q_bias : random walk of the common
    range bias (m^2/s; 0 with init_sigma_bias_m 0 switches the bias state off).
    gate_sigma : innovation gate, |nu| / sqrt(S) (4: a chi-square(1) tail of 6e-5).
    reinit_epochs : consecutive epochs with more gated than accepted ranges (>= 2 gated) that
    trigger a re-initialisation from the joint fit. nis_limit : the same when the running mean
    NIS (weight 1/200 per update, each NIS clipped at 100) exceeds it (expected 1).
    init_sigma_* : initial standard deviations (m, rad, m/s, rad/s, m) at (re)initialisation.
    max_init_age_s : a joint fit older than this cannot (re)initialise the filter.
    max_gap_s : after a gap in the ranges longer than this the filter re-initialises from
    the joint fit (coasting a constant-velocity model for seconds predicts nothing; the
    shared static runs have gaps of up to 8.8 s).
    """

    sigma_range_m: float = 0.05
    q_accel: float = 1.0
    q_yaw_accel: float = 1.0
    q_bias: float = 1e-6
    gate_sigma: float = 4.0
    reinit_epochs: int = 10
    nis_limit: float = 10.0
    init_sigma_pos_m: float = 0.1
    init_sigma_yaw: float = 0.1
    init_sigma_vel: float = 1.0
    init_sigma_yaw_rate: float = 1.0
    init_sigma_bias_m: float = 0.3
    max_init_age_s: float = 0.5
    max_gap_s: float = 1.0

    def __post_init__(self):
        for f in ("sigma_range_m", "q_accel", "q_yaw_accel", "gate_sigma", "nis_limit",
                  "init_sigma_pos_m", "init_sigma_yaw", "init_sigma_vel",
                  "init_sigma_yaw_rate", "max_init_age_s", "max_gap_s"):
            check_real(getattr(self, f), f"FilterConfig.{f}", lo=0.0, lo_open=True, hi=1e6)
        for f in ("q_bias", "init_sigma_bias_m"):
            check_real(getattr(self, f), f"FilterConfig.{f}", lo=0.0, hi=1e6)
        check_int(self.reinit_epochs, "FilterConfig.reinit_epochs", lo=1, hi=10**9)


#: state order of :func:`track`
STATE = ("x", "y", "yaw", "vx", "vy", "yaw_rate", "bias")
_IU, _JU = np.triu_indices(7)


@dataclass(frozen=True)
class TrackResult:
    """Per epoch (T distinct update times) and per range update (K).

    times (T,) s; state_pred / state_post (T, 7) before / after the epoch's updates
    (order :data:`STATE`, yaw unwrapped); cov_pred / cov_post (T, 7, 7); segment (T,) int
    (a new segment starts at every (re)initialisation; -1 before the first); reinit (T,)
    bool; n_accepted / n_gated (T,); nis (K,) normalised innovation squared of every update
    (NaN before initialisation), accepted (K,) bool; seconds : wall time of the whole
    :func:`track` call (checks, loop, outputs); updates : number of range updates processed.
    """

    times: np.ndarray
    state_pred: np.ndarray
    cov_pred: np.ndarray
    state_post: np.ndarray
    cov_post: np.ndarray
    segment: np.ndarray
    reinit: np.ndarray
    n_accepted: np.ndarray
    n_gated: np.ndarray
    nis: np.ndarray
    accepted: np.ndarray
    seconds: float
    updates: int

    @property
    def pose(self) -> np.ndarray:
        """(T, 3) x, y (m), wrapped yaw (rad) after each epoch's updates."""
        return np.column_stack([self.state_post[:, :2], wrap_angle(self.state_post[:, 2])])


def grid_to_stream(times, ranges):
    """(T,) s and (T, N, M) m ranges (NaN missing) -> long stream (t, tag, anchor, r), finite
    ranges only, in time order then tag, anchor (each one asynchronous update)."""
    t = check_array(times, "times")
    D = check_array(ranges, "ranges", allow_nan=True)
    if t.ndim != 1 or D.ndim != 3 or D.shape[0] != t.size:
        raise ValueError(f"ranges: expected shape ({t.size}, N, M) for times {t.shape}, "
                         f"got {D.shape}")
    e, n, m = np.nonzero(np.isfinite(D))
    return t[e], n, m, D[e, n, m]


def _check_stream(t, tag, anc, r, N, M):
    t = check_array(t, "t")
    r = check_array(r, "r", max_abs=_MAX_ABS_M)
    tag, anc = np.asarray(tag), np.asarray(anc)
    if not (t.ndim == 1 and t.shape == r.shape == tag.shape == anc.shape):
        raise ValueError(f"t, tag, anchor, r: expected equal 1-D shapes, got {t.shape}, "
                         f"{tag.shape}, {anc.shape}, {r.shape}")
    if t.size and np.any(np.diff(t) < 0):
        k = int(np.flatnonzero(np.diff(t) < 0)[0])
        raise ValueError(f"t: must be non-decreasing, t[{k + 1}] = {t[k + 1]!r} < {t[k]!r}")
    for name, a, hi in (("tag", tag, N), ("anchor", anc, M)):
        if a.size and (not np.issubdtype(a.dtype, np.integer) or a.min() < 0 or a.max() >= hi):
            raise ValueError(f"{name}: must be integers in [0, {hi}), got {a.dtype} "
                             f"[{a.min()}, {a.max()}]")
    return t, tag.astype(int), anc.astype(int), r


def track(anchors, body, t, tag, anchor, r, init_times, init_pose, *, origin_z_m=0.0,
          init_bias=None, config: FilterConfig | None = None,
          reference: bool = False) -> TrackResult:
    """Tightly coupled EKF on (x, y, yaw, vx, vy, yaw rate, common bias): each range is one
    scalar update at its time (thesis Appendix C's constant-velocity model, extended to the
    rigid pose and the range model of :func:`fit_pose`).

    anchors (M, 3), body (N, 2|3) m as :func:`fit_pose`; t (K,) s non-decreasing, tag (K,),
    anchor (K,) indices, r (K,) m (see :func:`grid_to_stream`). init_times (L,) s,
    init_pose (L, 3) x, y, yaw, init_bias (L,) m or None: joint fits (NaN = none) that
    initialise the filter and re-initialise it when the innovations stay inconsistent
    (:class:`FilterConfig`). Gated ranges are not used; the gate cannot lock the filter
    out because of the re-initialisation. Returns :class:`TrackResult`. The loop runs in
    the compiled kernel :func:`estimator.range_kernels.rigid_ekf`; ``reference=True`` runs
    the scalar-Python reference instead (the same outputs to rounding; for tests and timing).
    """
    import time as _time

    start = _time.perf_counter()
    cfg = FilterConfig() if config is None else config
    A, B, _, _ = _check_geometry(anchors, body, np.zeros((np.shape(body)[0],
                                                          np.shape(anchors)[0])))
    z0 = check_real(origin_z_m, "origin_z_m", lo=-_MAX_ABS_M, hi=_MAX_ABS_M)
    t, tag, anc, r = _check_stream(t, tag, anchor, r, B.shape[0], A.shape[0])
    it = check_array(init_times, "init_times")
    ip = check_array(init_pose, "init_pose", allow_nan=True)
    if ip.shape != (it.size, 3):
        raise ValueError(f"init_pose: expected shape ({it.size}, 3), got {ip.shape}")
    ib = np.zeros(it.size) if init_bias is None else check_array(init_bias, "init_bias",
                                                                 allow_nan=True)
    if ib.shape != it.shape:
        raise ValueError(f"init_bias: expected shape {it.shape}, got {ib.shape}")
    times, first = np.unique(t, return_index=True)
    k = np.searchsorted(it, times, side="right") - 1
    valid = (k >= 0) & (times - it[np.maximum(k, 0)] <= cfg.max_init_age_s)
    valid &= np.all(np.isfinite(ip[np.maximum(k, 0)]), axis=1)
    kk = np.maximum(k, 0)
    init = np.where(valid[:, None], np.column_stack([ip[kk], np.nan_to_num(ib[kk])]), 0.0)
    dz = (z0 + B[:, 2])[:, None] - A[None, :, 2]
    out = _loop(t, r, np.append(first, t.size), B[tag, 0], B[tag, 1], dz[tag, anc] ** 2,
                A[anc, 0], A[anc, 1], init, valid, cfg, reference)
    xs_pred, ps_pred, xs_post, ps_post, seg, rei, nacc, ngat, nis, acc = out
    res = TrackResult(times=times, state_pred=np.asarray(xs_pred, float).reshape(-1, 7),
                      cov_pred=_unpack(ps_pred),
                      state_post=np.asarray(xs_post, float).reshape(-1, 7),
                      cov_post=_unpack(ps_post), segment=np.asarray(seg, dtype=int),
                      reinit=np.asarray(rei, dtype=bool), n_accepted=np.asarray(nacc, int),
                      n_gated=np.asarray(ngat, int), nis=np.asarray(nis, float),
                      accepted=np.asarray(acc, dtype=bool), seconds=0.0, updates=t.size)
    return replace(res, seconds=_time.perf_counter() - start)


def _loop(t, r, bounds, bx, by, dz2, ax, ay, init, has, cfg, reference):
    """The filter loop: the compiled kernel (:func:`estimator.range_kernels.rigid_ekf`) or,
    with ``reference``, the scalar-Python reference :func:`_run_reference` (same outputs).
    init (T, 4) x, y, yaw, bias of the joint fit usable at each epoch where has (T,)."""
    if reference:
        lst = [tuple(v) if ok else None for v, ok in zip(init.tolist(), has.tolist())]
        return _run_reference(t.tolist(), r.tolist(), bounds.tolist(), bx.tolist(),
                              by.tolist(), dz2.tolist(), ax.tolist(), ay.tolist(), lst, cfg)
    v0 = np.array([cfg.init_sigma_pos_m, cfg.init_sigma_pos_m, cfg.init_sigma_yaw,
                   cfg.init_sigma_vel, cfg.init_sigma_vel, cfg.init_sigma_yaw_rate,
                   cfg.init_sigma_bias_m]) ** 2
    return range_kernels.rigid_ekf(t, r, bounds.astype(np.int64), bx, by, dz2, ax, ay, init,
                                   has, v0, cfg.sigma_range_m ** 2, cfg.gate_sigma ** 2,
                                   cfg.q_accel, cfg.q_yaw_accel, cfg.q_bias,
                                   cfg.reinit_epochs, cfg.nis_limit, cfg.max_gap_s)


def _unpack(rows):
    """(T, 28) upper-triangle rows (list or array) -> (T, 7, 7) symmetric matrices."""
    P = np.zeros((len(rows), 7, 7))
    if len(rows):
        U = np.asarray(rows, float)
        P[:, _IU, _JU] = U
        P[:, _JU, _IU] = U
    return P


def _run_reference(t, r, bounds, bx, by, dz2, ax, ay, init, cfg):
    """The filter loop in scalar Python: the 28 covariance entries (upper triangle, p{i}{j},
    state order :data:`STATE`) are local variables, the predict and update steps are written
    out (F sparse, H = [hx, hy, hyaw, 0, 0, 0, 1]), so one range update does no allocation.
    bx, by, ax, ay, dz2 (K,): the updates' tag x, y (body), anchor x, y and squared height
    difference, zipped with the ranges (no indexing in the loop)."""
    sqrt, cos, sin = math.sqrt, math.cos, math.sin
    R = cfg.sigma_range_m ** 2
    gate2 = cfg.gate_sigma ** 2
    qa, qw, qb = cfg.q_accel, cfg.q_yaw_accel, cfg.q_bias
    v0 = (cfg.init_sigma_pos_m ** 2, cfg.init_sigma_pos_m ** 2, cfg.init_sigma_yaw ** 2,
          cfg.init_sigma_vel ** 2, cfg.init_sigma_vel ** 2, cfg.init_sigma_yaw_rate ** 2,
          cfg.init_sigma_bias_m ** 2)
    nan = float("nan")
    xs_pred, ps_pred, xs_post, ps_post = [], [], [], []
    seg, rei, nacc, ngat = [], [], [], []
    nis_out = [nan] * len(t)
    acc_out = [False] * len(t)
    x0 = x1 = x2 = x3 = x4 = x5 = x6 = 0.0
    (p00, p01, p02, p03, p04, p05, p06, p11, p12, p13, p14, p15, p16, p22, p23, p24, p25, p26,
        p33, p34, p35, p36, p44, p45, p46, p55, p56, p66) = (0.0,) * 28
    live = False
    segment = -1
    bad_run = 0
    ewma = 1.0
    t_prev = 0.0
    for e in range(len(bounds) - 1):
        lo, hi = bounds[e], bounds[e + 1]
        te = t[lo]
        restart = init[e] is not None and (not live or bad_run >= cfg.reinit_epochs
                                           or ewma > cfg.nis_limit
                                           or te - t_prev > cfg.max_gap_s)
        if restart:
            x0, x1, x2, x6 = init[e][0], init[e][1], init[e][2], init[e][3]
            x3 = x4 = x5 = 0.0
            (p00, p01, p02, p03, p04, p05, p06, p11, p12, p13, p14, p15, p16, p22, p23, p24, p25,
                p26, p33, p34, p35, p36, p44, p45, p46, p55, p56, p66) = (0.0,) * 28
            p00, p11, p22, p33, p44, p55, p66 = v0
            live, segment, bad_run, ewma = True, segment + 1, 0, 1.0
        elif live:
            dt = te - t_prev
            dt2 = dt * dt
            qa1, qa2, qa3 = qa * dt, qa * dt2 / 2, qa * dt2 * dt / 3
            qw1, qw2, qw3 = qw * dt, qw * dt2 / 2, qw * dt2 * dt / 3
            qb1 = qb * dt
            x0 += x3 * dt
            x1 += x4 * dt
            x2 += x5 * dt
            # P <- F P F' + Q (F = I + dt [0 I; 0 0] on the (pose, rate) blocks); the
            # rate-rate and rate-bias entries p34 p35 p36 p45 p46 p56 are unchanged
            (p00, p01, p02, p03, p04, p05, p06, p11, p12, p13, p14, p15, p16, p22, p23, p24,
                p25, p26, p33, p44, p55, p66) = (
                p00 + dt * (p03 + p03) + dt2 * p33 + qa3,
                p01 + dt * (p13 + p04) + dt2 * p34,
                p02 + dt * (p23 + p05) + dt2 * p35,
                p03 + dt * p33 + qa2,
                p04 + dt * p34,
                p05 + dt * p35,
                p06 + dt * p36,
                p11 + dt * (p14 + p14) + dt2 * p44 + qa3,
                p12 + dt * (p24 + p15) + dt2 * p45,
                p13 + dt * p34,
                p14 + dt * p44 + qa2,
                p15 + dt * p45,
                p16 + dt * p46,
                p22 + dt * (p25 + p25) + dt2 * p55 + qw3,
                p23 + dt * p35,
                p24 + dt * p45,
                p25 + dt * p55 + qw2,
                p26 + dt * p56,
                p33 + qa1,
                p44 + qa1,
                p55 + qw1,
                p66 + qb1,
            )
        t_prev = te
        xs_pred.append((x0, x1, x2, x3, x4, x5, x6))
        ps_pred.append((p00, p01, p02, p03, p04, p05, p06, p11, p12, p13, p14, p15, p16, p22,
                        p23, p24, p25, p26, p33, p34, p35, p36, p44, p45, p46, p55, p56, p66))
        na = ng = 0
        if live:
            for u, bxu, byu, axu, ayu, dzu, ru in zip(range(lo, hi), bx[lo:hi], by[lo:hi],
                                                     ax[lo:hi], ay[lo:hi], dz2[lo:hi],
                                                     r[lo:hi]):
                c, s = cos(x2), sin(x2)
                rx = c * bxu - s * byu
                ry = s * bxu + c * byu
                ex = x0 + rx - axu
                ey = x1 + ry - ayu
                rho = sqrt(ex * ex + ey * ey + dzu)
                hx, hy = ex / rho, ey / rho
                ht = (ey * rx - ex * ry) / rho
                nu = ru - rho - x6
                h0 = p00 * hx + p01 * hy + p02 * ht + p06
                h1 = p01 * hx + p11 * hy + p12 * ht + p16
                h2 = p02 * hx + p12 * hy + p22 * ht + p26
                h3 = p03 * hx + p13 * hy + p23 * ht + p36
                h4 = p04 * hx + p14 * hy + p24 * ht + p46
                h5 = p05 * hx + p15 * hy + p25 * ht + p56
                h6 = p06 * hx + p16 * hy + p26 * ht + p66
                S = hx * h0 + hy * h1 + ht * h2 + h6 + R
                nis = nu * nu / S
                nis_out[u] = nis
                ewma += ((min(100.0, nis)) - ewma) * 0.005
                if nis > gate2:
                    ng += 1
                    continue
                na += 1
                acc_out[u] = True
                si = 1.0 / S
                k0, k1, k2, k3, k4, k5, k6 = h0 * si, h1 * si, h2 * si, h3 * si, h4 * si, \
                    h5 * si, h6 * si
                x0 += k0 * nu
                x1 += k1 * nu
                x2 += k2 * nu
                x3 += k3 * nu
                x4 += k4 * nu
                x5 += k5 * nu
                x6 += k6 * nu
                p00 -= k0 * h0
                p01 -= k0 * h1
                p02 -= k0 * h2
                p03 -= k0 * h3
                p04 -= k0 * h4
                p05 -= k0 * h5
                p06 -= k0 * h6
                p11 -= k1 * h1
                p12 -= k1 * h2
                p13 -= k1 * h3
                p14 -= k1 * h4
                p15 -= k1 * h5
                p16 -= k1 * h6
                p22 -= k2 * h2
                p23 -= k2 * h3
                p24 -= k2 * h4
                p25 -= k2 * h5
                p26 -= k2 * h6
                p33 -= k3 * h3
                p34 -= k3 * h4
                p35 -= k3 * h5
                p36 -= k3 * h6
                p44 -= k4 * h4
                p45 -= k4 * h5
                p46 -= k4 * h6
                p55 -= k5 * h5
                p56 -= k5 * h6
                p66 -= k6 * h6
            bad_run = bad_run + 1 if (ng >= 2 and ng > na) else 0
        xs_post.append((x0, x1, x2, x3, x4, x5, x6))
        ps_post.append((p00, p01, p02, p03, p04, p05, p06, p11, p12, p13, p14, p15, p16, p22,
                        p23, p24, p25, p26, p33, p34, p35, p36, p44, p45, p46, p55, p56, p66))
        seg.append(segment if live else -1)
        rei.append(restart)
        nacc.append(na)
        ngat.append(ng)
    return xs_pred, ps_pred, xs_post, ps_post, seg, rei, nacc, ngat, nis_out, acc_out


def _f_matrix(dt):
    F = np.eye(7)
    F[0, 3] = F[1, 4] = F[2, 5] = dt
    return F


def smooth(res: TrackResult, *, reference: bool = False) -> TrackResult:
    """Rauch-Tung-Striebel smoother over :func:`track`'s epochs, per segment (a
    re-initialisation breaks the chain). Returns a TrackResult whose ``state_post`` /
    ``cov_post`` are the smoothed ones (the other fields as in ``res``). Runs the compiled
    :func:`estimator.range_kernels.rigid_rts`; ``reference=True`` the numpy reference."""
    ok = False
    if not reference:
        xs, Ps, ok = range_kernels.rigid_rts(res.times, res.segment.astype(np.int64),
                                             res.state_pred, res.cov_pred, res.state_post,
                                             res.cov_post)
    if not ok:                  # asked for, or a singular prediction the kernel leaves
        xs, Ps = _smooth_reference(res)
    return replace(res, state_post=xs, cov_post=Ps)


def _smooth_reference(res: TrackResult) -> tuple[np.ndarray, np.ndarray]:
    """The numpy RTS pass of :func:`smooth`: smoothed states (T, 7), covariances (T, 7, 7)."""
    xs, Ps = res.state_post.copy(), res.cov_post.copy()
    T = res.times.size
    for k in range(T - 2, -1, -1):
        if res.segment[k] < 0 or res.segment[k + 1] != res.segment[k]:
            continue
        F = _f_matrix(res.times[k + 1] - res.times[k])
        Pp = res.cov_pred[k + 1]
        try:  # C = P_k F' Pp^-1 = (Pp^-1 F P_k)' (both symmetric)
            C = np.linalg.solve(Pp, F @ res.cov_post[k]).T
        except np.linalg.LinAlgError:  # singular prediction (bias state off): pseudo-inverse
            C = res.cov_post[k] @ F.T @ np.linalg.pinv(Pp, hermitian=True)
        xs[k] = res.state_post[k] + C @ (xs[k + 1] - res.state_pred[k + 1])
        Ps[k] = res.cov_post[k] + C @ (Ps[k + 1] - Pp) @ C.T
    return xs, Ps


def nees(res: TrackResult, truth_times, truth_pose) -> np.ndarray:
    """(T,) normalised estimation error squared of (x, y, yaw) against truth (L, 3) given at
    truth_times (L,) s (linear interpolation, yaw unwrapped; NaN outside or before init)."""
    tt = check_array(truth_times, "truth_times")
    tp = check_array(truth_pose, "truth_pose")
    if tp.shape != (tt.size, 3):
        raise ValueError(f"truth_pose: expected shape ({tt.size}, 3), got {tp.shape}")
    yaw = np.unwrap(tp[:, 2])
    ref = np.column_stack([np.interp(res.times, tt, tp[:, 0]), np.interp(res.times, tt, tp[:, 1]),
                           np.interp(res.times, tt, yaw)])
    err = res.state_post[:, :3] - ref
    err[:, 2] = wrap_angle(err[:, 2])
    P = res.cov_post[:, :3, :3]
    out = np.full(res.times.size, np.nan)
    ok = (res.segment >= 0) & (res.times >= tt[0]) & (res.times <= tt[-1])
    if ok.any():
        out[ok] = np.einsum("ei,ei->e", err[ok], np.linalg.solve(P[ok], err[ok][..., None])[..., 0])
    return out
