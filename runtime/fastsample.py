"""One random sample of a robust search in one compiled call (codegen/c/kanagen_sample.c).

:class:`~kanagen.runtime.robust.ModelSearch` solves each sample from each start
(:func:`~kanagen.runtime.coherence.solve_minimal`) and scores every solution by the errors
of all measures (:func:`~kanagen.runtime.coherence.coherence_errors`); on the compiled
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

import numpy as np

from .coherence import coherence_errors, solve_minimal
from .fastpath import TWINS
from .initializers import _TWO_VIEW_Q
from .scoring import relevance

_MINIMAL = {name: inspect.signature(solve_minimal).parameters[name].default
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
        head += [index[named[i]] if i in named else -1 for i in range(len(_TWO_VIEW_Q))]
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
            errors, at = [], 1 + self.n
            for M in self.sizes:
                errors.append(block[at:at + M])
                at += M
            out.append((block[1:1 + self.n], tuple(errors)))
        return out


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
