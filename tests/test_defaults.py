"""Defaults that fit the data (issue 18): L* from a χ² quantile of the equations per measure,
adaptive sample budgets, and a progress total that follows them."""

from __future__ import annotations

import numpy as np
import pytest
from scenes import arc
from scipy.stats import chi2

import kanagen
from kanagen.runtime.scoring import SCALE_QUANTILE, default_scale
from kanagen.scenes import two_view_scene


@pytest.fixture(scope="module")
def lattice():
    return kanagen.load("conic_lattice")


@pytest.fixture(scope="module")
def two_view():
    return kanagen.load("two_view")


def test_default_scale_is_the_documented_quantile():
    assert SCALE_QUANTILE == 0.999
    assert default_scale(1) == pytest.approx(chi2.ppf(0.999, 1))
    assert default_scale(2) == pytest.approx(chi2.ppf(0.999, 2) / 2)
    assert default_scale(1) == pytest.approx(10.8276, abs=1e-4)
    assert default_scale(2) == pytest.approx(6.9078, abs=1e-4)
    assert default_scale(1, 0.95) == pytest.approx(3.8415, abs=1e-4)
    with pytest.raises(ValueError):
        default_scale(0)


def test_the_chi_square_law_is_scipy_stats_bit_for_bit():
    """runtime/chisquare.py computes what ``scipy.stats.chi2`` does, from scipy.special
    alone (importing scipy.stats costs a first search half a second): the same numbers."""
    from kanagen.runtime import chisquare

    rng = np.random.default_rng(0)
    for dof in [*range(1, 41), 100, 1001]:
        for p in (0.999, 0.99, 0.95, 0.5, 1e-3, 0.9999):
            assert chisquare.quantile(p, dof) == float(chi2.ppf(p, dof))
        for x in np.r_[rng.uniform(0.0, 3.0 * dof, 20), 0.0, 1e6]:
            assert chisquare.tail(x, dof) == float(chi2.sf(x, dof))
    assert default_scale(3) == float(chi2.ppf(SCALE_QUANTILE, 3) / 3)


def test_each_model_takes_the_quantile_of_its_equations(lattice, two_view):
    """A point on a conic is one equation (p = 1); a match under a homography two (p = 2),
    under a fundamental matrix one."""
    xy, _ = arc("circle", 3, n=60, outliers=0.2)
    est = kanagen.Estimator(lattice, model="circle", seed=0)
    est.add_measures("point", xy, info=1.0)
    est.run(max_samples=30)
    assert est.scale is None
    assert est.scales == {"circle": pytest.approx(chi2.ppf(0.999, 1))}
    scene = two_view_scene("planar", n=60, outliers=0.2, seed=1)
    for model, p in (("planar", 2), ("general", 1)):
        est = kanagen.Estimator(two_view, model=model, seed=0, constants=scene.constants)
        est.add_measures("match", scene.data, info=1.0 / scene.sigma**2)
        est.run(max_samples=5)
        assert est.scales[model] == pytest.approx(chi2.ppf(0.999, p) / p)
    # an explicit scale stays an override
    est = kanagen.Estimator(lattice, model="circle", seed=0, scale=4.0)
    est.add_measures("point", xy, info=1.0)
    est.run(max_samples=30)
    assert est.scale == 4.0 and est.scales == {"circle": 4.0}


def test_robust_fit_says_its_scale(lattice):
    xy, _ = arc("circle", 5, n=80, outliers=0.2)
    res = kanagen.robust_fit(lattice, "circle", data={"point": xy}, info={"point": 1.0})
    assert res.scale == pytest.approx(default_scale(1))
    res = kanagen.robust_fit(lattice, "circle", data={"point": xy}, info={"point": 1.0},
                             scale=3.0)
    assert res.scale == 3.0


def test_clean_circle_points_are_inliers_at_the_default_scale(lattice):
    """σ = 1 px and info = 1: every clean point is an inlier at the default L*; at the old
    default L* = 1 the same points lose some to the outliers."""
    all_in, lost_at_one = 0, 0
    for seed in range(10):
        xy, _ = arc("circle", 100 + seed, n=200, outliers=0.0, sigma=1.0)
        for scale in (None, 1.0):
            est = kanagen.Estimator(lattice, seed=0, **({} if scale is None else
                                                        {"scale": scale}))
            est.add_measures("point", xy, info=1.0)
            best = est.run(max_samples=2000)
            assert best.model == "circle"
            if scale is None:
                all_in += best.outliers.size == 0
                assert best.outliers.size <= 1  # a 3.3 σ point, now and then
            else:
                lost_at_one += best.outliers.size > 0
    assert all_in >= 9
    assert lost_at_one >= 8


def _samples(lattice, outliers: float, adaptive: bool) -> int:
    xy, _ = arc("circle", 12, n=150, outliers=outliers)
    est = kanagen.Estimator(lattice, model="circle", seed=0, adaptive=adaptive)
    est.add_measures("point", xy, info=1.0)
    best = est.run(max_samples=5000)
    assert best.model == "circle" and est.status == "done"
    return est.samples


def test_adaptive_budget_follows_the_inlier_ratio(lattice):
    """Eq. 25 at an assumed half of inliers draws 35 samples of 3 points whatever the data;
    the adaptive budget draws fewer on easy data (10 % outliers) and more on hard data
    (60 %)."""
    fixed_easy, fixed_hard = _samples(lattice, 0.1, False), _samples(lattice, 0.6, False)
    assert fixed_easy == fixed_hard == 35
    assert _samples(lattice, 0.1, True) < fixed_easy
    assert _samples(lattice, 0.6, True) > fixed_hard


def test_adaptive_budget_is_deterministic(lattice):
    xy, _ = arc("ellipse", 4, n=150, outliers=0.5)
    runs = []
    for _ in range(2):
        est = kanagen.Estimator(lattice, seed=3)
        est.add_measures("point", xy, info=1.0)
        best = est.run(max_samples=3000)
        runs.append((best.model, est.samples, best.inliers.tolist()))
    assert runs[0] == runs[1]


def test_planned_total_moves_as_the_budget_adapts(lattice):
    """The progress total: at first the assumed budgets; on hard data it grows once the
    best estimate shows how few inliers there are; done, it is the samples drawn."""
    xy, _ = arc("circle", 12, n=150, outliers=0.6)
    est = kanagen.Estimator(lattice, model="circle", seed=0)
    est.add_measures("point", xy, info=1.0)
    first = est.planned
    seen = {first}
    while est.step():
        seen.add(est.planned)
    assert len(seen) > 2
    assert max(seen) > first
    assert est.planned == est.samples


def test_cli_progress_total_follows_the_plan(lattice):
    """What ``kanagen fit``'s bar shows after each sample: the samples planned (not
    ``--max-samples``), moving as the budget adapts, full at the end."""
    from kanagen.cli import planned_total
    from kanagen.fitjob import search

    xy, _ = arc("circle", 12, n=150, outliers=0.6)
    est = kanagen.Estimator(lattice, model="circle", seed=0)
    est.add_measures("point", xy, info=1.0)
    totals = []
    drawn = search(est, 2000, lambda e: totals.append(planned_total(e, 2000, e.samples)))
    assert drawn == est.samples == len(totals) < 2000
    assert len(set(totals)) > 1
    assert all(t <= 2000 for t in totals) and totals[-1] == est.samples
    assert planned_total(est, 10, est.samples) == est.samples  # never below what is drawn


@pytest.mark.parametrize("seed", [0, 7, 9])
def test_a_conic_that_is_an_ellipse_goes_to_the_ellipse(lattice, seed):
    """Seed stability (issue 18): on this scene the ellipse's own samples stopped on part of
    the arc for seeds 7 and 9 (cost 216 on 192 inliers) while the conic's found the whole
    ellipse (98.5 on 211) and was chosen. Its estimate lies in the ellipse model: refined
    there it replaces the ellipse's state, and every seed chooses the ellipse with the same
    estimate."""
    from scenes import LATTICE_MODEL

    j = list(LATTICE_MODEL).index("ellipse")
    xy, _ = arc("ellipse", 7000 + 97 * j, n=200, outliers=0.3)
    est = kanagen.Estimator(lattice, seed=seed)
    est.add_measures("point", xy, info=1.0)
    best = est.run(max_samples=5000)
    assert best.model == "ellipse"
    assert best.cost == pytest.approx(98.4766, rel=1e-4)
    assert best.inliers.size == 201
