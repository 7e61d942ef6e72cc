"""``kanagen.load``: from a spec to a :class:`ModelFamily`, through generated code."""

from __future__ import annotations

from pathlib import Path

from .codegen import FORMAT, generator_fingerprint, render_spec
from .modelspec import Family, load_spec, parse_spec
from .runtime.family import ModelFamily, cache_dir, cache_key, import_file, shipped_module


def load(spec: str | Path | Family, *, use_generated_kernels: bool = True) -> ModelFamily:
    """Load a model family.

    Parameters
    ----------
    spec : path, family name or Family
        A YAML spec file; the name of a shipped family (``"conic"``); or a validated
        :class:`kanagen.modelspec.Family` (e.g. from :func:`kanagen.modelspec.family_from_data`).
    use_generated_kernels : bool
        Use the unrolled per-measure algebra of the generated module (default) or the
        generic runtime implementation.

    The committed module under ``kanagen.generated`` is used when it was generated from the
    same spec text; otherwise the spec is built into a cache directory (``$KANAGEN_CACHE``,
    default ``~/.cache/kanagen``) keyed by the spec hash and the generator, and imported.

    Examples
    --------
    >>> import kanagen
    >>> fam = kanagen.load("conic")
    >>> fam.parameter_names
    ('A', 'B', 'C', 'D', 'E', 'F')
    """
    if isinstance(spec, Family):
        family = spec
    else:
        path = Path(spec)
        if path.suffix in (".yaml", ".yml") or path.exists():
            family = load_spec(path)
        else:
            module = _shipped_by_name(str(spec))
            return ModelFamily(module, use_generated_kernels)
    return ModelFamily(_module_for(family), use_generated_kernels)


def load_text(text: str, source: str = "<spec>", *,
              use_generated_kernels: bool = True) -> ModelFamily:
    """Load a family from YAML text; ``source`` names it in errors and in the header."""
    return load(parse_spec(text, source), use_generated_kernels=use_generated_kernels)


def _shipped_by_name(name: str):
    import importlib

    try:
        return importlib.import_module(f"kanagen.generated.{name}")
    except ImportError:
        raise FileNotFoundError(f"no spec file {name!r} and no shipped family of that name")\
            from None


def _module_for(family: Family):
    module = shipped_module(family.name, family.sha256, FORMAT)
    if module is not None:
        return module
    key = cache_key(family.sha256, generator_fingerprint())
    folder = cache_dir() / key
    files = render_spec(family)
    target = folder / f"{family.name}.py"
    if not target.exists() or target.read_text(encoding="utf-8") != files[target.name]:
        folder.mkdir(parents=True, exist_ok=True)
        tmp = target.with_suffix(".tmp")
        tmp.write_text(files[target.name], encoding="utf-8")
        tmp.replace(target)  # atomic: concurrent loaders never see half a file
    return import_file(target, f"kanagen_cache_{family.name}_{key}")
