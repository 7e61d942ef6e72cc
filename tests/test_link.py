"""Linked kernels (kanagen.common.link): compiled once, called through an address."""

from __future__ import annotations

import numpy as np
import pytest

from kanagen.common.jit import NUMBA, jit
from kanagen.common.link import _LINKED, link, linked

pytestmark = pytest.mark.skipif(NUMBA is None or jit.disabled, reason="numba kernels only")


@linked("f1 f -> f1 f")
def _scaled(v, s):
    if s < 0:
        raise ValueError("a negative scale")
    out = v * s
    return out, out.sum()


@jit
def _twice(v):
    a, total = _scaled(v, 2)  # a literal integer, converted to the declared float
    b, more = _scaled(a, 1.5)
    return b, total + more


@jit
def _negative(v):
    return _scaled(v, -1.0)


@jit
def _wrong(v):
    return _scaled(v.astype(np.int64), 1.0)


def _entry():
    return next(e for e in _LINKED if e.name == "_scaled")


def test_called_from_a_kernel_as_written():
    link()  # as the engine does before its first kernel runs (a caller loaded from the
    # cache was never typed: nothing compiled its callee for it)
    v = np.arange(4.0)
    b, total = _twice(v)
    np.testing.assert_array_equal(b, v * 3.0)
    assert total == pytest.approx(v.sum() * 2 + v.sum() * 3)
    # from Python: the same kernel
    out, s = _scaled(v, 2.0)
    np.testing.assert_array_equal(out, 2 * v)
    assert _entry().cell[0] != 0


def test_exceptions_cross_the_call():
    link()
    with pytest.raises(ValueError, match="negative scale"):
        _negative(np.ones(3))


def test_an_argument_of_another_kind_is_a_typing_error_naming_it():
    from numba.core.errors import TypingError

    with pytest.raises(TypingError, match=r"_scaled: argument 0 is array\(int64"):
        _wrong(np.ones(3))


def test_an_empty_cell_raises_instead_of_jumping_to_zero():
    _twice(np.ones(2))  # compiled (and the cell filled)
    entry = _entry()
    address = int(entry.cell[0])
    entry.cell[0] = 0
    try:
        with pytest.raises(RuntimeError, match="_scaled called before"):
            _twice(np.ones(2))
    finally:
        entry.cell[0] = address
    link()
    assert _twice(np.ones(2))[1] == pytest.approx(2 * 2 + 2 * 3)


def test_the_engine_kernels_are_linked_once_each():
    from kanagen.runtime.engine import iterate  # noqa: F401 - defines every kernel

    names = [e.symbol for e in _LINKED]
    assert len(names) == len(set(names))
    engine = [e for e in _LINKED if ".engine." in e.kernel.py_func.__module__]
    assert len(engine) >= 30
    link()
    for e in engine:
        assert e.cell[0] != 0 and len(e.kernel.signatures) >= 1, e.name


_FIT = """
import json, sys
import numpy as np, kanagen
t = np.linspace(0, np.pi, 30)
xy = np.c_[100 + 50 * np.cos(t), 80 + 30 * np.sin(t)] + \\
    np.random.default_rng(0).normal(0, 1, (30, 2))
r = kanagen.fit(kanagen.load("conic"), "conic", data={"point": xy}, info={"point": 1.0},
                q0=[1, 0, 1, -200, -160, 15000.0])
print(json.dumps([r.status, r.iterations, r.cost, r.q.tolist()]))
"""


def test_interpreted_kernels_give_the_compiled_answers():
    """``NUMBA_DISABLE_JIT=1``: the linked kernels are their Python functions; the same fit."""
    import json
    import os
    import subprocess
    import sys

    runs = []
    for disabled in ("1", "0"):
        env = dict(os.environ, NUMBA_DISABLE_JIT=disabled)
        out = subprocess.run([sys.executable, "-c", _FIT], env=env, capture_output=True,
                             text=True, timeout=600, check=True)
        runs.append(json.loads(out.stdout.strip().splitlines()[-1]))
    (s1, it1, cost1, q1), (s2, it2, cost2, q2) = runs
    assert (s1, it1) == (s2, it2) == (0, 7)
    assert cost1 == pytest.approx(cost2, rel=1e-10)
    np.testing.assert_allclose(q1, q2, rtol=1e-10, atol=1e-12)


def test_old_kernel_caches_are_pruned_to_the_most_recent(tmp_path):
    import os

    from kanagen.common.jit import KEEP_OTHERS, prune

    root = tmp_path / "numba"
    current = root / "0123456789abcdef"
    current.mkdir(parents=True)
    others = []
    for age in range(5):
        folder = root / f"{age:016x}"
        (folder / "kanagen_engine").mkdir(parents=True)
        entry = folder / "kanagen_engine" / "x.nbi"
        entry.write_text("index")
        os.utime(entry, (1e9 - age * 1e5, 1e9 - age * 1e5))
        others.append(folder)
    (root / "not-a-digest").mkdir()
    removed = prune(current)
    assert sorted(removed) == sorted(others[KEEP_OTHERS:])
    assert current.exists() and (root / "not-a-digest").exists()
    assert all(f.exists() for f in others[:KEEP_OTHERS])


def _progress_kernel(v):
    return v + 1.0


def test_a_first_compile_shows_its_progress_on_a_terminal(monkeypatch):
    import io
    import sys

    kernel = linked("f -> f")(_progress_kernel)  # a kernel not linked yet
    monkeypatch.setattr(jit, "compiling", True)
    entry = next(e for e in _LINKED if e.name == "_progress_kernel")
    monkeypatch.setattr(entry, "cached", lambda: False)  # as on a fresh machine

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    err = Terminal()
    monkeypatch.setattr(sys, "stderr", err)
    link()
    assert "kanagen: compiling the kernels" in err.getvalue()
    assert kernel(1.0) == 2.0


def _negated(v):
    return -v


_NEGATED = None  # the linked _negated, made by the test below


def _calls(v):
    return 2.0 * _NEGATED(v)


def _declared_wrong(v):
    return v.sum()


def test_a_kernel_declares_its_result():
    with pytest.raises(ValueError, match="declare the result's kinds after '->'"):
        linked("f1")(_declared_wrong)
    kernel = linked("f1 -> f1")(_declared_wrong)  # returns a number
    try:
        with pytest.raises(TypeError, match=r"_declared_wrong: returns float64, declared "
                                            r"array"):
            kernel(np.ones(2))
    finally:  # link() resolves every kernel: this one must not stay among them
        _LINKED[:] = [e for e in _LINKED if e.name != "_declared_wrong"]


def test_while_linking_a_caller_compiles_without_its_callees(monkeypatch):
    """What lets several processes share a cold cache: inside link() a caller is typed from
    its callee's declared result, not by compiling the callee; link() then fills every cell."""
    global _NEGATED
    from kanagen.common import link as module

    _NEGATED = linked("f -> f")(_negated)
    caller = linked("f -> f")(_calls)
    entry = {e.name: e for e in _LINKED}
    monkeypatch.setattr(module._sharing, "active", True)
    entry["_calls"].resolve()
    assert entry["_negated"].signature is None  # not compiled for its caller
    monkeypatch.setattr(module._sharing, "active", False)
    link()
    assert entry["_negated"].signature is not None and caller(3.0) == pytest.approx(-6.0)


def test_how_many_processes_compile(monkeypatch):
    from kanagen.common.link import MAX_PROCESSES, processes

    monkeypatch.setenv("KANAGEN_COMPILE_PROCESSES", "1")
    assert processes(100) == 1
    monkeypatch.setenv("KANAGEN_COMPILE_PROCESSES", "3")
    assert processes(100) == 3 and processes(8) == 2 and processes(3) == 1
    monkeypatch.setenv("KANAGEN_COMPILE_PROCESSES", "many")
    with pytest.raises(ValueError, match="KANAGEN_COMPILE_PROCESSES must be a whole number"):
        processes(100)
    monkeypatch.delenv("KANAGEN_COMPILE_PROCESSES")
    assert 1 <= processes(1000) <= MAX_PROCESSES


def _halved(x):
    return 0.5 * x


def _quarter(x):
    return _HALVED(_HALVED(x))


def _apart(x):
    return x + 1.0


def test_link_fills_only_what_the_roots_may_call(monkeypatch):
    """``link(*roots)`` compiles the linked kernels of the modules ``roots`` and of those
    their namespaces reach, not every kernel a program has loaded (the engine's first fit
    does not compile the two-view closed forms)."""
    import sys
    import types

    from kanagen.common.link import reach

    global _HALVED
    names = ("kg_test_callee", "kg_test_caller", "kg_test_apart")
    stubs = {}
    try:
        for name, function in zip(names, (_halved, _quarter, _apart), strict=True):
            monkeypatch.setattr(function, "__module__", name)
            stubs[name] = linked("f -> f")(function)
            sys.modules[name] = types.ModuleType(name)
        _HALVED = stubs[names[0]]
        vars(sys.modules[names[0]]).update(halved=stubs[names[0]])
        vars(sys.modules[names[1]]).update(halved=stubs[names[0]], quarter=stubs[names[1]])
        vars(sys.modules[names[2]]).update(apart=stubs[names[2]])
        assert reach((names[1],)) >= {names[0], names[1]}
        assert names[2] not in reach((names[1],))
        link(names[1])
        state = {e.module: e.signature is not None for e in _LINKED if e.module in names}
        assert state == {names[0]: True, names[1]: True, names[2]: False}
        assert stubs[names[1]](8.0) == 2.0
        assert stubs[names[2]](1.0) == 2.0  # called from Python: linked then
    finally:
        _LINKED[:] = [e for e in _LINKED if e.module not in names]
        for name in names:
            sys.modules.pop(name, None)


def test_a_fit_does_not_compile_the_vision_kernels_a_program_loaded():
    import json
    import subprocess
    import sys

    code = ("import numpy as np, kanagen\n"
            "import kanagen.runtime.two_view_kernels\n"  # loaded (kanagen.scenes loads it)
            "from kanagen.common.link import _LINKED\n"
            "fam = kanagen.load('line')\n"
            "xy = np.array([[0.0, 1.0], [1.0, 2.9], [2.0, 5.1], [3.0, 7.0]])\n"
            "assert kanagen.fit(fam, 'line', data={'point': xy}).success\n"
            "import json\n"
            "print(json.dumps(sorted({e.module for e in _LINKED if e.signature is None})))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, timeout=900)
    left = set(json.loads(out.stdout.strip().splitlines()[-1]))
    assert "kanagen.runtime.two_view_kernels" in left
    assert left <= {"kanagen.runtime.two_view_kernels", "kanagen.runtime.numpy_rules"}


def test_the_closed_forms_called_first_from_python_in_a_fresh_process():
    """A kernel called from Python links what it calls, whatever ran before it: the public
    closed forms first thing in a process whose cache holds them (epipoles calls the linked
    SVD: it used to be an ordinary kernel, whose cached code found the SVD's cell empty)."""
    import subprocess
    import sys

    code = ("import numpy as np\n"
            "from kanagen.runtime import geometry\n"
            "F = np.array([[0, -1e-3, 0.1], [1e-3, 0, -0.2], [-0.1, 0.2, 1.0]])\n"
            "geometry.epipoles(F)\n"
            "X = np.random.default_rng(0).uniform(0, 500, (8, 4))\n"
            "geometry.fundamental_8point(X[:, :2], X[:, 2:])\n"
            "geometry.homography_dlt(X[:, :2], X[:, 2:])\n"
            "print('ok')\n")
    for _ in range(2):  # the second run loads every kernel from the cache
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                             timeout=900)
        assert out.returncode == 0 and out.stdout.strip().endswith("ok"), out.stderr[-2000:]
