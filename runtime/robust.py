"""Robust estimation of one model by random minimal samples (report §4).

:class:`ModelSearch` is a small state machine the estimator drives a few samples at a time
(anytime, suspendable): each :meth:`~ModelSearch.step` draws a minimal sample (eq. 21),
scores the estimate by the errors of every measure (eq. 22–24, the Sampson first-order error
here; those samples: :mod:`.sampling`) and keeps the best; :meth:`~ModelSearch.finish`
thresholds the error histogram, refines on the inliers with the full estimator of §2–3,
thresholds once more and refines again (those fits: :mod:`.refine`). :func:`robust_fit` runs
one search to the end.
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace

import numpy as np

from .family import ModelFamily
from .fit import check_correct_bias, make_problem
from .hyper import corrected
from .initializers import InitializerFn, admission, model_initializers
from .inputs import check_search_options
from .minimal import coherence_errors, manifold_ranks
from .projector import Problem
from .refine import Refinement
from .results import Chance, FitResult, ResultProtocol
from .sampling import MinimalSamples
from .scoring import default_scale, samples_for_confidence
from .scoring import scorer as get_scorer
from .significance import false_alarms, hypotheses


@dataclass(frozen=True, repr=False)
class RobustEstimate(ResultProtocol):
    """The outcome of a robust search of one model. The fields common to every result
    (:class:`~kanagen.runtime.results.ResultProtocol`: ``params``, ``q``, ``std``,
    ``covariance``, ``cost`` = L̃², ``dof``, ``chi2``, ``reduced_chi2``, ``success``, ...)
    are those of ``fit``, the refined estimate on the inliers."""

    model: str
    fit: FitResult  # the refined estimate (full estimator on the inliers)
    inliers: dict[str, np.ndarray]  # per channel, indices into the data given
    outliers: dict[str, np.ndarray]
    errors: dict[str, np.ndarray]  # per channel, every measure's error at the estimate
    threshold: float
    relevance: float  # score of the final estimate on all measures
    samples: int
    degenerate: int
    history: list[tuple[int, float]] = field(default_factory=list)  # (samples, best score)
    scale: float | None = None  # the L* of the search (given, or its default)
    chance: Chance | None = field(default=None, compare=False)  # the NFA, when read

    @property
    def q(self) -> np.ndarray:
        return self.fit.q

    @property
    def params(self) -> dict[str, float]:
        return self.fit.params

    @property
    def slacks(self) -> dict[str, float]:
        return self.fit.slacks

    @property
    def info(self) -> np.ndarray:
        return self.fit.info

    @property
    def covariance(self) -> np.ndarray:
        return self.fit.covariance

    @property
    def derived(self) -> dict:
        return self.fit.derived

    @property
    def units(self) -> dict[str, str]:
        return self.fit.units

    @property
    def pinned(self) -> dict[str, float]:
        return self.fit.pinned

    @property
    def assumed(self) -> dict[str, float]:
        return self.fit.assumed

    @property
    def cost(self) -> float:
        return self.fit.cost

    @property
    def dof(self) -> int:
        return self.fit.dof

    @property
    def equations(self) -> int:
        return self.fit.equations

    @property
    def success(self) -> bool:
        return self.fit.success

    @property
    def status(self) -> int:
        return self.fit.status

    @property
    def message(self) -> str:
        return self.fit.message

    def _headline(self) -> str:
        inliers = sum(len(v) for v in self.inliers.values())
        outliers = sum(len(v) for v in self.outliers.values())
        return (f"model {self.model!r} ({self.fit.message}): {inliers} inlier(s), "
                f"{outliers} outlier(s), relevance {self.relevance:.4g}, "
                f"{self.samples} sample(s)") + self._chance_line()


class ModelSearch:
    """Random minimal samples for one model, scored against every measure; the best estimate
    they give, refined.

    The samples — which measures, their solves and every measure's error at each estimate —
    are :attr:`draws` (:class:`~kanagen.runtime.sampling.MinimalSamples`); the full
    estimator on the measures an estimate explains is :attr:`refinement`
    (:class:`~kanagen.runtime.refine.Refinement`). The search keeps the best estimate so far
    and counts the samples (eq. 25: :meth:`samples_needed`); a sample that beats the best is
    refined at once (LO-RANSAC), and :meth:`finish` refines the best on its inliers.

    Parameters
    ----------
    fam, model : the family and the model searched.
    problem : Problem
        The validated measures (all channels); samples are drawn from ``channel``.
    channel : int
        Index of the sampled channel in ``problem.channels``.
    start : ndarray
        Starting value of the minimal solves (the parent's estimate, or q0).
    scale : float, optional
        ``L*``; default (None): :func:`~kanagen.runtime.scoring.default_scale` of the fewest
        equations per measure among the channels (``χ²_p(0.999) / p``, :attr:`scale`).
    pool : ndarray, optional
        Measures of the sampled channel that samples may use (default all).
    sample_size : int, optional
        Measures per sample (default: the minimal size for the model's free degrees of
        freedom, or for the extra ones over ``parent_free``).
    initializer : callable, optional
        Closed-form starts for the minimal solves (:mod:`~kanagen.runtime.initializers`):
        ``f(rows, constants) -> [{name: value}, ...]``; each candidate starts one solve.
    local : float in [0, 1]
        Fraction of the samples drawn locally (NAPSAC, Nasuto & Craddock 2002): one measure
        at random, the others among its nearest measures (Euclidean distance of the data
        rows). Structures in clustered data are spatially coherent: a local sample is far
        likelier to be outlier-free than a uniform one when each structure holds a small
        share of the measures. 0: uniform samples only.
    max_threshold : float, optional
        A ceiling on the outlier threshold (error units, at least ``scale``).
    ceiling : float, optional
        The same ceiling in units of the search's ``L*`` (when ``max_threshold`` is None):
        it follows each model's default ``L*``.
    ranks : tuple of int, optional
        Equations per measure of each channel at ``start``
        (:func:`~kanagen.runtime.minimal.manifold_ranks`, computed when not given).

    A sample whose independent equations outnumber the free degrees of freedom (a zoom from
    one match: two equations, one unknown; the null model: none) cannot be passed through
    exactly: its estimate is the full estimator's on the sample (measures corrected).
    """

    def __init__(self, fam: ModelFamily, model: str, problem: Problem, channel: int,
                 start: np.ndarray, rng: np.random.Generator, scale: float | None = None,
                 scorer: str | Callable = "relevance", pool: np.ndarray | None = None,
                 sample_size: int | None = None, parent_free: int | None = None,
                 base: np.ndarray | None = None, initializer: InitializerFn | None = None,
                 local: float = 0.0, max_threshold: float | None = None,
                 ranks: tuple[int, ...] | None = None, ceiling: float | None = None):
        if not 0.0 <= local <= 1.0:
            raise ValueError(f"local must be a fraction in [0, 1], got {local}")
        self.fam = fam
        self.model = model
        self.problem = problem
        self.channel = channel
        start = fam.with_slacks(np.asarray(start, dtype=float), problem.k, model)
        self.score_fn = get_scorer(scorer)
        # equations per measure, per channel (the caller's when it has them already)
        self.ranks = manifold_ranks(problem, start) if ranks is None else ranks
        #: L*: the one given, else the χ² quantile of the measures' equations
        self.scale = float(scale) if scale is not None else default_scale(self.equations)
        if max_threshold is None and ceiling is not None:
            max_threshold = max(float(ceiling), 1.0) * self.scale
        self.max_threshold = max_threshold
        #: the samples: which measures, their solves, each estimate's errors
        self.draws = MinimalSamples(fam, model, problem, channel, start, rng, self.scale,
                                    self.score_fn, self.ranks, pool, sample_size,
                                    parent_free, base, initializer, local)
        #: the full estimator on the measures an estimate explains (LO, the final rounds)
        self.refinement = Refinement(fam, model, problem, self.scale, self.score_fn,
                                     self.ranks, self.draws.size, max_threshold,
                                     admission(fam, model))
        self.samples = 0
        self.degenerate = 0
        self.best_q: np.ndarray | None = None
        self.best_score = -np.inf
        self.best_errors: tuple[np.ndarray, ...] | None = None
        self._needed: tuple = (None, None, None)  # samples_needed of the best estimate
        #: samples of this model drawn before from every measure of the channel (a probe of
        #: the estimator's): eq. 25 counts what they would have found (samples_needed)
        self.drawn_afresh = 0
        self.history: list[tuple[int, float]] = []

    @property
    def equations(self) -> int:
        """The fewest independent equations of a measure among the channels with measures
        (the ``p`` of the default ``L*``: the largest of the channels' quantiles)."""
        counts = [max(int(r), 1) for r, ch in zip(self.ranks, self.problem.channels,
                                                  strict=True) if ch.size]
        return min(counts, default=max(int(self.ranks[self.channel]), 1))

    @property
    def exhausted(self) -> bool:
        """Too few measures in the pools for one sample (:attr:`draws`)."""
        return self.draws.exhausted

    def samples_needed(self, confidence: float,
                       floor: tuple[float, ...] = (0.0, 0.0, 0.0)) -> int | None:
        """Eq. 25 with the inlier fractions (errors below ``L*``) of the best estimate so far
        in the pools the samples are drawn from — adaptive budgets (None before any
        estimate, or when no sample can be all inliers). ``floor``: the least inlier
        fractions of the pool, of the base and of the channel planned for (a structure with
        fewer would not matter: :meth:`~kanagen.runtime.budget.SampleBudget.floor`).

        With :attr:`drawn_afresh` samples of the model drawn before from every measure, the
        chance that all of them and the samples planned here miss the structure planned for
        is what the confidence leaves: a child's samples (its extra measures among its
        parent's outliers) then only make up what those did not settle
        (:meth:`~kanagen.runtime.sampling.MinimalSamples.needed`)."""
        if self.best_errors is None or not self.draws.pool.size:
            return None
        key = (confidence, tuple(floor), self.drawn_afresh)
        if self._needed[0] is self.best_errors and self._needed[1] == key:
            return self._needed[2]  # the best estimate has not changed since
        needed = self.draws.needed(self.best_errors[self.channel] < self.scale, confidence,
                                   floor, self.drawn_afresh)
        self._needed = (self.best_errors, key, needed)
        return needed

    # -- the samples ----------------------------------------------------------------------------
    def step(self, limit: int = 1) -> bool:
        """Draw and score one sample, or up to ``limit`` samples stopping after one that gives
        a better estimate; True when the last one did. Never raises.

        With the engine's sampler and the relevance scorer the samples run a batch at a
        time (:meth:`~kanagen.runtime.fastsample.Sampler.burst`), with the same draws,
        solutions and scores as one by one."""
        if self.exhausted:
            return False
        while limit > 0:
            rows = None
            if self.draws.bursts and limit > 1:
                done, outcome, rows = self._burst(limit)
                limit -= done
                if outcome != 2:  # the limit, or a better estimate
                    return outcome == 1
                # the closed form left the drawn sample `rows` to the Python
            if self._one(rows):
                return True
            limit -= 1
        return False

    def _burst(self, limit: int) -> tuple[int, int, np.ndarray | None]:
        """Up to ``limit`` samples in one engine call: (samples scored, outcome, rows),
        the outcome 0 at the limit, 1 when the last beat the best (taken, and locally
        optimised), 2 when the closed form left the sample ``rows`` (drawn, not counted) to the
        Python."""
        out = self.draws.burst(limit, self.best_score)
        if out is None:  # refused before drawing: the samples go one by one
            return 0, 2, None
        done, degenerate, outcome, best, rows = out
        before = self.best_score
        self.history.extend((self.samples + i, before) for i in range(1, done + 1))
        self.samples += done
        self.degenerate += degenerate
        if outcome == 1:
            self.best_q, self.best_score, self.best_errors = best
            try:
                with np.errstate(all="ignore"):
                    self._local_optimisation()
            except (np.linalg.LinAlgError, ValueError, FloatingPointError, ZeroDivisionError):
                self.degenerate += 1
            self.history[-1] = (self.samples, self.best_score)
        return done, outcome, rows

    def _one(self, rows: np.ndarray | None = None) -> bool:
        """Draw (unless ``rows`` are drawn already) and score one sample."""
        self.samples += 1
        compiled = rows is None  # a sample left to the Python goes solve by solve
        if rows is None:
            rows = self.draws.draw()
        improved = False
        solutions = 0
        try:
            with np.errstate(all="ignore"):
                for q, errors in self.draws.scored(rows, self.best_score, compiled):
                    solutions += 1
                    if errors is None:
                        continue  # its relevance is bounded below the best (errors_at)
                    score = self.score_fn(np.concatenate(errors), self.scale)
                    if score > self.best_score:
                        self.best_q, self.best_score, self.best_errors = q, score, errors
                        improved = True
                if improved:
                    self._local_optimisation()
        except (np.linalg.LinAlgError, ValueError, FloatingPointError, ZeroDivisionError):
            solutions = 0
        self.degenerate += solutions == 0
        self.history.append((self.samples, self.best_score))
        return improved

    # -- the best estimate, refined -------------------------------------------------------------
    def seed_estimate(self, q: np.ndarray) -> None:
        """Start from a known estimate (a re-queued model): it is the best so far."""
        with np.errstate(all="ignore"):
            errors = coherence_errors(self.problem, np.asarray(q, dtype=float), iterations=1,
                                      ranks=self.ranks)
        self.best_q = np.asarray(q, dtype=float)
        self.best_errors = errors
        self.best_score = self.score_fn(np.concatenate(errors), self.scale)

    def split(self, errors: tuple[np.ndarray, ...], window: float = 0.35):
        """The outlier threshold of ``errors`` and, per channel, the measures below it
        (:meth:`~kanagen.runtime.refine.Refinement.split`)."""
        return self.refinement.split(errors, window)

    def _local_optimisation(self, max_iter: int = 10) -> None:
        """LO-RANSAC (Chum, Matas & Kittler 2003): a sample that beats the best is refined
        at once on the measures it explains, and the refined estimate kept if it scores
        better. A minimal sample of nearby measures extrapolates badly; without this the
        search keeps a partial structure whenever its budget held few spread samples."""
        refined = self.refinement.refined(self.best_q, self.best_errors, max_iter)
        if refined is not None and refined[1] > self.best_score:
            self.best_q, self.best_score, self.best_errors = refined

    def consider(self, q: np.ndarray, floor: float) -> bool:
        """An estimate from elsewhere (the parent's) as a candidate: refined in this model on
        the measures it explains (:meth:`_local_optimisation`'s refinement), and taken as the
        best when it scores at least ``floor`` and better than the best so far. True when
        taken. Never raises."""
        try:
            with np.errstate(all="ignore"):
                q = self.fam.with_slacks(np.asarray(q, dtype=float), self.problem.k,
                                         self.model)
                errors = coherence_errors(self.problem, q, iterations=1, ranks=self.ranks)
                refined = self.refinement.refined(q, errors)
        except (np.linalg.LinAlgError, ValueError, FloatingPointError, ZeroDivisionError):
            return False
        if refined is None or not (refined[1] >= floor and refined[1] > self.best_score):
            return False
        self.best_q, self.best_score, self.best_errors = refined
        return True

    def finish(self, q0: np.ndarray, Q0: np.ndarray, window: float = 0.35,
               max_iter: int = 100, short_of: float | None = None) -> RobustEstimate | None:
        """Threshold, refine on the inliers, threshold again, ... (report §4), until the
        inliers stop changing (at most ``_REFINE_ROUNDS`` refinements): the reported
        estimate (its cost, d, Q̃) is the fit on the reported inliers. With an initializer,
        the first refinement also starts from its closed form on the inliers (the
        eight-point F on all of them, say) and keeps the fit of least cost: a minimal
        sample's estimate can sit in another basin of a non-linear cost.

        ``short_of``: the inliers the model must reach to matter, when only their number
        decides (its parent's test across a change of equations per measure,
        :func:`~kanagen.runtime.lattice.explains_more`). While it has fewer, its refinements
        run in laps and stop when a lap makes no progress.

        Returns None when no sample gave an estimate.
        """
        if self.best_q is None:
            return None
        first = None if self.draws.initializer is None else \
            (lambda rows: self.draws.starts(rows[self.channel]))
        result, rows, errors, threshold = self.refinement.rounds(
            self.best_q, self.best_errors, q0, Q0, first, window, max_iter, short_of)
        names = [ch.name for ch in self.problem.channels]
        return RobustEstimate(
            model=self.model,
            fit=result,
            inliers=dict(zip(names, rows, strict=True)),
            outliers={n: np.flatnonzero(~(e < threshold)) for n, e in zip(names, errors,
                                                                          strict=True)},
            errors=dict(zip(names, errors, strict=True)),
            threshold=threshold,
            relevance=self.score_fn(np.concatenate(errors), self.scale),
            samples=self.samples,
            degenerate=self.degenerate,
            history=list(self.history),
            scale=self.scale,
            chance=Chance(functools.partial(
                false_alarms, self.problem, result.q, threshold,
                hypotheses(sum(ch.size for ch in self.problem.channels),
                           self.draws.sample_size), self.draws.sample_size)),
        )


def robust_fit(fam: ModelFamily, model: str | None = None, data: Mapping | None = None,
               info: Mapping | None = None, *, channel: str | None = None,
               scale: float | None = None, scorer: str | Callable = "relevance",
               seed: int | None = 0, max_samples: int = 500, confidence: float | None = None,
               inlier_ratio: float | None = None, adaptive: bool = False,
               min_samples: int = 20, no_gain: int | None = None,
               time_budget: float | None = None, stop: Callable | None = None,
               window: float = 0.35, q0=None, Q0=None, constants=None,
               initializers: dict | None = None,
               correct_bias: bool | str = False) -> RobustEstimate | None:
    """Robust estimate of one model: random minimal samples, threshold, refinement.

    ``scale``: ``L*``; default: the χ² quantile of the measures' equations
    (:func:`~kanagen.runtime.scoring.default_scale`), said in the result's ``scale``.

    Stopping: ``max_samples``; eq. 25 when ``confidence`` and ``inlier_ratio`` are given;
    else, ``adaptive``, eq. 25 at the inlier ratio of the best estimate so far (``confidence``
    default 0.99; at least ``min_samples``; off by default: ``max_samples`` is this search's
    budget, where the :class:`Estimator` adapts each model's); ``no_gain`` samples without a
    better estimate; ``time_budget`` seconds; or ``stop(history)`` returning True (history:
    list of (samples, best score)).
    ``initializers``: ``{model: name or callable or None}`` over the spec's closed-form
    initializer (see :class:`~kanagen.Estimator`).
    ``correct_bias``: the refined estimate on the inliers less its second-order bias, as
    :func:`kanagen.fit`'s (True, or ``"relative"``: the noise from the reduced χ²).

    Examples
    --------
    >>> import numpy as np, kanagen
    >>> rng = np.random.default_rng(1)
    >>> x = rng.uniform(0, 10, 60)
    >>> xy = np.c_[x, 2 * x + 1 + rng.normal(0, 0.1, 60)]
    >>> xy[:15, 1] += rng.choice([-1, 1], 15) * rng.uniform(3, 20, 15)  # 25 % outliers
    >>> est = kanagen.robust_fit(kanagen.load("line"), "line", data={"point": xy},
    ...                          info={"point": 100.0}, max_samples=100)
    >>> sorted(set(range(15)) & set(est.inliers["point"]))
    []
    >>> round(est.params["a"], 1), round(est.scale, 2)  # the default L* of one equation
    (2.0, 10.83)
    """
    model = model or fam.null_model
    check_correct_bias(correct_bias)
    problem = make_problem(fam, model, {} if data is None else data, info, q0, Q0, constants)
    assumed = fam.warn_assumed(constants)
    names = [ch.name for ch in problem.channels]
    if channel is None:
        if len(names) != 1:
            raise ValueError(f"channel= is required: data has channels {names}")
        channel = names[0]
    if channel not in names:
        raise ValueError(f"no data for channel {channel!r} (data has {names})")
    check_search_options(scale=scale, seed=seed, max_samples=max_samples,
                         confidence=0.99 if confidence is None else confidence,
                         inlier_ratio=0.5 if inlier_ratio is None else inlier_ratio,
                         window=window, min_samples=min_samples)
    search = ModelSearch(fam, model, problem, names.index(channel), problem.q0,
                         np.random.default_rng(seed), scale, scorer,
                         initializer=model_initializers(fam, initializers).get(model))
    budget = max_samples
    fixed = confidence is not None and inlier_ratio is not None
    if fixed:
        budget = min(budget, samples_for_confidence(confidence, inlier_ratio,
                                                    search.draws.sample_size))

    def planned() -> int:  # adaptive: eq. 25 at the best estimate's inlier ratio
        needed = None if fixed or not adaptive else \
            search.samples_needed(0.99 if confidence is None else confidence)
        return budget if needed is None else min(budget, max(needed, min_samples))

    started = time.perf_counter()
    since_gain = 0
    while search.samples < planned() and not search.exhausted:
        since_gain = 0 if search.step() else since_gain + 1
        if no_gain is not None and since_gain >= no_gain:
            break
        if time_budget is not None and time.perf_counter() - started > time_budget:
            break
        if stop is not None and stop(search.history):
            break
    est = search.finish(problem.q0, problem.Q0, window)
    if est is not None and correct_bias:  # the ML fit on the inliers, then its bias
        rows = tuple(np.asarray(est.inliers[ch.name], dtype=int) for ch in problem.channels)
        est = replace(est, fit=corrected(fam, model, problem.subset(rows), est.fit,
                                         relative=correct_bias == "relative"))
    if est is not None and assumed:
        est = replace(est, fit=replace(est.fit, assumed=assumed))
    return est
