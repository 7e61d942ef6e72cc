"""The block local projector of the report (appendix A, Fig. 17; SPEC §2).

At a linearisation point ``(q•, m•_i)`` it solves the linearised problem for ``q`` and every
corrected measure in O(n³ + Σ n_i³ + p³ + Σ p_i³): per-measure work is vectorised over the
measures of a channel, and the big KKT matrix is never formed.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from .inputs import ChannelData
from .sqrt import EPS, closest_sqrt, reduced_solve, reduced_sqrt, triangular_solve

#: Relative rounding level of stored values (moves below it are noise).
_ROUNDING = 1e3 * np.finfo(float).eps


@dataclass(frozen=True)
class Problem:
    """Everything fixed during one estimation: model functions, prior, measures."""

    c0: Callable  # q, k -> (c0, C0)
    measures: tuple[Callable, ...]  # per channel: q, X, k -> (c, C, D)
    kernels: tuple[tuple[Callable, Callable], ...]  # per channel: (whiten, correct)
    channels: tuple[ChannelData, ...]
    q0: np.ndarray
    Q0: np.ndarray
    k: np.ndarray
    eps: float = EPS
    relations: Callable | None = None  # q -> whether the model's inequalities hold (app. F)
    # slacks of the model's strict relations: (component, p) with c = 1/s^p (c > 0: 2, c != 0: 1)
    strict_slacks: tuple[tuple[int, int], ...] = ()
    # (FastPath, model) when the family is compiled: coherence errors in C (fastpath.py)
    compiled: tuple | None = None
    names: tuple[str, ...] = ()  # the parameter's components, for messages


    def subset(self, rows) -> Problem:
        """The same problem on some measures only: ``rows`` per channel (index arrays)."""
        return replace(self, channels=tuple(ch.subset(r) for ch, r in zip(self.channels, rows,
                                                                           strict=True)))


@dataclass(frozen=True)
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


@dataclass(frozen=True)
class Projection:
    """``P(x•)`` (damped by μ when μ > 0): the new point and what the solve kept."""

    q: np.ndarray
    mt: tuple[np.ndarray, ...]
    C0: np.ndarray  # kept rows of C0 (reduced square root)
    rank0: int
    residual: float  # E² (eq. 13/17) at the linearisation point


def quadratic(v: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """``vᵀ Q v`` per measure for v (M, k) and Q (k, k) or (M, k, k)."""
    if Q.ndim == 2:
        return np.einsum("mk,kl,ml->m", v, Q, v)
    return np.einsum("mk,mkl,ml->m", v, Q, v)


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
    (report eq. 22: the projector in measure space only, with eq. 18's halving per measure,
    vectorised over the measures).

    ``iterations`` counts projector steps plus one: 1 evaluates at ``mt`` and moves nothing.
    Returns ``(mt, violations, ranks, evals)`` with, per channel and measure, the whitened
    violation ``‖c(q, m̃)‖²_{(D Q⁺ Dᵀ)⁻}`` and the number of equations kept, and per channel
    the equations ``(c, C, D)``, all at the returned point.
    """
    out_mt, out_violation, out_rank, out_evals = [], [], [], []
    for fn, (whiten, correct), ch, m in zip(problem.measures, problem.kernels,
                                            problem.channels, mt, strict=True):
        m = m.copy()
        violation = np.zeros(ch.size)
        rank = np.zeros(ch.size, dtype=int)
        c, C, D = fn(q, ch.with_corrected(m), problem.k)
        active = np.ones(ch.size, dtype=bool)
        for it in range(iterations if ch.size else 0):
            r = (D @ (m - ch.m)[..., None])[..., 0] - c  # r − C q with q fixed
            Bbar, kept, state = whiten(D, ch.G, np.stack([r, c], axis=2), problem.eps)
            violation = np.sum(Bbar[..., 1] ** 2, axis=1)
            rank = kept.sum(axis=1)
            if it == iterations - 1 or not active.any():
                break
            step = ch.m + correct(state, ch.G, Bbar[..., 0]) - m
            step[~active | ~np.all(np.isfinite(step), axis=1)] = 0.0
            m, (c, C, D), moved = _halving(problem, fn, ch, q, m, c, step)
            seen = quadratic(moved, ch.Q) > tol**2
            # where the information does not see a move (Q semi-definite): the rounding level
            unseen = np.any(np.abs(moved) > _ROUNDING * (1.0 + np.abs(m)), axis=1)
            active &= seen | unseen
        out_mt.append(m)
        out_violation.append(violation)
        out_rank.append(rank)
        out_evals.append((c, C, D))
    return tuple(out_mt), tuple(out_violation), tuple(out_rank), tuple(out_evals)


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
    Steps that do not lower ``‖c0‖∞`` are not taken (call under np.errstate). ``root``
    None: the Euclidean metric.
    """
    c0, C0 = problem.c0(q, problem.k)
    if not c0.size:
        return q
    worst = float(np.max(np.abs(c0)))
    if root is None:
        root = np.eye(q.size)
    for _ in range(iterations):
        if not worst > _ROUNDING * (1.0 + float(np.max(np.abs(q)))) * 1e-3:
            break
        C0bar_t = triangular_solve(root, C0.T)  # Ā⁻¹ C0ᵀ
        L0, kept0 = reduced_sqrt(C0bar_t.T @ C0bar_t, problem.eps)
        y = reduced_solve(L0, kept0, reduced_solve(L0, kept0, c0), transpose=True)
        trial = q - triangular_solve(root, C0bar_t @ y, transpose=True)
        c0_new, C0_new = problem.c0(trial, problem.k)
        new_worst = float(np.max(np.abs(c0_new)))
        if not new_worst < worst:
            break
        q, c0, C0, worst = trial, c0_new, C0_new, new_worst
    return q


def _halving(problem: Problem, fn, ch, q, m, c, step, halvings: int = 4):
    """Eq. 18 per measure: take ``m + α step`` with α halved where the violation grows (a few
    times: the far-point instability of the plain step needs α <= 1/4); a measure whose
    violation still grows stays where it is."""
    worst = np.max(np.abs(c), axis=1) if c.shape[1] else np.zeros(len(m))
    alpha = np.ones(len(m))
    for _ in range(halvings):
        cand = m + alpha[:, None] * step
        new = fn(q, ch.with_corrected(cand), problem.k)
        c_new = new[0]
        new_worst = np.max(np.abs(c_new), axis=1) if c_new.shape[1] else worst
        grew = ~(new_worst <= worst + 1e-9 * (1.0 + worst))  # NaN counts as growth
        if not grew.any():
            break
        alpha = np.where(grew, alpha / 2, alpha)
    else:
        alpha = np.where(grew, 0.0, alpha)
        cand = m + alpha[:, None] * step
        new = fn(q, ch.with_corrected(cand), problem.k)
    return cand, new, cand - m


def linearise(problem: Problem, x: Point) -> Linearisation:
    """Whitened linearisation at ``x`` (report appendix A, Fig. 17), per-measure work
    vectorised over the measures of each channel."""
    q = x.q
    n = q.size
    A = np.zeros((n, n))
    g = np.zeros(n)
    residual = 0.0
    whitened, ranks = [], []
    for (whiten, _), ch, m, (c, C, D) in zip(problem.kernels, problem.channels, x.mt, x.evals,
                                             strict=True):
        if ch.size == 0:
            whitened.append(None)
            ranks.append(np.zeros(0, dtype=int))
            continue
        stacked = np.empty(C.shape[:2] + (n + 2,))
        stacked[..., :n] = C
        # r_i − C_i q• = D_i (m• − m) − c_i (SPEC §2, in increments)
        stacked[..., n] = (D @ (m - ch.m)[..., None])[..., 0] - c
        stacked[..., n + 1] = c
        Bbar, kept, state = whiten(D, ch.G, stacked, problem.eps)
        flat = Bbar.reshape(-1, n + 2)
        A += flat[:, :n].T @ flat[:, :n]
        g += flat[:, :n].T @ flat[:, n]
        residual += float(flat[:, n + 1] @ flat[:, n + 1])
        whitened.append((Bbar[..., :n], Bbar[..., n], state))
        ranks.append(kept.sum(axis=1))
    info = problem.Q0 + A
    rhs = problem.Q0 @ (problem.q0 - q) + g
    gradient = -rhs
    H = info
    C0 = x.C0
    if C0.shape[0]:
        # Augmented form of the same KKT system: adding ρ C0ᵀ(C0 Δq + c0) = 0 changes neither
        # Δq nor λ0, but makes H definite wherever the constraints fix what the data leave
        # free (e.g. the scale of a homogeneous parameter), so the closest root needs no ε
        # floor there and C̄0 = Ā⁻¹ C0ᵀ stays well conditioned.
        gram = C0.T @ C0
        rho = _augmentation(H, gram)
        H = H + rho * gram
        rhs = rhs - rho * (C0.T @ x.c0)
    return Linearisation(x, info, H, rhs, gradient, tuple(whitened), tuple(ranks), residual)


def solve(problem: Problem, lin: Linearisation, mu: float = 0.0,
          weights: np.ndarray | None = None) -> Projection:
    """The projector's point from a linearisation (report eq. 12/43, Fig. 17).

    ``mu > 0`` adds Levenberg–Marquardt damping ``μ diag(w)`` to the parameter block (our
    globalisation for starts far from the solution), ``w`` the given ``weights`` or else
    ``diag(H)``; ``mu = 0`` is the report's projector.
    """
    x = lin.x
    dq, rank0, kept0, residual = _parameter_block(problem, lin, mu, weights)
    mt_new = []
    for (_, correct), ch, w in zip(problem.kernels, problem.channels, lin.whitened,
                                   strict=True):
        if w is None:
            mt_new.append(ch.m.copy())
            continue
        Cbar, rbar, state = w
        mt_new.append(ch.m + correct(state, ch.G, rbar - Cbar @ dq))  # eq. 44
    return Projection(x.q + dq, tuple(mt_new), x.C0[kept0], rank0, residual)


def parameter_step(problem: Problem, lin: Linearisation, mu: float = 0.0,
                   weights: np.ndarray | None = None) -> np.ndarray:
    """``Δq`` of :func:`solve` alone (the measures not corrected)."""
    return _parameter_block(problem, lin, mu, weights)[0]


def _parameter_block(problem: Problem, lin: Linearisation, mu: float,
                     weights: np.ndarray | None) -> tuple[np.ndarray, int, np.ndarray, float]:
    """``Δq`` of eq. 43 (damped by ``μ diag(w)``), the rank of the constraints, the rows kept
    and the residual E²."""
    x = lin.x
    H = lin.H
    if mu > 0.0:
        H = H + mu * np.diag(_equilibrium_weights(H) if weights is None else weights)
    # A component that neither the data nor the constraints see (a slack in a factor of a
    # disjunction that does not hold: its column is rounding) holds only rounding in the
    # right-hand side, which the closest root would divide by ε: it does not move.
    seen = _seen(lin.info, x.C0, x.q)
    dq = np.zeros(x.q.size)
    if not seen.all():
        H, rhs, C0 = H[np.ix_(seen, seen)], lin.rhs[seen], x.C0[:, seen]
    else:
        rhs, C0 = lin.rhs, x.C0
    residual = lin.residual
    rank0, kept0 = 0, np.zeros(x.C0.shape[0], dtype=bool)
    if seen.any():  # none seen, e.g. every gradient vanishes at the start: q stays
        rank0, kept0, residual = _solve_seen(problem, x, H, rhs, C0, seen, dq, residual)
    return dq, rank0, kept0, residual


def _solve_seen(problem: Problem, x: Point, H: np.ndarray, rhs: np.ndarray, C0: np.ndarray,
                seen: np.ndarray, dq: np.ndarray, residual: float,
                ) -> tuple[int, np.ndarray, float]:
    """The parameter block of eq. 43 on the seen components: writes ``dq[seen]``; returns the
    rank of the constraints, the rows kept and the residual with ``‖c0‖²`` whitened."""
    Abar = closest_sqrt(H, problem.eps)  # H = Ā Āᵀ
    bbar = triangular_solve(Abar, rhs)
    rank0, kept0 = 0, np.zeros(C0.shape[0], dtype=bool)
    if C0.shape[0]:
        C0bar_t = triangular_solve(Abar, C0.T)  # Ā⁻¹ C0ᵀ
        L0, kept0 = reduced_sqrt(C0bar_t.T @ C0bar_t, problem.eps)
        lam = reduced_solve(L0, kept0, reduced_solve(L0, kept0, C0bar_t.T @ bbar + x.c0),
                            transpose=True)
        bbar = bbar - C0bar_t @ lam
        e0 = reduced_solve(L0, kept0, x.c0)
        residual += float(e0 @ e0)
        rank0 = int(kept0.sum())
    dq[seen] = triangular_solve(Abar, bbar, transpose=True)
    return rank0, kept0, residual

def project(problem: Problem, x: Point) -> tuple[Linearisation, Projection]:
    """One application of the projector ``P_{x0}(x•)`` (report eq. 12, Fig. 17)."""
    lin = linearise(problem, x)
    return lin, solve(problem, lin)


def _seen(info: np.ndarray, C0: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Components the data or the constraints see: some information (however small: the
    scales of components may differ by many orders) or a constraint Jacobian entry above the
    rounding level of its row — as it is, or as the change ``C0[r, j] q_j`` of a relative
    move of the component (a slack near its boundary, ``s² (AC − B²) − 1`` with ``s`` large,
    has a small but exact derivative ``2 s (AC − B²)``; a slack in a factor of a disjunction
    that does not hold has rounding there, whatever its scale)."""
    seen = np.diagonal(info) != 0.0
    if C0.shape[0]:
        for J in (np.abs(C0), np.abs(C0 * q)):
            rows = np.max(J, axis=1, keepdims=True)
            seen |= np.any(J > _ROUNDING * rows, axis=0)
    return seen


def _equilibrium_weights(H: np.ndarray) -> np.ndarray:
    diag = np.abs(np.diagonal(H))
    top = float(diag.max(initial=0.0))
    return np.where(diag > 0, diag, top if top > 0 else 1.0)


def _augmentation(info: np.ndarray, gram: np.ndarray) -> float:
    """ρ that puts ρ C0ᵀC0 on the scale of the information matrix."""
    top = float(np.max(np.diagonal(info), initial=0.0))
    bottom = float(np.max(np.diagonal(gram), initial=0.0))
    if bottom <= 0.0:
        return 0.0
    return (top if top > 0.0 else 1.0) / bottom
