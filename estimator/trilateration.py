"""Trilateration: position from ranges to known receivers (thesis 003, Appendix A).

Five methods, all batched over many range sets and all in metres:

=================  ==========  ==============================================================
method             receivers   what it is (Appendix A function)
=================  ==========  ==============================================================
``simple``         3           textbook closed form in the receiver frame (``SimpleMethod``)
``linear_ls``      >= 4        differences against receiver 1, least squares (``LeastSquare``,
                               ``'ls'``)
``nonlinear_ls``   >= 4        Gauss-Newton on the range residuals from the linear solution
                               (``LeastSquare``, ``'nls'``)
``closed_form``    3           "CFP": two linear sphere-difference equations plus the
                               quadratic in the out-of-plane coordinate (``ExplicitMethod_CFP``)
``cayley_menger``  3           "CMD": Cayley-Menger bideterminants (``ExplicitMethod_CMD``)
``damped_ls``      >= 3        not in the thesis: damped (Levenberg-Marquardt) range least
                               squares with missing receivers, a trust region, a known-height
                               mode and a per-row mirror choice (see below)
=================  ==========  ==============================================================

Shapes: ``receivers`` ``(k, 3)``; ``ranges`` ``(k,)`` (one set, returns ``(3,)``) or ``(N, k)``
(returns ``(N, 3)``). With ``return_info=True`` every function returns
``(positions, TrilaterationInfo)``.

Mirror ambiguity. Three spheres meet in two points mirrored in the receivers' plane. ``side=+1``
returns the one on the positive side of the plane normal ``n``, where ``n`` is the unit normal of
the plane through the receivers oriented so that ``n_z > 0`` (for a ground array: the solution
above the receivers, where the quadcopter flies); ``side=-1`` the other one. For a vertical
receiver plane (``n_z == 0``) ``n`` is the right-hand normal ``(p2 - p1) x (p3 - p1)``.

No intersection. With noisy ranges the three spheres can miss each other (the discriminant
of the out-of-plane coordinate is negative). The thesis's Matlab then carried complex numbers
and took ``real()`` afterwards; here the out-of-plane offset is set to zero, i.e. the returned
point is where the radical line of the three spheres pierces the receivers' plane (the real
part of the complex solution; the same point for ``simple``, ``closed_form`` and
``cayley_menger``), and ``info.no_intersection`` is True for that row. Rows whose ranges
contain NaN (a dropout) give NaN positions with ``info.missing`` True: never a silent NaN.

Degenerate Gauss-Newton rows. ``nonlinear_ls`` has no step where the range Jacobian is
undefined (the iterate sits exactly on a receiver) or ``J'J`` is singular or numerically so
(coplanar receivers and the iterate in their plane, e.g. a start taken from a three-receiver
``no_intersection`` point), or where the start itself is not finite. Such a row stops at its
last iterate, ``info.degenerate`` is True and ``info.converged`` False; the other rows of the
batch are solved as if it were not there.

Degenerate geometry (coincident or collinear receivers, coplanar receivers for ``linear_ls``),
wrong shapes and negative ranges raise ``ValueError`` naming the field; a non-numeric argument
raises ``TypeError`` naming it. Coordinates and ranges are limited to ``|value| <= MAX_ABS_M``
(1e8 m, beyond any Earth-fixed coordinate) so that squared ranges never overflow.

Large coordinates. ``closed_form`` works with squared norms of receiver positions, which loses
every digit at UTM-sized coordinates (1e7 m: squares of 1e14 m^2); every method therefore
solves in coordinates centred on the receivers' centroid and adds it back (exact ranges at
1e7 m offsets are recovered to < 1e-7 m, tested).

Beyond the thesis: :func:`damped_ls`, the solver for real ranging data. Levenberg-Marquardt
(Madsen, Nielsen and Tingleff 2004, "Methods for non-linear least squares problems",
Algorithm 3.16) on the range residuals of whichever receivers reported in each row (any
``>= 3``; NaN = that receiver missing), with

* a trust region: every iterate stays inside the ball the data allow (a point consistent with
  range ``r_i`` lies within ``r_i`` of receiver ``i``, so within ``min_i (r_i + |p_i - c|)``
  of the centroid ``c``, plus a slack); a result on that boundary is flagged ``bounded``;
* ``converged`` meaning converged: the gradient or the step test of Algorithm 3.16 was met,
  at an interior, well-determined point (not on the bound, not degenerate, not ``max_iter``);
* a known-height mode (``height_m``): the tag's z is given and only x, y are solved, which
  removes the nearly unobservable z of a flat or small array seen from afar;
* the mirror side chosen per row, not fixed for a run: the solver also starts from its
  solution reflected in the receivers' best-fit plane (in known-height mode: their best-fit
  line in x-y); the better fit wins, and when both fit equally well (within 9 sigma^2) the row
  is ``ambiguous`` and the one nearer ``prior`` (e.g. the previous fix) is returned, or, with
  no prior, the one on ``side``; the other is ``info.alternative``.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from estimator import range_kernels
from estimator._checks import check_array, check_int, check_real

__all__ = [
    "DLS_MAX_ITER",
    "DLS_TOL",
    "MAX_ABS_M",
    "METHODS",
    "NLS_MAX_ITER",
    "NLS_TOL_M",
    "TrilaterationInfo",
    "cayley_menger",
    "closed_form",
    "damped_ls",
    "linear_ls",
    "nonlinear_ls",
    "simple",
]

#: Gauss-Newton stops when the step norm is below this (metres). The thesis used 1e-6 mm.
NLS_TOL_M = 1e-9
#: Gauss-Newton iteration cap; the thesis's ``while ... i_count_nls <= 15``.
NLS_MAX_ITER = 15
#: Levenberg-Marquardt iteration cap of :func:`damped_ls`. Rows far from a small array sit in a
#: long flat valley (HDOP ~ 30) where the damped steps need 60-130 iterations (measured).
DLS_MAX_ITER = 200
#: Relative tolerance of :func:`damped_ls`'s gradient and step tests (eps_1, eps_2 of
#: Algorithm 3.16): 1e-10 x the problem's length scale, five digits above float64 rounding.
DLS_TOL = 1e-10
#: Largest accepted |coordinate| and range (m): squares stay far from overflow.
MAX_ABS_M = 1e8
#: Largest iteration cap accepted by the iterative solvers (a cap, not a target).
_MAX_ITER_CAP = 1_000_000

# Relative tolerances for degenerate geometry, against the layout's own length scale.
_COINCIDENT_REL = 1e-9   # receivers closer than this x array size are "coincident"
_COLLINEAR_SIN = 1e-9    # |v1 x v2| <= this * |v1| |v2|: the three receivers are collinear
_COPLANAR_REL = 1e-9     # smallest singular value of the difference matrix vs the largest
#: Gauss-Newton: J'J counts as singular when its smallest eigenvalue is <= this x its largest
#: (condition number >= 1e12: the step would keep fewer than ~4 significant digits).
_NLS_SINGULAR_REL = 1e-12


def _well_conditioned(A: np.ndarray) -> np.ndarray:
    """(M,) bool for symmetric PSD (M, d, d), d = 2 or 3: smallest eigenvalue >
    _NLS_SINGULAR_REL x largest.

    Cheap sufficient test first: det > rel * trace^d implies lambda_min >= det /
    lambda_max^(d-1) > rel * lambda_max (trace >= lambda_max). Only rows failing it (rare:
    degenerate ones) get the exact eigenvalue test, so the Gauss-Newton loop does not pay an
    eigendecomposition per row and iteration.
    """
    d = A.shape[-1]
    if d == 2:
        det = A[:, 0, 0] * A[:, 1, 1] - A[:, 0, 1] * A[:, 1, 0]
    else:
        det = (A[:, 0, 0] * (A[:, 1, 1] * A[:, 2, 2] - A[:, 1, 2] * A[:, 2, 1])
               - A[:, 0, 1] * (A[:, 1, 0] * A[:, 2, 2] - A[:, 1, 2] * A[:, 2, 0])
               + A[:, 0, 2] * (A[:, 1, 0] * A[:, 2, 1] - A[:, 1, 1] * A[:, 2, 0]))
    tr = np.trace(A, axis1=1, axis2=2)
    ok = det > _NLS_SINGULAR_REL * tr ** d
    rest = np.flatnonzero(~ok & np.all(np.isfinite(A), axis=(1, 2)))
    if rest.size:
        ev = np.linalg.eigvalsh(A[rest])                      # ascending, >= 0 up to rounding
        ok[rest] = ev[:, 0] > _NLS_SINGULAR_REL * ev[:, -1]
    return ok


@dataclass(frozen=True)
class TrilaterationInfo:
    """Per-row diagnostics of a trilateration call.

    Attributes (each ``(N,)``, ``alternative`` ``(N, 3)``; 0-d / ``(3,)`` for a single range set):
    no_intersection : bool, the spheres do not meet; the closest real point was returned
        (three-receiver closed forms; False for the least-squares methods).
    missing : bool, the row had too few ranges (the thesis methods: any NaN; ``damped_ls``:
        fewer than 3 finite ranges); the position is NaN.
    iterations : int, Gauss-Newton / Levenberg-Marquardt iterations; 1 for ``linear_ls`` (as the
        thesis's ``i_count_ls``); 0 for the closed forms.
    converged : bool, the iterative methods met their convergence test (``nonlinear_ls``: step
        below ``tol`` within ``max_iter``; ``damped_ls``: gradient or step test at an interior,
        well-determined point); True for the direct methods.
    degenerate : bool, no well-determined solution: ``nonlinear_ls`` found no Gauss-Newton step
        (start not finite, iterate on a receiver, or ``J'J`` singular: condition number
        >= 1e12) and stopped the row at its last iterate; ``damped_ls``: the receivers of the
        row do not fix a start (collinear in 3-D, coincident in x-y in known-height mode) or
        ``J'J`` is singular at the solution. False for the direct methods.
    bounded : bool, ``damped_ls`` only: the solution lies on the trust-region bound (the
        ranges allow no point farther out; the fit wanted one), i.e. the ranges are mutually
        inconsistent (a spike, a blunder).
    ambiguous : bool, ``damped_ls`` only: two mirror minima fit equally well; ``prior`` or
        ``side`` picked the returned one.
    rms_residual_m : float, RMS of ``|p - p_i| - r_i`` over the receivers used (NaN if missing).
    alternative : ``damped_ls`` only: the other mirror minimum where one exists and differs
        from the returned point (NaN otherwise).
    """

    no_intersection: np.ndarray
    missing: np.ndarray
    iterations: np.ndarray
    converged: np.ndarray
    degenerate: np.ndarray
    bounded: np.ndarray
    ambiguous: np.ndarray
    rms_residual_m: np.ndarray
    alternative: np.ndarray


# ---------------------------------------------------------------------------------------------
# validation helpers
# ---------------------------------------------------------------------------------------------


def _check_receivers(receivers: np.ndarray, k: int | None, min_k: int, method: str) -> np.ndarray:
    rec = check_array(receivers, "receivers", max_abs=MAX_ABS_M)
    if rec.ndim != 2 or rec.shape[1] != 3:
        raise ValueError(f"receivers: expected shape (k, 3), got {rec.shape}")
    if k is not None and rec.shape[0] != k:
        raise ValueError(f"receivers: {method} needs exactly {k} receivers, got {rec.shape[0]}")
    if rec.shape[0] < min_k:
        raise ValueError(f"receivers: {method} needs >= {min_k} receivers, got {rec.shape[0]}")
    scale = float(np.max(np.ptp(rec, axis=0))) if rec.shape[0] > 1 else 0.0
    diff = rec[:, None, :] - rec[None, :, :]
    dist = np.sqrt(np.einsum("ijk,ijk->ij", diff, diff))
    iu = np.triu_indices(rec.shape[0], 1)
    if scale == 0.0 or np.min(dist[iu]) <= _COINCIDENT_REL * scale:
        i, j = iu[0][np.argmin(dist[iu])], iu[1][np.argmin(dist[iu])]
        raise ValueError(f"receivers: receivers {i} and {j} coincide ({dist[i, j]:.3g} m apart)")
    return rec


def _check_ranges(ranges: np.ndarray, k: int) -> tuple[np.ndarray, bool]:
    r = check_array(ranges, "ranges", allow_nan=True, max_abs=MAX_ABS_M)
    single = r.ndim == 1
    if single:
        r = r[None, :]
    if r.ndim != 2 or r.shape[1] != k:
        raise ValueError(f"ranges: expected shape ({k},) or (N, {k}), got {np.shape(r)}")
    with np.errstate(invalid="ignore"):
        neg = r < 0
    if neg.any():
        raise ValueError(f"ranges: must be >= 0, got min {np.nanmin(r):.6g} m")
    return r, single


def _check_side(side: int) -> int:
    if isinstance(side, (bool, np.bool_)) or side not in (1, -1):
        raise ValueError(f"side: must be +1 or -1, got {side!r}")
    return int(side)


def _check_iter_tol(max_iter: int, tol: float) -> tuple[int, float]:
    it = check_int(max_iter, "max_iter", lo=1, hi=_MAX_ITER_CAP)
    return it, check_real(tol, "tol", lo=0.0, lo_open=True)


def _rows_of_points(x, name: str, n: int, *, allow_nan: bool, d: int = 3) -> np.ndarray:
    """``x`` as (n, d) float: a (d,) point repeated or an (n, d) array; the message names
    ``name`` and the shape it got."""
    a = check_array(x, name, allow_nan=allow_nan, max_abs=MAX_ABS_M)
    if a.shape == (d,):
        return np.broadcast_to(a, (n, d)).copy()
    if a.shape != (n, d):
        raise ValueError(f"{name}: expected shape ({d},) or ({n}, {d}), got {a.shape}")
    return a.copy()


def _plane_frame(p1: np.ndarray, p2: np.ndarray, p3: np.ndarray):
    """Orthonormal frame (ex, ey, ez) with p1 origin, ex toward p2, ey in the plane; the sign
    ``s`` such that ``s * ez`` is the module's ``+side`` normal (n_z > 0, else right-hand)."""
    v1 = p2 - p1
    v2 = p3 - p1
    cr = np.cross(v1, v2)
    n1, n2, nc = np.linalg.norm(v1), np.linalg.norm(v2), np.linalg.norm(cr)
    if nc <= _COLLINEAR_SIN * n1 * n2:
        raise ValueError("receivers: the three receivers are collinear (no unique plane)")
    ex = v1 / n1
    ez = cr / nc
    ey = np.cross(ez, ex)
    # orientation of the side normal relative to ez (right-hand normal of p1, p2, p3)
    s = 1.0 if ez[2] >= 0 else -1.0
    if ez[2] == 0.0:
        s = 1.0
    return ex, ey, ez, s


def _rms_residual(rec: np.ndarray, pos: np.ndarray, r: np.ndarray) -> np.ndarray:
    """RMS over the finite ranges of |p - p_i| - r_i, (N,) m; NaN where pos or all r are NaN."""
    res = np.linalg.norm(pos[:, None, :] - rec[None, :, :], axis=2) - r
    ok = np.isfinite(res)
    n = ok.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, np.sqrt(np.sum(np.where(ok, res, 0.0) ** 2, axis=1) / n), np.nan)


def _finish(pos: np.ndarray, info: TrilaterationInfo, single: bool, return_info: bool):
    if single:
        pos = pos[0]
        info = TrilaterationInfo(*(np.asarray(getattr(info, f.name))[0] for f in fields(info)))
    return (pos, info) if return_info else pos


def _info(rec: np.ndarray, pos: np.ndarray, r: np.ndarray, *, no_intersection=None,
          missing, iterations, converged, degenerate=None, bounded=None, ambiguous=None,
          alternative=None) -> TrilaterationInfo:
    """Fill every diagnostic field; unset ones get their 'not applicable' value."""
    n = pos.shape[0]
    no = np.zeros(n, dtype=bool)
    return TrilaterationInfo(
        no if no_intersection is None else no_intersection, missing, iterations, converged,
        no if degenerate is None else degenerate, no if bounded is None else bounded,
        no if ambiguous is None else ambiguous, _rms_residual(rec, pos, r),
        np.full((n, 3), np.nan) if alternative is None else alternative)


def _direct_info(rec: np.ndarray, pos: np.ndarray, r: np.ndarray, no_int: np.ndarray,
                 missing: np.ndarray) -> TrilaterationInfo:
    n = no_int.shape[0]
    return _info(rec, pos, r, no_intersection=no_int & ~missing, missing=missing,
                 iterations=np.zeros(n, dtype=int), converged=np.ones(n, dtype=bool))


# ---------------------------------------------------------------------------------------------
# three-receiver closed forms
# ---------------------------------------------------------------------------------------------


def simple(receivers: np.ndarray, ranges: np.ndarray, *, side: int = 1,
           return_info: bool = False) -> np.ndarray | tuple[np.ndarray, TrilaterationInfo]:
    """Textbook three-sphere intersection (Appendix A ``SimpleMethod``).

    Works in the frame the thesis's pseudo-positions describe (Appendix B ``RCM_SM``):
    receiver 1 at the origin, receiver 2 on +x at distance d, receiver 3 in the xy-plane at
    (i, j). Then x = (r1^2 - r2^2 + d^2) / 2d, y = (r1^2 - r3^2 + i^2 + j^2) / 2j - i x / j,
    z = +/- sqrt(r1^2 - x^2 - y^2), mapped back to the world frame.

    receivers (3, 3) m, ranges (3,) or (N, 3) m -> (3,) or (N, 3) m.
    """
    side = _check_side(side)
    rec = _check_receivers(receivers, 3, 3, "simple")
    r, single = _check_ranges(ranges, 3)
    p1, p2, p3 = rec
    ex, ey, ez, s = _plane_frame(p1, p2, p3)
    d = float(np.linalg.norm(p2 - p1))
    i = float(ex @ (p3 - p1))
    j = float(ey @ (p3 - p1))
    r1s, r2s, r3s = r[:, 0] ** 2, r[:, 1] ** 2, r[:, 2] ** 2
    x = (r1s - r2s + d * d) / (2.0 * d)
    y = (r1s - r3s + i * i + j * j) / (2.0 * j) - (i / j) * x
    z2 = r1s - x * x - y * y
    missing = np.isnan(z2)
    no_int = z2 < 0
    z = np.sqrt(np.where(no_int, 0.0, z2)) * (side * s)
    pos = p1 + x[:, None] * ex + y[:, None] * ey + z[:, None] * ez
    return _finish(pos, _direct_info(rec, pos, r, no_int, missing), single, return_info)


def closed_form(receivers: np.ndarray, ranges: np.ndarray, *, side: int = 1,
                return_info: bool = False) -> np.ndarray | tuple[np.ndarray, TrilaterationInfo]:
    """Closed-form "CFP" trilateration (Appendix A ``ExplicitMethod_CFP``).

    Subtracting sphere 1 from spheres 2 and 3 gives two linear equations
    ``W [x, y]^T + d z = beta`` with ``W = [[x21, y21], [x31, y31]]``, ``d = [z21, z31]``,
    ``beta_i = (R1^2 - Ri^2 - S1^2 + Si^2) / 2`` (S_i = |p_i|). Hence
    ``[x, y] = W^-1 (beta - d z)``, and sphere 1 becomes the quadratic
    ``a z^2 + b z + c = 0`` with the thesis's ``a_cf = 1 + |W^-1 d|^2``, ``b_cf``, ``c_cf``.
    The thesis's "original position calculation" (``R_cfp1``) is implemented; its "improved"
    re-expression (``R_cfp2``, Lambda/zeta) is algebraically the same point. Computed in
    coordinates centred on the receivers (see the module docstring: the S_i^2 terms lose every
    digit at UTM-sized coordinates otherwise).

    Generalisation: the thesis eliminates x, y and solves for z, which needs the receivers'
    xy-projection to be non-collinear. Here the quadratic is in the world coordinate most
    aligned with the plane normal (z for any roughly horizontal array, exactly the thesis's
    formula), so tilted and vertical arrays work too. The root is chosen by ``side``.

    receivers (3, 3) m, ranges (3,) or (N, 3) m -> (3,) or (N, 3) m.
    """
    side = _check_side(side)
    rec = _check_receivers(receivers, 3, 3, "closed_form")
    r, single = _check_ranges(ranges, 3)
    _, _, ez, s = _plane_frame(*rec)
    normal = ez * s
    q = int(np.argmax(np.abs(ez)))           # coordinate solved by the quadratic ("z")
    a_idx = [c for c in range(3) if c != q]   # the two eliminated ("x", "y")
    # centred on the receivers' centroid: S_i^2 below are squared norms, which at UTM-sized
    # coordinates (1e7 m) would keep no significant digit of the metre-sized differences
    centre = rec.mean(axis=0)
    P = (rec - centre)[:, a_idx + [q]]        # permuted so the quadratic coordinate is last
    x1, y1, z1 = P[0]
    W = np.array([[P[1, 0] - x1, P[1, 1] - y1], [P[2, 0] - x1, P[2, 1] - y1]])
    dvec = np.array([P[1, 2] - z1, P[2, 2] - z1])
    S2 = np.sum(P * P, axis=1)                # S_i^2
    R2 = r * r
    beta = np.stack([(R2[:, 0] - R2[:, 1] - S2[0] + S2[1]) / 2.0,
                     (R2[:, 0] - R2[:, 2] - S2[0] + S2[2]) / 2.0], axis=1)   # (N, 2)
    Winv = np.linalg.inv(W)
    g = Winv @ dvec                           # W^-1 d
    h = beta @ Winv.T - np.array([x1, y1])    # W^-1 beta - rh1, (N, 2)
    # |h - g z|^2 + (z - z1)^2 = R1^2
    a = 1.0 + g @ g
    b = -2.0 * (h @ g) - 2.0 * z1
    c = np.sum(h * h, axis=1) + z1 * z1 - R2[:, 0]
    disc = b * b - 4.0 * a * c
    missing = np.isnan(disc)
    no_int = disc < 0
    sq = np.sqrt(np.where(no_int, 0.0, disc))
    # the root on the +side: d(coordinate q)/d(offset along normal) has the sign of normal[q]
    # along the solution line (the line is perpendicular to the plane).
    sgn = side * np.sign(normal[q] + (normal[q] == 0))
    z = (-b + sgn * sq) / (2.0 * a)
    xy = h - np.outer(z, g) + np.array([x1, y1])
    pos = np.empty((r.shape[0], 3))
    pos[:, a_idx[0]] = xy[:, 0]
    pos[:, a_idx[1]] = xy[:, 1]
    pos[:, q] = z
    pos += centre
    return _finish(pos, _direct_info(rec, pos, r, no_int, missing), single, return_info)


def cayley_menger(receivers: np.ndarray, ranges: np.ndarray, *, side: int = 1,
                  return_info: bool = False) -> np.ndarray | tuple[np.ndarray, TrilaterationInfo]:
    """Trilateration by Cayley-Menger bideterminants, "CMD" (Appendix A
    ``ExplicitMethod_CMD``; Thomas and Ros 2005).

    With v1 = p2 - p1, v2 = p3 - p1, squared distances d12, d13, d23 and
    ``k = |v1 x v2|^2``, the point is ``p1 + k1 v1 + k2 v2 +/- k3 (v1 x v2)`` with
    ``k1 = -CMBD_k1 / k``, ``k2 = CMBD_k2 / k``, ``k3 = sqrt(CMBD_k3) / k``, where CMBD_k1 and
    CMBD_k2 are -1/4 of the 4x4 bideterminants and CMBD_k3 is 1/8 of the 5x5 Cayley-Menger
    determinant, exactly as in the thesis's code (evaluated as batched determinants).

    receivers (3, 3) m, ranges (3,) or (N, 3) m -> (3,) or (N, 3) m.
    """
    side = _check_side(side)
    rec = _check_receivers(receivers, 3, 3, "cayley_menger")
    r, single = _check_ranges(ranges, 3)
    p1, p2, p3 = rec
    _, _, _, s = _plane_frame(p1, p2, p3)
    v1, v2 = p2 - p1, p3 - p1
    d12 = float(v1 @ v1)
    d13 = float(v2 @ v2)
    d23 = float((p3 - p2) @ (p3 - p2))
    cr = np.cross(v1, v2)
    kk = float(cr @ cr)
    l1, l2, l3 = r[:, 0] ** 2, r[:, 1] ** 2, r[:, 2] ** 2
    n = r.shape[0]
    one = np.ones(n)
    zero = np.zeros(n)

    def full(v):
        return np.full(n, v)

    m1 = np.stack([np.stack([zero, one, one, one], -1),
                   np.stack([one, zero, full(d13), l1], -1),
                   np.stack([one, full(d12), full(d23), l2], -1),
                   np.stack([one, full(d13), zero, l3], -1)], axis=1)
    m2 = np.stack([np.stack([zero, one, one, one], -1),
                   np.stack([one, zero, full(d12), l1], -1),
                   np.stack([one, full(d12), zero, l2], -1),
                   np.stack([one, full(d13), full(d23), l3], -1)], axis=1)
    m3 = np.stack([np.stack([zero, one, one, one, one], -1),
                   np.stack([one, zero, full(d12), full(d13), l1], -1),
                   np.stack([one, full(d12), zero, full(d23), l2], -1),
                   np.stack([one, full(d13), full(d23), zero, l3], -1),
                   np.stack([one, l1, l2, l3, zero], -1)], axis=1)
    missing = np.isnan(r).any(axis=1)
    m1[missing] = 0.0
    m2[missing] = 0.0
    m3[missing] = 0.0
    cmbd_k1 = -0.25 * np.linalg.det(m1)
    cmbd_k2 = -0.25 * np.linalg.det(m2)
    cmbd_k3 = 0.125 * np.linalg.det(m3)
    k1 = -cmbd_k1 / kk
    k2 = cmbd_k2 / kk
    no_int = cmbd_k3 < 0
    k3 = np.sqrt(np.where(no_int, 0.0, cmbd_k3)) / kk * (side * s)
    pos = p1 + k1[:, None] * v1 + k2[:, None] * v2 + k3[:, None] * cr
    pos[missing] = np.nan
    return _finish(pos, _direct_info(rec, pos, r, no_int, missing), single, return_info)


# ---------------------------------------------------------------------------------------------
# least squares (>= 4 receivers)
# ---------------------------------------------------------------------------------------------


def _linear_system(rec: np.ndarray, method: str):
    A = rec[1:] - rec[0]
    sv = np.linalg.svd(A, compute_uv=False)
    if sv[-1] <= _COPLANAR_REL * sv[0]:
        raise ValueError(f"receivers: {method} needs receivers that are not all in one plane "
                         "(the linear system has rank < 3); use a three-receiver method or "
                         "pass x0 to nonlinear_ls")
    return A, np.linalg.pinv(A)


def linear_ls(receivers: np.ndarray, ranges: np.ndarray, *, side: int = 1,
              return_info: bool = False) -> np.ndarray | tuple[np.ndarray, TrilaterationInfo]:
    """Linear least squares (Appendix A ``LeastSquare``, method ``'ls'``).

    Rows ``A_i = p_{i+1} - p_1``, ``b_i = (R1^2 - R_{i+1}^2 + |p_{i+1} - p_1|^2) / 2``,
    ``x = argmin |A x - b|`` (solved with the pseudo-inverse rather than the thesis's normal
    equations ``(A'A) \\ (A'b)``: same minimiser, better conditioned), position ``x + p1``.
    Needs >= 4 receivers not all in one plane (no mirror ambiguity, so ``side`` is only
    validated). The thesis's nearly flat arrays (z spread 22 mm) make the z coordinate of this
    estimate very noisy; that is the method, not a bug.

    receivers (k, 3) m, ranges (k,) or (N, k) m -> (3,) or (N, 3) m.
    """
    _check_side(side)
    rec = _check_receivers(receivers, None, 4, "linear_ls")
    r, single = _check_ranges(ranges, rec.shape[0])
    _, Apinv = _linear_system(rec, "linear_ls")
    pos, missing = _linear_solve(rec, Apinv, r)
    n = r.shape[0]
    info = _info(rec, pos, r, missing=missing, iterations=np.ones(n, dtype=int),
                 converged=np.ones(n, dtype=bool))
    return _finish(pos, info, single, return_info)


def _linear_solve(rec: np.ndarray, Apinv: np.ndarray, r: np.ndarray):
    A = rec[1:] - rec[0]
    dist2 = np.sum(A * A, axis=1)
    b = 0.5 * (r[:, :1] ** 2 - r[:, 1:] ** 2 + dist2)      # (N, k-1)
    pos = b @ Apinv.T + rec[0]
    missing = np.isnan(r).any(axis=1)
    return pos, missing


def nonlinear_ls(receivers: np.ndarray, ranges: np.ndarray, *, side: int = 1,
                 x0: np.ndarray | None = None, tol: float = NLS_TOL_M,
                 max_iter: int = NLS_MAX_ITER, reflect_start: bool = False,
                 return_info: bool = False) -> np.ndarray | tuple[np.ndarray, TrilaterationInfo]:
    """Gauss-Newton range least squares (Appendix A ``LeastSquare``, method ``'nls'``).

    Minimises ``sum_i (|p - p_i| - R_i)^2``; each step solves ``J'J dp = -J'f`` with
    ``J_i = (p - p_i) / |p - p_i|`` (the thesis's JtJ/Jtf sums). Starts from ``linear_ls``
    (or ``x0``, ``(3,)`` or ``(N, 3)``, required when the receivers are coplanar); a row stops
    when its step norm is below ``tol`` metres (default 1e-9 m = the thesis's 1e-6 mm) or after
    ``max_iter`` iterations (default 15). ``info.iterations`` counts the Gauss-Newton steps
    taken, ``info.converged`` whether the step test was met. A row with no Gauss-Newton step
    (start not finite, iterate exactly on a receiver, or ``J'J`` singular, e.g. coplanar
    receivers with the iterate in their plane) stops at its last iterate with
    ``info.degenerate`` True and ``info.converged`` False; the batch never fails for one row
    and the other rows are unaffected.

    Mirror solutions: for a nearly flat array the cost has two minima mirrored in the array's
    plane and Gauss-Newton converges to the one nearer its start; the thesis's linear start
    lands on the wrong side for some points (its z is poorly determined by 22 mm of receiver
    height). ``reflect_start=True`` (not in the thesis) mirrors a start lying on the ``-side``
    of the receivers' best-fit plane (normal with n_z > 0) to the ``side`` before iterating;
    with the default False, ``side`` is only validated and the start decides.

    receivers (k, 3) m, ranges (k,) or (N, k) m -> (3,) or (N, 3) m.
    """
    _check_side(side)
    max_iter, tol = _check_iter_tol(max_iter, tol)
    rec = _check_receivers(receivers, None, 4, "nonlinear_ls")
    r, single = _check_ranges(ranges, rec.shape[0])
    n = r.shape[0]
    missing = np.isnan(r).any(axis=1)
    if x0 is None:
        _, Apinv = _linear_system(rec, "nonlinear_ls")
        p, _ = _linear_solve(rec, Apinv, r)
    else:
        p = _rows_of_points(x0, "x0", n, allow_nan=True)
    if reflect_start:
        centre = rec.mean(axis=0)
        normal = np.linalg.svd(rec - centre)[2][-1]
        normal = normal if normal[2] > 0 or (normal[2] == 0 and normal[0] >= 0) else -normal
        h = (p - centre) @ normal
        wrong = side * h < 0
        p[wrong] -= 2.0 * h[wrong, None] * normal
    iters = np.zeros(n, dtype=int)
    converged = np.zeros(n, dtype=bool)
    finite = np.all(np.isfinite(p), axis=1)
    degenerate = ~missing & ~finite          # a start that is not a point: no step at all
    active = ~missing & finite
    for _ in range(int(max_iter)):
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        pa = p[idx]
        diff = pa[:, None, :] - rec[None, :, :]               # (M, k, 3)
        dist = np.sqrt(np.einsum("mkc,mkc->mk", diff, diff))
        # on a receiver the Jacobian row (p - p_i) / |p - p_i| is undefined
        ok = np.all(dist > 0, axis=1)
        J = diff / np.where(dist > 0, dist, 1.0)[:, :, None]
        f = dist - r[idx]
        JtJ = np.einsum("mki,mkj->mij", J, J)
        Jtf = np.einsum("mki,mk->mi", J, f)
        ok &= _well_conditioned(JtJ)
        if not ok.all():
            # stop these rows at their current iterate; the others step as before
            degenerate[idx[~ok]] = True
            active[idx[~ok]] = False
            idx, pa, JtJ, Jtf = idx[ok], pa[ok], JtJ[ok], Jtf[ok]
            if idx.size == 0:
                break
        step = -np.linalg.solve(JtJ, Jtf[:, :, None])[:, :, 0]
        p[idx] = pa + step
        iters[idx] += 1
        done = np.linalg.norm(step, axis=1) < tol
        converged[idx[done]] = True
        active[idx[done]] = False
    p[missing] = np.nan
    info = _info(rec, p, r, missing=missing, iterations=iters, converged=converged | missing,
                 degenerate=degenerate)
    return _finish(p, info, single, return_info)


# ---------------------------------------------------------------------------------------------
# damped least squares (>= 3 receivers, missing ranges, known height): not in the thesis
# ---------------------------------------------------------------------------------------------


def _orient(normal: np.ndarray) -> np.ndarray:
    """Unit normals (M, d) oriented as the module's ``+side``: n_z > 0 in 3-D (x, then y
    breaking ties); in 2-D n_x > 0 (then n_y)."""
    key = normal[:, -1] if normal.shape[1] == 3 else normal[:, 0]
    alt = normal[:, 0] if normal.shape[1] == 3 else normal[:, 1]
    flip = (key < 0) | ((key == 0) & (alt < 0))
    return np.where(flip[:, None], -normal, normal)


def _model(G: np.ndarray, dz: np.ndarray | None, p: np.ndarray):
    """Distances (M, k) from points p (M, d) to receivers G (k, d) (plus the fixed vertical
    offsets dz (M, k) in known-height mode) and the unit Jacobian rows (M, k, d)."""
    diff = p[:, None, :] - G[None, :, :]
    d2 = np.einsum("mkc,mkc->mk", diff, diff)
    if dz is not None:
        d2 = d2 + dz * dz
    dist = np.sqrt(d2)
    J = diff / np.where(dist > 0, dist, 1.0)[:, :, None]
    return dist, J


def _project(p: np.ndarray, radius: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points (M, d) pulled onto the ball |p| <= radius (M,); returns (points, on_bound)."""
    norm = np.linalg.norm(p, axis=1)
    out = norm > radius
    scale = np.where(out, radius / np.where(norm > 0, norm, 1.0), 1.0)
    return p * scale[:, None], out


def _levenberg_marquardt(G, dz, r, w, p0, radius, tol, max_iter, scale):
    """Algorithm 3.16 of Madsen, Nielsen and Tingleff (2004) on the range residuals, per row
    in the compiled :func:`estimator.range_kernels.lm_rows`; arguments and results as
    :func:`_levenberg_marquardt_reference` (the batched numpy version, kept as the reference:
    the same iterates to rounding, tested)."""
    m, d = p0.shape
    has_dz = dz is not None
    dzz = np.ascontiguousarray(dz, dtype=float) if has_dz else np.zeros((m, G.shape[0]))
    p, iters, done, bound, cost, A = range_kernels.lm_rows(
        np.ascontiguousarray(G, dtype=float), dzz, has_dz, np.ascontiguousarray(r, float),
        np.ascontiguousarray(w, dtype=bool), np.array(p0, dtype=float), np.asarray(radius, float),
        float(tol), int(max_iter), np.asarray(scale, dtype=float))
    return p, iters, done, bound, cost, _well_conditioned(A)


def _levenberg_marquardt_reference(G, dz, r, w, p0, radius, tol, max_iter, scale):
    """Batched Algorithm 3.16 of Madsen, Nielsen and Tingleff (2004) on the range residuals.

    G (k, d) receivers (centred), dz (M, k) or None, r (M, k) with 0 where w is False, w (M, k)
    bool, p0 (M, d) finite starts inside the ball, radius (M,) trust-region bound, scale (M,)
    the problem's length scale for the relative tests. Returns p, iterations, stopped-by-test,
    on-bound, cost (sum of squared residuals), well-conditioned J'J at the end.
    """
    m, d = p0.shape
    eye = np.eye(d)
    p = p0.copy()

    def evaluate(pts, rows):
        dist, J = _model(G, None if dz is None else dz[rows], pts)
        f = np.where(w[rows], dist - r[rows], 0.0)
        J = J * w[rows][:, :, None]
        return f, np.einsum("mki,mkj->mij", J, J), np.einsum("mki,mk->mi", J, f)

    f, A, g = evaluate(p, np.arange(m))
    cost = np.sum(f * f, axis=1)
    eps1 = tol * scale
    mu = 1e-3 * np.max(np.diagonal(A, axis1=1, axis2=2), axis=1)   # tau = 1e-3 (Eq. 3.14)
    mu = np.where(mu > 0, mu, 1e-3)
    nu = np.full(m, 2.0)
    done = np.max(np.abs(g), axis=1) <= eps1
    iters = np.zeros(m, dtype=int)
    bound = np.zeros(m, dtype=bool)
    for _ in range(max_iter):
        idx = np.flatnonzero(~done)
        if idx.size == 0:
            break
        iters[idx] += 1
        h = -np.linalg.solve(A[idx] + mu[idx, None, None] * eye, g[idx][:, :, None])[:, :, 0]
        hn = np.linalg.norm(h, axis=1)
        small = hn <= tol * (np.linalg.norm(p[idx], axis=1) + scale[idx])
        done[idx[small]] = True
        idx, h = idx[~small], h[~small]
        if idx.size == 0:
            break
        p_new, on_b = _project(p[idx] + h, radius[idx])
        f_new, A_new, g_new = evaluate(p_new, idx)
        cost_new = np.sum(f_new * f_new, axis=1)
        # gain ratio (Eq. 3.15): actual / predicted decrease of F = cost / 2
        pred = 0.5 * np.einsum("mi,mi->m", h, mu[idx, None] * h - g[idx])
        with np.errstate(divide="ignore", invalid="ignore"):
            rho = 0.5 * (cost[idx] - cost_new) / pred
        acc = (cost_new < cost[idx]) & (rho > 0)
        ia, ir = idx[acc], idx[~acc]
        p[ia], cost[ia], A[ia], g[ia], bound[ia] = (p_new[acc], cost_new[acc], A_new[acc],
                                                  g_new[acc], on_b[acc])
        mu[ia] *= np.maximum(1.0 / 3.0, 1.0 - (2.0 * rho[acc] - 1.0) ** 3)
        nu[ia] = 2.0
        mu[ir] *= nu[ir]
        nu[ir] *= 2.0
        done[ia[np.max(np.abs(g[ia]), axis=1) <= eps1[ia]]] = True
        # a damping factor this large means no step can lower the cost: stuck, not converged
        stuck = ~np.isfinite(mu) | (mu > 1e300)
        mu = np.where(stuck, 1e300, mu)
        nu = np.minimum(nu, 1e300)
    return p, iters, done, bound, cost, _well_conditioned(A)


def _linear_start(G, rho2, w, side):
    """Linearised start: differences against the first receiver of each row, solved by SVD.

    Full rank: the least-squares point. One rank short (three receivers, a coplanar set in 3-D,
    a collinear one in known-height mode): the minimum-norm point plus the offset along the
    null direction that puts it on the reference sphere, on ``side`` of the oriented normal.
    Returns starts (M, d) (NaN where rank < d - 1), oriented normals (M, d), the reference
    receiver's index and the rank (M,).
    """
    m = rho2.shape[0]
    d = G.shape[1]
    a = np.argmax(w, axis=1)
    rows = np.arange(m)
    Ga = G[a]
    rho2a = rho2[rows, a]
    use = w.copy()
    use[rows, a] = False
    A = (G[None, :, :] - Ga[:, None, :]) * use[:, :, None]
    b = 0.5 * (rho2a[:, None] - np.where(use, rho2, 0.0)
               + np.sum(G * G, axis=1)[None, :] - np.sum(Ga * Ga, axis=1)[:, None]) * use
    U, S, Vt = np.linalg.svd(A, full_matrices=False)
    sig = _COPLANAR_REL * S[:, :1] < S
    inv = np.where(sig, 1.0 / np.where(sig, S, 1.0), 0.0)
    x = np.einsum("mji,mj,mkj,mk->mi", Vt, inv, U, b)          # V diag(1/S) U' b
    rank = sig.sum(axis=1)
    normal = _orient(Vt[:, -1, :])
    short = rank == d - 1
    if short.any():
        beta = np.einsum("mi,mi->m", normal, x - Ga)
        gamma = np.sum((x - Ga) ** 2, axis=1) - rho2a
        t = -beta + side * np.sqrt(np.maximum(beta * beta - gamma, 0.0))
        x = np.where(short[:, None], x + t[:, None] * normal, x)
    x[rank < d - 1] = np.nan
    return x, normal, a, rank


def damped_ls(receivers: np.ndarray, ranges: np.ndarray, *, height_m=None,
              x0: np.ndarray | None = None, prior: np.ndarray | None = None, side: int = 1,
              sigma_m: float = 0.1, bound_slack_m: float | None = None, tol: float = DLS_TOL,
              max_iter: int = DLS_MAX_ITER,
              return_info: bool = False) -> np.ndarray | tuple[np.ndarray, TrilaterationInfo]:
    """Damped range least squares for real data (not in the thesis; see the module docstring).

    Minimises ``sum_i (|p - p_i| - R_i)^2`` over the receivers with a finite range in each row
    (>= 3 needed; fewer: ``missing``) by Levenberg-Marquardt (Madsen, Nielsen and Tingleff
    2004, Algorithm 3.16) inside the trust-region ball ``|p - c| <= min_i (R_i + |p_i - c|) +
    bound_slack_m`` (``c`` the receivers' centroid; default slack 10 ``sigma_m``).

    receivers (k, 3) m, k >= 3; ranges (k,) or (N, k) m, NaN = that receiver missing.
    height_m : None (solve x, y, z) or the tag's known z, scalar or (N,) m: only x, y are
        solved (known-height mode, for a ground tag or a flat array seen from afar).
    x0 : start, (3,) or (N, 3) m (e.g. the previous fix); default the linearised solution.
    prior : (3,) or (N, 3) m, NaN allowed: decides between two mirror minima that fit equally
        well (continuity with the previous fix); rows without a prior use ``side``.
    side : +1 / -1, the mirror side when there is no prior (the module's convention).
    sigma_m : range noise std (m): mirror minima whose sums of squared residuals differ by
        less than 9 sigma_m^2 are ``ambiguous``; also sets the default bound slack.
    tol, max_iter : relative gradient/step tolerance and iteration cap of Algorithm 3.16.

    Returns positions (3,) or (N, 3) m (NaN for ``missing`` rows and rows whose receivers fix
    no start, flagged ``degenerate``) [and :class:`TrilaterationInfo`].
    """
    side = _check_side(side)
    max_iter, tol = _check_iter_tol(max_iter, tol)
    sigma = check_real(sigma_m, "sigma_m", lo=0.0, lo_open=True, hi=MAX_ABS_M)
    slack = 10.0 * sigma if bound_slack_m is None else check_real(
        bound_slack_m, "bound_slack_m", lo=0.0, hi=MAX_ABS_M)
    rec = _check_receivers(receivers, None, 3, "damped_ls")
    r, single = _check_ranges(ranges, rec.shape[0])
    n = r.shape[0]
    centre = rec.mean(axis=0)
    q = rec - centre
    w = np.isfinite(r)
    missing = w.sum(axis=1) < 3
    w &= ~missing[:, None]
    r0 = np.where(w, r, 0.0)
    if height_m is None:
        d, G, dz, rho2 = 3, q, None, r0 * r0
    else:
        h = check_array(height_m, "height_m", max_abs=MAX_ABS_M)
        if h.shape not in ((), (n,)):
            raise ValueError(f"height_m: expected a scalar or shape ({n},), got {h.shape}")
        d, G = 2, q[:, :2]
        hz = np.broadcast_to(h, (n,))
        dz = (hz - centre[2])[:, None] - q[None, :, 2]
        rho2 = np.maximum(r0 * r0 - dz * dz, 0.0)
    pri = None if prior is None else _rows_of_points(prior, "prior", n, allow_nan=True) - centre

    pos = np.full((n, d), np.nan)
    iters = np.zeros(n, dtype=int)
    conv = np.zeros(n, dtype=bool)
    degen = np.zeros(n, dtype=bool)
    bnd = np.zeros(n, dtype=bool)
    amb = np.zeros(n, dtype=bool)
    alt = np.full((n, 3), np.nan)
    live = np.flatnonzero(~missing)
    if live.size:
        wl, rl, rho2l = w[live], r0[live], rho2[live]
        dzl = None if dz is None else dz[live]
        start, normal, ref, rank = _linear_start(G, rho2l, wl, side)
        if x0 is not None:
            start = _rows_of_points(x0, "x0", n, allow_nan=False)[live] - centre
            start = start[:, :d]
        radius = np.min(np.where(wl, np.sqrt(rho2l) + np.linalg.norm(G, axis=1)[None], np.inf),
                        axis=1) + slack
        scale = np.maximum(np.max(rl, axis=1), float(np.max(np.ptp(G, axis=0))))
        ok = np.all(np.isfinite(start), axis=1)
        degen[live[~ok]] = True
        li, start, normal, ref, rank = live[ok], start[ok], normal[ok], ref[ok], rank[ok]
        wl, rl, radius, scale = wl[ok], rl[ok], radius[ok], scale[ok]
        dzl = None if dzl is None else dzl[ok]
        start, _ = _project(start, radius)
        pa, ia, ca, ba, costa, wca = _levenberg_marquardt(G, dzl, rl, wl, start, radius, tol,
                                                          max_iter, scale)
        # the mirror minimum: restart from the solution reflected in the receivers' best-fit
        # plane (3-D) or, in known-height mode, their best-fit line in x-y: exact for a
        # coplanar (collinear) set, a second local minimum for a nearly flat (nearly
        # collinear) one, the same minimum again otherwise
        mir = np.ones(li.size, dtype=bool)
        pb, cb, bb, costb, wcb = pa.copy(), ca.copy(), ba.copy(), costa.copy(), wca.copy()
        ib = np.zeros_like(ia)
        if mir.any():
            Ga = G[ref[mir]]
            hgt = np.einsum("mi,mi->m", pa[mir] - Ga, normal[mir])
            sb, _ = _project(pa[mir] - 2.0 * hgt[:, None] * normal[mir], radius[mir])
            out = _levenberg_marquardt(G, None if dzl is None else dzl[mir], rl[mir], wl[mir],
                                       sb, radius[mir], tol, max_iter, scale[mir])
            pb[mir], ib[mir], cb[mir], bb[mir], costb[mir], wcb[mir] = out
        distinct = np.linalg.norm(pa - pb, axis=1) > 1e-6 * scale
        delta = costb - costa                           # sums of squared residuals, m^2
        b_better = distinct & (delta < -9.0 * sigma ** 2)
        tie = distinct & ~b_better & (delta <= 9.0 * sigma ** 2)
        # ties: nearer the prior, else on `side` of the oriented normal
        choose_b = b_better.copy()
        if tie.any():
            hb = np.einsum("mi,mi->m", pb - G[ref], normal)
            ha = np.einsum("mi,mi->m", pa - G[ref], normal)
            by_side = side * hb > side * ha
            if pri is not None:
                pr = pri[li][:, :d]
                has = np.all(np.isfinite(pr), axis=1)
                nearer_b = np.linalg.norm(pb - pr, axis=1) < np.linalg.norm(pa - pr, axis=1)
                by_side = np.where(has, nearer_b, by_side)
            choose_b |= tie & by_side
        sel = choose_b[:, None]
        pos[li] = np.where(sel, pb, pa)
        other = np.where(sel, pa, pb)
        iters[li] = ia + ib
        bnd[li] = np.where(choose_b, bb, ba)
        wc = np.where(choose_b, wcb, wca)
        conv[li] = np.where(choose_b, cb, ca) & ~bnd[li] & wc
        degen[li] = ~wc
        amb[li] = tie
        full_other = np.empty((li.size, 3))
        full_other[:, :d] = other + centre[:d]
        if d == 2:
            full_other[:, 2] = hz[li]
        alt[li] = np.where(distinct[:, None], full_other, np.nan)
    out = np.full((n, 3), np.nan)
    out[:, :d] = pos + centre[:d]
    if d == 2:
        out[:, 2] = hz
        out[np.isnan(pos[:, 0])] = np.nan
    info = _info(rec, out, np.where(w, r, np.nan), missing=missing, iterations=iters,
                 converged=conv, degenerate=degen, bounded=bnd, ambiguous=amb,
                 alternative=alt)
    return _finish(out, info, single, return_info)


#: name -> function, in the thesis's order, then the damped solver (not in the thesis).
METHODS = {
    "simple": simple,
    "linear_ls": linear_ls,
    "nonlinear_ls": nonlinear_ls,
    "closed_form": closed_form,
    "cayley_menger": cayley_menger,
    "damped_ls": damped_ls,
}
