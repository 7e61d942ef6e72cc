"""What importing kanagen and fitting a shipped family import (issue 17): properties, not
timings (``python benchmarks/import_time.py`` measures the time).

A shipped family loaded by name is its committed generated module: no spec reader (SymPy,
PyYAML), no generator (jinja2), and CasADi only for the backends that ask for it.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

import kanagen

ROOT = Path(__file__).resolve().parents[1]

#: what a fit of a shipped family must not import
SPEC_AND_GENERATOR = ("sympy", "jinja2", "yaml")
#: what ``import kanagen`` must not import: those, the optional or heavy dependencies, and
#: SciPy (the estimator imports it on first use)
HEAVY = SPEC_AND_GENERATOR + ("casadi", "matplotlib", "dask", "distributed", "pandas", "click",
                              "scipy")


def imported_after(code: str, watched: tuple[str, ...], env: dict | None = None) -> list[str]:
    """The modules of ``watched`` in ``sys.modules`` after running ``code`` in a fresh
    interpreter (``env``: environment variables set besides this process's)."""
    probe = (f"{code}\nimport json, sys\n"
             f"print(json.dumps([m for m in {list(watched)!r} if m in sys.modules]))")
    done = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, capture_output=True,
                          text=True, env=dict(os.environ, **(env or {})), timeout=300)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_import_kanagen_is_light():
    assert imported_after("import kanagen", HEAVY) == []


@pytest.mark.parametrize("backend", ["numpy", "casadi"])
def test_fit_of_a_shipped_family_reads_no_spec(backend):
    code = ("import numpy as np, kanagen\n"
            f"fam = kanagen.load('conic', backend={backend!r})\n"
            "res = kanagen.fit(fam, 'conic', data={'point': np.random.default_rng(0)"
            ".random((10, 2))})\n"
            "assert res.params")
    loaded = imported_after(code, SPEC_AND_GENERATOR + ("casadi",))
    assert loaded == ([] if backend == "numpy" else ["casadi"])


def test_a_robust_search_and_its_nfa_import_no_scipy_stats():
    """scipy.stats costs half a second of a process's first search: the NFA of a robust
    result (runtime/significance.py) takes the binomial tail from scipy.special."""
    code = ("import numpy as np, kanagen\n"
            "xy = np.random.default_rng(0).uniform(-9, 9, (60, 2))\n"
            "r = kanagen.robust_fit(kanagen.load('line'), 'line', data={'point': xy})\n"
            "assert r.false_alarms > 0 and 'NOT' in r.summary()")
    assert imported_after(code, ("scipy.stats",) + SPEC_AND_GENERATOR) == []


def test_a_compiled_fit_from_its_cache_loads_no_generator():
    """Once a family is compiled (its library cached), loading and fitting it with the
    compiled backend imports neither SymPy nor jinja2: the cache key is computed by the
    light kanagen.codegen.version, not by the generator."""
    from kanagen.codegen.compile import CompileError

    try:
        kanagen.load("conic", backend="compiled")  # compiled into the cache, if needed
    except CompileError as exc:  # pragma: no cover - a machine without a C compiler
        pytest.skip(f"no compiled backend here: {exc}")
    code = ("import numpy as np, kanagen\n"
            "fam = kanagen.load('conic', backend='compiled')\n"
            "assert fam.backend == 'compiled'\n"
            "res = kanagen.fit(fam, 'conic', data={'point': np.random.default_rng(0)"
            ".random((10, 2))})\n"
            "assert res.params")
    assert imported_after(code, SPEC_AND_GENERATOR) == []


def test_the_spec_reader_imports_nothing_of_the_runtime():
    """modelspec is the lowest layer: reading a spec (even one naming initialisers) imports
    neither the runtime nor the generator."""
    code = ("from kanagen.modelspec import load_spec\n"
            "fam = load_spec('examples/two_view.yaml')\n"
            "import sys\n"
            "assert not [m for m in sys.modules if m.startswith(('kanagen.runtime', "
            "'kanagen.codegen'))], sorted(sys.modules)")
    assert imported_after(code, ("jinja2",)) == []


def test_loading_a_spec_still_reads_it(tmp_path):
    # a spec file goes through the full pipeline: its reader and (not current) the generator
    spec = (ROOT / "examples" / "line.yaml").read_text(encoding="utf-8")
    path = tmp_path / "myline.yaml"
    path.write_text(spec.replace("name: line", "name: myline"), encoding="utf-8")
    code = f"import kanagen\nfam = kanagen.load({str(path)!r})\nassert fam.name == 'myline'"
    env = {"KANAGEN_CACHE": str(tmp_path / "cache")}
    assert imported_after(code, SPEC_AND_GENERATOR, env) == list(SPEC_AND_GENERATOR)


def test_a_spec_read_and_built_once_is_not_read_again(tmp_path):
    """The next process that loads the same text (the same limits, registry of initialisers,
    spec reader and generator) imports the modules built from it: neither the reader nor the
    generator; the casadi module only once it is built. An edited text, or tighter limits,
    are read again."""
    spec = (ROOT / "examples" / "line.yaml").read_text(encoding="utf-8")
    path = tmp_path / "myline.yaml"
    path.write_text(spec.replace("name: line", "name: myline"), encoding="utf-8")
    env = {"KANAGEN_CACHE": str(tmp_path / "cache")}

    def load(options: str = "") -> list[str]:
        code = (f"import kanagen\nfam = kanagen.load({str(path)!r}{options})\n"
                "assert fam.name == 'myline' and fam.module.__name__.startswith("
                "'kanagen_cache_myline_'), fam.module.__name__")
        return imported_after(code, SPEC_AND_GENERATOR, env)

    assert load(", backend='numpy'") == list(SPEC_AND_GENERATOR)
    assert load(", backend='numpy'") == []
    assert load(", backend='casadi'") == list(SPEC_AND_GENERATOR)  # its module not built yet
    assert load(", backend='casadi'") == []
    assert load(", backend='numpy', limits=kanagen.modelspec.Limits(max_depth=63)") == \
        list(SPEC_AND_GENERATOR)
    path.write_text(path.read_text(encoding="utf-8") + "\n# edited\n", encoding="utf-8")
    assert load(", backend='numpy'") == list(SPEC_AND_GENERATOR)


def test_a_spec_refused_once_is_refused_again(tmp_path, monkeypatch):
    """Only a text that was read is remembered: a refused one is read (and refused, naming
    its file) at every load; the key of a text changes with the limits, the registry and
    the reader."""
    from kanagen import loader
    from kanagen.modelspec import Limits, SpecError

    monkeypatch.setenv("KANAGEN_CACHE", str(tmp_path / "cache"))
    path = tmp_path / "bad.yaml"
    path.write_text("name: bad\nparameter: {a: 1.0}\nchannels:\n  pts:\n"
                    "    components: [x, y]\n    equations: [y - a*x - zz]\n"
                    "models:\n  m: {}\n", encoding="utf-8")
    for _ in range(2):
        with pytest.raises(SpecError, match="bad.yaml"):
            kanagen.load(path, backend="numpy")
    assert not (tmp_path / "cache" / "texts").exists()
    key = loader._text_key("0" * 64, Limits())
    assert loader._text_key("0" * 64, Limits(max_depth=63)) != key
    monkeypatch.setattr(loader, "_reader_fingerprint", lambda: "another reader")
    assert loader._text_key("0" * 64, Limits()) != key


def test_a_shipped_example_loaded_by_its_path_reads_no_spec(tmp_path):
    """The text a committed module was generated from is that module (``kanagen fit
    examples/...``): no spec reader, the committed modules — a copy of the file elsewhere
    too; not under limits tighter than the default's (the reader checks those)."""
    copy = tmp_path / "copy.yaml"
    copy.write_bytes((ROOT / "examples" / "conic_lattice.yaml").read_bytes())
    for path in ("examples/conic_lattice.yaml", str(copy)):
        code = (f"import kanagen\nfam = kanagen.load({path!r}, backend='casadi')\n"
                "assert fam.module.__name__ == 'kanagen.generated.conic_lattice', "
                "fam.module.__name__")
        assert imported_after(code, SPEC_AND_GENERATOR) == []
    code = ("import kanagen\nfrom kanagen.modelspec import Limits\n"
            "fam = kanagen.load('examples/conic_lattice.yaml', limits=Limits(max_depth=63))\n"
            "assert fam.module.__name__ == 'kanagen.generated.conic_lattice'")
    assert "sympy" in imported_after(code, SPEC_AND_GENERATOR)


def test_a_spec_within_a_tighter_limit_is_still_refused():
    from kanagen.modelspec import Limits, SpecError

    with pytest.raises(SpecError, match="max_nodes"):
        kanagen.load(ROOT / "examples" / "conic_lattice.yaml", limits=Limits(max_nodes=5))


def test_public_names_resolve():
    for name in kanagen.__all__:
        assert getattr(kanagen, name) is not None, name
    assert set(kanagen.__all__) <= set(dir(kanagen))
    namespace: dict = {}
    exec("from kanagen import *", namespace)
    assert set(kanagen.__all__) <= set(namespace)
    assert kanagen.fit is kanagen.runtime.fit.fit
    assert kanagen.SpecError is kanagen.modelspec.SpecError
    assert kanagen.codegen.build.__module__ == "kanagen.codegen.generate"  # the function
    with pytest.raises(AttributeError):
        kanagen.no_such_name  # noqa: B018
    with pytest.raises(AttributeError):
        kanagen.runtime.no_such_module  # noqa: B018


#: the two-view code, a plugin of the initializer registry (issue 17, "Vision as a plugin"):
#: the registered closed forms first, with their compiled kernels
VISION = ("kanagen.runtime.two_view_starts", "kanagen.runtime.two_view_twins",
          "kanagen.runtime.two_view_kernels", "kanagen.runtime.numpy_rules",
          "kanagen.runtime.geometry", "kanagen.scenes", "kanagen.datasets",
          "kanagen.runtime.calibrated_starts")
#: what looking up a two-view closed form imports: the registered functions and their kernels
TWO_VIEW = list(VISION[:4])

LATTICE_SEARCH = """\
import numpy as np, kanagen
fam = kanagen.load('conic_lattice', backend={backend!r})
assert fam.backend == {backend!r}
rng = np.random.default_rng(0)
t = rng.uniform(0.0, 3.0, 60)
xy = np.c_[5 * np.cos(t), 3 * np.sin(t)] + rng.normal(0.0, 0.02, (60, 2))
xy[::6] = rng.uniform(-6, 6, (10, 2))
est = kanagen.Estimator(fam, scale=4.0, seed=0)
est.add_measures('point', xy, info=1.0)
assert est.run(max_samples=400) is not None
res = kanagen.robust_fit(fam, 'conic', {{'point': xy}}, {{'point': 1.0}}, scale=4.0, seed=1)
"""


@pytest.mark.parametrize("backend", ["numpy", "compiled"])
def test_a_family_naming_no_two_view_initializer_loads_no_vision_code(backend):
    """A search and a robust fit of the conic lattice (its models name no initializer)
    import neither the two-view closed forms nor the epipolar geometry, on the compiled
    backend either (its library has no twins: their fingerprints are not checked)."""
    if backend == "compiled":
        from kanagen.codegen.compile import CompileError, compiler

        try:
            compiler()
        except CompileError as exc:
            pytest.skip(f"no compiled backend here: {exc}")
    assert imported_after(LATTICE_SEARCH.format(backend=backend), VISION) == []


def test_the_registry_names_its_initializers_without_importing_them():
    code = ("from kanagen.runtime.initializers import INITIALIZERS, resolve\n"
            "names = sorted(INITIALIZERS)\n"
            "assert names == ['calibrated_five_point', 'calibrated_homography', "
            "'calibrated_in_front', "
            "'calibrated_retinal_displacement', 'calibrated_retinal_translation', "
            "'calibrated_rotation', 'calibrated_translation', "
            "'two_view_fundamental', 'two_view_homography', "
            "'two_view_retinal_displacement', 'two_view_retinal_translation', "
            "'two_view_rotation', 'two_view_translation', 'two_view_zoom'], names\n"
            "assert 'two_view_rotation' in INITIALIZERS and len(INITIALIZERS) == 14\n"
            "assert INITIALIZERS.get('nope') is None\n"
            "try:\n"
            "    resolve('nope')\n"
            "except ValueError as exc:\n"
            "    assert 'known: calibrated_five_point, calibrated_homography' in str(exc)\n")
    assert imported_after(code, VISION) == []
    # a lookup imports the provider, which registers all four
    looked_up = code + ("import sys\n"
                        "from kanagen.runtime import two_view_starts\n"
                        "assert INITIALIZERS['two_view_homography'].equivalent\n"
                        "assert resolve('two_view_rotation') is two_view_starts"
                        ".two_view_rotation\n")
    assert imported_after(looked_up, VISION) == TWO_VIEW


def test_reading_a_spec_imports_the_closed_forms_it_names_only():
    """The spec reader checks an ``initializer:`` against the registry: a spec naming none
    (or an unknown one: the error lists every name) imports no two-view code; the two-view
    spec imports the closed forms it names (their needs are checked)."""
    read = ("from kanagen.modelspec.parse import parse_spec\n"
            "from kanagen.runtime.initializers import INITIALIZERS\n"
            "text = open('examples/{}.yaml', encoding='utf-8').read()\n")
    assert imported_after(read.format("conic_lattice") + "parse_spec(text)", VISION) == []
    unknown = read.format("conic") + (
        "from kanagen.modelspec import SpecError\n"
        "text = text.replace('  conic:\\n', '  conic:\\n    initializer: nope\\n', 1)\n"
        "try:\n"
        "    parse_spec(text, initializers=INITIALIZERS)\n"
        "    raise AssertionError('accepted')\n"
        "except SpecError as exc:\n"
        "    assert \"unknown initializer 'nope' (known: calibrated_five_point, "
        "calibrated_homography, calibrated_retinal_displacement, "
        "calibrated_retinal_translation, calibrated_rotation, calibrated_translation, "
        "two_view_fundamental, two_view_homography, two_view_retinal_displacement, "
        "two_view_retinal_translation, two_view_rotation, two_view_translation, "
        "two_view_zoom)\" in "
        "str(exc), exc\n")
    assert imported_after(unknown, VISION) == []
    assert imported_after(read.format("two_view") + "parse_spec(text, initializers="
                          "INITIALIZERS)", VISION) == TWO_VIEW
    assert imported_after(read.format("two_view_calibrated") + "parse_spec(text, "
                          "initializers=INITIALIZERS)", VISION) == \
        ["kanagen.runtime.two_view_kernels", "kanagen.runtime.numpy_rules",
         "kanagen.runtime.geometry", "kanagen.runtime.calibrated_starts"]


def test_a_plugin_registers_its_initializers(monkeypatch, tmp_path):
    """A module listed in PROVIDERS is imported on the first lookup of its name and must
    register it; :func:`register` refuses another function under a taken name."""
    from kanagen.runtime import initializers as reg

    def mine(rows, constants):
        return [{"a": 1.0}]

    entry = reg.Initializer("my_start", mine, ("a",), (), 2, "a test start")
    monkeypatch.setattr(reg, "_REGISTERED", dict(reg._REGISTERED))
    monkeypatch.setattr(reg, "PROVIDERS", {**reg.PROVIDERS, "lazy_start": "my_kanagen_plugin"})
    assert "lazy_start" in reg.INITIALIZERS and "my_start" not in reg.INITIALIZERS
    assert reg.register(entry) is entry and reg.register(entry) is entry
    assert reg.resolve("my_start") is mine and "my_start" in sorted(reg.INITIALIZERS)
    with pytest.raises(ValueError, match="registered already"):
        reg.register(reg.Initializer("my_start", lambda r, k: [], ("a",), (), 2, "another"))
    (tmp_path / "my_kanagen_plugin.py").write_text(
        "from kanagen.runtime.initializers import Initializer, register\n"
        "register(Initializer('lazy_start', lambda rows, k: [{'b': 2.0}], ('b',), (), 2, "
        "'lazy'))\n", encoding="utf-8")
    monkeypatch.syspath_prepend(str(tmp_path))
    try:
        assert reg.INITIALIZERS["lazy_start"].fn(None, {}) == [{"b": 2.0}]
        # a provider that does not register what it is listed for is an error (not a
        # KeyError, which would read as an unknown name)
        monkeypatch.setitem(reg.PROVIDERS, "ghost_start", "my_kanagen_plugin")
        with pytest.raises(LookupError, match="does not register"):
            reg.INITIALIZERS.get("ghost_start")
    finally:
        sys.modules.pop("my_kanagen_plugin", None)


def test_the_runtime_imports_nothing_of_the_spec_reader_or_the_generator():
    """Layers (modelspec -> codegen -> generated <- runtime <- API): a module of the runtime
    imports neither ``modelspec`` nor ``codegen``, at its top or inside a function; what
    the layers share (``lazy``, ``slack_value``) is the lowest package, ``kanagen.common``."""
    import ast

    offending = []
    for path in sorted((ROOT / "runtime").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom):
                names = [("." * node.level) + (node.module or "")]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            else:
                continue
            for name in names:
                parts = name.lstrip(".").split(".")
                if {"modelspec", "codegen"} & set(parts[:2]) and \
                        (name.startswith("..") or parts[0] == "kanagen"):
                    offending.append(f"{path.name}:{node.lineno} {name}")
    assert offending == []
