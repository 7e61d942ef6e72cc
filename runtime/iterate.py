"""The non-linear iteration of the report (eq. 18) with a cost safeguard.

Report rule: with ``δ_n = ‖c(x_n)‖∞``, step ``x_{n+1} = P(x_n)`` while ``δ`` does not grow
(by more than ``ε``), else halve back towards the previous point.

Safeguard (ours): eq. 18 watches only the constraints, so near a feasible point it can
cycle or walk uphill in cost. A trial point is accepted only if, besides the report's rule,
it lowers the cost ``L²`` or makes a sufficient decrease in ``δ`` (``δ_new <= (1 − α/2) δ``
for a step fraction ``α``) — a two-criterion filter. From a feasible point the projector step
is a descent direction of the cost to first order, so halving always ends in an accepted step
or in a step below the tolerance.

Status codes (``FitResult.status``):
0 converged — the projector step is below the tolerance (a fixed point of ``P``);
1 the iteration cap was reached;
2 stalled — no fraction of the step is acceptable: precision limit, returns the best point;
3 numerical failure — non-finite values at the start or in the projector.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .projector import Linearisation, Point, Problem, evaluate, project, quadratic

CONVERGED, MAX_ITER, STALLED, FAILED = 0, 1, 2, 3
MESSAGES = {
    CONVERGED: "converged: the projector step is below the tolerance",
    MAX_ITER: "stopped: iteration cap reached",
    STALLED: "stalled: no fraction of the projector step improves the constraints or the cost",
    FAILED: "numerical failure: non-finite values",
}
_MAX_HALVINGS = 40
_ROUNDING = 1e3 * np.finfo(float).eps


@dataclass(frozen=True)
class Outcome:
    point: Point
    lin: Linearisation | None
    iterations: int
    status: int
    message: str


def _small_step(problem: Problem, x: Point, lin: Linearisation, xtol: float) -> bool:
    """``x`` is a fixed point of ``P``: each component of q moves by less than ``xtol``
    relative to itself (or than the rounding level of ``q`` as a whole), and each measure by
    less than ``xtol`` standard deviations (its information metric)."""
    dq = np.abs(lin.q - x.q)
    rounding = _ROUNDING * float(np.max(np.abs(x.q), initial=0.0))
    if np.any(dq > xtol * np.abs(x.q) + rounding):
        return False
    for ch, m_new, m_old in zip(problem.channels, lin.mt, x.mt, strict=True):
        if ch.size and np.max(quadratic(m_new - m_old, ch.Q)) > xtol**2:
            return False
    return True


def iterate(problem: Problem, q_start: np.ndarray, max_iter: int = 100,
            xtol: float = 1e-10) -> Outcome:
    """Run eq. 18 from ``(q_start, m)``; never raises on numerical trouble."""
    with np.errstate(all="ignore"):
        return _iterate(problem, q_start, max_iter, xtol)


def _iterate(problem: Problem, q_start: np.ndarray, max_iter: int, xtol: float) -> Outcome:
    x = evaluate(problem, q_start, tuple(ch.m.copy() for ch in problem.channels))
    if not x.finite:
        return Outcome(x, None, 0, FAILED, MESSAGES[FAILED] + " at the starting point")
    eps_delta = 1e-12 * (1.0 + x.delta)
    lin = None
    for it in range(1, max_iter + 1):
        try:
            lin = project(problem, x)
            ok = np.all(np.isfinite(lin.q)) and all(np.all(np.isfinite(m)) for m in lin.mt)
        except (np.linalg.LinAlgError, ValueError, ZeroDivisionError, FloatingPointError):
            ok = False
        if not ok:
            return Outcome(x, None, it, FAILED, MESSAGES[FAILED] + " in the projector")
        if _small_step(problem, x, lin, xtol):
            new = evaluate(problem, lin.q, lin.mt)
            return Outcome(new if new.finite else x, lin, it, CONVERGED, MESSAGES[CONVERGED])
        alpha = 1.0
        for _ in range(_MAX_HALVINGS):
            q = x.q + alpha * (lin.q - x.q)
            mt = tuple(a + alpha * (b - a) for a, b in zip(x.mt, lin.mt, strict=True))
            trial = evaluate(problem, q, mt)
            if trial.finite and trial.delta < x.delta + eps_delta and (
                trial.cost <= x.cost * (1 + 1e-13) + 1e-300
                or trial.delta <= (1 - alpha / 2) * x.delta
            ):
                x = trial
                break
            alpha /= 2
        else:
            return Outcome(x, lin, it, STALLED, MESSAGES[STALLED])
    return Outcome(x, lin, max_iter, MAX_ITER, MESSAGES[MAX_ITER])
