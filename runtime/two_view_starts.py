"""The two-view closed forms: starting values of the two-view family's minimal solves
(report eq. 21), a plugin of the initializer registry (:mod:`~kanagen.runtime.initializers`).

``two_view_fundamental`` (seven- or eight-point ``F``, focal lengths, pose),
``two_view_homography`` (DLT ``H``, its two poses), ``two_view_rotation``,
``two_view_translation``, ``two_view_zoom``, ``two_view_retinal_translation`` and
``two_view_retinal_displacement``: compiled kernels
(:mod:`~kanagen.runtime.two_view_twins`, on the closed forms of
:mod:`~kanagen.runtime.two_view_kernels`). The functions here wrap them, and the robust
search's samples call the same kernels by address (their registry entries'
:class:`~kanagen.runtime.initializers.Kernel`:
:func:`~kanagen.runtime.two_view_twins.twin_address`). Importing this module registers
them (:func:`~kanagen.runtime.initializers.register`); the registry imports it the first
time one of their names is looked up (:data:`~kanagen.runtime.initializers.PROVIDERS`), so a
family whose models name none of them (conic, line, ...) neither loads nor compiles this
module or the geometry.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from . import two_view_twins as twins
from .initializers import Candidates, Initializer, Kernel, register

_TWO_VIEW_Q = twins.PARAMETERS


def _rows(X) -> np.ndarray:
    """The matches as the kernels read them: an (n, 4) C-ordered float array."""
    X = np.asarray(X, dtype=float)
    return np.ascontiguousarray(X[:, :4]) if X.ndim == 2 else np.empty((0, 4))


def _constants(k: Mapping[str, float]) -> np.ndarray:
    return np.array([k["cx"], k["cy"], k["f0"]], dtype=float)


def _candidates(name: str, X: np.ndarray, k: Mapping[str, float]) -> Candidates:
    """The candidates of the compiled initialiser ``name`` on the sample ``X``, by name."""
    out = np.empty((twins.CANDIDATES, twins.WIDTH))
    count = twins.KERNELS[name](_rows(X), _constants(k), out)
    names = twins.NAMES[name]
    return [{n: row[i] for i, n in names} for row in out[:count].tolist()]


def two_view_fundamental(X: np.ndarray, k: Mapping[str, float]) -> Candidates:
    """``F`` by the seven-point (7 matches) or normalised eight-point algorithm (more), the
    focal lengths read off it (Bougnoux), then ``R, t`` from the essential matrix, chosen
    by cheirality. An ``F`` whose focal lengths are imaginary or out of range has no
    physical parameter through the sample: it gives no candidate."""
    return _candidates("two_view_fundamental", X, k)


def two_view_homography(X: np.ndarray, k: Mapping[str, float]) -> Candidates:
    """``H`` by the normalised DLT (4 matches or more), then ``(R, t, w)`` with
    ``H ∝ R + t wᵀ`` at the nominal focal length (the planar model's), in front of
    camera 1; each of the (two) decompositions is a candidate."""
    return _candidates("two_view_homography", X, k)


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
    return _candidates("two_view_rotation", X, k)


def two_view_translation(X: np.ndarray, k: Mapping[str, float]) -> Candidates:
    """A translation at the nominal focal length (the translation model: ``R = I``,
    ``f1 = f2 = 1``, ``‖t‖ = 1``). Each match gives ``t · (r1 × r2) = 0``: two matches fix
    ``t = unit(n1 × n2)``, ``n_i = r1_i × r2_i``; more matches the least-squares ``t``, the
    right singular vector of the least singular value of the stacked ``n_i`` (none when
    the second least is negligible: the null space is larger). Its sign is first made
    canonical (largest component positive), then chosen by cheirality (the more points in
    front of both cameras; ``t`` itself on a tie). One candidate."""
    return _candidates("two_view_translation", X, k)


def two_view_zoom(X: np.ndarray, k: Mapping[str, float]) -> Candidates:
    """A zoom about the principal point (the zoom model: ``R = I``, ``f1 = 1``, no
    translation): each match's rays are parallel, ``r2 = f2 r1`` in the image plane
    (``x2 = f2 x1`` in the normalised coordinates), so ``f2`` is the least-squares ratio
    ``Σ x1·x2 / Σ x1·x1`` over the matches; none when the matches sit on the principal
    point or the ratio is out of the focal range. One candidate."""
    return _candidates("two_view_zoom", X, k)


def two_view_retinal_translation(X: np.ndarray, k: Mapping[str, float]) -> Candidates:
    """A translation parallel to the retinal plane (``R = I``, ``tz = 0``, focal lengths
    pinned): the calibrated closed form of the nominal camera
    (:func:`~kanagen.runtime.two_view_kernels.retinal_translation`, as
    ``calibrated_retinal_translation``)."""
    return _candidates("two_view_retinal_translation", X, k)


def two_view_retinal_displacement(X: np.ndarray, k: Mapping[str, float]) -> Candidates:
    """A rotation about the optical axis with a translation parallel to the retinal plane
    (focal lengths pinned): the calibrated closed form of the nominal camera
    (:func:`~kanagen.runtime.two_view_kernels.retinal_displacement`, as
    ``calibrated_retinal_displacement``)."""
    return _candidates("two_view_retinal_displacement", X, k)


_CONSTANTS = ("cx", "cy", "f0")  # what the kernels read, in their order


def _kernel(name: str) -> Kernel:
    """The compiled kernel of the registered closed form ``name``, for a search's samples."""
    return Kernel(lambda: twins.twin_address(name), twins.NAMES[name], _CONSTANTS)


for _entry in (
        Initializer("two_view_retinal_translation", two_view_retinal_translation,
                    _TWO_VIEW_Q, _CONSTANTS, 4,
                    two_view_retinal_translation.__doc__.splitlines()[0],
                    kernel=_kernel("two_view_retinal_translation")),
        Initializer("two_view_retinal_displacement", two_view_retinal_displacement,
                    _TWO_VIEW_Q, _CONSTANTS, 4,
                    two_view_retinal_displacement.__doc__.splitlines()[0],
                    kernel=_kernel("two_view_retinal_displacement")),
        Initializer("two_view_fundamental", two_view_fundamental, _TWO_VIEW_Q,
                    _CONSTANTS, 4, two_view_fundamental.__doc__.splitlines()[0],
                    kernel=_kernel("two_view_fundamental")),
        Initializer("two_view_homography", two_view_homography, _TWO_VIEW_Q,
                    _CONSTANTS, 4, two_view_homography.__doc__.splitlines()[0],
                    equivalent=True, kernel=_kernel("two_view_homography")),
        Initializer("two_view_rotation", two_view_rotation, _TWO_VIEW_Q,
                    _CONSTANTS, 4, two_view_rotation.__doc__.splitlines()[0],
                    kernel=_kernel("two_view_rotation")),
        Initializer("two_view_translation", two_view_translation, _TWO_VIEW_Q,
                    _CONSTANTS, 4, two_view_translation.__doc__.splitlines()[0],
                    kernel=_kernel("two_view_translation")),
        Initializer("two_view_zoom", two_view_zoom, _TWO_VIEW_Q, _CONSTANTS, 4,
                    two_view_zoom.__doc__.splitlines()[0], kernel=_kernel("two_view_zoom"))):
    register(_entry)
del _entry
