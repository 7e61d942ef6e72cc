"""The CasADi backend: one Python module per family whose functions are CasADi ``Function``s.

Each function is built on ``SX`` symbols with named inputs and outputs; measurement
functions take ONE measure and the runtime maps them over the measures of a channel
(``Function.map``, :mod:`kanagen.runtime.backends`). Common subexpressions found by SymPy's
CSE are ``SX`` nodes shared by every output. CasADi is 2-D: an output of shape ``()`` is
1×1, ``(a,)`` is a×1, and ``(a, b, …, z)`` is ``(a·b·…) × z`` in row-major order (the
runtime reshapes). The module's ``FUNCTIONS`` feed CasADi's C code generator
(:mod:`kanagen.codegen.compile`).
"""

from __future__ import annotations

import math
import re

from .backend import Backend, printed
from .description import FORMAT, Description, Function
from .printer import CasadiPrinter


def matrix_shape(shape: tuple[int, ...]) -> tuple[int, int]:
    """The 2-D CasADi shape of an output of NumPy shape ``shape`` (per measure)."""
    if len(shape) <= 1:
        return (shape[0] if shape else 1), 1
    return math.prod(shape[:-1]), shape[-1]


def _index(index: tuple[int, ...], shape: tuple[int, ...]) -> str:
    if len(index) <= 1:
        return f"{index[0] if index else 0}, 0"
    row = 0
    for i, size in zip(index[:-1], shape[:-1], strict=True):
        row = row * size + i
    return f"{row}, {index[-1]}"


def _doc(f: Function) -> str:
    shapes = ", ".join(f"{o.name} ({'×'.join(map(str, matrix_shape(o.shape)))})"
                       for o in f.outputs)
    one = " (one measure)" if f.per_measure else ""
    return f"{f.summary}{one}: {shapes}."


def casadi_names(functions: list[Function]) -> dict[str, str]:
    """CasADi's name of each function: CasADi refuses consecutive underscores (``c0_m__x``),
    so runs of them become one, and a clash gets a numbered suffix."""
    out, taken = {}, set()
    for f in functions:
        base = re.sub("_+", "_", f.name)
        name, i = base, 1
        while name in taken:
            name, i = f"{base}_{i}", i + 1
        taken.add(name)
        out[f.name] = name
    return out


def function_context(f: Function, cname: str) -> dict:
    """One function as plain data for the CasADi templates."""
    temps, outputs = printed(f, CasadiPrinter)
    return {
        "name": f.name,
        "cname": cname,
        "doc": _doc(f),
        "inputs": [(inp.name, len(inp.symbols)) for inp in f.inputs],
        "unpack": [f"{inp.prefix}{s.name} = {inp.name}[{i}]" for inp, i, s in f.used()],
        "temps": temps,
        "outputs": [{"name": o.name, "shape": matrix_shape(o.shape),
                     "entries": [(_index(i, o.shape), code) for i, code in entries]}
                    for o, entries in zip(f.outputs, outputs, strict=True)],
    }


def context(desc: Description) -> dict:
    """The plain data the CasADi module template sees."""
    every = [*desc.functions, *(f for f in (desc.derived, desc.slack_measures) if f)]
    cnames = casadi_names(every)
    return {
        "format": FORMAT,
        "source": desc.source,
        "sha256": desc.sha256,
        "name": desc.family.name,
        "functions": [function_context(f, cnames[f.name]) for f in every],
        "derived": desc.derived.name if desc.derived else None,
        "slack_measures": desc.slack_measures.name if desc.slack_measures else None,
        "models": [{"name": name, "c0": e.c0, "channels": list(e.channels),
                    "reduced": {"c0": e.reduced_c0, "channels": list(e.reduced_channels)}
                    if e.reduction else None}
                   for name, e in desc.models],
    }


BACKEND = Backend("casadi", "casadi", {"module.py.jinja": "{name}_casadi.py"}, context)
