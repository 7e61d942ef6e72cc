"""Generated two-view scenes with ground truth: 3-D points, two cameras, a motion class,
noise and outliers (for tests, examples and benchmarks of the ``two_view`` family).

Motion classes, named as the family's models: ``none`` (the same camera), ``zoom`` (the
focal length changes), ``rotation`` (about the optical centre), ``translation`` (pure, same
camera), ``planar`` (any motion, a planar scene), ``general`` (any motion and focal
lengths, a 3-D scene), and the report's retinal motions (Fig. 16), the same camera:
``retinal_translation`` (``R = I``, ``t`` parallel to the image plane: rectified stereo) and
``retinal_displacement`` (5–20° about the optical axis and such a ``t``). Camera 1 sits at
the origin; ``X2 = R X1 + t``.

Examples
--------
>>> s = two_view_scene("rotation", n=50, outliers=0.2, seed=3)
>>> s.data.shape, int(s.inliers.sum())
((62, 4), 50)
>>> s.H.shape, s.F is None
((3, 3), True)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .runtime import geometry as g

MOTIONS = ("none", "zoom", "rotation", "translation", "planar", "general",
           "retinal_translation", "retinal_displacement")


@dataclass(frozen=True)
class TwoViewScene:
    """A generated pair of views with everything known."""

    motion: str
    data: np.ndarray  # (N, 4) matches [u, v, u2, v2] in pixels, noisy, outliers included
    clean: np.ndarray  # (N, 4) the inliers without noise (outlier rows: their data)
    inliers: np.ndarray  # (N,) bool
    K1: np.ndarray
    K2: np.ndarray
    R: np.ndarray
    t: np.ndarray  # translation (scene units); zero for none/zoom/rotation
    points: np.ndarray  # (n, 3) the inliers' 3-D points in camera 1's frame
    plane: tuple[np.ndarray, float] | None  # (n, d) with nᵀX = d, for planar scenes
    F: np.ndarray | None  # fundamental matrix (pixels, unit norm); None without translation
    H: np.ndarray | None  # homography (pixels, unit norm); None for a 3-D scene that moves
    size: tuple[int, int]  # image (width, height)
    sigma: float

    @property
    def x1(self) -> np.ndarray:
        return self.data[:, :2]

    @property
    def x2(self) -> np.ndarray:
        return self.data[:, 2:]

    @property
    def constants(self) -> dict[str, float]:
        """The family's constants for these images: principal point at the centre and the
        nominal focal length (and conditioning scale) ``f0`` = the image width."""
        return image_constants(*self.size)

    def params(self) -> dict[str, float]:
        """The true parameter of the two_view family (with :attr:`constants`), as the model
        of the scene's motion class writes it (pinned components at their nominal values).
        The plane comes in units of ``‖t‖``. Where focal lengths are not observable they
        are pinned at ``f0`` (``none``, ``translation``, ``planar``, the retinal motions;
        the first one under ``zoom``), and the direction and plane are those of the nominal
        calibration."""
        f0 = self.constants["f0"]
        f1, f2 = self.K1[0, 0] / f0, self.K2[0, 0] / f0
        R, t, w = self.R, self.t, np.zeros(3)
        norm = np.linalg.norm(t)
        if self.motion in ("none", "zoom"):
            f1, f2 = 1.0, f2 / f1  # only the ratio is observable
        elif self.motion in ("retinal_translation", "retinal_displacement"):
            f1 = f2 = 1.0  # the focal length cancels: the same F at the nominal one
        elif self.motion in ("translation", "planar"):
            # re-expressed at the nominal focal length: same F / H in pixels
            A1, A2 = np.diag([f1, f1, 1.0]), np.diag([f2, f2, 1.0])
            if self.motion == "translation":
                t = A2 @ t  # K t is the epipole: t ∝ K⁻¹ e at f = 1
            else:
                Hn = A2 @ (R + np.outer(t, self.plane[0]) / self.plane[1]) @ np.linalg.inv(A1)
                R, t, w = g.homography_poses(Hn, *self._rays())[0]
            f1 = f2 = 1.0
            norm = np.linalg.norm(t)
        elif self.plane is not None and norm > 0:
            w = self.plane[0] / self.plane[1] * norm
        q = g.quaternion_from_rotation(R)
        t = t / norm if norm > 0 else np.array([1.0, 0.0, 0.0])
        return {"f1": f1, "f2": f2, "qw": q[0], "qx": q[1], "qy": q[2], "qz": q[3],
                "tx": t[0], "ty": t[1], "tz": t[2], "wx": w[0], "wy": w[1], "wz": w[2]}

    def _rays(self):
        c = self.constants
        x = self.clean[self.inliers]
        y1 = np.c_[(x[:, 0] - c["cx"]) / c["f0"], (x[:, 1] - c["cy"]) / c["f0"], np.ones(len(x))]
        y2 = np.c_[(x[:, 2] - c["cx"]) / c["f0"], (x[:, 3] - c["cy"]) / c["f0"], np.ones(len(x))]
        return y1, y2


def image_constants(width: float, height: float) -> dict[str, float]:
    """``cx, cy`` at the image centre and ``f0`` = the width (a 53° field of view)."""
    return {"cx": width / 2.0, "cy": height / 2.0, "f0": float(max(width, height))}


def _camera(focal: float, size) -> np.ndarray:
    return np.array([[focal, 0.0, size[0] / 2.0], [0.0, focal, size[1] / 2.0], [0.0, 0.0, 1.0]])


def _project(K: np.ndarray, X: np.ndarray) -> np.ndarray:
    p = X @ K.T
    return p[:, :2] / p[:, 2:]


def _inside(x: np.ndarray, size, margin: float = 0.0) -> np.ndarray:
    return np.all((x >= margin) & (x <= np.array(size) - margin), axis=1)


def _retinal(rng, motion: str, norm: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(R, t)`` of a retinal motion: ``t`` of norm ``norm`` (None: drawn in 1–2 after its
    direction) in the image plane, in a random direction; ``R`` 5–20° about the optical
    axis (either sense) for a displacement, else the identity."""
    phi = rng.uniform(0.0, 2 * np.pi)
    t = np.array([np.cos(phi), np.sin(phi), 0.0]) * (rng.uniform(1.0, 2.0) if norm is None
                                                     else norm)
    R = np.eye(3)
    if motion == "retinal_displacement":
        R = g.rotation_about([0.0, 0.0, 1.0],
                             rng.choice([-1, 1]) * np.radians(rng.uniform(5.0, 20.0)))
    return R, t


def _rotation(rng, low_deg: float, high_deg: float) -> np.ndarray:
    axis = rng.normal(size=3)
    return g.rotation_about(axis, np.radians(rng.uniform(low_deg, high_deg)))


def _unit(v):
    return v / np.linalg.norm(v)


def two_view_scene(motion: str, n: int = 200, outliers: float = 0.0, sigma: float = 0.5,
                   size: tuple[int, int] = (640, 480), seed: int | None = 0,
                   depth: tuple[float, float] = (4.0, 12.0),
                   on_plane: float = 0.0) -> TwoViewScene:
    """A random scene of one motion class.

    Parameters
    ----------
    motion : str
        One of :data:`MOTIONS`.
    n : int
        Inlier matches (points seen in both images).
    outliers : float
        Fraction of the returned matches that are outliers (random pairs of points), in
        [0, 1).
    sigma : float
        Standard deviation of the Gaussian pixel noise on each coordinate.
    size : (width, height)
        Image size in pixels; the principal points are at the centre.
    seed : int
        Random seed (same seed, same scene).
    depth : (near, far)
        Depths of the 3-D points in camera 1 (the translation has norm 1 to 2).
    on_plane : float
        For ``general``: the fraction of the inliers on one plane (a dominant plane and
        some parallax, as in many real scenes); :attr:`TwoViewScene.plane` is that plane.

    Returns
    -------
    TwoViewScene
    """
    _check_scene(motion, MOTIONS, n, outliers, sigma)
    if not 0.0 <= on_plane <= 1.0 or (on_plane and motion != "general"):
        raise ValueError("on_plane is a fraction in [0, 1], for general scenes only")
    rng = np.random.default_rng(seed)
    width = float(size[0])
    focal1 = width * rng.uniform(0.8, 1.4)
    focal2 = focal1
    R, t, plane = np.eye(3), np.zeros(3), None
    if motion == "zoom":
        focal2 = focal1 * np.exp(rng.choice([-1, 1]) * rng.uniform(np.log(1.15), np.log(1.5)))
    elif motion == "rotation":
        R = _rotation(rng, 5.0, 20.0)
    elif motion == "translation":
        t = _unit(rng.normal(size=3)) * rng.uniform(1.0, 2.0)
    elif motion in ("retinal_translation", "retinal_displacement"):
        R, t = _retinal(rng, motion)
    elif motion in ("planar", "general"):
        R = _rotation(rng, 3.0, 15.0)
        t = _unit(rng.normal(size=3)) * rng.uniform(1.0, 2.0)
        if motion == "general":
            focal2 = focal1 * rng.uniform(0.8, 1.25)
        if motion == "planar" or on_plane:
            normal = _unit(np.array([0.0, 0.0, 1.0]) + 0.5 * rng.normal(size=3))
            plane = (normal, float(rng.uniform(*depth)))
    planar_count = n if motion == "planar" else int(round(on_plane * n))
    K1, K2 = _camera(focal1, size), _camera(focal2, size)
    points = np.r_[_visible(rng, K1, K2, R, t, size, depth, plane, planar_count),
                   _visible(rng, K1, K2, R, t, size, depth, None, n - planar_count)]
    return _observed(TwoViewScene, motion, rng, K1, K2, R, t, points, plane, outliers, sigma,
                     size)


def _observed(kind, motion: str, rng, K1, K2, R, t, points, plane, outliers: float,
              sigma: float, size):
    """The scene ``kind`` (:class:`TwoViewScene` or :class:`CalibratedScene`) of ``points``
    seen by both cameras: their projections with Gaussian noise ``sigma``, random pairs as
    the ``outliers`` share, shuffled; ``F`` when the camera moves (``t ≠ 0``), ``H`` when it
    does not or the scene is planar (``plane``)."""
    n = len(points)
    clean = np.c_[_project(K1, points), _project(K2, points @ R.T + t)]
    noisy = clean + rng.normal(scale=sigma, size=clean.shape)
    n_out = int(round(outliers * n / (1.0 - outliers)))
    junk = np.c_[rng.uniform([0, 0], size, size=(n_out, 2)),
                 rng.uniform([0, 0], size, size=(n_out, 2))]
    order = rng.permutation(n + n_out)
    data = np.r_[noisy, junk][order]
    truth = np.r_[np.ones(n, bool), np.zeros(n_out, bool)][order]
    clean_all = np.r_[clean, junk][order]
    F = H = None
    if np.any(t):
        F = _unit(np.linalg.inv(K2).T @ g.skew(t) @ R @ np.linalg.inv(K1))
    if not np.any(t) or motion == "planar":
        Hc = R if plane is None else R + np.outer(t, plane[0]) / plane[1]
        H = _unit(K2 @ Hc @ np.linalg.inv(K1))
    return kind(motion, data, clean_all, truth, K1, K2, R, t, points, plane, F, H,
                (int(size[0]), int(size[1])), float(sigma))


def _check_scene(motion: str, motions: tuple[str, ...], n: int, outliers: float,
                 sigma: float) -> None:
    if motion not in motions:
        raise ValueError(f"unknown motion {motion!r} (one of {', '.join(motions)})")
    if not 0.0 <= outliers < 1.0:
        raise ValueError(f"outliers is a fraction in [0, 1), got {outliers}")
    if n < 1 or sigma < 0:
        raise ValueError("n must be positive and sigma non-negative")


def _visible(rng, K1, K2, R, t, size, depth, plane, n: int) -> np.ndarray:
    """``n`` 3-D points seen in both images: on ``plane`` if given, else at random depths."""
    points = np.zeros((0, 3))
    for _ in range(100):
        if len(points) == n:
            return points
        m = 4 * n
        x1 = rng.uniform([0, 0], size, size=(m, 2))
        rays = np.c_[x1, np.ones(m)] @ np.linalg.inv(K1).T
        lam = rng.uniform(*depth, size=m) if plane is None else plane[1] / (rays @ plane[0])
        X = rays * lam[:, None]
        X2 = X @ R.T + t
        ok = (lam > 0) & (X2[:, 2] > 0.1)
        ok[ok] &= _inside(_project(K2, X2[ok]), size)
        points = np.r_[points, X[ok]][:n]
    if len(points) == n:
        return points
    raise ValueError(f"could not place {n} points in both images")


def sampson_rms(F: np.ndarray, matches: np.ndarray) -> float:
    """RMS Sampson distance (pixels) of matches ``[u, v, u2, v2]`` to ``p2ᵀ F p1 = 0``."""
    p1, p2 = g.homogeneous(matches[:, :2]), g.homogeneous(matches[:, 2:])
    Fp1, Ftp2 = p1 @ F.T, p2 @ F
    num = np.einsum("ni,ni->n", p2, Fp1) ** 2
    den = Fp1[:, 0] ** 2 + Fp1[:, 1] ** 2 + Ftp2[:, 0] ** 2 + Ftp2[:, 1] ** 2
    return float(np.sqrt(np.mean(num / den)))


def transfer_rms(H: np.ndarray, matches: np.ndarray) -> float:
    """RMS transfer distance (pixels) from ``H p1`` to ``p2``."""
    y = g.homogeneous(matches[:, :2]) @ H.T
    return float(np.sqrt(np.mean(np.sum((y[:, :2] / y[:, 2:] - matches[:, 2:]) ** 2,
                                        axis=1))))


# --- calibrated cameras (the two_view_calibrated family) ---------------------------------

#: Motion classes of the ``two_view_calibrated`` family, named as its models.
CALIBRATED_MOTIONS = ("none", "rotation", "retinal_translation", "translation",
                      "retinal_displacement", "planar", "general")
_INTRINSICS = ("fx", "fy", "cx", "cy")


def camera_matrix(width: float, height: float, focal: float,
                  fy: float | None = None) -> np.ndarray:
    """The 3×3 ``K`` of an image of ``width × height`` pixels with its principal point at the
    centre and the focal length ``focal`` (pixels; ``fy`` the vertical one if it differs).

    >>> camera_matrix(640, 480, 800.0)[:2]
    array([[800.,   0., 320.],
           [  0., 800., 240.]])
    """
    fy = focal if fy is None else fy
    for name, value in (("width", width), ("height", height), ("focal", focal), ("fy", fy)):
        if not (np.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a positive number of pixels, got {value!r}")
    return np.array([[float(focal), 0.0, width / 2.0], [0.0, float(fy), height / 2.0],
                     [0.0, 0.0, 1.0]])


#: A skew at most this share of fx is a calibration's rounding, ignored (it moves a point by
#: at most that share of its distance to the centre in y: 0.03 px at 3000 px from it).
_SKEW = 1e-5


def _intrinsics(K, which: str) -> tuple[float, float, float, float]:
    """``(fx, fy, cx, cy)`` of a 3×3 ``K``, with an error naming what is wrong."""
    try:
        K = np.array(K, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{which} must be a 3×3 matrix of numbers: {exc}") from None
    if K.shape != (3, 3):
        raise ValueError(f"{which} must be a 3×3 matrix, got shape {K.shape}")
    if not np.all(np.isfinite(K)):
        raise ValueError(f"{which} has a non-finite entry: {K.tolist()}")
    if K[2, 0] != 0 or K[2, 1] != 0 or K[1, 0] != 0 or not K[2, 2] != 0:
        raise ValueError(f"{which} must be upper triangular with K[2, 2] != 0 (a pinhole "
                         f"camera [[fx, s, cx], [0, fy, cy], [0, 0, 1]]), got {K.tolist()}")
    K = K / K[2, 2]
    if abs(K[0, 1]) > _SKEW * abs(K[0, 0]):
        raise ValueError(f"{which} has a skew K[0, 1] = {K[0, 1]:g}: the calibrated family "
                         f"models cameras without skew (at most {_SKEW:g} fx, the rounding "
                         f"of a calibration, is ignored)")
    if not (K[0, 0] > 0 and K[1, 1] > 0):
        raise ValueError(f"{which} must have positive focal lengths, got fx = {K[0, 0]:g}, "
                         f"fy = {K[1, 1]:g}")
    return float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])


def calibrated_constants(K1, K2=None) -> dict[str, float]:
    """The constants ``fx1 fy1 cx1 cy1 fx2 fy2 cx2 cy2`` of the ``two_view_calibrated``
    family from the 3×3 intrinsic matrices of the two cameras (``K2`` = ``K1`` when one
    camera took both images); :func:`camera_matrix` makes a ``K`` from an image size and a
    focal length. A ``K`` scaled by ``K[2, 2]`` is accepted, and a skew of at most 1e-5 fx
    (a calibration's rounding, e.g. the Strecha fountain's) is ignored; a larger skew, a
    non-positive focal length, a lower-triangular entry or a non-finite one is an error.

    >>> calibrated_constants(camera_matrix(640, 480, 800.0))["cx2"]
    320.0
    """
    out = {}
    for i, K in ((1, K1), (2, K1 if K2 is None else K2)):
        for name, value in zip(_INTRINSICS, _intrinsics(K, f"K{i}"), strict=True):
            out[f"{name}{i}"] = value
    return out


@dataclass(frozen=True)
class CalibratedScene(TwoViewScene):
    """A generated pair of views of calibrated cameras (``two_view_calibrated``): the same
    fields as :class:`TwoViewScene`; the constants are both cameras' intrinsics."""

    @property
    def constants(self) -> dict[str, float]:
        """``fx1 fy1 cx1 cy1 fx2 fy2 cx2 cy2`` of the two cameras."""
        return calibrated_constants(self.K1, self.K2)

    def params(self) -> dict[str, float]:
        """The true parameter of the ``two_view_calibrated`` family: the unit quaternion of
        ``R``, the unit translation direction (``(1, 0, 0)`` without translation) and, for a
        planar scene, ``w = ‖t‖ n/d``."""
        norm = float(np.linalg.norm(self.t))
        w = np.zeros(3)
        if self.motion == "planar":
            w = self.plane[0] / self.plane[1] * norm
        q = g.quaternion_from_rotation(self.R)
        t = self.t / norm if norm > 0 else np.array([1.0, 0.0, 0.0])
        return {"qw": q[0], "qx": q[1], "qy": q[2], "qz": q[3],
                "tx": t[0], "ty": t[1], "tz": t[2], "wx": w[0], "wy": w[1], "wz": w[2]}

    @property
    def rotation_angle(self) -> float:
        """The true rotation angle (degrees)."""
        return float(np.degrees(np.arccos(np.clip((np.trace(self.R) - 1) / 2, -1.0, 1.0))))

    @property
    def translation_direction(self) -> np.ndarray:
        """The true unit translation (zeros without translation)."""
        norm = np.linalg.norm(self.t)
        return self.t / norm if norm > 0 else np.zeros(3)


def _calibrated_camera(rng, size) -> np.ndarray:
    width, height = size
    fx = width * rng.uniform(0.8, 1.4)
    return np.array([[fx, 0.0, width / 2.0 + rng.uniform(-0.03, 0.03) * width],
                     [0.0, fx * rng.uniform(0.98, 1.02), height / 2.0
                      + rng.uniform(-0.03, 0.03) * height],
                     [0.0, 0.0, 1.0]])


def _off_axis(rng, min_tz: float) -> np.ndarray:
    """A random unit translation with ``|tz| ≥ min_tz``; not a retinal one."""
    while True:
        t = _unit(rng.normal(size=3))
        if abs(t[2]) >= min_tz:
            return t


def calibrated_scene(motion: str, n: int = 200, outliers: float = 0.0, sigma: float = 0.5,
                     size: tuple[int, int] = (640, 480), seed: int | None = 0,
                     depth: tuple[float, float] = (4.0, 12.0)) -> CalibratedScene:
    """A random scene of one calibrated motion class (:data:`CALIBRATED_MOTIONS`), two
    cameras of different known intrinsics (focal lengths 0.8–1.4 × the width, ``fy`` within
    2 % of ``fx``, principal points within 3 % of the centre).

    ``none``: ``R = I``, no translation; ``rotation``: 5–20° about a random axis, no
    translation; ``retinal_translation``: ``R = I``, ``t`` in the retinal plane;
    ``translation``: ``R = I``, ``t`` with ``|tz| ≥ 0.3 ‖t‖``; ``retinal_displacement``:
    5–20° about the optical axis (either sense) and ``t`` in the retinal plane; ``planar``:
    3–15° about a random axis, any ``t``, a plane; ``general``: 3–15°, ``t`` with
    ``|tz| ≥ 0.3 ‖t‖``, 3-D points. Translations have norms 1–2, depths ``depth``. Noise,
    outliers and the returned fields as in :func:`two_view_scene`.
    """
    _check_scene(motion, CALIBRATED_MOTIONS, n, outliers, sigma)
    rng = np.random.default_rng(seed)
    K1, K2 = _calibrated_camera(rng, size), _calibrated_camera(rng, size)
    R, t, plane = np.eye(3), np.zeros(3), None
    norm = rng.uniform(1.0, 2.0)
    if motion == "rotation":
        R = _rotation(rng, 5.0, 20.0)
    elif motion in ("retinal_translation", "retinal_displacement"):
        R, t = _retinal(rng, motion, norm)
    elif motion == "translation":
        t = _off_axis(rng, 0.3) * norm
    elif motion in ("planar", "general"):
        R = _rotation(rng, 3.0, 15.0)
        t = (_unit(rng.normal(size=3)) if motion == "planar" else _off_axis(rng, 0.3)) * norm
        if motion == "planar":
            normal = _unit(np.array([0.0, 0.0, 1.0]) + 0.5 * rng.normal(size=3))
            plane = (normal, float(rng.uniform(*depth)))
    points = _visible(rng, K1, K2, R, t, size, depth, plane, n)
    return _observed(CalibratedScene, motion, rng, K1, K2, R, t, points, plane, outliers,
                     sigma, size)
