"""The default backend (issue 17, fast by default): ``kanagen.load`` without ``backend`` runs
the compiled family where a C compiler works, says so while it compiles, and falls back to
the NumPy backend with one warning — the same estimates — where none does."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from scenarios import close

import kanagen
from kanagen.codegen.compile import CompileError, CompileWarning, compiler
from kanagen.loader import BACKEND_VARIABLE, default_backend

SPEC = """\
name: defaultline
parameter: {a: 1.0, b: 0.0}
channels:
  point:
    components: [x, y]
    equations: [y - a*x - b]
models:
  line:
    constraints: []
"""


def _compiler_works() -> bool:
    try:
        compiler()
    except CompileError:
        return False
    return True


def _points() -> dict:
    rng = np.random.default_rng(3)
    x = np.linspace(0.0, 10.0, 25)
    return {"point": np.c_[x, 0.5 * x + 2.0] + rng.normal(0.0, 0.1, (25, 2))}


def test_the_default_is_compiled_unless_the_variable_says(monkeypatch):
    monkeypatch.delenv(BACKEND_VARIABLE, raising=False)
    assert default_backend() == "compiled"
    monkeypatch.setenv(BACKEND_VARIABLE, "numpy")
    assert default_backend() == "numpy"
    monkeypatch.setenv(BACKEND_VARIABLE, "fortran")
    with pytest.raises(ValueError, match="KANAGEN_BACKEND='fortran' is not a backend"):
        default_backend()


@pytest.mark.skipif(not _compiler_works(), reason="no C compiler here")
def test_load_compiles_by_default_and_says_so_once(monkeypatch, capfd):
    monkeypatch.delenv(BACKEND_VARIABLE, raising=False)
    fam = kanagen.load_text(SPEC, "default.yaml")
    assert fam.backend == "compiled"
    err = capfd.readouterr().err
    assert "kanagen: compiling family 'defaultline'" in err and "compiled family" in err
    again = kanagen.load_text(SPEC, "default.yaml")  # from the cache: nothing said
    assert again.backend == "compiled" and capfd.readouterr().err == ""
    ref = kanagen.load_text(SPEC, "default.yaml", backend="numpy")
    a = kanagen.fit(fam, "line", data=_points(), info={"point": 100.0})
    b = kanagen.fit(ref, "line", data=_points(), info={"point": 100.0})
    assert a.success and b.success
    close(a.q, b.q, rtol=1e-10)
    close(a.covariance, b.covariance, rtol=1e-8)


def test_without_a_compiler_one_warning_and_the_numpy_backend(monkeypatch):
    monkeypatch.delenv(BACKEND_VARIABLE, raising=False)
    monkeypatch.setenv("CC", "/nonexistent/cc")
    spec = SPEC.replace("defaultline", "nocompiler")  # not in the cache
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        fam = kanagen.load_text(spec, "nocompiler.yaml")
    messages = [str(w.message) for w in caught if issubclass(w.category, CompileWarning)]
    assert len(messages) == 1
    assert "NumPy backend (the same estimates, slower)" in messages[0]
    assert "KANAGEN_BACKEND=numpy" in messages[0]
    assert fam.backend == "numpy"
    res = kanagen.fit(fam, "line", data=_points(), info={"point": 100.0})
    assert res.success
    # asked for by name, "compiled" keeps its documented fallback (CasADi)
    with pytest.warns(CompileWarning, match="uncompiled CasADi backend"):
        assert kanagen.load_text(spec, "nocompiler.yaml", backend="compiled").backend == "casadi"


def test_an_unwritable_cache_falls_back_with_a_warning(monkeypatch, tmp_path):
    """The cache folder cannot be made (a file stands in its way): the same warning and
    the NumPy backend, no traceback."""
    monkeypatch.delenv(BACKEND_VARIABLE, raising=False)
    blocker = tmp_path / "not-a-folder"
    blocker.write_text("")
    monkeypatch.setenv("KANAGEN_CACHE", str(blocker / "cache"))
    with pytest.warns(CompileWarning, match="KANAGEN_CACHE to a writable folder"):
        fam = kanagen.load("line")  # shipped: only the compiled library needs the cache
    assert fam.backend == "numpy"
    # a spec of one's own needs the cache for its generated module: a clear error
    with pytest.raises(OSError, match="KANAGEN_CACHE"):
        kanagen.load_text(SPEC.replace("defaultline", "nocache"), "nocache.yaml")
