"""The error histogram of the outlier threshold (report §4) as kernels: its counts and its
walk to the first minimum after the mode. :func:`kanagen.runtime.refine.outlier_threshold`
describes the method and does the smoothing between the two (NumPy's ``convolve``); a robust
search calls it after every refinement, where NumPy's per-call costs were most of its time.
"""

from __future__ import annotations

import math

import numpy as np

from kanagen.common.jit import jit


@jit
def reflected_counts(errors, top, edges, half):
    """The counts of the finite ``errors`` (clipped to ``[0, top]``) in the equal bins
    of ``edges`` — the last bin closed, as ``np.histogram`` counts, by its own arithmetic: the
    bin from the scaled value, corrected by one against the edges — with the last bin (the
    clipped tail: not a population) emptied, and preceded by its first ``half`` bins
    reflected (errors are >= 0): ``half + bins`` counts, as floats."""
    bins = edges.size - 1
    end = edges[bins]
    out = np.zeros(half + bins)
    for a in range(errors.size):
        v = errors[a]
        if not np.isfinite(v):
            continue
        v = min(max(v, 0.0), top)
        index = int(v / end * bins)
        if index == bins:
            index -= 1
        if v < edges[index]:
            index -= 1
        if v >= edges[index + 1] and index != bins - 1:
            index += 1
        out[half + index] += 1.0
    out[half + bins - 1] = 0.0
    for a in range(half):
        out[a] = out[2 * half - 1 - a]
    return out


@jit
def first_minimum(smooth, half):
    """The bin of the smoothed histogram's first minimum after its mode: a bin after which
    it rises by more than its Poisson noise (the smoothing averages about ``half`` bins), or
    the first of a flat empty stretch (a saddle); the last bin without either."""
    i = int(np.argmax(smooth))
    size = smooth.size
    while i + 1 < size:
        if smooth[i + 1] < smooth[i]:
            i += 1
            continue
        if smooth[i] * half < 0.5:
            break  # flat and empty: saddle
        end = min(size, i + 1 + 2 * half)
        noise = 3.0 * math.sqrt((smooth[i] + 1.0 / half) / half)
        if end > i + 1:
            ahead = smooth[i + 1]
            for b in range(i + 2, end):
                ahead = max(ahead, smooth[b])
            if ahead - smooth[i] > noise:
                break  # a genuine local minimum
        i += 1
    return i
