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

The closed forms are compiled kernels (:mod:`~kanagen.runtime.two_view_kernels`, the one
source the two-view initialisers run too); the functions here take and return NumPy arrays
and lists, and check their inputs. :func:`homogeneous`, :func:`skew` and the rotations of a
quaternion or an axis stay NumPy (no initialiser uses them).
"""

from __future__ import annotations

import numpy as np

from . import numpy_rules
from . import two_view_kernels as kernels


def homogeneous(x: np.ndarray) -> np.ndarray:
    """(N, 2) → (N, 3) with a last coordinate 1."""
    x = np.asarray(x, dtype=float)
    out = np.ones((len(x), 3))
    out[:, :2] = x
    return out


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a × b`` of two 3-vectors: ``np.cross``'s arithmetic without its per-call overhead
    (the minimal solves of a robust search call it tens of thousands of times)."""
    return numpy_rules.cross(_vector(a), _vector(b))


def skew(v: np.ndarray) -> np.ndarray:
    """``[v]×``, the matrix of ``x ↦ v × x``."""
    x, y, z = v
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def _vector(v) -> np.ndarray:
    return np.ascontiguousarray(v, dtype=float)


def _matrix(M) -> np.ndarray:
    return np.ascontiguousarray(M, dtype=float)


def _matches(x1, x2) -> np.ndarray:
    """The correspondences as the kernels read them: rows ``(x1, y1, x2, y2)``."""
    return np.ascontiguousarray(np.concatenate(
        [np.asarray(x1, dtype=float), np.asarray(x2, dtype=float)], axis=1))


def normalising_transform(x: np.ndarray) -> np.ndarray:
    """Hartley's conditioning: centroid to the origin, mean distance √2."""
    return kernels.normalising_transform(_matrix(x), 0)


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
    X = _matches(x1, x2)
    if len(X) < 8:
        raise ValueError(f"the eight-point algorithm needs 8 correspondences, got {len(X)}")
    return kernels.fundamental_8point(X)


def fundamental_7point(x1: np.ndarray, x2: np.ndarray) -> list[np.ndarray]:
    """The seven-point fundamental matrices (exactly 7 correspondences): the real roots of
    ``det(α F1 + (1 − α) F2) = 0`` on the two-dimensional null space; unit norm each."""
    X = _matches(x1, x2)
    if len(X) != 7:
        raise ValueError(f"the seven-point algorithm needs 7 correspondences, got {len(X)}")
    Fs, count = kernels.fundamental_7point(X)
    return list(Fs[:count])


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
    X = _matches(x1, x2)
    if len(X) < 4:
        raise ValueError(f"the DLT needs 4 correspondences, got {len(X)}")
    return kernels.homography_dlt(X)


def epipoles(F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(e1, e2)`` with ``F e1 = 0`` and ``Fᵀ e2 = 0`` (unit vectors)."""
    return kernels.epipoles(_matrix(F))


def focal_lengths(F: np.ndarray, pp1, pp2) -> tuple[float, float]:
    """Squared focal lengths ``(f1², f2²)`` of the two cameras from ``F`` (pixels), square
    pixels, no skew and the principal points ``pp1``, ``pp2`` known (Bougnoux 1998).

    Negative or infinite values say the focal length cannot be read off this ``F`` (noise,
    or a critical motion: optical axes that meet).
    """
    return kernels.focal_lengths(_matrix(F), homogeneous([pp1])[0], homogeneous([pp2])[0])


def essential_poses(E: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """The four ``(R, t)`` (``t`` unit) with ``E ∝ [t]× R``."""
    Rs, ts = kernels.essential_poses(_matrix(E))
    return list(zip(Rs, ts, strict=True))


def depths(R: np.ndarray, t: np.ndarray, y1: np.ndarray, y2: np.ndarray):
    """Depths of the points along the rays ``y1`` (camera 1) and ``y2`` (camera 2), (N, 3)
    each, triangulated by least squares for ``X2 = R X1 + t``: ``λ2 y2 ≈ λ1 R y1 + t``
    (the 2×2 normal equations, per point)."""
    return kernels.depths(_matrix(R), _vector(t), _matrix(y1), _matrix(y2))


def best_pose(poses, y1: np.ndarray, y2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The pose that puts most points in front of both cameras (cheirality). A tie (a
    sample of outliers, say) goes to the smaller rotation (the larger trace), then to the
    ``t`` whose largest component is positive: the order of ``poses`` follows the SVD's
    arbitrary basis, the choice does not."""
    poses = list(poses)
    if not poses:
        raise ValueError("best_pose of no pose")
    Rs = np.array([np.asarray(R, dtype=float) for R, _ in poses], dtype=float)
    ts = np.array([np.asarray(t, dtype=float) for _, t in poses], dtype=float)
    return poses[kernels.best_pose(Rs, ts, _matrix(y1), _matrix(y2))]


def nearest_essential(E: np.ndarray) -> np.ndarray:
    """The closest matrix with singular values (1, 1, 0)."""
    return kernels.nearest_essential(_matrix(E))


def homography_poses(H: np.ndarray, y1: np.ndarray | None = None,
                     y2: np.ndarray | None = None) -> list[tuple[np.ndarray, ...]]:
    """``(R, t, w)`` with ``H ∝ R + t wᵀ`` (``t`` unit) for a calibrated homography.

    Four solutions; with the rays ``y1``, ``y2`` of the correspondences, only those that
    see the plane in front of camera 1 (``wᵀ y1 > 0``: ``w`` is the plane's normal over its
    distance, and a point ``λ y1`` on it has ``λ > 0``) are kept, two in general. A pure
    rotation (``H ∝ R``) gives ``w = 0`` and an arbitrary ``t``.
    """
    none = np.zeros((0, 3))
    # the sign that gives positive depths, λ2 y2 = H y1 with λ2 > 0: the same for H and −H
    # (the DLT's sign is arbitrary), det(H) only when the depths do not decide
    Rs, ts, ws, count = kernels.homography_poses(
        _matrix(H), none if y1 is None else _matrix(y1), none if y2 is None else _matrix(y2),
        y1 is not None and y2 is not None, y1 is not None)
    return list(zip(Rs[:count], ts[:count], ws[:count], strict=True))


def rotation_from_pairs(a1, a2, b1, b2) -> np.ndarray | None:
    """The rotation with ``R â1 = b̂1`` and ``R (a1 × a2) ∝ b1 × b2`` (the triad method:
    ``R = B Aᵀ``, ``A = [e1, e2, e1 × e2]``, ``e1 = â1``, ``e2 = unit(a1 × a2)``); None when
    a pair is parallel."""
    R, found = kernels.rotation_from_pairs(_vector(a1), _vector(a2), _vector(b1), _vector(b2))
    return R if found else None


def quaternion_from_rotation(R: np.ndarray) -> np.ndarray:
    """Unit quaternion ``(w, x, y, z)``, ``w >= 0`` (Shepperd's method)."""
    return kernels.quaternion_from_rotation(_matrix(R))


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
