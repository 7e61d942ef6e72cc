"""LAPACK called directly from the kernels (runtime/lapack.py): NumPy's numbers."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from kanagen.common.jit import jit
from kanagen.runtime.lapack import eigenvalues, least_squares


@jit
def _eigenvalues(A):
    return eigenvalues(A)


@jit
def _lstsq(A, b, rcond):
    return least_squares(A, b, rcond)


_finite = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False)


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 6), st.data())
def test_eigenvalues_are_numpys(n, data):
    """NumPy's eigenvalues in NumPy's order, to rounding (numba's LAPACK is SciPy's build,
    NumPy has its own: their balancing of entries near the underflow differs)."""
    A = data.draw(arrays(np.float64, (n, n), elements=_finite))
    A[np.abs(A) < 1e-100] = 0.0
    w = np.linalg.eigvals(A)
    re, im = _eigenvalues(A)
    scale = 1e-12 * max(np.abs(A).max(), 1e-300)
    np.testing.assert_allclose(re, w.real, rtol=1e-12, atol=scale)
    np.testing.assert_allclose(im, w.imag, rtol=1e-12, atol=scale)


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 7), st.integers(1, 7), st.data())
def test_least_squares_is_numpys(m, n, data):
    A = data.draw(arrays(np.float64, (m, n), elements=_finite))
    b = data.draw(arrays(np.float64, (m,), elements=_finite))
    rcond = np.finfo(float).eps * max(m, n)
    np.testing.assert_array_equal(_lstsq(A, b, rcond), np.linalg.lstsq(A, b, rcond=rcond)[0])


def test_bad_input_raises_as_numpy():
    with pytest.raises(np.linalg.LinAlgError, match="infs or NaNs"):
        _eigenvalues(np.array([[np.nan]]))
    with pytest.raises(np.linalg.LinAlgError, match="infs or NaNs"):
        _lstsq(np.array([[np.inf, 1.0]]), np.ones(1), 1e-15)
