"""A structure must be more than chance (runtime/significance.py): measures without
structure make none, at find_structures' defaults; the a-contrario bound holds for a fixed
model on uniform data; a small true structure among many outliers is still found."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy import stats
from test_structures import crossing_lines

import kanagen
from kanagen.runtime.fit import make_problem
from kanagen.runtime.minimal import coherence_errors
from kanagen.runtime.significance import false_alarms

BOX = ([-50.0, -20.0], [50.0, 20.0])


@pytest.fixture(scope="module")
def line():
    return kanagen.load("line")


def horizontal(line, xy):
    """A problem of the points ``xy`` (σ 1) and the line ``y = 0`` (``y = a x + b``)."""
    return make_problem(line, "line", {"point": xy}), np.zeros(2)


def test_uniform_points_make_no_structure(line):
    """Before the test, uniform outliers gave structures of 4 to 9 points up to
    ``max_structures``."""
    rng = np.random.default_rng(3)
    for seed in range(4):
        xy = rng.uniform(*BOX, (100, 2))
        assert kanagen.find_structures(line, data={"point": xy}, seed=seed) == []
        assert len(kanagen.find_structures(line, data={"point": xy}, seed=seed,
                                           false_alarms=None)) >= 1


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_two_lines_and_outliers_give_two_structures(line, seed):
    """At the default max_structures (5), only the two lines: the outliers left make
    nothing meaningful; each structure holds its line's points."""
    xy, labels = crossing_lines(seed)
    found = kanagen.find_structures(line, data={"point": xy}, seed=seed)
    assert len(found) == 2
    held = sorted(np.bincount(labels[state.inliers], minlength=3)[1:].argmax() + 1
                  for state in found)
    assert held == [1, 2]  # one structure for each line, holding nearly all its points
    for state, label in zip(found, (1, 2), strict=True):
        assert np.count_nonzero(labels[state.inliers] == label) >= 0.9 * np.sum(labels == label)
    assert len(kanagen.find_structures(line, data={"point": xy}, seed=seed,
                                       false_alarms=None)) > 2


def test_small_line_among_many_outliers_is_found(line):
    rng = np.random.default_rng(5)
    x = rng.uniform(-50, 50, 20)
    xy = np.r_[np.c_[x, 0.2 * x + rng.normal(0, 0.5, 20)], rng.uniform(*BOX, (100, 2))]
    found = kanagen.find_structures(line, data={"point": xy}, seed=0)
    assert len(found) == 1
    assert np.isin(np.arange(20), found[0].inliers).mean() >= 0.9


def test_false_alarms_bound_on_uniform_data(line):
    """For one fixed model, P(NFA ≤ ε) ≤ ε under the null (the tests: the n thresholds
    the least NFA chooses among); measured on 300 uniform data sets at ε = 0.1 and 0.3,
    with the binomial's 3σ slack."""
    rng = np.random.default_rng(11)
    values = []
    for _ in range(300):
        problem, q = horizontal(line, rng.uniform(*BOX, (40, 2)))
        values.append(false_alarms(problem, q, 10.0, tests=40, seed=int(rng.integers(1000))))
    values = np.array(values)
    for eps in (0.1, 0.3):
        bound = eps * 300 + 3 * np.sqrt(eps * (1 - eps) * 300)
        assert np.count_nonzero(values <= eps) <= bound


def test_false_alarms_bound_where_a_structure_was_taken_out(line):
    """Uniform points with a band ``|y| < 10`` taken out (a structure found before): the
    points left are twice as dense elsewhere. Told what that structure explains, the null
    avoids the band too and the bound holds for a line in the rest (``y = 15``); without,
    that line is "meaningful" in nearly half of the data sets."""
    rng = np.random.default_rng(11)
    box = tuple(np.array(b) for b in BOX)

    def explained(channels):
        found = make_problem(line, "line", channels=channels)
        return [errors < 100.0 for errors in coherence_errors(found, np.zeros(2))]

    told, blind = [], []
    for _ in range(300):
        xy = rng.uniform(*BOX, (80, 2))
        problem = make_problem(line, "line", {"point": xy[np.abs(xy[:, 1]) >= 10]})
        seed, tests = int(rng.integers(1000)), problem.channels[0].size
        q = np.array([0.0, 15.0])
        told.append(false_alarms(problem, q, 10.0, tests, boxes=[box], explained=explained,
                                 seed=seed))
        blind.append(false_alarms(problem, q, 10.0, tests, boxes=[box], seed=seed))
    bound = 0.1 * 300 + 3 * np.sqrt(0.1 * 0.9 * 300)
    assert np.count_nonzero(np.array(told) <= 0.1) <= bound
    assert np.count_nonzero(np.array(blind) <= 0.1) > 3 * bound


def test_a_remnant_is_no_structure(line):
    """A line's points left after it was taken out at a tighter threshold than its search's
    are not another structure: the line explains them at its search's threshold."""
    rng = np.random.default_rng(4)
    x = rng.uniform(-50, 50, 200)
    xy = np.c_[x, rng.normal(0, 1.5, 200)]  # y = 0 at σ 1.5, fitted at σ 1
    rest = xy[xy[:, 1] ** 2 >= 1.0]  # taken out at the error 1: its tails are left
    problem = make_problem(line, "line", {"point": rest})

    def explained(channels):
        found = make_problem(line, "line", channels=channels)
        return [errors < 10.83 for errors in coherence_errors(found, np.zeros(2))]

    tests = 1000 * rest.shape[0]
    assert false_alarms(problem, np.zeros(2), 10.83, tests, boxes=[(xy.min(0), xy.max(0))]) < 1
    assert false_alarms(problem, np.zeros(2), 10.83, tests, boxes=[(xy.min(0), xy.max(0))],
                        explained=explained) >= tests


def test_false_alarms_matches_a_closed_form(line):
    """Uniform points and ``y = 0`` at σ 1: a point is an inlier under the error ``t`` when
    ``|y| < sqrt(t)``, of chance ``|[-√t, √t] ∩ [y_min, y_max]| / (y_max − y_min)`` in the
    data's box. The NFA is the least of the binomial tails at those chances over the
    thresholds at the points' errors (to the Monte Carlo error of the chance)."""
    rng = np.random.default_rng(2)
    xy = rng.uniform(*BOX, (60, 2))
    xy[:12, 1] = rng.uniform(-0.3, 0.3, 12)  # 12 points near the line
    problem, q = horizontal(line, xy)
    nfa = false_alarms(problem, q, 4.0, tests=1, draws=200_000)
    t = np.sort(xy[:, 1] ** 2)
    t = t[t < 4.0]
    k = np.arange(1, t.size + 1)
    lo, hi = xy[:, 1].min(), xy[:, 1].max()
    chance = (np.minimum(np.sqrt(t), hi) - np.maximum(-np.sqrt(t), lo)) / (hi - lo)
    reference = np.min(stats.binom.sf(k - 1, 60, chance))
    assert 0.5 * reference < nfa < 2 * reference
    assert nfa < 1e-6


def test_false_alarms_is_checked(line):
    xy = np.random.default_rng(0).uniform(*BOX, (30, 2))
    for bad in (0.0, -1.0, np.nan):
        with pytest.raises(ValueError, match="false_alarms"):
            kanagen.find_structures(line, data={"point": xy}, false_alarms=bad)


def test_robust_fit_says_whether_its_structure_is_more_than_chance(line):
    """robust_fit on uniform points converges on the points of some band; its NFA says that
    uniform points give as many (> 1), where a line's points among outliers give far
    below 1. Read when asked (the summary); a pickled or copied estimate keeps the value."""
    import copy
    import pickle

    rng = np.random.default_rng(0)
    noise = kanagen.robust_fit(line, "line", data={"point": rng.uniform(*BOX, (100, 2))})
    assert noise.success and noise.chance._value is None  # not computed yet
    assert noise.false_alarms > 1
    assert "NOT more than chance" in noise.summary()
    x = rng.uniform(-50, 50, 70)
    xy = np.r_[np.c_[x, 0.2 * x + rng.normal(0, 1, 70)], rng.uniform(*BOX, (30, 2))]
    found = kanagen.robust_fit(line, "line", data={"point": xy})
    assert found.false_alarms < 1e-10
    assert "more than chance" in found.summary() and "NOT" not in found.summary()
    for clone in (pickle.loads(pickle.dumps(found)), copy.deepcopy(found)):
        assert clone.false_alarms == found.false_alarms
    fresh = kanagen.robust_fit(line, "line", data={"point": xy})  # same seed: same value
    assert fresh.false_alarms == found.false_alarms


def test_estimator_and_structures_carry_their_false_alarms(line, tmp_path):
    """The lattice search's chosen state, its JSON record and each structure say their NFA:
    a line's points far below 1, uniform points above (the lattice still picks a model)."""
    import json

    from click.testing import CliRunner

    from kanagen.cli import main

    rng = np.random.default_rng(8)
    noise = rng.uniform(*BOX, (100, 2))
    est = kanagen.Estimator(line, seed=0)
    est.add_measures("point", noise)
    assert est.run(max_samples=300).false_alarms > 1
    xy, _ = crossing_lines(0)
    for state in kanagen.find_structures(line, data={"point": xy}, seed=0):
        assert state.false_alarms < 1e-10
    path = tmp_path / "noise.csv"
    np.savetxt(path, noise, delimiter=",", header="x,y", comments="")
    spec = Path(__file__).resolve().parents[1] / "examples" / "line.yaml"
    out = CliRunner().invoke(main, ["fit", str(spec), str(path), "--json", "-"],
                             catch_exceptions=False)
    record = json.loads(out.stdout)
    assert record["false_alarms"] > 1
    assert "NOT more than chance" in out.stderr and out.exit_code == 1
    np.savetxt(path, xy, delimiter=",", header="x,y", comments="")  # two lines: one found
    out = CliRunner().invoke(main, ["fit", str(spec), str(path), "--json", "-"],
                             catch_exceptions=False)
    assert json.loads(out.stdout)["false_alarms"] < 1e-10 and out.exit_code == 0


def test_orsas_count_of_hypotheses():
    from kanagen.runtime.significance import hypotheses

    assert hypotheses(10, 2) == 45 * 10  # C(10, 2) samples, times 10 inlier counts
    assert hypotheses(1, 2) == 1.0  # fewer measures than a sample: one hypothesis
    assert hypotheses(10**6, 80) == np.inf  # beyond a float
