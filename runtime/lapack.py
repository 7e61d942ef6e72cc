"""LAPACK called directly from the kernels, as NumPy calls it: the routines of numba's
``np.linalg`` (SciPy's LAPACK, through numba's helpers ``numba_ez_gelsd`` ...) on copies laid
out by columns, without numba's ``np.linalg`` wrappers — seconds of compile each for their
checks of every shape and layout (``lstsq`` 2.3 s on this machine) — and a call numba lacks
(the eigenvalues of a real matrix that has complex ones).

Each function is NumPy's own when run interpreted; compiled, the same LAPACK routine on the
same numbers (the same results: tests/test_lapack.py; NumPy's own LAPACK build may differ
in the last bits). A matrix that is not finite raises ``LinAlgError``.
"""

from __future__ import annotations

import numpy as np

from kanagen.common.jit import NUMBA, jit


def eigenvalues(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The real and imaginary parts of the eigenvalues of the real square ``A``, in
    LAPACK's order: ``np.linalg.eigvals(A)`` (geev without vectors; numba's own refuses a
    real matrix with complex eigenvalues)."""
    w = np.linalg.eigvals(A)
    return np.ascontiguousarray(w.real), np.ascontiguousarray(w.imag)


def least_squares(A: np.ndarray, b: np.ndarray, rcond: float) -> np.ndarray:
    """``np.linalg.lstsq(A, b, rcond)[0]`` for a vector ``b`` (LAPACK's gelsd, as NumPy and
    numba call it; compiled, a direct call: numba's own ``lstsq`` is seconds of compile for
    its checks of every shape and layout)."""
    return np.linalg.lstsq(A, b, rcond=rcond)[0]


if NUMBA is not None:
    from numba import types
    from numba.extending import overload
    from numba.np.linalg import F_INT_nbtype, F_INT_nptype

    _KIND, _NONE = ord("d"), ord("N")  # double precision; no vectors
    _P = types.CPointer(types.float64)
    # numba's LAPACK helpers (numba/_lapack.c, as numba.np.linalg declares them): a
    # workspace query, then the routine; the LAPACK is SciPy's, as for np.linalg in numba
    _GEEV = types.ExternalFunction("numba_ez_rgeev", types.intc(
        types.char, types.char, types.char, types.intp, _P, types.intp, _P, _P, _P,
        types.intp, _P, types.intp))

    _GELSD = types.ExternalFunction("numba_ez_gelsd", types.intc(
        types.char, types.intp, types.intp, types.intp, _P, types.intp, _P, types.intp, _P,
        types.float64, types.CPointer(F_INT_nbtype)))

    @overload(least_squares, jit_options={"cache": True})
    def _least_squares(A, b, rcond):
        def impl(A, b, rcond):
            m, n = A.shape
            if not (finite(A) and finite(b)):
                raise np.linalg.LinAlgError("Array must not contain infs or NaNs.")
            if m == 0 or n == 0 or b.shape[0] == 0:
                raise np.linalg.LinAlgError("Arrays cannot be empty")
            if b.shape[0] != m:
                raise np.linalg.LinAlgError("Incompatible array sizes, system is not "
                                            "dimensionally valid.")
            a = column_major(A)
            rhs = np.zeros(max(m, n))  # gelsd's solution: its first n entries
            for i in range(m):
                rhs[i] = b[i]
            s, rank = np.empty(min(m, n)), np.empty(1, dtype=F_INT_nptype)
            info = _GELSD(_KIND, m, n, 1, a.ctypes, m, rhs.ctypes, rhs.size, s.ctypes,
                          rcond, rank.ctypes)
            if info != 0 or a.size == 0 or s.size == 0 or rank.size == 0:  # kept alive
                raise ValueError("Internal algorithm failed to converge.")
            return rhs[:n].copy()
        return impl

    @overload(eigenvalues, jit_options={"cache": True})
    def _eigenvalues(A):
        def impl(A):
            n = A.shape[0]
            if not finite(A):
                raise np.linalg.LinAlgError("Array must not contain infs or NaNs")
            a = column_major(A)
            wr, wi, unused = np.empty(n), np.empty(n), np.empty(1)
            info = _GEEV(_KIND, _NONE, _NONE, n, a.ctypes, n, wr.ctypes, wi.ctypes,
                         unused.ctypes, 1, unused.ctypes, 1)
            if info != 0 or a.size == 0 or unused.size == 0:
                raise np.linalg.LinAlgError("Eigenvalues did not converge")
            return wr, wi
        return impl



@jit
def column_major(A):
    """A copy of the matrix ``A`` laid out by columns (LAPACK's order; LAPACK overwrites
    it): ``A[i, j]`` at ``j * rows + i``."""
    m, n = A.shape
    a = np.empty((n, m))
    for i in range(m):
        for j in range(n):
            a[j, i] = A[i, j]
    return a


@jit
def finite(A) -> bool:
    """Every entry of ``A`` is finite."""
    for v in A.flat:
        if not np.isfinite(v):
            return False
    return True


