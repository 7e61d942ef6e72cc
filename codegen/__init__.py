"""Code generation: a description of WHAT to generate (derivatives, CSE, reductions), and
backends (NumPy, CasADi) that render it through jinja2 templates.

Generating imports SymPy and jinja2; importing this package does not (its names load on
first use), so the run time may use :mod:`kanagen.codegen.version` (cache keys) and
:mod:`kanagen.codegen.compile` (the "compiled" backend) without them.
"""

from ..common.lazy import lazy as _lazy

_NAMES = {
    "BACKENDS": ".generate", "build": ".generate", "check": ".generate",
    "committed_backends": ".generate", "render_spec": ".generate",
    "generator_fingerprint": ".version", "FORMAT": ".version",
    "Backend": ".backend", "Description": ".description", "describe": ".description",
    "CASADI_FUNCTIONS": ".printer", "NUMPY_FUNCTIONS": ".printer",
    "CasadiPrinter": ".printer", "CodegenError": ".printer", "NumpyPrinter": ".printer",
}

__all__ = sorted(_NAMES)

# each name (and a submodule such as ``kanagen.codegen.compile``) on first access (PEP 562)
__getattr__, __dir__ = _lazy(__name__, _NAMES)
