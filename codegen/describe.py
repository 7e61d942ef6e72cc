"""What to generate for a family, as plain data: derivatives, CSE, printed statements.

The description is built from the validated IR only, and templates see nothing else
(names, shapes, code strings). One description per family; backends render it.
"""

from __future__ import annotations

from dataclasses import dataclass

import sympy as sp

from ..modelspec.constructs import qualitative_labels
from ..modelspec.ir import Family, symbol
from .printer import NumpyPrinter

#: Version of the generated-file layout; generated modules carry it and the loader checks it.
FORMAT = 1


@dataclass(frozen=True)
class Output:
    """One output array: its name, NumPy shape text and the non-zero entries."""

    name: str
    shape: str
    entries: tuple[tuple[str, str], ...]  # (index text, code)


@dataclass(frozen=True)
class Function:
    """One generated function: signature, unpacking, CSE temporaries and outputs."""

    name: str
    args: tuple[str, ...]
    doc: str
    unpack: tuple[str, ...]
    temps: tuple[tuple[str, str], ...]
    outputs: tuple[Output, ...]
    returns: str


def _names(family: Family, components: tuple[str, ...] = ()) -> dict[sp.Symbol, str]:
    names = {symbol(n): f"p_{n}" for n in family.parameter_names}
    names.update({symbol(n): f"k_{n}" for n, _ in family.constants})
    names.update({symbol(c): f"m_{c}" for c in components})
    return names


def _unpack(family: Family, exprs, components: tuple[str, ...] = ()) -> tuple[str, ...]:
    """Unpacking lines for the symbols that the expressions use, in declaration order."""
    used = set().union(*(e.free_symbols for e in exprs)) if exprs else set()
    lines = [f"p_{n} = q[{i}]" for i, n in enumerate(family.parameter_names) if symbol(n) in used]
    lines += [f"k_{n} = k[{i}]" for i, (n, _) in enumerate(family.constants) if symbol(n) in used]
    lines += [f"m_{c} = m[:, {i}]" for i, c in enumerate(components) if symbol(c) in used]
    return tuple(lines)


def _function(name, args, doc, family, outputs, returns, components=()) -> Function:
    """CSE over every entry of every output, then print."""
    flat = [(o_name, shape, index, expr) for o_name, shape, entries in outputs
            for index, expr in entries if expr != 0]
    temps, reduced = sp.cse([e for *_, e in flat], symbols=sp.numbered_symbols("_tmp"),
                            order="canonical")
    names = _names(family, components)
    names.update({t: t.name for t, _ in temps})
    printer = NumpyPrinter(names)
    printed = {}
    for (o_name, _, index, _), expr in zip(flat, reduced, strict=True):
        printed.setdefault(o_name, []).append((index, printer.doprint(expr)))
    return Function(
        name=name,
        args=args,
        doc=doc,
        unpack=_unpack(family, [e for *_, e in flat], components),
        temps=tuple((t.name, printer.doprint(e)) for t, e in temps),
        outputs=tuple(Output(o, shape, tuple(printed.get(o, ()))) for o, shape, _ in outputs),
        returns=returns,
    )


def _shape_text(shape: tuple[int, ...]) -> str:
    return "(" + ", ".join(map(str, shape)) + ("," if len(shape) == 1 else "") + ")"


def _jacobian(exprs, variables):
    return [[sp.diff(e, v) for v in variables] for e in exprs]


def c0_function(family: Family, model: str) -> Function:
    """``c0(q)`` and ``∂c0/∂q`` of one model (report eq. 38)."""
    q = [symbol(n) for n in family.parameter_names]
    cons = family.model(model).constraints
    jac = _jacobian(cons, q)
    p, n = len(cons), len(q)
    return _function(
        f"c0_{model}", ("q", "k"),
        f"Constraints c0(q) of model {model!r} and their Jacobian: shapes ({p},), ({p}, {n}).",
        family,
        [("c0", f"({p},)", [(f"{i}", e) for i, e in enumerate(cons)]),
         ("C0", f"({p}, {n})", [(f"{i}, {j}", jac[i][j]) for i in range(p) for j in range(n)])],
        "c0, C0",
    )


def measure_function(family: Family, name: str, channel: str, equations) -> Function:
    """``c_i``, ``∂c_i/∂q`` and ``∂c_i/∂m_i`` of a channel, vectorised over measures."""
    ch = family.channel(channel)
    q = [symbol(n) for n in family.parameter_names]
    m = [symbol(c) for c in ch.corrected]
    jq, jm = _jacobian(equations, q), _jacobian(equations, m)
    p, n, k = len(equations), len(q), len(m)
    return _function(
        name, ("q", "m", "k"),
        f"Equations of channel {channel!r}, their Jacobians in q and in the corrected\n"
        f"    components {list(ch.corrected)}: shapes (M, {p}), (M, {p}, {n}), (M, {p}, {k}).",
        family,
        [("c", f"(M, {p})", [(f":, {i}", e) for i, e in enumerate(equations)]),
         ("C", f"(M, {p}, {n})",
          [(f":, {i}, {j}", jq[i][j]) for i in range(p) for j in range(n)]),
         ("D", f"(M, {p}, {k})",
          [(f":, {i}, {j}", jm[i][j]) for i in range(p) for j in range(k)])],
        "c, C, D",
        components=ch.components,
    )


def derived_function(family: Family) -> Function:
    """Every derived quantity and its Jacobian in q (for uncertainty propagation)."""
    q = [symbol(n) for n in family.parameter_names]
    outputs, ret = [], []
    n = len(q)
    for d in family.derived:
        shape = d.shape
        if shape:
            idx = [", ".join(map(str, divmod(i, shape[1]))) if len(shape) == 2 else str(i)
                   for i in range(len(d.expressions))]
        else:
            idx = ["()"]
        outputs.append((f"v_{d.name}", _shape_text(shape),
                        [(i, e) for i, e in zip(idx, d.expressions, strict=True)]))
        outputs.append((f"j_{d.name}", _shape_text(shape + (n,)),
                        [(f"{i}, {j}" if shape else f"{j}", sp.diff(e, v))
                         for i, e in zip(idx, d.expressions, strict=True)
                         for j, v in enumerate(q)]))
        ret.append(f"{d.name!r}: (v_{d.name}, j_{d.name})")
    return _function(
        "derived", ("q", "k"),
        "Derived quantities and their Jacobians in q, by name: {name: (value, jacobian)}.",
        family, outputs, "{" + ", ".join(ret) + "}",
    )


def slack_function(family: Family) -> Function:
    """The measure ``c`` of each slack's relation (``c >= 0``, ``c > 0``, ``c != 0``)."""
    k = len(family.slack_relations)
    return _function(
        "slack_measures", ("q", "k"),
        "For each slack component, c of its relation (c >= 0, c > 0 or c != 0).",
        family,
        [("c", f"({k},)", [(f"{i}", c) for i, (_, c) in enumerate(family.slack_relations)])],
        "c",
    )


def describe(family: Family, source_name: str) -> dict:
    """The plain-data description of everything generated for ``family``."""
    functions, models, shapes = [], {}, set()
    measure_names: dict[tuple, str] = {}
    for model in family.models:
        functions.append(c0_function(family, model.name))
        channels = {}
        for ch in family.channels:
            eqs = family.equations(model.name, ch.name)
            key = (ch.name, eqs)
            if key not in measure_names:
                overridden = eqs != ch.equations
                fname = f"measure_{ch.name}" + (f"__{model.name}" if overridden else "")
                measure_names[key] = fname
                functions.append(measure_function(family, fname, ch.name, eqs))
            channels[ch.name] = measure_names[key]
            shapes.add((len(eqs), len(ch.corrected)))
        models[model.name] = {"c0": f"c0_{model.name}", "channels": channels}
    return {
        "format": FORMAT,
        "source": source_name,
        "sha256": family.sha256,
        "family": family_metadata(family),
        "functions": functions,
        "models": models,
        "has_derived": bool(family.derived),
        "derived": derived_function(family) if family.derived else None,
        "slack_measures": slack_function(family) if family.slack else None,
        "kernels": sorted(shapes),
    }


def family_metadata(family: Family) -> dict:
    """What the runtime needs to know of the family, as plain data (no SymPy objects)."""
    return {
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
    }


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
    labels = qualitative_labels(model.constraints, parameter)
    if labels:
        out["labels"] = {name: list(values) for name, values in sorted(labels.items())}
    return out
