"""``kanagen build``: write generated modules, or check that committed ones are current."""

from __future__ import annotations

import difflib
import hashlib
from functools import cache
from pathlib import Path

from ..modelspec import Family, load_spec
from .describe import FORMAT
from .numpy_backend import render


def render_spec(family: Family) -> dict[str, str]:
    """Generated files for a validated family, named after the spec file it came from."""
    return render(family, Path(family.source).name)


def build(spec: str | Path, out_dir: str | Path) -> list[Path]:
    """Generate the module(s) of ``spec`` into ``out_dir``; returns the written paths.

    Files are rewritten only when their text changes.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for name, text in render_spec(load_spec(spec)).items():
        path = out / name
        if not path.exists() or path.read_text(encoding="utf-8") != text:
            path.write_text(text, encoding="utf-8")
        written.append(path)
    return written


def check(specs: list[str | Path], out_dir: str | Path) -> list[str]:
    """Unified diffs between the committed files in ``out_dir`` and a fresh generation.

    An empty list means everything is current.
    """
    diffs = []
    for spec in specs:
        for name, text in render_spec(load_spec(spec)).items():
            path = Path(out_dir) / name
            old = path.read_text(encoding="utf-8") if path.exists() else ""
            if old != text:
                diffs.append("".join(difflib.unified_diff(
                    old.splitlines(keepends=True), text.splitlines(keepends=True),
                    fromfile=f"{path} (committed)", tofile=f"{path} (generated from {spec})")))
    return diffs


@cache
def generator_fingerprint() -> str:
    """Hash of the generator itself (code and templates): keys the run-time build cache."""
    digest = hashlib.sha256(f"format {FORMAT}".encode())
    root = Path(__file__).parent
    for path in sorted(list(root.glob("*.py")) + list(root.glob("templates/*.jinja"))):
        digest.update(path.name.encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()
