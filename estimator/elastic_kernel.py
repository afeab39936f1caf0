"""The eps-elastic window fit's interior-point iteration as one compiled loop (issue 27).

The same iteration as :func:`estimator.elastic._barrier_solve` (the numpy reference, batched
over the windows; its module docstring describes the method), written for one window at a
time and compiled with ``numba.njit(cache=True)``: every window runs the reference's steps
(the Hessian of the Lagrangian, the inertia-corrected Cholesky, Mehrotra's predictor-corrector
or the monotone barrier rule, the fraction-to-the-boundary step with its second-order
correction, Armijo backtracking over the halvings 2^-1 .. 2^-HALVINGS, the per-window
convergence test) in scalar loops over its n = d m coordinates and P pairs. The reference
spends most of its time in numpy calls on (n, n, N) arrays and in the iterations in which
only a few stragglers are left; here a window costs what its own iterations cost.

Numbers follow the reference up to the order of floating-point sums (the Cholesky
factorization and the products with the pair-difference matrix are summed in another order
than LAPACK and BLAS do), so iterates agree to rounding and the converged fits to the
convergence tolerance (tests/test_elastic_kernel.py states the bounds). The IEEE rules the
reference gets from numpy (x / 0 = inf, NaN propagating through minimum and maximum, the log
of a non-positive slack rejecting a step) are spelled out, so the code runs the same, only
slower, with ``NUMBA_DISABLE_JIT=1``. One difference: where no shift of the inertia
correction up to the largest float factors the Hessian (non-finite values; the reference loops
forever there) the factor is NaN, the step is rejected and the window stays where it is.

The tuning constants come with each call in ``par`` (read from :mod:`estimator.elastic`
then: one definition, and a compiled cache never holds stale values).
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["N_PAR", "barrier_kernel"]

#: indices of the constants in ``par`` (see :func:`barrier_kernel`)
(P_RTOL, P_ATOL, P_TAU0, P_FRAC, P_KEPS, P_KMU, P_THMU, P_KSIG, P_D0, P_DGROW, P_DSHRINK,
 P_DMIN, P_ARMIJO, P_HALVINGS) = range(14)
N_PAR = 14

INF = math.inf
NAN = math.nan

#: internal helpers: called from compiled code only (no CPython wrapper: less to compile)
#: error_model="numpy": a float division never checks for zero (x / 0 = inf as in the numpy
#: reference; the code divides by zero only through _div anyway), so no division can raise
#: and the call sites need fewer exception checks: bit-identical fits, ~4 % less CPU per
#: window (measured, issue 27; tests/test_elastic_kernel.py pins today's outputs)
_OPTS = {"cache": True, "nogil": True, "error_model": "numpy"}
_jit = numba.njit(no_cpython_wrapper=True, **_OPTS)  # type: ignore[call-overload]


@_jit
def _div(a, b):
    """a / b with IEEE semantics (x / 0 = +-inf, 0 / 0 = NaN) also without the JIT."""
    if b != 0.0 or a != a or b != b:
        return a / b
    if a == 0.0:
        return NAN
    return INF if (a > 0.0) == (math.copysign(1.0, b) > 0.0) else -INF


@_jit
def _min(a, b):
    """np.minimum: NaN when either is NaN."""
    if a != a or b != b:
        return NAN
    return min(b, a)


@_jit
def _max(a, b):
    """np.maximum: NaN when either is NaN."""
    if a != a or b != b:
        return NAN
    return max(b, a)


@_jit
def _sqrt(x):
    return math.sqrt(x) if x >= 0.0 else NAN


@_jit
def _copy(src, dst):
    """dst[:] = src for 1-D arrays (a loop: slice assignment compiles a shape check with a
    formatted message, a third of the compile time)"""
    for k in range(src.size):
        dst[k] = src[k]


@_jit
def _pairs(z, I, J, d, m, V):
    """V (d, P) = pair differences z_i - z_j of z (d * m,), coordinate ca at ca * m + i."""
    for ca in range(d):
        o = ca * m
        for p in range(I.size):
            V[ca, p] = z[o + I[p]] - z[o + J[p]]


@_jit
def _accumulate(x, I, J, d, m, out):
    """out (d * m,) += S^T x for pair terms x (d, P) (+ at sensor I[p], - at J[p])."""
    for ca in range(d):
        o = ca * m
        for p in range(I.size):
            out[o + I[p]] += x[ca, p]
            out[o + J[p]] -= x[ca, p]


@_jit
def _cholesky(A, L, rd, n):
    """Lower Cholesky factor of A (lower triangle read) into L, the reciprocals of its
    diagonal into rd; False where A is not positive definite (a pivot <= 0 or NaN, LAPACK's
    test)."""
    for j in range(n):
        s = A[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        if not s > 0.0:
            return False
        ljj = math.sqrt(s)
        L[j, j] = ljj
        r = 1.0 / ljj    # scaled by the reciprocal, as LAPACK's dpotf2
        rd[j] = r
        for i in range(j + 1, n):
            s = A[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s * r
    return True


@_jit
def _inertia_cholesky(H, A, L, rd, n, last, par):
    """Factor H + delta I with delta = 0 when H is positive definite, else the smallest of
    DELTA0 (or last / 3) x 8^k that factors (the reference's _inertia_cholesky). Returns
    delta; NaN in L when no finite shift factors."""
    if _cholesky(H, L, rd, n):
        return 0.0
    dd = max(par[P_DMIN], last * par[P_DSHRINK]) if last > 0.0 else par[P_D0]
    while dd < INF:
        for i in range(n):
            for j in range(i + 1):
                A[i, j] = H[i, j]
            A[i, i] += dd
        if _cholesky(A, L, rd, n):
            return dd
        dd *= par[P_DGROW]
    L[:, :] = NAN
    rd[:] = NAN
    return dd


@_jit
def _cho_solve(L, rd, b, x, n):
    """x = -(L L^T)^-1 b (the Newton direction for the gradient b); rd = 1 / diag(L)."""
    for i in range(n):
        s = b[i]
        for k in range(i):
            s -= L[i, k] * x[k]
        x[i] = s * rd[i]
    for i in range(n - 1, -1, -1):
        s = x[i]
        for k in range(i + 1, n):
            s -= L[k, i] * x[k]
        x[i] = s * rd[i]
    for i in range(n):
        x[i] = -x[i]


@_jit
def _primal_step(su, sl, dq, c, frac):
    """Largest step <= 1 keeping every slack >= (1 - frac) of its value (reference's
    _primal_step: exact root for the upper slacks, linear bound for the lower ones)."""
    t = 1.0
    for p in range(su.size):
        ts = frac * su[p]
        if not ts - dq[p] >= c[p]:   # else the root is >= 1 (ts > 0): it cannot bind
            t = _min(t, _div(2.0 * ts, dq[p] + _sqrt(dq[p] * dq[p] + 4.0 * c[p] * ts)))
        if dq[p] < 0.0:   # else frac sl / 0 = inf: never binds (a NaN dq makes tu NaN)
            t = _min(t, _div(frac * sl[p], -dq[p]))
    return t


@_jit
def _dual_step(lam, dlam, frac):
    t = 1.0
    for p in range(lam.size):
        r = _div(-frac * lam[p], _min(dlam[p], 0.0))
        if r > 0.0:
            t = _min(t, r)
    return t


@_jit
def _dq(V, dv, d, dq, c):
    """dq = 2 <v, dv> and c = |dv|^2 per pair."""
    for p in range(dq.size):
        s = 0.0
        s2 = 0.0
        for ca in range(d):
            s += V[ca, p] * dv[ca, p]
            s2 += dv[ca, p] * dv[ca, p]
        dq[p] = 2.0 * s
        c[p] = s2


@_jit
def _hessian(V, sig, mu, W, I, J, d, m, H):
    """Lower triangle of the Hessian of the Lagrangian plus the barrier terms (reference:
    per pair the d x d block 4 sig v v^T + 2 mu I on the pair's Laplacian, plus 2 W)."""
    n = d * m
    for i in range(n):
        for j in range(i + 1):
            H[i, j] = 0.0
    for ca in range(d):
        for cb in range(ca + 1):
            for p in range(I.size):
                b = 4.0 * sig[p] * V[ca, p] * V[cb, p]
                off = -b
                if ca == cb:
                    b += 2.0 * mu[p]
                    off -= 2.0 * mu[p]
                H[ca * m + J[p], cb * m + I[p]] = off
                if ca != cb:
                    H[ca * m + I[p], cb * m + J[p]] = -b
                H[ca * m + I[p], cb * m + I[p]] += b
                H[ca * m + J[p], cb * m + J[p]] += b
            if ca == cb:
                for i in range(m):
                    H[ca * m + i, ca * m + i] += 2.0 * W[ca * m + i]


@_jit
def _slacks(z, I, J, d, m, hi2, lo2, V, su, sl):
    """V, upper and lower slacks of the squared distances at z; True where all > 0."""
    _pairs(z, I, J, d, m, V)
    inside = True
    for p in range(I.size):
        q = 0.0
        for ca in range(d):
            q += V[ca, p] * V[ca, p]
        su[p] = hi2[p] - q
        sl[p] = q - lo2[p]
        if not (su[p] > 0.0 and sl[p] > 0.0):
            inside = False
    return inside


@_jit
def _logsum(su, sl):
    """sum log(slacks) (slacks > 0)."""
    s = 0.0
    for p in range(su.size):
        s += math.log(su[p]) + math.log(sl[p])
    return s


@_jit
def _objective(z, y, W):
    f = 0.0
    for k in range(z.size):
        r = z[k] - y[k]
        f += W[k] * r * r
    return f


@_jit
def _trial(z, dz, t, y, W, I, J, d, m, hi2, lo2, ta, bound, zt, Vt, sut, slt):
    """Take z + t dz into (zt, Vt, sut, slt). Returns (accepted, sum log slacks): accepted
    when it is strictly feasible and passes the Armijo test on the barrier function,
    phi <= bound (bound = phi0 + ARMIJO t slope + 1e-14 |phi0|)."""
    for k in range(z.size):
        zt[k] = z[k] + t * dz[k]
    if not _slacks(zt, I, J, d, m, hi2, lo2, Vt, sut, slt):
        return False, NAN
    ls = _logsum(sut, slt)
    return _objective(zt, y, W) - ta * ls <= bound, ls


@_jit
def _soc(L, V, sig, cq, dz, I, J, d, m, su, sl, frac, ws_v, ws_n, ws_p):
    """Second-order correction (reference): re-solve with the curvature |dv|^2 moved into
    the constraint residual; returns its step length tp2, with dz2 = dz - H^-1 S^T (2 sig cq v)
    in ws_n[1] and its dq in ws_p[0] (ws_n[2]: 1 / diag(L))."""
    tmp, dv2 = ws_v[0], ws_v[1]
    g, dz2, wn_rd = ws_n[0], ws_n[1], ws_n[2]
    dq2, cq2 = ws_p[0], ws_p[1]
    n = d * m
    for ca in range(d):
        for p in range(I.size):
            tmp[ca, p] = 2.0 * sig[p] * cq[p] * V[ca, p]
    g[:] = 0.0
    _accumulate(tmp, I, J, d, m, g)
    _cho_solve(L, wn_rd, g, dz2, n)
    for k in range(n):
        dz2[k] = dz[k] + dz2[k]
    _pairs(dz2, I, J, d, m, dv2)
    _dq(V, dv2, d, dq2, cq2)
    return _primal_step(su, sl, dq2, cq2, frac)


@_jit
def _newton_rhs(G, coef, V, I, J, d, m, tmp, g):
    """g = G + S^T (2 coef v) (the gradient of f + sum coef q)."""
    for ca in range(d):
        for p in range(I.size):
            tmp[ca, p] = 2.0 * coef[p] * V[ca, p]
    g[:] = 0.0
    _accumulate(tmp, I, J, d, m, g)
    for k in range(g.size):
        g[k] += G[k]


@_jit
def _monotone_tau(cu, cl, err_d, ta, tm, tr, par):
    """Monotone (Fiacco-McCormick) rule: lower tau, up to 4 times, while the barrier
    problem is solved to KAPPA_EPS tau (cu, cl: the complementarities lambda s)."""
    for _ in range(4):
        err_c = 0.0
        for p in range(cu.size):
            err_c = _max(err_c, _max(abs(cu[p] - ta), abs(cl[p] - ta)))
        if not (_max(err_d, err_c) <= par[P_KEPS] * ta and ta > tm):
            break
        ta = _max(tm, _min(par[P_KMU] * ta, tr * (ta / tr) ** par[P_THMU]))
    return ta


@_jit
def _predictor(su, sl, lu, ll, isu, isl, dqa, cqa, dlu, dll, gap, tm, cor_u, cor_l):
    """Mehrotra's rule from the affine step (dqa, cqa: its dq and |dv|^2 per pair): returns
    tau = (mu_aff / mu)^3 mu (at least tm); cor_u, cor_l = the second-order terms
    ds_aff dlam_aff of the upper / lower complementarity."""
    P = su.size
    for p in range(P):
        dlu[p] = -lu[p] * (1.0 - dqa[p] * isu[p])
        dll[p] = -ll[p] * (1.0 + dqa[p] * isl[p])
    tp = _primal_step(su, sl, dqa, cqa, 1.0)
    td = _min(_dual_step(lu, dlu, 1.0), _dual_step(ll, dll, 1.0))
    s = 0.0
    for p in range(P):
        s += ((su[p] - tp * dqa[p]) * (lu[p] + td * dlu[p])
              + (sl[p] + tp * dqa[p]) * (ll[p] + td * dll[p]))
    mu_aff = s / (2 * P)
    mu_cur = gap / (2 * P)
    sigma = _min(_max(_div(mu_aff, mu_cur), 0.0), 1.0) ** 3
    for p in range(P):
        cor_u[p] = -dqa[p] * dlu[p]
        cor_l[p] = dqa[p] * dll[p]
    return _max(sigma * mu_cur, tm)


@_jit
def _line_search(z, dz, tp, phi0, slope, y, W, I, J, d, m, hi2, lo2, ta, par, zn, Vn, sun,
                 sln):
    """Armijo test on the barrier function for the step tp, then 2^-1 .. 2^-HALVINGS of it;
    the accepted trial in (zn, Vn, sun, sln). Returns (the full step passed, some step
    passed, its sum log slacks)."""
    slack = 1e-14 * abs(phi0)
    ok, ls = _trial(z, dz, tp, y, W, I, J, d, m, hi2, lo2, ta,
                    phi0 + par[P_ARMIJO] * tp * slope + slack, zn, Vn, sun, sln)
    full = ok
    h = 0
    while not ok and h < par[P_HALVINGS]:
        h += 1
        t = tp * 0.5 ** h
        ok, ls = _trial(z, dz, t, y, W, I, J, d, m, hi2, lo2, ta,
                        phi0 + par[P_ARMIJO] * t * slope + slack, zn, Vn, sun, sln)
    return full, ok, ls


@_jit
def _window(y, W, z, a, eps, maxiter, par, I, J, d, m, wm, wv, wn, wp):
    """The reference iteration for one window: y, W, z (d m,) targets, normalized weights,
    start (strictly inside every band; overwritten with the last iterate); a (P,) pair
    distances. wm, wv, wn, wp: work arrays. Returns (iterations, converged)."""
    H, A, L = wm[0], wm[1], wm[2]
    V, Vn, tmp = wv[0], wv[1], wv[2]
    zn, G, g, dz, rd = wn[0], wn[1], wn[2], wn[3], wn[6]
    hi2, lo2, su, sl, sun, sln, lu, ll = wp[0], wp[1], wp[2], wp[3], wp[4], wp[5], wp[6], wp[7]
    mu, sig, isu, isl, dq, cq, dqa, cqa = wp[8], wp[9], wp[10], wp[11], wp[12], wp[13], wp[14], \
        wp[15]
    dlu, dll, cu, cl, cor_u, cor_l, dsu, dsl = wp[16], wp[17], wp[18], wp[19], wp[20], wp[21], \
        wp[22], wp[23]
    coef = wp[24]
    n = d * m
    P = I.size
    rtol, atol, frac, ks = par[P_RTOL], par[P_ATOL], par[P_FRAC], par[P_KSIG]
    a_max = -INF
    for p in range(P):
        hi2[p] = (a[p] + eps) ** 2
        lo2[p] = (a[p] - eps) ** 2
        a_max = max(a_max, a[p])
    _slacks(z, I, J, d, m, hi2, lo2, V, su, sl)
    sc = 0.0
    sw = 0.0
    gmax = 0.0
    for k in range(n):
        r = z[k] - y[k]
        sc += W[k] * r * r
        sw += W[k]
        gmax = _max(gmax, abs(2.0 * W[k] * r))
    sc += eps ** 2 * sw
    tr = sc / (2 * P)
    tm = 0.1 * atol * tr
    ta = par[P_TAU0] * gmax * eps + atol * sc
    for p in range(P):
        lu[p] = _div(ta, su[p])
        ll[p] = _div(ta, sl[p])
    logs = _logsum(su, sl)   # sum log(slacks) of the iterate (then of each accepted trial)
    md = True            # adaptive (Mehrotra) barrier rule still in use
    dprev = 0.0          # last inertia correction
    iters = 0
    for it in range(maxiter + 1):
        f = 0.0
        for k in range(n):
            r = z[k] - y[k]
            f += W[k] * r * r
            G[k] = 2.0 * W[k] * r
        for p in range(P):
            mu[p] = lu[p] - ll[p]
        _newton_rhs(G, mu, V, I, J, d, m, tmp, g)
        err_d = 0.0
        for k in range(n):
            err_d = _max(err_d, abs(g[k]))
        err_d *= a_max
        gap = 0.0
        for p in range(P):
            cu[p] = lu[p] * su[p]
            cl[p] = ll[p] * sl[p]
            gap += cu[p] + cl[p]
        tol = rtol * f + atol * sc
        if gap <= tol and err_d <= tol:
            return iters, True
        if not md:
            ta = _monotone_tau(cu, cl, err_d, ta, tm, tr, par)
        if it == maxiter:
            return iters, False
        iters += 1
        for p in range(P):
            isu[p] = _div(1.0, su[p])
            isl[p] = _div(1.0, sl[p])
            sig[p] = lu[p] * isu[p] + ll[p] * isl[p]
            cor_u[p] = 0.0
            cor_l[p] = 0.0
        _hessian(V, sig, mu, W, I, J, d, m, H)
        dl = _inertia_cholesky(H, A, L, rd, n, dprev, par)
        md = md and dl == 0.0
        if md:   # Mehrotra predictor: affine step (tau = 0)
            _cho_solve(L, rd, G, dz, n)
            _pairs(dz, I, J, d, m, tmp)
            _dq(V, tmp, d, dqa, cqa)
            ta = _predictor(su, sl, lu, ll, isu, isl, dqa, cqa, dlu, dll, gap, tm, cor_u,
                            cor_l)
        # centring (+ corrector) step: complementarity targets lam s + corr = tau
        for p in range(P):
            coef[p] = ta * (isu[p] - isl[p]) - cor_u[p] * isu[p] + cor_l[p] * isl[p]
        _newton_rhs(G, coef, V, I, J, d, m, tmp, g)
        _cho_solve(L, rd, g, dz, n)
        _pairs(dz, I, J, d, m, tmp)
        _dq(V, tmp, d, dq, cq)
        tp = _primal_step(su, sl, dq, cq, frac)
        for p in range(P):
            dsu[p] = -dq[p]
            dsl[p] = dq[p]
        if tp < 1.0:   # second-order correction for the curvature of the distances
            tp2 = _soc(L, V, sig, cq, dz, I, J, d, m, su, sl, frac, wv[3:], wn[4:], wp[25:])
            if tp2 > tp:
                _copy(wn[5], dz)
                dq2 = wp[25]
                for p in range(P):
                    dsu[p] = -cq[p] - dq2[p]
                    dsl[p] = cq[p] + dq2[p]
                tp = tp2
        for p in range(P):
            dlu[p] = (ta - cu[p] - cor_u[p] - lu[p] * dsu[p]) * isu[p]
            dll[p] = (ta - cl[p] - cor_l[p] - ll[p] * dsl[p]) * isl[p]
        td = _min(_dual_step(lu, dlu, frac), _dual_step(ll, dll, frac))

        # Armijo backtracking on the barrier function: the step, then 2^-1 .. 2^-HALVINGS
        for p in range(P):
            coef[p] = ta * (isu[p] - isl[p])
        _newton_rhs(G, coef, V, I, J, d, m, tmp, g)
        slope = 0.0
        for k in range(n):
            slope += g[k] * dz[k]
        md = md and slope < 0.0
        slope = _min(slope, 0.0)
        full, ok, ls = _line_search(z, dz, tp, f - ta * logs, slope, y, W, I, J, d, m, hi2,
                                    lo2, ta, par, zn, Vn, sun, sln)
        md = md and full
        if ok:
            logs = ls
            _copy(zn, z)
            _copy(sun, su)
            _copy(sln, sl)
            for ca in range(d):
                _copy(Vn[ca], V[ca])
        else:   # no acceptable step (e.g. non-finite values): stay
            td = 0.0
            for p in range(P):
                dlu[p] = 0.0
                dll[p] = 0.0
        for p in range(P):
            lu[p] = _min(_max(lu[p] + td * dlu[p], _div(ta, ks * su[p])),
                         _div(ks * ta, su[p]))
            ll[p] = _min(_max(ll[p] + td * dll[p], _div(ta, ks * sl[p])),
                         _div(ks * ta, sl[p]))
        dprev = dl
    return iters, False


@numba.njit(**_OPTS)  # type: ignore[call-overload]
def _windows(Y, Wn, Z, a, eps, maxiter, par, d, m, I, J, wm, wv, wn, wp, iters, conv):
    for w in range(Y.shape[0]):
        iters[w], conv[w] = _window(Y[w], Wn[w], Z[w], a, eps, maxiter, par, I, J, d, m,
                                    wm, wv, wn, wp)


def barrier_kernel(Y: np.ndarray, Wn: np.ndarray, Z: np.ndarray, a: np.ndarray, eps: float,
                   maxiter: int, par: np.ndarray, d: int, m: int
                   ) -> tuple[np.ndarray, np.ndarray]:
    """The interior-point iteration for N windows, one after the other.

    Y, Wn, Z : (N, d m) float, C-contiguous, coordinate ca of sensor i at ca m + i: targets
    (window means, centred), normalized weights (> 0), start strictly inside every band
    (overwritten with the result: the converged or the last iterate). a : (P,) pair
    distances in the order of np.triu_indices(m, 1). par : (N_PAR,) the constants of
    estimator.elastic. Returns iterations (N,) int64 and converged (N,) bool. (The work
    arrays are allocated here, outside the compiled code: less to compile.)
    """
    N, n = Y.shape
    I, J = (x.astype(np.int64) for x in np.triu_indices(m, 1))
    P = I.size
    iters = np.zeros(N, np.int64)
    conv = np.zeros(N, np.bool_)
    _windows(Y, Wn, Z, np.ascontiguousarray(a, dtype=float), float(eps), int(maxiter),
             np.ascontiguousarray(par, dtype=float), int(d), int(m), I, J,
             np.zeros((3, n, n)), np.zeros((5, d, P)), np.zeros((7, n)), np.zeros((27, P)),
             iters, conv)
    return iters, conv
