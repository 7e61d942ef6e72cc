"""The calibrated two-view closed forms: starting values of the minimal solves of the
``two_view_calibrated`` family (report eq. 21), a plugin of the initializer registry
(:mod:`~kanagen.runtime.initializers`).

The intrinsics are known (constants ``fx1 fy1 cx1 cy1 fx2 fy2 cx2 cy2``, pixels): a match
``[u, v, u2, v2]`` gives the rays ``r1 = ((u − cx1)/fx1, (v − cy1)/fy1, 1)`` and ``r2``
alike, and the motion ``X2 = R X1 + t`` (``‖t‖ = 1``) satisfies ``r2ᵀ [t]× R r1 = 0``
(``E = [t]× R``, the essential matrix) or, without translation or on a plane,
``r2 ∝ (R + t wᵀ) r1``.

* ``calibrated_five_point`` — the general motion: the five-point essential matrices
  (:func:`five_point`, after Nistér 2004 and Stewénius et al. 2006: the 4-dimensional null
  space of the epipolar equations, the ten cubic constraints ``det E = 0`` and
  ``2 E Eᵀ E − tr(E Eᵀ) E = 0`` reduced by elimination of the ten cubic monomials, and the
  eigenvectors of the 10×10 action matrix of ``x`` on the ten monomials of degree ≤ 2); each
  real ``E`` gives its pose among the four of the decomposition by cheirality.
* ``calibrated_rotation`` (2 matches: the triad of the two ray pairs; more: Kabsch),
  ``calibrated_translation`` (2 matches: ``t = n1 × n2``, ``n = r1 × r2``),
  ``calibrated_retinal_translation`` (1 match: ``t ⊥ n`` in the retinal plane),
  ``calibrated_retinal_displacement`` (2 matches: a rotation about the optical axis, the
  angle from one equation linear in ``(cos θ, sin θ)``), ``calibrated_homography`` (the DLT
  on rays, then its ``(R, t, w)`` decompositions).

Importing this module registers them; the registry imports it the first time one of their
names is looked up (:data:`~kanagen.runtime.initializers.PROVIDERS`). They have no compiled
:class:`~kanagen.runtime.initializers.Kernel` (the intrinsics are eight constants, the
kernels' contract three): a search's samples with them go solve by solve from Python (the
minimal solves and errors in the engine). The retinal motions' closed forms, the sign by
cheirality and the least-squares null vector are the two-view family's kernels
(:mod:`~kanagen.runtime.two_view_kernels`), on these rays.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping

import numpy as np

from . import geometry as g
from . import two_view_kernels as kernels
from .initializers import Candidates, Initializer, register

_Q = ("qw", "qx", "qy", "qz", "tx", "ty", "tz", "wx", "wy", "wz")
_K = ("fx1", "fy1", "cx1", "cy1", "fx2", "fy2", "cx2", "cy2")
_DEGENERATE = kernels.CALIBRATED_DEGENERATE  # a singular value below it (relative): zero
_ERRORS = (np.linalg.LinAlgError, ValueError, ZeroDivisionError, FloatingPointError)


def rays(X: np.ndarray, k: Mapping[str, float]) -> tuple[np.ndarray, np.ndarray]:
    """Pixel matches ``[u, v, u2, v2]`` → the rays ``(x, y, 1)`` of both cameras, (N, 3)."""
    X = np.asarray(X, dtype=float)
    y1, y2 = np.ones((len(X), 3)), np.ones((len(X), 3))
    y1[:, 0], y1[:, 1] = (X[:, 0] - k["cx1"]) / k["fx1"], (X[:, 1] - k["cy1"]) / k["fy1"]
    y2[:, 0], y2[:, 1] = (X[:, 2] - k["cx2"]) / k["fx2"], (X[:, 3] - k["cy2"]) / k["fy2"]
    return y1, y2


def pose_params(R: np.ndarray, t: np.ndarray) -> dict[str, float]:
    """The family's parameter components of a pose (quaternion with ``qw ≥ 0``, unit t)."""
    q = g.quaternion_from_rotation(R)
    t = np.asarray(t, dtype=float) / np.linalg.norm(t)
    return {"qw": q[0], "qx": q[1], "qy": q[2], "qz": q[3],
            "tx": t[0], "ty": t[1], "tz": t[2]}


# --- the five-point solver --------------------------------------------------------------
#
# Polynomials in (x, y, z) of degree ≤ 3 are coefficient vectors over _MONOS: the ten cubic
# monomials first (eliminated), then the ten of degree ≤ 2 (the basis of the quotient ring:
# ten solutions). E = x X + y Y + z Z + W; its entries are linear polynomials over
# (x, y, z, 1).

_CUBIC = [e for e in itertools.product(range(4), repeat=3) if sum(e) == 3]
_LOW = [(2, 0, 0), (0, 2, 0), (0, 0, 2), (1, 1, 0), (1, 0, 1), (0, 1, 1),
        (1, 0, 0), (0, 1, 0), (0, 0, 1), (0, 0, 0)]
_MONOS = _CUBIC + _LOW
_INDEX = {e: i for i, e in enumerate(_MONOS)}
_LIN = [(1, 0, 0), (0, 1, 0), (0, 0, 1), (0, 0, 0)]
_QUAD = [e for e in _LOW]  # degree ≤ 2, in the basis order


def _product_table(left, right) -> np.ndarray:
    """``T[a, b, m] = 1`` when monomial ``left[a]`` times ``right[b]`` is ``_MONOS[m]``."""
    T = np.zeros((len(left), len(right), len(_MONOS)))
    for a, ea in enumerate(left):
        for b, eb in enumerate(right):
            T[a, b, _INDEX[tuple(i + j for i, j in zip(ea, eb, strict=True))]] = 1.0
    return T


_LIN_LIN = _product_table(_LIN, _LIN)[:, :, 10:]  # products of two linear polys: degree ≤ 2
_QUAD_LIN = _product_table(_QUAD, _LIN)  # a degree-≤2 poly times a linear one
# multiplication by x on the basis: x·b_j is a basis monomial or a cubic one
_TIMES_X = [_INDEX[(e[0] + 1, e[1], e[2])] for e in _LOW]
_AT = {name: 10 + _LOW.index(e) for name, e in
       (("x", (1, 0, 0)), ("y", (0, 1, 0)), ("z", (0, 0, 1)), ("1", (0, 0, 0)))}


def _constraints(basis: np.ndarray) -> np.ndarray:
    """The 10×20 coefficients of ``det E = 0`` and ``2 E Eᵀ E − tr(E Eᵀ) E = 0`` for
    ``E = x X + y Y + z Z + W`` (``basis`` = the four 3×3 matrices X, Y, Z, W)."""
    Ec = np.moveaxis(basis, 0, -1)  # (3, 3, 4): entry (i, j) as a linear polynomial
    EEt = np.einsum("ika,jkb,abm->ijm", Ec, Ec, _LIN_LIN)  # (3, 3, 10)
    trace = EEt[0, 0] + EEt[1, 1] + EEt[2, 2]
    lam = EEt.copy()
    for i in range(3):
        lam[i, i] -= 0.5 * trace
    rows = np.einsum("ikm,kja,man->ijn", lam, Ec, _QUAD_LIN).reshape(9, 20)
    # det E = E[0] · (E[1] × E[2])
    cof = np.stack([
        np.einsum("a,b,abm->m", Ec[1, 1], Ec[2, 2], _LIN_LIN)
        - np.einsum("a,b,abm->m", Ec[1, 2], Ec[2, 1], _LIN_LIN),
        np.einsum("a,b,abm->m", Ec[1, 2], Ec[2, 0], _LIN_LIN)
        - np.einsum("a,b,abm->m", Ec[1, 0], Ec[2, 2], _LIN_LIN),
        np.einsum("a,b,abm->m", Ec[1, 0], Ec[2, 1], _LIN_LIN)
        - np.einsum("a,b,abm->m", Ec[1, 1], Ec[2, 0], _LIN_LIN)])
    det = np.einsum("jm,ja,man->n", cof, Ec[0], _QUAD_LIN)
    return np.vstack([rows, det])


def essential_from_nullspace(basis: np.ndarray) -> list[np.ndarray]:
    """The real essential matrices ``E = x X + y Y + z Z + W`` of the 4-dimensional space
    spanned by ``basis`` (4, 3, 3): at most ten, ‖E‖ = √2 each."""
    A = _constraints(basis)
    C = np.linalg.solve(A[:, :10], A[:, 10:])  # cubic monomial i = −C[i] · basis monomials
    M = np.zeros((10, 10))
    for j, m in enumerate(_TIMES_X):
        if m < 10:
            M[j] = -C[m]
        else:
            M[j, m - 10] = 1.0
    values, vectors = np.linalg.eig(M)
    out = []
    scale = np.max(np.abs(values)) if len(values) else 1.0
    for value, v in zip(values, vectors.T, strict=True):
        if abs(value.imag) > 1e-8 * (1.0 + scale):
            continue
        v = v.real
        one = v[_AT["1"] - 10]
        if not abs(one) > 1e-12 * np.max(np.abs(v)):
            continue
        x, y, z = (v[_AT[n] - 10] / one for n in "xyz")
        E = x * basis[0] + y * basis[1] + z * basis[2] + basis[3]
        norm = np.linalg.norm(E)
        if norm > 0 and np.isfinite(norm):
            out.append(E * (np.sqrt(2.0) / norm))
    return out


def epipolar_rows(y1: np.ndarray, y2: np.ndarray) -> np.ndarray:
    """``(N, 9)``: row ``n`` is ``y2ₙ ⊗ y1ₙ``, so that ``row · vec(E) = y2ᵀ E y1``."""
    return np.einsum("ni,nj->nij", y2, y1).reshape(len(y1), 9)


def five_point(y1: np.ndarray, y2: np.ndarray) -> list[np.ndarray]:
    """The essential matrices through five ray pairs (more: through the 4-dimensional
    least-squares null space of their epipolar equations), at most ten."""
    A = epipolar_rows(y1, y2)
    if len(A) < 5:
        raise ValueError(f"the five-point solver needs 5 correspondences, got {len(A)}")
    Vt = np.linalg.svd(A)[2]  # full: its last four rows span the (least-squares) null space
    return essential_from_nullspace(Vt[-4:].reshape(4, 3, 3))


def sampson_sq(E: np.ndarray, y1: np.ndarray, y2: np.ndarray) -> np.ndarray:
    """Squared Sampson errors of the rays to ``y2ᵀ E y1 = 0`` (in ray units)."""
    Ey1, Ety2 = y1 @ E.T, y2 @ E
    num = np.sum(y2 * Ey1, 1) ** 2
    den = Ey1[:, 0] ** 2 + Ey1[:, 1] ** 2 + Ety2[:, 0] ** 2 + Ety2[:, 1] ** 2
    with np.errstate(all="ignore"):
        return num / den


def calibrated_five_point(X: np.ndarray, k: Mapping[str, float]) -> Candidates:
    """The general calibrated motion: five matches give the five-point essential matrices
    (at most ten), each with its pose among the four of the decomposition that puts the
    most points in front of both cameras; more matches (the refinement on the inliers) give
    the one essential matrix of least Sampson error among those of the least-squares null
    space and, from eight matches, the linear eight-point one made essential."""
    X = np.asarray(X, dtype=float)
    if len(X) < 5 or not np.all(np.isfinite(X)):
        return []
    try:
        y1, y2 = rays(X, k)
        Es = five_point(y1, y2)
        if len(X) > 5:
            if len(X) >= 8:
                E8 = np.linalg.svd(epipolar_rows(y1, y2))[2][-1].reshape(3, 3)
                Es.append(g.nearest_essential(E8))
            if not Es:
                return []
            Es = [min(Es, key=lambda E: float(np.sum(sampson_sq(E, y1, y2))))]
        out = []
        for E in Es:
            R, t = g.best_pose(g.essential_poses(E), y1, y2)
            out.append(pose_params(R, t))
        return out
    except _ERRORS:
        return []


# --- the specific motions ---------------------------------------------------------------

def _unit_rows(y: np.ndarray) -> np.ndarray:
    return y / np.sqrt(np.sum(y * y, 1))[:, None]


def kabsch(y1: np.ndarray, y2: np.ndarray) -> np.ndarray | None:
    """The rotation mapping the unit rays ``ŷ1`` closest onto ``ŷ2`` (least squares, det +1);
    None when the rays do not fix it."""
    U, S, Vt = np.linalg.svd(_unit_rows(y2).T @ _unit_rows(y1))
    if not S[1] > _DEGENERATE * S[0]:
        return None
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt)) or 1.0])
    return U @ D @ Vt


def calibrated_rotation(X: np.ndarray, k: Mapping[str, float]) -> Candidates:
    """A rotation about the optical centre (``r2 ∝ R r1``): from two matches the triad of the
    two ray pairs (exact on the first ray and on the plane of the two), from more the
    least-squares rotation of the unit rays (Kabsch). One candidate."""
    X = np.asarray(X, dtype=float)
    if len(X) < 2 or not np.all(np.isfinite(X)):
        return []
    try:
        y1, y2 = rays(X, k)
        R = g.rotation_from_pairs(y1[0], y1[1], y2[0], y2[1]) if len(X) == 2 else kabsch(y1, y2)
        if R is None:
            return []
        q = g.quaternion_from_rotation(R)
        return [{"qw": q[0], "qx": q[1], "qy": q[2], "qz": q[3]}]
    except _ERRORS:
        return []


def _signed(R: np.ndarray, t: np.ndarray, y1: np.ndarray, y2: np.ndarray) -> np.ndarray:
    """``t`` or ``−t`` (unit), whichever puts more points in front of both cameras (the
    sign that makes the largest component positive on a tie):
    :func:`~kanagen.runtime.two_view_kernels.signed_translation`."""
    return kernels.signed_translation(_matrix(R), _matrix(t), _matrix(y1), _matrix(y2))


def _least_singular(A: np.ndarray) -> np.ndarray | None:
    """The unit null vector of ``A`` in least squares; None when it is not unique
    (:func:`~kanagen.runtime.two_view_kernels.least_singular`)."""
    v, unique = kernels.least_singular(_matrix(A), _DEGENERATE)
    return v if unique else None


def _matrix(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=float)


def calibrated_translation(X: np.ndarray, k: Mapping[str, float]) -> Candidates:
    """A pure translation (``R = I``): each match gives ``t · (r1 × r2) = 0``, two fix
    ``t ∝ n1 × n2`` (``n = r1 × r2``), more the least-squares null vector of the stacked
    ``n``; the sign by cheirality. One candidate."""
    X = np.asarray(X, dtype=float)
    if len(X) < 2 or not np.all(np.isfinite(X)):
        return []
    try:
        y1, y2 = rays(X, k)
        n = np.cross(y1, y2)
        t = g.cross(n[0], n[1]) if len(X) == 2 else _least_singular(n)
        if t is None or not np.linalg.norm(t) > 0:
            return []
        t = _signed(np.eye(3), t, y1, y2)
        return [{"tx": t[0], "ty": t[1], "tz": t[2]}]
    except _ERRORS:
        return []


def calibrated_retinal_translation(X: np.ndarray, k: Mapping[str, float]) -> Candidates:
    """A translation parallel to the retinal plane (``R = I``, ``tz = 0``: rectified
    stereo): ``t · n = 0`` with ``n = r1 × r2`` gives ``t ∝ (n_y, −n_x, 0)`` from one match,
    the least-squares direction in the plane from more; the sign by cheirality
    (:func:`~kanagen.runtime.two_view_kernels.retinal_translation`)."""
    X = np.asarray(X, dtype=float)
    if len(X) < 1 or not np.all(np.isfinite(X)):
        return []
    try:
        y1, y2 = rays(X, k)
        t, found = kernels.retinal_translation(y1, y2, _DEGENERATE)
        return [{"tx": t[0], "ty": t[1], "tz": 0.0}] if found else []
    except _ERRORS:
        return []


def calibrated_retinal_displacement(X: np.ndarray, k: Mapping[str, float]) -> Candidates:
    """A displacement that keeps the retinal plane: ``R = Rz(θ)`` about the optical axis and
    ``t = (tx, ty, 0)``. Two matches: the two ``θ`` of one equation linear in ``(cos θ,
    sin θ)``, each with ``t`` along the displacement; three or more: a least-squares null
    vector linear in ``t`` and ``(cos θ, sin θ) t``
    (:func:`~kanagen.runtime.two_view_kernels.retinal_displacement`)."""
    X = np.asarray(X, dtype=float)
    if len(X) < 2 or not np.all(np.isfinite(X)):
        return []
    try:
        y1, y2 = rays(X, k)
        Rs, ts, count = kernels.retinal_displacement(y1, y2, _DEGENERATE)
        return [{**pose_params(Rs[i], ts[i]), "qx": 0.0, "qy": 0.0, "tz": 0.0}
                for i in range(count)]
    except _ERRORS:
        return []


def calibrated_homography(X: np.ndarray, k: Mapping[str, float]) -> Candidates:
    """A planar scene: the normalised DLT homography of the rays (4 matches or more),
    ``Hn ∝ R + t wᵀ``, then its decompositions with the plane in front of camera 1 (two in
    general), each a candidate."""
    X = np.asarray(X, dtype=float)
    if len(X) < 4 or not np.all(np.isfinite(X)):
        return []
    try:
        y1, y2 = rays(X, k)
        Hn = g.homography_dlt(y1[:, :2], y2[:, :2])
        return [{**pose_params(R, t), "wx": w[0], "wy": w[1], "wz": w[2]}
                for R, t, w in g.homography_poses(Hn, y1, y2)]
    except _ERRORS:
        return []


for _entry in (
        Initializer("calibrated_five_point", calibrated_five_point, _Q, _K, 4,
                    calibrated_five_point.__doc__.splitlines()[0]),
        Initializer("calibrated_rotation", calibrated_rotation, _Q, _K, 4,
                    calibrated_rotation.__doc__.splitlines()[0]),
        Initializer("calibrated_translation", calibrated_translation, _Q, _K, 4,
                    calibrated_translation.__doc__.splitlines()[0]),
        Initializer("calibrated_retinal_translation", calibrated_retinal_translation, _Q, _K,
                    4, calibrated_retinal_translation.__doc__.splitlines()[0]),
        Initializer("calibrated_retinal_displacement", calibrated_retinal_displacement, _Q,
                    _K, 4, calibrated_retinal_displacement.__doc__.splitlines()[0]),
        Initializer("calibrated_homography", calibrated_homography, _Q, _K, 4,
                    calibrated_homography.__doc__.splitlines()[0], equivalent=True)):
    register(_entry)
del _entry
