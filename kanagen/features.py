"""Tentative correspondences between two images with OpenCV features (optional extra).

Needs ``opencv-python-headless``: ``pip install "kanagen[examples]"``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

#: The detectors offered, with the norm their descriptors are compared with.
DETECTORS = ("sift", "orb")


def _cv2():
    try:
        import cv2
    except ImportError:
        raise ImportError('feature matching needs OpenCV: pip install "kanagen[examples]" '
                          "(opencv-python-headless)") from None
    return cv2


def read_gray(image: str | Path | np.ndarray) -> np.ndarray:
    """An 8-bit grey image from a file name or an array (RGB/BGR arrays are converted)."""
    cv2 = _cv2()
    if isinstance(image, (str, Path)):
        out = cv2.imread(str(image), cv2.IMREAD_GRAYSCALE)
        if out is None:
            raise ValueError(f"cannot read an image from {image}")
        return out
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] in (3, 4):
        img = cv2.cvtColor(img[..., :3].astype(np.uint8), cv2.COLOR_BGR2GRAY)
    if img.ndim != 2:
        raise ValueError(f"an image must be (H, W) or (H, W, 3), got {img.shape}")
    return img.astype(np.uint8)


def match_features(image1, image2, detector: str = "sift", ratio: float = 0.75,
                   max_features: int = 4000, mutual: bool = True) -> np.ndarray:
    """Correspondences ``[u, v, u2, v2]`` (pixels) between two images.

    Keypoints and descriptors by SIFT (L2) or ORB (Hamming); each descriptor of the first
    image keeps its nearest neighbour in the second when it is closer than ``ratio`` times
    the second nearest (Lowe's ratio test); with ``mutual``, only pairs that are each
    other's nearest neighbours are kept.

    Parameters
    ----------
    image1, image2 : file names or arrays
    detector : ``"sift"`` or ``"orb"``
    ratio : float in (0, 1]
    max_features : int
        Keypoints kept per image (strongest first).

    Returns
    -------
    ndarray (N, 4)
    """
    if detector not in DETECTORS:
        raise ValueError(f"unknown detector {detector!r}; choose from {DETECTORS}")
    if not 0 < ratio <= 1:
        raise ValueError(f"ratio must be in (0, 1], got {ratio}")
    cv2 = _cv2()
    g1, g2 = read_gray(image1), read_gray(image2)
    if detector == "sift":
        det, norm = cv2.SIFT_create(nfeatures=max_features), cv2.NORM_L2
    else:
        det, norm = cv2.ORB_create(nfeatures=max_features), cv2.NORM_HAMMING
    k1, d1 = det.detectAndCompute(g1, None)
    k2, d2 = det.detectAndCompute(g2, None)
    if d1 is None or d2 is None or len(k1) < 2 or len(k2) < 2:
        return np.zeros((0, 4))
    matcher = cv2.BFMatcher(norm)
    forward = matcher.knnMatch(d1, d2, k=2)
    backward = {m.queryIdx: m.trainIdx for m in matcher.match(d2, d1)} if mutual else None
    rows = []
    for pair in forward:
        if len(pair) < 2:
            continue
        best, second = pair
        if best.distance >= ratio * second.distance:
            continue
        if backward is not None and backward.get(best.trainIdx) != best.queryIdx:
            continue
        rows.append((*k1[best.queryIdx].pt, *k2[best.trainIdx].pt))
    return np.array(rows, dtype=float).reshape(-1, 4)
