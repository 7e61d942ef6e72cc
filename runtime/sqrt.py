"""The two generalised square-root decompositions of the report (§3.3, appendix D).

Both work on symmetric positive semi-definite matrices, batched over leading axes, with
loops over the (small, fixed) matrix size and vector operations over the batch.

* :func:`closest_sqrt` — Cholesky where a pivot that is not > ε·scale is replaced by ε·scale:
  the factor of a definite matrix next to the input.
* :func:`reduced_sqrt` — Cholesky where a row/column whose pivot is <= ε·scale is dropped and
  the factorisation goes on with the rest: it keeps the first independent equations.

ε defaults to 10× machine epsilon and is relative to the matrix scale (its largest diagonal).
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import lapack

#: Default relative pivot threshold, 10× machine precision (report §3.3).
EPS = 10 * np.finfo(float).eps
_TINY = np.finfo(float).tiny


def _scale(S: np.ndarray) -> np.ndarray:
    diag = np.diagonal(S, axis1=-2, axis2=-1)
    return np.maximum(diag.max(axis=-1, initial=0.0), _TINY)


def closest_sqrt(S: np.ndarray, eps: float = EPS) -> np.ndarray:
    """Lower-triangular ``L`` with ``L Lᵀ = S + Σ v_k e_k e_kᵀ`` for the smallest pivots fixes.

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
    if S.ndim == 2:
        return _closest_single(S, eps)
    scale = _scale(S)
    floor = np.where(scale > _TINY, eps * scale, eps)
    try:
        L = np.linalg.cholesky(S)
        if (np.diagonal(L, axis1=-2, axis2=-1) ** 2 > floor[..., None]).all():
            return L  # no pivot needs the fix: the plain factor is the closest one
    except np.linalg.LinAlgError:
        pass
    L = np.zeros_like(S)
    for k in range(n):
        piv = S[..., k, k] - np.sum(L[..., k, :k] ** 2, axis=-1)
        L[..., k, k] = np.sqrt(np.where(piv > floor, piv, floor))
        if k + 1 < n:
            rest = S[..., k + 1 :, k] - np.einsum("...ij,...j->...i", L[..., k + 1 :, :k],
                                                  L[..., k, :k])
            L[..., k + 1 :, k] = rest / L[..., k, k][..., None]
    return L


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
        keep = piv > tol
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


def _closest_single(S: np.ndarray, eps: float) -> np.ndarray:
    """One matrix through LAPACK: a pivot fix is the same as adding ``floor − pivot`` to that
    diagonal entry, so each fix is followed by a fresh factorisation (usually none or one)."""
    scale = float(S.diagonal().max()) if S.size else 0.0
    floor = eps * scale if scale > _TINY else eps
    work = S.copy()
    fixed = np.zeros(S.shape[0], dtype=bool)
    for _ in range(2 * S.shape[0] + 2):
        L, info = lapack.dpotrf(work, lower=1, clean=1)
        if info == 0:
            bad = np.flatnonzero(~(L.diagonal() ** 2 > floor) & ~fixed)
            if bad.size == 0:
                return L
            k = int(bad[0])
        elif info > 0:
            k = info - 1
        else:  # pragma: no cover - LAPACK argument error
            raise np.linalg.LinAlgError(f"dpotrf failed (info {info})")
        piv = work[k, k] - float(L[k, :k] @ L[k, :k])
        # the pivot becomes `floor` (once more if rounding left it non-positive)
        work[k, k] += floor - piv if not fixed[k] and np.isfinite(piv) else floor
        fixed[k] = True
    raise np.linalg.LinAlgError("closest square root did not settle")


def _reduced_single(S: np.ndarray, eps: float) -> tuple[np.ndarray, np.ndarray]:
    """One matrix through LAPACK: the first pivot <= tol drops its row and column, and the
    factorisation restarts on the rest (the kept prefix is unchanged by the restart)."""
    n = S.shape[0]
    if n == 0:
        return np.zeros((0, 0)), np.zeros(0, dtype=bool)
    tol = eps * max(float(S.diagonal().max()), _TINY)
    L, info = lapack.dpotrf(S, lower=1, clean=1)
    if info == 0 and (L.diagonal() ** 2 > tol).all():
        return L, np.ones(n, dtype=bool)  # every equation independent: the plain factor
    kept = np.ones(n, dtype=bool)
    while kept.any():
        idx = np.flatnonzero(kept)
        L, info = lapack.dpotrf(S[np.ix_(idx, idx)], lower=1, clean=1)
        bad = info - 1 if info > 0 else None
        if info == 0:
            small = np.flatnonzero(~(np.diagonal(L) ** 2 > tol))
            bad = int(small[0]) if small.size else None
        if bad is not None:
            kept[idx[bad]] = False
            continue
        full = np.zeros_like(S)
        full[np.ix_(idx, idx)] = L
        return full, kept
    return np.zeros_like(S), kept
