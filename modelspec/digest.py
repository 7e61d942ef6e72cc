"""The digest of a spec's text: what ``Family.sha256`` holds and keys the family's
generated modules; and of a folder's files: what keys a cache to the code that fills it
(the generator's, the spec reader's). Light (no SymPy, no YAML): the loader finds the
modules generated from a file's text without reading it as a spec."""

from __future__ import annotations

import hashlib
from collections.abc import Iterable
from pathlib import Path


def sha256_text(text: str) -> str:
    """The hex SHA-256 of ``text`` as UTF-8."""
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def files_digest(root: Path, paths: Iterable[Path], seed: str = "") -> str:
    """The hex SHA-256 of ``seed`` then, in sorted order, each file's path relative to
    ``root`` and its bytes."""
    digest = hashlib.sha256(seed.encode())
    for path in sorted(paths):
        digest.update(str(path.relative_to(root)).encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()
