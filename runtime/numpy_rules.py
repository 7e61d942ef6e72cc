"""NumPy's linear algebra, sums and array operations as kernels that round as NumPy does.

A kernel that must give the results of NumPy code bit for bit — the two-view closed forms
(:mod:`~kanagen.runtime.two_view_kernels`), whose outcome on a degenerate sample follows
LAPACK's arbitrary basis of a null space — is written with these:

* LAPACK as NumPy calls it: numba's ``np.linalg`` runs the same routines (SciPy's build of
  LAPACK, NumPy has its own: the same results here, tests/test_two_view_kernels.py), its
  factors laid out by rows as NumPy returns them (:func:`svd`); :mod:`.lapack`'s direct
  calls for the two numba's lacks (``singular_values``, ``eigenvalues``) and for ``solve``
  (``gesv``, whose numba wrapper is seconds of compile); ``np.linalg.inv`` solved as NumPy
  solves it (:func:`inverse`); the shared parts linked kernels, compiled once;
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

from kanagen.common.jit import jit
from kanagen.common.link import linked

from .lapack import (  # noqa: F401 - eigenvalues, singular_values: for the two-view kernels
    eigenvalues,
    finite,
    gesv,
    singular_values,
)

# -- NumPy's rules ---------------------------------------------------------------------------

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
