"""The random minimal samples of one model's search (report §4, eq. 21–25): which measures a
sample takes, the solves of each, every measure's error at each estimate, and how many
samples find a structure of a given share of the measures.

:class:`MinimalSamples` draws a sample — uniform, local (NAPSAC), or a child's extra measures
among its parent's outliers with the rest among its parent's inliers — solves it from each
start (eq. 21) and scores each solution against every measure (eq. 24): in one engine call
(:mod:`~kanagen.runtime.fastsample`), a burst of samples per call, or solve by solve. The
:class:`~kanagen.runtime.robust.ModelSearch` keeps the best of them and refines it.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from .engine.data import arrays
from .engine.sample import minimal_solve as solve_sample
from .family import ModelFamily
from .fastsample import MINIMAL, draws_as_numpy, sampler_for
from .fit import fit_problem
from .initializers import InitializerFn, equivalent, start_from
from .iterate import CONVERGED, UNVERIFIED
from .minimal import coherence_errors
from .projector import Problem
from .scoring import relevance

_NEIGHBOURHOOD = 4  # a local sample is drawn among this many sample sizes of nearest measures


class MinimalSamples:
    """The samples of one model's search and their scored estimates.

    Parameters
    ----------
    fam, model, problem, channel, pool, sample_size, parent_free, base, initializer, local :
        As for :class:`~kanagen.runtime.robust.ModelSearch`.
    start : ndarray
        Starting value of the minimal solves, with the model's slacks.
    rng : numpy.random.Generator
    scale, score_fn, ranks :
        The search's ``L*``, its scorer (eq. 29's relevance lets the engine abandon a
        hopeless solution, and draw the samples in bursts) and the equations per measure of
        each channel at ``start``.
    """

    def __init__(self, fam: ModelFamily, model: str, problem: Problem, channel: int,
                 start: np.ndarray, rng: np.random.Generator, scale: float,
                 score_fn: Callable, ranks: tuple[int, ...], pool: np.ndarray | None = None,
                 sample_size: int | None = None, parent_free: int | None = None,
                 base: np.ndarray | None = None, initializer: InitializerFn | None = None,
                 local: float = 0.0):
        self.fam = fam
        self.model = model
        self.problem = problem
        self.channel = channel
        self.start = start
        self.rng = rng
        self.scale = scale
        self.score_fn = score_fn
        self.ranks = ranks
        self.initializer = initializer
        self.equivalent = equivalent(initializer)
        self.constants = dict(zip(fam.constant_names, problem.k.tolist(), strict=True))
        size = problem.channels[channel].size
        self.pool = np.arange(size) if pool is None else np.asarray(pool, dtype=int)
        self.sample_size = sample_size or self._minimal(parent_free)
        # a child model: the extra measures come from `pool` (not coherent with the parent),
        # the rest of a full minimal sample from `base` (the parent's inliers)
        self.base = None if base is None else np.asarray(base, dtype=int)
        self.base_size = self._minimal(None) - self.sample_size if base is not None else 0
        # a sample must fix this many equations (constraints + sampled), else it is degenerate
        equations = self.size * self._equations_per_measure()
        free = fam.free_dof(model, self.problem.k)
        self.full_rank = min(fam.n, fam.n - free + equations)
        self.overdetermined = equations > free
        self.local = float(local)
        self._sampler = sampler_for(self)  # the engine's sample, or None
        # several samples per engine call (Sampler.burst): eq. 29's relevance scored there,
        # uniform samples only, drawn as numpy draws them (fastsample.draws_as_numpy)
        self._pool64 = self.pool.astype(np.int64)
        self._base64 = np.zeros(0, np.int64) if self.base is None else \
            self.base.astype(np.int64)
        #: samples are drawn a burst per engine call (:meth:`burst`)
        self.bursts = self._sampler is not None and self.score_fn is relevance and \
            not (self.local > 0.0 and self.base_size == 0) and \
            draws_as_numpy(((self.pool.size, self.sample_size),
                            (self._base64.size, self.base_size)))
        self._neighbours: np.ndarray | None = None

    @property
    def size(self) -> int:
        """The measures of a full minimal sample (from the pool and from the base)."""
        return self.sample_size + self.base_size

    @property
    def exhausted(self) -> bool:
        """Too few measures in the pools for one sample."""
        short_base = self.base is not None and self.base.size < self.base_size
        return self.pool.size < self.sample_size or short_base

    def _equations_per_measure(self) -> int:
        """Independent equations of one measure (on its equations' zero set)."""
        return max(self.ranks[self.channel], 1)

    def _minimal(self, parent_free: int | None) -> int:
        free = self.fam.free_dof(self.model, self.problem.k)
        extra = free if parent_free is None else max(free - parent_free, 1)
        return max(1, math.ceil(extra / self._equations_per_measure()))

    # -- a sample -------------------------------------------------------------------------------
    def draw(self) -> np.ndarray:
        """A sample's measures: ``sample_size`` of the pool, uniform or local with
        probability ``local``, then ``base_size`` of the base."""
        rows = self._from_pool()
        if self.base_size > 0:
            rows = np.r_[rows, self.rng.choice(self.base, size=self.base_size, replace=False)]
        return rows

    def _from_pool(self) -> np.ndarray:
        """The sampled measures of the pool: uniform, or local with probability ``local``."""
        size = self.sample_size
        if self.local > 0.0 and self.base_size == 0 and self.pool.size > size \
                and self.rng.random() < self.local:
            if self._neighbours is None:
                from scipy.spatial import cKDTree

                X = self.problem.channels[self.channel].X[self.pool]
                k = min(self.pool.size, _NEIGHBOURHOOD * size)
                self._neighbours = self.pool[cKDTree(X).query(X, k)[1]]
            near = self._neighbours[self.rng.integers(self.pool.size)]
            return np.r_[near[0], self.rng.choice(near[1:], size=size - 1, replace=False)]
        return self.rng.choice(self.pool, size=size, replace=False)

    def scored(self, rows: np.ndarray, best: float = -np.inf, compiled: bool = True):
        """The sample's solutions, each with every measure's error (eq. 24): in one engine
        call (:mod:`~kanagen.runtime.fastsample`; a solution whose relevance is bounded below
        ``best`` comes without its errors) when there is a sampler and ``compiled``, else
        solve by solve."""
        if self._sampler is not None and compiled:
            out = self._sampler(rows, best)
            if out is not None:
                return out
        return ((q, coherence_errors(self.problem, q, iterations=1, ranks=self.ranks))
                for q in self.solutions(rows))

    def burst(self, limit: int, best: float):
        """Up to ``limit`` samples in one engine call
        (:meth:`~kanagen.runtime.fastsample.Sampler.burst`): (samples scored, degenerate
        ones, outcome, the better estimate, rows), or None when it refused before drawing
        (then :attr:`bursts` is off: the samples go one by one)."""
        out = self._sampler.burst(limit, best, self._pool64, self.sample_size, self._base64,
                                  self.base_size, self.rng)
        if out is None:
            self.bursts = False
        return out

    def starts(self, rows: np.ndarray) -> list[np.ndarray]:
        """Starting values of solves on ``rows``: the initializer's candidates (none: no
        parameter of the model passes through the sample, which is skipped), else the
        parent's estimate."""
        if self.initializer is None:
            return [self.start]
        starts = []
        for cand in self.initializer(self.problem.channels[self.channel].X[rows],
                                     self.constants):
            q = start_from(self.fam, cand, self.start)
            if q is not None:
                starts.append(self.fam.with_slacks(q, self.problem.k, self.model))
        return starts

    def solutions(self, rows: np.ndarray) -> list[np.ndarray]:
        """The estimates of the sample ``rows`` that pass: minimal solves (eq. 21) of full
        rank from each start, or the full estimator on an over-determined sample."""
        out = []
        starts = self.starts(rows)
        if not starts:
            return out
        if not self.overdetermined:  # the engine's minimal solve, on the sample's rows
            A = arrays(self.problem)
            at = np.ascontiguousarray(A.start[self.channel] + rows, dtype=np.int64)
            for start in starts:
                q, solved, rank, _, _ = solve_sample(A, at, np.asarray(start, dtype=float),
                                                     *MINIMAL)
                if solved and rank >= self.full_rank:
                    out.append(q)
                    if self.equivalent:
                        break  # the other candidates are the same estimate
            return out
        sample = self.problem.subset(tuple(
            rows if i == self.channel else np.zeros(0, dtype=int)
            for i in range(len(self.problem.channels))))
        for start in starts:
            if self.initializer is not None:
                # a closed form on an over-determined sample is its least-squares hypothesis
                # already (LO and the final rounds refine the best): kept on the constraints
                c0 = self.problem.c0(start, self.problem.k)[0]
                if np.all(np.isfinite(start)) and np.max(np.abs(c0), initial=0.0) <= 1e-8:
                    out.append(start)
                continue
            # a hypothesis, scored next: its end is not verified
            fit = fit_problem(self.fam, self.model, sample, q_start=start, max_iter=20,
                              verify=False, brief=True)
            if fit.status in (CONVERGED, UNVERIFIED) and np.all(np.isfinite(fit.q)):
                out.append(fit.q)
        return out

    # -- how many samples -----------------------------------------------------------------------
    def needed(self, good: np.ndarray, confidence: float, floor: tuple[float, ...],
               afresh: int = 0) -> int | None:
        """Eq. 25 for these pools, ``good`` marking the measures of the sampled channel an
        estimate explains (the search's
        :meth:`~kanagen.runtime.robust.ModelSearch.samples_needed`): None when no sample
        can be all inliers. ``floor``: the least inlier fractions of the pool, of the base
        and of the channel planned for; ``afresh``: full samples of the model drawn before
        from every measure of the channel, and what they missed already."""
        pool = max(float(np.mean(good[self.pool])), min(floor[0], 1.0))
        p, found = pool ** self.sample_size, pool * self.pool.size
        if self.base_size:
            base = max(float(np.mean(good[self.base])), min(floor[1], 1.0))
            p, found = p * base ** self.base_size, found + base * self.base.size
        if p <= 0.0:
            return None
        if p >= 1.0:
            return 1
        miss = math.log1p(-confidence)
        if afresh:  # what full samples from every measure missed already
            share = min(max(found / max(self.problem.channels[self.channel].size, 1),
                            floor[2]), 1.0)
            if share >= 1.0:
                return 0
            miss -= afresh * math.log1p(-share ** self.size)
            if miss >= 0.0:
                return 0
        return math.ceil(miss / math.log1p(-p))
