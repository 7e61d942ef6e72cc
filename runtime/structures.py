"""Several structures in the same data (report §4, clustered data): find one, take its
inliers out, search again."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace

import numpy as np

from .estimator import Estimator, ModelState
from .family import ModelFamily


def find_structures(fam: ModelFamily, data: Mapping, info: Mapping | None = None,
                    max_structures: int = 5, model: str | None = None,
                    min_inliers: int | None = None, max_samples: int = 2000,
                    **options) -> list[ModelState]:
    """Several structures in the same data (report §4, clustered data): find one, take its
    inliers out, search again, until nothing relevant is left or ``max_structures``.

    Parameters
    ----------
    data, info : dicts by channel, as for :func:`kanagen.fit`.
    model : str, optional
        The model of every structure; default: the lattice search picks one per structure.
    min_inliers : int, optional
        A structure needs more inliers than this (default: twice the minimal sample).
    options : the :class:`Estimator` options (``scale``, ``scorer``, ``phi``, ``seed``,
        ``channel``, ``constants``, ...).

    Returns
    -------
    list of ModelState
        Strongest (most inliers) first; ``inliers``/``outliers`` are row indices into the
        arrays given (ids follow the rows of ``data``, channel after channel).
    """
    sizes = {name: len(np.asarray(rows)) for name, rows in data.items()}
    offsets = dict(zip(sizes, np.cumsum([0] + list(sizes.values()))[:-1].tolist(),
                       strict=True))
    remaining = {name: np.arange(size) for name, size in sizes.items()}
    info = dict(info or {})
    found: list[ModelState] = []
    seed = options.pop("seed", 0)
    for k in range(max_structures):
        est = Estimator(fam, model=model, seed=None if seed is None else seed + k, **options)
        index = []  # estimator id -> global row (channel offset + row)
        for name, rows in remaining.items():
            if rows.size == 0:
                continue
            est.add_measures(name, np.asarray(data[name], dtype=float)[rows],
                             _rows_of(info.get(name), rows, sizes[name]))
            index.append(offsets[name] + rows)
        if not index:
            break
        best = est.run(max_samples=max_samples)
        if best is None or not best.samples:
            break
        needed = min_inliers if min_inliers is not None else 2 * _minimal(est, best)
        if len(best.inliers) <= needed:
            break
        index = np.concatenate(index)
        state = replace(best, inliers=index[best.inliers], outliers=index[best.outliers])
        found.append(state)
        for name, rows in remaining.items():
            remaining[name] = rows[~np.isin(offsets[name] + rows, state.inliers)]
    return sorted(found, key=lambda s: -len(s.inliers))


def _rows_of(info, rows: np.ndarray, size: int):
    """The information of some measures: per-measure forms are sliced, shared ones kept."""
    if info is None or np.ndim(info) == 0:
        return info
    info = np.asarray(info, dtype=float)
    per_measure = info.ndim == 3 or (info.ndim == 1 and info.shape[0] == size)
    return info[rows] if per_measure else info


def _minimal(est: Estimator, state: ModelState) -> int:
    return max(1, est._free(state.model, state.q))
