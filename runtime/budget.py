"""How many random samples a model's search draws (report eq. 25)."""

from __future__ import annotations

from dataclasses import dataclass

from . import lattice
from .robust import ModelSearch
from .scoring import samples_for_confidence

#: The most samples an adaptive budget grows to for one model (``samples_per_model`` when
#: given): a model that fits next to nothing of the data (a plane among matches of a 3-D
#: scene) asks eq. 25 for tens of thousands, and would leave the rest of the lattice none.
MODEL_CAP = 5000


@dataclass(frozen=True)
class SampleBudget:
    """Eq. 25 for each model's search.

    ``adaptive`` (the default): eq. 25 at the inlier ratio of the search's best estimate so
    far (:meth:`~kanagen.runtime.robust.ModelSearch.samples_needed`), updated as samples
    come — fewer samples than the assumed ratio's on easy data, more on hard data, as
    adaptive RANSAC draws — at least ``min_samples``, at most ``samples_per_model``
    (default :data:`MODEL_CAP`; the caller's sample and time budgets bound the whole
    search). Before the first
    estimate, and while no sample can be all inliers, it plans eq. 25 at ``inlier_ratio``
    (:meth:`initial`). The ratio planned for is at least :meth:`floor`: a structure smaller
    than that would not matter.

    Not adaptive: eq. 25 at the assumed ``inlier_ratio``, or exactly ``samples_per_model``
    (the behaviour before budgets adapted)."""

    samples_per_model: int | None = None
    confidence: float = 0.99
    inlier_ratio: float = 0.5
    adaptive: bool = True
    min_samples: int = 20

    def initial(self, search: ModelSearch, parent_inliers: int | None = None) -> int:
        """Samples for ``search`` before any estimate (not adaptive: its budget).
        ``parent_inliers``: the inliers of a parent with more equations per measure: its
        child wins only by explaining a fifth more measures
        (:func:`~kanagen.runtime.lattice.explains_more`), so its extra measures must be at
        least that share of the parent's outliers it samples, and eq. 25 is taken at that
        inlier ratio when it is higher — enough samples to find any estimate that could win.
        """
        if self.samples_per_model is not None:
            return self.samples_per_model
        draws = search.draws
        if parent_inliers is not None:
            needed = (lattice.MORE_SUPPORT - 1) * parent_inliers / max(draws.pool.size, 1)
            return samples_for_confidence(self.confidence,
                                          min(1.0, max(needed, self.inlier_ratio)),
                                          draws.sample_size)
        return samples_for_confidence(self.confidence, self.inlier_ratio, draws.size)

    @staticmethod
    def floor(search: ModelSearch, need: float = 0) -> tuple[float, float, float]:
        """The least inlier ratios of the sampled pool, of the base (a child's samples
        among its parent's inliers) and of the whole channel an adaptive budget plans for:
        a structure with fewer does not matter, and the plan need not be sure to find one.

        ``need``: the inliers of the sampled channel a structure must explain to matter —
        to be chosen at all (a :data:`~kanagen.runtime.lattice.MORE_SUPPORT` th of the most
        any model explains so far, :func:`~kanagen.runtime.lattice.select`) and, for a
        child, to replace its parent (:func:`~kanagen.runtime.lattice.support_needed`).

        A search from scratch: at least :data:`~kanagen.runtime.lattice.RELEVANT` of the
        pool (a structure explaining fewer measures is no base of the lattice). A child
        drawing its extra measures among its parent's outliers: a fifth of its parent's
        inliers among them — a child that explains fewer extra measures wins only on its
        fit of the parent's inliers, which the parent's estimate refined in the child's
        model tries (:meth:`~kanagen.runtime.schedule.Scheduler._from_parent`) — and of the
        base, what ``need`` asks for beyond the whole pool: a child that explains little of
        its parent's inliers cannot replace it, however few its best sample explains."""
        draws = search.draws
        pool = max(draws.pool.size, 1)
        share = min(1.0, need / max(search.problem.channels[search.channel].size, 1))
        if draws.base is None or not draws.pool.size:
            return min(1.0, max(lattice.RELEVANT, need / pool)), 0.0, share
        base = max(draws.base.size, 1)
        extra = (lattice.MORE_SUPPORT - 1) * draws.base.size / pool
        return (min(1.0, max(extra, lattice.RELEVANT, (need - draws.base.size) / pool)),
                min(1.0, max(0.0, (need - draws.pool.size) / base)), share)

    def now(self, search: ModelSearch, budget: int, cap: int | None = None,
            need: float = 0) -> int:
        """The samples the search plans in all now. Adaptive: eq. 25 at its best estimate's
        inlier ratio (``budget`` while it has none), at least ``min_samples``, at most
        ``cap`` (``budget`` for a resumed search or a model with nothing to sample) and
        ``samples_per_model`` (default :data:`MODEL_CAP`)."""
        if not self.adaptive:
            return budget
        needed = search.samples_needed(self.confidence, self.floor(search, need))
        plan = budget if needed is None else needed
        for bound in (cap, self.samples_per_model or MODEL_CAP):
            if bound is not None:
                plan = min(plan, bound)
        least = min(self.min_samples, budget, cap if cap is not None else budget)
        return max(plan, least, 1)

    def limit(self, search: ModelSearch, budget: int, batch: int,
              cap: int | None = None, need: float = 0) -> int:
        """Samples the next step may draw (at least one): the batch, within the plan — which
        changes only with a better estimate, and that ends a batch."""
        return max(min(batch, self.now(search, budget, cap, need) - search.samples), 1)
