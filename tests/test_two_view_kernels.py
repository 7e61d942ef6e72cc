"""The compiled two-view closed forms (runtime/two_view_kernels.py, runtime/two_view_twins.py)
against the NumPy closed forms they replaced (tests/reference_two_view.py, kept verbatim).

The kernels factor their small matrices by Jacobi rotations (runtime/linalg.py), not by
LAPACK: on random samples of every motion the registered initialisers give the reference's
candidates to 1e-8 relative, in any order (a root of the seven-point cubic, a decomposition
of a homography may come in another order); a degenerate sample — a system with more null
vectors than its closed form takes: points on a line, repeated or identical, a pure rotation
or no motion seen by the eight-point algorithm — gives no candidate, where the reference
gave LAPACK's arbitrary ones. The C functions of :func:`twin_address` give the kernels'
output bit for bit, and the public functions of runtime/geometry.py the reference's (up to
the signs and the order the factorisations leave free).
"""

from __future__ import annotations

import ctypes
import math
import os
import subprocess
import sys

import numpy as np
import pytest
import reference_two_view as ref
from hypothesis import given, settings
from hypothesis import strategies as st

from kanagen.runtime import geometry as g
from kanagen.runtime import two_view_kernels as kernels
from kanagen.runtime import two_view_starts as starts
from kanagen.runtime import two_view_twins as twins
from kanagen.scenes import MOTIONS, two_view_scene

K = {"cx": 320.0, "cy": 240.0, "f0": 640.0}
K3 = np.array([K["cx"], K["cy"], K["f0"]])
NAMES = tuple(twins.KERNELS)
REFERENCE = {name: getattr(ref, name) for name in NAMES}
REGISTERED = {name: getattr(starts, name) for name in NAMES}
#: The sample sizes of each initialiser: minimal, and a few over-determined
SIZES = {"two_view_fundamental": (7, 8, 9, 12, 20), "two_view_homography": (4, 5, 8, 20),
         "two_view_rotation": (2, 4, 5, 12), "two_view_translation": (2, 3, 5, 20),
         "two_view_zoom": (1, 2, 5, 20), "two_view_retinal_translation": (1, 2, 3, 20),
         "two_view_retinal_displacement": (2, 3, 4, 20)}


def close(a: float, b: float, rtol: float = 1e-10) -> bool:
    return a == b or math.isnan(a) and math.isnan(b) or abs(a - b) <= rtol * max(1.0, abs(a))


def assert_same_candidates(expected: list, got: list, rtol: float = 1e-8) -> None:
    """The same candidates in any order — the same names in the same order, the values to
    ``rtol`` relative —, each matched once."""
    assert len(got) == len(expected), (expected, got)
    left = list(got)
    for a in expected:
        match = next((j for j, b in enumerate(left) if list(a) == list(b)
                      and all(close(float(a[n]), b[n], rtol) for n in a)), None)
        assert match is not None, (a, got)
        left.pop(match)


def reference(name: str, rows: np.ndarray, k: dict = K) -> list:
    with np.errstate(all="ignore"):
        return REFERENCE[name](rows, k)


def _random_samples():
    rng = np.random.default_rng(11)
    for seed, motion in enumerate(MOTIONS):
        scene = two_view_scene(motion, n=120, outliers=0.3, sigma=0.5, seed=seed)
        X, inliers = np.ascontiguousarray(scene.data), np.flatnonzero(scene.inliers)
        for trial in range(12):
            pool = inliers if trial % 2 == 0 else np.arange(len(X))
            for name, sizes in SIZES.items():
                for m in sizes:
                    yield name, X[rng.choice(pool, m, replace=False)]


@pytest.mark.parametrize("name", NAMES)
def test_the_initialisers_give_the_numpy_candidates(name):
    samples = [rows for which, rows in _random_samples() if which == name]
    found = 0
    for rows in samples:
        expected = reference(name, rows)
        assert_same_candidates(expected, REGISTERED[name](rows, K))
        found += len(expected)
    assert found > len(samples) / 4  # many samples have candidates: not a vacuous test


def degenerate_samples() -> dict[str, np.ndarray]:
    """Samples whose closed forms are degenerate or refused, by the sizes that make them so."""
    X = np.ascontiguousarray(two_view_scene("general", n=30, sigma=0.5, seed=2).data)
    line = np.linspace(0.0, 1.0, 12)[:, None]
    collinear = np.c_[100 + 400 * line, 50 + 300 * line, 120 + 380 * line, 60 + 290 * line]
    rotation = two_view_scene("rotation", n=20, sigma=0.0, seed=3).data
    planar = two_view_scene("planar", n=20, sigma=0.0, seed=4).data
    still = two_view_scene("none", n=20, sigma=0.0, seed=5).data
    nan, inf = X[:12].copy(), X[:12].copy()
    nan[3, 2], inf[0, 0] = np.nan, np.inf
    samples = {
        "nan": nan, "inf": inf, "empty": X[:0], "one": X[:1], "three": X[:3], "six": X[:6],
        "zeros": np.zeros((12, 4)), "principal": np.tile([320.0, 240.0, 320.0, 240.0], (12, 1)),
        "noise": np.random.default_rng(3).uniform(0, 640, (12, 4)),
        "collinear": collinear, "rotation": rotation, "planar": planar, "still": still,
        "identical": np.tile(X[:1], (12, 1)), "repeated": X[[0, 1, 2, 3] * 3],
    }
    out = {}
    for case, rows in samples.items():
        for m in sorted({2, 4, 7, 8, 12} if len(rows) >= 12 else {len(rows)}):
            out[f"{case}{m}"] = np.ascontiguousarray(rows[:m])
    out["duplicate7"] = np.ascontiguousarray(X[[0, 0, 1, 2, 3, 4, 5]])
    out["duplicate4"] = np.ascontiguousarray(X[[0, 0, 1, 2]])
    out["duplicate2"] = np.ascontiguousarray(X[[0, 0]])
    return out


def _degenerate(name: str, rows: np.ndarray) -> bool:
    """Has the closed form's linear system more null vectors than it takes (NumPy's SVD,
    singular values below 1e-6 of the largest)? The eight-point (one) and seven-point (two)
    systems of ``two_view_fundamental``, the DLT's of ``two_view_homography`` (one) and of
    ``two_view_rotation`` on four matches or more (its homography: a repeated match leaves
    the DLT more null vectors, and LAPACK's choice among them decides whether the
    reference's focal length is in range); no motion for ``two_view_rotation`` either (the
    DLT's homography is the identity: no rotation fixes the focal length)."""
    if len(rows) < 2 or not np.all(np.isfinite(rows)):
        return False
    x1, x2 = rows[:, :2], rows[:, 2:]
    if name == "two_view_rotation" and len(rows) >= 4 and \
            np.allclose(x1, x2, rtol=0, atol=1e-9):
        return True
    if name == "two_view_fundamental" and len(rows) >= 7:
        A, takes = ref._epipolar_rows(x1, x2)[0], 2 if len(rows) == 7 else 1
    elif name in ("two_view_homography", "two_view_rotation") and len(rows) >= 4:
        p1, p2, _, _ = ref._normalised(x1, x2)
        zero = np.zeros_like(p1)
        A = np.concatenate([np.concatenate([zero, -p2[:, 2:] * p1, p2[:, 1:2] * p1], axis=1),
                            np.concatenate([p2[:, 2:] * p1, zero, -p2[:, :1] * p1], axis=1)])
        takes = 1
    else:
        return False
    S = np.linalg.svd(A, compute_uv=False)
    return 9 - int(np.sum(S > 1e-6 * S[0])) > takes


@pytest.mark.parametrize("case", sorted(degenerate_samples()))
@pytest.mark.parametrize("name", NAMES)
def test_degenerate_samples_give_no_arbitrary_candidate(name, case):
    """A sample whose system has more null vectors than its closed form takes gives no
    candidate (the reference's were drawn from LAPACK's arbitrary basis of that null space);
    any other gives the reference's; the layout of the rows does not matter."""
    rows = degenerate_samples()[case]
    got = REGISTERED[name](rows, K)
    if _degenerate(name, rows):
        assert got == []
    else:
        assert_same_candidates(reference(name, rows), got)
    for layout in (rows.tolist(), np.asfortranarray(rows)):  # the wrapper copies by rows
        assert_same_candidates(got, REGISTERED[name](layout, K), rtol=0.0)


def test_the_degenerate_samples_are_degenerate():
    """Not a vacuous rule: the degenerate cases of every closed form with a linear system
    are there, and the reference gave candidates for some (its arbitrary ones)."""
    cases = degenerate_samples()
    for name in ("two_view_fundamental", "two_view_homography", "two_view_rotation"):
        flagged = [c for c, rows in cases.items() if _degenerate(name, rows)]
        assert len(flagged) >= 3, name
        assert any(reference(name, cases[c]) for c in flagged), name


@pytest.mark.parametrize("name", NAMES)
def test_a_sample_the_kernels_cannot_use_has_no_candidate(name):
    """No camera (``f0 = 0``, a constant not finite), coordinates whose products overflow:
    no candidate, and the kernels do not leave a degenerate sample to anyone (the count is
    never negative). (NumPy's LAPACK may not return on an infinite matrix: the kernels check
    finiteness first.)"""
    X = two_view_scene("general", n=20, sigma=0.5, seed=1).data
    for k in ({**K, "f0": 0.0}, {**K, "cx": np.inf}, {**K, "f0": np.nan}):
        assert REGISTERED[name](X[:8], k) == []
    huge = np.ascontiguousarray(X[:8] * 1e300)
    out = np.empty((twins.CANDIDATES, twins.WIDTH))
    with np.errstate(all="ignore"):
        assert twins.KERNELS[name](huge, K3, out) >= 0
    for rows in degenerate_samples().values():
        assert twins.KERNELS[name](rows, K3, out) >= 0


def _c_function(name: str):
    return ctypes.CFUNCTYPE(ctypes.c_int64, ctypes.c_int64, *[ctypes.c_void_p] * 3)(
        twins.twin_address(name))


@pytest.mark.parametrize("name", NAMES)
def test_the_c_functions_are_the_kernels(name):
    """The address of :func:`twin_address` called through ctypes writes what the kernel
    writes, bit for bit (NaN where a candidate names no value), and returns its count."""
    call = _c_function(name)
    assert twins.twin_address(name) == twins.twin_address(name)  # compiled once
    rows_of = [rows for which, rows in _random_samples() if which == name][:40]
    for rows in rows_of + list(degenerate_samples().values()):
        rows = np.ascontiguousarray(rows)
        a, b = np.full((4, 12), 7.0), np.full((4, 12), 7.0)
        count = twins.KERNELS[name](rows, K3, a)
        assert call(len(rows), rows.ctypes.data, K3.ctypes.data, b.ctypes.data) == count
        np.testing.assert_array_equal(a, b)
        unnamed = np.setdiff1d(np.arange(twins.WIDTH), [i for i, _ in twins.NAMES[name]])
        assert np.all(np.isnan(a[:count][:, unnamed]))


def test_the_interpreted_source_gives_the_same_candidates():
    """``NUMBA_DISABLE_JIT=1`` runs the kernels as Python on the same samples: the same
    candidates (the C function is then a ctypes callback of the Python kernel)."""
    script = (
        "import ctypes, json, sys, numpy as np\n"
        "from kanagen.runtime import two_view_twins as tw\n"
        "X, k3 = np.array(json.loads(sys.argv[1])), np.array([320.0, 240.0, 640.0])\n"
        "out = []\n"
        "for name, m in (('two_view_fundamental', 7), ('two_view_fundamental', 9),\n"
        "                ('two_view_homography', 5), ('two_view_rotation', 2),\n"
        "                ('two_view_rotation', 6), ('two_view_translation', 4),\n"
        "                ('two_view_zoom', 3), ('two_view_retinal_translation', 1),\n"
        "                ('two_view_retinal_translation', 5),\n"
        "                ('two_view_retinal_displacement', 2),\n"
        "                ('two_view_retinal_displacement', 6)):\n"
        "    rows, res = np.ascontiguousarray(X[:m]), np.empty((4, 12))\n"
        "    f = ctypes.CFUNCTYPE(ctypes.c_int64, ctypes.c_int64, *[ctypes.c_void_p] * 3)(\n"
        "        tw.twin_address(name))\n"
        "    count = f(m, rows.ctypes.data, k3.ctypes.data, res.ctypes.data)\n"
        "    out.append(res[:count].tolist())\n"
        "print(json.dumps(out))\n")
    import json

    X = two_view_scene("general", n=12, sigma=0.5, seed=8).data
    env = {**os.environ, "NUMBA_DISABLE_JIT": "1"}
    run = subprocess.run([sys.executable, "-c", script, json.dumps(X.tolist())], env=env,
                         capture_output=True, text=True, timeout=300, check=True)
    interpreted = json.loads(run.stdout.strip().splitlines()[-1])
    at = 0
    for name, m in (("two_view_fundamental", 7), ("two_view_fundamental", 9),
                    ("two_view_homography", 5), ("two_view_rotation", 2),
                    ("two_view_rotation", 6), ("two_view_translation", 4),
                    ("two_view_zoom", 3), ("two_view_retinal_translation", 1),
                    ("two_view_retinal_translation", 5), ("two_view_retinal_displacement", 2),
                    ("two_view_retinal_displacement", 6)):
        out = np.empty((4, 12))
        count = twins.KERNELS[name](np.ascontiguousarray(X[:m]), K3, out)
        assert count == len(interpreted[at]) > 0
        np.testing.assert_allclose(np.array(interpreted[at]), out[:count], rtol=1e-12,
                                   atol=1e-14)
        at += 1


# -- the public closed forms of runtime/geometry.py ------------------------------------------

def _scenes():
    for seed in range(4):
        yield two_view_scene("general", n=30, outliers=0.2, sigma=0.5, seed=seed)
        yield two_view_scene("planar", n=30, outliers=0.2, sigma=0.5, seed=seed)
    yield two_view_scene("rotation", n=30, sigma=0.0, seed=9)
    yield two_view_scene("none", n=30, sigma=0.0, seed=9)


def assert_same_arrays(expected, got, rtol=1e-10):
    """Arrays, or tuples and lists of them, equal to 1e-10 relative (NaN where NaN)."""
    if isinstance(expected, list | tuple):
        assert isinstance(got, list | tuple) and len(got) == len(expected)
        for a, b in zip(expected, got, strict=True):
            assert_same_arrays(a, b, rtol)
        return
    expected, got = np.asarray(expected, dtype=float), np.asarray(got, dtype=float)
    assert expected.shape == got.shape
    near = np.abs(got - expected) <= rtol * np.maximum(1.0, np.abs(expected))
    assert np.all(near | np.isnan(expected) & np.isnan(got)), (expected, got)


def assert_same_up_to_sign(expected, got, rtol=1e-10):
    """An array equal to ``expected`` or to its opposite (a singular vector's sign, a
    homogeneous matrix's scale: the factorisation leaves them free)."""
    expected, got = np.asarray(expected, dtype=float), np.asarray(got, dtype=float)
    flip = -1.0 if np.vdot(expected, got) < 0 else 1.0
    assert_same_arrays(expected, flip * got, rtol)


def _signed(M):
    """``M`` with its entry of largest magnitude positive (a homogeneous matrix's sign)."""
    return M * np.sign(M.flat[np.argmax(np.abs(M))])


def assert_same_sets(expected, got, rtol=1e-10):
    """Lists of arrays or of tuples of arrays with the same members, in any order."""
    assert len(got) == len(expected)
    left = list(got)
    for a in expected:
        flat_a = np.concatenate([np.ravel(x) for x in (a if isinstance(a, tuple) else (a,))])
        for j, b in enumerate(left):
            flat_b = np.concatenate([np.ravel(x) for x in (b if isinstance(b, tuple) else (b,))])
            if np.all(np.abs(flat_a - flat_b) <= rtol * np.maximum(1.0, np.abs(flat_a))):
                left.pop(j)
                break
        else:
            raise AssertionError((a, got))


def test_the_geometry_functions_are_the_numpy_ones():
    rng = np.random.default_rng(4)
    for s in _scenes():
        x1, x2 = s.x1, s.x2
        if s.motion in ("rotation", "none"):  # the eight- and seven-point systems: degenerate
            with pytest.raises(np.linalg.LinAlgError, match="degenerate"):
                g.fundamental_8point(x1, x2)
            assert g.fundamental_7point(x1[:7], x2[:7]) == []
        else:
            assert_same_up_to_sign(ref.fundamental_8point(x1, x2), g.fundamental_8point(x1, x2))
            for m in (8, 12):
                assert_same_up_to_sign(ref.fundamental_8point(x1[:m], x2[:m]),
                                       g.fundamental_8point(x1[:m], x2[:m]))
            assert_same_sets([_signed(F) for F in ref.fundamental_7point(x1[:7], x2[:7])],
                             [_signed(F) for F in g.fundamental_7point(x1[:7], x2[:7])],
                             rtol=1e-8)
            F = ref.fundamental_8point(x1, x2)
            for e_ref, e in zip(ref.epipoles(F), g.epipoles(F), strict=True):
                assert_same_up_to_sign(e_ref, e)
            assert_same_arrays(ref.focal_lengths(F, (320, 240), (300, 250)),
                               g.focal_lengths(F, (320, 240), (300, 250)), rtol=1e-8)
        for m in (4, 5, 30):
            assert_same_up_to_sign(ref.homography_dlt(x1[:m], x2[:m]),
                                   g.homography_dlt(x1[:m], x2[:m]))
        y1, y2 = ref._rays(s.data, K)
        E = rng.normal(size=(3, 3))
        assert_same_arrays(ref.nearest_essential(E), g.nearest_essential(E))
        poses = g.essential_poses(E)
        assert_same_sets(ref.essential_poses(E), poses)
        assert_same_arrays(ref.best_pose(poses, y1, y2), g.best_pose(poses, y1, y2))
        assert_same_arrays(ref.best_pose(ref.essential_poses(E), y1, y2),
                           g.best_pose(poses, y1, y2))
        for R, t in poses:
            assert_same_arrays(ref.depths(R, t, y1, y2), g.depths(R, t, y1, y2))
        H = ref.homography_dlt(x1, x2)
        for args in ((H, y1, y2), (-H, y1, y2), (H, y1), (H,), (np.eye(3) * 2.0, y1, y2)):
            assert_same_sets(ref.homography_poses(*args), g.homography_poses(*args), rtol=1e-8)
        assert_same_arrays(ref.normalising_transform(x1), g.normalising_transform(x1))
        a, b = rng.normal(size=(2, 3))
        assert_same_arrays(ref.cross(a, b), g.cross(a, b))


def test_rotations_and_quaternions_are_the_numpy_ones():
    rng = np.random.default_rng(5)
    for _ in range(200):
        a1, a2, b1, b2 = rng.normal(size=(4, 3))
        assert_same_arrays(ref.rotation_from_pairs(a1, a2, b1, b2),
                           g.rotation_from_pairs(a1, a2, b1, b2))
        R = g.rotation_about(rng.normal(size=3), rng.uniform(0, np.pi))
        assert_same_arrays(ref.quaternion_from_rotation(R), g.quaternion_from_rotation(R))
    assert g.rotation_from_pairs(a1, 2 * a1, b1, b2) is None
    for R in (np.eye(3), np.diag([1.0, -1.0, -1.0]), np.diag([-1.0, 1.0, -1.0]),
              np.diag([-1.0, -1.0, 1.0])):  # the half turns: w = 0
        assert_same_arrays(ref.quaternion_from_rotation(R), g.quaternion_from_rotation(R))
    poses = [(np.eye(3), np.array([0.0, 0.0, 1.0])), (np.eye(3), np.array([0.0, 0.0, -1.0]))]
    y = np.zeros((3, 3))  # no point decides: the tie rule
    assert g.best_pose(poses, y, y) is poses[0]
    with pytest.raises(ValueError):
        g.best_pose([], y, y)


@pytest.mark.parametrize("n", [*range(0, 40), 127, 128, 129, 255, 256, 257, 1000, 4099])
def test_vector_sum_rounds_as_numpy(n):
    """The kernels' sums are NumPy's, bit for bit (pairwise, blocks of eight)."""
    a = np.random.default_rng(n).normal(size=n) * 10.0 ** np.random.default_rng(n).uniform(
        -8, 8, n)
    assert kernels.vector_sum(a) == np.sum(a)


@settings(max_examples=80, deadline=None)
@given(n=st.integers(1, 6), k=st.integers(1, 3), seed=st.integers(0, 2**32 - 1),
       scale=st.sampled_from([1e-8, 1.0, 1e8]))
def test_small_solves_and_determinants_as_numpy(n, k, seed, scale):
    """The closed forms' solve (Gaussian elimination with partial pivoting) and 3 × 3
    determinant (cofactors): NumPy's to rounding on well-conditioned matrices; a singular or
    non-finite matrix raises ``LinAlgError``, as NumPy's."""
    from kanagen.runtime.numpy_rules import det3, solved

    rng = np.random.default_rng(seed)
    A = scale * (rng.standard_normal((n, n)) + n * np.eye(n))
    B = rng.standard_normal((n, k))
    np.testing.assert_allclose(solved(A, B), np.linalg.solve(A, B), rtol=1e-12,
                               atol=1e-12 * np.abs(np.linalg.solve(A, B)).max())
    M = scale * rng.standard_normal((3, 3))
    assert abs(det3(M) - np.linalg.det(M)) <= 1e-12 * scale**3 * np.abs(M / scale).max() ** 3
    for bad in (np.zeros((n, n)), np.full((n, n), np.nan)):
        with pytest.raises(np.linalg.LinAlgError):
            solved(bad, B)
