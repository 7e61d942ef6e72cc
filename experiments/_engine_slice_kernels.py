"""The measure projection of ``runtime/projector.py: project_measures`` for one channel,
written once for numba's ``@njit(cache=True)`` and plain Python (issue 17's slice).

Arrays in, arrays out: no :class:`~kanagen.runtime.projector.Problem`, no
:class:`~kanagen.runtime.inputs.ChannelData`. The family's generated functions are the
arguments ``measure`` (``q, X, k -> (c, C, D)``), ``whiten`` and ``correct`` (the unrolled
kernels of the generated module). As written, :func:`project_channel` runs as plain Python
with plain functions. For numba it is *specialised*: experiments/engine_slice.py copies the
syntax trees of :func:`project_channel` and :func:`halving` into the family's njit-able
module once per (model, channel), the three arguments replaced by the generated functions'
global names (what the code generator would emit), and numba compiles that copy. Why not
pass the compiled functions as arguments (experiments/engine_slice.py ``--alternatives``
measures both):

* a dispatcher passed as a value (an argument, a closure cell, or a global passed on) is
  keyed by its identity: numba's cache never hits in a new process, and a caller that passes
  a global dispatcher on "uses dynamic globals" and cannot be cached at all;
* as a first-class function value (``numba.types.FunctionType``, explicit signatures) the
  projector is cached, but unboxing each function value from Python costs ~50 µs a call.

Loops over measures replace the NumPy version's vectorised masks; the order of every
floating-point operation per measure is the NumPy version's, up to the order of the short
sums of ``D (m − m•)`` and ``movedᵀ Q moved`` (rounding level; on the slice's cases the
results are bit for bit the NumPy ones). Only the generated functions work on whole arrays
(they are vectorised over the measures as emitted).

Used by experiments/engine_slice.py only.
"""

from __future__ import annotations

import os

import numpy as np

try:  # numba when present (NUMBA_DISABLE_JIT=1 makes njit return the Python function)
    from numba import njit as _njit

    def jit(fn):
        # cached unless ENGINE_SLICE_CACHE=0 (engine_slice.py's cold compile, cache off)
        return _njit(cache=os.environ.get("ENGINE_SLICE_CACHE", "1") != "0",
                     error_model="numpy")(fn)
except ImportError:  # plain Python
    def jit(fn):
        return fn

#: Relative rounding level of stored values (runtime/projector.py's _ROUNDING).
_ROUNDING = float(1e3 * np.finfo(float).eps)


@jit
def with_corrected(X, index, mt):
    """``ChannelData.with_corrected``: ``X`` with the corrected columns ``index`` replaced by
    ``mt`` (``mt`` itself when every column is corrected)."""
    if index.size == X.shape[1]:
        return mt
    out = X.copy()
    for i in range(X.shape[0]):
        for j in range(index.size):
            out[i, index[j]] = mt[i, j]
    return out


def halving(measure, q, X, index, k, m, c, step):
    """``runtime/projector.py: _halving`` with its 4 halvings: ``m + α step`` with α halved
    per measure where ``‖c‖∞`` grows (NaN counts as growth), 0 where it still grows.
    Returns the new measures and the equations ``(c, C, D)`` there."""
    M, kk = m.shape
    p = c.shape[1]
    worst = np.zeros(M)
    for i in range(M):
        w = 0.0
        for a in range(p):
            v = abs(c[i, a])
            if v != v:  # np.max propagates NaN
                w = v
                break
            if v > w:
                w = v
        worst[i] = w
    alpha = np.ones(M)
    grew = np.zeros(M, np.bool_)
    cand = m.copy()
    settled = False
    for _ in range(4):
        for i in range(M):
            for j in range(kk):
                cand[i, j] = m[i, j] + alpha[i] * step[i, j]
        c_new, C_new, D_new = measure(q, with_corrected(X, index, cand), k)
        any_grew = False
        for i in range(M):
            w = worst[i]
            if p:
                w = 0.0
                for a in range(p):
                    v = abs(c_new[i, a])
                    if v != v:
                        w = v
                        break
                    if v > w:
                        w = v
            g = not (w <= worst[i] + 1e-9 * (1.0 + worst[i]))
            grew[i] = g
            any_grew = any_grew or g
        if not any_grew:
            settled = True
            break
        for i in range(M):
            if grew[i]:
                alpha[i] = alpha[i] / 2
    if not settled:
        for i in range(M):
            if grew[i]:
                alpha[i] = 0.0
            for j in range(kk):
                cand[i, j] = m[i, j] + alpha[i] * step[i, j]
        c_new, C_new, D_new = measure(q, with_corrected(X, index, cand), k)
    return cand, c_new, C_new, D_new


def project_channel(measure, whiten, correct, q, X, index, Q, G, k, iterations, tol, eps):
    """``project_measures`` for one channel whose measures start where they were observed
    (as ``coherence_errors`` calls it): each measure projected onto ``c(q, ·) = 0`` in its
    ``Q`` metric (report eq. 22, eq. 18's halving per measure).

    ``X`` (M, w) observed data, ``index`` the corrected columns, ``Q`` and ``G`` (k, k) or
    (M, k, k). Returns ``(mt, violation, rank, steps)``: the projected measures (M, k), per
    measure the whitened violation and the equations kept, and the projector steps taken.
    """
    M = X.shape[0]
    kk = index.size
    m_obs = np.empty((M, kk))
    for i in range(M):
        for j in range(kk):
            m_obs[i, j] = X[i, index[j]]
    Qm = Q.reshape((-1, kk, kk))  # (1, k, k) shared or (M, k, k) per measure
    per_measure = Qm.shape[0] > 1
    m = m_obs.copy()
    violation = np.zeros(M)
    rank = np.zeros(M, np.int64)
    c, C, D = measure(q, with_corrected(X, index, m), k)
    p = c.shape[1]
    active = np.ones(M, np.bool_)
    B = np.empty((M, p, 2))
    z = np.empty((M, p))
    step = np.empty((M, kk))
    steps = 0
    for it in range(iterations if M else 0):
        for i in range(M):  # r − C q with q fixed, and c: whiten's two right-hand sides
            for a in range(p):
                s = 0.0
                for j in range(kk):
                    s += D[i, a, j] * (m[i, j] - m_obs[i, j])
                B[i, a, 0] = s - c[i, a]
                B[i, a, 1] = c[i, a]
        Bbar, kept, state = whiten(D, G, B, eps)
        any_active = False
        for i in range(M):
            v = 0.0
            r = 0
            for a in range(p):
                v += Bbar[i, a, 1] ** 2
                r += 1 if kept[i, a] else 0
            violation[i] = v
            rank[i] = r
            any_active = any_active or active[i]
        if it == iterations - 1 or not any_active:
            break
        for i in range(M):
            for a in range(p):
                z[i, a] = Bbar[i, a, 0]
        dm = correct(state, G, z)
        for i in range(M):
            ok = active[i]
            for j in range(kk):
                step[i, j] = m_obs[i, j] + dm[i, j] - m[i, j]
                ok = ok and np.isfinite(step[i, j])
            if not ok:
                for j in range(kk):
                    step[i, j] = 0.0
        m_new, c, C, D = halving(measure, q, X, index, k, m, c, step)
        steps += 1
        for i in range(M):
            Qi = Qm[i] if per_measure else Qm[0]
            seen = 0.0
            unseen = False
            for a in range(kk):
                da = m_new[i, a] - m[i, a]
                for b in range(kk):
                    seen += da * Qi[a, b] * (m_new[i, b] - m[i, b])
                unseen = unseen or abs(da) > _ROUNDING * (1.0 + abs(m_new[i, a]))
            active[i] = active[i] and (seen > tol**2 or unseen)
        m = m_new
    return m, violation, rank, steps


# -- per measure, as codegen/c/kanagen_fast.c's kg_project_measures ----------------------------
#
# The same projection, one measure at a time to its end (as the C port runs it): a measure
# that has converged is not evaluated again, and nothing is allocated per step. Only the
# measure function is generated, in a per-measure form ``measure_row(q, x, k, c, C, D)``
# writing one measure's equations into c (p,), C (p, n), D (p, k) (the generated vectorised
# function with its ``[:, ...]`` dropped: experiments/engine_slice.py's ``_RowForm``);
# whiten and correct are the runtime's, generic over (p, k), with the arithmetic of the
# generated unrolled kernels (inverse pivots multiplied), written here once.

_TINY = float(np.finfo(float).tiny)
_REDUNDANT = float(1e3 * np.finfo(float).eps)


@jit
def whiten_row(D, G, B, eps, E, L, kept):
    """``whiten_<p>_<k>`` for one measure: ``E = D Gᵀ``, ``L`` the reduced root of ``E Eᵀ``
    (as inverse pivots on its diagonal), ``B`` (p, t) ← ``L⁻¹ B``; returns the rank."""
    p, kk = D.shape
    for a in range(p):
        for j in range(kk):
            acc = D[a, 0] * G[j, 0]
            for i in range(1, j + 1):
                acc += D[a, i] * G[j, i]
            E[a, j] = acc
    top = 0.0
    for a in range(p):
        s = 0.0
        for j in range(kk):
            s += E[a, j] * E[a, j]
        L[a, a] = s  # S_aa, until its pivot
        top = s if (s > top or s != s) else top
    tol = eps * (top if (top > _TINY or top != top) else _TINY)
    rank = 0
    for a in range(p):
        saa = L[a, a]
        piv = saa
        for b in range(a):
            piv -= L[a, b] ** 2
        keep = piv > tol and (a == 0 or piv > _REDUNDANT * saa)
        kept[a] = keep
        inv = 1.0 / np.sqrt(piv if keep else 1.0) if keep else 0.0
        L[a, a] = inv
        rank += 1 if keep else 0
        for i in range(a + 1, p):
            s = 0.0
            for j in range(kk):
                s += E[i, j] * E[a, j]
            for b in range(a):
                s -= L[i, b] * L[a, b]
            L[i, a] = s * inv
    for a in range(p):
        for t in range(B.shape[1]):
            acc = B[a, t]
            for b in range(a):
                acc -= L[a, b] * B[b, t]
            B[a, t] = acc * L[a, a]
    return rank


@jit
def correct_row(E, L, G, z, dm, y):
    """``correct_<p>_<k>`` for one measure: ``dm = Gᵀ Eᵀ L⁻ᵀ z``."""
    p, kk = E.shape
    for a in range(p - 1, -1, -1):
        acc = z[a]
        for i in range(a + 1, p):
            acc -= L[i, a] * y[i]
        y[a] = acc * L[a, a]
    for c in range(kk):
        acc = 0.0
        for j in range(c, kk):
            t = E[0, j] * y[0]
            for a in range(1, p):
                t += E[a, j] * y[a]
            acc = G[j, c] * t if j == c else acc + G[j, c] * t
        dm[c] = acc


@jit
def _nanmax_abs(c):
    w = 0.0
    for a in range(c.size):
        v = abs(c[a])
        if v != v:
            return v
        if v > w:
            w = v
    return w


def halving_row(measure_row, q, x, index, k, m, c, C, D, step, cand):
    """``_halving`` for one measure (writes ``cand`` and ``c, C, D`` there)."""
    kk = m.size
    worst = _nanmax_abs(c) if c.size else 0.0
    alpha = 1.0
    grew = False
    for _ in range(4):
        for j in range(kk):
            cand[j] = m[j] + alpha * step[j]
            x[index[j]] = cand[j]
        measure_row(q, x, k, c, C, D)
        new_worst = _nanmax_abs(c) if c.size else worst
        grew = not (new_worst <= worst + 1e-9 * (1.0 + worst))
        if not grew:
            break
        alpha /= 2
    if grew:
        alpha = 0.0
        for j in range(kk):
            cand[j] = m[j] + alpha * step[j]
            x[index[j]] = cand[j]
        measure_row(q, x, k, c, C, D)


def project_rows(measure_row, p, q, X, index, Q, G, k, iterations, tol, eps):
    """:func:`project_channel` one measure at a time (``p`` equations per measure):
    the same ``(mt, violation, rank, steps)``, ``steps`` the most any measure took."""
    M, w = X.shape
    kk = index.size
    n = q.size
    Qm = Q.reshape((-1, kk, kk))
    Gm = G.reshape((-1, kk, kk))
    mt = np.empty((M, kk))
    violation = np.zeros(M)
    rank = np.zeros(M, np.int64)
    x = np.empty(w)
    m = np.empty(kk)
    mobs = np.empty(kk)
    c, C, D = np.empty(p), np.empty((p, n)), np.empty((p, kk))
    B = np.empty((p, 2))
    E, L, kept = np.empty((p, kk)), np.zeros((p, p)), np.zeros(p, np.bool_)
    z, y, dm = np.empty(p), np.empty(p), np.empty(kk)
    step, cand = np.empty(kk), np.empty(kk)
    steps = 0
    for i in range(M):
        Qi = Qm[i] if Qm.shape[0] > 1 else Qm[0]
        Gi = Gm[i] if Gm.shape[0] > 1 else Gm[0]
        for j in range(w):
            x[j] = X[i, j]
        for j in range(kk):
            mobs[j] = X[i, index[j]]
            m[j] = mobs[j]
        measure_row(q, x, k, c, C, D)
        active = True
        viol = 0.0
        rk = 0
        for it in range(iterations):
            for a in range(p):  # r − C q with q fixed, and c
                s = 0.0
                for j in range(kk):
                    s += D[a, j] * (m[j] - mobs[j])
                B[a, 0] = s - c[a]
                B[a, 1] = c[a]
            rk = whiten_row(D, Gi, B, eps, E, L, kept)
            viol = 0.0
            for a in range(p):
                viol += B[a, 1] ** 2
            if it == iterations - 1 or not active:
                break
            for a in range(p):
                z[a] = B[a, 0]
            correct_row(E, L, Gi, z, dm, y)
            finite = True
            for j in range(kk):
                step[j] = mobs[j] + dm[j] - m[j]
                finite = finite and np.isfinite(step[j])
            if not finite:
                for j in range(kk):
                    step[j] = 0.0
            halving_row(measure_row, q, x, index, k, m, c, C, D, step, cand)
            steps = max(steps, it + 1)
            seen = 0.0
            unseen = False
            for a in range(kk):
                da = cand[a] - m[a]
                for b in range(kk):
                    seen += da * Qi[a, b] * (cand[b] - m[b])
                unseen = unseen or abs(da) > _ROUNDING * (1.0 + abs(cand[a]))
            for j in range(kk):
                m[j] = cand[j]
            active = active and (seen > tol**2 or unseen)
        for j in range(kk):
            mt[i, j] = m[j]
        violation[i] = viol
        rank[i] = rk
    return mt, violation, rank, steps
