"""LAPACK called directly from the kernels (runtime/lapack.py): NumPy's numbers, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from kanagen.common.jit import jit
from kanagen.runtime.lapack import gesv, least_squares


@jit
def _solve(A, B):
    return gesv(A, B)


@jit
def _lstsq(A, b, rcond):
    return least_squares(A, b, rcond)


_finite = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False)


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 6), st.integers(1, 3), st.data())
def test_solve_is_numpys(n, k, data):
    A = data.draw(arrays(np.float64, (n, n), elements=_finite))
    B = data.draw(arrays(np.float64, (n, k), elements=_finite))
    try:
        expected = np.linalg.solve(A, B)
    except np.linalg.LinAlgError:
        with pytest.raises(np.linalg.LinAlgError):
            _solve(A, B)
        return
    np.testing.assert_array_equal(_solve(A, B), expected)


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 7), st.integers(1, 7), st.data())
def test_least_squares_is_numpys(m, n, data):
    A = data.draw(arrays(np.float64, (m, n), elements=_finite))
    b = data.draw(arrays(np.float64, (m,), elements=_finite))
    rcond = np.finfo(float).eps * max(m, n)
    np.testing.assert_array_equal(_lstsq(A, b, rcond), np.linalg.lstsq(A, b, rcond=rcond)[0])


def test_bad_input_raises_as_numpy():
    with pytest.raises(np.linalg.LinAlgError, match="infs or NaNs"):
        _solve(np.array([[np.nan]]), np.ones((1, 1)))
    with pytest.raises(np.linalg.LinAlgError, match="singular"):
        _solve(np.zeros((2, 2)), np.ones((2, 1)))
    with pytest.raises(np.linalg.LinAlgError, match="infs or NaNs"):
        _lstsq(np.array([[np.inf, 1.0]]), np.ones(1), 1e-15)
