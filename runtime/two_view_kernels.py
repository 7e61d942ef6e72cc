"""The closed forms of two-view geometry as compiled kernels: the one source of the two-view
initialisers (:mod:`~kanagen.runtime.two_view_twins`) and of the functions of
:mod:`~kanagen.runtime.geometry` that wrap them.

Written in the subset of Python and NumPy that numba compiles (``@jit``;
``NUMBA_DISABLE_JIT=1`` runs the same source interpreted). Matches are the rows
``(x1, y1, x2, y2)`` of an (n, 4) array ``X``, pixels; rays are (n, 3) arrays.

Their linear algebra is that of small matrices (:mod:`~kanagen.runtime.numpy_rules`:
Jacobi rotations, not LAPACK, whose fixed costs were most of a sample's time): on a sample
they give the candidates of the NumPy closed forms they replaced
(tests/reference_two_view.py) to rounding; on a degenerate one — a null space larger than
the algorithm expects — another arbitrary basis of it, so other arbitrary candidates, or
none. The closed forms are ``@linked`` (compiled once each and called through an address,
not copied into every caller); the small helpers are ordinary kernels.
"""

from __future__ import annotations

import numpy as np

from kanagen.common.jit import jit
from kanagen.common.link import linked

from .linalg import dot, matmul, matvec, sym_eigh, vecmat
from .numpy_rules import (
    argmax_abs,
    columns,
    cross,
    det3,
    divided,
    eigenvalues,
    finite,
    floor0,
    negated,
    norm,
    null_space_svd,
    null_vectors,
    put,
    put_matrix,
    solved,
    svd,
    unit,
    vector_sum,
)

#: A singular value below this fraction of the largest is taken as zero: a sample whose
#: system has more null vectors than its algorithm expects is degenerate.
DEGENERATE = 1e-6
#: ... the calibrated closed forms' least-squares null vectors (runtime/calibrated_starts.py,
#: the retinal motions here): the second least singular value above this fraction.
CALIBRATED_DEGENERATE = 1e-9
_ALPHAS = np.array([0.0, 1.0, -1.0, 2.0])
_CUBIC_FROM_VALUES = np.linalg.inv(np.vander(_ALPHAS, 4))  # values at _ALPHAS -> coefficients


# -- fundamental matrix and homography ------------------------------------------------------

@linked("f2 i -> f2", python=True)
def normalising_transform(X, c: int):
    """Hartley's conditioning of the points in columns ``c, c + 1`` of ``X``: centroid to the
    origin, mean distance √2 (``T``, 3 × 3)."""
    n = X.shape[0]
    cx, cy = X[0, c], X[0, c + 1]  # the mean over the points: a sum in sequence
    for i in range(1, n):
        cx += X[i, c]
        cy += X[i, c + 1]
    cx, cy = cx / n, cy / n
    distance = np.empty(n)
    for i in range(n):
        dx, dy = X[i, c] - cx, X[i, c + 1] - cy
        distance[i] = np.sqrt(dx * dx + dy * dy)
    spread = vector_sum(distance) / n
    s = np.sqrt(2.0) / spread if spread > 0 else 1.0
    T = np.zeros((3, 3))
    T[0, 0], T[0, 2], T[1, 1], T[1, 2], T[2, 2] = s, -s * cx, s, -s * cy, 1.0
    return T


@linked("f2 i f2 -> f2")
def normalised(X, c: int, T):
    """The points of columns ``c, c + 1`` of ``X``, homogeneous, mapped by ``T``."""
    n = X.shape[0]
    p = np.ones((n, 3))
    for i in range(n):
        p[i, 0], p[i, 1] = X[i, c], X[i, c + 1]
    return matmul(p, T.T)


@linked("f2 -> f2 f2 f2")
def epipolar_rows(X):
    """The rows ``p2 ⊗ p1`` of ``p2ᵀ F p1 = 0`` in Hartley's conditioning, and its two
    transforms."""
    T1, T2 = normalising_transform(X, 0), normalising_transform(X, 2)
    p1, p2 = normalised(X, 0, T1), normalised(X, 2, T2)
    A = np.empty((X.shape[0], 9))
    for k in range(X.shape[0]):
        for i in range(3):
            for j in range(3):
                A[k, 3 * i + j] = p2[k, i] * p1[k, j]
    return A, T1, T2


@linked("f2 -> f2", python=True)
def fundamental_8point(X):
    """The normalised eight-point ``F`` of the matches ``X`` (n ≥ 8), rank 2, unit norm.
    Raises ``LinAlgError`` on a degenerate sample (more than one null vector: points on a
    line, repeated, a pure rotation or a plane seen without noise)."""
    A, T1, T2 = epipolar_rows(X)
    S, Vt = null_space_svd(A)
    _determined(S[7] > DEGENERATE * S[0])
    F = Vt[-1].copy().reshape(3, 3)
    U, S, Vt = svd(F)
    D = np.zeros((3, 3))
    D[0, 0], D[1, 1] = S[0], S[1]  # rank 2: the closest in Frobenius norm
    return unit(matmul(matmul(T2.T, matmul(matmul(U, D), Vt)), T1))


@jit
def _determined(determined: bool) -> None:
    """Raise ``LinAlgError`` on a degenerate sample: its system has more null vectors than
    the closed form takes (a singular value, or a pivot, below :data:`DEGENERATE` of the
    largest)."""
    if not determined:
        raise np.linalg.LinAlgError("a degenerate sample: its system has more null vectors "
                                    "than the closed form expects")


@jit
def polynomial_roots(p):
    """``np.roots(p)`` as (real parts, imaginary parts): the eigenvalues of the companion
    matrix, then a zero for each trailing zero coefficient."""
    first, last = -1, -1
    for i in range(p.shape[0]):
        if p[i] != 0:
            last = i
            if first < 0:
                first = i
    if first < 0:
        return np.empty(0), np.empty(0)
    trailing = p.shape[0] - last - 1
    q = p[first:last + 1]
    N = q.shape[0]
    re, im = np.zeros(N - 1 + trailing), np.zeros(N - 1 + trailing)
    if N > 1:
        A = np.zeros((N - 1, N - 1))
        for i in range(1, N - 1):
            A[i, i - 1] = 1.0
        for j in range(N - 1):
            A[0, j] = -q[j + 1] / q[0]
        wr, wi = eigenvalues(A)
        put(re, 0, wr)
        put(im, 0, wi)
    return re, im


@linked("f2 -> f3 i", python=True)
def fundamental_7point(X):
    """The seven-point ``F`` of the 7 matches ``X``: the real roots ``α`` of
    ``det(α F1 + (1 − α) F2) = 0`` on the two-dimensional null space, unit norm each; as
    ``(Fs (3, 3, 3), count)``; none on a degenerate sample (more than two null vectors)."""
    A, T1, T2 = epipolar_rows(X)
    N, full = null_vectors(A, DEGENERATE)
    Fs, count = np.empty((3, 3, 3)), 0
    if not full:
        return Fs, count
    F1, F2 = N[:, 0].copy().reshape(3, 3), N[:, 1].copy().reshape(3, 3)
    dets = np.empty(4)  # det(a F1 + (1 − a) F2) is a cubic in a: four values fix it
    for i in range(4):
        dets[i] = det3(_pencil(_ALPHAS[i], F1, F2))
    re, im = polynomial_roots(matvec(_CUBIC_FROM_VALUES, dets))
    for i in range(re.shape[0]):
        if abs(im[i]) > 1e-8 * (1 + abs(re[i])):
            continue
        put_matrix(Fs, count, unit(matmul(matmul(T2.T, _pencil(re[i], F1, F2)), T1)))
        count += 1
    return Fs, count


@jit
def _pencil(a: float, F1, F2):
    """``a F1 + (1 − a) F2``."""
    F = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            F[i, j] = a * F1[i, j] + (1 - a) * F2[i, j]
    return F


@linked("f2 -> f2", python=True)
def homography_dlt(X):
    """The normalised DLT homography of the matches ``X`` (n ≥ 4), ``p2 ∝ H p1``, unit
    norm. Raises ``LinAlgError`` on a degenerate sample (more than one null vector: three
    of the points on a line, or repeated)."""
    n = X.shape[0]
    T1, T2 = normalising_transform(X, 0), normalising_transform(X, 2)
    p1, p2 = normalised(X, 0, T1), normalised(X, 2, T2)
    A = np.zeros((2 * n, 9))
    for k in range(n):
        for j in range(3):
            A[k, 3 + j] = -p2[k, 2] * p1[k, j]
            A[k, 6 + j] = p2[k, 1] * p1[k, j]
            A[n + k, j] = p2[k, 2] * p1[k, j]
            A[n + k, 6 + j] = -p2[k, 0] * p1[k, j]
    if n == 4:  # exactly one null vector, unless degenerate
        N, full = null_vectors(A, DEGENERATE)
        _determined(full)
        H = N[:, 0].copy().reshape(3, 3)
    else:
        S, Vt = null_space_svd(A)
        _determined(S[7] > DEGENERATE * S[0])
        H = Vt[-1].copy().reshape(3, 3)
    return unit(solved(T2, matmul(H, T1)))


@jit
def _squared(G, e, p, p_other) -> float:
    """Bougnoux's squared focal length of one camera:
    ``−(p'ᵀ [e]× Ĩ G p pᵀ Gᵀ p') / (p'ᵀ [e]× Ĩ G Ĩ Gᵀ p')``, ``Ĩ = diag(1, 1, 0)``."""
    a = cross(p_other, e)  # p'ᵀ [e]× as a vector: (p' × e)
    a[2] = 0.0  # … Ĩ
    aG, Gtp = vecmat(a, G), matvec(G.T, p_other)
    den = aG[0] * Gtp[0] + aG[1] * Gtp[1]
    return -dot(aG, p) * dot(p, Gtp) / den if den != 0 else np.inf


@linked("f2 -> f1 f1", python=True)
def epipoles(F):
    """``(e1, e2)`` with ``F e1 = 0`` and ``Fᵀ e2 = 0``: the singular vectors of ``F``'s
    least singular value (unit)."""
    U, _, Vt = svd(F)
    return Vt[-1].copy(), np.ascontiguousarray(U[:, -1])


@linked("f2 f1 f1 -> f f", python=True)
def focal_lengths(F, pp1, pp2):
    """Squared focal lengths ``(f1², f2²)`` from ``F`` and the principal points ``pp1``,
    ``pp2`` (homogeneous 3-vectors), Bougnoux 1998."""
    e1, e2 = epipoles(F)
    return _squared(F, e2, pp1, pp2), _squared(F.T, e1, pp2, pp1)


# -- poses -----------------------------------------------------------------------------------

@linked("f2 -> f3 f2", python=True)
def essential_poses(E):
    """The four ``(R, t)`` with ``E ∝ [t]× R``, ``t`` unit: ``(Rs (4, 3, 3), ts (4, 3))`` in
    the order ``(Ra, t), (Ra, −t), (Rb, t), (Rb, −t)``."""
    U, _, Vt = svd(E)
    if det3(U) < 0:
        U = negated(U)
    if det3(Vt) < 0:
        Vt = negated(Vt)
    W = np.zeros((3, 3))
    W[0, 1], W[1, 0], W[2, 2] = -1.0, 1.0, 1.0
    Rs, ts = np.empty((4, 3, 3)), np.empty((4, 3))
    for k in range(2):
        R = matmul(matmul(U, W if k == 0 else W.T), Vt)
        for s in range(2):
            put_matrix(Rs, 2 * k + s, R)
            for i in range(3):
                ts[2 * k + s, i] = U[i, 2] if s == 0 else -U[i, 2]
    return Rs, ts


@linked("f2 -> f2", python=True)
def nearest_essential(E):
    """The closest matrix to ``E`` with singular values (1, 1, 0)."""
    U, _, Vt = svd(E)
    D = np.zeros((3, 3))
    D[0, 0], D[1, 1] = 1.0, 1.0
    return matmul(matmul(U, D), Vt)


@linked("f2 f1 f2 f2 -> f1 f1", python=True)
def depths(R, t, y1, y2):
    """Depths ``(λ1, λ2)`` of the points along the rays ``y1``, ``y2`` for ``X2 = R X1 + t``,
    by least squares on ``λ2 y2 ≈ λ1 R y1 + t`` (the 2 × 2 normal equations, per point)."""
    a = matmul(y1, R.T)
    at, bt = matvec(a, t), matvec(y2, t)
    n = y1.shape[0]
    lam1, lam2 = np.empty(n), np.empty(n)
    for i in range(n):
        aa = a[i, 0] * a[i, 0] + a[i, 1] * a[i, 1] + a[i, 2] * a[i, 2]
        bb = y2[i, 0] * y2[i, 0] + y2[i, 1] * y2[i, 1] + y2[i, 2] * y2[i, 2]
        ab = a[i, 0] * y2[i, 0] + a[i, 1] * y2[i, 1] + a[i, 2] * y2[i, 2]
        d = aa * bb - ab * ab
        lam1[i] = (-bb * at[i] + ab * bt[i]) / d
        lam2[i] = (ab * at[i] - aa * bt[i]) / -d
    return lam1, lam2


@jit
def _sign_of_largest(t) -> float:
    """The sign of ``t``'s component of largest magnitude (the first of equals)."""
    return np.sign(t[argmax_abs(t)])


@jit
def _opposite(t, u) -> bool:
    """``np.array_equal(t, -u)``."""
    for i in range(t.shape[0]):
        if not t[i] == -u[i]:
            return False
    return True


@linked("f3 f2 f2 f2 -> i", python=True)
def best_pose(Rs, ts, y1, y2) -> int:
    """The index of the pose ``(Rs[i], ts[i])`` that puts most points in front of both
    cameras (cheirality); a tie goes to the smaller rotation (the larger trace), then to
    the ``t`` whose largest component is positive, then to the first: the choice does not
    depend on the order the SVD's arbitrary basis gave the poses."""
    count = Rs.shape[0]
    # per pose whose depths were computed, the points in front and behind both cameras
    done = np.zeros(count, np.bool_)
    ahead, behind = np.zeros(count, np.int64), np.zeros(count, np.int64)
    best, key = -1, (0, 0.0, 0.0)
    for p in range(count):
        twin = -1  # (R, −t) of a pose done: its depths are those negated, exactly
        for o in range(p):
            if done[o] and np.array_equal(Rs[p], Rs[o]) and _opposite(ts[p], ts[o]):
                twin = o
                break
        if twin >= 0:
            front = behind[twin]
        else:
            d1, d2 = depths(Rs[p], ts[p], y1, y2)
            done[p] = True
            for i in range(d1.shape[0]):
                ahead[p] += d1[i] > 0 and d2[i] > 0
                behind[p] += d1[i] < 0 and d2[i] < 0
            front = ahead[p]
        R = Rs[p]
        mine = (front, R[0, 0] + R[1, 1] + R[2, 2], _sign_of_largest(ts[p]))
        if best < 0 or _greater(mine, key):
            best, key = p, mine
    return best


@jit
def _greater(a, b) -> bool:
    """``a > b`` for tuples as Python compares them: at the first entry that differs (a NaN
    differs from everything), which is greater."""
    if a[0] != b[0]:
        return a[0] > b[0]
    if a[1] != b[1]:
        return a[1] > b[1]
    return a[2] > b[2]


@linked("f2 f2 f2 b b -> f3 f2 f2 i", python=True)
def homography_poses(H0, y1, y2, depths_sign: bool, in_front: bool):
    """``(R, t, w)`` with ``H0 ∝ R + t wᵀ`` (``t`` unit) for a calibrated homography:
    ``(Rs (4, 3, 3), ts (4, 3), ws (4, 3), count)``.

    The sign of ``H0`` is the one that gives positive depths to the rays ``y1``, ``y2``
    (``depths_sign``; ``det(H0)`` when they do not decide, or without them); with
    ``in_front`` only the decompositions that see the plane in front of camera 1 for most of
    ``y1`` are kept, when there are any; the smaller rotation first. A pure rotation gives
    one pose, ``w = 0``.
    """
    H = divided(H0, svd(H0)[1][1])
    if not finite(H):  # σ2 = 0 (NumPy's eigh then failed, or gave poses of NaN): no pose
        raise np.linalg.LinAlgError("a homography of rank one has no pose")
    if depths_sign:
        products = np.empty(y1.shape[0])  # Σ y2ᵀ H y1, in NumPy's einsum order
        for k in range(y1.shape[0]):
            acc = 0.0
            for i in range(3):
                for j in range(3):
                    acc += y2[k, i] * H[i, j] * y1[k, j]
            products[k] = acc
        total = vector_sum(products)
        flip = total < 0 or total == 0 and det3(H) < 0
    else:
        flip = det3(H) < 0
    if flip:
        H = negated(H)
    w2, V = sym_eigh(matmul(H.T, H))
    V = np.ascontiguousarray(V[:, ::-1])  # decreasing
    if det3(V) < 0:
        V = negated(V)
    s1, s3 = w2[2], w2[0]
    Rs, ts, ws = np.zeros((4, 3, 3)), np.zeros((4, 3)), np.zeros((4, 3))
    if s1 - s3 < 1e-12:  # a pure rotation, H ∝ R
        U, _, Vt = svd(H)
        R = matmul(U, Vt)
        sign = np.sign(det3(R))
        for i in range(3):
            for j in range(3):
                Rs[0, i, j] = R[i, j] * sign
        ts[0, 2] = 1.0
        return Rs, ts, ws, 1
    v1, v2, v3 = V[:, 0].copy(), V[:, 1].copy(), V[:, 2].copy()
    a, b = np.sqrt(floor0(1.0 - s3)), np.sqrt(floor0(s1 - 1.0))
    root = np.sqrt(s1 - s3)
    for side in range(2):
        u = np.empty(3)
        for i in range(3):
            u[i] = (a * v1[i] + (b if side == 0 else -b) * v3[i]) / root
        n = cross(v2, u)
        Hv2, Hu = matvec(H, v2), matvec(H, u)
        R = matmul(columns(Hv2, Hu, cross(Hv2, Hu)), columns(v2, u, n).T)
        D = np.empty((3, 3))
        for i in range(3):
            for j in range(3):
                D[i, j] = H[i, j] - R[i, j]
        T = matvec(D, n)  # H = R + T nᵀ (d = 1)
        for s in range(2):
            sign, scale, p = 1.0 if s == 0 else -1.0, norm(T), 2 * side + s
            put_matrix(Rs, p, R)
            for i in range(3):
                ts[p, i], ws[p, i] = sign * T[i] / scale, sign * n[i] * scale
    count = 4
    if in_front:
        kept = 0
        for p in range(4):  # w is the plane's normal over its distance: λ wᵀ y1 = 1
            ahead = 0
            for value in matvec(y1, ws[p]):
                ahead += value > 0
            if ahead / y1.shape[0] > 0.5:
                put_matrix(Rs, kept, Rs[p])
                put(ts[kept], 0, ts[p])
                put(ws[kept], 0, ws[p])
                kept += 1
        count = kept if kept > 0 else 4
    _smaller_rotation_first(Rs, ts, ws, count)
    return Rs, ts, ws, count


@jit
def _smaller_rotation_first(Rs, ts, ws, count: int) -> None:
    """Order the first ``count`` poses by decreasing trace of ``R`` (the smaller rotation
    first; equal traces keep their order), in place: the decompositions of a homography
    then come in an order its factorisation's signs do not decide, and a search that takes
    the first of equivalent candidates takes the same one."""
    for p in range(1, count):
        k = p
        while k > 0 and Rs[k, 0, 0] + Rs[k, 1, 1] + Rs[k, 2, 2] > \
                Rs[k - 1, 0, 0] + Rs[k - 1, 1, 1] + Rs[k - 1, 2, 2]:
            for i in range(3):
                ts[k, i], ts[k - 1, i] = ts[k - 1, i], ts[k, i]
                ws[k, i], ws[k - 1, i] = ws[k - 1, i], ws[k, i]
                for j in range(3):
                    Rs[k, i, j], Rs[k - 1, i, j] = Rs[k - 1, i, j], Rs[k, i, j]
            k -= 1


@linked("f1 f1 f1 f1 -> f2 b", python=True)
def rotation_from_pairs(a1, a2, b1, b2):
    """The rotation with ``R â1 = b̂1`` and ``R (a1 × a2) ∝ b1 × b2`` (the triad method:
    ``R = B Aᵀ``), and whether it exists (no pair parallel)."""
    A, ok_a = _triad(a1, a2)
    B, ok_b = _triad(b1, b2)
    return matmul(B, A.T), ok_a and ok_b


@jit
def _triad(u, v):
    """``[û, n̂, û × n̂]``, ``n = u × v``, and whether ``u`` and ``n`` are not null."""
    n = cross(u, v)
    nu, nn = np.sqrt(dot(u, u)), np.sqrt(dot(n, n))
    if not (nu > 0 and nn > 0):
        return np.zeros((3, 3)), False
    e1, e2 = divided(u, nu), divided(n, nn)
    return columns(e1, e2, cross(e1, e2)), True


@linked("f2 -> f1", python=True)
def quaternion_from_rotation(R):
    """Unit quaternion ``(w, x, y, z)``, ``w >= 0``, of the rotation ``R`` (Shepperd)."""
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    cands = np.array([1 + tr, 1 + 2 * R[0, 0] - tr, 1 + 2 * R[1, 1] - tr,
                      1 + 2 * R[2, 2] - tr])
    i = np.argmax(cands)
    r = np.sqrt(floor0(cands[i])) / 2
    if i == 0:
        q = np.array([r, (R[2, 1] - R[1, 2]) / (4 * r), (R[0, 2] - R[2, 0]) / (4 * r),
                      (R[1, 0] - R[0, 1]) / (4 * r)])
    elif i == 1:
        q = np.array([(R[2, 1] - R[1, 2]) / (4 * r), r, (R[0, 1] + R[1, 0]) / (4 * r),
                      (R[0, 2] + R[2, 0]) / (4 * r)])
    elif i == 2:
        q = np.array([(R[0, 2] - R[2, 0]) / (4 * r), (R[0, 1] + R[1, 0]) / (4 * r), r,
                      (R[1, 2] + R[2, 1]) / (4 * r)])
    else:
        q = np.array([(R[1, 0] - R[0, 1]) / (4 * r), (R[0, 2] + R[2, 0]) / (4 * r),
                      (R[1, 2] + R[2, 1]) / (4 * r), r])
    q = divided(q, norm(q))
    return q if q[0] >= 0 else negated(q)


# -- the calibrated closed forms of the retinal motions (on rays) --------------------------

@linked("f2 f -> f1 b", python=True)
def least_singular(A, cut: float):
    """The unit null vector of ``A`` (m, n) in least squares — the right singular vector of
    its least singular value, rows of zeros added to a system of fewer rows than columns —
    and whether it is unique (the second least above ``cut`` times the largest)."""
    m, n = A.shape
    B = np.zeros((max(m, n), n))
    for i in range(m):
        for j in range(n):
            B[i, j] = A[i, j]
    S, Vt = null_space_svd(B)
    return Vt[n - 1].copy(), S[n - 2] > cut * S[0]


@linked("f2 f1 f2 f2 -> f1", python=True)
def signed_translation(R, t, y1, y2):
    """``t`` or ``−t`` (unit), whichever puts more of the rays ``y1``, ``y2`` in front of
    both cameras for ``X2 = R X1 + t`` (:func:`best_pose`); on a tie the one whose largest
    component is positive."""
    t = divided(t, norm(t))
    if t[argmax_abs(t)] < 0:
        t = negated(t)
    Rs, ts = np.empty((2, 3, 3)), np.empty((2, 3))
    put_matrix(Rs, 0, R)
    put_matrix(Rs, 1, R)
    for i in range(3):
        ts[0, i], ts[1, i] = t[i], -t[i]
    return ts[best_pose(Rs, ts, y1, y2)].copy()


@linked("f2 f2 f -> f1 b", python=True)
def retinal_translation(y1, y2, cut: float):
    """A translation parallel to the retinal plane (``R = I``, ``tz = 0``: rectified
    stereo) through the rays: ``t · n = 0``, ``n = r1 × r2``, gives ``t ∝ (n_y, −n_x, 0)``
    from one match, the least-squares direction in the plane from more (none when it is
    not unique: :func:`least_singular` with ``cut``); the sign by cheirality. ``(t,
    found)``."""
    m = y1.shape[0]
    normals = np.empty((m, 2))
    for i in range(m):
        n = cross(y1[i], y2[i])
        normals[i, 0], normals[i, 1] = n[0], n[1]
    t = np.zeros(3)
    if m == 1:
        t[0], t[1] = normals[0, 1], -normals[0, 0]
    else:
        d, unique = least_singular(normals, cut)
        if not unique:
            return t, False
        t[0], t[1] = d[0], d[1]
    if not norm(t) > 0:
        return t, False
    return signed_translation(np.eye(3), t, y1, y2), True


@jit
def _about_the_axis(theta: float):
    """``Rz(θ)``."""
    c, s = np.cos(theta), np.sin(theta)
    R = np.zeros((3, 3))
    R[0, 0], R[0, 1], R[1, 0], R[1, 1], R[2, 2] = c, -s, s, c, 1.0
    return R


@jit
def _cross2(a0: float, a1: float, b0: float, b1: float) -> float:
    return a0 * b1 - a1 * b0


@linked("f2 f2 f -> f3 f2 i", python=True)
def retinal_displacement(y1, y2, cut: float):
    """A displacement that keeps the retinal plane, ``R = Rz(θ)`` about the optical axis and
    ``t = (tx, ty, 0)``, through the rays: ``(Rs (2, 3, 3), ts (2, 3), count)``.

    Two matches: with ``a = (x1, y1)``, ``b = J a`` (a turned by 90°), ``e = (x2, y2)``, the
    displacement ``dᵢ = c aᵢ + s bᵢ − eᵢ`` (``c, s = cos θ, sin θ``) is parallel to ``t``:
    ``d₁ × d₂ = 0``, whose ``c²``, ``s²`` and ``cs`` terms reduce to the constant
    ``a1 × a2`` — one equation ``P c + Q s = K``, two ``θ`` (one when they coincide), each
    with ``t`` along the longer displacement, its sign by cheirality. Three or more: the
    equation ``tx (s x + c y − y2) − ty (c x − s y − x2) = 0`` is linear in ``(P, Q, tx,
    ty) = (c tx + s ty, s tx − c ty, tx, ty)`` (row ``(y, x, −y2, x2)``): the least-squares
    null vector (:func:`least_singular` with ``cut``) gives ``t``, then
    ``c ∝ tx P − ty Q``, ``s ∝ ty P + tx Q``."""
    Rs, ts = np.zeros((2, 3, 3)), np.zeros((2, 3))
    m = y1.shape[0]
    if m == 2:
        a1x, a1y, a2x, a2y = y1[0, 0], y1[0, 1], y1[1, 0], y1[1, 1]
        e1x, e1y, e2x, e2y = y2[0, 0], y2[0, 1], y2[1, 0], y2[1, 1]
        b1x, b1y, b2x, b2y = -a1y, a1x, -a2y, a2x
        P = -(_cross2(a1x, a1y, e2x, e2y) + _cross2(e1x, e1y, a2x, a2y))
        Q = -(_cross2(b1x, b1y, e2x, e2y) + _cross2(e1x, e1y, b2x, b2y))
        K = -(_cross2(a1x, a1y, a2x, a2y) + _cross2(e1x, e1y, e2x, e2y))
        r = np.hypot(P, Q)
        if not r > 0 or abs(K) > r:
            return Rs, ts, 0
        phi, delta = np.arctan2(Q, P), np.arccos(min(max(K / r, -1.0), 1.0))
        count = 0
        for side in range(2):
            theta = phi + delta if side == 0 else phi - delta
            if side == 1 and theta == phi + delta:
                break
            c, s = np.cos(theta), np.sin(theta)
            d1x, d1y = c * a1x + s * b1x - e1x, c * a1y + s * b1y - e1y
            d2x, d2y = c * a2x + s * b2x - e2x, c * a2y + s * b2y - e2y
            longer = d2x * d2x + d2y * d2y > d1x * d1x + d1y * d1y
            dx, dy = (d2x, d2y) if longer else (d1x, d1y)
            if not dx * dx + dy * dy > 0:
                continue
            R = _about_the_axis(theta)
            t = np.zeros(3)
            t[0], t[1] = dx, dy
            put_matrix(Rs, count, R)
            put(ts[count], 0, signed_translation(R, t, y1, y2))
            count += 1
        return Rs, ts, count
    A = np.empty((m, 4))
    for i in range(m):
        A[i, 0], A[i, 1], A[i, 2], A[i, 3] = y1[i, 1], y1[i, 0], -y2[i, 1], y2[i, 0]
    z, unique = least_singular(A, cut)
    if not unique:
        return Rs, ts, 0
    P, Q, tx, ty = z[0], z[1], z[2], z[3]
    if not tx * tx + ty * ty > 0:
        return Rs, ts, 0
    R = _about_the_axis(np.arctan2(ty * P + tx * Q, tx * P - ty * Q))
    t = np.zeros(3)
    t[0], t[1] = tx, ty
    put_matrix(Rs, 0, R)
    put(ts[0], 0, signed_translation(R, t, y1, y2))
    return Rs, ts, 1
