"""Measures restored onto their equations for a fixed parameter: the inner problem of the
iteration (report eq. 22, solved to convergence).

For a fixed ``q`` each measure's corrected value is the point of ``c(q, ·) = 0`` nearest to the
observed one in its information metric. :func:`~.projector.project_measures` (the report's
projector in measure space, with eq. 18's halving per measure) finds it from a nearby start.
Far from a curved manifold — a point 500 px from a small circle — its step, a move along the
tangent plane plus a normal correction, raises the violation at every fraction and the measure
stops off its equations. Those measures are finished by a feasible descent on the manifold:

1. onto the manifold: Newton steps on ``c = 0`` along ``Q⁺ Dᵀ`` (the normal in the metric),
   with halving on ``|c|`` — in the measure's metric, then in its channel's largest
   variances, then in its data's extent (the squared ranges of the observed values: a
   point above a peak whose ordinate is far more precise than its abscissa reaches the
   curve only by moving the ordinate);
2. along it: the step to the nearest point of the distance's second-order model on the
   manifold — the equations' curvature weighted by their multipliers, the SQP (Newton) step
   of ``min ½‖m̃ − m‖²_Q`` subject to ``c = 0`` (``measures.curved_step``) — or, where that
   model has no minimum along the step (a negative curvature) or its system is singular,
   the tangent-plane projection of the observed measure (the projector's point at a feasible
   ``m̃``); back onto the manifold by 1., taken when the distance falls, halved otherwise,
   until the fall the model predicts is below the distance's rounding — or until eight
   trial points were left off the manifold by 1. (where it runs off: a flat curve whose
   nearest points lie at overflowing abscissas), the point reached kept.

Each accepted step lowers the distance on the manifold: it ends at a local nearest point.
A measure the projector's steps leave on its equations but still moving (observed above a
peak, near the centre of the curve's curvature, where the steps contract slowly) is finished
by the same descent from where they left it: "on" by the whitened violation's 1e-16, it
could still be off enough to lower its distance by 1e-8, above the cost differences the
trust region compares, which then refused every step at a minimum.
Both are kernels, measure by measure (:mod:`kanagen.runtime.engine.measures`:
``restore_all``, ``descend``). The tangent-plane step alone is the same step without the
curvature: far from a curved manifold it converges linearly, and at its cap of 12 steps it
stopped short of the nearest point (a measure under a Gaussian's tail, its ordinate 10⁴
times more precise than its abscissa: 3.7e-10 relative in the distance, and twice the
fit's time in halvings).

A point where the equations' slope is infinite (``sqrt(x)`` at ``x = 0``) is not on them:
its whitened violation ``c² / (D Q⁺ Dᵀ)`` would be 0 for any ``c`` (``measures.whitened``
makes it infinite there).

A local nearest point may not be the nearest: with an anisotropic information a curve can
hold two nearest points of a measure (the near and the far side of a circle). The iteration
follows the branch it started on, and its profile cost is smooth along it, so a stationary
point there is a local minimum of the joint problem in ``(q, m̃)`` only — not of the cost of
``q``. Where the iteration ends, each measure is restored again from its observed value and
moved to that point when it is nearer (:func:`kanagen.runtime.engine.points.nearer_points`).
"""

from __future__ import annotations

import numpy as np

from .engine.data import arrays, pack_measures, unpack_evals, unpack_measures
from .engine.measures import RESTORE_STEPS, RESTORE_TOL, restore_all
from .projector import Point, Problem, point

__all__ = ["RESTORE_STEPS", "RESTORE_TOL", "restore_measures"]


def restore_measures(problem: Problem, q: np.ndarray, mt: tuple[np.ndarray, ...],
                     iterations: int = RESTORE_STEPS) -> tuple[Point, float]:
    """The point ``(q, m̃)`` with the measures projected onto their equations for ``q`` from
    ``mt``, and their whitened violation ``Σ ‖c‖²_{(D Q⁺ Dᵀ)⁻}`` there, in cost units (call
    under np.errstate).

    A measure the projector's steps leave off its equations is finished by the descent on
    the manifold, from where they left it and from its observed value; the nearer kept."""
    A = arrays(problem)
    out, violations, c, C, D = restore_all(A, np.ascontiguousarray(q, dtype=float),
                                           pack_measures(A, mt), int(iterations))
    return (point(problem, q, unpack_measures(A, out), unpack_evals(A, c, C, D)),
            float(violations.sum()))
