"""Where a family's functions come from: the backends behind :class:`ModelFamily`.

Every backend offers the same callables on NumPy arrays, so the runtime never knows which one
it runs on:

* ``c0(model)(q, k) -> (c0 (p,), C0 (p, n))``;
* ``measure(model, channel)(q, X, k) -> (c (M, p), C (M, p, n), D (M, p, k))``;
* ``derived(q, k) -> {name: (value, jacobian)}`` and ``slack_measures(q, k) -> (s,)``, or None;

``reduced=True`` gives the model's functions in its free components ``r`` (linear
constraints eliminated at build time, :mod:`kanagen.codegen.eliminate`).

:class:`NumpyFunctions` reads the generated NumPy module. :class:`CasadiFunctions` wraps
CasADi ``Function``s — from the generated CasADi module, or compiled and loaded with
``casadi.external`` (:mod:`kanagen.codegen.compile`) — mapping the per-measure functions
over the measures of a channel with ``Function.map``.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Mapping
from types import ModuleType

import numpy as np


class NumpyFunctions:
    """The functions of the generated NumPy module (the reference backend)."""

    name = "numpy"

    def __init__(self, module: ModuleType):
        self.module = module
        self.derived: Callable | None = module.DERIVED
        self.slack_measures: Callable | None = module.SLACK_MEASURES

    def _entry(self, model: str, reduced: bool) -> Mapping:
        entry = self.module.MODELS[model]
        return entry["reduced"] if reduced else entry

    def c0(self, model: str, reduced: bool = False) -> Callable:
        return self._entry(model, reduced)["c0"]

    def measure(self, model: str, channel: str, reduced: bool = False) -> Callable:
        return self._entry(model, reduced)["channels"][channel]


#: Mapped CasADi functions kept per (function, number of measures).
_MAPPED_CACHE = 64


class CasadiFunctions:
    """CasADi ``Function``s behind the NumPy-array interface of :class:`NumpyFunctions`.

    Parameters
    ----------
    module : module
        The generated CasADi module (``MODELS``, ``DERIVED``, ``SLACK_MEASURES``).
    derived_shapes : dict
        ``{name: shape}`` of the derived quantities (CasADi outputs are 2-D).
    replace : dict, optional
        Functions by name that replace the module's, e.g. compiled ones from
        ``casadi.external``; same names, inputs and outputs.
    name : str
        Backend name reported by :attr:`ModelFamily.backend`.
    """

    def __init__(self, module: ModuleType, derived_shapes: Mapping[str, tuple[int, ...]],
                 replace: Mapping | None = None, name: str = "casadi"):
        self.name = name
        self.module = module
        self._replace = dict(replace or {})
        self._mapped: OrderedDict = OrderedDict()
        self._shapes = {k: tuple(v) for k, v in derived_shapes.items()}
        self.derived = self._derived if module.DERIVED is not None else None
        self.slack_measures = self._slack if module.SLACK_MEASURES is not None else None

    def function(self, f):
        """The function to call for the module's function ``f`` (compiled when replaced)."""
        return self._replace.get(f.name(), f)

    def _entry(self, model: str, reduced: bool) -> Mapping:
        entry = self.module.MODELS[model]
        return entry["reduced"] if reduced else entry

    def c0(self, model: str, reduced: bool = False) -> Callable:
        f = self.function(self._entry(model, reduced)["c0"])

        def c0(q, k):
            c, C = f(q, k)
            return c.full().ravel(), C.full()

        return c0

    def measure(self, model: str, channel: str, reduced: bool = False) -> Callable:
        f = self.function(self._entry(model, reduced)["channels"][channel])
        p, n, k = f.size1_out(0), f.size2_out(1), f.size2_out(2)

        def measure(q, X, consts):
            M = X.shape[0]
            if M == 0:
                return np.zeros((0, p)), np.zeros((0, p, n)), np.zeros((0, p, k))
            c, C, D = self._map(f, M)(q, X.T, consts)
            return (c.full().T, C.full().reshape(p, M, n).transpose(1, 0, 2),
                    D.full().reshape(p, M, k).transpose(1, 0, 2))

        return measure

    def _map(self, f, M: int):
        """``f`` over M measures: ``q`` and ``k`` shared, measures side by side."""
        key = (f.name(), M)
        mapped = self._mapped.get(key)
        if mapped is None:
            mapped = f.map(f"{f.name()}_map{M}", "serial", M, [0, 2], [])
            self._mapped[key] = mapped
            if len(self._mapped) > _MAPPED_CACHE:
                self._mapped.popitem(last=False)
        else:
            self._mapped.move_to_end(key)
        return mapped

    def _derived(self, q, k) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        outs = self.function(self.module.DERIVED)(q, k)
        n = np.size(q)
        return {name: (outs[2 * i].full().reshape(shape),
                       outs[2 * i + 1].full().reshape(shape + (n,)))
                for i, (name, shape) in enumerate(self._shapes.items())}

    def _slack(self, q, k) -> np.ndarray:
        return self.function(self.module.SLACK_MEASURES)(q, k).full().ravel()
