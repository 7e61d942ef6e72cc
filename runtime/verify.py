"""Is the end of an iteration a minimum? (SPEC §2: a success is a local minimum of ``L̃²``.)

At a point whose measures are projected onto their equations (report eq. 22), the cost is the
profile ``F(q)`` and the projector's right-hand side its exact gradient. The checks:

* **Stationary**: the Newton decrement ``½ sᵀ Q̃ s`` of the projector's step ``s`` — the fall
  of the cost a Gauss–Newton step predicts, on the constraints' tangent space — is negligible
  against the cost (``1e-10`` of it, or the cost's rounding level). Units do not enter: the
  decrement is invariant to a change of the parameter's units.
* **No negative curvature** (report footnote 5: a maximum or a saddle "would be detected"):
  the Hessian of the Lagrangian ``F + λ0ᵀ c0`` on the tangent space of ``c0 = 0``, in a
  basis orthonormal in the information (so its eigenvalues compare with one, the
  Gauss–Newton curvature), has no eigenvalue below ``−1e-5``. The profile's Hessian is
  exact: each measure's corrections follow the parameter by the implicit function theorem
  on its KKT system, the equations' second derivatives from their analytic Jacobians
  (runtime/engine/curvature.py) — one pass over the measures. A negative eigenvalue (or a
  measure whose system is singular: the profile is not smooth there) is confirmed by
  differences of the exact gradient along the basis, each a restoration of the measures:
  forward differences screen (a least eigenvalue above ``0.05``, far beyond their
  ``O(step)`` error, settles it), central differences decide, at a second step to agree.
* **Every parameter still seen**: a component whose information has fallen by twelve orders
  of magnitude since the start no longer enters the equations (an exponential vanished on
  every measure): the iteration stands on a plateau, not at a minimum.
* **No slope where the step is blind**: a direction whose scaled information is at the
  level where the projector's square root floors its pivots is outside the step, and so
  outside the decrement; the gradient along it must be at its rounding level. Where it is
  not, the cost still falls towards a degenerate limit of the model (a circle growing
  towards the best line: the equations see its radius and centre only in one combination).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .engine import points as engine_points
from .engine import verify as engine
from .engine.data import arrays, pack_evals, pack_measures
from .engine.points import feasible  # noqa: F401 - the engine's test, for Python callers
from .projector import Point, Problem

NEGATIVE = engine.NEGATIVE


@dataclass(frozen=True)
class Verdict:
    """What the checks found at a point."""

    stationary: bool
    decrement: float  # ½ sᵀ Q̃ s: the fall a Gauss–Newton step from here predicts
    cost: float
    curvature: float = np.nan  # least eigenvalue of the reduced Hessian (information units)
    direction: np.ndarray | None = None  # its direction in q, of unit information norm
    plateau: str = ""  # which parameters the equations no longer depend on

    @property
    def minimum(self) -> bool:
        return self.stationary and not self.plateau and not self.curvature < -NEGATIVE

    def describe(self) -> str:
        if not self.stationary:
            return (f"a Gauss–Newton step would still lower the cost by {self.decrement:.3g} "
                    f"of {self.cost:.6g}")
        if self.curvature < -NEGATIVE:
            return f"negative curvature {self.curvature:.3g} of the cost on the constraints"
        return ""


def plateau_text(kind: int, vector: np.ndarray, names: tuple[str, ...]) -> str:
    """The plateau as a sentence: the components whose information vanished (``kind`` 1),
    or the direction the equations lost along which the cost still falls (2)."""
    if kind == 0:
        return ""
    names = names or tuple(f"q[{i}]" for i in range(vector.size))
    if kind == 1:
        return "the equations no longer depend on " + ", ".join(
            names[i] for i in np.flatnonzero(vector))
    parts = []
    for c, name in zip(vector, names, strict=True):
        if abs(c) >= 1e-3:
            size = f"{abs(c):.2g}"
            parts.append(f"{'-' if c < 0 else '+'} {'' if size == '1' else size + ' '}{name}")
    combination = " ".join(parts).removeprefix("+ ")
    return (f"the equations no longer see the direction {combination} of the parameter, "
            f"along which the cost still falls (the estimate runs off towards a degenerate "
            f"limit of the model; no minimum is attained)")


def verify(problem: Problem, x: Point, info_start: np.ndarray | None = None,
           at_rounding: bool = False) -> Verdict:
    """The checks at the restored point ``x`` (:func:`kanagen.runtime.engine.verify.verify`,
    with the step's model of :func:`kanagen.runtime.engine.points.lagrangian`)."""
    A = arrays(problem)
    c, C, D = pack_evals(A, x.evals, x.q.size)
    pt = engine_points.Pt(np.ascontiguousarray(x.q, dtype=float), pack_measures(A, x.mt).copy(),
                          np.ascontiguousarray(x.c0, dtype=float),
                          np.ascontiguousarray(x.C0, dtype=float), c.copy(), C.copy(),
                          D.copy(), float(x.delta), float(x.cost))
    with np.errstate(all="ignore"):
        stationary, decrement, cost, curvature, direction, plateau, vector = engine.verify_at(
            A, pt, np.zeros(0) if info_start is None else
            np.ascontiguousarray(info_start, dtype=float), bool(at_rounding))
    return Verdict(bool(stationary), float(decrement), float(cost), float(curvature),
                   direction if direction.size else None,
                   plateau_text(int(plateau), vector, problem.names))
