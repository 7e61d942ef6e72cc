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
"""

from __future__ import annotations

import numpy as np

from .projector import Point, Problem, point, project_measures, quadratic

#: Projection steps of a restoration (eq. 22) at most, and the move (in standard
#: deviations) below which a measure has converged.
RESTORE_STEPS, RESTORE_TOL = 30, 1e-10
#: A measure whose whitened violation stays above this (cost units) did not reach its
#: equations by the projector's steps.
_UNREACHED = 1e-16
_NEWTON = 8  # normal (Newton) steps onto the manifold, at most
_HALVINGS = 12  # halvings of a step along the manifold
_DESCENT = 40  # steps along the manifold, at most


def restore_measures(problem: Problem, q: np.ndarray, mt: tuple[np.ndarray, ...],
                     iterations: int = RESTORE_STEPS) -> tuple[Point, float]:
    """The point ``(q, m̃)`` with the measures projected onto their equations for ``q`` from
    ``mt``, and their whitened violation ``Σ ‖c‖²_{(D Q⁺ Dᵀ)⁻}`` there, in cost units (call
    under np.errstate).

    A measure the projector's steps leave off its equations is finished by the descent on
    the manifold, from where they left it and from its observed value; the nearer kept."""
    mt, violations, _, evals = project_measures(problem, q, mt, iterations, RESTORE_TOL)
    retry = tuple(np.flatnonzero(~(v <= _UNREACHED)) for v in violations)
    if any(r.size for r in retry):
        mt, violations, evals = list(mt), list(violations), list(evals)
        sub = problem.subset(retry)
        starts = (tuple(m[r] for m, r in zip(mt, retry, strict=True)),
                  tuple(ch.m for ch in sub.channels))
        for start in starts:
            done = _manifold_descent(sub, q, start)
            for i, rows in enumerate(retry):
                m_new, v_new, e_new = done[0][i], done[1][i], done[2][i]
                old = violations[i][rows]
                d_old = quadratic(mt[i][rows] - sub.channels[i].m, sub.channels[i].Q)
                d_new = quadratic(m_new - sub.channels[i].m, sub.channels[i].Q)
                reached = v_new <= _UNREACHED
                better = reached & (~(old <= _UNREACHED) | (d_new < d_old)) | \
                    (~reached & (v_new < np.where(np.isfinite(old), old, np.inf)))
                if better.any():
                    at = rows[better]
                    mt[i] = mt[i].copy()
                    mt[i][at] = m_new[better]
                    violations[i] = violations[i].copy()
                    violations[i][at] = v_new[better]
                    evals[i] = tuple(e.copy() for e in evals[i])
                    for e, e_new_part in zip(evals[i], e_new, strict=True):
                        e[at] = e_new_part[better]
    return point(problem, q, tuple(mt), tuple(evals)), sum(float(v.sum()) for v in violations)


def _manifold_descent(problem: Problem, q: np.ndarray, mt: tuple[np.ndarray, ...]):
    """Per channel: the measures moved onto ``c(q, ·) = 0`` and down the distance along it
    (module docstring); returns (mt, violations, evals) per channel."""
    out_m, out_v, out_e = [], [], []
    for fn, (whiten, correct), ch, m in zip(problem.measures, problem.kernels,
                                            problem.channels, mt, strict=True):
        def evaluate(values, ch=ch, fn=fn):
            return fn(q, ch.with_corrected(values), problem.k)

        def normal(values, c, D, whiten=whiten, correct=correct, ch=ch):
            """Newton steps onto the manifold along Q⁺Dᵀ, halved where |c| grows."""
            for _ in range(_NEWTON):
                Bbar, _, state = whiten(D, ch.G, c[..., None], problem.eps)
                step = -correct(state, ch.G, Bbar[..., 0])
                step[~np.all(np.isfinite(step), axis=1)] = 0.0
                worst = np.max(np.abs(c), axis=1)
                alpha = np.ones(len(values))
                for _ in range(_HALVINGS):
                    cand = values + alpha[:, None] * step
                    c_new, _, D_new = evaluate(cand)
                    grew = ~(np.max(np.abs(c_new), axis=1) < worst)
                    if not grew.any():
                        break
                    alpha = np.where(grew, alpha / 2, alpha)
                alpha = np.where(grew, 0.0, alpha)
                if not alpha.any():
                    break
                values = values + alpha[:, None] * step
                c, _, D = evaluate(values)
            return values, c, D

        values = m.copy()
        c, C, D = evaluate(values)
        values, c, D = normal(values, c, D)
        distance = quadratic(values - ch.m, ch.Q)
        active = np.ones(len(values), dtype=bool)
        for _ in range(_DESCENT):
            if not active.any():
                break
            # the projector's point at m̃: the observed measure projected onto the tangent
            r = (D @ (values - ch.m)[..., None])[..., 0] - c
            Bbar, _, state = whiten(D, ch.G, r[..., None], problem.eps)
            step = ch.m + correct(state, ch.G, Bbar[..., 0]) - values
            step[~active | ~np.all(np.isfinite(step), axis=1)] = 0.0
            alpha = np.ones(len(values))
            accepted = np.zeros(len(values), dtype=bool)
            best = values.copy()
            best_c, best_D, best_d = c.copy(), D.copy(), distance.copy()
            for _ in range(_HALVINGS):
                todo = active & ~accepted
                if not todo.any():
                    break
                cand = values + alpha[:, None] * step
                c_cand, _, D_cand = evaluate(cand)
                cand, c_cand, D_cand = normal(cand, c_cand, D_cand)
                d_cand = quadratic(cand - ch.m, ch.Q)
                ok = todo & (d_cand < distance) & (np.max(np.abs(c_cand), axis=1)
                                                   <= np.max(np.abs(c), axis=1) + 1e-12 *
                                                   (1 + np.max(np.abs(c), axis=1)))
                best[ok], best_c[ok], best_D[ok], best_d[ok] = \
                    cand[ok], c_cand[ok], D_cand[ok], d_cand[ok]
                accepted |= ok
                alpha = np.where(todo & ~ok, alpha / 2, alpha)
            moved = quadratic(best - values, ch.Q)
            active &= accepted & (moved > RESTORE_TOL**2)
            values, c, D, distance = best, best_c, best_D, best_d
        c, C, D = evaluate(values)
        Bbar, _, _ = whiten(D, ch.G, c[..., None], problem.eps)
        out_m.append(values)
        out_v.append(np.sum(Bbar[..., 0] ** 2, axis=1))
        out_e.append((c, C, D))
    return tuple(out_m), tuple(out_v), tuple(out_e)
