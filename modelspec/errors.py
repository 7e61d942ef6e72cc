"""The one error type a spec can raise: it names the file, the line and the problem."""

from __future__ import annotations


class SpecError(ValueError):
    """A model specification is invalid.

    Parameters
    ----------
    message : str
        What is wrong, in the spec's own terms.
    source : str
        The file (or a label such as ``"<sympy>"``) the spec came from.
    line : int or None
        1-based line of the offending item, when known.
    """

    def __init__(self, message: str, source: str = "<spec>", line: int | None = None):
        self.message = message
        self.source = source
        self.line = line
        where = f"{source}:{line}" if line is not None else source
        super().__init__(f"{where}: {message}")
