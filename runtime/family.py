"""A model family at run time: the generated module behind a small typed interface."""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import os
import sys
from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from types import ModuleType

import numpy as np

from ..common.jit import announce
from ..common.slack import slack_value
from .backends import NumpyFunctions
from .minimal import generic_free_dof


@dataclass(frozen=True)
class ChannelInfo:
    """An input channel: data columns, exact ones, and the corrected ones with their columns."""

    name: str
    components: tuple[str, ...]
    exact: tuple[str, ...]
    corrected: tuple[str, ...]

    @cached_property
    def corrected_index(self) -> np.ndarray:
        """The columns of the corrected components (read-only: shared by the channel's
        data)."""
        index = np.array([self.components.index(c) for c in self.corrected], dtype=int)
        index.flags.writeable = False
        return index


@dataclass(frozen=True)
class Reduction:
    """``q = T r + t``: a model with its linear constraints eliminated (report §6);
    ``r = q[free]``."""

    free: np.ndarray
    T: np.ndarray
    t: np.ndarray

    def full(self, r: np.ndarray) -> np.ndarray:
        return self.T @ r + self.t


@dataclass(frozen=True)
class ModelInfo:
    """A model of the family: its constraints (as text), alternatives, equation overrides,
    the derived quantities it reports, the name of its closed-form initializer and that of
    the test of the measures it admits (:func:`~kanagen.runtime.initializers.admission`)."""

    name: str
    constraints: tuple[str, ...]
    alternatives: tuple[tuple[str, float | str], ...]
    equations: Mapping[str, tuple[str, ...]]
    derived: tuple[str, ...]
    initializer: str | None = None
    #: qualitative variables (appendix F, ``x in {a, b, ...}``): component -> its labels
    labels: Mapping[str, tuple[float, ...]] = field(default_factory=dict)
    admissible: str | None = None


class ModelFamily:
    """A compiled model family: evaluates equations and Jacobians through generated code.

    Obtain one with :func:`kanagen.load`. ``module`` is the generated NumPy module (the
    family's metadata, its functions and their row forms, which the engine compiles);
    ``functions`` the backend that evaluates the equations (default: the same NumPy module,
    :mod:`kanagen.runtime.backends`). ``eliminate_linear=True`` fits the models that have
    linear constraints in their free components (:meth:`reduction`).
    """

    def __init__(self, module: ModuleType, functions=None, eliminate_linear: bool = False):
        announce()  # a family's first kernels: the first compile on a machine takes minutes
        self.module = module
        self.functions = functions if functions is not None else NumpyFunctions(module)
        self.eliminate_linear = eliminate_linear
        meta = module.FAMILY
        self.name: str = meta["name"]
        self.sha256: str = module.SPEC_SHA256
        self.parameter_names = tuple(n for n, _ in meta["parameter"])
        self._q0 = np.array([v for _, v in meta["parameter"]], dtype=float)
        self.constant_names = tuple(n for n, _ in meta["constants"])
        self._constants = {n: float(v) for n, v in meta["constants"]}
        self.channels = {
            name: ChannelInfo(name, tuple(c["components"]), tuple(c["exact"]),
                              tuple(c["corrected"]))
            for name, c in meta["channels"].items()
        }
        self.models = {
            name: ModelInfo(name, tuple(m["constraints"]),
                            tuple((a, phi) for a, phi in m["alternatives"]),
                            {c: tuple(e) for c, e in m["equations"].items()},
                            tuple(m.get("derived", meta["derived"])), m.get("initializer"),
                            {x: tuple(v) for x, v in m.get("labels", {}).items()},
                            m.get("admissible"))
            for name, m in meta["models"].items()
        }
        self.derived_shapes = {k: tuple(v) for k, v in meta["derived"].items()}
        #: the spec's ``units:`` (name -> unit text; display only)
        self.units: dict[str, str] = dict(meta.get("units", {}))
        #: constants whose default stands for something of the data: name -> what to give
        self.assumptions: dict[str, str] = dict(meta.get("assumed", {}))
        self.null_model: str = meta["null_model"]
        #: Components added for inequalities (appendix F), last in q; not "the parameter".
        self.slack_names = tuple(meta.get("slack", ()))
        self._reductions = {
            name: Reduction(np.array(r["free"], dtype=int), np.array(r["T"], dtype=float),
                            np.array(r["t"], dtype=float))
            for name, r in meta.get("reductions", {}).items()}
        self._free: dict[tuple[str, bytes], int] = {}  # free_dof's, per model and constants
        self._pinned = {name: {self.parameter_names[i]: float(r.t[i])
                               for i in np.flatnonzero(~np.any(r.T != 0.0, axis=1))}
                        for name, r in self._reductions.items()}  # pinned's, per model

    def __repr__(self) -> str:
        return (f"<ModelFamily {self.name!r}: parameter {list(self.parameter_names)}, "
                f"models {list(self.models)}, channels {list(self.channels)}, "
                f"backend {self.backend!r}>")

    @property
    def backend(self) -> str:
        """Which backend evaluates the equations: "numpy", "casadi" or "compiled"."""
        return self.functions.name

    @property
    def n(self) -> int:
        return len(self.parameter_names)

    @property
    def q0(self) -> np.ndarray:
        """The default parameter value declared in the spec."""
        return self._q0.copy()

    @property
    def constants(self) -> dict[str, float]:
        """Default values of the constants."""
        return dict(self._constants)

    def constant_vector(self, constants: Mapping[str, float] | None = None) -> np.ndarray:
        """Constants in declaration order, defaults overridden by ``constants``."""
        if not constants:  # the defaults: made once
            defaults = self.__dict__.get("_default_constants")
            if defaults is None:
                defaults = self._default_constants = np.array(
                    [self._constants[n] for n in self.constant_names], dtype=float)
            return defaults.copy()
        values = dict(self._constants)
        for key, value in (constants or {}).items():
            if key not in values:
                raise ValueError(f"unknown constant {key!r} (family {self.name!r} has "
                                 f"{list(values) or 'none'})")
            value = float(value)
            if not np.isfinite(value):
                raise ValueError(f"constant {key!r} must be finite, got {value}")
            values[key] = value
        return np.array([values[n] for n in self.constant_names], dtype=float)

    def params_dict(self, q: np.ndarray, slack: bool = False) -> dict[str, float]:
        """The parameter by component name; slack components only with ``slack=True``."""
        if slack or not self.slack_names:
            return dict(zip(self.parameter_names, np.asarray(q, dtype=float).tolist(),
                            strict=True))
        return {n: float(v) for n, v in zip(self.parameter_names, q, strict=True)
                if n not in self.slack_names}

    def with_slacks(self, q, constants=None, model: str | None = None) -> np.ndarray:
        """``q`` with its slack components (appendix F) completed or refreshed.

        ``q`` may omit the slacks. The slacks of ``model`` are set from their relations at
        ``q``: ``s = √c`` for ``c >= 0``, ``1/√c`` for ``c > 0``, ``1/c`` for ``c != 0`` where
        the relation holds, else a non-zero value of the same magnitude (the iteration then
        moves the parameter until it holds; :func:`~kanagen.common.slack.slack_value`).
        The other slacks (pinned in ``model``) take the
        spec's values; without ``model``, every slack does.
        """
        q = np.asarray(q, dtype=float)
        if not self.slack_names:
            return q
        n_user = self.n - len(self.slack_names)
        full = np.r_[q[:n_user], self._q0[n_user:]]
        owners = self.module.FAMILY.get("slack_owner", [])
        own = [i for i, m in enumerate(owners) if m == model]
        if not own:
            return full
        with np.errstate(all="ignore"):
            c = self.functions.slack_measures(full, self._k(constants))
        kinds = self.module.FAMILY["slack_kinds"]
        for i in own:
            full[n_user + i] = slack_value(kinds[i], float(c[i]))
        return full

    def relations_hold(self, model: str, q, constants=None) -> bool:
        """Whether ``model``'s inequality relations (appendix F) hold at ``q``: in each of
        its clauses made of inequalities only, at least one (the clauses with an equation
        are the projector's business)."""
        clauses = self.module.FAMILY.get("slack_clauses", {}).get(model)
        if not clauses:
            return True
        kinds = self.module.FAMILY["slack_kinds"]
        with np.errstate(all="ignore"):
            c = self.functions.slack_measures(np.asarray(q, dtype=float), self._k(constants))
        holds = [bool(c[i] >= 0 if kind == ">=" else c[i] > 0 if kind == ">" else
                      np.isfinite(c[i]) and c[i] != 0) for i, kind in enumerate(kinds)]
        return all(any(holds[i] for i in clause) for clause in clauses)

    def strict_slacks(self, model: str) -> tuple[tuple[int, int], ...]:
        """The slacks of ``model``'s strict relations, which diverge when the optimum lies on
        the boundary: ``(index in q, p)`` with the relation ``c = 1/s^p`` on its equation
        (``c·s² − 1``: p = 2; ``c·s − 1`` for ``c != 0``: p = 1)."""
        if not self.slack_names:
            return ()
        n_user = self.n - len(self.slack_names)
        kinds = self.module.FAMILY["slack_kinds"]
        power = {">": 2, "!=": 1}
        # a relation alone in its clause: within a disjunction (a product of equations) the
        # slack of a relation that does not hold is free to wander
        alone = {c[0] for c in self.module.FAMILY.get("slack_clauses", {}).get(model, [])
                 if len(c) == 1}
        return tuple((n_user + i, power[kinds[i]]) for i in sorted(alone)
                     if kinds[i] in power)

    def slack_dict(self, q: np.ndarray) -> dict[str, float]:
        """The slack components by name."""
        if not self.slack_names:
            return {}
        return {n: float(v) for n, v in zip(self.parameter_names, q, strict=True)
                if n in self.slack_names}

    def model(self, name: str) -> ModelInfo:
        try:
            return self.models[name]
        except KeyError:
            raise ValueError(f"unknown model {name!r} (family {self.name!r} has "
                             f"{list(self.models)})") from None

    def channel(self, name: str) -> ChannelInfo:
        try:
            return self.channels[name]
        except KeyError:
            raise ValueError(f"unknown channel {name!r} (family {self.name!r} has "
                             f"{list(self.channels)})") from None

    def _k(self, constants):
        return constants if isinstance(constants, np.ndarray) else self.constant_vector(constants)

    def c0_function(self, model: str, reduced: bool = False):
        """The callable ``(q, k) -> (c0 (p,), C0 (p, n))`` of ``model`` (in ``r`` with
        ``reduced=True``)."""
        self.model(model)
        return self.functions.c0(model, reduced)

    def measurement_function(self, model: str, channel: str, reduced: bool = False):
        """The callable ``(q, X, k) -> (c (M, p), C (M, p, n), D (M, p, k))`` of a channel
        under ``model`` (in ``r`` with ``reduced=True``)."""
        self.model(model)
        self.channel(channel)
        return self.functions.measure(model, channel, reduced)

    def reduction(self, model: str) -> Reduction | None:
        """``q = T r + t`` for ``model`` when its linear constraints are eliminated (report
        §6, :mod:`kanagen.codegen.eliminate`): only with ``eliminate_linear=True``."""
        return self._reductions.get(model) if self.eliminate_linear else None

    def assumed(self, constants=None) -> dict[str, float]:
        """The constants of :attr:`assumptions` that ``constants`` does not give: their
        defaults, which a fit then assumes (and says so: :meth:`warn_assumed`)."""
        if not self.assumptions:
            return {}
        given = constants or {}
        defaults = self.constants
        return {name: defaults[name] for name in self.assumptions if name not in given}

    def warn_assumed(self, constants=None, stacklevel: int = 3) -> dict[str, float]:
        """:meth:`assumed`, with one warning naming each assumed value and what to give."""
        assumed = self.assumed(constants)
        if assumed:
            import warnings

            what = "; ".join(f"{name} = {value:g} ({self.assumptions[name]})"
                             for name, value in assumed.items())
            warnings.warn(f"family {self.name!r}: constants not given, assumed {what}; pass "
                          f"constants={{...}} to use your data's", AssumedConstantsWarning,
                          stacklevel=stacklevel)
        return assumed

    def pinned(self, model: str) -> dict[str, float]:
        """The components of q ``model``'s linear constraints fix to a value (a circle's
        ``B = 0``; the slacks of the other models' inequalities): not estimates, so results
        list them apart."""
        return dict(self._pinned.get(model, {}))

    def free_dof(self, model: str, constants=None) -> int:
        """``n − p``: the degrees of freedom ``model``'s constraints leave free, ``p`` their
        generic rank (:func:`~kanagen.runtime.minimal.generic_free_dof` at the spec's q0 and
        two perturbations of it: the same anywhere but at special points), once per model and
        constants."""
        k = self._k(constants)
        key = (model, k.tobytes())
        free = self._free.get(key)
        if free is None:
            free = self._free[key] = generic_free_dof(lambda x: self.c0(model, x, k)[1],
                                              self.with_slacks(self.q0, k, model))
        return free

    def c0(self, model: str, q, constants=None) -> tuple[np.ndarray, np.ndarray]:
        """Constraints ``c0(q)`` (p,) and their Jacobian (p, n)."""
        return self.c0_function(model)(np.asarray(q, dtype=float), self._k(constants))

    def measurement(self, model: str, channel: str, q, m, constants=None):
        """Equations (M, p), Jacobian in q (M, p, n) and in the corrected components (M, p, k).

        ``m`` is the full data array (M, len(components)) in component order.
        """
        fn = self.measurement_function(model, channel)
        return fn(np.asarray(q, dtype=float), np.asarray(m, dtype=float), self._k(constants))

    def derived(self, q, constants=None) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Every derived quantity and its Jacobian in q. A quantity undefined at q (a
        circle's radius on a line) is NaN, without a floating-point warning."""
        if self.functions.derived is None:
            return {}
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            return self.functions.derived(np.asarray(q, dtype=float), self._k(constants))

class AssumedConstantsWarning(UserWarning):
    """A fit relies on a constant's default that stands for something of the data (a
    spec's ``assume:``): the result's ``assumed`` lists them."""


def cache_dir() -> Path:
    """Where specs built at run time are cached (``$KANAGEN_CACHE`` or the user cache)."""
    root = os.environ.get("KANAGEN_CACHE")
    if root:
        return Path(root)
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "kanagen"


def import_file(path: Path, module_name: str) -> ModuleType:
    """Import a generated module from a file (generated by kanagen; never user text)."""
    if module_name in sys.modules:
        return sys.modules[module_name]
    spec = importlib.util.spec_from_file_location(module_name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    sys.modules[module_name] = module
    return module


def shipped_module(name: str, sha256: str, fmt: int) -> ModuleType | None:
    """The module under ``kanagen.generated`` for this spec, if it is there and up to date."""
    try:
        module = importlib.import_module(f"kanagen.generated.{name}")
    except ImportError:
        return None
    if getattr(module, "SPEC_SHA256", None) == sha256 and getattr(module, "FORMAT", None) == fmt:
        return module
    return None


def cache_key(sha256: str, generator_version: str) -> str:
    return hashlib.sha256(f"{sha256}:{generator_version}".encode()).hexdigest()[:20]
