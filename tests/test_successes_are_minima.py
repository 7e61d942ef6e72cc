"""A success is a minimum, checked by another optimiser: every fit of the shipped scenarios,
from its start and from starts around it, that reports success is on its equations and
constraints, and SLSQP (scipy) started at its point — over every unknown ``(q, m̃)``, with
the same equations — finds no feasible point of lower cost near it.

The engine's own checks (runtime/engine/verify.py) are tested piece by piece elsewhere;
this is the contract seen from outside, by an optimiser that shares nothing with it but
the generated equations."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from reference import slsqp_solve
from scenarios import OFF_CONSTRAINTS, ROOT, SCENARIOS

import kanagen
from kanagen.runtime.fit import make_problem

#: A success's equations and constraints hold to this (‖c‖∞ of the scenarios' successes:
#: ≤ 1.1e-11, the conics' pixel-scaled equations; the hysteresis fits' false successes had 1
#: and 2).
FEASIBLE = 1e-9
#: SLSQP's lower point counts where it is feasible, lower by this much of the cost, and
#: within this much (relative to the parameter's largest component) of the fit's point.
LOWER, NEAR = 1e-7, 0.1

CASES = [(spec, k) for spec, make in SCENARIOS.items() for k in range(len(make()))]


def _lower_nearby(problem, q, mt):
    """SLSQP (:func:`reference.slsqp_solve`) from ``(q, m̃)``, with the problem's equations:
    its point's cost, ``‖c‖∞`` and distance in ``q``."""
    channels = [(lambda qq, m, fn=fn, ch=ch: fn(qq, ch.with_corrected(m), problem.k))
                for fn, ch in zip(problem.measures, problem.channels, strict=True)]
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore")
        out = slsqp_solve(lambda qq: problem.c0(qq, problem.k), channels, problem.q0,
                          problem.Q0, [ch.m for ch in problem.channels],
                          [ch.Q for ch in problem.channels], q_start=q, m_start=mt,
                          tol=1e-14, max_iter=500)
    return out.cost, out.c_inf, np.max(np.abs(out.q - q)) / (1.0 + np.max(np.abs(q)))


def _starts(spec, k, q0):
    """The scenario's start and two around it (seeded): every component moved by a normal
    draw of 5 % of ``1 + |q|``; the hysteresis's by 0.3 (its slacks too: starts from which
    its fits used to end a success off their constraints)."""
    rng = np.random.default_rng(100 * list(SCENARIOS).index(spec) + k)
    spread = 0.3 if spec == "hysteresis.yaml" else 0.05 * (1.0 + np.abs(q0))
    return [None] + [q0 + rng.normal(0.0, 1.0, q0.size) * spread for _ in range(3)]


@pytest.mark.parametrize("spec,k", CASES, ids=[f"{s.removesuffix('.yaml')}-{k}"
                                               for s, k in CASES])
def test_every_success_is_a_minimum_another_optimiser_confirms(spec, k):
    fam = kanagen.load(str(ROOT / "examples" / spec))
    model, data, info, start, constants = SCENARIOS[spec]()[k]
    problem = make_problem(fam, model, data, info, start, constants=constants)
    successes = 0
    for q_start in _starts(spec, k, problem.q0):
        res = kanagen.fit(fam, model, data=data, info=info, q0=start, q_start=q_start,
                          constants=constants)
        if not res.success:
            assert res.status != 0, res.message
            continue
        successes += 1
        assert res.constraint_violation <= FEASIBLE, (q_start, res.message)
        mt = tuple(res.measures[ch.name][:, ch.index] for ch in problem.channels)
        cost, delta, distance = _lower_nearby(problem, np.asarray(res.q), mt)
        lower = delta <= FEASIBLE and cost < res.cost - LOWER * max(1.0, res.cost) and \
            distance < NEAR
        assert not lower, (q_start, res.cost, cost, delta, distance)
    if (spec, k) not in OFF_CONSTRAINTS:
        assert successes, "the scenario's own fit is a success"
