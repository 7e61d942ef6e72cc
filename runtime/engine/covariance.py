"""The covariance of the estimate under its constraints (runtime/results.py:
``constrained_covariance`` documents it and is its entry point)."""

from __future__ import annotations

import numpy as np

from kanagen.common.jit import jit

from ..linalg import complement as linalg_complement
from ..linalg import matmul, projected, svd_null_space, sym_eigh


@jit
def null_basis(C0, n):
    """An orthonormal basis of the null space of ``C0`` (rank: singular values above
    1e-12 of the largest): one constraint's by a reflection (:func:`complement`), more
    LAPACK's SVD's — a pinned component's variance exactly zero either way."""
    if C0.shape[0] == 0:
        return np.eye(n)
    if C0.shape[0] == 1:
        return complement(C0[0])
    return svd_null_space(C0, 1e-12)


@jit
def complement(c):
    """Orthonormal columns spanning the vectors orthogonal to ``c`` (``n − 1`` of them; all
    ``n`` axes when ``c`` is zero): :func:`~..linalg.complement`'s reflection of ``c``
    scaled by its largest magnitude, that component moved first — so a unit ``c = ±e_k``
    (a pinned component) is reflected onto its own axis and gives the other axes exactly.
    LAPACK's SVD of one row costs several times more (its workspace queries and copies), in
    another basis of the same space."""
    n = c.size
    k, top = 0, 0.0
    for j in range(n):
        if abs(c[j]) > top:
            k, top = j, abs(c[j])
    if not top > 0.0:
        return np.eye(n)
    V = np.empty((n, 1))  # c / top with component k moved first, the others in order
    for j in range(n):
        V[moved_first(j, k), 0] = c[j] / top
    W = linalg_complement(V, 1)
    Z = np.empty((n, n - 1))  # back to c's order
    for j in range(n):
        for col in range(n - 1):
            Z[j, col] = W[moved_first(j, k), col]
    return Z


@jit(inline=True)
def moved_first(j, k):
    """Where component ``j`` lies once component ``k`` is moved first, the others kept in
    order."""
    return 0 if j == k else j + 1 if j < k else j


@jit
def constrained_covariance(info, C0):
    """``Z (Zᵀ Q̃ Z)⁻¹ Zᵀ`` with ``Z`` a basis of the null space of ``C0``; an infinite
    variance on the components that an unobservable direction moves; NaN where ``info``
    or ``C0`` is not finite."""
    n = info.shape[0]
    if not (np.all(np.isfinite(info)) and np.all(np.isfinite(C0))):
        return np.full((n, n), np.nan)
    Z = null_basis(C0, n)
    k = Z.shape[1]
    if k == 0:
        return np.zeros((n, n))
    H = projected(Z, info)
    top = 0.0
    for a in range(k):
        top = max(top, abs(H[a, a]))
    d = np.empty(k)
    for a in range(k):
        diag = abs(H[a, a])
        d[a] = np.sqrt(diag if diag > 0 else max(top, 1.0))
    scaled = np.empty((k, k))
    for a in range(k):
        for b in range(k):
            scaled[a, b] = H[a, b] / (d[a] * d[b])
    w, V = sym_eigh(scaled)
    scale = 0.0
    for a in range(k):
        scale = max(scale, abs(w[a]))
    inv_w = np.zeros(k)
    null = np.zeros(k, dtype=np.bool_)
    for a in range(k):
        null[a] = abs(w[a]) <= 1e-12 * scale if scale > 0 else True
        inv_w[a] = 0.0 if null[a] else 1.0 / w[a]
    VD = np.empty((k, k))
    for a in range(k):
        for b in range(k):
            VD[a, b] = V[a, b] / d[a]
    ZV = matmul(Z, VD)
    cov = matmul(ZV * inv_w, ZV.T)
    cov = 0.5 * (cov + cov.T)
    ZN = matmul(Z, V)
    for i in range(n):
        free = False
        for b in range(k):
            free = free or (null[b] and abs(ZN[i, b]) > 1e-8)
        if free:
            cov[i, :] = np.inf
            cov[:, i] = np.inf
    return cov
