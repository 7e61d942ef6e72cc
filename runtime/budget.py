"""How many random samples a model's search draws (report eq. 25)."""

from __future__ import annotations

from dataclasses import dataclass

from . import lattice
from .robust import ModelSearch
from .scoring import samples_for_confidence


@dataclass(frozen=True)
class SampleBudget:
    """Eq. 25 at an assumed inlier ratio (or ``samples_per_model``), lowered — ``adaptive``,
    after ``min_samples`` samples — by eq. 25 at the inlier ratio of the search's best
    estimate so far (:meth:`~kanagen.runtime.robust.ModelSearch.samples_needed`)."""

    samples_per_model: int | None = None
    confidence: float = 0.99
    inlier_ratio: float = 0.5
    adaptive: bool = False
    min_samples: int = 20

    def initial(self, search: ModelSearch, parent_inliers: int | None = None) -> int:
        """Samples for ``search``. ``parent_inliers``: the inliers of a parent with more
        equations per measure: its child wins only by explaining a fifth more measures
        (:func:`~kanagen.runtime.lattice.explains_more`), so its extra measures must be at
        least that share of the parent's outliers it samples, and eq. 25 is taken at that
        inlier ratio when it is higher — enough samples to find any estimate that could win.
        """
        if self.samples_per_model is not None:
            return self.samples_per_model
        if parent_inliers is not None:
            needed = (lattice.MORE_SUPPORT - 1) * parent_inliers / max(search.pool.size, 1)
            return samples_for_confidence(self.confidence,
                                          min(1.0, max(needed, self.inlier_ratio)),
                                          search.sample_size)
        return samples_for_confidence(self.confidence, self.inlier_ratio,
                                      search.sample_size + search.base_size)

    def now(self, search: ModelSearch, budget: int) -> int:
        """The search's budget, lowered by eq. 25 at its best estimate so far (adaptive)."""
        if self.adaptive and search.samples >= self.min_samples:
            needed = search.samples_needed(self.confidence)
            return min(budget, needed) if needed is not None else budget
        return budget

    def limit(self, search: ModelSearch, budget: int, batch: int) -> int:
        """Samples the next step may draw (at least one): the batch, within the budget left
        — eq. 25's adaptive bound changes only with a better estimate, which ends a batch —
        and, adaptive, up to ``min_samples`` first."""
        limit = min(batch, self.now(search, budget) - search.samples)
        if self.adaptive and search.samples < self.min_samples:
            limit = min(limit, self.min_samples - search.samples)
        return max(limit, 1)
