"""``kanagen.load``: from a spec to a :class:`ModelFamily`, through generated code.

A shipped family loaded by name is its committed module under ``kanagen.generated``: no spec
is read and nothing is generated, so SymPy, PyYAML and jinja2 (the spec reader's and the
generator's) are imported only when a spec is (:func:`_module_for`), and CasADi only for the
"casadi" and "compiled" backends.
"""

from __future__ import annotations

import functools
import hashlib
import importlib
import os
import tempfile
import warnings
from dataclasses import fields
from pathlib import Path
from typing import TYPE_CHECKING

from .modelspec.digest import files_digest, sha256_text
from .modelspec.limits import DEFAULT, Limits
from .runtime.backends import CasadiFunctions, CompiledFunctions
from .runtime.family import ModelFamily, cache_dir, cache_key, import_file, shipped_module

if TYPE_CHECKING:
    from .modelspec.ir import Family

#: The backends :func:`load` accepts.
LOAD_BACKENDS = ("numpy", "casadi", "compiled")
#: The environment variable naming the default backend (:func:`default_backend`).
BACKEND_VARIABLE = "KANAGEN_BACKEND"


def default_backend() -> str:
    """The backend :func:`load` uses when none is given: ``$KANAGEN_BACKEND`` when set
    (one of :data:`LOAD_BACKENDS`), else ``"compiled"`` — which falls back to ``"numpy"``
    with one :class:`~kanagen.codegen.compile.CompileWarning` where no C compiler works."""
    chosen = os.environ.get(BACKEND_VARIABLE, "").strip() or "compiled"
    if chosen not in LOAD_BACKENDS:
        raise ValueError(f"${BACKEND_VARIABLE}={chosen!r} is not a backend (choose from "
                         f"{', '.join(LOAD_BACKENDS)})")
    return chosen


def load(spec: str | Path | Family, *, backend: str | None = None,
         eliminate_linear: bool = False,
         limits: Limits = DEFAULT) -> ModelFamily:
    """Load a model family.

    Parameters
    ----------
    spec : path, family name or Family
        A YAML spec file; the name of a shipped family (``"conic"``); or a validated
        :class:`kanagen.modelspec.Family` (e.g. from :func:`kanagen.modelspec.family_from_data`).
    backend : {"compiled", "numpy", "casadi"}, optional
        What evaluates the equations outside the estimator's kernels (which are numba's on
        every backend, docs/engine.md): the family compiled to C (CasADi's code generator
        and the system C compiler: compiled once per machine and spec, cached, a line on
        stderr while it compiles);
        the generated NumPy module; or the generated CasADi functions. Same estimates to
        rounding level. Default: :func:`default_backend` (``$KANAGEN_BACKEND``, else
        "compiled"; where no C compiler works, one
        :class:`~kanagen.codegen.compile.CompileWarning` and "numpy"). "compiled" asked
        for by name falls back to "casadi" with the same warning.
    eliminate_linear : bool
        Fit models with linear parameter constraints in their free components (the
        constraints solved at build time, report §6); same results.
    limits : Limits
        What reading a spec may cost (:class:`kanagen.modelspec.Limits`; a spec may come
        from anyone): ``Limits.trusted()`` lifts every bound.

    The committed modules under ``kanagen.generated`` are used when they were generated from
    the same spec text; otherwise the spec is built into a cache directory
    (``$KANAGEN_CACHE``, default ``~/.cache/kanagen``) keyed by the spec hash and the
    generator, and imported. A spec file whose text a committed module was generated from,
    or that an earlier load read and built (within the same limits, initialiser registry,
    spec reader and generator: ``texts/`` in the cache), is not read again: its modules
    are imported as they are (no SymPy, no jinja2).

    Examples
    --------
    >>> import kanagen
    >>> fam = kanagen.load("conic")
    >>> fam.parameter_names
    ('A', 'B', 'C', 'D', 'E', 'F')
    >>> kanagen.load("conic", backend="casadi").backend
    'casadi'
    """
    by_default = backend is None
    backend = default_backend() if by_default else backend
    if backend not in LOAD_BACKENDS:
        raise ValueError(f"unknown backend {backend!r} (choose from {', '.join(LOAD_BACKENDS)})")
    casadi_module = None  # made below unless a known text gives it
    read = False  # a spec file read here: its text is remembered once its modules are made
    if _is_family(spec):
        family = spec
        _check_initializers(family)
    else:
        path = Path(spec)
        if path.suffix in (".yaml", ".yml") or path.exists():
            family, module = None, None
            known = _generated_from_text(path, limits, backend != "numpy")
            if known is not None:
                module, casadi_module = known
            else:
                from .modelspec.parse import load_spec
                from .runtime.initializers import INITIALIZERS

                family, read = load_spec(path, limits, INITIALIZERS), True
        else:
            family = None
            module = _shipped_by_name(str(spec))
    if family is not None:
        module = _module_for(family, "numpy")
    functions = None
    if backend != "numpy":
        if casadi_module is None:
            casadi_module = _module_for(family, "casadi") if family is not None else \
                _shipped_by_name(f"{module.FAMILY['name']}_casadi")
        if backend == "compiled":
            functions = _compiled(casadi_module, module, by_default)
            if functions is None and by_default:
                return ModelFamily(module, None, eliminate_linear)
        if functions is None:
            functions = CasadiFunctions(casadi_module, module.FAMILY["derived"])
    if read:
        _remember_text(family, limits)
    return ModelFamily(module, functions, eliminate_linear)


def _compiled(casadi_module, module, by_default: bool):
    """The compiled functions of a family, or None with one warning (per family and
    process) when it cannot be compiled; a first compile says so on stderr."""
    from .codegen.compile import CompileError, CompileWarning, compile_family, load_compiled

    name = module.FAMILY["name"]
    try:
        library = compile_family(casadi_module, module.FAMILY, cache_dir(), _announce)
        return CompiledFunctions(casadi_module, module.FAMILY["derived"],
                                 load_compiled(casadi_module, library), library, module)
    except CompileError as exc:
        instead = "the NumPy backend (the same estimates, slower)" if by_default else \
            "the uncompiled CasADi backend"
        warnings.warn(f"cannot compile family {name!r}: {exc}; using {instead}. Install a C "
                      f"compiler (cc, gcc or clang; or set CC), or set "
                      f"{BACKEND_VARIABLE}=numpy to choose the NumPy backend",
                      CompileWarning, stacklevel=3)
        return None


def _announce(name: str, seconds: float | None) -> None:
    """A first compile of a family, on stderr: when it starts and how long it took."""
    import sys

    if seconds is None:
        sys.stderr.write(f"kanagen: compiling family {name!r} for this machine (once; cached "
                         f"in {cache_dir()})...\n")
    else:
        sys.stderr.write(f"kanagen: compiled family {name!r} in {seconds:.1f} s\n")
    sys.stderr.flush()


def _check_initializers(family) -> None:
    """A family built elsewhere (``family_from_data`` without the registry): the
    initialisers and admission tests its models name must be registered and have what they
    need (the spec reader's check, :func:`~kanagen.modelspec.parse.registry_problem`)."""
    from .modelspec import SpecError
    from .modelspec.parse import NAMED_KEYS, registry_problem
    from .runtime.initializers import INITIALIZERS

    for model in family.models:
        for key, kind in NAMED_KEYS:
            name = getattr(model, key)
            problem = None if name is None else registry_problem(
                INITIALIZERS, name, kind, family.parameter_names,
                [n for n, _ in family.constants],
                {c.name: c.components for c in family.channels})
            if problem:
                raise SpecError(f"model {model.name!r}: {problem}", family.source)


def load_text(text: str, source: str = "<spec>", *, limits: Limits = DEFAULT,
              **options) -> ModelFamily:
    """Load a family from YAML text; ``source`` names it in errors and in the header.
    ``limits`` and ``options`` are those of :func:`load`."""
    from .modelspec.parse import parse_spec
    from .runtime.initializers import INITIALIZERS

    return load(parse_spec(text, source, limits, INITIALIZERS), **options)


def _is_family(spec) -> bool:
    """Whether ``spec`` is a validated :class:`~kanagen.modelspec.Family` (a path or a name
    is not: the spec reader is imported only for what may be one)."""
    if isinstance(spec, (str, os.PathLike)):
        return False
    from .modelspec.ir import Family

    return isinstance(spec, Family)


def _generated_from_text(path: Path, limits: Limits, casadi: bool):
    """The modules generated from this file's very text, ``(numpy module, casadi module or
    None)``, or None: the committed ones (a shipped example loaded by its path, ``kanagen fit
    examples/conic_lattice.yaml ...``), else those a load of the same text built into the
    cache before (:func:`_remember_text`) — with ``casadi``, only when both are there. The
    text was read and checked when they were made: the spec reader, SymPy and the generator
    (half a second to two seconds a process) are not imported. A committed module was
    checked under the default limits (not when ``limits`` tightens one); a built one under
    the same limits, registry of initialisers, reader and generator (:func:`_text_key`).
    Any other text, or one that cannot be read, goes to the reader
    (:func:`~kanagen.modelspec.parse.load_spec`: its errors name the file)."""
    try:
        if path.stat().st_size > min(limits.max_bytes, DEFAULT.max_bytes):
            return None
        text = path.read_text(encoding="utf-8")  # as the reader reads it
    except (OSError, UnicodeDecodeError):
        return None
    digest = sha256_text(text)  # as the reader names the family it reads
    from .codegen.version import FORMAT

    stems = _shipped_digests().get(digest, ())
    name = next((stem for stem in stems if f"{stem}_casadi" in stems), None)
    if name is not None and not any(getattr(limits, f.name) < getattr(DEFAULT, f.name)
                                    for f in fields(Limits)):
        module = shipped_module(name, digest, FORMAT)
        if module is not None:
            return module, _shipped_by_name(f"{name}_casadi") if casadi else None
    try:
        name = (_texts_dir() / _text_key(digest, limits)).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError):
        return None
    places = [_cached(digest, stem) for stem in (name, f"{name}_casadi")[:2 if casadi else 1]]
    if not name.isidentifier() or not all(path.is_file() for path, _ in places):
        return None
    modules = [import_file(*place) for place in places]
    return modules[0], modules[1] if casadi else None


def _remember_text(family: Family, limits: Limits) -> None:
    """Note that the text of ``family`` reads, within ``limits``, as the family its cached
    modules were built from (:func:`_generated_from_text`). Never raises: a cache that cannot
    be written only means the next load reads the text again."""
    try:
        folder = _texts_dir()
        folder.mkdir(parents=True, exist_ok=True)
        _write_atomically(folder / _text_key(family.sha256, limits), family.name)
    except OSError:
        pass


def _texts_dir() -> Path:
    return cache_dir() / "texts"


def _text_key(digest: str, limits: Limits) -> str:
    """What a text's reading depends on besides the text (its ``digest``): the limits, the
    registry's names (an initialiser a model names must be registered), the reader's and the
    generator's own files, and the versions of what shapes the generated text."""
    from importlib import metadata

    from .codegen.version import generator_fingerprint
    from .runtime.initializers import INITIALIZERS

    versions = []
    for package in ("sympy", "jinja2", "pyyaml"):
        try:
            versions.append(f"{package} {metadata.version(package)}")
        except metadata.PackageNotFoundError:
            versions.append(f"{package} -")
    parts = (digest, repr(limits), ",".join(sorted(INITIALIZERS)), _reader_fingerprint(),
             generator_fingerprint(), *versions)
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()[:32]


@functools.lru_cache(maxsize=1)
def _reader_fingerprint() -> str:
    """A hash of the spec reader's own files (``kanagen.modelspec``), found without
    importing it."""
    import importlib.util

    folder = Path(importlib.util.find_spec("kanagen.modelspec").submodule_search_locations[0])
    return files_digest(folder, folder.glob("*.py"))


@functools.lru_cache(maxsize=1)
def _shipped_digests() -> dict[str, tuple[str, ...]]:
    """The committed modules by the digest of the spec text each was generated from (their
    ``SPEC_SHA256`` line, read from their header without importing them)."""
    from . import generated

    out: dict[str, tuple[str, ...]] = {}
    for file in sorted(Path(generated.__file__).parent.glob("*.py")):
        try:
            with file.open(encoding="utf-8") as lines:
                head = [next(lines, "") for _ in range(_HEADER_LINES)]
        except OSError:
            continue
        for line in head:
            if line.startswith("SPEC_SHA256 = "):
                digest = line.partition("=")[2].strip().strip("\"'")
                out[digest] = out.get(digest, ()) + (file.stem,)
                break
    return out


#: The lines of a generated module's header that hold its ``SPEC_SHA256``.
_HEADER_LINES = 20


def _shipped_by_name(name: str):
    try:
        return importlib.import_module(f"kanagen.generated.{name}")
    except ImportError:
        raise FileNotFoundError(f"no spec file {name!r} and no shipped family of that name")\
            from None


def _module_for(family: Family, backend: str):
    """The generated module of ``family`` for ``backend``: the shipped one when current,
    else built into the cache."""
    from .codegen.version import FORMAT

    stem = f"{family.name}_{backend}" if backend != "numpy" else family.name
    module = shipped_module(stem, family.sha256, FORMAT)
    if module is not None:
        return module
    from .codegen import BACKENDS, render_spec  # SymPy and jinja2: only to generate

    target = BACKENDS[backend].templates["module.py.jinja"].format(name=family.name)
    assert target == f"{stem}.py", target
    path, name = _cached(family.sha256, stem)
    text = render_spec(family, [backend])[target]
    if not path.exists() or path.read_text(encoding="utf-8") != text:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise OSError(f"cannot write the generated module of {family.name!r} into "
                          f"{path.parent}: {exc} (set KANAGEN_CACHE to a writable folder)") \
                from None
        _write_atomically(path, text)
    return import_file(path, name)


def _cached(sha256: str, stem: str) -> tuple[Path, str]:
    """Where the module ``stem`` generated from the spec text of digest ``sha256`` is built
    in the cache (keyed by the text and the generator), and the name it is imported as."""
    from .codegen.version import generator_fingerprint

    key = cache_key(sha256, generator_fingerprint())
    return cache_dir() / key / f"{stem}.py", f"kanagen_cache_{stem}_{key}"


def _write_atomically(path: Path, text: str) -> None:
    """``text`` into ``path`` (its folder exists) through a temporary file of this
    process's own and an atomic rename: concurrent first loads never share a partial file,
    and a reader never sees half of one."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as out:
            out.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
