"""Generated derivatives are finite where their limit is, and the generated code never raises
at a power of 0 (codegen/limits.py, codegen/printer.py: ``NumpyPrinter._print_Pow``).

A Hill curve's zero dose (``x = 0`` in ``b0 x^b2 / (b1^b2 + x^b2)``) gave SymPy's
``b2 x^b2 / x`` and ``x^b2 log x``: NaN there, and a fit with such a measure stalled at its
start. ``x**(-2)`` at 0 raised ZeroDivisionError inside numba whatever the error model, and
the compiled fit printed it as an ignored exception, over and over.
"""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import least_squares

import kanagen
from kanagen.codegen.limits import finite_limits, powlog
from kanagen.codegen.printer import NumpyPrinter

X, B, C = sp.symbols("x b c", real=True)


def _numpy_function(expr):
    """``expr`` printed by the NumPy backend's printer, as a function of (x, b, c)."""
    text = NumpyPrinter({X: "x", B: "b", C: "c"}).doprint(expr)
    return eval(f"lambda x, b, c: {text}", {"np": np})  # noqa: S307 - our own printed text


def test_power_derivatives_are_finite_at_zero():
    d_x = finite_limits(sp.diff(X**B, X))
    assert sp.simplify(d_x - B * X ** (B - 1)) == 0
    d_b = finite_limits(sp.diff(C * X**B, B))
    assert d_b.has(powlog)
    f_x, f_b = _numpy_function(d_x), _numpy_function(d_b)
    assert f_x(0.0, 2.5, 1.0) == 0.0 and f_x(0.0, 1.0, 1.0) == 1.0
    assert f_b(0.0, 2.5, 3.0) == 0.0
    assert f_b(2.0, 2.5, 3.0) == pytest.approx(3 * 2.0**2.5 * np.log(2.0), rel=1e-15)
    # below 0 at an integer exponent (a model pinning it), the real continuation's slope
    assert f_b(-2.0, 1.0, 3.0) == pytest.approx(3 * -2.0 * np.log(2.0), rel=1e-15)
    # below 1, the derivative in x is truly infinite at 0, and stays so
    assert np.isinf(f_x(np.float64(0.0), 0.5, 1.0))


def test_polynomials_are_left_alone():
    expr = 3 * X**2 * C - X / C**2
    assert finite_limits(sp.diff(expr, X)) == sp.diff(expr, X)
    assert finite_limits(sp.diff(expr, C)) == sp.diff(expr, C)


@settings(max_examples=40, deadline=None)
@given(st.floats(0.05, 20), st.floats(-3, 3), st.floats(-3, 3))
def test_rewritten_derivatives_equal_sympys_where_both_are_defined(x, b, c):
    hill = C * X**B / (2 ** B + X**B) + sp.log(X) * X ** (B * C)
    for variable in (X, B, C):
        plain = sp.diff(hill, variable)
        value = _numpy_function(finite_limits(plain))(x, b, c)
        expected = float(plain.subs({X: x, B: b, C: c}))
        assert value == pytest.approx(expected, rel=1e-9, abs=1e-12)


def test_negative_integer_powers_of_zero_do_not_raise_in_numba():
    numba = pytest.importorskip("numba")
    text = NumpyPrinter({X: "x", B: "b", C: "c"}).doprint(sp.Pow(X + B, -2, evaluate=False))
    assert "**(-" not in text
    scope = {"np": np}
    exec(f"def f(x, b, c):\n    return {text}\n", scope)  # noqa: S102 - our own printed text
    compiled = numba.njit(error_model="numpy")(scope["f"])
    assert np.isinf(compiled(0.0, 0.0, 0.0))
    assert compiled(0.5, 1.0, 0.0) == (0.5 + 1.0) ** (-2)


HILL = """
name: hill_zero_dose
parameter: {b0: 1.0, b1: 1.0, b2: 1.0}
channels:
  pt:
    components: [x, y]
    equations: ["y - b0*x**b2/(b1**b2 + x**b2)"]
models:
  m: {}
"""


def _zero_dose_data():
    rng = np.random.default_rng(1)
    x = np.r_[0, 0, np.linspace(0.2, 5, 10)]
    y = 4 * x**2 / (1.5**2 + x**2)
    x, y = x + 0.01 * rng.standard_normal(12), y + 0.01 * rng.standard_normal(12)
    x[:2] = 0
    return x, y


def _dense_minimum(x, y, start):
    """The errors-in-variables minimum over (b, δ) jointly, with |x + δ| (the same model
    where x + δ ≥ 0): scipy's MINPACK, finite differences."""
    def residuals(z):
        b, xx = z[:3], np.abs(x + z[3:])
        return 100 * np.r_[z[3:], y - b[0] * xx ** b[2] / (b[1] ** b[2] + xx ** b[2])]
    fit = least_squares(residuals, np.r_[start, np.zeros(x.size)], method="lm",
                        xtol=1e-15, ftol=1e-15)
    return fit.x[:3], fit.cost


@pytest.mark.parametrize("start", [(4.0, 1.5, 2.0), (3.0, 1.0, 1.5)])
def test_hill_fit_with_zero_doses_reaches_the_minimum(start):
    x, y = _zero_dose_data()
    family = kanagen.load_text(HILL)
    fit = kanagen.fit(family, "m", data={"pt": np.c_[x, y]}, info={"pt": 1e4},
                      q0=np.array(start))
    q, cost = _dense_minimum(x, y, np.array(start))
    assert fit.success, fit.message
    np.testing.assert_allclose(fit.q, q, rtol=1e-7)
    assert fit.cost == pytest.approx(cost, rel=1e-9)
    np.testing.assert_array_equal(fit.measures["pt"][:2, 0], 0.0)


def test_a_fit_at_a_zero_power_fails_quietly(capfd):
    family = kanagen.load_text(HILL.replace("hill_zero_dose", "hill_abs").replace(
        "b0*x**b2/(b1**b2 + x**b2)", "b0*abs(x)**b2/(abs(b1)**b2 + abs(x)**b2)"))
    x = np.linspace(0, 5, 12)
    y = 4 * x**2 / (1.5**2 + x**2)
    fit = kanagen.fit(family, "m", data={"pt": np.c_[x, y]}, info={"pt": 1e4},
                      q0=np.array([4.0, 0.0, 2.0]))
    assert not fit.success and np.isinf(fit.cost)
    err = capfd.readouterr().err
    assert "ZeroDivisionError" not in err and "Exception ignored" not in err
