"""The compiled fast path of the robust search (docs/fastpath.md) against the NumPy runtime:
the coherence errors (eq. 22–24) and minimal solves (eq. 21) to 1e-10 on problems that
exercise their paths (several channels, exact components, per-measure information, far
outliers, two-view scenes), the local fit's restorations (kg_project), the closest square
root, threads, and the fingerprints that name the Python the C must follow."""

from __future__ import annotations

import warnings

import numpy as np
import port_fingerprints
import pytest
from scenarios import close

import kanagen
from kanagen.codegen.compile import CompileWarning

SPEC = """\
name: twochan
constants: {s: 2.0}
parameter: {a: 1.0, b: 0.5, c: 0.1}
channels:
  pts:
    components: [x, y]
    equations: [y - a*x**2 - b*x - c]
  obs:
    components: [t, u, v]
    exact: [t]
    equations: [u - a*t - b, v - s*c*t - exp(-b*t)]
models:
  free:
    constraints: []
    alternatives: [tied, sphere]
  tied:
    constraints: [a - 2*b]
  sphere:
    constraints: [a**2 + b**2 + c**2 - 1.61]
    alternatives: [positive]
  positive:
    constraints: {norm: a**2 + b**2 + c**2 - 1.61, pos: c > 0}
derived:
  ab: [[a*b, b/c], [c, a + b]]
  r: sqrt(a**2 + b**2)
"""


def compiled(spec, name="test.yaml", **options):
    """The family on the compiled backend (skips without a C compiler)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", CompileWarning)
        try:
            if isinstance(spec, str) and "\n" in spec:
                return kanagen.load_text(spec, name, backend="compiled", **options)
            return kanagen.load(spec, backend="compiled", **options)
        except CompileWarning as exc:
            pytest.skip(f"no compiled backend here: {exc}")


def reference(spec, name="test.yaml", **options):
    if isinstance(spec, str) and "\n" in spec:
        return kanagen.load_text(spec, name, **options)
    return kanagen.load(spec, **options)


@pytest.fixture(scope="module")
def families():
    return reference(SPEC), compiled(SPEC)


def _data(seed: int, M1: int, M2: int, noise: float = 0.05):
    rng = np.random.default_rng(seed)
    a, b, c = 0.8, 0.4, 0.9
    x = rng.uniform(-2, 2, M1)
    t = rng.uniform(0, 3, M2)
    pts = np.c_[x, a * x**2 + b * x + c] + rng.normal(0, noise, (M1, 2))
    obs = np.c_[t, a * t + b, 2.0 * c * t + np.exp(-b * t)]
    obs[:, 1:] += rng.normal(0, noise, (M2, 2))
    return {"pts": pts, "obs": obs}

@pytest.mark.parametrize("iterations", [1, 3, None])
def test_coherence_errors_as_on_the_numpy_runtime(families, iterations):
    """The robust search's scoring (eq. 24, minimal.coherence_errors) through kg_coherence:
    per-measure information, far outliers (the halving), a two-view scene with 30 %
    outliers; the same errors to 1e-10 (outliers' beyond 100 σ²: 1e-7)."""
    from kanagen.runtime.fit import make_problem
    from kanagen.runtime.minimal import coherence_errors
    from kanagen.scenes import two_view_scene

    ref, fast = families
    data = _data(8, 25, 12)
    data["pts"][::5] += 40.0
    rng = np.random.default_rng(9)
    info = {"pts": rng.uniform(0.5, 3.0, 25), "obs": 2.0}
    cases = [(ref, fast, model, data, info, None, q)
             for model in ("free", "sphere", "positive")
             for q in (np.array([0.8, 0.4, 0.9, 1.0]), np.array([2.0, -1.0, 0.3, 0.5]))]
    scene = two_view_scene("general", n=60, outliers=0.3, sigma=0.5, seed=3)
    tv = reference("two_view"), compiled("two_view")
    p = scene.params()
    q = np.array([p[name] for name in tv[0].parameter_names])
    cases += [(*tv, model, {"match": scene.data}, {"match": 4.0}, scene.constants, q)
              for model in ("general", "planar")]
    for a, b, model, data, info, constants, q in cases:
        q = q[:a.n]
        pa, pb = (make_problem(f, model, data, info, constants=constants) for f in (a, b))
        assert pa.compiled is None and pb.compiled is not None
        want = coherence_errors(pa, q, iterations)
        got = coherence_errors(pb, q, iterations)
        for x, y in zip(got, want, strict=True):
            # an outlier (100 σ² and beyond) is projected from far off the zero set, where
            # the third of the two-view H equations (rank two on the zero set) is nearly
            # dependent: its small pivot carries the rounding of the two evaluations of the
            # equations (CasADi's C, NumPy) into the steps. 1e-7 there (e.g. 221 σ² ± 5e-6)
            far = y > 100.0
            close(x[~far], y[~far])
            close(x[far], y[far], rtol=1e-7)


def test_restorations_as_on_the_numpy_runtime(families):
    """The local fit's restorations (restoration.restore_measures: the engine's kernels, the
    same on every backend) on a compiled family and on the NumPy one: the same measures,
    violations and equations at the returned point to 1e-10, on several channels, an exact
    component, per-measure information, far measures and a two-view scene; and the same
    fit."""
    from kanagen.runtime.fit import make_problem
    from kanagen.runtime.restoration import restore_measures
    from kanagen.scenes import two_view_scene

    ref, fast = families
    data = _data(5, 20, 9)
    data["pts"][::4] += 10.0
    rng = np.random.default_rng(4)
    info = {"pts": rng.uniform(0.5, 3.0, 20), "obs": 2.0}
    scene = two_view_scene("general", n=60, outliers=0.3, sigma=0.5, seed=3)
    tv = reference("two_view"), compiled("two_view")
    p = scene.params()
    q_tv = np.array([p[name] for name in tv[0].parameter_names])
    cases = [(ref, fast, "sphere", data, info, None, np.array([0.8, 0.4, 0.9, 1.0])),
             (*tv, "general", {"match": scene.data}, {"match": 4.0}, scene.constants, q_tv)]
    for a, b, model, values, weights, constants, q in cases:
        q = q[:a.n]
        pa, pb = (make_problem(f, model, values, weights, constants=constants)
                  for f in (a, b))
        assert pa.compiled is None and pb.compiled is not None
        start = tuple(ch.m + 0.3 * rng.standard_normal(ch.m.shape) for ch in pa.channels)
        (xa, va), (xb, vb) = (restore_measures(pr, q, start) for pr in (pa, pb))
        close(vb, va, scale=1.0)
        for ma, mb in zip(xa.mt, xb.mt, strict=True):
            close(mb, ma)
        for ea, eb in zip(xa.evals, xb.evals, strict=True):
            close(eb[0], ea[0], scale=1.0)  # the equations at their zero: rounding apart
            for u, v in zip(ea[1:], eb[1:], strict=True):
                close(v, u)
        close(xb.cost, xa.cost)
    fa = kanagen.fit(ref, "sphere", data=data, info=info)
    fb = kanagen.fit(fast, "sphere", data=data, info=info)
    assert fa.status == fb.status and fa.iterations == fb.iterations
    close(fb.q, fa.q)


def test_minimal_solves_as_on_the_numpy_runtime():
    """The robust search's minimal solves (eq. 21, minimal.minimal_solve_problem) through
    kg_minimal: random minimal samples of two-view scenes (30 % outliers) for every model,
    from each closed-form start; the same success, rank and iterations, q to 1e-10."""
    from kanagen.runtime.fit import make_problem
    from kanagen.runtime.initializers import model_initializers
    from kanagen.runtime.minimal import minimal_solve_problem
    from kanagen.runtime.robust import start_from
    from kanagen.scenes import two_view_scene

    ref, fast = reference("two_view"), compiled("two_view")
    starts_of = model_initializers(ref)
    count = 0
    for seed, motion in enumerate(("general", "planar", "rotation")):
        scene = two_view_scene(motion, n=40, outliers=0.3, sigma=0.5, seed=seed)
        rng = np.random.default_rng(seed)
        for model in ref.models:
            size = kanagen.minimal_sample_size(ref, model, "match", None, scene.constants)
            for _ in range(4):
                X = scene.data[rng.choice(len(scene.data), size=size, replace=False)]
                pa, pb = (make_problem(f, model, {"match": X}, None, constants=scene.constants)
                          for f in (ref, fast))
                starts = [ref.q0]
                if model in starts_of:
                    starts = [start_from(ref, c, ref.q0)
                              for c in starts_of[model](X, scene.constants)]
                    starts = [ref.with_slacks(q, pa.k, model) for q in starts if q is not None]
                for start in starts:
                    want, got = minimal_solve_problem(pa, start), minimal_solve_problem(pb, start)
                    assert (got.success, got.rank, got.iterations) == \
                        (want.success, want.rank, want.iterations)
                    # at a solution the violation is rounding (1e-16 of scaled equations)
                    close(got.violation, want.violation, scale=1e-4)
                    if want.success:
                        close(got.q, want.q)
                    count += 1
    assert count > 50




@pytest.mark.parametrize("seed", [1688030, 3, 4])
def test_closest_sqrt_of_a_rank_deficient_matrix(seed):
    """The compiled closest root zeroes the column below a fixed pivot as the Python does
    (rank 3 of 6: without it the noise under the vanishing pivots, amplified by 1/√ε, gave
    |LLᵀ − S| = 259 on the first)."""
    from kanagen.runtime.sqrt import EPS, closest_sqrt

    C = np.random.default_rng(seed).normal(size=(6, 3))
    S = C @ C.T
    fast = compiled("conic")
    with pytest.raises(ValueError, match="at most 6"):
        fast.fastpath.closest_sqrt(np.eye(7), EPS)
    L = fast.fastpath.closest_sqrt(S, EPS)
    close(L, closest_sqrt(S, EPS), rtol=1e-9)
    assert np.abs(L @ L.T - S).max() <= 1e-6 * np.max(np.diag(S))




def test_the_port_is_current_with_the_python_it_mirrors():
    stale = port_fingerprints.changed()
    assert not stale, (
        "the Python that codegen/c/ ports has changed: " + ", ".join(stale) + ". Port the "
        "change to the C (docs/fastpath.md), run tests/test_fastpath.py and "
        "tests/test_fast_initializers.py, then paste the output of `python "
        "tests/port_fingerprints.py` into FINGERPRINTS in tests/port_fingerprints.py.")


def test_threads_share_a_compiled_family(families):
    """Per-thread argument buffers: concurrent scorings (kg_coherence) and minimal solves
    (kg_minimal) give the sequential answers."""
    from concurrent.futures import ThreadPoolExecutor

    from kanagen.runtime.fit import make_problem
    from kanagen.runtime.minimal import coherence_errors, minimal_solve_problem

    _, fast = families
    cases = [(make_problem(fast, model, _data(seed, 10 + seed, 6 + seed)), seed)
             for seed in range(6) for model in ("free", "sphere")]

    def work(case):
        problem, seed = case
        q = np.array([0.8, 0.4, 0.9, 1.0])[:fast.n] + 0.1 * seed
        errors = coherence_errors(problem, q, None)
        minimal = minimal_solve_problem(
            problem.subset(tuple(np.arange(2) for _ in problem.channels)), q)
        return np.concatenate([*errors, minimal.q])

    expected = [work(case) for case in cases]
    with ThreadPoolExecutor(4) as pool:
        got = list(pool.map(work, cases * 3))
    for value, ref in zip(got, expected * 3, strict=True):
        np.testing.assert_array_equal(value, ref)
