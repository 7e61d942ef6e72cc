"""Is a structure more than chance? The a-contrario test of a found structure (Desolneux,
Moisan & Morel, *From Gestalt Theory to Image Analysis*, 2008; Moisan & Stival's ORSA, IJCV
2004, for models estimated from random samples).

A structure with ``k`` inliers among ``n`` measures is meaningful when measures without any
structure would rarely give as many: its *number of false alarms*

    NFA = N_tests · P(K ≥ k),  K ~ Binomial(n, p)

stays below ``ε`` (default 1: at most one structure a search of unstructured data would
report, on average). ``p`` is the chance that a measure of the null data passes the
structure's threshold, taken where the NFA is least; ``N_tests`` counts the hypotheses a
search could try (:func:`hypotheses`, ORSA's count): every minimal sample of ``s`` of the
``n`` measures, times the ``n`` inlier counts that choice of threshold could give. Not the
samples a search drew: its estimate is refined on its inliers, which no drawn sample is.
On AdelaideRMF without the number of structures (seeds 0 and 1), the samples' count left
29 and 27 structures beyond the scenes' own, mostly groups of mismatches; ORSA's leaves 9
and 10 (one on an F scene), and misses one small motion (toycubecar's 14 matches).

The null data are measures uniform in the box of the channel's values (each column uniform
between its least and greatest value): the null of the a-contrario tests in images (ORSA's
chance of a match near an epipolar line is the band's area over the image's). A box keeps
a structure along an axis (a horizontal line, a constant reading) from being read as its
own null, as a null drawn from the data's own marginals would. ``p`` is measured by Monte
Carlo on ``draws`` null measures with the structure's own coherence errors (eq. 24), so any
model of any family is tested the same way.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np
from scipy.special import bdtrc

from .inputs import ChannelData
from .minimal import coherence_errors
from .projector import Problem

#: null measures drawn per channel to measure ``p`` (its relative error ~1/sqrt(p draws))
DRAWS = 4000


def hypotheses(n: int, s: int) -> float:
    """ORSA's count of the hypotheses a search of minimal samples of ``s`` among ``n``
    measures tries: ``C(n, s)`` models, times the ``n`` inlier counts a threshold chosen from
    the data may give."""
    if n < s:
        return 1.0
    try:
        return float(math.comb(n, s)) * n
    except OverflowError:  # beyond a float: no tail that is not 0 makes it meaningful
        return math.inf


def false_alarms(problem: Problem, q: np.ndarray, threshold: float, tests: float,
                 sample: int = 0, *, boxes: Sequence | None = None,
                 explained: Callable | None = None, seed: int = 0,
                 draws: int = DRAWS) -> float:
    """The NFA of the structure ``q`` on the measures of ``problem``, at its most meaningful
    threshold up to ``threshold``: ``tests`` times the least, over the thresholds ``t`` at
    its measures' errors, of the chance that null measures (:func:`null_channel`: uniform
    in each channel's box, ``boxes[c] = (lo, hi)``, default the box of the channel's
    measures) give at least as many inliers under ``t``.

    ``explained(channels)``, when given, says which measures (a boolean array per channel)
    structures found before explain: they count on neither side. The measures left then
    avoid the regions those structures hold, and so do the null's (a band left between two
    bands taken out is not dense by chance), and a structure's remnant (its measures left
    near it, beyond the tighter threshold it was taken out at) does not make another.

    The ``sample`` measures of the minimal sample a structure comes from are its inliers
    by construction: they count on neither side (ORSA's ``k − s`` of ``n − s``). Channels
    of different chances ``p_c`` pool into one binomial of their mean chance, whose tail
    bounds theirs above the mean (Hoeffding 1956). Non-finite errors (a measure the
    projection cannot bring onto the model) are outliers."""
    rng = np.random.default_rng(seed)
    own = coherence_errors(problem, q)
    gone = [np.zeros(e.size, bool) for e in own] if explained is None else \
        [np.asarray(g, bool) for g in explained(problem.channels)]
    sizes = np.array([np.count_nonzero(~g) for g in gone])
    own = np.concatenate([np.where(g, np.inf, e) for e, g in zip(own, gone, strict=True)])
    t = np.sort(own[own < threshold])  # the thresholds: k = 1, 2... inliers
    n, k = int(sizes.sum()) - sample, np.arange(1, t.size + 1) - sample
    if n <= 0 or not np.any(k > 0):
        return float(tests)
    t, k = t[k > 0], k[k > 0]
    channels = tuple(null_channel(ch, draws, rng, None if boxes is None else boxes[c])
                     for c, ch in enumerate(problem.channels))
    left = [np.ones(ch.size, bool) for ch in channels] if explained is None else \
        [~np.asarray(e, bool) for e in explained(channels)]
    errors = coherence_errors(replace(problem, channels=channels), q)
    # (hits + 1) / (draws + 1): never 0, so a rare null inlier is not read as impossible
    p = sum(m * (np.searchsorted(np.sort(e[keep]), t, side="right") + 1) / (keep.sum() + 1)
            for m, e, keep in zip(sizes, errors, left, strict=True) if m) / sizes.sum()
    # P(K >= k) of K ~ Binomial(n, p): scipy.stats' binom.sf(k - 1), without importing
    # scipy.stats (half a second of a process's first search)
    tail = float(np.min(bdtrc(k - 1, n, p)))
    return tests * tail if tail > 0 else 0.0  # (an infinite count times a 0 tail: 0)


def null_channel(ch: ChannelData, draws: int, rng: np.random.Generator,
                 box: tuple | None = None) -> ChannelData:
    """``draws`` measures of ``ch``'s null law: each column uniform in ``box = (lo, hi)``
    (default: between its least and greatest value in ``ch``); a measure's information and
    exact values those of one of ``ch``'s rows drawn at random (none when ``ch`` has
    none)."""
    if not ch.size:
        return ch
    lo, hi = (ch.X.min(axis=0), ch.X.max(axis=0)) if box is None else box
    X = lo + (hi - lo) * rng.random((draws, ch.X.shape[1]))
    rows = rng.integers(ch.size, size=draws)
    per_measure = ch.Q.ndim == 3
    return ChannelData(ch.name, X, ch.index, np.ascontiguousarray(X[:, ch.index]),
                       ch.Q[rows] if per_measure else ch.Q,
                       ch.G[rows] if per_measure else ch.G,
                       None if ch.fixed is None else ch.fixed[rows])
