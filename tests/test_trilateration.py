"""Trilateration (thesis 003, Appendix A): exact recovery, agreement, flags, validation."""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from estimator import trilateration as T

THREE = ("simple", "closed_form", "cayley_menger")
MANY = ("linear_ls", "nonlinear_ls")

# Exact ranges: every method is a closed form or converges quadratically, so the only error is
# floating-point rounding amplified by the geometry's conditioning. 1e-9 relative to the
# problem size (issue 7) leaves that rounding 4-6 orders of headroom for the well-conditioned
# layouts drawn below (triangle angles and heights bounded away from zero).
REL = 1e-9


def _side_normal(r3):
    n = np.cross(r3[1] - r3[0], r3[2] - r3[0])
    return n if n[2] > 0 else -n


def _well_conditioned(rec, tri_only=True):
    r3 = rec[:3]
    v1, v2 = r3[1] - r3[0], r3[2] - r3[0]
    sin = np.linalg.norm(np.cross(v1, v2)) / (np.linalg.norm(v1) * np.linalg.norm(v2))
    short = min(np.linalg.norm(v1), np.linalg.norm(v2), np.linalg.norm(r3[2] - r3[1]))
    ok = sin > 0.2 and short > 0.2
    if not tri_only:
        A = rec[1:] - rec[0]
        sv = np.linalg.svd(A, compute_uv=False)
        ok = ok and sv[-1] / sv[0] > 0.1
    return ok


layouts = st.integers(0, 2**32 - 1)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.filter_too_much])
@given(seed=layouts)
def test_three_receiver_methods_recover_exact_positions(seed):
    rng = np.random.default_rng(seed)
    rec = rng.uniform(-2, 2, size=(3, 3))
    if not _well_conditioned(rec):
        return
    n = _side_normal(rec)
    P = rng.uniform(-6, 6, size=(50, 3))
    height = (P - rec[0]) @ n / np.linalg.norm(n)
    P = P[np.abs(height) > 0.3]          # points on the plane are a double root
    R = np.linalg.norm(P[:, None] - rec[None], axis=2)
    side = np.where((P - rec[0]) @ n > 0, 1, -1)
    scale = np.max(np.linalg.norm(P[:, None] - rec[None], axis=2))
    for name in THREE:
        f = T.METHODS[name]
        for s in (1, -1):
            m = side == s
            if not m.any():
                continue
            out, info = f(rec, R[m], side=s, return_info=True)
            assert out.shape == (m.sum(), 3)
            np.testing.assert_allclose(out, P[m], rtol=0, atol=REL * scale, err_msg=name)
            assert not info.no_intersection.any()
            # single range set == the batched row
            one = f(rec, R[m][0], side=s)
            assert one.shape == (3,)
            np.testing.assert_allclose(one, out[0], rtol=0, atol=1e-12 * scale)


@settings(max_examples=40, deadline=None)
@given(seed=layouts, k=st.integers(4, 8))
def test_least_squares_recover_exact_positions(seed, k):
    rng = np.random.default_rng(seed)
    rec = rng.uniform(-2, 2, size=(k, 3))
    if not _well_conditioned(rec, tri_only=False):
        return
    P = rng.uniform(-6, 6, size=(50, 3))
    R = np.linalg.norm(P[:, None] - rec[None], axis=2)
    scale = np.max(R)
    for name in MANY:
        out, info = T.METHODS[name](rec, R, return_info=True)
        np.testing.assert_allclose(out, P, rtol=0, atol=REL * scale, err_msg=name)
        np.testing.assert_allclose(T.METHODS[name](rec, R[3]), out[3], rtol=0,
                                   atol=1e-12 * scale)
    _, info = T.nonlinear_ls(rec, R, return_info=True)
    assert info.converged.all()
    assert (info.iterations >= 1).all() and (info.iterations <= T.NLS_MAX_ITER).all()


def test_cfp_and_cmd_agree_on_noisy_ranges():
    # Same point in exact arithmetic, noise or not (both solve the same three sphere
    # equations); they differ only by rounding, which 1e-9 m covers at these 10 m scales.
    rng = np.random.default_rng(3)
    rec = np.array([[0.0, 0.0, 0.0], [1.3, 0.0, 0.0], [0.65, 1.13, 0.0]])
    P = np.c_[rng.uniform(-8, 8, (2000, 2)), np.full(2000, 5.0)]
    R = np.linalg.norm(P[:, None] - rec[None], axis=2) + rng.normal(0, 0.005, (2000, 3))
    a, ia = T.closed_form(rec, R, return_info=True)
    b, ib = T.cayley_menger(rec, R, return_info=True)
    c = T.simple(rec, R)
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-9 * 10)
    np.testing.assert_allclose(a, c, rtol=0, atol=1e-9 * 10)
    np.testing.assert_array_equal(ia.no_intersection, ib.no_intersection)


def test_no_intersection_returns_real_in_plane_point_and_flags():
    rec = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 2.0, 0.0]])
    # row 0: unit spheres around points 2 m apart: the radical line pierces the plane at
    # (1, 1, 0), sqrt(2) m from every centre, so the spheres miss it; row 1 intersects.
    R = np.array([[1.0, 1.0, 1.0], [0.5, 1.9, 1.9]])
    for name in THREE:
        out, info = T.METHODS[name](rec, R, return_info=True)
        assert np.all(np.isfinite(out)) and out.dtype == float
        assert info.no_intersection.tolist() == [True, False], name
        np.testing.assert_allclose(out[0], [1.0, 1.0, 0.0], atol=1e-12)
        # the returned point satisfies both sphere-difference equations (the radical line)
        d = np.linalg.norm(out[0] - rec, axis=1) ** 2 - R[0] ** 2
        assert d[1] - d[0] == pytest.approx(0.0, abs=1e-9)
        assert d[2] - d[0] == pytest.approx(0.0, abs=1e-9)


def test_missing_ranges_give_flagged_nan_rows():
    rng = np.random.default_rng(0)
    rec = rng.uniform(-2, 2, size=(6, 3))
    R = np.linalg.norm(rng.uniform(-5, 5, (4, 3))[:, None] - rec[None], axis=2)
    R[1, 2] = np.nan
    for name, rr in [(m, rec[:3]) for m in THREE] + [(m, rec) for m in MANY]:
        out, info = T.METHODS[name](rr, R[:, : rr.shape[0]], return_info=True)
        assert info.missing.tolist() == [False, True, False, False], name
        assert np.isnan(out[1]).all() and np.isfinite(out[[0, 2, 3]]).all()


def test_side_picks_mirror_solutions():
    rec = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    P = np.array([0.3, 0.4, 2.0])
    R = np.linalg.norm(P - rec, axis=1)
    for name in THREE:
        np.testing.assert_allclose(T.METHODS[name](rec, R, side=1), P, atol=1e-12)
        np.testing.assert_allclose(T.METHODS[name](rec, R, side=-1), P * [1, 1, -1], atol=1e-12)
        # the receivers' order (right-hand normal down) must not flip "above"
        np.testing.assert_allclose(T.METHODS[name](rec[[0, 2, 1]], R[[0, 2, 1]], side=1), P,
                                   atol=1e-12)


def test_vertical_receiver_plane_closed_form():
    rec = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])   # plane y = 0
    P = np.array([[0.2, 3.0, 0.4], [0.7, -2.0, 0.1]])
    R = np.linalg.norm(P[:, None] - rec[None], axis=2)
    for name in THREE:
        a = T.METHODS[name](rec, R, side=1)
        b = T.METHODS[name](rec, R, side=-1)
        got = np.where(np.isclose(a, P, atol=1e-9).all(axis=1)[:, None], a, b)
        np.testing.assert_allclose(got, P, atol=1e-9, err_msg=name)


def test_nonlinear_ls_reports_iterations_and_reduces_residual():
    rng = np.random.default_rng(5)
    rec = np.array([[0.325, 0.534, 0.022], [0.975, 0.534, 0.022], [0.65, 0.0, 0.022],
                    [0.65, 1.126, 0.0], [0.0, 0.0, 0.0], [1.3, 0.0, 0.0]])
    P = np.c_[rng.uniform(-3, 3, (200, 2)), np.full(200, 2.0)]
    R = np.linalg.norm(P[:, None] - rec[None], axis=2) + rng.normal(0, 0.005, (200, 6))
    lin = T.linear_ls(rec, R)
    nl, info = T.nonlinear_ls(rec, R, return_info=True)
    def cost(X):
        return np.sum((np.linalg.norm(X[:, None] - rec[None], axis=2) - R) ** 2, axis=1)

    assert np.all(cost(nl) <= cost(lin) + 1e-15)
    assert info.iterations.dtype.kind == "i" and info.iterations.max() <= T.NLS_MAX_ITER
    _, info1 = T.nonlinear_ls(rec, R, max_iter=1, return_info=True)
    assert (info1.iterations == 1).all()


@pytest.mark.parametrize("bad, field", [
    (np.zeros((3, 2)), "receivers"),
    (np.array([[0, 0, 0], [0, 0, 0], [1, 1, 0.0]]), "receivers"),     # coincident
    (np.array([[0, 0, 0], [1, 1, 1], [2, 2, 2.0]]), "receivers"),     # collinear
])
def test_degenerate_geometry_raises(bad, field):
    for name in THREE:
        with pytest.raises(ValueError, match=field):
            T.METHODS[name](bad, np.ones(3))


def test_bad_inputs_raise_naming_field():
    rec = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    with pytest.raises(ValueError, match="ranges"):
        T.cayley_menger(rec[:3], np.ones(4))
    with pytest.raises(ValueError, match="ranges"):
        T.simple(rec[:3], np.array([1.0, -1.0, 1.0]))
    with pytest.raises(ValueError, match="side"):
        T.closed_form(rec[:3], np.ones(3), side=0)
    with pytest.raises(ValueError, match="receivers"):
        T.linear_ls(rec[:3], np.ones(3))
    flat = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    with pytest.raises(ValueError, match="receivers"):
        T.linear_ls(flat, np.ones(4))
    with pytest.raises(ValueError, match="x0"):
        T.nonlinear_ls(flat, np.ones((2, 4)), x0=np.zeros((3, 3)))
    # coplanar receivers work for Gauss-Newton from a given start
    P = np.array([0.4, 0.3, 2.0])
    out = T.nonlinear_ls(flat, np.linalg.norm(P - flat, axis=1), x0=[0.5, 0.5, 1.0])
    np.testing.assert_allclose(out, P, atol=1e-9)


def test_reflect_start_removes_mirror_solutions_of_a_flat_array():
    # Appendix B layout: 22 mm of receiver height spread, so the linear start's z is nearly
    # unobservable and some starts fall below the array; Gauss-Newton then converges to the
    # mirror point. reflect_start moves the start to the platform side first.
    rec = np.array([[0.325, 0.534, 0.022], [0.975, 0.534, 0.022], [0.65, 0.0, 0.022],
                    [0.65, 1.126, 0.0], [0.0, 0.0, 0.0], [1.3, 0.0, 0.0]])
    rng = np.random.default_rng(11)
    P = np.c_[rng.uniform(-8, 8, (4000, 2)), np.full(4000, 5.0)]
    R = np.linalg.norm(P[:, None] - rec[None], axis=2) + rng.normal(0, 0.005, (4000, 6))
    plain = T.nonlinear_ls(rec, R)
    fixed = T.nonlinear_ls(rec, R, reflect_start=True)
    assert np.sum(plain[:, 2] < 0) > 0                 # the thesis's start does mirror
    assert np.all(fixed[:, 2] > 0)
    same = plain[:, 2] > 0                             # where the start was right: unchanged
    np.testing.assert_allclose(fixed[same], plain[same], atol=1e-9)
    single, info = T.nonlinear_ls(rec, R[0], reflect_start=True, return_info=True)
    assert single.shape == (3,) and np.ndim(info.iterations) == 0


def test_nonlinear_ls_degenerate_rows_are_flagged_and_do_not_touch_the_batch():
    # Coplanar receivers (z = 0). Rows 0 and 3 start above the plane (normal Gauss-Newton);
    # row 1 starts in the plane at a three-receiver no_intersection point, where J'J is
    # singular (every Jacobian row has zero z); row 2 starts exactly on receiver 1, where
    # the Jacobian divides by zero. Before: LinAlgError for the whole batch.
    flat = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    P = np.array([[0.4, 0.3, 2.0], [0.2, 0.7, 1.5], [0.6, 0.6, 1.0], [0.9, 0.1, 3.0]])
    R = np.linalg.norm(P[:, None] - flat[None], axis=2)
    R[1, :3] = 0.2                                   # three spheres of 0.2 m do not meet
    x3, i3 = T.cayley_menger(flat[:3], R[1, :3], return_info=True)
    assert i3.no_intersection and x3[2] == 0.0       # the start lies in the receivers' plane
    x0 = np.array([[0.5, 0.5, 1.0], x3, flat[1], [0.5, 0.5, 1.0]])
    out, info = T.nonlinear_ls(flat, R, x0=x0, return_info=True)
    normal = [0, 3]
    alone, info_alone = T.nonlinear_ls(flat, R[normal], x0=x0[normal], return_info=True)
    np.testing.assert_allclose(out[normal], alone, rtol=0, atol=1e-12)
    np.testing.assert_allclose(out[normal], P[normal], atol=1e-9)
    assert list(info.degenerate) == [False, True, True, False]
    assert list(info.converged) == [True, False, False, True]
    assert not info.missing.any()
    # degenerate rows stop at their last (here: first) iterate, finite, never a silent NaN
    np.testing.assert_array_equal(out[[1, 2]], x0[[1, 2]])
    assert list(info.iterations) == [info_alone.iterations[0], 0, 0, info_alone.iterations[1]]
    # a start that is not a point is flagged too; NaN ranges stay "missing", not degenerate
    x0n = x0.copy()
    x0n[1] = np.nan
    Rn = R.copy()
    Rn[2, 0] = np.nan
    out2, info2 = T.nonlinear_ls(flat, Rn, x0=x0n, return_info=True)
    assert list(info2.degenerate) == [False, True, False, False]
    assert list(info2.missing) == [False, False, True, False]
    np.testing.assert_allclose(out2[normal], alone, rtol=0, atol=1e-12)
    # the direct methods never report degenerate rows
    _, i_lin = T.linear_ls(np.r_[flat[:3], [[0.0, 0.0, 1.0]]], R, return_info=True)
    assert not i_lin.degenerate.any() and not i3.degenerate


def test_nls_conditioning_test_equals_the_eigenvalue_rule():
    """The cheap determinant pre-test classifies exactly like lambda_min > rel * lambda_max."""
    from estimator.trilateration import _NLS_SINGULAR_REL, _well_conditioned

    rng = np.random.default_rng(5)
    M = rng.normal(size=(20000, 6, 3))
    # a tenth nearly rank-deficient, spanning condition numbers around the 1e12 threshold
    k = 2000
    M[:k, :, 2] = M[:k, :, 1] + rng.normal(0, 1, (k, 1)) * 10 ** rng.uniform(-9, -4, (k, 1))
    A = np.einsum("mki,mkj->mij", M, M)
    ev = np.linalg.eigvalsh(A)
    exact = ev[:, 0] > _NLS_SINGULAR_REL * ev[:, -1]
    assert 0 < (~exact).sum() < k  # both sides of the threshold are exercised
    np.testing.assert_array_equal(_well_conditioned(A), exact)


# ---------------------------------------------------------------------------------------------
# issue 13: large coordinates, bad arguments, extremes
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("offset", [1e5, 1e6, 1e7])
def test_every_method_is_exact_at_utm_sized_coordinates(offset):
    """Exact ranges to receivers shifted by UTM-sized offsets: every method recovers the point
    to 1e-7 m (closed_form lost 3e-4 / 0.08 / 3 m here before it centred the geometry; the
    remaining error is rounding of 1e7-sized coordinates, 1e7 * 2.2e-16 = 2e-9 m, amplified
    by the layout's conditioning)."""
    rec = np.array([[0.0, 0, 0], [1.3, 0, 0], [0.65, 1.13, 0.05], [0.2, 0.9, 0.4]])
    P = np.array([[1.0, 2.0, 3.0], [-2.0, 0.5, 4.0]])
    o = np.array([offset, -offset, 0.3 * offset])
    R = np.linalg.norm(P[:, None] - rec[None], axis=2)
    for name, f in T.METHODS.items():
        rr = rec[:3] if name in THREE else rec
        out = f(rr + o, R[:, : rr.shape[0]])
        np.testing.assert_allclose(out, P + o, rtol=0, atol=1e-7, err_msg=name)


@pytest.mark.parametrize("kwargs, field, exc", [
    ({"max_iter": np.inf}, "max_iter", TypeError),
    ({"max_iter": 0}, "max_iter", ValueError),
    ({"max_iter": "15"}, "max_iter", TypeError),
    ({"tol": np.nan}, "tol", ValueError),
    ({"tol": None}, "tol", TypeError),
    ({"x0": np.zeros(2)}, "x0", ValueError),
    ({"x0": "start"}, "x0", TypeError),
    ({"side": True}, "side", ValueError),
])
def test_nonlinear_ls_bad_arguments_are_named(kwargs, field, exc):
    rec = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    with pytest.raises(exc, match=field):
        T.nonlinear_ls(rec, np.ones(4), **kwargs)


@pytest.mark.parametrize("bad, field, exc", [
    ({"receivers": "abc"}, "receivers", TypeError),
    ({"receivers": None}, "receivers", ValueError),
    ({"ranges": ["a", "b", "c"]}, "ranges", TypeError),
    ({"ranges": None}, "ranges", ValueError),
    ({"ranges": [1.0, np.inf, 1.0]}, "ranges", ValueError),
    ({"ranges": [1e300, 1.0, 1.0]}, "ranges", ValueError),
    ({"receivers": np.eye(3) * 1e300}, "receivers", ValueError),
])
def test_strings_none_and_overflowing_numbers_are_named(bad, field, exc):
    base = {"receivers": np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]), "ranges": np.ones(3)}
    for name in (*THREE, "damped_ls"):
        with pytest.raises(exc, match=field):
            T.METHODS[name](**{**base, **bad})


@settings(max_examples=40, deadline=None)
@given(value=st.sampled_from([0.0, 1e-300, 5e-324, 1e8, np.nan]),
       n=st.sampled_from([0, 1, 7, 2000]),
       method=st.sampled_from(list(T.METHODS)))
def test_extreme_ranges_give_flagged_rows_never_garbage(value, n, method):
    """Zero, subnormal, huge (1e8 m) and NaN ranges, empty and large batches: each method
    returns (n, 3) rows that are finite or NaN-and-flagged, with finite diagnostics; memory is
    bounded by the batch (no per-row matrices beyond (n, k, 3))."""
    rec = np.array([[0.0, 0, 0], [1.3, 0, 0], [0.65, 1.13, 0.3], [0.2, 0.9, 1.0]])
    rr = rec[:3] if method in THREE else rec
    R = np.full((n, rr.shape[0]), 2.0)
    R[:, 0] = value
    out, info = T.METHODS[method](rr, R, return_info=True)
    assert out.shape == (n, 3)
    bad = ~np.all(np.isfinite(out), axis=1)
    assert not np.any(bad & ~(info.missing | info.degenerate)), method
    assert np.all(np.isfinite(info.iterations))
    if method == "damped_ls" and n:
        # never farther than the ranges allow
        c = rr.mean(axis=0)
        ok = ~bad
        lim = np.nanmin(R[ok] + np.linalg.norm(rr - c, axis=1), axis=1) + 1.0   # NaN: unused
        assert np.all(np.linalg.norm(out[ok] - c, axis=1) <= lim + 1e-9)


# ---------------------------------------------------------------------------------------------
# damped_ls: the solver for real data
# ---------------------------------------------------------------------------------------------


@settings(max_examples=30, deadline=None)
@given(seed=layouts, k=st.integers(3, 7), known=st.booleans())
def test_damped_ls_recovers_exact_positions(seed, k, known):
    """Exact ranges, any k >= 3 receivers with some ranges missing per row, with and without
    the known height: the true point to 1e-7 relative (Levenberg-Marquardt converges
    quadratically at a zero-residual minimum; the tolerance is its stopping test, 1e-10, with
    the geometry's conditioning on top)."""
    rng = np.random.default_rng(seed)
    rec = rng.uniform(-2, 2, size=(k, 3))
    if not _well_conditioned(rec):
        return
    P = rng.uniform(-6, 6, size=(40, 3))
    R = np.linalg.norm(P[:, None] - rec[None], axis=2)
    if k > 3:
        R[rng.random(R.shape) < 0.15] = np.nan          # up to k - 3 receivers missing
    prior = P            # decides the mirror ties (e.g. three receivers: two exact points)
    out, info = T.damped_ls(rec, R, height_m=P[:, 2] if known else None, prior=prior,
                            return_info=True)
    ok = ~info.missing & ~info.degenerate
    scale = np.max(np.abs(P)) + 4
    np.testing.assert_allclose(out[ok], P[ok], rtol=0, atol=1e-7 * scale)
    assert info.converged[ok].all()
    assert (info.missing == (np.isfinite(R).sum(axis=1) < 3)).all()


def test_damped_ls_agrees_with_scipy_least_squares_on_noisy_data():
    """A second solver (scipy's trust-region reflective least_squares on the same residuals,
    run to 1e-15) reaches the same minimum. Tolerance 1e-5 m: damped_ls stops when the
    gradient is below eps_1 = 1e-10 x 45 m = 4.5e-9 m, which leaves a position error up to
    eps_1 / lambda_min(J'J); far from this 2 m array lambda_min ~ 1 / HDOP^2 ~ 1e-3."""
    from scipy.optimize import least_squares

    rng = np.random.default_rng(2)
    rec = np.array([[2.5775, 0.87, 1.97], [2.5775, -0.87, 1.97], [2.5775, -0.87, 0.5],
                    [0.69, 0.87, 0.5]])
    P = np.c_[rng.uniform(-5, 45, 60), rng.uniform(-5, 5, 60), np.ones(60)]
    R = np.linalg.norm(P[:, None] - rec[None], axis=2) + rng.normal(0, 0.1, (60, 4))
    for known in (True, False):
        out, info = T.damped_ls(rec, R, height_m=1.0 if known else None, prior=P,
                                return_info=True)
        assert info.converged.all()
        for i in range(60):
            def res(x, i=i, known=known):
                p = np.r_[x, 1.0] if known else x
                return np.linalg.norm(p - rec, axis=1) - R[i]
            x0 = out[i, :2] if known else out[i]
            ref = least_squares(res, x0 + 0.3, xtol=1e-15, ftol=1e-15, gtol=1e-15)
            np.testing.assert_allclose(out[i, : x0.size], ref.x, atol=1e-5)


def test_damped_ls_picks_the_mirror_by_prior_then_side():
    # three receivers in the plane z = 0: two exact mirror solutions
    rec = np.array([[0.0, 0, 0], [2, 0, 0], [0, 2, 0]])
    P = np.array([0.5, 0.7, 3.0])
    R = np.linalg.norm(P - rec, axis=1)
    up, info = T.damped_ls(rec, R, return_info=True)
    assert info.ambiguous and up[2] > 0
    np.testing.assert_allclose(info.alternative, P * [1, 1, -1], atol=1e-7)
    down = T.damped_ls(rec, R, side=-1)
    np.testing.assert_allclose(down, P * [1, 1, -1], atol=1e-7)
    near = T.damped_ls(rec, np.stack([R, R]), prior=[[0, 0, -1.0], [np.nan] * 3])
    np.testing.assert_allclose(near, [P * [1, 1, -1], P], atol=1e-7)


def test_damped_ls_known_height_with_receivers_collinear_in_xy():
    """Receivers on one vertical plane (collinear in x-y): the 2-D fix has a mirror across
    that line; the prior (continuity) picks the right one, and three of four anchors with a
    shared x is enough."""
    rec = np.array([[2.5775, 0.87, 1.97], [2.5775, -0.87, 1.97], [2.5775, -0.87, 0.5]])
    P = np.array([30.0, 2.0, 1.0])
    R = np.linalg.norm(P - rec, axis=1)
    p, info = T.damped_ls(rec, R, height_m=1.0, prior=[29.0, 1.5, 1.0], return_info=True)
    np.testing.assert_allclose(p, P, atol=1e-6)
    assert info.ambiguous and info.alternative[0] < 0       # the mirror behind the array


def test_damped_ls_converged_means_converged():
    rng = np.random.default_rng(4)
    rec = np.array([[0.0, 0, 0], [1.3, 0, 0], [0.65, 1.13, 0.02], [0.65, 0.4, 0.5]])
    P = np.c_[rng.uniform(-20, 20, (300, 2)), rng.uniform(0.5, 5, 300)]
    R = np.linalg.norm(P[:, None] - rec[None], axis=2) + rng.normal(0, 0.05, (300, 4))
    out, info = T.damped_ls(rec, R, return_info=True)
    # at a converged row the gradient J'f vanishes (to the stopping test's scale)
    d = out[:, None] - rec[None]
    dist = np.linalg.norm(d, axis=2)
    g = np.einsum("nki,nk->ni", d / dist[:, :, None], dist - R)
    assert info.converged.mean() > 0.99
    assert np.all(np.abs(g[info.converged]) < 1e-6)
    _, short = T.damped_ls(rec, R, max_iter=1, return_info=True)
    assert not short.converged.all()                      # one step does not converge them
