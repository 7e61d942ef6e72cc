"""Code generation: derivatives, CSE and unrolled per-measure algebra, rendered by jinja2."""

from .build import build, check, generator_fingerprint, render_spec
from .describe import FORMAT, describe
from .numpy_backend import render
from .printer import NUMPY_FUNCTIONS, CodegenError, NumpyPrinter

__all__ = [
    "FORMAT",
    "NUMPY_FUNCTIONS",
    "CodegenError",
    "NumpyPrinter",
    "build",
    "check",
    "describe",
    "generator_fingerprint",
    "render",
    "render_spec",
]
