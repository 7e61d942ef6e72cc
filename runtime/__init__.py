"""The estimation runtime: square roots (§3.3), the block projector (appendix A), the
iteration (eq. 18), coherence (eq. 22–24), the minimal solve (eq. 21) and the results.

Submodules are imported on first use (``kanagen.runtime.scoring`` after ``import kanagen``).
"""

from ..common.lazy import lazy as _lazy

__getattr__ = _lazy(__name__)[0]
