"""Deciding between two models fitted on the same measures (report §5, eq. 36).

``L̃'²/d' < Φ(d, d') L̃²/d``: the general model replaces the specific one when its
normalised cost is lower by the cost factor Φ (:mod:`kanagen.runtime.phi`). Both are fitted
on the measures both take as inliers, so that ``d' − d`` counts only the extra freedom, as
the F-test of appendix B presumes.
"""

from __future__ import annotations

import numpy as np

from .results import FitResult

SAME_FIT = 1e-6  # relative cost difference below which two fits are the same fit


def general_wins(specific: FitResult, general: FitResult, phi) -> bool:
    """Does ``general`` replace ``specific`` (eq. 36), strictly beyond rounding?

    A model that only drops an inequality (ellipse → conic, same ``d``) reaches the very
    same fit when the inequality is not active: it must be better by more than rounding.
    """
    if not (np.isfinite(specific.normalized_cost) and np.isfinite(general.normalized_cost)):
        return False
    factor = phi(specific.dof, general.dof)
    return bool(general.normalized_cost < factor * specific.normalized_cost * (1 - SAME_FIT))
