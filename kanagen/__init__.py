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

from .loader import load, load_text
from .modelspec import SpecError, family_from_data
from .runtime.coherence import coherence, minimal_sample_size, minimal_solve
from .runtime.family import ModelFamily
from .runtime.fit import fit
from .runtime.results import DerivedValue, FitResult

__version__ = "0.1.0"

__all__ = [
    "DerivedValue",
    "FitResult",
    "ModelFamily",
    "SpecError",
    "__version__",
    "coherence",
    "family_from_data",
    "fit",
    "load",
    "load_text",
    "minimal_sample_size",
    "minimal_solve",
]
