"""The two-view scene generator: ground truth that holds, outliers, determinism."""

from __future__ import annotations

import numpy as np
import pytest

from kanagen.runtime import geometry as g
from kanagen.scenes import MOTIONS, image_constants, sampson_rms, transfer_rms, two_view_scene


@pytest.mark.parametrize("motion", MOTIONS)
def test_ground_truth_holds_on_the_clean_inliers(motion):
    s = two_view_scene(motion, n=50, outliers=0.25, sigma=0.5, seed=1)
    assert s.data.shape == s.clean.shape == (len(s.inliers), 4)
    assert s.inliers.sum() == 50 and (~s.inliers).sum() == round(0.25 * 50 / 0.75)
    clean = s.clean[s.inliers]
    assert np.all((clean >= 0) & (clean <= [640, 480, 640, 480]))  # seen in both images
    # the 3-D points project onto the clean matches
    p1 = s.points @ s.K1.T
    p2 = (s.points @ s.R.T + s.t) @ s.K2.T
    assert np.allclose(np.sort(clean[:, 0]), np.sort(p1[:, 0] / p1[:, 2]))
    assert np.allclose(np.sort(clean[:, 2]), np.sort(p2[:, 0] / p2[:, 2]))
    assert np.all(s.points[:, 2] > 0) and np.all((s.points @ s.R.T + s.t)[:, 2] > 0)
    if s.F is not None:
        assert sampson_rms(s.F, clean) < 1e-9
        assert sampson_rms(s.F, s.data[~s.inliers]) > 1.0  # outliers are not on it
    if s.H is not None:
        assert transfer_rms(s.H, clean) < 1e-8
    noise = s.data[s.inliers] - clean
    assert 0.4 < noise.std() < 0.6


def test_motion_classes_are_what_they_say():
    assert np.allclose(two_view_scene("none", seed=2).H, np.eye(3) / np.sqrt(3))
    z = two_view_scene("zoom", seed=2)
    ratio = z.K2[0, 0] / z.K1[0, 0]
    assert 1.15 <= max(ratio, 1 / ratio) <= 1.5 and np.allclose(z.R, np.eye(3))
    r = two_view_scene("rotation", seed=2)
    angle = np.degrees(np.arccos((np.trace(r.R) - 1) / 2))
    assert 5 <= angle <= 20 and not r.t.any()
    t = two_view_scene("translation", seed=2)
    assert np.allclose(t.R, np.eye(3)) and 1 <= np.linalg.norm(t.t) <= 2 and t.H is None
    p = two_view_scene("planar", seed=2)
    n, d = p.plane
    assert np.allclose(p.points @ n, d) and p.F is not None and p.H is not None
    assert two_view_scene("general", seed=2).H is None


def test_params_are_the_family_parameter():
    s = two_view_scene("general", n=10, seed=3)
    p = s.params()
    q = np.array([p[k] for k in ("qw", "qx", "qy", "qz")])
    assert np.allclose(g.rotation_from_quaternion(q), s.R)
    assert p["f1"] * s.constants["f0"] == pytest.approx(s.K1[0, 0])
    assert np.linalg.norm([p["tx"], p["ty"], p["tz"]]) == pytest.approx(1.0)
    assert image_constants(640, 480) == {"cx": 320.0, "cy": 240.0, "f0": 640.0}


def test_same_seed_same_scene_and_bad_input():
    a, b = two_view_scene("planar", seed=4), two_view_scene("planar", seed=4)
    assert np.array_equal(a.data, b.data) and np.array_equal(a.inliers, b.inliers)
    assert not np.array_equal(a.data, two_view_scene("planar", seed=5).data)
    with pytest.raises(ValueError, match="unknown motion"):
        two_view_scene("spin")
    with pytest.raises(ValueError, match="fraction"):
        two_view_scene("none", outliers=1.0)
    with pytest.raises(ValueError, match="sigma"):
        two_view_scene("none", sigma=-1)
