"""Code generation: a description of WHAT to generate (derivatives, CSE, reductions), and
backends (NumPy, CasADi) that render it through jinja2 templates.

Importing this package imports SymPy and jinja2: the runtime never does (it imports
:mod:`kanagen.codegen.compile` only for the "compiled" backend).
"""

from ..modelspec.lazy import lazy as _lazy
from .backend import Backend
from .build import BACKENDS, build, check, committed_backends, generator_fingerprint, render_spec
from .describe import FORMAT, Description, describe
from .printer import CASADI_FUNCTIONS, NUMPY_FUNCTIONS, CasadiPrinter, CodegenError, NumpyPrinter

__all__ = [
    "BACKENDS",
    "CASADI_FUNCTIONS",
    "FORMAT",
    "NUMPY_FUNCTIONS",
    "Backend",
    "CasadiPrinter",
    "CodegenError",
    "Description",
    "NumpyPrinter",
    "build",
    "check",
    "committed_backends",
    "describe",
    "generator_fingerprint",
    "render_spec",
]


# a submodule not imported yet (``kanagen.codegen.compile``), on first access (PEP 562)
__getattr__ = _lazy(__name__)[0]
