"""The value of an inequality's slack (appendix F), in plain floats: the spec reader and the
runtime both use it, and the runtime must not need SymPy (:mod:`kanagen.modelspec.constructs`
compiles the relations themselves)."""

from __future__ import annotations

import math


def slack_value(kind: str, c: float) -> float:
    """The slack solving its relation's equation at ``c``: ``√c`` for ``c >= 0``, ``1/√c`` for
    ``c > 0``, ``1/c`` for ``c != 0`` where the relation holds; otherwise a non-zero value of
    the right magnitude (the equation's gradient in ``s`` must not vanish), and the iteration
    moves the parameter until the relation holds. Plain floats: the runtime uses it too."""
    if not math.isfinite(c) or c == 0.0:
        c = 1.0
    if kind == ">=":
        return math.sqrt(abs(c))
    if kind == ">":
        return 1.0 / math.sqrt(abs(c))
    return 1.0 / c
