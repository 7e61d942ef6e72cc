"""Scoring two-view results against ground truth: geometric errors and the misclassification
of multi-structure fits (AdelaideRMF protocol).

Conventions as in :mod:`kanagen.datasets`: rows ``[u, v, u2, v2]``, ``p2 ~ H p1``,
``p2ᵀ F p1 = 0``.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment


def misclassification(labels, assigned) -> float:
    """Fraction of the measures given the wrong class, under the best matching of the found
    structures to the labelled ones.

    Class 0 is "outlier" on both sides and is matched to itself: an outlier put in a
    structure, or a structure's measure called an outlier, is an error. The found structures
    ``1..K'`` are matched one-to-one to the labelled ``1..K`` so as to maximise the measures
    on which they agree (Hungarian method, :func:`scipy.optimize.linear_sum_assignment`);
    a structure left without a partner (``K' ≠ K``) has all its measures wrong.

    Parameters
    ----------
    labels : (N,) ints
        Ground truth: 0 outlier, ``k ≥ 1`` structure ``k``.
    assigned : (N,) ints
        The fit's classes, same meaning (the numbering need not match).

    Examples
    --------
    >>> misclassification([0, 1, 1, 2, 2, 2], [0, 2, 2, 1, 1, 0])  # one structure point lost
    0.16666666666666666
    """
    labels = np.asarray(labels)
    assigned = np.asarray(assigned)
    if labels.ndim != 1 or labels.shape != assigned.shape or labels.size == 0:
        raise ValueError(f"labels and assigned must be two (N,) arrays of the same length, got "
                         f"{labels.shape} and {assigned.shape}")
    for name, a in (("labels", labels), ("assigned", assigned)):
        if not np.issubdtype(a.dtype, np.integer) or np.any(a < 0):
            raise ValueError(f"{name} must be non-negative integers (0 = outlier)")
    true_k = np.unique(labels[labels > 0])
    found_k = np.unique(assigned[assigned > 0])
    agree = int(np.count_nonzero((labels == 0) & (assigned == 0)))
    if true_k.size and found_k.size:
        both = (labels > 0) & (assigned > 0)
        t = np.searchsorted(true_k, labels[both])
        f = np.searchsorted(found_k, assigned[both])
        overlap = np.zeros((true_k.size, found_k.size), dtype=int)
        np.add.at(overlap, (t, f), 1)
        rows, cols = linear_sum_assignment(overlap, maximize=True)
        agree += int(overlap[rows, cols].sum())
    return 1.0 - agree / labels.size


def labels_from_structures(n: int, inliers: list) -> np.ndarray:
    """Per-measure classes from the inlier index sets of found structures: structure ``k``
    (1-based, in the order given) or 0. A measure claimed by several keeps the first."""
    out = np.zeros(n, dtype=int)
    for k, rows in enumerate(inliers, start=1):
        rows = np.asarray(rows, dtype=int)
        if rows.size and (rows.min() < 0 or rows.max() >= n):
            raise ValueError(f"structure {k}: inlier index out of range 0..{n - 1}")
        free = rows[out[rows] == 0]
        out[free] = k
    return out


def homogeneous(points: np.ndarray) -> np.ndarray:
    """``(N, 2) → (N, 3)`` with a last column of ones."""
    points = np.asarray(points, dtype=float)
    return np.c_[points, np.ones(len(points))]


def transfer_errors(H: np.ndarray, matches: np.ndarray) -> np.ndarray:
    """Per match, ``‖(u2, v2) − π(H p1)‖`` in pixels (one-way transfer error)."""
    m = _matches(matches)
    p = homogeneous(m[:, :2]) @ np.asarray(H, dtype=float).T
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.hypot(p[:, 0] / p[:, 2] - m[:, 2], p[:, 1] / p[:, 2] - m[:, 3])


def sampson_errors(F: np.ndarray, matches: np.ndarray) -> np.ndarray:
    """Per match, the Sampson distance of ``p2ᵀ F p1 = 0`` in pixels (first-order geometric
    error of the four coordinates)."""
    m = _matches(matches)
    F = np.asarray(F, dtype=float)
    p1, p2 = homogeneous(m[:, :2]), homogeneous(m[:, 2:])
    Fp1 = p1 @ F.T
    Ftp2 = p2 @ F
    r = np.sum(p2 * Fp1, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.abs(r) / np.sqrt(Fp1[:, 0]**2 + Fp1[:, 1]**2 + Ftp2[:, 0]**2 + Ftp2[:, 1]**2)


def _matches(matches) -> np.ndarray:
    m = np.asarray(matches, dtype=float)
    if m.ndim != 2 or m.shape[1] != 4:
        raise ValueError(f"matches must be an (N, 4) array of [u, v, u2, v2], got {m.shape}")
    return m
