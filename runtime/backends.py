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
over the measures of a channel with ``Function.map``. :class:`CompiledFunctions` is the
latter with the constraints and equations evaluated by the same compiled library through
its batch entry point (one ctypes call instead of a CasADi call from Python, ~50 µs).
"""

from __future__ import annotations

import ctypes
import threading
from collections import OrderedDict
from collections.abc import Callable, Mapping
from pathlib import Path
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


class CompiledFunctions(CasadiFunctions):
    """The compiled library's functions: ``casadi.external`` ones (``replace``), with
    ``c0`` and the measurement equations evaluated through the library's ``kg_eval`` (the
    same compiled code, one call per evaluation over all the measures).

    Parameters
    ----------
    module, derived_shapes, replace
        As :class:`CasadiFunctions`.
    library : path
        The compiled library (:func:`kanagen.codegen.compile.compile_family`).
    numpy_module : module
        The generated NumPy module: its ``FAMILY`` (model and channel order, sizes), and
        its derived quantities and slack measures, evaluated at one point (16 µs for the
        conic's six quantities, against 91 µs through a CasADi call and its conversions).
    """

    def __init__(self, module: ModuleType, derived_shapes: Mapping[str, tuple[int, ...]],
                 replace: Mapping, library: Path, numpy_module: ModuleType):
        super().__init__(module, derived_shapes, replace, "compiled")
        family = numpy_module.FAMILY
        self.derived = numpy_module.DERIVED
        self.slack_measures = numpy_module.SLACK_MEASURES
        lib = ctypes.CDLL(str(library))
        sizes = (ctypes.c_longlong * 6)()  # the library's layout is the family's
        lib.kg_sizes(sizes)
        expected = [len(family["parameter"]), len(family["constants"]),
                    len(family["channels"]), len(family["models"]), len(family["derived"]),
                    len(family.get("slack", ()))]
        if list(sizes) != expected:
            raise RuntimeError(f"compiled library {library} does not match family "
                               f"{family['name']!r}: sizes {list(sizes)} vs {expected}")
        self._eval = lib.kg_eval
        self._eval.argtypes = [ctypes.c_void_p] * 2
        self._eval.restype = ctypes.c_int
        self._models = {name: i for i, name in enumerate(family["models"])}
        self._channels = {name: (i, len(ch["corrected"]))
                          for i, (name, ch) in enumerate(family["channels"].items())}
        self._n = len(family["parameter"])
        self._p = {(m, c): lib.kg_equations(i, j) for m, i in self._models.items()
                   for c, (j, _) in [(None, (-1, 0)), *self._channels.items()]}
        self._local = threading.local()

    def _buffers(self, size_in: int, size_out: int):
        ws = getattr(self._local, "ws", None)
        if ws is None or ws[0].size < size_in or ws[1].size < size_out:
            inp = np.empty(max(size_in, 2 * (ws[0].size if ws else 0), 256))
            out = np.empty(max(size_out, 2 * (ws[1].size if ws else 0), 256))
            ws = self._local.ws = (inp, out, inp.ctypes.data, out.ctypes.data)
        return ws

    def _call(self, head, q, k, X, size_out):
        n = self._n
        size_in = 4 + n + k.size + (X.size if X is not None else 0)
        inp, out, a_in, a_out = self._buffers(size_in, size_out)
        inp[:4] = head
        inp[4:4 + n] = q
        inp[4 + n:4 + n + k.size] = k
        if X is not None:
            inp[4 + n + k.size:size_in] = X.reshape(-1)
        self._eval(a_in, a_out)
        return out[:size_out].copy()

    def c0(self, model: str, reduced: bool = False) -> Callable:
        if reduced:
            return super().c0(model, reduced)
        m, p, n = self._models[model], self._p[(model, None)], self._n

        def c0(q, k):
            q, k = np.asarray(q, dtype=float), np.asarray(k, dtype=float)
            out = self._call((0, m, 0, 0), q, k, None, p + p * n)
            return out[:p], out[p:].reshape(p, n)

        return c0

    def measure(self, model: str, channel: str, reduced: bool = False) -> Callable:
        if reduced:
            return super().measure(model, channel, reduced)
        m, (j, kc) = self._models[model], self._channels[channel]
        p, n = self._p[(model, channel)], self._n

        def measure(q, X, k):
            X = np.ascontiguousarray(X, dtype=float)
            M = X.shape[0]
            out = self._call((1, m, j, M), np.asarray(q, dtype=float),
                             np.asarray(k, dtype=float), X, M * p * (1 + n + kc))
            return (out[:M * p].reshape(M, p), out[M * p:M * p * (1 + n)].reshape(M, p, n),
                    out[M * p * (1 + n):].reshape(M, p, kc))

        return measure
