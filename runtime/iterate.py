"""The non-linear iteration of the report (eq. 18), with restoration, damping and a filter.

Report rule: with ``δ_n = ‖c(x_n)‖∞``, step ``x_{n+1} = P(x_n)`` while ``δ`` does not grow
(by more than ``ε``), else halve back towards the previous point.

Restoration (ours): every trial point (and the start) has its measures projected back onto
their equations for its ``q`` (the report's eq. 22 projection, a few vectorised steps), so
points are compared at their true cost and δ measures what the measures cannot absorb.

Trust region (ours): without parameter constraints eq. 18 has only the cost to watch (a
Gauss–Newton iteration on the measures' distances); it is globalised by a trust region on
``‖Δq‖`` (:class:`_TrustRegion`), which keeps a first step from a far start from jumping to
a plateau (NIST BoxBOD, MGH10, MGH17 from their first starts).

Globalisation (ours): with parameter constraints, when the report's step is refused and a
few halvings (eq. 18) do not help, the parameter step is damped Levenberg–Marquardt style
(``μ diag(H)`` added to the information, the linearised equations still solved exactly),
``μ`` growing tenfold until a step is accepted and shrinking tenfold after. Far from the
solution this follows the gradient of the cost instead of a Gauss–Newton step that
overshoots.

Safeguard (ours): eq. 18 watches only the constraints, so near a feasible point it can walk
uphill in cost, and it refuses every long step there, since curvature raises δ a little. A
trial point is accepted by a small filter over (cost, δ), see :func:`_acceptable`: it lowers
δ (above δ's rounding level); or it raises neither the cost nor δ; or it clearly lowers the
cost while δ stays below a hundredth of its starting value. Far from feasibility this is
eq. 18 (a Newton-like step that lowers the violation is taken even if the cost grows); once
feasible, the projector step is a descent direction of the cost to first order.

Inequalities (ours, appendix F): once an iterate satisfies the model's inequality relations
(``c > 0`` of an ``ellipse`` model, say), a trial point that breaks them is refused, so the
iteration approaches the boundary instead of jumping across it.

Stopping (ours): when the step stops shrinking at the rounding level while the cost stays
put, the iteration stops as "stalled" (the precision limit) instead of wandering.

Status codes (``FitResult.status``):
0 converged — the projector step is below the tolerance (a fixed point of ``P``);
1 the iteration cap was reached;
2 stalled — no fraction of the step is acceptable, only a negligible one is, or the step has
  stopped shrinking (rounding noise): the precision limit; returns the best point (a success
  when the equations hold there);
3 numerical failure — non-finite values at the start or in the projector;
4 at the boundary of a strict inequality (``c > 0``, ``c != 0``: appendix F) — the
  relation's slack diverges (``c = 1/s² → 0``, below 1e-8 of its start): the infimum lies
  on the boundary, outside the open set the model allows, so no minimum is attained;
  returns the first iterate that close to the boundary (not a success).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .projector import (
    _ROUNDING,
    Linearisation,
    Point,
    Problem,
    Projection,
    evaluate,
    linearise,
    point,
    project_measures,
    quadratic,
    restore_parameter,
    solve,
)
from .sqrt import closest_sqrt

CONVERGED, MAX_ITER, STALLED, FAILED, BOUNDARY = 0, 1, 2, 3, 4
MESSAGES = {
    CONVERGED: "converged: the projector step is below the tolerance",
    MAX_ITER: "stopped: iteration cap reached",
    STALLED: "stalled: no fraction of the projector step improves the constraints or the cost",
    FAILED: "numerical failure: non-finite values",
    BOUNDARY: "at the boundary of a strict inequality: its slack diverges (no minimum inside "
              "the open set the model allows); returning the last point inside",
}
_MAX_HALVINGS = 40
_RESTORATION = 2  # one projection step restores the measures of a trial point
_STAGNATION = 5  # iterations without a smaller projector step
_MU_MIN, _MU_MAX = 1e-4, 1e8  # Levenberg–Marquardt damping range, relative to diag(H)
_HALVINGS_PER_DAMPING = 4


@dataclass(frozen=True)
class Outcome:
    point: Point
    lin: Linearisation | None
    proj: Projection | None
    iterations: int
    status: int
    message: str
    start_violation: float = 0.0


def _step_sizes(problem: Problem, x: Point, proj: Projection) -> tuple[float, float]:
    """Size of the projector step: q components relative to themselves (floored at the
    rounding level of q), and measures in standard deviations (their information metric)."""
    floor = max(_ROUNDING * float(np.max(np.abs(x.q), initial=0.0)), np.finfo(float).tiny)
    size_q = float(np.max(np.abs(proj.q - x.q) / (np.abs(x.q) + floor), initial=0.0))
    size_m = 0.0
    for ch, m_new, m_old in zip(problem.channels, proj.mt, x.mt, strict=True):
        if ch.size:
            size_m = max(size_m, float(np.max(quadratic(m_new - m_old, ch.Q))))
    return size_q, np.sqrt(size_m)


def _negligible(problem: Problem, q_old, q_new, mt_old, mt_new, xtol: float) -> bool:
    """A move is negligible when each component of q moves by less than ``xtol`` relative to
    itself, each measure by less than ``xtol`` standard deviations (its information metric) —
    or, for both, by no more than the rounding level of the values."""
    dq = np.abs(q_new - q_old)
    rounding = _ROUNDING * float(np.max(np.abs(q_old), initial=0.0))
    if np.any(dq > xtol * np.abs(q_old) + rounding):
        return False
    for ch, m_new, m_old in zip(problem.channels, mt_new, mt_old, strict=True):
        if ch.size:
            moved = float(np.max(quadratic(m_new - m_old, ch.Q)))
            if moved > (xtol + _ROUNDING * ch.scale) ** 2:
                return False
    return True


def _diverging(problem: Problem, q_old: np.ndarray, q_new: np.ndarray,
               start: np.ndarray) -> bool:
    """A slack of a strict inequality diverges: it at least doubles in this step and its
    relation ``c = 1/s²`` (``1/s`` for ``c != 0``) has fallen below 1e-8 of its starting
    value. The parameter is then within that of the boundary of the open set the model
    allows; letting the slack grow on would only make its equation ill-conditioned."""
    for index, power in problem.strict_slacks:
        s_old, s_new = abs(q_old[index]), abs(q_new[index])
        if s_new > 2.0 * s_old and (abs(start[index]) / s_new) ** power < 1e-8:
            return True
    return False


def iterate(problem: Problem, q_start: np.ndarray, max_iter: int = 100,
            xtol: float = 1e-10) -> Outcome:
    """Run eq. 18 from ``(q_start, m)``; never raises on numerical trouble."""
    with np.errstate(all="ignore"):
        return _iterate(problem, q_start, max_iter, xtol)


def _acceptable(trial: Point, x: Point, eps_delta: float, delta_cap: float) -> bool:
    """A small filter over (cost, violation): accept a trial point that

    * lowers the violation δ (eq. 18's aim), or
    * does not raise the cost and does not raise δ (eq. 18's rule plus our cost guard), or
    * clearly lowers the cost while δ stays below ``delta_cap`` (a hundredth of the starting
      violation, measures restored: what the constraints start with): near feasibility, a
      long step raises δ by second-order terms that the next projection removes, and eq. 18
      alone would refuse every such step — but a feasible start stays feasible.
    """
    if not trial.finite:
        return False
    if _lowers_violation(trial, x, eps_delta):
        return True
    # At rounding-level feasibility, moving costs λ·δ of the same order: rounding too.
    slack = 1e-10 if x.delta <= eps_delta else 1e-13
    if trial.delta < x.delta + eps_delta and trial.cost <= x.cost * (1 + slack) + 1e-300:
        return True
    return trial.delta <= delta_cap and trial.cost < x.cost * (1 - 1e-10)


def _lowers_violation(trial: Point, x: Point, eps_delta: float) -> bool:
    """Eq. 18's aim: the violation δ falls (a fall within its rounding level is no
    progress)."""
    return x.delta > eps_delta and trial.delta <= (1 - 1e-4) * x.delta


def _restored(problem: Problem, q: np.ndarray, mt, root: np.ndarray | None = None) -> Point:
    """The point with ``q`` projected back onto the parameter constraints (in the metric of
    the step, when ``root`` is given) and its measures onto their equations for that ``q``
    (report eq. 22, a few measure-space steps): trial points are compared at their true cost
    and violation."""
    if root is not None:
        q = restore_parameter(problem, q, root)
    mt, _, _, evals = project_measures(problem, q, mt, _RESTORATION)
    return point(problem, q, mt, evals)


def _iterate(problem: Problem, q_start: np.ndarray, max_iter: int, xtol: float) -> Outcome:
    x = evaluate(problem, q_start, tuple(ch.m.copy() for ch in problem.channels))
    if not x.finite:
        return Outcome(x, None, None, 0, FAILED, MESSAGES[FAILED] + " at the starting point")
    eps_delta = 1e-12 * (1.0 + x.delta)
    delta0 = x.delta
    restored = _restored(problem, q_start, x.mt)
    if restored.finite and restored.delta <= x.delta:
        x = restored
    # what the measures cannot absorb at the start (restored): the parameter constraints
    delta_cap = 1e-2 * x.delta
    lin = proj = None
    mu = 0.0  # Levenberg–Marquardt damping, raised only when the plain step is refused
    best = (np.inf, np.inf)
    since_best = 0
    last_cost = np.inf
    # no parameter constraints: eq. 18 has nothing to watch but the cost (Gauss–Newton on
    # the measures' distances), globalised by a trust region
    region = _TrustRegion(x.q) if not x.c0.size else None

    def outcome(point, it, status, linearisation=None, projection=None):
        return Outcome(point, linearisation, projection, it, status, MESSAGES[status], delta0)

    for it in range(1, max_iter + 1):
        try:
            lin = linearise(problem, x)
            proj = solve(problem, lin)
            ok = np.all(np.isfinite(proj.q)) and all(np.all(np.isfinite(m)) for m in proj.mt)
        except (np.linalg.LinAlgError, ValueError, ZeroDivisionError, FloatingPointError):
            ok = False
        if not ok:
            return Outcome(x, None, None, it, FAILED, MESSAGES[FAILED] + " in the projector",
                           delta0)
        if _negligible(problem, x.q, proj.q, x.mt, proj.mt, xtol):
            new = evaluate(problem, proj.q, proj.mt)
            return outcome(new if new.finite else x, it, CONVERGED, lin, proj)
        # Under linear convergence the step shrinks every iteration; once it stops shrinking
        # while the cost stays put, it is rounding noise around the solution: stop there.
        sizes = _step_sizes(problem, x, proj)
        if (sizes[0] < 0.9 * best[0] or sizes[1] < 0.9 * best[1]
                or x.cost < (1 - 1e-12) * last_cost):
            best = (min(best[0], sizes[0]), min(best[1], sizes[1]))
            since_best = 0
        else:
            since_best += 1
            if since_best >= _STAGNATION:
                return outcome(x, it, STALLED, lin, proj)
        guard = problem.relations if problem.relations is not None and \
            problem.relations(x.q) else None
        if region is not None:
            trial = _trust_region_step(problem, lin, proj, x, region, eps_delta, delta_cap)
        else:
            trial = _line_search(problem, lin, proj, x, mu, eps_delta, delta_cap, guard)
        if trial is None:
            return outcome(x, it, STALLED, lin, proj)
        trial, mu_used, alpha = trial
        if _diverging(problem, x.q, trial.q, q_start):
            return outcome(trial, it, BOUNDARY)  # on the boundary of the open set
        mu = mu_used / 10 if mu_used > _MU_MIN else 0.0
        if alpha < 1 and _negligible(problem, x.q, trial.q, x.mt, trial.mt, xtol):
            return outcome(trial, it, STALLED, lin, proj)
        last_cost = x.cost
        x = trial
    return outcome(x, max_iter, MAX_ITER, lin, proj)


_SHRINK, _GROW = 0.25, 0.75  # ρ below which the trust radius shrinks, above which it grows


class _TrustRegion:
    """The trust region of the unconstrained iteration: a radius on ``‖Δq‖``, first the size of
    the start ``‖q_start‖`` (1 at the origin), as scipy's ``trf``; steps beyond it are damped,
    ``(H + μ I) Δq = rhs``, with μ just large enough. Measured on NIST StRD: MINPACK's scaled
    norm ``‖D Δq‖`` (``D²`` the running maximum of ``diag(Q̃)``) leaves Bennett5's first start
    crawling along its valley for 500 iterations; the plain norm solves all 54 cases. The
    parameter's units set the shape of the region: declare it in comparable units."""

    def __init__(self, q_start: np.ndarray) -> None:
        self.radius = float(np.linalg.norm(q_start)) or 1.0
        self.weights = np.ones(q_start.size)


def _trust_region_step(problem, lin, proj, x, region, eps_delta, delta_cap):
    """An acceptable point within the trust radius (Moré 1978; Nocedal & Wright §4.1): the
    projector's step if it fits, else the damped step with ``‖Δq‖`` at the radius. A step that
    lowers the violation δ is taken as eq. 18 takes it; otherwise a step is taken when the
    cost falls by more than 1e-4 of what the linearisation predicts (ratio
    ``ρ``); the radius shrinks to a quarter of the step when ``ρ < ¼`` (or the step is
    refused) and doubles when ``ρ > ¾``. Returns (point, μ, 1) or None."""
    length = float(np.linalg.norm(proj.q - x.q))
    for attempt in range(_MAX_HALVINGS):
        mu = 0.0
        # the projector's step is tried first whatever its length: taken beyond the radius
        # only if the linearisation predicts its fall of the cost to 5 % (a linear problem in
        # one step, report §3.6)
        beyond = attempt == 0 and length > region.radius
        if attempt and length > region.radius:
            mu = _damping_for(problem, lin, region.radius, region.weights)
        target = proj if mu == 0.0 else solve(problem, lin, mu, region.weights)
        trial = _restored(problem, target.q, target.mt)
        s = trial.q - x.q
        size = float(np.linalg.norm(s))
        pred = float(s @ lin.rhs - 0.5 * s @ lin.info @ s)  # the linearised fall of L²
        if trial.finite and _lowers_violation(trial, x, eps_delta):
            return trial, mu, 1.0  # eq. 18: the violation falls (the cost may rise meanwhile)
        if trial.finite and _acceptable(trial, x, eps_delta, delta_cap):
            rounding = pred <= 1e-13 * x.cost  # the cost's rounding level: no ratio to read
            rho = (x.cost - trial.cost) / pred if pred > 0.0 else 0.0
            if mu == 0.0 and beyond and not abs(rho - 1.0) <= 0.05:
                continue
            if rounding or rho > 1e-4:
                if rho < _SHRINK and not rounding:
                    region.radius = 0.25 * size
                elif rho > _GROW:
                    region.radius = max(region.radius, 2.0 * size)
                return trial, mu, 1.0
        if mu == 0.0 and beyond:
            continue  # the projector's step beyond the radius: damp it
        region.radius = 0.25 * (min(region.radius, size) if np.isfinite(size) else region.radius)
        if not region.radius > 0.0:
            return None
    return None


def _damping_for(problem: Problem, lin: Linearisation, radius: float,
                 weights: np.ndarray) -> float:
    """The damping μ (of ``μ diag(weights)``) whose step has ``‖Δq‖`` just within ``radius``
    (bisection on log μ)."""

    def size(log_mu: float) -> float:
        return float(np.linalg.norm(solve(problem, lin, 10.0 ** log_mu, weights).q - lin.x.q))

    lo, hi = -12.0, 12.0
    while size(hi) > radius and hi < 300.0:
        lo, hi = hi, 2.0 * hi
    while hi - lo > 0.02:
        mid = 0.5 * (lo + hi)
        if size(mid) > radius:
            lo = mid
        else:
            hi = mid
    return 10.0 ** hi


def _line_search(problem, lin, proj, x, mu, eps_delta, delta_cap, guard=None):
    """Find an acceptable point: the report's step (or the damped one the last iteration
    needed) — as it is, or else with its parameter restored onto the constraints (a
    second-order correction) — halved back towards ``x`` a few times as eq. 18 does; if
    still refused, damp more (Levenberg–Marquardt, tenfold, up to ``_MU_MAX``) and halve
    again — at the last damping level for as long as eq. 18 would. Returns (point, μ used,
    α) or None."""
    root = None  # the information's closest square root, the metric of the correction
    correctable = bool(x.c0.size)
    while True:
        target = proj if mu == 0.0 else solve(problem, lin, mu)
        alpha = 1.0
        for _ in range(_MAX_HALVINGS if mu >= _MU_MAX else _HALVINGS_PER_DAMPING):
            q = x.q + alpha * (target.q - x.q)
            mt = tuple(a + alpha * (b - a) for a, b in zip(x.mt, target.mt, strict=True))
            # the plain step first (eq. 18: linear problems in one step, Newton's iterates);
            # if it lowers the cost but is refused for its violation — curvature of the
            # constraints, the Maratos effect — with its second-order correction onto them
            trial = _restored(problem, q, mt)
            if correctable and trial.finite and trial.cost < x.cost and \
                    not _acceptable(trial, x, eps_delta, delta_cap):
                if root is None:
                    root = closest_sqrt(lin.info, problem.eps)
                # second order: small against the step, else this is no Maratos effect. In
                # the step's metric first (it moves what the data do not see, a slack,
                # first); without slacks, else in the Euclidean one, the textbook
                # correction: a direction the data see only weakly (a focal length near a
                # pure rotation) makes the metric's correction refused, and the iteration
                # would crawl along it (a rotation fit: 102 iterations, now 10)
                metrics = (root,) if problem.relations is not None else (root, np.eye(q.size))
                chosen = None
                for metric in metrics:
                    corrected = _restored(problem, q, mt, metric)
                    if np.linalg.norm(corrected.q - q) > 0.5 * np.linalg.norm(q - x.q):
                        continue
                    accepted = _acceptable(corrected, x, eps_delta, delta_cap)
                    if chosen is None or accepted:
                        chosen = corrected
                    if accepted:
                        break
                if chosen is not None:
                    trial = chosen
            # once the model's inequalities hold, they hold at every later iterate
            if (guard is None or guard(trial.q)) and _acceptable(trial, x, eps_delta, delta_cap):
                return trial, mu, alpha
            alpha /= 2
        if mu >= _MU_MAX:
            return None
        mu = max(10 * mu, _MU_MIN)
