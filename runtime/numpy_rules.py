"""The two-view closed forms' small-matrix operations as kernels (for
:mod:`~kanagen.runtime.two_view_kernels`), over :mod:`~kanagen.runtime.linalg`.

* The factorisations of :mod:`.linalg` — Jacobi rotations for the SVD and the symmetric
  eigenproblem, a pivoted QR for a minimal system's null space, Gaussian elimination for a
  solve — linked here (compiled once for their callers), a 3 × 3 determinant by cofactors:
  LAPACK's fixed costs were most of a seven-point sample's time (a 3 × 3 SVD ~2 µs, 0.75 by
  rotations), BLAS's of its products (a 3 × 3 product ~150 ns, ~20 by loops: :func:`matmul`).
  They give NumPy's results to rounding, the singular vectors up to their signs and the
  basis of a repeated or null singular value (tests/test_two_view_kernels.py holds the
  closed forms to the NumPy ones, tests/reference_two_view.py). The eigenvalues of a
  companion matrix stay LAPACK's (:mod:`.lapack`).
* Sums in NumPy's order (:func:`vector_sum`), ``max`` as Python reads a NaN (:func:`floor0`).
* Loops instead of array expressions and slice assignments (:func:`divided`, :func:`put`,
  ...): each of those compiles a loop nest with its shape checks and error message into the
  kernel (the two-view kernels' first compile: 42 s → 38 s).

A matrix that is not finite makes the factorisations raise ``LinAlgError``.
"""

from __future__ import annotations

import numpy as np

from kanagen.common.jit import jit
from kanagen.common.link import linked

from .lapack import (  # noqa: F401 - eigenvalues: for the two-view kernels
    eigenvalues,
    finite,
)
from .linalg import dot, null_basis, right_singular, small_svd, solve_small

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
    """The full SVD of a small matrix, ``U, S, Vᵀ`` as ``np.linalg.svd(A)`` orders them
    (:func:`~.linalg.small_svd`, compiled once for its callers)."""
    return small_svd(A)


@linked("f2 -> f1 f2")
def null_space_svd(A):
    """The singular values and the full ``Vᵀ`` of a system whose null vectors are wanted,
    ``np.linalg.svd(A)[1:]`` (:func:`~.linalg.right_singular`: no left vectors)."""
    return right_singular(A)


@linked("f2 f -> f2 b")
def null_vectors(A, cut):
    """The null space of a wide system that has exactly as many null vectors as columns
    beyond its rows (a minimal sample's), as orthonormal columns, and whether it has (every
    pivot above ``cut`` times the largest): :func:`~.linalg.null_basis`, a pivoted QR."""
    return null_basis(A, cut)


@linked("f2 f2 -> f2")
def solved(A, B):
    """``A⁻¹ B`` for a small square ``A`` (:func:`~.linalg.solve_small`: Gaussian
    elimination with partial pivoting). Raises ``LinAlgError`` on a non-finite or a
    singular ``A``."""
    if not (finite(A) and finite(B)):
        raise np.linalg.LinAlgError("Array must not contain infs or NaNs")
    M, X = A.copy(), B.copy()
    if not solve_small(M, X, A.shape[0], B.shape[1]):
        raise np.linalg.LinAlgError("Singular matrix")
    return X


@jit
def inverse(A):
    """``np.linalg.inv`` of a small ``A`` (:func:`solved` on the identity)."""
    return solved(A, np.eye(A.shape[0]))


@jit
def det3(M) -> float:
    """``np.linalg.det`` of a 3 × 3 ``M``, by cofactors of its first row."""
    return (M[0, 0] * (M[1, 1] * M[2, 2] - M[1, 2] * M[2, 1])
            - M[0, 1] * (M[1, 0] * M[2, 2] - M[1, 2] * M[2, 0])
            + M[0, 2] * (M[1, 0] * M[2, 1] - M[1, 1] * M[2, 0]))


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
    """``np.linalg.norm`` of a contiguous vector or matrix (Frobenius)."""
    flat = v.reshape(v.size)
    return np.sqrt(dot(flat, flat))


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
