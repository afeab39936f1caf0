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
wrong shapes and negative ranges raise ``ValueError`` naming the field.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "METHODS",
    "NLS_MAX_ITER",
    "NLS_TOL_M",
    "TrilaterationInfo",
    "cayley_menger",
    "closed_form",
    "linear_ls",
    "nonlinear_ls",
    "simple",
]

#: Gauss-Newton stops when the step norm is below this (metres). The thesis used 1e-6 mm.
NLS_TOL_M = 1e-9
#: Gauss-Newton iteration cap; the thesis's ``while ... i_count_nls <= 15``.
NLS_MAX_ITER = 15

# Relative tolerances for degenerate geometry, against the layout's own length scale.
_COINCIDENT_REL = 1e-9   # receivers closer than this x array size are "coincident"
_COLLINEAR_SIN = 1e-9    # |v1 x v2| <= this * |v1| |v2|: the three receivers are collinear
_COPLANAR_REL = 1e-9     # smallest singular value of the difference matrix vs the largest
#: Gauss-Newton: J'J counts as singular when its smallest eigenvalue is <= this x its largest
#: (condition number >= 1e12: the step would keep fewer than ~4 significant digits).
_NLS_SINGULAR_REL = 1e-12


def _well_conditioned(A: np.ndarray) -> np.ndarray:
    """(M,) bool for symmetric PSD (M, 3, 3): smallest eigenvalue > _NLS_SINGULAR_REL x largest.

    Cheap sufficient test first: det > rel * trace^3 implies lambda_min >= det / lambda_max^2
    > rel * lambda_max (trace >= lambda_max). Only rows failing it (rare: degenerate ones)
    get the exact eigenvalue test, so the Gauss-Newton loop does not pay an eigen-
    decomposition per row and iteration.
    """
    det = (A[:, 0, 0] * (A[:, 1, 1] * A[:, 2, 2] - A[:, 1, 2] * A[:, 2, 1])
           - A[:, 0, 1] * (A[:, 1, 0] * A[:, 2, 2] - A[:, 1, 2] * A[:, 2, 0])
           + A[:, 0, 2] * (A[:, 1, 0] * A[:, 2, 1] - A[:, 1, 1] * A[:, 2, 0]))
    tr = A[:, 0, 0] + A[:, 1, 1] + A[:, 2, 2]
    ok = det > _NLS_SINGULAR_REL * tr ** 3
    rest = np.flatnonzero(~ok)
    if rest.size:
        ev = np.linalg.eigvalsh(A[rest])                      # ascending, >= 0 up to rounding
        ok[rest] = ev[:, 0] > _NLS_SINGULAR_REL * ev[:, -1]
    return ok


@dataclass(frozen=True)
class TrilaterationInfo:
    """Per-row diagnostics of a trilateration call.

    Attributes (each ``(N,)``, or 0-d for a single range set):
    no_intersection : bool, the spheres do not meet; the closest real point was returned.
    missing : bool, the row had a NaN range; the position is NaN.
    iterations : int, Gauss-Newton iterations (``nonlinear_ls``); 1 for ``linear_ls`` (as the
        thesis's ``i_count_ls``); 0 for the closed forms.
    converged : bool, ``nonlinear_ls`` step fell below ``tol`` within ``max_iter``; True for the
        direct methods.
    degenerate : bool, ``nonlinear_ls`` found no Gauss-Newton step (start not finite, iterate
        on a receiver, or ``J'J`` singular: condition number >= 1e12) and stopped the row at
        its last iterate (see the module docstring); False for the other methods.
    """

    no_intersection: np.ndarray
    missing: np.ndarray
    iterations: np.ndarray
    converged: np.ndarray
    degenerate: np.ndarray


# ---------------------------------------------------------------------------------------------
# validation helpers
# ---------------------------------------------------------------------------------------------


def _check_receivers(receivers: np.ndarray, k: int | None, min_k: int, method: str) -> np.ndarray:
    rec = np.asarray(receivers, dtype=float)
    if rec.ndim != 2 or rec.shape[1] != 3:
        raise ValueError(f"receivers: expected shape (k, 3), got {rec.shape}")
    if k is not None and rec.shape[0] != k:
        raise ValueError(f"receivers: {method} needs exactly {k} receivers, got {rec.shape[0]}")
    if rec.shape[0] < min_k:
        raise ValueError(f"receivers: {method} needs >= {min_k} receivers, got {rec.shape[0]}")
    if not np.all(np.isfinite(rec)):
        raise ValueError("receivers: must be finite")
    scale = float(np.max(np.ptp(rec, axis=0))) if rec.shape[0] > 1 else 0.0
    diff = rec[:, None, :] - rec[None, :, :]
    dist = np.sqrt(np.einsum("ijk,ijk->ij", diff, diff))
    iu = np.triu_indices(rec.shape[0], 1)
    if scale == 0.0 or np.min(dist[iu]) <= _COINCIDENT_REL * scale:
        i, j = iu[0][np.argmin(dist[iu])], iu[1][np.argmin(dist[iu])]
        raise ValueError(f"receivers: receivers {i} and {j} coincide ({dist[i, j]:.3g} m apart)")
    return rec


def _check_ranges(ranges: np.ndarray, k: int) -> tuple[np.ndarray, bool]:
    r = np.asarray(ranges, dtype=float)
    single = r.ndim == 1
    if single:
        r = r[None, :]
    if r.ndim != 2 or r.shape[1] != k:
        raise ValueError(f"ranges: expected shape ({k},) or (N, {k}), got {np.shape(ranges)}")
    if np.any(np.isinf(r)):
        raise ValueError("ranges: must be finite or NaN (NaN = missing), got inf")
    if np.any(r < 0):
        raise ValueError(f"ranges: must be >= 0, got min {np.nanmin(r):.6g} m")
    return r, single


def _check_side(side: int) -> int:
    if side not in (1, -1):
        raise ValueError(f"side: must be +1 or -1, got {side!r}")
    return int(side)


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


def _finish(pos: np.ndarray, info: TrilaterationInfo, single: bool, return_info: bool):
    if single:
        pos = pos[0]
        info = TrilaterationInfo(*(np.asarray(a)[0] for a in (
            info.no_intersection, info.missing, info.iterations, info.converged,
            info.degenerate)))
    return (pos, info) if return_info else pos


def _direct_info(no_int: np.ndarray, missing: np.ndarray) -> TrilaterationInfo:
    n = no_int.shape[0]
    return TrilaterationInfo(no_int & ~missing, missing, np.zeros(n, dtype=int),
                             np.ones(n, dtype=bool), np.zeros(n, dtype=bool))


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
    return _finish(pos, _direct_info(no_int, missing), single, return_info)


def closed_form(receivers: np.ndarray, ranges: np.ndarray, *, side: int = 1,
                return_info: bool = False) -> np.ndarray | tuple[np.ndarray, TrilaterationInfo]:
    """Closed-form "CFP" trilateration (Appendix A ``ExplicitMethod_CFP``).

    Subtracting sphere 1 from spheres 2 and 3 gives two linear equations
    ``W [x, y]^T + d z = beta`` with ``W = [[x21, y21], [x31, y31]]``, ``d = [z21, z31]``,
    ``beta_i = (R1^2 - Ri^2 - S1^2 + Si^2) / 2`` (S_i = |p_i|). Hence
    ``[x, y] = W^-1 (beta - d z)``, and sphere 1 becomes the quadratic
    ``a z^2 + b z + c = 0`` with the thesis's ``a_cf = 1 + |W^-1 d|^2``, ``b_cf``, ``c_cf``.
    The thesis's "original position calculation" (``R_cfp1``) is implemented; its "improved"
    re-expression (``R_cfp2``, Lambda/zeta) is algebraically the same point.

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
    P = rec[:, a_idx + [q]]                   # permuted so the quadratic coordinate is last
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
    return _finish(pos, _direct_info(no_int, missing), single, return_info)


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
    return _finish(pos, _direct_info(no_int, missing), single, return_info)


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
    info = TrilaterationInfo(np.zeros(n, dtype=bool), missing, np.ones(n, dtype=int),
                             np.ones(n, dtype=bool), np.zeros(n, dtype=bool))
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
    if not (tol > 0):
        raise ValueError(f"tol: must be > 0 metres, got {tol!r}")
    if int(max_iter) != max_iter or max_iter < 1:
        raise ValueError(f"max_iter: must be a positive integer, got {max_iter!r}")
    rec = _check_receivers(receivers, None, 4, "nonlinear_ls")
    r, single = _check_ranges(ranges, rec.shape[0])
    n = r.shape[0]
    missing = np.isnan(r).any(axis=1)
    if x0 is None:
        _, Apinv = _linear_system(rec, "nonlinear_ls")
        p, _ = _linear_solve(rec, Apinv, r)
    else:
        p = np.broadcast_to(np.asarray(x0, dtype=float), (n, 3)).copy() if np.ndim(x0) == 1 \
            else np.asarray(x0, dtype=float).copy()
        if p.shape != (n, 3):
            raise ValueError(f"x0: expected shape (3,) or ({n}, 3), got {np.shape(x0)}")
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
    info = TrilaterationInfo(np.zeros(n, dtype=bool), missing, iters, converged | missing,
                             degenerate)
    return _finish(p, info, single, return_info)


#: name -> function, in the thesis's order.
METHODS = {
    "simple": simple,
    "linear_ls": linear_ls,
    "nonlinear_ls": nonlinear_ls,
    "closed_form": closed_form,
    "cayley_menger": cayley_menger,
}
