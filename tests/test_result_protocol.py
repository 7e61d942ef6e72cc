"""One result protocol (issue 20): ``FitResult``, ``RobustEstimate`` and ``ModelState`` say
the same things with the same meanings: ``cost`` = L̃², ``normalized_cost`` = L̃²/d, the χ²
statistics a metrologist reads (reduced χ² about 1 with the right weights), ``std`` by name,
a short ``repr`` and a ``summary()`` table."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from scenes import arc

import kanagen
from kanagen.fitjob import finite, result_to_json
from kanagen.runtime.results import DerivedValue, ResultProtocol

FIELDS = ("model", "params", "q", "std", "covariance", "cost", "total_cost", "normalized_cost",
          "dof", "derived", "success", "chi2", "chi2_dof", "reduced_chi2", "chi2_pvalue")

LINE = """name: line
parameter: {b0: 1.0, b1: 1.0}
channels:
  pt:
    components: [x, y]
    equations: ["y - (b0 + b1*x)"]
models:
  m: {}
"""


@pytest.fixture(scope="module")
def xy():
    pts, _ = arc("ellipse", 3, n=200, outliers=0.05, sigma=1.0)
    return pts


@pytest.fixture(scope="module")
def results(xy):
    """One result of each entry point on the same noisy ellipse (σ = 1, info 1)."""
    conic, lattice = kanagen.load("conic"), kanagen.load("conic_lattice")
    fit = kanagen.fit(conic, "conic", data={"point": xy})
    robust = kanagen.robust_fit(conic, "conic", data={"point": xy}, scale=4.0,
                                max_samples=100)
    est = kanagen.Estimator(lattice, scale=4.0, seed=0)
    ids = est.add_measures("point", xy, info=1.0)
    best = est.run(max_samples=300)
    found = kanagen.find_structures(lattice, data={"point": xy}, max_structures=1, scale=4.0,
                                    seed=0)
    return {"fit": fit, "robust": robust, "best": best, "structure": found[0],
            "ids": ids, "lattice": lattice}


def _check_protocol(r):
    assert isinstance(r, ResultProtocol)
    for name in FIELDS:
        assert hasattr(r, name), name
    assert isinstance(r.params, dict) and isinstance(r.std, dict)
    assert list(r.std) == [*r.params, *r.slacks]
    np.testing.assert_array_equal(np.asarray(r.std),
                                  np.sqrt(np.clip(np.diag(r.covariance), 0, None)))
    assert r.total_cost == r.cost
    assert r.normalized_cost == pytest.approx(r.cost / r.dof)
    assert r.chi2 == pytest.approx(2 * r.cost)
    assert r.chi2_dof > 0 and r.chi2_dof < r.dof
    assert r.reduced_chi2 == pytest.approx(2 * r.cost / r.chi2_dof)
    assert 0.0 <= r.chi2_pvalue <= 1.0
    text = r.summary()
    assert isinstance(text, str)
    for name in r.params:
        assert f"{name} " in text or f"{name}=" in text
    assert "chi2/nu" in text
    assert len(repr(r)) < 1000 and "\n" not in repr(r)
    assert repr(r).startswith(type(r).__name__ + "(model=")


@pytest.mark.parametrize("entry", ["fit", "robust", "best", "structure"])
def test_every_entry_point_speaks_the_protocol(results, entry):
    _check_protocol(results[entry])


def test_the_same_fit_has_the_same_cost_everywhere(results, xy):
    robust = results["robust"]
    assert robust.cost == robust.fit.cost and robust.chi2_dof == robust.fit.chi2_dof
    # the lattice's state is the fit on its inliers: refit them locally, same cost
    best = results["best"]
    rows = np.searchsorted(results["ids"], best.inliers)
    again = kanagen.fit(results["lattice"], best.model, data={"point": xy[rows]}, q0=best.q)
    assert again.cost == pytest.approx(best.cost, rel=1e-6)
    assert again.dof == best.dof and again.chi2_dof == best.chi2_dof
    assert again.reduced_chi2 == pytest.approx(best.reduced_chi2, rel=1e-6)
    # d = N + free, ν = N − free: one equation per point, five free components of an ellipse
    assert best.dof == best.inliers.size + 5 and best.chi2_dof == best.inliers.size - 5


def test_pinned_components_have_zero_std(results):
    lattice, xy = results["lattice"], arc("circle", 2, n=60, outliers=0.0)[0]
    circle = kanagen.fit(lattice, "circle", data={"point": xy})
    std = np.asarray(circle.std)
    assert np.all(np.isfinite(std))
    assert circle.std["B"] <= 1e-12 * std.max()  # the circle pins B = 0 (to rounding)
    assert circle.std[1] == circle.std["B"] and circle.std["D"] > 1e-6 * std.max()


@pytest.mark.parametrize("entry", ["fit", "robust", "best", "structure"])
def test_every_result_names_units_and_what_its_model_pins(results, entry):
    r = results[entry]
    assert r.units["semi_axes"] == "px" and r.units["angle"] == "deg"
    assert set(r.pinned) <= {*r.params, *r.slacks}
    text = r.summary()
    assert "px" in text
    for name in r.pinned:  # a pinned component is no estimate: no "name = value ± std" line
        assert not re.search(rf"^  {name}\s+= ", text, re.M), name


def test_a_circle_pins_b_and_says_so(results):
    lattice, xy = results["lattice"], arc("circle", 2, n=60, outliers=0.0)[0]
    circle = kanagen.fit(lattice, "circle", data={"point": xy})
    assert circle.pinned == {"B": 0.0, "s_ellipse": 1.0, "s_proper": 1.0}
    text = circle.summary()
    assert "pinned by the model (not estimated): B = 0" in text
    assert re.search(r"^  radius = .* px$", text, re.M)
    ellipse = kanagen.fit(lattice, "ellipse", data={"point": xy})
    assert "B" not in ellipse.pinned and ellipse.pinned == {"s_proper": 1.0}


def test_json_record_carries_the_chi2(results):
    rec = finite(result_to_json(results["fit"]))
    json.dumps(rec)
    res = results["fit"]
    assert rec["cost"] == res.cost and rec["normalized_cost"] == res.normalized_cost
    assert rec["chi2_dof"] == res.chi2_dof
    assert rec["reduced_chi2"] == pytest.approx(res.reduced_chi2)
    assert rec["chi2_pvalue"] == pytest.approx(res.chi2_pvalue)


def test_estimator_and_fit_records_use_the_same_names(results):
    """``kanagen fit --json`` with or without ``--local`` (and ``kanagen batch``): the same
    names with the same meanings, in the chosen model and in each lattice row."""
    from kanagen.fitjob import estimator_to_json

    est = kanagen.Estimator(results["lattice"], scale=4.0, seed=0)
    est.add_measures("point", arc("ellipse", 3, n=120, outliers=0.05, sigma=1.0)[0], info=1.0)
    best = est.run(max_samples=200)
    rec = finite(estimator_to_json(est, best.model))
    json.dumps(rec)
    local = finite(result_to_json(results["fit"]))
    names = ("cost", "normalized_cost", "dof", "chi2", "chi2_dof", "reduced_chi2",
             "chi2_pvalue")
    assert all(name in rec and name in local for name in names)
    assert rec["cost"] == best.cost and rec["normalized_cost"] == best.normalized_cost
    assert rec["reduced_chi2"] == pytest.approx(best.reduced_chi2)
    (row,) = [r for r in rec["lattice"] if r["chosen"]]
    assert row["cost"] == best.cost and row["normalized_cost"] == best.normalized_cost


def test_derived_values_behave_as_numbers(results):
    derived = results["fit"].derived
    angle = derived["angle"]
    assert isinstance(angle, DerivedValue)
    assert float(angle) == pytest.approx(float(np.asarray(angle.value)))
    assert 2 * angle == pytest.approx(2 * float(angle))
    assert angle + 1 == pytest.approx(float(angle) + 1)
    assert -angle == pytest.approx(-float(angle))
    assert angle / 2 == pytest.approx(float(angle) / 2)
    assert isinstance(2 * angle, np.floating | np.ndarray)
    matrix = derived["matrix"]
    assert np.asarray(matrix).shape == (3, 3) and matrix.std.shape == (3, 3)
    assert np.asarray(matrix, dtype=np.float32).dtype == np.float32
    np.testing.assert_array_equal(matrix @ np.ones(3), np.asarray(matrix.value) @ np.ones(3))
    with pytest.raises(TypeError):
        float(matrix)


def test_py_typed_is_shipped():
    from importlib.resources import files

    assert files("kanagen").joinpath("py.typed").is_file()


def test_mean_reduced_chi2_is_one_with_the_right_sigma():
    """The floor: on 1,000 simulated fits with the right σ, the mean reduced χ² is within
    0.05 of 1 (a line, errors in x and y, 20 points: ν = 18)."""
    fam = kanagen.load_text(LINE, source="line.yaml")
    rng = np.random.default_rng(20)
    sx, sy, M = 0.3, 0.5, 20
    info = np.diag([sx**-2, sy**-2])
    x = np.linspace(0.0, 10.0, M)
    values = []
    for _ in range(1000):
        X = np.c_[x + sx * rng.standard_normal(M), 2.0 - 0.5 * x + sy * rng.standard_normal(M)]
        res = kanagen.fit(fam, "m", data={"pt": X}, info={"pt": info}, q0=[2.0, -0.5])
        assert res.success and res.chi2_dof == M - 2
        values.append(res.reduced_chi2)
    mean = float(np.mean(values))
    print(f"mean reduced chi2 over {len(values)} line fits with the right sigma: {mean:.4f}")
    assert abs(mean - 1.0) < 0.05, mean
    # and L̃²/d is about ½ (d = N + free parameters), as before
    assert float(np.mean([v * (M - 2) / (2 * (M + 2)) for v in values])) == pytest.approx(
        0.5 * (M - 2) / (M + 2), rel=0.06)


def test_derived_quantities_are_computed_when_read():
    """A fit's derived quantities are evaluated on first read, at the estimate as it was
    returned (changing the result's arrays afterwards does not change them); they pickle
    and copy as a plain dict equal to :func:`derived_values`'."""
    import copy
    import pickle

    from kanagen.runtime.results import DerivedQuantities, derived_values

    fam = kanagen.load("conic")
    xy, _ = arc("ellipse", 3, n=30, outliers=0.0, sigma=0.5)
    res = kanagen.fit(fam, "conic", data={"point": xy}, info={"point": 4.0},
                      q0=np.array([1.0, 0.0, 1.0, -6.6, -5.0, 15.0]) / 18.0)
    assert isinstance(res.derived, DerivedQuantities) and res.derived._values is None
    q, covariance = res.q.copy(), res.covariance.copy()
    reference = derived_values(fam, q, covariance, fam.constant_vector(None), "conic")
    res.covariance[...] = 0.0  # the user's copy changed: the derived stay the estimate's
    assert list(res.derived) == list(reference) and len(res.derived) == len(reference)
    for name, value in reference.items():
        np.testing.assert_array_equal(res.derived[name].value, value.value)
        np.testing.assert_array_equal(res.derived[name].covariance, value.covariance)
    for clone in (pickle.loads(pickle.dumps(res.derived)), copy.deepcopy(res.derived)):
        assert type(clone) is dict and list(clone) == list(reference)
    assert "centre" in repr(res.derived)
