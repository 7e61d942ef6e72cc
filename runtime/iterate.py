"""The non-linear iteration of the report (eq. 18), globalised by a trust region on restored
points, its end verified (SPEC §2: a success is a local minimum).

Report rule: step ``x_{n+1} = P(x_n)`` while the violation ``δ = ‖c(x)‖∞`` does not grow,
else halve back. On errors-in-variables problems that rule cannot tell a good step from a
bad one — corrected measures can always be made to satisfy their equations — so here:

Restored points (ours). Every point the iteration compares has its parameter moved back
onto ``c0(q) = 0`` (a few Gauss–Newton steps in the metric of the information, a
retraction) and its measures projected onto their equations for that ``q`` (report eq. 22,
iterated to convergence). The cost at such a point is the profile ``F(q) = min L²`` over the
corrected measures, a function of ``q`` alone, and the projector's right-hand side is its
exact gradient (eq. 44's multipliers): ``P`` is a Gauss–Newton step on ``F``.

Trust region (ours; Moré 1978, Nocedal & Wright §4). The projector's step is tried first
whatever its length and taken when the cost falls as the linearisation predicts, to 5 %
(a linear problem in one step, Newton's iterates: report §3.6); otherwise a step within a
radius on ``‖Δq‖`` (Levenberg–Marquardt damping of the parameter block, the linearised
equations still solved exactly) is taken when the cost falls by at least 1e-4 of the
prediction, the radius shrinking or growing with the ratio ``ρ`` of actual to predicted
fall. On curved constraints the prediction includes the multipliers' curvature,
``λ0ᵀ c0(q + s)``, so ``ρ`` tends to one. The first radius is the size of the start, as in
scipy's ``trf``. While the start is not yet on its equations (a minimal solve that failed),
eq. 18's rule is kept: a step is taken when it lowers the violation.

Inequalities (appendix F): once an iterate satisfies the model's inequality relations, a
trial point that breaks them is refused; a strict relation whose slack diverges stops the
iteration at the boundary (status 4).

Starts (ours). The projector's step from the observed measures (ODRPACK's first step) is
tried first; when the descent from there fails, the same step damped to the first trust
radius, then the restored start with every step inside the trust region, then the restored
start as the first.

The end (:mod:`.verify`): wherever the iteration stops, the point is checked — stationary
(the Newton decrement of the projector's step small against the cost), no negative
curvature of the Lagrangian on the constraints' tangent space (finite differences of the
exact gradient), every parameter seen by the data, no slope along a direction the step no
longer sees. A saddle or a maximum (report footnote 5) is left along its negative-curvature
direction and the iteration goes on; only a verified minimum is status 0. An iteration that
runs off along a lost direction (five rounds in a row, the parameter growing) stops there.

Status codes (``FitResult.status``):
0 converged — a verified local minimum;
1 iteration cap reached before a verified minimum;
2 stalled — no step lowers the cost while the point is not stationary;
3 numerical failure — non-finite values at the start or in the projector;
4 at the boundary of a strict inequality (``c > 0``, ``c != 0``: appendix F) — the
  relation's slack diverges (``c = 1/s² → 0``, below 1e-8 of its start): no minimum inside
  the open set the model allows; returns the first iterate that close to the boundary;
5 saddle — negative curvature that no step along it could use;
6 plateau — the equations no longer depend on some parameter, or on some direction along
  which the cost still falls (the minimum is not attained, or the model is not identifiable
  from these measures);
7 infeasible — the measures or the constraints could not be brought onto their equations;
8 stationary, not verified — the end of an intermediate refinement run without the checks
  (``verify=False``: a robust search's local optimisation, which keeps only its estimate).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .projector import (
    _ROUNDING,
    Linearisation,
    Point,
    Problem,
    Projection,
    evaluate,
    linearise,
    parameter_step,
    quadratic,
    restore_parameter,
    solve,
)
from .restoration import nearer_points, restore_measures
from .sqrt import closest_sqrt, reduced_solve, reduced_sqrt, triangular_solve
from .verify import (
    Verdict,
    cost_rounding,
    escape,
    feasible,
    lost_direction,
    stationary,
    verify,
)

CONVERGED, MAX_ITER, STALLED, FAILED, BOUNDARY, SADDLE, PLATEAU, INFEASIBLE, UNVERIFIED = \
    range(9)
MESSAGES = {
    CONVERGED: "converged: a local minimum (stationary, no negative curvature)",
    MAX_ITER: "stopped: iteration cap reached",
    STALLED: "stalled away from a stationary point: no step lowers the cost",
    FAILED: "numerical failure: non-finite values",
    BOUNDARY: "at the boundary of a strict inequality: its slack diverges (no minimum inside "
              "the open set the model allows); returning the last point inside",
    SADDLE: "saddle point: the cost falls along a direction no step could follow",
    PLATEAU: "plateau",
    INFEASIBLE: "infeasible: the equations could not be satisfied near this point",
    UNVERIFIED: "stationary, not verified (an intermediate refinement)",
}
_RETRACTION = 64  # Gauss–Newton steps onto c0 = 0, at most (a double root: linear)
_ACCEPT = 1e-4  # ρ above which a step within the radius is taken
_EXACT = 0.05  # |ρ − 1| within which the projector's step is taken whatever its length
_SHRINK, _GROW = 0.25, 0.75  # ρ below which the radius shrinks, above which it grows
_STAGNATION = 5  # accepted steps in a row that lower the cost by rounding only
_ESCAPES = 6  # negative-curvature escapes in one fit, at most
_COST_NOISE = 1e-13  # the relative rounding of a cost summed over many measures
_MAX_REFUSALS = 40  # trial points refused in one iteration, at most
_LINE_STEPS = 3  # halvings of the projector's step before damping
_JOINT = 1e3  # the joint start's step, at most, in first trust radii
_LOST_ROUNDS = 5  # iterations in a row with a lost direction that still falls: a run-off
_SLOW = 1e-6  # a fall of the cost below this share of it: a slow step
_LOOK = 10  # iterations between two looks for nearer branches during a crawl
_LINEAR = 0.1  # a fall above this share of the previous one: a linear rate
_CRAWL = 3  # such falls in a row make a crawl
_GROWING = 1.0  # ... while the parameter grows at each (in the scaling of the start)
_JOINT_STEPS = 4  # joint steps (linearised at the unrestored measures) of the start, at most


@dataclass(frozen=True)
class Outcome:
    point: Point
    lin: Linearisation | None
    proj: Projection | None
    iterations: int
    status: int
    message: str
    start_violation: float = 0.0
    verdict: Verdict | None = None


def iterate(problem: Problem, q_start: np.ndarray, max_iter: int = 100,
            xtol: float = 1e-10, verify: bool = True) -> Outcome:
    """Run the iteration from ``(q_start, m)``; never raises on numerical trouble.

    ``verify=False``: a stationary end is not checked (no curvature, no escapes; status
    :data:`UNVERIFIED`), nor one where ``max_iter`` stops the iteration — for an
    intermediate refinement whose estimate alone is used."""
    with np.errstate(all="ignore"):
        return _Run(problem, max_iter, xtol, verify).run(q_start)


def negligible(problem: Problem, q_old, q_new, mt_old, mt_new, xtol: float) -> bool:
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


def restored(problem: Problem, q: np.ndarray, mt, root: np.ndarray | None = None,
             iterations: int | None = None, retract: bool = True) -> tuple[Point, float]:
    """The point with ``q`` moved back onto ``c0 = 0`` (a retraction, in the metric ``root``:
    the information's closest square root; Euclidean when that fails) and its measures
    projected onto their equations for that ``q`` (report eq. 22, iterated). Returns the
    point and its violation ``E²`` in cost units: the measures' whitened violations plus
    ``‖c0‖²`` in the metric of the step. ``retract=False``: ``q`` as it is."""
    if retract and problem.c0(q, problem.k)[0].size:
        best = None
        for metric in ((root, None) if root is not None else (None,)):
            candidate = restore_parameter(problem, q, metric, _RETRACTION)
            worst = float(np.max(np.abs(problem.c0(candidate, problem.k)[0])))
            if best is None or worst < best[1]:
                best = (candidate, worst)
            if worst <= _c0_rounding(candidate):
                break
        q = best[0]
    x, violation = restore_measures(problem, q, mt) if iterations is None else \
        restore_measures(problem, q, mt, iterations)
    return x, violation + _c0_violation(x, root)


def _c0_rounding(q: np.ndarray) -> float:
    return 1e-13 * (1.0 + float(np.max(np.abs(q), initial=0.0))) ** 2


def _c0_violation(x: Point, root: np.ndarray | None) -> float:
    """``‖c0‖²`` whitened by ``C0 Q̃⁻¹ C0ᵀ`` (in cost units: what moving ``q`` onto the
    constraints would cost the data), or 0 when it is below rounding."""
    if not x.c0.size or float(np.max(np.abs(x.c0))) <= _c0_rounding(x.q):
        return 0.0
    if root is None:
        return float(x.c0 @ x.c0)
    C0bar_t = triangular_solve(root, x.C0.T)
    L0, kept0 = reduced_sqrt(C0bar_t.T @ C0bar_t)
    e0 = reduced_solve(L0, kept0, x.c0)
    return float(e0 @ e0) if np.all(np.isfinite(e0)) else np.inf


class _Run:
    """One run of the iteration (its state between iterations)."""

    def __init__(self, problem: Problem, max_iter: int, xtol: float, verify: bool):
        self.problem = problem
        self.max_iter = max_iter
        self.xtol = xtol
        self.verify = verify
        self.escapes = 0
        self.info_start = None  # diagonal of the information at the start (plateaus)
        self.strict = False

    def run(self, q_start: np.ndarray) -> Outcome:
        problem = self.problem
        raw = evaluate(problem, q_start, tuple(ch.m.copy() for ch in problem.channels))
        self.delta0 = raw.delta
        if not raw.finite:
            return self.outcome(raw, 0, FAILED, " at the starting point")
        self.q_start = q_start
        # the start moved onto its constraints (Newton's method in the information's metric,
        # report §3.6); where that fails, eq. 18's steps take it there
        lin0, proj0 = _project(problem, raw)
        root = None if lin0 is None else closest_sqrt(lin0.info, problem.eps)
        x, violation = restored(problem, q_start, raw.mt, root)
        if not (x.finite and _on_constraints(x, violation)):
            x, violation = restored(problem, q_start, raw.mt, retract=False)
        self.radius = self.size0 = float(np.linalg.norm(q_start)) or 1.0
        # ODRPACK's scaling (Boggs, Byrd & Schnabel): each component measured against its
        # own magnitude at the start, floored at a tenth of the typical one
        typical = float(np.sqrt(np.mean(q_start**2))) or 1.0
        self.scale = self.size0 / np.maximum(np.abs(q_start), 0.1 * typical)
        if not x.finite:
            return self.descend(raw, np.inf)
        if proj0 is None:
            return self.descend(x, violation)
        joint = self.joint_start(x, violation, proj0, root)
        # the starts, each tried when the descents before failed: the joint step's point
        # (lower, or on the equations); the joint step damped to the first trust radius
        # (ODRPACK's first steps: a full step can jump into another valley that the
        # profile cost, lower there, cannot tell from the right one); the restored start
        # with every step within the trust region (a rate whose sign flips at once, then
        # runs off to where the model degenerates); the restored start as the first
        restored_start = (x, violation)
        plan = [(lambda: joint, False)]
        if _on_constraints(x, violation):
            if self.verify:
                plan.append((lambda: self.damped_joint(lin0, root), False))
                plan.append((lambda: restored_start, True))
            if joint[0] is not x:
                plan.append((lambda: restored_start, False))
        best, iterations = None, 0
        for start, strict in plan:
            if best is not None:
                # an intermediate refinement (verify=False) keeps a descent unless it failed
                if best.status == CONVERGED or (
                        not self.verify and best.status in (UNVERIFIED, MAX_ITER)):
                    break
                self.radius, self.escapes, self.info_start = self.size0, 0, None
            point = start()  # built only when needed (the damped step costs a bisection)
            if point is None:
                continue
            self.strict = strict
            out = self.descend(*point)
            self.strict = False
            iterations += out.iterations
            if best is None or out.status == CONVERGED or out.point.cost < best.point.cost:
                best = out
        return replace(best, iterations=iterations)

    def descend(self, x: Point, violation: float) -> Outcome:
        """The iteration from the point ``x`` (restored, or off its equations)."""
        problem = self.problem
        q_start = self.q_start
        since_progress = since_lost = next_look = crawl = 0
        last_fall = np.inf
        last_size = np.inf
        lin = proj = None
        for it in range(1, self.max_iter + 1):
            lin, proj = _project(problem, x)
            if lin is None:
                return self.outcome(x, it, FAILED, " in the projector")
            if self.info_start is None:
                self.info_start = np.abs(np.diagonal(lin.info)).copy()
            x_feasible = feasible(violation, x.cost)
            # a run-off towards a degenerate limit of the model: the equations lose a
            # direction along which the cost still falls, and the parameter grows along it
            # round after round (one passing through such a region comes back)
            size = float(np.linalg.norm(self.scale * x.q))
            lost = lost_direction(problem, x, lin) if x_feasible and self.verify and \
                size > _GROWING * last_size else ""
            since_lost, last_size = (since_lost + 1 if lost else 0), size
            if since_lost >= _LOST_ROUNDS:
                return self.outcome(x, it, PLATEAU, lost, lin, proj)
            model = lagrangian(problem, lin, proj)
            if x_feasible and (stationary(problem, *model) or _at_rounding(x.q, model[1].q)) \
                    and negligible(problem, x.q, model[1].q, x.mt, model[1].mt, self.xtol):
                end = self.end(x, lin, proj, it)
                if end is not None:
                    return end
                x, violation = self.x, self.violation
                continue
            step = self.step(x, violation, *model)
            if step is None:  # nothing acceptable, down to the rounding level
                end = self.end(x, lin, proj, it)
                if end is not None:
                    return end
                x, violation = self.x, self.violation
                continue
            trial, trial_violation = step
            if _diverging(problem, x.q, trial.q, q_start):
                return self.outcome(trial, it, BOUNDARY)
            fall = x.cost - trial.cost
            progress = not _on_constraints(x, violation) or fall > 1e-14 * x.cost
            since_progress = 0 if progress else since_progress + 1
            x, violation = trial, trial_violation
            # a crawl: small falls shrinking at a linear rate (Gauss–Newton at a large
            # residual), not Newton's quadratic one
            crawl = crawl + 1 if (progress and fall <= _SLOW * x.cost and
                                  fall > _LINEAR * last_fall) else 0
            last_fall = fall
            if crawl >= _CRAWL and self.verify and self.escapes < _ESCAPES and \
                    it >= next_look and _on_constraints(x, violation):
                # is a measure on a farther branch than it need be?
                next_look = it + _LOOK
                moved = self.nearer(x, closest_sqrt(lin.info, problem.eps))
                if moved is not None:
                    self.escapes += 1
                    x, violation = moved
                    continue
            if since_progress >= _STAGNATION:  # rounding noise about the point
                end = self.end(x, None, None, it)
                if end is not None:
                    return end
                x, violation = self.x, self.violation
                since_progress = 0
        lin, proj = _project(problem, x)
        if self.verify and lin is not None and feasible(violation, x.cost) and \
                self.nearer(x, closest_sqrt(lin.info, problem.eps)) is None:
            verdict = verify(problem, x, lin, proj, self.info_start,
                             model=lagrangian(problem, lin, proj))
            if verdict.minimum:
                return self.outcome(x, self.max_iter, CONVERGED, "", lin, proj, verdict)
        return self.outcome(x, self.max_iter, MAX_ITER, "", lin, proj)

    def joint_start(self, x: Point, violation: float, proj0: Projection, root):
        """The restored start, or the projector's step from the raw start (the measures as
        observed, not yet on their equations) when that step lowers the profile cost — or
        reaches the equations where the start could not (a circle of negative radius).

        That step is Gauss–Newton on the joint problem in ``(q, m̃)`` linearised at the
        observations — ODRPACK's first step (its corrections start at zero): the weights of
        the residuals are frozen at the start, so it crosses barriers of the profile ``F``
        that a descent on ``F`` cannot (a line's slope through zero when the abscissas'
        errors dominate some measures)."""
        best = (x, violation)
        proj = proj0
        for _ in range(_JOINT_STEPS):  # the joint iteration, on while its points improve
            s = proj.q - x.q
            if not float(np.sqrt(s @ (self.weights(x.q) * s))) <= _JOINT * self.radius:
                break  # a jump no trust region would take (a slack to 1e8)
            trial = restored(self.problem, proj.q, proj.mt, root)
            if not (trial[0].finite and _on_constraints(*trial) and (
                    trial[0].cost < best[0].cost or not _on_constraints(*best)) and (
                    self.problem.relations is None or self.problem.relations(trial[0].q))):
                break
            best = trial
            _, proj = _project(self.problem, evaluate(self.problem, proj.q, proj.mt))
            if proj is None:
                break
        return best

    def damped_joint(self, lin0: Linearisation, root) -> tuple[Point, float] | None:
        """The projector's step from the raw start damped to the first trust radius,
        restored; None when it cannot be restored onto the equations."""
        damped = _damped(self.problem, lin0, self.size0, self.weights(self.q_start))
        trial = restored(self.problem, damped.q, damped.mt, root)
        return trial if trial[0].finite and _on_constraints(*trial) else None

    def end(self, x: Point, lin, proj, it: int):
        """Verify ``x``; return the outcome, or None after an escape from a saddle (the
        iteration goes on from ``self.x``)."""
        problem = self.problem
        if lin is None or lin.x is not x:
            lin, proj = _project(problem, x)
            if lin is None:
                return self.outcome(x, it, FAILED, " in the projector")
        if not self.verify:
            return self.outcome(x, it, UNVERIFIED, "", lin, proj)
        root = closest_sqrt(lin.info, problem.eps)
        _, violation = restored(problem, x.q, x.mt, root)
        if not feasible(violation, x.cost):
            return self.outcome(x, it, INFEASIBLE, "", lin, proj)
        if self.escapes < _ESCAPES:  # a measure nearer on another branch: go on from there
            moved = self.nearer(x, root)
            if moved is not None:
                self.escapes += 1
                self.x, self.violation = moved
                return None
        model = lagrangian(problem, lin, proj)
        verdict = verify(problem, x, lin, proj, self.info_start, model=model,
                         at_rounding=_at_rounding(x.q, model[1].q))
        if verdict.minimum:
            return self.outcome(x, it, CONVERGED, "", lin, proj, verdict)
        if verdict.plateau:
            return self.outcome(x, it, PLATEAU, verdict.plateau, lin, proj, verdict)
        if not verdict.stationary:
            return self.outcome(x, it, STALLED, verdict.describe(), lin, proj, verdict)
        # a stationary point with negative curvature: leave it along that direction
        if self.escapes < _ESCAPES and verdict.direction is not None:
            self.escapes += 1
            moved = escape(problem, x, lin, verdict, self.retract)
            if moved is not None:
                self.x, self.violation = moved
                self.radius = max(self.radius, float(np.linalg.norm(moved[0].q - x.q)))
                return None
        return self.outcome(x, it, SADDLE, verdict.describe(), lin, proj, verdict)

    def nearer(self, x: Point, root) -> tuple[Point, float] | None:
        """``x`` with its measures at nearer points of their equations (another branch),
        restored, when that lowers the cost; else None."""
        problem = self.problem
        nearer = nearer_points(problem, x)
        if nearer is None:
            return None
        moved = restored(problem, x.q, nearer.mt, root, retract=False)
        if moved[0].finite and _on_constraints(*moved) and moved[0].cost < x.cost - (
                _COST_NOISE * x.cost + cost_rounding(problem)):
            return moved
        return None

    def retract(self, q: np.ndarray, mt, root=None) -> tuple[Point, float]:
        return restored(self.problem, q, mt, root)

    def outcome(self, x, it, status, detail="", lin=None, proj=None, verdict=None) -> Outcome:
        """``detail``: a phrase appended to the status's message (one that starts with a
        space is appended as it is, others after a colon)."""
        message = MESSAGES[status] + (detail if detail.startswith(" ") else
                                      f": {detail}" if detail else "")
        return Outcome(x, lin, proj, it, status, message, self.delta0, verdict)

    # -- one step -------------------------------------------------------------------------
    def step(self, x: Point, violation: float, lin: Linearisation, proj: Projection):
        """An acceptable restored point: the projector's step; else that step shortened
        (a line search along the Gauss–Newton direction, which follows a curved valley
        where damping would turn towards the gradient); else a damped step within the trust
        radius. Returns (point, violation) or None."""
        problem = self.problem
        root = closest_sqrt(lin.info, problem.eps)
        guard = problem.relations if problem.relations is not None and \
            problem.relations(x.q) else None
        lam0 = _multipliers(x, lin)
        on = _on_constraints(x, violation)
        weights = self.weights(x.q)
        full = proj.q - x.q
        length = float(np.sqrt(full @ (weights * full)))
        alpha = 1.0
        # the projector's step, then — when it was within the radius — shortened
        line_steps = 0 if length > self.radius else _LINE_STEPS
        for attempt in range(_MAX_REFUSALS):
            line = attempt <= line_steps and not (self.strict and length > self.radius)
            beyond = attempt == 0 and length > self.radius and not self.strict
            if line:
                target_q = x.q + alpha * full
                target_mt = tuple(a + alpha * (b - a) for a, b in zip(x.mt, proj.mt,
                                                                      strict=True))
            else:
                damped = _damped(problem, lin, self.radius, weights)
                target_q, target_mt = damped.q, damped.mt
            s = target_q - x.q
            size = float(np.sqrt(s @ (weights * s)))
            if not on:
                taken = self.towards_constraints(x, violation, target_q, target_mt, root,
                                                 guard)
                if taken is not None:
                    return taken
            else:
                trial = restored(problem, target_q, target_mt, root)
                if trial[0].finite and (guard is None or guard(trial[0].q)) and \
                        _on_constraints(*trial):
                    pred = _predicted_fall(problem, lin, x, s, target_q, lam0)
                    rho = (x.cost - trial[0].cost) / pred if pred > 0.0 else -np.inf
                    # a fall the cost cannot resolve: the model is trusted, the cost must
                    # not rise beyond its rounding (Newton's last steps, §3.6)
                    noise = _COST_NOISE * x.cost + cost_rounding(problem)
                    rounding = abs(pred) <= 1e2 * noise and trial[0].cost <= x.cost + noise
                    if beyond:
                        if abs(rho - 1.0) <= _EXACT:
                            self.radius = max(self.radius, 2.0 * size)
                            return trial
                    elif rounding or rho > _ACCEPT:
                        if rho < _SHRINK and not rounding:
                            self.radius = _SHRINK * size
                        elif rho > _GROW:
                            self.radius = max(self.radius, 2.0 * size)
                        return trial
            if line:
                alpha /= 2
            if beyond or line:
                continue
            self.radius = _SHRINK * (min(self.radius, size) if np.isfinite(size)
                                     else self.radius)
            if not self.radius > 1e-15 * (1.0 + float(np.linalg.norm(x.q))):
                return None
        return None

    def weights(self, q: np.ndarray) -> np.ndarray:
        """The trust region's norm, ``‖Δq‖² = Σ w_j Δq_j²``: Euclidean, but for the slacks of
        strict relations (``c = 1/s²``), whose steps are measured relative to themselves —
        they diverge geometrically at the boundary of the open set."""
        w = self.scale**2
        for index, _ in self.problem.strict_slacks:
            w[index] = (self.size0 / max(abs(q[index]), np.finfo(float).tiny)) ** 2
        return w

    def towards_constraints(self, x: Point, violation: float, target_q, target_mt, root,
                            guard):
        """Eq. 18 while ``x`` is off its equations (its start could not be moved onto them):
        the trial point is taken when it lowers the violation, or keeps it (to its rounding
        level) without raising the cost; once close to the constraints, it is moved onto
        them (the trust region then takes over)."""
        problem = self.problem
        trial = restored(problem, target_q, target_mt, root, retract=False)
        if not (trial[0].finite and (guard is None or guard(trial[0].q))
                and _lowers_violation(trial, x, violation)):
            return None
        if feasible(trial[1], trial[0].cost):
            onto = restored(problem, trial[0].q, trial[0].mt, root)
            if onto[0].finite and _on_constraints(*onto):
                return onto
        return trial


def _lowers_violation(trial: tuple[Point, float], x: Point, violation: float) -> bool:
    """Eq. 18's rule on restored points: the violation falls, or stays within its rounding
    level (``1e-14`` of the cost) while the cost does not rise."""
    noise = 1e-14 * max(1.0, x.cost)
    return trial[1] < (1 - 1e-4) * violation - noise or (
        trial[1] <= violation + noise and trial[0].cost <= x.cost)


def _on_constraints(x: Point, violation: float) -> bool:
    """The measures are on their equations (the violation negligible against the cost) and
    the parameter on its constraints to their rounding level: from here on, every trial
    point is moved back onto them. Until then eq. 18 rules (a Newton iteration on the
    constraints, report §3.6)."""
    return feasible(violation, x.cost) and (
        not x.c0.size or float(np.max(np.abs(x.c0))) <= _c0_rounding(x.q))


def _at_rounding(q: np.ndarray, q_new: np.ndarray) -> bool:
    """The step moves no component beyond the rounding level of ``q``."""
    return bool(np.all(np.abs(q_new - q) <= _ROUNDING * np.max(np.abs(q), initial=0.0)))


def _project(problem: Problem, x: Point):
    try:
        lin = linearise(problem, x)
        return lin, solve(problem, lin)
    except (np.linalg.LinAlgError, ValueError, ZeroDivisionError, FloatingPointError):
        return None, None


def lagrangian(problem: Problem, lin: Linearisation,
               proj: Projection) -> tuple[Linearisation, Projection]:
    """The linearisation with the curvature of the constraints, ``Σ λ0k ∇²c0k`` (its positive
    part), added to the information — the Hessian of the Lagrangian the step's model needs on
    curved constraints: a slack ``s`` of ``c − s² = 0`` at an active inequality (``s = 0``)
    has no information from the data, and without the curvature ``−2 λ0`` the model would
    move it without bound — and the projector's point with it. The data's own ``lin, proj``
    when the constraints are linear or their multipliers vanish."""
    x = lin.x
    lam0 = _multipliers(x, lin)
    if not lam0.size or not np.any(lam0):
        return lin, proj
    K = _constraint_curvature(problem, x.q, lam0)
    for index, _ in problem.strict_slacks:
        # a strict relation's slack (c = 1/s²) diverges at the boundary: its curvature would
        # hold it to steps of s/3 (Newton on 1/s²), the trust region lets it grow
        K[index, :] = K[:, index] = 0.0
    w, V = np.linalg.eigh(K)
    top = float(np.max(np.abs(np.diagonal(lin.H)), initial=0.0))
    if not np.all(np.isfinite(w)) or float(w.max(initial=0.0)) <= 1e-14 * top:
        return lin, proj
    K = (V * np.maximum(w, 0.0)) @ V.T
    model = replace(lin, H=lin.H + K, info=lin.info + K)
    try:
        return model, solve(problem, model)
    except (np.linalg.LinAlgError, ValueError, ZeroDivisionError, FloatingPointError):
        return lin, proj


def _constraint_curvature(problem: Problem, q: np.ndarray, lam0: np.ndarray) -> np.ndarray:
    """``Σ λ0k ∇²c0k`` by central differences of the constraints' Jacobian (exact for the
    quadratic constraints of unit norms and slacks, up to rounding)."""
    n = q.size
    K = np.zeros((n, n))
    scale = float(np.max(np.abs(q), initial=0.0))
    for j in range(n):
        h = 1e-5 * max(abs(q[j]), 1e-3 * scale, 1e-8)
        up, down = q.copy(), q.copy()
        up[j] += h
        down[j] -= h
        K[:, j] = (problem.c0(up, problem.k)[1] - problem.c0(down, problem.k)[1]).T @ lam0 / (2 * h)
    return 0.5 * (K + K.T)


def _multipliers(x: Point, lin: Linearisation) -> np.ndarray:
    """``λ0``: least-squares multipliers of the parameter constraints at ``x``,
    ``C0ᵀ λ0 = −∇F``."""
    if not x.C0.shape[0]:
        return np.zeros(0)
    lam, *_ = np.linalg.lstsq(x.C0.T, -lin.gradient, rcond=None)
    return lam


def _predicted_fall(problem: Problem, lin: Linearisation, x: Point, s: np.ndarray,
                    target_q: np.ndarray, lam0: np.ndarray) -> float:
    """The fall of the cost the linearisation predicts for the step ``s`` (Gauss–Newton
    model of the profile), the retraction onto curved constraints included:
    ``−(gᵀs + ½ sᵀ Q̃ s + λ0ᵀ c0(q + s))``."""
    fall = -float(lin.gradient @ s + 0.5 * s @ lin.info @ s)
    if lam0.size:
        fall -= float(lam0 @ problem.c0(target_q, problem.k)[0]) - float(lam0 @ x.c0)
    return fall


def _damped(problem: Problem, lin: Linearisation, radius: float,
            weights: np.ndarray) -> Projection:
    """The projector's point with the parameter's step damped to ``radius``
    (Levenberg–Marquardt, ``‖Δq‖_w`` just within it)."""
    return solve(problem, lin, _damping_for(problem, lin, radius, weights), weights)


def _damping_for(problem: Problem, lin: Linearisation, radius: float,
                 weights: np.ndarray) -> float:
    """The damping μ (of ``μ diag(w)``) whose step has ``‖Δq‖_w`` just within ``radius``
    (bisection on log μ)."""

    def size(log_mu: float) -> float:
        s = parameter_step(problem, lin, 10.0 ** log_mu, weights)
        return float(np.sqrt(s @ (weights * s)))

    lo, hi = -12.0, 12.0
    if size(hi) > radius:  # the constraints' linearisation alone asks more: its step
        return 10.0**hi
    while hi - lo > 0.02:
        mid = 0.5 * (lo + hi)
        if size(mid) > radius:
            lo = mid
        else:
            hi = mid
    return 10.0 ** hi


def _diverging(problem: Problem, q_old: np.ndarray, q_new: np.ndarray,
               start: np.ndarray) -> bool:
    """A slack of a strict inequality diverges: it grows by a tenth at least in this step
    and its relation ``c = 1/s²`` (``1/s`` for ``c != 0``) has fallen below 1e-8 of its
    starting value. The parameter is then within that of the boundary of the open set the model
    allows; letting the slack grow on would only make its equation ill-conditioned."""
    for index, power in problem.strict_slacks:
        s_old, s_new = abs(q_old[index]), abs(q_new[index])
        if s_new > 1.1 * s_old and (abs(start[index]) / s_new) ** power < 1e-8:
            return True
    return False
