"""Scoring a parameter estimate by the errors of all measures (report §4).

Scorers follow scipy's ``least_squares`` shape: a dict of named choices plus "or a
callable". A scorer maps the per-measure errors ``e_j`` (eq. 24) to a number where larger is
better; ``scale`` is ``L*``, the user's order of magnitude of an inlier error (not a
threshold).
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import numpy as np

Scorer = Callable[[np.ndarray, float], float]

#: The χ² quantile of the default ``L*`` (:func:`default_scale`): an inlier's error falls
#: under ``L*`` with this probability when the information is right (``info = 1/σ²``).
SCALE_QUANTILE = 0.999


def default_scale(equations: int, quantile: float | None = None) -> float:
    """The default ``L*`` of a measure of ``equations`` independent equations (``p`` of
    eq. 24): ``χ²_p(quantile) / p``.

    An inlier's error (eq. 24) is ``‖m̃ − m‖²_Q / p``; with the right information
    (``info = 1/σ²``) ``‖m̃ − m‖²_Q`` is χ² with ``p`` degrees of freedom to first order, so
    an inlier's error falls under this ``L*`` with probability ``quantile``: 10.83 for one
    equation (a point on a conic, an epipolar constraint), 6.91 for two (a homography's
    transfer), at the default :data:`SCALE_QUANTILE` 0.999 (``quantile`` None).

    Examples
    --------
    >>> round(default_scale(1), 2), round(default_scale(2), 2)
    (10.83, 6.91)
    """
    if not (isinstance(equations, int | np.integer) and equations >= 1):
        raise ValueError(f"equations per measure must be an integer >= 1, got {equations!r}")
    quantile = SCALE_QUANTILE if quantile is None else float(quantile)
    if not 0.0 < quantile < 1.0:
        raise ValueError(f"the quantile of L* must be in (0, 1), got {quantile!r}")
    return _chi2_scale(int(equations), quantile)


@functools.lru_cache(maxsize=32)
def _chi2_scale(equations: int, quantile: float) -> float:
    from .chisquare import quantile as chi2_quantile  # lazily: import kanagen stays light

    return chi2_quantile(quantile, equations) / equations


def relevance(errors: np.ndarray, scale: float) -> float:
    """Relevance ``R = (1/M) Σ_{e_j < L*} (1 − 2 e_j / L*)`` (report eq. 29).

    Examples
    --------
    >>> relevance(np.array([0.0, 0.25, 0.5, 3.0]), 1.0)
    0.375
    """
    e = np.asarray(errors, dtype=float)
    if e.size == 0:
        return 0.0
    terms = 1.0 - 2.0 * e[e < scale] / scale
    # summed in order (an accumulation, not np.sum's pairwise sum): the engine's samples
    # (runtime/engine/sample.py: errors_at) add them in the same order, and their scores
    # are these to the last bit
    total = float(np.add.accumulate(terms)[-1]) if terms.size else 0.0
    return total / e.size


def ransac(errors: np.ndarray, scale: float) -> float:
    """Fraction of the measures with an error below ``L*`` (ransac-like, the report's S_A)."""
    e = np.asarray(errors, dtype=float)
    return float(np.count_nonzero(e < scale) / e.size) if e.size else 0.0


def trimmed(errors: np.ndarray, scale: float, quantile: float = 0.5) -> float:
    """Minus the error at a quantile (trimmed median, the report's S_B), in units of ``L*``."""
    e = np.asarray(errors, dtype=float)
    e = e[np.isfinite(e)]
    if e.size == 0:
        return -np.inf
    return -float(np.quantile(e, quantile)) / scale


#: The named scorers.
SCORERS: dict[str, Scorer] = {"relevance": relevance, "ransac": ransac, "trimmed": trimmed}


def scorer(choice: str | Scorer) -> Scorer:
    """A scorer by name (``"relevance"``, ``"ransac"``, ``"trimmed"``) or a callable
    ``f(errors, scale) -> float`` (larger is better)."""
    if callable(choice):
        return choice
    try:
        return SCORERS[choice]
    except KeyError:
        raise ValueError(f"unknown scorer {choice!r} (choose from {sorted(SCORERS)} or pass a "
                         "callable f(errors, scale) -> float)") from None


def samples_for_confidence(confidence: float, inlier_ratio: float, sample_size: int) -> int:
    """Samples needed to draw one outlier-free sample with probability ``confidence`` when a
    fraction ``inlier_ratio`` of the measures are inliers (report eq. 25).

    Examples
    --------
    >>> samples_for_confidence(0.99, 0.5, 5)
    146
    """
    if not 0 < confidence < 1 or not 0 < inlier_ratio <= 1 or sample_size < 1:
        raise ValueError("need 0 < confidence < 1, 0 < inlier_ratio <= 1, sample_size >= 1")
    good = inlier_ratio**sample_size
    if good >= 1.0:
        return 1
    return int(np.ceil(np.log1p(-confidence) / np.log1p(-good)))
