"""The full estimator on the measures a search's estimate explains (report §4): the outlier
threshold from the error histogram, LO-RANSAC's refinement of each new best sample, and the
final threshold-and-refine rounds of :meth:`~kanagen.runtime.robust.ModelSearch.finish`.
"""

from __future__ import annotations

import bisect
import functools
import itertools
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from .engine.histogram import first_minimum, reflected_counts
from .family import ModelFamily
from .fit import fit_problem
from .influence import Influence
from .iterate import MAX_ITER, UNVERIFIED
from .minimal import coherence_errors
from .projector import Problem
from .results import DerivedQuantities, FitResult

_REFINE_ROUNDS = 6  # threshold-and-refine rounds at most (they stop when the inliers do)
_ROUND_ITER = 20  # iterations of a refinement round whose inliers may still change
_PRUNE = 10  # deletions at most that the deletion test makes in a finished fit
_PAIRS = 8  # measures of largest drops whose pairs it tries when no one measure stands out
_LEVERAGE = 3.0  # a measure of leverage above this many times the mean is cross-checked
_FEW = 0.1  # ... when the mean leverage is at most this (ten measures a parameter or more)
_CHECKS = 4  # cross-checks at most: one outlier's pull can hide another's leverage
_TIE = 1e-9  # fits whose costs differ by less than this (relative) are equally good
_SAMPLES = 32  # subsets of a refinement's problem kept (Refinement.sample)
#: a refinement that only its inliers' number can make matter (ModelSearch.finish's
#: short_of) runs in laps of this many iterations, and stops after a lap that lowered its
#: cost by less than _PROGRESS of itself
_LAP, _PROGRESS = 5, 1e-4


def outlier_threshold(errors: np.ndarray, scale: float, window: float = 0.35,
                      ceiling: float | None = None) -> float:
    """Threshold between inliers and outliers from the histogram of the errors (report §4).

    The histogram (bins of ``L*/20`` up to ``20 L*``) is smoothed over a window of
    ``window·L*`` (25–50 % of ``L*``); the threshold is its first local minimum or saddle
    after the mode. Without one in range (no outlier population there), it is the range end.
    ``ceiling`` caps it (several structures close to one another make no minimum between
    them: their errors form one slope).

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> e = np.r_[rng.chisquare(1, 200), rng.uniform(30, 80, 50)]  # inliers, outliers
    >>> 4.0 < outlier_threshold(e, 4.0) < 30.0                       # L* = 4
    True
    """
    if not 0.25 <= window <= 0.5:
        raise ValueError("the smoothing window is 25–50 % of L*")
    e = np.ascontiguousarray(np.asarray(errors, dtype=float).ravel())
    edges, half, kernel = _histogram_layout(float(scale), float(window))
    # the finite errors' counts (bins of L*/20 up to 20 L*, the clipped tail not counted),
    # reflected at 0 (errors are >= 0), smoothed; a minimum is real when the histogram
    # rises after it by more than its Poisson noise (the kernel averages about `half`
    # bins), a plateau at zero is a saddle (engine/histogram.py)
    padded = reflected_counts(e, 20.0 * scale, edges, half)
    i = first_minimum(np.convolve(padded, kernel, mode="same")[half:], half)
    threshold = max(float(edges[i + 1]), float(scale))
    return threshold if ceiling is None else min(threshold, max(float(ceiling), float(scale)))


@functools.lru_cache(maxsize=64)
def _histogram_layout(scale: float, window: float) -> tuple[np.ndarray, int, np.ndarray]:
    """:func:`outlier_threshold`'s bins (``L*/20`` wide, up to ``20 L*``: their edges), the
    half width of its smoothing window in bins and the window's triangular kernel."""
    top, width = 20.0 * scale, scale / 20.0
    edges = np.linspace(0.0, top + 1e-12 * top, int(round(top / width)) + 1)
    edges.flags.writeable = False
    half = max(1, int(round(window * scale / width / 2)))
    kernel = np.r_[np.arange(1, half + 1), np.arange(half + 1, 0, -1)].astype(float)
    kernel /= kernel.sum()  # triangular, of full width window·L*
    kernel.flags.writeable = False
    return edges, half, kernel


class Refinement:
    """Fits of one model on the measures an estimate explains (its errors below the outlier
    threshold of their histogram).

    Parameters
    ----------
    fam, model, problem : the family, the model and the validated measures (all channels).
    scale : float
        ``L*``, the error scale of the threshold.
    score_fn : callable
        The search's scorer, ``f(errors, scale)``.
    ranks : tuple of int
        Equations per measure of each channel (eq. 24's ``p•``).
    min_rows : int
        A refinement needs more measures than this (a sample's size).
    max_threshold : float, optional
        A ceiling on the outlier threshold.
    admit : callable, optional
        The model's admission test (:func:`~kanagen.runtime.initializers.admission`): a
        measure it refuses has an infinite error here (an outlier whatever its distance to
        the model's equations: a match behind a camera).
    """

    def __init__(self, fam: ModelFamily, model: str, problem: Problem, scale: float,
                 score_fn: Callable, ranks: tuple[int, ...], min_rows: int,
                 max_threshold: float | None = None, admit: Callable | None = None):
        self.fam = fam
        self.model = model
        self.problem = problem
        self.scale = scale
        self.score_fn = score_fn
        self.ranks = ranks
        self.min_rows = min_rows
        self.max_threshold = max_threshold
        self.admit = admit
        self._samples: dict = {}  # rows -> the problem on them (sample)

    def sample(self, rows) -> Problem:
        """The problem on the measures ``rows`` (per channel, index arrays), made once per
        set of rows: the rounds, the deletion tests and the verification fit the same
        inliers several times (half a two-view search's subsets are repeats), and a subset
        and its engine arrays are only read."""
        key = tuple((r.dtype.char, r.tobytes()) for r in rows)
        samples = self._samples
        out = samples.get(key)
        if out is None:
            if len(samples) >= _SAMPLES:
                del samples[next(iter(samples))]  # the oldest
            out = samples[key] = self.problem.subset(rows)
        return out

    def errors(self, q: np.ndarray, **options) -> tuple[np.ndarray, ...]:
        """Every measure's coherence error at ``q`` (eq. 24, per channel; ``options`` those
        of :func:`~kanagen.runtime.minimal.coherence_errors`), infinite where the model
        does not admit the measure."""
        return self.admitted(q, coherence_errors(self.problem, q, **options))

    def admitted(self, q: np.ndarray, errors) -> tuple[np.ndarray, ...]:
        """``errors`` at ``q``, infinite where the model does not admit the measure."""
        if self.admit is None:
            return tuple(errors)
        return tuple(e if ok is None else np.where(ok, e, np.inf)
                     for e, ok in zip(errors, self.admit(self.problem, q), strict=True))

    def split(self, errors: tuple[np.ndarray, ...], window: float = 0.35):
        """The outlier threshold of ``errors`` (per channel; :func:`outlier_threshold` with
        the search's ceiling, and its default window) and, per channel, the measures below
        it."""
        threshold = outlier_threshold(np.concatenate(errors), self.scale, window,
                                      self.max_threshold)
        return threshold, tuple(np.flatnonzero(e < threshold) for e in errors)

    def refined(self, q: np.ndarray, errors, max_iter: int = 10):
        """``q`` refined on the measures it explains (their errors ``errors``):
        ``(q, score, errors)``, or None when too few to refine or the fit failed."""
        rows = self.split(self.admitted(q, errors))[1]
        if sum(r.size for r in rows) <= self.min_rows:
            return None
        fit = fit_problem(self.fam, self.model, self.sample(rows), q_start=q,
                          max_iter=max_iter, verify=False, brief=True)  # its estimate alone
        if not np.all(np.isfinite(fit.q)):
            return None
        refined = self.errors(fit.q, iterations=1, ranks=self.ranks)
        return fit.q, self.score_fn(np.concatenate(refined), self.scale), refined

    def rounds(self, q: np.ndarray, errors, q0: np.ndarray, Q0: np.ndarray,
               first: Callable | None = None, window: float = 0.35, max_iter: int = 100,
               short_of: float | None = None):
        """Threshold, refine on the inliers, threshold again, ... (report §4) from the
        estimate ``q`` with ``errors``, until the inliers stop changing (at most
        :data:`_REFINE_ROUNDS` refinements): ``(fit, inliers, errors, threshold)``, the fit
        on the reported inliers. ``first(rows)``: more starts of the first refinement (a
        closed form on the inliers), which keeps the fit of least cost. ``short_of``: see
        :meth:`~kanagen.runtime.robust.ModelSearch.finish`.

        The rounds' fits are not verified (their ends are starts of the next); the reported
        fit is (:meth:`_verified`)."""
        result, rows, errors, threshold = self._rounds(q, errors, q0, Q0, first, window,
                                                       max_iter, short_of)
        if result is None or not np.all(np.isfinite(result.q)):
            return self._derived(result), rows, errors, threshold
        verified = self._derived(self._verified(result, rows, q0, Q0, max_iter))
        if verified.q is not result.q and not np.array_equal(verified.q, result.q) and \
                np.all(np.isfinite(verified.q)):
            errors = self.errors(verified.q)  # at the reported q
            threshold = self.split(errors, window)[0]
        return verified, rows, errors, threshold

    def _fit(self, sample: Problem, start: np.ndarray, q0, Q0, max_iter: int) -> FitResult:
        """A round's fit of the model on ``sample`` from ``start``: not verified and without
        derived quantities — its end is a start of the next round; :meth:`rounds` verifies
        and derives the one it reports."""
        return fit_problem(self.fam, self.model, sample, q_start=start, q0=q0, Q0=Q0,
                           max_iter=max_iter, verify=False, derive=False)

    def _derived(self, fit: FitResult | None) -> FitResult | None:
        """``fit`` with its derived quantities (the rounds' fits are made without)."""
        if fit is None or isinstance(fit.derived, DerivedQuantities) or fit.derived:
            return fit
        return replace(fit, derived=DerivedQuantities(self.fam, fit.q, fit.covariance,
                                                      self.problem.k, self.model))

    def _verified(self, fit: FitResult, rows, q0, Q0, max_iter: int) -> FitResult:
        """The rounds' last fit, its end verified (:func:`~kanagen.runtime.iterate.iterate`):
        a stationary point goes on from where it stopped (at once a verified minimum, or
        left along its negative curvature as a verified fit would), one stopped at its cap
        is checked where it stopped — as a verified fit's cap is; any other end is kept."""
        if fit.status not in (UNVERIFIED, MAX_ITER):
            return fit
        return fit_problem(self.fam, self.model, self.sample(rows), q_start=fit.q,
                           q0=q0, Q0=Q0, max_iter=max_iter if fit.status == UNVERIFIED else 0)

    def _rounds(self, q: np.ndarray, errors, q0: np.ndarray, Q0: np.ndarray,
                first: Callable | None, window: float, max_iter: int,
                short_of: float | None):
        """:meth:`rounds`, its fits not verified."""
        errors = self.admitted(q, errors)
        threshold, rows = self.split(errors, window)
        result = None

        def short(rows) -> bool:
            return short_of is not None and sum(r.size for r in rows) < short_of

        # the first refinement (which picks among the starts) takes max_iter iterations;
        # a later one, whose inliers may still change, a few, and the fit on the stable
        # inliers goes on to max_iter in all (a model that does not fit its data crawls: it
        # would crawl max_iter iterations every round)
        per_round = max_iter
        for round_ in range(_REFINE_ROUNDS):
            starts = [q] + (first(rows) if round_ == 0 and first is not None else [])
            result = self._race(starts, rows, q0, Q0, per_round, short(rows))
            if not np.all(np.isfinite(result.q)):
                break
            q = result.q
            errors = self.errors(q)
            threshold, new = self.split(errors, window)
            if _same(new, rows):
                result = self._go_on(result, self.sample(rows), q0, Q0, per_round,
                                     max_iter, short(rows))
                if result.q is not q and np.all(np.isfinite(result.q)):
                    errors = self.errors(result.q)  # at the reported q
                    threshold = self.split(errors, window)[0]
                break  # stable: the fit is on the reported inliers
            rows = new
            per_round = min(max_iter, _ROUND_ITER)
        else:
            result = self._fit(self.sample(rows), q, q0, Q0, max_iter)
            if np.all(np.isfinite(result.q)):
                errors = self.errors(result.q)
                threshold = self.split(errors, window)[0]
        if short(rows) or result is None or not np.all(np.isfinite(result.q)):
            return result, rows, errors, threshold
        before = rows
        pruned = self._pruned(result, rows, errors, threshold, q0, Q0, max_iter)
        if pruned is not None:
            result, rows, errors = pruned
        out = _less(before, rows)
        for check in range(_CHECKS):
            level = threshold
            checked = self._cross_checked(result, rows, threshold, q0, Q0, max_iter)
            if checked is not None:
                out = tuple(np.union1d(o, d) for o, d in
                            zip(out, _less(rows, checked[1]), strict=True))
                result, rows, errors = checked
            elif rows is before:  # nothing taken out
                return result, rows, errors, threshold
            elif check > 0:
                break
            for _ in range(_REFINE_ROUNDS):  # measures may cross the threshold: rounds again
                threshold, new = self.split(errors, window)  # (those taken out stay out)
                new = _less(new, out)
                if _same(new, rows):
                    break
                fit = self._fit(self.sample(new), result.q, q0, Q0, max_iter)
                if not np.all(np.isfinite(fit.q)):
                    break
                result, rows, errors = fit, new, self.errors(fit.q)
            if threshold > level:
                break  # the threshold rose with the inliers it took in: not settled
        threshold = self.split(errors, window)[0]
        return result, rows, errors, threshold

    def _pruned(self, fit: FitResult, rows, errors, threshold: float, q0, Q0,
                max_iter: int):
        """Measures that hold ``fit`` away from the rest taken out of its inliers ``rows``:
        ``(fit, rows, errors)`` without them, or None when none is.

        An outlier can pull a fit onto itself, its own error small, the inliers' errors all
        larger (a match near the epipoles, a point far along a line): thresholds do not see
        it. Its deletion drop (:class:`~kanagen.runtime.influence.Influence`) does: the
        measure of largest drop, when the drop exceeds the threshold — else the pair of
        largest joint drop among the :data:`_PAIRS` largest, when it exceeds twice the
        threshold (two outliers pulling together mask each other) — is left out and the fit
        made again from ``fit``; the new fit is kept when it lowers the truncated cost of
        all measures, ``Σ min(eᵢ, threshold)`` (MSAC's score, a left-out measure at most the
        threshold), and the test goes on (at most :data:`_PRUNE` deletions)."""
        def truncated(errs) -> float:
            e = np.concatenate(errs)
            return float(np.sum(np.minimum(np.where(np.isnan(e), np.inf, e), threshold)))

        total = truncated(errors)
        changed = False
        sample = self.sample(rows)
        for _ in range(_PRUNE):
            influence = Influence(sample, fit)
            drops = np.concatenate(influence.drops())
            drops = np.where(np.isnan(drops), -np.inf, drops)
            if drops.size <= self.min_rows + 2:
                break
            place = functools.partial(_place, _ends(rows))
            out = [int(np.argmax(drops))]
            if not drops[out[0]] > threshold:
                best, out = 2.0 * threshold, None
                pairs = list(itertools.combinations(np.argsort(-drops)[:_PAIRS], 2))
                joint = influence.joints([[place(a), place(b)] for a, b in pairs])
                for (a, b), d in zip(pairs, joint, strict=True):
                    if d > best:
                        best, out = d, [int(a), int(b)]
                if out is None:
                    break
            trial_rows = _without(rows, out)
            trial_sample = self.sample(trial_rows)
            trial = self._fit(trial_sample, fit.q, q0, Q0, max_iter)
            if not np.all(np.isfinite(trial.q)):
                break
            trial_errors = self.errors(trial.q)
            t = truncated(trial_errors)
            if not t < total:
                break
            fit, rows, errors, total, changed = trial, trial_rows, trial_errors, t, True
            sample = trial_sample
        return (fit, rows, errors) if changed else None

    def _cross_checked(self, fit: FitResult, rows, threshold: float, q0, Q0, max_iter: int):
        """The measures of high leverage judged by the fit of the others: ``(fit, rows,
        errors)`` without those the others do not explain, or None when they all pass.

        An outlier of high leverage (a random match: its parallax much larger than the
        scene's) moves the fit until its own error is small, and its deletion drop stays
        small too — first order misses how far the fit moved, and two such outliers mask each
        other. The others tell: every measure whose leverage exceeds :data:`_LEVERAGE` times
        the mean (at most a tenth of the inliers) is left out together, the fit is made on
        the rest, and those whose error there exceeds ``L*`` (the threshold when lower) —
        the outlier test on the model of the others, as cross-validation makes it — stay
        out. ``L*``, not the histogram's cut: where outliers crowd the histogram the cut
        rises above the inliers' own spread, and an outlier of high leverage sits just
        under it. Only with ten measures a parameter or more (mean leverage at most
        :data:`_FEW`): with fewer, every measure holds much of the fit, leverage singles
        out no one, and a tenth of them left out moves the fit of the others by itself (a
        small structure of AdelaideRMF's F scenes lost that way).

        :meth:`rounds` repeats it, with the settling rounds between, until it takes nothing
        out (at most :data:`_CHECKS` times): one outlier's pull can hide another's
        leverage (calibrated scene 56004 at 60 % outliers: with two random matches of
        leverage 0.74 and 0.82 out, a third had 0.92; direction error 0.58° → 0.32°). Not
        once the settling rounds raise the threshold: it then rises with the inliers it
        takes in (a circle fitted to a hyperbola's arc: each check took out one measure
        and the rounds took in ten, until the circle no longer beat the line and the
        lattice stopped there)."""
        levels = np.concatenate(Influence(self.sample(rows), fit).leverages())
        n = levels.size
        if not np.all(np.isfinite(levels)) or n <= self.min_rows + 2 or \
                levels.mean() > _FEW:
            return None
        order = np.argsort(-levels)[:max(1, min(n // 10, n - self.min_rows - 2))]
        suspects = order[levels[order] > _LEVERAGE * levels.mean()]
        if suspects.size == 0:
            return None
        rest = _without(rows, suspects)
        others = self._fit(self.sample(rest), fit.q, q0, Q0, max_iter)
        if not np.all(np.isfinite(others.q)):
            return None
        errors = self.errors(others.q)
        theirs = np.concatenate([e[r] for e, r in zip(errors, rows, strict=True)])
        level = min(threshold, self.scale)  # their χ² test at L*, not the histogram's cut
        out = [j for j in suspects if not theirs[j] <= level]  # nan: out
        if not out:
            return None
        if len(out) < suspects.size:
            rest = _without(rows, out)
            others = self._fit(self.sample(rest), others.q, q0, Q0, max_iter)
            if not np.all(np.isfinite(others.q)):
                return None
            errors = self.errors(others.q)
        return others, rest, errors

    def _race(self, starts, rows, q0, Q0, max_iter: int, laps: bool = False) -> FitResult:
        """The fit of least cost on ``rows`` from several starts: each runs
        :data:`_ROUND_ITER` iterations, and the cheapest goes on to ``max_iter`` in all — a
        start in a degenerate valley (focal lengths running off to the affine limit) crawls
        on without the others waiting for it. ``laps``: see :meth:`_go_on`."""
        sample = self.sample(rows)
        lap = min(max_iter, _ROUND_ITER) if len(starts) > 1 else max_iter
        if laps:
            lap = min(lap, _LAP)
        fits = [self._fit(sample, start, q0, Q0, lap) for start in starts]
        costs = [f.cost if np.isfinite(f.cost) else np.inf for f in fits]
        least = min(costs)
        # a tie (an estimate and an equivalent one: t and −t of an essential matrix) goes to
        # the closed forms on the inliers, which decide what the equations cannot (the sign
        # of t by cheirality over all of them), before the estimate the rounds came with
        order = list(range(1, len(fits))) + [0]
        best = fits[next(i for i in order if costs[i] <= least + _TIE * abs(least))]
        return self._go_on(best, sample, q0, Q0, lap, max_iter, laps)

    def _go_on(self, fit: FitResult, sample: Problem, q0, Q0, done: int,
               max_iter: int, laps: bool = False) -> FitResult:
        """``fit``, stopped at its cap of ``done`` iterations, taken on from where it stopped
        to ``max_iter`` in all (as it is when it stopped otherwise). With ``laps``, in laps of
        :data:`_LAP` iterations, stopping after one that lowered the cost by less than
        :data:`_PROGRESS` of itself: a fit crawling along a degenerate valley (a fundamental
        matrix on matches of no motion: its cost falls by 1e-6 of itself per iteration)
        stops there, one still descending (out of a plane's basin, its inliers growing)
        goes on."""
        while fit.status == MAX_ITER and done < max_iter and np.all(np.isfinite(fit.q)):
            lap = min(_LAP, max_iter - done) if laps else max_iter - done
            more = self._fit(sample, fit.q, q0, Q0, lap)
            done += lap
            if laps and not fit.cost - more.cost >= _PROGRESS * abs(fit.cost):
                return more if more.cost <= fit.cost else fit
            fit = more
        return fit


def _less(a, b) -> tuple[np.ndarray, ...]:
    """The measures of ``a`` not in ``b``, per channel (index arrays): ``np.setdiff1d``'s
    result (sorted, unique)."""
    return tuple(_setdiff(x, y) for x, y in zip(a, b, strict=True))


def _setdiff(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``np.setdiff1d(x, y)`` for index arrays; where ``x`` is increasing already (the rounds'
    inliers always are) by a table of ``y``'s indices — setdiff1d sorts both, ~20 times the
    cost on a few hundred measures."""
    if not (x.dtype.kind == y.dtype.kind == "i" and x.size and (x.size == 1 or np.all(
            x[1:] > x[:-1])) and x[0] >= 0 and (y.size == 0 or y.min() >= 0)):
        return np.setdiff1d(x, y)
    table = np.zeros(int(max(x[-1], y.max() if y.size else 0)) + 1, dtype=bool)
    table[y] = True
    return x[~table[x]]


def _same(a, b) -> bool:
    """The same measures per channel (index arrays)."""
    return all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))


def _without(rows, positions) -> tuple[np.ndarray, ...]:
    """``rows`` (index arrays per channel) less the measures at ``positions`` (numbered
    channel after channel)."""
    ends = _ends(rows)
    gone = [_place(ends, j) for j in positions]
    return tuple(np.delete(r, [i for c, i in gone if c == k]) for k, r in enumerate(rows))


def _ends(rows) -> list[int]:
    """The cumulated channel sizes of ``rows`` (index arrays per channel), from 0: where
    each channel's measures start when numbered channel after channel, and their total."""
    return np.cumsum([0] + [r.size for r in rows]).tolist()


def _place(ends: list[int], j: int) -> tuple[int, int]:
    """``(channel, index in it)`` of measure ``j`` of measures numbered channel after
    channel (``ends``: the cumulated channel sizes from 0, a list)."""
    c = bisect.bisect_right(ends, j) - 1
    return c, int(j - ends[c])
