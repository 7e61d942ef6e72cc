"""The robust search's samples in the engine (runtime/engine/sample.py) against NumPy
references (tests/reference_minimal.py): the minimal solves (eq. 21) and the errors of every
measure at a solution (eq. 24 at one projection step) on problems that exercise their paths
(several channels, exact components, per-measure information, far outliers, two-view scenes),
the relevance bound that abandons a hopeless solution, the draws (NumPy's
``Generator.choice``, bit for bit) and threads."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from reference_minimal import errors_at_observed, minimal_solve
from scenarios import TWOCHAN, close, twochan_data

import kanagen
from kanagen.runtime.engine import sample as kernels
from kanagen.runtime.engine.data import _FIELDS, arrays
from kanagen.runtime.fastsample import generator_addresses
from kanagen.runtime.fit import make_problem
from kanagen.runtime.minimal import coherence_errors, minimal_solve_problem
from kanagen.runtime.scoring import relevance
from kanagen.scenes import two_view_scene


@pytest.fixture(scope="module")
def twochan():
    return kanagen.load_text(TWOCHAN, "twochan.yaml")


@pytest.fixture(scope="module")
def two_view():
    return kanagen.load("two_view")


def _cases(twochan, two_view):
    """(problem, q, caps) on both families: several channels with an exact component,
    per-measure information and far outliers; two-view scenes with 30 % outliers."""
    data = twochan_data(8, 25, 12)
    data["pts"][::5] += 40.0
    info = {"pts": np.random.default_rng(9).uniform(0.5, 3.0, 25), "obs": 2.0}
    out = [(make_problem(twochan, model, data, info), q, (1, 2))
           for model in ("free", "sphere")
           for q in (np.array([0.8, 0.4, 0.9]), np.array([2.0, -1.0, 0.3]))]
    for motion in ("general", "planar"):
        scene = two_view_scene(motion, n=60, outliers=0.3, sigma=0.5, seed=3)
        p = scene.params()
        q = np.array([p.get(name, 0.0) for name in two_view.parameter_names])
        for model, caps in (("general", (1,)), ("planar", (2,))):
            out.append((make_problem(two_view, model, {"match": scene.data}, {"match": 4.0},
                                     constants=scene.constants), q, caps))
    return out


def test_errors_at_a_solution_as_the_reference(twochan, two_view):
    """:func:`errors_at` (the sample's scoring) gives every measure's error at one
    projection step: the reference's eigendecomposition of ``D Q⁺ Dᵀ``, and
    ``coherence_errors(iterations=1)`` (the projection kernel), to 1e-10; its relevance is
    eq. 29's of them."""
    for problem, q, caps in _cases(twochan, two_view):
        A = arrays(problem)
        errors = np.empty(A.chan.size)
        complete, score = kernels.errors_at(A, q, np.array(caps), 9.0, -np.inf, errors)
        assert complete
        want = np.concatenate(errors_at_observed(problem, q, caps))
        finite = np.isfinite(want)
        assert np.array_equal(np.isfinite(errors), finite)
        close(errors[finite], want[finite], rtol=1e-9)
        np.testing.assert_array_equal(
            errors, np.concatenate(coherence_errors(problem, q, 1, ranks=caps)))
        assert score == pytest.approx(relevance(errors, 9.0), rel=1e-12, abs=1e-15)


def test_projected_errors_are_the_projection_and_its_distance(twochan, two_view):
    """``coherence_errors`` with projection steps (:func:`.measures.projected_errors`, one
    kernel, the values forms alone) gives what the projection of every measure gives —
    ``project_measures``, ``‖m̃ − m‖²_Q`` by NumPy's ``einsum`` plus the violation, over the
    equations kept — bit for bit."""
    from kanagen.runtime.projector import project_measures

    for problem, q, caps in _cases(twochan, two_view):
        for iterations in (2, 5, 50):
            with np.errstate(all="ignore"):
                mt, violations, kept, _ = project_measures(
                    problem, q, tuple(ch.m for ch in problem.channels), iterations, 1e-10)
                for ch, m, v, r, got, cap in zip(
                        problem.channels, mt, violations, kept,
                        coherence_errors(problem, q, iterations, ranks=caps), caps,
                        strict=True):
                    Q = ch.Q if ch.Q.ndim == 3 else np.broadcast_to(ch.Q, (ch.size,) +
                                                                     ch.Q.shape)
                    want = (np.einsum("mk,mkl,ml->m", m - ch.m, Q, m - ch.m) + v) / \
                        np.maximum(np.minimum(r, cap), 1)
                    np.testing.assert_array_equal(got, np.where(np.isfinite(want), want,
                                                                np.inf))


def test_a_hopeless_solution_is_abandoned_exactly(two_view):
    """With the best relevance so far, a solution is abandoned only when the measures left
    could not lift it there: below the best (by more than rounding) it is, at or above
    it never."""
    scene = two_view_scene("general", n=300, outliers=0.3, sigma=0.5, seed=4)
    problem = make_problem(two_view, "general", {"match": scene.data}, {"match": 4.0},
                           constants=scene.constants)
    p = scene.params()
    A = arrays(problem)
    errors = np.empty(A.chan.size)
    for shift in (0.0, 1e-3, 3e-2):
        q = np.array([p.get(name, 0.0) for name in two_view.parameter_names]) + shift
        score = kernels.errors_at(A, q, np.array([1]), 9.0, -np.inf, errors)[1]
        assert kernels.errors_at(A, q, np.array([1]), 9.0, score, errors)[0]
        assert kernels.errors_at(A, q, np.array([1]), 9.0, score - 1e-3, errors)[0]
        if score < 0.5:  # the first 64 measures cannot carry it to 0.9
            assert not kernels.errors_at(A, q, np.array([1]), 9.0, 0.9, errors)[0]


def test_minimal_solves_as_the_reference(two_view):
    """Random minimal samples of two-view scenes (30 % outliers) for every sampled model,
    from each closed-form start: the engine's solve gives the reference's success and
    rank, the same iterations, ``q`` to 1e-9."""
    from kanagen.runtime.initializers import model_initializers, start_from

    fam = two_view
    starts_of = model_initializers(fam)
    count = 0
    for seed, motion in enumerate(("general", "planar", "rotation")):
        scene = two_view_scene(motion, n=40, outliers=0.3, sigma=0.5, seed=seed)
        rng = np.random.default_rng(seed)
        for model in fam.models:
            size = kanagen.minimal_sample_size(fam, model, "match", None, scene.constants)
            for _ in range(4):
                X = scene.data[rng.choice(len(scene.data), size=size, replace=False)]
                problem = make_problem(fam, model, {"match": X}, None,
                                       constants=scene.constants)
                starts = [fam.q0]
                if model in starts_of:
                    starts = [start_from(fam, c, fam.q0)
                              for c in starts_of[model](X, scene.constants)]
                    starts = [fam.with_slacks(q, problem.k, model)
                              for q in starts if q is not None]
                for start in starts:
                    q, success, rank, iterations, violation = minimal_solve(problem, start)
                    got = minimal_solve_problem(problem, start)
                    assert (got.success, got.rank, got.iterations) == \
                        (success, rank, iterations)
                    close(got.violation, violation, scale=1e-4)
                    if success:
                        close(got.q, q, rtol=1e-9)
                    count += 1
    assert count > 50


def test_minimal_solves_of_several_channels(twochan):
    """A sample of two channels (one with an exact component), a constraint: the same
    solve as the reference's."""
    data = twochan_data(3, 12, 6)
    for model in ("free", "tied", "sphere"):
        for rows in ((np.arange(2), np.arange(1)), (np.arange(1), np.arange(1)),
                     (np.arange(3), np.arange(0))):
            problem = make_problem(twochan, model, data).subset(rows)
            for start in (np.array([0.7, 0.3, 1.0]), np.array([1.2, 0.6, 0.5])):
                q, success, rank, iterations, _ = minimal_solve(problem, start)
                got = minimal_solve_problem(problem, start)
                assert (got.success, got.rank, got.iterations) == (success, rank, iterations)
                if success:
                    close(got.q, q, rtol=1e-9)


def test_a_non_finite_sample_is_no_solution(twochan):
    """Equations that overflow (NaN Jacobian) end the solve unsolved, never raise."""
    data = twochan_data(3, 4, 2)
    data["pts"][0, 0] = 1e300
    problem = make_problem(twochan, "free", data).subset((np.arange(2), np.arange(1)))
    got = minimal_solve_problem(problem, np.array([0.7, 0.3, 1.0]))
    assert not got.success


def draw(rng: np.random.Generator, size: int, k: int) -> np.ndarray:
    """``k`` of ``range(size)`` drawn by the engine from ``rng``."""
    idx = np.empty(max(k, 1), dtype=np.int64)
    kernels.choice(*generator_addresses(rng.bit_generator), size, k, idx)
    return idx[:k]


def bounded_draw(rng: np.random.Generator, top: int) -> int:
    """A uniform integer of ``[0, top]`` drawn by the engine from ``rng``."""
    return int(kernels.bounded(*generator_addresses(rng.bit_generator), top))


@given(size=st.integers(1, 20_000), data=st.data())
@settings(max_examples=60, deadline=None)
def test_draws_as_numpy(size, data):
    """The engine draws samples as ``Generator.choice(size, k, replace=False)`` does, on
    the same bit generator: the same indices, the generator left in the same state."""
    k = data.draw(st.integers(1, min(size, 12)))
    seed = data.draw(st.integers(0, 2**32 - 1))
    ours, theirs = np.random.default_rng(seed), np.random.default_rng(seed)
    for _ in range(3):
        np.testing.assert_array_equal(draw(ours, size, k),
                                      theirs.choice(size, k, replace=False))
    assert ours.bit_generator.state == theirs.bit_generator.state


@pytest.mark.parametrize("top", [0, 1, 6, 2**31, 2**32 - 2, 2**32 - 1])
def test_bounded_draws_as_numpy(top):
    """NumPy's bounded integer (Lemire's rejection on 32-bit words, none for 0)."""
    ours, theirs = np.random.default_rng(11), np.random.default_rng(11)
    for _ in range(50):
        assert bounded_draw(ours, top) == theirs.integers(0, top, endpoint=True)
    assert ours.bit_generator.state == theirs.bit_generator.state


def test_threads_share_a_family(twochan):
    """Concurrent scorings and minimal solves give the sequential answers."""
    from concurrent.futures import ThreadPoolExecutor

    cases = [(make_problem(twochan, model, twochan_data(seed, 10 + seed, 6 + seed)), seed)
             for seed in range(6) for model in ("free", "sphere")]

    def work(case):
        problem, seed = case
        q = np.array([0.8, 0.4, 0.9]) + 0.1 * seed
        errors = coherence_errors(problem, q, None)
        minimal = minimal_solve_problem(
            problem.subset(tuple(np.arange(2) for _ in problem.channels)), q)
        return np.concatenate([*errors, minimal.q])

    expected = [work(case) for case in cases]
    with ThreadPoolExecutor(4) as pool:
        got = list(pool.map(work, cases * 3))
    for value, ref in zip(got, expected * 3, strict=True):
        np.testing.assert_array_equal(value, ref)


@given(m=st.integers(1, 14), extra=st.integers(-3, 6), rank=st.integers(0, 12),
       seed=st.integers(0, 2**32 - 1), scale=st.sampled_from([1e-8, 1.0, 1e6]))
@settings(max_examples=80, deadline=None)
def test_jacobi_svd_as_lapack(m, extra, rank, seed, scale):
    """The minimal solves' SVD (one-sided Jacobi on the rows): ``J = Wᵀ diag(S) V`` with
    orthogonal ``W`` and orthonormal rows of ``V``, LAPACK's singular values to 1e-12 of
    the largest, on matrices of every rank and shape (more rows than columns: the rows
    beyond the rank left at rounding level)."""
    from kanagen.runtime.linalg import row_svd

    rng = np.random.default_rng(seed)
    n = max(m + extra, 1)
    k = min(rank, m, n)
    J = scale * (rng.standard_normal((m, k)) @ rng.standard_normal((k, n)))
    R, W, S = np.empty((m, n)), np.empty((m, m)), np.empty(m)
    assert row_svd(J, R, W, S) > 0
    top = max(S.max(), 1e-300)
    want = np.zeros(m)
    want[:min(m, n)] = np.linalg.svd(J, compute_uv=False)
    np.testing.assert_allclose(np.sort(S)[::-1], want, rtol=0, atol=1e-12 * top)
    np.testing.assert_allclose(W @ W.T, np.eye(m), atol=1e-13)
    np.testing.assert_allclose(W.T @ R, J, atol=1e-13 * top)
    big = S > 1e-10 * top
    V = R[big] / S[big, None]
    np.testing.assert_allclose(V @ V.T, np.eye(big.sum()), atol=1e-12)


@given(m=st.integers(1, 16), extra=st.integers(-6, 4), rank=st.integers(0, 12),
       seed=st.integers(0, 2**32 - 1), scale=st.sampled_from([1e-8, 1.0, 1e6]))
@settings(max_examples=80, deadline=None)
def test_triangular_rows_keep_the_least_squares_problem(m, extra, rank, seed, scale):
    """The minimal solves' reduction of a tall Jacobian (Householder ``J = Q [T; 0]``):
    ``TᵀT = JᵀJ`` and ``Tᵀg = Jᵀc`` — the same normal equations, so the same singular
    values and right singular vectors and the same least-squares steps — ``T`` upper
    triangular; a Jacobian of no more rows than columns is kept as it is."""
    from kanagen.runtime.linalg import triangular_rows

    rng = np.random.default_rng(seed)
    n = max(m + extra, 1)
    k = min(rank, m, n)
    J = scale * (rng.standard_normal((m, k)) @ rng.standard_normal((k, n)))
    c = scale * rng.standard_normal(m)
    rows = min(m, n)
    T, g = np.full((rows, n), np.nan), np.full(rows, np.nan)
    triangular_rows(J, c, np.empty((m, n + 1)), np.empty((m, n)), T, g)
    top = scale * scale * max(1.0, np.abs(J).max() / scale) ** 2 * m
    np.testing.assert_allclose(T.T @ T, J.T @ J, rtol=0, atol=1e-13 * top)
    np.testing.assert_allclose(T.T @ g, J.T @ c, rtol=0, atol=1e-13 * top)
    if m <= n:
        assert np.array_equal(T, J) and np.array_equal(g, c)
    else:
        assert np.array_equal(np.tril(T, -1), np.zeros((n, n)))


@pytest.mark.parametrize("picks", [
    lambda M1, M2: (np.arange(0, M1, 2), np.arange(M2 - 1, -1, -3)),  # index arrays
    lambda M1, M2: (np.arange(M1) % 3 == 0, np.ones(M2, dtype=bool)),  # boolean masks
    lambda M1, M2: (np.array([-1, 0, 5]), np.zeros(0, dtype=int)),  # negative, none
])
def test_a_subset_gathers_the_arrays_it_would_make(twochan, picks):
    """A subset of a problem whose engine arrays are made gathers its own from them (one
    kernel call): every field the same, to the bit and the dtype, as made from the subset's
    channels; a shared and a per-measure information, an exact component."""
    from dataclasses import replace

    fam, data = twochan, twochan_data(3, 25, 20)
    for info in ({"pts": 400.0, "obs": 400.0},
                 {"pts": np.linspace(100.0, 900.0, len(data["pts"])), "obs": 400.0}):
        problem = make_problem(fam, "free", data, info)
        arrays(problem)
        rows = picks(len(data["pts"]), len(data["obs"]))
        sub = problem.subset(rows)
        gathered = arrays(sub)
        made = arrays(replace(sub))  # a new problem object: made from its channels
        for name in _FIELDS:
            a, b = getattr(gathered, name), getattr(made, name)
            assert type(a) is type(b) and np.asarray(a).dtype == np.asarray(b).dtype, name
            np.testing.assert_array_equal(a, b, err_msg=name)
        assert sub.channels[0].size == gathered.size[0]
