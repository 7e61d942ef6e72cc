"""``--compile``: C from CasADi's code generator, compiled with the system C compiler.

The CasADi functions of a family (its generated CasADi module's ``FUNCTIONS``) go through
``casadi.CodeGenerator`` into one C file, compiled into a shared library in a cache folder
keyed by the spec hash, the kanagen version, the generator and the CasADi version, and loaded
back with ``casadi.external`` (same names, inputs and outputs). The C compiler is ``$CC``
(split like a shell word list), else the first of ``cc``, ``gcc``, ``clang`` on the PATH.

Without a working compiler, :func:`compile_family` raises :class:`CompileError` with a
message that says so; :func:`kanagen.load` turns it into a :class:`CompileWarning` and uses
the uncompiled CasADi backend, ``kanagen build --compile`` into a warning line.
"""

from __future__ import annotations

import hashlib
import os
import shlex
import shutil
import subprocess
from pathlib import Path
from types import ModuleType

#: C flags: position-independent shared library, optimised; the math library for -lm.
CFLAGS = ("-O2", "-shared", "-fPIC")
_TIMEOUT = 300  # seconds


class CompileError(RuntimeError):
    """No usable C compiler, or the generated C did not compile."""


class CompileWarning(UserWarning):
    """Compilation was asked for but is not possible: the uncompiled backend is used."""


def compiler() -> list[str]:
    """The C compiler command: ``$CC`` or the first of cc, gcc, clang on the PATH."""
    cc = os.environ.get("CC")
    if cc:
        command = shlex.split(cc)
        if not command or shutil.which(command[0]) is None:
            raise CompileError(f"no C compiler: CC={cc!r} is not an executable")
        return command
    for name in ("cc", "gcc", "clang"):
        if shutil.which(name):
            return [name]
    raise CompileError("no C compiler found (set CC, or install cc, gcc or clang)")


def cache_key(sha256: str) -> str:
    """Key of a compiled library: the spec hash, kanagen's version, the generator, CasADi."""
    import casadi

    from .. import __version__
    from .build import generator_fingerprint

    text = f"{sha256}:{__version__}:{generator_fingerprint()}:{casadi.__version__}"
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def c_source(module: ModuleType, name: str) -> str:
    """The C code of every CasADi function of a generated module, in one unit."""
    import casadi

    generator = casadi.CodeGenerator(f"{name}.c", {"with_header": False})
    for f in module.FUNCTIONS:
        generator.add(f)
    return generator.dump()


def compile_family(module: ModuleType, name: str, sha256: str, cache: Path) -> Path:
    """The shared library of a generated CasADi module, compiled once into ``cache``.

    Raises
    ------
    CompileError
        No compiler, or compilation failed (the message names the command and its errors).
    """
    folder = Path(cache) / "compiled" / cache_key(sha256)
    library = folder / f"{name}.so"
    if library.exists():
        return library
    command = compiler()
    folder.mkdir(parents=True, exist_ok=True)
    source = folder / f"{name}.c"
    source.write_text(c_source(module, name), encoding="utf-8")
    partial = folder / f"{name}.{os.getpid()}.so.tmp"
    cmd = [*command, *CFLAGS, str(source), "-o", str(partial), "-lm"]
    try:
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=_TIMEOUT)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise CompileError(f"cannot run the C compiler ({shlex.join(cmd)}): {exc}") from None
    if done.returncode != 0:
        tail = "\n".join(done.stderr.strip().splitlines()[-10:])
        raise CompileError(f"the C compiler failed ({shlex.join(cmd)}):\n{tail}")
    partial.replace(library)  # atomic: concurrent loaders never see half a library
    return library


def load_compiled(module: ModuleType, library: Path) -> dict:
    """The module's functions loaded from ``library`` with ``casadi.external``, by name."""
    import casadi

    return {f.name(): casadi.external(f.name(), str(library)) for f in module.FUNCTIONS}
