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
_DESCENT = 12  # steps along the manifold, at most


def restore_measures(problem: Problem, q: np.ndarray, mt: tuple[np.ndarray, ...],
                     iterations: int = RESTORE_STEPS) -> tuple[Point, float]:
    """The point ``(q, m̃)`` with the measures projected onto their equations for ``q`` from
    ``mt``, and their whitened violation ``Σ ‖c‖²_{(D Q⁺ Dᵀ)⁻}`` there, in cost units (call
    under np.errstate).

    A measure the projector's steps leave off its equations is finished by the descent on
    the manifold, from where they left it and from its observed value; the nearer kept."""
    projected = None if problem.compiled is None else \
        problem.compiled[0].project(problem.compiled[1], problem, q, mt, iterations,
                                    RESTORE_TOL)  # the same projection in C (kg_project)
    if projected is None:
        projected = project_measures(problem, q, mt, iterations, RESTORE_TOL)
    mt, violations, _, evals = projected
    retry = tuple(np.flatnonzero(~(v <= _UNREACHED)) for v in violations)
    if any(r.size for r in retry):
        mt, violations, evals = list(mt), list(violations), list(evals)
        sub = problem.subset(retry)
        starts = (tuple(m[r] for m, r in zip(mt, retry, strict=True)),
                  tuple(ch.m for ch in sub.channels))
        tops = tuple(_top_variance(ch.G) for ch in problem.channels)
        for start in starts:
            done = _manifold_descent(sub, q, start, tops)
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


def _manifold_descent(problem: Problem, q: np.ndarray, mt: tuple[np.ndarray, ...],
                      tops: tuple[np.ndarray, ...]):
    """Per channel: the measures moved onto ``c(q, ·) = 0`` and down the distance along it
    (module docstring); returns (mt, violations, evals) per channel. Each step evaluates
    only the measures still moving. ``tops``: each channel's largest variance of each
    component (over all its measures)."""
    out_m, out_v, out_e = [], [], []
    for fn, kernel, ch, m, top in zip(problem.measures, problem.kernels, problem.channels,
                                      mt, tops, strict=True):
        whiten, correct = kernel
        reach = _reaching(ch.G, top)

        def evaluate(rows, values, ch=ch, fn=fn):
            return fn(q, ch.with_corrected(values, rows), problem.k)

        values = m.copy()
        everyone = np.arange(len(values))
        c, _, D = evaluate(everyone, values)
        values, c, D = _normal(problem, ch, reach, kernel, evaluate, everyone, values, c,
                                D)
        distance = quadratic(values - ch.m, ch.Q)
        # only the measures on their manifold descend along it (the others cannot be
        # brought onto it for this q: a circle of negative radius)
        active = everyone[_violations(problem, whiten, ch.G, c, D) <= _UNREACHED]
        for _ in range(_DESCENT):
            if not active.size:
                break
            sub = ch.subset(active)
            # the projector's point at m̃: the observed measure projected onto the tangent
            r = (D[active] @ (values[active] - sub.m)[..., None])[..., 0] - c[active]
            Bbar, _, state = whiten(D[active], sub.G, r[..., None], problem.eps)
            step = sub.m + correct(state, sub.G, Bbar[..., 0]) - values[active]
            finite = np.all(np.isfinite(step), axis=1)
            todo = np.flatnonzero(finite)
            alpha = np.ones(active.size)
            moved = np.zeros(active.size)
            for _ in range(_HALVINGS):
                if not todo.size:
                    break
                rows = active[todo]
                cand = values[rows] + alpha[todo, None] * step[todo]
                c_cand, _, D_cand = evaluate(rows, cand)
                cand, c_cand, D_cand = _normal(problem, ch, reach, kernel, evaluate, rows,
                                               cand, c_cand, D_cand)
                d_cand = quadratic(cand - ch.m[rows], ch.Q[rows] if ch.Q.ndim == 3 else ch.Q)
                worst = np.max(np.abs(c[rows]), axis=1)
                ok = (d_cand < distance[rows]) & (np.max(np.abs(c_cand), axis=1)
                                                  <= worst + 1e-12 * (1 + worst))
                at = rows[ok]
                moved[todo[ok]] = quadratic(cand[ok] - values[at],
                                            ch.Q[at] if ch.Q.ndim == 3 else ch.Q)
                values[at], c[at], D[at], distance[at] = cand[ok], c_cand[ok], D_cand[ok], \
                    d_cand[ok]
                todo = todo[~ok]
                alpha[todo] /= 2
            active = active[moved > RESTORE_TOL**2]
        c, C, D = evaluate(everyone, values)
        out_m.append(values)
        out_v.append(_violations(problem, whiten, ch.G, c, D))
        out_e.append((c, C, D))
    return tuple(out_m), tuple(out_v), tuple(out_e)


def _normal(problem: Problem, ch, reach, kernel, evaluate, rows: np.ndarray,
            values: np.ndarray, c: np.ndarray, D: np.ndarray):
    """Newton steps of the measures ``rows`` onto the manifold along ``Q⁺Dᵀ`` (the normal in
    the information metric), halved where ``|c|`` grows; a measure stops once on its
    equations. A measure those steps leave off — a point under the minimum of an explicit
    curve whose ordinate is far more precise than its abscissa: the normal moves it along
    the abscissa, which cannot reach the curve — takes the same steps in the metric of its
    channel's largest variance of each component (unit-invariant, every free component may
    move). Returns (values, c, D) of those rows."""
    values, c, D = values.copy(), c.copy(), D.copy()
    left = np.arange(len(rows))
    for metric in (ch.G, reach):
        metric = metric[rows] if metric.ndim == 3 else metric
        left = _newton(problem, kernel, evaluate, rows, values, c, D, metric, left)
        if not left.size:
            break
    return values, c, D


def _violations(problem: Problem, whiten, G: np.ndarray, c: np.ndarray,
                D: np.ndarray) -> np.ndarray:
    """Each measure's whitened violation ``‖c‖²_{(D Q⁺ Dᵀ)⁻}`` (cost units)."""
    Bbar, _, _ = whiten(D, G, c[..., None], problem.eps)
    return np.sum(Bbar[..., 0] ** 2, axis=1)


def _top_variance(G: np.ndarray) -> np.ndarray:
    """The largest variance of each component over a channel's measures (``Q⁺ = GᵀG``)."""
    var = np.sum(G**2, axis=-2)
    return np.max(var.reshape(-1, var.shape[-1]), axis=0)


def _reaching(G: np.ndarray, top: np.ndarray) -> np.ndarray:
    """``G`` of the diagonal metric ``top`` (zero where a measure's component is exact)."""
    var = np.sum(G**2, axis=-2)  # diag(GᵀG) = diag(Q⁺), per measure when G is
    root = np.sqrt(top) * (var > 0)
    return root[..., :, None] * np.eye(G.shape[-1]) if root.ndim == 2 else np.diag(root)


def _newton(problem: Problem, kernel, evaluate, rows, values, c, D, G, left):
    """Newton steps in the metric ``G`` of the rows ``left`` (indices into ``rows``),
    updating ``values, c, D`` in place; returns the rows still off their equations."""
    whiten, correct = kernel
    stuck = []
    for attempt in range(_NEWTON + 1):
        if not left.size:
            break
        Gl = G[left] if G.ndim == 3 else G
        Bbar, _, state = whiten(D[left], Gl, c[left][..., None], problem.eps)
        far = np.sum(Bbar[..., 0] ** 2, axis=1) > _UNREACHED * 1e-4
        far &= np.all(np.isfinite(Bbar[..., 0]), axis=1)
        step = -correct(state, Gl, Bbar[..., 0])
        left, step = left[far], step[far]
        if attempt == _NEWTON:  # steps spent: still off
            break
        step[~np.all(np.isfinite(step), axis=1)] = 0.0
        worst = np.max(np.abs(c[left]), axis=1)
        alpha = np.ones(left.size)
        todo = np.arange(left.size)
        moved = np.zeros(left.size, dtype=bool)
        for _ in range(_HALVINGS):
            if not todo.size:
                break
            at = left[todo]
            cand = values[at] + alpha[todo, None] * step[todo]
            c_new, _, D_new = evaluate(rows[at], cand)
            ok = np.max(np.abs(c_new), axis=1) < worst[todo]
            values[at[ok]], c[at[ok]], D[at[ok]] = cand[ok], c_new[ok], D_new[ok]
            moved[todo[ok]] = True
            todo = todo[~ok]
            alpha[todo] /= 2
        stuck.append(left[~moved])
        left = left[moved]
    return np.concatenate([left, *stuck]).astype(int)


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
    mt, evals, changed = [], [], False
    for fn_kernel, ch, m_x, m_o, e_x, e_o in zip(problem.kernels, problem.channels, x.mt,
                                                 other.mt, x.evals, other.evals, strict=True):
        c, _, D = e_o
        on = _violations(problem, fn_kernel[0], ch.G, c, D) <= _UNREACHED
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
