"""Safe parsing of expression text into SymPy, through Python's ``ast`` and a whitelist.

Nothing here evaluates text: ``ast.parse`` builds a tree, each node kind is checked against a
fixed list, and SymPy objects are built node by node. Names must be declared symbols or entries
of :data:`FUNCTIONS` / :data:`CONSTANTS`.
"""

from __future__ import annotations

import ast
import re
from collections.abc import Mapping

import sympy as sp

from .errors import SpecError

#: The functions a spec may call: name in the spec -> SymPy function. Code generators map these
#: SymPy classes to their target library through one table each (see ``kanagen.codegen.printer``).
FUNCTIONS: dict[str, object] = {
    "sqrt": sp.sqrt,
    "exp": sp.exp,
    "log": sp.log,
    "sin": sp.sin,
    "cos": sp.cos,
    "tan": sp.tan,
    "atan": sp.atan,
    "atan2": sp.atan2,
    "asin": sp.asin,
    "acos": sp.acos,
    "sinh": sp.sinh,
    "cosh": sp.cosh,
    "tanh": sp.tanh,
    "abs": sp.Abs,
}
_ARITY = {"atan2": 2}

#: Named constants of the expression language.
CONSTANTS: dict[str, sp.Expr] = {"pi": sp.pi}

#: Names a spec may not declare (they would shadow the language).
RESERVED = frozenset(FUNCTIONS) | frozenset(CONSTANTS)

_IDENTIFIER = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")
_MAX_LENGTH = 20_000
_MAX_POWER = 64


def check_identifier(name: object, what: str, source: str, line: int | None) -> str:
    """Return ``name`` if it is a plain identifier usable in generated code, else raise."""
    import keyword

    if not isinstance(name, str) or not _IDENTIFIER.match(name):
        raise SpecError(
            f"{what} name {name!r} is not an identifier (letters, digits, '_', starting with a "
            "letter)",
            source,
            line,
        )
    if keyword.iskeyword(name) or name in RESERVED:
        raise SpecError(f"{what} name {name!r} is reserved", source, line)
    return name


def parse_expression(
    text: object,
    symbols: Mapping[str, sp.Symbol],
    source: str = "<spec>",
    line: int | None = None,
) -> sp.Expr:
    """Parse one expression.

    Parameters
    ----------
    text : str or number
        The expression, in Python syntax restricted to numbers, declared names, ``+ - * / **``,
        unary minus and the functions of :data:`FUNCTIONS`.
    symbols : mapping
        Declared names and their SymPy symbols.
    source, line : str, int
        Where the text comes from, for error messages.

    Examples
    --------
    >>> import sympy as sp
    >>> x = sp.Symbol("x")
    >>> parse_expression("2*x**2 - sqrt(x)", {"x": x})
    -sqrt(x) + 2*x**2
    """
    if isinstance(text, bool):
        raise SpecError(f"expected an expression, got the boolean {text}", source, line)
    if isinstance(text, int | float):
        return sp.Float(text) if isinstance(text, float) else sp.Integer(text)
    if not isinstance(text, str):
        raise SpecError(
            f"expected an expression, got {type(text).__name__} {text!r}", source, line
        )
    if len(text) > _MAX_LENGTH:
        raise SpecError(f"expression longer than {_MAX_LENGTH} characters", source, line)
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except SyntaxError as exc:
        raise SpecError(f"cannot parse expression {text!r}: {exc.msg}", source, line) from None
    return _Builder(symbols, source, line, text).build(tree.body)


class _Builder:
    def __init__(self, symbols, source, line, text):
        self.symbols = symbols
        self.source = source
        self.line = line
        self.text = text

    def fail(self, what: str) -> SpecError:
        return SpecError(f"{what} in expression {self.text!r}", self.source, self.line)

    def build(self, node: ast.AST) -> sp.Expr:
        if isinstance(node, ast.Constant):
            value = node.value
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise self.fail(f"literal {value!r} is not a number")
            return sp.Integer(value) if isinstance(value, int) else sp.Float(value)
        if isinstance(node, ast.Name):
            if node.id in self.symbols:
                return self.symbols[node.id]
            if node.id in CONSTANTS:
                return CONSTANTS[node.id]
            if node.id in FUNCTIONS:
                raise self.fail(f"function {node.id!r} used without a call")
            raise self.fail(f"unknown symbol {node.id!r}")
        if isinstance(node, ast.UnaryOp):
            operand = self.build(node.operand)
            if isinstance(node.op, ast.USub):
                return -operand
            if isinstance(node.op, ast.UAdd):
                return operand
            raise self.fail(f"operator {type(node.op).__name__} not allowed")
        if isinstance(node, ast.BinOp):
            left, right = self.build(node.left), self.build(node.right)
            op = node.op
            if isinstance(op, ast.Add):
                return left + right
            if isinstance(op, ast.Sub):
                return left - right
            if isinstance(op, ast.Mult):
                return left * right
            if isinstance(op, ast.Div):
                return left / right
            if isinstance(op, ast.Pow):
                if right.is_Number and abs(float(right)) > _MAX_POWER:
                    raise self.fail(f"exponent {right} larger than {_MAX_POWER}")
                return left**right
            raise self.fail(f"operator {type(op).__name__} not allowed")
        if isinstance(node, ast.Call):
            if not isinstance(node.func, ast.Name) or node.func.id not in FUNCTIONS:
                name = node.func.id if isinstance(node.func, ast.Name) else ast.dump(node.func)
                raise self.fail(f"call to {name!r} not allowed (allowed: {', '.join(FUNCTIONS)})")
            if node.keywords:
                raise self.fail("keyword arguments not allowed")
            arity = _ARITY.get(node.func.id, 1)
            if len(node.args) != arity:
                raise self.fail(f"{node.func.id} takes {arity} argument(s), got {len(node.args)}")
            return FUNCTIONS[node.func.id](*(self.build(a) for a in node.args))
        raise self.fail(f"{type(node).__name__} not allowed")
