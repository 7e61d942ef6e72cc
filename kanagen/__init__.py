"""kanagen — robust, non-linear, multi-model parameter estimation by symbolic code generation.

An implementation of the estimation method of INRIA report RR-4050, "Implementing a variant of
the Kanatani's estimation method" (Viéville, Lingrand, Gaspard, 2000).

Examples
--------
>>> import numpy as np, kanagen
>>> fam = kanagen.load("line")
>>> xy = np.array([[0.0, 1.0], [1.0, 2.9], [2.0, 5.1], [3.0, 7.0]])
>>> res = kanagen.fit(fam, "line", data={"point": xy})
>>> res.success
True
"""

from pathlib import Path as _Path
from typing import TYPE_CHECKING as _TYPE_CHECKING

# In a source checkout the subpackages sit beside this folder (modelspec/, codegen/, runtime/,
# generated/); an installed kanagen has them inside it. Make the checkout importable as is.
_here = _Path(__file__).resolve().parent
if not (_here / "runtime").is_dir() and (_here.parent / "runtime" / "__init__.py").is_file():
    __path__.append(str(_here.parent))  # noqa: F821 - the package's own __path__

from .common.lazy import lazy as _lazy  # noqa: E402 - after the path is set

__version__ = "0.1.0"

# The public names are imported on first use (PEP 562): ``import kanagen`` costs little more
# than the interpreter, and a fit of a shipped family imports neither the spec reader (SymPy,
# PyYAML) nor the generator (jinja2) (tests/test_imports.py, benchmarks/import_time.py).
if _TYPE_CHECKING:  # the same names, for type checkers and editors
    from .batching import BatchSummary, batch
    from .fitjob import FitOptions
    from .loader import load, load_text
    from .modelspec import SpecError, family_from_data
    from .resultsdb import read_results
    from .runtime.coherence import coherence, minimal_sample_size, minimal_solve
    from .runtime.estimator import Estimator
    from .runtime.family import AssumedConstantsWarning, ModelFamily
    from .runtime.fit import fit
    from .runtime.results import DerivedValue, FitResult, ModelState
    from .runtime.robust import RobustEstimate, robust_fit
    from .runtime.structures import find_structures

#: public name -> the module defining it
_LAZY = {
    "BatchSummary": ".batching",
    "batch": ".batching",
    "FitOptions": ".fitjob",
    "load": ".loader",
    "load_text": ".loader",
    "SpecError": ".modelspec.errors",
    "family_from_data": ".modelspec.parse",
    "read_results": ".resultsdb",
    "coherence": ".runtime.coherence",
    "minimal_sample_size": ".runtime.coherence",
    "minimal_solve": ".runtime.coherence",
    "Estimator": ".runtime.estimator",
    "ModelState": ".runtime.results",
    "ModelFamily": ".runtime.family",
    "AssumedConstantsWarning": ".runtime.family",
    "fit": ".runtime.fit",
    "DerivedValue": ".runtime.results",
    "FitResult": ".runtime.results",
    "RobustEstimate": ".runtime.robust",
    "robust_fit": ".runtime.robust",
    "find_structures": ".runtime.structures",
}

#: the submodules that ``import kanagen`` made attributes before its names became lazy
_SUBMODULES = frozenset({"batching", "codegen", "dataio", "fitjob", "loader", "modelspec",
                         "resultsdb", "runtime"})

__all__ = [
    "AssumedConstantsWarning",
    "BatchSummary",
    "DerivedValue",
    "Estimator",
    "FitOptions",
    "ModelState",
    "FitResult",
    "ModelFamily",
    "SpecError",
    "__version__",
    "batch",
    "coherence",
    "family_from_data",
    "find_structures",
    "fit",
    "load",
    "load_text",
    "minimal_sample_size",
    "minimal_solve",
    "read_results",
    "robust_fit",
    "RobustEstimate",
]


# a public name (or one of _SUBMODULES), imported on first use (PEP 562)
__getattr__, __dir__ = _lazy(__name__, _LAZY, _SUBMODULES)
