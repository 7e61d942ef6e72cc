"""The exact Hessian of the profile ``F(q) = min L²`` over the corrected measures (SPEC §2:
the end's curvature check, runtime/iterate.py "The end").

At a restored point each measure's corrections solve ``min ½‖m̃ − m‖²_Q`` subject to
``c(q, m̃) = 0``, and ``∇F = Q0 (q − q0) + Σ Cᵀ λ`` with ``λ = −S⁻ D (m̃ − m)`` (eq. 44's
multipliers; ``S = D Q⁺ Dᵀ``). As ``q`` moves, ``m̃`` and ``λ`` follow by the implicit
function theorem on each measure's KKT system; in the whitened corrections ``z``
(``m̃ = m + Gᵀ z``, ``Q⁺ = GᵀG``, ``E = D Gᵀ``):

    [ I + G Φmm Gᵀ   Eᵀ ] [ ż ]     [ G Φmq ]
    [ E              0  ] [ λ̇ ] = − [ C     ]          ṁ = Gᵀ ż,

    ∇²F = Q0 + Σ ( Φqq + Φqm ṁ + Cᵀ λ̇ ),

with ``Φ = λᵀ c`` the measure's equations weighted by its multipliers, whose second
derivatives are taken by central differences of the analytic Jacobians ``C, D`` (the row
kernels; exact up to rounding for equations of degree two in each variable, as the
constraints' in :func:`.points.constraint_curvature`). Dropped equations (a vanishing pivot
of the reduced square root) carry no multiplier and no condition.

Only ``Wᵀ ∇²F W`` is formed, for the ``k`` directions the check needs (the columns of
``W``): per measure ``2 (k + d)`` evaluations of its equations — along each direction
(``Φqq w``, ``Φmq w``) and each corrected component (``Φqm``, ``Φmm``) — in one pass over
the measures, against the ``2 k`` restorations of every measure that central differences
of ``∇F`` cost. Equations linear in ``q`` (``C`` free of it, as the generator finds them:
``Arrays.linear``; the report's ``θ · ξ(m) = 0``) take only the ``2 d``: there ``Φqq = 0``
and ``Φmq w = Φqmᵀ w``.
"""

from __future__ import annotations

import numpy as np

from kanagen.common.borrow import alive, borrow
from kanagen.common.jit import jit
from kanagen.common.link import linked

from ..linalg import matmul, solve_small
from .measures import (
    STEP,
    difference_step,
    eval_shaped,
    fields,
    multipliers_of,
    row_buffer,
    weighted_gradient,
)


@jit(inline=True)
def measure_hessian(args, p, d):
    """Measure ``i``'s term of :func:`profile_hessian` added to ``T`` (``p`` equations, ``d``
    components); False where its KKT system is singular. ``args``: the kernel's arrays
    and buffers, borrowed."""
    (i, n, k, F, q, qh, mh, c, C, D, buf, mt, Cx, W, G, E, L, inv, rbar, lam, kept, steps,
     grads, Pqm, Pmm, PqW, PmW, S, R, mdot, T, linear) = args
    pk = multipliers_of(L, inv, rbar, p, lam, kept)
    if pk == 0:
        return True
    # central differences of (Cᵀλ, Dᵀλ): along each corrected component, then along
    # each direction of W — but for equations linear in q: Φqq = 0 and Φmq W = Φqmᵀ W
    for v in range(d if linear else d + k):
        if v < d:
            h = difference_step(mt[i], v, d)
        else:
            h = steps[v - d]
            if h == 0.0:
                for a in range(n):
                    PqW[a, v - d] = 0.0
                for u in range(d):
                    PmW[u, v - d] = 0.0
                continue
        for side in range(2):
            sign = h if side == 0 else -h
            for j in range(n):
                qh[j] = q[j] + (sign * W[j, v - d] if v >= d else 0.0)
            for u in range(d):
                mh[u] = mt[i, u] + (sign if u == v else 0.0)
            eval_shaped(F, i, qh, mh, c, C, D, buf, p, d)
            weighted_gradient(lam, c, C, D, p, n, d, grads, side)
        if v < d:
            for a in range(n):
                Pqm[a, v] = (grads[0, a] - grads[1, a]) / (2.0 * h)
            for u in range(d):
                Pmm[u, v] = (grads[0, n + u] - grads[1, n + u]) / (2.0 * h)
        else:
            for a in range(n):
                PqW[a, v - d] = (grads[0, a] - grads[1, a]) / (2.0 * h)
            for u in range(d):
                PmW[u, v - d] = (grads[0, n + u] - grads[1, n + u]) / (2.0 * h)
    if linear:
        for j in range(k):
            for a in range(n):
                PqW[a, j] = 0.0
            for u in range(d):
                acc = 0.0
                for a in range(n):
                    acc += Pqm[a, u] * W[a, j]
                PmW[u, j] = acc
    # the KKT system in (ż, λ̇) for the k directions
    size = d + pk
    for a in range(size):
        for b in range(size):
            S[a, b] = 0.0
    for a in range(d):  # I + G Φmm Gᵀ (Φmm symmetrised)
        for b in range(d):
            acc = 1.0 if a == b else 0.0
            for u in range(d):
                t = 0.0
                for w in range(d):
                    t += 0.5 * (Pmm[u, w] + Pmm[w, u]) * G[b, w]
                acc += G[a, u] * t
            S[a, b] = acc
    for e in range(pk):  # E on the kept equations
        for b in range(d):
            S[d + e, b] = E[kept[e], b]
            S[b, d + e] = E[kept[e], b]
    for j in range(k):
        for e in range(pk):  # C w
            acc = 0.0
            for a in range(n):
                acc += Cx[i, kept[e], a] * W[a, j]
            R[d + e, j] = -acc
        for a in range(d):  # −G Φmq w
            acc = 0.0
            for u in range(d):
                acc += G[a, u] * PmW[u, j]
            R[a, j] = -acc
    if not solve_small(S, R, size, k):
        return False
    for u in range(d):  # ṁ = Gᵀ ż
        for j in range(k):
            acc = 0.0
            for a in range(d):
                acc += G[a, u] * R[a, j]
            mdot[u, j] = acc
    for j in range(k):  # T += Φqq w_j + Φqm ṁ_j + Cᵀ λ̇_j (K = Wᵀ Σ T, once at the end)
        for b in range(n):
            acc = PqW[b, j]
            for u in range(d):
                acc += Pqm[b, u] * mdot[u, j]
            for e in range(pk):
                acc += Cx[i, kept[e], b] * R[d + e, j]
            T[b, j] += acc
    return True


@linked("A Pt Lin f2 -> b f2")
def profile_hessian(A, x, lin, W):
    """``Wᵀ ∇²F W`` at the restored point ``x`` (its linearisation ``lin``): ``ok`` False
    where a measure's KKT system is singular (the profile is not smooth there) or a value
    is not finite."""
    q = np.ascontiguousarray(x.q)
    n, k = q.size, W.shape[1]
    M = A.chan.size
    pmax, dmax = x.c.shape[1], A.m.shape[1]
    T = np.zeros((n, k))  # Σ over the measures of ∇²F's columns along W
    s_max = dmax + pmax
    lam = np.zeros(pmax)
    kept = np.zeros(pmax, np.int64)
    grads = np.zeros((2, n + dmax))
    Pqm = np.zeros((n, dmax))  # Φqm
    Pmm = np.zeros((dmax, dmax))  # Φmm
    PqW = np.zeros((n, k))  # Φqq W
    PmW = np.zeros((dmax, k))  # Φmq W
    S = np.zeros((s_max, s_max))
    R = np.zeros((s_max, k))
    mdot = np.zeros((dmax, k))
    c, C, D = np.zeros(pmax), np.zeros((pmax, n)), np.zeros((pmax, dmax))
    buf = row_buffer(A, n)
    qh, mh = q.copy(), np.zeros(dmax)
    scale_q = 0.0
    for j in range(n):
        scale_q = max(scale_q, abs(q[j]))
    steps = np.zeros(k)  # each direction's step: its largest component STEP·|q|
    for j in range(k):
        top = 0.0
        for a in range(n):
            top = max(top, abs(W[a, j]))
        steps[j] = STEP * max(scale_q, 1e-8) / top if top > 0.0 else 0.0
    bq, bqh, bmh, bc, bC, bD, bbuf = borrow((q, qh, mh, c, C, D, buf))
    mt, Cx, bW = borrow((x.mt, x.C, W))
    F = fields(A)
    chan, P, Dn, Gs = F[0], F[1], F[2], F[8]
    linear = borrow(A.linear)
    Es, Ls, invs, rbars = borrow((lin.E, lin.L, lin.inv, lin.rbar))
    blam, bkept, bsteps, bgrads = borrow((lam, kept, steps, grads))
    bPqm, bPmm, bPqW, bPmW, bS, bR, bmdot, bT = borrow((Pqm, Pmm, PqW, PmW, S, R, mdot, T))
    for i in range(M):
        ch = chan[i]
        p, d = P[ch], Dn[ch]
        args = (i, n, k, F, bq, bqh, bmh, bc, bC, bD, bbuf, mt, Cx, bW, Gs[i], Es[i], Ls[i],
                invs[i], rbars[i], blam, bkept, bsteps, bgrads, bPqm, bPmm, bPqW, bPmW, bS, bR,
                bmdot, bT, linear[ch] != 0)
        if p == 1 and d == 2:  # the shipped families' shapes: their loops unrolled
            ok = measure_hessian(args, 1, 2)
        elif p == 1 and d == 4:
            ok = measure_hessian(args, 1, 4)
        elif p == 3 and d == 4:
            ok = measure_hessian(args, 3, 4)
        else:
            ok = measure_hessian(args, p, d)
        if not ok:
            return False, np.zeros((k, k))
    alive((q, qh, mh, c, C, D, buf, x, W, lin, lam, kept, steps, grads, Pqm, Pmm, PqW, PmW, S,
           R, mdot, T))
    K = matmul(W.T, matmul(A.Q0, W) + T)
    for a in range(k):
        for b in range(a):
            mean = 0.5 * (K[a, b] + K[b, a])
            K[a, b] = mean
            K[b, a] = mean
    return bool(np.all(np.isfinite(K))), K
