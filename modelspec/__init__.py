"""Model specifications: safe parsing and validation into a frozen IR (SPEC §1)."""

from .errors import SpecError
from .expressions import FUNCTIONS, parse_expression
from .ir import Alternative, Channel, Derived, Family, Model, symbol
from .limits import Limits
from .parse import family_from_data, load_spec, parse_spec

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
