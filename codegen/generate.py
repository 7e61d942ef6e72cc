"""``kanagen build``: write generated modules, or check that committed ones are current."""

from __future__ import annotations

import difflib
from collections.abc import Iterable, Mapping
from pathlib import Path

from ..modelspec import Family, load_spec
from ..modelspec.limits import DEFAULT, Limits
from .backend import Backend
from .casadi_backend import BACKEND as CASADI
from .description import describe
from .numpy_backend import BACKEND as NUMPY
from .version import generator_fingerprint  # noqa: F401 - re-exported

#: Every backend by name. The NumPy module is the family's reference (metadata, kernels):
#: it is always generated; the others add their module beside it.
BACKENDS: dict[str, Backend] = {b.name: b for b in (NUMPY, CASADI)}


def _backends(names: Iterable[str]) -> list[Backend]:
    out = []
    for name in names:
        if name not in BACKENDS:
            raise ValueError(f"unknown backend {name!r} (known: {', '.join(BACKENDS)})")
        out.append(BACKENDS[name])
    return out


def render_spec(family: Family, backends: Iterable[str] = ("numpy",)) -> dict[str, str]:
    """Generated files for a validated family, named after the spec file it came from."""
    source = Path(family.source).name
    desc = describe(family, source)
    files = {}
    for backend in _backends(backends):
        files.update(backend.render(family, source, desc))
    return files


def build(spec: str | Path, out_dir: str | Path,
          backends: Iterable[str] = ("numpy",), limits: Limits = DEFAULT,
          initializers: Mapping | None = None) -> list[Path]:
    """Generate the module(s) of ``spec`` into ``out_dir``; returns the written paths.

    Files are rewritten only when their text changes; ``limits``: what reading the spec may
    cost (:mod:`kanagen.modelspec.limits`); ``initializers``: the names a model may give
    and their needs (:func:`~kanagen.modelspec.load_spec`).
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for name, text in render_spec(load_spec(spec, limits, initializers), backends).items():
        path = out / name
        if not path.exists() or path.read_text(encoding="utf-8") != text:
            path.write_text(text, encoding="utf-8")
        written.append(path)
    return written


def committed_backends(family: Family, out_dir: str | Path) -> list[str]:
    """The NumPy backend, and every other backend whose file for ``family`` is in
    ``out_dir``."""
    names = ["numpy"]
    for backend in BACKENDS.values():
        if backend.name != "numpy" and any(
                (Path(out_dir) / t.format(name=family.name)).exists()
                for t in backend.templates.values()):
            names.append(backend.name)
    return names


def check(specs: list[str | Path], out_dir: str | Path,
          backends: Iterable[str] | None = None,
          initializers: Mapping | None = None) -> list[str]:
    """Unified diffs between the committed files in ``out_dir`` and a fresh generation.

    ``backends`` default: :func:`committed_backends`. An empty list means everything is
    current.
    """
    diffs = []
    for spec in specs:
        family = load_spec(spec, initializers=initializers)
        names = committed_backends(family, out_dir) if backends is None else backends
        for name, text in render_spec(family, names).items():
            path = Path(out_dir) / name
            old = path.read_text(encoding="utf-8") if path.exists() else ""
            if old != text:
                diffs.append("".join(difflib.unified_diff(
                    old.splitlines(keepends=True), text.splitlines(keepends=True),
                    fromfile=f"{path} (committed)", tofile=f"{path} (generated from {spec})")))
    return diffs


