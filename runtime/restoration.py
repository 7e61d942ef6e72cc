"""Measures restored onto their equations for a fixed parameter: the inner problem of the
iteration (report eq. 22, solved to convergence).

For a fixed ``q`` each measure's corrected value is the point of ``c(q, ·) = 0`` nearest to the
observed one in its information metric. :func:`~.projector.project_measures` (the report's
projector in measure space, with eq. 18's halving per measure) finds it from a nearby start.
Far from a curved manifold — a point 500 px from a small circle — its step, a move along the
tangent plane plus a normal correction, raises the violation at every fraction and the measure
stops off its equations. Those measures are finished by a feasible descent on the manifold:

1. onto the manifold: Newton steps on ``c = 0`` along ``Q⁺ Dᵀ`` (the normal in the metric),
   with halving on ``|c|``;
2. along it: the tangent-plane projection of the observed measure (the projector's point at a
   feasible ``m̃``), back onto the manifold by 1., taken when the distance falls, halved
   otherwise.

Each accepted step lowers the distance on the manifold: it ends at a local nearest point.
Both are kernels, measure by measure (:mod:`kanagen.runtime.engine.measures`:
``restore_all``, ``descend``).
"""

from __future__ import annotations

import numpy as np

from .engine.data import arrays, pack_evals, pack_measures, unpack_evals, unpack_measures
from .engine.measures import RESTORE_STEPS, RESTORE_TOL, UNREACHED, restore_all, violations_all
from .projector import Point, Problem, point, quadratic

__all__ = ["RESTORE_STEPS", "RESTORE_TOL", "nearer_points", "restore_measures"]


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


def nearer_points(problem: Problem, x: Point) -> Point | None:
    """``x`` with each measure moved to the nearer of its current nearest point and the one
    restored from its observed value — None when no measure has a nearer one.

    With an anisotropic information a curve can hold two nearest points of a measure (the
    near and the far side of a circle): the iteration follows the branch it started on, and
    its profile cost is smooth along it, so a stationary point there is a local minimum of
    the joint problem in ``(q, m̃)`` only — not of the cost of ``q``. Checked where the
    iteration ends."""
    observed = tuple(ch.m.copy() for ch in problem.channels)
    other, _ = restore_measures(problem, x.q, observed)
    if not other.finite:
        return None
    A = arrays(problem)
    c, _, D = pack_evals(A, other.evals, x.q.size)
    on_all = violations_all(A, c, D) <= UNREACHED
    mt, evals, changed = [], [], False
    for j, (ch, m_x, m_o, e_x, e_o) in enumerate(zip(problem.channels, x.mt, other.mt, x.evals,
                                                    other.evals, strict=True)):
        on = on_all[A.start[j]:A.start[j] + A.size[j]]
        d_x, d_o = quadratic(m_x - ch.m, ch.Q), quadratic(m_o - ch.m, ch.Q)
        better = on & (d_o < d_x - 1e-9 * (1.0 + d_x))
        if better.any():
            changed = True
            m_x = m_x.copy()
            m_x[better] = m_o[better]
            e_x = tuple(np.where(better.reshape((-1,) + (1,) * (a.ndim - 1)), b, a)
                        for a, b in zip(e_x, e_o, strict=True))
        mt.append(m_x)
        evals.append(e_x)
    return point(problem, x.q, tuple(mt), tuple(evals)) if changed else None
