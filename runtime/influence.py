"""How much each measure holds a fit: the fall of the cost when it is left out (deletion
diagnostics; Cook 1977, Belsley, Kuh & Welsch 1980), to first order.

At a fit ``q̂`` with its corrected measures, measure ``i`` enters the linearised problem
(report eq. 38–43) by its whitened equations: the residual ``r̄ᵢ`` (``pᵢ`` values, its share
of the cost ``‖r̄ᵢ‖²``) and the Jacobian ``C̄ᵢ = ∂r̄ᵢ/∂q``. With ``Σ`` the covariance of
``q̂`` on the tangent space of the constraints, its leverage is ``Hᵢ = C̄ᵢ Σ C̄ᵢᵀ`` and,
refitting without it, the cost falls by

    Δᵢ = r̄ᵢᵀ (I − Hᵢ)⁻¹ r̄ᵢ

— exactly for a linear least-squares problem (the PRESS identity), to first order here. An
outlier that has pulled the fit onto itself has a small error ``‖r̄ᵢ‖²`` and a leverage near
one: its ``Δᵢ`` is large where its error is not.
"""

from __future__ import annotations

import numpy as np

from .iterate import evaluated
from .projector import Problem, linearise
from .results import FitResult


class Influence:
    """A fit's measures as the linearised problem at the fit sees them (their whitened
    residuals and Jacobians, the covariance of ``q``): the deletion drop of each measure, or
    of a few together (``r̄_Sᵀ (I − C̄_S Σ C̄_Sᵀ)⁻¹ r̄_S``: outliers that pull a fit together
    mask one another one by one)."""

    def __init__(self, problem: Problem, fit: FitResult):
        mt = tuple(np.asarray(fit.measures[ch.name])[:, ch.index] for ch in problem.channels)
        with np.errstate(all="ignore"):  # the point as the fit's kernels evaluate it
            lin = linearise(problem, evaluated(problem, fit.q, mt))
        self.S = np.asarray(fit.covariance, dtype=float)
        self.blind = not np.isfinite(self.S).all()
        self.parts = [None if w is None else (w[0], w[1], np.maximum(rank, 1))
                      for w, rank in zip(lin.whitened, lin.ranks, strict=True)]
        self.sizes = [ch.size for ch in problem.channels]

    def drops(self) -> tuple[np.ndarray, ...]:
        """Per channel, ``Δᵢ / pᵢ`` of each measure (see :func:`deletion_drops`)."""
        def drop(Cbar, rbar, rank):  # (M, p, n), (M, p), (M,)
            K = np.eye(Cbar.shape[1]) - _sandwich(Cbar, self.S)
            return _quadratic_or_inf(K, rbar) / rank

        return self._per_measure(drop)

    def leverages(self) -> tuple[np.ndarray, ...]:
        """Per channel, each measure's leverage ``tr(Hᵢ) / pᵢ`` (``Hᵢ = C̄ᵢ Σ C̄ᵢᵀ``): the
        share of its own fitted value it holds; they sum to the parameter's degrees of
        freedom. ``nan`` where the fit has no covariance."""
        return self._per_measure(
            lambda Cbar, _, rank: np.trace(_sandwich(Cbar, self.S), axis1=1, axis2=2) / rank)

    def _per_measure(self, value) -> tuple[np.ndarray, ...]:
        """Per channel, ``value(C̄, r̄, p)`` of its measures: 0 for a channel with no
        equations in the linearised problem, ``nan`` where the fit has no covariance."""
        out = []
        for size, part in zip(self.sizes, self.parts, strict=True):
            if part is None:
                out.append(np.zeros(size))
            elif self.blind:
                out.append(np.full(size, np.nan))
            else:
                with np.errstate(all="ignore"):
                    out.append(value(*part))
        return tuple(out)

    def joints(self, groups) -> np.ndarray:
        """The deletion drop of each group of ``groups`` (lists of ``(channel, index)``
        pairs: the group's measures left out together), per equation kept — groups of one
        shape (their measures' equations alike) in one stack."""
        out = np.full(len(groups), np.nan)
        if self.blind or not groups:
            return out
        stacked = self._one_channel(groups)
        if stacked is not None:  # the usual case: the stack gathered at once
            A, r, p = stacked
            with np.errstate(all="ignore"):
                K = np.eye(A.shape[1]) - _sandwich(A, self.S)
                return _quadratic_or_inf(K, r) / p
        shapes: dict = {}
        for g, measures in enumerate(groups):
            A = np.concatenate([self.parts[c][0][i] for c, i in measures])  # (P, n)
            r = np.concatenate([self.parts[c][1][i] for c, i in measures])
            p = sum(int(self.parts[c][2][i]) for c, i in measures) / len(measures)
            shapes.setdefault(A.shape, []).append((g, A, r, p))
        for (P, _), members in shapes.items():
            A = np.stack([m[1] for m in members])  # (G, P, n)
            r = np.stack([m[2] for m in members])
            with np.errstate(all="ignore"):
                K = np.eye(P) - _sandwich(A, self.S)
                drops = _quadratic_or_inf(K, r)
            for (g, _, _, p), drop in zip(members, drops, strict=True):
                out[g] = drop / p
        return out

    def _one_channel(self, groups):
        """:meth:`joints`' stack ``(A, r, p)`` when every group has as many measures, all of
        one channel with equations: gathered by one index (the same arrays, in the same
        order, as joining each group's); None otherwise."""
        channel, size = groups[0][0][0], len(groups[0])
        if self.parts[channel] is None or any(
                len(g) != size or any(c != channel for c, _ in g) for g in groups):
            return None
        Cbar, rbar, rank = self.parts[channel]
        index = np.array([[i for _, i in g] for g in groups], dtype=np.intp)
        G, (p, n) = index.shape[0], Cbar.shape[1:]
        return (Cbar[index].reshape(G, size * p, n), rbar[index].reshape(G, size * p),
                rank[index].sum(axis=1) / size)


def _sandwich(A: np.ndarray, S: np.ndarray) -> np.ndarray:
    """``A_m S A_mᵀ`` for each matrix of the stack ``A`` (m, p, n): two matrix products
    (an ``einsum`` of the three operands sums over both indices at once, ~10× slower)."""
    return (A @ S) @ A.transpose(0, 2, 1)


def _quadratic_or_inf(K: np.ndarray, r: np.ndarray) -> np.ndarray:
    """``rᵀ K⁻¹ r`` per row of a stack, ``inf`` where ``K`` (``I`` less a leverage) is
    singular: the measures alone hold a direction of the parameter."""
    singular = ~(np.linalg.det(K) > 1e-12)
    K = np.where(singular[:, None, None], np.eye(K.shape[1]), K)
    if K.shape[1] == 1:  # one equation a measure: LAPACK's solve is this division, and
        return np.where(singular, np.inf, (r * (r / K[:, :, 0]))[:, 0])  # the same numbers
    z = np.linalg.solve(K, r[..., None])[..., 0]
    return np.where(singular, np.inf, np.einsum("mp,mp->m", r, z))


def deletion_drops(problem: Problem, fit: FitResult) -> tuple[np.ndarray, ...]:
    """Per channel, ``Δᵢ / pᵢ`` of each measure of ``problem`` (the problem ``fit`` was made
    on): the fall of the cost ``Σ ‖m̃ − m‖²_Q`` when the fit is made without it, per
    equation kept — the units of its error (eq. 24) — ``inf`` where the rest would not
    determine the parameter, ``nan`` where the fit has no covariance."""
    return Influence(problem, fit).drops()
