"""Safe parsing of expression text into SymPy, through Python's ``ast`` and a whitelist.

Nothing here evaluates text: ``ast.parse`` builds a tree, each node kind is checked against a
fixed list, and SymPy objects are built node by node. Names must be declared symbols, helper
definitions, or entries of :data:`FUNCTIONS` / :data:`MATRIX_FUNCTIONS` / :data:`CONSTANTS`.

Values are scalars or matrices (``sympy.ImmutableMatrix``; a vector is a column): list
literals ``[a, b, c]`` and ``[[a, b], [c, d]]``, ``@`` for the matrix product, ``*`` and ``/``
by a scalar, ``+``/``-`` of equal shapes, subscripts by integer literals (``v[0]``,
``M[1, 2]``) and the functions of :data:`MATRIX_FUNCTIONS`. Matrices expand into scalar
arithmetic at parse time: the IR and the code generators only ever see scalars.
"""

from __future__ import annotations

import ast
import math
import re
from collections.abc import Mapping

import sympy as sp

from .errors import SpecError
from .guards import constant_problem, long_groups, power_digits, scan, tree_size
from .limits import DEFAULT, Limits

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

Matrix = sp.ImmutableMatrix


def _cross(a, b):
    return Matrix(a.reshape(3, 1)).cross(Matrix(b.reshape(3, 1)))


def _skew(v):
    x, y, z = v
    return Matrix([[0, -z, y], [z, 0, -x], [-y, x, 0]])


#: Functions on matrices: name -> (arity or None for any, argument check, implementation).
#: They expand into scalar arithmetic, so code generators never meet them.
MATRIX_FUNCTIONS: dict[str, tuple[int | None, str, object]] = {
    "transpose": (1, "matrix", lambda m: m.T),
    "det": (1, "square", lambda m: m.det(method="berkowitz")),
    "trace": (1, "square", lambda m: m.trace()),
    "cross": (2, "vector3", _cross),
    "dot": (2, "vectors", lambda a, b: sum(x * y for x, y in zip(a, b, strict=True))),
    "skew": (1, "vector3", _skew),
    "diag": (None, "scalars", lambda *d: Matrix(sp.diag(*d))),
}

#: Parenthesised sums longer than this are parsed on their own (Python's parser nests).
_LONG_GROUP = 100

#: Named constants of the expression language.
CONSTANTS: dict[str, sp.Expr] = {"pi": sp.pi}

#: Names a spec may not declare (they would shadow the language).
RESERVED = frozenset(FUNCTIONS) | frozenset(MATRIX_FUNCTIONS) | frozenset(CONSTANTS)

_IDENTIFIER = re.compile(r"[A-Za-z][A-Za-z0-9_]*")
#: Longest name a spec may declare (generated file and function names are built from them).
MAX_NAME = 64


def check_identifier(name: object, what: str, source: str, line: int | None) -> str:
    """Return ``name`` if it is a plain identifier usable in generated code, else raise.

    ``__`` is refused: generated names join names with it (``measure_<channel>__<model>``,
    ``c0_<model>__reduced``), which keeps them injective."""
    import keyword

    if not isinstance(name, str) or not _IDENTIFIER.fullmatch(name):
        raise SpecError(
            f"{what} name {name!r} is not an identifier (letters, digits, '_', starting with a "
            "letter)",
            source,
            line,
        )
    if "__" in name:
        raise SpecError(f"{what} name {name!r} contains '__' (generated names are joined "
                        "with it)", source, line)
    if len(name) > MAX_NAME:
        raise SpecError(f"{what} name {name[:20]!r}... is longer than {MAX_NAME} characters",
                        source, line)
    if keyword.iskeyword(name) or name in RESERVED:
        raise SpecError(f"{what} name {name!r} is reserved", source, line)
    return name


def parse_expression(
    text: object,
    symbols: Mapping[str, sp.Expr | Matrix],
    source: str = "<spec>",
    line: int | None = None,
    limits: Limits = DEFAULT,
) -> sp.Expr | Matrix:
    """Parse one expression.

    Parameters
    ----------
    text : str or number
        The expression, in Python syntax restricted to numbers, declared names, ``+ - * / **
        @``, unary minus, list literals, integer subscripts and the functions of
        :data:`FUNCTIONS` and :data:`MATRIX_FUNCTIONS`.
    symbols : mapping
        Declared names and their values: SymPy symbols, or the expressions and matrices of
        helper definitions.
    source, line : str, int
        Where the text comes from, for error messages.
    limits : Limits
        What the expression may cost (:mod:`kanagen.modelspec.limits`).

    Returns
    -------
    sympy.Expr or sympy.ImmutableMatrix

    Examples
    --------
    >>> import sympy as sp
    >>> x = sp.Symbol("x")
    >>> parse_expression("2*x**2 - sqrt(x)", {"x": x})
    -sqrt(x) + 2*x**2
    >>> parse_expression("cross([1, 0, 0], [0, x, 0])", {"x": x}).T
    Matrix([[0, 0, x]])
    """
    if isinstance(text, bool):
        raise SpecError(f"expected an expression, got the boolean {text}", source, line)
    if isinstance(text, int | float):
        value = sp.Float(text) if isinstance(text, float) else sp.Integer(text)
        return _Builder(symbols, source, line, repr(text), limits).checked(value)
    if not isinstance(text, str):
        raise SpecError(
            f"expected an expression, got {type(text).__name__} {text!r}", source, line
        )
    if len(text) > limits.max_bytes:
        raise SpecError(f"expression longer than {limits.max_bytes} characters (limit "
                        "max_bytes)", source, line)
    text = text.strip()
    builder = _Builder(symbols, source, line, text, limits)
    if scan(text)[0] > limits.max_depth:
        raise builder.fail(f"nesting deeper than {limits.max_depth} (limit max_depth)")
    groups = long_groups(text, _LONG_GROUP)
    if groups:  # each long parenthesised sum parsed on its own, then used by name
        symbols = dict(symbols)
        pieces, at = [], 0
        for number, (start, end) in enumerate(groups):
            name = f"_kg_group{number}"
            symbols[name] = parse_expression(text[start:end], symbols, source, line, limits)
            pieces += [text[at:start], name]
            at = end
        text = "".join(pieces + [text[at:]])
        builder = _Builder(symbols, source, line, builder.text, limits)
    terms = scan(text)[1]
    try:
        if terms is None:
            value = builder.build(builder.tree(text))
        else:  # a long sum, term by term: Python's parser nests one level per term
            parts = [(sign, builder.build(builder.tree(term))) for sign, term in terms]
            if any(isinstance(v, Matrix) for _, v in parts):
                value = parts[0][1] if parts[0][0] == "+" else -parts[0][1]
                for sign, v in parts[1:]:
                    value = builder.add(value, v, sign)
            else:
                value = sp.Add(*(v if sign == "+" else -v for sign, v in parts))
    except RecursionError:
        raise builder.fail("too deeply nested (split it into definitions)") from None
    return builder.sized(value)


def _short(value) -> str:
    text = str(value)
    return text if len(text) <= 40 else text[:37] + "..."


def shape_text(value) -> str:
    """``"scalar"`` or ``"3×3 matrix"`` — for messages."""
    return f"{value.rows}×{value.cols} matrix" if isinstance(value, Matrix) else "scalar"


def _called(func: ast.AST) -> str:
    """What a call calls, as written (``np.hypot``), shortened; never an AST dump."""
    try:
        text = ast.unparse(func)
    except (RecursionError, ValueError):
        return type(func).__name__
    return text if len(text) <= 60 else text[:60] + "..."


class _Builder:
    def __init__(self, symbols, source, line, text, limits: Limits):
        self.symbols = symbols
        self.source = source
        self.line = line
        self.text = text
        self.limits = limits

    def fail(self, what: str) -> SpecError:
        shown = self.text if len(self.text) <= 200 else self.text[:200] + "..."
        return SpecError(f"{what} in expression {shown!r}", self.source, self.line)

    def tree(self, text: str) -> ast.AST:
        try:
            return ast.parse(text, mode="eval").body
        except SyntaxError as exc:
            raise SpecError(f"cannot parse expression {self.text!r}: {exc.msg}", self.source,
                            self.line) from None
        except (RecursionError, MemoryError, ValueError):
            raise self.fail("too deeply nested or too large (split it into definitions)") \
                from None

    def checked(self, value):
        """``value`` if it is no constant, or a real, finite one of bounded size."""
        if isinstance(value, Matrix):
            if max(value.shape) > self.limits.max_matrix:
                raise self.fail(f"a {shape_text(value)} (limit max_matrix = "
                                f"{self.limits.max_matrix})")
            return value
        if isinstance(value, sp.Basic) and not value.free_symbols and value.is_number:
            problem = constant_problem(value, self.limits.max_number_digits)
            if problem is not None:
                raise self.fail(f"the constant {_short(value)} is {problem}")
        return value

    def sized(self, value):
        """``value`` if its tree (definitions substituted) is within ``max_nodes``."""
        cap = self.limits.max_nodes
        parts = list(value) if isinstance(value, Matrix) else [value]
        total = 0
        for part in parts:
            total += tree_size(part, cap)
            if total > cap:
                raise self.fail(f"more than {cap} terms and factors once its definitions "
                                "are substituted (limit max_nodes)")
        return value

    def add(self, left, right, sign: str):
        shapes = (isinstance(left, Matrix), isinstance(right, Matrix))
        if shapes[0] != shapes[1] or (all(shapes) and left.shape != right.shape):
            raise self.fail(f"cannot add a {shape_text(left)} and a {shape_text(right)}")
        return left + right if sign == "+" else left - right

    def scalar(self, node: ast.AST, what: str) -> sp.Expr:
        value = self.build(node)
        if isinstance(value, Matrix):
            raise self.fail(f"{what} needs a scalar, got a {shape_text(value)}")
        return value

    def build(self, node: ast.AST) -> sp.Expr | Matrix:
        if isinstance(node, ast.Constant):
            value = node.value
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise self.fail(f"literal {value!r} is not a number")
            if isinstance(value, float) and not math.isfinite(value):
                raise self.fail(f"literal {value!r} is not finite")
            return self.checked(sp.Integer(value) if isinstance(value, int)
                                else sp.Float(value))
        if isinstance(node, ast.Name):
            if node.id in self.symbols:
                return self.symbols[node.id]
            if node.id in CONSTANTS:
                return CONSTANTS[node.id]
            if node.id in FUNCTIONS or node.id in MATRIX_FUNCTIONS:
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
            return self.binary(node)
        if isinstance(node, ast.Call):
            return self.call(node)
        if isinstance(node, ast.List):
            return self.matrix(node)
        if isinstance(node, ast.Subscript):
            return self.subscript(node)
        raise self.fail(f"{type(node).__name__} not allowed")

    def binary(self, node: ast.BinOp) -> sp.Expr | Matrix:
        op = node.op
        if isinstance(op, ast.BitXor):
            raise self.fail("'^' is not allowed (in Python it is not a power): write '**' "
                            "for the power, e.g. x**2")
        left, right = self.build(node.left), self.build(node.right)
        shapes = (isinstance(left, Matrix), isinstance(right, Matrix))
        if isinstance(op, ast.Add | ast.Sub):
            return self.checked(self.add(left, right, "+" if isinstance(op, ast.Add) else "-"))
        if isinstance(op, ast.Mult):
            if all(shapes):
                raise self.fail("'*' of two matrices: write '@' for the matrix product")
            return self.checked(left * right)
        if isinstance(op, ast.MatMult):
            if not all(shapes) or left.cols != right.rows:
                raise self.fail(f"'@' of a {shape_text(left)} and a {shape_text(right)}")
            return self.checked(left @ right)
        if isinstance(op, ast.Div):
            if shapes[1]:
                raise self.fail(f"division by a {shape_text(right)}")
            if right == 0:
                raise self.fail("division by zero: not finite")
            return self.checked(left / right)
        if isinstance(op, ast.Pow):
            if any(shapes):
                raise self.fail("'**' of a matrix not allowed")
            return self.power(left, right)
        raise self.fail(f"operator {type(op).__name__} not allowed")

    def power(self, base: sp.Expr, exponent: sp.Expr) -> sp.Expr:
        """``base ** exponent``, refused before it is computed when numbers would grow beyond
        ``max_number_digits``, and after when a symbol's folded exponent exceeds
        ``max_exponent`` (``(x**64)**64`` is ``x**4096``)."""
        limit = self.limits.max_exponent
        if exponent.is_Number and abs(exponent) > limit:
            raise self.fail(f"exponent {_short(exponent)} larger than {limit} (limit "
                            "max_exponent)")
        if base.is_number and exponent.is_number and not base.free_symbols and \
                power_digits(base, exponent) > self.limits.max_number_digits:
            raise self.fail(f"the constant {_short(base)}**{_short(exponent)} has more than "
                            f"{self.limits.max_number_digits} digits (limit "
                            "max_number_digits)")
        value = base**exponent
        for part in (value, *value.args):
            if part.is_Pow and part.exp.is_Number and abs(part.exp) > limit:
                raise self.fail(f"exponent {_short(part.exp)} after folding, larger than "
                                f"{limit} (limit max_exponent)")
        return self.checked(value)

    def call(self, node: ast.Call) -> sp.Expr | Matrix:
        name = node.func.id if isinstance(node.func, ast.Name) else None
        if name not in FUNCTIONS and name not in MATRIX_FUNCTIONS:
            allowed = ", ".join([*FUNCTIONS, *MATRIX_FUNCTIONS])
            hint = ""
            if name is None:  # np.hypot, math.sqrt, f(x)(y): name it as written
                name = _called(node.func)
                last = node.func.attr if isinstance(node.func, ast.Attribute) else None
                if last in FUNCTIONS or last in MATRIX_FUNCTIONS:
                    hint = f"; write {last}(...) without the module"
            raise self.fail(f"call to {name!r} not allowed{hint} (allowed: {allowed})")
        if node.keywords:
            raise self.fail("keyword arguments not allowed")
        if name in FUNCTIONS:
            arity = _ARITY.get(name, 1)
            if len(node.args) != arity:
                raise self.fail(f"{name} takes {arity} argument(s), got {len(node.args)}")
            return self.checked(FUNCTIONS[name](*(self.scalar(a, name) for a in node.args)))
        arity, kind, fn = MATRIX_FUNCTIONS[name]
        if arity is not None and len(node.args) != arity:
            raise self.fail(f"{name} takes {arity} argument(s), got {len(node.args)}")
        if kind == "scalars":
            if not node.args:
                raise self.fail(f"{name} takes at least one argument")
            return self.checked(fn(*(self.scalar(a, name) for a in node.args)))
        args = [self.build(a) for a in node.args]
        for value in args:
            if not isinstance(value, Matrix):
                raise self.fail(f"{name} needs a matrix or vector, got a scalar")
            vector = 1 in value.shape
            if (kind == "square" and value.rows != value.cols) or \
                    (kind == "vector3" and (not vector or len(value) != 3)) or \
                    (kind == "vectors" and (not vector or len(value) != len(args[0]))):
                raise self.fail(f"{name} of a {shape_text(value)} not allowed")
        if name == "det" and args[0].rows > self.limits.max_det:
            raise self.fail(f"det of a {shape_text(args[0])}: its expansion has "
                            f"{math.factorial(args[0].rows)} terms (limit max_det = "
                            f"{self.limits.max_det})")
        return self.checked(fn(*args))

    def matrix(self, node: ast.List) -> Matrix:
        if not node.elts:
            raise self.fail("empty list not allowed")
        if all(isinstance(e, ast.List) for e in node.elts):
            rows = [[self.scalar(e, "a matrix entry") for e in row.elts] for row in node.elts]
            if len({len(r) for r in rows}) != 1 or not rows[0]:
                raise self.fail("matrix rows of unequal length")
            return self.checked(Matrix(rows))
        return self.checked(Matrix([[self.scalar(e, "a vector entry")] for e in node.elts]))

    def subscript(self, node: ast.Subscript) -> sp.Expr:
        value = self.build(node.value)
        if not isinstance(value, Matrix):
            raise self.fail("Subscript not allowed on a scalar")
        index = node.slice.elts if isinstance(node.slice, ast.Tuple) else [node.slice]
        if not all(isinstance(i, ast.Constant) and type(i.value) is int for i in index):
            raise self.fail("subscripts must be integer literals")
        index = [i.value for i in index]
        if len(index) == 1 and 1 in value.shape:
            index = [index[0], 0] if value.cols == 1 else [0, index[0]]
        if len(index) != 2 or not all(0 <= i < n for i, n in zip(index, value.shape,
                                                                  strict=True)):
            raise self.fail(f"subscript {index} out of range for a {shape_text(value)}")
        return value[index[0], index[1]]
