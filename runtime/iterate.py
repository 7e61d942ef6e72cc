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
up to a hundred times the radius and taken when the cost falls as the linearisation
predicts, to 5 % (a linear problem in one step, Newton's iterates: report §3.6) — a longer
one, whose restored point is costly and may lie in another valley, is not tried on its
prediction alone (docs/engine.md, thirty-second session); otherwise a step within a
radius on ``‖Δq‖`` (Levenberg–Marquardt damping of the parameter block, the linearised
equations still solved exactly) is taken when the cost falls by at least 1e-4 of the
prediction, the radius shrinking or growing with the ratio ``ρ`` of actual to predicted
fall. On curved constraints the prediction includes the multipliers' curvature,
``λ0ᵀ c0(q + s)``, so ``ρ`` tends to one. The first radius is the size of the start, as in
scipy's ``trf``. The damping ``μ`` that holds a step to the radius is bisected on
``log10 μ`` in [−12, 12], widened to twelve decades either side of the Hessian's scale
(its largest diagonal) where that range does not hold it: the steps do not depend on the
information's overall scale (σ stated in other units). While the start is not yet on its
equations (a minimal solve that failed), eq. 18's rule is kept: a step is taken when it
lowers the violation.

Inequalities (appendix F): once an iterate satisfies the model's inequality relations, a
trial point that breaks them is refused; a strict relation whose slack diverges stops the
iteration at the boundary (status 4).

Starts (ours). The projector's step from the observed measures (ODRPACK's first step) is
tried first, and the joint problem's Gauss–Newton steps on from its point while they lower
the cost (four steps at most; a step's restoration, most of its cost, is made for the first
point and the last only when every step lowers it:
:func:`kanagen.runtime.engine.iterate.joint_start`); when the descent from there fails, the
same step damped to the first trust radius, then the restored start with every step inside
the trust region, then the restored start as the first; and when none of them ends at a
verified minimum, the joint step's point once more with the trust region in Marquardt's
scaling (the information's diagonal, each kept at its largest: MINPACK's) instead of the
start's magnitudes (ODRPACK's) — a valley whose parameters change by orders of magnitude
(NIST's MGH10) is crawled under the one and followed under the other.

The end (:mod:`.verify`): wherever the iteration stops, the point is checked — stationary
(the Newton decrement of the projector's step small against the cost), no negative
curvature of the Lagrangian on the constraints' tangent space (the profile's exact Hessian;
a negative eigenvalue confirmed by differences of its gradient; where the constraints'
gradients are dependent, a direction they leave free to first order but forbid to second
order is no tangent: no curve on them goes along it), every parameter seen by the data, no
slope along a direction the step no longer sees — and first, the constraints themselves
within rounding (each row of ``c0`` within the rounding of the components it involves, not
only their whitened violation, which a dropped pivot of dependent rows does not see; a slack
run off elsewhere does not loosen it). A saddle or a maximum
(report footnote 5) is left along its negative-curvature direction and the iteration goes
on; only a verified minimum is status 0. Where the measures have a lower cost at the
end's parameter (the nearer points of a restoration), the iteration goes on from there
with the radius its refused steps shrank started again. An iteration that runs off along a
lost direction (five rounds in a row, the parameter growing) stops there.

The iteration is one compiled kernel (:func:`kanagen.runtime.engine.iterate.run`, with the
checks of :mod:`kanagen.runtime.engine.verify`); this module runs it on a
:class:`~kanagen.runtime.projector.Problem` and words its outcome.

Status codes (``FitResult.status``):
0 converged — a verified local minimum;
1 iteration cap reached before a verified minimum (the message says when the point is off
  its equations or constraints);
2 stalled — no step lowers the cost while the point is not stationary;
3 numerical failure — non-finite values at the start or in the projector (at the start:
  the cost is infinite, the observed measures being off their equations);
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

from dataclasses import dataclass

import numpy as np

from kanagen.common.jit import interrupted

from .engine import iterate as engine
from .engine import points as engine_points
from .engine.data import arrays, pack_measures, per_channel, unpack_evals, unpack_measures
from .engine.measures import RESTORE_STEPS
from .projector import Point, Problem, kernel_metric
from .verify import Verdict, plateau_text

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


@dataclass  # output records, not frozen: a frozen dataclass's fields cost ~0.2 µs each to set
class Projected:
    """What a fit reports from the projector at its returned point: the information
    ``Q̃``, each measure's equations kept (per channel), the rows of ``C0`` kept and their
    rank, the residual E² (:func:`~kanagen.runtime.engine.iterate.projected_at`) and the
    covariance they give (:func:`~kanagen.runtime.results.constrained_covariance`; None:
    not computed yet)."""

    info: np.ndarray
    ranks: tuple
    C0: np.ndarray
    rank0: int
    residual: float
    covariance: np.ndarray | None = None


class Outcome:
    """What :func:`iterate` returns: the returned point's parameter ``q``, corrected
    measures ``mt`` (per channel), cost and violation ``delta``; the iterations, status and
    message; the start's violation; the report at the point (:class:`Projected`, None when
    not asked for or where the projector fails). The whole point (:attr:`point`, with its
    equations) and the checks' :attr:`verdict` are made when first read: a fit reads
    neither, and the Python run after a kernel call is most of a small fit's overhead."""

    __slots__ = ("q", "mt", "cost", "delta", "iterations", "status", "message",
                 "start_violation", "projected", "_point", "_verdict")

    def __init__(self, point, iterations: int, status: int, message: str,
                 start_violation: float = 0.0, verdict=None, projected: Projected | None = None,
                 head: tuple | None = None):
        # ``point``: a Point, or ``(A, values, width, at)`` to cut it from when read, with
        # ``head`` its ``q, mt, cost, delta`` (:func:`point_head`); ``verdict``: a Verdict,
        # None, or the arguments that make it
        if head is None:
            head = (point.q, point.mt, point.cost, point.delta)
        self.q, self.mt, self.cost, self.delta = head
        self.iterations, self.status, self.message = iterations, status, message
        self.start_violation, self.projected = start_violation, projected
        self._point, self._verdict = point, verdict

    @property
    def point(self) -> Point:
        if type(self._point) is tuple:
            self._point = unpack_point(*self._point)[0]
        return self._point

    @property
    def verdict(self) -> Verdict | None:
        if type(self._verdict) is tuple:
            self._verdict = _verdict(*self._verdict)
        return self._verdict


def iterate(problem: Problem, q_start: np.ndarray, max_iter: int = 100,
            xtol: float = 1e-10, verify: bool = True, report: bool = False) -> Outcome:
    """Run the iteration from ``(q_start, m)``; never raises on numerical trouble.

    ``verify=False``: a stationary end is not checked (no curvature, no escapes; status
    :data:`UNVERIFIED`), nor one where ``max_iter`` stops the iteration — for an
    intermediate refinement whose estimate alone is used. ``report``: the outcome carries
    what the projector gives at the returned point (:class:`Projected`)."""
    A = arrays(problem)
    q_start = np.ascontiguousarray(q_start, dtype=float).copy()
    try:
        (status, iterations, kind, stationary, plateau, ok, rank0, width, sizes, values,
         integers) = engine.run_flat(A, q_start, int(max_iter), float(xtol), bool(verify),
                                     bool(report))
    except SystemError as exc:
        if interrupted(exc):  # Ctrl-C, raised inside the kernel's boxing of its results
            raise KeyboardInterrupt from exc
        raise
    except (ValueError, ZeroDivisionError, np.linalg.LinAlgError) as exc:
        # the compiled linear algebra refuses non-finite matrices: a numerical failure
        x = evaluated(problem, q_start, unpack_measures(A, A.m))
        return Outcome(x, 0, FAILED, MESSAGES[FAILED] + f" ({exc})", np.inf,
                       head=(x.q, x.mt, np.inf, x.delta))
    status, iterations = int(status), int(iterations)
    delta0, decrement, cost, curvature, residual = values[:5].tolist()
    starts = point_starts(A, width, 5)  # the point from 5, then the verdict's vectors
    at = starts[8]
    head = point_head(A, values, starts)
    detail = _DETAILS.get(kind)
    at_start = status == FAILED and kind == engine.AT_START
    if at_start or status == INFEASIBLE:
        # the start's equations are not finite, or the end is off them: its cost (the
        # observed measures', 0, at the start) is no cost of a point on them, and must not
        # win a comparison of fits
        head = (*head[:2], np.inf, head[3])
    if at_start:
        detail += not_finite_at(A, problem, values, starts, width)
    n_direction, n_vector, n_info, n_covariance = sizes
    checked = status in (CONVERGED, STALLED, SADDLE) or kind == engine.PLATEAU_DETAIL
    if kind == engine.OFF_CONSTRAINTS:  # the returned point's ‖c‖∞ (eq. 18)
        detail = (" with the point off its equations or constraints" if status == MAX_ITER
                  else "") + f" (constraint_violation {head[3]:.3g})"
    verdict = None
    if checked or detail is None:  # the checks' verdict is reported or described
        verdict = (bool(stationary), decrement, cost, curvature,
                   values[at:at + n_direction] if n_direction else None, int(plateau),
                   values[at + n_direction:at + n_direction + n_vector], problem.names)
    if detail is None:
        verdict = _verdict(*verdict)
        detail = verdict.plateau if kind in (engine.LOST, engine.PLATEAU_DETAIL) else \
            verdict.describe()
    message = MESSAGES[status] if not detail else MESSAGES[status] + (
        detail if detail.startswith(" ") else f": {detail}")
    projected = None
    if report and ok:
        at += n_direction + n_vector
        info = values[at:at + n_info * n_info].reshape(n_info, n_info)
        at += n_info * n_info
        covariance = values[at:at + n_covariance * n_covariance].reshape(n_covariance,
                                                                         n_covariance)
        M = A.chan.size
        kept = integers[M:].tolist()
        C0 = values[starts[4]:starts[5]].reshape(A.r, A.q0.size)
        projected = Projected(info, per_channel(A, integers[:M]),
                              C0 if 0 not in kept else C0[np.array(kept, dtype=bool)],
                              int(rank0), residual, covariance)
    return Outcome((A, values, width, 5), iterations, status, message, delta0, verdict,
                   projected, head)


def not_finite_at(A, problem: Problem, values: np.ndarray, starts: tuple[int, ...],
                  width: int) -> str:
    """What is not finite at a start laid out in ``values`` (:func:`point_starts`, its
    equations padded to ``width``): the parameter, its constraints, or the first measures
    whose equations or Jacobians are not, named by channel, row and observed value (a
    measure outside its equations' domain: ``sqrt(x)`` or ``x**b`` at an observed
    ``x < 0``); ``""`` when all are."""
    if not np.all(np.isfinite(values[starts[1]:starts[2]])):
        return ": the parameter is not finite"
    if not np.all(np.isfinite(values[starts[3]:starts[5]])):
        return ": the model's constraints are not finite at the parameter"
    M = A.chan.size
    finite = [np.isfinite(e).reshape(M, -1).all(axis=1)
              for e in flat_evals(A, values, starts, width)]
    bad = np.flatnonzero(~(finite[0] & finite[1] & finite[2])).tolist()
    if not bad:
        return ""
    named = []
    for i in bad[:3]:
        ch = int(A.chan[i])
        channel = problem.channels[ch]
        row = i - int(A.start[ch])
        observed = ", ".join(f"{v:.4g}" for v in channel.X[row])
        named.append(f"{channel.name!r} row {row} (observed {observed})")
    more = f" and {len(bad) - 3} more" if len(bad) > 3 else ""
    return (f": the equations of {len(bad)} measure(s) are not finite there — "
            f"{'; '.join(named)}{more}: observed outside the equations' domain?")


def _verdict(stationary, decrement, cost, curvature, direction, plateau, vector,
             names) -> Verdict:
    """The checks' :class:`~kanagen.runtime.verify.Verdict` from the kernel's numbers."""
    return Verdict(stationary, decrement, cost, curvature, direction,
                   plateau_text(plateau, vector, names))


#: The fixed details of a status's message, by the engine's code.
_DETAILS = {engine.NO_DETAIL: "", engine.AT_START: " at the starting point",
            engine.IN_PROJECTOR: " in the projector"}


def point_starts(A, width: int, at: int = 0) -> tuple[int, ...]:
    """Where the fields of the engine's layout of a point (``runtime/engine/points.py:
    put_point``: ``delta`` and ``cost``, ``q, mt, c0, C0, c, C, D``), its equations padded
    to ``width``, start in a flat array holding it from ``at``, and where it ends."""
    n, M, d, r, p = A.q0.size, A.chan.size, A.m.shape[1], A.r, width
    starts = [at]
    for size in (2, n, M * d, r, r * n, M * p, M * p * n, M * p * d):
        starts.append(starts[-1] + size)
    return tuple(starts)


def point_head(A, values: np.ndarray, starts: tuple[int, ...]) -> tuple:
    """``q``, ``mt`` (per channel), cost and violation of the point laid out in ``values``
    at ``starts`` (:func:`point_starts`; views of ``values``): what a fit reads of it,
    without its equations."""
    delta, cost = values[starts[0]:starts[1]].tolist()
    mt = values[starts[2]:starts[3]].reshape(A.chan.size, A.m.shape[1])
    return values[starts[1]:starts[2]], unpack_measures(A, mt), cost, delta


def unpack_point(A, values: np.ndarray, width: int, at: int = 0) -> tuple[Point, int]:
    """A :class:`~kanagen.runtime.projector.Point` from the engine's layout of one in
    ``values`` from ``at`` (:func:`point_starts`), its equations padded to ``width``: the
    point (views of ``values``) and the index after it."""
    n, r = A.q0.size, A.r
    s = point_starts(A, width, at)
    q, mt, cost, delta = point_head(A, values, s)
    evals = unpack_evals(A, *flat_evals(A, values, s, width))
    return Point(q, mt, values[s[3]:s[4]], values[s[4]:s[5]].reshape(r, n), evals, delta,
                 cost), s[8]


def flat_evals(A, values: np.ndarray, starts: tuple[int, ...], width: int) -> tuple:
    """``c, C, D`` of the point laid out in ``values`` at ``starts`` (:func:`point_starts`),
    per measure and padded to ``width`` equations: views of ``values``."""
    n, M, d = A.q0.size, A.chan.size, A.m.shape[1]
    return (values[starts[5]:starts[6]].reshape(M, width),
            values[starts[6]:starts[7]].reshape(M, width, n),
            values[starts[7]:starts[8]].reshape(M, width, d))


def evaluated(problem: Problem, q: np.ndarray, mt) -> Point:
    """The point ``(q, m̃)`` (``mt`` per channel) with its equations, as the iteration's
    kernels evaluate it (their row kernels; :func:`~.projector.evaluate` calls the family's
    vectorised functions, which may differ in the last bits)."""
    A = arrays(problem)
    return unpack_point(A, *engine_points.evaluate_flat(
        A, np.ascontiguousarray(q, dtype=float), pack_measures(A, mt)))[0]


def restored(problem: Problem, q: np.ndarray, mt, root: np.ndarray | None = None,
             iterations: int | None = None, retract: bool = True) -> tuple[Point, float]:
    """The point with ``q`` moved back onto ``c0 = 0`` (a retraction, in the metric ``root``:
    the information's closest square root; Euclidean when None) and its measures projected
    onto their equations for that ``q`` (report eq. 22, iterated), and its violation ``E²``
    in cost units. ``retract=False``: ``q`` as it is."""
    A = arrays(problem)
    values, width, violation = engine_points.restored_flat(
        A, np.ascontiguousarray(q, dtype=float), pack_measures(A, mt),
        kernel_metric(root),
        RESTORE_STEPS if iterations is None else int(iterations), bool(retract))
    return unpack_point(A, values, width)[0], violation
