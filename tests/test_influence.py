"""Deletion drops and leverages (runtime/influence.py) against refits without the measure
and the hat matrix, and the final refinement's use of them (Refinement._pruned,
Refinement._cross_checked): an outlier that pulled a fit onto itself is taken out of the
inliers."""

from __future__ import annotations

import numpy as np
import pytest

import kanagen
from kanagen.runtime.fit import fit_problem, make_problem
from kanagen.runtime.influence import Influence, deletion_drops
from kanagen.scenes import calibrated_scene


def _line_data(seed: int = 0):
    rng = np.random.default_rng(seed)
    x = np.linspace(0.0, 10.0, 20)
    y = 2.0 * x + 1.0 + rng.normal(0.0, 0.1, x.size)
    x[-1], y[-1] = 30.0, 40.0  # far along x and off the line: it pulls the fit
    return np.c_[x, y]


def _fall(fam, problem, fit, i: int) -> float:
    """``Σ ‖m̃ − m‖²_Q`` of the fit less that of the fit without measure ``i``."""
    rows = np.delete(np.arange(problem.channels[0].size), i)
    without = fit_problem(fam, "line", problem.subset((rows,)), q_start=fit.q)
    assert without.success
    return 2.0 * (fit.cost - without.cost)


def test_the_drop_is_the_fall_of_the_cost_exactly_for_a_linear_problem():
    fam = kanagen.load("line")
    problem = make_problem(fam, "line", {"point": _line_data()}, {"point": 1 / 0.1**2},
                           exact={"point": {"x": np.ones(20, dtype=bool)}})
    fit = fit_problem(fam, "line", problem)
    drops = deletion_drops(problem, fit)[0]
    for i in (0, 7, 19):
        assert drops[i] == pytest.approx(_fall(fam, problem, fit, i), rel=1e-8)
    # the pulling point: its drop is several times its error
    x, y = _line_data().T
    errors = ((y - fit.params["a"] * x - fit.params["b"]) / 0.1) ** 2
    assert drops[19] > 4 * errors[19]  # its leverage: 1 − h = 0.2
    assert int(np.argmax(drops)) == 19


def test_the_drop_is_the_fall_of_the_cost_to_first_order_with_errors_in_both():
    fam = kanagen.load("line")
    problem = make_problem(fam, "line", {"point": _line_data(1)}, {"point": 1 / 0.1**2})
    fit = fit_problem(fam, "line", problem)
    drops = deletion_drops(problem, fit)[0]
    for i in (0, 7, 19):
        assert drops[i] == pytest.approx(_fall(fam, problem, fit, i), rel=0.05)


def test_leverages_are_the_hat_matrix_diagonal_for_a_linear_problem():
    fam = kanagen.load("line")
    data = _line_data()
    problem = make_problem(fam, "line", {"point": data}, {"point": 1 / 0.1**2},
                           exact={"point": {"x": np.ones(20, dtype=bool)}})
    fit = fit_problem(fam, "line", problem)
    levels = Influence(problem, fit).leverages()[0]
    X = np.c_[data[:, 0], np.ones(20)]
    hat = np.diag(X @ np.linalg.solve(X.T @ X, X.T))
    np.testing.assert_allclose(levels, hat, rtol=1e-8)
    assert levels.sum() == pytest.approx(2.0)  # the parameter's degrees of freedom


def test_a_fit_without_covariance_gives_no_drops():
    fam = kanagen.load("line")
    problem = make_problem(fam, "line", {"point": _line_data()}, {"point": 1 / 0.1**2})
    fit = fit_problem(fam, "line", problem)
    from dataclasses import replace
    blind = replace(fit, covariance=np.full_like(fit.covariance, np.nan))
    assert np.isnan(deletion_drops(problem, blind)[0]).all()


def _calibrated_search(outliers: float, seed: int):
    """A scene of benchmarks/calibrated.py (general motion) and the Estimator's choice on it
    at the defaults (the general model)."""
    fam = kanagen.load("two_view_calibrated")
    scene = calibrated_scene("general", n=200, outliers=outliers, sigma=0.5, seed=seed)
    est = kanagen.Estimator(fam, seed=seed, constants=scene.constants)
    est.add_measures("match", scene.data, info=1.0 / scene.sigma**2)
    best = est.run()
    assert best.model == "general"
    return scene, best


def test_an_outlier_that_pulled_the_fit_is_not_an_inlier():
    """Calibrated general motion, 60 % outliers (benchmarks/calibrated.py's scene 56010):
    match 460 is 270 error units off the fit on the true inliers, but the fit that takes it
    in lays it on its epipolar line (error 0.9) and turns the direction by 1.2°."""
    scene, best = _calibrated_search(0.6, 56010)
    assert 460 not in set(np.asarray(best.inliers).tolist())
    assert scene.inliers[np.asarray(best.inliers)].sum() == scene.inliers.sum()


def test_an_outlier_of_high_leverage_is_judged_by_the_fit_of_the_others():
    """Calibrated general motion, 30 % outliers (benchmarks/calibrated.py's scene 53015):
    match 231 is 14.7 error units off the truth, but the fit that takes it in lays it at
    3.4 and turns the direction by 0.35°; its deletion drop (8.6) stays under the threshold
    (10.8) — first order misses how far the fit moved. Its leverage is ten times the
    mean: left out, the fit of the others puts it above the threshold, and it stays out."""
    scene, best = _calibrated_search(0.3, 53015)
    inliers = np.asarray(best.inliers)
    assert 231 not in set(inliers.tolist())
    assert np.array_equal(np.sort(inliers), np.flatnonzero(scene.inliers))


def test_outliers_of_high_leverage_hidden_behind_others_are_found_too():
    """Calibrated general motion, 60 % outliers (benchmarks/calibrated.py's scene 56004):
    matches 46 and 50 are 42 and 340 error units off the fit on the true inliers, yet at
    the fit they sit at 1.2 and 0.2 with leverages 0.74 and 0.82 — hidden, while other
    outliers of high leverage held the fit, behind leverages no higher than an inlier's.
    The cross-check is repeated until it takes nothing out: they are out, and the direction
    is within 0.4° of the truth (0.58° with one cross-check)."""
    scene, best = _calibrated_search(0.6, 56004)
    inliers = set(np.asarray(best.inliers).tolist())
    assert not inliers & {46, 50}
    assert scene.inliers[np.asarray(best.inliers)].sum() == scene.inliers.sum()
    p = best.params
    t = np.array([p["tx"], p["ty"], p["tz"]])
    cos = t @ scene.t / np.linalg.norm(t) / np.linalg.norm(scene.t)
    assert np.degrees(np.arccos(min(cos, 1.0))) < 0.4


def test_the_cross_check_stops_when_the_inliers_grow_back():
    """The conic-lattice benchmark's hyperbola scene 3 (296 points, 30 % outliers): a circle
    fitted to the hyperbola's arc has no settled inliers — repeating the cross-check took
    out one measure each time and the settling rounds took in ten, until the circle no
    longer beat the line and the lattice stopped at the line. The repeat stops once the
    rounds bring back as many measures as the check took out: the conic is found."""
    from scenes import LATTICE_MODEL, arc

    fam = kanagen.load("conic_lattice")
    xy, truth = arc("hyperbola", 3291, n=296, outliers=0.3, radius=144.24626880115866)
    est = kanagen.Estimator(fam, seed=3291)
    est.add_measures("point", xy, info=1.0)
    assert est.run(max_samples=5000).model == LATTICE_MODEL["hyperbola"]


def _reference_joints(influence: Influence, groups) -> np.ndarray:
    """:meth:`Influence.joints` group by group: each group's rows joined, its drop
    ``r̄ᵀ (I − C̄ Σ C̄ᵀ)⁻¹ r̄`` by LAPACK's solve, per equation kept."""
    out = []
    for measures in groups:
        A = np.concatenate([influence.parts[c][0][i] for c, i in measures])
        r = np.concatenate([influence.parts[c][1][i] for c, i in measures])
        p = sum(int(influence.parts[c][2][i]) for c, i in measures) / len(measures)
        K = np.eye(A.shape[0]) - A @ influence.S @ A.T
        out.append(r @ np.linalg.solve(K, r) / p if np.linalg.det(K) > 1e-12 else np.inf)
    return np.array(out)


def test_joint_drops_of_groups_gathered_at_once_are_each_groups_own():
    # the stack of pairs of one channel gathered by one index, and the drops of one measure
    # (one equation: the solve a division), give each group's own numbers
    fam = kanagen.load("line")
    problem = make_problem(fam, "line", {"point": _line_data(2)}, {"point": 1 / 0.1**2})
    fit = fit_problem(fam, "line", problem)
    influence = Influence(problem, fit)
    pairs = [[(0, a), (0, b)] for a, b in ((19, 3), (0, 1), (5, 12), (7, 7))]
    np.testing.assert_allclose(influence.joints(pairs), _reference_joints(influence, pairs),
                               rtol=1e-12)
    singles = [[(0, i)] for i in range(20)]
    np.testing.assert_allclose(influence.joints(singles),
                               _reference_joints(influence, singles), rtol=1e-12)
    np.testing.assert_allclose(influence.drops()[0], influence.joints(singles), rtol=1e-12)
    mixed = [[(0, 1)], [(0, 2), (0, 3)]]  # groups of several sizes: stacked by shape
    np.testing.assert_allclose(influence.joints(mixed), _reference_joints(influence, mixed),
                               rtol=1e-12)


def test_the_drops_read_the_fit_as_its_kernels_evaluate_it():
    # the whitened rows the drops use are those of the engine's linearisation at the fit's
    # point — the fit's own numbers (its row kernels), not the family's vectorised functions
    # (two views: the two differ in their last bits)
    from kanagen.runtime.engine.data import arrays, pack_measures
    from kanagen.runtime.engine.points import evaluate_flat
    from kanagen.runtime.iterate import evaluated, unpack_point
    from kanagen.runtime.projector import linearise
    from kanagen.scenes import two_view_scene

    scene = two_view_scene("general", n=60, outliers=0.0, sigma=0.5, seed=4)
    # the product's backend (CasADi's compiled functions; the suite's default, NumPy's, runs
    # the same expressions as the row kernels)
    fam = kanagen.load("two_view", backend="compiled")
    problem = make_problem(fam, "general", {"match": scene.data}, {"match": 4.0},
                           scene.params(), constants=scene.constants)
    fit = fit_problem(fam, "general", problem)
    assert fit.success
    A = arrays(problem)
    x = unpack_point(A, *evaluate_flat(A, fit.q.copy(), pack_measures(
        A, (fit.measures["match"],))))[0]
    Cbar, rbar, _ = linearise(problem, x).whitened[0]
    assert np.array_equal(evaluated(problem, fit.q, (fit.measures["match"],)).evals[0][1],
                          x.evals[0][1])
    influence = Influence(problem, fit)
    assert np.array_equal(influence.parts[0][0], Cbar)
    assert np.array_equal(influence.parts[0][1], rbar)


def test_a_subset_is_the_problem_replaced_on_its_measures():
    # Problem.subset makes its record without dataclasses.replace's __init__: the same
    # fields (the very objects, the channels cut), nothing cached carried over
    from dataclasses import fields, replace

    fam = kanagen.load("line")
    problem = make_problem(fam, "line", {"point": _line_data()}, {"point": 1 / 0.1**2})
    fit_problem(fam, "line", problem)  # its engine arrays made (cached on it)
    rows = (np.array([0, 3, 4, 19]),)
    sub = problem.subset(rows)
    ref = replace(problem, channels=tuple(ch.subset(r) for ch, r in
                                          zip(problem.channels, rows, strict=True)))
    assert type(sub) is type(ref)
    for f in fields(ref):
        if f.name == "channels":
            assert np.array_equal(sub.channels[0].X, ref.channels[0].X)
            assert np.array_equal(sub.channels[0].m, ref.channels[0].m)
        else:
            assert getattr(sub, f.name) is getattr(ref, f.name)
    assert "_arrays" not in sub.__dict__ and "_subset_of" in sub.__dict__
    with pytest.raises(AttributeError):
        sub.q0 = None  # still frozen
