"""Loaders of the shared real data: shapes, labels, and the ground truth checked against
itself (GT H maps the annotated points, GT F holds on them, the disparity on its grid).
Skipped when the shared data folder is absent."""

from __future__ import annotations

import numpy as np
import pytest

from kanagen import datasets
from kanagen.evaluation import sampson_errors, transfer_errors


def need(folder: str) -> None:
    if not datasets.available(folder):
        pytest.skip(f"shared data folder {folder} not found")


def test_data_root_errors(tmp_path, monkeypatch):
    monkeypatch.setenv(datasets.DATA_ENV, str(tmp_path / "nowhere"))
    with pytest.raises(FileNotFoundError, match="KANAGEN_DATA"):
        datasets.data_root()
    assert not datasets.available()
    monkeypatch.setenv(datasets.DATA_ENV, str(tmp_path))
    assert datasets.available() and not datasets.available("magsac_cmp")
    with pytest.raises(FileNotFoundError, match="magsac_cmp"):
        datasets.homography_pair("adam")


def test_unknown_names_are_refused():
    need("magsac_cmp")
    with pytest.raises(ValueError, match="choose from"):
        datasets.homography_pair("nope")
    with pytest.raises(ValueError, match="choose from"):
        datasets.fundamental_pair("dino1")  # tentative matches of another pair upstream
    with pytest.raises(ValueError, match="kind"):
        datasets.adelaide_scene("E", "biscuit")


@pytest.mark.parametrize("name", datasets.HOMOGRAPHY_PAIRS)
def test_homography_pairs(name):
    """H (first → second, the inverse of the file's B → A) maps the annotated points within
    2 px, and explains a part of the tentative matches."""
    need("magsac_cmp")
    pair = datasets.homography_pair(name)
    assert pair.matches.ndim == 2 and pair.matches.shape[1] == 4 and len(pair.matches) >= 19
    assert pair.truth.shape == (8, 4)
    assert transfer_errors(pair.H, pair.truth).max() < 2.0
    assert np.mean(transfer_errors(pair.H, pair.matches) < 3.0) > 0.05
    w, h = pair.image_size
    assert np.all(pair.matches[:, 0] <= w) and np.all(pair.matches[:, 1] <= h)


@pytest.mark.parametrize("name", datasets.FUNDAMENTAL_PAIRS)
def test_fundamental_pairs(name):
    """F (transposed from the file's x_Aᵀ F x_B = 0) holds on the annotated points within
    the annotation's accuracy (Sampson error, px); all-zero files give no F."""
    need("magsac_cmp")
    pair = datasets.fundamental_pair(name)
    assert pair.matches.shape[1] == 4 and len(pair.matches) >= 30
    assert 9 <= len(pair.truth) <= 14
    if pair.F is None:
        assert name in {"box", "corr", "graff", "head", "Kyoto", "rotunda", "valbonne",
                        "wash", "zoom"}
        return
    e = sampson_errors(pair.F, pair.truth)
    assert np.median(e) < 1.0 and e.max() < 6.0
    flipped = sampson_errors(pair.F.T, pair.truth)  # the file's own orientation: wrong here
    assert np.median(flipped) > 10 * np.median(e)


def test_oxford_graf():
    """OpenCV's H1to3p and the CMP annotation of the same pair agree (0.1–1.9 px)."""
    need("oxford_graf")
    need("magsac_cmp")
    pair = datasets.oxford_graf()
    assert transfer_errors(pair.H, pair.truth).max() < 2.0
    cmp = datasets.homography_pair("graf")
    assert transfer_errors(pair.H, cmp.truth).max() < 2.0
    assert all(p.is_file() for p in pair.images)


def test_middlebury():
    need("middlebury_motorcycle_skimage")
    stereo = datasets.middlebury_motorcycle()
    assert stereo.disparity.shape == (500, 741) and stereo.image_size == (741, 500)
    known = stereo.disparity[np.isfinite(stereo.disparity)]
    assert 0.9 < known.size / stereo.disparity.size < 0.95
    assert 7.0 < known.min() and known.max() < 60.0
    truth = stereo.truth(step=25)
    assert np.all(truth[:, 1] == truth[:, 3]) and np.all(truth[:, 2] < truth[:, 0])
    assert np.nanmax(stereo.disparity_errors(truth)) < 1e-9
    assert sampson_errors(stereo.F, truth).max() == 0.0
    # half way between two grid pixels the disparity is their mean
    r, c = 200, 300
    d = stereo.disparity[r, c:c + 2]
    assert stereo.disparity_at(np.array([c + 0.5]), np.array([r]))[0] == pytest.approx(
        d.mean())
    assert np.isnan(stereo.disparity_at(np.array([-1.0]), np.array([0.0]))[0])


@pytest.mark.parametrize("kind, names", [("H", datasets.ADELAIDE_H),
                                         ("F", datasets.ADELAIDE_F)])
def test_adelaide(kind, names):
    need("adelaidermf")
    scenes = datasets.adelaide_scenes(kind)
    assert [s.name for s in scenes] == list(names) and len(scenes) == 19
    for s in scenes:
        assert s.kind == kind and s.matches.shape == (s.labels.size, 4)
        assert s.labels.min() == 0 and 1 <= s.structures <= 7
        assert sorted(set(s.labels.tolist())) == list(range(s.structures + 1))
    by_name = {s.name: s for s in scenes}
    if kind == "H":
        # the original unionhouse (not the copy of unihouse at RCMSA's HEAD)
        assert np.bincount(by_name["unionhouse"].labels).tolist() == [254, 78]
        assert by_name["johnsonb"].structures == 7 and by_name["johnsona"].image_size is None
    else:
        assert by_name["breadcartoychips"].structures == 4


def test_adelaide_structures_are_homographies():
    """Each labelled plane of an H scene is one homography (DLT on its points, < 3 px RMS
    for most points), an independent check of the loader's column order."""
    need("adelaidermf")
    scene = datasets.adelaide_scene("H", "barrsmith")
    for k in range(1, scene.structures + 1):
        m = scene.matches[scene.labels == k]
        H = dlt_homography(m)
        assert np.median(transfer_errors(H, m)) < 1.5


def dlt_homography(m: np.ndarray) -> np.ndarray:
    """Normalised DLT (Hartley & Zisserman, alg. 4.2)."""
    def normaliser(p):
        c = p.mean(axis=0)
        s = np.sqrt(2) / np.mean(np.linalg.norm(p - c, axis=1))
        return np.array([[s, 0, -s * c[0]], [0, s, -s * c[1]], [0, 0, 1]])
    T1, T2 = normaliser(m[:, :2]), normaliser(m[:, 2:])
    p1 = np.c_[m[:, :2], np.ones(len(m))] @ T1.T
    p2 = np.c_[m[:, 2:], np.ones(len(m))] @ T2.T
    rows = []
    for a, b in zip(p1, p2, strict=True):
        rows.append(np.r_[np.zeros(3), -b[2] * a, b[1] * a])
        rows.append(np.r_[b[2] * a, np.zeros(3), -b[0] * a])
    H = np.linalg.svd(np.array(rows))[2][-1].reshape(3, 3)
    return np.linalg.inv(T2) @ H @ T1
