"""Name numba's compiled kernels for ``perf``: a script run under this module leaves
``/tmp/perf-<pid>.map``, the map ``perf report`` reads for code in anonymous memory.

numba's kernels live in memory its JIT maps, without symbols ``perf`` can see: a profile
of a search shows "[JIT]" and addresses. Installed before numba's JIT starts, this module
keeps every object file the JIT loads or compiles (numba's object-code cache hooks:
kernels loaded from the cache pass through them too), and at the end of the run reads
each one's ELF symbol table (the functions: name, size) and asks the JIT where it put
each function. A kernel inlined into its caller has no symbol of its own: its time is its
caller's.

Run, for a profile of the two-view benchmark with the kernels named::

    perf record -F 4000 -o /tmp/perf.data \\
        python experiments/perf_map.py benchmarks/two_view.py --trials 3
    perf report -i /tmp/perf.data --no-children --sort sym

(``perf report`` must run while the map is there, on the same machine.) The docs'
profiles (docs/performance.md, twenty-third session) were made so.
"""

from __future__ import annotations

import atexit
import os
import runpy
import struct
import sys

_BUFFERS: list[bytes] = []


def install() -> None:
    """Keep every object file numba's JIT loads or compiles from now on (call it before
    the first kernel compiles or loads: the hooks are read when the JIT starts)."""
    from numba.core import codegen

    library = codegen.CPUCodeLibrary
    loaded, compiled = library._object_getbuffer_hook.__func__, \
        library._object_compiled_hook.__func__

    def getbuffer(cls, module):
        buf = loaded(cls, module)
        if buf:
            _BUFFERS.append(bytes(buf))
        return buf

    def notify(cls, module, buf):
        _BUFFERS.append(bytes(buf))
        return compiled(cls, module, buf)

    library._object_getbuffer_hook = classmethod(getbuffer)
    library._object_compiled_hook = classmethod(notify)


def functions(elf: bytes) -> list[tuple[str, int]]:
    """The defined functions of a 64-bit little-endian ELF object file: (name, size)."""
    if elf[:4] != b"\x7fELF" or elf[4] != 2 or elf[5] != 1:
        return []
    (table,) = struct.unpack_from("<Q", elf, 0x28)
    entry, count = struct.unpack_from("<HH", elf, 0x3A)
    sections = [struct.unpack_from("<IIQQQQIIQQ", elf, table + k * entry) for k in range(count)]
    out = []
    for _, kind, _, _, offset, size, link, _, _, _ in sections:
        if kind != 2:  # SHT_SYMTAB
            continue
        names = sections[link][4]
        for k in range(size // 24):
            name, info, _, section, _, length = struct.unpack_from("<IBBHQQ", elf,
                                                                   offset + 24 * k)
            if info & 0xF == 2 and section != 0:  # STT_FUNC, defined here
                start = names + name
                out.append((elf[start:elf.index(b"\0", start)].decode(), length))
    return out


def write(path: str | None = None) -> tuple[str, int]:
    """Write the map of every function of the kept object files that the JIT placed:
    ``(path, functions)``."""
    from numba.core.registry import cpu_target

    engine = cpu_target.target_context.codegen()._engine
    placed = {}
    for elf in _BUFFERS:
        for name, size in functions(elf):
            try:
                address = engine.get_function_address(name)
            except Exception:  # noqa: BLE001 — a symbol the JIT did not keep: skipped
                continue
            if address:
                placed[address] = (size, name)
    placed.update(runtime_functions())
    path = path or f"/tmp/perf-{os.getpid()}.map"
    with open(path, "w") as out:
        for address, (size, name) in sorted(placed.items()):
            out.write(f"{address:x} {size:x} {name}\n")
    return path, len(placed)


def runtime_functions() -> dict[int, tuple[int, str]]:
    """numba's reference counts and allocation helpers (``NRT_incref``, ``NRT_decref``, ...):
    compiled in the process when its runtime starts, not through the object-code hooks, so
    named here from its library — each sized up to the next one (at most 256 bytes). A
    kernel's reference counts are calls of these: unnamed, they were a tenth of a conic fit's
    kernel time seen as bare addresses (docs/performance.md, thirty-fifth session)."""
    from numba.core.runtime import nrt

    library = getattr(nrt.rtsys, "_library", None)
    if library is None:
        return {}
    found = {}
    for function in library._final_module.functions:
        if function.is_declaration:
            continue
        try:
            address = library.get_pointer_to_function(function.name)
        except Exception:  # noqa: BLE001 — not kept by the JIT: skipped
            continue
        if address:
            found[address] = function.name
    ordered = sorted(found)
    return {address: (min(256, following - address), found[address])
            for address, following in zip(ordered, ordered[1:] + [ordered[-1] + 256],
                                          strict=True)}


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] in ("-h", "--help"):
        print(__doc__)
        return
    install()

    def at_exit():
        path, count = write()
        print(f"perf map: {path} ({count} functions)", file=sys.stderr)

    atexit.register(at_exit)
    sys.argv = list(argv)
    sys.path.insert(0, os.path.dirname(os.path.abspath(argv[0])))
    runpy.run_path(argv[0], run_name="__main__")


if __name__ == "__main__":
    main()
