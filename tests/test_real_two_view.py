"""Small fits of the two-view family on the shared real data, checked against ground truth
the fits never see (annotated points, the Middlebury disparity, AdelaideRMF labels).
Skipped when the shared data are absent."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

import kanagen
from kanagen import datasets
from kanagen.evaluation import misclassification, sampson_errors, transfer_errors

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "experiments"))


@pytest.fixture(scope="module")
def fam():
    return kanagen.load("two_view")


def rms(e):
    return float(np.sqrt(np.mean(np.square(e))))


def need(folder):
    if not datasets.available(folder):
        pytest.skip(f"shared data folder {folder} not found")


@pytest.mark.parametrize("name", ["adam", "boat"])
def test_planar_fit_of_a_cmp_pair(fam, name):
    """The planar model on SIFT matches with outliers: its H maps the annotated points
    within 2 px RMS (the ground-truth H itself: 0)."""
    need("magsac_cmp")
    pair = datasets.homography_pair(name)
    est = kanagen.robust_fit(fam, "planar", data={"match": pair.matches}, info={"match": 1.0},
                             scale=9.0, constants=datasets.nominal_constants(pair), max_samples=200)
    H = est.fit.derived["H"].value
    assert rms(transfer_errors(H, pair.truth)) < 2.0
    inlier = np.zeros(len(pair.matches), bool)
    inlier[est.inliers["match"]] = True
    truly = transfer_errors(pair.H, pair.matches) < 3.0  # inliers of the ground truth
    assert np.count_nonzero(inlier & truly) >= 0.9 * np.count_nonzero(truly)


def test_general_fit_of_a_kusvod2_pair(fam):
    """The general model on booksh: the annotated points lie within 1 px (Sampson RMS) of
    its epipolar geometry, as close as the shipped ground-truth F's 0.56 px allows."""
    need("magsac_cmp")
    pair = datasets.fundamental_pair("booksh")
    est = kanagen.robust_fit(fam, "general", data={"match": pair.matches},
                             info={"match": 1.0}, scale=9.0,
                             constants=datasets.nominal_constants(pair), max_samples=300)
    F = est.fit.derived["F"].value
    assert rms(sampson_errors(F, pair.truth)) < 1.0
    assert rms(sampson_errors(pair.F, pair.truth)) < 0.6


def test_lattice_names_a_planar_scene(fam):
    need("magsac_cmp")
    pair = datasets.homography_pair("adam")
    est = kanagen.Estimator(fam, scale=9.0, seed=0, constants=datasets.nominal_constants(pair),
                            adaptive=True)
    est.add_measures("match", pair.matches, info=1.0)
    assert est.run(max_samples=3000).model == "planar"


def test_lattice_names_the_rectified_pair_a_retinal_translation(fam):
    """Middlebury Motorcycle: ground-truth correspondences from the disparity (σ = 0.3 px
    added) are a translation parallel to the image plane (the report's "pure retinal
    translation", Fig. 16); the lattice at its defaults must say so, and its F is the
    rectified pair's (v2 = v) to within a tenth of a pixel."""
    need("middlebury_motorcycle_skimage")
    stereo = datasets.middlebury_motorcycle()
    truth = stereo.truth(step=60)
    matches = truth + np.random.default_rng(0).normal(0.0, 0.3, truth.shape)
    est = kanagen.Estimator(fam, seed=0,
                            constants={"cx": stereo.cx, "cy": stereo.cy, "f0": stereo.focal})
    est.add_measures("match", matches, info=1 / 0.3**2)
    best = est.run(max_samples=3000)
    assert best.model == "retinal_translation"
    assert abs(best.derived["translation_direction"].value[0]) > 0.999
    assert rms(sampson_errors(best.derived["F"].value, truth)) < 0.1


def test_adelaide_metric_and_peers():
    """One scene of each kind through experiments/adelaide.py: kanagen's misclassification
    with the known number of structures, and sequential OpenCV MAGSAC's, both scored by
    the best-matching metric."""
    need("adelaidermf")
    cv2 = pytest.importorskip("cv2")
    import adelaide

    fam = kanagen.load("two_view")
    scene = datasets.adelaide_scene("F", "book")
    labels, found = adelaide.kanagen_labels(fam, scene, samples=300, restarts=1)
    assert found == 1 and misclassification(scene.labels, labels) < 0.05
    assert cv2 is not None
    magsac = adelaide.magsac_labels(scene, 2.0)
    assert set(np.unique(magsac)) <= {0, 1}
    assert misclassification(scene.labels, magsac) < 0.10
    results = [adelaide.SceneResult("F", name, 187, 1, 0.44, share, 1, 1.0,
                                    {"1": 0.1, "2": magsac}, 0.01)
               for name, share, magsac in (("a", 0.02, 0.03), ("b", 0.01, 0.05),
                                           ("c", 0.09, 0.01))]
    text, means = adelaide.report(results)
    assert "floor: kanagen 4.0 % < sequential MAGSAC 3.0 %" in text and "NOT met" in text
    assert means["F"]["magsac_best"] == pytest.approx(3.0)
    assert means["F"]["kanagen_median"] == pytest.approx(2.0)


@pytest.mark.parametrize("kind, name", [("H", "oldclassicswing"), ("F", "cubetoy")])
def test_adelaide_count_unknown(kind, name):
    """Without the number of structures (find_structures' default max_structures, 5), a
    scene of two structures gives two: the matches labelled outliers make none that is
    more than chance (before the a-contrario test: 4 and 3, at 7.7 % and 8.8 %)."""
    need("adelaidermf")
    import adelaide

    scene = datasets.adelaide_scene(kind, name)
    labels, found = adelaide.kanagen_labels(kanagen.load("two_view"), scene, defaults=True,
                                            unknown=True)
    assert found == 2 and misclassification(scene.labels, labels) < 0.05



def test_adelaide_restarts_keep_no_structure_of_two_motions():
    """toycubecar (three motions) with its count at the defaults: of the three restarts,
    one's first fundamental matrix holds two motions at a threshold of 17 px², between L*
    and the ceiling 2 L*. Compared by errors truncated at 2 L*, that restart won (27 %
    misclassified); truncated at L*, where an inlier's error is, each structure kept is one
    motion (10 %)."""
    need("adelaidermf")
    scene = datasets.adelaide_scene("F", "toycubecar")
    found = kanagen.find_structures(
        kanagen.load("two_view"), data={"match": scene.matches}, info={"match": 1.0},
        max_structures=scene.structures, model="general", seed=0,
        constants=datasets.nominal_constants(scene))
    assert found
    for state in found:
        counts = np.bincount(scene.labels[state.inliers])
        assert counts.max() >= 0.9 * len(state.inliers), counts

def test_real_table_helpers():
    """experiments/two_view_real.py: what each pair should come out as, and the error of a
    model on the ground truth (the ground truth's own H and F: zero and its Sampson error)."""
    need("magsac_cmp")
    import two_view_real as real

    city, adam = datasets.homography_pair("city"), datasets.homography_pair("adam")
    assert "none" in real.expected_models("homography", city)  # its H: 0.48 px from I
    assert real.expected_models("homography", adam) == {"planar", "rotation", "zoom"}
    kind, err = real.truth_error(adam, {"model": "planar", "derived": {"H": adam.H}})
    assert kind == "transfer" and err < 1e-6
    booksh = datasets.fundamental_pair("booksh")
    kind, err = real.truth_error(booksh, {"model": "general", "derived": {"F": booksh.F}})
    assert kind == "Sampson" and 0.3 < err < 0.7
    c = datasets.nominal_constants(adam)
    assert c == {"cx": 300.0, "cy": 225.0, "f0": 600.0}


def test_the_fountain_pair_beside_poselib():
    """The Strecha fountain pair with its two K (issue 19): the calibrated lattice at its
    defaults names a general motion and gives PoseLib's pose on the same matches, rotation
    and translation direction to 0.1° (they differ by 0.02° here, OpenCV by 0.35°:
    experiments/strecha_fountain.py, docs/real_data.md)."""
    need("magsac_cmp")
    poselib = pytest.importorskip("poselib")
    from kanagen.runtime import geometry as g
    from kanagen.scenes import calibrated_constants

    pair = datasets.strecha_fountain()
    fam = kanagen.load("two_view_calibrated")
    est = kanagen.Estimator(fam, seed=0, constants=calibrated_constants(pair.K1, pair.K2))
    est.add_measures("match", pair.matches, info=1.0)
    best = est.run()
    assert best.model == "general" and best.inliers.size >= 200
    p = best.params
    R = g.rotation_from_quaternion([p["qw"], p["qx"], p["qy"], p["qz"]])
    t = np.array([p["tx"], p["ty"], p["tz"]])

    def camera(K):
        w, h = pair.image_size
        return {"model": "PINHOLE", "width": w, "height": h,
                "params": [K[0, 0], K[1, 1], K[0, 2], K[1, 2]]}

    pose, _ = poselib.estimate_relative_pose(pair.matches[:, :2], pair.matches[:, 2:],
                                             camera(pair.K1), camera(pair.K2),
                                             {"max_epipolar_error": 1.5}, {})
    rotation = np.degrees(np.arccos(np.clip((np.trace(R.T @ pose.R) - 1) / 2, -1, 1)))
    direction = np.degrees(np.arccos(np.clip(t @ pose.t / np.linalg.norm(t)
                                             / np.linalg.norm(pose.t), -1, 1)))
    assert rotation < 0.1 and direction < 0.1
    angle = best.derived["rotation_angle"]
    assert abs(angle.value - np.degrees(np.arccos((np.trace(pose.R) - 1) / 2))) < 3 * angle.std
