"""Random samples of a robust search in one engine call (runtime/engine/sample.py).

:class:`~kanagen.runtime.robust.ModelSearch` solves each sample from each start (eq. 21)
and scores every solution by the errors of all measures (eq. 24). :class:`Sampler` makes
the whole sample — a closed form's candidates put into the start, their minimal solves and
the errors at each solution that passes — one call of the engine's
:func:`~kanagen.runtime.engine.sample.sample` on the problem's arrays, and a batch of samples
(drawn from the search's generator as ``Generator.choice`` draws them, scored by relevance,
eq. 29, until one beats the best) one call of :func:`~kanagen.runtime.engine.sample.search`.
With relevance, a solution whose relevance the measures left cannot lift to the best so far
is abandoned (an exact bound: the search is the same).
"""

from __future__ import annotations

import ctypes
import inspect

import numpy as np

from .engine.data import arrays, per_channel
from .engine.sample import CANDIDATES, WIDTH, choice, sample, search
from .minimal import minimal_solve_problem
from .scoring import relevance

#: ``(max_iter, xtol, eps)`` of the search's minimal solves: minimal_solve_problem's defaults
MINIMAL = tuple(inspect.signature(minimal_solve_problem).parameters[name].default
                for name in ("max_iter", "xtol", "eps"))


class Sampler:
    """``sampler(rows) -> [(q, errors per channel), ...]`` for a search of ``model`` on the
    validated ``problem``: the solutions of the sample ``rows`` (indices into the sampled
    ``channel``) from ``start`` or from the candidates of the closed form at address
    ``form`` (0: the start alone; ``names``: the parameter index of each of its values,
    −1 for one its candidates do not name; ``constants``: what it reads), each with
    every measure's error at one projection step capped at ``ranks`` equations (eq. 24),
    as the Python path gives them;
    None when the closed form leaves the sample to the Python path.
    """

    def __init__(self, problem, channel: int, start: np.ndarray, ranks, form: int,
                 names: np.ndarray, constants: np.ndarray, equivalent: bool, full_rank: int,
                 size: int, scale: float, relevance: bool):
        self.A = A = arrays(problem)
        self.n = start.size
        self.channel = channel
        self.offset = int(A.start[channel])
        self.start = np.ascontiguousarray(start, dtype=float)
        self.form, self.names = int(form), np.asarray(names, dtype=np.int64)
        self.consts = np.ascontiguousarray(constants, dtype=float)
        self.equivalent, self.full_rank = bool(equivalent), int(full_rank)
        self.caps = np.asarray(ranks, dtype=np.int64)
        self.scale = float(scale)
        self.relevance = relevance  # the scorer is eq. 29's: hopeless solutions abandoned
        total = A.chan.size
        self.qs = np.empty((CANDIDATES, self.n))
        self.errors = np.empty((CANDIDATES, total))
        self.complete = np.zeros(CANDIDATES, dtype=np.bool_)
        self.scores = np.empty(CANDIDATES)
        self.rows = np.empty(size, dtype=np.int64)
        self.best_q, self.best_errors = np.empty(self.n), np.empty(total)
        self._generator = (None, 0, 0)  # the search's bit generator and its addresses

    def _args(self):
        return (self.start, self.form, self.consts, self.names, self.equivalent,
                self.full_rank, *MINIMAL, self.caps, self.scale)

    def __call__(self, rows: np.ndarray, best: float = -np.inf):
        """The solutions of the sample ``rows``, as ``(q, errors)``; with the scorer
        relevance and the ``best`` score so far, ``errors`` is None for a solution that
        cannot beat it (its relevance is bounded below ``best``)."""
        self.rows[:] = rows
        self.rows += self.offset
        count = sample(self.A, self.rows, *self._args(), best if self.relevance else -np.inf,
                       self.qs, self.errors, self.complete, self.scores)
        if count < 0:
            return None
        return [(self.qs[j].copy(),
                 per_channel(self.A, self.errors[j].copy()) if self.complete[j] else None)
                for j in range(count)]

    def burst(self, limit: int, best: float, pool: np.ndarray, kpool: int, base: np.ndarray,
              kbase: int, rng: np.random.Generator):
        """Up to ``limit`` samples in one engine call, each of ``kpool`` measures of
        ``pool`` and ``kbase`` of ``base`` (int64 arrays) drawn with ``rng``'s bit generator
        as ``rng.choice(pool, kpool, replace=False)`` then ``rng.choice(base, kbase, ...)``
        draw them (:func:`draws_as_numpy`), scored by relevance against ``best``, stopping
        after one that beats it:
        ``(samples scored, of them without a solution, outcome, (q, relevance, errors) of the
        best, the rows of a sample left to the Python)``, the outcome 0 at the limit, 1 when
        the last sample beat ``best``, 2 when the closed form left the sample drawn last to
        the Python (not counted)."""
        function, state = self._addresses(rng)
        done, degenerate, outcome, score = search(
            self.A, self.channel, pool, kpool, base, kbase, limit, function, state,
            *self._args(), best, self.rows, self.qs, self.errors, self.complete, self.scores,
            self.best_q, self.best_errors)
        found = rows = None
        if outcome == 1:
            found = (self.best_q.copy(), float(score),
                     per_channel(self.A, self.best_errors.copy()))
        elif outcome == 2:
            rows = self.rows - self.offset
        return done, degenerate, outcome, found, rows

    def _addresses(self, rng: np.random.Generator) -> tuple[int, int]:
        """The addresses of ``rng``'s bit generator's ``next_uint32`` and state."""
        generator = rng.bit_generator
        if self._generator[0] is not generator:
            self._generator = (generator, *generator_addresses(generator))
        return self._generator[1], self._generator[2]


def generator_addresses(generator) -> tuple[int, int]:
    """``(next_uint32, state)`` addresses of a NumPy bit generator (its ctypes interface)."""
    face = generator.ctypes
    return ctypes.cast(face.next_uint32, ctypes.c_void_p).value, int(face.state_address)


#: Generator.choice(replace=False) switches to a tail shuffle, which the engine's choice
#: does not replicate, above this population when more than 1/_TAIL of it is drawn
_FLOYD_MAX, _TAIL = 10_000, 50
_MATCHES: list = []  # draws_as_numpy's check, made once a process


def draws_as_numpy(draws) -> bool:
    """Can the engine draw ``(population, count)`` samples (each pair: one
    ``rng.choice(population, count, replace=False)``) exactly as NumPy draws them? Its
    :func:`~kanagen.runtime.engine.sample.choice` follows NumPy's ``Generator.choice``
    (Floyd's algorithm, then a shuffle, on bounded 32-bit draws); this installation's
    NumPy is checked once, on draws of every kind a search makes: any difference, and the
    searches draw in Python (the same samples, one call per sample)."""
    if any(n > _FLOYD_MAX and k > n // _TAIL for n, k in draws):
        return False
    if not _MATCHES:
        _MATCHES.append(_check_choice())
    return _MATCHES[0]


def _check_choice() -> bool:
    ours, theirs = np.random.default_rng(2024), np.random.default_rng(2024)
    function, state = generator_addresses(ours.bit_generator)
    idx = np.empty(16, dtype=np.int64)
    for size, k in [(1, 1), (2, 2), (7, 7), (8, 7), (9, 1), (60, 2), (200, 5), (286, 7),
                    (1000, 8), (4099, 3), (10_000, 16), (123_457, 4)] * 5:
        choice(function, state, size, k, idx)
        if not np.array_equal(idx[:k], theirs.choice(size, k, replace=False)):
            return False
    return ours.bit_generator.state == theirs.bit_generator.state


def sampler_for(draws) -> Sampler | None:
    """The engine's sampler of a search's samples
    (:class:`~kanagen.runtime.sampling.MinimalSamples`), or None when they take the Python
    path: slacks (a candidate's slacks are set in Python), over-determined samples (fitted),
    an initializer without a compiled :class:`~kanagen.runtime.initializers.Kernel`."""
    problem, init = draws.problem, draws.initializer
    if draws.fam.slack_names or draws.overdetermined:
        return None
    address, names, constants = 0, np.full(WIDTH, -1, dtype=np.int64), np.zeros(0)
    if init is not None:
        kernel = getattr(init, "kernel", None)
        if kernel is None:
            return None
        index = {name: i for i, name in enumerate(draws.fam.parameter_names)}
        for column, name in kernel.names:
            names[column] = index[name]
        constants = np.array([draws.constants[name] for name in kernel.constants])
        address = kernel.address()
    return Sampler(problem, draws.channel, draws.start, draws.ranks, address, names,
                   constants, draws.equivalent, draws.full_rank, draws.size, draws.scale,
                   draws.score_fn is relevance)
