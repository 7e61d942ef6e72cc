"""SymPy -> NumPy source text, through ONE lookup table of functions (checked one-to-one)."""

from __future__ import annotations

import sympy as sp
from sympy.printing.str import StrPrinter

#: SymPy function class -> NumPy function. Every function a spec may use, and every function
#: their derivatives produce (``sign`` from ``abs``), appears here exactly once.
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
assert len(set(NUMPY_FUNCTIONS.values())) == len(NUMPY_FUNCTIONS), "table must be one-to-one"


class CodegenError(ValueError):
    """An expression cannot be turned into code (e.g. a function with no NumPy counterpart)."""


class NumpyPrinter(StrPrinter):
    """Print SymPy expressions as NumPy code, with symbols renamed by ``names``."""

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
        return "np.pi"

    def _print_Exp1(self, expr):
        return "np.e"

    def _print_Pow(self, expr, rational=False):
        if expr.exp == sp.S.Half:
            return f"np.sqrt({self._print(expr.base)})"
        if expr.exp == -sp.S.Half:
            return f"1/np.sqrt({self._print(expr.base)})"
        return super()._print_Pow(expr, rational)

    def _print_Function(self, expr):
        target = NUMPY_FUNCTIONS.get(type(expr))
        if target is None:
            raise CodegenError(f"function {type(expr).__name__} has no NumPy counterpart")
        return f"{target}({', '.join(self._print(a) for a in expr.args)})"

    def _print_NaN(self, expr):
        raise CodegenError("expression evaluates to NaN")

    _print_ComplexInfinity = _print_Infinity = _print_NegativeInfinity = _print_NaN
