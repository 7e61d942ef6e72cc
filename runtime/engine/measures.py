"""Per-measure kernels: equations at a point, the per-measure algebra of the projector
(report appendix A, Fig. 17), the measures projected onto their equations for a fixed
parameter (eq. 22 iterated, with eq. 18's halving) and the restoration that finishes the
measures those steps leave off (runtime/restoration.py describes the method).

Every measure is handled on its own: the results do not depend on which other measures a
call holds. ``A`` is the problem's :class:`~.data.Arrays`.
"""

from __future__ import annotations

import numpy as np

from kanagen.common.borrow import alive, borrow
from kanagen.common.jit import jit
from kanagen.common.link import linked, record_kind

from ..linalg import solve_small
from ..sqrt import REDUNDANT
from .rows import call3, call4

_TINY = np.finfo(float).tiny
#: Relative rounding level of stored values (moves below it are noise).
ROUNDING = 1e3 * np.finfo(float).eps
#: Projection steps of a restoration (eq. 22) at most, and the move (in standard
#: deviations) below which a measure has converged.
RESTORE_STEPS, RESTORE_TOL = 30, 1e-10
#: A measure whose whitened violation stays above this (cost units) did not reach its
#: equations by the projector's steps.
UNREACHED = 1e-16
_NEWTON = 8  # normal (Newton) steps onto the manifold, at most
_HALVINGS = 12  # halvings of a step along the manifold
_DESCENT = 12  # steps along the manifold, at most
#: Trial points of a descent left off the manifold since its last full step, at most: each
#: was tried in every metric, the descent's cost where the manifold runs off (docs/engine.md,
#: thirty-second and thirty-fifth sections).
_MISSES = 8
_PROJECT_HALVINGS = 4  # halvings of a projector step per measure (eq. 18)
#: Relative step of the central differences of the equations' Jacobians.
STEP = 1e-5


# -- equations --------------------------------------------------------------------------

@jit
def c0_eval(A, q):
    """``c0 (r)`` and ``C0 (r, n)`` at ``q`` (views of one new array)."""
    n, r = q.size, A.r
    out = np.empty(r + r * n)
    call3(A.c0_addr, np.ascontiguousarray(q), A.k, out)
    return out[:r], out[r:].reshape(r, n)


@jit(inline=True)
def fields(A):
    """The per-measure arrays of ``A`` that the loops over the measures read — ``(chan, P,
    Dn, W, X, col, meas_addr, k, G, Q, m, vals_addr)`` — borrowed (kanagen.common.borrow): a
    field read from ``A`` and each view of it are otherwise counted up and down, atomically,
    at every use, which cost more than a measure's arithmetic. Valid while ``A`` (the
    kernel's argument) is."""
    return borrow((A.chan, A.P, A.Dn, A.W, A.X, A.col, A.meas_addr, A.k, A.G, A.Q, A.m,
                   A.vals_addr))


@jit(inline=True)
def eval_measure(F, i, q, mt_i, c, C, D, x):
    """Write measure ``i``'s ``c (p)``, ``C (p, n)``, ``D (p, d)`` at ``(q, mt_i)`` (``F``:
    :func:`fields`; ``x``: a buffer of :func:`row_buffer`'s size)."""
    ch = F[0][i]
    eval_shaped(F, i, q, mt_i, c, C, D, x, F[1][ch], F[2][ch])


@jit(inline=True)
def eval_shaped(F, i, q, mt_i, c, C, D, x, p, d):
    """:func:`eval_measure` for a measure of ``p`` equations and ``d`` components: constants
    in the loops specialised to the shipped shapes — (1, 2), (1, 4), (3, 4), in that order
    in :func:`eval_all`, :func:`project_all` and ``curvature.profile_hessian``
    (docs/engine.md) — the sizes read elsewhere."""
    n = q.size
    out = call_row(F, i, q, mt_i, x, d, F[6])
    take_values(out, c, D, p, n, d)
    for a in range(p):
        for j in range(n):
            C[a, j] = out[p + a * n + j]


@jit(inline=True)
def eval_values(F, i, q, mt_i, c, D, x, p, d):
    """:func:`eval_shaped`'s ``c`` and ``D`` alone, from the row form's values form (the
    generated module's ``VALUES``: the row form's statements that they need, in its order —
    the same numbers, without the Jacobian in the parameter ``C``, most of a row form's
    work where the parameter is large); its loops specialised as :func:`eval_shaped`'s in
    :func:`project_all`, ``sample.observed_all`` and ``sample.errors_at``."""
    take_values(call_row(F, i, q, mt_i, x, d, F[11]), c, D, p, q.size, d)


@jit(inline=True)
def take_values(out, c, D, p, n, d):
    """``c`` and ``D`` from a row kernel's outputs ``out`` (the row form's layout: ``c``,
    ``C``, ``D``; ``n`` the parameter's size)."""
    for a in range(p):
        c[a] = out[a]
        for j in range(d):
            D[a, j] = out[p + p * n + a * d + j]


@jit(inline=True)
def call_row(F, i, q, mt_i, x, d, addresses):
    """Measure ``i``'s data row, its corrected components ``mt_i`` in place, into ``x``, and
    the row kernel of its channel in ``addresses`` called on it: its outputs (a view of
    ``x``, in the row form's layout)."""
    chan, W, X, col, k = F[0], F[3], F[4], F[5], F[7]
    ch = chan[i]
    w = W[ch]
    for j in range(w):
        x[j] = X[i, j]
    for j in range(d):
        x[col[ch, j]] = mt_i[j]
    out = x[w:]
    call4(addresses[ch], q, x[:w], k, out)
    return out


@jit
def equations_max(A):
    """The most equations a measure has (at least one: the padded arrays' width)."""
    return max(1, A.P.max()) if A.P.size else 1


@jit
def row_buffer(A, n):
    """A buffer for :func:`eval_measure`: a data row and the kernel's outputs."""
    pmax = equations_max(A)
    return np.empty(A.X.shape[1] + pmax + pmax * n + pmax * A.m.shape[1])


@jit
def empty_evals(A, n):
    pmax = equations_max(A)
    return (np.zeros((A.chan.size, pmax)), np.zeros((A.chan.size, pmax, n)),
            np.zeros((A.chan.size, pmax, A.m.shape[1])))


@jit(inline=True)
def copy_into(dst, src):
    """``dst[...] = src`` for C-ordered arrays of one size, without the broadcasting
    check whose error message (built at run time) is most of a small kernel's code; through
    their flat iterators, not a reshape (numba's reshape calls a C helper: 30-40 ns a copy of
    a few numbers, against 3-7)."""
    into, values = dst.flat, src.flat
    for a in range(src.size):
        into[a] = values[a]


@jit(inline=True)
def residual_into(D, m, m_obs, c, p, d, out):
    """``out = D (m̃ − m) − c``: the right-hand side ``r − C q•`` of a measure's linearised
    equations (SPEC §2, in increments; with ``q`` fixed, eq. 22's)."""
    for a in range(p):
        acc = 0.0
        for j in range(d):
            acc += D[a, j] * (m[j] - m_obs[j])
        out[a] = acc - c[a]


@jit
def eval_all(A, q, mt):
    """The equations of every measure at ``(q, mt)``: ``c, C, D`` padded."""
    q = np.ascontiguousarray(q)
    c, C, D = empty_evals(A, q.size)
    x = row_buffer(A, q.size)
    bq, bmt, bc, bC, bD, bx = borrow((q, mt, c, C, D, x))
    F = fields(A)
    for i in range(A.chan.size):
        ch = F[0][i]
        p, d = F[1][ch], F[2][ch]
        if p == 1 and d == 2:  # the shipped families' shapes: their loops unrolled
            eval_shaped(F, i, bq, bmt[i], bc[i], bC[i], bD[i], bx, 1, 2)
        elif p == 1 and d == 4:
            eval_shaped(F, i, bq, bmt[i], bc[i], bC[i], bD[i], bx, 1, 4)
        elif p == 3 and d == 4:
            eval_shaped(F, i, bq, bmt[i], bc[i], bC[i], bD[i], bx, 3, 4)
        else:
            eval_shaped(F, i, bq, bmt[i], bc[i], bC[i], bD[i], bx, p, d)
    alive((q, x))
    return c, C, D


@jit(inline=True)
def quad(v, Q, d):
    """``vᵀ Q v`` over the first ``d`` components."""
    total = 0.0
    for a in range(d):
        acc = 0.0
        for b in range(d):
            acc += Q[a, b] * v[b]
        total += v[a] * acc
    return total


@jit
def point_values(A, q, mt, c, c0):
    """``(delta, cost)`` of a point: ``‖c(x)‖∞`` over every equation (NaN counts as
    infinite) and ``L² = ½‖q−q0‖²_Q0 + Σ ½‖m̃−m‖²_Q`` (eq. 2)."""
    delta = 0.0
    for a in range(c0.size):
        v = abs(c0[a])
        delta = np.inf if v != v or delta == np.inf else max(delta, v)
    n = q.size
    dq = q - A.q0
    cost = 0.0
    for a in range(n):
        acc = 0.0
        for b in range(n):
            acc += A.Q0[a, b] * dq[b]
        cost += dq[a] * acc
    cost *= 0.5
    F = fields(A)  # A's arrays borrowed, and the loop's: no reference counts per measure
    chan, P, Dn, Q, m_obs = F[0], F[1], F[2], F[9], F[10]
    bmt, bc = borrow((mt, c))
    for i in range(chan.size):
        ch = chan[i]
        p, d = P[ch], Dn[ch]
        args = (bc[i], bmt[i], m_obs[i], Q[i])
        if p == 1 and d == 2:  # the shipped families' shapes: their loops unrolled
            delta, cost = measure_values(args, 1, 2, delta, cost)
        elif p == 1 and d == 4:
            delta, cost = measure_values(args, 1, 4, delta, cost)
        elif p == 3 and d == 4:
            delta, cost = measure_values(args, 3, 4, delta, cost)
        else:
            delta, cost = measure_values(args, p, d, delta, cost)
    return delta, cost


@jit(inline=True)
def measure_values(args, p, d, delta, cost):
    """:func:`point_values`'s ``delta`` and ``cost`` with one measure's terms (``p``
    equations, ``d`` components; ``args``: its ``c, m̃, m, Q``)."""
    c, mt, m_obs, Q = args
    for a in range(p):
        v = abs(c[a])
        delta = np.inf if v != v or delta == np.inf else max(delta, v)
    return delta, cost + 0.5 * quad_between(mt, m_obs, Q, d)


@jit(inline=True)
def quad_between(m, m_obs, Q, d):
    """``(m − m_obs)ᵀ Q (m − m_obs)`` over the first ``d`` components (:func:`quad` of the
    difference, without forming it)."""
    total = 0.0
    for a in range(d):
        acc = 0.0
        for b in range(d):
            acc += Q[a, b] * (m[b] - m_obs[b])
        total += (m[a] - m_obs[a]) * acc
    return total


# -- the per-measure algebra: whiten and correct ----------------------------------------

@jit(inline=True)
def factor(D, G, p, d, eps, E, L, inv, kept):
    """``E = D Gᵀ`` and the reduced square root of ``S = E Eᵀ = D Q⁺ Dᵀ`` (``Q⁺ = GᵀG``, G
    lower triangular), written into ``E, L, inv, kept``: ``inv`` the inverse pivots, 0 for
    a dropped equation (a pivot <= eps·scale, or <= REDUNDANT times its own diagonal). The
    operations are those of the generated unrolled kernels (``whiten_p_k``)."""
    for a in range(p):
        for j in range(d):
            acc = 0.0
            for u in range(j + 1):
                acc += D[a, u] * G[j, u]
            E[a, j] = acc
    top = 0.0
    for a in range(p):
        acc = 0.0
        for j in range(d):
            acc += E[a, j] * E[a, j]
        if a == 0 or acc != acc:  # NaN propagates, as through np.maximum
            top = acc
        elif top == top:
            top = max(top, acc)
    tol = eps * max(top, _TINY) if top == top else np.nan
    for a in range(p):
        piv = 0.0
        for j in range(d):
            piv += E[a, j] * E[a, j]
        S_aa = piv
        for b in range(a):
            piv -= L[a, b] ** 2
        keep = piv > tol and (a == 0 or piv > REDUNDANT * S_aa)
        kept[a] = keep
        inv[a] = 1.0 / np.sqrt(piv) if keep else 0.0
        for i in range(a + 1, p):
            acc = 0.0
            for j in range(d):
                acc += E[i, j] * E[a, j]
            for b in range(a):
                acc -= L[i, b] * L[a, b]
            L[i, a] = acc * inv[a]


@jit(inline=True)
def whiten_column(L, inv, b, p, out):
    """``out = L⁻¹ b`` on the kept equations (dropped ones give 0)."""
    for a in range(p):
        acc = b[a]
        for k in range(a):
            acc -= L[a, k] * out[k]
        out[a] = acc * inv[a]


@jit(inline=True)
def whiten_rows(L, inv, B, p, n, out):
    """``out = L⁻¹ B`` for a ``(p, n)`` matrix ``B``: :func:`whiten_column` on each of its
    ``n`` columns (the same operations), in one pass over its rows."""
    for a in range(p):
        for j in range(n):
            acc = B[a, j]
            for k in range(a):
                acc -= L[a, k] * out[k, j]
            out[a, j] = acc * inv[a]


@jit(inline=True)
def unwhiten_column(L, inv, z, p, y):
    """``y = L⁻ᵀ z`` on the kept equations (``Lᵀ``'s diagonal is ``1 / inv``; dropped ones
    give 0)."""
    for a in range(p - 1, -1, -1):
        acc = z[a]
        for i in range(a + 1, p):
            acc -= L[i, a] * y[i]
        y[a] = acc * inv[a]


@jit(inline=True)
def correct(E, L, inv, G, z, p, d, y, dm):
    """``dm = Gᵀ Eᵀ S⁻ z``: the measure correction from the whitened ``z`` (``y`` scratch,
    ``p`` long; ``dm`` is ``d`` long)."""
    unwhiten_column(L, inv, z, p, y)
    for u in range(d):
        acc = 0.0
        for j in range(u, d):
            t = 0.0
            for a in range(p):
                t += E[a, j] * y[a]
            acc += G[j, u] * t
        dm[u] = acc


@jit(inline=True)
def multipliers_of(L, inv, rbar, p, lam, kept):
    """``λ = −L⁻ᵀ r̄`` (a dropped equation's 0) and the kept equations' indices; returns
    their number."""
    pk = 0
    unwhiten_column(L, inv, rbar, p, lam)
    for a in range(p):
        lam[a] = -lam[a]
        if inv[a] != 0.0:
            kept[pk] = a
            pk += 1
    return pk


@jit(inline=True)
def weighted_gradient(lam, c, C, D, p, n, d, out, at):
    """``out[at] = (Cᵀλ, Dᵀλ)``: the gradient of ``λᵀ c`` in ``(q, m̃)`` (``n = 0``: in ``m̃``
    alone, ``C`` unread)."""
    for j in range(n):
        acc = 0.0
        for a in range(p):
            acc += lam[a] * C[a, j]
        out[at, j] = acc
    for u in range(d):
        acc = 0.0
        for a in range(p):
            acc += lam[a] * D[a, u]
        out[at, n + u] = acc


@jit(inline=True)
def difference_step(m, v, d):
    """The step of a central difference along component ``v`` of a measure ``m`` (``d``
    components): ``STEP · max(|m_v|, 10⁻³ max|m|, 10⁻⁸)``."""
    scale = 0.0
    for u in range(d):
        scale = max(scale, abs(m[u]))
    return STEP * max(abs(m[v]), 1e-3 * scale, 1e-8)


#: The buffers of :func:`scratch` (a plain tuple).
record_kind("Work", None, "f2 f2 f1 b1 f1 f1 f1 f1 f1 f1 f1 f1")


@jit
def scratch(A, n):
    """Buffers of the per-measure algebra, for the largest channel of ``A``: ``E, L, inv,
    kept, y, w1, w2`` (equations), ``dm, step, cand, moved`` (components), ``x``
    (:func:`row_buffer`). Allocated once a kernel call."""
    p = equations_max(A)
    d = A.m.shape[1]
    flat = np.zeros(p * d + p * p + 4 * p + 4 * d)  # one allocation, cut into the buffers
    square = p * d + p * p
    of_p = flat[square:square + 4 * p].reshape(4, p)  # four buffers of p, then four of d
    of_d = flat[square + 4 * p:].reshape(4, d)
    return (flat[:p * d].reshape(p, d), flat[p * d:square].reshape(p, p), of_p[0],
            np.zeros(p, dtype=np.bool_), of_p[1], of_p[2], of_p[3], of_d[0], of_d[1],
            of_d[2], of_d[3], row_buffer(A, n))


@jit(inline=True)
def violation(c, D, G, p, d, eps, work):
    """A measure's whitened violation ``‖c‖²_{(D Q⁺ Dᵀ)⁻}`` in metric ``G``, and whether
    the whitened values are finite (``work``: :func:`scratch`); infinite where ``D`` is
    not (:func:`whitened`)."""
    E, L, inv, kept, y, w1, w2, dm, step, cand, moved, x = work
    total = whitened(c, D, G, p, d, eps, E, L, inv, kept, w1)[0]
    return total, np.isfinite(total)


@jit(inline=True)
def whitened(c, D, G, p, d, eps, E, L, inv, kept, w):
    """``S = D Q⁺ Dᵀ`` factored (:func:`factor`) and ``c`` whitened into ``w``: the
    violation ``‖c‖²_{S⁻}`` and the number of equations kept. The violation is infinite
    where ``E = D Gᵀ`` is not finite: an infinite pivot whitens any ``c`` to 0, and a NaN
    drops its equation — a point where the equations' slope is infinite (``dose**n`` at
    ``dose = 0``, ``n < 1``) would pass for one on them."""
    factor(D, G, p, d, eps, E, L, inv, kept)
    whiten_column(L, inv, c, p, w)
    viol, rank = 0.0, 0
    for a in range(p):
        viol += w[a] ** 2
        rank += 1 if kept[a] else 0
        for j in range(d):
            if not np.isfinite(E[a, j]):
                viol = np.inf
    return viol, rank


@jit(inline=True)
def worst_abs(c, p):
    """``‖c‖∞`` of the first ``p`` equations, infinite where one is not finite (``max``
    would pass over a NaN, and a step into the equations' domain's outside be taken)."""
    worst = 0.0
    for a in range(p):
        if not np.isfinite(c[a]):
            return np.inf
        worst = max(worst, abs(c[a]))
    return worst


@jit
def all_finite(v):
    for a in range(v.size):
        if not np.isfinite(v[a]):
            return False
    return True


# -- eq. 22: the measures projected for a fixed q ---------------------------------------

@jit(inline=True)
def project_measure(args, p, d):
    """Project measure ``i`` onto ``c_i(q, ·) = 0`` from ``m`` (updated in place) in its
    ``Q_i`` metric (eq. 22 with eq. 18's halving; ``F``: :func:`fields`). ``iterations``
    counts projector steps plus one. Writes ``c, C, D`` at the returned point (``C`` only
    with ``jacobian``: else the values forms alone, the same ``c`` and ``D``); returns
    ``(violation, rank, unsettled)``. ``args``: ``(F, i, q, m, iterations, tol, eps, c, C, D,
    jacobian)`` and the buffers of :func:`scratch`; ``p, d`` the measure's equations and
    components. ``unsettled``: its last step still moved it (the steps ran out before it
    converged)."""
    F, i, q, m, iterations, tol, eps, c, C, D, jacobian, E, L, inv, kept, y, rbar, cbar, dm, \
        step, cand, moved, x = args
    G, Q, m_obs = F[8][i], F[9][i], F[10][i]
    if iterations <= 1 and jacobian:  # no step: the point returned
        eval_shaped(F, i, q, m, c, C, D, x, p, d)
    else:  # a step at least, whose point is returned (halving)
        eval_values(F, i, q, m, c, D, x, p, d)
    viol, rank = 0.0, 0
    active = True
    for it in range(iterations):
        residual_into(D, m, m_obs, c, p, d, y)
        viol, rank = whitened(c, D, G, p, d, eps, E, L, inv, kept, cbar)
        whiten_column(L, inv, y, p, rbar)
        if it == iterations - 1 or not active:
            break
        correct(E, L, inv, G, rbar, p, d, y, dm)
        finite = True
        for j in range(d):
            step[j] = m_obs[j] + dm[j] - m[j]
            finite = finite and np.isfinite(step[j])
        if not finite:
            step[:d] = 0.0
        active = halving(F, i, q, m, c, C, D, step, p, d, cand, moved, x, Q, tol,
                         it == iterations - 2, jacobian)
    return viol, rank, active and iterations > 1


@jit(inline=True)
def moving(moved, m, Q, tol, d):
    """A measure's projection goes on after the move ``moved`` to ``m``: the move is seen in
    its metric, or above rounding in a component the metric does not see."""
    unseen = False
    for j in range(d):
        unseen = unseen or abs(moved[j]) > ROUNDING * (1.0 + abs(m[j]))
    return quad(moved, Q, d) > tol ** 2 or unseen


@jit(inline=True)
def halving(F, i, q, m, c, C, D, step, p, d, cand, moved, x, Q, tol, last, jacobian):
    """Eq. 18 for one measure: ``m + α step`` with α halved while the violation grows (four
    times at most), else no move; updates ``m, c, C, D`` in place, writes the move into
    ``moved``; returns whether the projection goes on after the move (:func:`moving`).
    ``C`` is made only at a candidate that would end the projection — its last step
    (``last``), or a move :func:`moving` stops at — the others need only ``c`` and ``D``
    (:func:`eval_values`); so ``C`` is the returned point's. Without ``jacobian``, never."""
    worst = worst_abs(c, p)
    alpha = 1.0
    goes_on = False
    for attempt in range(_PROJECT_HALVINGS + 1):
        if attempt == _PROJECT_HALVINGS:
            alpha = 0.0
        for j in range(d):
            cand[j] = m[j] + alpha * step[j]
            moved[j] = cand[j] - m[j]
        goes_on = moving(moved, cand, Q, tol, d)
        if jacobian and (last or not goes_on):
            eval_shaped(F, i, q, cand, c, C, D, x, p, d)
        else:
            eval_values(F, i, q, cand, c, D, x, p, d)
        new_worst = worst_abs(c, p) if p else worst
        if new_worst <= worst + 1e-9 * (1.0 + worst) or attempt == _PROJECT_HALVINGS:
            break
        alpha /= 2
    for j in range(d):  # moved: the candidate taken's move
        m[j] = cand[j]
    return goes_on


@linked("A f1 f2 i f -> f2 f1 i1 f2 f3 f3", python=True)
def project_all(A, q, mt, iterations, tol):
    """:func:`project_measure` for every measure: ``(m̃, violations, ranks, c, C, D)``."""
    return project_flagged(A, q, mt, iterations, tol, np.zeros(0, dtype=np.bool_))


@jit
def project_flagged(A, q, mt, iterations, tol, unsettled):
    """:func:`project_all`, each measure's ``unsettled`` flag (:func:`project_measure`)
    written into ``unsettled`` unless it is empty."""
    q = np.ascontiguousarray(q)
    M = A.chan.size
    c, C, D = empty_evals(A, q.size)
    out = mt.copy()
    viol = np.zeros(M)
    rank = np.zeros(M, dtype=np.int64)
    project_each(A, q, out, iterations, tol, c, C, D, True, viol, rank,
                 np.zeros(0, dtype=np.bool_), unsettled)  # chosen empty: every measure
    return out, viol, rank, c, C, D


@jit
def project_chosen(A, q, mt, chosen, iterations, tol):
    """:func:`project_measure` for the measures ``chosen`` (a flag each) from ``mt``:
    ``(m̃, violations, c, C, D)``, the others left where they are, their violation
    infinite."""
    q = np.ascontiguousarray(q)
    c, C, D = empty_evals(A, q.size)
    out = mt.copy()
    viol = np.full(A.chan.size, np.inf)
    rank = np.zeros(A.chan.size, dtype=np.int64)
    project_each(A, q, out, iterations, tol, c, C, D, True, viol, rank, chosen,
                 np.zeros(0, dtype=np.bool_))
    return out, viol, c, C, D


@jit
def projected_errors(A, q, iterations, tol):
    """Every measure projected onto its equations for ``q`` from where it was observed
    (:func:`project_measure`, its values forms alone: nothing reads the Jacobians) and its
    error there before eq. 24's division: ``(‖m̃ − m‖²_Q + violation, equations kept)``
    (:func:`kanagen.runtime.minimal.coherence_errors`; the quadratic summed as NumPy's
    ``einsum("mk,mkl,ml->m")`` sums it, the same numbers)."""
    q = np.ascontiguousarray(q)
    M, pmax = A.chan.size, equations_max(A)
    out = A.m.copy()
    viol = np.zeros(M)
    rank = np.zeros(M, dtype=np.int64)
    c, C, D = np.zeros((1, pmax)), np.zeros((1, pmax, q.size)), np.zeros((1, pmax, A.m.shape[1]))
    project_each(A, q, out, iterations, tol, c, C, D, False, viol, rank,
                 np.zeros(0, dtype=np.bool_), np.zeros(0, dtype=np.bool_))
    totals = np.empty(M)
    F = fields(A)
    for i in range(M):
        d, Q, m_obs = F[2][F[0][i]], F[9][i], F[10][i]
        acc = 0.0
        for u in range(d):
            for v in range(d):
                acc += (out[i, u] - m_obs[u]) * Q[u, v] * (out[i, v] - m_obs[v])
        totals[i] = acc + viol[i]
    return totals, rank


@jit
def project_each(A, q, out, iterations, tol, c, C, D, jacobian, viol, rank, chosen,
                 unsettled):
    """:func:`project_measure` for every measure of ``A`` (those flagged in ``chosen``
    unless it is empty) from ``out`` (updated in place), its violation and rank into
    ``viol, rank`` and, unless it is empty, whether its steps ran out before it converged
    into ``unsettled``; its equations into the rows of ``c, C, D`` (its own row each, or one
    row for all when they have one). Returns the number of measures projected.

    The measures of each shipped shape (:data:`SHAPES`) are projected by that shape's
    kernel, its loops unrolled, the others by the generic one (:func:`project_span`); each
    measure's projection is its own, so their order does not matter. The four kernels are
    linked (compiled once each, called through their addresses): inlined into each of the
    three callers, the four copies of :func:`project_measure` made two thirds of the
    engine's first compile (docs/performance.md)."""
    present = 0  # a bit per shape's index (the last: another shape)
    for ch in range(A.P.size):
        present |= 1 << shape_index(A.P[ch], A.Dn[ch])
    count = 0
    if present & 1:
        count += project_1_2(A, q, out, iterations, tol, c, C, D, jacobian, viol, rank,
                             chosen, unsettled)
    if present & 2:
        count += project_1_4(A, q, out, iterations, tol, c, C, D, jacobian, viol, rank,
                             chosen, unsettled)
    if present & 4:
        count += project_3_4(A, q, out, iterations, tol, c, C, D, jacobian, viol, rank,
                             chosen, unsettled)
    if present & 8:
        count += project_other(A, q, out, iterations, tol, c, C, D, jacobian, viol, rank,
                               chosen, unsettled)
    return count


#: The shipped families' measure shapes ``(equations, components)``: each has a projection
#: kernel with its loops unrolled (:func:`project_each`).
SHAPES = ((1, 2), (1, 4), (3, 4))


@jit(inline=True)
def shape_index(p, d):
    """The index of ``(p, d)`` in :data:`SHAPES`, ``len(SHAPES)`` for another shape."""
    if p == 1 and d == 2:
        return 0
    if p == 1 and d == 4:
        return 1
    if p == 3 and d == 4:
        return 2
    return 3


@jit(inline=True)
def project_span(A, q, out, iterations, tol, c, C, D, jacobian, viol, rank, chosen,
                 unsettled, P, Dm, shape):
    """:func:`project_each` for the measures of one shape: ``shape`` its index in
    :data:`SHAPES` and ``(P, Dm)`` the shape (constants: the loops unrolled), or ``shape``
    ``len(SHAPES)`` for every measure of another shape (``P``, ``Dm`` unused: its own).
    Returns the number of measures it projected."""
    work = scratch(A, q.size)
    E, L, inv, kept, y, rbar, cbar, dm, step, cand, moved, x = borrow(work)
    bq, bout, bc, bC, bD = borrow((q, out, c, C, D))
    F = fields(A)
    eps = A.eps
    own = c.shape[0] == out.shape[0]
    count = 0
    for i in range(out.shape[0]):
        if chosen.size and not chosen[i]:
            continue
        ch = F[0][i]
        p, d = F[1][ch], F[2][ch]
        if shape_index(p, d) != shape:
            continue
        count += 1
        r = i if own else 0
        args = (F, i, bq, bout[i], iterations, tol, eps, bc[r], bC[r], bD[r], jacobian, E, L,
                inv, kept, y, rbar, cbar, dm, step, cand, moved, x)
        if shape < len(SHAPES):  # a constant of each kernel: one call, its shape constant
            p, d = P, Dm
        viol[i], rank[i], moving = project_measure(args, p, d)
        if unsettled.size:
            unsettled[i] = moving
    alive((q, out, c, C, D, work))
    return count


#: The kinds of :func:`project_each`'s kernels.
_EACH = "A f1 f2 i f f2 f3 f3 b f1 i1 b1 b1 -> i"


@linked(_EACH)
def project_1_2(A, q, out, iterations, tol, c, C, D, jacobian, viol, rank, chosen, unsettled):
    """:func:`project_span` of the measures of one equation in two components."""
    return project_span(A, q, out, iterations, tol, c, C, D, jacobian, viol, rank, chosen,
                        unsettled, 1, 2, 0)


@linked(_EACH)
def project_1_4(A, q, out, iterations, tol, c, C, D, jacobian, viol, rank, chosen, unsettled):
    """:func:`project_span` of the measures of one equation in four components."""
    return project_span(A, q, out, iterations, tol, c, C, D, jacobian, viol, rank, chosen,
                        unsettled, 1, 4, 1)


@linked(_EACH)
def project_3_4(A, q, out, iterations, tol, c, C, D, jacobian, viol, rank, chosen, unsettled):
    """:func:`project_span` of the measures of three equations in four components."""
    return project_span(A, q, out, iterations, tol, c, C, D, jacobian, viol, rank, chosen,
                        unsettled, 3, 4, 2)


@linked(_EACH)
def project_other(A, q, out, iterations, tol, c, C, D, jacobian, viol, rank, chosen,
                  unsettled):
    """:func:`project_span` of the measures of any shape not in :data:`SHAPES`."""
    return project_span(A, q, out, iterations, tol, c, C, D, jacobian, viol, rank, chosen,
                        unsettled, 0, 0, 3)


# -- the restoration: measures the projector's steps leave off ---------------------------

@jit
def wide_variances(A):
    """Per channel and component, the variances of the metrics that a restoration's Newton
    steps try where the measure's own leaves it off: ``[0]`` the largest over the channel's
    measures (``Q⁺ = GᵀG``), ``[1]`` the square of its observed values' range — the data's
    extent, which moves a precise component as far as the others (a point above a peak
    whose ordinate is far more precise than its abscissa: in the first two metrics its
    steps move the abscissa to the peak and stop short) — the largest variance where that
    range is 0."""
    nch, dmax = A.P.size, A.m.shape[1]
    out = np.zeros((2, nch, dmax))
    lo, hi = np.full((nch, dmax), np.inf), np.full((nch, dmax), -np.inf)
    for i in range(A.chan.size):
        ch = A.chan[i]
        for u in range(A.Dn[ch]):
            var = 0.0
            for j in range(A.Dn[ch]):
                var += A.G[i, j, u] ** 2
            out[0, ch, u] = max(out[0, ch, u], var)
            lo[ch, u] = min(lo[ch, u], A.m[i, u])
            hi[ch, u] = max(hi[ch, u], A.m[i, u])
    for ch in range(nch):
        for u in range(dmax):
            span = hi[ch, u] - lo[ch, u]
            out[1, ch, u] = span * span if span > 0.0 and np.isfinite(span) else out[0, ch, u]
    return out


@jit
def reaching(A, i, top):
    """``G`` of the diagonal metric of the channel's variances ``top`` (one of
    :func:`wide_variances`; zero where the measure's component is exact)."""
    ch = A.chan[i]
    d = A.Dn[ch]
    R = np.zeros((A.m.shape[1], A.m.shape[1]))
    for u in range(d):
        var = 0.0
        for j in range(d):
            var += A.G[i, j, u] ** 2
        R[u, u] = np.sqrt(top[ch, u]) if var > 0 else 0.0
    return R


@linked("A i f1 f1 f1 f2 f2 f2 Work f1 f2 -> b")
def newton(A, i, q, values, c, C, D, G, work, c_new, D_new):
    """Newton steps of measure ``i`` onto its equations along ``Q⁺Dᵀ`` in the metric ``G``,
    halved where ``|c|`` grows; updates ``values, c, C, D``; True when it is on them.
    Its arrays borrowed (the caller's: alive through the call): no reference counts in
    its loops — counted, they were a fifth of a hard Hill fit's time (docs/engine.md)."""
    ch = A.chan[i]
    on = newton_steps(fields(A), i, A.P[ch], A.Dn[ch], A.eps, borrow(work),
                      borrow((q, values, c, C, D, G, c_new, D_new)))
    alive((q, values, c, C, D, G, work, c_new, D_new))
    return on


@jit(inline=True)
def newton_steps(F, i, p, d, eps, work, arrays):
    """:func:`newton`'s steps on borrowed arrays (``F``: :func:`fields`). The trial points
    are evaluated in the values form (``c`` and ``D``: the same numbers, without the
    Jacobian in the parameter, most of the row form's work — its powers and logarithms);
    ``C`` once, at the point the steps reached."""
    q, values, c, C, D, G, c_new, D_new = arrays
    E, L, inv, kept, y, w, w2, dm, step, cand, moved, x = work
    on, stepped = False, False
    for attempt in range(_NEWTON + 1):
        size, finite = violation(c, D, G, p, d, eps, work)  # the factor and w = L⁻¹c
        if not (size > UNREACHED * 1e-4 and finite):
            on = True
            break
        correct(E, L, inv, G, w, p, d, y, dm)
        if attempt == _NEWTON:
            break
        finite = True
        for j in range(d):
            step[j] = -dm[j]
            finite = finite and np.isfinite(step[j])
        if not finite:
            step[:d] = 0.0
        worst = worst_abs(c, p)
        alpha = 1.0
        done = False
        for _ in range(_HALVINGS):
            for j in range(d):
                cand[j] = values[j] + alpha * step[j]
            eval_values(F, i, q, cand, c_new, D_new, x, p, d)
            if worst_abs(c_new, p) < worst:
                for j in range(d):
                    values[j] = cand[j]
                copy_into(c, c_new)
                copy_into(D, D_new)
                done = stepped = True
                break
            alpha /= 2
        if not done:
            break
    if stepped:  # C at the point reached (c and D the same numbers again)
        eval_shaped(F, i, q, values, c, C, D, x, p, d)
    return on


@jit
def normal(A, i, q, values, c, C, D, reach, span, work, spare):
    """Newton steps onto the manifold in the measure's metric, then — for a measure they
    leave off — in its channel's largest variances (``reach``), then in its data's extent
    (``span``; :func:`wide_variances`, runtime/restoration.py describes it). ``spare``:
    buffers for the trial points' ``(c, D)`` (their ``C`` is not made: :func:`newton_steps`)."""
    if not newton(A, i, q, values, c, C, D, A.G[i], work, *spare):
        if not newton(A, i, q, values, c, C, D, reach, work, *spare):
            newton(A, i, q, values, c, C, D, span, work, *spare)


@jit(inline=True)
def curved_step(F, i, q, values, m_obs, c, D, G, Q, p, d, work, sqp, evals):
    """The step from ``values`` (on the manifold ``c(q, ·) = 0``) to the nearest point of
    the distance's second-order model there — the tangent-plane step with the equations'
    curvature weighted by their multipliers (the SQP step of ``min ½‖m̃ − m‖²_Q`` subject
    to ``c = 0``, in the whitened corrections ``m̃ = m + Gᵀz``: the KKT system of
    ``curvature.measure_hessian``). Written into ``work``'s ``step``; returns the fall of
    the distance ``‖m̃ − m‖²_Q`` along the equations that the model predicts, −1 where the
    system is singular or the model's curvature along the equations is not positive (no
    minimum there: the tangent-plane step is then the one to take). ``work``:
    :func:`scratch`, factored at ``values`` (``E, L, inv`` and the whitened residual
    ``w1``); ``sqp``: :func:`newton_scratch`; ``evals``: buffers for ``c, D``."""
    E, L, inv, kept, y, w1, w2, dm, step, cand, moved, x = work
    lam, index, Pmm, grads, H, S, R, z, t, Ew = sqp
    pk = multipliers_of(L, inv, w1, p, lam, index)
    if pk == 0:
        return -1.0
    c2, D2 = evals
    for v in range(d):  # Φmm: central differences of Dᵀλ along each component
        h = difference_step(values, v, d)
        for side in range(2):
            for u in range(d):
                cand[u] = values[u] + ((h if side == 0 else -h) if u == v else 0.0)
            eval_values(F, i, q, cand, c2, D2, x, p, d)
            weighted_gradient(lam, c2, D2, D2, p, 0, d, grads, side)
        for u in range(d):
            Pmm[u, v] = (grads[0, u] - grads[1, u]) / (2.0 * h)
    for u in range(d):  # t = Q (m̃ − m), z = G t: the distance's gradient in z
        acc = 0.0
        for v in range(d):
            acc += Q[u, v] * (values[v] - m_obs[v])
        t[u] = acc
    for a in range(d):
        acc = 0.0
        for u in range(d):
            acc += G[a, u] * t[u]
        z[a] = acc
    size = d + pk
    for a in range(size):
        R[a, 0] = 0.0
        for b in range(size):
            S[a, b] = 0.0
    for a in range(d):  # H = G (Q + Φmm) Gᵀ, Φmm symmetrised
        for b in range(d):
            acc = 0.0
            for u in range(d):
                row = 0.0
                for v in range(d):
                    row += (Q[u, v] + 0.5 * (Pmm[u, v] + Pmm[v, u])) * G[b, v]
                acc += G[a, u] * row
            H[a, b] = acc
            S[a, b] = acc
        R[a, 0] = -z[a]
    # the kept equations whitened, L⁻¹E (orthonormal rows) and L⁻¹c: the KKT system's
    # scale is then the Hessian's alone (E's rows may be 10⁻⁴ of it where the metric is
    # narrow, and its last pivot below any tolerance relative to it)
    whiten_rows(L, inv, E, p, d, Ew)
    whiten_column(L, inv, c, p, w2)
    for e in range(pk):
        for b in range(d):
            S[d + e, b] = Ew[index[e], b]
            S[b, d + e] = Ew[index[e], b]
        R[d + e, 0] = -w2[index[e]]
    if not solve_small(S, R, size, 1):
        return -1.0
    # the step's part back onto the linearised equations, −Eᵀ S⁻ c, and its part along
    # them: the model's fall and curvature are those along them (the part back onto them
    # may raise the distance, and by far more than the fall where the metric is narrow)
    back, along = grads[0], grads[1]
    for a in range(d):
        acc = 0.0
        for e in range(pk):
            acc += Ew[index[e], a] * w2[index[e]]
        back[a] = -acc
        along[a] = R[a, 0] + acc
    slope, curve = 0.0, 0.0
    for a in range(d):
        pull, bend = 0.0, 0.0
        for b in range(d):
            pull += H[a, b] * back[b]
            bend += H[a, b] * along[b]
        slope += (z[a] + pull) * along[a]
        curve += along[a] * bend
    if not curve > 0.0:
        return -1.0
    for u in range(d):  # the step in m̃: Gᵀ Δz
        acc = 0.0
        for a in range(d):
            acc += G[a, u] * R[a, 0]
        if not np.isfinite(acc):
            return -1.0
        step[u] = acc
    return max(-(2.0 * slope + curve), 0.0)


@jit
def newton_scratch(p, d):
    """Buffers of :func:`curved_step` for ``p`` equations and ``d`` components."""
    return (np.zeros(p), np.zeros(p, np.int64), np.zeros((d, d)), np.zeros((2, d)),
            np.zeros((d, d)), np.zeros((d + p, d + p)), np.zeros((d + p, 1)), np.zeros(d),
            np.zeros(d), np.zeros((p, d)))


@linked("A i f1 f1 f3 f1 f2 f2 Work -> f1 f")
def descend(A, i, q, start, wide, c, C, D, work):
    """Measure ``i`` moved onto ``c(q, ·) = 0`` and down the distance along it from
    ``start``; writes ``c, C, D``; returns ``(m̃, violation)``. The descent stops, keeping
    its point, once :data:`_MISSES` of its trial points since its last full step taken were
    left off the manifold (counted over the whole descent, the misses of its first, far
    steps stopped it short of the nearest point where its full steps converge linearly).
    Its buffers made here, its arrays borrowed in its loops (:func:`descent`)."""
    ch = A.chan[i]
    p, d = A.P[ch], A.Dn[ch]
    reach, span = reaching(A, i, wide[0]), reaching(A, i, wide[1])
    spare = (c.copy(), D.copy())  # the Newton steps' trial equations (c, D)
    values = start.copy()
    trials = (c.copy(), C.copy(), D.copy())  # the trial points' equations
    steps = (np.zeros(p), values.copy(), values.copy())  # r, the step, the trial point
    sqp = newton_scratch(p, d)
    evals = (np.zeros(c.size), np.zeros(D.shape))
    owned = (A.G[i], A.Q[i], A.m[i, :d], q, values, c, C, D, reach, span)
    violation_ = descent(A, fields(A), i, p, d, borrow(owned), borrow(work), borrow(spare),
                         borrow(trials), borrow(steps), borrow(sqp), borrow(evals))
    alive((owned, work, spare, trials, steps, sqp, evals))
    return values, violation_


@jit(inline=True)
def descent(A, F, i, p, d, owned, work, spare, trials, steps, sqp, evals):
    """:func:`descend`'s steps on borrowed arrays; returns the violation at the end (the
    point in ``owned``'s ``values``, its equations in ``c, C, D``)."""
    G, Q, m_obs, q, values, c, C, D, reach, span = owned
    E, L, inv, kept, y, w, w2, dm, step, cand, moved, x = work
    c2, C2, D2 = trials
    r, along, trial = steps
    eval_measure(F, i, q, values, c, C, D, x)
    normal(A, i, q, values, c, C, D, reach, span, work, spare)
    distance = quad_between(values, m_obs, Q, d)
    active = violation(c, D, G, p, d, A.eps, work)[0] <= UNREACHED
    misses = 0
    for _ in range(_DESCENT):
        if not active:
            break
        residual_into(D, values, m_obs, c, p, d, r)
        factor(D, G, p, d, A.eps, E, L, inv, kept)
        whiten_column(L, inv, r, p, w)
        copy_into(along, values)
        fall = curved_step(F, i, q, values, m_obs, c, D, G, Q, p, d, work, sqp, evals)
        if fall >= 0.0:
            if fall <= ROUNDING * distance:
                break  # no fall the distance's rounding would show: there
            for j in range(d):
                along[j] = step[j]
        else:  # the tangent-plane projection of the observed measure
            correct(E, L, inv, G, w, p, d, y, dm)
            for j in range(d):
                along[j] = m_obs[j] + dm[j] - values[j]
        finite = True
        for j in range(d):
            finite = finite and np.isfinite(along[j])
        if finite and quad(along, Q, d) <= RESTORE_TOL ** 2:
            break  # a step below the tolerance: there
        shift = 0.0
        if finite:
            alpha = 1.0
            for _ in range(_HALVINGS):
                for j in range(trial.size):  # values + alpha * along
                    trial[j] = values[j] + alpha * along[j]
                eval_measure(F, i, q, trial, c2, C2, D2, x)
                normal(A, i, q, trial, c2, C2, D2, reach, span, work, spare)
                d_trial = quad_between(trial, m_obs, Q, d)
                worst = worst_abs(c, p)
                if not worst_abs(c2, p) <= worst + 1e-12 * (1 + worst):
                    misses += 1  # its Newton steps, every metric tried, left it off
                    if misses >= _MISSES:
                        break
                elif d_trial < distance:
                    shift = quad_between(trial, values, Q, d)
                    copy_into(values, trial)
                    copy_into(c, c2)
                    copy_into(C, C2)
                    copy_into(D, D2)
                    distance = d_trial
                    if alpha == 1.0:  # a full step taken: the misses counted since
                        misses = 0
                    break
                alpha /= 2
        active = shift > RESTORE_TOL ** 2  # 0 after the last miss: no trial taken
    eval_measure(F, i, q, values, c, C, D, x)
    return violation(c, D, G, p, d, A.eps, work)[0]


@linked("A f1 f2 i -> f2 f1 f2 f3 f3", python=True)
def restore_all(A, q, mt, iterations):
    """The measures projected onto their equations for ``q`` from ``mt`` (eq. 22), those
    left off finished by the descent on the manifold from where they were left and from
    their observed values, the nearer kept, and those whose steps ran out before they
    converged by the descent from where they were left: ``(m̃, violations, c, C, D)``.

    A measure the steps leave unsettled (observed near the centre of the curve's
    curvature: above a peak, the steps' contraction is slow) may be on its equations by
    :data:`UNREACHED` and still off them by enough to lower its distance, to first order,
    by far more than the cost's rounding: the iteration's comparisons of costs then see
    that error, not the steps' falls. Its descent from where the steps left it (in its
    basin: not from its observed value), reached, replaces it."""
    q = np.ascontiguousarray(q)
    unsettled = np.zeros(A.chan.size, dtype=np.bool_)
    out, viol, rank, c, C, D = project_flagged(A, q, mt, iterations, RESTORE_TOL, unsettled)
    left_off = False
    for i in range(A.chan.size):
        left_off = left_off or not viol[i] <= UNREACHED or unsettled[i]
    if not left_off:  # the usual case
        return out, viol, c, C, D
    wide = wide_variances(A)
    work = scratch(A, q.size)
    for i in range(A.chan.size):
        if viol[i] <= UNREACHED and not unsettled[i]:
            continue
        ch = A.chan[i]
        d = A.Dn[ch]
        Q, m_obs = A.Q[i], A.m[i, :d]
        starts = (out[i, :d].copy(), m_obs.copy())
        on = viol[i] <= UNREACHED  # on its equations, unsettled only
        for s in range(2):
            if s == 1 and on:
                break  # finished from where the steps left it, its own basin, alone
            c2, C2, D2 = c[i].copy(), C[i].copy(), D[i].copy()
            m_new, v_new = descend(A, i, q, starts[s], wide, c2, C2, D2, work)
            old = viol[i]
            d_old = quad_between(out[i, :d], m_obs, Q, d)
            d_new = quad_between(m_new, m_obs, Q, d)
            reached = v_new <= UNREACHED
            if reached:
                better = on or not (old <= UNREACHED) or d_new < d_old
            else:
                better = v_new < (old if np.isfinite(old) else np.inf)
            if better:
                for j in range(d):
                    out[i, j] = m_new[j]
                viol[i] = v_new
                copy_into(c[i], c2)
                copy_into(C[i], C2)
                copy_into(D[i], D2)
    return out, viol, c, C, D


@jit
def violations_all(A, c, D):
    """Every measure's whitened violation ``‖c‖²_{(D Q⁺ Dᵀ)⁻}`` (cost units)."""
    out = np.zeros(A.chan.size)
    work = scratch(A, 0)
    F = fields(A)
    chan, P, Dn, G = F[0], F[1], F[2], F[8]
    bc, bD = borrow((c, D))
    bwork = borrow(work)
    eps = A.eps
    for i in range(chan.size):
        ch = chan[i]
        out[i] = violation(bc[i], bD[i], G[i], P[ch], Dn[ch], eps, bwork)[0]
    alive((c, D, work))
    return out
