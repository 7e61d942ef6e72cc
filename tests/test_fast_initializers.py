"""The compiled closed-form initialisers (codegen/c/kanagen_geometry.c) against the Python.

On samples of the generated two-view scenes of every motion (minimal and over-determined,
inliers only and with outliers) the compiled twin of each registered initializer gives the
Python's candidates: the same number, the same names, the values to 1e-8 relative. The order
of the candidates is compared as a set: in the Python it follows LAPACK's arbitrary basis of
a null space (the roots of the seven-point cubic) or of an eigenspace (the two
decompositions of a homography). Degenerate samples give what the Python gives.
"""

from __future__ import annotations

import ctypes

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_fastpath import compiled

import kanagen
from kanagen.runtime import two_view_starts as init
from kanagen.runtime.initializers import INITIALIZERS, model_initializers
from kanagen.scenes import MOTIONS, two_view_scene

NAMES = ("two_view_fundamental", "two_view_homography", "two_view_rotation",
         "two_view_translation")
CONSTANTS = {"cx": 320.0, "cy": 240.0, "f0": 640.0}
QUATERNION = ("qw", "qx", "qy", "qz")


@pytest.fixture(scope="module")
def family():
    return compiled("two_view")


def _same_candidate(a: dict, b: dict) -> bool:
    if a.keys() != b.keys():
        return False
    # w >= 0 decides the quaternion's sign, but not at w = 0 (a half turn)
    sign = -1.0 if "qw" in a and abs(a["qw"]) < 1e-6 and np.dot(
        [a[n] for n in QUATERNION], [b[n] for n in QUATERNION]) < 0 else 1.0
    return all(abs(float(a[n]) * (sign if n in QUATERNION else 1.0) - b[n])
               <= 1e-8 * max(1.0, abs(float(a[n]))) for n in a)


def same_candidates(python: list, twin: list) -> None:
    """The twin's candidates are the Python's (in some order)."""
    assert len(twin) == len(python), (python, twin)
    left = list(twin)
    for cand in python:
        match = next((i for i, c in enumerate(left) if _same_candidate(cand, c)), None)
        assert match is not None, (cand, twin)
        assert list(left[match]) == list(cand)  # the names, in the Python's order
        left.pop(match)


def test_twins_give_the_python_candidates(family):
    rng = np.random.default_rng(7)
    twins = {name: family.fastpath.initializer(name) for name in NAMES}
    covered = {name: 0 for name in NAMES}
    total = dict(covered)
    out, k = np.empty(48), np.array([CONSTANTS["cx"], CONSTANTS["cy"], CONSTANTS["f0"]])
    for seed, motion in enumerate(MOTIONS):
        scene = two_view_scene(motion, n=200, outliers=0.3, sigma=0.5, seed=seed)
        X, inliers = np.ascontiguousarray(scene.data), np.flatnonzero(scene.inliers)
        for trial in range(40):
            pool = inliers if trial % 3 == 0 else np.arange(len(X))
            for name, m in (("two_view_fundamental", 7),
                            ("two_view_fundamental", int(rng.integers(8, 21))),
                            ("two_view_homography", 4),
                            ("two_view_homography", int(rng.integers(5, 21))),
                            ("two_view_rotation", 2),
                            ("two_view_rotation", int(rng.integers(4, 21))),
                            ("two_view_translation", 2),
                            ("two_view_translation", int(rng.integers(3, 21)))):
                rows = X[rng.choice(pool, m, replace=False)]
                same_candidates(INITIALIZERS[name].fn(rows, CONSTANTS),
                                twins[name](rows, CONSTANTS))
                total[name] += 1
                covered[name] += family.fastpath._twins[name](
                    m, rows.ctypes.data, k.ctypes.data, out.ctypes.data) >= 0
    for name in NAMES:  # the C code answers, not the Python fallback
        assert covered[name] >= 0.9 * total[name], (name, covered[name], total[name])


def _degenerate_samples():
    rng = np.random.default_rng(3)
    X = np.ascontiguousarray(two_view_scene("general", n=30, sigma=0.5, seed=2).data)
    nan = X[:10].copy()
    nan[3, 2] = np.nan
    inf = X[:10].copy()
    inf[0, 0] = np.inf
    line = np.linspace(0, 1, 12)[:, None]
    collinear = np.c_[100 + 400 * line, 50 + 300 * line, 120 + 380 * line, 60 + 290 * line]
    return {
        "nan": nan, "inf": inf, "few3": X[:3], "few6": X[:6], "empty": X[:0], "one": X[:1],
        "nan2": nan[2:4], "identical2": np.tile(X[:1], (2, 1)),
        "duplicates7": X[[0, 0, 1, 2, 3, 4, 5]], "duplicates4": X[[0, 0, 1, 2]],
        "duplicates12": X[[0, 1, 2, 3] * 3],
        "identical": np.tile(X[:1], (9, 1)), "identical4": np.tile(X[:1], (4, 1)),
        "collinear": collinear, "collinear7": collinear[:7], "collinear4": collinear[:4],
        "zeros": np.zeros((8, 4)), "noise": rng.uniform(0, 640, (7, 4)),
    }


@pytest.mark.parametrize("case", sorted(_degenerate_samples()))
@pytest.mark.parametrize("name", NAMES)
def test_degenerate_samples_as_the_python(family, name, case):
    twin = family.fastpath.initializer(name)
    # another layout (a list, a Fortran array) runs the Python. On a degenerate sample the
    # Python's outcome follows LAPACK's arbitrary null vector, which may differ with the
    # memory layout: each layout against the Python on the same layout.
    rows = _degenerate_samples()[case]
    for layout in (rows, rows.tolist(), np.asfortranarray(rows)):
        with np.errstate(all="ignore"):
            same_candidates(INITIALIZERS[name].fn(layout, CONSTANTS),
                            twin(layout, CONSTANTS))


def test_the_compiled_backend_uses_the_twins(family):
    chosen = model_initializers(family)
    fast = family.fastpath
    for model, info in family.models.items():
        if info.initializer in NAMES:
            assert chosen[model] is not INITIALIZERS[info.initializer].fn
            assert chosen[model].__qualname__.startswith("FastPath.initializer")
    assert fast.initializer("no_such_initializer") is None
    # a callable override runs as given; a name runs as the twin
    assert model_initializers(family, {"general": init.two_view_homography})["general"] \
        is init.two_view_homography
    named = model_initializers(family, {"general": "two_view_homography"})["general"]
    assert named is not init.two_view_homography
    # the NumPy backend runs the Python
    assert model_initializers(kanagen.load("two_view"))["general"] \
        is init.two_view_fundamental


def test_only_a_family_naming_a_two_view_initializer_has_the_twins(family):
    """kanagen_geometry.c is compiled into a family's library only when one of its models
    names a two-view initializer (issue 17, "Vision as a plugin"): the conic library has no
    kg_two_view_* and no twins to call; a name it lacks runs the Python closed form."""
    from kanagen.codegen.compile import TWIN_INITIALIZERS, uses_twins
    from kanagen.runtime.fastpath import TWIN_WIDTH, TWINS

    assert TWIN_INITIALIZERS == tuple(TWINS) == NAMES
    assert TWIN_WIDTH == len(init._TWO_VIEW_Q)
    conic = compiled("conic")
    assert not uses_twins(conic.module.FAMILY) and uses_twins(family.module.FAMILY)
    with_twins = ctypes.CDLL(str(family.fastpath.library))
    without = ctypes.CDLL(str(conic.fastpath.library))
    for name in NAMES:
        assert hasattr(with_twins, f"kg_{name}") and not hasattr(without, f"kg_{name}")
    assert with_twins.kg_sample_twins() == len(TWINS) and without.kg_sample_twins() == 0
    assert family.fastpath.has_twins and not conic.fastpath.has_twins
    assert conic.fastpath.initializer("two_view_fundamental") is None
    # an override naming a closed form the library lacks runs the Python
    assert model_initializers(conic, {"conic": "two_view_fundamental"})["conic"] \
        is init.two_view_fundamental


@pytest.mark.parametrize("motion", ["planar", "general"])
def test_one_call_per_batch_gives_the_solve_by_solve_search(family, motion, monkeypatch):
    """kg_search (runtime/fastsample.py) runs a batch of samples in one call: it draws them
    as numpy's Generator.choice draws them, runs each sample's starts, minimal solves and
    coherence errors (kg_sample's C, in the same order) and scores them by relevance in
    the same order of sums: the lattice search is the one of the solve-by-solve compiled
    path, bit for bit — and the one of one sample per call (Estimator.step)."""
    from kanagen.runtime import robust
    from kanagen.runtime.fastsample import Sampler

    scene = two_view_scene(motion, n=60, outliers=0.3, sigma=0.5, seed=7)
    used, batches = [], []

    def spy(search):
        sampler = original(search)
        used.append((search.model, sampler is not None))
        return sampler

    def run(stepwise=False):
        est = kanagen.Estimator(family, scale=9.0, seed=3, constants=scene.constants,
                                adaptive=True)
        est.add_measures("match", scene.data, info=4.0)
        if stepwise:  # one sample per call (the same run: its budgets share its samples)
            best = est.run(max_samples=2000, until=lambda history: False)
        else:
            best = est.run(max_samples=2000)
        return best, [(s.model, s.samples, s.relevance, s.q) for s in est.states()], \
            est.history

    burst = Sampler.burst

    def counted(self, *args):
        out = burst(self, *args)
        batches.append(out[0] if out is not None else 0)
        return out

    original = robust.sampler_for
    monkeypatch.setattr(robust, "sampler_for", spy)
    monkeypatch.setattr(Sampler, "burst", counted)
    fused = run()
    in_c = {model for model, compiled in used if compiled}
    # sampled models in C; zoom's samples fitted, the retinal models' closed forms Python
    assert in_c and {"zoom", "retinal_translation"} <= {m for m, c in used if not c}
    # most samples of those models ran in batches (the Python only for degenerate ones)
    sampled = sum(samples for model, samples, *_ in fused[1] if model in in_c)
    assert sum(batches) > 0.8 * sampled and len(batches) < 0.2 * sampled
    one_by_one = run(stepwise=True)
    monkeypatch.setattr(robust, "sampler_for", lambda search: None)
    plain = run()
    for other in (one_by_one, plain):
        assert fused[0].model == other[0].model
        np.testing.assert_array_equal(fused[0].q, other[0].q)
        assert fused[2] == other[2]
        for a, b in zip(fused[1], other[1], strict=True):
            assert a[:3] == b[:3]
        np.testing.assert_array_equal(a[3], b[3])


@given(size=st.integers(1, 20_000), data=st.data())
@settings(max_examples=60, deadline=None)
def test_kg_choice_draws_as_numpy(family, size, data):
    """kg_search draws its samples as Generator.choice(size, k, replace=False) does, on the
    same bit generator: the same indices, and the generator left in the same state."""
    k = data.draw(st.integers(1, min(size, 12)))
    seed = data.draw(st.integers(0, 2**32 - 1))
    ours, theirs = np.random.default_rng(seed), np.random.default_rng(seed)
    idx = np.empty(k, dtype=np.int64)
    for _ in range(3):
        family.fastpath.choice(ours.bit_generator.ctypes.bit_generator, size, k,
                               idx.ctypes.data)
        np.testing.assert_array_equal(idx, theirs.choice(size, k, replace=False))
    assert ours.bit_generator.state == theirs.bit_generator.state


def test_a_partial_parent_hands_its_estimate_to_the_child(family, monkeypatch):
    """A translation holding 169 of a general motion's 200 matches leaves 31 of them among
    its 117 outliers, the pool of the general model's samples: 5 drawn there are all
    inliers once in ~800 samples. Where the samples missed them, the translation's
    estimate refined as a general model (its 31 extra matches explained) replaces them:
    with this seed the lattice ended at `translation` before."""
    from kanagen.runtime import robust

    scene = two_view_scene("general", n=200, outliers=0.3, sigma=0.5, seed=5000)
    taken = []
    consider = robust.ModelSearch.consider

    def spy(self, q, floor):
        taken.append((self.model, consider(self, q, floor)))
        return taken[-1][1]

    monkeypatch.setattr(robust.ModelSearch, "consider", spy)
    # the fixed budget: the adaptive one draws the child's samples until one finds it
    est = kanagen.Estimator(family, scale=9.0, seed=6, constants=scene.constants,
                            adaptive=False)  # a seed whose samples miss (6, 7, 9, 10 of 0-11)
    est.add_measures("match", scene.data, info=4.0)
    best = est.run(max_samples=10_000)
    parent = next(s for s in est.states() if s.model == "translation")
    assert parent.inliers.size < 180 and taken == [("general", True)]
    assert best.model == "general" and best.parent == "translation"
    assert np.count_nonzero(scene.inliers[best.inliers]) >= 195


def test_a_child_short_of_its_parent_stops_refining(family, monkeypatch):
    """A fundamental matrix on matches of no motion is degenerate: its fit crawls along
    the valley (its cost falls by 1e-6 of itself per iteration). Across a change of
    equations per measure it needs a fifth more inliers than its parent to matter; while
    short of them its refinement stops after a lap without progress, instead of
    iterating 100 times (26 ms of a 49 ms scene)."""
    from kanagen.runtime import robust

    scene = two_view_scene("none", n=200, outliers=0.3, sigma=0.5, seed=0)
    iterations = []
    fit_problem = robust.fit_problem

    def spy(fam, model, *args, **kwargs):
        res = fit_problem(fam, model, *args, **kwargs)
        if model == "general":
            iterations.append(res.iterations)
        return res

    monkeypatch.setattr(robust, "fit_problem", spy)
    est = kanagen.Estimator(family, scale=9.0, seed=0, constants=scene.constants,
                            adaptive=True)
    est.add_measures("match", scene.data, info=4.0)
    assert est.run(max_samples=10_000).model == "none"
    general = next(s for s in est.states() if s.model == "general")
    assert not general.accepted and general.inliers.size < 1.2 * 200
    assert sum(iterations) < 100  # the samples' local optimisation and the refinement
