"""Measures against a fixed parameter, from a family and data: coherence errors (eq. 22–24),
the minimal solve (eq. 21) and the minimal sample size — validated into a problem, then
:mod:`.minimal`'s algorithms."""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from .family import ModelFamily
from .fit import make_problem
from .inputs import parameter_vector
from .minimal import (
    MinimalSolution,
    coherence_errors,
    generic_free_dof,
    manifold_ranks,
    minimal_solve_problem,
)
from .sqrt import EPS


def coherence(fam: ModelFamily, model: str, q, data: Mapping, info: Mapping | None = None,
              constants=None, iterations: int | None = None, tol: float = 1e-10,
              ) -> dict[str, np.ndarray]:
    """Coherence error of every measure with a fixed parameter ``q`` (report eq. 22–24).

    Each measure ``m•`` is projected onto ``c•(q, ·) = 0`` in its ``Q•`` metric (the projector
    iteration in measure space only, vectorised over measures); its error is
    ``e• = (‖m̃• − m•‖²_Q• + ‖c•(q, m̃•)‖²_{(D• Q•⁺ D•ᵀ)⁻}) / p•``.

    Parameters
    ----------
    iterations : int, optional
        Number of evaluations: 1 gives the Sampson error (first-order), ``None`` iterates to
        convergence (the geometric error).

    Returns
    -------
    dict
        ``{channel: (M,) errors}``.

    Examples
    --------
    >>> import numpy as np, kanagen
    >>> fam = kanagen.load("line")
    >>> e = kanagen.coherence(fam, "line", [1.0, 0.0], data={"point": [[0.0, 1.0]]})
    >>> round(float(e["point"][0]), 6)   # distance² to y = x is 1/2, p = 1
    0.5
    """
    problem = make_problem(fam, model, data, info, constants=constants)
    q = parameter_vector(fam, q, "q")
    errors = coherence_errors(problem, q, iterations, tol)
    return {ch.name: e for ch, e in zip(problem.channels, errors, strict=True)}


def minimal_solve(fam: ModelFamily, model: str, data: Mapping, q_start=None, constants=None,
                  max_iter: int = 50, xtol: float = 1e-12, eps: float = EPS) -> MinimalSolution:
    """The ``q`` closest to ``q_start`` (identity metric) satisfying ``c0`` and the equations
    of the given measures, held fixed (report eq. 21, ``Q0 = 0``).

    Never raises on numerical trouble: a degenerate sample gives ``success=False``.
    """
    problem = make_problem(fam, model, data, None, constants=constants)
    target = parameter_vector(fam, q_start, "q_start")
    return minimal_solve_problem(problem, target, max_iter, xtol, eps)


def minimal_sample_size(fam: ModelFamily, model: str, channel: str, q=None,
                        constants=None, data=None) -> int:
    """The fewest measures of ``channel`` whose equations fix the ``n − p`` free degrees of
    freedom of ``model`` (p: rank of the constraints at ``q``, default the spec's q0); each
    measure counts its equations' rank on their zero set (:func:`manifold_ranks`), at a few
    measures of ``data`` (default: random ones) projected onto it."""
    k = fam.constant_vector(constants)
    q = parameter_vector(fam, q, "q")
    width = len(fam.channel(channel).components)
    if data is None:
        data = np.random.default_rng(0).standard_normal((8, width))
    problem = make_problem(fam, model, {channel: data}, constants=constants)
    rank = max(manifold_ranks(problem, q)[0], 1)
    return math.ceil(generic_free_dof(lambda x: fam.c0(model, x, k)[1], q) / rank)
