"""The pose filter's forward pass as one compiled loop (issue 27).

The same filter as :func:`estimator.pose_filter.run_pose_filter` with ``engine="numpy"`` (the
reference; module docstring of :mod:`estimator.pose_filter` for the model): CTRA prediction
with stochastic cloning, the iterated robust update (prior gate, deleted-residual test,
re-admission), the start and restart from the per-epoch rigid fits, the 10 s NIS window and
the heading check with its re-initialisation, the standstill hold, the flip logic and the
limits, all in one ``numba.njit(cache=True)`` function over plain arrays.

One change of arithmetic, not of the model: the update works in the 12-dimensional state
space instead of the 2k-dimensional measurement space (push-through identity, exact in exact
arithmetic). With ``N = H^T R^-1 H``, ``b = H^T R^-1 nu`` and ``M = I + N Y``:
``P+ = Y M^-1``, ``x+ = y + P+ b``, ``nu^T S^-1 nu = nu^T R^-1 nu - b^T P+ b``, and the
2 x 2 diagonal blocks of ``S^-1`` that the deleted-residual test needs are
``(R^-1)_ii - G_i P+ G_i^T`` with ``G = R^-1 H`` (``H^T S^-1 = M^-1 H^T R^-1``; for a
measurement uncorrelated with the others ``(I - H_i P+ H_i^T / r_i) / r_i``). R is the
reference's joint noise: diagonal, plus the covariance of a displacement and its own fix
when both are accepted (``fix_step_covariance``; :func:`_rinv` inverts each such pair).
A 12 x 12 solve replaces the inverse of the innovation covariance (up to 32 x 32 with eight
antennas), and a deletion costs a new 12 x 12 solve. ``M`` is invertible exactly when ``S``
is (Sylvester's determinant identity); a zero pivot counts as the reference's LinAlgError.

Chi-square quantiles of the NIS window come from a table the caller fills with
``scipy.special.chdtri`` (the reference's function) for every even number of degrees of
freedom the window can sum to (an epoch's own dof among them: the per-epoch test and the
winsorising read the same table). Runs unchanged, only slower, with ``NUMBA_DISABLE_JIT=1``.

Every per-epoch array is allocated once per pass (the kernels' buffers and :func:`_work`) and
written in place by the helpers, which are compiled without reference counting (``_jit``):
no allocation and no atomic refcount per epoch (tests/test_pose_filter_kernel.py checks the
first).
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["forward_kernel", "relinearised_kernel", "rts_kernel"]

# state layout: that of estimator.pose_filter (checked equal by the tests); the filter's
# tuning constants (INIT_MAX_YAW_SD, ...) come with each call in ``par``, read from
# estimator.pose_filter then, so there is one definition (and a test may patch it)
PX, PY, YAW, V, A, OMEGA = 0, 1, 2, 3, 4, 5
NX = 6
MAX_DELETED = 3
SERIES_BELOW = 1.0
TWO_PI = 2.0 * math.pi
#: status codes: indices into estimator.pose_filter.STATUSES
S_NO_DATA, S_WAITING, S_INIT, S_RESET, S_OK, S_PREDICTED, S_FLIP, S_REINIT, S_INCONS = (
    1, 2, 3, 4, 5, 6, 7, 8, 9)
#: indices of the scalar parameters in ``par`` (see :func:`forward_kernel`)
(I_SA, I_VA, I_VS, I_DTMED, I_GATE, I_FLIPTHR, I_QA, I_QY, I_OMMAX, I_ALAT, I_AMAX,
 I_VMAX, I_LEVER, I_FLIPDIST, I_VARMIN, I_FLIPMEM, I_THR1, I_REVERSE, I_MAXREJ,
 I_WINDOW, I_INIT_YAW_SD, I_INIT_SIGMAS, I_LOST_SD, I_FIT_SD, I_STAND_SIGMAS, I_REINIT_N,
 I_REINIT_YAW, I_MAXIT, I_PRIOR_RATIO, I_KAPPA, I_YACC) = range(31)
N_PAR = 31

#: internal helpers: called from compiled code only (no CPython wrapper: less to compile).
#: They allocate no arrays (the work arrays come from the caller), so they are compiled
#: without the runtime's reference counting (``_nrt=False``, as numba's own array helpers,
#: numba.misc.mergesort): an array argument costs no atomic incref / decref per call (they
#: were ~30 % of the forward pass on the car). The callers, which own the arrays, keep
#: them alive. The few helpers that allocate take :data:`_jit_nrt`. ``_nrt`` is a numba
#: internal (a CPU target option since 0.49, through 0.68 at least): a numba without it gets
#: the plain options, the same results with reference counting (:func:`jit_options`).
_JIT_OPTIONS = {"cache": True, "nogil": True, "no_cpython_wrapper": True}


def jit_options(target_options: type | None = None) -> dict[str, bool]:
    """The options of the helpers' ``numba.njit``: :data:`_JIT_OPTIONS` plus ``_nrt=False``
    when ``target_options`` (default numba's ``CPUTargetOptions``; a class, for the tests)
    declares ``_nrt``, else :data:`_JIT_OPTIONS` alone (numba may drop an internal)."""
    if target_options is None:
        try:
            from numba.core.cpu import CPUTargetOptions as target_options
        except ImportError:
            return dict(_JIT_OPTIONS)
    if hasattr(target_options, "_nrt"):
        return {**_JIT_OPTIONS, "_nrt": False}
    return dict(_JIT_OPTIONS)


_jit = numba.njit(**jit_options())  # type: ignore[call-overload]
_jit_nrt = numba.njit(**_JIT_OPTIONS)  # type: ignore[call-overload]


@_jit
def _wrap(a):
    """Angle to (-pi, pi], the reference's ``_wrap`` (same operations)."""
    if -math.pi < a <= math.pi:
        return a
    return math.pi - np.fmod(np.fmod(math.pi - a, TWO_PI) + TWO_PI, TWO_PI)


@_jit
def _pmax(a, b):
    """Python's ``max(a, b)`` (a unless b > a: NaN and -0.0 kept as Python keeps them)."""
    return b if b > a else a  # noqa: FURB136


@_jit
def _pmin(a, b):
    """Python's ``min(a, b)``."""
    return b if b < a else a  # noqa: FURB136


@_jit
def _vec(v, a0, a1, a2, a3, a4, a5):
    """v (6,) = (a0, ..., a5) in place (no list literal: array expressions and lists
    compile slowly)."""
    v[0], v[1], v[2], v[3], v[4], v[5] = a0, a1, a2, a3, a4, a5


@_jit
def _axpy(a, x, y, out):
    """out = a x + y for vectors (plain loop; out may be x or y)."""
    for i in range(y.shape[0]):
        out[i] = a * x[i] + y[i]


@_jit
def _zero(out, n, m):
    """out[:n, :m] = 0 (plain loops)."""
    for i in range(n):
        for j in range(m):
            out[i, j] = 0.0


@_jit
def _copy(a, out):
    """out[:] = a for vectors of a's length (plain loop)."""
    for i in range(a.shape[0]):
        out[i] = a[i]


@_jit
def _copy2(A, out):
    """out[:] = A for matrices of A's shape (plain loops)."""
    for i in range(A.shape[0]):
        for j in range(A.shape[1]):
            out[i, j] = A[i, j]


@_jit
def _anyrow(b, k):
    """Any of the bool row b[k]."""
    for i in range(b.shape[1]):  # noqa: SIM110 (a generator does not compile)
        if b[k, i]:
            return True
    return False


@_jit
def _count(b, lo, hi):
    """Number of True in b[lo:hi]."""
    c = 0
    for i in range(lo, hi):
        c += b[i]
    return c


@_jit
def _put(Xo, Po, k, y, Y, off):
    """Xo[k] = y[off:off + 6] and Po[k] = Y[off:off + 6, off:off + 6] (loops)."""
    for i in range(NX):
        Xo[k, i] = y[off + i]
        for j in range(NX):
            Po[k, i, j] = Y[off + i, off + j]


@_jit
def _nan_rows(XC, PC, PX_, k):
    """Row k of the clone outputs NaN."""
    for i in range(NX):
        XC[k, i] = math.nan
        for j in range(NX):
            PC[k, i, j] = math.nan
            PX_[k, i, j] = math.nan


@_jit
def _integrals(q, horner):
    """F1, F2, F3 of the CTRA motion (reference ``_integrals_scalar``, same operations);
    horner (10, 6): the series coefficients, highest power first."""
    aq = abs(q)
    if aq >= SERIES_BELOW:
        e = complex(math.cos(q), math.sin(q))
        iq = 1j * q
        f1 = (e - 1.0) / iq
        f2 = (e - f1) / iq
        return f1, f2, (e - 2.0 * f2) / iq
    half = 3 if aq < 0.01 else 5 if aq < 0.1 else 7 if aq < 0.5 else 10
    q2 = q * q
    r1 = r2 = r3 = i1 = i2 = i3 = 0.0
    for j in range(10 - half, 10):
        r1 = r1 * q2 + horner[j, 0]
        r2 = r2 * q2 + horner[j, 1]
        r3 = r3 * q2 + horner[j, 2]
        i1 = i1 * q2 + horner[j, 3]
        i2 = i2 * q2 + horner[j, 4]
        i3 = i3 * q2 + horner[j, 5]
    return complex(r1, q * i1), complex(r2, q * i2), complex(r3, q * i3)


@_jit
def _add_noise(Pn, c, s, v, dt, qa, qy, cw):
    """Process noise over dt added to Pn (6, 6) in place (reference ``_add_noise``, the same
    operations; the moments as tuples, no arrays allocated)."""
    ja = (qa / dt) if dt > 0 else 0.0
    jy = qy * dt
    pw = (1.0, dt, dt * dt)
    lat = (1.0, 1.0, v)
    qa_, qy_ = ja * dt, jy * dt
    ma00 = qa_ * cw[0, 0] * (pw[0] * pw[0])
    ma01 = qa_ * cw[0, 1] * (pw[0] * pw[1])
    ma10 = qa_ * cw[1, 0] * (pw[1] * pw[0])
    ma11 = qa_ * cw[1, 1] * (pw[1] * pw[1])
    ma20 = qa_ * cw[2, 0] * (pw[2] * pw[0])
    ma21 = qa_ * cw[2, 1] * (pw[2] * pw[1])
    ma22 = qa_ * cw[2, 2] * (pw[2] * pw[2])
    my00 = qy_ * cw[0, 0] * (pw[0] * pw[0]) * (lat[0] * lat[0])
    my01 = qy_ * cw[0, 1] * (pw[0] * pw[1]) * (lat[0] * lat[1])
    my10 = qy_ * cw[1, 0] * (pw[1] * pw[0]) * (lat[1] * lat[0])
    my11 = qy_ * cw[1, 1] * (pw[1] * pw[1]) * (lat[1] * lat[1])
    my20 = qy_ * cw[2, 0] * (pw[2] * pw[0]) * (lat[2] * lat[0])
    my21 = qy_ * cw[2, 1] * (pw[2] * pw[1]) * (lat[2] * lat[1])
    my22 = qy_ * cw[2, 2] * (pw[2] * pw[2]) * (lat[2] * lat[2])
    # along: (a, v) = (A, V) rows of Ma; yaw: (omega, yaw) = (OMEGA, YAW) rows of My
    Pn[A, A] += ma00
    Pn[A, V] += ma01
    Pn[V, A] += ma10
    Pn[V, V] += ma11
    Pn[PX, A] += c * ma20
    Pn[A, PX] += c * ma20
    Pn[PY, A] += s * ma20
    Pn[A, PY] += s * ma20
    Pn[PX, V] += c * ma21
    Pn[V, PX] += c * ma21
    Pn[PY, V] += s * ma21
    Pn[V, PY] += s * ma21
    Pn[OMEGA, OMEGA] += my00
    Pn[OMEGA, YAW] += my01
    Pn[YAW, OMEGA] += my10
    Pn[YAW, YAW] += my11
    Pn[PX, OMEGA] -= s * my20
    Pn[OMEGA, PX] -= s * my20
    Pn[PY, OMEGA] += c * my20
    Pn[OMEGA, PY] += c * my20
    Pn[PX, YAW] -= s * my21
    Pn[YAW, PX] -= s * my21
    Pn[PY, YAW] += c * my21
    Pn[YAW, PY] += c * my21
    Pn[PX, PX] += c * c * ma22 + s * s * my22
    Pn[PY, PY] += s * s * ma22 + c * c * my22
    Pn[PX, PY] += c * s * (ma22 - my22)
    Pn[PY, PX] += c * s * (ma22 - my22)


@_jit
def _matmul(Aa, Bb, out):
    """out = Aa @ Bb for 6 x 6 matrices (plain loops of constant length, which the compiler
    unrolls: no BLAS call overhead; out not Aa or Bb)."""
    _zero(out, NX, NX)
    for i in range(NX):
        for p in range(NX):
            a = Aa[i, p]
            if a != 0.0:
                for j in range(NX):
                    out[i, j] += a * Bb[p, j]


@_jit
def _matmul_bt(Aa, Bb, out):
    """out = Aa @ Bb.T for 6 x 6 matrices (the same sums in the same order as
    :func:`_matmul` of Aa and a transposed copy of Bb, without the copy; out not Aa or
    Bb)."""
    _zero(out, NX, NX)
    for i in range(NX):
        for p in range(NX):
            a = Aa[i, p]
            if a != 0.0:
                for j in range(NX):
                    out[i, j] += a * Bb[j, p]


@_jit
def _predict(x, P, dt, qa, qy, horner, cw, xn, Pn, FP, F):
    """CTRA prediction (reference ``_predict``) into xn (6,), Pn (6, 6) (P') and FP (6, 6)
    (F P); F (6, 6) receives the transition matrix (none of them x or P)."""
    px, py, yaw, v, acc, om = x[0], x[1], x[2], x[3], x[4], x[5]
    f1, f2, f3 = _integrals(om * dt, horner)
    rot = complex(math.cos(yaw), math.sin(yaw))
    d = rot * (v * dt * f1 + acc * dt * dt * f2)
    dv = rot * dt * f1
    da = rot * dt * dt * f2
    dq = rot * 1j * (v * dt * f2 + acc * dt * dt * f3) * dt
    _zero(F, NX, NX)
    for i in range(NX):
        F[i, i] = 1.0
    F[PX, YAW], F[PY, YAW] = -d.imag, d.real
    F[PX, V], F[PY, V] = dv.real, dv.imag
    F[PX, A], F[PY, A] = da.real, da.imag
    F[PX, OMEGA], F[PY, OMEGA] = dq.real, dq.imag
    F[YAW, OMEGA] = dt
    F[V, A] = dt
    _matmul(F, P, FP)
    _matmul_bt(FP, F, Pn)
    _add_noise(Pn, rot.real, rot.imag, v, dt, qa, qy, cw)
    _vec(xn, px + d.real, py + d.imag, _wrap(yaw + om * dt), v + acc * dt, acc, om)


#: The stacked state's components a measurement involves (position and heading of x_k and
#: x_{k-1}): the Jacobians are stored over these six columns only.
COLS = (PX, PY, YAW, NX + PX, NX + PY, NX + YAW)
NC = 6


@_jit
def _measure(yl, rr, nfix, k, h, H):
    """Predicted measurements h[:k] (k, 2) and Jacobian H[:2k] (2k, 6) over :data:`COLS`
    at the stacked state yl (12,) for the lever arms rr[:k] (k, 2): the first ``nfix`` are
    fixes, the rest displacements (reference ``_fill_measurements``, same operations)."""
    c, s = math.cos(yl[YAW]), math.sin(yl[YAW])
    cp, sp = math.cos(yl[NX + YAW]), math.sin(yl[NX + YAW])
    _zero(H, 2 * k, NC)
    for i in range(k):
        ax, ay = rr[i, 0], rr[i, 1]
        rx = c * ax - s * ay
        ry = s * ax + c * ay
        H[2 * i, 0] = 1.0
        H[2 * i + 1, 1] = 1.0
        H[2 * i, 2] = -ry
        H[2 * i + 1, 2] = rx
        if i < nfix:
            h[i, 0] = yl[PX] + rx
            h[i, 1] = yl[PY] + ry
        else:
            qx = cp * ax - sp * ay
            qy = sp * ax + cp * ay
            h[i, 0] = yl[PX] - yl[NX + PX] + rx - qx
            h[i, 1] = yl[PY] - yl[NX + PY] + ry - qy
            H[2 * i, 3] = -1.0
            H[2 * i + 1, 4] = -1.0
            H[2 * i, 5] = qy
            H[2 * i + 1, 5] = -qx


@_jit
def _col(j):
    """Column of the stacked state for measured column j (:data:`COLS`)."""
    return j if j < 3 else j + 3


@_jit
def _sub(Y, Yr, Yc):
    """Y's rows :data:`COLS` into Yr (6, 12) and their (6, 6) block into Yc."""
    for i in range(NC):
        for j in range(2 * NX):
            Yr[i, j] = Y[_col(i), j]
        for j in range(NC):
            Yc[i, j] = Y[_col(i), _col(j)]


@_jit
def _subc(Y, Yc):
    """Y's (6, 6) block at :data:`COLS` into Yc (:func:`_sub`'s second array alone)."""
    for i in range(NC):
        for j in range(NC):
            Yc[i, j] = Y[_col(i), _col(j)]


@_jit
def _hdot(H, r, d):
    """Row r of H (6 columns) times the stacked vector d (12,) at :data:`COLS`."""
    s = 0.0
    for j in range(NC):
        s += H[r, j] * d[_col(j)]
    return s


@_jit
def _xcol(j, wide):
    """Column of the j-th possibly non-zero entry of a measurement's x row (:func:`_measure`):
    a fix's (0, 2), a displacement's (0, 2, 3, 5)."""
    return j + (j + 1) // 2 if wide else 2 * j


@_jit
def _ycol(j, wide):
    """Column of the j-th possibly non-zero entry of a measurement's y row: a fix's (1, 2),
    a displacement's (1, 2, 4, 5)."""
    return j + 1 + j // 2 if wide else j + 1


@_jit
def _block_n(H, Yc, r0, r1, n, wide):
    """:func:`_block` over the rows' first n possibly non-zero columns."""
    a = b = c = 0.0
    for jp in range(n):
        p = _xcol(jp, wide)
        h0 = H[r0, p]
        for jq in range(n):
            q = _xcol(jq, wide)
            a += h0 * Yc[p, q] * H[r0, q]
        for jq in range(n):
            q = _ycol(jq, wide)
            b += h0 * Yc[p, q] * H[r1, q]
    for jp in range(n):
        p = _ycol(jp, wide)
        h1 = H[r1, p]
        for jq in range(n):
            q = _ycol(jq, wide)
            c += h1 * Yc[p, q] * H[r1, q]
    return a, b, c


@_jit
def _block(H, Yc, i, wide):
    """The 2 x 2 block H_i Yc H_i^T (a, b, c) of measurement i (Yc over :data:`COLS`): a
    fix's (``wide`` False) or a displacement's (True; also any row of ``G = R^-1 H``, a fix's
    mixed with its displacement's) Jacobian rows, zero outside the columns of :func:`_xcol`
    and :func:`_ycol`. Each sum takes its terms in the order of the full double loop over
    (p, q) and leaves out only the terms that are zero by that structure: adding a zero to a
    sum begun at 0.0 changes no bit (finite Yc), and the chains of dependent additions,
    which bound this loop, shrink from 36 terms to 4 (a fix) or 16 (a displacement)."""
    if wide:
        return _block_n(H, Yc, 2 * i, 2 * i + 1, 4, True)
    return _block_n(H, Yc, 2 * i, 2 * i + 1, 2, False)


@_jit
def _quad(a, b, c, ex, ey):
    """e^T [[a, b], [b, c]]^-1 e."""
    return (c * ex * ex - 2.0 * b * ex * ey + a * ey * ey) / (a * c - b * b)


@_jit
def _solve_inplace(Mm, B):
    """Solve Mm X = B (n, n), (n, r) in place by Gaussian elimination with partial pivoting;
    B receives X. False on a zero or non-finite pivot (the reference's LinAlgError). Sizes
    NC x NC and NC x (2 NX + 1) (:func:`_posterior`'s), constants the compiler unrolls; the
    back substitution subtracts row by row, each element's terms in the order of the dot
    product ``B[col] - sum_p Mm[col, p] B[p]`` (the same bits)."""
    n = NC
    r = 2 * NX + 1
    for col in range(n):
        piv = col
        best = abs(Mm[col, col])
        for i in range(col + 1, n):
            v = abs(Mm[i, col])
            if v > best:
                best, piv = v, i
        if not (best > 0.0 and best < math.inf):
            return False
        if piv != col:
            for j in range(n):
                Mm[col, j], Mm[piv, j] = Mm[piv, j], Mm[col, j]
            for j in range(r):
                B[col, j], B[piv, j] = B[piv, j], B[col, j]
        d = Mm[col, col]
        for i in range(col + 1, n):
            f = Mm[i, col] / d
            if f != 0.0:
                for j in range(col + 1, n):
                    Mm[i, j] -= f * Mm[col, j]
                for j in range(r):
                    B[i, j] -= f * B[col, j]
    for col in range(n - 1, -1, -1):
        d = Mm[col, col]
        for p in range(col + 1, n):
            mp = Mm[col, p]
            for j in range(r):
                B[col, j] -= mp * B[p, j]
        for j in range(r):
            B[col, j] = B[col, j] / d
    return True


@_jit
def _rinv_row(G, g, rd, H, v, i, o, wi, wo):
    """Row i of R^-1 applied to [H | v]: wi times measurement i's rows plus wo times
    measurement o's (:func:`_rinv`); rd[i] = wi."""
    rd[i] = wi
    for a in range(2):
        g[i, a] = wi * v[i, a] + wo * v[o, a]
        for c in range(NC):
            G[2 * i + a, c] = wi * H[2 * i + a, c] + wo * H[2 * o + a, c]


@_jit
def _rinv(H, v, var, acc, nfix, pos, nd, cv, k, G, g, rd):
    """The joint noise's inverse over the accepted measurements of the first k applied to
    their Jacobian rows H (2k, 6) and values v (k, 2), into G = R^-1 H (2k, 6),
    g = R^-1 v (k, 2) and rd, the diagonal of R^-1 (k,), 0 where not accepted. R: var (k,)
    per axis on the diagonal, cv between displacement j < nd (measurement nfix + j) and
    its fix pos[j] when both are accepted (reference: ``_kalman_update``'s ``cross``; each
    such pair per axis inverted as a 2 x 2)."""
    _zero(G, 2 * k, NC)
    _zero(g, k, 2)
    for i in range(k):
        rd[i] = 0.0
    for i in range(k):
        if acc[i]:
            _rinv_row(G, g, rd, H, v, i, i, 1.0 / var[i], 0.0)
    for j in range(nd):
        f, d = pos[j], nfix + j
        if acc[f] and acc[d]:
            det = var[f] * var[d] - cv * cv
            _rinv_row(G, g, rd, H, v, f, d, var[d] / det, -cv / det)
            _rinv_row(G, g, rd, H, v, d, f, var[f] / det, -cv / det)


@_jit
def _rinv_vec(v, var, acc, nfix, pos, nd, cv, k, g):
    """g = R^-1 v (k, 2) alone, the operations of :func:`_rinv`'s g (each row
    ``wi v_i + wo v_o``, a lone measurement's with wo = 0.0), for a G = R^-1 H already
    formed for the same accepted set."""
    _zero(g, k, 2)
    for i in range(k):
        if acc[i]:
            wi = 1.0 / var[i]
            for a in range(2):
                g[i, a] = wi * v[i, a] + 0.0 * v[i, a]
    for j in range(nd):
        f, d = pos[j], nfix + j
        if acc[f] and acc[d]:
            det = var[f] * var[d] - cv * cv
            wf, wd, wo = var[d] / det, var[f] / det, -cv / det
            for a in range(2):
                g[f, a] = wf * v[f, a] + wo * v[d, a]
            for a in range(2):
                g[d, a] = wd * v[d, a] + wo * v[f, a]


@_jit
def _posterior(Y, H, nu, var, acc, nfix, pos, nd, cv, k, w):
    """The joint update over the accepted measurements of the first k in the measured
    columns (module docstring), solved: with ``N = H^T R^-1 H``, ``b = H^T R^-1 nu``
    (6 columns; R^-1 from :func:`_rinv`) and ``M = I + N Y_cc``, Z = M^-1 [N Y_c: | b]
    (6, 13) into the work arrays ``w`` (:func:`_work`; Z is ``w[8]``); returns
    ``b^T Y_cc M^-1 b``, ok (False on a zero pivot) and ``nu^T R^-1 nu`` (for the NIS).
    P+ = Y - Y_:c Z[:, :12] (:func:`_cov_full`, :func:`_cov_cc`), the step dx = Y_:c
    Z[:, 12] (:func:`_step`)."""
    G, g, rd, N, b, Yr, Yc, Mm, Z = w[0], w[1], w[2], w[3], w[4], w[5], w[6], w[7], w[8]
    n = 2 * NX
    nc = NC
    _rinv(H, nu, var, acc, nfix, pos, nd, cv, k, G, g, rd)
    _zero(N, nc, nc)
    for p in range(nc):
        b[p] = 0.0
    nrn = 0.0
    for i in range(k):
        if not acc[i]:
            continue
        for j in range(2):
            r = 2 * i + j
            e = g[i, j]
            nrn += nu[i, j] * e
            for p in range(nc):
                hp = H[r, p]
                if hp == 0.0:
                    continue
                b[p] += hp * e
                for q in range(nc):
                    N[p, q] += hp * G[r, q]
    _sub(Y, Yr, Yc)
    _matmul(N, Yc, Mm)
    for p in range(nc):
        Mm[p, p] += 1.0
        # Z[p, :n] = N[p] Yr: each element's sum 0.0 + N[p, 0] Yr[0, j] + ... in order,
        # accumulated row by row (independent elements: the compiler vectorises)
        for j in range(n):
            Z[p, j] = 0.0
        for q in range(nc):
            npq = N[p, q]
            for j in range(n):
                Z[p, j] += npq * Yr[q, j]
        Z[p, n] = b[p]
    ok = _solve_inplace(Mm, Z)
    byb = 0.0
    for p in range(nc):
        s = 0.0
        for q in range(nc):
            s += Yc[p, q] * Z[q, n]
        byb += b[p] * s
    return byb, ok, nrn


@_jit_nrt
def _work(kmax):
    """The update's work arrays for up to kmax measurements (allocated once per pass):
    G (2 kmax, 6), g (kmax, 2), rd (kmax,) (:func:`_rinv`), N (6, 6), b (6,), Yr (6, 12),
    Yc (6, 6), Mm (6, 6), Z (6, 13) (:func:`_posterior`), the gate's Yc (6, 6), dx (12,),
    Pc (6, 6), residuals (kmax, 2) (:func:`_kalman_update`, :func:`_worst`), an all-True
    acc (kmax,); yl (12,), h (kmax, 2), H (2 kmax, 6), nu (kmax, 2), d (12,), dd (12,) and
    Y1c (6, 6) (:func:`_iterated_update`). Every value but the all-True acc's is written
    before it is read."""
    n = 2 * NX
    return (np.zeros((2 * kmax, NC)), np.zeros((kmax, 2)), np.zeros(kmax),
            np.zeros((NC, NC)), np.zeros(NC), np.zeros((NC, n)), np.zeros((NC, NC)),
            np.zeros((NC, NC)), np.zeros((NC, n + 1)), np.zeros((NC, NC)), np.zeros(n),
            np.zeros((NC, NC)), np.zeros((kmax, 2)), np.ones(kmax, dtype=np.bool_),
            np.zeros(n), np.zeros((kmax, 2)), np.zeros((2 * kmax, NC)), np.zeros((kmax, 2)),
            np.zeros(n), np.zeros(n), np.zeros((NC, NC)))


@_jit_nrt
def _pass_buffers(m):
    """A pass's per-epoch buffers for m antennas, allocated once (forward and relinearised
    kernels): the stacked prior y (12,), Y (12, 12) and posterior y1, Y1; the measurements
    rr, z (2 m, 2), var (2 m,), the index arrays ik, js, pos (m,) and acc (2 m,); the
    update's work arrays :func:`_work` (2 m)."""
    n = 2 * NX
    return (np.zeros(n), np.zeros((n, n)), np.zeros(n), np.zeros((n, n)),
            np.zeros((2 * m, 2)), np.zeros((2 * m, 2)), np.zeros(2 * m),
            np.zeros(m, dtype=np.int64), np.zeros(m, dtype=np.int64),
            np.zeros(m, dtype=np.int64), np.zeros(2 * m, dtype=np.bool_), _work(2 * m))


@_jit
def _step(Y, Z, dx):
    """dx (12,) = Y_:c Z[:, -1]: the update's step of the stacked state."""
    n = 2 * NX
    for i in range(n):
        dx[i] = 0.0
    for i in range(n):
        for p in range(NC):
            yip = Y[i, _col(p)]
            if yip != 0.0:
                dx[i] += yip * Z[p, n]


@_jit
def _cov_cc(Y, Z, Pc):
    """P+ over the measured columns into Pc (6, 6): Y_cc - Y_cc Z[:, c]."""
    for a in range(NC):
        for b in range(NC):
            s = Y[_col(a), _col(b)]
            for p in range(NC):
                yip = Y[_col(a), _col(p)]
                if yip != 0.0:
                    s -= yip * Z[p, _col(b)]
            Pc[a, b] = s


@_jit
def _cov_full(Y, Z, Pa):
    """P+ = Y - Y_:c Z[:, :12] into Pa (12, 12, not Y), symmetrised."""
    n = 2 * NX
    _copy2(Y, Pa)
    for i in range(n):
        for p in range(NC):
            yip = Y[i, _col(p)]
            if yip != 0.0:
                for j in range(n):
                    Pa[i, j] -= yip * Z[p, j]
    for i in range(n):            # symmetrised in place: the same values as a new array
        for j in range(i + 1, n):
            v = 0.5 * (Pa[i, j] + Pa[j, i])
            Pa[i, j] = v
            Pa[j, i] = v
        Pa[i, i] = 0.5 * (Pa[i, i] + Pa[i, i])


@_jit
def _sym_cc(Pc, Yc):
    """Yc (6, 6) = the symmetrised Pc, as :func:`_cov_full` symmetrises P+ (the mean of the
    two unsymmetrised entries; the diagonal ``0.5 (p + p)``): P+ over the measured columns
    without forming all of it."""
    for a in range(NC):
        for b in range(NC):
            Yc[a, b] = 0.5 * (Pc[a, b] + Pc[b, a])


@_jit
def _kalman_update(y, Y, nu, H, var, gate, acc, gated, want_nis, nfix, pos, nd, cv, k, yo,
                   w):
    """Reference ``_kalman_update`` in the state space over the first k measurements: prior
    gate (``gated``: acc from the prior's blocks, else the caller's acc), deleted-residual
    test, joint update; the joint noise of :func:`_rinv` (nfix, pos, nd, cv); w the work
    arrays (:func:`_work`). Returns (nis (NaN unless want_nis), ok, pc): when ok and any
    measurement is accepted the posterior state goes to yo (12,) (not y) and its covariance
    is left as Z (``w[8]``, :func:`_posterior`) for the caller to form (:func:`_cov_full`,
    only for the iteration it keeps); pc: the work array Pc (``w[11]``) holds that
    covariance's measured block before symmetrising (:func:`_cov_cc`, the deletion test's).
    Otherwise the reference's posterior is the prior y, Y and yo is untouched."""
    Z, Yg, dx, Pc, ones = w[8], w[9], w[10], w[11], w[13]
    nis = math.nan
    finite_gate = gate != math.inf
    have_all = False            # Z holds the update with every measurement
    if want_nis:
        byb, ok, nrn = _posterior(Y, H, nu, var, ones, nfix, pos, nd, cv, k, w)
        if not ok:
            return nis, False, False
        have_all = True
        nis = nrn - byb
    if gated:
        _subc(Y, Yg)
        for i in range(k):
            if finite_gate:
                a, bb, c = _block(H, Yg, i, i >= nfix)
                acc[i] = _quad(a + var[i], bb, c + var[i], nu[i, 0], nu[i, 1]) <= gate
            else:
                acc[i] = True
    deletions = MAX_DELETED if finite_gate else 0
    while _count(acc, 0, k):
        if not (have_all and _count(acc, 0, k) == k):   # else: the NIS pass's update
            _, ok, _ = _posterior(Y, H, nu, var, acc, nfix, pos, nd, cv, k, w)
            if not ok:
                return nis, False, False
        _step(Y, Z, dx)
        pc = False
        if deletions and _count(acc, 0, k) >= 2:
            _cov_cc(Y, Z, Pc)
            pc = True
            worst, wstat = _worst(Pc, dx, H, nu, var, acc, nfix, pos, nd, cv, k, w)
            if wstat > gate:
                acc[worst] = False
                deletions -= 1
                continue
        _axpy(1.0, dx, y, yo)
        return nis, True, pc
    return nis, True, False


@_jit
def _worst(Pc, dx, H, nu, var, acc, nfix, pos, nd, cv, k, w):
    """The deleted-residual test (reference test 2) over the first k measurements: the
    accepted measurement with the largest ``u_i^T ((S^-1)_ii)^-1 u_i``, with
    ``u = S^-1 nu = R^-1 (nu - H dx)`` and ``(S^-1)_ii = (R^-1)_ii - G_i P+ G_i^T``,
    ``G = R^-1 H`` (Pc: P+ over the measured columns); returns (index, statistic). G and
    rd, the diagonal of R^-1, are the work arrays' (``w[0]``, ``w[2]``) as the update's
    :func:`_posterior` left them for the same accepted set (:func:`_kalman_update` calls
    this right after it); u is :func:`_rinv_vec`'s."""
    G, u, rd, res = w[0], w[1], w[2], w[12]
    for i in range(k):
        res[i, 0] = nu[i, 0] - _hdot(H, 2 * i, dx)
        res[i, 1] = nu[i, 1] - _hdot(H, 2 * i + 1, dx)
    _rinv_vec(res, var, acc, nfix, pos, nd, cv, k, u)
    worst, wstat = -1, -math.inf
    for i in range(k):
        if not acc[i]:
            continue
        a, bb, c = _block(G, Pc, i, True)
        st = _quad(rd[i] - a, -bb, rd[i] - c, u[i, 0], u[i, 1])
        if st > wstat:
            worst, wstat = i, st
    return worst, wstat


@_jit
def _iterated_update(y, Y, z, rr, nfix, var, gate, lever, tol, maxit, hold, pos, nd, cv, k,
                     acc, y1, Y1, w):
    """Reference ``_iterated_update`` over the first k measurements: returns (prior NIS,
    ok); acc (k,) receives the accepted ones and y1 (12,), Y1 (12, 12) the posterior when
    any is (otherwise the reference's result is the prior y, Y and y1, Y1 hold no
    result); pos, nd, cv: the joint noise (:func:`_rinv`); w the work arrays
    (:func:`_work`)."""
    yl, h, H, nu, d, dd, Y1c = w[14], w[15], w[16], w[17], w[18], w[19], w[20]
    Z, Pc = w[8], w[11]
    pc = False
    _copy(y, yl)
    for i in range(k):
        acc[i] = False
    nis = math.nan
    for it in range(maxit):
        _measure(yl, rr, nfix, k, h, H)
        if hold:
            for i in range(nfix):
                H[2 * i, 2] = 0.0
                H[2 * i + 1, 2] = 0.0
        for i in range(k):
            nu[i, 0], nu[i, 1] = z[i, 0] - h[i, 0], z[i, 1] - h[i, 1]
        if it > 0:
            _axpy(-1.0, yl, y, d)
            _axpy(-1.0, y, y1, dd)
            # the previous iteration's posterior covariance over the measured columns, as
            # _cov_full would leave it there (from Z, still the previous update's)
            if not pc:
                _cov_cc(Y, Z, Pc)
            _sym_cc(Pc, Y1c)
            for i in range(k):
                nu[i, 0] -= _hdot(H, 2 * i, d)
                nu[i, 1] -= _hdot(H, 2 * i + 1, d)
                if acc[i]:
                    continue
                a, b, c = _block(H, Y1c, i, i >= nfix)
                ex = nu[i, 0] - _hdot(H, 2 * i, dd)
                ey = nu[i, 1] - _hdot(H, 2 * i + 1, dd)
                if _quad(a + var[i], b, c + var[i], ex, ey) <= gate:
                    acc[i] = True
        nis_i, ok, pc = _kalman_update(y, Y, nu, H, var, gate, acc, it == 0, it == 0, nfix,
                                       pos, nd, cv, k, y1, w)
        if it == 0:
            nis = nis_i
        if not ok:
            for i in range(k):
                acc[i] = False
            return nis, False
        if not _count(acc, 0, k):
            break
        turn = _pmax(abs(_wrap(y1[YAW] - yl[YAW])), abs(_wrap(y1[NX + YAW] - yl[NX + YAW])))
        if 0.5 * turn * turn * lever < tol:
            break
        _copy(y1, yl)
    if _count(acc, 0, k):
        _cov_full(Y, Z, Y1)      # the kept iteration's covariance (Z: its update)
    return nis, True


@_jit
def _start_state(k, org, yaw0, v0, ysd, vsd, om0, sa, cnt, amax, omsd, x, P):
    """Start / re-initialisation state into x (6,) and its diagonal covariance into P
    (6, 6) (reference ``FilterStart.offer`` / ``refit``)."""
    pvar = sa * sa / cnt[k]
    _vec(x, org[k, 0], org[k, 1], _wrap(yaw0), v0, 0.0, om0)
    _zero(P, NX, NX)
    P[0, 0], P[1, 1], P[2, 2] = pvar, pvar, ysd ** 2
    P[3, 3], P[4, 4], P[5, 5] = vsd ** 2, amax ** 2, omsd ** 2


@_jit
def _fit_speed(k, yaw0, tt, org, cnt, sa, amax, reverse):
    """Speed along yaw0 from the fits of k-1 and k and its sd (reference ``_fit_speed``)."""
    dt = tt[k] - tt[k - 1]
    d0, d1 = org[k, 0] - org[k - 1, 0], org[k, 1] - org[k - 1, 1]
    v0 = (d0 * math.cos(yaw0) + d1 * math.sin(yaw0)) / dt
    vsd = math.hypot(amax * dt, sa * math.sqrt(1.0 / cnt[k] + 1.0 / cnt[k - 1]) / dt)
    if not reverse:
        v0 = _pmax(v0, 0.0)
    return v0, vsd


@_jit
def _fit_heading(k, fyaw, cnt, spread, sa):
    """Epoch k's rigid-fit heading and its sd (reference ``FilterStart.fit_heading``)."""
    if cnt[k] < 2:
        return math.nan, math.inf
    sp = spread[k]
    return fyaw[k], (sa / math.sqrt(sp) if sp > 0 else math.inf)


@_jit
def _travel(j, k, present, obs, par):
    """Reference ``FilterStart.travel``: (thr, dmax), the motion bound
    INIT_MOTION_SIGMAS sigma_step sqrt(k - j) (m) and the largest move from epoch j to k of
    an antenna present at both (m; -1 without one)."""
    thr = par[I_INIT_SIGMAS] * math.sqrt(par[I_VS]) * math.sqrt(k - j)
    dmax = -1.0
    for i in range(present.shape[1]):
        if present[k, i] and present[j, i]:
            d0, d1 = obs[k, i, 0] - obs[j, i, 0], obs[k, i, 1] - obs[j, i, 1]
            dmax = _pmax(dmax, math.sqrt(d0 * d0 + d1 * d1))
    return thr, dmax


@_jit
def _standstill_start(k, mem, tt, obs, present, par):
    """Reference ``FilterStart._standstill_start``: (ok, yaw0, ysd, v0, vsd)."""
    j = int(mem[0])
    kappa = par[I_KAPPA]
    if j < 0 or not kappa < math.inf:
        return False, 0.0, 0.0, 0.0, 0.0
    thr, dmax = _travel(j, k, present, obs, par)
    ysd = math.sqrt(mem[2] + (kappa * thr) ** 2)
    if dmax < 0.0 or not (dmax <= thr and ysd <= par[I_LOST_SD]):
        return False, 0.0, 0.0, 0.0, 0.0
    dt = tt[k] - tt[j]
    return True, mem[1], ysd, 0.0, math.hypot(par[I_AMAX] * dt, thr / dt)


@_jit
def _offer(k, anchor, tt, org, fyaw, cnt, r2, sa, amax, ommax, reverse, par, mem, obs,
           present, x0, P0):
    """Reference ``FilterStart.offer``: (started, new anchor); the start state into x0 (6,),
    P0 (6, 6) (zeros when not started)."""
    _vec(x0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    _zero(P0, NX, NX)
    if cnt[k] < 2:
        return False, anchor
    yaw_sd = sa / math.sqrt(r2[k]) if r2[k] > 0 else math.inf
    fixed = yaw_sd < par[I_INIT_YAW_SD]
    still = False
    yaw0 = ysd = v0 = vsd = 0.0
    if fixed:
        if k == 0 or cnt[k - 1] < 2:
            return False, anchor
        yaw0, ysd = fyaw[k], yaw_sd
        v0, vsd = _fit_speed(k, yaw0, tt, org, cnt, sa, amax, reverse)
    else:
        still, yaw0, ysd, v0, vsd = _standstill_start(k, mem, tt, obs, present, par)
    if fixed or still:
        pass
    elif anchor < 0:
        return False, k
    else:
        a = anchor
        d0, d1 = org[k, 0] - org[a, 0], org[k, 1] - org[a, 1]
        dist = math.hypot(d0, d1)
        sd = sa * math.sqrt(1.0 / cnt[k] + 1.0 / cnt[a])
        if dist <= par[I_INIT_SIGMAS] * sd:
            return False, anchor
        course = math.atan2(d1, d0)
        sp = dist / (tt[k] - tt[a])
        ysd, vsd = sd / dist, _pmax(sp, amax)
        if reverse and math.cos(course - fyaw[k]) < 0:
            yaw0, v0 = course + math.pi, -sp
        else:
            yaw0, v0 = course, sp
    _start_state(k, org, yaw0, v0, ysd, vsd, 0.0, sa, cnt, amax, 0.5 * ommax, x0, P0)
    return True, -1


@_jit
def _fit_rate(k, om, v0, vsd, tt, fyaw, cnt, spread, par):
    """Reference ``FilterStart._fit_rate``: (yaw rate, sd)."""
    om_max = par[I_OMMAX]
    lim = om_max if v0 == 0 else _pmin(om_max, par[I_ALAT] / abs(v0))
    if par[I_KAPPA] < math.inf:
        lim = _pmin(lim, par[I_KAPPA] * (abs(v0) + vsd))
    omsd = 0.5 * om_max
    y1, s1 = _fit_heading(k, fyaw, cnt, spread, par[I_SA])
    y0, s0 = math.nan, math.inf
    if k > 0:
        y0, s0 = _fit_heading(k - 1, fyaw, cnt, spread, par[I_SA])
    if s1 <= par[I_FIT_SD] and s0 <= par[I_FIT_SD]:
        dt = tt[k] - tt[k - 1]
        om = _wrap(y1 - y0) / dt
        omsd = math.hypot(math.hypot(s0, s1) / dt, par[I_YACC] * dt)
    return _pmax(-lim, _pmin(lim, om)), omsd


@_jit
def _refit(k, x, P, tt, org, fyaw, cnt, spread, sa, amax, reverse, par):
    """Reference ``FilterStart.refit`` of the state x (6,), in place (P (6, 6) replaced)."""
    yaw0, ysd = _fit_heading(k, fyaw, cnt, spread, sa)
    v0, vsd = x[V], _pmax(abs(x[V]), amax)
    if k > 0 and cnt[k - 1] >= 2:
        v0, vsd = _fit_speed(k, yaw0, tt, org, cnt, sa, amax, reverse)
    om0, omsd = _fit_rate(k, x[OMEGA], v0, vsd, tt, fyaw, cnt, spread, par)
    _start_state(k, org, yaw0, v0, ysd, vsd, om0, sa, cnt, amax, omsd, x, P)


@_jit
def _flip(x, P):
    """Reference ``_flip``, in place: heading + pi, -v, -a; P mapped by
    diag(1, 1, 1, -1, -1, 1)."""
    x[YAW] = _wrap(x[YAW] + math.pi)
    x[V] = -x[V]
    x[A] = -x[A]
    J = (1.0, 1.0, 1.0, -1.0, -1.0, 1.0)
    for i in range(NX):
        for j in range(NX):
            P[i, j] = P[i, j] * J[i] * J[j]


@_jit
def _finite(x, P):
    for i in range(NX):
        if not math.isfinite(x[i]):
            return False
        for j in range(NX):
            if not math.isfinite(P[i, j]):
                return False
    return True


@_jit
def _project(x, par):
    """Forward speed, speed limit, yaw-rate and acceleration limits (reference, in place)."""
    if par[I_REVERSE] == 0.0 and x[V] < 0.0:
        x[V] = 0.0
    vmax = par[I_VMAX]
    if abs(x[V]) > vmax:
        x[V] = math.copysign(vmax, x[V])
    om_max = par[I_OMMAX]
    lim = om_max if x[V] == 0 else _pmin(om_max, par[I_ALAT] / abs(x[V]))
    if abs(x[OMEGA]) > lim:
        x[OMEGA] = math.copysign(lim, x[OMEGA])
    if abs(x[A]) > par[I_AMAX]:
        x[A] = math.copysign(par[I_AMAX], x[A])


@_jit
def _cap_variance(P, j, bound):
    """Reference ``_cap_variance``: P[j, j] at most ``bound`` (row and column j scaled, in
    place); returns the variance after."""
    var = P[j, j]
    if var > bound:
        s = math.sqrt(bound / var)
        for i in range(NX):
            P[j, i] *= s
        for i in range(NX):
            P[i, j] *= s
        var = bound
    return var


@_jit
def _bound_yaw_rate(x, P, dt, par, qy):
    """Reference ``_bound_yaw_rate`` (x, P changed in place); returns the yaw-rate noise."""
    kappa, om_max = par[I_KAPPA], par[I_OMMAX]
    v2 = x[V] * x[V] + P[V, V] + dt * dt * (x[A] * x[A] + P[A, A])
    b2 = kappa * kappa * v2 if kappa < math.inf else math.inf
    if not b2 < om_max * om_max:
        return qy
    if x[OMEGA] * x[OMEGA] > b2:
        x[OMEGA] = math.copysign(math.sqrt(b2), x[OMEGA])
    var = _cap_variance(P, OMEGA, b2)
    return _pmin(qy, _pmax(b2 - var, 0.0) / (dt * dt))


@_jit
def _after_gap(k, present):
    """Reference ``_after_gap``: no antenna at both k-2 and k-1."""
    if k < 2:
        return True
    for i in range(present.shape[1]):  # noqa: SIM110 (a generator does not compile)
        if present[k - 1, i] and present[k - 2, i]:
            return False
    return True


@_jit_nrt
def _moved(k, present, obs, par):
    """Reference ``_moved``: the median squared displacement to epoch k of the antennas at
    both k-1 and k beyond (INIT_MOTION_SIGMAS sigma_step)^2 (False without one)."""
    if k == 0:
        return False
    m = present.shape[1]
    d2 = np.empty(m)
    nb = 0
    for i in range(m):
        if present[k, i] and present[k - 1, i]:
            d0, d1 = obs[k, i, 0] - obs[k - 1, i, 0], obs[k, i, 1] - obs[k - 1, i, 1]
            d2[nb] = d0 * d0 + d1 * d1
            nb += 1
    if nb == 0:
        return False
    thr = par[I_INIT_SIGMAS] * math.sqrt(par[I_VS])
    return np.median(d2[:nb]) > thr * thr


@_jit
def _hold_test(x, P, k, present, fyaw, cnt, spread, par):
    """Reference ``_standstill_hold``'s tests but the motion test: 0 no hold, 1 hold, 2 hold
    unless :func:`_moved` (after a gap). Compiled without reference counting (it runs every
    epoch); the allocating :func:`_moved` is left to the caller (the kernels' loops)."""
    if not _anyrow(present, k):
        return 0
    if not x[V] <= par[I_STAND_SIGMAS] * math.sqrt(_pmax(P[V, V], 0.0)):
        return 0
    if _fit_heading(k, fyaw, cnt, spread, par[I_SA])[1] <= par[I_FIT_SD]:
        return 0
    return 2 if _after_gap(k, present) else 1


@_jit
def _bound_after_standstill_gap(P, PP, k, present, obs, par):
    """Reference ``_bound_after_standstill_gap`` (P changed in place): after an all-antenna
    gap at which the platform stood since j, the last epoch with a fix, the heading's
    variance at most PP[j]'s plus (kappa thr)^2."""
    kappa = par[I_KAPPA]
    if k < 2 or not kappa < math.inf or _anyrow(present, k - 1) or not _anyrow(present, k):
        return
    j = k - 2
    while j >= 0 and not _anyrow(present, j):
        j -= 1
    if j < 0:
        return
    thr, dmax = _travel(j, k, present, obs, par)
    if dmax < 0.0 or not dmax <= thr:
        return
    _cap_variance(P, YAW, PP[j, YAW, YAW] + (kappa * thr) ** 2)


@_jit
def _hold_state(x, P):
    """A standstill hold's change of x (6,) and P (6, 6), in place: yaw rate 0, its
    variance at most 1e-12 and uncorrelated (``estimator.pose_filter._hold_state``)."""
    x[OMEGA] = 0.0
    var = P[OMEGA, OMEGA]
    for i in range(NX):
        P[OMEGA, i] = 0.0
        P[i, OMEGA] = 0.0
    P[OMEGA, OMEGA] = _pmin(var, 1e-12)


@_jit
def _measurements(k, present, obs, r_m, va, vs, rr, z, var, ik, js, pos):
    """Epoch k's lever arms rr (fixes first, then displacements since k-1), measurements z
    (k, 2), variances var (k,), the fixes' antenna indices ik, each displacement's antenna
    js and its fix among the measurements pos (for :func:`_rinv`), into the first rows of
    those arrays (2m rows, m for ik, js, pos); returns the numbers of fixes and of
    displacements."""
    m = r_m.shape[0]
    nf = nd = 0
    for i in range(m):
        if present[k, i]:
            if present[k - 1, i]:
                js[nd], pos[nd] = i, nf
                nd += 1
            ik[nf] = i
            nf += 1
    for j in range(nf):
        i = ik[j]
        rr[j, 0], rr[j, 1] = r_m[i, 0], r_m[i, 1]
        z[j, 0], z[j, 1] = obs[k, i, 0], obs[k, i, 1]
        var[j] = va
    for j in range(nd):
        i = js[j]
        rr[nf + j, 0], rr[nf + j, 1] = r_m[i, 0], r_m[i, 1]
        z[nf + j, 0] = obs[k, i, 0] - obs[k - 1, i, 0]
        z[nf + j, 1] = obs[k, i, 1] - obs[k - 1, i, 1]
        var[nf + j] = vs
    return nf, nd


@_jit
def _monitor(buf, head, count, k, nis, dof, x, P, n_gated, counters, thr_table, par,
             fyaw, cnt, spread):
    """Reference ``_Monitor.check``: returns (bad, refit wanted, head, count); the window's
    (winsorised nis, dof) ring buffer ``buf`` (window, 2), ``counters`` = [disagree,
    locked]. bad = the epoch's NIS above its own quantile or the window's winsorised sum
    above the summed dof's; the lock-out counter takes the window test only."""
    if dof == 0 or not math.isfinite(nis):
        return False, False, head, count
    window = buf.shape[0]
    q = thr_table[dof // 2]
    buf[head, 0], buf[head, 1] = min(q, nis), dof
    head = (head + 1) % window
    count = min(count + 1, window)
    tot = 0.0
    df = 0
    for j in range(count):
        e = (head - count + j) % window
        tot += buf[e, 0]
        df += int(buf[e, 1])
    win = tot > thr_table[df // 2]
    bad = nis > q or win
    yaw, sd = _fit_heading(k, fyaw, cnt, spread, par[I_SA])
    if not sd <= par[I_FIT_SD]:
        counters[0] = counters[1] = 0
        return bad, False, head, count
    d = _wrap(yaw - x[YAW])
    var = P[YAW, YAW] + sd * sd
    off = d * d > par[I_THR1] * var and abs(d) > par[I_REINIT_YAW]
    counters[0] = counters[0] + 1 if off else 0
    counters[1] = counters[1] + 1 if (win and n_gated > 0) else 0
    if max(counters[0], counters[1]) >= par[I_REINIT_N]:
        return bad, True, 0, 0
    return bad, False, head, count


@_jit
def _direction(x, P, y, k, ik, nf, acc, obs, r_m, dt, par, back, llr):
    """Direction of travel after epoch k's update (reference; x (6,), P (6, 6) changed in
    place; the fixes' antennas ik[:nf]): (flipped, back, llr)."""
    flipped = False
    if par[I_REVERSE] == 0.0:
        mh = y[YAW] + 0.5 * _wrap(y[NX + YAW] - y[YAW])
        step = ((y[PX] - y[NX + PX]) * math.cos(mh) + (y[PY] - y[NX + PY]) * math.sin(mh))
        back = back - step if step < 0.0 else 0.0
        if back > par[I_FLIPDIST]:
            _flip(x, P)
            flipped, back = True, 0.0
        elif x[V] < 0.0:
            x[V] = 0.0
        return flipped, back, llr
    ngood = 0
    for j in range(nf):
        ngood += acc[j]
    if ngood >= 2:
        c, s = math.cos(x[YAW]), math.sin(x[YAW])
        sp = sm = 0.0
        for j in range(nf):
            if not acc[j]:
                continue
            i = ik[j]
            hx = x[PX] + (c * r_m[i, 0] - s * r_m[i, 1])
            hy = x[PY] + (s * r_m[i, 0] + c * r_m[i, 1])
            ex, ey = obs[k, i, 0] - hx, obs[k, i, 1] - hy
            mx, my = ex + 2.0 * (hx - x[PX]), ey + 2.0 * (hy - x[PY])
            sp += ex * ex + ey * ey
            sm += mx * mx + my * my
        llr = llr * math.exp(-dt / par[I_FLIPMEM]) + (sp - sm) / (2.0 * par[I_VA])
        if llr > par[I_FLIPTHR]:
            _flip(x, P)
            flipped, llr = True, 0.0
    return flipped, back, llr


@_jit
def _stack(xp, Pp, FP, x, P, y, Y):
    """The stacked state (x_k, x_{k-1}) into y (12,) and its covariance into Y (12, 12)."""
    for i in range(NX):
        y[i], y[NX + i] = xp[i], x[i]
        for j in range(NX):
            Y[i, j] = Pp[i, j]
            Y[i, NX + j] = FP[i, j]
            Y[NX + i, j] = FP[j, i]
            Y[NX + i, NX + j] = P[i, j]


@_jit
def _take(ys, Ys, x, P, XC, PC, PX_, k):
    """The epoch's stacked result ys (12,), Ys (12, 12) into the state x, P and the clone
    rows XC[k], PC[k], PX_[k]."""
    for i in range(NX):
        x[i] = ys[i]
        XC[k, i] = ys[NX + i]
        for j in range(NX):
            P[i, j] = Ys[i, j]
            PC[k, i, j] = Ys[NX + i, NX + j]
            PX_[k, i, j] = Ys[i, NX + j]


@numba.njit(cache=True, nogil=True)
def forward_kernel(tt, obs, present, r_m, org, fyaw, cnt, spread, r2, fit_ok, par, thr_table,
                   horner, cw, X, PP, XC, PC, PX_, seg, status, n_used, n_gated, n_steps,
                   nis, nis_dof):
    """The forward pass (reference loop of ``run_pose_filter``) over prepared arrays.

    tt (n,) s; obs (n, m, 2) m; present (n, m) bool; r_m (m, 2) lever arms from the no-slip
    point (travel frame); the rigid fits org (n, 2), fyaw (n,), cnt (n,) float, spread (n,)
    (sum of squared offsets about the present antennas' centroid) and r2 (n,) (sum of the
    present antennas' |r|^2); par (N_PAR,) the scalars (I_* indices); thr_table: chi-square
    upper quantiles by summed dof / 2; horner (10, 6), cw (3, 3) the reference's constants.
    Fills the output arrays (NaN / 0 initialised by the caller; status as codes)."""
    n = tt.shape[0]
    sa, va, vs = par[I_SA], par[I_VA], par[I_VS]
    cv = _pmin(0.5 * vs, va)      # reference fix_step_covariance (same operations)
    amax, ommax = par[I_AMAX], par[I_OMMAX]
    reverse = par[I_REVERSE] != 0.0
    max_rejects = int(par[I_MAXREJ])
    dt_med = par[I_DTMED]
    maxit = int(par[I_MAXIT])
    lost_var = par[I_LOST_SD] ** 2
    buf = np.zeros((int(par[I_WINDOW]), 2))
    head = count = 0
    counters = np.zeros(2, dtype=np.int64)
    # every per-epoch array, allocated once: the state x, P; the prediction xp, Pp, FP (and
    # F); the stacked prior y, Y and posterior y1, Y1; the measurements; the update's work
    m = present.shape[1]
    x = np.zeros(NX)
    P = np.zeros((NX, NX))
    xp, Pp, FP, F = np.zeros(NX), np.zeros((NX, NX)), np.zeros((NX, NX)), np.zeros((NX, NX))
    y, Y, y1, Y1, rr, z, var, ik, js, pos, acc, w = _pass_buffers(m)
    running = lost = False
    anchor = -1
    mem = np.array([-1.0, 0.0, 0.0])     # the last update's (epoch, heading, variance)
    rej_abs = rej_step = 0
    llr = back = 0.0
    dt = 0.0
    hold = False
    for k in range(n):
        if running:
            dt = tt[k] - tt[k - 1]
            _bound_after_standstill_gap(P, PP, k, present, obs, par)
            # the standstill hold; the arguments below are plain variables: an expression
            # with a branch in a call costs reference counting of the call's arrays
            hc = _hold_test(x, P, k, present, fyaw, cnt, spread, par)
            hold = hc == 1
            if hc == 2:
                hold = not _moved(k, present, obs, par)
            qy_in = 0.0
            if hold:
                _hold_state(x, P)
            else:
                qy_in = par[I_QY] * dt_med / dt
            qy_k = _bound_yaw_rate(x, P, dt, par, qy_in)
            _predict(x, P, dt, par[I_QA] * dt / dt_med, qy_k, horner, cw, xp, Pp, FP, F)
            if _anyrow(present, k):
                spr = _pmax(Pp[PX, PX], Pp[PY, PY]) + par[I_LEVER] * par[I_LEVER] * Pp[YAW, YAW]
                if not spr <= par[I_PRIOR_RATIO] * par[I_VARMIN]:
                    running, anchor, lost = False, -1, True
        if not running:
            if not _anyrow(present, k):
                status[k] = S_NO_DATA
                continue
            status[k] = S_WAITING
            got, anchor = _offer(k, anchor, tt, org, fyaw, cnt, r2, sa, amax, ommax, reverse,
                                 par, mem, obs, present, x, P)
            if not got:
                continue
            running = True
            _put(X, PP, k, x, P, 0)
            seg[k] = True
            status[k] = S_RESET if lost else S_INIT
            n_used[k] = _count(present[k], 0, present.shape[1])
            rej_abs, rej_step, llr, back = 0, 0, 0.0, 0.0
            head = count = 0
            counters[0] = counters[1] = 0
            continue
        _stack(xp, Pp, FP, x, P, y, Y)
        # the epoch's result: the prior y, Y, or y1, Y1 when updated (a flag, not a rebound
        # array name: that would cost reference counting every epoch)
        upd = False
        st = S_PREDICTED
        nf, nd = _measurements(k, present, obs, r_m, va, vs, rr, z, var, ik, js, pos)
        if nf:
            nis_k, ok = _iterated_update(y, Y, z, rr, nf, var, par[I_GATE], par[I_LEVER],
                                         0.1 * sa, maxit, hold, pos, nd, cv, nf + nd, acc, y1,
                                         Y1, w)
            if not ok:
                rej_abs = rej_step = max_rejects
            if math.isfinite(nis_k):
                nis[k], nis_dof[k] = nis_k, 2 * (nf + nd)
            n_used[k] = _count(acc, 0, nf)
            n_gated[k] = nf - n_used[k]
            n_steps[k] = _count(acc, nf, nf + nd)
            if (nf >= 2 and n_used[k] == 0 and fit_ok[k] and cnt[k - 1] >= 2
                    and _fit_heading(k, fyaw, cnt, spread, sa)[1] <= par[I_FIT_SD]):
                # reference: FilterStart.motion_miss, then a re-initialisation
                _refit(k, x, P, tt, org, fyaw, cnt, spread, sa, amax, reverse, par)
                _put(X, PP, k, x, P, 0)
                seg[k], status[k] = True, S_REINIT
                head = count = 0
                counters[0] = counters[1] = 0
                rej_abs, rej_step, llr, back = 0, 0, 0.0, 0.0
                mem[0], mem[1], mem[2] = k, x[YAW], P[YAW, YAW]
                continue
            rej_abs = rej_abs + 1 if n_used[k] == 0 else 0
            rej_step = rej_step + 1 if (nd >= 2 and n_steps[k] == 0) else 0
            if max(rej_abs, rej_step) >= max_rejects:
                running, anchor, lost = False, -1, True
                status[k] = S_WAITING
                continue
            if _count(acc, 0, nf + nd):
                upd, st = True, S_OK
                y1[YAW] = _wrap(y1[YAW])
                y1[NX + YAW] = _wrap(y1[NX + YAW])
        if upd:
            _take(y1, Y1, x, P, XC, PC, PX_, k)
        else:
            _take(y, Y, x, P, XC, PC, PX_, k)
        bad, want, head, count = _monitor(buf, head, count, k, nis[k], nis_dof[k], x, P,
                                          n_gated[k], counters, thr_table, par, fyaw, cnt,
                                          spread)
        if want:
            counters[0] = counters[1] = 0
            _refit(k, x, P, tt, org, fyaw, cnt, spread, sa, amax, reverse, par)
            _put(X, PP, k, x, P, 0)
            seg[k], status[k] = True, S_REINIT
            _nan_rows(XC, PC, PX_, k)
            rej_abs, rej_step, llr, back = 0, 0, 0.0, 0.0
            continue
        if bad and st == S_OK:
            st = S_INCONS
        if nf:
            if upd:
                flipped, back, llr = _direction(x, P, y1, k, ik, nf, acc, obs, r_m, dt, par,
                                                back, llr)
            else:
                flipped, back, llr = _direction(x, P, y, k, ik, nf, acc, obs, r_m, dt, par,
                                                back, llr)
            if flipped:
                st = S_FLIP
        if not (P[YAW, YAW] <= lost_var and _finite(x, P)):
            running, anchor, lost = False, -1, True
            status[k] = S_WAITING
            _nan_rows(XC, PC, PX_, k)
            continue
        _project(x, par)
        _put(X, PP, k, x, P, 0)
        status[k] = st
        if st != S_PREDICTED:
            mem[0], mem[1], mem[2] = k, x[YAW], P[YAW, YAW]
        if st == S_FLIP:
            seg[k] = True


# ----------------------------------------------------------------------------- RTS smoother
@_jit
def _wrap_angle(a):
    """:func:`estimator.orientation.wrap_angle` of one angle (same operations: np.mod, the
    -pi fix, angles in range returned unchanged)."""
    if -math.pi < a <= math.pi:
        return a
    w = math.pi - np.mod(math.pi - a, TWO_PI)
    if w <= -math.pi:
        w += TWO_PI
    return w


@numba.njit(cache=True, nogil=True)
def rts_kernel(rows, C, X, XC, PP, PC, Xs, Ps, covariances):
    """The RTS recursion of :func:`estimator.pose_smoother.rts_smooth` over the rows with a
    valid gain ``rows`` (descending): Xs (n, 6) and Ps (n, 6, 6) hold the filtered values
    on entry and the smoothed ones on exit (Ps untouched unless ``covariances``). C (n, 6,
    6) gains, X / XC / PP / PC the forward pass's states, clones and covariances."""
    d = np.empty(NX)
    D = np.empty((NX, NX))
    CD = np.empty((NX, NX))
    for k in rows:
        for i in range(NX):
            d[i] = Xs[k + 1, i] - X[k + 1, i]
        d[YAW] = _wrap_angle(d[YAW])
        for i in range(NX):
            s = XC[k + 1, i]
            for j in range(NX):
                s += C[k, i, j] * d[j]
            Xs[k, i] = s
        Xs[k, YAW] = _wrap_angle(Xs[k, YAW])
        if not covariances:
            continue
        for i in range(NX):
            for j in range(NX):
                D[i, j] = Ps[k + 1, i, j] - PP[k + 1, i, j]
        for i in range(NX):
            for j in range(NX):
                s = 0.0
                for p in range(NX):
                    s += C[k, i, p] * D[p, j]
                CD[i, j] = s
        for i in range(NX):
            for j in range(NX):
                s = 0.0
                for p in range(NX):
                    s += CD[i, p] * C[k, j, p]
                D[i, j] = PC[k + 1, i, j] + s
        for i in range(NX):
            for j in range(NX):
                Ps[k, i, j] = 0.5 * (D[i, j] + D[j, i])


# ----------------------------------------------------------------- iterated RTS (issue 25)
@_jit_nrt
def _median_step(j, present, obs, c, s):
    """Reference ``estimator.pose_smoother._median_step``: (found, along, across)."""
    m = present.shape[1]
    al = np.empty(m)
    ac = np.empty(m)
    nb = 0
    for i in range(m):
        if present[j, i] and present[j - 1, i]:
            d0, d1 = obs[j, i, 0] - obs[j - 1, i, 0], obs[j, i, 1] - obs[j - 1, i, 1]
            al[nb] = d0 * c + d1 * s
            ac[nb] = d1 * c - d0 * s
            nb += 1
    if nb == 0:
        return False, 0.0, 0.0
    return True, np.median(al[:nb]), np.median(ac[:nb])


@_jit_nrt
def _moving_off(k, present, obs, yaw, yaw_var, par):
    """Reference ``estimator.pose_smoother._moving_off``: the displacements to k and k+1
    both move along the heading, in the same direction."""
    if k + 1 >= present.shape[0]:
        return False
    c, s = math.cos(yaw), math.sin(yaw)
    thr = par[I_INIT_SIGMAS] * math.sqrt(par[I_VS])
    sd3 = 3.0 * math.sqrt(_pmax(yaw_var, 0.0))
    kap = par[I_KAPPA]
    arc, sign = 0.0, 0.0
    for j in range(k, k + 2):
        found, a, lat = _median_step(j, present, obs, c, s)
        if not found:
            return False
        if a * a + lat * lat <= thr * thr or a * sign < 0.0:
            return False
        if math.isfinite(kap):
            ang = _pmin(sd3 + kap * (arc + 0.5 * abs(a)), 0.5 * math.pi)
            turn = _pmin(kap * abs(a), 0.5 * math.pi)
            if abs(lat) > thr + abs(a) * math.sin(ang) + par[I_LEVER] * turn:
                return False
        arc, sign = arc + abs(a), a
    return True


@numba.njit(cache=True, nogil=True)
def relinearised_kernel(tt, obs, present, r_m, fyaw, cnt, spread, par, horner, cw, huber_k,
                        X0, P0, XC0, seg, Xb, X, PP, XC, PC, PX_):
    """The forward pass relinearised at the trajectory Xb (n, 6) (the iterated smoother's
    Gauss-Newton pass; reference ``estimator.pose_smoother._relinearised_pass``, same
    steps): X0 / P0 / XC0 / seg the first pass's states, covariances, clones and segment
    starts (travel frame), huber_k the Huber threshold (sd); fills X, PP, XC, PC, PX_
    (NaN-initialised by the caller)."""
    n = tt.shape[0]
    eye = np.eye(NX)
    dt_med, gate, k2 = par[I_DTMED], par[I_GATE], huber_k * huber_k
    # every per-epoch array, allocated once (as in forward_kernel)
    m = present.shape[1]
    x, P, xh, Ph = np.zeros(NX), np.zeros((NX, NX)), np.zeros(NX), np.zeros((NX, NX))
    xb0, fb, F, xs, Ps = (np.zeros(NX), np.zeros(NX), np.zeros((NX, NX)), np.zeros(NX),
                          np.zeros((NX, NX)))
    xp, Pp, FP, Fs, d = (np.zeros(NX), np.zeros((NX, NX)), np.zeros((NX, NX)),
                         np.zeros((NX, NX)), np.zeros(NX))
    yb, dy = np.zeros(2 * NX), np.zeros(2 * NX)
    y, Y, y1, Y1, rr, z, var, ik, js, pos, acc, w = _pass_buffers(m)
    h, H, nu = w[15], w[16], w[17]
    for k in range(n):
        if not math.isfinite(X0[k, 0]):
            continue
        if seg[k] or k == 0 or not (math.isfinite(XC0[k, 0]) and math.isfinite(X[k - 1, 0])):
            _put(X, PP, k, X0[k], P0[k], 0)
            continue
        for i in range(NX):
            x[i], xh[i], xb0[i] = X[k - 1, i], X0[k - 1, i], Xb[k - 1, i]
            for j in range(NX):
                P[i, j], Ph[i, j] = PP[k - 1, i, j], P0[k - 1, i, j]
        dt = tt[k] - tt[k - 1]
        _bound_after_standstill_gap(P, PP, k, present, obs, par)
        hc = _hold_test(xh, Ph, k, present, fyaw, cnt, spread, par)   # the standstill hold:
        hold = hc == 1 or (hc == 2 and not _moved(k, present, obs, par))  # the first pass's
        if hold:                                                     # decision (reference)
            _hold_state(xh, Ph)
        if hold and _moving_off(k, present, obs, X0[k - 1, YAW], P0[k - 1, YAW, YAW], par):
            hold = False
        if hold:
            _hold_state(x, P)
        qy = _bound_yaw_rate(x, P, dt, par, 0.0 if hold else par[I_QY] * dt_med / dt)
        qa = par[I_QA] * dt / dt_med
        _predict(xb0, eye, dt, qa, qy, horner, cw, fb, Ps, F, Fs)
        _predict(xb0, P, dt, qa, qy, horner, cw, xs, Pp, FP, Fs)
        _axpy(-1.0, xb0, x, d)
        d[YAW] = _wrap_angle(d[YAW])
        _copy(fb, xp)
        for i in range(NX):
            for j in range(NX):
                xp[i] += F[i, j] * d[j]
        _stack(xp, Pp, FP, x, P, y, Y)
        ys, Ys = y, Y                 # the epoch's result: the prior, or y1, Y1 when updated
        for i in range(NX):
            yb[i], yb[NX + i] = Xb[k, i], xb0[i]
        nf, nd = _measurements(k, present, obs, r_m, par[I_VA], par[I_VS], rr, z, var, ik, js,
                               pos)
        if nf:
            kk = nf + nd
            _measure(yb, rr, nf, kk, h, H)
            if hold:
                for i in range(nf):
                    H[2 * i, 2] = 0.0
                    H[2 * i + 1, 2] = 0.0
            _axpy(-1.0, yb, y, dy)
            dy[YAW], dy[NX + YAW] = _wrap_angle(dy[YAW]), _wrap_angle(dy[NX + YAW])
            for i in range(kk):
                ex, ey = z[i, 0] - h[i, 0], z[i, 1] - h[i, 1]
                r2 = (ex * ex + ey * ey) / var[i]
                acc[i] = r2 <= gate
                if not r2 <= k2:
                    var[i] = var[i] / (huber_k / math.sqrt(_pmax(r2, 1e-300)))
                nu[i, 0] = ex - _hdot(H, 2 * i, dy)
                nu[i, 1] = ey - _hdot(H, 2 * i + 1, dy)
            if _count(acc, 0, kk):
                _, ok, _ = _posterior(Y, H, nu, var, acc, nf, pos, nd,
                                      _pmin(0.5 * par[I_VS], par[I_VA]), kk, w)
                if ok:
                    Z, dx = w[8], w[10]
                    _step(Y, Z, dx)
                    _axpy(1.0, dx, y, y1)
                    _cov_full(Y, Z, Y1)
                    ys, Ys = y1, Y1
                    ys[YAW], ys[NX + YAW] = _wrap_angle(ys[YAW]), _wrap_angle(ys[NX + YAW])
        for i in range(NX):
            x[i] = ys[i]
        _put(XC, PC, k, ys, Ys, NX)
        for i in range(NX):
            for j in range(NX):
                PX_[k, i, j] = Ys[i, NX + j]
        _project(x, par)
        _put(X, PP, k, x, Ys, 0)
