"""What keys a generated module or a compiled library to the generator that made it: the
layout version and a hash of the generator's own files. Light on purpose (no SymPy, no
jinja2): the run time checks caches with it."""

from __future__ import annotations

import hashlib
from functools import cache
from pathlib import Path

#: Version of the generated-file layout; generated modules carry it and the loader checks it.
FORMAT = 4


@cache
def generator_fingerprint() -> str:
    """Hash of the generator itself (code and templates): keys the run-time build cache."""
    digest = hashlib.sha256(f"format {FORMAT}".encode())
    root = Path(__file__).parent
    for path in sorted(list(root.glob("*.py")) + list(root.glob("templates/*/*.jinja"))
                       + list(root.glob("c/*.c"))):
        digest.update(str(path.relative_to(root)).encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()
