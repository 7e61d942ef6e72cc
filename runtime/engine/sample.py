"""Random samples of the robust search (report §3.6, §4): the minimal solve (eq. 21), the
errors of every measure at a solution (eq. 24, one projection step) and whole samples —
drawn, solved and scored — in one kernel call.

:class:`~kanagen.runtime.robust.ModelSearch` draws a sample of the measures, solves each of
its starts for the parameter that passes through it (:func:`minimal_solve`) and scores every
solution by the errors of all the measures (:func:`errors_at`). :func:`sample` does one
sample's solves and errors, :func:`search` draws and scores samples until one beats the best
relevance (eq. 29), drawing them from the search's own NumPy generator exactly as
``Generator.choice(pool, k, replace=False)`` would (:func:`choice`), so that a search gives
the same samples whichever of the Python and the kernels draws them.

A closed-form initialiser (the two-view family's) is a C-callable function
``int64 (int64 s, double *X, double *consts, double *out)`` given by its address
(:class:`kanagen.runtime.initializers.Kernel`): ``s`` sample rows ``X``, the constants it
reads, up to :data:`CANDIDATES` candidates of :data:`WIDTH` values written into ``out``; it
returns their number, or −1 to leave the sample to the Python. The engine is compiled once
for every family: a closed form's code is its own module's, compiled only for the families
that name it.
"""

from __future__ import annotations

import ctypes

import numpy as np

from kanagen.common.borrow import alive, borrow
from kanagen.common.jit import NUMBA, jit

from ..linalg import certified_solve, row_svd, triangular_rows
from .measures import c0_eval, eval_measure, eval_values, fields, row_buffer, scratch, whitened

#: Values per candidate of a closed-form initialiser, and candidates at most.
WIDTH, CANDIDATES = 12, 4
#: Measures scored at a time before a solution may be abandoned (:func:`errors_at`).
CHUNK = 64
_FREE_STEPS = 3  # full steps allowed to raise the violation before the line search
_WATCHDOG = 1e8  # ... by at most this factor over the best violation so far
_SLOW = 4  # line-search steps in a row that lower the violation by less than a tenth

def call_form(address, X, consts, out):
    """The closed form at ``address`` on the sample rows ``X`` (s, w): its count (run
    interpreted: through ctypes)."""
    double = ctypes.c_void_p
    function = ctypes.CFUNCTYPE(ctypes.c_int64, ctypes.c_int64, double, double, double)
    return function(address)(X.shape[0], X.ctypes.data, consts.ctypes.data, out.ctypes.data)


def next_uint32(function, state):
    """A 32-bit draw of a NumPy bit generator (its ``next_uint32`` and state addresses)."""
    return ctypes.CFUNCTYPE(ctypes.c_uint32, ctypes.c_void_p)(function)(state)


if NUMBA is not None and not jit.disabled:
    from llvmlite import ir
    from numba import types
    from numba.extending import intrinsic, overload

    @intrinsic
    def _next_uint32(typingctx, function, state):
        def codegen(context, builder, signature, args):
            voidp = ir.IntType(8).as_pointer()
            fnty = ir.FunctionType(ir.IntType(32), [voidp])
            fn = builder.inttoptr(args[0], fnty.as_pointer())
            return builder.call(fn, [builder.inttoptr(args[1], voidp)])
        return types.uint32(types.int64, types.int64), codegen

    @intrinsic
    def _call_form(typingctx, address, s, X, consts, out):
        def codegen(context, builder, signature, args):
            doublep = ir.DoubleType().as_pointer()
            fnty = ir.FunctionType(ir.IntType(64), [ir.IntType(64), doublep, doublep,
                                                    doublep])
            fn = builder.inttoptr(args[0], fnty.as_pointer())
            return builder.call(fn, [args[1], *(builder.inttoptr(a, doublep)
                                                for a in args[2:])])
        return types.int64(types.int64, types.int64, types.int64, types.int64,
                           types.int64), codegen

    @overload(next_uint32, jit_options={"cache": True})
    def _next_uint32_impl(function, state):
        def impl(function, state):
            return _next_uint32(function, state)
        return impl

    @overload(call_form, jit_options={"cache": True})
    def _call_form_impl(address, X, consts, out):
        def impl(address, X, consts, out):
            return _call_form(address, X.shape[0], X.ctypes.data, consts.ctypes.data,
                              out.ctypes.data)
        return impl


# -- draws as numpy's Generator.choice(replace=False) draws them -------------------------

@jit
def bounded(function, state, rng):
    """A uniform integer of ``[0, rng]``, ``rng < 2^32``: NumPy's
    ``random_bounded_uint64(bitgen, 0, rng, 0, 0)`` (numpy/random/src/distributions:
    Lemire's multiply-and-reject on 32-bit words; no draw when ``rng`` is 0)."""
    if rng == 0:
        return 0
    if rng == 0xFFFFFFFF:
        return np.int64(next_uint32(function, state))
    excl = np.uint64(rng + 1)
    low = np.uint64(0xFFFFFFFF)
    m = np.uint64(next_uint32(function, state)) * excl
    left = m & low
    if left < excl:
        floor = (low - np.uint64(rng)) % excl
        while left < floor:
            m = np.uint64(next_uint32(function, state)) * excl
            left = m & low
    return np.int64(m >> np.uint64(32))


@jit
def choice(function, state, size, k, idx):
    """``k`` of ``range(size)`` without replacement into ``idx``, as NumPy's
    ``Generator.choice(size, k, replace=False)`` draws them: Floyd's algorithm, then a
    Fisher–Yates shuffle of the ``k`` drawn (not NumPy's tail shuffle, which it takes for
    ``size > 10000`` and ``k > size / 50``: the caller checks,
    :func:`kanagen.runtime.fastsample.draws_as_numpy`)."""
    for j in range(size - k, size):
        val = bounded(function, state, j)
        t = j - size + k
        seen = False
        for u in range(t):
            if idx[u] == val:
                seen = True
                break
        idx[t] = j if seen else val
    for i in range(k - 1, 0, -1):
        j = bounded(function, state, i)
        idx[i], idx[j] = idx[j], idx[i]


# -- eq. 21: the parameter through a sample ----------------------------------------------

@jit
def _equations(A, rows, q, w, c, J, x, cm, Cm, Dm):
    """The constraints' and the sample's equations at ``q`` (the measures as observed),
    each row scaled by ``w``: ``c``, ``J``, and ``max |c|``."""
    n, r = q.size, A.r
    if r:
        c0, C0 = c0_eval(A, q)
        for a in range(r):
            c[a] = c0[a]
            for j in range(n):
                J[a, j] = C0[a, j]
    at = r
    F = fields(A)
    chan, P, m = F[0], F[1], F[10]
    for s in range(rows.size):
        i = rows[s]
        p = P[chan[i]]
        eval_measure(F, i, q, m[i], cm, Cm, Dm, x)
        for a in range(p):
            c[at + a] = cm[a]
            for j in range(n):
                J[at + a, j] = Cm[a, j]
        at += p
    return _scaled(c, J, w)


@jit
def _scaled(c, J, w):
    """Each row of ``c``, ``J`` scaled by ``w``, in place: ``max |c|`` (NaN if any)."""
    worst = 0.0
    for a in range(c.size):
        c[a] *= w[a]
        for j in range(J.shape[1]):
            J[a, j] *= w[a]
        v = abs(c[a])
        worst = v if v > worst or v != v else worst
    return worst


@jit
def _solved(delta, q):
    """Equations (scaled to parameter units) hold to rounding-level accuracy."""
    return np.isfinite(delta) and delta <= 1e-8 * (1.0 + np.max(np.abs(q)))


@jit
def minimal_solve(A, rows, target, max_iter, xtol, eps):
    """The parameter closest to ``target`` on the equations of the sample ``rows`` (indices
    into ``A``'s measures, as observed) and the constraints (report eq. 21): Gauss–Newton
    steps to the nearest point of the linearised equations, from the SVD of their Jacobian
    (:func:`~kanagen.runtime.linalg.row_svd`, of its triangular factor when it has more
    rows than columns: :func:`~kanagen.runtime.linalg.triangular_rows`; not ``J Jᵀ``,
    whose condition number is squared; a square factor of certified full rank by Gaussian
    elimination instead, the same step: :func:`_newton_step`), each equation in units of
    the parameter (scaled by its gradient's norm at the start), with a watchdog (full steps
    may raise the violation a few times: far from the solution a curved equation needs it)
    and a line search after it. Returns ``(q, solved, rank, iterations, violation)``."""
    n = target.size
    rows_eq, pmax = A.r, 1
    for s in range(rows.size):
        p = A.P[A.chan[rows[s]]]
        rows_eq += p
        pmax = max(pmax, p)
    x = row_buffer(A, n)
    cm, Cm, Dm = np.zeros(pmax), np.zeros((pmax, n)), np.zeros((pmax, A.m.shape[1]))
    q = target.copy()
    w = np.ones(rows_eq)
    c, J = np.zeros(rows_eq), np.zeros((rows_eq, n))
    _equations(A, rows, q, w, c, J, x, cm, Cm, Dm)
    for a in range(rows_eq):  # each equation in units of the parameter
        norm = np.sqrt(np.sum(J[a] ** 2))
        w[a] = 1.0 / norm if np.isfinite(norm) and norm > 0 else 1.0
    delta = _scaled(c, J, w)
    best_delta, best_q, best_c, best_J = delta, q.copy(), c.copy(), J.copy()
    free, slow, rank = _FREE_STEPS, 0, 0
    c_new, J_new = np.zeros(rows_eq), np.zeros((rows_eq, n))
    trial, step = np.zeros(n), np.zeros(n)
    k = min(rows_eq, n)  # rows of the decomposed J (triangular_rows)
    R, W, S = np.empty((k, n)), np.empty((k, k)), np.empty(k)
    T, g = np.empty((k, n)), np.empty(k)
    work, U = np.empty((rows_eq, n + 1)), np.empty((rows_eq, n))  # triangular_rows' scratch
    K, X = np.empty((n, n)), np.empty((n, n + 1))  # _newton_step's
    for it in range(1, max_iter + 1):
        if rows_eq == 0 or not (np.all(np.isfinite(J)) and np.all(np.isfinite(c))):
            return q, False, rank, it, delta
        triangular_rows(J, c, work, U, T, g)
        if k == n and _newton_step(T, g, eps, K, X, step):
            rank = n
        else:
            if row_svd(T, R, W, S) < 0:
                return q, False, rank, it, delta
            rank = _svd_step(R, W, S, g, target, q, eps, step)
        if not np.all(np.isfinite(step)):
            return q, False, rank, it, delta
        for j in range(n):
            trial[j] = q[j] + step[j]
        d_new = _equations(A, rows, trial, w, c_new, J_new, x, cm, Cm, Dm)
        if free > 0 and np.isfinite(d_new) and d_new < _WATCHDOG * (1.0 + best_delta):
            free -= 1 if d_new >= delta else 0
            moved = np.max(np.abs(step)) if n else 0.0
        else:
            if delta > best_delta:  # the watchdog's steps did not pay: back to the best
                delta, q, c, J = best_delta, best_q.copy(), best_c.copy(), best_J.copy()
                free = 0
                continue
            free = 0
            alpha = 1.0
            found = False
            while alpha > 2.0 ** -30:
                for j in range(n):
                    trial[j] = q[j] + alpha * step[j]
                d_new = _equations(A, rows, trial, w, c_new, J_new, x, cm, Cm, Dm)
                if np.isfinite(d_new) and d_new < delta + 1e-12 * (1.0 + delta):
                    found = True
                    break
                alpha /= 2
            if not found:
                return q, _solved(delta, q), rank, it, delta
            moved = alpha * np.max(np.abs(step)) if n else 0.0
        slow = slow + 1 if free == 0 and d_new > 0.9 * delta else 0
        q, delta = trial.copy(), d_new
        c, c_new = c_new, c
        J, J_new = J_new, J
        if delta < best_delta:
            best_delta, best_q, best_c, best_J = delta, q.copy(), c.copy(), J.copy()
        if slow >= _SLOW:  # no solution near (a sample the model cannot pass through)
            return q, _solved(delta, q), rank, it, delta
        size = 1.0 + np.max(np.abs(q)) if n else 1.0
        if moved <= xtol * size or _solved(delta, q) and moved <= 1e-8 * size:
            return q, _solved(delta, q), rank, it, delta
    return q, _solved(delta, q), rank, max_iter, delta


@jit
def _newton_step(J, c, eps, K, X, step):
    """``step = −J⁻¹ c`` for a square ``J`` (the rows of the linearised equations, or the
    triangular factor of more of them, ``c`` then ``Qᵀ c``'s first n entries:
    :func:`~kanagen.runtime.linalg.triangular_rows`) every singular value of which
    :func:`_svd_step` keeps (above ``√eps`` of the largest: certified,
    :func:`~kanagen.runtime.linalg.certified_solve`) — its step then, in exact arithmetic
    (the target drops out: no direction is free), at a fraction of an SVD's cost. False,
    ``step`` undefined, when not certified (``K, X``: scratch, n × n and n × (n + 1))."""
    if not certified_solve(J, c, np.sqrt(eps), K, X, step):
        return False
    for a in range(c.size):
        step[a] = -step[a]
    return True


@jit
def _svd_step(R, W, S, g, target, q, eps, step):
    """The step of least norm from ``q`` towards ``target`` onto the linearised equations,
    from :func:`~kanagen.runtime.linalg.row_svd` of their rows: with ``J = Qₖ Wᵀ diag(S)
    V``, V's rows R's divided by S, and ``g = Qₖᵀ c``, ``step = r − V_k (V_kᵀ r + S_k⁻¹
    W_k g)``, ``r = target − q``, over the singular values above ``√eps`` of the largest
    (their number returned)."""
    n, k = q.size, S.size
    top = np.max(S)
    rank = 0
    for j in range(n):
        step[j] = target[j] - q[j]
    r = step.copy()
    for u in range(k):
        if not (top > 0 and S[u] > np.sqrt(eps) * top):
            continue
        rank += 1
        along = 0.0
        for j in range(n):
            along += R[u, j] * r[j]
        for a in range(k):
            along += W[u, a] * g[a]
        along /= S[u] * S[u]
        for j in range(n):
            step[j] -= R[u, j] * along
    return rank


# -- eq. 24: every measure's error at a solution -----------------------------------------

@jit(inline=True)
def observed_error(F, i, q, eps, c, D, E, L, inv, kept, w, x, p, d):
    """Measure ``i`` (``p`` equations, ``d`` components) at ``q`` where it was observed: its
    whitened violation ``‖c‖²_{(D Q⁺ Dᵀ)⁻}`` and the equations kept (``F``:
    :func:`~.measures.fields`; the rest: buffers of :func:`~.measures.scratch`, borrowed by
    the caller's loop: kanagen.common.borrow)."""
    eval_values(F, i, q, F[10][i], c, D, x, p, d)
    return whitened(c, D, F[8][i], p, d, eps, E, L, inv, kept, w)


@jit
def _buffers(A, n):
    """The buffers of :func:`observed_error` for the largest channel of ``A``."""
    E, L, inv, kept, y, w, _, _, _, _, _, x = scratch(A, n)
    pmax = E.shape[0]
    return np.zeros(pmax), np.zeros((pmax, A.m.shape[1])), E, L, inv, kept, w, x


@jit
def observed_all(A, q):
    """:func:`observed_error` of every measure: ``(violations, ranks)`` — the errors of eq.
    24 at one projection step (:func:`kanagen.runtime.minimal.coherence_errors`)."""
    q = np.ascontiguousarray(q)
    buffers = _buffers(A, q.size)
    c, D, E, L, inv, kept, w, x = borrow(buffers)
    viol, rank = np.empty(A.chan.size), np.empty(A.chan.size, dtype=np.int64)
    F = fields(A)
    eps = A.eps
    for i in range(A.chan.size):
        ch = F[0][i]
        p, d = F[1][ch], F[2][ch]
        if p == 1 and d == 2:  # the shipped families' shapes: their loops unrolled
            viol[i], rank[i] = observed_error(F, i, q, eps, c, D, E, L, inv, kept, w, x, 1, 2)
        elif p == 1 and d == 4:
            viol[i], rank[i] = observed_error(F, i, q, eps, c, D, E, L, inv, kept, w, x, 1, 4)
        elif p == 3 and d == 4:
            viol[i], rank[i] = observed_error(F, i, q, eps, c, D, E, L, inv, kept, w, x, 3, 4)
        else:
            viol[i], rank[i] = observed_error(F, i, q, eps, c, D, E, L, inv, kept, w, x, p, d)
    alive(buffers)
    return viol, rank


@jit(inline=True)
def channel_errors(args, ch, p, d, score, seen):
    """:func:`errors_at` over the measures of channel ``ch`` (``p`` equations, ``d``
    components): ``(complete, score, seen)``, not complete when the solution is abandoned."""
    A, F, q, caps, scale, best, errors, c, D, E, L, inv, kept, w, x = args
    total = A.chan.size
    eps = A.eps
    cap, start, size = caps[ch], A.start[ch], A.size[ch]
    for i in range(start, start + size):
        viol, rank = observed_error(F, i, q, eps, c, D, E, L, inv, kept, w, x, p, d)
        err = viol / max(min(rank, cap), 1)
        err = err if np.isfinite(err) else np.inf
        errors[i] = err
        if err < scale:
            score += 1.0 - 2.0 * err / scale
        seen += 1
        if (i - start + 1) % CHUNK == 0 or i == start + size - 1:
            if seen < total and (score + (total - seen)) / total < best - 1e-9 * abs(best):
                return False, score, seen
    return True, score, seen


@jit
def errors_at(A, q, caps, scale, best, errors):
    """Every measure's error at ``q`` where it was observed (eq. 24 at one projection
    step: :func:`observed_error` over the equations kept, at most ``caps`` of its
    channel's) into ``errors``, and the relevance (eq. 29) of ``q`` with the scale ``L*``.
    With ``best`` (a relevance; −inf: none) the solution is abandoned as soon as the
    measures left, each adding at most 1/M, cannot lift it there — checked every
    :data:`CHUNK` measures of a channel, an exact bound with a margin far above the
    rounding of the sum. Returns ``(complete, relevance)``."""
    buffers = _buffers(A, q.size)
    c, D, E, L, inv, kept, w, x = borrow(buffers)
    F = fields(A)
    args = (A, F, q, caps, scale, best, errors, c, D, E, L, inv, kept, w, x)
    total = A.chan.size
    score = 0.0
    seen = 0
    for ch in range(A.size.size):
        p, d = A.P[ch], A.Dn[ch]
        if p == 1 and d == 2:  # the shipped families' shapes: their loops unrolled
            complete, score, seen = channel_errors(args, ch, 1, 2, score, seen)
        elif p == 1 and d == 4:
            complete, score, seen = channel_errors(args, ch, 1, 4, score, seen)
        elif p == 3 and d == 4:
            complete, score, seen = channel_errors(args, ch, 3, 4, score, seen)
        else:
            complete, score, seen = channel_errors(args, ch, p, d, score, seen)
        if not complete:
            alive(buffers)
            return False, 0.0
    alive(buffers)
    return True, score / total if total else 0.0


# -- a whole sample ----------------------------------------------------------------------

@jit
def sample(A, rows, start, form, consts, names, equivalent, full_rank, max_iter, xtol, eps,
           caps, scale, best, qs, errors, complete, scores):
    """The solutions of the sample ``rows`` (indices into ``A``'s measures) and their
    errors: from ``start``, or from each candidate of the closed form at address ``form``
    (0: none) put into it (``names``: the parameter index of each of the candidate's
    values, −1 for one it does not name; a non-finite value drops the candidate), a
    minimal solve (eq. 21), and for each solution that passes (solved, of rank
    ``full_rank``) every measure's error at one projection step (:func:`errors_at` with
    the best relevance ``best``) — into ``qs``, ``errors``, ``complete``, ``scores``;
    ``equivalent``: stop at the first solution (the candidates are the same estimate).
    Returns the number of solutions, or −1 when the closed form leaves the sample to the
    Python."""
    n = start.size
    starts = np.empty((CANDIDATES, n))
    count = 1
    if form == 0:
        starts[0] = start
    else:
        width = A.W[A.chan[rows[0]]]
        X = np.empty((rows.size, width))
        for s in range(rows.size):
            for j in range(width):
                X[s, j] = A.X[rows[s], j]
        cand = np.full((CANDIDATES, WIDTH), np.nan)
        found = call_form(form, X, consts, cand)
        if found < 0 or found > CANDIDATES:
            return -1
        count = 0
        for u in range(found):
            starts[count] = start
            ok = True
            for v in range(WIDTH):
                if names[v] >= 0:
                    if not np.isfinite(cand[u, v]):
                        ok = False
                        break
                    starts[count, names[v]] = cand[u, v]
            count += 1 if ok else 0
    solutions = 0
    for u in range(count):
        q, solved, rank, _, _ = minimal_solve(A, rows, starts[u], max_iter, xtol, eps)
        if not (solved and rank >= full_rank):
            continue
        qs[solutions] = q
        whole, score = errors_at(A, q, caps, scale, best, errors[solutions])
        complete[solutions], scores[solutions] = whole, score
        solutions += 1
        if equivalent:
            break
    return solutions


@jit
def search(A, channel, pool, kpool, base, kbase, limit, function, state, start, form, consts,
           names, equivalent, full_rank, max_iter, xtol, eps, caps, scale, best,
           rows, qs, errors, complete, scores, best_q, best_errors):
    """Samples of a search until one beats the relevance ``best`` (eq. 29), or ``limit``
    samples: each draws ``kpool`` measures of ``pool`` then ``kbase`` of ``base`` (indices
    into ``channel``) with the bit generator at ``(function, state)``, as the search's
    ``Generator.choice`` draws them (:func:`choice`), into ``rows``, then runs
    :func:`sample`. Writes the best solution into ``best_q`` and ``best_errors``. Returns
    ``(samples scored, of them without a solution, outcome, best)``, the outcome 0 at the
    limit, 1 when the last sample beat ``best``, 2 when the closed form left the sample
    drawn last (its ``rows``, not counted) to the Python."""
    idx = np.empty(max(kpool, kbase, 1), dtype=np.int64)
    offset = A.start[channel]
    done, degenerate, outcome = 0, 0, 0
    while done < limit:
        choice(function, state, pool.size, kpool, idx)
        for u in range(kpool):
            rows[u] = offset + pool[idx[u]]
        choice(function, state, base.size, kbase, idx)
        for u in range(kbase):
            rows[kpool + u] = offset + base[idx[u]]
        count = sample(A, rows, start, form, consts, names, equivalent, full_rank, max_iter,
                       xtol, eps, caps, scale, best, qs, errors, complete, scores)
        if count < 0:
            outcome = 2
            break
        done += 1
        degenerate += 1 if count == 0 else 0
        for u in range(count):
            if complete[u] and scores[u] > best:
                best = scores[u]
                best_q[:] = qs[u]
                best_errors[:] = errors[u]
                outcome = 1
        if outcome:
            break
    return done, degenerate, outcome, best
