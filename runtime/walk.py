"""A search's walk through the lattice of models (report §5): the models queued and the parent
each is searched from, what each searched model became, and which one is best.

The estimator's :class:`~kanagen.runtime.schedule.Scheduler` drives it: it takes the next
model (:meth:`LatticeWalk.pop`), searches it, and hands the outcome back
(:meth:`LatticeWalk.record` or :meth:`LatticeWalk.skip`), which queues the more general models
whose parents are all settled. The decisions between two models are
:mod:`~kanagen.runtime.lattice`'s pure functions; the walk holds what they decide on.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np

from . import lattice
from .phi import phi as get_phi
from .results import FitResult, ModelState

#: ``refit(states, ids)``: each state's model fitted on the measures of ``ids`` from its
#: estimate (the cost test of eq. 36 fits both models on the measures both take as inliers)
Refit = Callable[[tuple[ModelState, ...], np.ndarray], list[FitResult]]


class LatticeWalk:
    """The lattice's bookkeeping of one search, from ``root`` (its null model, or the one
    model searched when ``single``), holding ``null`` as the root's state until it is
    searched.

    Parameters
    ----------
    fam : ModelFamily
    root : str
    null : ModelState
        The root's state before its search (the prior estimate, nothing explained).
    single : bool
        Search the root alone (no lattice).
    phi : optional
        The factor of every edge (:func:`~kanagen.runtime.phi.phi`); None: each edge's own.
    refit : callable
        See :data:`Refit`.
    """

    def __init__(self, fam, root: str, null: ModelState, single: bool, phi, refit: Refit):
        self.fam = fam
        self.root = root
        self.single = single
        self.phi = phi
        self._refit = refit
        #: every model searched (or the root's null state), by name
        self.states: dict[str, ModelState] = {root: null}
        #: (model, parent, estimate to resume from or None), searched in order
        self.queue: list[tuple[str, str | None, np.ndarray | None]] = [(root, None, None)]
        #: models never estimated (too few measures, or their search failed) -> their parent
        self.skipped: dict[str, str | None] = {}
        #: per model searched: equations per measure (sampled channel), free dof
        self.shape: dict[str, tuple[int, int]] = {}
        #: per model searched: its corrected measures per channel
        self.corrected: dict[str, dict[str, np.ndarray]] = {}
        self.reachable = {root} if single else lattice.reachable(fam, root)
        self._declared_by: dict[str, str] = {}  # model -> the model whose edge queued it
        self._selected: dict[tuple, ModelState] = {}
        self._relevance: float | None = None  # best_relevance() of the states so far

    # -- the queue -------------------------------------------------------------------------
    def pop(self) -> tuple[str, str | None, np.ndarray | None] | None:
        """The next model to search, its parent and the estimate to resume from."""
        return self.queue.pop(0) if self.queue else None

    def clear(self) -> None:
        """Nothing more to search (the search stopped on an error)."""
        self.queue.clear()

    def queued(self) -> list[str]:
        return [m for m, _, _ in self.queue]

    def unsettled(self) -> int:
        """Models of the lattice neither searched nor skipped yet."""
        return len(self.reachable - set(self.states) - set(self.skipped))

    def requeue(self, model: str) -> bool:
        """Search ``model`` again first, from its estimate; False when it was never
        estimated (nothing to resume)."""
        state = self.states.get(model)
        if state is None or state.status == "null":
            return False
        self.first(model, state.parent, state.q)
        return True

    def first(self, model: str, parent: str | None, resume: np.ndarray | None) -> None:
        """``model`` searched next, from ``parent`` (from the estimate ``resume``, None:
        afresh), unless it is queued already."""
        if all(m != model for m, _, _ in self.queue):
            self.queue.insert(0, (model, parent, resume))

    # -- outcomes --------------------------------------------------------------------------
    def skip(self, model: str, parent: str | None) -> None:
        """``model`` gave no estimate: the lattice goes on past it."""
        self.skipped[model] = parent
        self.queue_alternatives(model)

    def record(self, state: ModelState, corrected) -> None:
        """The estimate of a model searched, and its corrected measures (its :attr:`shape`
        was set by its verdict, :meth:`accepted`; its more general models are queued by
        :meth:`queue_alternatives` once the caller has reported it)."""
        self.corrected[state.model] = corrected
        self.states[state.model] = state
        self._relevance = None
        self.skipped.pop(state.model, None)

    def improve(self, state: ModelState, corrected) -> None:
        """A searched model's better estimate (found from a child's: Scheduler._into_parent)."""
        self.states[state.model] = state
        self.corrected[state.model] = corrected
        self._relevance = None

    def forget(self, removed: np.ndarray) -> list[ModelState]:
        """Measures removed: the states forget them at once (best() must not list them).
        Returns the accepted states that had some of them as inliers."""
        gone = set(removed.tolist())
        touched = [s for s in self.states.values()
                   if s.accepted and gone & set(s.inliers.tolist())]
        for name, state in self.states.items():
            kept = ~np.isin(state.measure_ids, removed)
            self.states[name] = replace(
                state, inliers=state.inliers[~np.isin(state.inliers, removed)],
                outliers=state.outliers[~np.isin(state.outliers, removed)],
                measure_ids=state.measure_ids[kept],
                errors=state.errors[kept] if state.errors.size == kept.size
                else state.errors)
        self._selected.clear()
        return touched

    def queue_alternatives(self, model: str) -> None:
        """Queue each more general model once all its parents in the lattice are settled
        (report §5: a model is not estimated before its parents), against the best of their
        accepted anchors."""
        if self.single:
            return
        known = {m for m, _, _ in self.queue}
        for alt, _ in self.fam.model(model).alternatives:
            if alt in known or alt in self.states or alt in self.skipped:
                continue
            parents = lattice.lattice_parents(self.fam, alt, self.reachable)
            if not all(p in self.states or p in self.skipped for p in parents):
                continue  # the others will queue it
            anchors: dict[str, str] = {}
            for p in parents:
                anchor = lattice.anchor(self.states, self.skipped, p)
                if anchor is not None:
                    anchors.setdefault(anchor, p)
            if not anchors:
                continue
            chosen = self.select([self.states[a] for a in anchors])
            self.queue.append((alt, chosen.model, None))
            self._declared_by[alt] = anchors[chosen.model]  # the edge whose Φ decides

    # -- the decisions ---------------------------------------------------------------------
    def searched(self, model: str | None) -> ModelState | None:
        """The state of ``model`` when it was searched (drew samples), else None."""
        state = self.states.get(model) if model else None
        return state if state is not None and state.samples else None

    def across(self, parent: str, rank: int) -> bool:
        """Does the edge from ``parent`` to a model of ``rank`` equations per measure (on the
        sampled channel) change that number (an H-type parent, an F-type child)?"""
        return parent in self.shape and self.shape[parent][0] != max(rank, 1)

    def accepted(self, state: ModelState, success: bool,
                 shape: tuple[int, int] | None = None) -> ModelState:
        """``state`` (a model's new estimate) with its verdict against its parent: only an
        honest success (a verified minimum) may replace a searched parent, and then only as
        :func:`~kanagen.runtime.lattice.beats` decides (which reads the models'
        :attr:`shape`: ``shape``, the equations per measure and free degrees of freedom of
        a model searched the first time, is recorded first)."""
        if shape is not None:
            self.shape[state.model] = shape
        if state.parent is None:
            return state
        p = self.states.get(state.parent)
        if p is None or not p.samples or not np.isfinite(p.normalized_cost):
            return state
        return replace(state, accepted=bool(success) and lattice.beats(
            p, state, self.shape, self.replaces))

    def replaces(self, specific: ModelState, general: ModelState) -> bool:
        """Both refitted on the measures both take as inliers, ``L̃'²/d' < Φ(d, d') L̃²/d``
        (:func:`~kanagen.runtime.lattice.general_wins`)."""
        common = np.intersect1d(specific.inliers, general.inliers)
        fits = self._refit((specific, general), common)
        return lattice.general_wins(fits[0], fits[1],
                                    self.edge_phi(specific.model, general.model))

    def edge_phi(self, parent: str, model: str):
        """The factor of the edge that queued ``model``; between models with no edge (two
        children of one parent), the F-test factor."""
        if self.phi is not None:
            return get_phi(self.phi)
        for alt, choice in self.fam.model(self._declared_by.get(model, parent)).alternatives:
            if alt == model:
                return get_phi(choice)
        return get_phi("ftest")

    def select(self, states: list[ModelState]) -> ModelState:
        """:func:`~kanagen.runtime.lattice.select`, remembered (its cost tests refit)."""
        key = tuple((s.model, s.samples, s.normalized_cost, s.relevance) for s in states)
        if key not in self._selected:
            self._selected[key] = lattice.select(states, self.shape, self.replaces)
        return self._selected[key]

    def best(self) -> ModelState | None:
        """The best accepted model that no accepted, more general model replaced."""
        accepted = [s for s in self.states.values() if s.accepted]
        if not accepted:
            return None
        replaced = {s.parent for s in accepted if s.parent is not None and s.samples}
        leaves = [s for s in accepted if s.model not in replaced]
        estimated = [s for s in leaves if s.samples] or leaves
        return self.select(estimated)

    def best_relevance(self) -> float:
        """The best relevance of the accepted models searched so far."""
        if self._relevance is None:  # the states changed: the best of them anew
            self._relevance = max(
                [s.relevance for s in self.states.values() if s.accepted and s.samples],
                default=-np.inf)
        return self._relevance

    def least_support(self) -> int:
        """The inliers a model must explain to be chosen by anyone (lattice.select): a
        fraction of the most any accepted model searched explains."""
        return int(max((s.inliers.size for s in self.states.values()
                        if s.accepted and s.samples), default=0) / lattice.MORE_SUPPORT)
