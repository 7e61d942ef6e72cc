"""Code generation: a description of WHAT to generate (derivatives, CSE, reductions), and
backends (NumPy, CasADi) that render it through jinja2 templates."""

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
