"""Deciding between two models (report §5, eq. 36, appendix B).

Two figures compare models fitted to the same measures:

* **support** — the relevance (eq. 29) over that of a perfect inlier population of the
  model's equations, so that models with different numbers of equations per measure compare
  (a homography's errors ``χ²₂/2`` and a fundamental matrix's ``χ²₁`` score differently for
  the same inliers): about the fraction of the measures the model explains;
* **cost** — ``L̃²/d`` against ``Φ(d, d')`` (eq. 36) once both models are refitted on the
  measures both take as inliers; where the general model has fewer equations per measure
  (``d' <= d``: the report's factors presume ``d' > d``) the extra-sum-of-squares F-test on
  residual degrees of freedom decides (eq. 51, :func:`~kanagen.runtime.phi.extra_sum_of_squares`).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy import stats

from .phi import extra_sum_of_squares
from .results import FitResult

_QUANTILES = 4001  # inlier errors drawn as quantiles: a deterministic expectation
SAME_FIT = 1e-6  # relative cost difference below which two fits are the same fit


@lru_cache(maxsize=256)
def _inlier_quantiles(rank: int) -> np.ndarray:
    u = (np.arange(_QUANTILES) + 0.5) / _QUANTILES
    return stats.chi2.ppf(u, rank) / rank  # e = χ²_p / p for an inlier (eq. 24)


def inlier_score(score_fn, scale: float, rank: int) -> float:
    """The score of a population of inliers whose equations have rank ``rank``."""
    return float(score_fn(_inlier_quantiles(max(int(rank), 1)), scale))


def support(relevance: float, score_fn, scale: float, rank: int) -> float:
    """Relevance relative to a perfect inlier population of the model's equations (a
    scorer whose inlier score is not positive — trimmed — is left as it is)."""
    perfect = inlier_score(score_fn, scale, rank)
    return float(relevance / perfect) if perfect > 0 else float(relevance)


def residual_dof(fit: FitResult, free: int) -> int:
    """``Σ p_i − (n − p)``: the equations left over by the free degrees of freedom
    (``d = n − p + Σ p_i``, report eq. 7)."""
    return fit.dof - 2 * free


def general_wins(specific: FitResult, general: FitResult, phi, free: tuple[int, int],
                 ) -> bool:
    """Does ``general`` replace ``specific``, both fitted on the same measures?

    ``L̃'²/d' < Φ(d, d') L̃²/d`` (eq. 36), strictly beyond rounding; ``phi`` carrying
    ``residual = True`` (and any ``phi`` when ``d' <= d``) compares residual degrees of
    freedom instead (``free``: the free degrees of freedom of the two models).
    """
    if not (np.isfinite(specific.normalized_cost) and np.isfinite(general.normalized_cost)):
        return False
    d, d_general = specific.dof, general.dof
    if getattr(phi, "residual", False) or d_general <= d:
        if not getattr(phi, "residual", False):
            phi = extra_sum_of_squares()
        d, d_general = residual_dof(specific, free[0]), residual_dof(general, free[1])
        if d <= 0 or d_general <= 0:
            return False
    factor = phi(d, d_general)
    # strictly better, beyond rounding: a model that only drops an inequality (ellipse ->
    # conic, same d) reaches the very same fit when the inequality is not active
    return bool(general.cost / d_general < factor * specific.cost / d * (1 - SAME_FIT))
