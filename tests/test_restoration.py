"""A measure's restoration onto its equations for a fixed parameter (runtime/restoration.py):
where the projector's steps leave it off, the descent along the manifold ends at its nearest
point, and a point where the equations' slope is infinite is not taken for one on them."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import minimize_scalar
from test_hostile_inputs import ROOT  # y = b sqrt(x)

import kanagen
from kanagen.runtime import fit as fitting
from kanagen.runtime.engine import measures
from kanagen.runtime.engine.data import arrays
from kanagen.runtime.restoration import restore_measures

PEAK = """
name: peak
parameter: {a: 1.0, s: 1.0}
channels:
  pt:
    components: [x, y]
    equations: ["y - a*exp(-x**2/(2*s**2))"]
models:
  m: {}
"""



def _nearest(observed, info):
    """The least ``info``-weighted squared distance from ``observed`` to ``y = exp(−x²/2)``:
    a dense grid, then a bounded refinement around its best node."""
    def gap(t):
        return info[0] * (t - observed[0]) ** 2 + info[1] * (np.exp(-t**2 / 2) - observed[1]) ** 2

    grid = np.linspace(-12.0, 12.0, 200_001)
    k = int(np.argmin(gap(grid)))
    return minimize_scalar(gap, bounds=(grid[k] - 1e-3, grid[k] + 1e-3), method="bounded",
                           options={"xatol": 1e-13}).fun


@pytest.mark.parametrize("observed, info", [((0.5, -0.2), (1.0, 1e4)),
                                            ((0.3, -0.05), (1.0, 1e6)),
                                            ((0.2, -0.5), (4.0, 1e3))])
def test_a_measure_under_a_peak_reaches_its_nearest_point(observed, info):
    """Below a Gaussian's tail, with an ordinate far more precise than the abscissa: no
    abscissa reaches the observed ordinate, the projector leaves the measure off, and the
    descent along the curve must run far (x from 0.5 to 3.9). Its steps now carry the
    curve's curvature (the SQP step of the nearest point): they end at the nearest point to
    rounding. The tangent-plane steps alone stopped at their cap of 12 short of it (3.7e-10
    relative in the distance for the first measure)."""
    fam = kanagen.load_text(PEAK)
    data = np.array([observed, [0.0, 1.0], [1.0, 0.6]])
    q = np.array([1.0, 1.0])
    problem = fitting.make_problem(fam, "m", {"pt": data}, {"pt": np.diag(info)}, q, None, None)
    with np.errstate(all="ignore"):
        x, _ = restore_measures(problem, q, (data.copy(),))
    moved = x.mt[0][0]
    assert moved[1] - np.exp(-moved[0] ** 2 / 2) == pytest.approx(0.0, abs=1e-12)
    distance = (moved - observed) @ np.diag(info) @ (moved - observed)
    assert distance == pytest.approx(_nearest(observed, info), rel=1e-12)


def test_an_infinite_slope_is_not_on_the_equations():
    """``(0, 0.5)`` is not on ``y = sqrt(x)``, but there ``∂c/∂x`` is infinite: the whitened
    violation ``c² / (D Q⁺ Dᵀ)`` was 0 and the measure passed for restored — a fit of such
    data reported a cost of 0 at a point off its equations. The violation is infinite now:
    the measure is reported off its equations."""
    fam = kanagen.load_text(ROOT)
    data = np.array([[0.0, 0.5], [1.0, 1.0], [4.0, 2.0]])
    problem = fitting.make_problem(fam, "m", {"pt": data}, {"pt": 1.0}, np.array([1.0]),
                                   None, None)
    A = arrays(problem)
    with np.errstate(all="ignore"):
        _, violations, *_ = measures.project_all(A, np.array([1.0]), A.m.copy(), 30, 1e-12)
    assert violations[0] == np.inf and violations[1] == 0.0 and violations[2] == 0.0
    res = kanagen.fit(fam, "m", data={"pt": data})
    assert not res.success and res.cost > 0.0
