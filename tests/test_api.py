"""The public API: input validation, coherence, minimal solve, robustness, docstrings."""

from __future__ import annotations

import doctest
import importlib

import numpy as np
import pytest

import kanagen

CIRCLE = """\
name: circ
parameter: {cx: 0.0, cy: 0.0, r: 1.0}
channels:
  pt:
    components: [x, y]
    equations: [(x - cx)**2 + (y - cy)**2 - r**2]
models:
  circle:
    constraints: []
"""


@pytest.fixture(scope="module")
def line():
    return kanagen.load("line")


@pytest.fixture(scope="module")
def circ():
    return kanagen.load_text(CIRCLE, "circ.yaml")


XY = np.array([[0.0, 1.0], [1.0, 2.9], [2.0, 5.1], [3.0, 7.0]])


@pytest.mark.parametrize(
    ("kwargs", "fragment"),
    [
        ({"data": {"point": XY[:, :1]}}, "expected (M, 2)"),
        ({"data": {"point": np.where(XY == 2.9, np.nan, XY)}}, "NaN or infinite"),
        ({"data": {"point": np.where(XY == 2.9, np.inf, XY)}}, "index (1, 1)"),
        ({"data": {"nope": XY}}, "unknown channel 'nope'"),
        ({"data": {"point": XY}, "info": {"point": -1.0}}, "must be positive"),
        ({"data": {"point": XY}, "info": {"point": -np.eye(2)}}, "semi-definite"),
        ({"data": {"point": XY}, "info": {"point": np.array([[1.0, 2.0], [0.0, 1.0]])}},
         "symmetric"),
        ({"data": {"point": XY}, "info": {"point": np.ones((3, 2, 2))}}, "has shape"),
        ({"data": {"point": XY}, "info": {"point": np.zeros(4)}}, "must be positive"),
        ({"data": {"point": XY}, "q0": [1.0]}, "q0 has shape"),
        ({"data": {"point": XY}, "q0": {"z": 1.0}}, "unknown parameter 'z'"),
        ({"data": {"point": XY}, "Q0": -np.eye(2)}, "semi-definite"),
        ({"data": {"point": XY}, "constants": {"f0": 1.0}}, "unknown constant 'f0'"),
    ],
)
def test_bad_inputs_raise_before_any_work(line, kwargs, fragment):
    with pytest.raises(ValueError, match=fragment.replace("(", r"\(").replace(")", r"\)")):
        kanagen.fit(line, "line", **kwargs)


def test_unknown_model(line):
    with pytest.raises(ValueError, match="unknown model 'curve'"):
        kanagen.fit(line, "curve", data={"point": XY})


def test_result_fields(line):
    res = kanagen.fit(line, "line", data={"point": XY}, info={"point": 4.0})
    assert res.success and res.status == 0 and res.iterations >= 1
    assert set(res.params) == {"a", "b"}
    assert res.dof == 2 - 0 + 4  # d = n − p + Σ p_i (eq. 7)
    assert res.normalized_cost == pytest.approx(res.cost / 6)
    assert res.measures["point"].shape == XY.shape
    assert res.info.shape == (2, 2) and res.covariance.shape == (2, 2)
    np.testing.assert_allclose(res.covariance, np.linalg.inv(res.info), rtol=1e-10)
    assert res.residual < 1e-20
    d = res.derived["angle"]
    assert d.value == pytest.approx(np.arctan(res.params["a"]))
    assert d.std == pytest.approx(res.std[0] / (1 + res.params["a"] ** 2))
    assert "a =" in res.summary()
    # the horizontal model: a = 0 exactly, b the mean of y
    flat = kanagen.fit(line, "horizontal", data={"point": XY})
    assert abs(flat.params["a"]) < 1e-14  # a linear constraint is solved in one step
    assert flat.params["b"] == pytest.approx(XY[:, 1].mean())
    assert flat.dof == 2 - 1 + 4


def test_coherence_sampson_and_geometric(circ):
    pts = np.array([[2.0, 0.0], [0.0, 0.5], [3.0, 4.0], [1.0, 0.0]])
    q = [0.0, 0.0, 1.0]
    geometric = kanagen.coherence(circ, "circle", q, data={"pt": pts})["pt"]
    radius = np.hypot(*pts.T)
    np.testing.assert_allclose(geometric, (radius - 1) ** 2, atol=1e-12)
    sampson = kanagen.coherence(circ, "circle", q, data={"pt": pts}, iterations=1)["pt"]
    c = radius**2 - 1
    np.testing.assert_allclose(sampson, c**2 / (4 * radius**2))  # c² / ‖∇c‖²
    weighted = kanagen.coherence(circ, "circle", q, data={"pt": pts}, info={"pt": 4.0})["pt"]
    np.testing.assert_allclose(weighted, 4 * (radius - 1) ** 2, atol=1e-12)


def test_minimal_solve_and_sample_size():
    conic = kanagen.load("conic")
    assert kanagen.minimal_sample_size(conic, "conic", "point") == 5
    assert kanagen.minimal_sample_size(conic, "circle", "point") == 3
    t = np.array([0.1, 0.9, 1.7, 2.6, 3.9])
    pts = np.c_[120 * np.cos(t) + 30, 60 * np.sin(t) - 20]
    sol = kanagen.minimal_solve(conic, "conic", data={"point": pts})
    assert sol.success and sol.rank == 6
    c, _, _ = conic.measurement("conic", "point", sol.q, pts)
    assert np.abs(c).max() < 1e-9
    assert np.linalg.norm(sol.q) == pytest.approx(1.0)
    degenerate = kanagen.minimal_solve(conic, "circle", data={"point": np.zeros((3, 2))})
    assert isinstance(degenerate.success, bool)  # no exception on a degenerate sample


def test_numerical_trouble_is_a_status_not_an_exception():
    fam = kanagen.load_text(
        "name: logfit\nparameter: {a: -1.0}\nchannels:\n  obs:\n    components: [y]\n"
        "    equations: [y - log(a)]\nmodels:\n  m:\n    constraints: []\n", "logfit.yaml")
    with np.errstate(all="raise"):
        res = kanagen.fit(fam, "m", data={"obs": np.ones((5, 1))})
    assert not res.success and res.status == 3 and "non-finite" in res.message


def test_measures_without_a_point_on_their_equation_are_infeasible():
    """x² + y² + a = 0 with the constraint a = 1 has no real point: no measure can be
    restored onto it, and the fit says so (status 7) rather than converging; the violation
    it reports is that of the point it returns, and its cost is infinite (the cost of a
    point off its equations would win a comparison of fits)."""
    fam = kanagen.load_text(
        "name: nosol\nparameter: {a: 1.0}\nchannels:\n  point:\n    components: [x, y]\n"
        "    equations: [x**2 + y**2 + a]\nmodels:\n  pinned:\n    constraints: [a - 1]\n",
        "nosol.yaml")
    xy = np.random.default_rng(0).normal(0.0, 1.0, (10, 2))
    res = kanagen.fit(fam, "pinned", data={"point": xy})
    assert not res.success and res.status == 7 and "infeasible" in res.message
    assert res.cost == np.inf
    worst = np.max(np.abs(res.measures["point"][:, 0] ** 2 + res.measures["point"][:, 1] ** 2
                          + res.q[0]))
    assert res.constraint_violation == pytest.approx(worst) and worst >= 1.0


def test_semidefinite_prior_and_partial_observation(line):
    # one point cannot fix both a and b: a semi-definite prior on a alone picks the solution
    res = kanagen.fit(line, "line", data={"point": XY[:1]}, q0=[1.5, 0.0], Q0=[1.0, 0.0])
    assert res.success
    assert res.params["a"] == pytest.approx(1.5) and res.params["b"] == pytest.approx(1.0)
    assert res.cost == pytest.approx(0.0, abs=1e-20)
    # without the prior any line through the point costs nothing: no unique solution, which
    # is said before any iteration (as ODRPACK and MINPACK refuse fewer observations than
    # parameters), not reported as a converged minimum with an infinite variance
    with pytest.raises(ValueError, match="too few measures"):
        kanagen.fit(line, "line", data={"point": XY[:1]})


@pytest.mark.parametrize("module", ["kanagen", "kanagen.loader", "kanagen.runtime.coherence",
                                    "kanagen.runtime.sqrt", "kanagen.modelspec.expressions",
                                    "kanagen.modelspec.parse", "kanagen.scenes",
                                    "kanagen.runtime.geometry",
                                    "kanagen.runtime.two_view_twins"])
def test_docstring_examples_run(module):
    failures, _ = doctest.testmod(importlib.import_module(module),
                                  optionflags=doctest.ELLIPSIS)
    assert failures == 0


def test_a_derived_value_behaves_as_its_number():
    """``np.asarray``, ``float`` (one entry), arithmetic and comparisons act on the value;
    ``.std`` is shaped like it (issue 20)."""
    import numpy as np

    from kanagen.runtime.results import DerivedValue

    scalar = DerivedValue(np.float64(3.0), np.array([[0.04]]), np.zeros((1, 2)))
    assert float(scalar) == 3.0 and 2 * scalar == 6.0 and scalar / 2 == 1.5
    assert 1 - scalar == -2.0 and -scalar == -3.0 and scalar ** 2 == 9.0 and scalar > 2
    assert np.asarray(scalar).dtype == float and scalar.std == pytest.approx(0.2)
    matrix = DerivedValue(np.arange(4.0).reshape(2, 2), np.eye(4), np.zeros((4, 2)))
    assert np.asarray(matrix).shape == (2, 2) and (2 * matrix)[1, 1] == 6.0 and bool(scalar)
    assert (matrix @ np.ones(2)).tolist() == [1.0, 5.0] and matrix.std.shape == (2, 2)
    with pytest.raises(TypeError, match="one entry"):
        float(matrix)
