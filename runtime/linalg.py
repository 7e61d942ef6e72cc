"""The linear algebra of small matrices (a dozen rows or fewer), written as kernels: LAPACK's
and BLAS's fixed costs per call (workspace queries, environment inquiries, the copies numba
makes to Fortran order) are most of the time on such sizes.

* The singular value decomposition by one-sided Jacobi rotations of the rows (Hestenes
  1958; Demmel & Veselić 1992 for its accuracy: small singular values to high relative
  accuracy): :func:`row_svd` (the minimal solves of a robust search, eq. 21, a Jacobian a few
  times per sample, thousands of samples a search; the constraints' multipliers), sorted
  and completed (:func:`small_svd`, :func:`right_singular`: the two-view closed forms); a
  null space from it (:func:`null_space`).
* Householder reflections: a tall matrix's triangular factor (:func:`triangular_rows`), the
  orthogonal complement of columns (:func:`complement`), a minimal system's null space by a
  pivoted QR (:func:`null_basis`).
* The symmetric eigenproblem by two-sided rotations (:func:`sym_eigh`), a solve by Gaussian
  elimination with partial pivoting (:func:`solve_small`), products by loops
  (:func:`matmul`, :func:`matvec`, :func:`dot`).

The engine and the two-view closed forms share it (outside ``engine/``: the closed forms use
it without importing the engine).
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
def triangular_rows(J, c, work, U, T, g):
    """The rows ``T`` (k, n) and the vector ``g`` (k) of a least-squares problem ``J x ≈
    −c`` (``J``: m × n) with ``J``'s singular values and right singular vectors: ``J`` and
    ``c`` themselves when ``m <= n`` (k = m); else, ``k = n``, the triangular factor of the
    Householder ``J = Q [T; 0]`` (:func:`reflector`) and the first ``n`` entries of ``Qᵀ c``
    (``work`` m × (n + 1) and ``U`` m × n are scratch). :func:`row_svd` of ``T`` then
    rotates n rows instead of m (the m − n rows beyond ``J``'s rank are those the rotations
    converge on slowest), and ``J``'s left singular vectors are ``Q``'s first n columns
    times ``T``'s."""
    m, n = J.shape
    if m <= n:
        for a in range(m):
            g[a] = c[a]
            for j in range(n):
                T[a, j] = J[a, j]
        return
    for a in range(m):  # [J | c], reflected together
        for j in range(n):
            work[a, j] = J[a, j]
        work[a, n] = c[a]
    for k in range(n):
        alpha = reflector(work, k, U)
        for j in range(k + 1, n + 1):
            reflect(U, k, work, j)
        work[k, k] = alpha
    for a in range(n):
        g[a] = work[a, n]
        for j in range(n):
            T[a, j] = work[a, j] if j >= a else 0.0


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
    return complement(V, rank)


@jit
def complement(V, rank):
    """Orthonormal columns (s, s − rank) orthogonal to the first ``rank`` columns of ``V``
    (s, ≥ rank; orthonormal; overwritten): Householder reflections ``H_k = I − 2 u_k u_kᵀ``
    with ``H_{rank−1} ⋯ H_0 V`` upper triangular, whose product's last ``s − rank`` columns
    are orthogonal to ``V``'s."""
    U = np.zeros((V.shape[0], rank))
    for k in range(rank):
        reflector(V, k, U)
        for col in range(k + 1, rank):
            reflect(U, k, V, col)
    return trailing_columns(U, rank)


@jit(inline=True)
def reflector(B, k, U):
    """The unit Householder vector ``u`` with ``(I − 2 u uᵀ)`` mapping the column ``k`` of
    ``B`` below row ``k`` onto a multiple of ``e_k`` (no cancellation), into ``U[:, k]``
    (zero above row ``k``); returns the multiple, ``∓`` that column's norm."""
    s = B.shape[0]
    norm = 0.0
    for j in range(k, s):
        norm += B[j, k] * B[j, k]
    length = np.sqrt(norm)
    alpha = -length if B[k, k] >= 0 else length
    size = 0.0
    for j in range(k, s):
        U[j, k] = B[j, k] - (alpha if j == k else 0.0)
        size += U[j, k] * U[j, k]
    size = np.sqrt(size)
    if size > 0:
        for j in range(k, s):
            U[j, k] /= size
    return alpha


@jit(inline=True)
def reflect(U, k, B, col):
    """Column ``col`` of ``B`` reflected by the ``k``-th vector of :func:`reflector`."""
    dot = 0.0
    for j in range(k, B.shape[0]):
        dot += U[j, k] * B[j, col]
    for j in range(k, B.shape[0]):
        B[j, col] -= 2.0 * dot * U[j, k]


@jit
def trailing_columns(U, rank):
    """The last ``s − rank`` columns of ``H_0 ⋯ H_{rank−1}``, ``H_k = I − 2 u_k u_kᵀ`` with
    ``u_k`` the unit columns of ``U`` (s, rank), zero above row ``k``."""
    s = U.shape[0]
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


@jit
def _power_scale(B):
    """A power of two near ``1 / max |B|`` (1 for a zero ``B``): the rotations then see
    ``B``'s numbers exactly, without overflow above 1e77 or underflow below 1e-162. Raises
    ``LinAlgError`` on non-finite entries, as NumPy's SVD does."""
    largest = 0.0
    for a in range(B.shape[0]):
        for j in range(B.shape[1]):
            if not np.isfinite(B[a, j]):
                raise np.linalg.LinAlgError("SVD did not converge")
            largest = max(largest, abs(B[a, j]))
    return 2.0 ** min(max(-np.floor(np.log2(largest)), -1000.0), 1000.0) if largest > 0 \
        else 1.0


@jit
def _wide_svd(B, left):
    """:func:`small_svd` of ``B`` (m, n) with m <= n: its rows rotated (:func:`row_svd`),
    sorted by decreasing norm; the right vectors of the norms at rounding level (m n ε of
    the largest, the rotations' own floor) and beyond m completed (:func:`complement`).
    ``left``: ``U`` too (else an empty one)."""
    m, n = B.shape
    scale = _power_scale(B)
    R, W, S = np.empty((m, n)), np.empty((m, m)), np.empty(m)
    if m and row_svd(B * scale, R, W, S) < 0:
        raise np.linalg.LinAlgError("SVD did not converge")
    order = np.argsort(-S, kind="mergesort")
    top = S[order[0]] if m else 0.0
    cut = _EPS * m * n * top
    values = np.empty(m)
    U = np.empty((m, m)) if left else np.empty((0, 0))
    V = np.empty((n, n))  # the right vectors as columns
    rank = 0
    for k in range(m):
        a = order[k]
        values[k] = S[a] / scale
        if left:
            for i in range(m):
                U[i, k] = W[a, i]
        if S[a] > cut and rank == k:
            for j in range(n):
                V[j, k] = R[a, j] / S[a]
            rank += 1
    Vt = np.empty((n, n))
    for k in range(rank):
        for j in range(n):
            Vt[k, j] = V[j, k]
    Z = complement(V, rank)
    for c in range(n - rank):
        for j in range(n):
            Vt[rank + c, j] = Z[j, c]
    return U, values, Vt


@jit
def small_svd(A):
    """``np.linalg.svd(A)`` of a small matrix: ``U`` (m, m), the singular values (min(m,
    n)) decreasing, ``Vᵀ`` (n, n), orthogonal, by one-sided Jacobi rotations of ``A``'s rows
    (of ``Aᵀ``'s when it has more rows than columns) — LAPACK's fixed costs are most of its
    time on a 3 × 3 or a 7 × 9. The singular vectors are those of LAPACK up to the signs and
    the basis of a repeated (or null) singular value; the right ones of a singular value at
    rounding level complete an orthonormal basis. Raises ``LinAlgError`` on non-finite
    entries, or when the rotations do not converge."""
    m, n = A.shape
    if m <= n:
        return _wide_svd(A, True)
    U, S, Vt = _wide_svd(np.ascontiguousarray(A.T), True)
    return np.ascontiguousarray(Vt.T), S, np.ascontiguousarray(U.T)


@jit
def right_singular(A):
    """``np.linalg.svd(A)[1:]`` of a small system whose right singular vectors are wanted —
    the singular values (min(m, n)), decreasing, and ``Vᵀ`` (n, n) — without the left
    ones: a tall ``A`` reduced to its triangular factor first (:func:`triangular_rows`,
    the same right vectors and values), then :func:`small_svd`'s rotations."""
    m, n = A.shape
    if m <= n:
        _, S, Vt = _wide_svd(A, False)
        return S, Vt
    T, g = np.empty((n, n)), np.empty(n)
    triangular_rows(A, np.zeros(m), np.empty((m, n + 1)), np.empty((m, n)), T, g)
    _, S, Vt = _wide_svd(T, False)
    return S, Vt


@jit
def null_basis(A, cut):
    """Orthonormal columns (n, n − m) spanning the null space of ``A`` (m, n), m < n, of
    full row rank, and whether it is (every pivot above ``cut`` times the largest): a
    Householder QR of ``Aᵀ`` with column pivoting, whose last ``n − m`` columns of ``Q`` are
    orthogonal to ``A``'s rows — a fraction of an SVD's cost for a system that has exactly
    the null vectors wanted (a minimal sample's). Raises ``LinAlgError`` on non-finite
    entries."""
    m, n = A.shape
    B = np.empty((n, m))  # Aᵀ, pivoted and reflected in place
    norms = np.zeros(m)
    for a in range(m):
        for j in range(n):
            v = A[a, j]
            if not np.isfinite(v):
                raise np.linalg.LinAlgError("Array must not contain infs or NaNs")
            B[j, a] = v
            norms[a] += v * v
    U = np.zeros((n, m))  # the unit Householder vectors
    top, full = 0.0, True
    for k in range(m):
        pivot = k
        for c in range(k + 1, m):
            if norms[c] > norms[pivot]:
                pivot = c
        if pivot != k:
            for j in range(n):
                B[j, k], B[j, pivot] = B[j, pivot], B[j, k]
            norms[k], norms[pivot] = norms[pivot], norms[k]
        length = abs(reflector(B, k, U))
        top = length if k == 0 else top
        full = full and length > cut * top
        for c in range(k + 1, m):
            reflect(U, k, B, c)
            norms[c] -= B[k, c] * B[k, c]  # the part of column c left below row k
    return trailing_columns(U, m), full


@jit
def solve_small(K, R, s, k):
    """``K[:s, :s] X = R[:s, :k]`` in place by Gaussian elimination with partial pivoting
    (``R`` receives ``X``); False when a pivot vanishes against the matrix's scale."""
    scale = 0.0
    for a in range(s):
        for b in range(s):
            scale = max(scale, abs(K[a, b]))
    if not (scale > 0.0 and np.isfinite(scale)):
        return False
    for col in range(s):
        best, at = abs(K[col, col]), col
        for a in range(col + 1, s):
            if abs(K[a, col]) > best:
                best, at = abs(K[a, col]), a
        if not best > 1e-13 * scale:
            return False
        if at != col:
            for b in range(s):
                K[col, b], K[at, b] = K[at, b], K[col, b]
            for b in range(k):
                R[col, b], R[at, b] = R[at, b], R[col, b]
        for a in range(col + 1, s):
            f = K[a, col] / K[col, col]
            if f != 0.0:
                for b in range(col, s):
                    K[a, b] -= f * K[col, b]
                for b in range(k):
                    R[a, b] -= f * R[col, b]
    for a in range(s - 1, -1, -1):
        for b in range(k):
            acc = R[a, b]
            for u in range(a + 1, s):
                acc -= K[a, u] * R[u, b]
            R[a, b] = acc / K[a, a]
    return True


@jit
def certified_solve(T, b, floor, K, X, x):
    """``x = T⁻¹ b`` for a square ``T`` (n × n) whose singular values are all above
    ``floor`` times the largest, which an SVD would keep every one of — its least-squares
    solution then, at a fraction of its cost: Gaussian elimination of ``[I | b]``
    (:func:`solve_small`), the inverse's norm the certificate (``σ_min / σ_max ≥ 1 /
    (‖T‖_F ‖T⁻¹‖_F) > 2 floor``, a margin for the rounding of ``T⁻¹``). False, ``x``
    undefined, when not certified. ``K`` (n × n) and ``X`` (n × (n + 1)): scratch. The
    norms are taken of ``T / max |T|`` and ``max |T| T⁻¹`` (no overflow or underflow at
    any scale of ``T``)."""
    n = b.size
    top = 0.0
    for a in range(n):
        for j in range(n):
            K[a, j] = T[a, j]
            X[a, j] = 1.0 if a == j else 0.0
            top = max(top, abs(T[a, j]))
        X[a, n] = b[a]
    if not (top > 0.0 and np.isfinite(top)) or not solve_small(K, X, n, n + 1):
        return False
    norm, inverse = 0.0, 0.0
    for a in range(n):
        for j in range(n):
            norm += (T[a, j] / top) ** 2
            inverse += (X[a, j] * top) ** 2
    if not 2.0 * floor * np.sqrt(norm * inverse) < 1.0:
        return False
    for a in range(n):
        x[a] = X[a, n]
    return True


@jit
def dot(a, b) -> float:
    """``a · b`` of two vectors, a loop (BLAS's call costs several times the arithmetic of
    the closed forms' products, as for :func:`matmul`)."""
    total = 0.0
    for i in range(a.shape[0]):
        total += a[i] * b[i]
    return total


@jit
def matmul(A, B):
    """``A @ B`` of small matrices (any layout), by loops: numba's ``@`` calls BLAS, whose
    fixed cost is ~8 times a 3 × 3 product's arithmetic."""
    m, k, n = A.shape[0], A.shape[1], B.shape[1]
    C = np.empty((m, n))
    for i in range(m):
        for j in range(n):
            total = 0.0
            for u in range(k):
                total += A[i, u] * B[u, j]
            C[i, j] = total
    return C


@jit
def projected(Z, M):
    """``ZᵀMZ`` symmetrised, ``½ (ZᵀMZ + (ZᵀMZ)ᵀ)``: a symmetric matrix on the columns of a
    basis ``Z`` (the information on a tangent space, a null space)."""
    P = matmul(matmul(Z.T, M), Z)
    return 0.5 * (P + P.T)


@jit
def matvec(A, x):
    """``A @ x`` of a small matrix and a vector (:func:`matmul`)."""
    y = np.empty(A.shape[0])
    for i in range(A.shape[0]):
        total = 0.0
        for u in range(A.shape[1]):
            total += A[i, u] * x[u]
        y[i] = total
    return y


@jit
def vecmat(x, A):
    """``x @ A`` of a vector and a small matrix (:func:`matmul`)."""
    return matvec(A.T, x)
