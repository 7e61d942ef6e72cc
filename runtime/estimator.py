"""The estimator as a module (report §5–6): measures in, the best model out, at any time.

``init(); while step(): check(); finalize()`` — the search through the lattice of models
advances one random sample per :meth:`Estimator.step`, so it can be fed, queried, suspended
and resumed between any two samples, from another thread too. Numerical trouble is absorbed
into the status; nothing raises out of :meth:`~Estimator.run` or :meth:`~Estimator.step`.

The Estimator is the driver and the API: it holds the measures
(:class:`~kanagen.runtime.measures.MeasureStore`), the samples drawn and their history, the
controls and the callbacks, and steps the searches of the lattice's models
(:class:`~kanagen.runtime.schedule.Scheduler`: which model next, from which parent, with how
many samples — :class:`~kanagen.runtime.budget.SampleBudget` — and the walk through the
lattice, :class:`~kanagen.runtime.walk.LatticeWalk`), each one a
:class:`~kanagen.runtime.robust.ModelSearch`.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import numpy as np

from kanagen.common.jit import interrupted

from .budget import SampleBudget
from .family import ModelFamily
from .fit import make_problem
from .inputs import ChannelData, check_search_options
from .measures import MeasureStore
from .minimal import coherence_errors
from .results import ModelState
from .schedule import Scheduler, SearchOptions

#: samples per step of run() at most (a batch in one engine call: ModelSearch.step), when
#: no stopping rule reads the history sample by sample
_BATCH = 128


def _option(name: str, doc: str) -> property:
    """An estimator's search option ``name``, read from its :class:`SearchOptions`."""
    return property(lambda est: getattr(est._options, name), doc=doc)


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
        found (:meth:`~kanagen.runtime.schedule.Scheduler._need`). False: eq. 25 at the
        assumed ``inlier_ratio`` (0.5) for every model, whatever the data, and no probe.
        :attr:`planned` is the samples the search plans in all so far.
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
        self._options = SearchOptions.build(
            fam, scale=scale, scorer=scorer, phi=phi, window=window, local=local,
            max_threshold=max_threshold, ceiling=ceiling, initializers=initializers, q0=q0,
            Q0=Q0, channel=channel, model=model)
        self.fam = fam
        #: the L* of each model searched so far (the one given, or the model's default)
        self.scales: dict[str, float] = {}
        #: the measures of a full minimal sample of each model searched so far
        self.sample_sizes: dict[str, int] = {}
        self.seed = seed
        #: how many samples each model's search draws (eq. 25)
        self.budget = SampleBudget(samples_per_model, confidence, inlier_ratio, adaptive,
                                   min_samples)
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

    #: the search options (read only: :class:`~kanagen.runtime.schedule.SearchOptions`)
    scale = _option("scale", "L* as given (None: each model's default, :attr:`scales`).")
    scorer = _option("scorer", "The scorer of the samples' estimates.")
    phi = _option("phi", "The cost factor of every edge (None: each edge's own).")
    channel = _option("channel", "The channel samples are drawn from (None: the only one).")
    window = _option("window", "The smoothing window of the error histogram (of L*).")
    local = _option("local", "The fraction of local samples of a search from scratch.")
    max_threshold = _option("max_threshold", "A ceiling on the outlier threshold, or None.")
    ceiling = _option("ceiling", "The same ceiling in units of L*, or None.")
    model = _option("model", "The one model searched (no lattice), or None.")
    initializers = _option("initializers", "The closed-form starts of each model.")
    q0 = _option("q0", "The prior parameter vector.")
    Q0 = _option("Q0", "The prior information matrix.")

    # -- measures and constants ---------------------------------------------------------------
    def add_measures(self, channel: str, data, info=None, exact=None) -> np.ndarray:
        """Add measures (any time); returns their stable integer ids.

        ``exact``: which measured components are known exactly, as for :func:`kanagen.fit`
        (``{component: mask}`` or (M, components) booleans). An outlier of the current best
        model changes nothing; an inlier re-queues the model.
        """
        with self._lock:
            ids, ch = self._measures.add(channel, data, info, exact)
            best = self._schedule.walk.best()
            if best is None or best.status == "null":
                self._restart_if_idle()
            elif _coherent(self.fam, best, channel, ch, self._constants):
                self._requeue(best.model)
            return ids

    def remove_measures(self, ids) -> None:
        """Remove measures by id (any time). Removing an inlier of an accepted model
        re-queues it and its parent; a model searched meanwhile is searched again, afresh,
        on the measures left."""
        with self._lock:
            gone = set(np.asarray(ids, dtype=int).tolist())
            self._measures.remove(gone)
            if gone:
                self._schedule.abandon()  # the search under way drew from the rows gone
            self._schedule.probed.clear()  # what the probes found may have been among them
            removed = np.fromiter(gone, dtype=int, count=len(gone))
            for state in self._schedule.walk.forget(removed):
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
        self._horizon = budget  # adaptive budgets share what is left of it (Scheduler._share)
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
            return self._samples + self._schedule.ahead(queued=not self._done)

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
                self._schedule.clear()
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
                    self.status = _with_errors(self.status, self.errors)
        return going

    # -- outputs --------------------------------------------------------------------------------
    def best(self) -> ModelState | None:
        """The best model so far (least normalised cost among accepted ones)."""
        with self._lock:
            return self._schedule.walk.best()

    def states(self) -> list[ModelState]:
        """Every model estimated so far, with its figures."""
        with self._lock:
            return list(self._schedule.walk.states.values())

    @property
    def probes(self) -> dict[str, dict[str, int]]:
        """The most general models probed before the lattice (a short search from all the
        measures: see ``adaptive``) and what each found: ``{model: {"inliers": n,
        "samples": k}}`` — its samples count in :attr:`samples`, not in the model's
        state."""
        with self._lock:
            return {m: {"inliers": n, "samples": k}
                    for m, (n, k) in self._schedule.probed.items()}

    # -- internals ------------------------------------------------------------------------------
    def _restart(self) -> None:
        #: the searches of the lattice: the walk, the search under way, the probes
        self._schedule = Scheduler(self.fam, self._options, self.budget, self._measures,
                                   self._constants, np.random.default_rng(self.seed),
                                   self.scales, self.sample_sizes)
        self._samples = 0
        self._done = False
        self._measures.invalidate()
        self.history = []

    def _restart_if_idle(self) -> None:
        if self._done or self._schedule.current is None:
            self._restart()

    def _step(self, batch: int = 1) -> bool:
        schedule = self._schedule
        if schedule.current is None:
            left = None if self._horizon is None else self._horizon - self._samples
            self.status = schedule.start(left) or self.status
            if schedule.current is None:
                self._finish()
                return False
        search = schedule.current.search
        limit = schedule.limit(batch)
        before, previous = search.samples, self.history[-1][1] if self.history else -np.inf
        level = max(previous, schedule.best_relevance())
        search.step(limit)
        done = max(search.samples - before, 1)
        self.history.extend((self._samples + i, level) for i in range(1, done))
        self._samples += done
        self.history.append((self._samples, max(previous, schedule.best_relevance())))
        if schedule.due():
            schedule.conclude(self._found)
        return True

    def _found(self, state: ModelState) -> None:
        """A better model: the callbacks of :meth:`on_model` are due."""
        self._pending.extend((cb, state) for cb in self._on_model)

    def _requeue(self, model: str) -> None:
        if self._schedule.walk.requeue(model):
            self._done = False

    def _finish(self) -> None:
        if self._done:
            return
        self._done = True
        best = self._schedule.walk.best()
        status = "done" if best is not None and not self.errors else self.status
        self.status = _with_errors(status, self.errors)
        self._pending.extend((cb, best) for cb in self._on_done)


def _coherent(fam: ModelFamily, state: ModelState, channel: str, ch: ChannelData,
              constants: dict) -> bool:
    """Are some of the measures ``ch`` of ``channel`` inliers of ``state``?"""
    problem = make_problem(fam, state.model, {channel: ch.X}, {channel: ch.Q},
                           constants=constants)
    errors = coherence_errors(problem, state.q, iterations=1)[0]
    return bool(np.any(errors < state.threshold))


def _with_errors(status: str, errors: list[str]) -> str:
    """``status`` with the absorbed ``errors`` said (once, the first one in full)."""
    if not errors:
        return status
    base = status.split(" — ", 1)[0]
    more = f" (and {len(errors) - 1} more)" if len(errors) > 1 else ""
    return f"{base} — stopped by an error: {errors[0]}{more}"

