"""Closed forms of two-view geometry: the starting values of the two-view family's models.

Pixel correspondences ``x1 ↔ x2`` ((N, 2) arrays), homogeneous ``p = (u, v, 1)``:

* :func:`fundamental_8point` — the normalised linear eight-point algorithm (Hartley 1997),
  ``p2ᵀ F p1 = 0``, rank 2 enforced; :func:`fundamental_7point` — the seven-point
  algorithm (up to three solutions of ``det(F) = 0``);
* :func:`homography_dlt` — the normalised direct linear transform, ``p2 ∝ H p1``;
* :func:`focal_lengths` — the two focal lengths from ``F`` and known principal points
  (Bougnoux 1998), squared, possibly negative;
* :func:`essential_poses` — the four ``(R, t)`` of an essential matrix, and
  :func:`best_pose` the one that puts the points in front of both cameras;
* :func:`homography_poses` — ``(R, t, w)`` with ``H ∝ R + t wᵀ`` for a calibrated
  homography (Faugeras & Lustman 1988; Ma et al., *An invitation to 3-D vision*, §5.3);
* unit quaternions ``(w, x, y, z)`` to and from rotation matrices.

Conventions: camera 1 at the origin, ``X2 = R X1 + t``; ``E = [t]× R``; a plane
``nᵀX1 = d`` gives ``H ∝ R + t nᵀ/d``.
"""

from __future__ import annotations

import numpy as np


def homogeneous(x: np.ndarray) -> np.ndarray:
    """(N, 2) → (N, 3) with a last coordinate 1."""
    x = np.asarray(x, dtype=float)
    out = np.ones((len(x), 3))
    out[:, :2] = x
    return out


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a × b`` of two 3-vectors: ``np.cross``'s arithmetic without its per-call overhead
    (the minimal solves of a robust search call it tens of thousands of times)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                     a[0] * b[1] - a[1] * b[0]])


def skew(v: np.ndarray) -> np.ndarray:
    """``[v]×``, the matrix of ``x ↦ v × x``."""
    x, y, z = v
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def normalising_transform(x: np.ndarray) -> np.ndarray:
    """Hartley's conditioning: centroid to the origin, mean distance √2."""
    x = np.asarray(x, dtype=float)
    centre = x.mean(axis=0)
    spread = np.sqrt(((x - centre) ** 2).sum(axis=1)).mean()
    s = np.sqrt(2.0) / spread if spread > 0 else 1.0
    return np.array([[s, 0.0, -s * centre[0]], [0.0, s, -s * centre[1]], [0.0, 0.0, 1.0]])


def _unit(M: np.ndarray) -> np.ndarray:
    norm = np.linalg.norm(M)
    return M / norm if norm > 0 else M


def _normalised(x1, x2):
    """Both views' points in Hartley's conditioning, and the two transforms."""
    T1, T2 = normalising_transform(x1), normalising_transform(x2)
    return homogeneous(x1) @ T1.T, homogeneous(x2) @ T2.T, T1, T2


def _epipolar_rows(x1, x2):
    p1, p2, T1, T2 = _normalised(x1, x2)
    return np.einsum("ni,nj->nij", p2, p1).reshape(len(p1), 9), T1, T2


def fundamental_8point(x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """The normalised eight-point fundamental matrix (N ≥ 8), unit Frobenius norm.

    Examples
    --------
    >>> from kanagen.scenes import two_view_scene
    >>> s = two_view_scene("general", n=20, sigma=0.0, seed=1)
    >>> F = fundamental_8point(s.x1, s.x2)
    >>> float(np.max(np.abs(np.einsum("ni,ij,nj->n", homogeneous(s.x2), F,
    ...                                 homogeneous(s.x1))))) < 1e-9
    True
    """
    A, T1, T2 = _epipolar_rows(x1, x2)
    if len(A) < 8:
        raise ValueError(f"the eight-point algorithm needs 8 correspondences, got {len(A)}")
    F = np.linalg.svd(A)[2][-1].reshape(3, 3)
    U, S, Vt = np.linalg.svd(F)
    F = U @ np.diag([S[0], S[1], 0.0]) @ Vt  # rank 2: the closest in Frobenius norm
    return _unit(T2.T @ F @ T1)


_ALPHAS = np.array([0.0, 1.0, -1.0, 2.0])
_CUBIC_FROM_VALUES = np.linalg.inv(np.vander(_ALPHAS, 4))  # values at _ALPHAS -> coefficients


def fundamental_7point(x1: np.ndarray, x2: np.ndarray) -> list[np.ndarray]:
    """The seven-point fundamental matrices (exactly 7 correspondences): the real roots of
    ``det(α F1 + (1 − α) F2) = 0`` on the two-dimensional null space; unit norm each."""
    A, T1, T2 = _epipolar_rows(x1, x2)
    if len(A) != 7:
        raise ValueError(f"the seven-point algorithm needs 7 correspondences, got {len(A)}")
    Vt = np.linalg.svd(A)[2]
    F1, F2 = Vt[-1].reshape(3, 3), Vt[-2].reshape(3, 3)
    # det(a F1 + (1 − a) F2) is a cubic in a: exactly interpolated from four values
    dets = np.linalg.det(_ALPHAS[:, None, None] * F1 + (1 - _ALPHAS[:, None, None]) * F2)
    coeffs = _CUBIC_FROM_VALUES @ dets
    out = []
    for root in np.roots(coeffs):
        if abs(root.imag) > 1e-8 * (1 + abs(root.real)):
            continue
        F = root.real * F1 + (1 - root.real) * F2
        out.append(_unit(T2.T @ F @ T1))
    return out


def homography_dlt(x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """The normalised DLT homography (N ≥ 4), ``p2 ∝ H p1``, unit Frobenius norm.

    Examples
    --------
    >>> from kanagen.scenes import two_view_scene
    >>> s = two_view_scene("planar", n=10, sigma=0.0, seed=1)
    >>> H = homography_dlt(s.x1, s.x2)
    >>> y = homogeneous(s.x1) @ H.T
    >>> bool(np.allclose(y[:, :2] / y[:, 2:], s.x2))
    True
    """
    x1, x2 = np.asarray(x1, dtype=float), np.asarray(x2, dtype=float)
    if len(x1) < 4:
        raise ValueError(f"the DLT needs 4 correspondences, got {len(x1)}")
    p1, p2, T1, T2 = _normalised(x1, x2)
    zero = np.zeros_like(p1)
    rows_a = np.concatenate([zero, -p2[:, 2:] * p1, p2[:, 1:2] * p1], axis=1)
    rows_b = np.concatenate([p2[:, 2:] * p1, zero, -p2[:, :1] * p1], axis=1)
    H = np.linalg.svd(np.concatenate([rows_a, rows_b]))[2][-1].reshape(3, 3)
    return _unit(np.linalg.solve(T2, H @ T1))


def epipoles(F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(e1, e2)`` with ``F e1 = 0`` and ``Fᵀ e2 = 0`` (unit vectors)."""
    U, _, Vt = np.linalg.svd(F)
    return Vt[-1], U[:, -1]


def focal_lengths(F: np.ndarray, pp1, pp2) -> tuple[float, float]:
    """Squared focal lengths ``(f1², f2²)`` of the two cameras from ``F`` (pixels), square
    pixels, no skew and the principal points ``pp1``, ``pp2`` known (Bougnoux 1998).

    Negative or infinite values say the focal length cannot be read off this ``F`` (noise,
    or a critical motion: optical axes that meet).
    """
    p1, p2 = homogeneous([pp1])[0], homogeneous([pp2])[0]
    e1, e2 = epipoles(F)

    def squared(G, e, p, p_other):
        # −(p'ᵀ [e]× Ĩ G p pᵀ Gᵀ p') / (p'ᵀ [e]× Ĩ G Ĩ Gᵀ p'), Ĩ = diag(1, 1, 0)
        a = cross(p_other, e)  # p'ᵀ [e]× as a vector: (p' × e)
        a[2] = 0.0  # … Ĩ
        aG, Gtp = a @ G, G.T @ p_other
        den = aG[0] * Gtp[0] + aG[1] * Gtp[1]
        return float(-(aG @ p) * (p @ Gtp) / den) if den != 0 else float("inf")

    return squared(F, e2, p1, p2), squared(F.T, e1, p2, p1)


def essential_poses(E: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """The four ``(R, t)`` (``t`` unit) with ``E ∝ [t]× R``."""
    U, _, Vt = np.linalg.svd(E)
    if np.linalg.det(U) < 0:
        U = -U
    if np.linalg.det(Vt) < 0:
        Vt = -Vt
    W = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    t = U[:, 2]
    return [(U @ W @ Vt, t), (U @ W @ Vt, -t), (U @ W.T @ Vt, t), (U @ W.T @ Vt, -t)]


def depths(R: np.ndarray, t: np.ndarray, y1: np.ndarray, y2: np.ndarray):
    """Depths of the points along the rays ``y1`` (camera 1) and ``y2`` (camera 2), (N, 3)
    each, triangulated by least squares for ``X2 = R X1 + t``: ``λ2 y2 ≈ λ1 R y1 + t``
    (the 2×2 normal equations, per point)."""
    a = y1 @ R.T
    aa, bb, ab = np.sum(a * a, 1), np.sum(y2 * y2, 1), np.sum(a * y2, 1)
    at, bt = a @ t, y2 @ t
    det = aa * bb - ab * ab
    with np.errstate(all="ignore"):
        lam1 = (-bb * at + ab * bt) / det
        lam2 = (ab * at - aa * bt) / -det
    return lam1, lam2


def best_pose(poses, y1: np.ndarray, y2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The pose that puts most points in front of both cameras (cheirality). A tie (a
    sample of outliers, say) goes to the smaller rotation (the larger trace), then to the
    ``t`` whose largest component is positive: the order of ``poses`` follows the SVD's
    arbitrary basis, the choice does not."""
    seen: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []

    def key(pose):
        R, t = pose
        for R0, t0, d1, d2 in seen:  # (R, −t) of a pose done: its depths negated, exactly
            if np.array_equal(R, R0) and np.array_equal(t, -t0):
                front = np.count_nonzero((d1 < 0) & (d2 < 0))
                break
        else:
            d1, d2 = depths(R, t, y1, y2)
            seen.append((R, t, d1, d2))
            front = np.count_nonzero((d1 > 0) & (d2 > 0))
        return (int(front), float(np.trace(R)), float(np.sign(t[int(np.argmax(np.abs(t)))])))

    return max(poses, key=key)


def nearest_essential(E: np.ndarray) -> np.ndarray:
    """The closest matrix with singular values (1, 1, 0)."""
    U, _, Vt = np.linalg.svd(E)
    return U @ np.diag([1.0, 1.0, 0.0]) @ Vt


def homography_poses(H: np.ndarray, y1: np.ndarray | None = None,
                     y2: np.ndarray | None = None) -> list[tuple[np.ndarray, ...]]:
    """``(R, t, w)`` with ``H ∝ R + t wᵀ`` (``t`` unit) for a calibrated homography.

    Four solutions; with the rays ``y1``, ``y2`` of the correspondences, only those that
    see the plane in front of camera 1 (``wᵀ y1 > 0``: ``w`` is the plane's normal over its
    distance, and a point ``λ y1`` on it has ``λ > 0``) are kept, two in general. A pure
    rotation (``H ∝ R``) gives ``w = 0`` and an arbitrary ``t``.
    """
    H = np.asarray(H, dtype=float)
    H = H / np.linalg.svd(H, compute_uv=False)[1]
    if y1 is not None and y2 is not None:
        # the sign that gives positive depths, λ2 y2 = H y1 with λ2 > 0: the same for H and
        # −H (the DLT's sign is arbitrary), det(H) only when the depths do not decide
        total = np.sum(np.einsum("ni,ij,nj->n", y2, H, y1))
        flip = total < 0 or total == 0 and np.linalg.det(H) < 0
    else:
        flip = np.linalg.det(H) < 0
    if flip:
        H = -H
    w2, V = np.linalg.eigh(H.T @ H)
    w2, V = w2[::-1], V[:, ::-1]
    if np.linalg.det(V) < 0:
        V = -V
    s1, s3 = w2[0], w2[2]
    if s1 - s3 < 1e-12:
        U, _, Vt = np.linalg.svd(H)
        R = U @ Vt
        return [(R * np.sign(np.linalg.det(R)), np.array([0.0, 0.0, 1.0]), np.zeros(3))]
    v1, v2, v3 = V.T
    a, b = np.sqrt(max(1.0 - s3, 0.0)), np.sqrt(max(s1 - 1.0, 0.0))
    out = []
    for u in ((a * v1 + b * v3) / np.sqrt(s1 - s3), (a * v1 - b * v3) / np.sqrt(s1 - s3)):
        n = cross(v2, u)
        U = np.column_stack([v2, u, n])
        Hv2, Hu = H @ v2, H @ u
        W = np.column_stack([Hv2, Hu, cross(Hv2, Hu)])
        R = W @ U.T
        T = (H - R) @ n  # H = R + T nᵀ (d = 1)
        for sign in (1.0, -1.0):
            scale = np.linalg.norm(T)
            t, w = sign * T / scale, sign * n * scale
            out.append((R, t, w))
    if y1 is not None:
        front = [p for p in out if np.mean(y1 @ p[2] > 0) > 0.5]
        out = front or out
    return out


def rotation_from_pairs(a1, a2, b1, b2) -> np.ndarray | None:
    """The rotation with ``R â1 = b̂1`` and ``R (a1 × a2) ∝ b1 × b2`` (the triad method:
    ``R = B Aᵀ``, ``A = [e1, e2, e1 × e2]``, ``e1 = â1``, ``e2 = unit(a1 × a2)``); None when a
    pair is parallel."""
    triads = []
    for u, v in ((a1, a2), (b1, b2)):
        n = cross(u, v)
        nu, nn = np.sqrt(u @ u), np.sqrt(n @ n)
        if not (nu > 0 and nn > 0):
            return None
        e1, e2 = u / nu, n / nn
        triads.append(np.column_stack([e1, e2, cross(e1, e2)]))
    return triads[1] @ triads[0].T


def quaternion_from_rotation(R: np.ndarray) -> np.ndarray:
    """Unit quaternion ``(w, x, y, z)``, ``w >= 0`` (Shepperd's method)."""
    R = np.asarray(R, dtype=float)
    tr = np.trace(R)
    cands = np.array([1 + tr, 1 + 2 * R[0, 0] - tr, 1 + 2 * R[1, 1] - tr, 1 + 2 * R[2, 2] - tr])
    i = int(np.argmax(cands))
    r = np.sqrt(max(cands[i], 0.0)) / 2
    if i == 0:
        q = [r, (R[2, 1] - R[1, 2]) / (4 * r), (R[0, 2] - R[2, 0]) / (4 * r),
             (R[1, 0] - R[0, 1]) / (4 * r)]
    elif i == 1:
        q = [(R[2, 1] - R[1, 2]) / (4 * r), r, (R[0, 1] + R[1, 0]) / (4 * r),
             (R[0, 2] + R[2, 0]) / (4 * r)]
    elif i == 2:
        q = [(R[0, 2] - R[2, 0]) / (4 * r), (R[0, 1] + R[1, 0]) / (4 * r), r,
             (R[1, 2] + R[2, 1]) / (4 * r)]
    else:
        q = [(R[1, 0] - R[0, 1]) / (4 * r), (R[0, 2] + R[2, 0]) / (4 * r),
             (R[1, 2] + R[2, 1]) / (4 * r), r]
    q = np.array(q)
    q /= np.linalg.norm(q)
    return q if q[0] >= 0 else -q


def rotation_from_quaternion(q) -> np.ndarray:
    """Rotation matrix of the quaternion ``(w, x, y, z)`` (normalised first)."""
    w, x, y, z = np.asarray(q, dtype=float) / np.linalg.norm(q)
    return np.array([
        [w * w + x * x - y * y - z * z, 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), w * w - x * x + y * y - z * z, 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), w * w - x * x - y * y + z * z],
    ])


def rotation_about(axis, angle: float) -> np.ndarray:
    """Rotation of ``angle`` radians about ``axis`` (Rodrigues)."""
    axis = np.asarray(axis, dtype=float)
    axis = axis / np.linalg.norm(axis)
    K = skew(axis)
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K
