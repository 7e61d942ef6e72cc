"""Ctrl-C during a compile, kept and raised where it is safe.

numba compiles (and loads its cache) through llvmlite. A KeyboardInterrupt raised in the
middle of their Python code can leave LLVM's objects half-released (a crash later, in the
same process), and one raised in llvmlite's callbacks from LLVM's object cache (ctypes
callbacks) or in a finaliser (``__del__``) is printed and dropped ("Exception ignored ...")
while the compile goes on: a first use compiling for a minute could not be interrupted.
:func:`keep_interrupts` replaces Python's default handler by one that does what it does,
but for a Ctrl-C landing in numba's or llvmlite's code or in a finaliser: that one is
delivered again a moment later, until it lands outside them (the compile of one kernel
over, the caller's code running).
"""

from __future__ import annotations

import _thread
import signal
import threading

#: The modules whose Python code a Ctrl-C waits out (prefixes of their names).
DEFERRED = ("numba.", "llvmlite.")
#: Seconds before a Ctrl-C that landed there is delivered again.
RETRY = 0.05


def deferred_at(frame) -> bool:
    """``frame`` or one of its callers runs numba's or llvmlite's code, or a finaliser."""
    while frame is not None:
        if frame.f_globals.get("__name__", "").startswith(DEFERRED) or \
                frame.f_code.co_name == "__del__":
            return True
        frame = frame.f_back
    return False


def on_interrupt(signum, frame) -> None:
    """Python's Ctrl-C (a KeyboardInterrupt where the main thread is), except in numba's or
    llvmlite's code or a finaliser (:func:`deferred_at`): there, the same signal again in
    :data:`RETRY` seconds."""
    if deferred_at(frame):
        timer = threading.Timer(RETRY, _thread.interrupt_main, (signum,))
        timer.daemon = True
        timer.start()
        return
    signal.default_int_handler(signum, frame)


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
