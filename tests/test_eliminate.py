"""Elimination of linear parameter constraints (report §6): the reduction is exact, and
fitting in the free components changes no result."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp
from scenarios import SCENARIOS, SPECS, close

import kanagen
from kanagen.codegen.eliminate import linear_reduction
from kanagen.modelspec import parse_spec, symbol

SPEC = """\
name: elim
constants: {f0: 2.0}
parameter: {a: 1.0, b: 0.5, c: 0.2, d: 0.1}
channels:
  obs:
    components: [u, v]
    equations: [a*u**2 + b*u*v + c*v + d*f0 - v**2]
models:
  pinned:
    constraints: [a - 2*c + 1, b - c, a**2 + b**2 + c**2 + d**2 - 4]
  redundant:
    constraints: [a - c, 2*a - 2*c, b*d - 1]
  inconsistent:
    constraints: [a - 1, a - 2]
  scaled:
    constraints: [a - f0*c]
  free:
    constraints: []
"""


@pytest.fixture(scope="module")
def family():
    return parse_spec(SPEC, "elim.yaml")


def _check_exact(family, red):
    """``q = T r + t`` solves every linear constraint exactly, and the reduced constraints
    are the others at that q."""
    q = [symbol(n) for n in family.parameter_names]
    r = [q[i] for i in red.free]
    T, t = sp.Matrix(red.T), sp.Matrix(red.t)
    full = dict(zip(q, T * sp.Matrix(r) + t, strict=True))
    constraints = family.model(red.model).constraints
    left = [sp.expand(c.xreplace(full)) for c in constraints]
    assert sum(e != 0 for e in left) == len(red.constraints)
    for e, reduced in zip([e for e in left if e != 0], red.constraints, strict=True):
        assert sp.expand(e - reduced) == 0


def test_linear_constraints_are_solved_exactly(family):
    red = linear_reduction(family, "pinned")
    # a − 2c + 1 = 0 and b − c = 0: the last components pivot, a and d stay free
    assert [family.parameter_names[i] for i in red.free] == ["a", "d"]
    assert dict(red.substitution) == {symbol("c"): (symbol("a") + 1) / 2,
                                      symbol("b"): (symbol("a") + 1) / 2}
    _check_exact(family, red)


def test_redundant_rows_are_dropped_and_inconsistent_ones_refused(family):
    red = linear_reduction(family, "redundant")
    assert len(red.free) == 3 and len(red.constraints) == 1
    _check_exact(family, red)
    assert linear_reduction(family, "inconsistent") is None


def test_constants_and_absent_constraints_are_not_eliminated(family):
    assert linear_reduction(family, "scaled") is None  # f0 is set at run time
    assert linear_reduction(family, "free") is None


def _results(fam, model, data, info, start, consts):
    """The fit and its outputs as (array, scale its rounding is relative to)."""
    res = kanagen.fit(fam, model, data=data, info=info, q0=start, constants=consts)
    sigma = float(np.max(np.abs(res.covariance[np.isfinite(res.covariance)]), initial=0.0))
    out = [(res.q, 0.0), (res.cost, 0.0), (res.dof, 0.0), (res.info, 0.0),
           (res.covariance, 0.0), *((m, 0.0) for m in res.measures.values())]
    for v in res.derived.values():
        # a derived quantity at its singular point (line's -b/a of a horizontal line, a = 0)
        # has no value to compare: the full fit leaves a rounding-noise a, the reduced a = 0
        if np.all(np.abs(v.value) < 1e12):
            J = np.abs(np.reshape(v.jacobian, (-1, res.q.size)))
            out.append((v.covariance, float(np.max(J.sum(axis=1))) ** 2 * sigma))
    return res, out


@pytest.mark.parametrize("spec", SPECS, ids=lambda p: p.name)
def test_fitting_in_the_free_components_changes_no_result(spec):
    full = kanagen.load(spec)
    reduced = kanagen.load(spec, eliminate_linear=True)
    for model, data, info, start, consts in SCENARIOS[spec.name]():
        a, ref = _results(full, model, data, info, start, consts)
        b, got = _results(reduced, model, data, info, start, consts)
        assert a.success == b.success and a.status == b.status
        # E² is rounding noise at a solution: negligible against the cost in both
        assert abs(a.residual - b.residual) <= 1e-10 * max(1.0, a.cost)
        for (x, _), (y, scale) in zip(got, ref, strict=True):
            close(x, y, 1e-10, scale)


def test_reduced_fit_with_a_prior_and_a_start_off_the_constraints(family):
    """A prior q0 that violates the linear constraints: the same estimate, cost included."""
    rng = np.random.default_rng(5)
    u = rng.uniform(-1, 1, 25)
    q_true = np.array([0.5, 0.75, 0.75, 1.0])  # a − 2c + 1 = 0, b = c; not on the sphere
    v = np.array([np.roots([-1, q_true[1] * x + q_true[2],
                            q_true[0] * x**2 + q_true[3] * 2.0]).real.max() for x in u])
    data = {"obs": np.c_[u, v] + rng.normal(0, 0.01, (25, 2))}
    q0 = np.array([0.6, 0.7, 0.9, 1.1])
    Q0 = np.diag([1.0, 2.0, 0.5, 3.0])
    for fam_model in ("redundant", "free"):
        fams = [kanagen.load(family, eliminate_linear=e) for e in (False, True)]
        outs = [_results(f, fam_model, data, {"obs": 1e4}, None, None)[1] for f in fams]
        assert fams[1].reduction(fam_model) is not None or fam_model == "free"
        for (x, _), (y, scale) in zip(outs[1], outs[0], strict=True):
            close(x, y, 1e-9, scale)
        res = [kanagen.fit(f, fam_model, data=data, info={"obs": 1e4}, q0=q0, Q0=Q0)
               for f in fams]
        assert res[0].success and res[1].success
        close(res[1].q, res[0].q, 1e-9)
        close(res[1].cost, res[0].cost, 1e-9)
