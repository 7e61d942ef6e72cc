"""The end of the iteration checked (SPEC §2: a success is a local minimum): stationary, no
negative curvature of the Lagrangian on the constraints' tangent space, every parameter seen
by the data, no slope along a lost direction (runtime/iterate.py, "The end"). Kernels.

A verdict is ``Verdict(stationary, decrement, cost, curvature, direction, plateau,
plateau_vector)``: ``curvature`` NaN where it was not measured, ``direction`` empty without
one; ``plateau`` 0 none, 1 the information of the components ``plateau_vector != 0`` has
vanished, 2 the equations lost the direction ``plateau_vector`` along which the cost falls.
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np

from kanagen.common.jit import jit
from kanagen.common.link import linked, record_kind

from ..linalg import complement, dot, matmul, matvec, null_space, projected, sym_eigh
from ..sqrt import put_column, reduced_root, solve_lower_columns
from .curvature import profile_hessian
from .linear import linearise, seen_components
from .measures import RESTORE_STEPS
from .points import (
    c0_eval,
    constraint_curvature,
    cost_rounding,
    feasible,
    finite,
    info_root,
    lagrangian,
    max_abs,
    multipliers,
    project_point,
    restore,
    restored,
)

STATIONARY = 1e-10  # decrement over cost below which a point is stationary
NEGATIVE = 1e-5  # curvature (relative to the information) below -this is negative
STEP = 1e-3  # central-difference step, in standard deviations of the parameter
VANISHED = 1e-12  # information fallen by this factor since the start: a plateau
SCREEN = 0.05  # least forward-difference curvature above which no central check is needed
LOST = 1e-12  # least eigenvalue of the scaled information, relative: a direction lost
SLOPE = 1e3  # the gradient along it, in rounding levels of its terms, above which it falls
_CERTAIN = 1e3  # a ratio certified above this many times LOST is no lost direction
UNREACHABLE = 1e-3  # share of the constraints' curvature outside C0's range: no tangent
CURVE_STEP = 1e-4  # second differences of c0, relative to the parameter's largest value

Verdict = namedtuple("Verdict", ["stationary", "decrement", "cost", "curvature", "direction",
                                 "plateau", "plateau_vector"])
record_kind("Verdict", Verdict, "b f f f f1 i f1")


@jit
def verdict(stationary, decrement, cost, curvature, direction):
    """A verdict without a plateau."""
    return Verdict(stationary, decrement, cost, curvature, direction, 0, np.zeros(0))


@jit(inline=True)
def is_minimum(v):
    return v.stationary and v.plateau == 0 and not v.curvature < -NEGATIVE


@jit(inline=True)
def decrement(x, lin, proj):
    """``½ sᵀ H s`` of the tangential part of the projector's step."""
    s = proj.q - x.q
    normal = proj.residual - lin.residual
    return max(0.5 * dot(s, matvec(lin.H, s)) - 0.5 * normal, 0.0)


@jit(inline=True)
def stationary(A, x, lin, proj):
    return decrement(x, lin, proj) <= STATIONARY * x.cost + cost_rounding(A)


@linked("f2 b1 -> f2")
def tangent_space(C0, seen):
    """Orthonormal columns spanning the null space of ``C0`` on the components ``seen``
    (zero on the others)."""
    n = seen.size
    idx = np.flatnonzero(seen)
    if C0.shape[0] == 0 or idx.size == 0:
        E = np.zeros((n, idx.size))
        for a in range(idx.size):
            E[idx[a], a] = 1.0
        return E
    B = np.empty((C0.shape[0], idx.size))  # C0's columns seen
    for k in range(C0.shape[0]):
        for a in range(idx.size):
            B[k, a] = C0[k, idx[a]]
    N = null_space(B, 1e-10)
    Z = np.zeros((n, N.shape[1]))
    for a in range(idx.size):
        for c in range(N.shape[1]):
            Z[idx[a], c] = N[a, c]
    return Z


@linked("Pt f2 -> f2")
def tangent_basis(x, info):
    """The tangent space of ``c0 = 0`` on the seen components, orthonormal in the
    information (directions without information left out)."""
    Z = tangent_space(x.C0, seen_components(info, x.C0, x.q))
    if Z.shape[1] == 0:
        return Z
    G = projected(Z, info)
    w, U = sym_eigh(G)
    top = max(w.max(), np.finfo(np.float64).tiny) if w.size else np.finfo(np.float64).tiny
    keep = np.flatnonzero(w > 1e-14 * max(top, np.finfo(np.float64).tiny))
    out = np.zeros((Z.shape[0], keep.size))
    for a in range(keep.size):
        put_column(out, a, matvec(Z, U[:, keep[a]] / np.sqrt(w[keep[a]])))
    return out


@linked("Pt f2 f1 -> b1 b")
def plateau_mask(x, info, info_start):
    """The components whose information fell by twelve orders of magnitude since the start
    (not those the constraints pin); empty when none."""
    n = x.q.size
    if info_start.size == 0:
        return np.zeros(n, dtype=np.bool_), False
    gone = np.zeros(n, dtype=np.bool_)
    for a in range(n):
        before = abs(info_start[a])
        gone[a] = before > 0 and abs(info[a, a]) <= VANISHED * before
    if x.C0.shape[0]:
        free = tangent_space(x.C0, np.ones(n, dtype=np.bool_))
        for a in range(n):
            norm = 0.0
            for b in range(free.shape[1]):
                norm += free[a, b] ** 2
            gone[a] = gone[a] and np.sqrt(norm) > 1e-6
    return gone, gone.any()


@jit
def certainly_above(S, ratio):
    """The least eigenvalue of the symmetric ``S`` (``k × k``, unit diagonal) is certainly
    above ``ratio`` times its largest: ``S = L Lᵀ`` exists and ``k tr S⁻¹ < 1 / ratio``
    (``tr S⁻¹ = ‖L⁻¹‖²_F``), for ``λmin ≥ 1 / tr S⁻¹`` and ``λmax ≤ tr S = k``. A sufficient
    test, far cheaper than the eigenproblem; ``ratio`` is taken far above the threshold it
    certifies (the factor's rounding, relative ``k ε cond S``, is then nothing)."""
    k = S.shape[0]
    L, kept = reduced_root(S, 0.0)  # a pivot dropped (not above rounding): no certificate
    if not kept.all():
        return False
    inverse = solve_lower_columns(L, np.eye(k), False)
    trace = 0.0
    for i in range(k):
        for j in range(i + 1):
            trace += inverse[i, j] * inverse[i, j]
    return k * trace * ratio < 1.0


@linked("f2 Pt f -> b f f1")
def weakest(info, x, only_below):
    """The least eigenvalue of ``info`` on the tangent space, scaled to a unit diagonal,
    relative to the largest, and its direction (``ok`` False without one; with
    ``only_below`` > 0, also when the ratio is certainly above ``only_below``:
    :func:`certainly_above`, no eigenproblem). The scaling is in the coordinates of the
    tangent space's basis (:func:`tangent_space`'s): with constraints the ratio depends on
    that basis, as it did on LAPACK's (a basis-free scaling moved a two-view fit's path to
    another minimum: docs/performance.md)."""
    n = x.q.size
    seen = np.zeros(n, dtype=np.bool_)
    for a in range(n):
        seen[a] = info[a, a] > 0
    Z = tangent_space(x.C0, seen)
    if Z.shape[1] < 1:
        return False, 0.0, np.zeros(0)
    M = projected(Z, info)
    k = M.shape[0]
    d = np.empty(k)
    for a in range(k):
        d[a] = np.sqrt(abs(M[a, a]))
    if not np.all(np.isfinite(M)) or not np.all(d > 0):
        return False, 0.0, np.zeros(0)
    scaled = np.empty((k, k))
    for a in range(k):
        for b in range(k):
            scaled[a, b] = M[a, b] / (d[a] * d[b])
    if only_below > 0.0 and certainly_above(scaled, only_below):
        return False, 0.0, np.zeros(0)
    w, U = sym_eigh(scaled)
    if not w[-1] > 0:
        return False, 0.0, np.zeros(0)
    return True, w[0] / w[-1], matvec(Z, U[:, 0] / d)


@linked("A Pt Lin -> b f1")
def lost_direction(A, x, lin):
    """A direction the equations no longer see along which the cost still falls, scaled to
    a largest component of one, its sign the falling one (``found`` False without one)."""
    ok, least, u = weakest(lin.info, x, _CERTAIN * LOST)
    if not ok or least > LOST:
        return False, np.zeros(0)
    slope = dot(lin.gradient, u)
    terms = 0.0
    M, pmax, n = lin.Cbar.shape
    au = np.abs(u)
    for i in range(M):
        p = A.P[A.chan[i]]
        for a in range(p):
            acc = 0.0
            for j in range(n):
                acc += abs(lin.Cbar[i, a, j]) * au[j]
            terms += abs(lin.rbar[i, a]) * acc
    if not abs(slope) > SLOPE * np.finfo(np.float64).eps * terms:
        return False, np.zeros(0)
    return True, -np.sign(slope) * u / np.max(au)


@linked("A Pt f1 -> b f1")
def profile_gradient(A, x, q):
    """The exact gradient of the profile at ``q`` (measures restored from ``x``'s)."""
    y, _ = restore(A, q, x.mt, RESTORE_STEPS)
    if not finite(y):
        return False, np.zeros(0)
    return True, linearise(A, y.q, y.mt, y.c, y.C, y.D, y.c0, y.C0)[3]


@linked("A Pt f1 f1 b f1 -> b f1")
def lagrangian_gradient(A, x, q, lam0, exact_at_x, gradient_x):
    """The gradient of ``F + λ0ᵀ c0`` at ``q`` (``exact_at_x``: ``q`` is ``x.q`` and the
    projector's gradient there is ``gradient_x``)."""
    if exact_at_x:
        ok, g = True, gradient_x.copy()
    else:
        ok, g = profile_gradient(A, x, q)
    if not ok:
        return False, g
    if lam0.size:
        g = g + matvec(c0_eval(A, q)[1].T, lam0)
    return True, g


@linked("f2 f2 -> b f f1")
def least_eigen(K, W):
    """The least eigenvalue of the symmetrised ``K`` and its direction ``W u`` (``ok``
    False when not finite)."""
    K = 0.5 * (K + K.T)
    if not np.all(np.isfinite(K)):
        return False, 0.0, np.zeros(0)
    w, U = sym_eigh(K)
    return True, w[0], matvec(W, U[:, 0])


@linked("A Pt f1 -> b")
def second_order_tangent(A, x, d):
    """The constraints ``c0 = 0`` allow a curve along their tangent ``d`` (``C0 d = 0``) to
    second order: their curvature along it, ``v = (dᵀ∇²c0ᵢ d)ᵢ`` (central second differences
    of ``c0``), is ``−C0 w`` for some ``w`` — the curve ``q + τ d + τ² w / 2`` stays on them.
    Always, where ``C0``'s rows are independent; where they are dependent (a slack at zero
    in the product of an inequality's branches: appendix F), the rows' first order may not
    see a direction the constraints forbid (``y − z² = 0`` and ``y = 0`` pin ``z``, their
    gradients at ``z = 0`` do not): the part of ``v`` outside ``C0``'s range (its component
    along ``C0``'s left null space, :data:`UNREACHABLE` of ``‖v‖`` or more) tells."""
    r = x.C0.shape[0]
    top = max_abs(d)
    if r == 0 or not top > 0:
        return True
    left = null_space(np.ascontiguousarray(x.C0.T), 1e-10)  # C0ᵀ ν = 0
    if left.shape[1] == 0:
        return True
    h = CURVE_STEP * max(max_abs(x.q), 1.0) / top
    plus = c0_eval(A, x.q + h * d)[0]
    minus = c0_eval(A, x.q - h * d)[0]
    v = np.empty(r)
    for a in range(r):
        v[a] = (plus[a] + minus[a] - 2.0 * x.c0[a]) / (h * h)
    along = matvec(left.T, v)
    total = dot(v, v)
    return not (np.isfinite(total) and np.sqrt(dot(along, along)) > UNREACHABLE * np.sqrt(total))


@linked("A Pt Lin f2 f1 -> b f f1 f2")
def exact_curvature(A, x, lin, W, lam0):
    """The least eigenvalue of ``Wᵀ ∇²(F + λ0ᵀ c0) W`` from the profile's exact Hessian
    (:func:`.curvature.profile_hessian`; ``ok`` False where it cannot be had), its direction
    and the tangent basis it was taken on: ``W`` less the directions of negative curvature
    that the constraints allow to first order only (:func:`second_order_tangent`; each
    left out in turn, the least eigenvalue taken again on the rest)."""
    ok, K = profile_hessian(A, x, lin, W)
    if not ok:
        return False, 0.0, np.zeros(0), W
    if lam0.size:
        K += matmul(matmul(W.T, constraint_curvature(A, x.q, lam0)), W)
    ok, least, direction = least_eigen(K, W)
    basis = W
    while ok and least < -NEGATIVE and not second_order_tangent(A, x, direction):
        if basis.shape[1] == 1:  # no direction the constraints allow: nothing to check
            return True, 0.0, np.zeros(0), np.zeros((x.q.size, 0))
        _, U = sym_eigh(0.5 * (K + K.T))
        rest = complement(np.ascontiguousarray(U[:, :1]), 1)  # all but the least's direction
        K, basis = projected(rest, K), matmul(basis, rest)
        ok, least, direction = least_eigen(K, basis)
    return ok, least, direction, basis


@linked("A Pt f2 f1 f f1 -> b f2")
def sided_gradients(A, x, W, lam0, step, gradient_x):
    """The Lagrangian's gradient at ``x.q + step W[:, j]`` for every column (``ok`` False
    when one cannot be evaluated)."""
    k = W.shape[1]
    out = np.zeros((x.q.size, k))
    for j in range(k):
        ok, g = lagrangian_gradient(A, x, x.q + step * W[:, j], lam0, False, gradient_x)
        if not ok:
            return False, out
        put_column(out, j, g)
    return True, out


@linked("A Pt f2 f1 f f2 b f1 -> b f f1")
def least_curvature(A, x, W, lam0, step, plus, have_plus, gradient_x):
    """The least eigenvalue of ``Wᵀ ∇²(F + λ0ᵀ c0) W`` by central differences."""
    if not have_plus:
        ok, plus = sided_gradients(A, x, W, lam0, step, gradient_x)
        if not ok:
            return False, 0.0, np.zeros(0)
    ok, minus = sided_gradients(A, x, W, lam0, -step, gradient_x)
    if not ok:
        return False, 0.0, np.zeros(0)
    K = matmul(W.T, plus - minus) / (2 * step)
    return least_eigen(np.ascontiguousarray(K.T), W)


@linked("A Pt Lin Proj f1 b Lin Proj -> Verdict")
def verify(A, x, lin, proj, info_start, at_rounding, model_lin, model_proj):
    """The checks at ``x`` (runtime/verify.py: ``verify``)."""
    dec = decrement(x, model_lin, model_proj)
    if not (at_rounding or stationary(A, x, model_lin, model_proj)):
        return verdict(False, dec, x.cost, np.nan, np.zeros(0))
    gone, any_gone = plateau_mask(x, lin.info, info_start)
    if any_gone:
        return Verdict(True, dec, x.cost, np.nan, np.zeros(0), 1, gone.astype(np.float64))
    lost, u = lost_direction(A, x, lin)
    if lost:
        return Verdict(True, dec, x.cost, np.nan, np.zeros(0), 2, u)
    if x.cost <= 10.0 * cost_rounding(A):
        return verdict(True, dec, x.cost, 0.0, np.zeros(0))
    W = tangent_basis(x, lin.info)
    if W.shape[1] == 0:
        return verdict(True, dec, x.cost, 0.0, np.zeros(0))
    lam0 = multipliers(x, lin.gradient)
    ok, least, direction, W = exact_curvature(A, x, lin, W, lam0)
    if ok and least >= -NEGATIVE:
        return verdict(True, dec, x.cost, least, direction)
    # a negative curvature (or none computed) is confirmed by differences of the gradient
    ok_here, here = lagrangian_gradient(A, x, x.q, lam0, True, lin.gradient)
    ok, plus = sided_gradients(A, x, W, lam0, STEP, lin.gradient)
    if not ok:
        return verdict(True, dec, x.cost, np.nan, np.zeros(0))
    K = np.zeros((W.shape[1], W.shape[1]))
    for j in range(W.shape[1]):
        put_column(K, j, matvec(W.T, plus[:, j] - here) / STEP)
    ok, screen, direction = least_eigen(np.ascontiguousarray(K.T), W)
    if ok and screen >= SCREEN:
        return verdict(True, dec, x.cost, screen, direction)
    ok, least, direction = least_curvature(A, x, W, lam0, STEP, plus, True, lin.gradient)
    if not ok:
        return verdict(True, dec, x.cost, np.nan, np.zeros(0))
    if least < -NEGATIVE:
        ok, again, _ = least_curvature(A, x, W, lam0, STEP / 4, plus, False, lin.gradient)
        if not ok or not abs(again - least) <= 0.1 * abs(least) + NEGATIVE:
            return verdict(True, dec, x.cost, np.nan, np.zeros(0))
    return verdict(True, dec, x.cost, least, direction)


@linked("A Pt Lin f1 -> b Pt f")
def escape(A, x, lin, direction):
    """A restored point lower than ``x`` along the negative-curvature direction (both
    senses, a few lengths), or ``found`` False."""
    root = info_root(A, lin.info)
    found = False
    best, best_violation = x, 0.0
    for length in (1.0, 3.0, 0.3, 10.0, 0.1, 30.0):
        for sign in (1.0, -1.0):
            q = x.q + sign * length * direction
            y, violation = restored(A, q, x.mt, root, RESTORE_STEPS, True)
            if finite(y) and feasible(violation, y.cost) and y.cost < x.cost * (1 - 1e-10) \
                    and (not found or y.cost < best.cost):
                best, best_violation, found = y, violation, True
        if found:
            return True, best, best_violation
    return False, x, 0.0


@jit
def verify_at(A, x, info_start, at_rounding):
    """:func:`verify` at the restored point ``x`` with the step's model there, as a plain
    tuple of the verdict's fields (``ok`` False where the projector fails)."""
    ok, lin, proj = project_point(A, x, 0.0, np.zeros(0))
    if not ok:
        v = Verdict(False, np.nan, x.cost, np.nan, np.zeros(0), 0, np.zeros(0))
    else:
        mlin, mproj = lagrangian(A, x, lin, proj)
        v = verify(A, x, lin, proj, info_start, at_rounding, mlin, mproj)
    return (v.stationary, v.decrement, v.cost, v.curvature, v.direction, v.plateau,
            v.plateau_vector)
