"""The minimal solve of random sampling (report eq. 21) in NumPy, vectorised over the
measures: an independent reference for the engine's
:func:`kanagen.runtime.engine.sample.minimal_solve` (the same method: Gauss–Newton steps to
the nearest point of the linearised equations from ``np.linalg.svd``, equations scaled to
parameter units, a watchdog then a line search), evaluated through the problem's NumPy
functions (``problem.c0``, ``problem.measures``), not the engine's row kernels."""

from __future__ import annotations

import numpy as np

FREE_STEPS, WATCHDOG, SLOW = 3, 1e8, 4


def solved(delta: float, q: np.ndarray) -> bool:
    return bool(np.isfinite(delta) and delta <= 1e-8 * (1 + np.max(np.abs(q))))


def minimal_solve(problem, target: np.ndarray, max_iter: int = 50, xtol: float = 1e-12,
                  eps: float = np.finfo(float).eps):
    """``(q, success, rank, iterations, violation)`` of the sample ``problem``."""
    def equations(q):
        c0, C0 = problem.c0(q, problem.k)
        cs, Js = [c0], [C0]
        for fn, ch in zip(problem.measures, problem.channels, strict=True):
            c, C, _ = fn(q, ch.X, problem.k)
            cs.append(c.reshape(-1))
            Js.append(C.reshape(-1, q.size))
        return np.concatenate(cs), np.concatenate(Js)

    def scaled(q, raw=None):
        c, J = equations(q) if raw is None else raw
        return w * c, w[:, None] * J, float(np.max(np.abs(w * c), initial=0.0))

    q, rank = target.copy(), 0
    with np.errstate(all="ignore"):
        raw = equations(q)
        norms = np.linalg.norm(raw[1], axis=1)
        w = np.where(np.isfinite(norms) & (norms > 0), 1.0 / norms, 1.0)
        c, J, delta = scaled(q, raw)
        best, free, slow = (delta, q, c, J), FREE_STEPS, 0
        for it in range(1, max_iter + 1):
            try:
                U, S, Vt = np.linalg.svd(J, full_matrices=False)
            except np.linalg.LinAlgError:
                return q, False, rank, it, delta
            kept = S > np.sqrt(eps) * S[0] if S.size and S[0] > 0 else np.zeros(S.size, bool)
            rank = int(kept.sum())
            V = Vt[kept].T
            r = target - q
            step = r - V @ (V.T @ r + (U[:, kept].T @ c) / S[kept])
            if not np.all(np.isfinite(step)):
                return q, False, rank, it, delta
            trial = q + step
            c_new, J_new, d_new = scaled(trial)
            if free > 0 and np.isfinite(d_new) and d_new < WATCHDOG * (1 + best[0]):
                free -= d_new >= delta
                moved = np.max(np.abs(step), initial=0.0)
            else:
                if delta > best[0]:
                    delta, q, c, J = best
                    free = 0
                    continue
                free = 0
                alpha = 1.0
                while alpha > 2.0**-30:
                    trial = q + alpha * step
                    c_new, J_new, d_new = scaled(trial)
                    if np.isfinite(d_new) and d_new < delta + 1e-12 * (1 + delta):
                        break
                    alpha /= 2
                else:
                    return q, solved(delta, q), rank, it, delta
                moved = np.max(np.abs(alpha * step), initial=0.0)
            slow = slow + 1 if free == 0 and d_new > 0.9 * delta else 0
            q, c, J, delta = trial, c_new, J_new, d_new
            if delta < best[0]:
                best = (delta, q, c, J)
            if slow >= SLOW:
                return q, solved(delta, q), rank, it, delta
            if moved <= xtol * (1 + np.max(np.abs(q))) or solved(delta, q) and \
                    moved <= 1e-8 * (1 + np.max(np.abs(q))):
                return q, solved(delta, q), rank, it, delta
    return q, solved(delta, q), rank, max_iter, delta


def errors_at_observed(problem, q: np.ndarray, caps) -> tuple[np.ndarray, ...]:
    """Per channel, each measure's error at one projection step (eq. 24 where it was
    observed): ``cᵀ (D Q⁺ Dᵀ)⁻ c`` over the independent equations, at most ``caps``, by an
    eigendecomposition (rank: eigenvalues above ``√ε`` of the largest)."""
    out = []
    for fn, ch, cap in zip(problem.measures, problem.channels, caps, strict=True):
        c, _, D = fn(q, ch.X, problem.k)
        errors = np.empty(ch.size)
        for i in range(ch.size):
            Qp = np.linalg.pinv(ch.Q[i] if ch.Q.ndim == 3 else ch.Q)
            S = D[i] @ Qp @ D[i].T
            vals, vecs = np.linalg.eigh(S)
            keep = vals > 1e-8 * max(vals.max(), 0.0)
            z = vecs[:, keep].T @ c[i]
            err = float(np.sum(z**2 / vals[keep])) / max(min(int(keep.sum()), cap), 1)
            errors[i] = err if np.isfinite(err) else np.inf
        out.append(errors)
    return tuple(out)
