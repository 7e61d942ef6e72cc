"""SymPy -> target source text, through ONE lookup table of functions per target.

Each table maps every SymPy function class a spec may use, and every class their derivatives
produce (``sign`` from ``abs``), to exactly one function of the target library, and is
checked one-to-one (two SymPy functions never print as the same target function). A printer
is the table plus the few spellings that differ between targets (square root, π, e).
"""

from __future__ import annotations

import sympy as sp
from sympy.printing.precedence import PRECEDENCE
from sympy.printing.str import StrPrinter

#: SymPy function class -> NumPy function.
NUMPY_FUNCTIONS: dict[type, str] = {
    sp.exp: "np.exp",
    sp.log: "np.log",
    sp.sin: "np.sin",
    sp.cos: "np.cos",
    sp.tan: "np.tan",
    sp.atan: "np.arctan",
    sp.atan2: "np.arctan2",
    sp.asin: "np.arcsin",
    sp.acos: "np.arccos",
    sp.sinh: "np.sinh",
    sp.cosh: "np.cosh",
    sp.tanh: "np.tanh",
    sp.Abs: "np.abs",
    sp.sign: "np.sign",
}

#: SymPy function class -> CasADi function (on ``SX`` symbols).
CASADI_FUNCTIONS: dict[type, str] = {
    sp.exp: "ca.exp",
    sp.log: "ca.log",
    sp.sin: "ca.sin",
    sp.cos: "ca.cos",
    sp.tan: "ca.tan",
    sp.atan: "ca.atan",
    sp.atan2: "ca.atan2",
    sp.asin: "ca.asin",
    sp.acos: "ca.acos",
    sp.sinh: "ca.sinh",
    sp.cosh: "ca.cosh",
    sp.tanh: "ca.tanh",
    sp.Abs: "ca.fabs",
    sp.sign: "ca.sign",
}

for _table in (NUMPY_FUNCTIONS, CASADI_FUNCTIONS):
    assert len(set(_table.values())) == len(_table), "a function table must be one-to-one"


class CodegenError(ValueError):
    """An expression cannot be turned into code (e.g. a function with no counterpart)."""


class TablePrinter(StrPrinter):
    """Print SymPy expressions as Python source for one target library.

    Symbols are renamed by ``names``; functions go through :attr:`functions`, the target's
    one table. Subclasses set the table, the module prefix and the target's name.
    """

    functions: dict[type, str] = {}
    module = ""
    target = ""

    def __init__(self, names: dict[sp.Symbol, str]):
        super().__init__({"full_prec": True})
        self.names = names

    def _print_Symbol(self, expr):
        try:
            return self.names[expr]
        except KeyError:
            raise CodegenError(f"symbol {expr} has no name in the generated code") from None

    def _print_Float(self, expr):
        return repr(float(expr))

    def _print_Pi(self, expr):
        return f"{self.module}.pi"

    def _print_Exp1(self, expr):
        return f"{self.module}.exp(1)" if self.module == "ca" else f"{self.module}.e"

    def _print_Pow(self, expr, rational=False):
        if expr.exp == sp.S.Half:
            return f"{self.module}.sqrt({self._print(expr.base)})"
        if expr.exp == -sp.S.Half:
            return f"1/{self.module}.sqrt({self._print(expr.base)})"
        return super()._print_Pow(expr, rational)

    def _print_powlog(self, expr):
        # u**e*log|u|, 0 at u = 0 (codegen/limits.py): log's argument is 1 there. Below 0,
        # u**e is real only at an integer e (NaN otherwise), where log|u| makes the
        # derivative finite: a model pinning e to an integer fits measures below 0.
        base, exponent = expr.args
        u = self._print(base)
        power = self._print(sp.Pow(base, exponent, evaluate=False))
        magnitude = f"{self.functions[sp.Abs]}({u})"
        return f"({power}*{self.module}.log({magnitude} + (({u}) == 0)))"

    def _print_Function(self, expr):
        target = self.functions.get(type(expr))
        if target is None:
            raise CodegenError(f"function {type(expr).__name__} has no {self.target} "
                               "counterpart")
        return f"{target}({', '.join(self._print(a) for a in expr.args)})"

    def _print_NaN(self, expr):
        raise CodegenError("expression evaluates to NaN")

    _print_ComplexInfinity = _print_Infinity = _print_NegativeInfinity = _print_NaN


class NumpyPrinter(TablePrinter):
    """SymPy -> NumPy (arrays of measures broadcast through every operation)."""

    functions = NUMPY_FUNCTIONS
    module = "np"
    target = "NumPy"

    def _print_Pow(self, expr, rational=False):
        # numba raises ZeroDivisionError for a float's negative integer power of 0 whatever
        # the kernel's error model (``x**(-2)`` at ``x = 0``: a fit must never raise); its
        # division follows the error model, so ``1/x**2`` is ``inf`` there as in NumPy, with
        # the same bits elsewhere (``x**2`` computed the same way, then inverted).
        if expr.exp.is_Integer and expr.exp < -1:
            power = sp.Pow(expr.base, -expr.exp, evaluate=False)
            return f"(1/{self.parenthesize(power, PRECEDENCE['Mul'])})"
        return super()._print_Pow(expr, rational)


class CasadiPrinter(TablePrinter):
    """SymPy -> CasADi ``SX`` expressions (one measure; the runtime maps over measures)."""

    functions = CASADI_FUNCTIONS
    module = "ca"
    target = "CasADi"
