"""The block local projector of the report (appendix A, Fig. 17; SPEC §2).

At a linearisation point ``(q•, m•_i)`` it solves the linearised problem for ``q`` and every
corrected measure in O(n³ + Σ n_i³ + p³ + Σ p_i³): per-measure work is vectorised over the
measures of a channel, and the big KKT matrix is never formed.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, fields

import numpy as np

from .engine.data import (
    arrays,
    pack_evals,
    pack_measures,
    per_channel,
    unpack_evals,
    unpack_measures,
)
from .engine.linear import (
    corrected,
    parameter_block,
    seen_components,
)
from .engine.linear import linearise as engine_linearise
from .engine.measures import project_all
from .engine.points import restore_parameter as engine_restore_parameter
from .inputs import ChannelData
from .sqrt import EPS


@dataclass(frozen=True)
class Problem:
    """Everything fixed during one estimation: model functions, prior, measures."""

    c0: Callable  # q, k -> (c0, C0)
    measures: tuple[Callable, ...]  # per channel: q, X, k -> (c, C, D)
    channels: tuple[ChannelData, ...]
    q0: np.ndarray
    Q0: np.ndarray
    k: np.ndarray
    eps: float = EPS
    relations: Callable | None = None  # q -> whether the model's inequalities hold (app. F)
    # slacks of the model's strict relations: (component, p) with c = 1/s^p (c > 0: 2, c != 0: 1)
    strict_slacks: tuple[tuple[int, int], ...] = ()
    names: tuple[str, ...] = ()  # the parameter's components, for messages
    rows: object = None  # the model's compiled row kernels (engine.data.RowKernels)


    def subset(self, rows) -> Problem:
        """The same problem on some measures only: ``rows`` per channel (index arrays).
        When this problem's engine arrays are made, the subset's are gathered from them
        (:func:`kanagen.runtime.engine.data.arrays`)."""
        values = {name: self.__dict__[name] for name in _FIELDS}  # not what is cached
        values["channels"] = tuple(ch.subset(r) for ch, r in zip(self.channels, rows,
                                                                 strict=True))
        out = object.__new__(type(self))  # dataclasses.replace's fields, without __init__'s
        out.__dict__.update(values)  # frozen setattrs (a subset a fit of a search: ~8 µs)
        made = self.__dict__.get("_arrays")
        if made is not None:
            object.__setattr__(out, "_subset_of", (made, tuple(rows)))
        return out


_FIELDS = tuple(f.name for f in fields(Problem))


@dataclass  # an output record, made at every fit and restoration: not frozen (iterate.py)
class Point:
    """A point ``x = (q, m̃_i)`` with its equations and Jacobians evaluated."""

    q: np.ndarray
    mt: tuple[np.ndarray, ...]
    c0: np.ndarray
    C0: np.ndarray
    evals: tuple[tuple[np.ndarray, np.ndarray, np.ndarray], ...]  # (c, C, D) per channel
    delta: float  # ‖c(x)‖∞ over all equations (eq. 18)
    cost: float  # L² = ½‖q−q0‖²_Q0 + Σ ½‖m̃−m‖²_Q (eq. 2)

    @property
    def finite(self) -> bool:
        return bool(np.isfinite(self.delta) and np.isfinite(self.cost))


@dataclass(frozen=True)
class Linearisation:
    """The linearised problem at a point (report eq. 38–43), whitened, ready to be solved.

    The projector is written in increments: it solves for ``Δq = q − q•`` (and corrects the
    measures for ``q• + Δq``), the same point ``P(x•)`` as eq. 12 without the cancellation of
    the large ``C q•`` terms in ``r``.
    """

    x: Point
    info: np.ndarray  # Q̃ = Q0 + A
    H: np.ndarray  # Q̃ + ρ C0ᵀC0 (augmented form of the same KKT system)
    rhs: np.ndarray  # Q0 (q0 − q•) + Σ C̄ᵀ r̄' + ρ C0ᵀ (−c0)
    gradient: np.ndarray  # ∇q L² = Q0 (q• − q0) − Σ C̄ᵀ r̄' (exact where the measures are
    # projected onto their equations: r̄' is then the whitened ν of eq. 44's multipliers)
    whitened: tuple  # per channel: (C̄, r̄', kernel state) or None
    ranks: tuple[np.ndarray, ...]  # p_i per measure, per channel
    residual: float  # Σ ‖W_i c_i‖², the measurement part of E²
    packed: tuple = ()  # C̄, r̄', E, L, L's inverse pivots: per measure, padded (engine)


@dataclass(frozen=True)
class Projection:
    """``P(x•)`` (damped by μ when μ > 0): the new point and what the solve kept."""

    q: np.ndarray
    mt: tuple[np.ndarray, ...]
    C0: np.ndarray  # kept rows of C0 (reduced square root)
    rank0: int
    residual: float  # E² (eq. 13/17) at the linearisation point


def total_quadratic(v: np.ndarray, Q: np.ndarray) -> float:
    """``Σ vᵢᵀ Q vᵢ`` over the measures."""
    return float(np.einsum("mk,kl,ml->", v, Q, v) if Q.ndim == 2 else
                 np.einsum("mk,mkl,ml->", v, Q, v))


def evaluate(problem: Problem, q: np.ndarray, mt: tuple[np.ndarray, ...]) -> Point:
    """Equations, Jacobians, ‖c‖∞ and the cost at ``(q, m̃)`` (call under np.errstate)."""
    evals = tuple(fn(q, ch.with_corrected(m), problem.k)
                  for fn, ch, m in zip(problem.measures, problem.channels, mt, strict=True))
    return point(problem, q, mt, evals)


def point(problem: Problem, q: np.ndarray, mt: tuple[np.ndarray, ...], evals) -> Point:
    """A :class:`Point` from the measurement equations already evaluated at ``(q, m̃)``."""
    c0, C0 = problem.c0(q, problem.k)
    delta = float(np.abs(c0).max()) if c0.size else 0.0
    dq = q - problem.q0
    cost = 0.5 * float(dq @ problem.Q0 @ dq)
    for ch, m, (c, _, _) in zip(problem.channels, mt, evals, strict=True):
        if c.size:
            worst = float(np.abs(c).max())
            delta = np.inf if worst != worst else max(delta, worst)  # NaN counts as infinite
            cost += 0.5 * total_quadratic(m - ch.m, ch.Q)
    if delta != delta:
        delta = np.inf
    return Point(q, tuple(mt), c0, C0, tuple(evals), delta, cost)


def project_measures(problem: Problem, q: np.ndarray, mt: tuple[np.ndarray, ...],
                     iterations: int, tol: float = 1e-10):
    """Project each measure onto ``c_i(q, ·) = 0`` with ``q`` fixed, in its ``Q_i`` metric
    (report eq. 22: the projector in measure space only, with eq. 18's halving per measure;
    :func:`~kanagen.runtime.engine.measures.project_measure`).

    ``iterations`` counts projector steps plus one: 1 evaluates at ``mt`` and moves nothing.
    Returns ``(mt, violations, ranks, evals)`` with, per channel and measure, the whitened
    violation ``‖c(q, m̃)‖²_{(D Q⁺ Dᵀ)⁻}`` and the number of equations kept, and per channel
    the equations ``(c, C, D)``, all at the returned point.
    """
    A = arrays(problem)
    out, viol, rank, c, C, D = project_all(A, q, pack_measures(A, mt), int(iterations),
                                           float(tol))
    return (unpack_measures(A, out), per_channel(A, viol), per_channel(A, rank),
            unpack_evals(A, c, C, D))


def restore_parameter(problem: Problem, q: np.ndarray, root: np.ndarray | None,
                      iterations: int = 3) -> np.ndarray:
    """Project ``q`` back onto ``c0(q) = 0`` with the least move in the metric ``Q̃ = Ā Āᵀ``
    (``root``, the closest square root of the information): ``Δq = −Q̃⁻¹ C0ᵀ (C0 Q̃⁻¹ C0ᵀ)⁻
    c0`` (the constraint rows of the projector, eq. 12, with the data part frozen), ``C0``
    re-evaluated at each of a few steps. Directions the data do not see (a slack, the scale
    of a homogeneous parameter) are free in this metric: the correction moves them first.

    This is the parameter-space twin of :func:`project_measures` — a second-order correction:
    a long projector step leaves a violation of the order of its square on curved
    constraints (a unit norm, a slack's ``c·s² − 1``), which would make eq. 18 refuse it.
    Steps that do not lower ``‖c0‖∞`` are not taken. ``root`` None: the Euclidean metric.
    The kernel :func:`~kanagen.runtime.engine.points.restore_parameter` (the iteration's
    retraction) on the problem's arrays.
    """
    return engine_restore_parameter(arrays(problem), np.ascontiguousarray(q, dtype=float),
                                    kernel_metric(root), int(iterations))


_EUCLIDEAN = np.zeros((0, 0))  # the kernels' empty metric: Euclidean


def kernel_metric(root: np.ndarray | None) -> np.ndarray:
    """A metric's square root as the kernels take it: a C-ordered float matrix, or the
    empty one (the Euclidean metric) for None."""
    return _EUCLIDEAN if root is None else np.ascontiguousarray(root, dtype=float)


def linearise(problem: Problem, x: Point) -> Linearisation:
    """Whitened linearisation at ``x`` (report appendix A, Fig. 17;
    :func:`~kanagen.runtime.engine.linear.linearise`)."""
    A = arrays(problem)
    c, C, D = pack_evals(A, x.evals, x.q.size)
    info, H, rhs, gradient, Cbar, rbar, E, L, inv, kept, ranks, residual = engine_linearise(
        A, np.ascontiguousarray(x.q, dtype=float), pack_measures(A, x.mt), c, C, D,
        np.ascontiguousarray(x.c0, dtype=float), np.ascontiguousarray(x.C0, dtype=float))
    whitened = tuple(None if A.size[j] == 0 else
                     (Cbar[A.start[j]:A.start[j] + A.size[j], :A.P[j]],
                      rbar[A.start[j]:A.start[j] + A.size[j], :A.P[j]], None)
                     for j in range(A.size.size))
    return Linearisation(x, info, H, rhs, gradient, whitened, per_channel(A, ranks),
                         float(residual), (Cbar, rbar, E, L, inv))


def solve(problem: Problem, lin: Linearisation, mu: float = 0.0,
          weights: np.ndarray | None = None) -> Projection:
    """The projector's point from a linearisation (report eq. 12/43, Fig. 17).

    ``mu > 0`` adds Levenberg–Marquardt damping ``μ diag(w)`` to the parameter block (our
    globalisation for starts far from the solution), ``w`` the given ``weights`` or else
    ``diag(H)`` equilibrated; ``mu = 0`` is the report's projector.
    """
    x = lin.x
    dq, kept0, rank0, residual = _parameter_block(problem, lin, mu, weights)
    A = arrays(problem)
    mt = unpack_measures(A, corrected(A, dq, *lin.packed))  # eq. 44
    return Projection(x.q + dq, mt, x.C0[kept0], rank0, residual)


def parameter_step(problem: Problem, lin: Linearisation, mu: float = 0.0,
                   weights: np.ndarray | None = None) -> np.ndarray:
    """``Δq`` of :func:`solve` alone (the measures not corrected)."""
    return _parameter_block(problem, lin, mu, weights)[0]


def _parameter_block(problem: Problem, lin: Linearisation, mu: float,
                     weights: np.ndarray | None):
    """``Δq`` of eq. 43 (damped by ``μ diag(w)``), the rows of ``C0`` kept, their rank and
    the residual E² (:func:`~kanagen.runtime.engine.linear.parameter_block`)."""
    x = lin.x
    dq, kept0, rank0, residual, ok = parameter_block(
        lin.H, lin.info, lin.rhs, np.ascontiguousarray(x.C0, dtype=float),
        np.ascontiguousarray(x.c0, dtype=float), np.ascontiguousarray(x.q, dtype=float),
        lin.residual, float(mu), _NO_WEIGHTS if weights is None else
        np.ascontiguousarray(weights, dtype=float), problem.eps)
    if not ok:
        raise np.linalg.LinAlgError("singular triangular factor")
    return dq, kept0, int(rank0), float(residual)


_NO_WEIGHTS = np.zeros(0)


def project(problem: Problem, x: Point) -> tuple[Linearisation, Projection]:
    """One application of the projector ``P_{x0}(x•)`` (report eq. 12, Fig. 17)."""
    lin = linearise(problem, x)
    return lin, solve(problem, lin)


def _seen(info: np.ndarray, C0: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Components the data or the constraints see
    (:func:`~kanagen.runtime.engine.linear.seen_components`)."""
    return seen_components(np.ascontiguousarray(info, dtype=float),
                           np.ascontiguousarray(C0, dtype=float),
                           np.ascontiguousarray(q, dtype=float))
