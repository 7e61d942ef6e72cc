"""The two-view closed forms as they were in NumPy (runtime/geometry.py and the four
initialisers of runtime/two_view_starts.py with a compiled twin, at commit 69e0490): the
reference the compiled kernels (runtime/two_view_kernels.py, runtime/two_view_twins.py) are
held to in tests/test_two_view_kernels.py.

Kept verbatim (the test-only reference, as tests/reference_kernels.py is the engine's): the
kernels give its candidates to rounding on every sample but the degenerate ones, where its
candidates come from LAPACK's arbitrary basis of a null space and the kernels give none.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

Candidates = list[dict[str, float]]
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




_TWO_VIEW_Q = ("f1", "f2", "qw", "qx", "qy", "qz", "tx", "ty", "tz", "wx", "wy", "wz")
_FOCAL_RANGE = (0.1, 10.0)  # focal lengths (× f0) read off F outside this range are noise
_DEGENERATE = 1e-6  # a singular value below this fraction of the largest is taken as zero


def _rays(X: np.ndarray, k: Mapping[str, float], f1: float = 1.0, f2: float = 1.0):
    """Pixel matches → rays (x, y, f) in the normalised coordinates of the family."""
    cx, cy, f0 = k["cx"], k["cy"], k["f0"]
    y1, y2 = np.empty((len(X), 3)), np.empty((len(X), 3))
    y1[:, 0], y1[:, 1], y1[:, 2] = (X[:, 0] - cx) / f0, (X[:, 1] - cy) / f0, f1
    y2[:, 0], y2[:, 1], y2[:, 2] = (X[:, 2] - cx) / f0, (X[:, 3] - cy) / f0, f2
    return y1, y2


def _pose_params(R: np.ndarray, t: np.ndarray) -> dict[str, float]:
    q = quaternion_from_rotation(R)
    return {"qw": q[0], "qx": q[1], "qy": q[2], "qz": q[3],
            "tx": t[0], "ty": t[1], "tz": t[2]}


def two_view_fundamental(X: np.ndarray, k: Mapping[str, float]) -> Candidates:
    """``F`` by the seven-point (7 matches) or normalised eight-point algorithm (more), the
    focal lengths read off it (Bougnoux), then ``R, t`` from the essential matrix, chosen
    by cheirality. An ``F`` whose focal lengths are imaginary or out of range has no
    physical parameter through the sample: it gives no candidate."""
    X = np.asarray(X, dtype=float)
    if len(X) < 7 or not np.all(np.isfinite(X)):
        return []
    x1, x2 = X[:, :2], X[:, 2:4]
    f0 = k["f0"]
    try:
        Fs = fundamental_7point(x1, x2) if len(X) == 7 else [fundamental_8point(x1, x2)]
        out = []
        for F in Fs:
            sq1, sq2 = focal_lengths(F, (k["cx"], k["cy"]), (k["cx"], k["cy"]))
            f1, f2 = np.sqrt(max(sq1, 0.0)) / f0, np.sqrt(max(sq2, 0.0)) / f0
            if not all(_FOCAL_RANGE[0] < f < _FOCAL_RANGE[1] for f in (f1, f2)):
                continue
            # F ∝ Tᵀ diag(1, 1, f2) E diag(1, 1, f1) T with T the pixel -> normalised map
            T = np.array([[1 / f0, 0, -k["cx"] / f0], [0, 1 / f0, -k["cy"] / f0], [0, 0, 1]])
            Tinv = np.linalg.inv(T)
            E = np.diag([1.0, 1.0, 1 / f2]) @ Tinv.T @ F @ Tinv @ np.diag([1.0, 1.0, 1 / f1])
            y1, y2 = _rays(X, k, f1, f2)
            R, t = best_pose(essential_poses(nearest_essential(E)), y1, y2)
            out.append({"f1": f1, "f2": f2, **_pose_params(R, t)})
        return out
    except (np.linalg.LinAlgError, ValueError, ZeroDivisionError):
        return []


def two_view_homography(X: np.ndarray, k: Mapping[str, float]) -> Candidates:
    """``H`` by the normalised DLT (4 matches or more), then ``(R, t, w)`` with
    ``H ∝ R + t wᵀ`` at the nominal focal length (the planar model's), in front of
    camera 1; each of the (two) decompositions is a candidate."""
    X = np.asarray(X, dtype=float)
    if len(X) < 4 or not np.all(np.isfinite(X)):
        return []
    try:
        H = homography_dlt(X[:, :2], X[:, 2:4])
        f0 = k["f0"]
        T = np.array([[1 / f0, 0, -k["cx"] / f0], [0, 1 / f0, -k["cy"] / f0], [0, 0, 1]])
        Hn = T @ H @ np.linalg.inv(T)
        y1, y2 = _rays(X, k)
        return [{"f1": 1.0, "f2": 1.0, **_pose_params(R, t), "wx": w[0], "wy": w[1],
                 "wz": w[2]} for R, t, w in homography_poses(Hn, y1, y2)]
    except (np.linalg.LinAlgError, ValueError, ZeroDivisionError):
        return []


def _kabsch(y1: np.ndarray, y2: np.ndarray) -> np.ndarray | None:
    """The rotation that best maps the unit rays ``ŷ1`` onto ``ŷ2`` (least squares, Kabsch:
    ``Σ ŷ2 ŷ1ᵀ = U S Vᵀ``, ``R = u1 v1ᵀ + u2 v2ᵀ + (u1 × u2)(v1 × v2)ᵀ``, det +1); None when
    the rays do not fix it (``σ2`` negligible)."""
    a = y1 / np.sqrt(np.sum(y1 * y1, 1))[:, None]
    b = y2 / np.sqrt(np.sum(y2 * y2, 1))[:, None]
    U, S, Vt = np.linalg.svd(b.T @ a)
    if not S[1] > _DEGENERATE * S[0]:
        return None
    u1, u2, v1, v2 = U[:, 0], U[:, 1], Vt[0], Vt[1]
    return np.outer(u1, v1) + np.outer(u2, v2) + np.outer(cross(u1, u2), cross(v1, v2))


def _in_focal_range(F: float) -> bool:
    return F > 0 and _FOCAL_RANGE[0] < np.sqrt(F) < _FOCAL_RANGE[1]


def _rotation_candidate(f: float, R: np.ndarray) -> dict[str, float]:
    q = quaternion_from_rotation(R)
    return {"f1": f, "f2": f, "qw": q[0], "qx": q[1], "qy": q[2], "qz": q[3]}


def two_view_rotation(X: np.ndarray, k: Mapping[str, float]) -> Candidates:
    """A rotation about the optical centre with an unknown common focal length (the
    rotation model: ``r2 ∝ R r1``, ``r = (x, y, f)``).

    Two matches (a minimal sample): a rotation keeps the angle between rays, so with
    ``F = f²``, ``p, q`` the dot products of the two first-view and of the two second-view
    image vectors ``(x, y)``, ``s_i, t_i`` their squared norms,
    ``(p + F)² (t1 + F)(t2 + F) = (q + F)² (s1 + F)(s2 + F)`` — its ``F⁴`` terms cancel: a
    cubic. Each real root with ``f = √F`` in the focal range and the cosines of the same
    sign (``a1·a2`` and ``b1·b2``) gives ``R`` exactly by the triad of the two ray pairs:
    one candidate per admissible root, each an exact solution of the sample.

    Four matches or more (the refinement on the inliers): least squares in closed form —
    the DLT homography ``Hn ∝ K R K⁻¹`` (``K = diag(f, f, 1)``) scaled to ``det Hn = 1``
    gives ``Hn ω Hnᵀ = ω``, ``ω = diag(F, F, 1)``, six linear equations in ``F`` (Hartley's
    self-calibration of a rotating camera) solved by least squares; then ``R`` by Kabsch
    on the unit rays at that ``f``. One candidate, near the optimum on good data; the
    refinement polishes it. Three matches: no closed form here (``[]``).
    """
    X = np.asarray(X, dtype=float)
    if len(X) < 2 or len(X) == 3 or not np.all(np.isfinite(X)):
        return []
    try:
        if len(X) > 3:
            H = homography_dlt(X[:, :2], X[:, 2:4])
            f0 = k["f0"]
            T = np.array([[1 / f0, 0, -k["cx"] / f0], [0, 1 / f0, -k["cy"] / f0], [0, 0, 1]])
            Hn = T @ H @ np.linalg.inv(T)
            det = np.linalg.det(Hn)
            if not det != 0:
                return []
            Hn = Hn / np.cbrt(det)
            h1, h2, h3 = Hn[:, 0], Hn[:, 1], Hn[:, 2]
            A = np.outer(h1, h1) + np.outer(h2, h2) - np.diag([1.0, 1.0, 0.0])
            B = np.diag([0.0, 0.0, 1.0]) - np.outer(h3, h3)
            den = np.sum(A * A)
            F = float(np.sum(A * B) / den) if den > 0 else -1.0
            if not _in_focal_range(F):
                return []
            f = float(np.sqrt(F))
            y1, y2 = _rays(X, k, f, f)
            R = _kabsch(y1, y2)
            return [] if R is None else [_rotation_candidate(f, R)]
        y1, y2 = _rays(X, k, 0.0, 0.0)  # the image vectors (x, y, 0)
        p, q = y1[0] @ y1[1], y2[0] @ y2[1]
        s1, s2, t1, t2 = y1[0] @ y1[0], y1[1] @ y1[1], y2[0] @ y2[0], y2[1] @ y2[1]
        # (p + F)² (t1 + F)(t2 + F) − (q + F)² (s1 + F)(s2 + F), highest power first
        cubic = [t1 + t2 + 2 * p - s1 - s2 - 2 * q,
                 t1 * t2 + 2 * p * (t1 + t2) + p * p - s1 * s2 - 2 * q * (s1 + s2) - q * q,
                 2 * p * t1 * t2 + p * p * (t1 + t2) - 2 * q * s1 * s2 - q * q * (s1 + s2),
                 p * p * t1 * t2 - q * q * s1 * s2]
        if not any(cubic):
            return []
        out = []
        for root in np.roots(cubic):
            if abs(root.imag) > 1e-8 * (1 + abs(root.real)):
                continue
            F = float(root.real)
            if not _in_focal_range(F) or (p + F > 0) != (q + F > 0):
                continue
            f = float(np.sqrt(F))
            y1[:, 2], y2[:, 2] = f, f
            R = rotation_from_pairs(y1[0], y1[1], y2[0], y2[1])
            if R is not None:
                out.append(_rotation_candidate(f, R))
        return out
    except (np.linalg.LinAlgError, ValueError, ZeroDivisionError):
        return []


def two_view_translation(X: np.ndarray, k: Mapping[str, float]) -> Candidates:
    """A translation at the nominal focal length (the translation model: ``R = I``,
    ``f1 = f2 = 1``, ``‖t‖ = 1``). Each match gives ``t · (r1 × r2) = 0``: two matches fix
    ``t = unit(n1 × n2)``, ``n_i = r1_i × r2_i``; more matches the least-squares ``t``, the
    right singular vector of the least singular value of the stacked ``n_i`` (none when
    the second least is negligible: the null space is larger). Its sign is first made
    canonical (largest component positive), then chosen by cheirality (the more points in
    front of both cameras; ``t`` itself on a tie). One candidate."""
    X = np.asarray(X, dtype=float)
    if len(X) < 2 or not np.all(np.isfinite(X)):
        return []
    y1, y2 = _rays(X, k)
    n = np.cross(y1, y2)
    if len(X) == 2:
        t = cross(n[0], n[1])
    else:
        try:
            _, S, Vt = np.linalg.svd(n)
        except np.linalg.LinAlgError:
            return []
        if not S[1] > _DEGENERATE * S[0]:
            return []
        t = Vt[2]
    norm = np.sqrt(t @ t)
    if not (norm > 0 and np.isfinite(norm)):
        return []
    t = t / norm
    if t[int(np.argmax(np.abs(t)))] < 0:
        t = -t
    t = best_pose([(np.eye(3), t), (np.eye(3), -t)], y1, y2)[1]
    return [{"tx": t[0], "ty": t[1], "tz": t[2]}]


# -- compiled on 2026-11-28: the zoom and the retinal motions' closed forms as they were in
# NumPy (runtime/two_view_starts.py: two_view_zoom; runtime/calibrated_starts.py at commit
# d107b8e: the retinal ones, which two_view_retinal_translation and
# two_view_retinal_displacement called with the nominal camera) ------------------------------

_DEGENERATE_CALIBRATED = 1e-9


def _calibrated_rays(X: np.ndarray, k: Mapping[str, float]) -> tuple[np.ndarray, np.ndarray]:
    X = np.asarray(X, dtype=float)
    y1, y2 = np.ones((len(X), 3)), np.ones((len(X), 3))
    y1[:, 0], y1[:, 1] = (X[:, 0] - k["cx1"]) / k["fx1"], (X[:, 1] - k["cy1"]) / k["fy1"]
    y2[:, 0], y2[:, 1] = (X[:, 2] - k["cx2"]) / k["fx2"], (X[:, 3] - k["cy2"]) / k["fy2"]
    return y1, y2


def _calibrated_pose_params(R: np.ndarray, t: np.ndarray) -> dict[str, float]:
    q = quaternion_from_rotation(R)
    t = np.asarray(t, dtype=float) / np.linalg.norm(t)
    return {"qw": q[0], "qx": q[1], "qy": q[2], "qz": q[3],
            "tx": t[0], "ty": t[1], "tz": t[2]}


def _as_calibrated(k: Mapping[str, float]) -> dict[str, float]:
    f0, cx, cy = k["f0"], k["cx"], k["cy"]
    return {"fx1": f0, "fy1": f0, "cx1": cx, "cy1": cy,
            "fx2": f0, "fy2": f0, "cx2": cx, "cy2": cy}


def _signed(R: np.ndarray, t: np.ndarray, y1: np.ndarray, y2: np.ndarray) -> np.ndarray:
    """``t`` or ``−t`` (unit), whichever puts more points in front of both cameras (the
    sign that makes the largest component positive on a tie)."""
    t = t / np.linalg.norm(t)
    if t[int(np.argmax(np.abs(t)))] < 0:
        t = -t
    return best_pose([(R, t), (R, -t)], y1, y2)[1]


def _least_singular(A: np.ndarray) -> np.ndarray | None:
    """The unit null vector of ``A`` in least squares; None when it is not unique."""
    if len(A) < A.shape[1]:
        A = np.r_[A, np.zeros((A.shape[1] - len(A), A.shape[1]))]
    _, S, Vt = np.linalg.svd(A)
    if not S[-2] > _DEGENERATE_CALIBRATED * S[0]:
        return None
    return Vt[-1]


def _rz(theta: float) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _cross2(a, b) -> float:
    return float(a[0] * b[1] - a[1] * b[0])


def _displacement_pair(y1: np.ndarray, y2: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """The (at most two) ``(Rz(θ), t)`` through two matches. With ``a = (x1, y1)``,
    ``b = J a`` (a turned by 90°), ``e = (x2, y2)``, the displacement ``dᵢ = c aᵢ + s bᵢ − eᵢ``
    (``c, s = cos θ, sin θ``) is parallel to ``t``: ``dₗ × d₂ = 0``, whose ``c²``, ``s²`` and
    ``cs`` terms reduce to the constant ``a1 × a2`` — one equation ``P c + Q s = K``."""
    a1, a2, e1, e2 = y1[0, :2], y1[1, :2], y2[0, :2], y2[1, :2]
    b1, b2 = np.array([-a1[1], a1[0]]), np.array([-a2[1], a2[0]])
    P = -(_cross2(a1, e2) + _cross2(e1, a2))
    Q = -(_cross2(b1, e2) + _cross2(e1, b2))
    K = -(_cross2(a1, a2) + _cross2(e1, e2))
    r = np.hypot(P, Q)
    if not r > 0 or abs(K) > r:
        return []
    phi, delta = np.arctan2(Q, P), np.arccos(np.clip(K / r, -1.0, 1.0))
    out = []
    for theta in dict.fromkeys((phi + delta, phi - delta)):
        c, s = np.cos(theta), np.sin(theta)
        d = [c * a + s * b - e for a, b, e in ((a1, b1, e1), (a2, b2, e2))]
        d = max(d, key=lambda v: float(v @ v))
        if not d @ d > 0:
            continue
        R = _rz(theta)
        out.append((R, _signed(R, np.array([d[0], d[1], 0.0]), y1, y2)))
    return out


def calibrated_retinal_translation(X: np.ndarray, k: Mapping[str, float]) -> Candidates:
    """A translation parallel to the retinal plane (``R = I``, ``tz = 0``: rectified
    stereo): ``t · n = 0`` with ``n = r1 × r2`` gives ``t ∝ (n_y, −n_x, 0)`` from one match,
    the least-squares direction in the plane from more; the sign by cheirality."""
    X = np.asarray(X, dtype=float)
    if len(X) < 1 or not np.all(np.isfinite(X)):
        return []
    try:
        y1, y2 = _calibrated_rays(X, k)
        n = np.cross(y1, y2)[:, :2]
        if len(X) == 1:
            d = np.array([n[0, 1], -n[0, 0]])
        else:
            d = _least_singular(n)
            if d is None:
                return []
        t = np.array([d[0], d[1], 0.0])
        if not np.linalg.norm(t) > 0:
            return []
        t = _signed(np.eye(3), t, y1, y2)
        return [{"tx": t[0], "ty": t[1], "tz": 0.0}]
    except (np.linalg.LinAlgError, ValueError, ZeroDivisionError, FloatingPointError):
        return []


def calibrated_retinal_displacement(X: np.ndarray, k: Mapping[str, float]) -> Candidates:
    """A displacement that keeps the retinal plane: ``R = Rz(θ)`` about the optical axis and
    ``t = (tx, ty, 0)``. Two matches: the two ``θ`` of :func:`_displacement_pair`, each with
    ``t`` along the displacement. Three or more: the equation
    ``tx (s x + c y − y2) − ty (c x − s y − x2) = 0`` is linear in
    ``(P, Q, tx, ty) = (c tx + s ty, s tx − c ty, tx, ty)`` (row ``(y, x, −y2, x2)``): the
    least-squares null vector gives ``t``, then ``c ∝ tx P − ty Q``, ``s ∝ ty P + tx Q``."""
    X = np.asarray(X, dtype=float)
    if len(X) < 2 or not np.all(np.isfinite(X)):
        return []
    try:
        y1, y2 = _calibrated_rays(X, k)
        if len(X) == 2:
            poses = _displacement_pair(y1, y2)
        else:
            x, y, x2, yy2 = y1[:, 0], y1[:, 1], y2[:, 0], y2[:, 1]
            z = _least_singular(np.column_stack([y, x, -yy2, x2]))
            if z is None:
                return []
            P, Q, tx, ty = z
            if not tx * tx + ty * ty > 0:
                return []
            R = _rz(np.arctan2(ty * P + tx * Q, tx * P - ty * Q))
            poses = [(R, _signed(R, np.array([tx, ty, 0.0]), y1, y2))]
        return [{**_calibrated_pose_params(R, t), "qx": 0.0, "qy": 0.0, "tz": 0.0}
                for R, t in poses]
    except (np.linalg.LinAlgError, ValueError, ZeroDivisionError, FloatingPointError):
        return []


def two_view_zoom(X: np.ndarray, k: Mapping[str, float]) -> Candidates:
    """A zoom about the principal point (the zoom model: ``R = I``, ``f1 = 1``, no
    translation): each match's rays are parallel, ``r2 = f2 r1`` in the image plane
    (``x2 = f2 x1`` in the normalised coordinates), so ``f2`` is the least-squares ratio
    ``Σ x1·x2 / Σ x1·x1`` over the matches; none when the matches sit on the principal
    point or the ratio is out of the focal range. One candidate."""
    X = np.asarray(X, dtype=float)
    if len(X) < 1 or not np.all(np.isfinite(X)):
        return []
    y1, y2 = _rays(X, k)
    norm = float(np.sum(y1[:, :2] * y1[:, :2]))
    if not norm > 0.0:
        return []
    f2 = float(np.sum(y1[:, :2] * y2[:, :2])) / norm
    return [{"f2": f2}] if _FOCAL_RANGE[0] < f2 < _FOCAL_RANGE[1] else []


def two_view_retinal_translation(X: np.ndarray, k: Mapping[str, float]) -> Candidates:
    return calibrated_retinal_translation(X, _as_calibrated(k))


def two_view_retinal_displacement(X: np.ndarray, k: Mapping[str, float]) -> Candidates:
    return calibrated_retinal_displacement(X, _as_calibrated(k))
