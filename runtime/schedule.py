"""The searches of the lattice's models, one at a time (report §5, eq. 25): which model the
estimator searches next and from which parent, how many samples its search draws, and what
it hands the walk when it is done.

The :class:`~kanagen.runtime.estimator.Estimator` drives a :class:`Scheduler` a step at a
time: :meth:`Scheduler.start` the next search, draw the samples :meth:`Scheduler.limit`
allows, :meth:`Scheduler.conclude` it once :meth:`Scheduler.due`. The scheduler owns the
walk through the lattice (:class:`~kanagen.runtime.walk.LatticeWalk`), the search under way
(:class:`SearchPlan`) and the probes of the most general models; the estimator keeps the
measures, the samples drawn, the history and the controls.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from . import lattice
from .budget import SampleBudget
from .family import ModelFamily
from .fit import fit_problem
from .initializers import model_initializers
from .inputs import parameter_vector, prior_information
from .measures import MeasureStore
from .minimal import manifold_ranks
from .phi import phi as get_phi
from .projector import Problem
from .results import ModelState
from .robust import ModelSearch, RobustEstimate
from .scoring import ransac, relevance
from .scoring import scorer as get_scorer
from .walk import LatticeWalk

_RESUME_FRACTION = 10  # a re-queued model draws a tenth of a fresh search's samples
_BRIEF = 10  # iterations of the final refinement of a model that cannot win (_hopeless)
#: iterations of a model's final refinement at most: a fit that crawls along a valley (a
#: general motion's focal lengths) and stops at the cap is no success and cannot replace its
#: parent, however much more it explains (the CMP wall pair: 80 matches against 44 at 100)
_FINAL_ITER = 300


@dataclass(frozen=True, eq=False)
class SearchOptions:
    """The options of every model's search, validated by the
    :class:`~kanagen.runtime.estimator.Estimator` (its parameters of the same names;
    ``initializers`` resolved by :func:`~kanagen.runtime.initializers.model_initializers`,
    ``q0`` and ``Q0`` as vector and matrix)."""

    scale: float | None
    scorer: str | Callable
    phi: object
    window: float
    local: float
    max_threshold: float | None
    ceiling: float | None
    initializers: dict
    q0: np.ndarray
    Q0: np.ndarray
    channel: str | None
    model: str | None  # a single model (no lattice), or None for the whole lattice

    @classmethod
    def build(cls, fam: ModelFamily, *, scale: float | None, scorer: str | Callable, phi,
              window: float, local: float, max_threshold: float | None,
              ceiling: float | None, initializers: dict | None, q0, Q0, channel: str | None,
              model: str | None) -> SearchOptions:
        """The options checked — a bad choice must not surface mid-run (``scale`` and
        ``window``: :func:`~kanagen.runtime.inputs.check_search_options`) — and resolved."""
        get_scorer(scorer)
        if phi is not None:
            get_phi(phi)
        if not 0.0 <= local <= 1.0:
            raise ValueError(f"local must be a fraction in [0, 1], got {local}")
        if max_threshold is not None and scale is not None and not max_threshold >= scale:
            raise ValueError(f"max_threshold must be at least scale (L* = {scale}), got "
                             f"{max_threshold}")
        if ceiling is not None and not (isinstance(ceiling, int | float) and ceiling >= 1.0):
            raise ValueError(f"ceiling is in units of L*, at least 1, got {ceiling!r}")
        if model is not None:
            fam.model(model)
        elif len(fam.models) > 1 and not any(fam.model(m).alternatives for m in fam.models):
            raise ValueError(
                f"family {fam.name!r} declares no lattice (none of its models names "
                f"alternatives): give model= one of {', '.join(map(repr, fam.models))} to "
                f"search that model, or link the models with alternatives: in the spec")
        return cls(None if scale is None else float(scale), scorer, phi, window, float(local),
                   max_threshold, None if ceiling is None else float(ceiling),
                   model_initializers(fam, initializers), parameter_vector(fam, q0),
                   prior_information(Q0, fam.n), channel, model)


class SearchPlan(NamedTuple):
    """The search under way and what it plans (:meth:`SampleBudget.now`)."""

    model: str
    parent: str | None
    search: ModelSearch
    budget: int  # samples before any estimate (SampleBudget.initial)
    cap: int | None  # the most the budget may grow to
    need: float  # the inliers of the sampled channel it must reach to matter (_need)
    probe: bool = False  # a probe (Scheduler._start_probe): no search of the lattice

    def now(self, budget: SampleBudget) -> int:
        """The samples the search plans in all now (:meth:`SampleBudget.now`)."""
        return budget.now(self.search, self.budget, self.cap, self.need)


class Scheduler:
    """The searches of one walk through the lattice, from the null model (or the one model
    of ``options.model``).

    Parameters
    ----------
    fam : ModelFamily
    options : SearchOptions
    budget : SampleBudget
        How many samples each model's search draws.
    measures : MeasureStore
        The estimator's measures (each model's problem is built on them).
    constants : dict
        The constants set.
    rng : numpy.random.Generator
        The random samples of every search.
    scales, sample_sizes : dict
        Where the ``L*`` and the measures of a full minimal sample of each model searched
        are recorded (the estimator's :attr:`~kanagen.runtime.estimator.Estimator.scales`
        and :attr:`~kanagen.runtime.estimator.Estimator.sample_sizes`).
    """

    def __init__(self, fam: ModelFamily, options: SearchOptions, budget: SampleBudget,
                 measures: MeasureStore, constants: dict, rng: np.random.Generator,
                 scales: dict[str, float], sample_sizes: dict[str, int]):
        self.fam = fam
        self.options = options
        self.budget = budget
        self._measures = measures
        self._constants = constants
        self._rng = rng
        self._scales, self._sample_sizes = scales, sample_sizes
        root = options.model or fam.null_model
        self.walk = LatticeWalk(fam, root, self._null_state(root), bool(options.model),
                                options.phi, self._refit)
        self.current: SearchPlan | None = None
        #: the most general models to probe before the lattice (_start_probe), and what each
        #: probe found: {model: (inliers its best estimate explains, samples drawn)}
        self.probes = [] if options.model or not budget.adaptive else \
            lattice.tops(fam, root)
        self.probed: dict[str, tuple[int, int]] = {}

    # -- the search under way -----------------------------------------------------------------
    def limit(self, batch: int) -> int:
        """Samples the current search's next step may draw (:meth:`SampleBudget.limit`)."""
        plan = self.current
        return self.budget.limit(plan.search, plan.budget, batch, plan.cap, plan.need)

    def due(self) -> bool:
        """Has the current search drawn the samples it plans (or run out of measures)?"""
        plan = self.current
        return plan.search.samples >= plan.now(self.budget) or plan.search.exhausted

    def ahead(self, queued: bool) -> int:
        """The samples planned beyond those drawn: the rest of the current search's budget
        and, with ``queued``, at least ``min_samples`` for each model queued."""
        total = 0
        if (plan := self.current) is not None:
            total += max(plan.now(self.budget) - plan.search.samples, 0)
        if queued:
            total += sum(1 if self.fam.free_dof(m, self._constants) == 0 else
                         self.budget.min_samples for m in self.probes + self.walk.queued())
        return total

    def best_relevance(self) -> float:
        """The best relevance of the accepted models so far and of the current search."""
        done = self.walk.best_relevance()
        score = self.current.search.best_score
        return max(done, score if np.isfinite(score) else 0.0)

    def abandon(self) -> None:
        """The search under way drops what it drew (measures were removed: its samples and
        estimates index rows that are gone) and is searched again first, afresh, on the
        measures left; a probe is probed again."""
        plan, self.current = self.current, None
        if plan is None:
            return
        if plan.probe:
            self.probes.insert(0, plan.model)
        else:
            self.walk.first(plan.model, plan.parent, None)

    def clear(self) -> None:
        """Nothing more to search (the search stopped on an error)."""
        self.walk.clear()
        self.current = None

    # -- what to search next --------------------------------------------------------------------
    def start(self, left: int | None = None) -> str | None:
        """Start the next search (:attr:`current`) and say what it does (``"probing m"``,
        ``"searching m"``); ``"no measures"`` when there are none to search, None when
        nothing is left. ``left``: the samples left in the estimator's run (None outside
        one), shared among the models still to search (:meth:`_share`)."""
        if self.probes and len(self._measures):
            return self._start_probe(self.probes.pop(0), left)
        while (entry := self.walk.pop()) is not None:
            model, parent, resume = entry
            if not len(self._measures):
                return "no measures"
            problem, ids, channel = self._problem_for(model)
            parent_state = self.walk.states.get(parent) if parent else None
            start = parent_state.q if parent_state is not None else self.options.q0
            search = self._model_search(model, parent_state, problem, ids, channel, start)
            if search.exhausted:
                self.walk.skip(model, parent)
                continue
            self._scales[model] = search.scale
            self._sample_sizes[model] = search.draws.size
            budget = self._budget(search, parent_state)
            cap = self._share(budget, left) if self.fam.free_dof(model, self._constants) > 0 \
                else budget
            if resume is not None:  # re-queued: resume from its estimate, a few more samples
                search.seed_estimate(resume)
                budget = cap = max(1, budget // _RESUME_FRACTION)
            elif model in self.probed:  # the probe's samples count (not its estimate)
                search.drawn_afresh = self.probed[model][1]
            self.current = SearchPlan(model, parent, search, budget, cap,
                                      self._need(parent_state, search, ids))
            return f"searching {model}"
        return None

    def _new_search(self, model: str, problem: Problem, channel: int, start: np.ndarray,
                **options) -> ModelSearch:
        """A search of ``model`` with the estimator's options (``options``: those of a child
        searched from its parent, :meth:`_model_search`)."""
        o = self.options
        return ModelSearch(self.fam, model, problem, channel, start, self._rng, o.scale,
                           o.scorer, initializer=o.initializers.get(model),
                           max_threshold=o.max_threshold, ceiling=o.ceiling, **options)

    def _model_search(self, model: str, parent: ModelState | None, problem: Problem,
                      ids: list[np.ndarray], channel: int, start: np.ndarray) -> ModelSearch:
        """The search of ``model``: its extra measures among those not coherent with its
        parent and the rest of its samples among the parent's inliers (report §5) — unless
        the parent explains next to nothing: then the child is searched afresh."""
        if parent is None or not parent.samples or \
                parent.inliers.size < lattice.RELEVANT * sum(len(i) for i in ids):
            return self._new_search(model, problem, channel, start, local=self.options.local)
        ch_ids = ids[channel]
        name = problem.channels[channel].name
        ranks = manifold_ranks(problem, self.fam.with_slacks(start, problem.k, model))
        across = self.walk.across(parent.model, ranks[channel])
        parent_free = lattice.fixed_by(
            self.fam, parent, self.fam.free_dof(parent.model, self._constants), model,
            name, self.walk.corrected.get(parent.model, {}).get(name), self._constants,
            across)
        return self._new_search(model, problem, channel, start,
                            pool=np.flatnonzero(np.isin(ch_ids, parent.outliers)),
                            base=np.flatnonzero(np.isin(ch_ids, parent.inliers)),
                            parent_free=parent_free, ranks=ranks)

    def _start_probe(self, model: str, left: int | None) -> str | None:
        """A short search of a most general model from all the measures, before the lattice
        (:attr:`probes`): the strongest explanation of the data, found first, tells every
        model's budget the support it must reach to matter (:meth:`_need`) — a model that
        fits next to nothing of the data (a plane among the matches of a 3-D scene) is
        then not searched to its cap for a structure that could not be chosen. Its samples,
        uniform ones, count in the model's own search later (eq. 25's chance is a uniform
        sample's: :attr:`ModelSearch.drawn_afresh`). Its estimate is no state of the
        lattice, nor a candidate of the model's search: a child extends its parent's
        structure (report §5), and a structure found from all the measures may be none the
        lattice reaches (a conic of two parallel lines straddling the points of a line,
        which the first-order error scores above the line)."""
        problem, _, channel = self._problem_for(model)
        search = self._new_search(model, problem, channel, self.options.q0)
        budget = self._budget(search, None)
        if left is not None:  # a share of the run's samples left, as a model's
            budget = min(budget, left // (self.walk.unsettled() + len(self.probes) + 1))
        if search.exhausted or budget < self.budget.min_samples:
            return self.start(left)  # too short a run to spend samples on a probe
        self.current = SearchPlan(model, None, search, budget, budget, 0.0, probe=True)
        return f"probing {model}"

    def _budget(self, search: ModelSearch, parent: ModelState | None) -> int:
        """Samples for the search (:meth:`SampleBudget.initial`): one when the model's
        parameter is fixed; a child across a change of equations per measure samples for the
        share of its parent's outliers it must explain."""
        if self.fam.free_dof(search.model, self._constants) == 0:
            return 1  # nothing to sample: the model's parameter is fixed
        across = parent is not None and search.draws.base is not None and \
            self.walk.across(parent.model, search.ranks[search.channel])
        return self.budget.initial(search, parent.inliers.size if across else None)

    def _share(self, budget: int, left: int | None) -> int | None:
        """The most samples an adaptive budget may grow to, within a run: an equal share of
        its samples ``left`` among this model and the models of the lattice not yet
        searched — a model that fits next to nothing of the data (a plane among the matches
        of a 3-D scene) asks eq. 25 for tens of thousands, and would leave the rest of the
        lattice none — but not less than ``budget``, eq. 25 at the assumed inlier ratio (a
        short run still searches each model as a fixed budget would); None outside a run
        (then :data:`~kanagen.runtime.budget.MODEL_CAP`)."""
        if left is None or not self.budget.adaptive:
            return None
        return max(budget, left // max(self.walk.unsettled(), 1))

    def _need(self, parent: ModelState | None, search: ModelSearch,
              ids: list[np.ndarray]) -> float:
        """The inliers of the sampled channel a structure of the searched model must explain
        to matter (:meth:`SampleBudget.floor`): to be chosen at all
        (:meth:`~kanagen.runtime.walk.LatticeWalk.least_support`, and a
        :data:`~kanagen.runtime.lattice.MORE_SUPPORT` th of what the probes explain) and to
        replace its parent (:func:`~kanagen.runtime.lattice.support_needed`: a bound on the
        inliers when the score is eq. 29's relevance or the ransac-like one) — less the
        measures of the other channels, which it may explain too."""
        total = sum(len(i) for i in ids)
        probed = max((n for n, _ in self.probed.values()), default=0)
        need = max(float(self.walk.least_support()), probed / lattice.MORE_SUPPORT)
        if parent is not None and parent.samples and search.score_fn in (relevance, ransac):
            across = self.walk.across(parent.model, search.ranks[search.channel])
            need = max(need, lattice.support_needed(parent, across, total))
        return max(need - (total - len(ids[search.channel])), 0.0)

    # -- a search done ------------------------------------------------------------------------
    def conclude(self, found: Callable[[ModelState], None]) -> None:
        """The current search is done (:meth:`due`): a probe's support is noted
        (:attr:`probed`), a model's estimate goes into the walk — ``found(state)`` when it
        is the best model now — and its more general models are queued."""
        plan, self.current = self.current, None
        search = plan.search
        if plan.probe:
            inliers = 0
            if search.best_errors is not None:
                inliers = sum(r.size for r in search.split(search.best_errors,
                                                           self.options.window)[1])
            self.probed[search.model] = (inliers, search.samples)
            return
        model, parent = plan.model, plan.parent
        self._from_parent(parent, search)
        estimate = search.finish(self.options.q0, self.options.Q0, self.options.window,
                                 _BRIEF if self._hopeless(parent, search) else _FINAL_ITER,
                                 self._short_of(parent, search))
        if estimate is None or not np.all(np.isfinite(estimate.q)):
            self.walk.skip(model, parent)
            return
        self._into_parent(parent, search, estimate)
        _, _, ids = self._measures.channels()
        state = self._state(model, parent, estimate, ids,
                            (max(search.ranks[search.channel], 1),
                             self.fam.free_dof(model, self._constants)))
        self.walk.record(state, estimate.fit.measures)
        if state.accepted and self.walk.best() is state:
            found(state)
        self.walk.queue_alternatives(model)

    def _from_parent(self, parent: str | None, search: ModelSearch) -> None:
        """A search whose samples did not clearly beat its parent (relevance up by more
        than the parent's noise, 1 / SUPPORT) also tries the parent's estimate, refined in
        its model: taken when it does. A parent that explains only part of the child's
        structure (a translation holding 169 of a general motion's 200 matches) leaves
        the rest of it in the pool the child's samples draw from, a small share of it: a
        sample of it may well not be drawn, and the parent's estimate is the child's best
        start. Along edges of the same equations per measure only: across them the
        parent's inliers are a singular configuration of the child."""
        state = self.walk.searched(parent)
        if state is None or search.draws.base is None or \
                self.walk.across(parent, search.ranks[search.channel]):
            return
        floor = state.relevance / lattice.SUPPORT
        if lattice.hopeless(state, search.best_score, 0, False) or search.best_score >= floor:
            return  # its samples found no structure near the parent's, or beat it already
        search.consider(state.q, floor)

    def _into_parent(self, parent: str | None, search: ModelSearch, estimate) -> None:
        """A child's estimate that lies in its parent's model (a conic that is an ellipse)
        and explains the data better than the parent's own: the parent's search missed that
        structure (its samples stopped on part of it). The estimate is refined in the parent's
        model (its final rounds) and replaces the parent's state when it is more relevant —
        the lattice then keeps the specific model for what both explain (the same model
        whatever the seed). Along edges of the same equations per measure only (an F's
        parameter may satisfy a plane's constraints, its matches not the plane's
        equations)."""
        state = self.walk.searched(parent)
        if state is None or not estimate.relevance > state.relevance or \
                self.walk.across(parent, search.ranks[search.channel]):
            return
        problem, ids, channel = self._problem_for(parent)
        q = self.fam.with_slacks(estimate.q, problem.k, parent)
        with np.errstate(all="ignore"):
            c0 = problem.c0(q, problem.k)[0]
        scale = 1.0 + float(np.max(np.abs(q), initial=0.0))
        if not (np.all(np.isfinite(q)) and float(np.max(np.abs(c0), initial=0.0)) <=
                1e-8 * scale and self.fam.relations_hold(parent, q, self._constants)):
            return
        search = self._new_search(parent, problem, channel, q)
        search.seed_estimate(q)
        refined = search.finish(self.options.q0, self.options.Q0, self.options.window)
        if refined is None or not np.all(np.isfinite(refined.q)):
            return
        again = self._state(parent, state.parent, refined, ids)
        if again.relevance > state.relevance and again.accepted >= state.accepted:
            self.walk.improve(replace(again, samples=state.samples), refined.fit.measures)

    def _hopeless(self, parent: str | None, search: ModelSearch) -> bool:
        """Can the model searched not replace its parent, by a wide margin
        (:func:`~kanagen.runtime.lattice.hopeless`)? Then its final refinement is brief."""
        state = self.walk.searched(parent)
        if state is None or search.best_errors is None:
            return False
        inliers = sum(r.size for r in search.split(search.best_errors, self.options.window)[1])
        return lattice.hopeless(state, search.best_score, inliers,
                                self.walk.across(parent, search.ranks[search.channel]))

    def _short_of(self, parent: str | None, search: ModelSearch) -> float | None:
        """The inliers the model searched must reach to replace its parent when only their
        number decides (across a change of equations per measure,
        :func:`~kanagen.runtime.lattice.explains_more`), else None."""
        state = self.walk.searched(parent)
        if state is None or not self.walk.across(parent, search.ranks[search.channel]):
            return None
        return lattice.MORE_SUPPORT * state.inliers.size

    # -- the states of the walk ---------------------------------------------------------------
    def _state(self, model, parent, est: RobustEstimate, ids,
               shape: tuple[int, int] | None = None) -> ModelState:
        """The search's estimate of ``model`` as a state of the lattice, with its verdict
        against its parent (``shape``: the model's equations per measure and free degrees
        of freedom, for a model searched the first time)."""
        names = list(est.inliers)
        channel_ids = dict(zip(self._measures.channels()[0], ids, strict=True))
        inliers = np.concatenate([channel_ids[n][est.inliers[n]] for n in names])
        outliers = np.concatenate([channel_ids[n][est.outliers[n]] for n in names])
        scored = np.concatenate([channel_ids[n] for n in names])
        errors = np.concatenate([est.errors[n] for n in names])
        order = np.argsort(scored, kind="stable")
        state = ModelState(model, parent, est.params, est.q, est.fit.info, est.fit.covariance,
                           np.sort(inliers), np.sort(outliers), est.fit.cost,
                           est.fit.dof, est.relevance, est.samples, est.threshold, True,
                           est.fit.derived,
                           "estimated" if est.fit.success else est.fit.message,
                           est.fit.slacks, scored[order], errors[order],
                           est.fit.equations, est.fit.units, est.fit.pinned,
                           self.fam.assumed(self._constants), est.chance)
        return self.walk.accepted(state, est.fit.success, shape)

    def _null_state(self, root: str) -> ModelState:
        n, q0, Q0 = self.fam.n, self.options.q0, self.options.Q0
        return ModelState(root, None, self.fam.params_dict(q0), q0.copy(), Q0.copy(),
                          np.full((n, n), np.inf), np.zeros(0, int), np.zeros(0, int), np.inf,
                          0, 0.0, 0, np.inf, True, status="null", units=self.fam.units,
                          pinned=self.fam.pinned(root),
                          assumed=self.fam.assumed(self._constants))

    def _refit(self, states: tuple[ModelState, ...], common: np.ndarray) -> list:
        """Each state's model fitted on the measures of ids ``common`` from its estimate
        (the walk's cost test between two models, eq. 36)."""
        _, _, ids = self._measures.channels()
        rows = tuple(np.flatnonzero(np.isin(ch_ids, common)) for ch_ids in ids)
        return [fit_problem(self.fam, s.model, self._problem_for(s.model)[0].subset(rows),
                            q_start=s.q) for s in states]

    def _problem_for(self, model: str) -> tuple[Problem, list[np.ndarray], int]:
        """The model's problem, the measure ids per channel, the sampled channel's index."""
        names, _, ids = self._measures.channels()
        problem = self._measures.problem(model, self.options.q0, self.options.Q0,
                                         self._constants)
        channel = self.options.channel or (names[0] if len(names) == 1 else None)
        if channel is None:
            raise ValueError(f"channel= is required: measures in {names}")
        return problem, ids, names.index(channel)
