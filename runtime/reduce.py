"""Fitting a model in its free components (report §6: linear constraints eliminated).

For a model whose linear constraints were solved at build time (``q = T r + t``,
:mod:`kanagen.codegen.eliminate`), the problem in ``r`` uses the reduced functions of the
generated module (remaining constraints, measurement equations in ``r``) and the prior
carried over: ``½‖T r + t − q0‖²_Q0 = ½‖r − r0‖²_{TᵀQ0T} + const`` with
``TᵀQ0T r0 = TᵀQ0 (q0 − t)`` (least squares when ``TᵀQ0T`` is singular). The constant does
not move the minimum; the caller evaluates every output on the full model.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .engine.data import model_rows
from .family import ModelFamily, Reduction
from .projector import Problem


def reduced_problem(fam: ModelFamily, model: str, problem: Problem,
                    red: Reduction) -> Problem:
    """``problem`` (on ``q``) as the same problem on ``r``."""
    T = red.T
    Q0 = T.T @ problem.Q0 @ T
    if np.any(problem.Q0):
        r0 = np.linalg.lstsq(Q0, T.T @ problem.Q0 @ (problem.q0 - red.t), rcond=None)[0]
    else:
        r0 = problem.q0[red.free]
    relations = problem.relations
    free = [int(i) for i in np.atleast_1d(red.free)]
    return replace(
        problem,
        c0=fam.c0_function(model, reduced=True),
        measures=tuple(fam.measurement_function(model, ch.name, reduced=True)
                       for ch in problem.channels),
        q0=r0,
        Q0=Q0,
        relations=None if relations is None else (lambda r: relations(red.full(r))),
        # a strict relation's slack, where it is free: its index in r
        strict_slacks=tuple((free.index(i), power) for i, power in problem.strict_slacks
                            if i in free),
        rows=model_rows(fam, model, red),
    )
