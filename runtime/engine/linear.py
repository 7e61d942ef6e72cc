"""The block local projector as kernels (report appendix A, Fig. 17; eq. 38–44): the
whitened linearisation at a point, the parameter block and the measures' corrections.

The per-measure algebra is :mod:`.measures`'.
"""

from __future__ import annotations

import numpy as np

from kanagen.common.borrow import alive, borrow
from kanagen.common.jit import jit
from kanagen.common.link import linked

from ..linalg import matmul
from ..sqrt import (
    REDUNDANT,
    closest_root,
    diagonal_max,
    reduced_root,
    solve_kept,
    solve_lower,
    solve_lower_columns,
)
from .measures import (
    ROUNDING,
    correct,
    factor,
    fields,
    residual_into,
    whiten_column,
    whiten_rows,
)


@linked("A f1 f2 f2 f3 f3 f1 f2 -> f2 f2 f1 f1 f3 f2 f3 f3 f2 b2 i1 f", python=True)
def linearise(A, q, mt, c, C, D, c0, C0):
    """The whitened linearisation at ``(q, m̃)`` (equations ``c, C, D`` there): returns
    ``(info, H, rhs, gradient, Cbar, rbar, E, L, inv, kept, ranks, residual)``.

    ``info = Q0 + Σ C̄ᵀC̄``; ``H`` the same augmented by ``ρ C0ᵀC0`` (a definite matrix
    wherever the constraints fix what the data leave free, with the same solution);
    ``rhs`` and ``gradient = −∇L²`` (without the augmentation), the whitened ``C̄, r̄'``,
    the per-measure factors and ranks, ``residual = Σ ‖W c‖²``."""
    n = q.size
    M = A.chan.size
    pmax = C.shape[1]
    dmax = A.m.shape[1]
    Cbar = np.zeros((M, pmax, n))
    rbar = np.zeros((M, pmax))
    E = np.zeros((M, pmax, dmax))
    L = np.zeros((M, pmax, pmax))
    inv = np.zeros((M, pmax))
    kept = np.zeros((M, pmax), dtype=np.bool_)
    ranks = np.zeros(M, dtype=np.int64)
    info = A.Q0.copy()
    g = np.zeros(n)
    residual = 0.0
    cbar, r = np.zeros(pmax), np.zeros(pmax)
    # the loop's arrays borrowed (kanagen.common.borrow): no reference counts per measure
    F = fields(A)
    bc, bC, bD, bmt = borrow((c, C, D, mt))
    bCbar, brbar, bE, bL, binv, bkept = borrow((Cbar, rbar, E, L, inv, kept))
    bcbar, br, binfo, bg = borrow((cbar, r, info, g))
    branks = borrow(ranks)
    eps = A.eps
    for i in range(M):
        ch = F[0][i]
        p, d = F[1][ch], F[2][ch]
        args = (i, n, eps, F[8][i], F[10][i], bc[i], bC[i], bD[i], bmt[i], bCbar[i], brbar[i],
                bE[i], bL[i], binv[i], bkept[i], branks, binfo, bg, bcbar, br)
        if p == 1 and d == 2:  # the shipped families' shapes: their loops unrolled
            residual = linearise_measure(args, 1, 2, residual)
        elif p == 1 and d == 4:
            residual = linearise_measure(args, 1, 4, residual)
        elif p == 3 and d == 4:
            residual = linearise_measure(args, 3, 4, residual)
        else:
            residual = linearise_measure(args, p, d, residual)
    alive((c, C, D, mt, A, cbar, r, info, g, ranks, Cbar, rbar, E, L, inv, kept))
    for j in range(n):
        for u in range(j):
            info[u, j] = info[j, u]
    rhs = g.copy()
    for a in range(n):
        acc = 0.0
        for b in range(n):
            acc += A.Q0[a, b] * (A.q0[b] - q[b])
        rhs[a] += acc
    gradient = -rhs
    H = info.copy()
    r0 = C0.shape[0]
    if r0:
        gram = matmul(C0.T, C0)
        top, bottom = diagonal_max(info), diagonal_max(gram)
        rho = 0.0 if not bottom > 0.0 else (top if top > 0.0 else 1.0) / bottom
        H += rho * gram
        for a in range(n):
            acc = 0.0
            for k in range(r0):
                acc += C0[k, a] * c0[k]
            rhs[a] -= rho * acc
    return info, H, rhs, gradient, Cbar, rbar, E, L, inv, kept, ranks, residual


@jit(inline=True)
def linearise_measure(args, p, d, residual):
    """Measure ``i``'s part of :func:`linearise` (``p`` equations, ``d`` components): its
    factor, rank and whitened rows, its terms added to ``info`` and ``g``; returns
    ``residual`` with its ``‖W c‖²`` added. ``args``: borrowed arrays."""
    (i, n, eps, G, m_obs, c, C, D, mt, Cbar, rbar, E, L, inv, kept, ranks, info, g, cbar,
     r) = args
    factor(D, G, p, d, eps, E, L, inv, kept)
    for a in range(p):
        ranks[i] += 1 if kept[a] else 0
    residual_into(D, mt, m_obs, c, p, d, r)
    whiten_column(L, inv, r, p, rbar)
    whiten_column(L, inv, c, p, cbar)
    whiten_rows(L, inv, C, p, n, Cbar)
    for a in range(p):
        residual += cbar[a] * cbar[a]
        for j in range(n):
            g[j] += Cbar[a, j] * rbar[a]
            for u in range(j + 1):
                info[j, u] += Cbar[a, j] * Cbar[a, u]
    return residual


@jit
def seen_components(info, C0, q):
    """Components the data or the constraints see (runtime/projector.py: ``_seen``)."""
    n = q.size
    seen = np.zeros(n, dtype=np.bool_)
    for j in range(n):
        seen[j] = info[j, j] != 0.0
    for form in range(2):
        for k in range(C0.shape[0]):
            top = 0.0
            for j in range(n):
                v = abs(C0[k, j]) if form == 0 else abs(C0[k, j] * q[j])
                if v != v:
                    top = np.nan
                    break
                top = max(top, v)
            for j in range(n):
                v = abs(C0[k, j]) if form == 0 else abs(C0[k, j] * q[j])
                if v > ROUNDING * top:
                    seen[j] = True
    return seen


@jit
def equilibrium_weights(H):
    n = H.shape[0]
    diag = np.empty(n)
    top = 0.0
    for a in range(n):
        diag[a] = abs(H[a, a])
        top = np.nan if diag[a] != diag[a] or top != top else max(top, diag[a])
    for a in range(n):
        if not diag[a] > 0:
            diag[a] = top if top > 0 else 1.0
    return diag


@linked("f2 f2 f1 f2 f1 f1 f f f1 f -> f1 b1 i f b", python=True)
def parameter_block(H, info, rhs, C0, c0, q, residual, mu, weights, eps):
    """``Δq`` of eq. 43 (damped by ``μ diag(w)``; ``w`` empty: the equilibrium weights of
    ``H``), the rows of ``C0`` kept, their rank and the residual E² (``ok`` False on a zero
    pivot)."""
    n, r0 = q.size, C0.shape[0]
    Hd = H.copy()
    if mu > 0.0:
        w = equilibrium_weights(H) if weights.size == 0 else weights
        for a in range(n):
            Hd[a, a] += mu * w[a]
    seen = seen_components(info, C0, q)
    idx = np.flatnonzero(seen)
    dq = np.zeros(n)
    kept0 = np.zeros(r0, dtype=np.bool_)
    if idx.size == 0:
        return dq, kept0, 0, residual, True
    Hs = np.empty((idx.size, idx.size))
    rs = np.empty(idx.size)
    Cs = np.empty((r0, idx.size))
    for a in range(idx.size):
        rs[a] = rhs[idx[a]]
        for b in range(idx.size):
            Hs[a, b] = Hd[idx[a], idx[b]]
        for k in range(r0):
            Cs[k, a] = C0[k, idx[a]]
    step, kept0, e0 = parameter_solve(Hs, rs, Cs, c0, eps)
    if step.size != idx.size:
        return dq, kept0, 0, residual, False
    for a in range(idx.size):
        dq[idx[a]] = step[a]
    return dq, kept0, int(kept0.sum()), residual + e0, True


@jit
def corrected(A, dq, Cbar, rbar, E, L, inv):
    """The measures of the projector's point for the step ``dq`` (eq. 44)."""
    M = A.chan.size
    out = np.zeros(A.m.shape)
    pmax, dmax = Cbar.shape[1], A.m.shape[1]
    z, y, dm = np.zeros(pmax), np.zeros(pmax), np.zeros(dmax)
    F = fields(A)  # A's arrays and the loop's borrowed: no reference counts per measure
    bdq, bCbar, brbar, bE, bL, binv, bout, bz, by, bdm = borrow((dq, Cbar, rbar, E, L, inv,
                                                                out, z, y, dm))
    for i in range(M):
        ch = F[0][i]
        p, d = F[1][ch], F[2][ch]
        args = (bdq, bCbar[i], brbar[i], bE[i], bL[i], binv[i], F[8][i], F[10][i], bout[i],
                bz, by, bdm)
        if p == 1 and d == 2:  # the shipped families' shapes: their loops unrolled
            corrected_measure(args, 1, 2)
        elif p == 1 and d == 4:
            corrected_measure(args, 1, 4)
        elif p == 3 and d == 4:
            corrected_measure(args, 3, 4)
        else:
            corrected_measure(args, p, d)
    alive((dq, Cbar, rbar, E, L, inv, z, y, dm, A))
    return out


@jit(inline=True)
def corrected_measure(args, p, d):
    """Measure ``i``'s corrected values of :func:`corrected` (``p`` equations, ``d``
    components). ``args``: borrowed arrays."""
    dq, Cbar, rbar, E, L, inv, G, m_obs, out, z, y, dm = args
    for a in range(p):
        acc = 0.0
        for j in range(dq.size):
            acc += Cbar[a, j] * dq[j]
        z[a] = rbar[a] - acc
    correct(E, L, inv, G, z, p, d, y, dm)
    for j in range(d):
        out[j] = m_obs[j] + dm[j]


# -- the parameter block and the constraints ----------------------------------------------

@jit
def constraint_root(Abar, C0, eps):
    """``C̄0ᵀ = Ā⁻¹ C0ᵀ`` and the reduced root ``L0`` (rows kept) of ``C̄0 C̄0ᵀ``: the
    constraints whitened by the metric ``Ā Āᵀ``. ``C̄0ᵀ`` is empty on a zero pivot of ``Ā``."""
    n, r = Abar.shape[0], C0.shape[0]
    C0bar_t = solve_lower_columns(Abar, np.ascontiguousarray(C0.T), False)
    gram = np.zeros((r, r))
    if C0bar_t.shape[0] == n:
        for a in range(r):
            for b in range(a + 1):
                acc = 0.0
                for i in range(n):
                    acc += C0bar_t[i, a] * C0bar_t[i, b]
                gram[a, b] = acc
                gram[b, a] = acc
    L0, kept0 = reduced_root(gram, eps)
    return C0bar_t, L0, kept0


@linked("f2 f1 f2 f1 f -> f1 b1 f")
def parameter_solve(H, rhs, C0, c0, eps):
    """``Δq`` of eq. 43 (``H = Ā Āᵀ`` its closest root, the constraints' rows reduced to
    their first independent ones), the rows of ``C0`` kept and ``‖L0⁻¹ c0‖²`` (the
    constraints' part of E²). ``Δq`` is empty on a zero pivot (non-finite input)."""
    n, r = H.shape[0], C0.shape[0]
    Abar = closest_root(H, max(eps, REDUNDANT))
    bbar = solve_lower(Abar, rhs, False)
    kept0 = np.zeros(r, dtype=np.bool_)
    e0sq = 0.0
    if bbar.size != n:
        return bbar, kept0, e0sq
    if r:
        C0bar_t, L0, kept0 = constraint_root(Abar, C0, eps)
        if C0bar_t.shape[0] != n:
            return np.empty(0), kept0, e0sq
        t = c0.copy()
        for a in range(r):
            for i in range(n):
                t[a] += C0bar_t[i, a] * bbar[i]
        lam = solve_kept(L0, kept0, solve_kept(L0, kept0, t, False), True)
        for i in range(n):
            acc = 0.0
            for a in range(r):
                acc += C0bar_t[i, a] * lam[a]
            bbar[i] -= acc
        e0 = solve_kept(L0, kept0, c0, False)
        for a in range(r):
            e0sq += e0[a] * e0[a]
    return solve_lower(Abar, bbar, True), kept0, e0sq


@jit
def retraction_step(root, C0, c0, eps):
    """The least move ``Q̃⁻¹ C0ᵀ (C0 Q̃⁻¹ C0ᵀ)⁻ c0`` onto ``c0 = 0`` in the metric
    ``Q̃ = root rootᵀ`` (:func:`restore_parameter`'s step, to subtract); NaN on a zero pivot."""
    n, r = root.shape[0], C0.shape[0]
    C0bar_t, L0, kept0 = constraint_root(root, C0, eps)
    if C0bar_t.shape[0] != n:
        return np.full(n, np.nan)
    y = solve_kept(L0, kept0, solve_kept(L0, kept0, c0, False), True)
    v = np.zeros(n)
    for i in range(n):
        for a in range(r):
            v[i] += C0bar_t[i, a] * y[a]
    step = solve_lower(root, v, True)
    return step if step.size == n else np.full(n, np.nan)


@jit
def whitened_violation(root, C0, c0, eps):
    """``‖c0‖²`` whitened by ``C0 Q̃⁻¹ C0ᵀ`` (its reduced root), ``Q̃ = root rootᵀ``; inf
    where that is not finite."""
    C0bar_t, L0, kept0 = constraint_root(root, C0, eps)
    if C0bar_t.shape[0] != root.shape[0]:
        return np.inf
    e0 = solve_kept(L0, kept0, c0, False)
    total = 0.0
    for a in range(e0.size):
        if not np.isfinite(e0[a]):
            return np.inf
        total += e0[a] * e0[a]
    return total
