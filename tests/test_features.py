"""OpenCV feature matching (the optional ``examples`` extra), checked against ground truth:
the Middlebury disparity and Oxford's H1to3p."""

from __future__ import annotations

import numpy as np
import pytest

from kanagen import datasets
from kanagen.evaluation import transfer_errors

cv2 = pytest.importorskip("cv2")
from kanagen.features import match_features  # noqa: E402


def test_middlebury_matches_agree_with_the_disparity():
    if not datasets.available("middlebury_motorcycle_skimage"):
        pytest.skip("Middlebury data not found")
    stereo = datasets.middlebury_motorcycle()
    matches = match_features(stereo.left, stereo.right, "sift")
    errors = stereo.disparity_errors(matches)
    known = np.isfinite(errors)
    assert len(matches) > 500 and known.sum() > 0.8 * len(matches)
    assert np.mean(errors[known] < 1.0) > 0.75  # 688 of 798 on this machine
    # rectified: most matches on the same row
    assert np.median(np.abs(matches[:, 3] - matches[:, 1])) < 0.5
    pair = stereo.as_pair(matches)
    assert pair.matches.shape == matches.shape and pair.F.shape == (3, 3)


def test_graf_matches_agree_with_h1to3p():
    if not datasets.available("oxford_graf"):
        pytest.skip("Oxford graf data not found")
    pair = datasets.oxford_graf()
    matches = match_features(*pair.images, detector="orb", ratio=0.8)
    assert np.count_nonzero(transfer_errors(pair.H, matches) < 3.0) > 50


def test_bad_arguments():
    img = np.zeros((20, 20), np.uint8)
    with pytest.raises(ValueError, match="detector"):
        match_features(img, img, detector="surf")
    with pytest.raises(ValueError, match="ratio"):
        match_features(img, img, ratio=0.0)
    with pytest.raises(ValueError, match="cannot read"):
        match_features("/nonexistent.png", img)
    assert match_features(img, img).shape == (0, 4)  # no texture, no keypoints
