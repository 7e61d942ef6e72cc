"""Ctrl-C during a compile, kept.

numba compiles (and loads its cache) through llvmlite, which calls back into Python from
LLVM's object cache by ctypes. A KeyboardInterrupt raised inside such a callback is printed
by ctypes ("Exception ignored on calling ctypes callback function") and dropped: the compile
goes on and the Ctrl-C is lost — a first use compiling for a minute could not be
interrupted. :func:`keep_interrupts` replaces Python's default handler by one that does what
it does, but for a Ctrl-C landing in one of those callbacks: that one is delivered again a
moment later, once out of it.
"""

from __future__ import annotations

import _thread
import signal
import threading

#: llvmlite's callbacks from LLVM's object cache (``ExecutionEngine``'s).
CALLBACKS = frozenset({"_raw_object_cache_notify", "_raw_object_cache_getbuffer"})
#: Seconds before a Ctrl-C that landed in a callback is delivered again.
RETRY = 0.05


def in_callback(frame) -> bool:
    """``frame`` or one of its callers is one of llvmlite's object-cache callbacks."""
    while frame is not None:
        if frame.f_code.co_name in CALLBACKS:
            return True
        frame = frame.f_back
    return False


def on_interrupt(signum, frame) -> None:
    """Python's Ctrl-C (a KeyboardInterrupt where the main thread is), except inside an
    object-cache callback: there, the same signal again in :data:`RETRY` seconds."""
    if in_callback(frame):
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
