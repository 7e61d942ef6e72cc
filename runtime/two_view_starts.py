"""The two-view closed forms: starting values of the two-view family's minimal solves
(report eq. 21), a plugin of the initializer registry (:mod:`~kanagen.runtime.initializers`).

``two_view_fundamental`` (seven- or eight-point ``F``, focal lengths, pose),
``two_view_homography`` (DLT ``H``, its two poses), ``two_view_rotation``,
``two_view_translation`` and ``two_view_zoom``, on the epipolar geometry of
:mod:`~kanagen.runtime.geometry`.
Importing this module registers them (:func:`~kanagen.runtime.initializers.register`); the
registry imports it the first time one of their names is looked up
(:data:`~kanagen.runtime.initializers.PROVIDERS`), so a family whose models name none of them
(conic, line, ...) loads neither this module nor the geometry. The family's compiled library
holds their C twins (codegen/c/kanagen_geometry.c, docs/fastpath.md) only when one of its
models names one of them.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from . import geometry as g
from .initializers import Candidates, Initializer, register

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
    q = g.quaternion_from_rotation(R)
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
        Fs = g.fundamental_7point(x1, x2) if len(X) == 7 else [g.fundamental_8point(x1, x2)]
        out = []
        for F in Fs:
            sq1, sq2 = g.focal_lengths(F, (k["cx"], k["cy"]), (k["cx"], k["cy"]))
            f1, f2 = np.sqrt(max(sq1, 0.0)) / f0, np.sqrt(max(sq2, 0.0)) / f0
            if not all(_FOCAL_RANGE[0] < f < _FOCAL_RANGE[1] for f in (f1, f2)):
                continue
            # F ∝ Tᵀ diag(1, 1, f2) E diag(1, 1, f1) T with T the pixel -> normalised map
            T = np.array([[1 / f0, 0, -k["cx"] / f0], [0, 1 / f0, -k["cy"] / f0], [0, 0, 1]])
            Tinv = np.linalg.inv(T)
            E = np.diag([1.0, 1.0, 1 / f2]) @ Tinv.T @ F @ Tinv @ np.diag([1.0, 1.0, 1 / f1])
            y1, y2 = _rays(X, k, f1, f2)
            R, t = g.best_pose(g.essential_poses(g.nearest_essential(E)), y1, y2)
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
        H = g.homography_dlt(X[:, :2], X[:, 2:4])
        f0 = k["f0"]
        T = np.array([[1 / f0, 0, -k["cx"] / f0], [0, 1 / f0, -k["cy"] / f0], [0, 0, 1]])
        Hn = T @ H @ np.linalg.inv(T)
        y1, y2 = _rays(X, k)
        return [{"f1": 1.0, "f2": 1.0, **_pose_params(R, t), "wx": w[0], "wy": w[1],
                 "wz": w[2]} for R, t, w in g.homography_poses(Hn, y1, y2)]
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
    return np.outer(u1, v1) + np.outer(u2, v2) + np.outer(g.cross(u1, u2), g.cross(v1, v2))


def _in_focal_range(F: float) -> bool:
    return F > 0 and _FOCAL_RANGE[0] < np.sqrt(F) < _FOCAL_RANGE[1]


def _rotation_candidate(f: float, R: np.ndarray) -> dict[str, float]:
    q = g.quaternion_from_rotation(R)
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
            H = g.homography_dlt(X[:, :2], X[:, 2:4])
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
            R = g.rotation_from_pairs(y1[0], y1[1], y2[0], y2[1])
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
        t = g.cross(n[0], n[1])
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
    t = g.best_pose([(np.eye(3), t), (np.eye(3), -t)], y1, y2)[1]
    return [{"tx": t[0], "ty": t[1], "tz": t[2]}]


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


def _as_calibrated(k: Mapping[str, float]) -> dict[str, float]:
    """The nominal camera of the family (focal length ``f0``, principal point ``(cx, cy)``)
    as the calibrated closed forms read intrinsics: under the retinal motions the focal
    length is pinned at ``f0``, so the rays are the calibrated ones."""
    f0, cx, cy = k["f0"], k["cx"], k["cy"]
    return {"fx1": f0, "fy1": f0, "cx1": cx, "cy1": cy,
            "fx2": f0, "fy2": f0, "cx2": cx, "cy2": cy}


def two_view_retinal_translation(X: np.ndarray, k: Mapping[str, float]) -> Candidates:
    """A translation parallel to the retinal plane (``R = I``, ``tz = 0``, focal lengths
    pinned): the calibrated closed form of the nominal camera
    (:func:`~kanagen.runtime.calibrated_starts.calibrated_retinal_translation`)."""
    from .calibrated_starts import calibrated_retinal_translation

    return calibrated_retinal_translation(X, _as_calibrated(k))


def two_view_retinal_displacement(X: np.ndarray, k: Mapping[str, float]) -> Candidates:
    """A rotation about the optical axis with a translation parallel to the retinal plane
    (focal lengths pinned): the calibrated closed form of the nominal camera
    (:func:`~kanagen.runtime.calibrated_starts.calibrated_retinal_displacement`)."""
    from .calibrated_starts import calibrated_retinal_displacement

    return calibrated_retinal_displacement(X, _as_calibrated(k))


for _entry in (
        Initializer("two_view_retinal_translation", two_view_retinal_translation,
                    _TWO_VIEW_Q, ("cx", "cy", "f0"), 4,
                    two_view_retinal_translation.__doc__.splitlines()[0]),
        Initializer("two_view_retinal_displacement", two_view_retinal_displacement,
                    _TWO_VIEW_Q, ("cx", "cy", "f0"), 4,
                    two_view_retinal_displacement.__doc__.splitlines()[0]),
        Initializer("two_view_fundamental", two_view_fundamental, _TWO_VIEW_Q,
                    ("cx", "cy", "f0"), 4, two_view_fundamental.__doc__.splitlines()[0]),
        Initializer("two_view_homography", two_view_homography, _TWO_VIEW_Q,
                    ("cx", "cy", "f0"), 4, two_view_homography.__doc__.splitlines()[0],
                    equivalent=True),
        Initializer("two_view_rotation", two_view_rotation, _TWO_VIEW_Q,
                    ("cx", "cy", "f0"), 4, two_view_rotation.__doc__.splitlines()[0]),
        Initializer("two_view_translation", two_view_translation, _TWO_VIEW_Q,
                    ("cx", "cy", "f0"), 4, two_view_translation.__doc__.splitlines()[0]),
        Initializer("two_view_zoom", two_view_zoom, _TWO_VIEW_Q, ("cx", "cy", "f0"), 4,
                    two_view_zoom.__doc__.splitlines()[0])):
    register(_entry)
del _entry
