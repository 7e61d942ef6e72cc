"""Kanatani's hyperaccurate correction (issue 21, runtime/hyper.py): the second-order bias it
computes against a closed form, zero where the estimate is linear in the data, and the
corrected estimate on its constraints."""

from __future__ import annotations

import numpy as np
import pytest

import kanagen
from kanagen.runtime.fit import make_problem
from kanagen.runtime.hyper import bias

CIRCLE = """\
name: circ
parameter: {a: 0.0, b: 0.0, r: 1.0}
channels:
  point:
    components: [x, y]
    equations: [(x - a)**2 + (y - b)**2 - r**2]
models:
  circle:
    constraints: []
"""

EXPLICIT = """\
name: explicit
parameter: {c0: 0.0, c1: 1.0}
channels:
  point:
    components: [x, y]
    exact: [x]
    equations: [y - c0 - c1*x]
models:
  line:
    constraints: []
"""


@pytest.fixture(scope="module")
def circle():
    return kanagen.load_text(CIRCLE, "circ.yaml")


def _ring(radius: float, n: int) -> np.ndarray:
    t = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    return np.c_[radius * np.cos(t), radius * np.sin(t)]


@pytest.mark.parametrize("sigma", [0.1, 0.5])
def test_the_bias_of_a_circle_fit_is_its_closed_form(circle, sigma):
    """The geometric (ML) fit of a full circle overestimates the radius by σ²/(2R) to
    leading order (Chernov, "Circular and linear regression", 2010, §7: the essential bias),
    its centre not at all (symmetry): here 200 points, R = 10, within 2 % (the O(1/N) term)."""
    xy = _ring(10.0, 200)
    problem = make_problem(circle, "circle", {"point": xy}, {"point": 1 / sigma**2})
    b = bias(circle, "circle", problem, np.array([0.0, 0.0, 10.0]), (xy,))
    assert abs(b[0]) < 1e-10 and abs(b[1]) < 1e-10
    assert b[2] == pytest.approx(sigma**2 / 20.0, rel=0.02)


def test_an_estimate_linear_in_the_data_is_not_corrected():
    """An explicit model linear in its parameter with exact abscissas: the ML estimate is
    linear in the measures, its second derivatives vanish, the correction is zero."""
    fam = kanagen.load_text(EXPLICIT, "explicit.yaml")
    rng = np.random.default_rng(2)
    x = np.linspace(0.0, 5.0, 30)
    data = {"point": np.c_[x, 1.5 + 0.7 * x + rng.normal(0.0, 0.2, x.size)]}
    ml = kanagen.fit(fam, "line", data=data, info={"point": 25.0})
    hyper = kanagen.fit(fam, "line", data=data, info={"point": 25.0}, correct_bias=True)
    assert ml.success and hyper.success
    assert np.max(np.abs(hyper.bias)) < 1e-12
    np.testing.assert_allclose(hyper.q, ml.q, rtol=0, atol=1e-12)


def test_the_corrected_estimate_stays_on_its_constraints():
    """A conic (unit norm): the corrected vector is unit, differs from the ML one by about
    the bias removed (in the tangent space), keeps the ML covariance and says so."""
    fam = kanagen.load("conic")
    rng = np.random.default_rng(5)
    t = np.linspace(0.1, np.pi - 0.1, 30)
    xy = np.c_[330 + 220 * np.cos(t), 250 + 130 * np.sin(t)] + rng.normal(0, 2.0, (30, 2))
    ml = kanagen.fit(fam, "conic", data={"point": xy}, info={"point": 0.25})
    hyper = kanagen.fit(fam, "conic", data={"point": xy}, info={"point": 0.25},
                        correct_bias=True)
    assert ml.success and hyper.success and hyper.bias is not None and ml.bias is None
    assert np.linalg.norm(hyper.q) == pytest.approx(1.0, abs=1e-12)
    tangent = hyper.bias - (hyper.bias @ ml.q) * ml.q
    assert np.linalg.norm(hyper.q - (ml.q - tangent)) < 0.1 * np.linalg.norm(tangent)
    np.testing.assert_array_equal(hyper.covariance, ml.covariance)
    assert "bias-corrected" in hyper.message
    # relative information: σ² from the reduced χ² (scale-free: info × 100, the same q)
    rel = kanagen.fit(fam, "conic", data={"point": xy}, info={"point": 25.0},
                      correct_bias="relative")
    again = kanagen.fit(fam, "conic", data={"point": xy}, info={"point": 0.25},
                        correct_bias="relative")
    np.testing.assert_allclose(rel.q, again.q, atol=1e-9)
    with pytest.raises(ValueError, match="correct_bias"):
        kanagen.fit(fam, "conic", data={"point": xy}, correct_bias="yes")


def test_a_noisy_circle_loses_its_radius_bias(circle):
    """On a noisy full circle the corrected radius is the ML one less about σ²/(2R)."""
    rng = np.random.default_rng(8)
    xy = _ring(10.0, 100) + rng.normal(0.0, 0.5, (100, 2))
    ml = kanagen.fit(circle, "circle", data={"point": xy}, info={"point": 4.0},
                     q0=[0.0, 0.0, 9.0])
    hyper = kanagen.fit(circle, "circle", data={"point": xy}, info={"point": 4.0},
                        q0=[0.0, 0.0, 9.0], correct_bias=True)
    assert ml.params["r"] - hyper.params["r"] == pytest.approx(0.25 / 20.0, rel=0.1)


def test_a_derived_quantity_loses_its_own_bias(circle):
    """A derived quantity is corrected by its own second differences: the circle's area
    πr² has the bias 2πr·b_r + π·var(r) (the curvature's share, which a value at the
    corrected radius would miss)."""
    spec = CIRCLE + "derived:\n  area: pi*r**2\n"
    fam = kanagen.load_text(spec, "circ_area.yaml")
    xy = _ring(10.0, 200)
    problem = make_problem(fam, "circle", {"point": xy}, {"point": 4.0})
    b, derived = bias(fam, "circle", problem, np.array([0.0, 0.0, 10.0]), (xy,),
                      derived=True)
    var_r = 0.25 / 200  # the radius's variance of a full circle: σ²/N
    want = 2 * np.pi * 10.0 * b[2] + np.pi * var_r
    assert float(derived["area"]) == pytest.approx(want, rel=0.005)
    assert float(derived["area"]) > 2 * np.pi * 10.0 * b[2]  # the curvature's share


def test_the_robust_search_corrects_its_refinement_on_the_inliers(circle):
    """``robust_fit(..., correct_bias=True)``: the fit on the inliers less its bias, the same
    as ``kanagen.fit`` with the correction on those inliers; the outliers play no part."""
    rng = np.random.default_rng(9)
    xy = np.r_[_ring(10.0, 100) + rng.normal(0.0, 0.5, (100, 2)),
               rng.uniform(-30.0, 30.0, (30, 2))]
    options = dict(data={"point": xy}, info={"point": 4.0}, q0=[0.0, 0.0, 9.0],
                   max_samples=200)
    ml = kanagen.robust_fit(circle, "circle", **options)
    hyper = kanagen.robust_fit(circle, "circle", correct_bias=True, **options)
    inliers = np.asarray(ml.inliers["point"])
    assert np.array_equal(inliers, hyper.inliers["point"]) and ml.fit.bias is None
    alone = kanagen.fit(circle, "circle", data={"point": xy[inliers]}, info={"point": 4.0},
                        q_start=ml.q, correct_bias=True)
    np.testing.assert_allclose(hyper.q, alone.q, rtol=1e-7, atol=1e-9)
    assert ml.params["r"] - hyper.params["r"] == pytest.approx(0.25 / 20.0, rel=0.1)
    with pytest.raises(ValueError, match="correct_bias"):
        kanagen.robust_fit(circle, "circle", correct_bias="yes", **options)
