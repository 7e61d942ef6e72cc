"""The closed forms of the rotation and translation models (two_view_rotation,
two_view_translation) against ground truth and the model's own equations.

Noise-free generated scenes: the candidates of a minimal sample (two matches) and of an
over-determined one contain the scene's true parameter (:meth:`TwoViewScene.params`) to
1e-9, and a minimal solve from it stops at once. Noisy samples with outliers: every
candidate of two matches is an exact solution of the sample (the model's equations vanish on
it to rounding) with the points in front of the cameras where the sample allows it; the
over-determined closed form on noisy inliers starts the refinement in the basin of the
least-squares fit. Degenerate samples give no candidate.
"""

from __future__ import annotations

import numpy as np
import pytest

import kanagen
from kanagen.runtime import geometry as g
from kanagen.runtime.initializers import INITIALIZERS, start_from
from kanagen.runtime.two_view_starts import two_view_rotation, two_view_translation
from kanagen.scenes import two_view_scene

CLOSED = {"rotation": two_view_rotation, "translation": two_view_translation}
NAMES = {"rotation": ("f1", "f2", "qw", "qx", "qy", "qz"), "translation": ("tx", "ty", "tz")}


@pytest.fixture(scope="module")
def fam():
    return kanagen.load("two_view")


def _distance(cand: dict, truth: dict, names) -> float:
    return max(abs(cand[n] - truth[n]) for n in names)


def _rays(rows, k, f):
    y1 = np.c_[(rows[:, 0] - k["cx"]) / k["f0"], (rows[:, 1] - k["cy"]) / k["f0"],
               np.full(len(rows), f)]
    y2 = np.c_[(rows[:, 2] - k["cx"]) / k["f0"], (rows[:, 3] - k["cy"]) / k["f0"],
               np.full(len(rows), f)]
    return y1, y2


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("motion", ["rotation", "translation"])
def test_noise_free_candidates_hold_the_truth(fam, motion, seed):
    scene = two_view_scene(motion, n=30, sigma=0.0, seed=seed)
    truth, k = scene.params(), scene.constants
    closed = CLOSED[motion]
    for rows in (scene.data[:2], scene.data[10:12], scene.data):
        cands = closed(rows, k)
        best = min(cands, key=lambda c: _distance(c, truth, NAMES[motion]))
        assert _distance(best, truth, NAMES[motion]) < 1e-9, (rows.shape, cands, truth)
        assert list(best) == list(NAMES[motion])
    # the minimal solve of a sample from its candidate: there already
    rows = scene.data[3:5]
    for cand in closed(rows, k):
        start = start_from(fam, cand, fam.q0)
        sol = kanagen.minimal_solve(fam, motion, data={"match": rows}, q_start=start,
                                    constants=k)
        assert sol.success and sol.iterations <= 2, sol
        assert np.max(np.abs(sol.q - start)) < 1e-9


def test_rotation_candidates_solve_noisy_samples_exactly():
    rng = np.random.default_rng(5)
    counts = []
    for seed in range(6):
        scene = two_view_scene("rotation", n=100, outliers=0.3, sigma=1.0, seed=seed)
        k = scene.constants
        for _ in range(40):
            rows = scene.data[rng.choice(len(scene.data), 2, replace=False)]
            cands = two_view_rotation(rows, k)
            counts.append(len(cands))
            for c in cands:
                assert c["f1"] == c["f2"] and 0.1 < c["f1"] < 10
                R = g.rotation_from_quaternion([c["qw"], c["qx"], c["qy"], c["qz"]])
                y1, y2 = _rays(rows, k, c["f1"])
                mapped = y1 @ R.T
                # r2 ∝ R r1 with a positive factor: the same unit ray
                unit = mapped / np.linalg.norm(mapped, axis=1)[:, None]
                assert np.allclose(unit, y2 / np.linalg.norm(y2, axis=1)[:, None],
                                   atol=1e-9)
    # most samples have a solution, some several (the cubic), some none
    assert 0 in counts and 1 in counts and np.mean(np.array(counts) > 0) > 0.4


def test_translation_candidates_solve_noisy_samples_exactly():
    rng = np.random.default_rng(6)
    for seed in range(6):
        scene = two_view_scene("translation", n=100, outliers=0.3, sigma=1.0, seed=seed)
        k = scene.constants
        for _ in range(40):
            rows = scene.data[rng.choice(len(scene.data), 2, replace=False)]
            (c,) = two_view_translation(rows, k)
            t = np.array([c["tx"], c["ty"], c["tz"]])
            y1, y2 = _rays(rows, k, 1.0)
            assert abs(np.linalg.norm(t) - 1) < 1e-12
            assert np.max(np.abs(np.cross(y1, y2) @ t)) < 1e-12  # t · (r1 × r2) = 0
            # cheirality: at least as many points in front as the opposite direction
            front = [np.count_nonzero(np.logical_and(*(d > 0 for d in
                                                       g.depths(np.eye(3), s * t, y1, y2))))
                     for s in (1.0, -1.0)]
            assert front[0] >= front[1]


@pytest.mark.parametrize("motion", ["rotation", "translation"])
def test_least_squares_closed_form_starts_in_the_basin_of_the_fit(fam, motion):
    """On noisy inliers the over-determined closed form is near the least-squares fit:
    the fit from it reaches the cost of the fit from the truth."""
    for seed in range(3):
        scene = two_view_scene(motion, n=60, sigma=0.5, seed=seed)
        k, data = scene.constants, {"match": scene.data}
        info = {"match": 1 / scene.sigma ** 2}
        (cand,) = CLOSED[motion](scene.data, k)
        truth = scene.params()
        assert _distance(cand, truth, NAMES[motion]) < 0.05
        from_truth = kanagen.fit(fam, motion, data, info, constants=k,
                                 q_start=np.array(list(truth.values())))
        ours = kanagen.fit(fam, motion, data, info, constants=k,
                           q_start=start_from(fam, cand, fam.q0))
        assert ours.success and from_truth.success
        assert ours.cost == pytest.approx(from_truth.cost, rel=1e-6)


def _degenerate(motion):
    X = two_view_scene(motion, n=10, sigma=0.5, seed=1).data
    nan = X[:5].copy()
    nan[1, 3] = np.nan
    inf = X[:2].copy()
    inf[0, 0] = np.inf
    return {"nan": nan, "inf": inf, "nan2": nan[:2], "empty": X[:0], "one": X[:1],
            "identical2": np.tile(X[:1], (2, 1)), "identical9": np.tile(X[:1], (9, 1)),
            "zeros": np.zeros((6, 4))}


@pytest.mark.parametrize("motion", ["rotation", "translation"])
def test_degenerate_samples_give_no_candidate(motion):
    k = {"cx": 320.0, "cy": 240.0, "f0": 640.0}
    for case, rows in _degenerate(motion).items():
        with np.errstate(all="ignore"):
            assert CLOSED[motion](rows, k) == [], case
    # three matches: no closed form for a rotation (between the minimal and the DLT)
    assert two_view_rotation(two_view_scene("rotation", n=3, sigma=0.0).data, k) == []


def test_the_spec_names_them_and_their_needs_are_checked(fam):
    assert fam.models["rotation"].initializer == "two_view_rotation"
    assert fam.models["translation"].initializer == "two_view_translation"
    for name in ("two_view_rotation", "two_view_translation"):
        lacks = INITIALIZERS[name].missing(
            parameter=("f1", "f2", "qw", "qx", "qy", "qz", "tx", "ty", "tz", "wx", "wy"),
            constants=("cx", "cy"), channels={"m": ("u", "v", "u2")})
        assert lacks == "parameter 'wz', constant 'f0', a channel of 4 components"


def test_the_zoom_closed_form_holds_the_truth(fam):
    """A zoom about the principal point (``x2 = f2 x1`` in the normalised coordinates):
    one match or all of a noise-free scene give the true ``f2``; on noisy matches the
    least-squares ratio starts the fit in its basin (the fit moves it by less than its
    standard deviation); a match on the principal point gives nothing."""
    from kanagen.runtime.two_view_starts import two_view_zoom

    scene = two_view_scene("zoom", n=30, sigma=0.0, seed=0)
    truth = scene.params()["f2"]
    for rows in (scene.data[:1], scene.data[7:8], scene.data):
        (cand,) = two_view_zoom(rows, scene.constants)
        assert abs(cand["f2"] - truth) < 1e-12
    noisy = two_view_scene("zoom", n=30, sigma=0.5, seed=1)
    (cand,) = two_view_zoom(noisy.data, noisy.constants)
    fit = kanagen.fit(fam, "zoom", data={"match": noisy.data}, info={"match": 4.0},
                      constants=noisy.constants, q_start=start_from(fam, cand, fam.q0))
    assert fit.success
    assert abs(fit.params["f2"] - cand["f2"]) < fit.std["f2"]
    k = noisy.constants
    assert two_view_zoom(np.array([[k["cx"], k["cy"], k["cx"], k["cy"]]]), k) == []
    assert fam.models["zoom"].initializer == "two_view_zoom"
