"""Backends: the same estimate to 1e-10 relative whatever evaluates the equations.

As CasADi tests its own code generator (generate, compile, load, compare every output with
the symbolic evaluator), every function of every shipped spec is evaluated by the NumPy
module, the CasADi ``SX`` functions and the compiled library, and the estimator's outputs
(fit, coherence, minimal solve, derived quantities) are compared on a scenario of every
shipped spec (tests/scenarios.py: a new shipped spec must add its scenario there).
"""

from __future__ import annotations

import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from scenarios import SCENARIOS, SPECS, close
from test_codegen import ALL_FUNCTIONS

import kanagen
from kanagen.codegen import CASADI_FUNCTIONS, NUMPY_FUNCTIONS
from kanagen.codegen.compile import CompileWarning
from kanagen.modelspec import FUNCTIONS, load_spec

ROOT = Path(__file__).resolve().parents[1]


def load(spec, backend, **options):
    """The family on ``backend``; ``compiled`` skips where no C compiler works."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", CompileWarning)
        try:
            return kanagen.load(spec, backend=backend, **options)
        except CompileWarning as exc:
            pytest.skip(f"no compiled backend here: {exc}")


def test_every_shipped_spec_has_a_scenario():
    assert sorted(SCENARIOS) == [p.name for p in SPECS]


def _derived_scale(value, jacobian, q) -> float:
    """The magnitude a derived quantity's rounding is relative to: its value, or its change
    when q moves by its own magnitude, ``Σ|J| max|q|`` (the discriminant AC − B² of a line
    is rounding noise around 0, from A, B, C that are rounding noise around 0)."""
    first = np.abs(np.reshape(jacobian, (-1, q.size))).sum(axis=1) * np.max(np.abs(q))
    return float(max(np.max(np.abs(value), initial=0.0), np.max(first, initial=0.0)))


def _outputs(fam, case, q_at=None):
    """Everything the estimator says on a case: name -> list of (array, scale) with the
    scale its rounding is relative to (0: its own magnitude). The fit's outputs when it
    succeeds (else its status); the coherence errors and the derived quantities at ``q_at``
    (default: the estimate), the same point for every backend; the minimal solve."""
    model, data, info, start, consts = case
    res = kanagen.fit(fam, model, data=data, info=info, q0=start, constants=consts)
    q_at = res.q if q_at is None else q_at
    out = {"status": [(res.status, 0.0)], "success": [(res.success, 0.0)]}
    identified = np.isfinite(np.diagonal(res.covariance))
    if res.success and not identified.all():
        # a minimum that is not isolated (hysteresis from two readings: the data fix 1 of
        # 11 components): the components of infinite variance take any value along it, and
        # the backends' last-bit differences pick different ones; the cost and the
        # identified components are the estimate
        out.update({"q[identified]": [(res.q[identified], 0.0)], "cost": [(res.cost, 0.0)]})
    elif res.success:  # an estimate: every output (a failed fit stops anywhere on a plateau)
        out.update({"q": [(res.q, 0.0)], "cost": [(res.cost, 0.0)], "info": [(res.info, 0.0)],
                    "covariance": [(res.covariance, 0.0)], "dof": [(res.dof, 0.0)],
                    # E² is rounding noise at a solution: negligible against the cost
                    "residual": [(res.residual, max(res.cost, 1.0))]})
        out.update({f"measures[{k}]": [(v, 0.0)] for k, v in res.measures.items()})
        sigma = float(np.max(np.abs(res.covariance[np.isfinite(res.covariance)]), initial=0.0))
        for k, v in res.derived.items():
            J = np.abs(np.reshape(v.jacobian, (-1, res.q.size)))
            # J Σ Jᵀ carries the rounding of Σ (a constrained component's 0 variance is
            # ±1e-19 noise): relative to |J|² max|Σ|
            out[f"derived[{k}]"] = [(v.value, _derived_scale(v.value, v.jacobian, res.q)),
                                    (v.covariance, float(np.max(J.sum(axis=1)) ** 2 * sigma))]
    for iterations in (1, None):
        errors = kanagen.coherence(fam, model, q_at, data=data, info=info, constants=consts,
                                   iterations=iterations)
        out.update({f"coherence{iterations}[{k}]": [(v, 0.0)] for k, v in errors.items()})
    channel, X = next(iter(data.items()))
    size = kanagen.minimal_sample_size(fam, model, channel, start, consts)
    sol = kanagen.minimal_solve(fam, model, data={channel: X[:size]}, q_start=start,
                                constants=consts)
    out["minimal.success"] = [(sol.success, 0.0)]
    if identified.all():  # else the minimal sample leaves the same directions free
        out["minimal.q"] = [(sol.q, 0.0)]
    for k, (value, jac) in fam.derived(q_at, consts).items():
        out[f"derived@q[{k}]"] = [(value, _derived_scale(value, jac, q_at)), (jac, 0.0)]
    return out


@pytest.mark.parametrize("backend", ["casadi", "compiled"])
@pytest.mark.parametrize("spec", SPECS, ids=lambda p: p.name)
def test_same_estimate_whatever_the_backend(spec, backend):
    reference = kanagen.load(spec)
    other = load(spec, backend)
    assert other.backend == backend
    for case in SCENARIOS[spec.name]():
        q_ref = kanagen.fit(reference, case[0], data=case[1], info=case[2], q0=case[3],
                            constants=case[4]).q
        ref, got = _outputs(reference, case, q_ref), _outputs(other, case, q_ref)
        assert ref.keys() == got.keys()
        for key in ref:
            for (a, _), (b, scale) in zip(got[key], ref[key], strict=True):
                close(a, b, scale=scale)


@pytest.mark.parametrize("backend", ["casadi", "compiled"])
@pytest.mark.parametrize("spec", [*SPECS, "allfun"], ids=lambda p: getattr(p, "name", p))
def test_every_function_equals_the_numpy_module(spec, backend):
    """Each function, evaluated at random points, by the NumPy module and by the backend, to
    1e-12 of the largest entry (the evaluation orders differ: the calibrated rays' terms
    cancel to 2e-13 of it)."""
    if spec == "allfun":
        spec = kanagen.modelspec.parse_spec(ALL_FUNCTIONS, "allfun.yaml")
    reference = kanagen.load(spec)
    other = load(spec, backend)
    rng = np.random.default_rng(7)
    k = reference.constant_vector()
    for model in reference.models:
        for reduced in ([False, True] if model in reference._reductions else [False]):
            n = len(reference._reductions[model].free) if reduced else reference.n
            q = rng.uniform(0.2, 0.6, n)
            for a, b in zip(other.c0_function(model, reduced)(q, k),
                            reference.c0_function(model, reduced)(q, k), strict=True):
                close(a, b, 1e-12)
            for ch, info in reference.channels.items():
                for M in (0, 1, 17):
                    X = rng.uniform(0.1, 0.9, (M, len(info.components)))
                    for a, b in zip(other.measurement_function(model, ch, reduced)(q, X, k),
                                    reference.measurement_function(model, ch, reduced)(q, X, k),
                                    strict=True):
                        close(a, b, 1e-12)
    q = rng.uniform(0.2, 0.6, reference.n)
    ref, got = reference.derived(q, k), other.derived(q, k)
    assert ref.keys() == got.keys()
    for name in ref:
        for a, b in zip(got[name], ref[name], strict=True):
            close(a, b, 1e-12)
    if reference.slack_names:
        close(other.functions.slack_measures(q, k), reference.functions.slack_measures(q, k),
              1e-12)


def test_casadi_functions_have_named_inputs_and_outputs():
    from kanagen.generated import conic_casadi as mod

    f = mod.MODELS["conic"]["channels"]["point"]
    assert f.name_in() == ["q", "m", "k"] and f.name_out() == ["c", "C", "D"]
    assert (f.size_in(0), f.size_in(1), f.size_out(1)) == ((6, 1), (2, 1), (1, 6))
    assert mod.MODELS["circle"]["reduced"]["c0"].name_in() == ["r", "k"]
    assert mod.DERIVED.name_out() == [f"{kind}_{name}" for name in (
        "matrix", "discriminant", "centre", "semi_axes", "angle", "radius") for kind in "vj"]


def test_printer_tables_are_one_to_one_and_cover_the_language():
    classes = {f for f in FUNCTIONS.values() if isinstance(f, type)}
    for table in (NUMPY_FUNCTIONS, CASADI_FUNCTIONS):
        assert classes <= set(table)
        assert len(set(table.values())) == len(table)
    assert set(NUMPY_FUNCTIONS) == set(CASADI_FUNCTIONS)


def test_shipped_examples_have_committed_casadi_modules():
    for spec in SPECS:
        assert (ROOT / "generated" / f"{load_spec(spec).name}_casadi.py").is_file()


def test_unknown_backend_is_refused():
    with pytest.raises(ValueError, match="unknown backend"):
        kanagen.load("conic", backend="jax")


def test_no_compiler_warns_and_falls_back_to_casadi(monkeypatch, tmp_path):
    """``CC`` names a missing compiler: a clear warning, the uncompiled backend, same fit."""
    monkeypatch.setenv("KANAGEN_CACHE", str(tmp_path))  # nothing compiled there yet
    monkeypatch.setenv("CC", str(tmp_path / "no-such-cc"))
    with pytest.warns(CompileWarning, match="no C compiler: CC=.*no-such-cc.*uncompiled CasADi"):
        fam = kanagen.load("line", backend="compiled")
    assert fam.backend == "casadi"
    xy = np.array([[0.0, 1.0], [1.0, 2.9], [2.0, 5.1], [3.0, 7.0]])
    close(kanagen.fit(fam, "line", data={"point": xy}).q,
          kanagen.fit(kanagen.load("line"), "line", data={"point": xy}).q)


def test_a_failing_compiler_is_reported_not_raised(monkeypatch, tmp_path):
    monkeypatch.setenv("KANAGEN_CACHE", str(tmp_path))
    monkeypatch.setenv("CC", "false")  # runs, and fails
    with pytest.warns(CompileWarning, match="the C compiler failed"):
        assert kanagen.load("line", backend="compiled").backend == "casadi"


def test_casadi_modules_are_byte_identical_across_processes():
    code = ("import sys; from kanagen.codegen import render_spec; from kanagen.modelspec import "
            "load_spec; [sys.stdout.write(render_spec(load_spec(s), ['casadi']).popitem()[1]) "
            "for s in sys.argv[1:]]")
    outs = {subprocess.run([sys.executable, "-c", code, *map(str, SPECS)], check=True,
                           env=dict(os.environ, PYTHONHASHSEED=seed), capture_output=True,
                           text=True).stdout for seed in ("0", "321")}
    assert len(outs) == 1
    assert "casadi 3." not in outs.pop().lower()  # no tool versions in generated text
