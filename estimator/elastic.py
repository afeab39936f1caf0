"""Batched eps-elastic window fit: the dissertation's Eq. 3.6/3.7/3.9 for many windows at once.

Source: ``000_8f82f8df647bf685.txt`` (GPS dissertation), Section 3.1, Eq. 3.6 (the distance
equalities relaxed to ``(a_ij - eps)^2 <= |p_i - p_j|^2 <= (a_ij + eps)^2``), Eq. 3.7
(stationary) and Eq. 3.9 (sliding window); per-axis weights of Eq. 3.12-3.14. By the reduction
in :mod:`estimator.window` each window is the problem

    minimize  sum_{i,a} W_ia (p_ia - y_ia)^2      (y = weighted window means, W = axis weights)
    s.t.      (a_ij - eps)^2 <= |p_i - p_j|^2 <= (a_ij + eps)^2     for all i < j,

the one the dissertation solved with MATLAB's active-set method and :func:`fit_window` solves
with scipy SLSQP (``solver="slsqp"``), one window at a time. :func:`elastic_batch` solves it for
all N windows of a track in one vectorized numpy iteration (``solver="elastic"``).

Method: a feasible primal-dual interior-point (barrier) method on the squared distances of
Eq. 3.6, every array batched over the windows (windows on the last axis, so each numpy call
works on contiguous rows), with a per-window convergence test; windows that converged leave the
batch. Per iteration and window:

* Start: the procrustes fit (every distance exact, so each constraint sits in the middle of
  its band: strictly feasible and proper-handed, ../shared/notes/window-solvers.md), or a
  caller's start that is strictly inside every band. Objective divided by the total weight;
  sensors (axes) without data get the vanishing proximal weight ``PROX_WEIGHT`` towards the
  start, exactly as slsqp/ccp (:mod:`estimator.window`).
* Newton step on the primal-dual optimality conditions of the barrier problem
  ``f(z) - tau sum log(slacks)``: the exact Hessian of the Lagrangian (the constraint curvature
  enters as ``2 (lambda_up - lambda_lo) I`` per pair) plus ``sum sigma grad q grad q^T``,
  factored by a batched Cholesky. Where it is not positive definite (the lower bounds are
  concave) a multiple of the identity is added (inertia correction; 1e-4, x8 until it
  factors, the next iteration starts from a third of it: the values of IPOPT, Waechter &
  Biegler 2006, Section 3.1).
* Barrier parameter: Mehrotra's predictor-corrector (an affine step with tau = 0 picks
  ``tau = (mu_aff / mu)^3 mu`` and adds the second-order term of the complementarity) while
  the window behaves; a window whose step needed an inertia correction, was not a descent
  direction of the barrier function or failed the first Armijo test switches for good to the
  monotone (Fiacco-McCormick) rule: tau is kept until the barrier problem is solved to
  ``KAPPA_EPS tau`` and then lowered to ``max(KAPPA_MU tau, tau^THETA_MU)`` (relative to the
  window's scale; IPOPT's 10, 0.2, 1.5). This keeps the speed of Mehrotra's rule (mean 6.9
  iterations on GPS-like windows of rover_gps8) and the robustness of the monotone one.
* Step length: the largest step keeping every slack above ``1 - FRACTION_TO_BOUNDARY`` of its
  value, exact along the step for the upper bounds (|p_i - p_j|^2 is a convex quadratic in
  the step length) and linear, hence conservative, for the lower bounds, so every iterate is
  feasible. When the curvature of the distances blocks the step (pairs sliding along an
  active upper bound), a second-order correction re-solves with that curvature |dv|^2 moved
  into the constraint residual (same factor) and is taken when it allows a longer step.
  Then Armijo backtracking (1e-4) on the barrier function.
* Convergence (per window): complementarity gap ``sum lambda s`` and scaled dual residual
  ``max |grad L| x max a_ij`` both below ``RTOL x f + ATOL x f_start``: the objective is then
  within about ``RTOL`` (1e-7, relative) of the local optimum, ten times inside the agreement
  with slsqp the issue asks for (1e-6); 1e-8 costs 7 % more iterations.

Engines: the iteration runs compiled, one window after the other
(:mod:`estimator.elastic_kernel`, ``engine="numba"``, the default), or batched in numpy
(:func:`_barrier_solve`, ``engine="numpy"``, the reference the kernel is tested against);
the same steps, fits equal to rounding (tests/test_elastic_kernel.py).

Why not the slsqp warm-start chain or a CCP: see ../shared/notes/window-solvers.md; both are
one window at a time. The result is checked like slsqp's (feasible by construction,
objective not worse than the start, proper-handed) and every window gets a status.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from estimator._checks import check_array, check_int
from estimator.configuration import SensorConfig
from estimator.elastic_kernel import N_PAR, barrier_kernel
from estimator.orientation import wrap_angle
from estimator.rigid_fit import (
    PROX_WEIGHT,
    _check_eps,
    _geometry,
    check_window_means,
    procrustes_batch,
)

__all__ = ["ELASTIC_STATUSES", "ENGINES", "ElasticFit", "elastic_batch", "warm_kernel"]

#: The iteration's engines (:func:`elastic_batch`): compiled per window, batched numpy.
ENGINES = ("numba", "numpy")

#: Per-window status of :class:`ElasticFit` (all of them in estimator.window.STATUSES).
ELASTIC_STATUSES = {
    "ok": "converged (gap and dual residual below RTOL x objective): feasible, objective not "
          "worse than the start, proper-handed",
    "maxiter": "iteration limit reached before the convergence test passed: the last iterate "
               "(feasible, objective not worse than the start) is returned",
    "insufficient_data": "fewer than 2 observed sensors (d=2) or fewer than 3 non-collinear "
                         "ones (d=3): NaN positions",
    "fallback_mirrored": "the solution was the mirror image of the configuration; procrustes "
                         "returned",
    "fallback_failed": "non-finite values in the iteration; procrustes returned",
}

#: convergence: objective within ~RTOL (relative) of the local optimum, ATOL x f_start absolute
RTOL = 1e-7
ATOL = 1e-12
#: initial barrier parameter: TAU0_FACTOR x max|grad f| x eps (the complementarity lambda s of
#: a pair pulled to its bound is ~ |grad f| x eps; measured on GPS-like windows of rover_gps8:
#: 0.1 needs 7.4 iterations at RTOL 1e-8, 0.03 and 0.3 7.6, 1.0 8.0)
TAU0_FACTOR = 0.1
#: slacks keep at least 1 - FRACTION_TO_BOUNDARY of their value per step (IPOPT's tau_min)
FRACTION_TO_BOUNDARY = 0.99
#: monotone barrier rule (IPOPT defaults kappa_eps, kappa_mu, theta_mu)
KAPPA_EPS, KAPPA_MU, THETA_MU = 10.0, 0.2, 1.5
#: multipliers are kept within [tau / (KAPPA_SIGMA s), KAPPA_SIGMA tau / s] (IPOPT's kappa_Sigma)
KAPPA_SIGMA = 1e10
#: inertia correction: first shift, growth, decrease (IPOPT delta_w^0, kappa_w^+, kappa_w^-)
DELTA0, DELTA_GROW, DELTA_SHRINK, DELTA_MIN = 1e-4, 8.0, 1.0 / 3.0, 1e-20
#: Armijo sufficient-decrease constant on the barrier function; a rejected step is tried at
#: 2^-1 .. 2^-HALVINGS of its length (all at once), else the window stays for that iteration
ARMIJO = 1e-4
HALVINGS = 30
#: default iteration limit (as slsqp's in fit_window): 99.9 % of GPS-like windows converge in
#: <= 30 iterations; the rest start near a saddle or crawl along curved bands (slsqp needs
#: 50-90 iterations on such windows too); a straggler holds its whole batch, so the limit
#: bounds the cost, and a window that reaches it gets status "maxiter"
MAXITER = 100


@dataclass(frozen=True)
class ElasticFit:
    """Result of :func:`elastic_batch` for N windows.

    positions (N, m, d) metres, cg (N, d) (Eq. 3.8), yaw (N,) rad (heading of the body +x axis
    of the best rigid fit to the positions, (-pi, pi]), objective (N,) m^2: the reduced Eq. 3.9
    value ``sum W (p - mean)^2`` (without the within-window scatter, as BatchFit.objective),
    start_objective (N,) the same at the start, max_violation (N,) m:
    ``max | |p_i - p_j| - a_ij |`` (<= eps when the constraints hold), iterations (N,),
    status (N,) str from :data:`ELASTIC_STATUSES`. NaN fields where the data are insufficient.
    """

    positions: np.ndarray
    cg: np.ndarray
    yaw: np.ndarray
    objective: np.ndarray
    start_objective: np.ndarray
    max_violation: np.ndarray
    iterations: np.ndarray
    status: np.ndarray


# ----------------------------------------------------------------------------- linear algebra
def _pair_difference(m: int, I: np.ndarray, J: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """S (P, m): v = S z (pair differences), +1 at (k, I[k]) and -1 at (k, J[k]); and S^T
    (contiguous), which accumulates pair terms per sensor. O(P m), built per call (no
    module-level cache: it is a few hundred numbers)."""
    P = I.size
    k = np.arange(P)
    S = np.zeros((P, m))
    S[k, I] = 1.0
    S[k, J] = -1.0
    return S, np.ascontiguousarray(S.T)


_CHOLESKY_LO: np.ufunc | None
try:  # the gufunc behind np.linalg.cholesky: NaN factors for the matrices that are not PD
    from numpy.linalg import _umath_linalg as _umath

    _CHOLESKY_LO = _umath.cholesky_lo
except (ImportError, AttributeError):  # pragma: no cover - other numpy layouts
    _CHOLESKY_LO = None


def _cholesky(Ht: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Batched Cholesky of Ht (n, n, N) (windows last) -> (Lt (n, n, N), not_pd (N,))."""
    n, _, N = Ht.shape
    Lt = np.empty_like(Ht)
    if _CHOLESKY_LO is not None:
        with np.errstate(invalid="ignore"):
            _CHOLESKY_LO(Ht.transpose(2, 0, 1), signature="d->d", out=Lt.transpose(2, 0, 1))
        return Lt, np.isnan(Lt[n - 1, n - 1])
    bad = np.zeros(N, dtype=bool)  # pragma: no cover - public-API path, one matrix at a time
    for k in range(N):
        try:
            Lt[:, :, k] = np.linalg.cholesky(Ht[:, :, k])
        except np.linalg.LinAlgError:
            Lt[:, :, k] = np.nan
            bad[k] = True
    return Lt, bad


def _inertia_cholesky(Ht: np.ndarray, last: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Factor Ht + delta I with delta = 0 where Ht is positive definite, else the smallest of
    DELTA0 (or last / 3) x 8^k that factors. Returns (Lt, delta (N,))."""
    Lt, bad = _cholesky(Ht)
    delta = np.zeros(Ht.shape[-1])
    idx = np.flatnonzero(bad)
    if idx.size:
        dd = np.where(last[idx] > 0, np.maximum(DELTA_MIN, last[idx] * DELTA_SHRINK), DELTA0)
        diag = np.arange(Ht.shape[0])
        while idx.size:
            Hs = Ht[:, :, idx]
            Hs[diag, diag] += dd
            Ls, b = _cholesky(Hs)
            Lt[:, :, idx[~b]] = Ls[:, :, ~b]
            delta[idx[~b]] = dd[~b]
            idx, dd = idx[b], dd[b] * DELTA_GROW
    return Lt, delta


def _cho_solve(Lt: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve (L L^T) x = b for every window: Lt (n, n, N), b (n, N)."""
    n = b.shape[0]
    x = b.copy()
    for i in range(n):
        if i:
            x[i] -= np.einsum("kn,kn->n", Lt[i, :i], x[:i])
        x[i] /= Lt[i, i]
    for i in range(n - 1, -1, -1):
        if i < n - 1:
            x[i] -= np.einsum("kn,kn->n", Lt[i + 1:, i], x[i + 1:])
        x[i] /= Lt[i, i]
    return x


def _primal_step(su: np.ndarray, sl: np.ndarray, dq: np.ndarray, c: np.ndarray,
                 frac: float) -> np.ndarray:
    """Largest step <= 1 keeping every slack >= (1 - frac) x its value, per window.

    Along a step t dz the squared distance is q + t dq + t^2 c (c = |dv|^2 >= 0): the upper
    slack su - t dq - t^2 c is handled exactly (positive root), the lower slack sl + t dq +
    t^2 c >= sl + t dq linearly (a conservative bound). Arrays (P, N) -> (N,)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        ts = frac * su
        tu = 2.0 * ts / (dq + np.sqrt(dq * dq + 4.0 * c * ts))   # 2ts/0 = inf: never binds
        tl = frac * sl / np.maximum(-dq, 0.0)                      # dq >= 0: inf
    return np.minimum(1.0, np.minimum(tu.min(axis=0), tl.min(axis=0)))


def _dual_step(lam: np.ndarray, dlam: np.ndarray, frac: float) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -frac * lam / np.minimum(dlam, 0.0)                    # dlam >= 0: inf or nan
    return np.minimum(1.0, np.where(t > 0, t, np.inf).min(axis=0))


# ----------------------------------------------------------------------------- the iteration
def _barrier_solve(Y: np.ndarray, Wn: np.ndarray, Z0: np.ndarray, a: np.ndarray, eps: float,
                   maxiter: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The interior-point iteration (module docstring) for N windows, windows last.

    Y, Wn, Z0 : (d, m, N) targets (window means, centred), normalized weights (> 0), start
    strictly inside every band. a : (P,) pair distances (pairs of np.triu_indices(m, 1)).
    Returns Z (d, m, N), iterations (N,), converged (N,) bool. The working arrays hold the
    windows not yet converged (``idx``); a window leaves them when it passes the test.
    """
    d, m, N = Y.shape
    n = d * m
    I, J = np.triu_indices(m, 1)
    P = I.size
    S, ST = _pair_difference(m, I, J)
    absST = np.abs(ST)
    hi2, lo2 = ((a + eps) ** 2)[:, None], ((a - eps) ** 2)[:, None]
    a_max = float(a.max())
    frac = FRACTION_TO_BOUNDARY
    rows = np.arange(m)

    Z_out = Z0.copy()
    iters = np.zeros(N, dtype=int)
    conv = np.zeros(N, dtype=bool)
    # working set
    idx = np.arange(N)
    Z, Yw, Ww = Z0.copy(), Y, Wn
    V = S @ Z
    q = (V * V).sum(axis=0)
    su, sl = hi2 - q, q - lo2
    R = Z - Yw
    sc = (Ww * R * R).sum(axis=(0, 1)) + eps ** 2 * Ww.sum(axis=(0, 1))  # > 0 for any start
    tr = sc / (2 * P)
    tm = 0.1 * ATOL * tr
    ta = TAU0_FACTOR * np.abs(2.0 * Ww * R).max(axis=(0, 1)) * eps + ATOL * sc
    lu, ll = ta / su, ta / sl
    md = np.ones(N, dtype=bool)          # adaptive (Mehrotra) barrier rule still in use
    dprev = np.zeros(N)                   # last inertia correction

    for it in range(maxiter + 1):
        R = Z - Yw
        f = (Ww * R * R).sum(axis=(0, 1))
        G = 2.0 * Ww * R
        mu = lu - ll
        err_d = np.abs(G + ST @ (2.0 * mu * V)).max(axis=(0, 1)) * a_max
        cu, cl = lu * su, ll * sl
        gap = (cu + cl).sum(axis=0)
        tol = RTOL * f + ATOL * sc
        done = (gap <= tol) & (err_d <= tol)
        mono = ~md & ~done
        if mono.any():   # monotone rule: lower tau once the barrier problem is solved
            for _ in range(4):
                err_c = np.maximum(np.abs(cu - ta).max(axis=0), np.abs(cl - ta).max(axis=0))
                lower = mono & (np.maximum(err_d, err_c) <= KAPPA_EPS * ta) & (ta > tm)
                if not lower.any():
                    break
                ta = np.where(lower, np.maximum(tm, np.minimum(KAPPA_MU * ta,
                                                               tr * (ta / tr) ** THETA_MU)), ta)
        if done.any():
            Z_out[..., idx[done]] = Z[..., done]
            conv[idx[done]] = True
            keep = ~done
            idx = idx[keep]
            Z, Yw, Ww, V, G = (np.compress(keep, x, axis=-1) for x in (Z, Yw, Ww, V, G))
            lu, ll, su, sl, mu, cu, cl = (
                np.compress(keep, x, axis=-1) for x in (lu, ll, su, sl, mu, cu, cl))
            ta, tm, tr, sc, f, gap, md, dprev = (
                x[keep] for x in (ta, tm, tr, sc, f, gap, md, dprev))
        if idx.size == 0:
            break
        if it == maxiter:
            Z_out[..., idx] = Z
            break
        iters[idx] += 1
        k_ = idx.size
        isu, isl = 1.0 / su, 1.0 / sl
        sig = lu * isu + ll * isl

        # Hessian (d, m, d, m, k_) -> (n, n, k_): per pair the d x d block
        # B = 4 sig v v^T + 2 mu I on the pair's Laplacian, plus 2 W on the diagonal
        # (only the lower triangle is filled: the Cholesky factorization reads no other)
        H = np.empty((d, m, d, m, k_))
        for ca in range(d):
            for cb_ in range(ca + 1):
                Bab = (4.0 * sig) * V[ca] * V[cb_]
                blk = H[ca, :, cb_]
                blk[J, I] = -Bab                 # J > I: below the diagonal
                if ca == cb_:
                    Bab += 2.0 * mu
                    blk[J, I] -= 2.0 * mu
                    blk[rows, rows] = absST @ Bab + 2.0 * Ww[ca]
                else:
                    blk[I, J] = -Bab
                    blk[rows, rows] = absST @ Bab
        Lt, dl = _inertia_cholesky(H.reshape(n, n, k_), dprev)
        md = md & (dl == 0)

        def solve(coef: np.ndarray, G=G, V=V, Lt=Lt, k_=k_) -> tuple[np.ndarray, np.ndarray]:
            """dz for rhs -(grad f + sum coef grad q) and its pair differences."""
            rhs = G + ST @ (2.0 * coef * V)
            dz = -_cho_solve(Lt, rhs.reshape(n, k_)).reshape(d, m, k_)
            return dz, S @ dz

        corr_u: float | np.ndarray = 0.0
        corr_l: float | np.ndarray = 0.0
        if md.any():  # Mehrotra predictor: affine step (tau = 0)
            _, dva = solve(np.zeros_like(mu))
            dqa = 2.0 * (V * dva).sum(axis=0)
            dlu_a = -lu * (1.0 - dqa * isu)
            dll_a = -ll * (1.0 + dqa * isl)
            tp = _primal_step(su, sl, dqa, (dva * dva).sum(axis=0), 1.0)
            td = np.minimum(_dual_step(lu, dlu_a, 1.0), _dual_step(ll, dll_a, 1.0))
            mu_aff = ((su - tp * dqa) * (lu + td * dlu_a)
                      + (sl + tp * dqa) * (ll + td * dll_a)).sum(axis=0) / (2 * P)
            mu_cur = gap / (2 * P)
            sigma = np.clip(mu_aff / mu_cur, 0.0, 1.0) ** 3
            ta = np.where(md, np.maximum(sigma * mu_cur, tm), ta)
            corr_u = np.where(md, -dqa * dlu_a, 0.0)   # ds_aff * dlam_aff, upper slack
            corr_l = np.where(md, dqa * dll_a, 0.0)
        # centring (+ corrector) step: complementarity targets lam s + corr = tau
        dz, dv = solve(ta * (isu - isl) - corr_u * isu + corr_l * isl)
        dq = 2.0 * (V * dv).sum(axis=0)
        cq = (dv * dv).sum(axis=0)
        tp = _primal_step(su, sl, dq, cq, frac)
        dsu, dsl = -dq, dq.copy()
        if (tp < 1.0).any():   # second-order correction for the curvature of the distances
            rhs = ST @ (2.0 * sig * cq * V)
            dz2 = dz - _cho_solve(Lt, rhs.reshape(n, k_)).reshape(d, m, k_)
            dv2 = S @ dz2
            dq2 = 2.0 * (V * dv2).sum(axis=0)
            tp2 = _primal_step(su, sl, dq2, (dv2 * dv2).sum(axis=0), frac)
            better = tp2 > tp
            dz = np.where(better, dz2, dz)
            dsu = np.where(better, -cq - dq2, dsu)
            dsl = np.where(better, cq + dq2, dsl)
            tp = np.where(better, tp2, tp)
        dlu = (ta - cu - corr_u - lu * dsu) * isu
        dll = (ta - cl - corr_l - ll * dsl) * isl
        td = np.minimum(_dual_step(lu, dlu, frac), _dual_step(ll, dll, frac))

        # Armijo backtracking on the barrier function, re-evaluating rejected windows only
        slope = ((G + ST @ (2.0 * ta * (isu - isl) * V)) * dz).sum(axis=(0, 1))
        md = md & (slope < 0)
        slope = np.minimum(slope, 0.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            phi0 = f - ta * (np.log(su) + np.log(sl)).sum(axis=0)
            Zn = Z + tp * dz
            Vn = S @ Zn
            qn = (Vn * Vn).sum(axis=0)
            sun, sln = hi2 - qn, qn - lo2
            Rn = Zn - Yw
            phi = (Ww * Rn * Rn).sum(axis=(0, 1)) - ta * (np.log(sun) + np.log(sln)).sum(axis=0)
        ok = (phi <= phi0 + ARMIJO * tp * slope + 1e-14 * np.abs(phi0)) \
            & (sun > 0).all(axis=0) & (sln > 0).all(axis=0)
        md &= ok
        todo = np.flatnonzero(~ok)
        if todo.size:   # backtracking: all halvings 2^-1 .. 2^-HALVINGS at once per window
            frac_k = 0.5 ** np.arange(1, HALVINGS + 1)
            tk = tp[todo][:, None] * frac_k                          # (r, h)
            zt = np.take(Z, todo, axis=-1)[..., None] + tk * np.take(dz, todo, axis=-1)[..., None]
            vt = np.einsum("pm,dmrh->dprh", S, zt)
            qt = (vt * vt).sum(axis=0)
            ut, lt = hi2[..., None] - qt, qt - lo2[..., None]
            with np.errstate(divide="ignore", invalid="ignore"):
                rt = zt - np.take(Yw, todo, axis=-1)[..., None]
                ph = (np.take(Ww, todo, axis=-1)[..., None] * rt * rt).sum(axis=(0, 1)) \
                    - ta[todo, None] * (np.log(ut) + np.log(lt)).sum(axis=0)
            good = (ph <= phi0[todo, None] + ARMIJO * tk * slope[todo, None]
                    + 1e-14 * np.abs(phi0[todo, None])) & (ut > 0).all(axis=0) \
                & (lt > 0).all(axis=0)
            found = good.any(axis=1)
            h = np.argmax(good, axis=1)                              # the longest acceptable
            r = np.arange(todo.size)
            g, gr, gh = todo[found], r[found], h[found]
            Zn[..., g], Vn[..., g] = zt[..., gr, gh], vt[..., gr, gh]
            sun[:, g], sln[:, g] = ut[:, gr, gh], lt[:, gr, gh]
            tp[g] = tk[gr, gh]
            stuck = todo[~found]     # no acceptable step (e.g. non-finite values): stay
            if stuck.size:
                Zn[..., stuck], Vn[..., stuck] = Z[..., stuck], V[..., stuck]
                sun[:, stuck], sln[:, stuck] = su[:, stuck], sl[:, stuck]
                td[stuck] = 0.0
                dlu[:, stuck] = dll[:, stuck] = 0.0
        Z, V, su, sl = Zn, Vn, sun, sln
        lu = np.clip(lu + td * dlu, ta / (KAPPA_SIGMA * su), KAPPA_SIGMA * ta / su)
        ll = np.clip(ll + td * dll, ta / (KAPPA_SIGMA * sl), KAPPA_SIGMA * ta / sl)
        dprev = dl
    return Z_out, iters, conv


# ----------------------------------------------------------------------------- public
def _mirrored(Pc: np.ndarray, B: np.ndarray) -> np.ndarray:
    """(N,) True where the best orthogonal fit of the body B onto positions Pc (N, m, d) is
    improper (batched :func:`estimator.window._is_mirrored`)."""
    P0 = Pc - Pc.mean(axis=1, keepdims=True)
    M = np.einsum("nma,mb->nab", P0, B - B.mean(axis=0))
    if B.shape[1] == 2:
        proper = np.hypot(M[:, 0, 0] + M[:, 1, 1], M[:, 1, 0] - M[:, 0, 1])
        improper = np.hypot(M[:, 0, 0] - M[:, 1, 1], M[:, 0, 1] + M[:, 1, 0])
        return improper > proper * (1.0 + 1e-9) + 1e-12   # equal for collinear layouts
    U, Sv, Vt = np.linalg.svd(M)
    return (np.linalg.det(U @ Vt) < 0) & (Sv[:, -1] > 1e-12 * Sv[:, 0])


def _yaw(Pc: np.ndarray, config: SensorConfig) -> np.ndarray:
    """(N,) heading of the best unweighted rigid fit of the body onto positions (N, m, d), as
    fit_window reports it. d = 2: the closed form of procrustes_batch, window by window
    (elementwise, so a window's yaw does not depend on its batch); d = 3: procrustes_batch."""
    if config.d != 2:
        return procrustes_batch(Pc, np.ones(Pc.shape[:2]), config).yaw
    P0 = Pc - Pc.mean(axis=1, keepdims=True)
    Bc = config.body_positions - config.body_positions.mean(axis=0)
    m00, m01 = (P0[..., 0] * Bc[:, 0]).sum(axis=1), (P0[..., 0] * Bc[:, 1]).sum(axis=1)
    m10, m11 = (P0[..., 1] * Bc[:, 0]).sum(axis=1), (P0[..., 1] * Bc[:, 1]).sum(axis=1)
    return wrap_angle(np.arctan2(m10 - m01, m00 + m11))


def _pair_gaps(P_: np.ndarray, config: SensorConfig) -> np.ndarray:
    """(N, P) |p_i - p_j| - a_ij for positions (N, m, d)."""
    g = _geometry(config)
    diff = np.matmul(g.difference, P_)   # (P, m) @ (N, m, d): p_i - p_j exactly, 4x faster
    return np.sqrt((diff * diff).sum(axis=-1)) - g.a                     # than a gather


def _strictly_inside(P_: np.ndarray, config: SensorConfig, eps: float) -> np.ndarray:
    """(N,) True where every squared distance lies strictly inside its Eq. 3.6 band."""
    g = _geometry(config)
    diff = P_[:, g.I] - P_[:, g.J]
    q = (diff * diff).sum(axis=-1)
    with np.errstate(invalid="ignore"):
        return ((q < (g.a + eps) ** 2) & (q > (g.a - eps) ** 2)).all(axis=1)


def _to_last(x: np.ndarray) -> np.ndarray:
    """(N, m, d) -> (d, m, N) contiguous (windows last)."""
    return np.ascontiguousarray(x.transpose(2, 1, 0))


def _kernel_constants() -> np.ndarray:
    """The tuning constants in the order of :mod:`estimator.elastic_kernel`'s ``par``
    (read at each call, so the kernel and the reference share one definition)."""
    par = np.array([RTOL, ATOL, TAU0_FACTOR, FRACTION_TO_BOUNDARY, KAPPA_EPS, KAPPA_MU,
                    THETA_MU, KAPPA_SIGMA, DELTA0, DELTA_GROW, DELTA_SHRINK, DELTA_MIN, ARMIJO,
                    HALVINGS], dtype=float)
    assert par.size == N_PAR
    return par


def _solve(Tg: np.ndarray, Wn: np.ndarray, Z0: np.ndarray, a: np.ndarray, eps: float,
           maxiter: int, engine: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The iteration on (N, m, d) targets, weights, starts -> (Z (N, m, d), iterations (N,),
    converged (N,)): the compiled per-window loop or the batched numpy reference."""
    if engine == "numpy":
        Zt, it, conv = _barrier_solve(_to_last(Tg), _to_last(Wn), _to_last(Z0), a, eps,
                                      maxiter)
        return Zt.transpose(2, 1, 0), it, conv
    N, m, d = Tg.shape

    def flat(x: np.ndarray) -> np.ndarray:   # (N, m, d) -> (N, d m), coordinate-major
        return np.ascontiguousarray(x.transpose(0, 2, 1)).reshape(N, d * m)

    Z = flat(Z0)
    it, conv = barrier_kernel(flat(Tg), flat(Wn), Z, np.ascontiguousarray(a, dtype=float),
                              float(eps), int(maxiter), _kernel_constants(), d, m)
    return Z.reshape(N, d, m).transpose(0, 2, 1), it.astype(int), conv


def elastic_batch(means: Any, axis_weight: Any, config: SensorConfig, eps: float = 0.01, *,
                  start: Any | None = None, maxiter: int = MAXITER,
                  engine: str = "numba") -> ElasticFit:
    """Eq. 3.9 with the eps-elastic distance constraints of Eq. 3.6 for N windows at once.

    means : (N, m, d) metres, per-axis weighted window means (NaN where the axis weight is 0);
        axis_weight : (N, m, d) >= 0, the per-axis total weights (:func:`estimator.window.
        window_moments` gives both; isotropic weights repeat one value over the axes).
    eps : constraint slack in metres, 0 < eps < min_ij a_ij / 2 (Eq. 3.6).
    start : optional (N, m, d) starting positions; a window starts there when every distance
        is strictly inside its band, otherwise (and by default) from the procrustes fit.
    maxiter : iteration limit (the batch iterates until every window converged or reached it).
    engine : "numba" (default: the compiled per-window loop of :mod:`estimator.elastic_kernel`)
        or "numpy" (the batched reference, :func:`_barrier_solve`); the same iteration, fits
        equal to rounding (tests/test_elastic_kernel.py).

    Returns :class:`ElasticFit`. Method and tolerances: module docstring. Sensors (axes)
    without data stay in the problem with the proximal weight of slsqp; after the fit they
    are put back at their start when that keeps every distance in its band (as slsqp's).
    Raises ValueError or TypeError naming the argument for malformed input.
    """
    if not isinstance(config, SensorConfig):
        raise TypeError(f"config: expected a SensorConfig, got {type(config).__name__}")
    Y, W = check_window_means(means, axis_weight, config, "axis_weight", per_axis=True)
    e = _check_eps(eps, config)
    check_int(maxiter, "maxiter", lo=1)
    if engine not in ENGINES:
        raise ValueError(f"engine: must be one of {ENGINES}, got {engine!r}")
    N, m, d = Y.shape
    if start is not None:
        X0 = check_array(start, "start", allow_nan=True)
        if X0.shape != Y.shape:
            raise ValueError(f"start: expected shape {Y.shape}, got {X0.shape}")
    geo = _geometry(config)

    # procrustes start (isotropic reduction of the per-axis weights, estimator.window)
    full = np.all(W > 0, axis=-1)
    sw = np.where(full, W.mean(axis=-1), 0.0)
    proc = procrustes_batch(np.where(full[..., None], Y, np.nan), sw, config)
    ok = proc.status == "ok"
    pos = np.full((N, m, d), np.nan)
    obj = np.full(N, np.nan)
    obj0 = np.full(N, np.nan)
    iters = np.zeros(N, dtype=int)
    status = np.where(ok, "ok", "insufficient_data").astype(object)
    idx = np.flatnonzero(ok)
    if idx.size:
        Z0w = proc.positions[idx]
        if start is not None:
            own = np.isfinite(X0[idx]).all(axis=(1, 2))
            own[own] = _strictly_inside(X0[idx][own], config, e)
            Z0w = np.where(own[:, None, None], X0[idx], Z0w)
        c = Z0w.mean(axis=1, keepdims=True)               # centre: UTM-sized coordinates
        Z0 = Z0w - c
        Wi = W[idx]
        has = Wi > 0
        Yc = np.where(has, Y[idx] - c, 0.0)
        # normalized weights; axes without data: proximal term towards the start (window.py)
        Wn = np.where(has, Wi / Wi.sum(axis=(1, 2), keepdims=True), PROX_WEIGHT)
        Tg = np.where(has, Yc, Z0)
        Z, it, conv = _solve(Tg, Wn, Z0, geo.a, e, maxiter, engine)
        # sensors without data back at the start when every band still holds (as slsqp)
        none = ~np.any(has, axis=-1)
        if none.any():
            Zr = np.where(none[..., None], Z0, Z)
            back = none.any(axis=1) & (np.abs(_pair_gaps(Zr, config)) <= e).all(axis=1)
            Z = np.where(back[:, None, None], Zr, Z)

        def data_obj(P_: np.ndarray) -> np.ndarray:
            r = np.where(has, P_ - Yc, 0.0)
            return (Wi * r * r).sum(axis=(1, 2))

        f_sol, f_start = data_obj(Z), data_obj(Z0)
        finite = np.isfinite(Z).all(axis=(1, 2)) & np.isfinite(f_sol)
        # a converged iterate is within RTOL of the optimum; when the start is better still
        # (e.g. noise-free data, where the start is the optimum) the start is returned
        take = finite & (f_sol <= f_start)
        Zb = np.where(take[:, None, None], Z, Z0)
        mirrored = finite & _mirrored(Zb, config.body_positions)
        st = np.where(conv, "ok", "maxiter").astype(object)
        st[mirrored] = "fallback_mirrored"
        st[~finite] = "fallback_failed"
        fall = mirrored | ~finite
        Zb[fall] = proc.positions[idx][fall] - c[fall]
        pos[idx] = Zb + c
        obj[idx] = data_obj(Zb)
        obj0[idx] = f_start
        iters[idx] = it
        status[idx] = st
        yaw_c = _yaw(Zb, config)
    yaw = np.full(N, np.nan)
    viol = np.full(N, np.nan)
    if idx.size:
        yaw[idx] = yaw_c
        viol[idx] = np.abs(_pair_gaps(Zb, config)).max(axis=1)
    return ElasticFit(positions=pos, cg=config.cg_from_positions(pos), yaw=yaw, objective=obj,
                      start_objective=obj0, max_violation=viol, iterations=iters,
                      status=status.astype(str))


def warm_kernel() -> None:
    """Compile the iteration's kernel (first use after a checkout: ~10 s CPU on the 2-core
    machine) or load it from numba's cache (~0.2 s), on two 3-antenna windows. One
    compilation serves every layout and window count (the argument types do not change), so
    a process pool that warms its workers one at a time compiles once."""
    cfg = SensorConfig(("a", "b", "c"), np.array([[0.5, 0.25], [0.5, -0.25], [-0.5, 0.0]]))
    means = cfg.body_positions[None] + np.array([[[0.003, 0.0], [0.0, -0.004], [0.0, 0.0]],
                                                 [[0.0, 0.0], [0.0, 0.0], [0.0, 0.0]]])
    elastic_batch(means, np.ones(means.shape), cfg, 0.01)
