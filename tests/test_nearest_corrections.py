"""A converged fit's corrected measures are the nearest points of their equations, also where
a measure's restoration from its observed value stops at a local, farther one
(runtime/engine/points.py: ``nearer_points``, ``neighbours_corrected``).

A dose-response curve ``response = top·dose^n / (ec50^n + dose^n)`` with zero-dose controls:
at ``dose = 0`` the curve is flat (``n > 1``), so a control's projection from its observed
value moves its response only, to the origin — a local minimum of its distance to the curve.
With a response of +0.9, the curve's point at dose 0.31 is nearer. Two of three starts
converged there and reported a minimum of cost 17.20; the true minimum is 16.85.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares, minimize_scalar

import kanagen

SPEC = """
name: dose_response_nearest
parameter: {top: 1.0, ec50: 1.0, n: 1.0}
channels:
  obs:
    components: [dose, response]
    equations:
      - response - top*dose**n/(ec50**n + dose**n)
models:
  hyperbolic:
    constraints: [n - 1]
    alternatives: [hill]
  hill:
    constraints: []
"""


def _data():
    rng = np.random.default_rng(7)
    dose = np.repeat([0, 0.1, 0.3, 1, 3, 10, 30], 3).astype(float)
    response = 100 * dose**1.8 / (2.0**1.8 + dose**1.8) + rng.normal(0, 3, dose.size)
    return np.c_[dose * np.exp(rng.normal(0, 0.02, dose.size)), response]


def _curve(q, dose):
    top, ec50, n = q
    return top * dose**n / (ec50**n + dose**n)


def _nearest_on_curve(q, point):
    """The squared distance from ``point`` to the curve (dose ≥ 0): a grid, then bounded
    refinement around its best node."""
    grid = np.r_[0.0, np.geomspace(1e-6, 60, 4000)]
    gaps = (grid - point[0]) ** 2 + (_curve(q, grid) - point[1]) ** 2
    k = int(np.argmin(gaps))
    lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, grid.size - 1)]
    fine = minimize_scalar(lambda t: (t - point[0]) ** 2 + (_curve(q, t) - point[1]) ** 2,
                           bounds=(lo, hi), method="bounded", options={"xatol": 1e-12})
    return min(gaps[k], fine.fun)


@pytest.mark.parametrize("start", [(100.0, 2.0, 1.8), (50.0, 1.0, 1.0), (1.0, 1.0, 1.0)])
def test_zero_dose_controls_reach_their_nearest_points(start):
    data = _data()
    fit = kanagen.fit(kanagen.load_text(SPEC), "hill", data={"obs": data},
                      q0=np.array(start))
    assert fit.success, fit.message
    corrected = fit.measures["obs"]
    assert np.all(corrected[:, 0] >= 0)
    for observed, moved in zip(data, corrected, strict=True):
        gap = np.sum((moved - observed) ** 2)
        assert gap <= _nearest_on_curve(fit.q, observed) + 1e-7 * (1 + gap)
    # the same minimum from every start, and a dense solve over (q, corrections) from it
    # finds nothing lower
    assert fit.cost == pytest.approx(16.8500825, rel=1e-7)

    def residuals(z):
        dose = np.abs(data[:, 0] + z[3:])
        return np.r_[z[3:], data[:, 1] - _curve(z[:3], dose)]

    dense = least_squares(residuals, np.r_[fit.q, corrected[:, 0] - data[:, 0]],
                          method="lm", xtol=1e-15, ftol=1e-15)
    assert dense.cost == pytest.approx(fit.cost, rel=1e-8)
    np.testing.assert_allclose(dense.x[:3], fit.q, rtol=1e-5)
