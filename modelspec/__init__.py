"""Model specifications: safe parsing and validation into a frozen IR (SPEC §1).

The names below are imported on first use (PEP 562): reading a spec needs SymPy and PyYAML,
while the runtime only needs :mod:`~kanagen.modelspec.errors`, :mod:`~kanagen.modelspec.limits`
and :mod:`~kanagen.modelspec.slack`, which import neither.
"""

from __future__ import annotations

import importlib
import importlib.util
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # the same names, for type checkers and editors
    from .errors import SpecError
    from .expressions import FUNCTIONS, parse_expression
    from .ir import Alternative, Channel, Derived, Family, Model, symbol
    from .limits import Limits
    from .parse import family_from_data, load_spec, parse_spec

#: public name -> the submodule defining it
_LAZY = {
    "SpecError": "errors",
    "FUNCTIONS": "expressions",
    "parse_expression": "expressions",
    "Alternative": "ir",
    "Channel": "ir",
    "Derived": "ir",
    "Family": "ir",
    "Model": "ir",
    "symbol": "ir",
    "Limits": "limits",
    "family_from_data": "parse",
    "load_spec": "parse",
    "parse_spec": "parse",
}

__all__ = [
    "FUNCTIONS",
    "Alternative",
    "Channel",
    "Derived",
    "Family",
    "Limits",
    "Model",
    "SpecError",
    "family_from_data",
    "load_spec",
    "parse_expression",
    "parse_spec",
    "symbol",
]


def __getattr__(name: str):
    """A public name, imported on first use; a submodule (``kanagen.modelspec.parse``)."""
    if name in _LAZY:
        value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value
        return value
    if not name.startswith("_") and importlib.util.find_spec(f"{__name__}.{name}") is not None:
        return importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
