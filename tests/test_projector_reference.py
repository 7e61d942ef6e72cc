"""The projector (`kanagen.fit`) against independent dense references, and report §3.6.

Each problem is written twice: as a YAML spec for kanagen and as hand-written NumPy
equations with exact Jacobians for the dense KKT solver of ``reference.py``. Random problems
are polynomials, rendered to spec text with ``repr`` numbers.
"""

from __future__ import annotations

import functools
import json
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from reference import (
    ReferenceResult,
    constrained_covariance,
    dense_kkt_solve,
    info_blocks,
    slsqp_solve,
)

import kanagen
from kanagen.runtime.fit import fit_problem, make_problem
from kanagen.runtime.projector import evaluate, project

RTOL = 1e-8

# --------------------------------------------------------------------------------------------
# Polynomials: one object gives the spec text, the values and the exact gradients.

Monomial = tuple[tuple[str, int], ...]


@dataclass(frozen=True)
class Poly:
    """A polynomial Σ coef·Π name**power, as spec text and as NumPy values/gradients."""

    terms: tuple[tuple[float, Monomial], ...]

    def text(self) -> str:
        """Spec text; every coefficient written with ``repr`` (exact round trip)."""
        parts = []
        for coef, mono in self.terms:
            factors = [f"({float(coef)!r})"]
            factors += [name if power == 1 else f"{name}**{power}" for name, power in mono]
            parts.append("*".join(factors))
        return " + ".join(parts) if parts else "0"

    def value(self, env: dict[str, np.ndarray | float], size: int) -> np.ndarray:
        """Values, shape (size,)."""
        out = np.zeros(size)
        for coef, mono in self.terms:
            term = np.full(size, float(coef))
            for name, power in mono:
                term = term * np.asarray(env[name]) ** power
            out = out + term
        return out

    def grad(self, env: dict[str, np.ndarray | float], size: int, wrt: Sequence[str]) -> np.ndarray:
        """Exact partial derivatives, shape (size, len(wrt))."""
        out = np.zeros((size, len(wrt)))
        for coef, mono in self.terms:
            for col, var in enumerate(wrt):
                powers = dict(mono)
                if var not in powers:
                    continue
                term = np.full(size, float(coef) * powers[var])
                for name, power in mono:
                    term = term * np.asarray(env[name]) ** (power - 1 if name == var else power)
                out[:, col] += term
        return out

    def __add__(self, other: Poly) -> Poly:
        return Poly(self.terms + other.terms)

    def scaled(self, s: float) -> Poly:
        return Poly(tuple((float(s) * c, m) for c, m in self.terms))

    def squared(self) -> Poly:
        return Poly(
            tuple((c1 * c2, _mul(m1, m2)) for c1, m1 in self.terms for c2, m2 in self.terms)
        )


def _mul(a: Monomial, b: Monomial) -> Monomial:
    powers: dict[str, int] = {}
    for name, power in a + b:
        powers[name] = powers.get(name, 0) + power
    return tuple(sorted(powers.items()))


def combine(G: np.ndarray, polys: Sequence[Poly]) -> list[Poly]:
    """The equations G·c as polynomials."""
    return [
        functools.reduce(Poly.__add__, [p.scaled(g) for g, p in zip(row, polys, strict=True)])
        for row in np.atleast_2d(G)
    ]


# --------------------------------------------------------------------------------------------
# A problem: spec text + hand-written equations + data.


@dataclass
class Problem:
    """One estimation problem, one channel ``obs``, one model ``main``."""

    names: list[str]
    components: list[str]
    exact: list[str]
    constraints: list[Poly]
    equations: list[Poly]
    data: np.ndarray
    info: object
    q0: np.ndarray
    Q0: np.ndarray
    constants: dict[str, float] = field(default_factory=dict)
    constraint_texts: list[str] | None = None
    equation_texts: list[str] | None = None

    @property
    def corrected(self) -> list[str]:
        return [c for c in self.components if c not in self.exact]

    @property
    def M(self) -> int:
        return self.data.shape[0]

    def yaml(self) -> str:
        """The spec as YAML text (expressions JSON-quoted, numbers with repr)."""
        eqs = self.equation_texts or [p.text() for p in self.equations]
        cons = self.constraint_texts
        if cons is None:
            cons = [p.text() for p in self.constraints]
        lines = ["name: problem"]
        if self.constants:
            lines.append(
                "constants: {" + ", ".join(f"{k}: {v!r}" for k, v in self.constants.items()) + "}"
            )
        lines.append("parameter:")
        lines += [f"  {n}: {float(v)!r}" for n, v in zip(self.names, self.q0, strict=True)]
        lines += [
            "channels:",
            "  obs:",
            f"    components: [{', '.join(self.components)}]",
            f"    exact: [{', '.join(self.exact)}]",
            "    equations:",
        ]
        lines += [f"      - {json.dumps(e)}" for e in eqs]
        lines += ["models:", "  main:", "    constraints:" + ("" if cons else " []")]
        lines += [f"      - {json.dumps(c)}" for c in cons]
        return "\n".join(lines) + "\n"

    def env(self, q: np.ndarray, mk: np.ndarray | None = None) -> dict[str, np.ndarray | float]:
        env: dict[str, np.ndarray | float] = dict(self.constants)
        env.update({n: float(v) for n, v in zip(self.names, q, strict=True)})
        for j, name in enumerate(self.corrected):
            env[name] = self.data[:, self.components.index(name)] if mk is None else mk[:, j]
        for name in self.exact:
            env[name] = self.data[:, self.components.index(name)]
        return env

    def c0(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        env = self.env(q)
        c = np.array([p.value(env, 1)[0] for p in self.constraints])
        C = np.array([p.grad(env, 1, self.names)[0] for p in self.constraints])
        return c, C.reshape(len(self.constraints), len(self.names))

    def ci(self, q: np.ndarray, mk: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        env, M = self.env(q, mk), mk.shape[0]
        c = np.stack([p.value(env, M) for p in self.equations], 1)
        C = np.stack([p.grad(env, M, self.names) for p in self.equations], 1)
        D = np.stack([p.grad(env, M, self.corrected) for p in self.equations], 1)
        return c, C, D

    def corrected_data(self) -> np.ndarray:
        return self.data[:, [self.components.index(c) for c in self.corrected]]

    def reference(self, **kw) -> ReferenceResult:
        c0 = self.c0 if self.constraints else None
        return dense_kkt_solve(
            c0, self.ci, self.q0, self.Q0, self.corrected_data(), self.info, **kw
        )

    def fit(self, fam=None, **kw):
        fam = family(self.yaml()) if fam is None else fam
        kw.setdefault("Q0", self.Q0)
        return kanagen.fit(
            fam,
            model="main",
            data={"obs": self.data},
            info={"obs": self.info},
            constants=self.constants or None,
            **kw,
        )


@functools.lru_cache(maxsize=64)
def family(text: str):
    """Build (once) the family of a spec text."""
    return kanagen.load_text(text, source="test_projector_reference.yaml")


def _mono(*names: str) -> Monomial:
    return _mul((), tuple((n, 1) for n in names))


def random_problem(n: int, p: int, k: int, pi: int, M: int, seed: int) -> Problem:
    """Random polynomial problem with a known truth, small noise and an identifiable q.

    Equation j is ``m_j − f_j(q, rest)`` mixed by a random invertible G, where ``rest`` are
    the other corrected components and exact covariates; constraints are random quadratics
    vanishing at the truth.
    """
    rng = np.random.default_rng(seed)
    names = [f"a{i}" for i in range(n)]
    corrected = [f"m{j}" for j in range(k)]
    rest = corrected[pi:]
    need = 1 if n <= 3 else 2
    exact = [f"t{j}" for j in range(max(need - len(rest), 0) + int(rng.integers(0, 2)))]
    regressors = rest + exact
    basis = [()] + [_mono(v) for v in regressors]
    basis += [_mono(v, w) for i, v in enumerate(regressors) for w in regressors[i:]]
    sign = lambda size=None: rng.choice([-1.0, 1.0], size)  # noqa: E731
    q_true = rng.uniform(0.5, 1.5, n) * sign(n)

    explicit = []
    for j in range(pi):
        order = rng.permutation(len(basis))
        terms = [
            (rng.uniform(0.5, 1.5) * sign(), _mul(_mono(names[i]), basis[order[i % len(basis)]]))
            for i in range(n)
        ]
        i1, i2 = rng.integers(0, n, 2)
        terms.append((0.3 * sign(), _mul(_mono(names[i1], names[i2]), basis[order[-1]])))
        terms += [(rng.uniform(0.2, 0.6) * sign(), _mono(v)) for v in regressors]
        explicit.append(Poly(((1.0, _mono(corrected[j])),)) + Poly(tuple(terms)).scaled(-1.0))
    G = np.eye(pi) + 0.4 * rng.standard_normal((pi, pi)) if pi > 1 else np.array([[-1.7]])
    equations = combine(G, explicit)

    constraints = []
    env_true = {nm: float(v) for nm, v in zip(names, q_true, strict=True)}
    for _ in range(p):
        g = Poly(tuple((rng.uniform(0.5, 1.5) * sign(), _mono(nm)) for nm in names))
        i1, i2 = rng.integers(0, n, 2)
        g = g + Poly(((0.5 * sign(), _mono(names[i1], names[i2])),))
        constraints.append(g + Poly(((-g.value(env_true, 1)[0], ()),)))

    components = corrected + exact
    rng.shuffle(components)
    data = np.zeros((M, len(components)))
    for v in regressors:
        data[:, components.index(v)] = rng.uniform(-1.0, 1.0, M)
    prob = Problem(
        names, list(components), exact, constraints, equations, data, None, q_true, np.zeros((n, n))
    )
    env = prob.env(q_true)
    for j in range(pi):
        f = explicit[j].scaled(-1.0) + Poly(((1.0, _mono(corrected[j])),))
        data[:, components.index(corrected[j])] = f.value({**env, corrected[j]: 0.0}, M)

    kind = ("matrix", "per_measure", "scalars")[seed % 3]
    if kind == "matrix":
        A = rng.standard_normal((k, k))
        prob.info = A @ A.T + 0.5 * np.eye(k)
    elif kind == "per_measure":
        A = rng.standard_normal((M, k, k))
        prob.info = A @ A.transpose(0, 2, 1) + 0.5 * np.eye(k)
    else:
        prob.info = rng.uniform(0.5, 2.0, M)
    Q = info_blocks(prob.info, M, k)
    noise = np.linalg.solve(
        np.linalg.cholesky(Q).transpose(0, 2, 1), 0.01 * rng.standard_normal((M, k, 1))
    )[..., 0]
    cols = [components.index(c) for c in prob.corrected]
    data[:, cols] += noise
    prob.q0 = q_true + 0.03 * rng.standard_normal(n)

    _, C, _ = prob.ci(q_true, prob.corrected_data())
    J = np.vstack([C.reshape(-1, n)] + ([prob.c0(q_true)[1]] if p else []))
    if np.linalg.matrix_rank(J, tol=1e-3) < n or rng.random() < 0.3:
        prob.Q0 = np.diag(rng.uniform(0.05, 0.5, n))
    return prob


# --------------------------------------------------------------------------------------------
# Comparisons.


def deviation(actual, expected) -> float:
    """max |a − e| / max(1, max |e|)."""
    a, e = np.asarray(actual, dtype=float), np.asarray(expected, dtype=float)
    return float(np.max(np.abs(a - e), initial=0.0) / max(1.0, np.max(np.abs(e), initial=0.0)))


def assert_close(what: str, actual, expected, tol: float = RTOL) -> None:
    dev = deviation(actual, expected)
    assert np.all(np.isfinite(actual)), f"{what}: not finite"
    assert dev <= tol, f"{what}: max relative deviation {dev:.3e} > {tol:.0e}"


def check_against_reference(prob: Problem, res, ref: ReferenceResult) -> None:
    """q, measures, cost, information and covariance of a fit against the dense reference."""
    assert ref.converged and ref.c_inf < 1e-10 and ref.stationarity < 1e-9, "reference failed"
    assert res.success, f"fit not successful: {res.status} {res.message}"
    assert_close("q", res.q, ref.q)
    assert_close("params", [res.params[n] for n in prob.names], ref.q)
    full = np.asarray(res.measures["obs"])
    cols = [prob.components.index(c) for c in prob.corrected]
    assert_close("corrected measures", full[:, cols], ref.m)
    for name in prob.exact:
        j = prob.components.index(name)
        assert np.array_equal(full[:, j], prob.data[:, j]), f"exact column {name} changed"
    assert abs(res.cost - ref.cost) <= RTOL * abs(ref.cost), (
        f"cost: {res.cost!r} vs {ref.cost!r}, rel {abs(res.cost - ref.cost) / ref.cost:.3e}"
    )
    scale = np.max(np.abs(ref.info))
    assert_close("info", np.asarray(res.info) / scale, ref.info / scale, 1e-6)
    C0 = prob.c0(res.q)[1] if prob.constraints else None
    cov = constrained_covariance(res.info, C0)
    cscale = np.max(np.abs(cov))
    assert_close(
        "covariance vs pinv(KKT(res.info))", np.asarray(res.covariance) / cscale, cov / cscale, 1e-8
    )
    assert_close(
        "covariance vs dense", np.asarray(res.covariance) / cscale, ref.covariance / cscale, 1e-6
    )


SHAPES = [  # n, p, k, p_i, M, seed
    (2, 0, 1, 1, 10, 1),
    (3, 1, 2, 1, 20, 2),
    (4, 2, 3, 2, 15, 3),
    (5, 1, 2, 2, 30, 4),
    (6, 2, 3, 1, 40, 5),
    (6, 0, 1, 1, 5, 6),
    (2, 1, 3, 2, 8, 7),
    (3, 2, 2, 2, 12, 8),
]


@pytest.mark.parametrize("shape", SHAPES, ids=lambda s: "n{}p{}k{}pi{}M{}".format(*s[:5]))
def test_random_polynomial_problems(shape: tuple[int, ...]) -> None:
    prob = random_problem(*shape)
    res, ref = prob.fit(), prob.reference()
    check_against_reference(prob, res, ref)
    n, p, _, pi, M, _ = shape
    assert res.dof == n - p + M * pi
    assert res.normalized_cost == pytest.approx(res.cost / res.dof, rel=1e-12)


@pytest.mark.parametrize("shape", SHAPES[:4], ids=lambda s: f"seed{s[-1]}")
def test_generated_functions_match_handwritten(shape: tuple[int, ...]) -> None:
    prob = random_problem(*shape)
    fam = family(prob.yaml())
    assert fam.parameter_names == tuple(prob.names)
    assert tuple(fam.channels["obs"].corrected) == tuple(prob.corrected)
    q = prob.q0 + 0.1
    c, C, D = fam.measurement("main", "obs", q, prob.data)
    c_ref, C_ref, D_ref = prob.ci(q, prob.corrected_data())
    for what, a, b in (("c", c, c_ref), ("C", C, C_ref), ("D", D, D_ref)):
        assert_close(what, a, b, 1e-12)
    if prob.constraints:
        c0, C0 = fam.c0("main", q)
        assert_close("c0", c0, prob.c0(q)[0], 1e-12)
        assert_close("C0", C0, prob.c0(q)[1], 1e-12)


def test_reference_agrees_with_slsqp() -> None:
    """The two reference methods agree (to the optimiser's accuracy) on a small problem."""
    prob = random_problem(3, 1, 2, 1, 8, 11)
    ref = prob.reference()
    c0 = prob.c0 if prob.constraints else None
    alt = slsqp_solve(c0, prob.ci, prob.q0, prob.Q0, prob.corrected_data(), prob.info)
    assert deviation(alt.q, ref.q) < 1e-6
    assert alt.cost == pytest.approx(ref.cost, rel=1e-6)


# --------------------------------------------------------------------------------------------
# Hand-written specs.


def _homogeneous_line(M: int = 25, seed: int = 3) -> Problem:
    rng = np.random.default_rng(seed)
    t = rng.uniform(-2.0, 2.0, M)
    data = np.c_[t, 0.5 * t + 0.3] + 0.05 * rng.standard_normal((M, 2))
    eq = Poly(((1.0, _mono("a", "x")), (1.0, _mono("b", "y")), (1.0, _mono("c"))))
    con = Poly(((1.0, (("a", 2),)), (1.0, (("b", 2),)), (-1.0, ())))
    return Problem(
        ["a", "b", "c"],
        ["x", "y"],
        [],
        [con],
        [eq],
        data,
        1.0,
        np.array([-0.4, 0.9, -0.2]),
        np.zeros((3, 3)),
    )


def test_orthogonal_line_is_total_least_squares() -> None:
    prob = _homogeneous_line()
    res, ref = prob.fit(), prob.reference()
    check_against_reference(prob, res, ref)
    mean = prob.data.mean(0)
    _, s, vt = np.linalg.svd(prob.data - mean)
    normal = vt[-1] * np.sign(vt[-1] @ res.q[:2])
    assert_close("TLS line", res.q, np.r_[normal, -normal @ mean])
    assert res.cost == pytest.approx(0.5 * s[-1] ** 2, rel=RTOL)


def _circle(M: int = 30, seed: int = 4) -> Problem:
    rng = np.random.default_rng(seed)
    th = rng.uniform(0.0, 2.0 * np.pi, M)
    A = rng.standard_normal((M, 2, 2))
    info = 0.2 * (A @ A.transpose(0, 2, 1) + 0.5 * np.eye(2))
    data = np.c_[1.0 + 2.0 * np.cos(th), -0.5 + 2.0 * np.sin(th)] + 0.05 * rng.standard_normal(
        (M, 2)
    )
    # (x − cx)² + (y − cy)² − r², expanded
    eq = Poly(
        (
            (1.0, (("x", 2),)),
            (-2.0, _mono("x", "cx")),
            (1.0, (("cx", 2),)),
            (1.0, (("y", 2),)),
            (-2.0, _mono("y", "cy")),
            (1.0, (("cy", 2),)),
            (-1.0, (("r", 2),)),
        )
    )
    prob = Problem(
        ["cx", "cy", "r"],
        ["x", "y"],
        [],
        [],
        [eq],
        data,
        info,
        np.array([0.8, -0.3, 1.8]),
        np.zeros((3, 3)),
    )
    prob.equation_texts = ["(x - cx)**2 + (y - cy)**2 - r**2"]
    return prob


def test_circle_per_measure_information() -> None:
    prob = _circle()
    check_against_reference(prob, prob.fit(), prob.reference())


def test_conic_with_normalisation() -> None:
    rng = np.random.default_rng(5)
    M = 40
    th = rng.uniform(0.0, 2.0 * np.pi, M)
    data = np.c_[0.3 + 2.0 * np.cos(th), -0.2 + np.sin(th)] + 0.02 * rng.standard_normal((M, 2))
    names = ["a", "b", "c", "d", "e", "f"]
    monos = [(("x", 2),), _mono("x", "y"), (("y", 2),), _mono("x"), _mono("y"), ()]
    eq = Poly(tuple((1.0, _mul(_mono(nm), mo)) for nm, mo in zip(names, monos, strict=True)))
    con = Poly(tuple((1.0, ((nm, 2),)) for nm in names) + ((-1.0, ()),))
    design = np.c_[data[:, 0] ** 2, data[:, 0] * data[:, 1], data[:, 1] ** 2, data, np.ones(M)]
    q0 = np.linalg.svd(design)[2][-1]  # algebraic fit as the starting point
    prob = Problem(names, ["x", "y"], [], [con], [eq], data, 1.0, q0, np.zeros((6, 6)))
    check_against_reference(prob, prob.fit(), prob.reference())


def test_two_channels_and_constants() -> None:
    """Points on y = a x + b·f0 and directions (u, v) ∥ (1, a); f0 set at run time."""
    rng = np.random.default_rng(6)
    f0, a, b = 2.0, 0.7, -0.4
    x = rng.uniform(-1.0, 1.0, 15)
    pts = np.c_[x, a * x + b * f0] + 0.02 * rng.standard_normal((15, 2))
    u = rng.uniform(0.5, 1.5, 10)
    dirs = np.c_[u, a * u] + 0.02 * rng.standard_normal((10, 2))
    text = (
        "name: two\nconstants: {f0: 1.0}\nparameter: {a: 0.6, b: -0.3}\nchannels:\n"
        '  pt:\n    components: [x, y]\n    equations: ["y - a*x - b*f0"]\n'
        '  dir:\n    components: [u, v]\n    equations: ["v - a*u"]\n'
        "models:\n  main:\n    constraints: []\n"
    )
    W = np.diag([2.0, 0.5])

    def ci_pt(q, m):
        M = len(m)
        return (
            (m[:, 1] - q[0] * m[:, 0] - q[1] * f0)[:, None],
            np.stack([-m[:, 0], np.full(M, -f0)], 1)[:, None, :],
            np.stack([np.full(M, -q[0]), np.ones(M)], 1)[:, None, :],
        )

    def ci_dir(q, m):
        M = len(m)
        return (
            (m[:, 1] - q[0] * m[:, 0])[:, None],
            np.stack([-m[:, 0], np.zeros(M)], 1)[:, None, :],
            np.stack([np.full(M, -q[0]), np.ones(M)], 1)[:, None, :],
        )

    q0 = np.array([0.6, -0.3])
    ref = dense_kkt_solve(None, [ci_pt, ci_dir], q0, 0.0, [pts, dirs], [W, 3.0])
    res = kanagen.fit(
        family(text),
        model="main",
        data={"pt": pts, "dir": dirs},
        info={"pt": W, "dir": 3.0},
        constants={"f0": f0},
        Q0=np.zeros((2, 2)),
    )
    assert res.success
    assert_close("q", res.q, ref.q)
    assert_close("pt measures", res.measures["pt"], ref.measures[0])
    assert_close("dir measures", res.measures["dir"], ref.measures[1])
    assert res.cost == pytest.approx(ref.cost, rel=RTOL)
    assert res.dof == 2 + 15 + 10
    assert_close("covariance", res.covariance, ref.covariance, 1e-6)


# --------------------------------------------------------------------------------------------
# Report §3.6 properties.


def test_linear_equations_solved_in_one_step() -> None:
    """Equations linear in (q, m̃): one projector step is the exact KKT solution (QL problem)."""
    rng = np.random.default_rng(7)
    M = 12
    t = rng.uniform(-1.0, 1.0, M)
    x = rng.standard_normal(M)
    y = (0.3 + 0.5 * t - x) / 2.0 + 0.05 * rng.standard_normal(M)
    data = np.c_[t, x, y]
    eqs = [
        Poly(((1.0, _mono("x")), (2.0, _mono("y")), (-1.0, _mono("a")), (-1.0, _mono("b", "t")))),
        Poly(((1.0, _mono("x")), (-1.0, _mono("y")), (-1.0, _mono("c")))),
    ]
    con = Poly(((1.0, _mono("a")), (1.0, _mono("b")), (1.0, _mono("c")), (-1.0, ())))
    prob = Problem(
        ["a", "b", "c"],
        ["t", "x", "y"],
        ["t"],
        [con],
        eqs,
        data,
        np.array([[2.0, 0.3], [0.3, 1.0]]),
        np.array([0.1, 0.2, 0.3]),
        0.1 * np.eye(3),
    )
    exact = prob.reference(max_iter=1, damping=False)
    assert exact.c_inf < 1e-12 and exact.stationarity < 1e-12
    one = prob.fit(max_iter=1)
    assert_close("q after one step", one.q, exact.q, 1e-10)
    assert_close("measures after one step", one.measures["obs"][:, 1:], exact.m, 1e-10)
    res = prob.fit()
    assert res.success and res.iterations <= 2, f"{res.iterations} iterations"
    assert_close("q", res.q, exact.q, 1e-10)
    assert res.cost == pytest.approx(exact.cost, rel=1e-10)


@pytest.mark.parametrize("kind", ["scalars", "matrices"])
def test_linear_measurements_are_weighted_least_squares(kind: str) -> None:
    """No constraint, c = y − X(t) q: the estimate solves the weighted normal equations."""
    rng = np.random.default_rng(8)
    M = 25
    t = rng.uniform(-1.0, 1.0, M)
    if kind == "scalars":  # y = a + b t + c t², weights per measure
        X = np.c_[np.ones(M), t, t**2][:, None, :]
        Y = (X[:, 0] @ [0.3, -1.0, 2.0])[:, None] + 0.1 * rng.standard_normal((M, 1))
        Q = rng.uniform(0.5, 3.0, M)
        Qb = Q[:, None, None]
        text_eqs, comps = ["y - a - b*t - c*t**2"], ["t", "y"]
    else:  # (y1, y2) = (a + b t, c + d t), correlated per-measure information
        X = np.zeros((M, 2, 4))
        X[:, 0, :2] = np.c_[np.ones(M), t]
        X[:, 1, 2:] = np.c_[np.ones(M), t]
        Y = X @ np.array([0.5, 1.0, -0.3, 2.0]) + 0.1 * rng.standard_normal((M, 2))
        A = rng.standard_normal((M, 2, 2))
        Q = Qb = A @ A.transpose(0, 2, 1) + 0.3 * np.eye(2)
        text_eqs, comps = ["y1 - a - b*t", "y2 - c - d*t"], ["t", "y1", "y2"]
    n = X.shape[2]
    names = ["a", "b", "c", "d"][:n]
    text = (
        f"name: wls\nparameter: {{{', '.join(f'{nm}: 0.0' for nm in names)}}}\n"
        f"channels:\n  obs:\n    components: [{', '.join(comps)}]\n    exact: [t]\n"
        f"    equations: {json.dumps(text_eqs)}\nmodels:\n  main:\n    constraints: []\n"
    )
    normal = np.einsum("mki,mkl,mlj->ij", X, Qb, X)
    rhs = np.einsum("mki,mkl,ml->i", X, Qb, Y)
    q_wls = np.linalg.lstsq(normal, rhs, rcond=None)[0]
    r = Y - np.einsum("mki,i->mk", X, q_wls)
    cost = 0.5 * float(np.einsum("mk,mkl,ml->", r, Qb, r))
    res = kanagen.fit(
        family(text), model="main", data={"obs": np.c_[t, Y]}, info={"obs": Q}, Q0=np.zeros((n, n))
    )
    assert res.success and res.iterations <= 2, f"{res.iterations} iterations"
    assert_close("q", res.q, q_wls, 1e-10)
    assert_close("corrected = fitted", res.measures["obs"][:, 1:], Y - r, 1e-10)
    assert res.cost == pytest.approx(cost, rel=1e-10)
    assert_close("covariance", res.covariance, np.linalg.inv(normal), 1e-8)


_NEWTON_SPEC = """\
name: newton
parameter: {a: 2.0, b: 0.6, c: 0.4}
channels:
  unused:
    components: [z]
    equations: ["z - a"]
models:
  main:
    constraints: ["a**2 + b**2 + c**2 - 4.5", "a*b - c - 0.5", "exp(c) - b - 0.8"]
"""


def _newton_c0(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a, b, c = q
    values = np.array([a * a + b * b + c * c - 4.5, a * b - c - 0.5, np.exp(c) - b - 0.8])
    return values, np.array([[2 * a, 2 * b, 2 * c], [b, a, -1.0], [0.0, -1.0, np.exp(c)]])


def _newton_iterates(x: np.ndarray, count: int) -> list[np.ndarray]:
    iterates = [x]
    for _ in range(count):
        c, C = _newton_c0(iterates[-1])
        iterates.append(iterates[-1] - np.linalg.solve(C, c))
    return iterates


@pytest.mark.parametrize(
    "start",
    [[2.11, 0.25, 0.08], [2.0, 0.6, 0.4]],
    ids=["near-root", "far"],
)
def test_square_constraints_give_newton(start: list[float]) -> None:
    """n = p, Q0 = I, no measures: the projector's step is Newton's, x − C⁻¹ c(x), and the
    iteration (which moves its start onto the constraints by such steps) ends at Newton's
    root.

    From the far start the first Newton step lowers ‖c‖∞ only from 0.30 to 0.23."""
    fam = family(_NEWTON_SPEC)
    x = np.array(start)
    iterates = _newton_iterates(x, 7)
    assert np.max(np.abs(_newton_c0(iterates[1])[0])) < np.max(np.abs(_newton_c0(x)[0]))
    problem = make_problem(fam, "main", {}, Q0=np.eye(3), q0=x)
    for steps in (1, 2):
        with np.errstate(all="ignore"):
            _, proj = project(problem, evaluate(problem, iterates[steps - 1], ()))
        assert_close(f"Newton step {steps}", proj.q, iterates[steps], 1e-12)
    res = kanagen.fit(fam, model="main", data={}, q0=x, Q0=np.eye(3))
    assert res.success
    assert_close("Newton root", res.q, iterates[-1], 1e-12)
    assert np.max(np.abs(_newton_c0(res.q)[0])) < 1e-12


# -- invariance to c -> G c -------------------------------------------------------------------


def _curve3d() -> Problem:
    """Points on y = a x + b, z = c x² + d in 3D, with a² + b² = 1 and c = a b (n=4, p=2)."""
    rng = np.random.default_rng(9)
    M = 20
    a, b = 0.6, 0.8
    c, d = a * b, -0.3
    x = rng.uniform(-1.0, 1.0, M)
    data = np.c_[x, a * x + b, c * x**2 + d] + 0.02 * rng.standard_normal((M, 3))
    eqs = [
        Poly(((1.0, _mono("y")), (-1.0, _mono("a", "x")), (-1.0, _mono("b")))),
        Poly(((1.0, _mono("z")), (-1.0, (("c", 1), ("x", 2))), (-1.0, _mono("d")))),
    ]
    cons = [
        Poly(((1.0, (("a", 2),)), (1.0, (("b", 2),)), (-1.0, ()))),
        Poly(((1.0, _mono("c")), (-1.0, _mono("a", "b")))),
    ]
    A = rng.standard_normal((3, 3))
    return Problem(
        ["a", "b", "c", "d"],
        ["x", "y", "z"],
        [],
        cons,
        eqs,
        data,
        A @ A.T + np.eye(3),
        np.array([0.55, 0.85, 0.5, -0.25]),
        np.zeros((4, 4)),
    )


@functools.lru_cache(maxsize=1)
def _curve3d_base():
    prob = _curve3d()
    return prob, prob.fit(), prob.reference()


def test_curve3d_against_reference() -> None:
    prob, res, ref = _curve3d_base()
    check_against_reference(prob, res, ref)


def _mixed_texts(G: np.ndarray, exprs: Sequence[str]) -> list[str]:
    return [
        " + ".join(f"({float(g)!r})*({e})" for g, e in zip(row, exprs, strict=True)) for row in G
    ]


_matrix2 = (
    st.lists(st.floats(-2.0, 2.0, allow_nan=False), min_size=4, max_size=4)
    .map(lambda v: np.array(v).reshape(2, 2))
    .filter(lambda G: abs(np.linalg.det(G)) > 0.2 and np.linalg.cond(G) < 50.0)
)


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(G=_matrix2, G0=_matrix2)
def test_invariance_to_equation_mixing(G: np.ndarray, G0: np.ndarray) -> None:
    """Replacing c by G c (channel) and c0 by G0 c0 (constraints) leaves the result unchanged."""
    prob, base, _ = _curve3d_base()
    mixed = _curve3d()
    mixed.equation_texts = _mixed_texts(G, [p.text() for p in prob.equations])
    mixed.constraint_texts = _mixed_texts(G0, [p.text() for p in prob.constraints])
    res = mixed.fit()
    assert res.success, f"{res.status} {res.message}"
    assert_close("q", res.q, base.q)
    assert_close("measures", res.measures["obs"], base.measures["obs"])
    assert res.cost == pytest.approx(base.cost, rel=RTOL)
    assert_close("covariance", res.covariance, base.covariance, 1e-6)
    assert res.dof == base.dof


# -- semi-definite information -----------------------------------------------------------------


def test_semidefinite_prior() -> None:
    """Q0 with zero eigenvalues (partial prior)."""
    prob = random_problem(4, 1, 2, 1, 20, 12)
    prob.Q0 = np.diag([0.5, 0.0, 0.2, 0.0])
    check_against_reference(prob, prob.fit(), prob.reference())


def test_semidefinite_measure_information() -> None:
    """A corrected component with zero information that no equation uses stays as measured."""
    base = _circle()
    M = base.M
    rng = np.random.default_rng(13)
    ext = _circle()
    ext.components = ["x", "y", "w"]
    ext.data = np.c_[base.data, rng.standard_normal(M)]
    info = np.zeros((M, 3, 3))
    info[:, :2, :2] = base.info
    ext.info = info
    res = ext.fit()
    ref = base.reference()
    assert res.success
    assert_close("q", res.q, ref.q)
    assert_close("measures", res.measures["obs"][:, :2], ref.m)
    assert np.array_equal(res.measures["obs"][:, 2], ext.data[:, 2]), "w moved"
    assert res.cost == pytest.approx(ref.cost, rel=RTOL)
    assert res.dof == 3 + M


def test_zero_information_measures_do_not_count() -> None:
    """Measures with Q_i = 0 leave q as if they were absent (their corrections are free)."""
    prob = _circle()
    keep = _circle()
    drop = np.arange(prob.M) % 5 == 0
    info = np.array(prob.info, copy=True)
    info[drop] = 0.0
    prob.info = info
    prob.data[drop] += 0.5  # gross outliers, invisible with zero information
    keep.data, keep.info = keep.data[~drop], keep.info[~drop]
    res, ref = prob.fit(), keep.reference()
    assert res.success
    assert_close("q", res.q, ref.q)
    assert res.cost == pytest.approx(ref.cost, rel=RTOL)
    c, _, _ = prob.ci(res.q, res.measures["obs"])
    assert np.max(np.abs(c)) < 1e-8


# -- redundant equations ----------------------------------------------------------------------


def test_redundant_measurement_equations() -> None:
    """Repeating an equation or adding a linear combination: same result, dof counts the rank."""
    prob, base, _ = _curve3d_base()
    e1, e2 = (p.text() for p in prob.equations)
    red = _curve3d()
    red.equation_texts = [e1, e2, f"2.0*({e1})", f"({e1}) - 3.0*({e2})"]
    res = red.fit()
    assert res.success, f"{res.status} {res.message}"
    assert_close("q", res.q, base.q)
    assert_close("measures", res.measures["obs"], base.measures["obs"])
    assert res.cost == pytest.approx(base.cost, rel=RTOL)
    assert res.dof == base.dof == 4 - 2 + 2 * prob.M


def test_redundant_constraints() -> None:
    prob, base, _ = _curve3d_base()
    k1, k2 = (p.text() for p in prob.constraints)
    red = _curve3d()
    red.constraint_texts = [k1, f"0.5*({k1}) + 2.0*({k2})", k2, k1]
    res = red.fit()
    assert res.success, f"{res.status} {res.message}"
    assert_close("q", res.q, base.q)
    assert res.cost == pytest.approx(base.cost, rel=RTOL)
    assert_close("covariance", res.covariance, base.covariance, 1e-6)
    assert res.dof == base.dof


# -- vanishing gradients ----------------------------------------------------------------------


def test_squared_equation_with_vanishing_gradient() -> None:
    """e and e² together: e²'s gradient vanishes on the solution; it must be dropped."""
    prob, base, _ = _curve3d_base()
    e1, e2 = (p.text() for p in prob.equations)
    sq = _curve3d()
    sq.equation_texts = [e1, e2, f"({e1})**2"]
    res = sq.fit()
    assert np.all(np.isfinite(res.q)) and np.isfinite(res.cost)
    assert res.success, f"{res.status} {res.message}"
    assert_close("q", res.q, base.q)
    assert res.cost == pytest.approx(base.cost, rel=RTOL)
    assert res.dof == base.dof


def test_constraint_given_squared() -> None:
    """c0 = (a² + b² − 1)²: a double root, linear convergence, no NaN, same estimate."""
    prob = _homogeneous_line()
    ref = prob.reference()
    sq = _homogeneous_line()
    sq.constraints = [prob.constraints[0].squared()]
    res = sq.fit()
    assert np.all(np.isfinite(res.q)) and np.isfinite(res.cost)
    assert_close("q", res.q, ref.q, 1e-6)
    assert res.cost == pytest.approx(ref.cost, rel=1e-6)


def test_gradient_vanishing_at_start() -> None:
    """Starting at q = 0 where every gradient of the homogeneous line vanishes: no NaN."""
    prob = _homogeneous_line()
    res = prob.fit(q0=np.zeros(3))
    for value in (res.q, res.cost, res.info, res.residual):
        assert np.all(np.isfinite(value))
    # nothing is observed nor constrained there: infinite variance, never NaN
    assert not np.any(np.isnan(res.covariance))
    assert np.all(np.isinf(np.diag(res.covariance)))


def test_infeasible_fixed_point_is_not_success() -> None:
    """At q = 0 every equation is dropped and P(q) = q, but c0 = −1: not a converged estimate."""
    prob = _homogeneous_line()
    res = prob.fit(q0=np.zeros(3))
    violation = float(np.max(np.abs(prob.c0(res.q)[0])))
    assert not res.success or violation < 1e-8, (
        f"success={res.success} status={res.status} ({res.message}) with |c0| = {violation}"
    )


def test_reference_sanity_on_problem_family() -> None:
    """Hand-written Jacobians match finite differences (guards the reference inputs)."""
    prob = random_problem(4, 2, 3, 2, 6, 14)
    q, mk = prob.q0, prob.corrected_data()
    c, C, D = prob.ci(q, mk)
    h = 1e-6
    for i in range(len(q)):
        dq = np.zeros_like(q)
        dq[i] = h
        fd = (prob.ci(q + dq, mk)[0] - prob.ci(q - dq, mk)[0]) / (2 * h)
        assert np.allclose(fd, C[:, :, i], atol=1e-7)
    for j in range(mk.shape[1]):
        dm = np.zeros_like(mk)
        dm[:, j] = h
        fd = (prob.ci(q, mk + dm)[0] - prob.ci(q, mk - dm)[0]) / (2 * h)
        assert np.allclose(fd, D[:, :, j], atol=1e-7)


@pytest.mark.parametrize("spec", ["conic.yaml", "hysteresis.yaml", "two_view.yaml",
                                  "two_view_calibrated.yaml"])
def test_reported_covariance_is_the_entry_points(spec):
    """The covariance a fit reports (made by the kernel that ran the iteration, beside its
    information) is :func:`~kanagen.runtime.results.constrained_covariance` of that
    information and the constraints kept, bit for bit — pinned components' zero variances
    and unobservable ones' infinite variances included (hysteresis: 19 constraints on 11
    components)."""
    from scenarios import SCENARIOS

    from kanagen.runtime.results import constrained_covariance as entry

    fam = kanagen.load(spec.removesuffix(".yaml"))
    for model, data, info, start, constants in SCENARIOS[spec]():
        problem = make_problem(fam, model, data, info, start, constants=constants)
        res = fit_problem(fam, model, problem)
        if fam.reduction(model) is not None:
            continue  # a reduced model's outputs are projected in Python
        x = evaluate(problem, res.q, tuple(res.measures[ch.name][:, ch.index]
                                           for ch in problem.channels))
        _, proj = project(problem, x)
        np.testing.assert_array_equal(res.covariance, entry(res.info, proj.C0))
