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

# In a source checkout the subpackages sit beside this folder (modelspec/, codegen/, runtime/,
# generated/); an installed kanagen has them inside it. Make the checkout importable as is.
_here = _Path(__file__).resolve().parent
if not (_here / "runtime").is_dir() and (_here.parent / "runtime" / "__init__.py").is_file():
    __path__.append(str(_here.parent))  # noqa: F821 - the package's own __path__

from .batching import BatchSummary, batch  # noqa: E402
from .fitjob import FitOptions  # noqa: E402
from .loader import load, load_text  # noqa: E402
from .modelspec import SpecError, family_from_data  # noqa: E402
from .resultsdb import read_results  # noqa: E402
from .runtime.coherence import coherence, minimal_sample_size, minimal_solve  # noqa: E402
from .runtime.estimator import Estimator, ModelState  # noqa: E402
from .runtime.family import ModelFamily  # noqa: E402
from .runtime.fit import fit  # noqa: E402
from .runtime.results import DerivedValue, FitResult  # noqa: E402
from .runtime.robust import RobustEstimate, robust_fit  # noqa: E402
from .runtime.structures import find_structures  # noqa: E402

__version__ = "0.1.0"

__all__ = [
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
