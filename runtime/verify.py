"""Is the end of an iteration a minimum? (SPEC §2: a success is a local minimum of ``L̃²``.)

At a point whose measures are projected onto their equations (report eq. 22), the cost is the
profile ``F(q)`` and the projector's right-hand side its exact gradient. The checks:

* **Stationary**: the Newton decrement ``½ sᵀ Q̃ s`` of the projector's step ``s`` — the fall
  of the cost a Gauss–Newton step predicts, on the constraints' tangent space — is negligible
  against the cost (``1e-10`` of it, or the cost's rounding level). Units do not enter: the
  decrement is invariant to a change of the parameter's units.
* **No negative curvature** (report footnote 5: a maximum or a saddle "would be detected"):
  the Hessian of the Lagrangian ``F + λ0ᵀ c0`` on the tangent space of ``c0 = 0``, from
  differences of the exact gradient along a basis orthonormal in the information (so its
  eigenvalues compare with one, the Gauss–Newton curvature), has no eigenvalue below
  ``−1e-5``. Forward differences screen first (one gradient per direction): a least
  eigenvalue above ``0.05`` — far beyond their ``O(step)`` error — settles it; otherwise
  central differences (the screen's gradients reused) decide.
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

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .projector import (
    Linearisation,
    Point,
    Problem,
    Projection,
    _seen,
    linearise,
)
from .restoration import restore_measures
from .sqrt import closest_sqrt

_STATIONARY = 1e-10  # decrement over cost below which a point is stationary
_NEGATIVE = 1e-5  # curvature (relative to the information) below -this is negative
_STEP = 1e-3  # central-difference step, in standard deviations of the parameter
_VANISHED = 1e-12  # information fallen by this factor since the start: a plateau
_SCREEN = 0.05  # least forward-difference curvature above which no central check is needed
_LOST = 1e-12  # least eigenvalue of the scaled information, relative: a direction lost
_SLOPE = 1e3  # the gradient along it, in rounding levels of its terms, above which it falls


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
        return self.stationary and not self.plateau and not self.curvature < -_NEGATIVE

    def describe(self) -> str:
        if not self.stationary:
            return (f"a Gauss–Newton step would still lower the cost by {self.decrement:.3g} "
                    f"of {self.cost:.6g}")
        if self.curvature < -_NEGATIVE:
            return f"negative curvature {self.curvature:.3g} of the cost on the constraints"
        return ""


def cost_rounding(problem: Problem) -> float:
    """The rounding level of the cost ``L²``: what a measure's rounding, ``10 ε`` of its
    size in its information metric, costs, summed over the measures."""
    eps = 10 * np.finfo(float).eps
    return sum(ch.size * (eps * ch.scale) ** 2 for ch in problem.channels) + \
        np.finfo(float).tiny


def decrement(lin: Linearisation, proj: Projection) -> float:
    """``½ sᵀ H s`` of the tangential part of the projector's step ``s``: the whole step's,
    less its part normal to the constraints, ``½ c0ᵀ (C0 H⁻¹ C0ᵀ)⁻ c0`` (H-orthogonal to
    the tangent space; zero on the constraints)."""
    s = proj.q - lin.x.q
    normal = proj.residual - lin.residual
    return max(0.5 * float(s @ lin.H @ s) - 0.5 * normal, 0.0)


def stationary(problem: Problem, lin: Linearisation, proj: Projection) -> bool:
    """The projector's step predicts a negligible fall of the cost."""
    return decrement(lin, proj) <= _STATIONARY * lin.x.cost + cost_rounding(problem)


def verify(problem: Problem, x: Point, lin: Linearisation, proj: Projection,
           info_start: np.ndarray | None = None,
           gradient_at: Callable[[np.ndarray], np.ndarray | None] | None = None,
           at_rounding: bool = False, model: tuple | None = None) -> Verdict:
    """The checks at ``x`` (measures projected, ``lin``/``proj`` the projector there).

    ``info_start``: the diagonal of the information at the start (for the plateau check);
    ``gradient_at(q)``: the exact gradient of the profile at ``q`` (default: measures
    projected from ``x``'s, then linearised); ``at_rounding``: the projector's step moves no
    component beyond the rounding level of ``q`` (no step can lower the cost further);
    ``model``: the linearisation and projection of the step's model (with the constraints'
    curvature: :func:`~kanagen.runtime.iterate.lagrangian`), for the decrement."""
    step_lin, step_proj = model if model is not None else (lin, proj)
    dec = decrement(step_lin, step_proj)
    if not (at_rounding or stationary(problem, step_lin, step_proj)):
        return Verdict(False, dec, x.cost)
    plateau = _plateau(problem, x, lin, info_start) or lost_direction(problem, x, lin)
    if plateau:
        return Verdict(True, dec, x.cost, plateau=plateau)
    if x.cost <= 10.0 * cost_rounding(problem):
        return Verdict(True, dec, x.cost, curvature=0.0)  # L² >= 0: a zero-residual minimum
    W = _tangent_basis(x, lin)
    if W.shape[1] == 0:
        return Verdict(True, dec, x.cost, curvature=0.0)
    lam0 = _multipliers(x, lin)
    if gradient_at is None:  # the profile's: at x itself, the projector's (x is restored)
        gradient_at = _profile_gradient(problem, x)
        here = _gradients(problem, [x.q], lam0, lambda q: lin.gradient)
    else:
        here = None
    plus = _gradients(problem, _moved(x, W, _STEP), lam0, gradient_at)
    if plus is None:
        return Verdict(True, dec, x.cost)  # no curvature where it cannot be seen
    if here is None:
        here = _gradients(problem, [x.q], lam0, gradient_at)
    if here is not None:  # the forward-difference screen
        screen = _least_eigen([W.T @ (g - here[0]) / _STEP for g in plus], W)
        if screen is not None and screen[0] >= _SCREEN:
            return Verdict(True, dec, x.cost, screen[0], screen[1])
    least = _least_curvature(problem, x, W, lam0, gradient_at, _STEP, plus)
    if least is None:
        return Verdict(True, dec, x.cost)
    if least[0] < -_NEGATIVE:
        # confirmed with a step four times shorter: rounding and third-order terms differ
        again = _least_curvature(problem, x, W, lam0, gradient_at, _STEP / 4)
        if again is None or not abs(again[0] - least[0]) <= 0.1 * abs(least[0]) + _NEGATIVE:
            return Verdict(True, dec, x.cost)
    return Verdict(True, dec, x.cost, least[0], least[1])


def _moved(x: Point, W: np.ndarray, step: float) -> list:
    """``x.q + step W[:, j]`` for each column."""
    return [x.q + step * W[:, j] for j in range(W.shape[1])]


def _gradients(problem: Problem, points: list, lam0: np.ndarray,
               gradient_at: Callable) -> list | None:
    """The gradients of ``F + λ0ᵀ c0`` at each of ``points``, or None when one cannot be
    evaluated."""
    out = []
    for q in points:
        grad = gradient_at(q)
        if grad is None:
            return None
        if lam0.size:
            grad = grad + problem.c0(q, problem.k)[1].T @ lam0
        out.append(grad)
    return out


def _least_curvature(problem: Problem, x: Point, W: np.ndarray, lam0: np.ndarray,
                     gradient_at: Callable, step: float,
                     plus: list | None = None) -> tuple[float, np.ndarray] | None:
    """The least eigenvalue of ``Wᵀ ∇²(F + λ0ᵀ c0) W`` from central differences of the
    gradient with ``step`` along each column, and its direction in q (None when a gradient
    cannot be evaluated). ``plus``: the gradients on the positive side, when known."""
    if plus is None:
        plus = _gradients(problem, _moved(x, W, step), lam0, gradient_at)
    minus = None if plus is None else _gradients(problem, _moved(x, W, -step), lam0,
                                                 gradient_at)
    if minus is None:
        return None
    return _least_eigen([W.T @ (a - b) / (2 * step) for a, b in zip(plus, minus, strict=True)],
                        W)


def _least_eigen(columns: list, W: np.ndarray) -> tuple[float, np.ndarray] | None:
    """The least eigenvalue of the symmetrised matrix of ``columns`` and its direction in q
    (``W`` times its eigenvector), or None when not finite."""
    K = np.array(columns).T
    K = 0.5 * (K + K.T)
    if not np.all(np.isfinite(K)):
        return None
    w, U = np.linalg.eigh(K)
    return float(w[0]), W @ U[:, 0]


def _profile_gradient(problem: Problem, x: Point) -> Callable[[np.ndarray], np.ndarray | None]:
    """The exact gradient of the profile at ``q`` (off the constraints too): the measures
    projected from ``x``'s, the projector's gradient there."""

    def gradient_at(q: np.ndarray) -> np.ndarray | None:
        y, _ = restore_measures(problem, q, x.mt)
        return linearise(problem, y).gradient if y.finite else None

    return gradient_at


def feasible(violation: float, cost: float) -> bool:
    """The equations hold: their violation is negligible against the cost (cost units:
    ``1e-10`` of a squared standard deviation at the least)."""
    return bool(violation <= 1e-10 * max(1.0, cost))


def _multipliers(x: Point, lin: Linearisation) -> np.ndarray:
    if not x.C0.shape[0]:
        return np.zeros(0)
    lam, *_ = np.linalg.lstsq(x.C0.T, -lin.gradient, rcond=None)
    return lam


def _tangent_basis(x: Point, lin: Linearisation) -> np.ndarray:
    """Columns spanning the tangent space of ``c0 = 0`` on the components the data or the
    constraints see, orthonormal in the information (directions without information left
    out: the plateau check looks at those)."""
    Z = _tangent_space(x.C0, _seen(lin.info, x.C0, x.q))
    if Z.shape[1] == 0:
        return Z
    G = Z.T @ lin.info @ Z
    G = 0.5 * (G + G.T)
    w, U = np.linalg.eigh(G)
    keep = w > 1e-14 * max(float(w.max(initial=0.0)), np.finfo(float).tiny)
    return Z @ (U[:, keep] / np.sqrt(w[keep]))


def _tangent_space(C0: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """Columns spanning the null space of ``C0`` on the components ``seen`` (the others
    held)."""
    E = np.eye(seen.size)[:, seen]
    if not C0.shape[0]:
        return E
    _, S, Vt = np.linalg.svd(C0 @ E)
    rank = int(np.count_nonzero(S > 1e-10 * S[0])) if S.size and S[0] > 0 else 0
    return E @ Vt[rank:].T


def _plateau(problem: Problem, x: Point, lin: Linearisation,
             info_start: np.ndarray | None) -> str:
    """The parameters whose information fell by twelve orders of magnitude since the start
    (their equations no longer depend on them), as a sentence, or ``""``."""
    if info_start is None:
        return ""
    now = np.abs(np.diagonal(lin.info))
    before = np.abs(info_start)
    gone = (before > 0) & (now <= _VANISHED * before)
    if x.C0.shape[0]:  # a component the constraints pin is no plateau
        free = _tangent_space(x.C0, np.ones(x.q.size, dtype=bool))
        gone &= np.linalg.norm(free, axis=1) > 1e-6
    if not gone.any():
        return ""
    which = [problem.names[i] if problem.names else f"q[{i}]" for i in np.flatnonzero(gone)]
    return "the equations no longer depend on " + ", ".join(which)


def lost_direction(problem: Problem, x: Point, lin: Linearisation) -> str:
    """A direction of the parameter the equations no longer see, along which the cost still
    falls: the iteration runs off towards a degenerate limit of the model (a circle whose
    radius grows without bound towards the best line), where no minimum is attained — as a
    sentence, or ``""``.

    On the constraints' tangent space, the information scaled to a unit diagonal (units do
    not enter) has its least eigenvalue at the level where the projector's square root
    floors its pivots (``_LOST`` of the largest: the step, and so the decrement, no longer
    see that direction), and the gradient along the direction is well above the rounding
    of its terms: a first-order point has no slope there. A cost constant along such a
    direction (a motion's translation on the matches of a pure rotation) has none."""
    end = _weakest(lin.info, x)
    if end is None or end[0] > _LOST:
        return ""
    u = end[1]
    slope = float(lin.gradient @ u)
    terms = 0.0
    for w in lin.whitened:
        if w is not None:
            Cbar, rbar, _ = w
            terms += float(np.sum(np.abs(rbar) * (np.abs(Cbar) @ np.abs(u))))
    if not abs(slope) > _SLOPE * np.finfo(float).eps * terms:
        return ""
    u = -np.sign(slope) * u / np.max(np.abs(u))
    names = problem.names or tuple(f"q[{i}]" for i in range(u.size))
    parts = []
    for c, name in zip(u, names, strict=True):
        if abs(c) >= 1e-3:
            size = f"{abs(c):.2g}"
            parts.append(f"{'-' if c < 0 else '+'} {'' if size == '1' else size + ' '}{name}")
    combination = " ".join(parts).removeprefix("+ ")
    return (f"the equations no longer see the direction {combination} of the parameter, "
            f"along which the cost still falls (the estimate runs off towards a degenerate "
            f"limit of the model; no minimum is attained)")


def _weakest(info: np.ndarray, x: Point) -> tuple[float, np.ndarray] | None:
    """The least eigenvalue of ``info`` on the tangent space of ``c0 = 0``, scaled to a unit
    diagonal, relative to the largest, and its direction in q (None without a direction)."""
    Z = _tangent_space(x.C0, np.diagonal(info) > 0)
    if Z.shape[1] < 1:
        return None
    M = Z.T @ info @ Z
    M = 0.5 * (M + M.T)
    d = np.sqrt(np.abs(np.diagonal(M)))
    if not np.all(np.isfinite(M)) or not np.all(d > 0):
        return None
    w, U = np.linalg.eigh(M / np.outer(d, d))
    if not w[-1] > 0:
        return None
    return float(w[0] / w[-1]), Z @ (U[:, 0] / d)


def escape(problem: Problem, x: Point, lin: Linearisation, verdict: Verdict,
           retract: Callable) -> tuple[Point, float] | None:
    """A restored point lower than ``x`` along the negative-curvature direction (both senses,
    a few lengths in standard deviations), or None."""
    root = closest_sqrt(lin.info, problem.eps)
    best = None
    for length in (1.0, 3.0, 0.3, 10.0, 0.1, 30.0):
        for sign in (1.0, -1.0):
            q = x.q + sign * length * verdict.direction
            y, violation = retract(q, x.mt, root)
            if y.finite and feasible(violation, y.cost) and \
                    y.cost < x.cost * (1 - 1e-10) and (best is None or y.cost < best[0].cost):
                best = (y, violation)
        if best is not None:
            return best
    return None
