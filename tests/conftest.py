"""Shared fixtures: the repository root on sys.path (for ``benchmarks``), the shared data."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

# The estimator's algebra is on small matrices, where BLAS threads only add overhead (five
# times slower on a loaded two-core machine); set before NumPy loads its BLAS.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
# The product's default backend is "compiled" (kanagen.load): one C compile per spec, a few
# seconds each. The suite's many small specs run on the NumPy backend unless the variable is
# set already (KANAGEN_BACKEND=compiled pytest ...); tests/test_default_backend.py checks the
# default itself (the estimator's kernels are numba's on every backend).
os.environ.setdefault("KANAGEN_BACKEND", "numpy")

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


def shared_data() -> Path:
    """``$KANAGEN_DATA`` or ``../shared/data`` beside the repository."""
    return Path(os.environ.get("KANAGEN_DATA", ROOT.parent / "shared" / "data"))


@pytest.fixture
def data_dir() -> Path:
    path = shared_data()
    if not path.is_dir():
        pytest.skip(f"shared data not found at {path}")
    return path


@pytest.fixture(autouse=True)
def _isolated_cache(tmp_path_factory, monkeypatch):
    """Specs built at run time go to a per-session temporary cache."""
    monkeypatch.setenv("KANAGEN_CACHE", str(tmp_path_factory.getbasetemp() / "kanagen-cache"))


def pytest_sessionstart(session):
    """The estimator's kernels compiled (or loaded from numba's cache) once, before any test:
    a first compile takes minutes, and a test's subprocess must not be the one that pays it
    (nor print its notice)."""
    import numpy as np

    import kanagen

    fam = kanagen.load("conic")
    t = np.linspace(0.0, np.pi, 12)
    xy = np.c_[100 + 50 * np.cos(t), 80 + 30 * np.sin(t)]
    kanagen.fit(fam, "conic", data={"point": xy})
