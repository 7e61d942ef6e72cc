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


def imported_after(code: str, watched: tuple[str, ...]) -> list[str]:
    """The modules of ``watched`` in ``sys.modules`` after running ``code`` in a fresh
    interpreter."""
    probe = (f"{code}\nimport json, sys\n"
             f"print(json.dumps([m for m in {list(watched)!r} if m in sys.modules]))")
    done = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, capture_output=True,
                          text=True, env=dict(os.environ), timeout=300)
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


def test_loading_a_spec_still_reads_it(tmp_path):
    # a spec file goes through the full pipeline: its reader and (not current) the generator
    spec = (ROOT / "examples" / "line.yaml").read_text(encoding="utf-8")
    path = tmp_path / "myline.yaml"
    path.write_text(spec.replace("name: line", "name: myline"), encoding="utf-8")
    code = f"import kanagen\nfam = kanagen.load({str(path)!r})\nassert fam.name == 'myline'"
    assert imported_after(code, SPEC_AND_GENERATOR) == list(SPEC_AND_GENERATOR)


def test_public_names_resolve():
    for name in kanagen.__all__:
        assert getattr(kanagen, name) is not None, name
    assert set(kanagen.__all__) <= set(dir(kanagen))
    namespace: dict = {}
    exec("from kanagen import *", namespace)
    assert set(kanagen.__all__) <= set(namespace)
    assert kanagen.fit is kanagen.runtime.fit.fit
    assert kanagen.SpecError is kanagen.modelspec.SpecError
    assert kanagen.codegen.build.__module__ == "kanagen.codegen.build"  # the function
    with pytest.raises(AttributeError):
        kanagen.no_such_name  # noqa: B018
    with pytest.raises(AttributeError):
        kanagen.runtime.no_such_module  # noqa: B018
