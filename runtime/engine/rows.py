"""A family's equations as compiled row kernels, called from the engine through addresses.

The generated module of a family carries, beside each vectorised function, its *row form*
(``ROWS``: one measure, every output entry written into one flat array). Here each row form
is compiled by numba into a C-callable function (``cfunc``, cached on disk) whose address
the engine receives in an integer table: the engine is compiled once for every family, and
a family adds only its small row kernels (docs/engine.md).

Signatures (``double*`` arguments):

* ``c0``: ``(q, k, out)`` — ``out`` = ``c0 (r)``, ``C0 (r, n)``;
* ``measure``: ``(q, m, k, out)`` — ``m`` one measure's whole row, ``out`` = ``c (p)``,
  ``C (p, n)``, ``D (p, d)``;
* ``slack``: ``(q, k, out)`` — the slack relations' values (appendix F).

Interpreted (``NUMBA_DISABLE_JIT=1``, or numba missing) the same Python row functions are
called through a table of the addresses this module hands out.
"""

from __future__ import annotations

import threading

from kanagen.common.jit import NUMBA, jit

_lock = threading.Lock()
_python_rows: dict[int, object] = {}  # address -> Python row function (interpreted runs)

if NUMBA is not None:
    from numba import types
    from numba.core import cgutils
    from numba.extending import intrinsic, overload

    _P = types.CPointer(types.float64)
    SIG3 = types.void(_P, _P, _P)
    SIG4 = types.void(_P, _P, _P, _P)
    _FT3 = types.FunctionType(SIG3)
    _FT4 = types.FunctionType(SIG4)

    def _pointer_intrinsic(ftype):
        @intrinsic
        def as_function(typingctx, address):
            def codegen(context, builder, signature, args):
                value = cgutils.create_struct_proxy(ftype)(context, builder)
                void = context.get_value_type(types.voidptr)
                value.c_addr = builder.inttoptr(args[0], void)
                value.py_addr = void(None)
                value.jit_addr = void(None)
                return value._getvalue()
            return ftype(types.int64), codegen
        return as_function

    _as3 = _pointer_intrinsic(_FT3)
    _as4 = _pointer_intrinsic(_FT4)


def call3(address, a, b, out):
    """Call the row kernel at ``address`` with ``(a, b, out)`` (``c0``, ``slack``)."""
    _python_rows[address](a, b, out)


def call4(address, a, b, c, out):
    """Call the row kernel at ``address`` with ``(a, b, c, out)`` (``measure``)."""
    _python_rows[address](a, b, c, out)


if NUMBA is not None:
    @overload(call3, jit_options={"cache": True})
    def _call3(address, a, b, out):
        def impl(address, a, b, out):
            _as3(address)(a.ctypes, b.ctypes, out.ctypes)
        return impl

    @overload(call4, jit_options={"cache": True})
    def _call4(address, a, b, c, out):
        def impl(address, a, b, c, out):
            _as4(address)(a.ctypes, b.ctypes, c.ctypes, out.ctypes)
        return impl


def compiled_row(function, arity: int) -> int:
    """The address of ``function`` (a generated row form) compiled as a C-callable kernel,
    once a process (models share their channels' functions); interpreted, a key of the
    Python table."""
    with _lock:
        if NUMBA is None or jit.disabled:
            address = id(function)
            _python_rows[address] = function
            return address
        kernel = _compiled.get(function)
        if kernel is None:
            kernel = _compiled[function] = NUMBA.cfunc(
                SIG3 if arity == 3 else SIG4, cache=_cacheable(function),
                error_model="numpy")(function)  # the code lives as long as the process
        return int(kernel.address)


_compiled: dict = {}  # row function -> its compiled kernel


def _cacheable(function) -> bool:
    """numba caches functions defined in a file (a family built in memory is not)."""
    code = getattr(function, "__code__", None)
    return bool(code and code.co_filename and not code.co_filename.startswith("<"))
