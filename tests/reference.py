"""Independent dense references for the constrained estimation problem (report §2, eq. 2-3).

Nothing here imports kanagen. The problem is

    minimise  L² = ½(q−q0)ᵀQ0(q−q0) + Σ_i ½(m̃_i−m_i)ᵀQ_i(m̃_i−m_i)
    subject to c0(q) = 0 and c(q, m̃_i) = 0 for every measure i of every channel,

with the equations given as callables returning values and exact Jacobians, in the calling
convention of the generated functions: ``c0(q) -> (c0 (p,), C0 (p, n))`` and
``ci(q, m) -> (c (M, p_i), C (M, p_i, n), D (M, p_i, k))`` vectorised over measures, where ``m``
holds the ``k`` corrected components only.

Unlike the projector of the report (appendix A) these solvers work on the FULL unknown
``x = (q, m̃_1 .. m̃_M)`` with the big dense KKT matrix, so they cost O((n + Σk)³) and are meant
for small test problems only.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla
from scipy.optimize import minimize

#: Relative singular-value cut (per row of the KKT matrix) for rank decisions in ``lstsq``.
_RCOND = 10 * np.finfo(float).eps

C0Func = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
CiFunc = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class ReferenceResult:
    """Solution of the dense reference solvers.

    ``measures`` holds one corrected array (M, k) per channel, in the order given; ``cost`` is
    L² with the ½; ``c_inf`` = ‖c(x)‖∞ over all equations; ``stationarity`` = ‖Zᵀ Q (x − x0)‖∞
    with Z an orthonormal basis of the tangent space ker J(x); ``covariance`` is the q block of
    the pseudo-inverse of the full KKT matrix at the solution; ``info`` is Q̃ = Q0 + A at the
    solution (report eq. 6), both computed densely.
    """

    q: np.ndarray
    measures: list[np.ndarray]
    cost: float
    c_inf: float
    stationarity: float
    iterations: int
    converged: bool
    covariance: np.ndarray
    info: np.ndarray

    @property
    def m(self) -> np.ndarray:
        """Corrected measures of the first channel."""
        return self.measures[0]


@dataclass(frozen=True)
class _Channel:
    ci: CiFunc
    m: np.ndarray  # (M, k)
    Q: np.ndarray  # (M, k, k)


def info_blocks(Qi: object, M: int, k: int) -> np.ndarray:
    """Expand per-channel information to (M, k, k): None, scalar, (M,), (k,k) or (M,k,k)."""
    if Qi is None:
        return np.broadcast_to(np.eye(k), (M, k, k)).copy()
    Q = np.asarray(Qi, dtype=float)
    if Q.ndim == 0:
        return float(Q) * np.broadcast_to(np.eye(k), (M, k, k)).copy()
    if Q.ndim == 1 and Q.shape == (M,):
        return Q[:, None, None] * np.eye(k)
    if Q.ndim == 2 and Q.shape == (k, k):
        return np.broadcast_to(Q, (M, k, k)).copy()
    if Q.shape == (M, k, k):
        return Q.copy()
    raise ValueError(f"information of shape {Q.shape} does not fit M={M}, k={k}")


def _channels(
    ci: CiFunc | Sequence[CiFunc] | None,
    m: np.ndarray | Sequence[np.ndarray] | None,
    Qi: object,
) -> list[_Channel]:
    if ci is None:
        return []
    if callable(ci):
        ci, m, Qi = [ci], [m], [Qi]
    if m is None or len(ci) != len(m):
        raise ValueError("one data array per channel is required")
    Qs = list(Qi) if isinstance(Qi, list | tuple) else [Qi] * len(ci)
    out = []
    for f, mm, QQ in zip(ci, m, Qs, strict=True):
        mm = np.atleast_2d(np.asarray(mm, dtype=float))
        out.append(_Channel(f, mm, info_blocks(QQ, *mm.shape)))
    return out


class _Problem:
    """The stacked problem in the full unknown x = (q, m̃ of each channel, flattened)."""

    def __init__(self, c0: C0Func | None, channels: list[_Channel], q0: np.ndarray, Q0):
        self.c0 = c0
        self.channels = channels
        self.q0 = np.asarray(q0, dtype=float).ravel()
        self.n = self.q0.size
        self.Q0 = np.zeros((self.n, self.n)) if Q0 is None else _as_matrix(Q0, self.n)
        self.sizes = [ch.m.size for ch in channels]
        self.N = self.n + sum(self.sizes)
        self.x0 = np.concatenate([self.q0] + [ch.m.ravel() for ch in channels])
        self.Q = sla.block_diag(self.Q0, *[sla.block_diag(*ch.Q) for ch in channels])

    def split(self, x: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
        q, out, pos = x[: self.n], [], self.n
        for ch, size in zip(self.channels, self.sizes, strict=True):
            out.append(x[pos : pos + size].reshape(ch.m.shape))
            pos += size
        return q, out

    def equations(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """All equation values c(x) and their Jacobian J (rows: c0, then measure by measure)."""
        q, ms = self.split(x)
        values, rows = [], []
        if self.c0 is not None:
            c, C = self.c0(q)
            c = np.atleast_1d(np.asarray(c, dtype=float))
            C = np.asarray(C, dtype=float).reshape(c.size, self.n)
            values.append(c)
            rows.append(np.hstack([C, np.zeros((c.size, self.N - self.n))]))
        pos = self.n
        for ch, mt in zip(self.channels, ms, strict=True):
            c, C, D = (np.asarray(a, dtype=float) for a in ch.ci(q, mt))
            M, k = mt.shape
            c = c.reshape(M, -1)
            pi = c.shape[1]
            C = C.reshape(M, pi, self.n)
            D = D.reshape(M, pi, k)
            J = np.zeros((M * pi, self.N))
            for i in range(M):
                J[i * pi : (i + 1) * pi, : self.n] = C[i]
                J[i * pi : (i + 1) * pi, pos + i * k : pos + (i + 1) * k] = D[i]
            values.append(c.ravel())
            rows.append(J)
            pos += M * k
        if not values:
            return np.zeros(0), np.zeros((0, self.N))
        return np.concatenate(values), np.vstack(rows)

    def cost(self, x: np.ndarray) -> float:
        r = x - self.x0
        return 0.5 * float(r @ self.Q @ r)

    def merit(self, x: np.ndarray, mu: float) -> float:
        """The ℓ1 merit function L² + μ‖c‖₁ used to damp far-away steps."""
        return self.cost(x) + mu * float(np.sum(np.abs(self.equations(x)[0])))

    def kkt(self, J: np.ndarray) -> np.ndarray:
        P = J.shape[0]
        return np.block([[self.Q, J.T], [J, np.zeros((P, P))]])

    def result(self, x: np.ndarray, iterations: int, converged: bool) -> ReferenceResult:
        c, J = self.equations(x)
        g = self.Q @ (x - self.x0)
        Z = sla.null_space(J) if J.shape[0] else np.eye(self.N)
        stationarity = float(np.max(np.abs(Z.T @ g), initial=0.0))
        covariance = sla.pinv(self.kkt(J))[: self.n, : self.n]
        q, ms = self.split(x)
        return ReferenceResult(
            q=q.copy(),
            measures=[mm.copy() for mm in ms],
            cost=self.cost(x),
            c_inf=float(np.max(np.abs(c), initial=0.0)),
            stationarity=stationarity,
            iterations=iterations,
            converged=converged,
            covariance=0.5 * (covariance + covariance.T),
            info=information_matrix([(ch.ci, ch.Q) for ch in self.channels], q, ms, self.Q0),
        )


def _as_matrix(Q0: object, n: int) -> np.ndarray:
    Q = np.asarray(Q0, dtype=float)
    if Q.ndim == 0:
        return float(Q) * np.eye(n)
    if Q.ndim == 1:
        return np.diag(Q)
    return Q.reshape(n, n)


def dense_kkt_solve(
    c0: C0Func | None,
    ci: CiFunc | Sequence[CiFunc] | None,
    q0: np.ndarray,
    Q0: object = None,
    m: np.ndarray | Sequence[np.ndarray] | None = None,
    Qi: object = None,
    *,
    q_start: np.ndarray | None = None,
    max_iter: int = 300,
    tol: float = 1e-14,
    damping: bool = True,
) -> ReferenceResult:
    """Gauss–Newton SQP on the full unknown with the dense KKT matrix (method A).

    Each step solves ``[[Q, Jᵀ], [J, 0]] [dx; λ] = [−Q (x − x0); −c(x)]`` by ``lstsq`` (minimum
    norm, so rank-deficient equations or semi-definite Q are fine). Far from the solution a
    step is halved until the ℓ1 merit ``L² + μ‖c‖₁`` decreases (Armijo); near it full steps
    are taken. Stops when ``‖dx‖∞ < tol (1 + ‖x‖∞)``, or when the step stagnates at rounding
    level. ``ci``, ``m`` and ``Qi`` may be lists (one entry per channel); ``Qi`` per channel is
    None, a scalar, (k,k), (M,) or (M,k,k). ``q_start`` defaults to ``q0``; measures start
    at the data.

    Examples
    --------
    >>> import numpy as np
    >>> ci = lambda q, m: (m - q, -np.ones((len(m), 1, 1)), np.ones((len(m), 1, 1)))
    >>> res = dense_kkt_solve(None, ci, np.zeros(1), 0.0, np.array([[1.0], [3.0]]))
    >>> round(float(res.q[0]), 12), round(res.cost, 12)
    (2.0, 1.0)
    """
    prob = _Problem(c0, _channels(ci, m, Qi), q0, Q0)
    x = prob.x0.copy()
    if q_start is not None:
        x[: prob.n] = np.asarray(q_start, dtype=float).ravel()
    mu, best_step, stalled, converged, iterations = 1.0, np.inf, 0, False, 0
    while iterations < max_iter:
        iterations += 1
        c, J = prob.equations(x)
        P = c.size
        rhs = np.concatenate([-prob.Q @ (x - prob.x0), -c])
        K = prob.kkt(J)
        sol = sla.lstsq(K, rhs, cond=_RCOND * K.shape[0], lapack_driver="gelsd")[0]
        dx, lam = sol[: prob.N], sol[prob.N :]
        scale = 1.0 + np.max(np.abs(x))
        step_norm = float(np.max(np.abs(dx), initial=0.0))
        alpha = 1.0
        if damping and step_norm > 1e-6 * scale and P:
            mu = max(mu, 2.0 * float(np.max(np.abs(lam))) + 1.0)
            phi = prob.merit(x, mu)
            slope = float(prob.Q @ (x - prob.x0) @ dx) - mu * float(np.sum(np.abs(c)))
            while alpha > 1e-6 and prob.merit(x + alpha * dx, mu) > phi + 1e-4 * alpha * slope:
                alpha *= 0.5
        x = x + alpha * dx
        if alpha == 1.0 and step_norm <= tol * scale:
            converged = True
            break
        if step_norm < best_step * 0.5:
            best_step, stalled = step_norm, 0
        else:
            stalled += 1
            if stalled >= 4 and step_norm < 1e-9 * scale:
                converged = True
                break
    return prob.result(x, iterations, converged)


def slsqp_solve(
    c0: C0Func | None,
    ci: CiFunc | Sequence[CiFunc] | None,
    q0: np.ndarray,
    Q0: object = None,
    m: np.ndarray | Sequence[np.ndarray] | None = None,
    Qi: object = None,
    *,
    q_start: np.ndarray | None = None,
    m_start: Sequence[np.ndarray] | None = None,
    method: str = "SLSQP",
    tol: float = 1e-12,
    max_iter: int = 1000,
) -> ReferenceResult:
    """The same problem by ``scipy.optimize.minimize`` (method B: "SLSQP" or "trust-constr"),
    from ``q_start`` (default ``q0``) and the corrected measures ``m_start``, one array per
    channel (default the data).

    Only for small problems; its accuracy is the optimiser's (about 1e-8), not the KKT solve's.
    """
    prob = _Problem(c0, _channels(ci, m, Qi), q0, Q0)
    x_start = prob.x0.copy()
    if q_start is not None:
        x_start[: prob.n] = np.asarray(q_start, dtype=float).ravel()
    if m_start is not None:
        x_start[prob.n:] = np.concatenate([np.asarray(mt, dtype=float).ravel()
                                           for mt in m_start])

    def fun(x: np.ndarray) -> float:
        return prob.cost(x)

    def jac(x: np.ndarray) -> np.ndarray:
        return prob.Q @ (x - prob.x0)

    constraints = []
    if prob.equations(x_start)[0].size:
        constraints.append(
            {
                "type": "eq",
                "fun": lambda x: prob.equations(x)[0],
                "jac": lambda x: prob.equations(x)[1],
            }
        )
    if method == "trust-constr":
        from scipy.optimize import NonlinearConstraint

        cons = [
            NonlinearConstraint(c["fun"], 0.0, 0.0, jac=c["jac"], hess=_zero_hess(prob.N))
            for c in constraints
        ]
        out = minimize(
            fun,
            x_start,
            jac=jac,
            hess=lambda x: prob.Q,
            method="trust-constr",
            constraints=cons,
            options={"xtol": tol, "gtol": tol, "maxiter": max_iter},
        )
    else:
        out = minimize(
            fun,
            x_start,
            jac=jac,
            method=method,
            constraints=constraints,
            options={"ftol": tol, "maxiter": max_iter},
        )
    return prob.result(np.asarray(out.x, dtype=float), int(out.nit), bool(out.success))


def _zero_hess(N: int) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    # trust-constr needs the constraint Hessian; the exact one is not available here, so the
    # Gauss–Newton (zero) approximation is used, as in the projector.
    return lambda x, v: np.zeros((N, N))


def information_matrix(
    channels: Sequence[tuple[CiFunc, np.ndarray]],
    q: np.ndarray,
    measures: Sequence[np.ndarray],
    Q0: np.ndarray,
) -> np.ndarray:
    """Q̃ = Q0 + Σ C_iᵀ W_i C_i at (q, m̃) (report eq. 6), dense, per measure.

    ``channels`` lists ``(ci, Q)`` with Q of shape (M, k, k). ``W_i`` is minus the λ block of
    ``pinv([[Q_i, D_iᵀ], [D_i, 0]])``: it equals ``(D_i Q_i⁻¹ D_iᵀ)⁻¹`` when that exists and
    is the correct limit for semi-definite ``Q_i`` and redundant or vanishing equations.
    """
    n = q.size
    info = np.array(Q0, dtype=float, copy=True).reshape(n, n)
    for (ci, Q), mt in zip(channels, measures, strict=True):
        c, C, D = (np.asarray(a, dtype=float) for a in ci(q, mt))
        M, k = mt.shape
        pi = c.reshape(M, -1).shape[1]
        C = C.reshape(M, pi, n)
        D = D.reshape(M, pi, k)
        for i in range(M):
            K = np.block([[Q[i], D[i].T], [D[i], np.zeros((pi, pi))]])
            W = -sla.pinv(K)[k:, k:]
            info += C[i].T @ W @ C[i]
    return 0.5 * (info + info.T)


def constrained_covariance(Qtilde: np.ndarray, C0: np.ndarray | None) -> np.ndarray:
    """Top-left n×n block of ``pinv([[Q̃, C0ᵀ], [C0, 0]])``, the covariance under ``C0 q = 0``.

    Examples
    --------
    >>> import numpy as np
    >>> constrained_covariance(np.eye(2), np.array([[1.0, 0.0]])).round(12)
    array([[0., 0.],
           [0., 1.]])
    """
    Qt = np.asarray(Qtilde, dtype=float)
    n = Qt.shape[0]
    C = np.zeros((0, n)) if C0 is None else np.asarray(C0, dtype=float).reshape(-1, n)
    p = C.shape[0]
    K = np.block([[Qt, C.T], [C, np.zeros((p, p))]])
    cov = sla.pinv(K)[:n, :n]
    return 0.5 * (cov + cov.T)
