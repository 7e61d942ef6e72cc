"""One random sample of a robust search in one compiled call (codegen/c/kanagen_sample.c).

:class:`~kanagen.runtime.robust.ModelSearch` solves each sample from each start
(:func:`~kanagen.runtime.minimal.minimal_solve_problem`) and scores every solution by the errors
of all measures (:func:`~kanagen.runtime.minimal.coherence_errors`); on the compiled
backend each of these is a C call with its input packed anew. :class:`Sampler` makes the
whole sample — the closed form's candidates put into the start, their minimal solves and
the errors at each solution that passes — one call of ``kg_sample`` on the problem packed
once: the same C functions in the same order, so the same solutions and errors. The
scoring stays in Python (any scorer); with relevance (eq. 29), a solution whose relevance
the measures left cannot lift to the best so far is abandoned in C (an exact bound: the
search is the same).
"""

from __future__ import annotations

import ctypes
import inspect
import weakref

import numpy as np

from .fastpath import TWIN_WIDTH, TWINS
from .minimal import coherence_errors, minimal_solve_problem
from .scoring import relevance

_MINIMAL = {name: inspect.signature(minimal_solve_problem).parameters[name].default
            for name in ("max_iter", "xtol", "eps")}  # the search's solves use the defaults
#: the tolerance of a sample's coherence errors (coherence_errors' default)
_TOL = inspect.signature(coherence_errors).parameters["tol"].default


class Sampler:
    """``sampler(rows) -> [(q, errors per channel), ...]`` for a search of ``model`` on the
    validated, compiled ``problem``: the solutions of the sample ``rows`` (indices into the
    sampled ``channel``) from ``start`` or from the candidates of the compiled ``twin``
    (its registry name, None for the start alone), each with every measure's error at one
    projection step capped at ``ranks`` equations (eq. 24), as the Python path gives them;
    None when the C leaves the sample to the Python path (a degenerate sample for the twin,
    non-finite input).
    """

    def __init__(self, problem, channel: int, start: np.ndarray, ranks, twin: str | None,
                 equivalent: bool, full_rank: int, size: int, constants, scale: float,
                 relevance: bool):
        fast, model = problem.compiled
        self.fast, self.n = fast, fast.n
        self.sizes = [ch.X.shape[0] for ch in problem.channels]
        index = {name: i for i, name in enumerate(fast.names)}
        named = dict(TWINS[twin]) if twin is not None else {}
        head = [channel, size, 0 if twin is None else list(TWINS).index(twin) + 1,
                int(equivalent), full_rank, _MINIMAL["max_iter"], _MINIMAL["xtol"],
                _MINIMAL["eps"], scale]
        self.best_at = len(head)  # the best score so far, written at each call
        head += [-np.inf, *ranks]
        head += [constants["cx"], constants["cy"], constants["f0"]] if twin is not None \
            else [0.0, 0.0, 0.0]
        head += [index[named[i]] if i in named else -1 for i in range(TWIN_WIDTH)]
        self.sin = np.array(head + list(np.asarray(start, dtype=float)) + [0.0] * size)
        self.rows_at = len(head) + self.n
        self.relevance = relevance  # the scorer is eq. 29's: hopeless solutions abandoned
        total = sum(self.sizes)
        self.out = np.empty(1 + 4 * (1 + self.n + total))
        # kg_coherence's input of the whole problem, this sampler's own (packed once; the
        # start in its start and prior slots: it must be finite for kg_read)
        self._ws = fast._packed_at(model, problem, start, problem.eps, 1, _TOL, 0,
                                   own=True)[0]
        self.inp = self._ws[2]
        self._sin = ctypes.c_void_p(self.sin.ctypes.data)
        self._out = ctypes.c_void_p(self.out.ctypes.data)
        self.width = 1 + self.n + total
        # kg_search's counts and output (the best solution: its q and errors)
        self.iin = np.zeros(5, dtype=np.int64)
        self.bout = np.empty(4 + self.n + total)
        self._iin = ctypes.c_void_p(self.iin.ctypes.data)
        self._bout = ctypes.c_void_p(self.bout.ctypes.data)

    def __call__(self, rows: np.ndarray, best: float = -np.inf):
        """The solutions of the sample ``rows``, as ``(q, errors)``; with the scorer
        relevance and the ``best`` score so far, ``errors`` is None for a solution that
        cannot beat it (its relevance is bounded below ``best``)."""
        self.sin[self.best_at] = best if self.relevance else -np.inf
        self.sin[self.rows_at:] = rows
        if self.fast.sample(self.inp, self._sin, self._out) != 0:
            return None
        count, width, out = int(self.out[0]), self.width, []
        for j in range(count):
            block = self.out[1 + j * width:1 + (j + 1) * width].copy()
            if not block[0]:
                out.append((block[1:1 + self.n], None))
                continue
            out.append((block[1:1 + self.n], self._per_channel(block, 1 + self.n)))
        return out

    def _per_channel(self, block: np.ndarray, at: int) -> tuple[np.ndarray, ...]:
        """The errors of every measure in ``block`` from ``at``, split per channel."""
        ends = np.cumsum([at, *self.sizes])
        return tuple(block[a:b] for a, b in zip(ends[:-1], ends[1:], strict=True))

    def burst(self, limit: int, best: float, pool: np.ndarray, kpool: int, base: np.ndarray,
              kbase: int, rng: np.random.Generator):
        """Up to ``limit`` samples in one call of ``kg_search``, each of ``kpool`` measures of
        ``pool`` and ``kbase`` of ``base`` (int64 arrays) drawn with ``rng``'s bit generator
        as ``rng.choice(pool, kpool, replace=False)`` then ``rng.choice(base, kbase, ...)``
        draw them (:func:`draws_as_numpy`), scored by relevance against ``best``, stopping
        after one that beats it:
        ``(samples scored, of them without a solution, outcome, (q, relevance, errors) of the
        best, the rows of a sample left to the Python)``, the outcome 0 at the limit, 1 when
        the last sample beat ``best``, 2 when the C left the sample drawn last to the Python
        (not counted); None when ``kg_search`` refused its input (nothing drawn)."""
        self.sin[self.best_at] = best
        self.iin[:] = (limit, pool.size, kpool, base.size, kbase)
        bitgen = rng.bit_generator.ctypes.bit_generator
        if self.fast.search(self.inp, self._sin, pool.ctypes.data, base.ctypes.data, bitgen,
                            self._iin, self._bout, self._out) != 0:
            return None
        out = self.bout
        done, degenerate, outcome = int(out[0]), int(out[1]), int(out[2])
        found = rows = None
        if outcome == 1:
            block = out.copy()
            found = (block[4:4 + self.n], float(out[3]), self._per_channel(block, 4 + self.n))
        elif outcome == 2:
            rows = self.sin[self.rows_at:].astype(int)
        return done, degenerate, outcome, found, rows


#: Generator.choice(replace=False) switches to a tail shuffle, which kg_choice does not
#: replicate, above this population when more than 1/_TAIL of it is drawn
_FLOYD_MAX, _TAIL = 10_000, 50
_MATCHES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()  # draws_as_numpy's check


def draws_as_numpy(fast, draws) -> bool:
    """Can the compiled search draw ``(population, count)`` samples (each pair: one
    ``rng.choice(population, count, replace=False)``) exactly as numpy draws them? Its
    kg_choice follows numpy's Generator.choice (Floyd's algorithm, then a shuffle, on
    bounded 32-bit draws); this installation's numpy is checked once, on draws of every
    kind a search makes: any difference, and the searches draw in Python (the same
    samples, one call per sample)."""
    if any(n > _FLOYD_MAX and k > n // _TAIL for n, k in draws):
        return False
    if fast not in _MATCHES:
        _MATCHES[fast] = _check_choice(fast)
    return _MATCHES[fast]


def _check_choice(fast) -> bool:
    ours, theirs = np.random.default_rng(2024), np.random.default_rng(2024)
    bitgen = ours.bit_generator.ctypes.bit_generator
    idx = np.empty(16, dtype=np.int64)
    for size, k in [(1, 1), (2, 2), (7, 7), (8, 7), (9, 1), (60, 2), (200, 5), (286, 7),
                    (1000, 8), (4099, 3), (10_000, 16), (123_457, 4)] * 5:
        fast.choice(bitgen, size, k, idx.ctypes.data)
        if not np.array_equal(idx[:k], theirs.choice(size, k, replace=False)):
            return False
    return ours.bit_generator.state == theirs.bit_generator.state


def sampler_for(search) -> Sampler | None:
    """The compiled sampler of a :class:`~kanagen.runtime.robust.ModelSearch`, or None
    when its samples take the Python path: an uncompiled family, slacks (a candidate's
    slacks are set in Python), over-determined samples (fitted), an initializer other than
    a registered closed form's compiled twin."""
    problem, init = search.problem, search.initializer
    if problem.compiled is None or search.fam.slack_names or search.overdetermined:
        return None
    twin = getattr(init, "twin", None) if init is not None else None
    if init is not None and twin is None:
        return None
    return Sampler(problem, search.channel, search.start, search.ranks, twin, search.equivalent,
                   search.full_rank, search.sample_size + search.base_size, search._constants,
                   search.scale, search.score_fn is relevance)
