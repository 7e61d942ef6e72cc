"""The NumPy backend: one Python module per family, vectorised over the measures of a channel,
and each function's row form (one measure, every entry written: report §6's unrolled code,
which the compiled engine calls, runtime/engine/rows.py)."""

from __future__ import annotations

import pprint

from .backend import Backend, printed
from .description import FORMAT, Description, Function, family_metadata
from .printer import NumpyPrinter


def _shape(shape: tuple[int, ...], per_measure: bool) -> str:
    dims = (("M",) if per_measure else ()) + tuple(map(str, shape))
    return "(" + ", ".join(dims) + ("," if len(dims) == 1 else "") + ")"


def _index(index: tuple[int, ...], per_measure: bool) -> str:
    if per_measure:
        return ", ".join((":",) + tuple(map(str, index)))
    return ", ".join(map(str, index)) if index else "()"


def _doc(f: Function) -> str:
    if f.kind == "derived":
        return f"{f.summary}: {{name: (value, jacobian)}}."
    if f.kind == "slack":
        return f"{f.summary}."
    shapes = ", ".join(_shape(o.shape, f.per_measure) for o in f.outputs)
    return f"{f.summary}: shapes {shapes}."


def _returns(f: Function) -> str:
    if f.kind == "derived":
        return "{" + ", ".join(f"{name!r}: ({v}, {j})" for name, v, j in f.pairs) + "}"
    return ", ".join(o.name for o in f.outputs)


def _flat(index: tuple[int, ...], shape: tuple[int, ...]) -> int:
    flat = 0
    for i, size in zip(index, shape, strict=True):
        flat = flat * size + i
    return flat


def row_context(f: Function, temps, outputs, only: tuple[str, ...] | None = None) -> dict:
    """The row form of a function: one measure (``m`` its whole row) and every output entry
    written, in order, into one flat ``out`` (the kernels' layout, runtime/engine). With
    ``only`` (output names), its *values form*: only those outputs' entries written, at the
    same places, with the temporaries and inputs they need — the same statements as the
    row form's, in the same order (the same numbers)."""
    if only is None:
        keep, used = {t for t, _ in f.temps}, f.used()
    else:
        keep, used = f.needed(only)
    used = sorted(used, key=lambda u: u[0].name == "m")
    entries, base = [], 0
    for o, printed_entries in zip(f.outputs, outputs, strict=True):
        size = 1
        for dim in o.shape:
            size *= dim
        if only is None or o.name in only:
            values = {_flat(index, o.shape): code for index, code in printed_entries}
            entries += [(base + i, values.get(i, "0.0")) for i in range(size)]
        base += size
    written = f.outputs if only is None else [o for o in f.outputs if o.name in only]
    return {
        "name": f"row_{f.name}" if only is None else f"row_values_{f.name}",
        "args": [inp.name for inp in f.inputs] + ["out"],
        "doc": (f"Row form of ``{f.name}`` (one measure, ``m`` its whole row): ``out`` holds "
                + ", ".join(f"{o.name} {o.shape}" for o in written)
                + ", row-major, one after the other.") if only is None else
               (f"Values form of ``row_{f.name}``: its statements that "
                + ", ".join(only) + " need; ``out`` holds "
                + ", ".join(f"{o.name} {o.shape}" for o in written)
                + " at their places in the row form's layout, the rest untouched."),
        "unpack": [f"{inp.prefix}{s.name} = {inp.name}[{i}]" for inp, i, s in used],
        "temps": [(name, code) for (t, _), (name, code) in zip(f.temps, temps, strict=True)
                  if t in keep],
        "entries": entries,
        "size": base,
    }


#: The outputs a measurement function's values form writes: its equations' values and their
#: Jacobian in the measure (a measure's error and its projection's steps need no ``C``).
VALUES = ("c", "D")


def function_context(f: Function) -> dict:
    """One function as plain data for the NumPy templates."""
    temps, outputs = printed(f, NumpyPrinter)
    per = f.per_measure
    # parameter, constants, then measure components
    used = sorted(f.used(), key=lambda u: u[0].name == "m")
    unpack = [f"{inp.prefix}{s.name} = {inp.name}[{':, ' if inp.name == 'm' else ''}{i}]"
              for inp, i, s in used]
    return {
        "name": f.name,
        "args": [inp.name for inp in f.inputs],
        "doc": _doc(f),
        "unpack": unpack,
        "per_measure": per,
        "temps": temps,
        "outputs": [{"name": o.name, "shape": _shape(o.shape, per),
                     "entries": [(_index(i, per), code) for i, code in entries]}
                    for o, entries in zip(f.outputs, outputs, strict=True)],
        "returns": _returns(f),
        "row": row_context(f, temps, outputs) if f.kind in ("c0", "measure", "slack") else None,
        "values_row": row_context(f, temps, outputs, VALUES) if f.kind == "measure" else None,
        "linear": f.kind == "measure" and f.free_of("C", f.inputs[0].name),
    }


def context(desc: Description) -> dict:
    """The plain data the NumPy module template sees."""
    family = family_metadata(desc)
    return {
        "format": FORMAT,
        "source": desc.source,
        "sha256": desc.sha256,
        "family": family,
        "family_literal": pprint.pformat(family, width=96, sort_dicts=False),
        "functions": [function_context(f) for f in desc.functions],
        "derived": function_context(desc.derived) if desc.derived else None,
        "slack_measures": function_context(desc.slack_measures) if desc.slack_measures
        else None,
        "models": [{"name": name, "c0": e.c0, "channels": list(e.channels),
                    "reduced": {"c0": e.reduced_c0, "channels": list(e.reduced_channels)}
                    if e.reduction else None}
                   for name, e in desc.models],
    }


#: Which templates render to which file: one module per family.
BACKEND = Backend("numpy", "numpy", {"module.py.jinja": "{name}.py"}, context)
