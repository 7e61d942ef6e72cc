"""What keys a generated module or a compiled library to the generator that made it: the
layout version and a hash of the generator's own files. Light on purpose (no SymPy, no
jinja2): the run time checks caches with it."""

from __future__ import annotations

from functools import cache
from pathlib import Path

from ..modelspec.digest import files_digest

#: Version of the generated-file layout; generated modules carry it and the loader checks it.
FORMAT = 4


@cache
def generator_fingerprint() -> str:
    """Hash of the generator itself (code and templates): keys the run-time build cache."""
    root = Path(__file__).parent
    return files_digest(root, [*root.glob("*.py"), *root.glob("templates/*/*.jinja"),
                               *root.glob("c/*.c")], f"format {FORMAT}")
