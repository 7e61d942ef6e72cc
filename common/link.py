"""Kernels compiled on their own and called through an address: ``@linked("A f1 f2 i")``.

numba links a called kernel's code into its caller and optimises the whole again: a kernel
deep in the call tree is optimised and translated to machine code once for every kernel
above it (the engine's first compile took ~4 minutes, 90 % of it LLVM re-optimising the
same callees; docs/engine.md). A *linked* kernel is compiled once, for one declared
signature, and its callers reach it through a cell holding its address: each caller's code
holds a call through a pointer, not a copy of the callee. Exceptions propagate as across an
ordinary call (numba's native calling convention, status and exception record).

The signature is a string of *kinds* (:data:`KINDS`; modules add their own with
:func:`kind`), the arguments' then the result's: ``"A Pt f f1 -> b Lin Proj"`` (several
result kinds: a tuple). A caller's arguments must convert to the declared kinds (a literal
to its type, an array to a less specific layout); anything else is a typing error when the
caller compiles. The declared result types a caller without compiling the callee: every
linked kernel compiles on its own, so a cold cache is filled by several processes at once
(:func:`link`); a kernel whose compiled result differs from its declaration is an error.

Each cell is a process symbol (``kanagen_link_<module>_<name>``) registered when the kernel
is defined, so a caller loaded from numba's cache resolves it at once; the cell is filled
by :func:`link` (every linked kernel compiled, or loaded from the cache, in definition
order), which the engine calls before its first kernel runs. A call through an empty cell
raises instead of jumping to address zero. Interpreted (numba missing, or
``NUMBA_DISABLE_JIT=1``) a linked kernel is its Python function.
"""

from __future__ import annotations

import os
import re
import sys
import threading

import numpy as np

from kanagen.common.interrupts import raise_pending
from kanagen.common.jit import NUMBA, jit

_lock = threading.RLock()  # numba's compiler lock where numba is (see below)
_LINKED: list = []  # every linked kernel, in definition order
_KIND_MODULES: dict = {}  # the modules that named kinds, in order (a set that keeps it)
_sharing = threading.local()  # active: kernels compile without their callees (link())
_sharing.active = False
#: kind name -> a function making its numba type (made when first needed)
KINDS: dict = {}
#: The letters of the basic kinds: ``f`` a float, ``i`` an integer, ``b`` a boolean; with
#: a rank, a C-ordered array of them (``f2``: a float matrix).
DTYPES = {"f": np.float64, "i": np.int64, "b": np.bool_}


def layout(name: str) -> tuple:
    """A basic kind's NumPy dtype and rank (0: a number)."""
    return DTYPES[name[0]], int(name[1:] or 0)


def kind(name: str, make, _depth: int = 1) -> None:
    """Name a numba type for signatures: ``make()`` returns it."""
    KINDS[name] = make
    _KIND_MODULES.setdefault(sys._getframe(_depth).f_globals.get("__name__", ""))


def record_kind(name: str, record, kinds: str) -> None:
    """Name the numba type of the named tuple class ``record`` whose fields are ``kinds``
    (``record`` None: a plain tuple)."""
    def make():
        from numba import types
        return types.BaseTuple.from_types([KINDS[k]() for k in kinds.split()], record)
    kind(name, make, 2)


if NUMBA is not None and not jit.disabled:
    from llvmlite import binding as ll
    from llvmlite import ir
    from numba import types
    from numba.core import cgutils
    from numba.core.compiler_lock import global_compiler_lock
    from numba.core.errors import TypingError
    from numba.core.typing.templates import AbstractTemplate, infer_global, signature
    from numba.extending import lower_builtin

    # One lock for linking and compiling: a kernel being compiled (under numba's lock)
    # resolves the linked kernels it calls, while link() compiles them.
    _lock = global_compiler_lock

    for _letter, _dtype in DTYPES.items():
        _scalar = NUMBA.from_dtype(_dtype)
        for _rank in range(4):
            kind(_letter + (str(_rank) if _rank else ""),
                 lambda s=_scalar, r=_rank: types.Array(s, r, "C") if r else s)

    class _Linked:
        """One linked kernel: its dispatcher, declared kinds, cell, and its callers' typing
        and code."""

        def __init__(self, function, kinds: str, python: bool):
            self.name = function.__name__
            arguments, arrow, results = kinds.partition("->")
            if not arrow or not results.split():
                raise ValueError(f"@linked {function.__name__}: declare the result's kinds "
                                 f"after '->' (got {kinds!r})")
            self.kinds = arguments.split()
            self.results = results.split()
            self.function = function
            self.module = function.__module__
            # the callers need its native code only: no wrappers (their boxing of named
            # tuples of arrays is most of the code of a small kernel)
            self.kernel = NUMBA.njit(cache=True, error_model="numpy",
                                     no_cpython_wrapper=not python,
                                     no_cfunc_wrapper=True)(function)
            self._python = self.kernel if python else None
            self.symbol = "kanagen_link_" + re.sub(r"\W", "_", function.__module__) + \
                "_" + self.name
            self.cell = np.zeros(1, dtype=np.int64)
            ll.add_symbol(self.symbol, self.cell.ctypes.data)
            self.signature = None
            self._declared = None

        def cached(self) -> bool:
            """Is the kernel in numba's cache already (its index written: loading it is
            cheap)? Unknown counts as cached: it is then compiled here, not shared."""
            try:
                return os.path.exists(self.kernel._cache._cache_file._index_path)
            except AttributeError:  # numba's cache laid out otherwise
                return True

        def declared(self):
            """The declared signature (made when first needed)."""
            if self._declared is None:
                results = [KINDS[k]() for k in self.results]
                result = results[0] if len(results) == 1 else \
                    types.BaseTuple.from_types(results)
                self._declared = signature(result, *(KINDS[k]() for k in self.kinds))
            return self._declared

        def resolve(self):
            """Compile (or load) the kernel for its signature and fill its cell."""
            with _lock:
                if self.signature is None:
                    sig = self.declared()
                    self.kernel.compile(sig.args)
                    result = self.kernel.overloads[sig.args]
                    if result.signature.return_type != sig.return_type:
                        raise TypeError(f"@linked {self.name}: returns "
                                        f"{result.signature.return_type}, declared "
                                        f"{sig.return_type} ({' '.join(self.results)})")
                    self.cell[0] = result.library.get_pointer_to_function(
                        result.fndesc.llvm_func_name)
                    self.signature = result.signature
            return self.signature

        def typer(self, context, args):
            """The return type for a call with arguments of types ``args``: the declared
            one. While :func:`link` compiles the kernels (each on its own, shares of them in
            other processes) the callee is not compiled for it; a caller compiled at another
            time compiles (or loads) the callee and fills its cell, to be callable at once."""
            sig = self.declared()
            if not _sharing.active:
                self.resolve()
            if len(args) != len(sig.args):
                raise TypingError(f"{self.name} takes {len(sig.args)} arguments "
                                  f"({' '.join(self.kinds)}), got {len(args)}")
            for at, (given, declared) in enumerate(zip(args, sig.args, strict=True)):
                if context.can_convert(given, declared) is None:
                    raise TypingError(f"{self.name}: argument {at} is {given}, "
                                      f"declared {declared} ({self.kinds[at]})")
            return sig.return_type

        def lower(self, context, builder, signature, llargs):
            """A call through the cell, the arguments converted to the declared kinds."""
            sig = self.declared()
            values = [context.cast(builder, value, given, declared)
                      for value, given, declared in zip(llargs, signature.args, sig.args,
                                                          strict=True)]
            module = builder.module
            cell = module.globals.get(self.symbol)
            if cell is None:
                cell = ir.GlobalVariable(module, ir.IntType(64), self.symbol)
            address = builder.load(cell)
            with cgutils.if_unlikely(builder, cgutils.is_null(builder, address)):
                context.call_conv.return_user_exc(
                    builder, RuntimeError, (f"kanagen: {self.name} called before "
                                            "kanagen.common.link.link()",))
            fnty = context.call_conv.get_function_type(sig.return_type, sig.args)
            function = builder.inttoptr(address, fnty.as_pointer())
            status, out = context.call_conv.call_function(builder, function, sig.return_type,
                                                          sig.args, values)
            with cgutils.if_unlikely(builder, status.is_error):
                context.call_conv.return_status_propagate(builder, status)
            return out

        def python(self):
            """The kernel as Python calls it: itself when declared ``python=True``, else a
            twin compiled with its wrapper, not cached (tests, explorations). Made under the
            lock once; read without it after (numba's compiler lock costs ~3 µs a call)."""
            made = self._python
            if made is None:
                with _lock:
                    if self._python is None:
                        self._python = NUMBA.njit(error_model="numpy")(self.function)
                    made = self._python
            return made

    def _make(function, kinds: str, python: bool):
        entry = _Linked(function, kinds, python)
        _LINKED.append(entry)

        def stub(*args):
            link(entry.module)
            return entry.python()(*args)

        class Call(AbstractTemplate):  # a caller's code: a call through the cell
            key = stub

            def generic(self, args, kws):
                if kws:
                    raise TypingError(f"{entry.name}: no keyword arguments")
                return signature(entry.typer(self.context, args), *args)

        infer_global(stub, types.Function(Call))
        lower_builtin(stub, types.VarArg(types.Any))(entry.lower)

        stub.__name__ = stub.__qualname__ = function.__name__
        stub.__doc__ = function.__doc__
        stub.__module__ = function.__module__
        stub.__wrapped__ = function
        return stub


def linked(kinds: str, python: bool = False):
    """Decorate a kernel to be compiled on its own for the signature ``kinds`` (a string
    of :data:`KINDS` names) and called through its address; ``python=True``: the runtime
    calls it from Python too (its cached code then has the Python wrapper)."""
    def decorate(function):
        if NUMBA is None or jit.disabled:
            return function
        return _make(function, kinds, python)
    return decorate


_linked_for: dict = {}  # roots -> len(_LINKED) when link(*roots) last filled their cells


def reach(roots) -> set:
    """The modules whose linked kernels the code of ``roots`` (names of modules, or of
    packages: every module loaded under one) may call: those modules and, transitively, the
    module of each kernel, function or module their namespaces hold (within kanagen and the
    modules that define linked kernels)."""
    owners = {e.module for e in _LINKED}
    todo = [name for name in list(sys.modules)
            if any(name == root or name.startswith(root + ".") for root in roots)]
    seen: set = set()
    while todo:
        name = todo.pop()
        module = sys.modules.get(name)
        if name in seen or module is None:
            continue
        seen.add(name)
        for value in list(vars(module).values()):
            owner = _owner(value)
            if isinstance(owner, str) and owner not in seen and (
                    owner.startswith("kanagen.") or owner in owners):
                todo.append(owner)
    return seen


def _owner(value):
    """The name of the module that defines ``value`` (a module's own name), or None."""
    if isinstance(value, type(sys)):
        return value.__name__
    try:  # any object: a proxy's attribute lookup may do anything
        return getattr(getattr(value, "py_func", value), "__module__", None)
    except Exception:  # noqa: BLE001 - an object that cannot say is no kernel's
        return None


def link(*roots: str) -> None:
    """Fill the cells of the linked kernels that the code of the modules (or packages)
    ``roots`` may call (:func:`reach`; none given: every linked kernel) — compiled, or
    loaded from numba's cache. A kernel no caller needs is not compiled: the engine's first
    fit does not compile the two-view closed forms, whose module a program may have loaded.
    The kernels not in the cache yet are compiled by this process and helper processes at
    the same time, shares of them each (:func:`processes`): this process then loads theirs
    from the cache they wrote. While the engine is first compiled
    (:func:`kanagen.common.jit.announce`), or when many kernels are (a family's own, the
    first time it is used), a line on stderr and a progress bar on a terminal."""
    if _linked_for.get(roots) == len(_LINKED):
        return
    with _lock:
        count = len(_LINKED)
        modules = reach(roots) if roots else None
        entries = [e for e in _LINKED[:count] if e.signature is None and (
            modules is None or e.module in modules)]
        cold = [e for e in entries if not e.cached()]
        helpers = _start_helpers(cold)
        mine = [e for e in cold if not any(e in share for share, _ in helpers)]
        if len(cold) >= _ANNOUNCE and not jit.compiling:  # a later family's own kernels
            shared = f" in {len(helpers) + 1} processes" if helpers else ""
            sys.stderr.write(f"kanagen: compiling {len(cold)} kernels for this machine "
                             f"(once{shared})...\n")
            sys.stderr.flush()
        _sharing.active = True
        try:
            if cold and (jit.compiling or len(cold) >= _ANNOUNCE) and _on_terminal():
                import click

                label = "kanagen: compiling the kernels" + (
                    f" ({len(helpers) + 1} processes)" if helpers else "")
                with click.progressbar(mine, label=label, file=sys.stderr,
                                       item_show_func=_current) as bar:
                    for entry in bar:
                        entry.resolve()
                        raise_pending()  # a Ctrl-C during that compile: raised here
            else:
                for entry in mine:
                    entry.resolve()
                    raise_pending()
            for _, process in helpers:
                _finish(process)
            for entry in entries:  # the helpers': from the cache (or compiled here)
                entry.resolve()
                raise_pending()
        finally:
            _sharing.active = False
            for _, process in helpers:  # an interrupted link leaves no helper behind
                if process.poll() is None:
                    process.kill()
        _linked_for[roots] = count


#: At most this many processes compile a cold cache together.
MAX_PROCESSES = 8
#: A link that compiles this many kernels or more says so (and shows its progress).
_ANNOUNCE = 8
#: Each process compiles at least this many kernels (fewer: not worth a process).
_LEAST_SHARE = 4


def processes(count: int) -> int:
    """How many processes compile ``count`` kernels: one a core available, at most
    :data:`MAX_PROCESSES`, each with a few kernels; ``KANAGEN_COMPILE_PROCESSES`` sets it
    (1: this process alone)."""
    given = os.environ.get("KANAGEN_COMPILE_PROCESSES", "").strip()
    if given:
        try:
            wanted = int(given)
        except ValueError:
            raise ValueError(f"KANAGEN_COMPILE_PROCESSES must be a whole number of processes, "
                             f"got {given!r}") from None
    else:
        cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else \
            (os.cpu_count() or 1)
        wanted = min(cores, MAX_PROCESSES)
    return max(1, min(wanted, count // _LEAST_SHARE))


def _start_helpers(entries) -> list:
    """Processes compiling shares of ``entries`` into numba's cache (every kernel compiles
    on its own: the callees' declared results type the calls): ``[(share, process)]``;
    none where only this process should (one core, or no interpreter to start)."""
    import json
    import subprocess

    portable = [e for e in entries if e.function.__module__.startswith("kanagen.")]
    count = processes(len(portable))
    if count < 2 or not sys.executable:
        return []
    modules = list(_KIND_MODULES) + [e.function.__module__ for e in portable]
    modules = [m for m in dict.fromkeys(modules) if m.startswith("kanagen.")]
    helpers = []
    for k in range(1, count):
        share = portable[k::count]
        names = [f"{e.function.__module__}:{e.name}" for e in share]
        try:
            process = subprocess.Popen(
                [sys.executable, "-c", "import sys, json; from kanagen.common.link import "
                 "compile_share; compile_share(*json.loads(sys.argv[1]))",
                 json.dumps([modules, names])],
                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL)
        except OSError:
            break
        helpers.append((share, process))
    return helpers


def _finish(process, timeout: float = 900.0) -> None:
    """Wait for a helper (stopped after ``timeout`` seconds: this process compiles what it
    left)."""
    import subprocess

    try:
        process.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()


def compile_share(modules: list, names: list) -> None:
    """A helper process of :func:`link`: import ``modules`` and compile the linked
    kernels ``names`` (``module:name``) into numba's cache."""
    import importlib

    for module in modules:
        importlib.import_module(module)
    wanted = set(names)
    _sharing.active = True
    for entry in list(_LINKED):
        if f"{entry.function.__module__}:{entry.name}" in wanted:
            entry.resolve()


def _on_terminal() -> bool:
    try:
        return sys.stderr.isatty()
    except (AttributeError, ValueError):  # replaced or closed
        return False


def _current(entry) -> str:
    return "" if entry is None else entry.name
