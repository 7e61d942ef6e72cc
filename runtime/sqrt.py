"""The two generalised square-root decompositions of the report (§3.3, appendix D).

Both work on symmetric positive semi-definite matrices, one at a time or batched over
leading axes; the factorisations and solves are kernels (``@jit``, :mod:`kanagen.common.jit`)
on one matrix, looped over a batch.

* :func:`closest_sqrt` — Cholesky where a pivot that is not > ε·scale is replaced by ε·scale
  (and the column below it, rounding noise for a PSD input, by zeros): the factor of a
  definite matrix next to the input.
* :func:`reduced_sqrt` — Cholesky where a row/column whose pivot is too small is dropped and
  the factorisation goes on with the rest: it keeps the first independent equations.

ε defaults to 10× machine epsilon and is relative to the matrix scale (its largest diagonal).
The reduced root drops row ``k`` when its pivot is <= ε·scale (a vanishing row, as in the
report) **or** <= :data:`REDUNDANT`·S_kk: the pivot over the row's own diagonal is sin² of
the angle between the row and the span of the rows kept before it, and the rounding of a Gram
matrix leaves a few ε·n there for a dependent row — 10 ε alone would keep some of them.
Relative to its own scale, the test also leaves the report's invariance to rescaling one
equation intact.
"""

from __future__ import annotations

import numpy as np

from kanagen.common.jit import jit

#: Default relative pivot threshold, 10× machine precision (report §3.3).
EPS = 10 * np.finfo(float).eps
_TINY = np.finfo(float).tiny
#: Relative pivot below which a row is taken as a combination of the rows kept before it.
REDUNDANT = 1e3 * np.finfo(float).eps


def closest_sqrt(S: np.ndarray, eps: float = EPS) -> np.ndarray:
    """Lower-triangular ``L`` with ``L Lᵀ = S + Σ v_k e_k e_kᵀ`` for the smallest pivot fixes.

    A pivot is compared with ε times its row's own diagonal entry (the factorisation runs on
    the equilibrated matrix), so parameters of very different scales are treated alike; a
    row with a zero diagonal gets ε times the matrix scale. ε is never taken below
    :data:`REDUNDANT`: on a semi-definite matrix a Schur complement that should vanish is
    left with rounding noise of a few ε·n, and keeping such a pivot would amplify the noise.

    Parameters
    ----------
    S : (..., n, n) array
        Symmetric positive semi-definite matrices.
    eps : float
        Relative pivot floor.

    Examples
    --------
    >>> L = closest_sqrt(np.array([[4.0, 2.0], [2.0, 1.0]]))   # singular input
    >>> bool(np.all(np.diag(L) > 0))
    True
    """
    S = np.asarray(S, dtype=float)
    eps = max(eps, REDUNDANT)
    if S.ndim == 2:
        return closest_root(S, eps)
    n = S.shape[-1]
    flat = np.ascontiguousarray(S).reshape(-1, n, n)
    return _closest_batch(flat, eps).reshape(S.shape)


def reduced_sqrt(S: np.ndarray, eps: float = EPS) -> tuple[np.ndarray, np.ndarray]:
    """Cholesky factor of the sub-matrix of ``S`` on its first independent rows.

    Returns ``(L, kept)``: ``L`` lower triangular with zero rows and columns for the dropped
    indices, and the boolean mask ``kept``. Use :func:`reduced_solve` to apply ``L⁻¹``.

    Examples
    --------
    >>> C = np.array([[1.0, 0.0], [2.0, 0.0], [0.0, 1.0]])   # row 2 = 2 × row 1
    >>> L, kept = reduced_sqrt(C @ C.T)
    >>> kept.tolist()
    [True, False, True]
    """
    S = np.asarray(S, dtype=float)
    if S.ndim == 2:
        return reduced_root(S, eps)
    n = S.shape[-1]
    L, kept = _reduced_batch(np.ascontiguousarray(S).reshape(-1, n, n), eps)
    return L.reshape(S.shape), kept.reshape(S.shape[:-1])


def triangular_solve(L: np.ndarray, b: np.ndarray, transpose: bool = False) -> np.ndarray:
    """Solve ``L x = b`` (or ``Lᵀ x = b``) for a lower-triangular, non-singular ``L``; ``b``
    a vector or a matrix of right-hand sides. A zero on the diagonal raises
    ``numpy.linalg.LinAlgError``."""
    L = np.asarray(L, dtype=float)
    b = np.asarray(b, dtype=float)
    x = solve_lower(L, b, transpose) if b.ndim == 1 else \
        solve_lower_columns(L, np.ascontiguousarray(b), transpose)
    if not x.size and b.size:
        raise np.linalg.LinAlgError("singular triangular factor")
    return x


def reduced_solve(L: np.ndarray, kept: np.ndarray, B: np.ndarray, transpose: bool = False):
    """Solve ``L y = B`` (or ``Lᵀ y = B``) on the kept indices; dropped entries of ``y`` are 0.

    ``L`` is (..., p, p), ``kept`` (..., p), ``B`` (..., p) or (..., p, t).
    """
    L = np.asarray(L, dtype=float)
    B = np.asarray(B, dtype=float)
    vector = B.ndim == L.ndim - 1
    if L.ndim == 2 and vector:
        return solve_kept(L, kept, B, transpose)
    p = L.shape[-1]
    Y = np.array(B[..., None] if vector else B, dtype=float)
    t = Y.shape[-1]
    flat = _solve_kept_batch(np.ascontiguousarray(L).reshape(-1, p, p),
                             np.ascontiguousarray(kept).reshape(-1, p),
                             Y.reshape(-1, p, t), transpose)
    Y = flat.reshape(Y.shape)
    return Y[..., 0] if vector else Y


# -- kernels: one matrix ------------------------------------------------------------------

@jit
def put_column(M, j, v):
    """``M[:, j] = v``, without the broadcasting check whose error message (built at run
    time) is most of a small kernel's code."""
    for a in range(v.size):
        M[a, j] = v[a]


@jit
def diagonal_max(S):
    """``max(diag(S), initial=0)`` as NumPy computes it (NaN propagates)."""
    top = 0.0
    for a in range(S.shape[0]):
        v = S[a, a]
        if v != v:
            return np.nan
        top = max(top, v)
    return top


@jit
def equilibrium(S):
    """Diagonal scaling that gives ``S`` a unit diagonal; a zero diagonal entry (a component
    nothing informs) takes the matrix scale, so its pivot floor is ε·scale."""
    n = S.shape[0]
    scale = diagonal_max(S)
    if not scale > _TINY:  # S = 0: the closest definite matrix is ε I
        scale = 1.0
    d = np.empty(n)
    for i in range(n):
        v = S[i, i]
        d[i] = np.sqrt(v if v > _TINY * scale else scale)
    return d


@jit
def closest_root(S, eps):
    """:func:`closest_sqrt` of one matrix (``eps`` already floored at :data:`REDUNDANT`):
    Cholesky on the equilibrated matrix, a pivot that is not > ε replaced by ε and the
    column below it (rounding noise for a PSD input, which √ε would amplify) by zeros."""
    n = S.shape[0]
    d = equilibrium(S)
    L = np.zeros((n, n))
    for k in range(n):
        piv = S[k, k] / (d[k] * d[k])
        for j in range(k):
            piv -= L[k, j] * L[k, j]
        fixed = not piv > eps
        root = np.sqrt(eps if fixed else piv)
        L[k, k] = root
        if fixed:
            continue
        for i in range(k + 1, n):
            acc = S[i, k] / (d[i] * d[k])
            for j in range(k):
                acc -= L[i, j] * L[k, j]
            L[i, k] = acc / root
    for i in range(n):
        for j in range(i + 1):
            L[i, j] *= d[i]
    return L


@jit
def reduced_root(S, eps):
    """:func:`reduced_sqrt` of one matrix: a pivot <= ε·scale or <= :data:`REDUNDANT` times
    its own diagonal drops its row and column, and the factorisation goes on."""
    n = S.shape[0]
    scale = diagonal_max(S)
    tol = eps * max(scale, _TINY) if scale == scale else np.nan
    L = np.zeros((n, n))
    kept = np.zeros(n, dtype=np.bool_)
    for k in range(n):
        piv = S[k, k]
        for j in range(k):
            piv -= L[k, j] * L[k, j]
        keep = piv > tol and piv > REDUNDANT * S[k, k]
        kept[k] = keep
        if not keep:
            for j in range(k):
                L[k, j] = 0.0
            continue
        root = np.sqrt(piv)
        L[k, k] = root
        for i in range(k + 1, n):
            acc = S[i, k]
            for j in range(k):
                acc -= L[i, j] * L[k, j]
            L[i, k] = acc / root
    return L, kept


@jit
def solve_lower(L, b, transpose):
    """``L⁻¹ b`` (``L⁻ᵀ b``) for one vector; an empty array when ``L`` has a zero pivot."""
    X = solve_lower_columns(L, np.ascontiguousarray(b).reshape(b.shape[0], 1), transpose)
    return X.reshape(X.size)


@jit
def solve_lower_columns(L, B, transpose):
    """:func:`solve_lower` for each column of ``B``; an empty array on a zero pivot."""
    n = B.shape[0]
    for i in range(n):
        if L[i, i] == 0.0:
            return np.empty((0, 0))
    X = np.zeros(B.shape)
    for c in range(B.shape[1]):
        _lower_into(L, B, c, transpose, X, c)
    return X


@jit(inline=True)
def _lower_into(L, B, c, transpose, X, k):
    """Column ``c`` of ``B`` solved with ``L`` (``Lᵀ``) into column ``k`` of ``X`` (zeros on
    entry): :func:`solve_kept`'s operations, every index kept, without its copies."""
    n = B.shape[0]
    if transpose:
        for i in range(n - 1, -1, -1):
            acc = B[i, c]
            for j in range(i + 1, n):
                acc -= L[j, i] * X[j, k]
            X[i, k] = acc / L[i, i]
    else:
        for i in range(n):
            acc = B[i, c]
            for j in range(i):
                acc -= L[i, j] * X[j, k]
            X[i, k] = acc / L[i, i]


@jit
def solve_kept(L, kept, b, transpose):
    """``L y = b`` (``Lᵀ y = b``) on the kept indices of a reduced root; dropped entries 0."""
    n = b.shape[0]
    y = np.zeros(n)
    if transpose:
        for i in range(n - 1, -1, -1):
            if kept[i]:
                acc = b[i]
                for j in range(i + 1, n):
                    acc -= L[j, i] * y[j]
                y[i] = acc / L[i, i]
    else:
        for i in range(n):
            if kept[i]:
                acc = b[i]
                for j in range(i):
                    acc -= L[i, j] * y[j]
                y[i] = acc / L[i, i]
    return y


# -- kernels: batches ---------------------------------------------------------------------

@jit
def _closest_batch(S, eps):
    L = np.empty(S.shape)
    for b in range(S.shape[0]):
        L[b] = closest_root(S[b], eps)
    return L


@jit
def _reduced_batch(S, eps):
    L = np.empty(S.shape)
    kept = np.empty(S.shape[:2], dtype=np.bool_)
    for b in range(S.shape[0]):
        L[b], kept[b] = reduced_root(S[b], eps)
    return L, kept


@jit
def _solve_kept_batch(L, kept, Y, transpose):
    out = np.empty(Y.shape)
    for b in range(Y.shape[0]):
        for c in range(Y.shape[2]):
            put_column(out[b], c, solve_kept(L[b], kept[b], np.ascontiguousarray(Y[b, :, c]),
                                             transpose))
    return out
