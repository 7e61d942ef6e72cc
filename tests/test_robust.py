"""Robust estimation of one model (report §4): sampling, scoring, threshold, refinement."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import kanagen
from kanagen.runtime.refine import outlier_threshold
from kanagen.runtime.scoring import relevance, samples_for_confidence, scorer


def ellipse_with_outliers(seed, n_in=150, outlier_fraction=0.3, sigma=1.0):
    rng = np.random.default_rng(seed)
    t = rng.uniform(0.2, np.pi - 0.2, n_in)
    a, b, th, cx, cy = 180.0, 90.0, 0.4, 320.0, 240.0
    x = cx + a * np.cos(t) * np.cos(th) - b * np.sin(t) * np.sin(th)
    y = cy + a * np.cos(t) * np.sin(th) + b * np.sin(t) * np.cos(th)
    inliers = np.c_[x, y] + rng.normal(0, sigma, (n_in, 2))
    n_out = int(round(n_in * outlier_fraction / (1 - outlier_fraction)))
    outliers = rng.uniform([100, 50], [540, 430], (n_out, 2))
    xy = np.r_[inliers, outliers]
    truth = np.r_[np.ones(n_in, bool), np.zeros(n_out, bool)]
    order = rng.permutation(len(xy))
    return xy[order], truth[order], (a, b, th, cx, cy)


def f1(found: np.ndarray, truth: np.ndarray) -> float:
    tp = np.count_nonzero(found & truth)
    return 2 * tp / (np.count_nonzero(found) + np.count_nonzero(truth))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_conic_with_30_percent_outliers(seed):
    xy, truth, (a, b, th, cx, cy) = ellipse_with_outliers(seed)
    fam = kanagen.load("conic")
    est = kanagen.robust_fit(fam, "conic", data={"point": xy}, info={"point": 1.0}, scale=4.0,
                             max_samples=300, seed=seed)
    found = np.zeros(len(xy), bool)
    found[est.inliers["point"]] = True
    assert f1(found, truth) >= 0.95
    assert est.fit.success
    # an ellipse near the true one (a half arc leaves the centre a few pixels loose) ...
    M = est.fit.derived["matrix"].value
    assert est.fit.derived["discriminant"].value > 0
    centre = np.linalg.solve(M[:2, :2], -M[:2, 2])
    np.testing.assert_allclose(centre, [cx, cy], atol=15.0)
    # ... that explains its inliers as well as the fit on the true inliers explains those
    oracle = kanagen.fit(fam, "conic", data={"point": xy[truth]}, q0=est.q)
    assert est.fit.normalized_cost <= 1.25 * oracle.normalized_cost
    assert est.samples <= 300 and est.history[-1][0] == est.samples
    scores = [s for _, s in est.history]
    assert scores == sorted(scores)  # the best-relevance curve never goes down


def test_same_seed_same_result_bit_for_bit():
    xy, _, _ = ellipse_with_outliers(5)
    fam = kanagen.load("conic")
    runs = [kanagen.robust_fit(fam, "conic", data={"point": xy}, scale=4.0, max_samples=80,
                               seed=11) for _ in range(2)]
    assert np.array_equal(runs[0].q, runs[1].q)
    assert np.array_equal(runs[0].inliers["point"], runs[1].inliers["point"])
    other = kanagen.robust_fit(fam, "conic", data={"point": xy}, scale=4.0, max_samples=80,
                               seed=12)
    assert other.history != runs[0].history


def test_degenerate_samples_are_counted_not_raised():
    fam = kanagen.load("line")
    xy = np.repeat([[0.0, 1.0], [1.0, 3.0]], 20, axis=0)  # only two distinct points
    xy[::2] += 1e-9  # the pairs drawn from one cluster are (numerically) degenerate
    est = kanagen.robust_fit(fam, "line", data={"point": xy}, scale=4.0, max_samples=60,
                             seed=0)
    assert est.degenerate > 0
    assert est.params["a"] == pytest.approx(2.0, abs=1e-6)


def test_stopping_rules():
    xy, _, _ = ellipse_with_outliers(3)
    fam = kanagen.load("conic")
    common = dict(data={"point": xy}, scale=4.0, seed=0)
    by_confidence = kanagen.robust_fit(fam, "conic", confidence=0.99, inlier_ratio=0.7,
                                       max_samples=10_000, **common)
    assert by_confidence.samples == samples_for_confidence(0.99, 0.7, 5)
    no_gain = kanagen.robust_fit(fam, "conic", no_gain=5, max_samples=10_000, **common)
    assert no_gain.samples < 10_000
    last_gain = max(i for i, (s, b) in enumerate(no_gain.history)
                    if i == 0 or b > no_gain.history[i - 1][1])
    assert no_gain.samples - (last_gain + 1) == 5
    by_callable = kanagen.robust_fit(fam, "conic", stop=lambda h: len(h) >= 7, **common)
    assert by_callable.samples == 7


def test_scorers_and_threshold():
    errors = np.array([0.0, 1.0, 2.0, 10.0])
    assert relevance(errors, 4.0) == pytest.approx((1 + 0.5 + 0.0) / 4)
    assert scorer("ransac")(errors, 4.0) == 0.75
    assert scorer("trimmed")(errors, 4.0) == pytest.approx(-1.5 / 4)
    assert scorer(lambda e, s: 42.0)(errors, 1.0) == 42.0
    with pytest.raises(ValueError, match="unknown scorer"):
        scorer("median")
    rng = np.random.default_rng(0)
    inliers = rng.chisquare(1, 300)
    for outliers in (rng.uniform(20, 100, 100), rng.uniform(0, 300, 100)):
        t = outlier_threshold(np.r_[inliers, outliers], 4.0)
        assert 4.0 < t < 20.0
        assert np.mean(inliers > t) < 0.05
    with pytest.raises(ValueError, match="25–50 %"):
        outlier_threshold(inliers, 4.0, window=0.1)


@given(st.lists(st.floats(0.0, 1e4, allow_nan=False), min_size=1, max_size=400),
       st.sampled_from([0.37, 1.0, 4.0, 9.0]))
@settings(max_examples=200, deadline=None)
def test_threshold_histogram_counts_as_numpy(errors, scale):
    """outlier_threshold's own binning (engine/histogram.py) gives np.histogram's counts
    (values on the edges included: the bins' edges in units of L*/20), the clipped tail's
    bin emptied, its first bins reflected before them; non-finite errors not counted."""
    from kanagen.runtime.engine.histogram import reflected_counts
    from kanagen.runtime.refine import _histogram_layout

    top = 20.0 * scale
    e = np.clip(np.r_[errors, np.arange(0, 401) * scale / 20.0], 0.0, top)
    edges, half, _ = _histogram_layout(scale, 0.35)
    expected = np.histogram(e, bins=400, range=(0.0, top + 1e-12 * top))[0]
    expected[-1] = 0
    got = reflected_counts(np.r_[e, np.inf, np.nan, -np.inf], top, edges, half)
    np.testing.assert_array_equal(got, np.r_[expected[half - 1::-1], expected])


@pytest.mark.parametrize("spec", ["conic_lattice", "two_view", "line", "conic"])
def test_free_dof_of_a_model_is_its_generic_rank(spec):
    """ModelFamily.free_dof (once per model) is generic_free_dof at any point of the model."""
    from kanagen.runtime.minimal import generic_free_dof

    fam = kanagen.load(spec)
    k = fam.constant_vector()
    rng = np.random.default_rng(0)
    for model in fam.models:
        for _ in range(3):
            q = fam.with_slacks(fam.q0 + rng.normal(0, 0.5, fam.n), k, model)
            assert fam.free_dof(model) == generic_free_dof(lambda x, m=model: fam.c0(m, x, k)[1], q)


def test_a_refinement_makes_each_subset_once():
    """The rounds, the deletion tests and the verification fit the same inliers several
    times: :meth:`Refinement.sample` makes the problem on a set of rows once (the subset
    and its engine arrays are only read), a bounded number of them."""
    from kanagen.runtime import refine
    from kanagen.runtime.fit import make_problem

    fam = kanagen.load("conic_lattice")
    rng = np.random.default_rng(0)
    problem = make_problem(fam, "ellipse", {"point": rng.normal(size=(40, 2))})
    ref = refine.Refinement(fam, "ellipse", problem, 1.0, relevance, (1,), 5)
    rows = (np.arange(0, 40, 2),)
    first = ref.sample(rows)
    assert ref.sample((rows[0].copy(),)) is first
    assert ref.sample((np.arange(1, 40, 2),)) is not first
    np.testing.assert_array_equal(first.channels[0].X, problem.channels[0].X[rows[0]])
    for k in range(refine._SAMPLES + 5):
        ref.sample((np.arange(k % 7, 40 - k // 7),))
    assert len(ref._samples) <= refine._SAMPLES


@settings(max_examples=300, deadline=None)
@given(st.lists(st.integers(0, 60), max_size=40), st.lists(st.integers(0, 80), max_size=30),
       st.booleans())
def test_the_rounds_set_difference_is_numpys(x, y, increasing):
    # Refinement's measures of a less those of b: np.setdiff1d's result, its fast path for
    # increasing index arrays (the rounds' inliers) by a table of b's indices included
    from kanagen.runtime.refine import _less, _setdiff

    a = np.unique(np.array(x, dtype=np.int64)) if increasing else np.array(x, dtype=np.int64)
    b = np.array(y, dtype=np.intp)
    out, ref = _setdiff(a, b), np.setdiff1d(a, b)
    assert out.dtype == ref.dtype and np.array_equal(out, ref)
    (pair,) = _less((a,), (b,))
    assert np.array_equal(pair, ref)
