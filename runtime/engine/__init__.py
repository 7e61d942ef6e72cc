"""The estimator's compiled kernels (numba, :mod:`kanagen.common.jit`): one source for every
backend. :mod:`.rows` binds a family's generated row forms, :mod:`.data` lays a problem out
for the kernels, :mod:`.measures` and :mod:`.linear` hold the per-measure algebra and the
projector (report appendix A)."""

from . import iterate as _iterate  # noqa: E402,F401 - every kernel defined before any is linked
