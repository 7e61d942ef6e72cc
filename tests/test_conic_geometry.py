"""Issue 20: the conic families report their geometry in human terms, with its uncertainty.

``examples/conic.yaml`` and ``examples/conic_lattice.yaml`` derive the centre, the semi-axes
``(a, b)`` (``a >= b``) and the angle (degrees, in [−90, 90]) of the ellipse and general conic
models, the centre and radius of the circle models. They are checked here against the truth
of noise-free points, against the independent ``ellipse_parameters`` of tests/test_conic.py
(its numerical Jacobian propagating the fit's covariance), against the classical standard
deviations of a circle fit, and for the way their standard deviations scale.
"""

from __future__ import annotations

import numpy as np
import pytest
from scenes import kasa_circle
from test_conic import ellipse_parameters, ellipse_points, taubin

import kanagen

#: The ellipse of benchmarks/conic_odr.py: centre, semi-axes, angle (degrees).
TRUTH = (330.0, 250.0, 220.0, 130.0, 25.0)
ELLIPSE_QUANTITIES = ("matrix", "discriminant", "centre", "semi_axes", "angle")
CIRCLE_QUANTITIES = ("matrix", "discriminant", "centre", "radius")


@pytest.fixture(scope="module")
def conic() -> kanagen.ModelFamily:
    return kanagen.load("conic")


@pytest.fixture(scope="module")
def lattice() -> kanagen.ModelFamily:
    return kanagen.load("conic_lattice")


def std(value: kanagen.DerivedValue) -> np.ndarray:
    """Standard deviations from the covariance's diagonal, shaped like the value."""
    return np.sqrt(np.diag(value.covariance)).reshape(np.shape(value.value))


def ellipse(n: int, sigma: float = 0.0, seed: int = 0, arc: float = 2 * np.pi) -> np.ndarray:
    cx, cy, a, b, angle = TRUTH
    t = np.linspace(0.0, arc, n, endpoint=arc < 2 * np.pi)
    xy = ellipse_points(cx, cy, a, b, np.radians(angle), t)
    return xy + np.random.default_rng(seed).normal(0.0, sigma, xy.shape) if sigma else xy


def circle(n: int, sigma: float = 0.0, seed: int = 0) -> np.ndarray:
    t = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    xy = np.column_stack([200.0 + 90.0 * np.cos(t), 150.0 + 90.0 * np.sin(t)])
    return xy + np.random.default_rng(seed).normal(0.0, sigma, xy.shape) if sigma else xy


def start(xy: np.ndarray) -> np.ndarray:
    """Taubin's estimate from the points moved by 0.5 px (exact points make its right-hand
    matrix singular): a start that is not the answer."""
    return taubin(xy + np.random.default_rng(1).normal(0.0, 0.5, xy.shape))


def fit_ellipse(fam, model, xy, sigma=1.0, sign=1.0):
    res = kanagen.fit(fam, model, data={"point": xy}, info={"point": 1 / sigma**2},
                      q0=sign * start(xy))
    assert res.success, res.status
    return res


def fit_circle(fam, xy, sigma=1.0):
    res = kanagen.fit(fam, "circle", data={"point": xy}, info={"point": 1 / sigma**2},
                      q0=kasa_circle(xy))
    assert res.success, res.status
    return res


def test_models_report_their_own_quantities(conic, lattice):
    for fam in (conic, lattice):
        assert fam.model("circle").derived == CIRCLE_QUANTITIES
        assert fam.model("conic").derived == ELLIPSE_QUANTITIES
    assert lattice.model("ellipse").derived == ELLIPSE_QUANTITIES
    assert lattice.model("line").derived == ("matrix", "discriminant")
    res = fit_ellipse(conic, "conic", ellipse(20))
    assert tuple(res.derived) == ELLIPSE_QUANTITIES


@pytest.mark.parametrize(("family", "model"), [("conic", "conic"), ("lattice", "ellipse"),
                                               ("lattice", "conic")])
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_noise_free_ellipse_gives_the_truth(request, family, model, sign):
    """Exact points: the truth to rounding, whatever the sign of the conic vector."""
    res = fit_ellipse(request.getfixturevalue(family), model, ellipse(40), sign=sign)
    d = res.derived
    np.testing.assert_allclose(d["centre"].value, TRUTH[:2], rtol=0, atol=1e-8)
    np.testing.assert_allclose(d["semi_axes"].value, TRUTH[2:4], rtol=0, atol=1e-8)
    np.testing.assert_allclose(d["angle"].value, TRUTH[4], rtol=0, atol=1e-9)
    for name in ("centre", "semi_axes", "angle"):
        assert d[name].value.shape == ((2,) if name != "angle" else ())
        assert np.all(np.isfinite(std(d[name]))) and np.all(std(d[name]) > 0)


def test_angle_range_and_axis_order(conic):
    """a >= b whichever axis is longer, the angle of the major axis folded into [−90, 90]
    (a vertical major axis is 90 or −90 by rounding)."""
    for angle in (-89.0, -40.0, 0.0, 60.0, 90.0, 115.0, 170.0):
        for a, b in ((220.0, 130.0), (130.0, 220.0)):
            t = np.linspace(0, 2 * np.pi, 30, endpoint=False)
            xy = ellipse_points(330.0, 250.0, a, b, np.radians(angle), t)
            d = fit_ellipse(conic, "conic", xy).derived
            major = angle if a > b else angle + 90.0
            got = float(d["angle"].value)
            assert -90.0 <= got <= 90.0
            assert (got - major + 90.0) % 180.0 - 90.0 == pytest.approx(0.0, abs=1e-8)
            if abs(abs(got) - 90.0) > 1e-6:
                assert got == pytest.approx((major + 90.0) % 180.0 - 90.0, abs=1e-8)
            np.testing.assert_allclose(d["semi_axes"].value, (220.0, 130.0), atol=1e-8)


def test_noisy_ellipse_agrees_with_an_independent_propagation(conic):
    """On noisy points: the derived values are ``ellipse_parameters`` of the estimate, and
    their covariance is that function's numerical Jacobian applied to the fit's covariance."""
    sigma = 1.0
    res = fit_ellipse(conic, "conic", ellipse(30, sigma, arc=np.pi), sigma)
    q, d = res.q, res.derived
    ref = np.array(ellipse_parameters(q))
    ref[4] = np.degrees(ref[4])
    got = np.r_[d["centre"].value, d["semi_axes"].value, d["angle"].value]
    np.testing.assert_allclose(got, ref, rtol=1e-10, atol=1e-9)
    J = np.empty((5, q.size))
    for i in range(q.size):
        h = np.zeros(q.size)
        h[i] = 1e-6 * max(abs(q[i]), 1e-3)
        plus, minus = np.array(ellipse_parameters(q + h)), np.array(ellipse_parameters(q - h))
        J[:, i] = (plus - minus) / (2 * h[i])
    J[4] = np.degrees(J[4])
    ref_std = np.sqrt(np.diag(J @ res.covariance @ J.T))
    got_std = np.r_[std(d["centre"]), std(d["semi_axes"]), std(d["angle"])]
    np.testing.assert_allclose(got_std, ref_std, rtol=1e-4)
    # the truth lies within a few standard deviations
    truth = np.array(TRUTH)
    assert np.all(np.abs(got - truth) < 5 * got_std), (got, got_std)


def test_ellipse_std_shrinks_with_more_points_and_less_noise(conic):
    def stds(n, sigma, noise=None):
        xy = ellipse(n, sigma if noise is None else noise)
        d = fit_ellipse(conic, "conic", xy, sigma).derived
        return np.r_[std(d["centre"]), std(d["semi_axes"]), std(d["angle"])]

    base = stds(40, 1.0)
    assert np.all(np.isfinite(base)) and np.all(base > 0)
    # four times the points: half the standard deviation (first order, all around)
    np.testing.assert_allclose(stds(160, 1.0) / base, 0.5, rtol=0.05)
    # a tenth of the noise: a tenth of the standard deviation
    np.testing.assert_allclose(stds(40, 0.1) / base, 0.1, rtol=0.05)
    # the noise-free fit's (sigma = 1 assumed) matches the noisy one to first order
    np.testing.assert_allclose(stds(40, 1.0, noise=0.0) / base, 1.0, rtol=0.05)


@pytest.mark.parametrize("family", ["conic", "lattice"])
def test_circle_centre_and_radius(request, family):
    """Exact points: the truth; the classical standard deviations of a geometric circle fit
    of ``n`` equally spaced points, ``sigma sqrt(2/n)`` per centre coordinate and
    ``sigma / sqrt(n)`` for the radius; noisy points: within a few of them."""
    fam = request.getfixturevalue(family)
    for n, sigma in ((40, 1.0), (160, 1.0), (40, 0.1)):
        d = fit_circle(fam, circle(n), sigma).derived
        assert set(d) == set(CIRCLE_QUANTITIES)
        np.testing.assert_allclose(d["centre"].value, (200.0, 150.0), rtol=0, atol=1e-8)
        np.testing.assert_allclose(d["radius"].value, 90.0, rtol=0, atol=1e-8)
        np.testing.assert_allclose(std(d["centre"]), sigma * np.sqrt(2 / n), rtol=1e-6)
        np.testing.assert_allclose(std(d["radius"]), sigma / np.sqrt(n), rtol=1e-6)
    d = fit_circle(fam, circle(60, 0.5, seed=3), 0.5).derived
    assert np.all(np.abs(d["centre"].value - (200.0, 150.0)) < 4 * std(d["centre"]))
    assert abs(d["radius"].value - 90.0) < 4 * std(d["radius"])


def test_hyperbola_semi_axes_and_asymptotes(conic):
    """A hyperbola has a centre, and semi-axes (a, b) with a along ``angle``: its asymptotes
    are at ±atan(b/a) from it."""
    cx, cy, a, b, angle = 300.0, 200.0, 120.0, 70.0, 30.0
    t = np.linspace(-1.2, 1.2, 15)
    c, s = np.cos(np.radians(angle)), np.sin(np.radians(angle))
    pts = []
    for branch in (1.0, -1.0):
        u, v = branch * a * np.cosh(t), b * np.sinh(t)
        pts.append(np.column_stack([cx + c * u - s * v, cy + s * u + c * v]))
    xy = np.vstack(pts)
    d = fit_ellipse(conic, "conic", xy).derived
    assert d["discriminant"].value < 0
    np.testing.assert_allclose(d["centre"].value, (cx, cy), atol=1e-8)
    np.testing.assert_allclose(d["semi_axes"].value, (a, b), atol=1e-8)
    assert d["angle"].value == pytest.approx(angle, abs=1e-9)
