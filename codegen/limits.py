"""Derivatives written to be finite where their limit is: at a measure or a parameter of 0 in
a power with a symbolic exponent.

SymPy differentiates ``x**b`` as ``b*x**b/x`` in ``x`` and ``x**b*log(x)`` in ``b``: at
``x = 0`` (a Hill curve's zero dose, a power law's origin) both are ``0/0`` or ``0·(−∞)``,
NaN, where the derivative's limit is finite (``b x**(b−1)`` for ``b ≥ 1``; 0 for ``b > 0``).
A fit with such a measure stopped at its start with no direction to go. The derivatives are
rewritten once, symbolically, before they are printed: the powers of one base combined
(``x**(b−1)``), and ``u**e*log(u)`` as :class:`powlog`, 0 at ``u = 0``. Only expressions
with a symbolic exponent are touched: a polynomial family's code is unchanged.
"""

from __future__ import annotations

import sympy as sp


class powlog(sp.Function):  # noqa: N801 - printed by name (``_print_powlog``)
    """``u**e * log|u|``: 0 at ``u = 0`` (its limit when ``e > 0``); below 0, where ``u**e``
    is real only at an integer ``e``, the derivative of ``u**e`` along the integers' real
    continuation (a model pinning ``e`` to 1 fits a measure below 0). Printed, never
    differentiated."""

    nargs = 2


def finite_limits(expr: sp.Expr) -> sp.Expr:
    """``expr`` (a derivative) with its removable 0/0 at a power's zero base rewritten away;
    ``expr`` itself when it has no power with a symbolic exponent."""
    if not any(not p.exp.is_Number for p in expr.atoms(sp.Pow)):
        return expr
    combined = sp.powsimp(expr, deep=True, combine="exp")
    return combined.replace(lambda node: node.is_Mul and node.has(sp.log), _fold_logs)


def _fold_logs(product: sp.Mul) -> sp.Expr:
    """A product's ``log(u)`` factor and a factor ``u**e`` (or ``u``) of the same ``u`` as
    one ``powlog(u, e)``."""
    factors = list(product.args)
    for log_at, log in enumerate(factors):
        if not isinstance(log, sp.log):
            continue
        base = log.args[0]
        for at, factor in enumerate(factors):
            if factor == base:
                exponent = sp.Integer(1)
            elif factor.is_Pow and factor.base == base:
                exponent = factor.exp
            else:
                continue
            rest = [f for i, f in enumerate(factors) if i not in (log_at, at)]
            return sp.Mul(powlog(base, exponent), *rest)
    return product
