"""The estimator as a module (report §5–6): measures in, the best model out, at any time.

``init(); while step(): check(); finalize()`` — the search through the lattice of models
advances one random sample per :meth:`Estimator.step`, so it can be fed, queried, suspended
and resumed between any two samples, from another thread too. Numerical trouble is absorbed
into the status; nothing raises out of :meth:`~Estimator.run` or :meth:`~Estimator.step`.

The Estimator drives the parts that do the work: its measures
(:class:`~kanagen.runtime.measures.MeasureStore`), the samples each model's search draws
(:class:`~kanagen.runtime.budget.SampleBudget`), the walk through the lattice — which model
next, from which parent, which one is best (:class:`~kanagen.runtime.walk.LatticeWalk`) —
and each model's search (:class:`~kanagen.runtime.robust.ModelSearch`).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from kanagen.common.jit import interrupted

from . import lattice
from .budget import SampleBudget
from .family import ModelFamily
from .fit import fit_problem, make_problem
from .initializers import model_initializers
from .inputs import (
    ChannelData,
    check_search_options,
    parameter_vector,
    prior_information,
)
from .measures import MeasureStore
from .minimal import coherence_errors, manifold_ranks
from .phi import phi as get_phi
from .projector import Problem
from .results import ModelState
from .robust import ModelSearch, RobustEstimate
from .scoring import ransac, relevance
from .scoring import scorer as get_scorer
from .walk import LatticeWalk

_PROBE = "(probe)"  # the parent of a probe's search (_start_probe): none of the lattice
_RESUME_FRACTION = 10  # a re-queued model draws a tenth of a fresh search's samples
_BRIEF = 10  # iterations of the final refinement of a model that cannot win (_hopeless)
#: iterations of a model's final refinement at most: a fit that crawls along a valley (a
#: general motion's focal lengths) and stops at the cap is no success and cannot replace its
#: parent, however much more it explains (the CMP wall pair: 80 matches against 44 at 100)
_FINAL_ITER = 300
#: samples per step of run() at most (a batch in one engine call: ModelSearch.step), when
#: no stopping rule reads the history sample by sample
_BATCH = 128


class Estimator:
    """Robust multi-model estimation over a family's lattice of models.

    Parameters
    ----------
    fam : ModelFamily
    scale : float, optional
        ``L*``, the order of magnitude of an inlier's error (eq. 29). Default (None): each
        model's from the χ² quantile of its measures' equations ``p``, ``χ²_p(0.999)/p``
        (:func:`~kanagen.runtime.scoring.default_scale`: 10.83 for one equation per measure,
        6.91 for two): with the right information (``info = 1/σ²``) 99.9 % of the inliers fall
        under it. The L* each search used: :attr:`scales`.
    scorer : str or callable
        ``"relevance"`` (default), ``"ransac"``, ``"trimmed"`` or ``f(errors, scale)``.
    phi : optional
        Cost factor for every edge (number, ``"aic"``, ``"ftest"``, ``"ftest:P"``,
        ``"exp:κ"`` or callable); default: each edge's factor from the spec.
    seed : int
        Seed of the random samples: same seed and same calls give the same results.
    channel : str, optional
        The channel samples are drawn from (default: the only one).
    samples_per_model : int, optional
        Adaptive: the most samples of one model's search (default
        :data:`~kanagen.runtime.budget.MODEL_CAP`, 5000; :meth:`run`'s ``max_samples`` and
        ``time_budget`` bound the whole search); not adaptive: the samples of each model's
        search (default: eq. 25 with ``confidence`` and ``inlier_ratio``).
    adaptive : bool
        Default True: each model's search draws the samples of eq. 25 at the inlier ratio of
        its best estimate so far, updated as samples come (as adaptive RANSAC does; at
        least ``min_samples``; :class:`~kanagen.runtime.budget.SampleBudget`): fewer than
        the assumed ``inlier_ratio`` asks on easy data, more on hard data — and no more than
        finds any structure that could be chosen: the lattice's most general models are
        probed first (a short search from all the measures), and a model searched later
        plans for the support a structure needs to matter beside the strongest explanation
        found (:meth:`_need`). False: eq. 25 at the assumed ``inlier_ratio`` (0.5) for every
        model, whatever the data, and no probe. :attr:`planned` is the samples the search
        plans in all so far.
    q0, Q0, constants : the prior and the constants, as for :func:`kanagen.fit`.
    model : str, optional
        Search this model only (no lattice); default: the lattice from the null model.
    initializers : dict, optional
        ``{model: name or callable or None}``: closed-form starts of the model's minimal
        solves (:mod:`kanagen.runtime.initializers`), over the spec's ``initializer:``;
        ``None`` switches one off.
    local : float in [0, 1]
        Fraction of local (nearest-neighbour) samples, see :class:`ModelSearch`, in the
        searches over all the measures; default 0. A more general model's samples stay as
        they are (extra measures among its parent's outliers).
    max_threshold : float, optional
        A ceiling on the outlier threshold of the error histogram (error units, at least
        ``scale``); default none.
    ceiling : float, optional
        The same ceiling in units of each model's ``L*`` (when ``max_threshold`` is not
        given; at least 1): structures close to one another leave no minimum in the error
        histogram between them. Default none (:func:`kanagen.find_structures`: 2).

    Examples
    --------
    >>> import numpy as np, kanagen
    >>> est = kanagen.Estimator(kanagen.load("line"), seed=0)
    >>> x = np.linspace(0, 10, 40)
    >>> ids = est.add_measures("point", np.c_[x, 0.5 * x + 3], info=100.0)
    >>> best = est.run(max_samples=200)
    >>> best.model, round(best.params["a"], 3), round(est.scales["line"], 2)
    ('line', 0.5, 10.83)
    """

    def __init__(self, fam: ModelFamily, scale: float | None = None,
                 scorer: str | Callable = "relevance", phi=None, seed: int | None = 0,
                 channel: str | None = None, samples_per_model: int | None = None,
                 confidence: float = 0.99, inlier_ratio: float = 0.5, adaptive: bool = True,
                 min_samples: int = 20, window: float = 0.35,
                 q0=None, Q0=None, constants=None, model: str | None = None,
                 initializers: dict | None = None, local: float = 0.0,
                 max_threshold: float | None = None, ceiling: float | None = None):
        check_search_options(scale=scale, seed=seed, samples_per_model=samples_per_model,
                       confidence=confidence, inlier_ratio=inlier_ratio,
                       min_samples=min_samples, window=window)
        get_scorer(scorer)  # validate now: a bad choice must not surface mid-run
        if phi is not None:
            get_phi(phi)
        self.fam = fam
        #: L* as given (None: each model's default, :attr:`scales`)
        self.scale = None if scale is None else float(scale)
        #: the L* of each model searched so far (the one given, or the model's default)
        self.scales: dict[str, float] = {}
        #: the measures of a full minimal sample of each model searched so far
        self.sample_sizes: dict[str, int] = {}
        self.scorer = scorer
        self.phi = phi
        self.seed = seed
        self.channel = channel
        #: how many samples each model's search draws (eq. 25)
        self.budget = SampleBudget(samples_per_model, confidence, inlier_ratio, adaptive,
                                   min_samples)
        self.window = window
        if not 0.0 <= local <= 1.0:
            raise ValueError(f"local must be a fraction in [0, 1], got {local}")
        self.local = float(local)
        if max_threshold is not None and scale is not None and not max_threshold >= scale:
            raise ValueError(f"max_threshold must be at least scale (L* = {scale}), got "
                             f"{max_threshold}")
        self.max_threshold = max_threshold
        if ceiling is not None and not (isinstance(ceiling, int | float) and ceiling >= 1.0):
            raise ValueError(f"ceiling is in units of L*, at least 1, got {ceiling!r}")
        self.ceiling = None if ceiling is None else float(ceiling)
        if model is not None:
            fam.model(model)
        elif len(fam.models) > 1 and not any(fam.model(m).alternatives for m in fam.models):
            raise ValueError(
                f"family {fam.name!r} declares no lattice (none of its models names "
                f"alternatives): give model= one of {', '.join(map(repr, fam.models))} to "
                f"search that model, or link the models with alternatives: in the spec")
        self.model = model  # a single model (no lattice), or None for the whole lattice
        self.initializers = model_initializers(fam, initializers)
        self.q0 = parameter_vector(fam, q0)
        self.Q0 = prior_information(Q0, fam.n)
        self._constants = dict(constants or {})
        fam.constant_vector(self._constants)  # validate now
        self._measures = MeasureStore(fam)
        self._lock = threading.RLock()
        self._running = threading.Event()
        self._running.set()
        self._stopped = False
        self._horizon: int | None = None  # in a run(): the samples drawn when it stops
        self._on_model: list[Callable] = []
        self._on_done: list[Callable] = []
        self._pending: list[tuple[Callable, object]] = []  # callbacks to call, lock released
        #: Errors absorbed (a scorer, initializer or callback that raised), in order.
        self.errors: list[str] = []
        self.history: list[tuple[int, float]] = []
        self.status = "no measures"
        self._restart()

    # -- measures and constants ---------------------------------------------------------------
    def add_measures(self, channel: str, data, info=None, exact=None) -> np.ndarray:
        """Add measures (any time); returns their stable integer ids.

        ``exact``: which measured components are known exactly, as for :func:`kanagen.fit`
        (``{component: mask}`` or (M, components) booleans). An outlier of the current best
        model changes nothing; an inlier re-queues the model.
        """
        with self._lock:
            ids, ch = self._measures.add(channel, data, info, exact)
            best = self._walk.best()
            if best is None or best.status == "null":
                self._restart_if_idle()
            elif self._coherent_with(best, channel, ch):
                self._requeue(best.model)
            return ids

    def remove_measures(self, ids) -> None:
        """Remove measures by id (any time). Removing an inlier of an accepted model
        re-queues it and its parent."""
        with self._lock:
            gone = set(np.asarray(ids, dtype=int).tolist())
            self._measures.remove(gone)
            self._probed.clear()  # what the probes found may have been among them
            for state in self._walk.forget(np.fromiter(gone, dtype=int, count=len(gone))):
                self._requeue(state.parent or state.model)
                self._requeue(state.model)

    def set_constants(self, **constants: float) -> None:
        """Set constants (state input); restarts the search from the null model."""
        with self._lock:
            merged = {**self._constants, **constants}
            self.fam.constant_vector(merged)
            self._constants = merged
            self._measures.invalidate()
            self._restart()

    # -- control --------------------------------------------------------------------------------
    def on_model(self, callback: Callable[[ModelState], None]) -> None:
        """Call ``callback(state)`` whenever a better model is found."""
        self._on_model.append(callback)

    def on_done(self, callback: Callable[[ModelState | None], None]) -> None:
        """Call ``callback(best)`` when the search ends."""
        self._on_done.append(callback)

    def suspend(self) -> None:
        """Pause :meth:`run` after the current sample (thread-safe)."""
        self._running.clear()

    def resume(self) -> None:
        self._running.set()

    def stop(self) -> None:
        """End :meth:`run` after the current sample (thread-safe; before :meth:`run`, the next
        run returns at once); :meth:`step` still works."""
        self._stopped = True
        self._running.set()

    def run(self, max_samples: int = 2000, time_budget: float | None = None,
            no_gain: int | None = None,
            until: Callable[[list[tuple[int, float]]], bool] | None = None) -> ModelState | None:
        """Step until the lattice is explored, or ``max_samples`` more samples, or
        ``time_budget`` seconds, or ``no_gain`` samples without a better relevance, or
        ``until(history)`` is true, or :meth:`stop` (also one called before this run); returns
        the best model. ``time_budget`` counts while suspended too."""
        started = time.perf_counter()
        self.fam.warn_assumed(self._constants)  # said where the user's search starts
        budget = self._samples + max_samples
        batch = _BATCH if no_gain is None and until is None else 1
        reason = None
        self._horizon = budget  # adaptive budgets share what is left of it (_share)
        try:
            reason = self._run(budget, batch, started, time_budget, no_gain, until)
        finally:
            self._horizon = None
        if reason is not None and not self._done:
            base = self.status.split("; ", 1)[1] if self.status.startswith("paused (") \
                else self.status
            self.status = f"paused ({reason}); {base}"
        return self.best()

    def _run(self, budget: int, batch: int, started: float, time_budget: float | None,
             no_gain: int | None, until: Callable | None) -> str | None:
        """:meth:`run`'s loop: the reason it paused, or None when the search is done."""
        reason = None
        while reason is None:
            if self._samples >= budget:
                reason = "sample budget"
                break
            remaining = None if time_budget is None else \
                time_budget - (time.perf_counter() - started)
            if remaining is not None and (remaining <= 0 or not self._running.wait(remaining)):
                reason = "time budget"
                break
            self._running.wait()
            if self._stopped:
                self._stopped = False  # consumed: the next run goes on
                reason = "stop()"
            elif not self._locked_step(min(batch, budget - self._samples)):
                break  # done: the status says so
            elif time_budget is not None and time.perf_counter() - started > time_budget:
                reason = "time budget"
            elif no_gain is not None and len(self.history) > no_gain and \
                    self.history[-1][1] <= self.history[-1 - no_gain][1]:
                reason = f"no gain in {no_gain} samples"
            elif until is not None and until(self.history):
                reason = "until()"
        return reason

    @property
    def samples(self) -> int:
        """Random samples drawn so far."""
        return self._samples

    @property
    def planned(self) -> int:
        """The samples the search plans in all, as far as it knows now: those drawn, the rest
        of the current model's budget (it moves as the budget adapts to the inlier ratio of
        the best estimate), and at least ``min_samples`` for each model queued (the lattice
        queues a model's more general ones when it is done). Equal to :attr:`samples` once
        the search is done."""
        with self._lock:
            total = self._samples
            if self._search is not None:
                _, _, search, budget, cap, need = self._search
                total += max(self.budget.now(search, budget, cap, need) - search.samples, 0)
            if not self._done:
                total += sum(1 if self.fam.free_dof(m, self._constants) == 0 else
                             self.budget.min_samples
                             for m in self._probes + self._walk.queued())
            return total

    def step(self) -> bool:
        """One unit of work (usually one random sample). False when nothing is left to do."""
        return self._locked_step(1)

    def _locked_step(self, batch: int) -> bool:
        """Up to ``batch`` samples of the current search (fewer when one improves it or its
        budget ends), under the lock; then the callbacks it triggered, the lock released
        (a callback may query the estimator from another thread). Numerical trouble and a
        scorer or initializer that raises are absorbed: the search stops, and the status
        and :attr:`errors` say why."""
        with self._lock:
            try:
                going = self._step(batch)
            except Exception as exc:  # absorbed: the reason stays in the status
                if interrupted(exc):  # Ctrl-C, raised inside a kernel's boxing
                    raise KeyboardInterrupt from exc
                self.errors.append(f"{type(exc).__name__}: {exc}")
                self._walk.clear()
                self._search = None
                self._finish()
                going = False
            pending, self._pending = self._pending, []
        for callback, argument in pending:
            try:
                callback(argument)
            except Exception as exc:  # a user's callback: noted, the search goes on
                with self._lock:
                    self.errors.append(f"callback {getattr(callback, '__name__', '?')} "
                                       f"raised {type(exc).__name__}: {exc}")
                    self.status = self._status_with_errors(self.status)
        return going

    # -- outputs --------------------------------------------------------------------------------
    def best(self) -> ModelState | None:
        """The best model so far (least normalised cost among accepted ones)."""
        with self._lock:
            return self._walk.best()

    def states(self) -> list[ModelState]:
        """Every model estimated so far, with its figures."""
        with self._lock:
            return list(self._walk.states.values())

    @property
    def probes(self) -> dict[str, dict[str, int]]:
        """The most general models probed before the lattice (a short search from all the
        measures: see ``adaptive``) and what each found: ``{model: {"inliers": n,
        "samples": k}}`` — its samples count in :attr:`samples`, not in the model's
        state."""
        with self._lock:
            return {m: {"inliers": n, "samples": k} for m, (n, k) in self._probed.items()}

    # -- internals ------------------------------------------------------------------------------
    def _restart(self) -> None:
        self._rng = np.random.default_rng(self.seed)
        root = self.model or self.fam.null_model
        self._walk = LatticeWalk(self.fam, root, self._null_state(root), bool(self.model),
                                 self.phi, self._refit)
        # (model, parent, search, budget, the most it may grow to, the inliers of the
        # sampled channel it must reach to matter: SampleBudget.now)
        self._search: tuple[str, str | None, ModelSearch, int, int | None, float] | None = None
        self._samples = 0
        self._done = False
        self._measures.invalidate()
        self.history = []
        #: the most general models probed before the lattice (_start_probe) and what each
        #: probe found: {model: (inliers its best estimate explains, samples drawn)}
        self._probes = [] if self.model or not self.budget.adaptive else \
            lattice.tops(self.fam, root)
        self._probed: dict[str, tuple[int, int]] = {}

    def _restart_if_idle(self) -> None:
        if self._done or self._search is None:
            self._restart()

    def _null_state(self, root: str) -> ModelState:
        n = self.fam.n
        return ModelState(root, None, self.fam.params_dict(self.q0),
                          self.q0.copy(), self.Q0.copy(), np.full((n, n), np.inf),
                          np.zeros(0, int), np.zeros(0, int), np.inf, 0, 0.0, 0, np.inf, True,
                          status="null", units=self.fam.units,
                          pinned=self.fam.pinned(root),
                          assumed=self.fam.assumed(self._constants))

    def _problem_for(self, model: str) -> tuple[Problem, list[np.ndarray], int]:
        """The model's problem, the measure ids per channel, the sampled channel's index."""
        names, _, ids = self._measures.channels()
        problem = self._measures.problem(model, self.q0, self.Q0, self._constants)
        channel = self.channel or (names[0] if len(names) == 1 else None)
        if channel is None:
            raise ValueError(f"channel= is required: measures in {names}")
        return problem, ids, names.index(channel)

    def _budget(self, search: ModelSearch, parent: ModelState | None) -> int:
        """Samples for the search (:meth:`SampleBudget.initial`): one when the model's
        parameter is fixed; a child across a change of equations per measure samples for the
        share of its parent's outliers it must explain."""
        if self.fam.free_dof(search.model, self._constants) == 0:
            return 1  # nothing to sample: the model's parameter is fixed
        across = parent is not None and search.base is not None and \
            self._walk.across(parent.model, search.ranks[search.channel])
        return self.budget.initial(search, parent.inliers.size if across else None)

    def _step(self, batch: int = 1) -> bool:
        if self._search is None and not self._start_next():
            self._finish()
            return False
        model, parent, search, budget, cap, need = self._search
        limit = self.budget.limit(search, budget, batch, cap, need)
        before, previous = search.samples, self.history[-1][1] if self.history else -np.inf
        level = max(previous, self._best_relevance(search))
        search.step(limit)
        done = max(search.samples - before, 1)
        self.history.extend((self._samples + i, level) for i in range(1, done))
        self._samples += done
        self.history.append((self._samples, max(previous, self._best_relevance(search))))
        if search.samples >= self.budget.now(search, budget, cap, need) or search.exhausted:
            self._search = None
            if parent is _PROBE:
                self._probed_support(search)
            else:
                self._conclude(model, parent, search)
        return True

    def _best_relevance(self, search: ModelSearch) -> float:
        """The best relevance of the accepted models so far and of the current search."""
        done = self._walk.best_relevance()
        current = search.best_score if np.isfinite(search.best_score) else 0.0
        return max(done, current)

    def _start_next(self) -> bool:
        if self._probes and len(self._measures):
            return self._start_probe(self._probes.pop(0))
        while (entry := self._walk.pop()) is not None:
            model, parent, resume = entry
            if not len(self._measures):
                self.status = "no measures"
                return False
            problem, ids, channel = self._problem_for(model)
            parent_state = self._walk.states.get(parent) if parent else None
            start = parent_state.q if parent_state is not None else self.q0
            search = self._model_search(model, parent_state, problem, ids, channel, start)
            if search.exhausted:
                self._walk.skip(model, parent)
                continue
            self.scales[model] = search.scale
            self.sample_sizes[model] = search.sample_size + search.base_size
            budget = self._budget(search, parent_state)
            cap = self._share(budget) if self.fam.free_dof(model, self._constants) > 0 \
                else budget
            if resume is not None:  # re-queued: resume from its estimate, a few more samples
                search.seed_estimate(resume)
                budget = cap = max(1, budget // _RESUME_FRACTION)
            elif model in self._probed:  # the probe's samples count (not its estimate)
                search.drawn_afresh = self._probed[model][1]
            self._search = (model, parent, search, budget, cap,
                            self._need(parent_state, search, ids))
            self.status = f"searching {model}"
            return True
        return False

    def _model_search(self, model: str, parent: ModelState | None, problem: Problem,
                      ids: list[np.ndarray], channel: int, start: np.ndarray) -> ModelSearch:
        """The search of ``model``: its extra measures among those not coherent with its
        parent and the rest of its samples among the parent's inliers (report §5) — unless
        the parent explains next to nothing: then the child is searched afresh."""
        def search(pool=None, base=None, parent_free=None, ranks=None) -> ModelSearch:
            return ModelSearch(self.fam, model, problem, channel, start, self._rng,
                               self.scale, self.scorer, pool=pool, parent_free=parent_free,
                               base=base, initializer=self.initializers.get(model),
                               local=self.local if pool is None else 0.0,
                               max_threshold=self.max_threshold, ranks=ranks,
                               ceiling=self.ceiling)

        if parent is None or not parent.samples or \
                parent.inliers.size < lattice.RELEVANT * sum(len(i) for i in ids):
            return search()
        ch_ids = ids[channel]
        name = problem.channels[channel].name
        ranks = manifold_ranks(problem, self.fam.with_slacks(start, problem.k, model))
        across = self._walk.across(parent.model, ranks[channel])
        parent_free = lattice.fixed_by(
            self.fam, parent, self.fam.free_dof(parent.model, self._constants), model,
            name, self._walk.corrected.get(parent.model, {}).get(name), self._constants,
            across)
        return search(np.flatnonzero(np.isin(ch_ids, parent.outliers)),
                      np.flatnonzero(np.isin(ch_ids, parent.inliers)), parent_free, ranks)

    def _start_probe(self, model: str) -> bool:
        """A short search of a most general model from all the measures, before the lattice
        (:attr:`_probes`): the strongest explanation of the data, found first, tells every
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
        search = ModelSearch(self.fam, model, problem, channel, self.q0, self._rng,
                             self.scale, self.scorer,
                             initializer=self.initializers.get(model),
                             max_threshold=self.max_threshold, ceiling=self.ceiling)
        budget = self._budget(search, None)
        if self._horizon is not None:  # a share of the run's samples left, as a model's
            budget = min(budget, (self._horizon - self._samples) //
                         (self._walk.unsettled() + len(self._probes) + 1))
        if search.exhausted or budget < self.budget.min_samples:
            return self._start_next()  # too short a run to spend samples on a probe
        self._search = (model, _PROBE, search, budget, budget, 0.0)
        self.status = f"probing {model}"
        return True

    def _probed_support(self, search: ModelSearch) -> None:
        """What the probe found (:meth:`_start_probe`): the inliers its best estimate
        explains, and its samples."""
        inliers = 0
        if search.best_errors is not None:
            inliers = sum(r.size for r in search.split(search.best_errors, self.window)[1])
        self._probed[search.model] = (inliers, search.samples)

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
        probed = max((n for n, _ in self._probed.values()), default=0)
        need = max(float(self._walk.least_support()), probed / lattice.MORE_SUPPORT)
        if parent is not None and parent.samples and search.score_fn in (relevance, ransac):
            across = self._walk.across(parent.model, search.ranks[search.channel])
            need = max(need, lattice.support_needed(parent, across, total))
        return max(need - (total - len(ids[search.channel])), 0.0)

    def _share(self, budget: int) -> int | None:
        """The most samples an adaptive budget may grow to, within a :meth:`run`: an equal
        share of its samples left among this model and the models of the lattice not yet
        searched — a model that fits next to nothing of the data (a plane among the matches
        of a 3-D scene) asks eq. 25 for tens of thousands, and would leave the rest of the
        lattice none — but not less than ``budget``, eq. 25 at the assumed inlier ratio (a
        short run still searches each model as a fixed budget would); None outside a run
        (then :data:`~kanagen.runtime.budget.MODEL_CAP`)."""
        if self._horizon is None or not self.budget.adaptive:
            return None
        return max(budget, (self._horizon - self._samples) // max(self._walk.unsettled(), 1))

    def _conclude(self, model: str, parent: str | None, search: ModelSearch) -> None:
        self._from_parent(parent, search)
        estimate = search.finish(self.q0, self.Q0, self.window,
                                 _BRIEF if self._hopeless(parent, search) else _FINAL_ITER,
                                 self._short_of(parent, search))
        if estimate is None or not np.all(np.isfinite(estimate.q)):
            self._walk.skip(model, parent)
            return
        self._into_parent(parent, search, estimate)
        _, _, ids = self._measures.channels()
        state = self._state(model, parent, estimate, ids,
                            (max(search.ranks[search.channel], 1),
                             self.fam.free_dof(model, self._constants)))
        self._walk.record(state, estimate.fit.measures)
        if state.accepted:
            best = self._walk.best()
            if best is state:
                self._pending.extend((cb, state) for cb in self._on_model)
        self._walk.queue_alternatives(model)

    def _from_parent(self, parent: str | None, search: ModelSearch) -> None:
        """A search whose samples did not clearly beat its parent (relevance up by more
        than the parent's noise, 1 / SUPPORT) also tries the parent's estimate, refined in
        its model: taken when it does. A parent that explains only part of the child's
        structure (a translation holding 169 of a general motion's 200 matches) leaves
        the rest of it in the pool the child's samples draw from, a small share of it: a
        sample of it may well not be drawn, and the parent's estimate is the child's best
        start. Along edges of the same equations per measure only: across them the
        parent's inliers are a singular configuration of the child."""
        state = self._walk.searched(parent)
        if state is None or search.base is None or \
                self._walk.across(parent, search.ranks[search.channel]):
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
        state = self._walk.searched(parent)
        if state is None or not estimate.relevance > state.relevance or \
                self._walk.across(parent, search.ranks[search.channel]):
            return
        problem, ids, channel = self._problem_for(parent)
        q = self.fam.with_slacks(estimate.q, problem.k, parent)
        with np.errstate(all="ignore"):
            c0 = problem.c0(q, problem.k)[0]
        scale = 1.0 + float(np.max(np.abs(q), initial=0.0))
        if not (np.all(np.isfinite(q)) and float(np.max(np.abs(c0), initial=0.0)) <=
                1e-8 * scale and self.fam.relations_hold(parent, q, self._constants)):
            return
        search = ModelSearch(self.fam, parent, problem, channel, q, self._rng, self.scale,
                             self.scorer, initializer=self.initializers.get(parent),
                             max_threshold=self.max_threshold, ceiling=self.ceiling)
        search.seed_estimate(q)
        refined = search.finish(self.q0, self.Q0, self.window)
        if refined is None or not np.all(np.isfinite(refined.q)):
            return
        again = self._state(parent, state.parent, refined, ids)
        if again.relevance > state.relevance and again.accepted >= state.accepted:
            self._walk.improve(replace(again, samples=state.samples), refined.fit.measures)

    def _hopeless(self, parent: str | None, search: ModelSearch) -> bool:
        """Can the model searched not replace its parent, by a wide margin
        (:func:`~kanagen.runtime.lattice.hopeless`)? Then its final refinement is brief."""
        state = self._walk.searched(parent)
        if state is None or search.best_errors is None:
            return False
        inliers = sum(r.size for r in search.split(search.best_errors, self.window)[1])
        return lattice.hopeless(state, search.best_score, inliers,
                                self._walk.across(parent, search.ranks[search.channel]))

    def _short_of(self, parent: str | None, search: ModelSearch) -> float | None:
        """The inliers the model searched must reach to replace its parent when only their
        number decides (across a change of equations per measure,
        :func:`~kanagen.runtime.lattice.explains_more`), else None."""
        state = self._walk.searched(parent)
        if state is None or not self._walk.across(parent, search.ranks[search.channel]):
            return None
        return lattice.MORE_SUPPORT * state.inliers.size

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
                           self.fam.assumed(self._constants))
        return self._walk.accepted(state, est.fit.success, shape)

    def _refit(self, states: tuple[ModelState, ...], common: np.ndarray) -> list:
        """Each state's model fitted on the measures of ids ``common`` from its estimate
        (the walk's cost test between two models, eq. 36)."""
        _, _, ids = self._measures.channels()
        rows = tuple(np.flatnonzero(np.isin(ch_ids, common)) for ch_ids in ids)
        return [fit_problem(self.fam, s.model, self._problem_for(s.model)[0].subset(rows),
                            q_start=s.q) for s in states]

    def _coherent_with(self, state: ModelState, channel: str, ch: ChannelData) -> bool:

        problem = make_problem(self.fam, state.model, {channel: ch.X}, {channel: ch.Q},
                               constants=self._constants)
        errors = coherence_errors(problem, state.q, iterations=1)[0]
        return bool(np.any(errors < state.threshold))

    def _requeue(self, model: str) -> None:
        if self._walk.requeue(model):
            self._done = False

    def _finish(self) -> None:
        if self._done:
            return
        self._done = True
        best = self._walk.best()
        status = "done" if best is not None and not self.errors else self.status
        self.status = self._status_with_errors(status)
        self._pending.extend((cb, best) for cb in self._on_done)

    def _status_with_errors(self, status: str) -> str:
        """``status`` with the absorbed errors said (once, the first one in full)."""
        if not self.errors:
            return status
        base = status.split(" — ", 1)[0]
        more = f" (and {len(self.errors) - 1} more)" if len(self.errors) > 1 else ""
        return f"{base} — stopped by an error: {self.errors[0]}{more}"



