"""WHAT to generate for a family: functions, their derivatives and CSE, as one description.

The description is built from the validated IR only. It holds SymPy expressions (after common
subexpression elimination), names and shapes — nothing about a target language. Backends
(:mod:`kanagen.codegen.backend`) print it into plain data for their templates.

Every function takes the parameter ``q`` (or ``r``, the free components of a model reduced
by :mod:`~kanagen.codegen.eliminate`) and the constants ``k``; measurement functions also
take one measure ``m`` (all the channel's components). Output shapes are per measure; a
backend vectorises measurement functions over the measures of a channel.
"""

from __future__ import annotations

from dataclasses import dataclass

import sympy as sp

from ..modelspec.constructs import qualitative_labels
from ..modelspec.ir import Family, symbol
from .eliminate import Reduction, linear_reduction
from .limits import finite_limits
from .version import FORMAT  # noqa: F401 - the layout version, re-exported here

#: Sums longer than this are differentiated as polynomials when they are.
_LONG_SUM = 100
#: An output with a sum of more terms than this is printed without common subexpressions.
_CSE_LIMIT = 500
#: Sums are printed in partial sums of this many terms.
_CHUNK = 200



@dataclass(frozen=True)
class Input:
    """An argument: its name, its size and the symbols it carries (by position)."""

    name: str  # "q", "r", "m" or "k"
    symbols: tuple[sp.Symbol, ...]
    prefix: str  # local names in generated code: prefix + symbol name


@dataclass(frozen=True)
class Output:
    """One output array: its name, shape (per measure) and non-zero entries after CSE."""

    name: str
    shape: tuple[int, ...]
    entries: tuple[tuple[tuple[int, ...], sp.Expr], ...]


@dataclass(frozen=True)
class Function:
    """One generated function: inputs, CSE temporaries (``_tmp0 …``) and outputs."""

    name: str
    kind: str  # "c0", "measure", "derived" or "slack"
    summary: str
    inputs: tuple[Input, ...]
    temps: tuple[tuple[sp.Symbol, sp.Expr], ...]
    outputs: tuple[Output, ...]
    #: derived quantities: (name, value output, Jacobian output), in declaration order
    pairs: tuple[tuple[str, str, str], ...] = ()

    @property
    def per_measure(self) -> bool:
        return any(i.name == "m" for i in self.inputs)

    def used(self) -> list[tuple[Input, int, sp.Symbol]]:
        """The input symbols the outputs and temporaries use, in input order."""
        used = set()
        for _, e in self.temps:
            used |= e.free_symbols
        for o in self.outputs:
            for _, e in o.entries:
                used |= e.free_symbols
        return [(inp, i, s) for inp in self.inputs for i, s in enumerate(inp.symbols)
                if s in used]

    def needed(self, outputs: tuple[str, ...]) -> tuple[set, list[tuple[Input, int, sp.Symbol]]]:
        """What the entries of ``outputs`` (names) need: the temporaries (a set of their
        symbols) and the input symbols (:meth:`used`'s triples), through the temporaries."""
        need = set()
        for o in self.outputs:
            if o.name in outputs:
                for _, e in o.entries:
                    need |= e.free_symbols
        temps = set()
        for t, e in reversed(self.temps):
            if t in need:
                temps.add(t)
                need |= e.free_symbols
        return temps, [(inp, i, s) for inp in self.inputs for i, s in enumerate(inp.symbols)
                       if s in need]

    def free_of(self, output: str, input_name: str) -> bool:
        """No entry of ``output`` depends on the symbols of the input ``input_name``, through
        the temporaries either (a measurement function's ``C`` free of ``q``: its equations
        are linear in the parameter)."""
        of_input = set(next(i for i in self.inputs if i.name == input_name).symbols)
        reach: dict[sp.Symbol, frozenset] = {}
        for t, e in self.temps:
            reach[t] = frozenset().union(*(reach.get(s, {s}) for s in e.free_symbols))
        out = next(o for o in self.outputs if o.name == output)
        return not any(reach.get(s, {s}) & of_input
                       for _, e in out.entries for s in e.free_symbols)

    def names(self) -> dict[sp.Symbol, str]:
        """Local name of every symbol in generated code."""
        out = {s: inp.prefix + s.name for inp in self.inputs for s in inp.symbols}
        out.update({t: t.name for t, _ in self.temps})
        return out


@dataclass(frozen=True)
class ModelEntry:
    """Which functions serve one model (and its reduced form, when it has one)."""

    c0: str
    channels: tuple[tuple[str, str], ...]  # (channel, measure function)
    reduction: Reduction | None = None
    reduced_c0: str | None = None
    reduced_channels: tuple[tuple[str, str], ...] = ()


@dataclass(frozen=True)
class Description:
    """Everything generated for a family; one per family, shared by every backend."""

    source: str
    sha256: str
    family: Family
    functions: tuple[Function, ...]  # c0 and measurement functions, reduced ones included
    models: tuple[tuple[str, ModelEntry], ...]
    derived: Function | None
    slack_measures: Function | None


def _function(name, kind, summary, inputs, outputs, pairs=()) -> Function:
    """CSE over every non-zero entry of every output — but for a long polynomial (a sum of
    more than :data:`_CSE_LIMIT` terms: SymPy's matching of common arguments grows with
    their square, and a polynomial's monomials share little); sums longer than
    :data:`_CHUNK` are printed in chunks (Python's compiler nests a sum one level per
    term)."""
    flat = [(o_name, index, expr) for o_name, _, entries in outputs
            for index, expr in entries if expr != 0]
    exprs = [e for *_, e in flat]
    if any(e.is_Add and len(e.args) > _CSE_LIMIT for e in exprs):
        temps, reduced = [], exprs
    else:
        temps, reduced = sp.cse(exprs, symbols=sp.numbered_symbols("_tmp"),
                                order="canonical")
    temps, reduced = _chunked(temps, reduced)
    entries: dict[str, list] = {o: [] for o, _, _ in outputs}
    for (o_name, index, _), expr in zip(flat, reduced, strict=True):
        entries[o_name].append((index, expr))
    return Function(name, kind, summary, tuple(inputs), tuple(temps),
                    tuple(Output(o, shape, tuple(entries[o])) for o, shape, _ in outputs),
                    tuple(pairs))


def _chunked(temps, reduced):
    """Temps and outputs with every sum longer than :data:`_CHUNK` terms split into partial
    sums (``_sum0``, ...) computed first."""
    names = sp.numbered_symbols("_sum")
    out_temps = []

    def split(expr):
        if not (expr.is_Add and len(expr.args) > _CHUNK):
            return expr
        parts = []
        for at in range(0, len(expr.args), _CHUNK):
            part = next(names)
            out_temps.append((part, sp.Add(*expr.args[at:at + _CHUNK], evaluate=False)))
            parts.append(part)
        return sp.Add(*parts, evaluate=False)

    for name, expr in temps:
        out_temps.append((name, split(expr)))
    outputs = [split(e) for e in reduced]
    return out_temps, outputs


def _parameter_input(family: Family, reduction: Reduction | None) -> Input:
    q = [symbol(n) for n in family.parameter_names]
    if reduction is None:
        return Input("q", tuple(q), "p_")
    return Input("r", tuple(q[i] for i in reduction.free), "p_")


def _constants_input(family: Family) -> Input:
    return Input("k", tuple(symbol(n) for n, _ in family.constants), "k_")


def _jacobian(exprs, variables):
    return [[_derivative(e, v) for v in variables] for e in exprs]


def _derivative(expr: sp.Expr, variable: sp.Symbol) -> sp.Expr:
    """``∂expr/∂variable``; a long polynomial (a sum of many monomials) through
    :class:`sympy.Poly`, ten times faster than term by term, the same expanded result."""
    if variable not in expr.free_symbols:
        return sp.Integer(0)
    if expr.is_Add and len(expr.args) > _LONG_SUM:
        try:
            return sp.Poly(expr, *sorted(expr.free_symbols, key=sp.default_sort_key)).diff(
                variable).as_expr()
        except sp.PolynomialError:
            pass
    return finite_limits(sp.diff(expr, variable))


def c0_function(family: Family, model: str, reduction: Reduction | None = None) -> Function:
    """``c0(q)`` and ``∂c0/∂q`` of one model (report eq. 38), or of its reduced form."""
    par = _parameter_input(family, reduction)
    cons = family.model(model).constraints if reduction is None else reduction.constraints
    jac = _jacobian(cons, par.symbols)
    p, n = len(cons), len(par.symbols)
    name = f"c0_{model}" + ("__reduced" if reduction else "")
    what = "Constraints" if reduction is None else "Remaining constraints"
    return _function(
        name, "c0", f"{what} c0({par.name}) of model {model!r} and their Jacobian",
        [par, _constants_input(family)],
        [("c0", (p,), [((i,), e) for i, e in enumerate(cons)]),
         ("C0", (p, n), [((i, j), jac[i][j]) for i in range(p) for j in range(n)])],
    )


def measure_function(family: Family, name: str, channel: str, equations,
                     reduction: Reduction | None = None) -> Function:
    """``c_i``, ``∂c_i/∂q`` and ``∂c_i/∂m_i`` of a channel, for one measure."""
    ch = family.channel(channel)
    par = _parameter_input(family, reduction)
    if reduction is not None:
        equations = tuple(reduction.substitute(e) for e in equations)
    m = [symbol(c) for c in ch.corrected]
    jq, jm = _jacobian(equations, par.symbols), _jacobian(equations, m)
    p, n, k = len(equations), len(par.symbols), len(m)
    return _function(
        name, "measure",
        f"Equations of channel {channel!r}, their Jacobians in {par.name} and in the corrected"
        f"\n    components {list(ch.corrected)}",
        [par, Input("m", tuple(symbol(c) for c in ch.components), "m_"),
         _constants_input(family)],
        [("c", (p,), [((i,), e) for i, e in enumerate(equations)]),
         ("C", (p, n), [((i, j), jq[i][j]) for i in range(p) for j in range(n)]),
         ("D", (p, k), [((i, j), jm[i][j]) for i in range(p) for j in range(k)])],
    )


def derived_function(family: Family) -> Function:
    """Every derived quantity and its Jacobian in q (for uncertainty propagation)."""
    par = _parameter_input(family, None)
    n = len(par.symbols)
    outputs, pairs = [], []
    for d in family.derived:
        shape = d.shape
        idx = [divmod(i, shape[1]) if len(shape) == 2 else (i,) if shape else ()
               for i in range(len(d.expressions))]
        outputs.append((f"v_{d.name}", shape, list(zip(idx, d.expressions, strict=True))))
        outputs.append((f"j_{d.name}", shape + (n,),
                        [(i + (j,), finite_limits(sp.diff(e, v)))
                         for i, e in zip(idx, d.expressions, strict=True)
                         for j, v in enumerate(par.symbols)]))
        pairs.append((d.name, f"v_{d.name}", f"j_{d.name}"))
    return _function("derived", "derived",
                     "Derived quantities and their Jacobians in q, by name",
                     [par, _constants_input(family)], outputs, pairs)


def slack_function(family: Family) -> Function:
    """The measure ``c`` of each slack's relation (``c >= 0``, ``c > 0``, ``c != 0``)."""
    k = len(family.slack_relations)
    return _function(
        "slack_measures", "slack",
        "For each slack component, c of its relation (c >= 0, c > 0 or c != 0)",
        [_parameter_input(family, None), _constants_input(family)],
        [("c", (k,), [((i,), c) for i, (_, c) in enumerate(family.slack_relations)])],
    )


def describe(family: Family, source_name: str) -> Description:
    """The description of everything generated for ``family``."""
    functions, models = [], []
    made: dict[tuple, str] = {}

    def measure(channel, eqs, fname, reduction=None):
        key = (channel, eqs, reduction)
        if key not in made:
            made[key] = fname
            functions.append(measure_function(family, fname, channel, eqs, reduction))
        return made[key]

    for model in family.models:
        functions.append(c0_function(family, model.name))
        channels = []
        for ch in family.channels:
            eqs = family.equations(model.name, ch.name)
            overridden = eqs != ch.equations
            fname = f"measure_{ch.name}" + (f"__{model.name}" if overridden else "")
            channels.append((ch.name, measure(ch.name, eqs, fname)))
        reduction = linear_reduction(family, model.name)
        entry = ModelEntry(f"c0_{model.name}", tuple(channels))
        if reduction is not None:
            functions.append(c0_function(family, model.name, reduction))
            reduced = tuple(
                (ch.name, measure(ch.name, family.equations(model.name, ch.name),
                                  f"measure_{ch.name}__{model.name}__reduced", reduction))
                for ch in family.channels)
            entry = ModelEntry(entry.c0, entry.channels, reduction,
                               f"c0_{model.name}__reduced", reduced)
        models.append((model.name, entry))
    names = [f.name for f in functions]
    if len(set(names)) != len(names):  # the spec's names are checked to keep them apart
        raise ValueError(f"generated function names collide: {sorted(names)}")
    return Description(
        source=source_name,
        sha256=family.sha256,
        family=family,
        functions=tuple(functions),
        models=tuple(models),
        derived=derived_function(family) if family.derived else None,
        slack_measures=slack_function(family) if family.slack else None,
    )


def family_metadata(desc: Description) -> dict:
    """What the runtime needs to know of the family, as plain data (no SymPy objects)."""
    family = desc.family
    meta = {
        "name": family.name,
        "parameter": [[n, v] for n, v in family.parameter],
        "constants": [[n, v] for n, v in family.constants],
        "channels": {
            ch.name: {
                "components": list(ch.components),
                "exact": list(ch.exact),
                "corrected": list(ch.corrected),
                "equations": [str(e) for e in ch.equations],
            }
            for ch in family.channels
        },
        "models": {m.name: _model_metadata(m, family.parameter_names) for m in family.models},
        "derived": {d.name: list(d.shape) for d in family.derived},
        "null_model": family.null_model,
        "slack": list(family.slack),
        "slack_kinds": [kind for kind, _ in family.slack_relations],
        "slack_owner": list(family.slack_owner),
        "slack_clauses": {m: [list(c) for c in cl] for m, cl in family.slack_clauses},
        "reductions": {
            name: {"free": list(e.reduction.free),
                   "T": [[float(v) for v in row] for row in e.reduction.T],
                   "t": [float(v) for v in e.reduction.t]}
            for name, e in desc.models if e.reduction is not None
        },
    }
    if family.units:  # only when the spec has some (families without generate as before)
        meta["units"] = dict(family.units)
    if family.assumed:
        meta["assumed"] = dict(family.assumed)
    return meta


def _model_metadata(model, parameter: tuple[str, ...]) -> dict:
    """A model's constraints (as text), overrides and alternatives; its derived list,
    initializer and qualitative variables' labels only when it has them (so families
    without them generate as before)."""
    out = {
        "constraints": [str(e) for e in model.constraints],
        "equations": {c: [str(e) for e in eqs] for c, eqs in model.equations},
        "alternatives": [[a.model, a.phi] for a in model.alternatives],
    }
    if model.derived is not None:
        out["derived"] = list(model.derived)
    if model.initializer is not None:
        out["initializer"] = model.initializer
    if model.admissible is not None:
        out["admissible"] = model.admissible
    labels = qualitative_labels(model.constraints, parameter)
    if labels:
        out["labels"] = {name: list(values) for name, values in sorted(labels.items())}
    return out
