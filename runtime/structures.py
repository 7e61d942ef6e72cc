"""Several structures in the same data (report §4, clustered data): find one, take its
inliers out, search again; then give each measure to the structure that explains it best."""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from dataclasses import replace

import numpy as np
from scipy.cluster.vq import kmeans2

from .chisquare import quantile as chi2_quantile
from .estimator import Estimator
from .family import ModelFamily
from .fit import fit_problem, make_problem
from .inputs import check_search_options
from .minimal import coherence_errors, manifold_ranks
from .refine import outlier_threshold
from .results import Chance, ModelState
from .scoring import scorer as get_scorer
from .significance import false_alarms as nfa
from .significance import hypotheses

_RESTART_SEEDS = 1000  # seeds of restart r: seed + 1000 r, then one per search
_CEILING = 2.0  # a structure's outlier threshold at most, in units of its L* (default)
_NOISE_ROUNDS = 10  # rounds of a structure's threshold at its own noise, at most
#: a structure is two when a search at this fraction of its noise variance finds a part that
#: fits at less than it (a single structure's part fits at ~3/4 of its noise, see _split)
_SPLIT = 0.25
_SPLIT_SEEDS = 500  # seeds of the searches within a structure: seed + 500 + attempt
#: seeds of the searches in the halves of a structure: seed + 700 + 4 attempt + 2 level + half
_HALF_SEEDS = 700
_HALF_LEVELS = 2  # a kept half is itself tested for two motions this many times at most


def find_structures(fam: ModelFamily, data: Mapping, info: Mapping | None = None,
                    max_structures: int = 5, model: str | None = None,
                    min_inliers: int | None = None, max_samples: int = 2000,
                    reassign: int = 5, local: float = 0.5, retries: int = 2,
                    restarts: int = 3, false_alarms: float | None = 1.0,
                    **options) -> list[ModelState]:
    """Several structures in the same data (report §4, clustered data): find one, take its
    inliers out, search again, until what it finds is no more than chance (``false_alarms``)
    or ``max_structures``; then
    (``reassign`` rounds) give each measure to the structure with the least coherence
    error among those whose threshold it passes, refit each structure on its measures, and
    repeat until the assignment is stable.

    Each structure is taken out at its own noise (where a measure has two equations or
    more): the median of its inliers' errors measures it, and the inliers under ``L*`` at
    that noise leave the data — not every measure under the search's threshold, which
    takes in a neighbouring plane's matches where the structure's noise is far below the
    one ``info`` assumes. A structure is tested for two in one: a part of it at a
    quarter of its noise that leaves a rest of its own (two planes under one homography),
    and two regions of its measures whose own estimates call each other outliers (two
    objects under one fundamental matrix); then only the part is taken out.

    The greedy search alone keeps its early mistakes: the first structure takes every
    measure under its threshold, including those of later structures near where they meet
    (two planes along their common line, two motions near the epipoles). The assignment
    rounds are the "assign, then refit" steps of Isack & Boykov's PEARL (IJCV 2012) without
    its smoothness term.

    Parameters
    ----------
    data, info : dicts by channel, as for :func:`kanagen.fit`.
    model : str, optional
        The model of every structure; default: the lattice search picks one per structure.
    min_inliers : int, optional
        A structure needs more inliers than this (default: twice the minimal sample).
    reassign : int
        Rounds of assignment and refit at most (0: the greedy result as found).
    local : float in [0, 1]
        Share of local samples (a measure and its nearest neighbours, see
        :class:`~kanagen.runtime.robust.ModelSearch`); default 0.5: structures of clustered
        data are spatially coherent and a small one is out of reach of uniform samples
        (0: uniform samples only).
    retries : int
        A search that finds nothing relevant is repeated with fresh samples up to this many
        times before the extraction stops (worth it when ``max_structures`` is the known
        number of structures); default 2.
    restarts : int
        Independent extractions (fresh samples); the one kept explains the measures best:
        least ``Σᵢ min(eᵢ, L*)`` over all measures, ``eᵢ`` the error to the closest
        structure and ``L*`` the largest of the structures' (an outlier's cost) — the
        truncated error of MSAC (Torr & Zisserman 2000) summed over the structures.
        Default 3 (three times the time of one extraction).
    false_alarms : float or None
        A structure is kept only when measures without structure would give as many inliers
        this rarely: its number of false alarms — the hypotheses a search may try (every
        minimal sample, times the measures), times the chance of its inlier count among
        measures uniform in the data's box, outside what the structures found before
        explain — at most this, shared among the ``(retries + 1) × restarts`` searches that
        may end an extraction (:mod:`~kanagen.runtime.significance`: the a-contrario test of
        Moisan & Stival's ORSA). Default 1: on average at most one structure of uniform
        outliers in a call. None: no test (the structures are then those above
        ``min_inliers``, up to ``max_structures``).
    options : the :class:`Estimator` options (``scale``, ``scorer``, ``phi``, ``seed``,
        ``channel``, ``constants``, ``max_threshold``, ``ceiling``...). ``scale`` (``L*``)
        defaults to each structure's model's χ² quantile, as the :class:`Estimator`'s.
        Structures close to one another make no minimum in the error histogram between
        them: the outlier threshold is capped at ``ceiling`` times each model's ``L*``
        (default 2 here) or at ``max_threshold`` (error units) when given.

    The defaults are the configuration measured best on AdelaideRMF
    (``experiments/adelaide.py --defaults``, docs/real_data.md).

    Returns
    -------
    list of ModelState
        Strongest (most inliers) first; ``inliers``/``outliers`` are row indices into the
        arrays given (ids follow the rows of ``data``, channel after channel). A measure is
        an inlier of one structure at most.
    """
    check_search_options(scale=options.get("scale"), seed=options.get("seed", 0),
                         max_samples=max_samples)
    if not (isinstance(max_structures, int) and max_structures >= 1):
        raise ValueError(f"max_structures must be an integer >= 1, got {max_structures!r}")
    if reassign < 0:
        raise ValueError(f"reassign must be a number of rounds >= 0, got {reassign}")
    if retries < 0:
        raise ValueError(f"retries must be >= 0, got {retries}")
    if restarts < 1:
        raise ValueError(f"restarts must be >= 1, got {restarts}")
    if false_alarms is not None and not (np.isfinite(false_alarms) and false_alarms > 0):
        raise ValueError(f"false_alarms must be a number > 0 or None, got {false_alarms!r}")
    info = dict(info or {})
    seed = options.pop("seed", 0)
    if options.get("max_threshold") is None:
        options.setdefault("ceiling", _CEILING)
    extractions = []
    for r in range(restarts):
        found, needed, scales = _extract(
            fam, data, info, max_structures, model, min_inliers, max_samples, local, retries,
            false_alarms, restarts, None if seed is None else seed + _RESTART_SEEDS * r,
            options)
        if reassign and found:
            found, scales = _assign(fam, data, info, found, needed, scales, reassign, options)
        extractions.append((found, scales))
    best = extractions[0][0]
    if len(extractions) > 1:  # one L* for all: an extraction finding nothing compares too
        top = max((max(scales) for _, scales in extractions if scales), default=1.0)
        energies = [_energy(fam, data, info, found, top, options) for found, _ in extractions]
        best = extractions[int(np.argmin(energies))][0]
    return sorted(best, key=lambda s: -len(s.inliers))


def _extract(fam: ModelFamily, data: Mapping, info: Mapping, max_structures: int,
             model: str | None, min_inliers: int | None, max_samples: int, local: float,
             retries: int, false_alarms: float | None, restarts: int, seed: int | None,
             options: Mapping) -> tuple[list[ModelState], list[int], list[float]]:
    """The greedy extraction: find a structure, take its inliers out, search again (a
    structure that chance explains, :func:`_chance`, is not taken). Returns the
    structures, the inliers each needs, and the L* of each."""
    sizes = {name: len(np.asarray(rows)) for name, rows in data.items()}
    offsets = dict(zip(sizes, np.cumsum([0] + list(sizes.values()))[:-1].tolist(),
                       strict=True))
    remaining = {name: np.arange(size) for name, size in sizes.items()}
    boxes = [(np.min(rows, axis=0), np.max(rows, axis=0)) if len(rows) else None
             for rows in (np.asarray(data[name], dtype=float) for name in sizes)]
    cut: list[tuple] = []  # what each structure explains: (model, q, search threshold)
    found: list[ModelState] = []
    needed: list[int] = []
    scales: list[float] = []
    attempt, failures = 0, 0
    while len(found) < max_structures:
        est, index = _estimator_on(fam, data, info, remaining, sizes, offsets, options,
                                   model=model, local=local,
                                   seed=None if seed is None else seed + attempt)
        attempt += 1
        if est is None:
            break
        best = est.run(max_samples=max_samples)
        if best is None or not best.samples:
            break
        sample = _minimal(est, best)
        need = min_inliers if min_inliers is not None else 2 * sample
        problem = chance = None
        if len(best.inliers) > need:
            problem = _problem_on(fam, best.model, data, info, remaining, sizes, options)
            # the hypotheses of a search, times every search that may end an extraction,
            # in each restart (the bound is on all of them)
            tests = hypotheses(len(index), sample) * (retries + 1) * restarts
            chance = None if false_alarms is None else \
                _chance(fam, problem, best, tests, sample, cut, boxes, options, attempt)
        if problem is None or (chance is not None and chance > false_alarms):
            failures += 1
            if failures > retries:
                break
            continue
        failures = 0
        scale = est.scales.get(best.model, est.scale or 1.0)
        taken, noise = _own_noise(fam, best, problem, scale, need)
        state = replace(taken, inliers=index[taken.inliers], outliers=index[taken.outliers])
        if noise is not None:
            state = _split(fam, data, info, state, scale, noise, need, sizes, offsets,
                           options, local, max_samples,
                           None if seed is None else seed + _SPLIT_SEEDS + attempt)
        state = _halves(fam, data, info, state, best.threshold, need, sizes, offsets, options,
                        local, max_samples,
                        None if seed is None else seed + _HALF_SEEDS + 4 * attempt)
        # the measures taken out are those at the structure's own noise; the assignment
        # decides at the search's threshold (a tight one would lose the tails of inliers)
        found.append(replace(state, threshold=best.threshold,
                             chance=state.chance if chance is None else Chance(None, chance)))
        cut.append((state.model, state.q, best.threshold))
        needed.append(need)
        scales.append(scale)
        for name, rows in remaining.items():
            remaining[name] = rows[~np.isin(offsets[name] + rows, state.inliers)]
    return found, needed, scales


def _chance(fam: ModelFamily, problem, state: ModelState, tests: float, sample: int,
            cut: list, boxes: list, options: Mapping, seed: int) -> float:
    """The number of false alarms of ``state`` among the measures of ``problem``
    (:func:`~.significance.false_alarms`: ``tests`` hypotheses, the null uniform in
    ``boxes`` — those of all the measures), among the measures that the structures found
    before (``cut``: their ``(model, q, threshold)``, at their search's threshold) do not
    explain."""

    def explained(channels):
        taken = [np.zeros(ch.size, bool) for ch in channels]
        for model, q, threshold in cut:
            null = make_problem(fam, model, channels=channels, q0=options.get("q0"),
                                Q0=options.get("Q0"), constants=options.get("constants"))
            for mask, errors in zip(taken, coherence_errors(null, q), strict=True):
                mask |= errors < threshold
        return taken

    return nfa(problem, state.q, state.threshold, tests, sample, boxes=boxes,
               explained=explained, seed=seed)


def _estimator_on(fam: ModelFamily, data: Mapping, info: Mapping, rows: Mapping,
                  sizes: Mapping, offsets: Mapping, options: Mapping, **more):
    """An :class:`Estimator` (``options`` and ``more``) holding the measures ``rows`` of each
    channel, and their global rows (channel offset + row) in its order; ``(None, None)``
    when there are none."""
    est = Estimator(fam, **{**options, **more})
    index = []  # estimator id -> global row (channel offset + row)
    for name, some in rows.items():
        if some.size == 0:
            continue
        est.add_measures(name, np.asarray(data[name], dtype=float)[some],
                         _rows_of(info.get(name), some, sizes[name]))
        index.append(offsets[name] + some)
    return (est, np.concatenate(index)) if index else (None, None)


def _split(fam: ModelFamily, data: Mapping, info: Mapping, state: ModelState,
           scale: float, noise: float, need: int, sizes: Mapping, offsets: Mapping,
           options: Mapping, local: float, max_samples: int,
           seed: int | None) -> ModelState:
    """The structure ``state`` (global rows; ``scale`` its L*, ``noise`` its own ``s²``), or
    the part of it that is a structure of its own.

    Two planes whose noise is far below the assumed one can both sit under one homography
    at a noise between theirs and the assumed (AdelaideRMF's elderhallb: two planes at
    ``s²`` 0.14 and 0.05 fit together at 1.6): the median of their errors is the
    mixture's, and :func:`_own_noise` cannot separate them. A search among the structure's
    inliers at :data:`_SPLIT` of its noise variance, its best part then taken at its own
    noise (a part that still holds some of both is mostly one of them: its median is
    that one's), tells: on one structure the part holds most of the measures at about 3/4
    of the noise (the median of an exponential error truncated at 1.7 ``s²``), on two it
    holds one of them at its own, far lower, noise. When that part's noise is below
    :data:`_SPLIT` of the whole's, and the best part of the rest (the same search on the
    rest: it may hold more than one structure — elderhallb's three planes under one
    homography on seed 4) fits at less than :data:`_SPLIT` of its noise under the part's
    estimate (a second structure, not the tail of the first: one plane's noisier matches
    are explained by its tighter ones' homography about as well as by their own), the
    part is the structure and the rest goes back to the data. Each noise is the median's,
    scaled by ``m / (m − d)`` (``m`` equations, ``d`` free parameters: a fit's errors
    fall short of the noise by its degrees of freedom, a small part's most), and the
    part, the rest and its part each need twice the measures of a structure (11 of
    napierb's third plane's 22 matches fit at a tenth of the noise of the 22, by luck)."""
    rows = _channel_rows(state.inliers, sizes, offsets)
    options = {k: v for k, v in options.items() if k != "scale"}
    tight = _SPLIT * noise * scale
    part = _tight_part(fam, state.model, data, info, rows, sizes, offsets, options, local,
                       max_samples, seed, tight, scale, need)
    if part is None:
        return state
    part, problem, index = part
    if len(part.inliers) < 2 * need or len(state.inliers) - len(part.inliers) < 2 * need:
        return state
    p = _equations(problem, part.q)
    free = fam.free_dof(part.model, options.get("constants"))

    def unbiased(s2: float, size: int) -> float:  # a fit's errors fall short by ν / m
        return s2 * p * size / (p * size - free) if p * size > free else np.inf

    def noise_at(errors: np.ndarray, some: np.ndarray) -> float:
        return unbiased(_noise(errors[some], p), some.size)

    if p < 1:
        return state
    at_part = np.concatenate(coherence_errors(problem, part.q))  # the part's errors
    if not noise_at(at_part, part.inliers) < _SPLIT * unbiased(noise, len(state.inliers)):
        return state
    rest = np.setdiff1d(np.arange(index.size), part.inliers)
    other = _tight_part(fam, state.model, data, info,
                        _channel_rows(index[rest], sizes, offsets), sizes, offsets, options,
                        local, max_samples, None if seed is None else seed + 1, tight,
                        scale, need)
    if other is None or len(other[0].inliers) < 2 * need:
        return state
    theirs = rest[other[0].inliers]  # the rest's own part, as positions in the structure
    own = np.concatenate(coherence_errors(problem, other[0].q))
    if not _SPLIT * noise_at(at_part, theirs) > noise_at(own, theirs):
        return state
    # its outliers: the structure's, and the rest of its inliers (they go back to the data)
    return replace(part, inliers=index[part.inliers],
                   outliers=np.union1d(state.outliers, index[rest]),
                   threshold=state.threshold)


def _halves(fam: ModelFamily, data: Mapping, info: Mapping, state: ModelState,
            threshold: float, need: int, sizes: Mapping, offsets: Mapping, options: Mapping,
            local: float, max_samples: int, seed: int | None) -> ModelState:
    """The structure ``state`` (global rows), or the part of it that is a structure of its
    own when it holds two regions of the measures that move differently.

    Two objects moving apart can share one epipolar geometry at a noise between theirs
    (AdelaideRMF's gamebiscuit: one fundamental matrix holds both objects at ``s²`` 0.38
    where their own are 0.03 and 0.17); a distance to an epipolar line is one equation, so
    the noise tests of :func:`_split` cannot see it. Objects are regions, though: the two
    clusters of the inliers' measures (2-means, the space in which local samples take
    their neighbours) are searched each alone, and the structure is two when each
    cluster's own estimate calls the other cluster outliers (the median of their errors
    above the structure's outlier ``threshold``). A half of one rigid object predicts the
    other half well enough (AdelaideRMF F, seed 0, structures of one object: medians of 0.4
    to 6 against thresholds of 11; of two objects: 160 to 12,600); a half whose estimate
    is poorly determined by its region may predict the other half badly, but not both
    halves each other. And one of the two must fit its own cluster at less than
    :data:`_SPLIT` of the noise the structure's estimate leaves there (two planes of one
    rigid motion: each plane's own fundamental matrix is degenerate and may predict the
    other plane badly both ways, but the motion's fits both planes as well as their own).
    The larger half's part is then the structure (tested again, up to
    :data:`_HALF_LEVELS` times: three objects in one), the rest goes back to the data.
    Only where the inliers are the measures of one channel (one space to cluster in)."""
    rows = _channel_rows(state.inliers, sizes, offsets)
    held = [name for name, r in rows.items() if r.size]
    if len(held) != 1:
        return state
    name = held[0]
    for level in range(_HALF_LEVELS):
        seeds = [None, None] if seed is None else [seed + 2 * level, seed + 2 * level + 1]
        index = np.asarray(state.inliers)  # sorted global rows: offset + rows[name]
        X = np.asarray(data[name], dtype=float)[index - offsets[name]]
        X = X.reshape(len(X), -1)
        if len(X) <= 4 * need or not np.all(np.isfinite(X)):
            return state
        with warnings.catch_warnings():  # an empty cluster: then a half is too small
            warnings.simplefilter("ignore")
            label = kmeans2(X, 2, minit="++", seed=np.random.default_rng(seeds[0]))[1]
        halves = [index[label == k] for k in range(2)]
        if min(h.size for h in halves) <= 2 * need:
            return state
        problem = _problem_on(fam, state.model, data, info, {name: index - offsets[name]},
                              sizes, options)
        whole = np.concatenate(coherence_errors(problem, state.q))
        parts, tighter = [], False
        for k, half in enumerate(halves):
            est, where = _estimator_on(fam, data, info, {name: half - offsets[name]}, sizes,
                                       offsets, options, model=state.model, local=local,
                                       seed=seeds[k])
            part = est.run(max_samples=max_samples)
            if part is None or not part.samples or len(part.inliers) <= need:
                return state
            errors = np.concatenate(coherence_errors(problem, part.q))
            other = np.isin(index, halves[1 - k])
            if not np.median(errors[other]) > threshold:
                return state
            own = np.isin(index, where[part.inliers])
            tighter |= bool(np.median(errors[own]) < _SPLIT * np.median(whole[own]))
            parts.append(replace(part, inliers=where[part.inliers],
                                 outliers=where[part.outliers]))
        if not tighter:
            return state
        kept = max(parts, key=lambda part: len(part.inliers))
        state = replace(kept, inliers=np.sort(kept.inliers),
                        outliers=np.setdiff1d(np.union1d(state.inliers, state.outliers),
                                              kept.inliers))
    return state


def _tight_part(fam: ModelFamily, model: str, data: Mapping, info: Mapping, rows: Mapping,
                sizes: Mapping, offsets: Mapping, options: Mapping, local: float,
                max_samples: int, seed: int | None, tight: float, scale: float,
                need: int):
    """The best structure of ``model`` among the measures ``rows`` at the error scale
    ``tight``, taken at its own noise (:func:`_own_noise`, ``scale`` its L*): ``(state,
    problem, index)`` — its rows and problem those of the measures, ``index`` their global
    rows — or None when the search finds nothing."""
    est, index = _estimator_on(fam, data, info, rows, sizes, offsets, options,
                               model=model, local=local, seed=seed, scale=tight)
    if est is None:
        return None
    part = est.run(max_samples=max_samples)
    if part is None or not part.samples:
        return None
    problem = _problem_on(fam, part.model, data, info, rows, sizes, options)
    return _own_noise(fam, part, problem, scale, need)[0], problem, index


def _problem_on(fam: ModelFamily, model: str, data: Mapping, info: Mapping, rows: Mapping,
                sizes: Mapping, options: Mapping):
    """``model``'s problem on the measures ``rows`` of each channel."""
    return make_problem(fam, model, {name: np.asarray(data[name], dtype=float)[r]
                                     for name, r in rows.items()},
                        {name: _rows_of(info.get(name), r, sizes[name])
                         for name, r in rows.items()},
                        options.get("q0"), options.get("Q0"), options.get("constants"))


def _channel_rows(rows: np.ndarray, sizes: Mapping, offsets: Mapping) -> dict:
    """Global rows (channel offset + row) as each channel's own rows, sorted."""
    bounds = np.r_[list(offsets.values()), sum(sizes.values())]
    return dict(zip(sizes, _per_channel(np.sort(rows), bounds), strict=True))


def _energy(fam: ModelFamily, data: Mapping, info: Mapping, found: list[ModelState],
            scale: float, options: Mapping) -> float:
    """``Σᵢ min(eᵢ, L*)``: each measure's error to its closest structure, truncated at
    ``scale`` (the largest L* of the extractions compared: an outlier costs L*). Not at a
    structure's threshold ceiling (2 L*): an inlier's error is below L* (the χ² quantile of
    the assumed noise), and between L* and 2 L* a structure holding two motions explained
    both for less than the third motion's matches left out cost (AdelaideRMF toycubecar)."""
    size = sum(len(np.asarray(rows)) for rows in data.values())
    closest = np.full(size, np.inf)
    for state in found:
        problem = make_problem(fam, state.model, data, info, options.get("q0"),
                               options.get("Q0"), options.get("constants"))
        closest = np.minimum(closest, np.concatenate(coherence_errors(problem, state.q)))
    return float(np.sum(np.minimum(closest, scale)))


def _assign(fam: ModelFamily, data: Mapping, info: Mapping, found: list[ModelState],
            needed: list[int], scales: list[float], rounds: int, options: Mapping,
            ) -> tuple[list[ModelState], list[float]]:
    """Assign each measure to its best structure, refit, until stable (PEARL's steps).
    Returns the structures kept and their L*."""
    constants = options.get("constants")
    window = options.get("window", 0.35)
    score = get_scorer(options.get("scorer", "relevance"))
    problems = {}

    def problem(model: str):
        if model not in problems:
            problems[model] = make_problem(fam, model, data, info, options.get("q0"),
                                           options.get("Q0"), constants)
        return problems[model]

    sizes = [ch.size for ch in problem(found[0].model).channels]
    bounds = np.cumsum([0] + sizes)
    owner = _owners(len(found), bounds[-1], [s.inliers for s in found])
    for _ in range(rounds):
        errors = np.array([np.concatenate(coherence_errors(problem(s.model), s.q))
                           for s in found])
        passed = np.where(errors < np.array([s.threshold for s in found])[:, None], errors,
                          np.inf)
        new = np.where(np.isfinite(passed.min(axis=0)), np.argmin(passed, axis=0), -1)
        if np.array_equal(new, owner):
            break
        owner = new
        kept, kept_needed, kept_scales = [], [], []
        for k, (state, need, scale) in enumerate(zip(found, needed, scales, strict=True)):
            rows = np.flatnonzero(owner == k)
            if rows.size <= need:
                continue  # a structure the others explain better is dropped
            prob = problem(state.model)
            fit = fit_problem(fam, state.model, prob.subset(_per_channel(rows, bounds)),
                              q_start=state.q, q0=prob.q0, Q0=prob.Q0)
            if not np.all(np.isfinite(fit.q)):
                kept.append(state)
                kept_needed.append(need)
                kept_scales.append(scale)
                continue
            all_errors = np.concatenate(coherence_errors(prob, fit.q))
            kept.append(replace(
                _with_fit(state, fit),
                threshold=outlier_threshold(all_errors, scale, window,
                                            _ceiling(options, scale)),
                relevance=score(all_errors, scale), inliers=rows))
            kept_needed.append(need)
            kept_scales.append(scale)
        if not kept:
            break
        found, needed, scales = kept, kept_needed, kept_scales
        owner = _owners(len(found), bounds[-1], [s.inliers for s in found])
    everything = np.arange(bounds[-1])
    return [replace(s, inliers=np.sort(s.inliers),
                    outliers=np.setdiff1d(everything, s.inliers)) for s in found], scales


def _with_fit(state: ModelState, fit) -> ModelState:
    """The state with the estimate of a refit (its inliers and threshold kept)."""
    return replace(state, params=fit.params, q=fit.q, info=fit.info, covariance=fit.covariance,
                   cost=fit.cost, dof=fit.dof, equations=fit.equations, derived=fit.derived,
                   slacks=fit.slacks, status="estimated" if fit.success else fit.message)


def _own_noise(fam: ModelFamily, state: ModelState, problem, scale: float,
               need: int) -> ModelState:
    """The structure at its own noise: its inliers those under ``L*`` at the noise of their
    own errors, refitted, until that threshold stops falling (rows of ``problem``); and that
    noise ``s²`` (None where it is not measured).

    ``info`` says the noise the user assumes for every measure; structures of real scenes
    have their own (AdelaideRMF: 0.2 to 1.5 px within a scene fitted at 1 px). Where a
    structure's noise is far below the assumed one, its threshold takes in the matches of a
    neighbouring plane along their common line, the planes merge and the next search does
    not find the second. The median of the inliers' errors over the χ² median gives their
    noise variance in units of the information (``s²``); the threshold becomes ``L* s²``
    (never above the search's). The median is robust to the other structure's matches as
    long as they are fewer than the structure's own.

    Only where a measure has two equations or more (a homography's transfer): with one (a
    match's distance to its epipolar line), another motion's matches also fall near the
    lines wherever the two motions' epipolar lines agree, and their median does not tell
    the structure's noise from theirs (AdelaideRMF F, seed 0: 7.9 to 8.9 % with it).
    """
    p = _equations(problem, state.q)
    if p < 2:
        return state, None
    bounds = np.cumsum([0] + [ch.size for ch in problem.channels])
    errors = np.concatenate(coherence_errors(problem, state.q))
    inliers, threshold = np.asarray(state.inliers), state.threshold
    noise = None
    for _ in range(_NOISE_ROUNDS):
        noise = _noise(errors[inliers], p) if inliers.size else np.inf
        tight = scale * noise
        rows = np.flatnonzero(errors < tight)
        if not tight < threshold or rows.size <= need:
            break
        threshold = tight
        fit = fit_problem(fam, state.model, problem.subset(_per_channel(rows, bounds)),
                          q_start=state.q)
        if not np.all(np.isfinite(fit.q)):
            inliers = rows
            break
        state = _with_fit(state, fit)
        errors = np.concatenate(coherence_errors(problem, state.q))
        inliers = np.flatnonzero(errors < threshold)
    return replace(state, threshold=threshold, inliers=inliers,
                   outliers=np.setdiff1d(np.arange(errors.size), inliers)), noise


def _equations(problem, q: np.ndarray) -> int:
    """Equations per measure at ``q`` (eq. 24's ``p``; the least over the channels that
    hold measures, 0 without any)."""
    return min((int(r) for r, ch in zip(manifold_ranks(problem, q), problem.channels,
                                        strict=True) if ch.size), default=0)


def _noise(errors: np.ndarray, p: int) -> float:
    """``s²``, the noise variance of measures of ``p`` equations in units of their
    information: the median of their errors over that of an inlier's (``χ²_p / p``)."""
    return float(np.median(errors)) / (chi2_quantile(0.5, p) / p)


def _per_channel(rows: np.ndarray, bounds: np.ndarray) -> tuple[np.ndarray, ...]:
    """Rows of the measures of all channels in turn, split into each channel's own
    (``bounds``: the channels' first rows, then the total)."""
    return tuple(rows[(rows >= a) & (rows < b)] - a
                 for a, b in zip(bounds[:-1], bounds[1:], strict=True))


def _ceiling(options: Mapping, scale: float) -> float | None:
    """A structure's threshold cap: ``max_threshold``, else ``ceiling`` × its L*."""
    if options.get("max_threshold") is not None:
        return options["max_threshold"]
    return None if options.get("ceiling") is None else options["ceiling"] * scale


def _owners(count: int, size: int, inliers: list[np.ndarray]) -> np.ndarray:
    owner = np.full(size, -1)
    for k in range(count):
        owner[inliers[k]] = k
    return owner


def _rows_of(info, rows: np.ndarray, size: int):
    """The information of some measures: per-measure forms are sliced, shared ones kept."""
    if info is None or np.ndim(info) == 0:
        return info
    info = np.asarray(info, dtype=float)
    per_measure = info.ndim == 3 or (info.ndim == 1 and info.shape[0] == size)
    return info[rows] if per_measure else info


def _minimal(est: Estimator, state: ModelState) -> int:
    """The measures of a minimal sample of the state's model (4 matches for a homography,
    whose 8 degrees of freedom 2 equations a match fix)."""
    return est.sample_sizes.get(state.model) or max(1, est.fam.free_dof(state.model,
                                                                        est._constants))
