"""Names a package imports on first use (PEP 562), for every package of kanagen: it lives in
the lowest layer (it imports nothing of kanagen), so each package's ``__init__`` can use it."""

from __future__ import annotations

import importlib
import importlib.util
import sys
from collections.abc import Collection, Mapping


def lazy(package: str, names: Mapping[str, str] | None = None,
         submodules: Collection[str] | None = None):
    """``(__getattr__, __dir__)`` for the package ``package``: each of ``names`` (public name
    -> the module defining it, relative to the package) is imported on first access and kept
    in the package; a submodule is imported on attribute access — one of ``submodules``, or
    any that exists when that is None."""
    names = dict(names or {})

    def is_submodule(name: str) -> bool:
        if submodules is not None:
            return name in submodules
        return not name.startswith("_") and \
            importlib.util.find_spec(f"{package}.{name}") is not None

    def __getattr__(name: str):
        if name in names:
            value = getattr(importlib.import_module(names[name], package), name)
            setattr(sys.modules[package], name, value)
            return value
        if is_submodule(name):
            return importlib.import_module(f".{name}", package)
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    def __dir__() -> list[str]:
        return sorted(set(vars(sys.modules[package])) | set(names) | set(submodules or ()))

    return __getattr__, __dir__
