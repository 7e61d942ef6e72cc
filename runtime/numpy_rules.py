"""NumPy's linear algebra, sums and array operations as kernels that round as NumPy does.

A kernel that must give the results of NumPy code bit for bit — the two-view closed forms
(:mod:`~kanagen.runtime.two_view_kernels`), whose outcome on a degenerate sample follows
LAPACK's arbitrary basis of a null space — is written with these:

* LAPACK as NumPy calls it: numba's ``np.linalg`` runs the same routines (SciPy's build of
  LAPACK, NumPy has its own: the same results here, tests/test_two_view_kernels.py), its
  factors laid out by rows as NumPy returns them (:func:`svd`); :func:`singular_values` and
  :func:`eigenvalues` for the two calls numba's lacks; ``np.linalg.inv`` solved as NumPy
  solves it (:func:`inverse`);
* products through BLAS where NumPy's went through it (``@``, ``np.dot``, :func:`norm`), the
  operands in the same layouts (a transposed operand stays a transposed view: a copy can
  change BLAS's order of sums);
* sums in NumPy's order (:func:`vector_sum`), ``max`` as Python reads a NaN (:func:`floor0`);
* loops instead of array expressions and slice assignments (:func:`divided`, :func:`put`,
  ...): each of those compiles a loop nest with its shape checks and error message into the
  kernel (the two-view kernels' first compile: 42 s → 38 s).

A matrix that is not finite makes the LAPACK calls raise ``LinAlgError`` (NumPy's SVD of an
infinite matrix may not return).
"""

from __future__ import annotations

import numpy as np

from kanagen.common.jit import NUMBA, jit
from kanagen.common.link import linked

# -- LAPACK calls numba's np.linalg does not offer -----------------------------------------

def singular_values(A: np.ndarray) -> np.ndarray:
    """The singular values of ``A``, decreasing: ``np.linalg.svd(A, compute_uv=False)``
    (LAPACK's gesdd without vectors, whose values may differ in the last bit from those
    computed with them)."""
    return np.linalg.svd(A, compute_uv=False)


def eigenvalues(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The real and imaginary parts of the eigenvalues of the real square ``A``, in
    LAPACK's order: ``np.linalg.eigvals(A)`` (geev without vectors; numba's own refuses a
    real matrix with complex eigenvalues)."""
    w = np.linalg.eigvals(A)
    return np.ascontiguousarray(w.real), np.ascontiguousarray(w.imag)


def gesv(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``np.linalg.solve(A, B)`` for a square ``A`` and a matrix ``B`` (LAPACK's gesv, as
    NumPy and numba call it; compiled, a direct call: numba's own ``solve`` is a few seconds
    of compile for its checks of every shape and layout)."""
    return np.linalg.solve(A, B)


if NUMBA is not None:
    from numba import types
    from numba.extending import overload
    from numba.np.linalg import F_INT_nbtype, F_INT_nptype

    _KIND, _NONE = ord("d"), ord("N")  # double precision; no vectors
    _P = types.CPointer(types.float64)
    # numba's LAPACK helpers (numba/_lapack.c, as numba.np.linalg declares them): a
    # workspace query, then the routine; the LAPACK is SciPy's, as for np.linalg in numba
    _GESDD = types.ExternalFunction("numba_ez_gesdd", types.intc(
        types.char, types.char, types.intp, types.intp, _P, types.intp, _P, _P, types.intp,
        _P, types.intp))
    _GEEV = types.ExternalFunction("numba_ez_rgeev", types.intc(
        types.char, types.char, types.char, types.intp, _P, types.intp, _P, _P, _P,
        types.intp, _P, types.intp))

    @overload(singular_values, jit_options={"cache": True})
    def _singular_values(A):
        def impl(A):
            m, n = A.shape
            if not finite(A):
                raise np.linalg.LinAlgError("SVD did not converge")
            a = column_major(A)
            s, unused = np.empty(min(m, n)), np.empty(1)
            info = _GESDD(_KIND, _NONE, m, n, a.ctypes, m, s.ctypes, unused.ctypes, 1,
                          unused.ctypes, 1)
            if info != 0 or a.size == 0 or unused.size == 0:  # the sizes keep them alive
                raise np.linalg.LinAlgError("SVD did not converge")
            return s
        return impl

    _GESV = types.ExternalFunction("numba_xgesv", types.intc(
        types.char, types.intp, types.intp, _P, types.intp, types.CPointer(F_INT_nbtype), _P,
        types.intp))

    @overload(gesv, jit_options={"cache": True})
    def _gesv(A, B):
        def impl(A, B):
            n, nrhs = A.shape[0], B.shape[1]
            if not (finite(A) and finite(B)):
                raise np.linalg.LinAlgError("Array must not contain infs or NaNs")
            a, b = column_major(A), column_major(B)
            pivots = np.empty(n, dtype=F_INT_nptype)
            info = _GESV(_KIND, n, nrhs, a.ctypes, n, pivots.ctypes, b.ctypes, n)
            if info != 0 or a.size == 0 or pivots.size == 0:  # the sizes keep them alive
                raise np.linalg.LinAlgError("Matrix is singular to machine precision.")
            out = np.empty((n, nrhs))
            for i in range(n):
                for j in range(nrhs):
                    out[i, j] = b[j, i]
            return out
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


# -- NumPy's rules ---------------------------------------------------------------------------

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


@jit
def vector_sum(a) -> float:
    """``np.sum`` of the 1-D ``a``, rounded as NumPy rounds it: pairwise summation, eight
    partial sums over blocks of at most 128 (a row of a few entries: in sequence)."""
    n = a.shape[0]
    if n < 8:
        total = -0.0
        for i in range(n):
            total += a[i]
        return total
    if n <= 128:
        r0, r1, r2, r3, r4, r5, r6, r7 = a[0], a[1], a[2], a[3], a[4], a[5], a[6], a[7]
        i = 8
        while i < n - n % 8:
            r0, r1, r2, r3 = r0 + a[i], r1 + a[i + 1], r2 + a[i + 2], r3 + a[i + 3]
            r4, r5, r6, r7 = r4 + a[i + 4], r5 + a[i + 5], r6 + a[i + 6], r7 + a[i + 7]
            i += 8
        total = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
        while i < n:
            total += a[i]
            i += 1
        return total
    half = n // 2
    half -= half % 8
    return vector_sum(a[:half]) + vector_sum(a[half:])


@jit
def floor0(x: float) -> float:
    """``max(x, 0.0)`` as Python's ``max`` reads it (a NaN stays)."""
    return 0.0 if 0.0 > x else x


@linked("f2 -> f2 f1 f2")
def svd(A):
    """``np.linalg.svd(A)`` (full matrices), its factors laid out by rows as NumPy's; a
    matrix that is not finite raises, as NumPy's does with a NaN (with an infinity LAPACK
    may not return)."""
    if not finite(A):
        raise np.linalg.LinAlgError("SVD did not converge")
    U, S, Vt = np.linalg.svd(A)
    return np.ascontiguousarray(U), S, np.ascontiguousarray(Vt)


@linked("f2 -> f1 f2")
def null_space_svd(A):
    """``np.linalg.svd(A)[1:]``, the singular values and ``Vᵀ`` (by rows), of a system whose
    null vectors are wanted: without the left vectors of a tall ``A`` (LAPACK's gesdd
    computes the same ``Vᵀ`` either way; the full ``U`` of 100 rows doubles its time)."""
    if not finite(A):
        raise np.linalg.LinAlgError("SVD did not converge")
    if A.shape[0] >= A.shape[1]:
        _, S, Vt = np.linalg.svd(A, full_matrices=False)
    else:
        _, S, Vt = np.linalg.svd(A)
    return S, np.ascontiguousarray(Vt)


@linked("f2 f2 -> f2")
def solved(A, B):
    """``np.linalg.solve(A, B)`` laid out by rows (:func:`gesv`), compiled once for its
    callers."""
    return np.ascontiguousarray(gesv(A, B))


@jit
def inverse(A):
    """``np.linalg.inv``: NumPy solves ``A X = I`` (gesv), numba would factor and invert."""
    return solved(A, np.eye(A.shape[0]))


@jit
def cross(a, b):
    """``a × b`` of two 3-vectors."""
    out = np.empty(3)
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]
    return out


@jit
def norm(v) -> float:
    """``np.linalg.norm`` of a contiguous vector or matrix: ``√(v · v)`` by BLAS, as NumPy."""
    flat = v.reshape(v.size)
    return np.sqrt(np.dot(flat, flat))


@jit
def divided(a, s: float):
    """``a / s`` entry by entry (``a`` C-ordered, any shape; a new array)."""
    out = np.empty_like(a)
    flat, into = a.reshape(a.size), out.reshape(out.size)
    for i in range(flat.size):
        into[i] = flat[i] / s
    return out


@jit
def negated(a):
    """``-a`` (``a`` C-ordered, any shape; a new array)."""
    out = np.empty_like(a)
    flat, into = a.reshape(a.size), out.reshape(out.size)
    for i in range(flat.size):
        into[i] = -flat[i]
    return out


@jit
def unit(M):
    """``M / ‖M‖`` (Frobenius), or ``M`` when its norm is 0."""
    size = norm(M)
    return divided(M, size) if size > 0 else M


@jit
def put(row, at: int, values) -> None:
    """``row[at:at + n] = values`` (``n`` values)."""
    for i in range(values.shape[0]):
        row[at + i] = values[i]


@jit
def put_matrix(stack, k: int, M) -> None:
    """``stack[k] = M`` for a 3 × 3 ``M`` (as :func:`put`)."""
    for i in range(3):
        for j in range(3):
            stack[k, i, j] = M[i, j]


@jit
def fill(M, value: float) -> None:
    """``M[:] = value`` for a matrix (as :func:`put`)."""
    for i in range(M.shape[0]):
        for j in range(M.shape[1]):
            M[i, j] = value


@jit
def argmax_abs(t) -> int:
    """``np.argmax(np.abs(t))``: the first entry of largest magnitude, or the first NaN."""
    best = 0
    for i in range(t.shape[0]):
        if np.isnan(t[i]):
            return i
        if abs(t[i]) > abs(t[best]):
            best = i
    return best


@jit
def columns(a, b, c):
    """The 3 × 3 matrix of columns ``a, b, c`` (``np.column_stack``)."""
    M = np.empty((3, 3))
    for i in range(3):
        M[i, 0], M[i, 1], M[i, 2] = a[i], b[i], c[i]
    return M
