"""Compiled per-update kernels of the range filters (issues 26 and 27).

Each kernel is the scalar loop of a filter in :mod:`estimator.rigid_ranging` or
:mod:`estimator.ranging`, compiled by numba (``@njit(cache=True)``: compiled on the first
call of a process that finds no cache, then loaded from ``__pycache__``). The plain
numpy/Python implementations stay in those modules as the references the tests compare
against (``tests/test_range_kernels.py``; tolerance 1e-9 relative: the kernels do the same
floating-point operations in the same order, so the results agree to rounding, measured
<= 1e-12). With ``NUMBA_DISABLE_JIT=1`` the kernels run as plain Python with the same results.

Arrays in, arrays out; no checks here (the callers validate). SI units.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["rf_hold_height", "rf_predict", "rf_state_at", "rf_step", "rf_update", "rigid_ekf",
           "pv_run", "rigid_rts", "tight_run", "velocity_gate_run"]


@njit(cache=True)
def rigid_ekf(t, r, bounds, bx, by, dz2, ax, ay, init, has_init, v0, R, gate2, qa, qw, qb,
              reinit_epochs, nis_limit, max_gap_s):
    """The loop of :func:`estimator.rigid_ranging.track` (reference:
    ``rigid_ranging._run_reference``), 7 states (x, y, yaw, vx, vy, yaw rate, bias).

    t, r, bx, by, dz2, ax, ay (K,): update times s, ranges m, tag body x, y m, squared height
    difference m^2, anchor x, y m; bounds (T + 1,) int: the updates of epoch e are
    bounds[e]:bounds[e + 1]; init (T, 4) x, y, yaw, bias and has_init (T,) bool: the joint fit
    that may (re)initialise epoch e; v0 (7,) initial variances. Returns x_pred, p_pred,
    x_post, p_post ((T, 7) states, (T, 28) upper-triangle covariances, row-major), segment,
    reinit, n_accepted, n_gated (T,), nis (K,), accepted (K,).
    """
    T = bounds.size - 1
    K = t.size
    xs_pred = np.zeros((T, 7))
    ps_pred = np.zeros((T, 28))
    xs_post = np.zeros((T, 7))
    ps_post = np.zeros((T, 28))
    seg = np.full(T, -1, dtype=np.int64)
    rei = np.zeros(T, dtype=np.bool_)
    nacc = np.zeros(T, dtype=np.int64)
    ngat = np.zeros(T, dtype=np.int64)
    nis_out = np.full(K, np.nan)
    acc_out = np.zeros(K, dtype=np.bool_)
    x = np.zeros(7)
    P = np.zeros(28)              # upper triangle, row-major: index of (i, j), i <= j
    live = False
    segment = -1
    bad_run = 0
    ewma = 1.0
    t_prev = 0.0
    for e in range(T):
        lo, hi = bounds[e], bounds[e + 1]
        te = t[lo]
        restart = has_init[e] and (not live or bad_run >= reinit_epochs or ewma > nis_limit
                                   or te - t_prev > max_gap_s)
        if restart:
            x[0], x[1], x[2], x[6] = init[e, 0], init[e, 1], init[e, 2], init[e, 3]
            x[3] = x[4] = x[5] = 0.0
            P[:] = 0.0
            P[0], P[7], P[13], P[18], P[22], P[25], P[27] = v0[0], v0[1], v0[2], v0[3], \
                v0[4], v0[5], v0[6]
            live, segment, bad_run, ewma = True, segment + 1, 0, 1.0
        elif live:
            _rigid_predict(x, P, te - t_prev, qa, qw, qb)
        t_prev = te
        xs_pred[e] = x
        ps_pred[e] = P
        na = ng = 0
        if live:
            for u in range(lo, hi):
                if _rigid_update(x, P, bx[u], by[u], dz2[u], ax[u], ay[u], r[u], R, gate2,
                                 nis_out, u):
                    na += 1
                    acc_out[u] = True
                else:
                    ng += 1
                ewma += (min(100.0, nis_out[u]) - ewma) * 0.005
            bad_run = bad_run + 1 if (ng >= 2 and ng > na) else 0
        xs_post[e] = x
        ps_post[e] = P
        seg[e] = segment if live else -1
        rei[e] = restart
        nacc[e] = na
        ngat[e] = ng
    return xs_pred, ps_pred, xs_post, ps_post, seg, rei, nacc, ngat, nis_out, acc_out


@njit(cache=True)
def _rigid_predict(x, P, dt, qa, qw, qb):
    """x <- F x, P <- F P F' + Q over dt (F = I + dt [0 I; 0 0] on the pose/rate blocks),
    in place on the 28 upper-triangle entries (the rate-rate/rate-bias ones unchanged)."""
    dt2 = dt * dt
    qa1, qa2, qa3 = qa * dt, qa * dt2 / 2, qa * dt2 * dt / 3
    qw1, qw2, qw3 = qw * dt, qw * dt2 / 2, qw * dt2 * dt / 3
    x[0] += x[3] * dt
    x[1] += x[4] * dt
    x[2] += x[5] * dt
    (p00, p01, p02, p03, p04, p05, p06, p11, p12, p13, p14, p15, p16, p22, p23, p24, p25, p26,
        p33, p34, p35, p36, p44, p45, p46, p55, p56, p66) = (
        P[0], P[1], P[2], P[3], P[4], P[5], P[6], P[7], P[8], P[9], P[10], P[11], P[12], P[13],
        P[14], P[15], P[16], P[17], P[18], P[19], P[20], P[21], P[22], P[23], P[24], P[25],
        P[26], P[27])
    P[0] = p00 + dt * (p03 + p03) + dt2 * p33 + qa3
    P[1] = p01 + dt * (p13 + p04) + dt2 * p34
    P[2] = p02 + dt * (p23 + p05) + dt2 * p35
    P[3] = p03 + dt * p33 + qa2
    P[4] = p04 + dt * p34
    P[5] = p05 + dt * p35
    P[6] = p06 + dt * p36
    P[7] = p11 + dt * (p14 + p14) + dt2 * p44 + qa3
    P[8] = p12 + dt * (p24 + p15) + dt2 * p45
    P[9] = p13 + dt * p34
    P[10] = p14 + dt * p44 + qa2
    P[11] = p15 + dt * p45
    P[12] = p16 + dt * p46
    P[13] = p22 + dt * (p25 + p25) + dt2 * p55 + qw3
    P[14] = p23 + dt * p35
    P[15] = p24 + dt * p45
    P[16] = p25 + dt * p55 + qw2
    P[17] = p26 + dt * p56
    P[18] = p33 + qa1
    P[22] = p44 + qa1
    P[25] = p55 + qw1
    P[27] = p66 + qb * dt


#: row start of the upper-triangle storage of a 7x7 matrix: entry (i, j >= i) at _ROW[i] + j - i
_ROW = (0, 7, 13, 18, 22, 25, 27)


@njit(cache=True)
def _rigid_update(x, P, bxu, byu, dzu, axu, ayu, ru, R, gate2, nis_out, u):
    """One range update of the rigid filter (H = [hx, hy, hyaw, 0, 0, 0, 1]); writes the NIS
    to nis_out[u]; False (no change) when the gate rejects it."""
    c, s = math.cos(x[2]), math.sin(x[2])
    rx = c * bxu - s * byu
    ry = s * bxu + c * byu
    ex = x[0] + rx - axu
    ey = x[1] + ry - ayu
    rho = math.sqrt(ex * ex + ey * ey + dzu)
    hx, hy = ex / rho, ey / rho
    ht = (ey * rx - ex * ry) / rho
    nu = ru - rho - x[6]
    h = np.empty(7)
    for i in range(7):          # h = P H': column i of P (symmetric) against H
        h[i] = (_sym(P, i, 0) * hx + _sym(P, i, 1) * hy + _sym(P, i, 2) * ht
                + _sym(P, i, 6))
    S = hx * h[0] + hy * h[1] + ht * h[2] + h[6] + R
    nis = nu * nu / S
    nis_out[u] = nis
    if nis > gate2:
        return False
    si = 1.0 / S
    for i in range(7):
        ki = h[i] * si
        x[i] += ki * nu
        base = _ROW[i] - i
        for j in range(i, 7):
            P[base + j] -= ki * h[j]
    return True


@njit(cache=True, inline="always")
def _sym(P, i, j):
    """Entry (i, j) of the symmetric 7x7 matrix stored as its upper triangle P (28,)."""
    if i <= j:
        return P[_ROW[i] + j - i]
    return P[_ROW[j] + i - j]


@njit(cache=True)
def rigid_rts(times, segment, x_pred, P_pred, x_post, P_post):
    """RTS smoother over :func:`rigid_ekf`'s epochs (reference: ``rigid_ranging
    ._smooth_reference``): full (T, 7) states and (T, 7, 7) covariances in, smoothed ones
    out, and ok; a change of segment (or segment -1) breaks the chain. The gain
    C = P_k F' Pp^-1 is solved by LU of Pp; a singular prediction whose zero-variance states
    (bias state off) have zero rows is solved on the other states (= the reference's
    pseudo-inverse); any other singular one returns ok False (the caller falls back to the
    reference). Plain loops, no BLAS/LAPACK (fast compilation)."""
    T = times.size
    xs = x_post.copy()
    Ps = P_post.copy()
    FP, C, D, tmp = np.empty((7, 7)), np.empty((7, 7)), np.empty((7, 7)), np.empty((7, 7))
    dx = np.empty(7)
    for k in range(T - 2, -1, -1):
        if segment[k] < 0 or segment[k + 1] != segment[k]:
            continue
        dt = times[k + 1] - times[k]
        Pk = P_post[k]
        for i in range(7):                   # F P_k (F = I + dt on (0,3), (1,4), (2,5))
            for j in range(7):
                FP[i, j] = Pk[i, j] + dt * Pk[i + 3, j] if i < 3 else Pk[i, j]
        if not _masked_solve(P_pred[k + 1], FP, C):     # C <- Pp^-1 F P_k = (P_k F' Pp^-1)'
            return xs, Ps, False
        for i in range(7):
            dx[i] = xs[k + 1, i] - x_pred[k + 1, i]
            for j in range(7):
                D[i, j] = Ps[k + 1, i, j] - P_pred[k + 1, i, j]
        for i in range(7):                   # x_k + C' dx; tmp = C' D
            acc = x_post[k, i]
            for j in range(7):
                acc += C[j, i] * dx[j]
            xs[k, i] = acc
            for j in range(7):
                a = 0.0
                for m in range(7):
                    a += C[m, i] * D[m, j]
                tmp[i, j] = a
        for i in range(7):                   # P_k + (C' D) C
            for j in range(7):
                a = Pk[i, j]
                for m in range(7):
                    a += tmp[i, m] * C[m, j]
                Ps[k, i, j] = a
    return xs, Ps, True


@njit(cache=True)
def _masked_solve(A, B, X):
    """X <- A^-1 B (7, 7) by LU; if A is singular, the same on the states whose variance is
    not 0 (the rows of X of the others set to 0), which is the pseudo-inverse solution when
    those states' rows of A are zero. False if that is singular too."""
    n = A.shape[0]
    keep = np.ones(n, dtype=np.bool_)
    for _ in range(2):
        idx = np.flatnonzero(keep)
        m = idx.size
        M = np.empty((m, m))
        Y = np.empty((m, B.shape[1]))
        for a in range(m):
            for b in range(m):
                M[a, b] = A[idx[a], idx[b]]
            for j in range(B.shape[1]):
                Y[a, j] = B[idx[a], j]
        ok, Z = _lu_solve(M, Y)
        if ok:
            X[:, :] = 0.0
            for a in range(m):
                for j in range(B.shape[1]):
                    X[idx[a], j] = Z[a, j]
            return True
        for i in range(n):
            if A[i, i] == 0.0:
                keep[i] = False
    return False


@njit(cache=True)
def _lu_solve(A, B):
    """(ok, A^-1 B) for A (n, n) by LU with partial pivoting (as numpy's solve); ok False
    when a pivot is zero or not finite (singular A)."""
    n = A.shape[0]
    M = A.copy()
    X = B.copy()
    for c in range(n):
        p = c
        for i in range(c + 1, n):
            if abs(M[i, c]) > abs(M[p, c]):
                p = i
        piv = M[p, c]
        if piv == 0.0 or not math.isfinite(piv):
            return False, X
        if p != c:
            for j in range(n):
                M[c, j], M[p, j] = M[p, j], M[c, j]
            for j in range(X.shape[1]):
                X[c, j], X[p, j] = X[p, j], X[c, j]
        for i in range(c + 1, n):
            f = M[i, c] / piv
            if f != 0.0:
                for j in range(c, n):
                    M[i, j] -= f * M[c, j]
                for j in range(X.shape[1]):
                    X[i, j] -= f * X[c, j]
    for c in range(n - 1, -1, -1):
        for j in range(X.shape[1]):
            s = X[c, j]
            for k in range(c + 1, n):
                s -= M[c, k] * X[k, j]
            X[c, j] = s / M[c, c]
    return True, X


# ------------------------------------------------------------- single-tag range filter
@njit(cache=True)
def rf_predict(x, P, dt, d, yaw, q, q_yaw):
    """Constant-velocity prediction of :class:`estimator.ranging.RangeFilter` over dt (s),
    in place (reference: ``RangeFilter._predict_reference``): x (n,), P (n, n); d position
    axes (velocities at d..2d-1), yaw and yaw rate at 2d, 2d + 1 when ``yaw``; q, q_yaw the
    spectral densities. F = I + dt E (E[p, v] = 1 per position/rate pair); no-op for dt <= 0."""
    if dt <= 0.0:
        return
    n = x.size
    m = d + 1 if yaw else d
    for i in range(m):
        p = i if i < d else 2 * d
        x[p] += dt * x[p + d if i < d else p + 1]
    for i in range(m):                 # rows: F P (the rate rows are unchanged)
        p = i if i < d else 2 * d
        v = p + d if i < d else p + 1
        for j in range(n):
            P[p, j] += dt * P[v, j]
    for i in range(m):                 # columns: (F P) F'
        p = i if i < d else 2 * d
        v = p + d if i < d else p + 1
        for j in range(n):
            P[j, p] += dt * P[j, v]
    dt2 = dt * dt
    for i in range(m):
        p = i if i < d else 2 * d
        v = p + d if i < d else p + 1
        qq = q if i < d else q_yaw
        P[p, p] += dt2 * dt / 3.0 * qq
        P[p, v] += dt2 / 2.0 * qq
        P[v, p] += dt2 / 2.0 * qq
        P[v, v] += dt * qq


@njit(cache=True)
def rf_update(x, P, rec, lev, rx, tx, r, d, yaw, height, R, gate2, H, PH):
    """One range r (m) of transmitter tx by receiver rx, in place (reference:
    ``RangeFilter._update_reference``): h = |p + Rz(yaw) l_tx - p_rx| (level platform; known
    height ``height`` when d == 2). H, PH (n,) scratch. Returns False (no change) when the
    gate rejects the range (nu^2 > gate2 S) or the point sits on the receiver."""
    n = x.size
    px, py = x[0], x[1]
    pz = x[2] if d == 3 else height
    gx = gy = 0.0
    if yaw:
        th = x[2 * d]
        c, s = math.cos(th), math.sin(th)
        lx, ly, lz = lev[tx, 0], lev[tx, 1], lev[tx, 2]
        px += c * lx - s * ly
        py += s * lx + c * ly
        pz += lz
        gx, gy = -s * lx - c * ly, c * lx - s * ly
    ex, ey, ez = px - rec[rx, 0], py - rec[rx, 1], pz - rec[rx, 2]
    dist = math.sqrt(ex * ex + ey * ey + ez * ez)
    if dist == 0.0:
        return False
    H[:] = 0.0
    H[0], H[1] = ex / dist, ey / dist
    if d == 3:
        H[2] = ez / dist
    if yaw:
        H[2 * d] = (ex * gx + ey * gy) / dist
    for i in range(n):
        acc = 0.0
        for j in range(n):
            acc += P[i, j] * H[j]
        PH[i] = acc
    hph = 0.0
    for i in range(n):
        hph += H[i] * PH[i]
    S = hph + R
    nu = r - dist
    if nu * nu > gate2 * S:
        return False
    for i in range(n):
        ki = PH[i] / S
        x[i] += ki * nu
        for j in range(n):
            P[i, j] -= ki * PH[j]
    return True


@njit(cache=True)
def rf_hold_height(x, P, zb):
    """Free-height bound of the range filter (reference: ``RangeFilter._hold_reference``), in
    place; z is state 2. zb = (lo, hi, fallback, fallback variance) m, m^2, NaN lo = none.
    When the filter's z std exceeds half the interval (the ranges do not resolve z, e.g. a
    nearly coplanar array seen from afar) z is measured at the fallback height with the
    fallback variance (the known-height fallback of the fixes, as a soft pseudo-measurement);
    then a z outside [lo, hi] is clipped to the nearest bound and a vertical speed pointing
    further out is zeroed (P kept; x and y untouched: moving them by their covariance with z,
    the estimate projection of Simon 2010, cost 1.7 mm of 2-D RMSE on the LOS run)."""
    lo, hi = zb[0], zb[1]
    if math.isnan(lo):
        return
    n = x.size
    if P[2, 2] > (0.5 * (hi - lo)) ** 2:
        S = P[2, 2] + zb[3]
        nu = zb[2] - x[2]
        g = P[2].copy()
        for i in range(n):
            ki = g[i] / S
            x[i] += ki * nu
            for j in range(n):
                P[i, j] -= ki * g[j]
    z = x[2]
    if z < lo or z > hi:
        x[2] = lo if z < lo else hi
        if (z < lo and x[5] < 0.0) or (z > hi and x[5] > 0.0):
            x[5] = 0.0


@njit(cache=True)
def rf_step(x, P, dt, rec, lev, rx, tx, r, d, yaw, height, q, q_yaw, R, gate2, H, PH, zb):
    """:func:`rf_predict` over dt, :func:`rf_update` with r, then :func:`rf_hold_height`
    (one call per range)."""
    rf_predict(x, P, dt, d, yaw, q, q_yaw)
    ok = rf_update(x, P, rec, lev, rx, tx, r, d, yaw, height, R, gate2, H, PH)
    rf_hold_height(x, P, zb)
    return ok


@njit(cache=True)
def rf_state_at(x, P, dt, d, yaw, height, q, zb, pos, vel, std):
    """Extrapolation of ``RangeFilter.state_at`` by dt >= 0 into pos, vel, std (3,), z
    clipped to the bounds zb (see :func:`rf_hold_height`); returns the unwrapped yaw (NaN
    without yaw)."""
    for i in range(3):
        pos[i] = vel[i] = std[i] = 0.0
    for i in range(d):
        pos[i] = x[i] + dt * x[i + d]
        vel[i] = x[i + d]
        var = P[i, i] + 2 * dt * P[i, i + d] + dt * dt * P[i + d, i + d] + q * dt ** 3 / 3.0
        std[i] = math.sqrt(max(var, 0.0))
    if d == 2:
        pos[2] = height
    elif not math.isnan(zb[0]):
        pos[2] = min(max(pos[2], zb[0]), zb[1])
    return x[2 * d] + dt * x[2 * d + 1] if yaw else np.nan


@njit(cache=True)
def tight_run(s, e, ts, rs, rxs, txs, skip, te, x, P, t_state, rec, lev, d, yaw, height, q,
              q_yaw, R, gate2, zb, run, lost_after, latest_t, latest_r, pos, vel, yaws, std,
              used, gated, H, PH):
    """The sample loop of :func:`estimator.ranging.tight_filter` while the filter is
    initialised and not lost: from sample s and epoch e, until the end or a sample at which
    ``run >= lost_after`` (that sample's epochs and ``latest_*`` already done). Epoch
    outputs (pos, vel, std (n, 3), yaws (n,) unwrapped) are written in place. Returns
    (s, e, run, t_state): the next sample to handle in Python (N at the end)."""
    N, n = ts.size, te.size
    while s < N:
        ti = ts[s]
        while e < n and te[e] < ti:
            yaws[e] = rf_state_at(x, P, max(te[e] - t_state, 0.0), d, yaw, height, q, zb,
                                  pos[e], vel[e], std[e])
            e += 1
        ri = rs[s]
        if math.isnan(ri) or skip[s]:
            s += 1
            continue
        tx, rx = txs[s], rxs[s]
        latest_t[tx, rx], latest_r[tx, rx] = ti, ri
        if run >= lost_after:
            return s, e, run, t_state
        ok = rf_step(x, P, ti - t_state, rec, lev, rx, tx, ri, d, yaw, height, q, q_yaw, R,
                     gate2, H, PH, zb)
        t_state = max(t_state, ti)
        if ok:
            used[s] = True
            run = 0
        else:
            gated[s] = True
            run += 1
        s += 1
    return s, e, run, t_state


# ------------------------------------------------------------------ PV Kalman on fixes
@njit(cache=True)
def pv_run(t, z, sm, x0, x1, P0, sp, gate, reinit_after):
    """The loop of :func:`estimator.kalman.pv_kalman` (the reference): PV Kalman of one
    signal z (n,) at times t (n,) s, per-sample measurement stds sm (n,), initial state
    (x0, x1) and covariance P0 (2, 2) (``PVKalman.from_thesis``), process sigma sp, gate in
    innovation stds (NaN: none), re-initialisation after ``reinit_after`` gated samples in a
    row. Returns the filtered position (n,)."""
    n = t.size
    out = np.empty(n)
    p00, p01, p10, p11 = P0[0, 0], P0[0, 1], P0[1, 0], P0[1, 1]
    out[0] = x0
    q2 = sp * sp
    run = 0
    for i in range(1, n):
        dt = t[i] - t[i - 1]
        x0 = x0 + dt * x1                     # A x
        a00, a01 = p00 + dt * p10, p01 + dt * p11      # A P
        p00 = a00 + a01 * dt + q2 * (dt ** 4 / 4.0)    # (A P) A' + Q
        p01 = a01 + q2 * (dt ** 3 / 2.0)
        p10 = p10 + p11 * dt + q2 * (dt ** 3 / 2.0)
        p11 = p11 + q2 * dt ** 2
        zi = z[i]
        if math.isnan(zi):
            out[i] = x0
            continue
        R = sm[i] * sm[i]
        S = p00 + R
        innov = zi - x0
        if not math.isnan(gate) and innov * innov > gate * gate * S:
            run += 1
            if run >= reinit_after:
                x0 = zi
                p00, p01, p10 = R, 0.0, 0.0
                run = 0
            out[i] = x0
            continue
        run = 0
        k0, k1 = p00 / S, p10 / S
        x0, x1 = x0 + k0 * innov, x1 + k1 * innov
        # (I - K [1, 0]) P, in the reference's operation order
        p00, p01, p10, p11 = ((1.0 - k0) * p00, (1.0 - k0) * p01, -k1 * p00 + p10,
                              -k1 * p01 + p11)
        out[i] = x0
    return out


# ---------------------------------------------------------------- Filter 1 (velocity)
@njit(cache=True)
def velocity_gate_run(rr, tt, ref, t_ref, thesis, fixed, margin, vmax, cap, relock_after):
    """The time loop of :func:`estimator.range_filters.velocity_gate` (reference: its numpy
    loop, ``range_filters._gate_loop_reference``): rr, tt (n, c) ranges m and per-channel
    times s, ref / t_ref (c,) the lead-in references (copied, not changed), thesis mode or
    robust; fixed = max_speed x sample_interval (thesis), margin, vmax, cap, relock_after
    (robust). Returns the gated ranges (n, c) and the rejected mask (n, c)."""
    n, c = rr.shape
    out = rr.copy()
    rejected = np.zeros((n, c), dtype=np.bool_)
    for j in range(c):
        rf, tr = ref[j], t_ref[j]
        rf2 = rf
        cand, t_cand = np.nan, np.nan
        count = 0
        for i in range(n):
            x = rr[i, j]
            ok = not math.isnan(x)
            if thesis:
                accept = ok and abs(x - rf) <= fixed
            else:
                ti = tt[i, j]
                a = margin + vmax * (ti - tr)
                allow = cap if cap < a else a  # noqa: FURB136 (np.minimum: NaN propagates)
                d_ref = abs(x - rf)
                accept = ok and (d_ref <= allow or abs(x - rf2) <= allow)
                a = margin + vmax * (ti - t_cand)
                allow_c = cap if cap < a else a  # noqa: FURB136
                d_c = abs(x - cand)
                cont = ok and count > 0 and d_c <= allow_c and d_c < d_ref
                accept = accept and not cont
                rej = ok and not accept
                if rej:
                    count = count + 1 if cont else 1
                    cand, t_cand = x, ti
                    if count >= relock_after:
                        accept = True
                if accept:
                    tr = ti
                    count = 0
            rej = ok and not accept
            if accept:
                rf2 = rf
                rf = x
            out[i, j] = rf if rej else x
            rejected[i, j] = rej
    return out, rejected


# ------------------------------------------------------- damped range least squares (LM)
@njit(cache=True)
def _lm_eval(G, dzm, has_dz, rm, wm, p, A, g, J):
    """Residuals' cost, J'J (into A) and J'f (into g) of one row at p (d,); J (d,) scratch."""
    k, d = G.shape
    A[:, :] = 0.0
    g[:] = 0.0
    cost = 0.0
    for i in range(k):
        d2 = 0.0
        for c in range(d):
            J[c] = p[c] - G[i, c]
            d2 += J[c] * J[c]
        if has_dz:
            d2 += dzm[i] * dzm[i]
        dist = math.sqrt(d2)
        if not wm[i]:
            continue
        inv = dist if dist > 0 else 1.0
        f = dist - rm[i]
        cost += f * f
        for a in range(d):
            J[a] /= inv
        for a in range(d):
            g[a] += J[a] * f
            for b in range(d):
                A[a, b] += J[a] * J[b]
    return cost


@njit(cache=True)
def lm_rows(G, dz, has_dz, r, w, p0, radius, tol, max_iter, scale):
    """Algorithm 3.16 of Madsen, Nielsen and Tingleff (2004) per row, the loop of
    :func:`estimator.trilateration._levenberg_marquardt` (the batched numpy reference; same
    arguments, dz (M, k) zeros when not has_dz). Returns p (M, d), iterations, stopped by a
    test, on the bound, cost (M,) and the final J'J (M, d, d). The row's inputs are taken
    once per row and an accepted step swaps the current and trial buffers (no copies)."""
    m, d = p0.shape
    P = p0.copy()
    iters = np.zeros(m, dtype=np.int64)
    done = np.zeros(m, dtype=np.bool_)
    bound = np.zeros(m, dtype=np.bool_)
    costs = np.zeros(m)
    AA = np.zeros((m, d, d))
    A, g = np.zeros((d, d)), np.zeros(d)
    An, gn = np.zeros((d, d)), np.zeros(d)
    p, pn = np.zeros(d), np.zeros(d)
    h, M, J = np.zeros(d), np.zeros((d, d)), np.zeros(d)
    for row in range(m):
        dzr, rr, wr, rad, sc_row = dz[row], r[row], w[row], radius[row], scale[row]
        for a in range(d):
            p[a] = P[row, a]
        cost = _lm_eval(G, dzr, has_dz, rr, wr, p, A, g, J)
        eps1 = tol * sc_row
        mu = 0.0
        for a in range(d):
            mu = max(mu, A[a, a])
        mu = 1e-3 * mu
        mu = mu if mu > 0 else 1e-3
        nu = 2.0
        stop = _absmax(g) <= eps1
        on_b = False
        for _ in range(max_iter):
            if stop:
                break
            iters[row] += 1
            _damped_step(A, g, mu, M, h)
            if _norm(h) <= tol * (_norm(p) + sc_row):
                stop = True
                break
            for a in range(d):
                pn[a] = p[a] + h[a]
            nrm = _norm(pn)
            out = nrm > rad
            if out:
                sc = rad / (nrm if nrm > 0 else 1.0)
                for a in range(d):
                    pn[a] *= sc
            cost_new = _lm_eval(G, dzr, has_dz, rr, wr, pn, An, gn, J)
            pred = 0.0
            for a in range(d):
                pred += h[a] * (mu * h[a] - g[a])
            pred *= 0.5
            num = 0.5 * (cost - cost_new)
            rho = num / pred if pred != 0.0 else (math.inf * num if num != 0 else math.nan)
            if cost_new < cost and rho > 0:
                p, pn = pn, p
                A, An = An, A
                g, gn = gn, g
                cost = cost_new
                on_b = out
                mu *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
                nu = 2.0
                if _absmax(g) <= eps1:
                    stop = True
            else:
                mu *= nu
                nu *= 2.0
            if not math.isfinite(mu) or mu > 1e300:
                mu = 1e300
            nu = min(nu, 1e300)
        for a in range(d):
            P[row, a] = p[a]
        done[row] = stop
        bound[row] = on_b
        costs[row] = cost
        AA[row] = A
    return P, iters, done, bound, costs, AA


@njit(cache=True)
def _absmax(g):
    out = 0.0
    for v in g:
        out = max(out, abs(v))
    return out


@njit(cache=True)
def _norm(v):
    acc = 0.0
    for x in v:
        acc += x * x
    return math.sqrt(acc)


@njit(cache=True)
def _damped_step(A, g, mu, M, h):
    """h = -(A + mu I)^-1 g by Gaussian elimination with partial pivoting in the scratch M
    (d, d) (A + mu I is positive definite for mu > 0)."""
    d = g.size
    for a in range(d):
        h[a] = -g[a]
        for b in range(d):
            M[a, b] = A[a, b]
        M[a, a] += mu
    for c in range(d):
        p = c
        for i in range(c + 1, d):
            if abs(M[i, c]) > abs(M[p, c]):
                p = i
        if p != c:
            for j in range(d):
                M[c, j], M[p, j] = M[p, j], M[c, j]
            h[c], h[p] = h[p], h[c]
        for i in range(c + 1, d):
            f = M[i, c] / M[c, c]
            for j in range(c, d):
                M[i, j] -= f * M[c, j]
            h[i] -= f * h[c]
    for c in range(d - 1, -1, -1):
        acc = h[c]
        for j in range(c + 1, d):
            acc -= M[c, j] * h[j]
        h[c] = acc / M[c, c]
