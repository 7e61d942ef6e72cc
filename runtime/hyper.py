"""Below the ML error: the second-order bias of the estimate and its removal — Kanatani's
hyperaccurate correction (Kanatani 2006, "Ellipse fitting with hyperaccuracy"), derived for
any spec (docs/equations.md, "Hyperaccurate correction").

The ML estimate ``q̂`` is a function of the measures, ``q̂ = Φ(m)``. With noise ``ε_i`` of
covariance ``V_i = σ² Q_i⁻¹`` on each measure, independent between measures, its expansion
about the true measures ``m̄`` is ``q̂ = q̄ + Φ' ε + ½ Φ''[ε, ε] + O(σ³)``: the first-order
term has zero mean (the KCR-attaining error), the second-order one does not — the bias

    b = E[q̂] − q̄ = ½ Σ_i tr(V_i ∂²Φ/∂m_i²) + O(σ⁴)
      = ½ Σ_i Σ_u (Φ(m̄ + d_iu) + Φ(m̄ − d_iu) − 2 Φ(m̄)) + O(σ⁴),

``d_iu = √λ_iu u_iu`` along the eigenvectors of ``V_i`` (one standard deviation each:
the central second difference of ``Φ`` is its second derivative times ``λ``, to fourth
order). Kanatani's idea is to evaluate it at the estimate instead of the truth: ``(q̂, m̃)``
— the estimate and the corrected measures, which satisfy the equations exactly — is a
noise-free configuration of the model, and its bias differs from the true one by ``O(σ³)``.
So ``b̂`` comes from ``2 Σ_i k_i`` fits of noise-free data with one measure moved by one
standard deviation along one direction (each from ``q̂``: a few iterations), and the
corrected estimate is ``q̂ − b̂`` moved along the tangent space of the parameter's
constraints and back onto them. Its residual bias is ``O(σ³)``; its covariance is the ML
one to first order. A derived quantity ``g(q)`` has a bias of its own (the curvature of
``g`` adds ``½ tr(∇²g Σ)``): it is corrected by the same second differences of ``g``,
``ĝ − b̂_g``, not evaluated at ``q̂ − b̂``.

Where it vanishes: an estimate linear in the measures (an explicit model linear in its
parameter, the abscissas exact) has ``Φ'' = 0``: the correction is zero to rounding.
``σ²``: 1 with the information as given (``info = 1/σ²``: absolute); when the information
is only relative, the reduced χ² of the fit (Kanatani's ``σ̂² = J/(N − n)``).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .projector import Problem, evaluate, linearise, restore_parameter, solve
from .restoration import restore_measures
from .results import derived_values

#: Projector steps of each perturbed fit (from the estimate, one measure moved by one σ:
#: Newton's quadratic convergence, report §3.6 — the move is ~1e-3 of q, its second-order
#: part ~1e-6: three steps leave ~1e-12).
_REFIT_STEPS = 4


def bias(fam, model: str, problem: Problem, q: np.ndarray, mt: tuple[np.ndarray, ...],
         sigma2: float = 1.0, derived: bool = False):
    """``b̂``: the second-order bias of the ML estimate of ``problem`` (its information) at
    the noise-free configuration ``(q, mt)`` (the estimate and its corrected measures),
    with the information scaled by ``1/sigma2``. Measures known exactly (``exact=``) carry
    no noise. ``derived``: also the bias of each derived quantity of the family
    (``{name: array}``, the same second differences of the quantity — not its Jacobian
    times ``b̂``: a nonlinear function of the estimate has a bias of its own), returned as
    ``(b̂, biases)``."""
    values = (lambda x: {name: np.asarray(v, dtype=float)
                         for name, (v, _) in fam.derived(x, problem.k).items()}) \
        if derived else None
    at = values(q) if derived else {}
    derived_total = {name: np.zeros_like(v) for name, v in at.items()}
    clean = tuple(replace(ch, X=ch.with_corrected(m), m=m.copy())
                  for ch, m in zip(problem.channels, mt, strict=True))
    base = replace(problem, channels=clean)
    total = np.zeros_like(q)
    for c, ch in enumerate(clean):
        for i in range(ch.size):
            V = np.linalg.pinv(ch.Q[i] if ch.Q.ndim == 3 else ch.Q) * sigma2
            if ch.fixed is not None:  # exact components (a boolean mask): no noise
                free = ~ch.fixed[i]
                V = V * np.outer(free, free)
            lam, U = np.linalg.eigh(0.5 * (V + V.T))
            for value, u in zip(lam, U.T, strict=True):
                if not value > 1e-14 * max(float(lam.max()), 1e-300):
                    continue
                step = np.sqrt(value) * u
                moved = []
                for sign in (1.0, -1.0):
                    m = ch.m.copy()
                    m[i] += sign * step
                    X = ch.X.copy()
                    X[i, ch.index] = m[i]
                    channels = list(clean)
                    channels[c] = replace(ch, X=X, m=m)
                    moved.append(_refit(replace(base, channels=tuple(channels)), q))
                total += 0.5 * (moved[0] + moved[1] - 2.0 * q)
                if derived:
                    plus, minus = values(moved[0]), values(moved[1])
                    for name in derived_total:
                        derived_total[name] += 0.5 * (plus[name] + minus[name] - 2 * at[name])
    return (total, derived_total) if derived else total


def _refit(problem: Problem, q: np.ndarray) -> np.ndarray:
    """The ML estimate of ``problem`` from ``q`` next to it: the report's projector steps
    ``x ← P(x)`` (a Newton iteration on the KKT conditions there), from the measures as
    observed."""
    x = evaluate(problem, q, tuple(ch.m for ch in problem.channels))
    for _ in range(_REFIT_STEPS):
        proj = solve(problem, linearise(problem, x))
        x = evaluate(problem, proj.q, proj.mt)
    return x.q


def corrected(fam, model: str, problem: Problem, result, relative: bool = False):
    """The hyperaccurate estimate of an ML ``result`` of ``problem`` (a
    :class:`~kanagen.runtime.results.FitResult`): ``q̂ − b̂`` in the tangent space of the
    parameter's constraints, moved back onto them, its measures projected onto the
    equations there, its derived values at it; ``bias`` holds ``b̂`` (the full vector),
    the covariance stays the ML one. ``relative``: the information is only relative, σ²
    is the fit's reduced χ². A result whose ML fit failed is returned as it is."""
    if not result.success:
        return result
    sigma2 = float(result.reduced_chi2) if relative else 1.0
    if not np.isfinite(sigma2) or sigma2 <= 0.0:
        return result
    mt = tuple(np.asarray(result.measures[ch.name], dtype=float)[:, ch.index]
               for ch in problem.channels)
    with np.errstate(all="ignore"):
        b, b_derived = bias(fam, model, problem, result.q, mt, sigma2, derived=True)
        c0, C0 = problem.c0(result.q, problem.k)
        step = b
        if c0.size:  # along the constraints' tangent space, then back onto them
            _, S, Vt = np.linalg.svd(C0)
            rank = int(np.count_nonzero(S > 1e-10 * S[0])) if S.size and S[0] > 0 else 0
            N = Vt[rank:].T
            step = N @ (N.T @ b)
        q = restore_parameter(problem, result.q - step, None, 8)
        x, _ = restore_measures(problem, q, mt)
    if not (np.all(np.isfinite(q)) and x.finite):
        return result
    measures = {ch.name: ch.with_corrected(m) for ch, m in zip(problem.channels, x.mt,
                                                                 strict=True)}
    # each derived quantity less its own bias (at the corrected q, its covariance)
    derived = {name: replace(value, value=np.asarray(result.derived[name].value) -
                             b_derived[name].reshape(np.shape(result.derived[name].value)))
               if name in result.derived and name in b_derived and
               np.all(np.isfinite(b_derived[name])) else value
               for name, value in derived_values(fam, q, result.covariance, problem.k,
                                                 model).items()}
    return replace(result, q=q.copy(), params=fam.params_dict(q), measures=measures,
                   cost=x.cost, constraint_violation=x.delta, derived=derived,
                   slacks=fam.slack_dict(q), bias=b,
                   message=result.message + "; bias-corrected (hyperaccurate)")
