"""The two generalised square-root decompositions of the report (§3.3, appendix D).

Both work on symmetric positive semi-definite matrices, batched over leading axes, with
loops over the (small, fixed) matrix size and vector operations over the batch.

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
from scipy.linalg import lapack

#: Default relative pivot threshold, 10× machine precision (report §3.3).
EPS = 10 * np.finfo(float).eps
_TINY = np.finfo(float).tiny
#: Relative pivot below which a row is taken as a combination of the rows kept before it.
REDUNDANT = 1e3 * np.finfo(float).eps


def _scale(S: np.ndarray) -> np.ndarray:
    diag = np.diagonal(S, axis1=-2, axis2=-1)
    return np.maximum(diag.max(axis=-1, initial=0.0), _TINY)


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
    n = S.shape[-1]
    eps = max(eps, REDUNDANT)
    if S.ndim == 2:
        return _closest_single(S, eps)
    d = _equilibrium(S)
    U = S / (d[..., :, None] * d[..., None, :])
    L = np.zeros_like(U)
    for k in range(n):
        piv = U[..., k, k] - np.sum(L[..., k, :k] ** 2, axis=-1)
        fixed = ~(piv > eps)
        L[..., k, k] = np.sqrt(np.where(fixed, eps, piv))
        if k + 1 < n:
            rest = U[..., k + 1 :, k] - np.einsum("...ij,...j->...i", L[..., k + 1 :, :k],
                                                  L[..., k, :k])
            # below a vanishing pivot a PSD matrix has a vanishing column (|rest|² <= piv ·
            # pivots below): what is left is rounding noise, which √ε would amplify
            L[..., k + 1 :, k] = np.where(fixed[..., None], 0.0,
                                          rest / L[..., k, k][..., None])
    return L * d[..., :, None]


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
    n = S.shape[-1]
    if S.ndim == 2:
        return _reduced_single(S, eps)
    tol = eps * _scale(S)
    L = np.zeros_like(S)
    kept = np.zeros(S.shape[:-1], dtype=bool)
    for k in range(n):
        piv = S[..., k, k] - np.sum(L[..., k, :k] ** 2, axis=-1)
        keep = (piv > tol) & (piv > REDUNDANT * S[..., k, k])
        kept[..., k] = keep
        root = np.sqrt(np.where(keep, piv, 1.0))
        L[..., k, :k] *= keep[..., None]  # a dropped equation leaves a zero row
        L[..., k, k] = np.where(keep, root, 0.0)
        if k + 1 < n:
            rest = S[..., k + 1 :, k] - np.einsum("...ij,...j->...i", L[..., k + 1 :, :k],
                                                  L[..., k, :k])
            L[..., k + 1 :, k] = np.where(keep[..., None], rest / root[..., None], 0.0)
    return L, kept


def triangular_solve(L: np.ndarray, b: np.ndarray, transpose: bool = False) -> np.ndarray:
    """Solve ``L x = b`` (or ``Lᵀ x = b``) for a lower-triangular, non-singular ``L``."""
    x, info = lapack.dtrtrs(L, b, lower=1, trans=1 if transpose else 0)
    if info != 0:
        raise np.linalg.LinAlgError(f"singular triangular factor (info {info})")
    return x


def reduced_solve(L: np.ndarray, kept: np.ndarray, B: np.ndarray, transpose: bool = False):
    """Solve ``L y = B`` (or ``Lᵀ y = B``) on the kept indices; dropped entries of ``y`` are 0.

    ``L`` is (..., p, p), ``kept`` (..., p), ``B`` (..., p) or (..., p, t).
    """
    vector = B.ndim == L.ndim - 1
    if L.ndim == 2 and vector:
        if kept.all():
            return triangular_solve(L, B, transpose)
        y = np.zeros(B.shape)
        if kept.any():
            y[kept] = triangular_solve(L[np.ix_(kept, kept)], B[kept], transpose)
        return y
    Y = np.array(B[..., None] if vector else B, dtype=float)
    p = L.shape[-1]
    diag = np.diagonal(L, axis1=-2, axis2=-1)
    inv = np.where(kept, 1.0 / np.where(kept, diag, 1.0), 0.0)[..., None]
    order = range(p - 1, -1, -1) if transpose else range(p)
    for a in order:
        if transpose:
            below = L[..., a + 1 :, a]
            acc = Y[..., a, :] - np.einsum("...i,...it->...t", below, Y[..., a + 1 :, :])
        else:
            acc = Y[..., a, :] - np.einsum("...i,...it->...t", L[..., a, :a], Y[..., :a, :])
        Y[..., a, :] = acc * inv[..., a, :]
    return Y[..., 0] if vector else Y


def _equilibrium(S: np.ndarray) -> np.ndarray:
    """Diagonal scaling that gives ``S`` a unit diagonal; a zero diagonal entry (a component
    nothing informs) takes the matrix scale, so its pivot floor is ε·scale."""
    diag = np.diagonal(S, axis1=-2, axis2=-1)
    scale = diag.max(axis=-1, initial=0.0)[..., None]
    scale = np.where(scale > _TINY, scale, 1.0)  # S = 0: the closest definite matrix is ε I
    return np.sqrt(np.where(diag > _TINY * scale, diag, scale))


def _closest_single(S: np.ndarray, eps: float) -> np.ndarray:
    """One matrix: LAPACK when no pivot needs the fix (the common case), else the row loop.

    (LAPACK's recursive Cholesky leaves no sequential partial factor to repair after a
    failure, so the pivot fixes are made by the reference loop.)"""
    d = _equilibrium(S)
    L, info = lapack.dpotrf(S / np.outer(d, d), lower=1, clean=1)
    if info == 0 and (L.diagonal() ** 2 > eps).all():
        return L * d[:, None]
    return closest_sqrt(S[None], eps)[0]


def _reduced_single(S: np.ndarray, eps: float) -> tuple[np.ndarray, np.ndarray]:
    """One matrix through LAPACK: the first pivot <= tol drops its row and column, and the
    factorisation restarts on the rest (the kept prefix is unchanged by the restart)."""
    n = S.shape[0]
    if n == 0:
        return np.zeros((0, 0)), np.zeros(0, dtype=bool)
    diag = S.diagonal()
    tol = np.maximum(eps * max(float(diag.max()), _TINY), REDUNDANT * diag)
    L, info = lapack.dpotrf(S, lower=1, clean=1)
    if info == 0 and (L.diagonal() ** 2 > tol).all():
        return L, np.ones(n, dtype=bool)  # every equation independent: the plain factor
    kept = np.ones(n, dtype=bool)
    while kept.any():
        idx = np.flatnonzero(kept)
        L, info = lapack.dpotrf(S[np.ix_(idx, idx)], lower=1, clean=1)
        bad = info - 1 if info > 0 else None
        if info == 0:
            small = np.flatnonzero(~(np.diagonal(L) ** 2 > tol[idx]))
            bad = int(small[0]) if small.size else None
        if bad is not None:
            kept[idx[bad]] = False
            continue
        full = np.zeros_like(S)
        full[np.ix_(idx, idx)] = L
        return full, kept
    return np.zeros_like(S), kept
