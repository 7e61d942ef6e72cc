"""What a spec may cost to read and compile: every bound in one place.

A spec may come from anyone; a few hundred bytes can ask for exponential work (a YAML alias
bomb, nested powers, a chain of definitions each squaring the last, a disjunction whose
conjunctive normal form has 2ⁿ clauses, the determinant of a large symbolic matrix). Each
such input is refused as early as it can be seen, with the file, the line and the limit.
The defaults admit every realistic model (a polynomial of thousands of terms, the two-view
family); trusted specs that need more pass ``limits=Limits.trusted()`` (command line:
``--trusted``) or raise one bound (``--limit max_nodes=1000000``).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, fields, replace

#: "No bound" for a limit.
UNLIMITED = 10**18


@dataclass(frozen=True)
class Limits:
    """Bounds on a spec's cost.

    Attributes
    ----------
    max_bytes : int
        Size of the spec text (a 25 MB spec took two minutes).
    max_yaml_nodes : int
        YAML nodes after alias expansion (an alias bomb of 400 bytes expands to 9⁹).
    max_depth : int
        Nesting of parentheses, brackets and calls in one expression.
    max_nodes : int
        Size of one expression after the definitions it uses are substituted, counted as a
        tree (shared subexpressions counted each time: what derivatives and printing see).
    max_exponent : int
        Largest integer exponent of a symbol after folding (``(x**64)**64`` is ``x**4096``).
    max_number_digits : int
        Digits of an exact integer constant (``((9**64)**64)**64``).
    max_matrix : int
        Rows and columns of a matrix value.
    max_det : int
        Size of a matrix whose symbolic determinant is expanded (9×9: 362,880 terms).
    max_clauses : int
        Clauses of a constraint formula's conjunctive normal form (each is an equation).
    max_slacks : int
        Relations (each a slack component before clauses are cleaned) in the conjunctive
        normal form of one constraint formula.
    """

    max_bytes: int = 2_000_000
    max_yaml_nodes: int = 200_000
    max_depth: int = 64
    max_nodes: int = 50_000
    max_exponent: int = 64
    max_number_digits: int = 300
    max_matrix: int = 16
    max_det: int = 5
    max_clauses: int = 32
    max_slacks: int = 256

    @classmethod
    def trusted(cls) -> Limits:
        """No bound at all (a spec you wrote yourself)."""
        return cls(**{f.name: UNLIMITED for f in fields(cls)})

    def with_options(self, options: Iterable[str]) -> Limits:
        """These limits with ``name=value`` overrides (the command line's ``--limit``).

        Examples
        --------
        >>> Limits().with_options(["max_nodes=500000"]).max_nodes
        500000
        """
        names = {f.name for f in fields(self)}
        changes = {}
        for option in options:
            name, sep, value = option.partition("=")
            name = name.strip()
            if not sep or name not in names:
                raise ValueError(f"--limit {option!r}: expected NAME=VALUE with NAME one of "
                                 f"{', '.join(sorted(names))}")
            try:
                number = int(value)
            except ValueError:
                raise ValueError(f"--limit {option!r}: {value!r} is not an integer") from None
            if number < 1:
                raise ValueError(f"--limit {option!r}: must be positive")
            changes[name] = number
        return replace(self, **changes)


#: The defaults.
DEFAULT = Limits()
