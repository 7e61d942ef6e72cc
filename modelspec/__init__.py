"""Model specifications: safe parsing and validation into a frozen IR (SPEC §1).

The names below are imported on first use (PEP 562): reading a spec needs SymPy and PyYAML;
:mod:`~kanagen.modelspec.errors` and :mod:`~kanagen.modelspec.limits` import neither (the
loader and the command line use them). The runtime imports nothing of this package (the
slack's value it shares with the spec reader is :mod:`~kanagen.common.slack`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..common.lazy import lazy as _lazy

if TYPE_CHECKING:  # the same names, for type checkers and editors
    from .errors import SpecError
    from .expressions import FUNCTIONS, parse_expression
    from .ir import Alternative, Channel, Derived, Family, Model, symbol
    from .limits import Limits
    from .parse import family_from_data, load_spec, parse_spec

#: public name -> the submodule defining it
_LAZY = {
    "SpecError": ".errors",
    "FUNCTIONS": ".expressions",
    "parse_expression": ".expressions",
    "Alternative": ".ir",
    "Channel": ".ir",
    "Derived": ".ir",
    "Family": ".ir",
    "Model": ".ir",
    "symbol": ".ir",
    "Limits": ".limits",
    "family_from_data": ".parse",
    "load_spec": ".parse",
    "parse_spec": ".parse",
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


# a public name, imported on first use; a submodule (``kanagen.modelspec.parse``)
__getattr__, __dir__ = _lazy(__name__, _LAZY)
