"""The compiled fast path of the estimator (docs/fastpath.md) against the NumPy runtime.

Every output of a fit to 1e-10 relative, the same status and iteration count, on problems
that exercise its paths: several channels, exact components, per-measure information,
priors, constraints of every kind, far starts (damping, halving), the iteration cap, NIST
problems; fallbacks where it does not apply; and the fingerprints that keep the C port in
step with the Python it ports.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from scenarios import close

import kanagen
from kanagen.codegen.compile import CompileWarning
from kanagen.runtime import fastpath

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
    alternatives: [tied]
  tied:
    constraints: [a - 2*b]
  sphere:
    constraints: [a**2 + b**2 + c**2 - 1.61]
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


def same_fit(a, b, path=True):
    """``b`` (compiled) is ``a`` (NumPy runtime) to 1e-10 relative. A failed fit (the
    iteration cap on a run that wanders, a stall far from a solution) only has to fail the
    same way: after a hundred iterations that do not converge, rounding has moved the point.
    ``path=False``: the same estimate, the number of iterations may differ (an ill-conditioned
    information damped by ``μ I`` in the trust region: rounding of order cond·ε in each step
    changes the radius' decisions, not where the iteration ends)."""
    assert (b.status, b.success) == (a.status, a.success), (a.message, b.message)
    if path:
        assert b.iterations == a.iterations, (a.iterations, b.iterations)
    assert b.message == a.message and b.model == a.model
    assert b.derived.keys() == a.derived.keys()
    if not a.success:
        return
    assert b.dof == a.dof
    close(b.q, a.q)
    close(b.cost, a.cost, scale=1e-300)
    # δ = ‖c‖∞ at a solution is rounding noise of the equations (of order |q|, the data)
    close(b.constraint_violation, a.constraint_violation, scale=max(1.0, np.abs(a.q).max()))
    close(b.residual, a.residual, scale=max(1.0, a.cost))
    close(b.info, a.info)
    sigma = float(np.max(np.abs(a.covariance[np.isfinite(a.covariance)]), initial=0.0))
    close(b.covariance, a.covariance, scale=sigma)
    assert a.params.keys() == b.params.keys() and a.slacks.keys() == b.slacks.keys()
    for name in a.measures:
        close(b.measures[name], a.measures[name])
        np.testing.assert_array_equal(b.ranks[name], a.ranks[name])
        assert b.ranks[name].dtype == a.ranks[name].dtype
    for name, d in a.derived.items():
        J = np.abs(d.jacobian.reshape(-1, a.q.size))
        close(b.derived[name].value, d.value, scale=float(J.sum(axis=1).max()) * float(
            np.abs(a.q).max()))
        close(b.derived[name].jacobian, d.jacobian)
        close(b.derived[name].covariance, d.covariance,
              scale=float(J.sum(axis=1).max()) ** 2 * sigma)


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


@pytest.mark.parametrize("model", ["free", "tied", "sphere", "positive"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_fit_equals_the_numpy_runtime(families, model, seed):
    ref, fast = families
    data = _data(seed, 12 + 5 * seed, 7 + 3 * seed)
    rng = np.random.default_rng(seed + 10)
    starts = [None, np.array([0.8, 0.4, 0.9]) + rng.normal(0, 0.3, 3), np.array([3.0, -2.0, 4.0])]
    infos = [None, {"pts": 4.0, "obs": 2.5}]
    for start in starts:
        for info in infos:
            args = dict(data=data, info=info, q_start=start, max_iter=40)
            same_fit(kanagen.fit(ref, model, **args), kanagen.fit(fast, model, **args))


def test_general_inputs_go_through_the_validated_problem(families):
    """Per-measure and matrix information, a prior, dict starts, constants: make_problem
    validates, and the compiled iteration runs on the validated problem."""
    ref, fast = families
    data = _data(3, 15, 9)
    rng = np.random.default_rng(4)
    A = rng.normal(size=(9, 2, 2))
    info = {"pts": rng.uniform(0.5, 3.0, 15), "obs": A @ np.swapaxes(A, 1, 2) + 0.2 * np.eye(2)}
    for model in ("free", "tied", "sphere"):
        for kwargs in ({"Q0": 0.5, "q0": [0.9, 0.3, 1.0]},
                       {"q0": {"a": 0.7}, "constants": {"s": 2.1}},
                       {"info": {"pts": [[2.0, 0.3], [0.3, 1.0]]}}):
            args = {"data": data, "info": info, **kwargs}
            same_fit(kanagen.fit(ref, model, **args), kanagen.fit(fast, model, **args))


def test_results_pickle_and_copy_as_plain_fit_results(families):
    """The compiled result builds its fields on demand; pickled or copied, it is the plain
    FitResult with the same values."""
    import copy
    import pickle

    ref, fast = families
    data = _data(6, 14, 8)
    res = kanagen.fit(fast, "positive", data=data)
    for other in (pickle.loads(pickle.dumps(res)), copy.deepcopy(res)):
        assert type(other) is kanagen.FitResult
        same_fit(res, other)
    same_fit(kanagen.fit(ref, "positive", data=data), res)


def test_iteration_cap_and_far_starts(families):
    ref, fast = families
    data = _data(5, 20, 10, noise=0.3)
    for max_iter in (0, 1, 2, 5):
        for start in (np.array([40.0, -30.0, 25.0]), np.array([0.0, 0.0, 1e-3])):
            args = dict(data=data, q_start=start, max_iter=max_iter)
            same_fit(kanagen.fit(ref, "sphere", **args), kanagen.fit(fast, "sphere", **args))


def test_bad_inputs_raise_as_on_the_numpy_path(families):
    _, fast = families
    data = _data(0, 5, 3)
    data["pts"][2, 1] = np.nan
    with pytest.raises(ValueError, match="NaN or infinite"):
        kanagen.fit(fast, "free", data=data)
    with pytest.raises(ValueError, match="shape"):
        kanagen.fit(fast, "free", data={"pts": np.zeros((4, 3))})
    with pytest.raises(ValueError, match="positive"):
        kanagen.fit(fast, "free", data=_data(0, 5, 3), info={"pts": -1.0})
    with pytest.raises(ValueError, match="unknown model"):
        kanagen.fit(fast, "nope", data=_data(0, 5, 3))


def test_robust_search_runs_the_compiled_refits():
    """robust_fit's refinements (fit_problem on subsets) on the fast path: same answer."""
    from scenes import arc, kasa_circle

    xy, _ = arc("ellipse", 7, n=60, outliers=0.25)
    start = kasa_circle(xy)
    out = [kanagen.robust_fit(f, "conic", data={"point": xy}, scale=4.0, seed=3, q0=start,
                              max_samples=60)
           for f in (reference("conic"), compiled("conic"))]
    assert out[0].samples == out[1].samples
    for name in out[0].inliers:
        np.testing.assert_array_equal(out[1].inliers[name], out[0].inliers[name])
    same_fit(out[0].fit, out[1].fit)


@pytest.mark.parametrize("iterations", [1, 3, None])
def test_coherence_errors_as_on_the_numpy_runtime(families, iterations):
    """The robust search's scoring (eq. 24, coherence.coherence_errors) through kg_coherence:
    per-measure information, far outliers (the halving), a two-view scene with 30 %
    outliers; the same errors to 1e-10 (outliers' beyond 100 σ²: 1e-7)."""
    from kanagen.runtime.coherence import coherence_errors
    from kanagen.runtime.fit import make_problem
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


def test_minimal_solves_as_on_the_numpy_runtime():
    """The robust search's minimal solves (eq. 21, coherence.solve_minimal) through
    kg_minimal: random minimal samples of two-view scenes (30 % outliers) for every model,
    from each closed-form start; the same success, rank and iterations, q to 1e-10."""
    from kanagen.runtime.coherence import solve_minimal
    from kanagen.runtime.fit import make_problem
    from kanagen.runtime.initializers import model_initializers
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
                    want, got = solve_minimal(pa, start), solve_minimal(pb, start)
                    assert (got.success, got.rank, got.iterations) == \
                        (want.success, want.rank, want.iterations)
                    # at a solution the violation is rounding (1e-16 of scaled equations)
                    close(got.violation, want.violation, scale=1e-4)
                    if want.success:
                        close(got.q, want.q)
                    count += 1
    assert count > 50


def test_eliminated_models_fall_back_to_the_numpy_iteration():
    ref = reference("conic", eliminate_linear=True)
    fast = compiled("conic", eliminate_linear=True)
    xy = _ellipse(30)
    calls = []
    original = fast.fastpath._fit  # the call into kg_fit
    fast.fastpath._fit = lambda *a: calls.append(a) or original(*a)
    same_fit(kanagen.fit(ref, "circle", data={"point": xy}, q0=_circle_start(xy)),
             kanagen.fit(fast, "circle", data={"point": xy}, q0=_circle_start(xy)))
    assert not calls  # the circle's reduction: NumPy iteration
    kanagen.fit(fast, "conic", data={"point": xy})
    assert calls  # the conic has no linear constraint: compiled


CONSTRUCTS = ["a >= 1", "a > 0", "a != 0", "a <= b", "a < 2", "a in {-1, 1}",
              "a >= 0 and b >= 0", "a <= 0 or b <= 0", "not a > 2",
              "(b >= 0) if a >= 0 else (b <= 0)"]
#: model, (a, b) the data are drawn from, start (None: the spec's), every output compared
CONSTRUCT_CASES = [(0, (0.5, 0.2), None, False), (0, (2.0, 0.2), None, True),
                   (1, (0.7, 0.2), None, True), (2, (0.7, 0.2), None, True),
                   (3, (1.5, 1.0), None, False), (4, (1.5, 1.0), None, True),
                   (5, (0.9, 0.2), None, True), (6, (0.5, -0.3), None, False),
                   (7, (0.5, -0.3), None, False), (8, (2.5, 0.1), None, False),
                   (9, (0.5, 0.3), None, False), (9, (-0.5, -0.3), (-1.0, -1.0), False)]


def test_every_construct_as_on_the_numpy_runtime():
    """Appendix F's constructs (the round trips of test_constructs) as the models of one
    family: each model's q carries the other models' slacks, which neither the data nor its
    constraints see (projector._seen: they do not move); the default start violates
    ``a <= b`` (the phase-1 minimal solve of fit._inside moves it inside first).

    Where a slack is left to rounding — at an active bound (s → 0: its variance grows as
    1/s²) or in the factor of a disjunction that does not hold (its column is rounding, its
    value wanders) — the estimate is compared: status, parameter, cost, d; elsewhere every
    output."""
    models = "\n".join(f"  m{i}:\n    constraints:\n      k{i}: \"{f}\""
                       for i, f in enumerate(CONSTRUCTS))
    spec = ("name: construct\nparameter: {a: 1.5, b: 0.5}\nchannels:\n  pt:\n"
            "    components: [u, v]\n    exact: [u]\n    equations: [v - a*u - b]\n"
            f"models:\n{models}\n")
    ref, fast = reference(spec, "construct.yaml"), compiled(spec, "construct.yaml")
    assert not ref.relations_hold("m3", ref.q0)  # phase 1 runs
    u = np.linspace(-2, 2, 30)
    noise = np.random.default_rng(0).normal(0, 0.01, u.size)
    for i, (a, b), start, every in CONSTRUCT_CASES:
        args = dict(data={"pt": np.c_[u, a * u + b + noise]}, info={"pt": 1e4},
                    q_start=None if start is None else np.array(start))
        want, got = kanagen.fit(ref, f"m{i}", **args), kanagen.fit(fast, f"m{i}", **args)
        assert want.success, (i, want.message)
        if every:
            same_fit(want, got)
            continue
        assert (got.status, got.success, got.dof) == (want.status, want.success, want.dof)
        close([got.params["a"], got.params["b"]], [want.params["a"], want.params["b"]])
        close(got.cost, want.cost)


def _ellipse(M):
    t = np.linspace(0.3, 2.9, M)
    rng = np.random.default_rng(2)
    return np.c_[120 * np.cos(t) + 300, 70 * np.sin(t) + 200] + rng.normal(0, 0.5, (M, 2))


def _circle_start(xy):
    from scenes import kasa_circle

    return kasa_circle(xy)


GAUGE = """\
name: gauge
parameter: {a: 1.0, b: 0.5}
channels:
  pt:
    components: [u, v]
    exact: [u]
    equations: [v - a*u - b]
models:
  signed:
    constraints:
      positive: a > 0
      bounded: b <= 2
"""


def test_second_order_correction_of_a_slack_model(monkeypatch):
    """A slack model from its feasible default start: the projector's step is tangent to
    ``a s² − 1 = 0``, so the plain step is refused and its second-order correction (the
    parameter restored onto the constraints in the information's metric) is taken; with
    b <= 2 active, the iteration runs into the cap the same way."""
    from kanagen.runtime import iterate

    calls = []
    restore = iterate.restore_parameter
    monkeypatch.setattr(iterate, "restore_parameter",
                        lambda *a, **k: calls.append(1) or restore(*a, **k))
    ref, fast = reference(GAUGE, "gauge.yaml"), compiled(GAUGE, "gauge.yaml")
    rng = np.random.default_rng(1)
    u = np.linspace(0, 10, 40)
    for b, slope in ((1.2, 0.7), (0.3, 0.05), (3.0, 0.7)):
        data = {"pt": np.c_[u, slope * u + b + rng.normal(0, 0.05, u.size)]}
        calls.clear()
        a = kanagen.fit(ref, "signed", data=data)
        assert calls  # the correction ran
        same_fit(a, kanagen.fit(fast, "signed", data=data))


def test_boundary_stop_on_a_hyperbolic_arc():
    """The ellipse model (``A C − B² > 0``) on hyperbolic arcs: the slack diverges and both
    stop at the same iterate with status 4. The slack ``1/√(A C − B²)`` there carries the
    cancellation of ``A C − B²`` (1e-8 of ``|A C|``): it is compared to that conditioning."""
    from scenes import kasa_circle

    ref, fast = reference("conic_lattice"), compiled("conic_lattice")
    rng = np.random.default_rng(5)
    seen = 0
    for _ in range(40):
        t = rng.uniform(-0.9, 0.9, 16)
        a, b = rng.uniform(60, 150, 2)
        xy = np.c_[320 + a * np.cosh(t), 240 + b * np.sinh(t)] + rng.normal(0, 0.5, (16, 2))
        start = kanagen.fit(ref, "circle", data={"point": xy}, q0=kasa_circle(xy)).q
        args = dict(data={"point": xy}, q0=start, max_iter=40)
        x, y = kanagen.fit(ref, "ellipse", **args), kanagen.fit(fast, "ellipse", **args)
        same_fit(x, y)
        if x.status != 4:
            continue
        seen += 1
        close(y.q[:6], x.q[:6])
        close(y.cost, x.cost)
        A, B, C = x.q[:3]
        condition = (abs(A * C) + B * B) / (A * C - B * B)
        close(y.slacks["s_ellipse"], x.slacks["s_ellipse"], rtol=1e-10 * condition)
        if seen == 2:
            return
    pytest.fail("no hyperbolic arc stopped at the boundary")


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


@pytest.mark.parametrize("motion", ["translation", "planar", "general"])
def test_feasible_starts_factor_a_rank_deficient_information(motion):
    """Two-view fits from the (feasible) truth: the second-order correction factors the
    information, rank-deficient where the constraints pin components (its closest root
    fixes 2–5 pivots, with rounding noise below them)."""
    from kanagen.scenes import two_view_scene

    ref, fast = reference("two_view"), compiled("two_view")
    s = two_view_scene(motion, n=40, sigma=0.5, seed=2)
    p = s.params()
    q = np.array([p[name] for name in ref.parameter_names])
    args = dict(data={"match": s.data}, info={"match": 4.0}, q0=q, constants=s.constants)
    same_fit(kanagen.fit(ref, motion, **args), kanagen.fit(fast, motion, **args))


def test_the_port_is_current_with_the_python_it_mirrors():
    stale = fastpath.changed()
    assert not stale, (
        "the Python that codegen/c/kanagen_fast.c ports has changed: "
        + ", ".join(stale) + ". Port the change to the C (docs/fastpath.md), run "
        "tests/test_fastpath.py, then paste the output of `python -m "
        "kanagen.runtime.fastpath` into FINGERPRINTS in runtime/fastpath.py.")


def test_a_stale_port_switches_itself_off(monkeypatch):
    monkeypatch.setitem(fastpath.FINGERPRINTS, "iterate._iterate", "0" * 12)
    with pytest.warns(fastpath.FastPathWarning, match="iterate._iterate"):
        fam = compiled("line")
    assert fam.fastpath is None and fam.backend == "compiled"
    xy = np.array([[0.0, 1.0], [1.0, 2.9], [2.0, 5.1], [3.0, 7.0]])
    same_fit(kanagen.fit(reference("line"), "line", data={"point": xy}),
             kanagen.fit(fam, "line", data={"point": xy}))


@pytest.mark.parametrize("name", ["Misra1a", "Thurber", "MGH09", "BoxBOD"])
def test_nist_problems(name, data_dir):
    """Hard starts: the trust region, damping, stalls — both starts of each problem; the
    same path where the information is well conditioned (Misra1a, BoxBOD, MGH09), the same
    estimate everywhere."""
    from benchmarks.nist_strd import CHANNEL, MODEL, kanagen_info, load_problem, spec_text

    problem = load_problem(name)
    text = spec_text(problem, 0)
    ref, fast = reference(text, f"nist_{name}.yaml"), compiled(text, f"nist_{name}.yaml")
    data, info = {CHANNEL: problem.data_array(False)}, {CHANNEL: kanagen_info(problem, False)}
    for start in problem.starts:
        args = dict(data=data, info=info, q0=np.asarray(start, dtype=float), max_iter=500)
        same_fit(kanagen.fit(ref, MODEL, **args), kanagen.fit(fast, MODEL, **args),
                 path=name != "Thurber")


def test_threads_share_a_compiled_family(families):
    """Per-thread argument buffers: concurrent fits give the sequential answers."""
    from concurrent.futures import ThreadPoolExecutor

    _, fast = families
    cases = [(_data(seed, 10 + seed, 6 + seed), model) for seed in range(6)
             for model in ("free", "sphere")]
    expected = [kanagen.fit(fast, model, data=data).q for data, model in cases]
    with ThreadPoolExecutor(4) as pool:
        got = list(pool.map(lambda c: kanagen.fit(fast, c[1], data=c[0]).q, cases * 3))
    for q, ref in zip(got, expected * 3, strict=True):
        np.testing.assert_array_equal(q, ref)
