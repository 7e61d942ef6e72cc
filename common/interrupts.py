"""Ctrl-C during a compile, kept and raised where it is safe.

numba compiles (and loads its cache) through llvmlite. A KeyboardInterrupt raised in their
Python code can leave them broken for the rest of the process: in llvmlite's, LLVM's
objects half-released (an "Exception ignored in ObjectRef.__del__", then a crash); in
numba's, a registry's generator closed mid-way ("RuntimeError: generator raised
StopIteration" at every later compile). One raised in llvmlite's callbacks from LLVM's
object cache (ctypes callbacks) or in a finaliser (``__del__``) is printed and dropped
("Exception ignored ...") while the compile goes on: a first use compiling for a minute
could not be interrupted. :func:`keep_interrupts` replaces Python's default handler by one
that does what it does, but for a Ctrl-C landing in numba's or llvmlite's code or in a
finaliser: that one is delivered again a moment later, until it lands outside them (the
compile over, the caller's code running), or raised between two kernels' compiles
(:func:`raise_pending`) — so a Ctrl-C during a run of compiles waits for the kernel being
compiled (seconds; ~20–30 s for the largest on a busy machine).
"""

from __future__ import annotations

import _thread
import signal
import threading

#: The modules whose Python code a Ctrl-C waits out (prefixes of their names).
DEFERRED = ("numba.", "llvmlite.")
#: Seconds before a Ctrl-C that landed there is delivered again.
RETRY = 0.05


#: numba's Python that runs when a compiled kernel boxes its results (unpickling a class):
#: a KeyboardInterrupt there reaches the caller as a SystemError caused by it, which the
#: callers turn back into one (:func:`kanagen.common.jit.interrupted`). It is where a long
#: run of kernel calls spends most of its Python time: deferred there, a Ctrl-C landed there
#: again at every delivery and a search ran to its end.
BOXING = (("numba.core.serialize", "_numba_unpickle"),)


def deferred_at(frame) -> bool:
    """``frame`` or one of its callers runs numba's or llvmlite's code (but the boxing of a
    kernel's results, :data:`BOXING`), or a finaliser."""
    while frame is not None:
        module = frame.f_globals.get("__name__", "")
        if (module.startswith(DEFERRED) and (module, frame.f_code.co_name) not in BOXING) or \
                frame.f_code.co_name == "__del__":
            return True
        frame = frame.f_back
    return False


#: ``pending``: a Ctrl-C waits to be raised; ``in_flight``: its deliveries again under way.
_state = {"pending": False, "in_flight": 0}


def on_interrupt(signum, frame) -> None:
    """Python's Ctrl-C (a KeyboardInterrupt where the main thread is), except in numba's or
    llvmlite's code or a finaliser (:func:`deferred_at`): there, the same signal again in
    :data:`RETRY` seconds. A delivery again of one already raised (by
    :func:`raise_pending`) is ignored."""
    if _state["in_flight"]:
        _state["in_flight"] -= 1
        if not _state["pending"]:
            return
    if deferred_at(frame):
        _state["pending"] = True
        _state["in_flight"] += 1
        timer = threading.Timer(RETRY, _thread.interrupt_main, (signum,))
        timer.daemon = True
        timer.start()
        return
    _state["pending"] = False
    signal.default_int_handler(signum, frame)


def raise_pending() -> None:
    """Raise the Ctrl-C that waits, if one does: called where it is safe, between two
    kernels' compiles (kanagen.common.link), so that a run of many compiles stops at the
    next one's end rather than at the last's (in the main thread, which a Ctrl-C
    interrupts; another thread's compiles do not raise it)."""
    if _state["pending"] and threading.current_thread() is threading.main_thread():
        _state["pending"] = False
        raise KeyboardInterrupt


def keep_interrupts() -> bool:
    """Handle Ctrl-C by :func:`on_interrupt` where Python's default handler does (in the
    main thread; a program's own handler, or an ignored SIGINT, is left as it is). True
    when installed."""
    if threading.current_thread() is not threading.main_thread():
        return False
    if signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        return False
    signal.signal(signal.SIGINT, on_interrupt)
    return True
