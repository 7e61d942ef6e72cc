"""The checks that keep reading a spec bounded (the limits of :mod:`.limits`).

Text is scanned with :mod:`tokenize` before :func:`ast.parse` sees it: nesting deeper than
``max_depth`` is refused there, and a long sum is split into its terms at the top level, so a
polynomial of thousands of terms is parsed term by term (Python's parser nests ``a + b + c``
one level per term and gives up near a thousand). Built values are checked as they are made:
constants must be real and finite floats, exact integers short, exponents of symbols small,
and an expression's size — as a tree, shared subexpressions counted each time they occur,
which is what derivatives and printing will see — under ``max_nodes``.
"""

from __future__ import annotations

import io
import keyword
import math
import token
import tokenize

import sympy as sp

_OPEN, _CLOSE = "([{", ")]}"
#: Top-level tokens that make a text more than a sum (left to the parser and its errors).
_NOT_A_SUM = {",", ":", "=", "==", "!=", "<", ">", "<=", ">=", ":=", "->", ";"}


def scan(text: str) -> tuple[int, list[tuple[str, str]] | None]:
    """``(depth, terms)``: the deepest nesting of brackets in ``text``, and its top-level
    terms as ``[(sign, text)]`` with ``sign`` ``"+"`` or ``"-"`` — or None when the text does
    not tokenize, has a single term, or is not a plain sum at its top level.

    Examples
    --------
    >>> scan("a - 2*(x + y) + -b**2")
    (1, [('+', 'a'), ('-', '2*(x + y)'), ('+', '-b**2')])
    >>> scan("sin(cos(x))")[0]
    2
    """
    try:
        tokens = list(tokenize.generate_tokens(io.StringIO(text).readline))
    except (tokenize.TokenError, IndentationError, SyntaxError):
        return 0, None
    depth = deepest = 0
    cuts: list[tuple[int, str]] = []  # (offset of the operator, sign)
    previous = None
    lines = text.splitlines(keepends=True)
    starts = [0]
    for line in lines:
        starts.append(starts[-1] + len(line))
    plain = True
    for tok in tokens:
        if tok.type in (token.NEWLINE, token.NL, token.INDENT, token.DEDENT, token.ENDMARKER,
                        token.COMMENT):
            continue
        if tok.type == token.ERRORTOKEN:
            plain = False
            continue
        s = tok.string
        if s in _OPEN:
            depth += 1
            deepest = max(deepest, depth)
        elif s in _CLOSE:
            depth -= 1
        elif depth == 0:
            if s in _NOT_A_SUM or (tok.type == token.NAME and keyword.iskeyword(s)):
                plain = False
            elif s in "+-" and previous is not None and _operand_end(previous):
                cuts.append((starts[tok.start[0] - 1] + tok.start[1], s))
        previous = tok
    if not plain or not cuts:
        return deepest, None
    terms, at, sign = [], 0, "+"
    for offset, op in cuts:
        terms.append((sign, text[at:offset].strip()))
        at, sign = offset + 1, op
    terms.append((sign, text[at:].strip()))
    if any(not t for _, t in terms):
        return deepest, None
    return deepest, terms


def long_groups(text: str, longer_than: int) -> list[tuple[int, int]]:
    """The outermost parenthesised groups of ``text`` holding a sum of more than
    ``longer_than`` terms at their own level, as ``(start, end)`` offsets of their inside
    (``a*(x + y + ... )``: Python's parser would nest one level per term)."""
    try:
        tokens = list(tokenize.generate_tokens(io.StringIO(text).readline))
    except (tokenize.TokenError, IndentationError, SyntaxError):
        return []
    starts = [0]
    for line in text.splitlines(keepends=True):
        starts.append(starts[-1] + len(line))
    stack: list[list] = []  # per open bracket: [kind, inner start offset, terms]
    groups: list[tuple[int, int]] = []
    previous = None
    for tok in tokens:
        if tok.type in (token.NEWLINE, token.NL, token.COMMENT, token.ENDMARKER):
            continue
        at = starts[tok.start[0] - 1] + tok.start[1]
        s = tok.string
        if s in _OPEN:
            stack.append([s, at + 1, 1])
        elif s in _CLOSE and stack:
            kind, inner, terms = stack.pop()
            if kind == "(" and terms > longer_than:
                groups = [g for g in groups if not (inner <= g[0] and g[1] <= at)]
                groups.append((inner, at))
        elif s in "+-" and stack and previous is not None and _operand_end(previous):
            stack[-1][2] += 1
        previous = tok
    return sorted(groups)


def _operand_end(tok: tokenize.TokenInfo) -> bool:
    """A token after which ``+``/``-`` is binary: a name, a number, a closing bracket."""
    if tok.type == token.NAME:
        return not keyword.iskeyword(tok.string)
    return tok.type == token.NUMBER or tok.string in _CLOSE


def tree_size(expr: sp.Basic, cap: int) -> int:
    """The number of nodes of ``expr`` as a tree (a shared subexpression counted each time it
    occurs), computed on the DAG; stops counting above ``cap``."""
    sizes: dict = {}
    stack = [(expr, False)]
    while stack:
        node, expanded = stack.pop()
        if node in sizes:
            continue
        if not node.args:
            sizes[node] = 1
        elif expanded:
            sizes[node] = min(cap + 1, 1 + sum(sizes[a] for a in node.args))
        else:
            stack.append((node, True))
            stack.extend((a, False) for a in node.args if a not in sizes)
    return sizes[expr]


def integer_digits(value: sp.Integer) -> int:
    """Decimal digits of an exact integer (without converting it to text)."""
    n = abs(int(value))
    return 1 if n == 0 else int(n.bit_length() * math.log10(2)) + 1


def power_digits(base: sp.Expr, exponent: sp.Expr) -> float:
    """An estimate of the digits of ``base ** exponent`` for numbers, before computing it."""
    try:
        b = abs(float(base)) if not base.is_Integer else None
    except (TypeError, OverflowError, ValueError):
        return math.inf
    magnitude = integer_digits(base) if base.is_Integer else (
        math.log10(b) if b and b > 0 else 0.0)
    try:
        e = abs(float(exponent))
    except (TypeError, OverflowError, ValueError):
        return math.inf
    return e * abs(magnitude)


def constant_problem(value: sp.Expr, max_digits: int) -> str | None:
    """What is wrong with a constant subexpression, or None: it must be a real number
    within the range of a double (``sqrt(-1)``, ``log(-1)``, ``(-8)**(1/3)``,
    ``exp(exp(1000))`` are refused), an exact integer at most ``max_digits`` long."""
    if value.is_Integer:
        return None if integer_digits(value) <= max_digits else \
            f"an integer of more than {max_digits} digits"
    if value.is_Rational:
        return None if max(integer_digits(value.p), integer_digits(value.q)) <= max_digits \
            else f"a fraction of more than {max_digits} digits"
    try:
        number = complex(sp.N(value, 20))
    except (TypeError, ValueError, OverflowError, ZeroDivisionError):
        return "not a finite real number"
    if number.imag != 0 and abs(number.imag) > 1e-15 * max(abs(number.real), 1e-300):
        return f"complex ({number.real:.6g}{number.imag:+.6g}i), not real"
    if not math.isfinite(number.real) or abs(number.real) > 1e300:
        return "beyond the range of a double"
    return None
