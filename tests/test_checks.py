"""The shared input checks (estimator._checks): one rule for every module."""

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from estimator._checks import check_array, check_fields, check_int, check_real


@pytest.mark.parametrize("bad", ["1.0", None, True, np.bool_(False), [1.0], np.array([1.0])])
def test_check_real_rejects_non_numbers_naming_the_argument(bad):
    with pytest.raises(TypeError, match="sigma_m"):
        check_real(bad, "sigma_m")


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf, np.float64("nan")])
def test_check_real_rejects_nan_and_inf(bad):
    with pytest.raises(ValueError, match="sigma_m: must be a finite number"):
        check_real(bad, "sigma_m")


def test_check_real_bounds_open_and_closed():
    assert check_real(0.0, "x", lo=0.0) == 0.0
    with pytest.raises(ValueError, match="x: must be > 0"):
        check_real(0.0, "x", lo=0.0, lo_open=True)
    with pytest.raises(ValueError, match="x: must be <= 1"):
        check_real(1.5, "x", hi=1.0)
    assert check_real(math.inf, "x", finite=False) == math.inf
    with pytest.raises(ValueError):
        check_real(math.nan, "x", finite=False)


@given(st.floats(allow_nan=True, allow_infinity=True))
def test_check_real_accepts_exactly_the_finite_floats(v):
    if math.isfinite(v):
        assert check_real(v, "v") == v
    else:
        with pytest.raises(ValueError, match="v:"):
            check_real(v, "v")


@pytest.mark.parametrize("bad", [2.0, True, "3", None, math.inf])
def test_check_int_rejects_non_integers(bad):
    with pytest.raises(TypeError, match="n_iter"):
        check_int(bad, "n_iter")


def test_check_int_range():
    assert check_int(np.int64(3), "k", 1, 5) == 3
    with pytest.raises(ValueError, match=r"k: must be an integer in \[1, 5\], got 6"):
        check_int(6, "k", 1, 5)


def test_check_fields_names_prefixed_field():
    class P:
        a = 1.0
        b = True
    with pytest.raises(TypeError, match="params.b"):
        check_fields(P(), ["a", "b"], prefix="params.")
    P.b = 0.0
    with pytest.raises(ValueError, match="params.b: must be > 0"):
        check_fields(P(), ["a", "b"], prefix="params.")
    check_fields(P(), ["a", "b"], prefix="params.", lo_open=False)


def test_check_array_shape_nan_inf_and_magnitude():
    a = check_array([[1, 2], [3, 4]], "obs", shape=(None, 2))
    assert a.dtype == float
    with pytest.raises(ValueError, match=r"obs: expected shape \(n, 3\)"):
        check_array(a, "obs", shape=(None, 3))
    with pytest.raises(ValueError, match=r"obs: values must be finite; obs\[0, 1\]"):
        check_array([[1, np.nan]], "obs")
    assert np.isnan(check_array([[1, np.nan]], "obs", allow_nan=True)[0, 1])
    with pytest.raises(ValueError, match="finite or NaN"):
        check_array([[1, np.inf]], "obs", allow_nan=True)
    with pytest.raises(ValueError, match=r"\|value\| must be <= 1e\+07"):
        check_array([1e300], "obs", max_abs=1e7)
    with pytest.raises(TypeError, match="obs: must be a numeric array"):
        check_array(["a"], "obs")
