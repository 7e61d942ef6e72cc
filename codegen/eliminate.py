"""Symbolic elimination of linear parameter constraints (report §6), an optimisation pass.

The report notes that "some parameter components may be eliminated using the constraints
which are linear, so that evaluation is only to be performed on a reduced set of equations
and variables". For a model whose constraints ``c0(q) = 0`` include linear ones with numeric
coefficients, ``G q = g``, this pass solves them exactly (rational arithmetic, reduced row
echelon form) for some components of ``q``:

    q = T r + t,    r = the components left free (a subset of q, in order),

and substitutes into the other constraints and into every measurement equation, so the
generated code of the *reduced model* works in ``r`` only: fewer unknowns, and the linear
constraints hold exactly at every iterate. The runtime (``kanagen.load(...,
eliminate_linear=True)``) iterates in ``r`` and maps the estimate back to ``q``; every
output (information, covariance, ranks, cost) is then evaluated on the full model, so the
pass changes no result (tests/test_eliminate.py).

A constraint is linear when it is a polynomial of degree ≤ 1 in the parameter components
whose coefficients are numbers (not constants, which are set at run time and could make a
pivot vanish). The slack components a model pins (appendix F, ``s − 1 = 0``) are eliminated
like any other; the runtime evaluates the inequality relations on ``q = T r + t``.
Redundant linear constraints are dropped (they do not change the reduced model);
inconsistent ones (``0 = 1``) leave the model unreduced.
"""

from __future__ import annotations

from dataclasses import dataclass

import sympy as sp

from ..modelspec.ir import Family, symbol


@dataclass(frozen=True)
class Reduction:
    """``q = T r + t`` for one model, with its remaining constraints in ``r``."""

    model: str
    free: tuple[int, ...]  # indices in q of the components kept as r
    T: tuple[tuple[sp.Rational, ...], ...]  # (n, len(free))
    t: tuple[sp.Rational, ...]  # (n,)
    constraints: tuple[sp.Expr, ...]  # the non-linear constraints, substituted
    substitution: tuple[tuple[sp.Symbol, sp.Expr], ...]  # eliminated symbol -> expression in r

    def substitute(self, expr: sp.Expr) -> sp.Expr:
        """``expr`` of ``q`` as an expression of the free components."""
        return expr.xreplace(dict(self.substitution))


def _linear_rows(constraints, q: list[sp.Symbol]):
    """Split ``constraints`` into linear ones as rows ``(coefficients, constant)`` of
    ``coefficients · q + constant = 0``, and the others."""
    linear, other = [], []
    for c in constraints:
        gradient = [sp.diff(c, v) for v in q]
        if c.free_symbols <= set(q) and all(g.is_number for g in gradient) and any(gradient):
            const = c.xreplace({v: 0 for v in q})
            linear.append(([sp.nsimplify(g, rational=True) for g in gradient],
                           sp.nsimplify(const, rational=True)))
        else:
            other.append(c)
    return linear, other


def linear_reduction(family: Family, model: str) -> Reduction | None:
    """The reduction of ``model`` by its linear constraints, or None if it has none usable."""
    q = [symbol(n) for n in family.parameter_names]
    n = len(q)
    linear, other = _linear_rows(family.model(model).constraints, q)
    if not linear:
        return None
    # Pivot on the last components first: the declared order keeps the leading components
    # (the ones a user reads first) free, and pinned slacks (last in q) are eliminated.
    order = list(range(n))[::-1]
    augmented = sp.Matrix([[c[i] for i in order] + [-g] for c, g in linear])
    rref, pivots = augmented.rref()
    if len(order) in pivots:
        return None  # inconsistent: 0 = non-zero
    pivot_idx = [order[p] for p in pivots]
    free = tuple(i for i in range(n) if i not in pivot_idx)
    substitution = []
    T = [[sp.Integer(0)] * len(free) for _ in range(n)]
    t = [sp.Integer(0)] * n
    for col, i in enumerate(free):
        T[i][col] = sp.Integer(1)
    for row, p in enumerate(pivots):
        i = order[p]
        rhs = rref[row, len(order)]
        expr = rhs
        for col, j in enumerate(free):
            a = rref[row, order.index(j)]
            T[i][col] = -a
            expr -= a * q[j]
        t[i] = rhs
        substitution.append((q[i], expr))
    red = Reduction(model, free, tuple(map(tuple, T)), tuple(t), (), tuple(substitution))
    remaining = tuple(e for e in (red.substitute(c) for c in other) if sp.expand(e) != 0)
    return Reduction(model, free, red.T, red.t, remaining, red.substitution)
