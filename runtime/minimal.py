"""The measures against a fixed parameter, on a validated :class:`~.projector.Problem`:
coherence errors (report eq. 22–24), the equations' rank on their zero set, the minimal solve
(eq. 21) of random sampling (report §3.6, §4), and the constraints' free degrees of freedom.

The algorithms only: the family-level API (data validated into a problem) is
:mod:`.coherence`. ``coherence_errors`` and ``minimal_solve_problem`` have a compiled twin
(codegen/c/kanagen_fast.c: ``kg_coherence``, ``kg_minimal``; runtime/fastpath.py).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .projector import Problem, project_measures, quadratic
from .sqrt import EPS, reduced_sqrt


def coherence_errors(problem: Problem, q: np.ndarray, iterations: int | None = None,
                     tol: float = 1e-10, ranks: tuple[int, ...] | None = None,
                     ) -> tuple[np.ndarray, ...]:
    """:func:`~.coherence.coherence` on a validated problem: per channel, the (M,) errors (eq. 24).

    ``ranks`` caps the equations counted per measure (``p•`` of eq. 24), per channel: the
    rank on the equations' zero set, from :func:`manifold_ranks` (computed here when
    ``iterations`` is 1 and a channel has several equations).
    """
    iterations = iterations if iterations is not None else 50
    compiled = None if problem.compiled is None else \
        problem.compiled[0].coherence(problem.compiled[1], problem, q, iterations, tol)
    with np.errstate(all="ignore"):
        if compiled is not None:  # the same projection in C: ‖m̃ − m‖²_Q + violation, ranks
            totals, kept = compiled
        else:
            mt, violations, kept, _ = project_measures(
                problem, q, tuple(ch.m for ch in problem.channels), iterations, tol)
            totals = [quadratic(m - ch.m, ch.Q) + violation
                    for ch, m, violation in zip(problem.channels, mt, violations, strict=True)]
        if ranks is None and iterations == 1 and any(r.size and r.max() > 1 for r in kept):
            ranks = manifold_ranks(problem, q)
    out = []
    for i, (total, rank) in enumerate(zip(totals, kept, strict=True)):
        if ranks is not None:
            rank = np.minimum(rank, ranks[i])
        with np.errstate(all="ignore"):
            errors = total / np.maximum(rank, 1)
        out.append(np.where(np.isfinite(errors), errors, np.inf))
    return tuple(out)


def manifold_ranks(problem: Problem, q: np.ndarray, sample: int = 8) -> tuple[int, ...]:
    """Per channel, the independent equations of a measure on its equations' zero set: the
    rank the reduced square root keeps at most of a few measures projected onto
    ``c(q, ·) = 0``.

    Equations may be dependent only on their zero set: ``p2 × H p1 = 0`` is three equations
    of rank two there, but off it the identity ``p2 · (p2 × H p1) = 0`` makes the third
    independent at second order, and a measure evaluated where it was observed would count
    three. The first-order (Sampson) error divides by the rank on the zero set; the minimal
    sample size counts it too.
    """
    rows = tuple(np.arange(min(sample, ch.size)) for ch in problem.channels)
    sub = problem.subset(rows)
    compiled = None if sub.compiled is None else \
        sub.compiled[0].coherence(sub.compiled[1], sub, q, 50, 1e-12)
    with np.errstate(all="ignore"):
        if compiled is not None:  # the same projection in C
            kept = compiled[1]
        else:
            _, _, kept, _ = project_measures(sub, q, tuple(ch.m for ch in sub.channels), 50,
                                             1e-12)
    # the most common rank: a measure whose projection stops short (a far outlier) keeps
    # the extra equation, one at a singular point of the zero set loses one
    return tuple(int(np.bincount(r).argmax()) if r.size else 0 for r in kept)


@dataclass(frozen=True)
class MinimalSolution:
    """Result of a minimal solve (:func:`minimal_solve_problem`)."""

    q: np.ndarray
    success: bool
    rank: int
    iterations: int
    violation: float


_FREE_STEPS = 3  # full steps allowed to raise the violation before the line search
_WATCHDOG = 1e8  # ... by at most this factor over the best violation so far
_SLOW = 4  # line-search steps in a row that lower the violation by less than a tenth


def minimal_solve_problem(problem: Problem, target: np.ndarray, max_iter: int = 50,
                  xtol: float = 1e-12, eps: float = EPS) -> MinimalSolution:
    """:func:`~.coherence.minimal_solve` on a validated problem (its measures are the sample)."""
    if problem.compiled is not None:  # the same iteration in C (kg_minimal)
        fastpath, model = problem.compiled
        out = fastpath.minimal(model, problem, target, max_iter, xtol, eps)
        if out is not None:
            q, success, rank, iterations, violation = out
            return MinimalSolution(q, success, rank, iterations, violation)

    def equations(q):
        c0, C0 = problem.c0(q, problem.k)
        cs, Js = [c0], [C0]
        for fn, ch in zip(problem.measures, problem.channels, strict=True):
            c, C, _ = fn(q, ch.X, problem.k)
            cs.append(c.reshape(-1))
            Js.append(C.reshape(-1, q.size))
        return np.concatenate(cs), np.concatenate(Js)

    def scaled(q, raw=None):
        c, J = equations(q) if raw is None else raw
        return w * c, w[:, None] * J, float(np.max(np.abs(w * c), initial=0.0))

    q, rank = target.copy(), 0
    with np.errstate(all="ignore"):
        # each equation in units of the parameter: rows scaled by their gradient's norm at
        # the start (the measures' equations are in pixels², a slack's in its own units)
        raw = equations(q)
        norms = np.linalg.norm(raw[1], axis=1)
        w = np.where(np.isfinite(norms) & (norms > 0), 1.0 / norms, 1.0)
        c, J, delta = scaled(q, raw)
        best, free, slow = (delta, q, c, J), _FREE_STEPS, 0
        for it in range(1, max_iter + 1):
            # q + step: the point closest to the target on the linearised equations, from
            # the SVD of J (not J Jᵀ, whose condition number is squared)
            try:
                U, S, Vt = np.linalg.svd(J, full_matrices=False)
            except np.linalg.LinAlgError:
                return MinimalSolution(q, False, rank, it, delta)
            kept = S > np.sqrt(eps) * S[0] if S.size and S[0] > 0 else np.zeros(S.size, bool)
            rank = int(kept.sum())
            V = Vt[kept].T
            r = target - q
            step = r - V @ (V.T @ r + (U[:, kept].T @ c) / S[kept])
            if not np.all(np.isfinite(step)):
                return MinimalSolution(q, False, rank, it, delta)
            trial = q + step
            c_new, J_new, d_new = scaled(trial)
            if free > 0 and np.isfinite(d_new) and d_new < _WATCHDOG * (1 + best[0]):
                # watchdog (Chamberlain et al. 1982): full steps may raise the violation a
                # few times — far from the solution a curved equation (a slack's, the unit
                # norm from a start nearly orthogonal to the solution) needs it
                free -= d_new >= delta
                moved = np.max(np.abs(step), initial=0.0)
            else:
                if delta > best[0]:  # the watchdog's steps did not pay: back to the best
                    delta, q, c, J = best
                    free = 0
                    continue
                free = 0
                alpha = 1.0
                while alpha > 2.0**-30:
                    trial = q + alpha * step
                    c_new, J_new, d_new = scaled(trial)
                    if np.isfinite(d_new) and d_new < delta + 1e-12 * (1 + delta):
                        break
                    alpha /= 2
                else:
                    return MinimalSolution(q, _solved(delta, q), rank, it, delta)
                moved = np.max(np.abs(alpha * step), initial=0.0)
            slow = slow + 1 if free == 0 and d_new > 0.9 * delta else 0
            q, c, J, delta = trial, c_new, J_new, d_new
            if delta < best[0]:
                best = (delta, q, c, J)
            if slow >= _SLOW:  # no solution near (a sample the model cannot pass through)
                return MinimalSolution(q, _solved(delta, q), rank, it, delta)
            if moved <= xtol * (1 + np.max(np.abs(q))) or _solved(delta, q) and \
                    moved <= 1e-8 * (1 + np.max(np.abs(q))):
                return MinimalSolution(q, _solved(delta, q), rank, it, delta)
    return MinimalSolution(q, _solved(delta, q), rank, max_iter, delta)


def _solved(delta: float, q: np.ndarray) -> bool:
    """Equations (scaled to parameter units) hold to rounding-level accuracy."""
    return bool(np.isfinite(delta) and delta <= 1e-8 * (1 + np.max(np.abs(q))))


def generic_free_dof(jacobian: Callable[[np.ndarray], np.ndarray], q: np.ndarray) -> int:
    """``n − p``: the parameter's degrees of freedom left free by the constraints, whose
    Jacobian at a point is ``jacobian(q)`` (``p`` its rank, as the reduced square root keeps
    it).

    ``p`` is the generic rank: the largest of the ranks at ``q`` and at two fixed
    perturbations of it. At a special point a constraint's gradient may vanish (the slack
    equation ``s²(AC − B²) − 1`` of an ellipse at a line, ``A = B = C = 0``) while the
    constraint still removes a degree of freedom everywhere it can hold.
    """
    q = np.asarray(q, dtype=float)
    rng = np.random.default_rng(0)  # fixed: the same answer on every call
    rank = 0
    with np.errstate(all="ignore"):
        for point in (q, *(q + rng.standard_normal((2, q.size)) * (0.1 + np.abs(q)))):
            C0 = np.asarray(jacobian(point), dtype=float)
            if C0.shape[0] and np.all(np.isfinite(C0)):
                rank = max(rank, int(reduced_sqrt(C0 @ C0.T)[1].sum()))
    return q.size - rank
