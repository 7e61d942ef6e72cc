"""A measure's restoration onto its equations for a fixed parameter (runtime/restoration.py):
where the projector's steps leave it off, the descent along the manifold ends at its nearest
point, and a point where the equations' slope is infinite is not taken for one on them."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
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
                                            ((0.2, -0.5), (4.0, 1e3)),
                                            ((1.5, 1.3), (1.0, 1e4))])
def test_a_measure_off_a_peak_reaches_its_nearest_point(observed, info):
    """Below a Gaussian's tail, with an ordinate far more precise than the abscissa: no
    abscissa reaches the observed ordinate, the projector leaves the measure off, and the
    descent along the curve must run far (x from 0.5 to 3.9). Its steps now carry the
    curve's curvature (the SQP step of the nearest point): they end at the nearest point to
    rounding. The tangent-plane steps alone stopped at their cap of 12 short of it (3.7e-10
    relative in the distance for the first measure). Above the peak (the last), Newton's
    steps onto the curve in the measure's metric, and in its channel's largest variances,
    move the abscissa to the peak and stop short: the measure was left 0.3 off the curve.
    In the metric of the data's extent they move the ordinate too."""
    fam = kanagen.load_text(PEAK)
    data = np.array([observed, [0.0, 1.0], [1.0, 0.6]])
    q = np.array([1.0, 1.0])
    problem = fitting.make_problem(fam, "m", {"pt": data}, {"pt": np.diag(info)}, q, None, None)
    with np.errstate(all="ignore"):
        x, _ = restore_measures(problem, q, (data.copy(),))
    moved = x.mt[0][0]
    assert moved[1] - np.exp(-moved[0] ** 2 / 2) == pytest.approx(0.0, abs=1e-12)
    distance = (moved - observed) @ np.diag(info) @ (moved - observed)
    assert distance == pytest.approx(_nearest(observed, info), rel=1e-10)


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


# derandomized: the same 60 examples in every run (a random draw found the counterexample
# below, a test's outcome may not depend on its run's seed)
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow],
          derandomize=True)
@given(x0=st.floats(0.05, 4.0), side=st.sampled_from([-1.0, 1.0]),
       y0=st.floats(-1.0, 2.0), log_ratio=st.floats(0.0, 4.0), a=st.floats(0.3, 3.0),
       s=st.floats(0.5, 2.0))
def test_a_restored_measure_is_a_local_nearest_point(x0, side, y0, log_ratio, a, s):
    """Wherever a measure is observed, in an anisotropic metric (its ordinate up to 10⁴
    times more precise than its abscissa), a measure restored onto ``y = a exp(−x²/2s²)`` is
    on the curve (to the restoration's tolerance, a whitened violation of 1e-16) and no
    point of the curve near it is nearer (a bounded 1-D search around it, to 1e-10 of the
    distance: where the projector's steps converge slowly, above the peak, and run out still
    moving, the descent finishes the measure; the steps alone left 1.7e-9 of it). Below the
    curve's tail the tangent-plane steps stopped at their cap short of that; above the peak
    the measure was left off the curve. Not straight under the peak (``x = 0``): there,
    where the curve is tighter than the distance, the point above is stationary and a
    maximum along it, and the projector stops at it by symmetry (a fit's end moves such a
    measure to a nearer point, ``points.nearer_points``). Not beyond 10⁴, nor under peaks
    narrower than 0.5: at 10⁷, under a peak of width 0.31 (observed ``(−0.05, 0)``), the
    descent stops in the far tail at distance 3.70 where the nearest point is at 1.90 (``x =
    −1.39``), and a measure far above a peak of width 0.35 (``(−1.5, 1.6)``, ratio 46) stops
    at 119.71 where 119.38 is near — as before its Newton steps: each step along the curve
    is taken back by the projection onto it in the measure's metric, which moves the
    abscissa, not the precise ordinate (docs/engine.md, known)."""
    _assert_local_nearest(side * x0, y0, log_ratio, a, s)


def test_a_restored_measure_left_off_by_the_steps_is_a_local_nearest_point():
    """A random draw of the property above that failed while a descent's misses were
    counted over its whole run: observed left of the peak, the projector's steps leave the
    measure off the curve (whitened violation 4e-8); the descents from where they left it
    and from the observed value spent their misses on their first, far steps and stopped
    at ``x = −0.596383``, 1.8e-10 of the distance above the nearest point at
    ``x = −0.596385``. Misses are now counted since the last full step taken
    (docs/engine.md, thirty-fifth section)."""
    _assert_local_nearest(-2.0, 1.125, 1.03125, 2.1875, 0.5)


def _assert_local_nearest(x0, y0, log_ratio, a, s):
    """The measure observed at ``(x0, y0)``, its ordinate ``10**log_ratio`` times as precise,
    restored onto ``y = a exp(−x²/2s²)``: on the curve, and no point of it near is nearer
    (to 1e-10 of the distance)."""
    fam = kanagen.load_text(PEAK)
    info = np.array([1.0, 10.0 ** log_ratio])
    data = np.array([[x0, y0], [0.0, a], [s, a * np.exp(-0.5)]])
    q = np.array([a, s])
    problem = fitting.make_problem(fam, "m", {"pt": data}, {"pt": np.diag(info)}, q, None,
                                   None)
    with np.errstate(all="ignore"):
        x, _ = restore_measures(problem, q, (data.copy(),))
    mx, my = x.mt[0][0]
    curve = a * np.exp(-mx**2 / (2 * s**2))
    slope = -mx / s**2 * curve
    assert abs(my - curve) <= 1e-8 * np.sqrt(slope**2 / info[0] + 1 / info[1])

    def gap(t):
        return info[0] * (t - x0) ** 2 + info[1] * (a * np.exp(-t**2 / (2 * s**2)) - y0) ** 2

    width = 1e-2 * (1.0 + abs(mx))
    near = minimize_scalar(gap, bounds=(mx - width, mx + width), method="bounded",
                           options={"xatol": 1e-14}).fun
    assert gap(mx) <= near + 1e-10 * (1 + near)
