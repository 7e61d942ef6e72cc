"""Real two-view data of the shared data folder (never copied into the repository).

The data root is ``$KANAGEN_DATA`` when set, else ``../shared/data`` beside the project root
(each folder there has a ``PROVENANCE.txt``). Every loader returns correspondences in the
convention of the ``two_view`` family: rows ``[u, v, u2, v2]`` in pixels, first image then
second, ``p2 ~ H p1`` and ``p2ᵀ F p1 = 0`` with ``p = (u, v, 1)``. The files' own
conventions are converted here, once:

* CMP ``homography/*_model.txt`` maps B → A (``x_A ~ H x_B``): ``H`` here is its inverse.
* CMP ``fundamental_matrix/*_model.txt`` has ``x_Aᵀ F x_B = 0``: ``F`` here is its
  transpose. For box, corr, graff, head, Kyoto, rotunda, valbonne, wash and zoom the file
  is all zeros: ``F`` is None and the ground truth is the annotated points (``truth``).
* Oxford ``H1to3p`` maps graf1 → graf3 (already our direction).
* Middlebury: the disparity is on the left grid; left ``(r, c)`` ↔ right ``(r, c − d)``.
* AdelaideRMF: ``label`` 0 is a gross outlier, ``k ≥ 1`` structure ``k``. ``unionhouse`` is
  the original one (332 points); ``johnsona``/``johnsonb`` come as text.

Examples
--------
>>> from kanagen import datasets
>>> if datasets.available():
...     pair = datasets.homography_pair("adam")
...     assert pair.matches.shape[1] == 4 and pair.H.shape == (3, 3)
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: Environment variable naming the data root.
DATA_ENV = "KANAGEN_DATA"

#: The CMP ``homogr`` pairs (planar scenes; ground-truth points and H).
HOMOGRAPHY_PAIRS = ("adam", "boat", "Boston", "BostonLib", "BruggeSquare", "BruggeTower",
                    "Brussels", "CapitalRegion", "city", "Eiffel", "ExtremeZoom", "graf",
                    "LePoint1", "LePoint2", "LePoint3", "WhiteBoard")

#: The CMP ``kusvod2`` pairs (non-planar scenes; ground-truth points, some with F).
#: The upstream folder also has Brussels, Dresden, Leuven1/2, dino1/2 and temple1/2: their
#: tentative matches are those of booksh, box, castle, corr, graff, head, kampa and Kyoto
#: (a copy error of ``makeInput.m``, which wrote ``input(i)`` of the kusvod2 list), so they
#: are not offered.
FUNDAMENTAL_PAIRS = ("booksh", "box", "castle", "corr", "graff", "head", "kampa", "Kyoto",
                     "leafs", "plant", "rotunda", "shout", "valbonne", "wall", "wash", "zoom")

#: AdelaideRMF multi-structure scenes: several planes (H) or several motions (F).
ADELAIDE_H = ("barrsmith", "bonhall", "bonython", "elderhalla", "elderhallb", "hartley",
              "johnsona", "johnsonb", "ladysymon", "library", "napiera", "napierb", "neem",
              "nese", "oldclassicswing", "physics", "sene", "unihouse", "unionhouse")
ADELAIDE_F = ("biscuit", "biscuitbook", "biscuitbookbox", "boardgame", "book",
              "breadcartoychips", "breadcube", "breadcubechips", "breadtoy", "breadtoycar",
              "carchipscube", "cube", "cubebreadtoychips", "cubechips", "cubetoy", "dinobooks",
              "game", "gamebiscuit", "toycubecar")

_CMP = "magsac_cmp"
_ADELAIDE = "adelaidermf"
_GRAF = "oxford_graf"
_MIDDLEBURY = "middlebury_motorcycle_skimage"


@dataclass(frozen=True)
class TwoViewPair:
    """One image pair: tentative matches and what is known of the truth.

    Attributes
    ----------
    name : str
    matches : ndarray (N, 4)
        Tentative correspondences ``[u, v, u2, v2]`` (SIFT matches, inliers unknown).
    truth : ndarray (n, 4)
        Manually annotated correspondences (ground truth), same layout.
    image_size : (width, height) of the first image, or None when unknown.
    H, F : ndarray (3, 3) or None
        Ground-truth homography (``p2 ~ H p1``) or fundamental matrix (``p2ᵀ F p1 = 0``).
    images : (Path, Path) or None
        The two image files when the data folder has them.
    """

    name: str
    matches: np.ndarray
    truth: np.ndarray
    image_size: tuple[int, int] | None = None
    H: np.ndarray | None = None
    F: np.ndarray | None = None
    images: tuple[Path, Path] | None = None

    @property
    def centre(self) -> tuple[float, float]:
        """The principal point guess ``(cx, cy)``: the image centre, else the centre of the
        matches' bounding box in the first image."""
        return _centre(self.image_size, self.matches)


@dataclass(frozen=True)
class CalibratedPair:
    """An image pair with the intrinsics of both cameras and no ground truth (the Strecha
    fountain pair of the CMP essential-matrix set).

    Attributes
    ----------
    name : str
    matches : ndarray (N, 4)
        Tentative correspondences ``[u, v, u2, v2]`` in pixels (inliers unknown).
    K1, K2 : ndarray (3, 3)
        The intrinsic matrices of the two cameras, as the files give them.
    image_size : (width, height) of the first image.
    images : (Path, Path)
    """

    name: str
    matches: np.ndarray
    K1: np.ndarray
    K2: np.ndarray
    image_size: tuple[int, int]
    images: tuple[Path, Path]


@dataclass(frozen=True)
class MultiStructureScene:
    """An AdelaideRMF scene: matches, each labelled 0 (gross outlier) or its structure k ≥ 1.

    Attributes
    ----------
    name : str
    kind : ``"H"`` (planes) or ``"F"`` (motions)
    matches : ndarray (N, 4) ``[u, v, u2, v2]``
    labels : ndarray (N,) int
    image_size : (width, height) of the first image, or None when unknown.
    """

    name: str
    kind: str
    matches: np.ndarray
    labels: np.ndarray
    image_size: tuple[int, int] | None = None

    @property
    def structures(self) -> int:
        """The number of labelled structures."""
        return int(np.unique(self.labels[self.labels > 0]).size)

    @property
    def centre(self) -> tuple[float, float]:
        """``(cx, cy)``: the image centre, else the centre of the matches' bounding box."""
        return _centre(self.image_size, self.matches)


@dataclass(frozen=True)
class StereoPair:
    """The Middlebury 2014 Motorcycle rectified pair (downsampled ×4, from scikit-image).

    Attributes
    ----------
    left, right : Path
        The image files (741×500 RGB PNG).
    disparity : ndarray (500, 741)
        Ground-truth disparity on the left grid, NaN where unknown: left ``(r, c)`` ↔
        right ``(r, c − d)``.
    focal, cx, cy, doffs, baseline : float
        Calibration (pixels; baseline in mm); the right principal point is ``cx + doffs``.
    """

    left: Path
    right: Path
    disparity: np.ndarray
    focal: float = 994.978
    cx: float = 311.193
    cy: float = 254.877
    doffs: float = 31.086
    baseline: float = 193.001

    @property
    def image_size(self) -> tuple[int, int]:
        return self.disparity.shape[1], self.disparity.shape[0]

    @property
    def F(self) -> np.ndarray:
        """The exact fundamental matrix of a rectified pair: ``v2 = v``."""
        return np.array([[0.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])

    def truth(self, step: int = 20) -> np.ndarray:
        """Ground-truth correspondences ``[u, v, u − d, v]`` on a grid of ``step`` pixels,
        where the disparity is known."""
        if step < 1:
            raise ValueError(f"step must be a positive number of pixels, got {step}")
        rows, cols = np.mgrid[0:self.disparity.shape[0]:step, 0:self.disparity.shape[1]:step]
        d = self.disparity[rows, cols]
        keep = np.isfinite(d)
        u, v, d = cols[keep].astype(float), rows[keep].astype(float), d[keep].astype(float)
        return np.c_[u, v, u - d, v]

    def disparity_at(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """The ground-truth disparity at sub-pixel left positions (bilinear; NaN where a
        neighbour is unknown or the point is outside the image)."""
        u, v = np.asarray(u, dtype=float), np.asarray(v, dtype=float)
        h, w = self.disparity.shape
        inside = (u >= 0) & (v >= 0) & (u <= w - 1) & (v <= h - 1)
        c0 = np.clip(np.floor(u), 0, w - 2).astype(int)
        r0 = np.clip(np.floor(v), 0, h - 2).astype(int)
        a, b = u - c0, v - r0
        out = np.zeros(u.shape)
        for dr, dc, weight in ((0, 0, (1 - a) * (1 - b)), (0, 1, a * (1 - b)),
                               (1, 0, (1 - a) * b), (1, 1, a * b)):
            d = self.disparity[np.clip(r0 + dr, 0, h - 1), np.clip(c0 + dc, 0, w - 1)]
            out += np.where(weight > 0, weight * d, 0.0)  # a weightless unknown is no NaN
        return np.where(inside, out, np.nan)

    def as_pair(self, matches: np.ndarray, step: int = 20) -> TwoViewPair:
        """The pair with the given tentative ``matches`` (e.g. from
        :func:`kanagen.features.match_features`), the disparity grid as ``truth`` and the
        exact ``F``."""
        return TwoViewPair("motorcycle", _as_matches(matches, "matches"), self.truth(step),
                           self.image_size, F=self.F, images=(self.left, self.right))

    def disparity_errors(self, matches: np.ndarray) -> np.ndarray:
        """Per match, the distance (px) of its second point from the ground truth's:
        ``hypot(u2 − (u − d(u, v)), v2 − v)``; NaN where the disparity is unknown."""
        m = _as_matches(matches, "matches")
        d = self.disparity_at(m[:, 0], m[:, 1])
        return np.hypot(m[:, 2] - (m[:, 0] - d), m[:, 3] - m[:, 1])


def data_root(root: str | Path | None = None) -> Path:
    """The shared data folder: ``root``, else ``$KANAGEN_DATA``, else ``../shared/data``
    beside the project root. Raises FileNotFoundError when it does not exist."""
    if root is None:
        root = os.environ.get(DATA_ENV) or Path(__file__).resolve().parents[1].parent / \
            "shared" / "data"
    path = Path(root)
    if not path.is_dir():
        raise FileNotFoundError(f"shared data not found at {path} (set ${DATA_ENV} to the "
                                "folder holding magsac_cmp/, adelaidermf/, ...)")
    return path


def available(folder: str | None = None, root: str | Path | None = None) -> bool:
    """True when the data root (and ``folder`` in it, if given) exists."""
    try:
        base = data_root(root)
    except FileNotFoundError:
        return False
    return folder is None or (base / folder).is_dir()


def homography_pair(name: str, root: str | Path | None = None) -> TwoViewPair:
    """A CMP ``homogr`` pair: SIFT matches, annotated points and H (first → second)."""
    folder = _folder(_CMP, root) / "homography"
    matches, truth, imsize = _cmp_pair(folder, _pick(name, HOMOGRAPHY_PAIRS, "homography"))
    H_BA = _read_matrix(folder / f"{name}_model.txt")
    H = np.linalg.inv(H_BA)
    return TwoViewPair(name, matches, truth, imsize, H=H / H[2, 2],
                       images=_images(folder, name))


def fundamental_pair(name: str, root: str | Path | None = None) -> TwoViewPair:
    """A CMP ``kusvod2`` pair: SIFT matches, annotated points and F when the file has one."""
    folder = _folder(_CMP, root) / "fundamental_matrix"
    matches, truth, imsize = _cmp_pair(folder, _pick(name, FUNDAMENTAL_PAIRS, "fundamental"))
    F_AB = _read_matrix(folder / f"{name}_model.txt")
    F = None if not np.any(F_AB) else F_AB.T / np.linalg.norm(F_AB)
    return TwoViewPair(name, matches, truth, imsize, F=F, images=_images(folder, name))


def strecha_fountain(root: str | Path | None = None) -> CalibratedPair:
    """The Strecha fountain pair of the CMP ``essential_matrix`` set: 270 tentative matches
    and the K of each camera (``fountain1.K``, ``fountain2.K``)."""
    folder = _folder(_CMP, root) / "essential_matrix"
    path = _exists(folder / "fountain_pts.txt")
    rows = np.loadtxt(path, skiprows=1, ndmin=2)  # a count, then x1 y1 x2 y2 per row
    if rows.shape[1] != 4 or not np.all(np.isfinite(rows)):
        raise ValueError(f"{path}: expected rows of 4 finite numbers, got {rows.shape}")
    images = (_exists(folder / "fountain1.jpg"), _exists(folder / "fountain2.jpg"))
    return CalibratedPair("fountain", rows, _read_matrix(folder / "fountain1.K"),
                          _read_matrix(folder / "fountain2.K"), _jpeg_size(images[0]), images)


def _jpeg_size(path: Path) -> tuple[int, int]:
    """(width, height) of a JPEG from its frame header (no image library needed)."""
    data = path.read_bytes()
    i = 2
    while i + 9 <= len(data) and data[i] == 0xFF:
        marker, length = data[i + 1], int.from_bytes(data[i + 2:i + 4], "big")
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):
            return (int.from_bytes(data[i + 7:i + 9], "big"),
                    int.from_bytes(data[i + 5:i + 7], "big"))
        i += 2 + length
    raise ValueError(f"{path}: no JPEG frame header")


def oxford_graf(root: str | Path | None = None) -> TwoViewPair:
    """The Oxford graffiti pair img1 → img3 with OpenCV's ``H1to3p``; matches and annotated
    points from the CMP copy of the same pair."""
    folder = _folder(_GRAF, root)
    cmp = homography_pair("graf", root)
    H = _read_opencv_matrix(folder / "H1to3p.xml", "H13")
    return TwoViewPair("oxford_graf", cmp.matches, cmp.truth, cmp.image_size, H=H,
                       images=(folder / "graf1.png", folder / "graf3.png"))


def middlebury_motorcycle(root: str | Path | None = None) -> StereoPair:
    """The Middlebury Motorcycle rectified pair with its ground-truth disparity."""
    folder = _folder(_MIDDLEBURY, root)
    path = folder / "motorcycle_disp.npz"
    _exists(path)
    with np.load(path, allow_pickle=False) as npz:
        disparity = np.asarray(npz["arr_0"], dtype=float)
    disparity[~np.isfinite(disparity)] = np.nan  # unknown pixels are stored as +inf
    return StereoPair(_exists(folder / "motorcycle_left.png"),
                      _exists(folder / "motorcycle_right.png"), disparity)


def adelaide_scene(kind: str, name: str, root: str | Path | None = None) -> MultiStructureScene:
    """An AdelaideRMF scene, ``kind`` ``"H"`` (planes) or ``"F"`` (motions)."""
    if kind not in ("H", "F"):
        raise ValueError(f"kind must be 'H' or 'F', got {kind!r}")
    folder = _folder(_ADELAIDE, root)
    _pick(name, ADELAIDE_H if kind == "H" else ADELAIDE_F, f"AdelaideRMF {kind}")
    if name in ("johnsona", "johnsonb"):
        rows = _read_rows(folder / "H_txt_from_magsac" / f"{name}_pts.txt", 7)
        return MultiStructureScene(name, kind, rows[:, [0, 1, 3, 4]],
                                   rows[:, 6].astype(int), None)
    from scipy.io import loadmat

    path = _exists(folder / kind / f"{name}.mat")
    mat = loadmat(path, variable_names=("data", "label", "img1"))
    data = np.asarray(mat["data"], dtype=float)
    labels = np.asarray(mat["label"]).ravel().astype(int)
    if data.shape[0] != 6 or data.shape[1] != labels.size:
        raise ValueError(f"{path}: expected data (6, N) and label (1, N), got "
                         f"{data.shape} and {labels.shape}")
    h, w = mat["img1"].shape[:2]
    return MultiStructureScene(name, kind, data[[0, 1, 3, 4]].T.copy(), labels, (w, h))


def adelaide_scenes(kind: str, root: str | Path | None = None) -> list[MultiStructureScene]:
    """Every AdelaideRMF scene of ``kind`` (``"H"`` or ``"F"``), in name order."""
    names = ADELAIDE_H if kind == "H" else ADELAIDE_F
    return [adelaide_scene(kind, n, root) for n in names]


# -- file helpers -------------------------------------------------------------------------------

def _folder(name: str, root) -> Path:
    path = data_root(root) / name
    if not path.is_dir():
        raise FileNotFoundError(f"{path} not found: the shared data lacks {name}/")
    return path


def _exists(path: Path) -> Path:
    if not path.is_file():
        raise FileNotFoundError(f"{path} not found")
    return path


def _pick(name: str, names: tuple[str, ...], what: str) -> str:
    if name not in names:
        raise ValueError(f"unknown {what} pair {name!r}; choose from {', '.join(names)}")
    return name


def _read_rows(path: Path, width: int) -> np.ndarray:
    rows = np.loadtxt(_exists(path), ndmin=2)
    if rows.shape[1] != width or not np.all(np.isfinite(rows)):
        raise ValueError(f"{path}: expected rows of {width} finite numbers, got {rows.shape}")
    return rows


def _read_matrix(path: Path) -> np.ndarray:
    m = np.loadtxt(_exists(path))
    if m.shape != (3, 3) or not np.all(np.isfinite(m)):
        raise ValueError(f"{path}: expected a finite 3×3 matrix, got shape {m.shape}")
    return m


def _read_opencv_matrix(path: Path, node: str) -> np.ndarray:
    """The 3×3 ``<data>`` of an OpenCV FileStorage XML node, parsed as numbers only."""
    import xml.etree.ElementTree as ET

    data = ET.parse(_exists(path)).getroot().find(f"{node}/data")
    values = np.array((data.text or "").split(), dtype=float) if data is not None else []
    if len(values) != 9:
        raise ValueError(f"{path}: node {node} does not hold a 3×3 matrix")
    return values.reshape(3, 3)


def _cmp_pair(folder: Path, name: str) -> tuple[np.ndarray, np.ndarray, tuple[int, int]]:
    """Tentative matches (flag 0), annotated points (flag 1) and the first image's size."""
    from scipy.io import loadmat

    rows = _read_rows(folder / f"{name}_pts.txt", 7)
    matches = rows[rows[:, 6] == 0][:, [0, 1, 3, 4]]
    truth = rows[rows[:, 6] == 1][:, [0, 1, 3, 4]]
    vpts = loadmat(_exists(folder / f"{name}_vpts.mat"), squeeze_me=True,
                   struct_as_record=False)["validation"]
    if not np.allclose(np.asarray(vpts.pts, dtype=float)[[0, 1, 3, 4]].T, truth):
        raise ValueError(f"{folder / name}: annotated points of _pts.txt and _vpts.mat differ")
    height, width = (int(x) for x in np.ravel(vpts.imsize)[:2])  # imsize is (rows, cols)
    return matches, truth, (width, height)


def _images(folder: Path, name: str) -> tuple[Path, Path] | None:
    for ext in ("png", "jpg"):
        a, b = folder / f"{name}A.{ext}", folder / f"{name}B.{ext}"
        if a.is_file() and b.is_file():
            return a, b
    return None


def nominal_constants(scene) -> dict[str, float]:
    """The ``two_view`` family's constants for a scene or pair (anything with ``centre`` and
    ``image_size``): ``cx, cy`` its centre, ``f0`` the larger side of its image (twice the
    centre's coordinates where the size is unknown) — a nominal focal length."""
    from .scenes import image_constants

    cx, cy = scene.centre
    return image_constants(*(scene.image_size or (2 * cx, 2 * cy)))


def _centre(image_size, matches: np.ndarray) -> tuple[float, float]:
    if image_size is not None:
        return image_size[0] / 2.0, image_size[1] / 2.0
    lo, hi = matches[:, :2].min(axis=0), matches[:, :2].max(axis=0)
    return float((lo[0] + hi[0]) / 2), float((lo[1] + hi[1]) / 2)


def _as_matches(matches, what: str) -> np.ndarray:
    m = np.asarray(matches, dtype=float)
    if m.ndim != 2 or m.shape[1] != 4:
        raise ValueError(f"{what} must be an (N, 4) array of [u, v, u2, v2], got {m.shape}")
    return m
