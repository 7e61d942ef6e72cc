"""The measures against a fixed parameter, on a validated :class:`~.projector.Problem`:
coherence errors (report eq. 22–24), the equations' rank on their zero set, the minimal solve
(eq. 21) of random sampling (report §3.6, §4), and the constraints' free degrees of freedom.

The family-level API (data validated into a problem) is :mod:`.coherence`; the projection
and the minimal solve are the engine's kernels (:mod:`.engine.measures`,
:mod:`.engine.sample`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .engine.data import arrays, per_channel
from .engine.measures import projected_errors
from .engine.sample import minimal_solve as solve_sample
from .engine.sample import observed_all
from .projector import Problem, project_measures
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
    A = arrays(problem)
    with np.errstate(all="ignore"):  # once: a search asks for the errors a thousand times
        if iterations == 1:  # where the measures were observed: no projection step
            violations, kept = observed_all(A, np.asarray(q, dtype=float))
            totals, kept = per_channel(A, violations), per_channel(A, kept)
        else:  # projected from where they were observed: ‖m̃ − m‖²_Q plus the violation
            totals, kept = projected_errors(A, np.ascontiguousarray(q, dtype=float),
                                            int(iterations), float(tol))
            totals, kept = per_channel(A, totals), per_channel(A, kept)
        if ranks is None and iterations == 1 and any(r.size and r.max() > 1 for r in kept):
            ranks = manifold_ranks(problem, q)
        out = []
        for i, (total, rank) in enumerate(zip(totals, kept, strict=True)):
            if ranks is not None:
                rank = np.minimum(rank, ranks[i])
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
    with np.errstate(all="ignore"):
        _, _, kept, _ = project_measures(sub, q, tuple(ch.m for ch in sub.channels), 50, 1e-12)
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


def minimal_solve_problem(problem: Problem, target: np.ndarray, max_iter: int = 50,
                          xtol: float = 1e-12, eps: float = EPS) -> MinimalSolution:
    """:func:`~.coherence.minimal_solve` on a validated problem (its measures are the
    sample): the engine's :func:`~kanagen.runtime.engine.sample.minimal_solve`."""
    A = arrays(problem)
    q, success, rank, iterations, violation = solve_sample(
        A, np.arange(A.chan.size, dtype=np.int64), np.ascontiguousarray(target, dtype=float),
        int(max_iter), float(xtol), float(eps))
    return MinimalSolution(q, bool(success), int(rank), int(iterations), float(violation))


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
