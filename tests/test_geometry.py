"""Closed forms of two-view geometry (the initialisers' building blocks) against ground truth,
hypothesis properties, and OpenCV as an independent implementation."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kanagen.runtime import geometry as g
from kanagen.runtime.two_view_starts import two_view_fundamental, two_view_homography
from kanagen.scenes import two_view_scene


def _same_up_to_sign(A, B, tol):
    A, B = A / np.linalg.norm(A), B / np.linalg.norm(B)
    return min(np.abs(A - B).max(), np.abs(A + B).max()) < tol


def _epipolar(F, x):
    return np.einsum("ni,ij,nj->n", g.homogeneous(x[:, 2:]), F, g.homogeneous(x[:, :2]))


@pytest.mark.parametrize("seed", range(3))
def test_eight_and_seven_point_recover_the_true_f(seed):
    s = two_view_scene("general", n=30, sigma=0.0, seed=seed)
    assert _same_up_to_sign(g.fundamental_8point(s.x1, s.x2), s.F, 1e-8)
    assert any(_same_up_to_sign(F, s.F, 1e-7)
               for F in g.fundamental_7point(s.x1[:7], s.x2[:7]))
    for F in g.fundamental_7point(s.x1[:7], s.x2[:7]):
        assert abs(np.linalg.det(F)) < 1e-10
        assert np.abs(_epipolar(F, s.data[:7])).max() < 1e-9


@pytest.mark.parametrize("seed", range(3))
def test_dlt_recovers_the_true_h(seed):
    s = two_view_scene("planar", n=12, sigma=0.0, seed=seed)
    assert _same_up_to_sign(g.homography_dlt(s.x1, s.x2), s.H, 1e-9)
    s = two_view_scene("rotation", n=4, sigma=0.0, seed=seed)
    assert _same_up_to_sign(g.homography_dlt(s.x1, s.x2), s.H, 1e-8)


@pytest.mark.parametrize("seed", range(4))
def test_focal_lengths_from_f(seed):
    s = two_view_scene("general", n=20, sigma=0.0, seed=seed)
    f1sq, f2sq = g.focal_lengths(s.F, s.K1[:2, 2], s.K2[:2, 2])
    assert np.sqrt(f1sq) == pytest.approx(s.K1[0, 0], rel=1e-6)
    assert np.sqrt(f2sq) == pytest.approx(s.K2[0, 0], rel=1e-6)


def test_essential_and_homography_poses():
    s = two_view_scene("planar", n=30, sigma=0.0, seed=5)
    y1 = g.homogeneous(s.x1) @ np.linalg.inv(s.K1).T
    y2 = g.homogeneous(s.x2) @ np.linalg.inv(s.K2).T
    E = g.skew(s.t) @ s.R
    R, t = g.best_pose(g.essential_poses(E), y1, y2)
    assert np.allclose(R, s.R, atol=1e-9) and np.allclose(t, s.t / np.linalg.norm(s.t))
    Hn = np.linalg.inv(s.K2) @ s.H @ s.K1
    poses = g.homography_poses(Hn, y1, y2)
    assert 1 <= len(poses) <= 2
    n, d = s.plane
    truth = [(s.R, s.t / np.linalg.norm(s.t), n / d * np.linalg.norm(s.t))]
    assert any(np.allclose(R, truth[0][0], atol=1e-8) and np.allclose(w, truth[0][2],
                                                                      atol=1e-8)
               for R, _, w in poses)
    for R, t, w in poses:  # every kept decomposition reproduces H, in front of camera 1
        assert _same_up_to_sign(R + np.outer(t, w), Hn, 1e-9)
        assert np.all(y1 @ w > 0)


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(-1, 1, allow_nan=False), min_size=4, max_size=4).filter(
    lambda v: np.linalg.norm(v) > 1e-3))
def test_quaternion_round_trip(v):
    q = np.array(v) / np.linalg.norm(v)
    R = g.rotation_from_quaternion(q)
    assert np.allclose(R @ R.T, np.eye(3), atol=1e-12) and np.linalg.det(R) > 0
    back = g.quaternion_from_rotation(R)
    assert back[0] >= 0  # the convention: w >= 0 (q and −q are the same rotation)
    assert np.allclose(back, q, atol=1e-9) or np.allclose(back, -q, atol=1e-9)
    assert np.allclose(g.rotation_from_quaternion(back), R, atol=1e-12)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10_000), st.floats(0.3, 3.0))
def test_eight_point_is_invariant_to_image_scaling(seed, scale):
    """Hartley normalisation: rescaling both images rescales F as ``S⁻ᵀ F S⁻¹``."""
    s = two_view_scene("general", n=20, sigma=0.5, seed=seed)
    S = np.diag([scale, scale, 1.0])
    F = g.fundamental_8point(s.x1, s.x2)
    F_scaled = g.fundamental_8point(s.x1 * scale, s.x2 * scale)
    assert _same_up_to_sign(np.linalg.inv(S).T @ F @ np.linalg.inv(S), F_scaled, 1e-8)


def test_initialisers_give_the_true_parameters():
    s = two_view_scene("general", n=7, sigma=0.0, seed=2)
    truth = s.params()
    cands = two_view_fundamental(s.data, s.constants)
    assert any(all(abs(c[k] - truth[k]) < 1e-7 for k in ("f1", "f2", "qw", "qx", "qy", "qz"))
               and np.allclose([c["tx"], c["ty"], c["tz"]],
                               [truth["tx"], truth["ty"], truth["tz"]], atol=1e-7)
               for c in cands)
    s = two_view_scene("planar", n=4, sigma=0.0, seed=2)
    for c in two_view_homography(s.data, s.constants):
        R = g.rotation_from_quaternion([c["qw"], c["qx"], c["qy"], c["qz"]])
        Hn = R + np.outer([c["tx"], c["ty"], c["tz"]], [c["wx"], c["wy"], c["wz"]])
        T = np.array([[1, 0, -s.constants["cx"]], [0, 1, -s.constants["cy"]],
                      [0, 0, s.constants["f0"]]])
        assert _same_up_to_sign(np.linalg.inv(T) @ Hn @ T, s.H, 1e-8)
    assert two_view_fundamental(s.data[:5], s.constants) == []
    assert two_view_homography(np.full((4, 4), np.nan), s.constants) == []


# -- OpenCV as an independent reference ----------------------------------------------------
@pytest.mark.parametrize("seed", range(3))
def test_eight_point_matches_opencv(seed):
    cv2 = pytest.importorskip("cv2")
    s = two_view_scene("general", n=40, sigma=0.5, seed=seed)
    F_cv, _ = cv2.findFundamentalMat(s.x1, s.x2, cv2.FM_8POINT)
    assert _same_up_to_sign(g.fundamental_8point(s.x1, s.x2), F_cv, 1e-6)


@pytest.mark.parametrize("seed", range(3))
def test_dlt_matches_opencv(seed):
    cv2 = pytest.importorskip("cv2")
    s = two_view_scene("planar", n=40, sigma=0.5, seed=seed)
    H_cv, _ = cv2.findHomography(s.x1, s.x2, 0)
    H = g.homography_dlt(s.x1, s.x2)
    # OpenCV refines its DLT (Levenberg–Marquardt on the transfer error): same to noise level
    y, y_cv = g.homogeneous(s.x1) @ H.T, g.homogeneous(s.x1) @ H_cv.T
    gap = np.abs(y[:, :2] / y[:, 2:] - y_cv[:, :2] / y_cv[:, 2:]).max()
    assert gap < 0.5
    s = two_view_scene("planar", n=10, sigma=0.0, seed=seed)
    H_cv, _ = cv2.findHomography(s.x1, s.x2, 0)
    assert _same_up_to_sign(g.homography_dlt(s.x1, s.x2), H_cv, 1e-6)


def test_homography_poses_do_not_depend_on_the_sign_of_h():
    """The DLT's sign is arbitrary: H and −H give the same decompositions (the depths'
    sign rule, det(H) only when the depths do not decide), also on samples with outliers
    where the sign of positive depths has det(H) < 0."""
    rng = np.random.default_rng(5)
    for _ in range(50):
        H = rng.normal(size=(3, 3))
        y1 = np.c_[rng.uniform(-0.5, 0.5, (6, 2)), np.ones(6)]
        y2 = np.c_[rng.uniform(-0.5, 0.5, (6, 2)), np.ones(6)]
        a, b = g.homography_poses(H, y1, y2), g.homography_poses(-H, y1, y2)
        assert len(a) == len(b)
        for R, t, w in a:
            assert any(np.allclose(R, R2) and np.allclose(t, t2) and np.allclose(w, w2)
                       for R2, t2, w2 in b)
