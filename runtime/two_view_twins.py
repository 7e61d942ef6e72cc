"""The closed-form initialisers of the two-view family as compiled kernels with one calling
convention, and their C-callable addresses.

One kernel per initialiser (``two_view_fundamental``, ``two_view_homography``,
``two_view_rotation``, ``two_view_translation``, ``two_view_zoom``,
``two_view_retinal_translation``, ``two_view_retinal_displacement``: :data:`KERNELS`), each
``kernel(X, k3, out) -> count``: ``X`` the sample's matches, an (n, 4) C-contiguous float
array of rows ``(x1, y1, x2, y2)``; ``k3`` the constants ``(cx, cy, f0)``; ``out`` a
(4, 12) array that receives up to four candidates, one a row, in the order of
:data:`PARAMETERS` (the values a candidate does not name are NaN: :data:`NAMES` says which
it names). The count is 0 when no parameter passes through the sample (a degenerate one, or
focal lengths out of range) and never negative: the kernels handle every sample themselves.

The registered initialisers of :mod:`~kanagen.runtime.two_view_starts` are thin wrappers over
these kernels; :func:`twin_address` gives each as a C function
``int64 (int64 n, double *X, double *k3, double *out)`` (a numba ``cfunc``, compiled or
loaded from numba's cache once a process), for a compiled sampler to call.
"""

from __future__ import annotations

import ctypes
import threading

import numpy as np

from kanagen.common.jit import NUMBA, jit
from kanagen.common.link import link, linked

from .linalg import dot, matmul
from .numpy_rules import (
    cross,
    det3,
    divided,
    fill,
    finite,
    floor0,
    inverse,
    put,
    put_matrix,
    svd,
    vector_sum,
)
from .two_view_kernels import (
    CALIBRATED_DEGENERATE,
    DEGENERATE,
    best_pose,
    essential_poses,
    focal_lengths,
    fundamental_7point,
    fundamental_8point,
    homography_dlt,
    homography_poses,
    least_singular,
    nearest_essential,
    polynomial_roots,
    quaternion_from_rotation,
    retinal_displacement,
    retinal_translation,
    rotation_from_pairs,
    signed_translation,
)

#: The parameter of the two-view family, in the order of a candidate's row.
PARAMETERS = ("f1", "f2", "qw", "qx", "qy", "qz", "tx", "ty", "tz", "wx", "wy", "wz")
WIDTH = len(PARAMETERS)
CANDIDATES = 4  # rows of ``out``: the most candidates a kernel gives
FOCAL_RANGE = (0.1, 10.0)  # focal lengths (× f0) read off F outside this range are noise
_LOW, _HIGH = FOCAL_RANGE


def _named(*names: str) -> tuple[tuple[int, str], ...]:
    return tuple((PARAMETERS.index(name), name) for name in names)


#: Per initialiser, the entries of a candidate's row it names: ``(column, name)``.
NAMES: dict[str, tuple[tuple[int, str], ...]] = {
    "two_view_fundamental": _named(*PARAMETERS[:9]),
    "two_view_homography": _named(*PARAMETERS),
    "two_view_rotation": _named(*PARAMETERS[:6]),
    "two_view_translation": _named("tx", "ty", "tz"),
    "two_view_zoom": _named("f2"),
    "two_view_retinal_translation": _named("tx", "ty", "tz"),
    "two_view_retinal_displacement": _named("qw", "qx", "qy", "qz", "tx", "ty", "tz"),
}


@jit
def rays(X, k3, f1: float, f2: float):
    """Pixel matches → rays ``(x, y, f)`` of both views in the family's normalised
    coordinates: ``((u − cx)/f0, (v − cy)/f0, f)``."""
    n = X.shape[0]
    cx, cy, f0 = k3[0], k3[1], k3[2]
    y1, y2 = np.empty((n, 3)), np.empty((n, 3))
    for i in range(n):
        y1[i, 0], y1[i, 1], y1[i, 2] = (X[i, 0] - cx) / f0, (X[i, 1] - cy) / f0, f1
        y2[i, 0], y2[i, 1], y2[i, 2] = (X[i, 2] - cx) / f0, (X[i, 3] - cy) / f0, f2
    return y1, y2


@jit
def _usable(X, k3, least: int) -> bool:
    """At least ``least`` matches, all finite, and a camera: a sample that can have
    candidates."""
    return X.shape[0] >= least and finite(X) and finite(k3) and k3[2] != 0


@jit
def _pixels_to_rays(k3):
    """``T``: pixels ``(u, v, 1)`` → ``((u − cx)/f0, (v − cy)/f0, 1)``."""
    cx, cy, f0 = k3[0], k3[1], k3[2]
    T = np.zeros((3, 3))
    T[0, 0], T[0, 2], T[1, 1], T[1, 2], T[2, 2] = 1 / f0, -cx / f0, 1 / f0, -cy / f0, 1.0
    return T


@jit
def _pose_into(row, R, t) -> None:
    """The rotation (as its quaternion, ``qw ≥ 0``) and ``t`` into a candidate's row."""
    put(row, 2, quaternion_from_rotation(R))
    put(row, 6, t)


@jit
def _in_focal_range(F: float) -> bool:
    """``F = f²`` gives a focal length in :data:`FOCAL_RANGE`."""
    return F > 0 and _LOW < np.sqrt(F) < _HIGH


# -- two_view_fundamental ------------------------------------------------------------------

@linked("f2 f1 f2 -> i", python=True)
def fundamental_twin(X, k3, out) -> int:
    """``F`` by the seven-point (7 matches) or normalised eight-point algorithm (more), the
    focal lengths read off it (Bougnoux), then ``R, t`` from the essential matrix, chosen by
    cheirality; an ``F`` whose focal lengths are imaginary or out of range gives no
    candidate. Up to three candidates (``w``: NaN)."""
    fill(out, np.nan)
    if not _usable(X, k3, 7):
        return 0
    try:
        return _fundamental(X, k3, out)
    except Exception:  # LAPACK refused (LinAlgError, caught by the NumPy closed forms too):
        return 0  # a matrix not finite (an overflow), no convergence, a singular solve


@linked("f2 f1 f2 -> i")
def _fundamental(X, k3, out) -> int:
    """:func:`fundamental_twin` on a usable sample (LAPACK's failures raise)."""
    if X.shape[0] == 7:
        Fs, found = fundamental_7point(X)
    else:
        Fs, found = np.empty((1, 3, 3)), 1
        put_matrix(Fs, 0, fundamental_8point(X))
    f0, principal = k3[2], np.array([k3[0], k3[1], 1.0])
    Tinv = inverse(_pixels_to_rays(k3))  # the same for every root
    count = 0
    for c in range(found):
        F = Fs[c]
        sq1, sq2 = focal_lengths(F, principal, principal)
        f1, f2 = np.sqrt(floor0(sq1)) / f0, np.sqrt(floor0(sq2)) / f0
        if not (_LOW < f1 < _HIGH and _LOW < f2 < _HIGH):
            continue
        # F ∝ Tᵀ diag(1, 1, f2) E diag(1, 1, f1) T with T the pixel -> normalised map
        D1, D2 = np.eye(3), np.eye(3)
        D1[2, 2], D2[2, 2] = 1 / f1, 1 / f2
        E = matmul(matmul(matmul(matmul(D2, Tinv.T), F), Tinv), D1)
        y1, y2 = rays(X, k3, f1, f2)
        Rs, ts = essential_poses(nearest_essential(E))
        best = best_pose(Rs, ts, y1, y2)
        out[count, 0], out[count, 1] = f1, f2
        _pose_into(out[count], Rs[best], ts[best])
        count += 1
    return count


# -- two_view_homography -------------------------------------------------------------------

@jit
def calibrated_dlt(X, k3):
    """The DLT homography in the family's normalised coordinates, ``T H T⁻¹``."""
    T = _pixels_to_rays(k3)
    return matmul(matmul(T, homography_dlt(X)), inverse(T))


@linked("f2 f1 f2 -> i", python=True)
def homography_twin(X, k3, out) -> int:
    """``H`` by the normalised DLT (4 matches or more), then ``(R, t, w)`` with
    ``H ∝ R + t wᵀ`` at the nominal focal length, in front of camera 1: each
    decomposition (two in general) a candidate."""
    fill(out, np.nan)
    if not _usable(X, k3, 4):
        return 0
    try:
        return _homography(X, k3, out)
    except Exception:
        return 0


@linked("f2 f1 f2 -> i")
def _homography(X, k3, out) -> int:
    """:func:`homography_twin` on a usable sample (LAPACK's failures raise)."""
    y1, y2 = rays(X, k3, 1.0, 1.0)
    Rs, ts, ws, count = homography_poses(calibrated_dlt(X, k3), y1, y2, True, True)
    for c in range(count):
        out[c, 0], out[c, 1] = 1.0, 1.0
        _pose_into(out[c], Rs[c], ts[c])
        put(out[c], 9, ws[c])
    return count


# -- two_view_rotation ---------------------------------------------------------------------

@linked("f2 f1 f2 -> i", python=True)
def rotation_twin(X, k3, out) -> int:
    """A rotation about the optical centre with an unknown common focal length
    (``r2 ∝ R r1``, ``r = (x, y, f)``). Two matches: the real roots ``F = f²`` of the cubic
    of the angle between the rays, each admissible one an exact rotation by the triad of the
    two ray pairs (up to three candidates); four or more: ``F`` by least squares from the DLT
    homography, ``R`` by Kabsch (one); three: none (two_view_starts.two_view_rotation says
    how)."""
    fill(out, np.nan)
    if not _usable(X, k3, 2) or X.shape[0] == 3:
        return 0
    try:
        return _rotation_pair(X, k3, out) if X.shape[0] == 2 else _rotation_many(X, k3, out)
    except Exception:
        return 0


@linked("f2 f1 f2 -> i")
def _rotation_pair(X, k3, out) -> int:
    """:func:`rotation_twin` on a usable sample of two matches: the cubic in ``F = f²``."""
    y1, y2 = rays(X, k3, 0.0, 0.0)  # the image vectors (x, y, 0)
    p, q = dot(y1[0], y1[1]), dot(y2[0], y2[1])
    s1, s2 = dot(y1[0], y1[0]), dot(y1[1], y1[1])
    t1, t2 = dot(y2[0], y2[0]), dot(y2[1], y2[1])
    # (p + F)² (t1 + F)(t2 + F) − (q + F)² (s1 + F)(s2 + F), highest power first
    cubic = np.array([
        t1 + t2 + 2 * p - s1 - s2 - 2 * q,
        t1 * t2 + 2 * p * (t1 + t2) + p * p - s1 * s2 - 2 * q * (s1 + s2) - q * q,
        2 * p * t1 * t2 + p * p * (t1 + t2) - 2 * q * s1 * s2 - q * q * (s1 + s2),
        p * p * t1 * t2 - q * q * s1 * s2])
    if not np.any(cubic):
        return 0
    re, im = polynomial_roots(cubic)
    count = 0
    for r in range(re.shape[0]):
        F = re[r]
        if abs(im[r]) > 1e-8 * (1 + abs(F)) or not _in_focal_range(F) \
                or (p + F > 0) != (q + F > 0):
            continue
        f = np.sqrt(F)
        y1[0, 2], y1[1, 2], y2[0, 2], y2[1, 2] = f, f, f, f
        R, found = rotation_from_pairs(y1[0], y1[1], y2[0], y2[1])
        if found:
            out[count, 0], out[count, 1] = f, f
            put(out[count], 2, quaternion_from_rotation(R))
            count += 1
    return count


@linked("f2 f1 f2 -> i")
def _rotation_many(X, k3, out) -> int:
    """:func:`rotation_twin` on a usable sample of four matches or more: ``F`` from the DLT
    homography, ``R`` by Kabsch."""
    # Hn ∝ K R K⁻¹ (K = diag(f, f, 1)) scaled to det Hn = 1: Hn ω Hnᵀ = ω, ω = diag(F, F, 1)
    Hn = calibrated_dlt(X, k3)
    d = det3(Hn)
    if not d != 0:
        return 0
    Hn = divided(Hn, np.cbrt(d))
    AA, AB = np.empty(9), np.empty(9)  # the six equations, linear in F: A F = B
    for i in range(3):
        for j in range(3):
            a = Hn[i, 0] * Hn[j, 0] + Hn[i, 1] * Hn[j, 1] - (1.0 if i == j and i < 2 else 0.0)
            b = (1.0 if i == j and i == 2 else 0.0) - Hn[i, 2] * Hn[j, 2]
            AA[3 * i + j], AB[3 * i + j] = a * a, a * b
    den = vector_sum(AA)  # ~ the squared angle: below DEGENERATE² no rotation fixes F
    F = vector_sum(AB) / den if den > DEGENERATE * DEGENERATE else -1.0
    if not _in_focal_range(F):
        return 0
    f = np.sqrt(F)
    y1, y2 = rays(X, k3, f, f)
    R, found = kabsch(y1, y2)
    if not found:
        return 0
    out[0, 0], out[0, 1] = f, f
    put(out[0], 2, quaternion_from_rotation(R))
    return 1


@linked("f2 f2 -> f2 b")
def kabsch(y1, y2):
    """The rotation that best maps the unit rays ``ŷ1`` onto ``ŷ2`` (least squares:
    ``Σ ŷ2 ŷ1ᵀ = U S Vᵀ``, ``R = u1 v1ᵀ + u2 v2ᵀ + (u1 × u2)(v1 × v2)ᵀ``, det +1), and
    whether the rays fix it (``σ2`` not negligible)."""
    a, b = np.empty_like(y1), np.empty_like(y2)
    for i in range(y1.shape[0]):
        na = np.sqrt(y1[i, 0] * y1[i, 0] + y1[i, 1] * y1[i, 1] + y1[i, 2] * y1[i, 2])
        nb = np.sqrt(y2[i, 0] * y2[i, 0] + y2[i, 1] * y2[i, 1] + y2[i, 2] * y2[i, 2])
        for j in range(3):
            a[i, j], b[i, j] = y1[i, j] / na, y2[i, j] / nb
    U, S, Vt = svd(matmul(b.T, a))
    if not S[1] > DEGENERATE * S[0]:
        return np.zeros((3, 3)), False
    u1, u2, v1, v2 = U[:, 0].copy(), U[:, 1].copy(), Vt[0], Vt[1]
    u3, v3 = cross(u1, u2), cross(v1, v2)
    R = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            R[i, j] = u1[i] * v1[j] + u2[i] * v2[j] + u3[i] * v3[j]
    return R, True


# -- two_view_translation ------------------------------------------------------------------

@linked("f2 f1 f2 -> i", python=True)
def translation_twin(X, k3, out) -> int:
    """A translation at the nominal focal length (``R = I``, ``‖t‖ = 1``): each match gives
    ``t · (r1 × r2) = 0``; two matches fix ``t = unit(n1 × n2)``, more the least-squares
    ``t`` (none when the null space is larger); its sign made canonical (largest component
    positive), then chosen by cheirality. One candidate (``f``, ``q``, ``w``: NaN)."""
    fill(out, np.nan)
    if not _usable(X, k3, 2):
        return 0
    try:
        return _translation(X, k3, out)
    except Exception:
        return 0


@linked("f2 f1 f2 -> i")
def _translation(X, k3, out) -> int:
    """:func:`translation_twin` on a usable sample (LAPACK's failures raise)."""
    y1, y2 = rays(X, k3, 1.0, 1.0)
    m = X.shape[0]
    normals = np.empty((m, 3))
    for i in range(m):
        put(normals[i], 0, cross(y1[i], y2[i]))
    if m == 2:
        t = cross(normals[0], normals[1])
    else:
        t, unique = least_singular(normals, DEGENERATE)
        if not unique:
            return 0
    size = np.sqrt(dot(t, t))
    if not (size > 0 and np.isfinite(size)):
        return 0
    put(out[0], 6, signed_translation(np.eye(3), t, y1, y2))
    return 1


# -- two_view_zoom, two_view_retinal_translation, two_view_retinal_displacement ------------

@linked("f2 f1 f2 -> i", python=True)
def zoom_twin(X, k3, out) -> int:
    """A zoom about the principal point (``R = I``, ``f1 = 1``, no translation): each
    match's rays are parallel, ``x2 = f2 x1`` in the normalised coordinates, so ``f2`` is
    the least-squares ratio ``Σ x1·x2 / Σ x1·x1``; none when the matches sit on the
    principal point or the ratio is out of the focal range. One candidate (``f2``)."""
    fill(out, np.nan)
    if not _usable(X, k3, 1):
        return 0
    y1, y2 = rays(X, k3, 1.0, 1.0)
    across, along = 0.0, 0.0
    for i in range(X.shape[0]):
        for j in range(2):
            across += y1[i, j] * y1[i, j]
            along += y1[i, j] * y2[i, j]
    if not across > 0.0:
        return 0
    f2 = along / across
    if not _LOW < f2 < _HIGH:
        return 0
    out[0, 1] = f2
    return 1


@linked("f2 f1 f2 -> i", python=True)
def retinal_translation_twin(X, k3, out) -> int:
    """A translation parallel to the retinal plane at the nominal focal length
    (:func:`~.two_view_kernels.retinal_translation` on the nominal camera's rays). One
    candidate (``t``)."""
    fill(out, np.nan)
    if not _usable(X, k3, 1):
        return 0
    y1, y2 = rays(X, k3, 1.0, 1.0)
    try:
        t, found = retinal_translation(y1, y2, CALIBRATED_DEGENERATE)
    except Exception:
        return 0
    if not found:
        return 0
    out[0, 6], out[0, 7], out[0, 8] = t[0], t[1], 0.0
    return 1


@linked("f2 f1 f2 -> i", python=True)
def retinal_displacement_twin(X, k3, out) -> int:
    """A rotation about the optical axis with a translation parallel to the retinal plane at
    the nominal focal length (:func:`~.two_view_kernels.retinal_displacement` on the
    nominal camera's rays). Up to two candidates (``q``, ``t``)."""
    fill(out, np.nan)
    if not _usable(X, k3, 2):
        return 0
    y1, y2 = rays(X, k3, 1.0, 1.0)
    try:
        Rs, ts, count = retinal_displacement(y1, y2, CALIBRATED_DEGENERATE)
    except Exception:
        return 0
    for c in range(count):
        _pose_into(out[c], Rs[c], ts[c])
        out[c, 3], out[c, 4], out[c, 8] = 0.0, 0.0, 0.0  # exactly the model's zeros
    return count


#: The kernels by the name of the initialiser they are.
KERNELS = {"two_view_fundamental": fundamental_twin, "two_view_homography": homography_twin,
           "two_view_rotation": rotation_twin, "two_view_translation": translation_twin,
           "two_view_zoom": zoom_twin,
           "two_view_retinal_translation": retinal_translation_twin,
           "two_view_retinal_displacement": retinal_displacement_twin}


# -- the C functions -------------------------------------------------------------------------

_lock = threading.Lock()
_addresses: dict[str, int] = {}
_keep: list = []  # the compiled cfuncs (or ctypes callbacks): their code lives while we do


def twin_address(name: str) -> int:
    """The address of the C function of the initialiser ``name`` (a key of
    :data:`KERNELS`): ``int64 (int64 n, double *X, double *k3, double *out)``, the kernel
    on ``X`` (n × 4, by rows), ``k3`` (3) and ``out`` (4 × 12, by rows), returning the
    count. Compiled (or loaded from numba's cache) the first time a process asks; run
    interpreted (``NUMBA_DISABLE_JIT=1``, or numba missing) it is a ctypes callback of the
    Python kernel, callable the same way.

    Examples
    --------
    >>> import ctypes
    >>> import numpy as np
    >>> call = ctypes.CFUNCTYPE(ctypes.c_int64, ctypes.c_int64, *[ctypes.c_void_p] * 3)(
    ...     twin_address("two_view_translation"))
    >>> X = np.array([[300.0, 200.0, 310.0, 200.0], [400.0, 250.0, 420.0, 251.0]])
    >>> k3, out = np.array([320.0, 240.0, 640.0]), np.empty((4, 12))
    >>> call(2, X.ctypes.data, k3.ctypes.data, out.ctypes.data)
    1
    """
    link(__name__)
    with _lock:
        address = _addresses.get(name)
        if address is None:
            kernel = KERNELS[name]
            if NUMBA is None or jit.disabled:
                function = _callback(kernel)
                address = ctypes.cast(function, ctypes.c_void_p).value
            else:
                function = NUMBA.cfunc(_SIGNATURE, cache=True, error_model="numpy")(
                    _C_ENTRIES[name])
                address = function.address
            _keep.append(function)
            address = _addresses[name] = int(address)
        return address


def _callback(kernel):
    """A ctypes C function of the interpreted ``kernel`` (its arrays on the caller's)."""
    pointer = ctypes.POINTER(ctypes.c_double)

    def call(n, X, k3, out):
        return kernel(np.ctypeslib.as_array(X, (n, 4)), np.ctypeslib.as_array(k3, (3,)),
                      np.ctypeslib.as_array(out, (CANDIDATES, WIDTH)))

    return ctypes.CFUNCTYPE(ctypes.c_int64, ctypes.c_int64, pointer, pointer, pointer)(call)


if NUMBA is not None:
    from numba import carray, types

    _DOUBLES = types.CPointer(types.float64)
    _SIGNATURE = types.int64(types.int64, _DOUBLES, _DOUBLES, _DOUBLES)

    # the C entries, one a kernel, each its own function: numba caches a cfunc by its
    # function's source and position
    def _fundamental_c(n, X, k3, out):
        return fundamental_twin(carray(X, (n, 4)), carray(k3, (3,)),
                                carray(out, (CANDIDATES, WIDTH)))

    def _homography_c(n, X, k3, out):
        return homography_twin(carray(X, (n, 4)), carray(k3, (3,)),
                               carray(out, (CANDIDATES, WIDTH)))

    def _rotation_c(n, X, k3, out):
        return rotation_twin(carray(X, (n, 4)), carray(k3, (3,)),
                             carray(out, (CANDIDATES, WIDTH)))

    def _translation_c(n, X, k3, out):
        return translation_twin(carray(X, (n, 4)), carray(k3, (3,)),
                                carray(out, (CANDIDATES, WIDTH)))

    def _zoom_c(n, X, k3, out):
        return zoom_twin(carray(X, (n, 4)), carray(k3, (3,)), carray(out, (CANDIDATES, WIDTH)))

    def _retinal_translation_c(n, X, k3, out):
        return retinal_translation_twin(carray(X, (n, 4)), carray(k3, (3,)),
                                        carray(out, (CANDIDATES, WIDTH)))

    def _retinal_displacement_c(n, X, k3, out):
        return retinal_displacement_twin(carray(X, (n, 4)), carray(k3, (3,)),
                                         carray(out, (CANDIDATES, WIDTH)))

    _C_ENTRIES = {"two_view_fundamental": _fundamental_c, "two_view_homography": _homography_c,
                  "two_view_rotation": _rotation_c, "two_view_translation": _translation_c,
                  "two_view_zoom": _zoom_c,
                  "two_view_retinal_translation": _retinal_translation_c,
                  "two_view_retinal_displacement": _retinal_displacement_c}
