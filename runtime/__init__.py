"""The estimation runtime: square roots (§3.3), the block projector (appendix A), the
iteration (eq. 18), coherence (eq. 22–24), the minimal solve (eq. 21) and the results.

Submodules are imported on first use (``kanagen.runtime.scoring`` after ``import kanagen``).
"""

import importlib
import importlib.util


def __getattr__(name: str):
    """A submodule, imported on first attribute access (PEP 562)."""
    if not name.startswith("_") and importlib.util.find_spec(f"{__name__}.{name}") is not None:
        return importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
