"""The non-linear iteration of the report (eq. 18) as one kernel: a trust region on restored
points, its end verified. runtime/iterate.py documents the method, its starts, its ends and
its status codes; this is its only implementation (:func:`run`).

``st`` holds the run's state between iterations: ``[radius, size0, escapes, strict,
delta0, has_info_start, marquardt]``; ``info0`` the diagonal of the information at the
start.
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np

from kanagen.common.jit import jit
from kanagen.common.link import linked, record_kind

from ..linalg import dot, matvec
from .covariance import constrained_covariance
from .linear import linearise, parameter_block
from .measures import RESTORE_STEPS, ROUNDING
from .points import (
    c0_eval,
    cost_rounding,
    evaluate,
    feasible,
    finite,
    has_relations,
    info_root,
    lagrangian,
    max_abs,
    multipliers,
    nearer_points,
    negligible,
    on_constraints,
    parameter_step,
    point_length,
    project_point,
    put_flat,
    put_point,
    relations_hold,
    restored,
    solve,
)
from .verify import Verdict, escape, is_minimum, lost_direction, stationary, verify

CONVERGED, MAX_ITER, STALLED, FAILED, BOUNDARY, SADDLE, PLATEAU, INFEASIBLE, UNVERIFIED = \
    range(9)
#: What follows a status's message: nothing, " at the starting point", " in the projector",
#: the lost direction (the verdict's plateau vector), the verdict's plateau, its description,
#: the returned point's violation of its equations or constraints.
NO_DETAIL, AT_START, IN_PROJECTOR, LOST, PLATEAU_DETAIL, DESCRIBED, OFF_CONSTRAINTS = \
    range(7)

_ACCEPT = 1e-4
_EXACT = 0.05
_SHRINK, _GROW = 0.25, 0.75
_STAGNATION = 5
_ESCAPES = 6
_COST_NOISE = 1e-13
_MAX_REFUSALS = 40
_LINE_STEPS = 3
_JOINT = 1e3
_LOST_ROUNDS = 5
_SLOW = 1e-6
_LOOK = 10
_LINEAR = 0.1
_CRAWL = 3
_GROWING = 1.0
_JOINT_STEPS = 4
_DAMPING_DECADES = 12.0
#: A full step longer than this many trust radii is not tried on its prediction alone
#: (runtime/iterate.py: "Trust region").
_BEYOND = 100.0

#: What a fit reports from the projector at a point (:func:`projected_at`): ``have`` False
#: when not taken (the rest empty); ``ok`` False where the projector fails there.
Rep = namedtuple("Rep", ["have", "ok", "info", "ranks", "kept0", "rank0", "residual"])
record_kind("Rep", Rep, "b b f2 i1 b1 i f")
#: An outcome: status, iterations, the point, which detail its message carries, a verdict,
#: the report at the point when the iteration linearised there (else ``have`` False).
Out = namedtuple("Out", ["status", "iterations", "x", "detail", "verdict", "report"])
record_kind("Out", Out, "i i Pt i Verdict Rep")


@jit
def _none_verdict(cost):
    return Verdict(False, 0.0, cost, np.nan, np.zeros(0), 0, np.zeros(0))


@jit
def no_report():
    return Rep(False, False, np.zeros((0, 0)), np.zeros(0, np.int64), np.zeros(0, np.bool_), 0,
               np.nan)


@jit
def report_of(ok, lin, proj):
    """The report at ``x`` from ``project_point(A, x, 0.0, np.zeros(0))``'s ``(ok, lin,
    proj)``: what :func:`projected_at` computes there."""
    return Rep(True, ok, lin.info, lin.ranks, proj.kept0, proj.rank0, proj.residual)


@linked("Pt i i i Verdict -> Out")
def outcome(x, it, status, detail, v):
    return Out(status, it, x, detail, v, no_report())


@linked("Pt i i i Verdict Rep -> Out")
def reported(x, it, status, detail, v, rep):
    """:func:`outcome` with the report at ``x``."""
    return Out(status, it, x, detail, v, rep)


@jit
def weights(A, st, scale, q):
    """The trust region's norm: ODRPACK's scaling, the strict slacks relative to
    themselves."""
    w = scale ** 2
    for s in range(A.strict_idx.size):
        index = A.strict_idx[s]
        w[index] = (st[1] / max(abs(q[index]), np.finfo(np.float64).tiny)) ** 2
    return w


@jit
def marquardt_scale(H):
    """Marquardt's scaling of the parameter, ``sqrt(H_aa)`` (MINPACK's ``diag``), or none
    (size 0) where a diagonal is not positive and finite."""
    out = np.zeros(H.shape[0])
    widen_marquardt(out, H)  # 0 where sqrt(|H_aa|) is 0 or not finite
    for a in range(out.size):
        if not out[a] > 0.0:
            return np.zeros(0)
    return out


@jit
def widen_marquardt(scale, H):
    """Marquardt's scaling kept at the largest ``sqrt(H_aa)`` seen (MINPACK's rule)."""
    for a in range(scale.size):
        d = np.sqrt(abs(H[a, a]))
        if d > scale[a] and np.isfinite(d):
            scale[a] = d


@jit
def wnorm(s, w):
    total = 0.0
    for a in range(s.size):
        total += s[a] * (w[a] * s[a])
    return np.sqrt(total)


@jit
def damping_decade(H, w):
    """``log10`` of the largest ``H_aa / w_a``: the Hessian's scale in the trust region's
    norm (NaN where no diagonal is positive and finite)."""
    top = 0.0
    for a in range(w.size):
        if w[a] > 0.0:
            ratio = H[a, a] / w[a]
            if ratio < np.inf and ratio > top:
                top = ratio
    return np.log10(top) if top > 0.0 else np.nan


@jit
def beyond(A, x, lin, radius, w, decade):
    """The step damped by ``μ = 10**decade`` is beyond the trust radius."""
    return wnorm(parameter_step(A, x, lin, 10.0 ** decade, w), w) > radius


@jit
def bisect_damping(A, x, lin, radius, w, lo, hi):
    """``(lo, hi)`` narrowed to 0.02 decades of ``μ``: ``10**hi``'s step within the radius,
    ``10**lo``'s beyond it (``lo`` unchanged where no step tried was)."""
    while hi - lo > 0.02:
        mid = 0.5 * (lo + hi)
        if beyond(A, x, lin, radius, w, mid):
            lo = mid
        else:
            hi = mid
    return lo, hi


@jit
def damping_for(A, x, lin, radius, w):
    """μ of ``μ diag(w)`` whose step has ``‖Δq‖_w`` just within ``radius``: bisected on
    ``log10 μ`` in [−12, 12], a range widened to :data:`_DAMPING_DECADES` either side of the
    Hessian's scale (:func:`damping_decade`) where it does not hold the radius — so the
    trust region does not depend on the information's overall scale (σ in other units).
    At unit information Eckerle4's Hessian is ~1e-9: the floor μ = 1e-12 alone held its
    steps to a tenth of the radius. (Widened below the largest diagonal's scale, not the
    least's: a slack whose curvature vanishes as it runs off, ``det(M3) = 1/s`` of the
    conic lattice's proper conics, would then be let run to a line pair.)"""
    if beyond(A, x, lin, radius, w, 12.0):
        top = damping_decade(lin.H, w) + _DAMPING_DECADES
        if top > 12.0 and not beyond(A, x, lin, radius, w, top):
            return 10.0 ** bisect_damping(A, x, lin, radius, w, 12.0, top)[1]
        return 10.0 ** (top if top > 12.0 else 12.0)
    lo, hi = bisect_damping(A, x, lin, radius, w, -12.0, 12.0)
    if lo == -12.0:  # every step tried within the radius: did μ = 1e-12 hold one back?
        bottom = damping_decade(lin.H, w) - _DAMPING_DECADES
        if bottom < lo and beyond(A, x, lin, radius, w, bottom):
            hi = bisect_damping(A, x, lin, radius, w, bottom, lo)[1]
    return 10.0 ** hi


@linked("A Pt Lin f f1 -> Proj")
def damped(A, x, lin, radius, w):
    """The projector's point with the parameter's step damped to ``radius``."""
    return solve(A, x, lin, damping_for(A, x, lin, radius, w), w)[1]


@jit(inline=True)
def predicted_fall(A, x, lin, s, target_q, lam0):
    fall = -(dot(lin.gradient, s) + 0.5 * dot(s, matvec(lin.info, s)))
    if lam0.size:
        fall -= dot(lam0, c0_eval(A, target_q)[0]) - dot(lam0, x.c0)
    return fall


@jit
def diverging(A, q_old, q_new, start):
    """A strict relation's slack diverges (runtime/iterate.py: ``_diverging``)."""
    for s in range(A.strict_idx.size):
        index, power = A.strict_idx[s], A.strict_pow[s]
        s_old, s_new = abs(q_old[index]), abs(q_new[index])
        if s_new > 1.1 * s_old and (abs(start[index]) / s_new) ** power < 1e-8:
            return True
    return False


@jit
def at_rounding(q, q_new):
    top = ROUNDING * max_abs(q)
    for a in range(q.size):
        if not abs(q_new[a] - q[a]) <= top:
            return False
    return True


@jit(inline=True)
def lowers_violation(trial, trial_violation, x, violation):
    noise = 1e-14 * max(1.0, x.cost)
    return trial_violation < (1 - 1e-4) * violation - noise or (
        trial_violation <= violation + noise and trial.cost <= x.cost)


@linked("A Pt f2 -> b Pt f")
def nearer(A, x, root):
    """``x`` with measures at nearer points of their equations, restored, when that lowers
    the cost (``found`` False otherwise)."""
    changed, y = nearer_points(A, x)
    if not changed:
        return False, x, 0.0
    moved, violation = restored(A, x.q, y.mt, root, RESTORE_STEPS, False)
    if finite(moved) and on_constraints(moved, violation) and moved.cost < x.cost - (
            _COST_NOISE * x.cost + cost_rounding(A)):
        return True, moved, violation
    return False, x, 0.0


@linked("A Pt f f1 f2 f2 b -> b Pt f")
def towards_constraints(A, x, violation, target_q, target_mt, root, guard):
    """Eq. 18 while ``x`` is off its equations: a trial that lowers the violation, moved
    onto the constraints once close to them."""
    trial, tv = restored(A, target_q, target_mt, root, RESTORE_STEPS, False)
    if not (finite(trial) and (not guard or relations_hold(A, trial.q))
            and lowers_violation(trial, tv, x, violation)):
        return False, x, 0.0
    if feasible(tv, trial.cost):
        onto, ov = restored(A, trial.q, trial.mt, root, RESTORE_STEPS, True)
        if finite(onto) and on_constraints(onto, ov):
            return True, onto, ov
    return True, trial, tv


@linked("A f1 f1 Pt f Lin Proj -> b Pt f")
def step(A, st, scale, x, violation, lin, proj):
    """An acceptable restored point: the projector's step, shortened, else damped within
    the trust radius (runtime/iterate.py: ``_Run.step``)."""
    root = info_root(A, lin.info)
    guard = has_relations(A) and relations_hold(A, x.q)
    lam0 = multipliers(x, lin.gradient)
    on = on_constraints(x, violation)
    w = weights(A, st, scale, x.q)
    full = proj.q - x.q
    length = wnorm(full, w)
    alpha = 1.0
    strict = st[3] != 0
    line_steps = 0 if length > st[0] else _LINE_STEPS
    far = on and length > _BEYOND * st[0]
    for attempt in range(_MAX_REFUSALS):
        line = attempt <= line_steps and not (strict and length > st[0]) and not far
        beyond = attempt == 0 and length > st[0] and not strict and not far
        if line:
            target_q = x.q + alpha * full
            target_mt = x.mt + alpha * (proj.mt - x.mt)
        else:
            dp = damped(A, x, lin, st[0], w)
            target_q, target_mt = dp.q, dp.mt
        s = target_q - x.q
        size = wnorm(s, w)
        if not on:
            taken, trial, tv = towards_constraints(A, x, violation, target_q, target_mt, root,
                                                   guard)
            if taken:
                return True, trial, tv
        else:
            trial, tv = restored(A, target_q, target_mt, root, RESTORE_STEPS, True)
            if finite(trial) and (not guard or relations_hold(A, trial.q)) and \
                    on_constraints(trial, tv):
                pred = predicted_fall(A, x, lin, s, target_q, lam0)
                rho = (x.cost - trial.cost) / pred if pred > 0.0 else -np.inf
                noise = _COST_NOISE * x.cost + cost_rounding(A)
                rounding = abs(pred) <= 1e2 * noise and trial.cost <= x.cost + noise
                if beyond:
                    if abs(rho - 1.0) <= _EXACT:
                        st[0] = max(st[0], 2.0 * size)
                        return True, trial, tv
                elif rounding or rho > _ACCEPT:
                    if rho < _SHRINK and not rounding:
                        st[0] = _SHRINK * size
                    elif rho > _GROW:
                        st[0] = max(st[0], 2.0 * size)
                    return True, trial, tv
        if line:
            alpha /= 2
        if beyond or line:
            continue
        st[0] = _SHRINK * (min(st[0], size) if np.isfinite(size) else st[0])
        if not st[0] > 1e-15 * (1.0 + (wnorm(x.q, w) if st[6] != 0 else
                                       np.sqrt(dot(x.q, x.q)))):
            return False, x, 0.0
    return False, x, 0.0


@linked("A f1 f1 Pt f b Lin Proj Lin Proj i b -> b Out Pt f")
def end(A, st, info0, x, violation, have_lin, lin, proj, mlin, mproj, it, verify_end):
    """Verify ``x`` (its violation ``violation``, from the restoration that made it):
    ``(done, outcome, next point, its violation)`` — not done after an escape (the
    iteration goes on from the next point). ``have_lin``: ``lin, proj`` are the projector's
    at ``x`` and ``mlin, mproj`` :func:`lagrangian`'s from them (else made here)."""
    none = _none_verdict(x.cost)
    if not have_lin:
        ok, lin, proj = project_point(A, x, 0.0, np.zeros(0))
        if not ok:
            return True, outcome(x, it, FAILED, IN_PROJECTOR, none), x, 0.0
    rep = report_of(True, lin, proj)  # lin, proj: the projector's at x, undamped
    if not verify_end:
        return True, reported(x, it, UNVERIFIED, NO_DETAIL, none, rep), x, 0.0
    if not on_constraints(x, violation):
        return True, reported(x, it, INFEASIBLE, OFF_CONSTRAINTS, none, rep), x, 0.0
    root = info_root(A, lin.info)
    if st[2] < _ESCAPES:
        found, moved, mv = nearer(A, x, root)
        if found:  # a lower cost at x: the radius its refused steps shrank starts again
            st[2] += 1
            st[0] = max(st[0], st[1])
            return False, outcome(x, it, FAILED, NO_DETAIL, none), moved, mv
    if not have_lin:
        mlin, mproj = lagrangian(A, x, lin, proj)
    start_info = info0 if st[5] != 0 else np.zeros(0)
    v = verify(A, x, lin, proj, start_info, at_rounding(x.q, mproj.q), mlin, mproj)
    if is_minimum(v):
        return True, reported(x, it, CONVERGED, NO_DETAIL, v, rep), x, 0.0
    if v.plateau:
        return True, reported(x, it, PLATEAU, PLATEAU_DETAIL, v, rep), x, 0.0
    if not v.stationary:
        return True, reported(x, it, STALLED, DESCRIBED, v, rep), x, 0.0
    if st[2] < _ESCAPES and v.direction.size:
        st[2] += 1
        found, moved, mv = escape(A, x, lin, v.direction)
        if found:
            d = moved.q - x.q
            st[0] = max(st[0], np.sqrt(dot(d, d)))
            return False, outcome(x, it, FAILED, NO_DETAIL, none), moved, mv
    return True, reported(x, it, SADDLE, DESCRIBED, v, rep), x, 0.0


@linked("A f1 f1 f1 f1 Pt f i f b -> Out")
def descend(A, st, info0, scale, q_start, x, violation, max_iter, xtol, verify_end):
    """The iteration from the point ``x`` (runtime/iterate.py: ``_Run.descend``)."""
    since_progress = since_lost = next_look = crawl = 0
    last_fall = np.inf
    last_size = np.inf
    for it in range(1, max_iter + 1):
        ok, lin, proj = project_point(A, x, 0.0, np.zeros(0))
        if not ok:
            return outcome(x, it, FAILED, IN_PROJECTOR, _none_verdict(x.cost))
        if st[5] == 0:
            for a in range(x.q.size):
                info0[a] = abs(lin.info[a, a])
            st[5] = 1
        if st[6] != 0:
            widen_marquardt(scale, lin.info)
        x_feasible = on_constraints(x, violation)
        scaled = scale * x.q
        size = np.sqrt(dot(scaled, scaled))
        lost = False
        u = np.zeros(0)
        if x_feasible and verify_end and size > _GROWING * last_size:
            lost, u = lost_direction(A, x, lin)
        since_lost = since_lost + 1 if lost else 0
        last_size = size
        if since_lost >= _LOST_ROUNDS:
            v = Verdict(True, 0.0, x.cost, np.nan, np.zeros(0), 2, u)
            return reported(x, it, PLATEAU, LOST, v, report_of(ok, lin, proj))
        mlin, mproj = lagrangian(A, x, lin, proj)
        if x_feasible and (stationary(A, x, mlin, mproj) or at_rounding(x.q, mproj.q)) \
                and negligible(A, x.q, mproj.q, x.mt, mproj.mt, xtol):
            done, out, x, violation = end(A, st, info0, x, violation, True, lin, proj, mlin,
                                          mproj, it, verify_end)
            if done:
                return out
            continue
        found, trial, trial_violation = step(A, st, scale, x, violation, mlin, mproj)
        if not found:
            done, out, x, violation = end(A, st, info0, x, violation, True, lin, proj, mlin,
                                          mproj, it, verify_end)
            if done:
                return out
            continue
        if diverging(A, x.q, trial.q, q_start):
            return outcome(trial, it, BOUNDARY, NO_DETAIL, _none_verdict(trial.cost))
        fall = x.cost - trial.cost
        progress = not on_constraints(x, violation) or fall > 1e-14 * x.cost
        since_progress = 0 if progress else since_progress + 1
        x, violation = trial, trial_violation
        crawl = crawl + 1 if (progress and fall <= _SLOW * x.cost and
                              fall > _LINEAR * last_fall) else 0
        last_fall = fall
        if crawl >= _CRAWL and verify_end and st[2] < _ESCAPES and it >= next_look and \
                on_constraints(x, violation):
            next_look = it + _LOOK
            found, moved, mv = nearer(A, x, info_root(A, lin.info))
            if found:
                st[2] += 1
                x, violation = moved, mv
                continue
        if since_progress >= _STAGNATION:
            done, out, x, violation = end(A, st, info0, x, violation, False, lin, proj, mlin,
                                          mproj, it, verify_end)
            if done:
                return out
            since_progress = 0
    ok, lin, proj = project_point(A, x, 0.0, np.zeros(0))
    x_feasible = on_constraints(x, violation)
    if verify_end and ok and x_feasible and not nearer(A, x, info_root(A, lin.info))[0]:
        mlin, mproj = lagrangian(A, x, lin, proj)
        start_info = info0 if st[5] != 0 else np.zeros(0)
        v = verify(A, x, lin, proj, start_info, False, mlin, mproj)
        if is_minimum(v):
            return reported(x, max_iter, CONVERGED, NO_DETAIL, v, report_of(ok, lin, proj))
    return reported(x, max_iter, MAX_ITER, NO_DETAIL if x_feasible else OFF_CONSTRAINTS,
                    _none_verdict(x.cost), report_of(ok, lin, proj))


@linked("A f1 f1 Pt f Proj f2 -> Pt f b")
def joint_start(A, st, scale, x, violation, proj0, root):
    """The restored start ``x``, or the point of the joint problem's steps from the raw
    start while they improve (runtime/iterate.py: "Starts"); ``moved`` whether it is not
    ``x``.

    The steps' projector points are made from the steps' unrestored points: their chain (at
    most :data:`_JOINT_STEPS` points, each within the start's reach) does not depend on the
    restorations, which only decide the point kept — and are most of a step's cost. So the
    first point and the last are restored, the others only where those two cannot decide:
    the first must improve on ``x`` (else ``x``); the last is kept when it improves on the
    first — when every step improves (the usual case), the point that restoring each would
    keep; else the points between are restored in turn while they improve."""
    w = weights(A, st, scale, x.q)
    reach = _JOINT * st[0]
    if not wnorm(proj0.q - x.q, w) <= reach:
        return x, violation, False
    best, best_violation = restored(A, proj0.q, proj0.mt, root, RESTORE_STEPS, True)
    if not improves(A, best, best_violation, x, violation):
        return x, violation, False
    chain = [proj0]
    proj = proj0
    for _ in range(_JOINT_STEPS - 1):
        ok, _, proj = project_point(A, evaluate(A, proj.q, proj.mt), 0.0, np.zeros(0))
        if not (ok and wnorm(proj.q - x.q, w) <= reach):
            break
        chain.append(proj)
    if len(chain) > 1:
        last = chain[len(chain) - 1]
        trial, tv = restored(A, last.q, last.mt, root, RESTORE_STEPS, True)
        if improves(A, trial, tv, best, best_violation):
            return trial, tv, True
    for k in range(1, len(chain) - 1):  # the last is above these when they improve
        trial, tv = restored(A, chain[k].q, chain[k].mt, root, RESTORE_STEPS, True)
        if not improves(A, trial, tv, best, best_violation):
            break
        best, best_violation = trial, tv
    return best, best_violation, True


@jit(inline=True)
def improves(A, trial, tv, best, best_violation):
    """A joint step's restored point improves on ``best``: finite, on its equations, of
    lower cost (or ``best`` off them), inside the model's relations."""
    return finite(trial) and on_constraints(trial, tv) and (
        trial.cost < best.cost or not on_constraints(best, best_violation)) and (
        not has_relations(A) or relations_hold(A, trial.q))


@jit
def run(A, q_start, max_iter, xtol, verify_end):
    """The iteration from ``(q_start, m)`` (runtime/iterate.py: ``iterate``): its outcome
    and the start's violation ``‖c‖∞``."""
    n = q_start.size
    st = np.zeros(7)
    info0 = np.zeros(n)
    raw = evaluate(A, q_start, A.m)
    st[4] = raw.delta
    if not finite(raw):
        return outcome(raw, 0, FAILED, AT_START, _none_verdict(raw.cost)), st[4]
    ok0, lin0, proj0 = project_point(A, raw, 0.0, np.zeros(0))
    root = info_root(A, lin0.info) if ok0 else np.zeros((0, 0))
    x, violation = restored(A, q_start, raw.mt, root, RESTORE_STEPS, True)
    if not (finite(x) and on_constraints(x, violation)):
        x, violation = restored(A, q_start, raw.mt, np.zeros((0, 0)), RESTORE_STEPS, False)
    size0 = np.sqrt(dot(q_start, q_start))
    size0 = size0 if size0 != 0 else 1.0
    st[0] = st[1] = size0
    typical = np.sqrt(np.mean(q_start ** 2))
    typical = typical if typical != 0 else 1.0
    scale = size0 / np.maximum(np.abs(q_start), 0.1 * typical)
    if not finite(x):
        return descend(A, st, info0, scale, q_start, raw, np.inf, max_iter, xtol,
                       verify_end), st[4]
    if not ok0:
        return descend(A, st, info0, scale, q_start, x, violation, max_iter, xtol,
                       verify_end), st[4]
    joint, joint_violation, joint_moved = joint_start(A, st, scale, x, violation, proj0, root)
    # the joint step's point; its damped step; the restored start (strict); it; the joint
    # step's point under Marquardt's scaling
    plan = [0]
    if on_constraints(x, violation):
        if verify_end:
            plan.append(1)
            plan.append(2)
        if joint_moved:
            plan.append(3)
    marquardt = marquardt_scale(lin0.info)
    if verify_end and marquardt.size:
        plan.append(4)
    have_best = False
    best = outcome(x, 0, FAILED, NO_DETAIL, _none_verdict(x.cost))
    iterations = 0
    for code in plan:
        if have_best:
            if best.status == CONVERGED or (not verify_end and (
                    best.status == UNVERIFIED or best.status == MAX_ITER)):
                break
            st[0], st[2], st[5] = st[1], 0.0, 0.0
        if code == 0 or code == 4:
            point, pv = joint, joint_violation
        elif code == 1:
            dp = damped(A, raw, lin0, st[1], weights(A, st, scale, q_start))
            point, pv = restored(A, dp.q, dp.mt, root, RESTORE_STEPS, True)
            if not (finite(point) and on_constraints(point, pv)):
                continue
        else:
            point, pv = x, violation
        st[3] = 1.0 if code == 2 else 0.0
        if code == 4:  # its own first radius, the start's size in its norm
            st[0] = st[1] = max(wnorm(q_start, marquardt ** 2), np.finfo(np.float64).tiny)
            st[6] = 1.0
        out = descend(A, st, info0, marquardt if code == 4 else scale, q_start, point, pv,
                      max_iter, xtol, verify_end)
        st[1], st[3], st[6] = size0, 0.0, 0.0
        iterations += out.iterations
        if not have_best or out.status == CONVERGED or out.x.cost < best.x.cost:
            best, have_best = out, True
    return Out(best.status, iterations, best.x, best.detail, best.verdict, best.report), \
        st[4]





@jit
def projected_at(A, x):
    """What a fit reports from the projector at its returned point ``x``: ``(ok, info,
    ranks, kept0, rank0, residual)`` — the information, each measure's equations kept, the
    constraints kept and their rank, the residual E² (``ok`` False where the projector
    fails)."""
    info, H, rhs, gradient, Cbar, rbar, E, L, inv, kept, ranks, residual = linearise(
        A, x.q, x.mt, x.c, x.C, x.D, x.c0, x.C0)
    dq, kept0, rank0, residual0, ok = parameter_block(H, info, rhs, x.C0, x.c0, x.q,
                                                      residual, 0.0, np.zeros(0), A.eps)
    return ok, info, ranks, kept0, rank0, residual0


@jit
def run_flat(A, q_start, max_iter, xtol, verify_end, report):
    """:func:`run` for Python: numbers, one float array and one integer array (boxing a
    named tuple calls its Python class, where a pending Ctrl-C would raise inside numba's
    boxing, and crash; each array boxed costs about a microsecond).

    ``report``: with :func:`projected_at` the returned point and the covariance there
    (:func:`.covariance.constrained_covariance`; else ``ok`` False and nothing of them).
    Returns ``(status, iterations, detail, stationary, plateau, ok, rank0, width, sizes,
    values, integers)``: ``width`` the point's equations' padded width; ``sizes`` those of
    the verdict's direction and plateau vector and the sides of the information and the
    covariance; ``values`` the start's violation, the verdict's decrement, cost and
    curvature, the residual, the point (:func:`.points.put_point`), the direction, the
    plateau vector, the information, the covariance; ``integers`` the ranks, then the
    constraints kept (0/1)."""
    out, delta0 = run(A, q_start, max_iter, xtol, verify_end)
    x, v = out.x, out.verdict
    covariance = np.zeros((0, 0))
    if report:
        rep = out.report
        if rep.have:  # the iteration's linearisation at x (the same numbers)
            ok, info, ranks, kept0, rank0, residual = rep.ok, rep.info, rep.ranks, rep.kept0, \
                rep.rank0, rep.residual
        else:
            ok, info, ranks, kept0, rank0, residual = projected_at(A, x)
        if ok:
            covariance = constrained_covariance(info, kept_rows(x.C0, kept0))
    else:
        ok, info, ranks, kept0 = False, np.zeros((0, 0)), np.zeros(0, np.int64), \
            np.zeros(0, np.bool_)
        rank0, residual = 0, np.nan
    values = np.empty(5 + point_length(x) + v.direction.size + v.plateau_vector.size +
                      info.size + covariance.size)
    values[0], values[1], values[2], values[3], values[4] = delta0, v.decrement, v.cost, \
        v.curvature, residual
    at = put_point(values, 5, x)
    at = put_flat(values, at, v.direction)
    at = put_flat(values, at, v.plateau_vector)
    at = put_flat(values, at, info)
    put_flat(values, at, covariance)
    integers = np.empty(ranks.size + kept0.size, np.int64)
    for i in range(ranks.size):
        integers[i] = ranks[i]
    for a in range(kept0.size):
        integers[ranks.size + a] = 1 if kept0[a] else 0
    sizes = (v.direction.size, v.plateau_vector.size, info.shape[0], covariance.shape[0])
    return (out.status, out.iterations, out.detail, v.stationary, v.plateau, ok, rank0,
            x.c.shape[1], sizes, values, integers)


@jit
def kept_rows(C0, kept0):
    """The rows of ``C0`` kept (``C0[kept0]``)."""
    out = np.empty((int(kept0.sum()), C0.shape[1]))
    at = 0
    for a in range(C0.shape[0]):
        if kept0[a]:
            out[at] = C0[a]
            at += 1
    return out
