"""``--compile``: C from CasADi's code generator, compiled with the system C compiler.

The CasADi functions of a family (its generated CasADi module's ``FUNCTIONS``) go through
``casadi.CodeGenerator`` into C, followed by the family's tables and its evaluation entry
points (``templates/c/family.c.jinja``: ``kg_eval``, the equations of all the measures in one
call), in one translation unit compiled into a shared library in a cache folder keyed by the
spec hash, the kanagen version, the generator and the CasADi version. The CasADi functions
are loaded back with ``casadi.external`` (same names, inputs and outputs), ``kg_eval``
through :class:`kanagen.runtime.backends.CompiledFunctions`. The estimator's kernels are
not in it: they are numba's, one source for every backend (docs/engine.md). The C compiler is
``$CC`` (split like a shell word list), else the first of ``cc``, ``gcc``, ``clang`` on the
PATH.

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
import time
from collections.abc import Callable
from pathlib import Path
from types import ModuleType

#: C flags: position-independent shared library, optimised, no fused multiply-adds (the
#: rounding of the NumPy runtime, up to the order of sums).
CFLAGS = ("-O3", "-ffp-contract=off", "-shared", "-fPIC")
#: Tried first, dropped when the compiler refuses them: calls between the family's functions
#: in the library need not go through the PLT (inlined, ~10 % of a fit); ``sqrt`` is the
#: instruction, without a branch to set ``errno`` on negative input (the same values; the
#: estimator never reads errno).
TUNING = ("-fno-semantic-interposition", "-fno-math-errno")
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
    from .version import generator_fingerprint

    text = f"{sha256}:{__version__}:{generator_fingerprint()}:{casadi.__version__}"
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def c_source(module: ModuleType, family: dict) -> str:
    """One C unit: every CasADi function of the generated module ``module``, then the
    tables and evaluation entry points of ``family`` (the NumPy module's ``FAMILY``)."""
    import casadi

    generator = casadi.CodeGenerator(f"{family['name']}.c", {"with_header": False})
    for f in module.FUNCTIONS:
        generator.add(f)
    from .backend import environment

    tables = environment("c").get_template("family.c.jinja").render(**_tables(module, family))
    return "\n".join([generator.dump(), tables])


def _tables(module: ModuleType, family: dict) -> dict:
    """What the family's C tables say, from its CasADi functions and its metadata."""
    import math

    channels = list(family["channels"].items())
    p = []
    models, measures = [], []
    for mi, entry in enumerate(module.MODELS.values()):
        models.append({"c0": entry["c0"].name(), "p0": entry["c0"].size1_out(0)})
        for ci, (ch, _) in enumerate(channels):
            f = entry["channels"][ch]
            measures.append({"case": mi * len(channels) + ci, "name": f.name(),
                             "p": f.size1_out(0), "k": f.size2_out(2)})
            p.append(f.size1_out(0))
    n = len(family["parameter"])
    functions = list(module.FUNCTIONS)
    largest = max((math.prod(f.size_out(i)) for f in functions for i in range(f.n_out())),
                  default=1)
    return {
        "source": module.SPEC_SOURCE, "sha256": module.SPEC_SHA256, "name": family["name"],
        "n": n, "nk": len(family["constants"]),
        "channels": [{"width": len(ch["components"]), "ncorr": len(ch["corrected"])}
                     for _, ch in channels],
        "p": p, "models": models,
        "measures": measures, "nderived": len(family["derived"]),
        "nslack": len(family["slack_kinds"]),
        "sz": {"arg": max(f.sz_arg() for f in functions), "res": max(f.sz_res() for f in functions),
               "iw": max(f.sz_iw() for f in functions), "w": max(f.sz_w() for f in functions),
               "buf": largest},
    }


def compile_family(module: ModuleType, family: dict, cache: Path,
                   announce: Callable[[str, float | None], None] | None = None) -> Path:
    """The shared library of a generated CasADi module and of its family's evaluation entry
    points (``family``: the NumPy module's ``FAMILY``), compiled once into ``cache``.
    ``announce(name, seconds)``: called before a compile (``seconds`` None) and after it.

    Raises
    ------
    CompileError
        No compiler, or compilation failed (the message names the command and its errors).
    """
    name = family["name"]
    folder = Path(cache) / "compiled" / cache_key(module.SPEC_SHA256)
    library = folder / f"{name}.so"
    if library.exists():
        return library
    command = compiler()
    started = time.perf_counter()
    if announce is not None:
        announce(name, None)
    # this process's own source and output: concurrent first compiles share no partial file
    source = folder / f"{name}.{os.getpid()}.c"
    try:
        folder.mkdir(parents=True, exist_ok=True)
        source.write_text(c_source(module, family), encoding="utf-8")
    except OSError as exc:
        raise CompileError(f"cannot write the compiled family into {folder}: {exc} (set "
                           f"KANAGEN_CACHE to a writable folder)") from None
    partial = folder / f"{name}.{os.getpid()}.so.tmp"
    for tuning in (TUNING, ()):
        cmd = [*command, *CFLAGS, *tuning, str(source), "-o", str(partial), "-lm"]
        try:
            done = subprocess.run(cmd, capture_output=True, text=True, timeout=_TIMEOUT)
        except (OSError, subprocess.TimeoutExpired) as exc:
            raise CompileError(f"cannot run the C compiler ({shlex.join(cmd)}): {exc}") \
                from None
        if done.returncode == 0:
            break
    if done.returncode != 0:
        tail = "\n".join(done.stderr.strip().splitlines()[-10:])
        raise CompileError(f"the C compiler failed ({shlex.join(cmd)}):\n{tail}")
    partial.replace(library)  # atomic: concurrent loaders never see half a library
    source.unlink(missing_ok=True)
    if announce is not None:
        announce(name, time.perf_counter() - started)
    return library


def load_compiled(module: ModuleType, library: Path) -> dict:
    """The module's functions loaded from ``library`` with ``casadi.external``, by name."""
    import casadi

    return {f.name(): casadi.external(f.name(), str(library)) for f in module.FUNCTIONS}
