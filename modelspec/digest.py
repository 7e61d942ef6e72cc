"""The digest of a spec's text: what ``Family.sha256`` holds and keys the family's
generated modules. Light (no SymPy, no YAML): the loader finds the modules generated from a
file's text without reading it as a spec."""

from __future__ import annotations

import hashlib


def sha256_text(text: str) -> str:
    """The hex SHA-256 of ``text`` as UTF-8."""
    return hashlib.sha256(text.encode("utf-8")).hexdigest()
