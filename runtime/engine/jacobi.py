"""The singular value decomposition of a small matrix by one-sided Jacobi rotations
(Hestenes 1958; Demmel & Veselić 1992 for its accuracy).

The minimal solves of a robust search (eq. 21) decompose a Jacobian of a dozen rows a few
times per sample, thousands of samples a search: LAPACK's fixed costs per call (workspace
queries, its environment inquiries, the copies numba makes to Fortran order) are most of the
time on such sizes. Rotating pairs of rows until they are orthogonal costs a few hundred
flops a pair and computes small singular values to high relative accuracy.
"""

from __future__ import annotations

import numpy as np

from kanagen.common.jit import jit

#: Sweeps over every pair of rows at most (Jacobi converges quadratically: 5–8 suffice).
SWEEPS = 30
_EPS = np.finfo(float).eps


@jit
def row_svd(J, R, W, S):
    """``J = Wᵀ diag(S) V`` for a real ``J`` (m, n): the rows of ``R`` (m, n) become
    ``S_k V_k`` (orthogonal rows, ``R = W J``; rows of norm ``m ε ‖J‖_F`` or less are
    left as rounding), ``W`` (m, m) is orthogonal, ``S`` the rows' norms — unsorted: the
    left singular vectors are the rows of ``W``, the right ones the rows of ``R`` divided
    by ``S``. Returns the number of sweeps, −1 when they did not converge within
    :data:`SWEEPS`."""
    m, n = J.shape
    frobenius = 0.0
    for a in range(m):
        for j in range(n):
            R[a, j] = J[a, j]
            frobenius += J[a, j] * J[a, j]
        for b in range(m):
            W[a, b] = 1.0 if a == b else 0.0
    tol = _EPS * max(m, 1)
    # a row of rounding-level norm is zero: more rows than columns leave m − n of them,
    # whose directions rounding decides (rotating them would never converge)
    floor = tol * tol * frobenius
    for sweep in range(SWEEPS):
        rotated = False
        for a in range(m - 1):
            for b in range(a + 1, m):
                alpha, beta, gamma = 0.0, 0.0, 0.0
                for j in range(n):
                    alpha += R[a, j] * R[a, j]
                    beta += R[b, j] * R[b, j]
                    gamma += R[a, j] * R[b, j]
                if gamma == 0.0 or abs(gamma) <= tol * np.sqrt(alpha * beta) or \
                        alpha <= floor or beta <= floor:
                    continue
                rotated = True
                zeta = (beta - alpha) / (2.0 * gamma)
                t = (1.0 if zeta >= 0 else -1.0) / (abs(zeta) + np.sqrt(1.0 + zeta * zeta))
                c = 1.0 / np.sqrt(1.0 + t * t)
                s = c * t
                for j in range(n):
                    ra, rb = R[a, j], R[b, j]
                    R[a, j] = c * ra - s * rb
                    R[b, j] = s * ra + c * rb
                for j in range(m):
                    wa, wb = W[a, j], W[b, j]
                    W[a, j] = c * wa - s * wb
                    W[b, j] = s * wa + c * wb
        if not rotated:
            for a in range(m):
                total = 0.0
                for j in range(n):
                    total += R[a, j] * R[a, j]
                S[a] = np.sqrt(total)
            return sweep + 1
    for a in range(m):
        total = 0.0
        for j in range(n):
            total += R[a, j] * R[a, j]
        S[a] = np.sqrt(total)
    return -1


@jit
def sym_eigh(K):
    """The eigenvalues (ascending) and eigenvectors (columns) of the symmetric ``K`` from
    its lower triangle, as ``np.linalg.eigh`` (``UPLO='L'``), by cyclic Jacobi rotations:
    LAPACK's fixed costs were most of the time on the engine's sizes (a dozen rows at
    most). Raises ``LinAlgError`` on non-finite entries, as NumPy's does."""
    n = K.shape[0]
    A = np.empty((n, n))
    for a in range(n):
        for b in range(a + 1):
            v = K[a, b]
            if not np.isfinite(v):
                raise np.linalg.LinAlgError("Array must not contain infs or NaNs")
            A[a, b] = v
            A[b, a] = v
    V = np.zeros((n, n))
    for a in range(n):
        V[a, a] = 1.0
    for _ in range(SWEEPS):
        rotated = False
        for p in range(n - 1):
            for q in range(p + 1, n):
                apq = A[p, q]
                if apq == 0.0 or abs(apq) <= _EPS * np.sqrt(abs(A[p, p] * A[q, q])) * 0.5:
                    continue
                rotated = True
                theta = (A[q, q] - A[p, p]) / (2.0 * apq)
                t = (1.0 if theta >= 0 else -1.0) / (abs(theta) + np.sqrt(1.0 + theta * theta))
                c = 1.0 / np.sqrt(1.0 + t * t)
                s = t * c
                for k in range(n):  # A ← A Jᵀ (columns p, q)
                    akp, akq = A[k, p], A[k, q]
                    A[k, p] = c * akp - s * akq
                    A[k, q] = s * akp + c * akq
                for k in range(n):  # A ← J A (rows p, q)
                    apk, aqk = A[p, k], A[q, k]
                    A[p, k] = c * apk - s * aqk
                    A[q, k] = s * apk + c * aqk
                A[p, q] = 0.0
                A[q, p] = 0.0
                for k in range(n):
                    vkp, vkq = V[k, p], V[k, q]
                    V[k, p] = c * vkp - s * vkq
                    V[k, q] = s * vkp + c * vkq
        if not rotated:
            break
    w = np.empty(n)
    for a in range(n):
        w[a] = A[a, a]
    order = np.argsort(w)
    out_w = np.empty(n)
    out_V = np.empty((n, n))
    for a in range(n):
        out_w[a] = w[order[a]]
        for k in range(n):
            out_V[k, a] = V[k, order[a]]
    return out_w, out_V


@jit
def _rank(S, cut):
    """The singular values ``S`` (any order) above ``cut`` times the largest."""
    top = S.max() if S.size else 0.0
    rank = 0
    if top > 0:
        for a in range(S.size):
            rank += 1 if S[a] > cut * top else 0
    return rank


@jit
def svd_null_space(B, cut):
    """The null space of ``B`` (r ≥ 1 rows) as LAPACK's SVD gives it: ``Vt[rank:].T``, the
    rank the singular values above ``cut`` times the largest."""
    _, S, Vt = np.linalg.svd(B)
    return np.ascontiguousarray(Vt[_rank(S, cut):].T)


@jit
def null_space(B, cut):
    """Orthonormal columns spanning the null space of ``B`` (r, s): the complement of the
    right singular vectors of the singular values above ``cut`` times the largest
    (:func:`row_svd`'s on ``B`` scaled by a power of two, completed by Householder
    reflections of them). The same space as ``np.linalg.svd``'s ``Vt[rank:].T``, in another
    basis; LAPACK's SVD where the rotations do not converge. Raises ``LinAlgError`` on
    non-finite entries, as NumPy's does."""
    r, s = B.shape
    largest = 0.0
    for a in range(r):
        for j in range(s):
            if not np.isfinite(B[a, j]):
                raise np.linalg.LinAlgError("Array must not contain infs or NaNs")
            largest = max(largest, abs(B[a, j]))
    # scaled by a power of two near 1 / max|B| (exactly: the rotations' numbers are those of
    # B's, without their overflow above 1e77 or underflow below 1e-162)
    scaled = B * 2.0 ** min(max(-np.floor(np.log2(largest)), -1000.0), 1000.0) \
        if largest > 0 else B.copy()
    R, W, S = np.empty((r, s)), np.empty((r, r)), np.empty(r)
    if r and (row_svd(scaled, R, W, S) < 0 or _rank(S, cut) > min(r, s)):
        return svd_null_space(B, cut)
    top = S.max() if r else 0.0
    V = np.empty((s, r))  # the kept right singular vectors, as columns
    rank = 0
    for a in range(r):
        if top > 0 and S[a] > cut * top:
            for j in range(s):
                V[j, rank] = R[a, j] / S[a]
            rank += 1
    # Householder reflections H_k = I − 2 v_k v_kᵀ with H_{rank−1} ⋯ H_0 V upper triangular:
    # the last s − rank columns of H_0 ⋯ H_{rank−1} are orthogonal to V's columns
    U = np.zeros((s, rank))
    for k in range(rank):
        norm = 0.0
        for j in range(k, s):
            norm += V[j, k] * V[j, k]
        alpha = -np.sqrt(norm) if V[k, k] >= 0 else np.sqrt(norm)
        length = 0.0
        for j in range(k, s):
            U[j, k] = V[j, k] - (alpha if j == k else 0.0)
            length += U[j, k] * U[j, k]
        length = np.sqrt(length)
        if length > 0:
            for j in range(k, s):
                U[j, k] /= length
        for col in range(k, rank):
            dot = 0.0
            for j in range(k, s):
                dot += U[j, k] * V[j, col]
            for j in range(k, s):
                V[j, col] -= 2.0 * dot * U[j, k]
    Z = np.zeros((s, s - rank))
    for c in range(s - rank):
        Z[rank + c, c] = 1.0
        for k in range(rank - 1, -1, -1):
            dot = 0.0
            for j in range(k, s):
                dot += U[j, k] * Z[j, c]
            for j in range(k, s):
                Z[j, c] -= 2.0 * dot * U[j, k]
    return Z
