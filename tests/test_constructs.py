"""Modelling constructs of the report's appendix F, compiled into equations."""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np
import pytest
import sympy as sp
from hypothesis import given, settings
from hypothesis import strategies as st
from scenes import kasa_circle

import kanagen
from kanagen.modelspec import SpecError, parse_spec
from kanagen.modelspec.constructs import compile_formula, parse_formula
from kanagen.modelspec.ir import symbol

ROOT = Path(__file__).resolve().parents[1]
x, y, s = symbol("x"), symbol("y"), symbol("s")
SYMBOLS = {"x": x, "y": y}


def compiled(text: str, label: str = "k"):
    return compile_formula(parse_formula(text, SYMBOLS, "<test>", 1), label)


def same(a, b) -> bool:
    return sp.expand(a - b) == 0


# -- each rewrite rule against the hand-derived equation (report appendix F) ---------------
@pytest.mark.parametrize("text, equation, kind, measure", [
    ("x >= 0", x - s**2, ">=", x),
    ("x > 0", x * s**2 - 1, ">", x),
    ("x != 0", x * s - 1, "!=", x),
    ("x <= y", y - x - s**2, ">=", y - x),
    ("x < 1", (1 - x) * s**2 - 1, ">", 1 - x),
    ("not x >= 0", -x * s**2 - 1, ">", -x),  # NOT c >= 0 -> -c > 0
    ("not x > 0", -x - s**2, ">=", -x),  # NOT c > 0 -> -c >= 0
    ("not x == 0", x * s - 1, "!=", x),  # NOT c = 0 -> c != 0
])
def test_inequalities_bring_one_slack(text, equation, kind, measure):
    out = compiled(text)
    assert len(out.equations) == 1 and len(out.slacks) == 1
    slack = out.slacks[0]
    assert slack.name == "s_k" and slack.kind == kind and same(slack.measure, measure)
    assert same(out.equations[0], equation.subs(s, symbol("s_k")))


def test_not_equal_is_equal():
    out = compiled("not x != 0")  # NOT c != 0 -> c = 0
    assert out.slacks == () and len(out.equations) == 1 and same(out.equations[0], x)


def test_qualitative_variable_is_a_product():
    out = compiled("x in {-1, 1, 3}")
    assert out.slacks == () and len(out.equations) == 1
    assert same(out.equations[0], (x + 1) * (x - 1) * (x - 3))


def test_and_stacks_or_multiplies():
    out = compiled("x == 1 and y == 2")
    assert sorted(map(str, out.equations)) == sorted(map(str, [x - 1, y - 2]))
    out = compiled("x == 1 or y == 2")
    assert len(out.equations) == 1 and same(out.equations[0], (x - 1) * (y - 2))


def test_if_then_else_through_cnf():
    # if x = 0 then y = 0 else y = 1  <=>  (x = 0 and y = 0) or (x != 0 and y = 1)
    out = compiled("y == 0 if x == 0 else y == 1")
    sk = symbol("s_k")
    expected = {sp.expand(e) for e in (y * (y - 1), x * (y - 1), y * (x * sk - 1))}
    assert {sp.expand(e) for e in out.equations} == expected  # (x = 0 or x != 0) dropped


def test_one_slack_per_relation_and_redundant_clauses_dropped():
    out = compiled("(x > 0 or y == 1) and (x > 0 or y == 2)")
    assert len(out.slacks) == 1
    out = compiled("x == 1 and (x == 1 or y == 2)")  # the second clause contains the first
    assert len(out.equations) == 1 and same(out.equations[0], x - 1)


@pytest.mark.parametrize("text, fragment", [
    ("x >= 0 and", "cannot parse"),
    ("x in y", "needs a set of values"),
    ("x is 1", "not allowed"),
    ("[x for x in y] == 0", "not allowed"),
    ("lambda: x > 0", "not allowed"),
])
def test_formula_errors(text, fragment):
    with pytest.raises(SpecError, match=fragment):
        compiled(text)


def test_always_false_is_refused():
    with pytest.raises(SpecError, match="always false"):
        compiled("x > 0 and not x > 0")


# -- the compiled equations hold exactly where the formula is true -------------------------
FORMULAS = [
    "x >= 1", "x > y", "x != 2", "x in {-1, 0, 2}", "x >= 0 and y < 1",
    "x > 0 or y > 0", "not (x > 1 and y <= 0)", "y == 1 if x > 0 else y == -1",
    "(x > 0 or y != 0) and x < 3",
]


def _slack_value(kind: str, c: float) -> float | None:
    """The slack that solves the relation's equation, or None where none does."""
    if kind == ">=":
        return np.sqrt(c) if c >= 0 else None
    if kind == ">":
        return 1 / np.sqrt(c) if c > 0 else None
    return 1 / c if c != 0 else None


@pytest.mark.parametrize("text", FORMULAS)
@settings(max_examples=30, deadline=None)
@given(xv=st.integers(-3, 3), yv=st.integers(-3, 3))
def test_equations_hold_exactly_where_the_formula_is_true(text, xv, yv):
    formula = parse_formula(text, SYMBOLS, "<test>", 1)
    truth = bool(formula.subs({x: xv, y: yv}))
    out = compile_formula(formula, "k")
    point = {x: sp.Integer(xv), y: sp.Integer(yv)}
    # each slack takes the value solving its own relation where it holds; in a clause where
    # the relation fails, the slack cannot zero that factor (any value: take 1)
    values = {}
    for sl in out.slacks:
        c = float(sl.measure.subs(point))
        v = _slack_value(sl.kind, c)
        values[symbol(sl.name)] = sp.nsimplify(1 if v is None else v)
    residuals = [sp.expand(e.subs(point).subs(values)) for e in out.equations]
    holds = all(r == 0 for r in residuals)
    assert holds == truth, (text, xv, yv, residuals)


def test_false_relations_cannot_be_satisfied_by_any_slack():
    # c >= 0 with c < 0: c − s² < 0 for all s; c > 0 with c <= 0: c s² − 1 < 0; c != 0 with
    # c = 0: c s − 1 = −1 — the equation has no root, so the formula's falsity is preserved
    for text, xv in (("x >= 0", -1), ("x > 0", 0), ("x > 0", -2), ("x != 0", 0)):
        out = compiled(text)
        eq = out.equations[0].subs(x, xv)
        sk = symbol("s_k")
        assert not [r for r in sp.solve(eq, sk) if r.is_real]


# -- specs: names, degrees of freedom, results -------------------------------------------
SPEC = textwrap.dedent("""\
    name: gauge
    parameter: {a: 1.0, b: 0.5}
    channels:
      pt:
        components: [u, v]
        exact: [u]
        equations: [v - a*u - b]
    models:
      free:
        constraints: []
        alternatives: {signed: 1}
      signed:
        constraints:
          positive: a > 0
          bounded: b <= 2
""")


def test_slacks_join_the_parameter_and_the_dof_count():
    fam = parse_spec(SPEC, "gauge.yaml")
    assert fam.parameter_names == ("a", "b", "s_positive", "s_bounded")
    assert fam.slack == ("s_positive", "s_bounded")
    assert dict(fam.parameter)["s_positive"] == pytest.approx(1.0)  # 1/sqrt(a0)
    assert dict(fam.parameter)["s_bounded"] == pytest.approx(np.sqrt(1.5))  # sqrt(2 − b0)
    free = {m.name: m for m in fam.models}["free"]
    assert len(free.constraints) == 2  # the slacks of `signed` are pinned in `free`


def test_round_trip_and_results_hide_the_slacks(tmp_path):
    spec = tmp_path / "gauge.yaml"
    spec.write_text(SPEC)
    fam = kanagen.load(spec)
    rng = np.random.default_rng(1)
    u = np.linspace(0, 10, 40)
    data = {"pt": np.c_[u, 0.7 * u + 1.2 + rng.normal(0, 0.05, u.size)]}
    res = kanagen.fit(fam, "signed", data=data)
    assert res.success and set(res.params) == {"a", "b"}
    assert set(res.slacks) == {"s_positive", "s_bounded"}
    free = kanagen.fit(fam, "free", data=data)
    assert res.params["a"] == pytest.approx(free.params["a"], rel=1e-8)  # not active
    a, b = res.params["a"], res.params["b"]
    assert abs(a * res.slacks["s_positive"] ** 2 - 1) <= 1e-9
    assert abs(2 - b - res.slacks["s_bounded"] ** 2) <= 1e-9
    assert res.dof == free.dof  # each slack: one component and one equation
    assert res.covariance.shape == (4, 4)
    # an active inequality: data with b ≈ 3 meets the bound b <= 2
    data = {"pt": np.c_[u, 0.7 * u + 3.0 + rng.normal(0, 0.05, u.size)]}
    res = kanagen.fit(fam, "signed", data=data)
    assert res.params["b"] <= 2 + 1e-9
    assert abs(2 - res.params["b"] - res.slacks["s_bounded"] ** 2) <= 1e-9


def test_spec_errors_name_the_line(tmp_path):
    bad = SPEC.replace("bounded: b <= 2", "bounded: b <= 2 or [b for b in a]")
    with pytest.raises(SpecError) as info:
        parse_spec(bad, "gauge.yaml")
    assert info.value.line == 15 and "gauge.yaml" in str(info.value)
    bad = SPEC.replace("positive: a > 0", "positive: a in b")
    with pytest.raises(SpecError, match="needs a set of values") as info:
        parse_spec(bad, "gauge.yaml")
    assert info.value.line == 14


# -- the ellipse model of the conic lattice ------------------------------------------------
def test_ellipse_model_never_returns_a_non_ellipse():
    fam = kanagen.load("conic_lattice")
    rng = np.random.default_rng(3)
    hyperbolic = 0
    for _ in range(10):  # short arcs of hyperbolas: the free conic fit is not an ellipse
        t = rng.uniform(-0.8, 0.8, 20)
        a, b = rng.uniform(60, 150, 2)
        xy = np.c_[320 + a * np.cosh(t), 240 + b * np.sinh(t)] + rng.normal(0, 1, (20, 2))
        circle = kanagen.fit(fam, "circle", data={"point": xy}, q0=kasa_circle(xy))
        conic = kanagen.fit(fam, "conic", data={"point": xy}, q0=circle.q)
        ellipse = kanagen.fit(fam, "ellipse", data={"point": xy}, q0=circle.q)
        hyperbolic += conic.q[0] * conic.q[2] - conic.q[1] ** 2 <= 0
        assert ellipse.q[0] * ellipse.q[2] - ellipse.q[1] ** 2 > 0
        if ellipse.success:
            s_ = ellipse.slacks["s_ellipse"]
            d = ellipse.q[0] * ellipse.q[2] - ellipse.q[1] ** 2
            assert abs(s_ * s_ * d - 1) <= 1e-9
    assert hyperbolic >= 6  # the test means something


def _constrained_geometric_fit(xy: np.ndarray, q: np.ndarray, mt: np.ndarray, f0: float):
    """Independent reference: SLSQP on the whole problem (conic and corrected points) with
    ``A C − B² >= 0`` as an inequality — the closure of the ellipse model's open set."""
    from scipy.optimize import minimize

    M = len(xy)

    def split(z):
        return z[:6], z[6:].reshape(M, 2)

    def equations(z):
        (A, B, C, D, E, F), (x, y) = z[:6], z[6:].reshape(M, 2).T
        conic = A * x * x + 2 * B * x * y + C * y * y + 2 * f0 * (D * x + E * y) + f0**2 * F
        return np.r_[conic, z[:6] @ z[:6] - 1]

    def jacobian(z):
        (A, B, C, D, E, _), (x, y) = z[:6], z[6:].reshape(M, 2).T
        J = np.zeros((M + 1, z.size))
        J[:M, :6] = np.c_[x * x, 2 * x * y, y * y, 2 * f0 * x, 2 * f0 * y, np.full(M, f0**2)]
        rows = np.arange(M)
        J[rows, 6 + 2 * rows] = 2 * (A * x + B * y + f0 * D)
        J[rows, 7 + 2 * rows] = 2 * (B * x + C * y + f0 * E)
        J[M, :6] = 2 * z[:6]
        return J

    def discriminant_gradient(z):
        g = np.zeros(z.size)
        g[:3] = z[2], -2 * z[1], z[0]
        return g

    out = minimize(lambda z: 0.5 * np.sum((split(z)[1] - xy) ** 2), np.r_[q, mt.ravel()],
                   jac=lambda z: np.r_[np.zeros(6), (split(z)[1] - xy).ravel()],
                   method="SLSQP", options={"maxiter": 3000, "ftol": 1e-15},
                   constraints=[{"type": "eq", "fun": equations, "jac": jacobian},
                                {"type": "ineq", "fun": lambda z: z[0] * z[2] - z[1] ** 2,
                                 "jac": discriminant_gradient}])
    assert np.abs(equations(out.x)).max() < 1e-8
    return out.fun


def test_ellipse_model_on_hyperbolic_data_stops_at_the_boundary():
    """The optimum of a hyperbolic arc over ellipses lies on A C − B² = 0 (a parabola), which
    the open set ``A C − B² > 0`` excludes: the slack diverges, the fit says so (status 4,
    not a success), returns an ellipse, and its cost is the constrained infimum."""
    fam = kanagen.load("conic_lattice")
    rng = np.random.default_rng(5)
    seen = 0
    for _ in range(12):
        if seen == 2:
            break
        t = rng.uniform(-0.9, 0.9, 16)
        a, b = rng.uniform(60, 150, 2)
        xy = np.c_[320 + a * np.cosh(t), 240 + b * np.sinh(t)] + rng.normal(0, 0.5, (16, 2))
        circle = kanagen.fit(fam, "circle", data={"point": xy}, q0=kasa_circle(xy))
        conic = kanagen.fit(fam, "conic", data={"point": xy}, q0=circle.q)
        if not (conic.success and conic.q[0] * conic.q[2] - conic.q[1] ** 2 < 0):
            continue
        ellipse = kanagen.fit(fam, "ellipse", data={"point": xy}, q0=circle.q, max_iter=40)
        if ellipse.status != 4:
            continue
        seen += 1
        assert not ellipse.success and "boundary" in ellipse.message
        inside = ellipse.q[0] * ellipse.q[2] - ellipse.q[1] ** 2
        assert 0 < inside < 1e-6 * (circle.q[0] * circle.q[2] - circle.q[1] ** 2)  # on it
        reference = _constrained_geometric_fit(xy, ellipse.q[:6], ellipse.measures["point"],
                                               fam.constants["f0"])
        # the first iterate within 1e-8 of the boundary: near the infimum, not on it (the
        # iteration stops there, before it has converged along the boundary)
        assert ellipse.cost == pytest.approx(reference, rel=1e-3)
        assert ellipse.cost >= reference * (1 - 1e-9)
        assert ellipse.cost > conic.cost
    assert seen == 2  # the test means something


# -- the hysteresis example ----------------------------------------------------------------
def test_hysteresis_example_follows_both_branches():
    import runpy

    out = runpy.run_path(str(ROOT / "examples/hysteresis.py"), run_name="not_main")
    ts, ys, states = out["ramp"](kanagen.load(ROOT / "examples/hysteresis.yaml"))
    prev = 1
    for t, y, st_ in zip(ts, ys, states, strict=True):
        s_ref = (-1 if t > 2 else 1) if prev == 1 else (1 if t < -2 else -1)
        assert st_ == s_ref and y == pytest.approx(np.clip(t - s_ref, -1, 1), abs=1e-9)
        prev = s_ref
    up, down = ts[: len(ts) // 2], ts[len(ts) // 2:]
    at_zero_up = ys[np.argmin(np.abs(up))]
    at_zero_down = ys[len(up) + np.argmin(np.abs(down))]
    assert at_zero_up < -0.9 and at_zero_down > 0.9  # two branches: hysteresis


# -- every construct round-trips: spec -> generated module -> fit ---------------------------
ROUND_TRIP = [  # formula, (a, b) the data are drawn from, start, the formula in Python
    ("a >= 1", (0.5, 0.2), None, lambda a, b: a >= 1 - 1e-9),  # active
    ("a >= 1", (2.0, 0.2), None, lambda a, b: a >= 1),
    ("a > 0", (0.7, 0.2), None, lambda a, b: a > 0),
    ("a != 0", (0.7, 0.2), None, lambda a, b: a != 0),
    ("a <= b", (1.5, 1.0), None, lambda a, b: a <= b + 1e-9),  # starts outside: moved in
    ("a < 2", (1.5, 1.0), None, lambda a, b: a < 2),
    ("a in {-1, 1}", (0.9, 0.2), None, lambda a, b: min(abs(a - 1), abs(a + 1)) < 1e-9),
    ("a >= 0 and b >= 0", (0.5, -0.3), None, lambda a, b: a >= 0 and b >= -1e-9),
    ("a <= 0 or b <= 0", (0.5, -0.3), None, lambda a, b: a <= 0 or b <= 0),
    ("not a > 2", (2.5, 0.1), None, lambda a, b: a <= 2 + 1e-9),
    ("(b >= 0) if a >= 0 else (b <= 0)", (0.5, 0.3), None, lambda a, b: b >= 0 <= a),
    ("(b >= 0) if a >= 0 else (b <= 0)", (-0.5, -0.3), (-1.0, -1.0),  # the other branch
     lambda a, b: a < 0 and b <= 0),
]


@pytest.mark.parametrize("formula, truth, start, holds", ROUND_TRIP,
                         ids=[f"{f} @ {t}" for f, t, _, _ in ROUND_TRIP])
def test_each_construct_round_trips(tmp_path, formula, truth, start, holds):
    """Appendix F floor: built into a module, fitted, the compiled equations hold at the
    solution to 1e-9 and the formula itself is true there."""
    spec = tmp_path / "construct.yaml"
    spec.write_text(textwrap.dedent(f"""\
        name: construct
        parameter: {{a: 1.5, b: 0.5}}
        channels:
          pt:
            components: [u, v]
            exact: [u]
            equations: [v - a*u - b]
        models:
          m:
            constraints:
              k: "{formula}"
        """))
    fam = kanagen.load(spec)
    rng = np.random.default_rng(0)
    u = np.linspace(-2, 2, 30)
    v = truth[0] * u + truth[1] + rng.normal(0, 0.01, u.size)
    res = kanagen.fit(fam, "m", data={"pt": np.c_[u, v]}, info={"pt": 1e4},
                      q_start=None if start is None else np.array(start))
    c0, _ = fam.c0("m", res.q)
    assert res.success, res.message
    assert np.abs(c0).max() <= 1e-9
    assert holds(res.params["a"], res.params["b"])
    assert set(res.params) == {"a", "b"}


# -- qualitative variables: labels, and the estimator choosing among them ------------------
def test_qualitative_labels_are_read_off_the_compiled_equation():
    from kanagen.modelspec.constructs import qualitative_labels

    (eq,) = compiled("x in {0.5, -2, 1}").equations
    assert qualitative_labels([eq], ["x"]) == {"x": (-2.0, 0.5, 1.0)}
    assert qualitative_labels([eq], ["y"]) == {}  # x is no parameter component here
    assert qualitative_labels([(x - 1) * (y - 2), x**2 + 1, x - 3], ["x", "y"]) == {}


def test_the_estimator_resolves_a_qualitative_variable_from_data():
    import runpy

    pga = runpy.run_path(str(ROOT / "examples/pga.py"), run_name="not_main")
    fam = kanagen.load("pga")
    assert fam.models["pga"].labels == {"g": (1.0, 2.0, 4.0, 8.0)}
    data = pga["readings"](4.0)
    best = pga["calibrate"](data)
    assert best.model == "pga" and best.params["g"] == pytest.approx(4.0, abs=1e-9)
    assert best.params["o"] == pytest.approx(0.3, abs=0.01)
    # a local fit stays on the setting it starts at: why the search starts on each
    inliers = data[best.inliers]
    local = kanagen.fit(fam, "pga", data={"reading": inliers}, info={"reading": 1e4})
    assert local.params["g"] == pytest.approx(1.0, abs=1e-9)
    assert local.cost > 10 * best.cost
    # a gain that is no setting (a fault): the more general model wins
    assert pga["calibrate"](pga["readings"](3.3)).model == "linear"


def test_a_start_between_two_gains_is_restored_onto_one():
    """The amplifier's gain is a root of ``(g−1)(g−2)(g−4)(g−8)``; from g = 1.5 the
    Gauss–Newton step onto it overshoots to 3.3, where the quartic is larger (9.8 against
    4.1): the retraction halves it (to g ≈ 1.95) and goes on, where it used to stop at the
    start and the fit end infeasible (status 7)."""
    from scenarios import pga_cases

    fam = kanagen.load("pga")
    model, data, info, _, _ = pga_cases()[1]
    for start in ([1.5, 0.16], [1.52, -0.22], [3.0, 0.3], [6.0, 0.3]):
        res = kanagen.fit(fam, model, data=data, info=info, q0=np.array(start))
        assert res.success, (start, res.message)
        assert min(abs(res.params["g"] - g) for g in (1.0, 2.0, 4.0, 8.0)) < 1e-9


def test_an_ellipse_fit_from_a_hyperbola_reaches_the_ellipse():
    """The ellipse model (``AC − B² = 1/s²``) from a hyperbola's coefficients (``AC − B²``
    = −0.27): the retraction's full steps raise the violation; halved, they reach an
    ellipse, and the fit ends at the minimum the scenario's start reaches."""
    from scenarios import conic_lattice_cases

    fam = kanagen.load("conic_lattice")
    model, data, info, start, _ = conic_lattice_cases()[2]
    ref = kanagen.fit(fam, model, data=data, info=info, q0=start)
    for q_start in ([0.2037, 0.4646, -0.2961, -0.2113, 0.1376, 1.3887, 1.5626, 1.0816],
                    [-0.1755, -0.2489, 0.1718, -0.0265, -0.0466, 1.3877, 0.8772, 1.2361]):
        res = kanagen.fit(fam, model, data=data, info=info, q0=start,
                          q_start=np.array(q_start))
        assert res.success, res.message
        assert res.cost == pytest.approx(ref.cost, rel=1e-9)
