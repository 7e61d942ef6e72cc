"""Which matches a calibrated motion admits: those in front of both cameras (cheirality), a
plugin of the registry (:mod:`~kanagen.runtime.initializers`, kind ``"admission"``).

The epipolar equation ``r2ᵀ [t]× R r1 = 0`` holds for a match whose rays meet behind a
camera as well as in front: it is the equation of the motion *and* of its mirror images.
A random match lying near its epipolar line (at 60 % outliers, two or three a scene within
the outlier threshold) fits the equation; about half of them meet behind a camera, where no
point of the scene can be. ``calibrated_in_front`` refuses those — the test that chooses
among the four poses of an essential matrix, applied to each match — where it is decided:
a match whose rays are almost parallel (a far point, or one near the epipole) has depths of
any sign within its noise and is admitted.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from . import geometry as g
from .calibrated_starts import rays
from .initializers import Initializer, register

#: a match's depths decide where the angle between its rays exceeds this many times the
#: angle its noise spans (σ/f for each ray)
_PARALLAX = 3.0


def calibrated_in_front(q: Mapping[str, float], X: np.ndarray, info: np.ndarray,
                        k: Mapping[str, float]) -> np.ndarray:
    """Per match of ``X`` (``[u, v, u2, v2]`` pixels, information ``info``): False where it
    meets behind a camera under the pose ``q`` (``X2 = R X1 + t``) and its rays are far
    enough from parallel for that to be more than its noise."""
    R = g.rotation_from_quaternion([q["qw"], q["qx"], q["qy"], q["qz"]])
    t = np.array([q["tx"], q["ty"], q["tz"]])
    y1, y2 = rays(X, k)
    d1, d2 = g.depths(R, t, y1, y2)
    a = y1 @ R.T  # camera 1's ray in camera 2's frame
    with np.errstate(all="ignore"):
        sine = np.linalg.norm(np.cross(a, y2), axis=1) / (
            np.linalg.norm(a, axis=1) * np.linalg.norm(y2, axis=1))
        trace = np.trace(np.asarray(info, dtype=float), axis1=-2, axis2=-1)
        sigma = np.sqrt(X.shape[1] / trace)  # pixels, from the information's mean
    focal = np.mean([k["fx1"], k["fy1"], k["fx2"], k["fy2"]])
    decided = sine > _PARALLAX * np.sqrt(2.0) * sigma / focal
    return ~(decided & ((d1 < 0) | (d2 < 0)))


register(Initializer("calibrated_in_front", calibrated_in_front,
                     ("qw", "qx", "qy", "qz", "tx", "ty", "tz"),
                     ("fx1", "fy1", "cx1", "cy1", "fx2", "fy2", "cx2", "cy2"), 4,
                     "matches in front of both cameras (cheirality)", kind="admission"))
