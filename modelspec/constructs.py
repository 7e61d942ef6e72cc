"""Modelling constructs of the report's appendix F, compiled into equations.

A model constraint may be a formula instead of an expression (``expr = 0``): comparisons,
``x in {a, b, ...}``, ``and``, ``or``, ``not`` and ``A if C else B``. The formula is brought
to conjunctive normal form (AND of ORs, negations pushed onto the relations), and then:

* each AND term (clause) is one equation; an OR multiplies its atoms' equations;
* ``c = 0`` → ``c``; ``c >= 0`` → ``c − s²``; ``c > 0`` → ``c·s² − 1``; ``c != 0`` →
  ``c·s − 1`` (``<=``/``<`` as ``−c >= 0``/``−c > 0``); each inequality brings a new
  parameter component, its slack ``s``;
* ``x in {a, b, ...}`` → ``(x − a)(x − b)… = 0`` (a qualitative variable);
* ``A if C else B`` → ``(C and A) or (not C and B)``; NOT flips a relation as the report lists.

Quantifiers do not exist in the language; booleans inside arithmetic are refused.
"""

from __future__ import annotations

import ast
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import sympy as sp
from sympy.logic.boolalg import BooleanFalse, BooleanTrue, to_cnf

from ..common.slack import slack_value
from .errors import SpecError
from .expressions import parse_expression
from .guards import scan
from .ir import symbol
from .limits import DEFAULT, Limits

_COMPARE = {ast.Eq: sp.Eq, ast.NotEq: sp.Ne, ast.Gt: sp.Gt, ast.GtE: sp.Ge, ast.Lt: sp.Lt,
            ast.LtE: sp.Le}


@dataclass(frozen=True)
class Slack:
    """A component added to the parameter for one inequality, and its relation."""

    name: str
    kind: str  # ">=", ">", "!="
    measure: sp.Expr  # c in c >= 0, c > 0 or c != 0


@dataclass(frozen=True)
class Compiled:
    equations: tuple[sp.Expr, ...]
    slacks: tuple[Slack, ...]
    #: clauses made of inequalities only, as indices into ``slacks``: the formula holds iff
    #: the equations hold and, in each of these clauses, at least one relation does
    clauses: tuple[tuple[int, ...], ...] = ()


def is_formula(text: object) -> bool:
    """Whether constraint text uses a construct (else it is a plain expression = 0)."""
    if not isinstance(text, str):
        return isinstance(text, sp.logic.boolalg.Boolean)
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except SyntaxError:
        return False
    return isinstance(tree.body, ast.Compare | ast.BoolOp | ast.IfExp) or (
        isinstance(tree.body, ast.UnaryOp) and isinstance(tree.body.op, ast.Not))


def parse_formula(text: str, symbols: Mapping[str, sp.Symbol], source: str, line: int | None,
                  limits: Limits = DEFAULT):
    """A constraint formula as a SymPy boolean (relations, And, Or, Not)."""
    if scan(text)[0] > limits.max_depth:
        raise SpecError(f"constraint {text[:80]!r} nested deeper than {limits.max_depth} "
                        "(limit max_depth)", source, line)
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except SyntaxError as exc:
        raise SpecError(f"cannot parse constraint {text!r}: {exc.msg}", source, line) from None
    except (RecursionError, MemoryError, ValueError):
        raise SpecError(f"constraint {text[:80]!r} too deeply nested", source, line) from None

    def fail(what):
        return SpecError(f"{what} in constraint {text!r}", source, line)

    def term(node):
        return parse_expression(ast.unparse(node), symbols, source, line, limits)

    def formula(node):
        if isinstance(node, ast.BoolOp):
            parts = [formula(v) for v in node.values]
            return sp.And(*parts) if isinstance(node.op, ast.And) else sp.Or(*parts)
        if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.Not):
            return sp.Not(formula(node.operand))
        if isinstance(node, ast.IfExp):
            cond = formula(node.test)
            return sp.Or(sp.And(cond, formula(node.body)),
                         sp.And(sp.Not(cond), formula(node.orelse)))
        if isinstance(node, ast.Compare):
            return compare(node)
        if isinstance(node, ast.Call | ast.Name | ast.BinOp | ast.UnaryOp | ast.Constant):
            # a bare expression inside a formula means "expression = 0"
            return sp.Eq(term(node), 0, evaluate=False)
        raise fail(f"{type(node).__name__} not allowed")

    def compare(node):
        atoms, left = [], node.left
        for op, right in zip(node.ops, node.comparators, strict=True):
            if isinstance(op, ast.In | ast.NotIn):
                if not isinstance(right, ast.Set | ast.Tuple | ast.List) or not right.elts:
                    raise fail("'in' needs a set of values, e.g. x in {-1, 1}")
                x = term(left)
                atom = sp.Or(*(sp.Eq(x - term(v), 0, evaluate=False) for v in right.elts))
                atoms.append(atom if isinstance(op, ast.In) else sp.Not(atom))
            elif type(op) in _COMPARE:
                atoms.append(_COMPARE[type(op)](term(left) - term(right), 0, evaluate=False))
            else:
                raise fail(f"operator {type(op).__name__} not allowed")
            left = right
        return sp.And(*atoms)

    result = formula(tree.body)
    for node in ast.walk(tree.body):
        if isinstance(node, ast.Lambda | ast.comprehension | ast.NamedExpr):
            raise fail("quantifiers and bindings cannot be compiled")
    return result


def compile_formula(formula, label: str, source: str = "<spec>",
                    line: int | None = None, limits: Limits = DEFAULT) -> Compiled:
    """Equations and slacks for a constraint formula (report appendix F).

    The conjunctive normal form is cleaned before it becomes equations: clauses holding a
    relation and its negation (always true) are dropped, and so is a clause that contains
    another (implied by it), so that no equation is repeated or redundant by construction.
    """
    if isinstance(formula, BooleanTrue):
        return Compiled((), ())
    if isinstance(formula, BooleanFalse):
        raise SpecError(f"constraint {label!r} is always false", source, line)
    clauses, literals = cnf_size(formula)
    if clauses > limits.max_clauses or literals > limits.max_slacks:
        raise SpecError(f"constraint {label!r}: its conjunctive normal form has {clauses} "
                        f"clauses of {literals} relations in all (limits max_clauses = "
                        f"{limits.max_clauses}, max_slacks = {limits.max_slacks})", source, line)
    cnf = to_cnf(formula, simplify=False)
    if isinstance(cnf, BooleanTrue):
        return Compiled((), ())
    if isinstance(cnf, BooleanFalse):
        raise SpecError(f"constraint {label!r} is always false", source, line)
    clauses = []
    for clause in cnf.args if isinstance(cnf, sp.And) else (cnf,):
        atoms = frozenset(_canonical(a, label, source, line)
                          for a in (clause.args if isinstance(clause, sp.Or) else (clause,)))
        if not any(_complement(a) in atoms for a in atoms):  # else always true
            clauses.append(atoms)
    clauses = [c for i, c in enumerate(clauses)
               if not any(o < c or (o == c and j < i) for j, o in enumerate(clauses))]
    if not clauses:
        return Compiled((), ())
    clauses.sort(key=lambda c: (len(c), sorted(map(sp.default_sort_key, _exprs(c)))))
    equations, slacks, only_inequalities = [], [], []
    for atoms in clauses:
        product, used = sp.Integer(1), []
        for kind, c in sorted(atoms, key=lambda a: (a[0], sp.default_sort_key(a[1]))):
            factor, index = _equation(kind, c, label, slacks)
            product *= factor
            used.append(index)
        equations.append(product)
        if all(i is not None for i in used):
            only_inequalities.append(tuple(sorted(set(used))))
    if len(slacks) == 1:
        slacks[0] = Slack(f"s_{label}", slacks[0].kind, slacks[0].measure)
        equations = [e.subs(symbol(f"s_{label}_1"), symbol(f"s_{label}")) for e in equations]
    return Compiled(tuple(equations), tuple(slacks), tuple(only_inequalities))


def cnf_size(formula) -> tuple[int, int]:
    """The clauses of ``formula``'s conjunctive normal form and the relations they hold in
    all, counted before distributing (``(a and b) or (c and d) or ...`` doubles them per
    term). Computed for the formula and its negation together, as NOT flips them."""
    cap = 10**9

    def sizes(f) -> tuple[tuple[int, int], tuple[int, int]]:
        """((clauses, literals) of f, of not f)."""
        if isinstance(f, sp.Not):
            pos, neg = sizes(f.args[0])
            return neg, pos
        if isinstance(f, sp.And | sp.Or):
            parts = [sizes(a) for a in f.args]
            conj = lambda ps: (min(cap, sum(p[0] for p in ps)),  # noqa: E731
                               min(cap, sum(p[1] for p in ps)))
            disj = lambda ps: _distributed(ps, cap)  # noqa: E731
            pos, neg = [p for p, _ in parts], [n for _, n in parts]
            return (conj(pos), disj(neg)) if isinstance(f, sp.And) else (disj(pos), conj(neg))
        return (1, 1), (1, 1)

    return sizes(formula)[0]


def _distributed(parts, cap: int) -> tuple[int, int]:
    """Clauses and literals of an OR of CNFs: every choice of one clause per part."""
    clauses, literals = 1, 0
    for c, lits in parts:
        # each clause of the product holds one clause of this part: literals add up over
        # the clauses of the others
        literals = min(cap, literals * c + lits * clauses)
        clauses = min(cap, clauses * c)
    return clauses, literals


def _exprs(atoms):
    return [c for _, c in atoms]


def _canonical(atom, label, source, line) -> tuple[str, sp.Expr]:
    """A relation as (kind, c) with kind "=", "!=", ">=" or ">" and the relation ``c kind
    0``; "=" and "!=" with a sign fixed, so that equal relations compare equal."""
    if isinstance(atom, sp.Not):  # to_cnf keeps Not on non-relational atoms only
        raise SpecError(f"cannot negate {atom.args[0]} in constraint {label!r}", source, line)
    if not isinstance(atom, sp.core.relational.Relational):
        raise SpecError(f"{atom} is not a relation (constraint {label!r})", source, line)
    c = sp.expand(atom.lhs - atom.rhs)
    if isinstance(atom, sp.Le | sp.Lt):
        c = -c
    kind = {sp.Eq: "=", sp.Ne: "!=", sp.Ge: ">=", sp.Le: ">=", sp.Gt: ">", sp.Lt: ">"}[
        type(atom)]
    if kind in ("=", "!=") and c.could_extract_minus_sign():
        c = -c
    return kind, c


def _complement(atom: tuple[str, sp.Expr]) -> tuple[str, sp.Expr]:
    """NOT of a relation, as the report lists: = ↔ !=, c >= 0 ↔ −c > 0."""
    kind, c = atom
    if kind in ("=", "!="):
        return ("!=" if kind == "=" else "="), c
    return (">" if kind == ">=" else ">="), sp.expand(-c)


def _equation(kind, c, label, slacks) -> tuple[sp.Expr, int | None]:
    """The equation of one relation, and the index of its slack (one per relation)."""
    if kind == "=":
        return c, None
    i = next((j for j, known in enumerate(slacks)
              if known.kind == kind and sp.expand(known.measure - c) == 0), None)
    if i is None:
        i = len(slacks)
        slacks.append(Slack(f"s_{label}_{i + 1}", kind, c))
    s = symbol(slacks[i].name)
    if kind == ">=":
        return c - s**2, i
    if kind == ">":
        return c * s**2 - 1, i
    return c * s - 1, i


def qualitative_labels(equations, parameter: Iterable[str]) -> dict[str, tuple[float, ...]]:
    """The qualitative variables among a model's equations: an equation that is a product of
    factors ``x − a`` in one parameter component ``x`` with numbers ``a`` (what ``x in {a, b,
    ...}`` compiles to) gives ``x`` its labels ``a, b, ...``, in increasing order.

    A local solver stays on the label it starts at; the robust search starts a solve on each
    label (or combination of labels) so the data choose.
    """
    names = set(parameter)
    labels: dict[str, tuple[float, ...]] = {}
    for eq in equations:
        factors = sp.Mul.make_args(sp.factor(eq))
        free = set().union(*(f.free_symbols for f in factors))
        if len(free) != 1 or len(factors) < 2:
            continue
        (x,) = free
        if x.name not in names:
            continue
        values = []
        for f in factors:
            if f.is_number:
                continue
            base, exponent = f.as_base_exp()
            poly = sp.Poly(base, x)
            if poly.degree() != 1 or not exponent.is_Integer:
                break
            a, b = poly.all_coeffs()
            values.append(float(-b / a))
        else:
            if len(values) >= 2:
                labels[x.name] = tuple(sorted(set(values)))
    return labels


def slack_start(slack: Slack, values: Mapping[sp.Symbol, float]) -> float:
    """The slack's value at the spec's default point (:func:`slack_value`)."""
    try:
        c = float(sp.sympify(slack.measure.xreplace(values)).evalf())  # a SymPy object
    except (TypeError, ValueError, AttributeError):
        c = 1.0
    return slack_value(slack.kind, c)
