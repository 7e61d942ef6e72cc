"""The χ² law where kanagen needs it — ``L*``'s quantile (:mod:`.scoring`), a fit's p-value
(:mod:`.results`), a scale from a median (:mod:`.structures`) — as ``scipy.stats.chi2``
computes them (its ``_ppf`` and ``_sf``: the same numbers, bit for bit), from
``scipy.special`` alone: importing ``scipy.stats`` costs half a second of a process's first
search or report, more than the search itself on a small example. Imported lazily by its
callers: ``import kanagen`` stays light."""

from __future__ import annotations

from scipy.special import chdtrc, gammaincinv


def quantile(probability: float, dof: int) -> float:
    """``χ²_dof``'s quantile of ``probability`` (``chi2.ppf``)."""
    return float(2 * gammaincinv(dof / 2, probability))


def tail(value: float, dof: int) -> float:
    """``P(χ²_dof ≥ value)`` (``chi2.sf``)."""
    return float(chdtrc(dof, value))
