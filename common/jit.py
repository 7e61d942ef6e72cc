"""The compiler of the runtime's kernels: ``@jit`` is numba's ``njit(cache=True)``.

A kernel is written once, in the subset of Python and NumPy that numba compiles (loops over
small fixed-size matrices, no Python objects); the same source runs interpreted where numba
is missing or ``NUMBA_DISABLE_JIT=1`` is set (for debugging: slower, the same answers up to
rounding). Compiled kernels are cached on disk (numba's cache, in the user's cache directory:
:func:`_cache_dir`), so a kernel is compiled once per machine and signature. An installed
kanagen ships the cache of its shipped families' kernels, compiled when its wheel was built
(:mod:`kanagen.precompile`); an empty cache is seeded from it (:func:`seed`).

Numba's cache keys a kernel by its own file only: a kernel calling a kernel of another file
would keep the old callee after that file changed. The cache directory is therefore named
after the sources of every module that defines kernels (:data:`KERNEL_SOURCES`): any change
to one starts a fresh cache.
"""

from __future__ import annotations

import hashlib
import os
import sys
import warnings
from pathlib import Path

_RUNTIME = Path(__file__).resolve().parent.parent / "runtime"
#: The sources that define ``@jit`` kernels or shape their code (globs under the package).
KERNEL_SOURCES = ("runtime/sqrt.py", "runtime/lapack.py", "runtime/linalg.py",
                  "runtime/engine/*.py", "common/jit.py", "common/link.py", "common/borrow.py",
                  "runtime/numpy_rules.py", "runtime/two_view_kernels.py",
                  "runtime/two_view_twins.py")


def _sources_digest(root: Path = _RUNTIME.parent) -> str:
    """The digest of the kernels' sources of the package at ``root`` (this one's)."""
    digest = hashlib.sha256()
    for pattern in KERNEL_SOURCES:
        for path in sorted(root.glob(pattern)):
            digest.update(path.name.encode())
            digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


def _cache_dir() -> str:
    """The user's cache (``$XDG_CACHE_HOME`` or ``~/.cache``), ``kanagen/numba/<digest>``:
    shared by every process and every ``$KANAGEN_CACHE`` (the kernels depend on their
    sources only, which the digest names)."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "kanagen", "numba", _sources_digest())


def _import_numba():
    """numba, or None (one warning: the kernels then run interpreted). numba reads an
    optional ``.numba_config.yaml`` when ``yaml`` imports: a fit loads no yaml, so it is
    hidden from numba's import when nothing loaded it before."""
    hide = "yaml" not in sys.modules
    if hide:
        sys.modules["yaml"] = None  # type: ignore[assignment]
    try:
        import numba
    except ImportError as exc:  # pragma: no cover - numba is a dependency
        warnings.warn(f"kanagen: numba is not available ({exc}); the estimator's kernels "
                      "run interpreted (the same answers, much slower)", RuntimeWarning,
                      stacklevel=3)
        return None
    finally:
        if hide:
            del sys.modules["yaml"]
    from .interrupts import keep_interrupts

    keep_interrupts()  # a Ctrl-C during a compile: kept, raised once out of it
    if not os.environ.get("NUMBA_CACHE_DIR"):
        numba.config.CACHE_DIR = _cache_dir()
        _locate_by_package(numba)
        if not numba.config.DISABLE_JIT:
            seed(Path(numba.config.CACHE_DIR))
    return numba


#: The kernels compiled when the wheel was built, beside the package's modules:
#: ``kernels/<digest>`` (none in a source checkout), with :data:`SHIPPED_MANIFEST`.
SHIPPED_KERNELS = _RUNTIME.parent / "kernels"
#: The file of a shipped kernels' folder naming what they were compiled for
#: (:func:`kernel_target`).
SHIPPED_MANIFEST = "kanagen-kernels.json"


def kernel_target() -> dict:
    """What numba's cached code is valid for in this process: numba's, NumPy's and
    Python's versions and numba's processor (its target triple, name and features, as
    numba keys its cache entries: ``NUMBA_CPU_NAME`` included)."""
    import numba
    import numpy
    from numba.core.registry import cpu_target

    return {"numba": numba.__version__,
            "numpy": ".".join(numpy.__version__.split(".")[:2]),
            "python": "{}.{}".format(*sys.version_info[:2]),
            "processor": list(cpu_target.target_context.codegen().magic_tuple())}


def seed(cache: Path, shipped: Path = SHIPPED_KERNELS, target: dict | None = None) -> bool:
    """Fill ``cache`` (a kernel cache folder, named by the sources' digest) from the
    kernels shipped for the same digest when ``cache`` does not exist yet and they were
    compiled for this process (their :data:`SHIPPED_MANIFEST` is ``target``, default
    :func:`kernel_target`): the package's first process on a machine then loads its
    kernels instead of compiling them (~40 s). Kernels compiled for another numba,
    processor ... are not copied: the cache stays empty and the first use compiles, saying
    so. The files are copied with the user's permissions (a read-only install gives a
    writable cache) into a folder of this process's own beside ``cache``, renamed into
    place, so that processes starting together never read a half-copied cache. Never
    raises; True when this call seeded ``cache``."""
    import json
    import shutil
    import tempfile

    source = shipped / cache.name
    try:
        if cache.exists() or not source.is_dir():
            return False
        made_for = json.loads((source / SHIPPED_MANIFEST).read_text())
        if made_for != (kernel_target() if target is None else target):
            return False
        cache.parent.mkdir(parents=True, exist_ok=True)
        partial = Path(tempfile.mkdtemp(prefix=f"{cache.name}.seeding-", dir=cache.parent))
    except Exception:  # noqa: BLE001 - no manifest, unreadable, a cache not writable ...
        return False
    try:
        for folder, _, files in os.walk(source):
            into = partial / Path(folder).relative_to(source)
            into.mkdir(exist_ok=True)
            for name in files:
                if name != SHIPPED_MANIFEST:
                    shutil.copyfile(Path(folder) / name, into / name)
        partial.rename(cache)
    except OSError:  # another process was first, or a copy failed
        shutil.rmtree(partial, ignore_errors=True)
        return False
    prune(cache)
    return True


def _locate_by_package(numba) -> None:
    """Cache kanagen's kernels under their package's folder name (``runtime``, ``engine``,
    ``generated``), not under a hash of their absolute path as numba does: the same
    sources imported from an installed copy and from a source tree (the tests) then share
    one compile (numba checks each entry against a hash of its source's content)."""
    try:
        from numba.core import caching
    except ImportError:  # pragma: no cover - another numba layout
        return
    base = getattr(caching, "UserProvidedCacheLocator", None) or \
        getattr(caching, "_UserProvidedCacheLocator", None)
    impl = getattr(caching, "CacheImpl", None) or getattr(caching, "_CacheImpl", None)
    if base is None or impl is None:  # pragma: no cover - another numba layout
        return
    roots = {str(_RUNTIME), str(_RUNTIME / "engine"), str(_RUNTIME.parent / "generated")}

    class PackageLocator(base):
        @classmethod
        def from_function(cls, py_func, py_file):
            if os.path.dirname(os.path.abspath(py_file)) not in roots:
                return None
            return super().from_function(py_func, py_file)

        @classmethod
        def get_suitable_cache_subpath(cls, py_file):
            return "kanagen_" + os.path.basename(os.path.dirname(os.path.abspath(py_file)))

    if not any(getattr(c, "__name__", "") == "PackageLocator" for c in impl._locator_classes):
        impl._locator_classes = [PackageLocator, *impl._locator_classes]


def jit(function=None, *, inline: bool = False):
    """Compile ``function`` with numba (nopython, cached; NumPy's rules for floating-point
    errors: a division by zero gives inf or NaN, as in the interpreted run), or return it
    as it is.

    ``@jit(inline=True)``: the function is merged into each caller's code (numba's IR
    inlining) — for the small per-measure helpers called in the innermost loops, where a
    call's fixed cost (every array argument's reference count taken and given back, the
    status check) is several times the helper's work."""
    if function is None:
        return lambda f: jit(f, inline=inline)
    if NUMBA is None:
        return function
    if inline:
        return NUMBA.njit(cache=True, error_model="numpy", inline="always")(function)
    return NUMBA.njit(cache=True, error_model="numpy")(function)


def interrupted(exc: BaseException) -> bool:
    """``exc`` is Ctrl-C in disguise: numba runs a little Python when it boxes a kernel's
    results (unpickling a class), and a KeyboardInterrupt raised there reaches the caller
    as a SystemError caused by it."""
    while exc is not None:
        if isinstance(exc, KeyboardInterrupt):
            return True
        exc = exc.__cause__ or exc.__context__
    return False


_announced = False


def announce() -> None:
    """Say, once a process, that the kernels are being compiled when the cache holds none
    of them yet (the first fit on a machine, or after kanagen changed): it takes about a
    minute. The caches of older kernels are pruned then (:func:`prune`)."""
    global _announced
    if _announced or NUMBA is None or jit.disabled:
        return
    _announced = True
    folder = NUMBA.config.CACHE_DIR
    # numba makes its folders when the kernels are defined; compiled ones leave index files
    for _, _, files in os.walk(folder or ""):
        if any(name.endswith(".nbi") for name in files):
            return
    sys.stderr.write(f"kanagen: compiling the estimator's kernels for this machine (once, "
                     f"about a minute; cached in {folder})...\n")
    sys.stderr.flush()
    jit.compiling = True  # kanagen.common.link shows the kernels' progress on a terminal
    if not os.environ.get("NUMBA_CACHE_DIR"):
        prune(Path(folder))


#: The caches of other kernel sources kept besides the current one (the most recently
#: written: other kanagen versions in use on the machine).
KEEP_OTHERS = 2


def prune(current: Path) -> list[Path]:
    """Remove the caches of kernel sources other than ``current`` (its siblings, named by
    digest) except the :data:`KEEP_OTHERS` most recently written: each holds 30–140 MB,
    and every kanagen upgrade starts a new one; and the partial copies of a :func:`seed`
    left by a process killed while copying (an hour old). Returns the folders removed."""
    import shutil
    import time

    def written(folder: Path) -> float:
        return max((f.stat().st_mtime for f in folder.rglob("*") if f.is_file()),
                   default=folder.stat().st_mtime)

    try:
        siblings = [f for f in current.parent.iterdir() if f.is_dir() and f != current]
        others = [f for f in siblings if len(f.name) == 16
                  and all(c in "0123456789abcdef" for c in f.name)]
        others.sort(key=written, reverse=True)
        stale = [f for f in siblings if ".seeding-" in f.name
                 and f.stat().st_mtime < time.time() - 3600]
    except OSError:
        return []
    removed = []
    for folder in others[KEEP_OTHERS:] + stale:
        shutil.rmtree(folder, ignore_errors=True)
        removed.append(folder)
    return removed


#: numba, or None where it cannot be imported.
NUMBA = _import_numba()


#: True when :func:`announce` found the cache empty: the kernels are being compiled.
jit.compiling = False
#: True when kernels run interpreted (numba missing, or ``NUMBA_DISABLE_JIT=1``).
jit.disabled = NUMBA is None or bool(NUMBA.config.DISABLE_JIT)
