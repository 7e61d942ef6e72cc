"""Points of the iteration and what is done to them: evaluated, projected (the block
projector, report appendix A), restored onto their equations (a retraction of the
parameter, the measures projected: runtime/iterate.py describes why), the Lagrangian's
curvature on curved constraints. Kernels on :class:`~.data.Arrays` ``A``.
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np

from kanagen.common.jit import jit
from kanagen.common.link import linked, record_kind

from ..lapack import least_squares
from ..linalg import certified_solve, matmul, row_svd, sym_eigh, triangular_rows
from ..sqrt import EPS, REDUNDANT, closest_root
from .linear import corrected, linearise, parameter_block, retraction_step, whitened_violation
from .measures import (
    RESTORE_STEPS,
    RESTORE_TOL,
    ROUNDING,
    UNREACHED,
    c0_eval,
    copy_into,
    eval_all,
    point_values,
    project_chosen,
    quad_between,
    restore_all,
    scratch,
    violation,
)
from .rows import call3

#: A point ``x = (q, m̃)`` with its equations: ``c0 (r)``, ``C0 (r, n)`` and per measure
#: ``c, C, D`` (padded), ``delta = ‖c(x)‖∞`` (eq. 18) and ``cost = L²`` (eq. 2).
Pt = namedtuple("Pt", ["q", "mt", "c0", "C0", "c", "C", "D", "delta", "cost"])
#: The whitened linearisation at a point (eq. 38–43) and the projector's point (eq. 12).
Lin = namedtuple("Lin", ["info", "H", "rhs", "gradient", "Cbar", "rbar", "E", "L", "inv",
                         "residual", "ranks"])
Proj = namedtuple("Proj", ["q", "mt", "kept0", "rank0", "residual"])
record_kind("Pt", Pt, "f1 f2 f1 f2 f2 f3 f3 f f")
record_kind("Lin", Lin, "f2 f2 f1 f1 f3 f2 f3 f3 f2 f i1")
record_kind("Proj", Proj, "f1 f2 b1 i f")

RETRACTION = 64  # Gauss–Newton steps onto c0 = 0, at most (a double root: linear)
#: A retraction step that does not lower ``‖c0‖∞`` is halved, at most this many times (a
#: quartic's Newton step from between two of its roots overshoots the nearer one)
RETRACTION_HALVINGS = 5



@jit
def make_point(A, q, mt, c, C, D):
    c0, C0 = c0_eval(A, q)
    delta, cost = point_values(A, q, mt, c, c0)
    return Pt(q, mt, c0, C0, c, C, D, delta, cost)


@jit
def evaluate(A, q, mt):
    """Equations, Jacobians, ``‖c‖∞`` and the cost at ``(q, m̃)``."""
    q = np.ascontiguousarray(q).copy()
    mt = np.ascontiguousarray(mt).copy()
    c, C, D = eval_all(A, q, mt)
    return make_point(A, q, mt, c, C, D)


@jit(inline=True)
def finite(x):
    return np.isfinite(x.delta) and np.isfinite(x.cost)


@linked("A Pt f f1 -> b Lin Proj")
def project_point(A, x, mu, weights):
    """The linearisation at ``x`` and the projector's point (damped by ``μ diag(w)``);
    ``ok`` False where the projector fails (a zero pivot)."""
    info, H, rhs, gradient, Cbar, rbar, E, L, inv, kept, ranks, residual = linearise(
        A, x.q, x.mt, x.c, x.C, x.D, x.c0, x.C0)
    lin = Lin(info, H, rhs, gradient, Cbar, rbar, E, L, inv, residual, ranks)
    ok, proj = solve(A, x, lin, mu, weights)
    return ok, lin, proj


@linked("A Pt Lin f f1 -> b Proj")
def solve(A, x, lin, mu, weights):
    """The projector's point from a linearisation (eq. 43–44)."""
    dq, kept0, rank0, residual, ok = parameter_block(lin.H, lin.info, lin.rhs, x.C0, x.c0,
                                                     x.q, lin.residual, mu, weights, A.eps)
    mt = corrected(A, dq, lin.Cbar, lin.rbar, lin.E, lin.L, lin.inv)
    return ok, Proj(x.q + dq, mt, kept0, rank0, residual)


@jit
def parameter_step(A, x, lin, mu, weights):
    return parameter_block(lin.H, lin.info, lin.rhs, x.C0, x.c0, x.q, lin.residual, mu,
                           weights, A.eps)[0]


@jit
def max_abs(v):
    """``max|v|`` as NumPy computes it (NaN propagates; 0 for an empty ``v``)."""
    top = 0.0
    for a in range(v.size):
        x = abs(v[a])
        if x != x:
            return np.nan
        top = max(top, x)
    return top


@jit
def c0_at_rounding(q, c0, C0):
    """Every row of ``c0`` within the rounding of its own terms: ``1e-13 (1 + max|q_j|)²``
    over the components ``j`` its gradient (a row of ``C0``) sees. A component no row of
    the constraint involves (a slack of another branch run off to 1e27) does not loosen
    it. NaN is never within."""
    for i in range(c0.size):
        top = 0.0
        for j in range(q.size):
            if C0[i, j] != 0.0:
                top = max(top, abs(q[j]))
        if not abs(c0[i]) <= 1e-13 * (1.0 + top) ** 2:
            return False
    return True


@linked("A f1 f2 i -> f1", python=True)
def restore_parameter(A, q, root, iterations):
    """``q`` moved back onto ``c0(q) = 0`` by Gauss–Newton steps in the metric ``root``
    (empty: Euclidean), each taken, halved up to :data:`RETRACTION_HALVINGS` times, when it
    lowers ``‖c0‖∞`` (runtime/projector.py)."""
    c0, C0 = c0_eval(A, q)
    if c0.size == 0:
        return q.copy()
    worst = max_abs(c0)
    if root.shape[0] == 0:
        root = np.eye(q.size)
    for _ in range(iterations):
        if not worst > ROUNDING * (1.0 + max_abs(q)) * 1e-3:
            break
        step = retraction_step(root, C0, c0, A.eps)
        trial, c0_new, C0_new, new_worst = q, c0, C0, worst
        for _halving in range(RETRACTION_HALVINGS + 1):
            trial = q - step
            c0_new, C0_new = c0_eval(A, trial)
            new_worst = max_abs(c0_new)
            if new_worst < worst:
                break
            step = 0.5 * step
        if not new_worst < worst:
            break
        q, c0, C0, worst = trial, c0_new, C0_new, new_worst
    return q.copy()


@linked("Pt f2 -> f")
def c0_violation(x, root):
    """``‖c0‖²`` whitened by ``C0 Q̃⁻¹ C0ᵀ``, or 0 below rounding."""
    if c0_at_rounding(x.q, x.c0, x.C0):
        return 0.0
    if root.shape[0] == 0:
        total = 0.0
        for a in range(x.c0.size):
            total += x.c0[a] * x.c0[a]
        return total
    return whitened_violation(root, x.C0, x.c0, EPS)


@linked("A f1 f2 i -> Pt f")
def restore(A, q, mt, iterations):
    """The point ``(q, m̃)`` with the measures restored (eq. 22) and their violation."""
    q = np.ascontiguousarray(q).copy()
    out, viol, c, C, D = restore_all(A, q, np.ascontiguousarray(mt), iterations)
    return make_point(A, q, out, c, C, D), viol.sum()


@linked("A f1 f2 f2 i b -> Pt f")
def restored(A, q, mt, root, iterations, retract):
    """``q`` retracted onto ``c0 = 0`` (in ``root``'s metric, else Euclidean) and its
    measures restored; returns the point and its violation ``E²`` in cost units."""
    if retract and A.r:
        best_q = q
        best = np.inf
        first = True
        for k in range(2 if root.shape[0] else 1):
            metric = root if k == 0 else np.zeros((0, 0))
            candidate = restore_parameter(A, q, metric, RETRACTION)
            c0, C0 = c0_eval(A, candidate)
            worst = max_abs(c0)
            if first or worst < best:
                best_q, best, first = candidate, worst, False
            if c0_at_rounding(candidate, c0, C0):
                break
        q = best_q
    x, violation = restore(A, q, mt, iterations)
    return x, violation + c0_violation(x, root)


@jit(inline=True)
def feasible(violation, cost):
    """The equations hold: their violation negligible against the cost."""
    return violation <= 1e-10 * max(1.0, cost)


@jit(inline=True)
def on_constraints(x, violation):
    """The measures on their equations and the parameter on its constraints (rounding)."""
    return feasible(violation, x.cost) and c0_at_rounding(x.q, x.c0, x.C0)


@jit
def cost_rounding(A):
    """The rounding level of the cost ``L²`` (runtime/verify.py)."""
    eps = 10 * np.finfo(np.float64).eps
    total = 0.0
    for j in range(A.size.size):
        total += A.size[j] * (eps * A.scale[j]) ** 2
    return total + np.finfo(np.float64).tiny


@jit
def negligible(A, q_old, q_new, mt_old, mt_new, xtol):
    """Each component of q moves by less than ``xtol`` of itself, each measure by less than
    ``xtol`` standard deviations, or by no more than the values' rounding."""
    rounding = ROUNDING * max_abs(q_old)
    for a in range(q_old.size):
        if abs(q_new[a] - q_old[a]) > xtol * abs(q_old[a]) + rounding:
            return False
    for j in range(A.size.size):
        if A.size[j] == 0:
            continue
        top = 0.0
        d = A.Dn[j]
        for i in range(A.start[j], A.start[j] + A.size[j]):
            moved = quad_between(mt_new[i], mt_old[i], A.Q[i], d)
            if moved != moved:
                top = np.nan
                break
            top = max(top, moved)
        if top > (xtol + ROUNDING * A.scale[j]) ** 2:
            return False
    return True


@jit
def relations_hold(A, q):
    """The model's inequality relations (appendix F) hold at ``q`` (in ``r`` for a reduced
    model: at ``T r + t``): in each clause of inequalities, at least one."""
    if A.slack_addr == 0:
        return True
    full = A.T @ q + A.t
    values = np.empty(A.kinds.size)
    call3(A.slack_addr, np.ascontiguousarray(full), A.k, values)
    for a in range(A.clauses.shape[0]):
        any_holds = False
        for i in range(A.kinds.size):
            if not A.clauses[a, i]:
                continue
            v = values[i]
            kind = A.kinds[i]
            holds = v >= 0 if kind == 0 else (v > 0 if kind == 1 else
                                              (np.isfinite(v) and v != 0))
            any_holds = any_holds or holds
        if not any_holds:
            return False
    return True


@jit
def has_relations(A):
    return A.slack_addr != 0


@linked("Pt f1 -> f1")
def multipliers(x, gradient):
    """``λ0``: least-squares multipliers of the parameter constraints, ``C0ᵀ λ0 = −∇F``."""
    r, n = x.C0.shape
    if r == 0:
        return np.zeros(0)
    if not (np.all(np.isfinite(x.C0)) and np.all(np.isfinite(gradient))):
        return np.full(r, np.nan)
    # independent constraints (the usual case): the least-squares solution, from the
    # Householder triangle of C0ᵀ (C0ᵀ = Q [T; 0], T λ0 = −(Qᵀ ∇F)₁..ᵣ) when its rank is
    # certified (:func:`certified_solve`: a singular value at least 1e3 times NumPy's lstsq
    # cut-off, ε·max(n, r) of the largest), else from C0's SVD (one-sided Jacobi: C0 = Wᵀ
    # R, R's rows orthogonal) — LAPACK's fixed costs were most of the time on such sizes;
    # dependent ones (a singular value under the cut-off): the minimum-norm solution, as
    # lstsq gives it
    cut = np.finfo(np.float64).eps * max(n, r)
    if r <= n:
        T, g = np.empty((r, r)), np.empty(r)
        triangular_rows(np.ascontiguousarray(x.C0.T), gradient, np.empty((n, r + 1)),
                        np.empty((n, r)), T, g)
        lam = np.empty(r)
        if certified_solve(T, g, 1e3 * cut, np.empty((r, r)), np.empty((r, r + 1)), lam):
            for a in range(r):
                lam[a] = -lam[a]
            return lam
    R, W, S = np.empty((r, n)), np.empty((r, r)), np.empty(r)
    if r > n or row_svd(x.C0, R, W, S) < 0 or not S.min() > 1e3 * cut * S.max():
        return least_squares(np.ascontiguousarray(x.C0.T), -gradient, cut)
    mu = np.zeros(r)
    for k in range(r):
        acc = 0.0
        for j in range(n):
            acc += R[k, j] * gradient[j]
        mu[k] = -acc / (S[k] * S[k])
    lam = np.zeros(r)
    for a in range(r):
        acc = 0.0
        for k in range(r):
            acc += W[k, a] * mu[k]
        lam[a] = acc
    return lam


@jit
def constraint_curvature(A, q, lam0):
    """``Σ λ0k ∇²c0k`` by central differences of the constraints' Jacobian."""
    n, r = q.size, A.r
    K = np.zeros((n, n))
    scale = max_abs(q)
    moved = np.ascontiguousarray(q).copy()
    up, down = np.empty(r + r * n), np.empty(r + r * n)  # c0 then C0 (n by row)
    for j in range(n):
        h = 1e-5 * max(abs(q[j]), 1e-3 * scale, 1e-8)
        moved[j] = q[j] + h
        call3(A.c0_addr, moved, A.k, up)
        moved[j] = q[j] - h
        call3(A.c0_addr, moved, A.k, down)
        moved[j] = q[j]
        for a in range(n):
            acc = 0.0
            for k in range(lam0.size):
                acc += (up[r + k * n + a] - down[r + k * n + a]) * lam0[k]
            K[a, j] = acc / (2 * h)
    return 0.5 * (K + K.T)


@linked("A Pt Lin Proj -> Lin Proj")
def lagrangian(A, x, lin, proj):
    """The linearisation with the constraints' curvature ``Σ λ0k ∇²c0k`` (its positive
    part) added to the information, and its projector's point (runtime/iterate.py)."""
    lam0 = multipliers(x, lin.gradient)
    nonzero = False
    for a in range(lam0.size):
        nonzero = nonzero or lam0[a] != 0
    if not nonzero:
        return lin, proj
    K = constraint_curvature(A, x.q, lam0)
    for s in range(A.strict_idx.size):
        index = A.strict_idx[s]
        K[index, :] = 0.0
        K[:, index] = 0.0
    if not np.all(np.isfinite(K)):
        return lin, proj
    w, V = sym_eigh(K)
    top = 0.0
    for a in range(lin.H.shape[0]):
        top = max(top, abs(lin.H[a, a]))
    if not np.all(np.isfinite(w)) or not max(w.max(), 0.0) > 1e-14 * top:
        return lin, proj
    K = matmul(V * np.maximum(w, 0.0), V.T)
    model = Lin(lin.info + K, lin.H + K, lin.rhs, lin.gradient, lin.Cbar, lin.rbar, lin.E,
                lin.L, lin.inv, lin.residual, lin.ranks)
    ok, proj_model = solve(A, x, model, 0.0, np.zeros(0))
    if not ok:
        return lin, proj
    return model, proj_model


@jit
def info_root(A, info):
    """The closest square root of the information (the metric of retractions)."""
    return closest_root(info, max(A.eps, REDUNDANT))


#: How many other measures of its channel a measure's nearest corrected value is sought
#: among (evenly spaced in the data's order): the check's cost linear in the measures.
NEIGHBOURS = 16
#: The steps of a measure's projection from its neighbour's corrected value (a start on the
#: equations: in the nearer point's basin, Newton's iteration reaches it in a few).
NEIGHBOUR_STEPS = 10


@jit
def neighbours_corrected(A, x):
    """Per measure, a start on its equations away from its corrected value: the corrected
    value nearest its observed value (its metric) among :data:`NEIGHBOURS` other measures
    of its channel, evenly spaced in the data's order; flagged where it is within twice the
    measure's distance to its own corrected value (in that distance's square root, where
    a nearer point lies), else not worth a projection. ``(starts, flags)``."""
    start = x.mt.copy()
    n = A.chan.size
    chosen = np.zeros(n, dtype=np.bool_)
    stride = max(1, -(-(n - 1) // NEIGHBOURS))
    for i in range(n):
        ch = A.chan[i]
        d = A.Dn[ch]
        Q, m_obs, own = A.Q[i], A.m[i], x.mt[i]
        reach = 4.0 * quad_between(own, m_obs, Q, d)
        best, at = reach, i
        for s in range(1, n, stride):
            j = (i + s) % n
            if A.chan[j] != ch:
                continue
            gap = quad_between(x.mt[j], m_obs, Q, d)
            if gap <= best and quad_between(x.mt[j], own, Q, d) > 1e-12 * reach:
                best, at = gap, j
        if at != i:
            chosen[i] = True
            for a in range(d):
                start[i, a] = x.mt[at, a]
    return start, chosen


@linked("A Pt -> b Pt")
def nearer_points(A, x):
    """``x`` with each measure at the nearest of its point and the ones restored from its
    observed value and from its neighbour's corrected value (:func:`neighbours_corrected`):
    a measure observed where its restoration stops at a local, not the nearest, point (a
    Hill curve's zero dose, where the curve is flat) is moved there too. ``changed`` False
    when no measure has a nearer point."""
    mt, c, C, D = x.mt, x.c, x.C, x.D  # copied at the first measure moved
    changed = False
    work = scratch(A, 0)
    viol = np.zeros(0)
    for k in range(2):
        if k == 0:
            other, _ = restore(A, x.q, A.m, RESTORE_STEPS)
            if not finite(other):
                continue
            o_mt, o_c, o_C, o_D = other.mt, other.c, other.C, other.D
        else:  # each measure projected alone: one left off is not descended
            starts, chosen = neighbours_corrected(A, x)
            if not chosen.any():
                break
            o_mt, viol, o_c, o_C, o_D = project_chosen(A, x.q, starts, chosen,
                                                       NEIGHBOUR_STEPS, RESTORE_TOL)
        for i in range(A.chan.size):
            ch = A.chan[i]
            d = A.Dn[ch]
            d_x = quad_between(mt[i], A.m[i], A.Q[i], d)
            d_o = quad_between(o_mt[i], A.m[i], A.Q[i], d)
            if not d_o < d_x - 1e-9 * (1.0 + d_x):
                continue
            if (viol[i] if k else violation(o_c[i], o_D[i], A.G[i], A.P[ch], d, A.eps,
                                            work)[0]) <= UNREACHED:
                if not changed:
                    mt, c, C, D = x.mt.copy(), x.c.copy(), x.C.copy(), x.D.copy()
                changed = True
                copy_into(mt[i], o_mt[i])
                copy_into(c[i], o_c[i])
                copy_into(C[i], o_C[i])
                copy_into(D[i], o_D[i])
    if not changed:
        return False, x
    return True, make_point(A, x.q.copy(), mt, c, C, D)


# -- points handed to Python: one array each ----------------------------------------------
#
# Boxing an array for Python costs about a microsecond, more than copying a point's values:
# a point reaches Python as one float array (its equations' padded width beside it), cut
# into views there (runtime/iterate.py: ``unpack_point``) — in this order: ``delta, cost``,
# then ``q, mt, c0, C0, c, C, D`` in C order.

@jit
def point_length(x):
    """The values of :func:`put_point`'s layout of ``x``."""
    return 2 + x.q.size + x.mt.size + x.c0.size + x.C0.size + x.c.size + x.C.size + x.D.size


@jit(inline=True)
def put_flat(out, at, values):
    """``values`` (any shape, C order) into ``out`` from ``at``: the next free index."""
    flat = np.ascontiguousarray(values).reshape(values.size)
    for a in range(flat.size):
        out[at + a] = flat[a]
    return at + flat.size


@jit
def put_point(out, at, x):
    """``x``'s values into ``out`` from ``at`` (the layout above): the next free index."""
    out[at], out[at + 1] = x.delta, x.cost
    at = put_flat(out, at + 2, x.q)
    at = put_flat(out, at, x.mt)
    at = put_flat(out, at, x.c0)
    at = put_flat(out, at, x.C0)
    at = put_flat(out, at, x.c)
    at = put_flat(out, at, x.C)
    return put_flat(out, at, x.D)


@jit
def flat_point(x):
    """``x`` as one array and its equations' padded width."""
    out = np.empty(point_length(x))
    put_point(out, 0, x)
    return out, x.c.shape[1]


@jit
def restored_flat(A, q, mt, root, iterations, retract):
    """:func:`restored` for Python: ``x`` as :func:`flat_point` gives it, and the
    violation."""
    x, violation = restored(A, q, mt, root, iterations, retract)
    flat, width = flat_point(x)
    return flat, width, violation


@jit
def evaluate_flat(A, q, mt):
    """:func:`evaluate` for Python: ``x`` as :func:`flat_point` gives it."""
    return flat_point(evaluate(A, q, mt))
