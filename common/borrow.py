"""Arrays without reference counting, for the engine's innermost loops.

numba counts references to every array a kernel holds: each view taken (``c[i]``) and each
array argument of a call is counted up and down again, an atomic operation each time, and
the counts that a call's error path keeps alive are not pruned. In a loop over the measures
calling small helpers with a dozen buffers this costs more than the helpers' arithmetic.

``borrow(a)`` is ``a`` without its reference (numba's view of external memory): taking views
of it and passing them on counts nothing; ``borrow((a, b, ...))`` borrows each array of a
tuple. It does not keep ``a``'s memory alive: the owner
must outlive every use of the borrowed array — :func:`alive` after the loop keeps a local
owner alive to that point (numba releases a variable after its last use) — and a borrowed
array must never be returned or stored. Interpreted, both are no-ops.
"""

from __future__ import annotations

from kanagen.common.jit import NUMBA, jit

if NUMBA is not None and not jit.disabled:
    from numba.core import cgutils, types
    from numba.extending import intrinsic

    def _borrowed(context, builder, typ, value):
        array = context.make_array(typ)(context, builder, value)
        array.meminfo = cgutils.get_null_value(array.meminfo.type)
        array.parent = cgutils.get_null_value(array.parent.type)
        return array._getvalue()

    @intrinsic
    def borrow(typingctx, a):
        if isinstance(a, types.Array):
            def codegen(context, builder, signature, args):
                return _borrowed(context, builder, signature.args[0], args[0])
            return a(a), codegen
        if isinstance(a, types.BaseTuple) and not isinstance(a, types.NamedTuple) and \
                all(isinstance(t, types.Array) for t in a.types):
            def codegen(context, builder, signature, args):
                values = [_borrowed(context, builder, t, builder.extract_value(args[0], k))
                          for k, t in enumerate(signature.args[0].types)]
                return context.make_tuple(builder, signature.return_type, values)
            return a(a), codegen
        return None

    @intrinsic
    def alive(typingctx, values):
        def codegen(context, builder, signature, args):
            return context.get_dummy_value()
        return types.void(values), codegen
else:
    def borrow(a):
        """``a``, an array or a tuple of them (interpreted: no reference counts to spare)."""
        return a

    def alive(values):
        """Nothing (interpreted)."""
