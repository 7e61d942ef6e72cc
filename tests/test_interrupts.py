"""Ctrl-C during a compile is kept (kanagen.common.interrupts): one landing in llvmlite's
object-cache callbacks, where ctypes would print and drop the KeyboardInterrupt, is
delivered again once out of them; anywhere else it raises at once, as Python's own."""

import signal
import subprocess
import sys
import time

import pytest

from kanagen.common import interrupts


def _raw_object_cache_notify(handler):  # llvmlite's callback's name (ExecutionEngine's)
    handler(signal.SIGINT, sys._getframe())  # returns: nothing may be raised in there
    return True


def _installed(handler):
    return signal.signal(signal.SIGINT, handler)


def test_a_ctrl_c_outside_the_callbacks_raises_at_once():
    with pytest.raises(KeyboardInterrupt):
        interrupts.on_interrupt(signal.SIGINT, sys._getframe())


def test_a_ctrl_c_in_a_callback_is_delivered_again_once_out_of_it():
    previous = _installed(interrupts.on_interrupt)
    try:
        assert _raw_object_cache_notify(interrupts.on_interrupt)  # deferred, not raised
        with pytest.raises(KeyboardInterrupt):
            deadline = time.monotonic() + 10.0
            while time.monotonic() < deadline:  # the retry lands here: out of the callback
                time.sleep(0.01)
    finally:
        signal.signal(signal.SIGINT, previous)


def test_only_the_default_handler_is_replaced():
    def own(signum, frame):
        pass

    previous = _installed(own)
    try:
        assert not interrupts.keep_interrupts()
        assert signal.getsignal(signal.SIGINT) is own
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # a background job's: left ignored
        assert not interrupts.keep_interrupts()
        signal.signal(signal.SIGINT, signal.default_int_handler)
        assert interrupts.keep_interrupts()
        assert signal.getsignal(signal.SIGINT) is interrupts.on_interrupt
    finally:
        signal.signal(signal.SIGINT, previous)


def test_a_fit_process_handles_ctrl_c_so():
    """The kernels' compiler installs the handler when numba is imported (a fit's first
    kernel), over Python's default one."""
    code = ("import signal, numpy as np, kanagen; fam = kanagen.load('line'); "
            "kanagen.fit(fam, data={'point': np.c_[np.arange(5.0), 2 * np.arange(5.0)]}); "
            "from kanagen.common.interrupts import on_interrupt; "
            "print(signal.getsignal(signal.SIGINT) is on_interrupt)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=600)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().endswith("True")
