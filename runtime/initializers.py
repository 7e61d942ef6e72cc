"""Closed-form initialisers: starting values for a model's minimal solves (report eq. 21).

The minimal solve of a sample starts from the parent model's estimate. For a model whose
solutions are far from it and several (a fundamental matrix from 7 matches has up to three;
a homography's pose two), a closed form on the sample gives better starts. A model names
its initializer in the spec (``initializer: two_view_fundamental``) — a key of
:data:`INITIALIZERS`, checked when the spec is read, never executable text — or the caller
passes ``initializers={model: name or callable}`` to :class:`~kanagen.Estimator` /
:func:`~kanagen.robust_fit` (``None`` switches one off).

An initializer is ``f(rows, constants) -> [ {parameter name: value}, ... ]``: ``rows`` are
the sample's measures of the sampled channel (data columns in the spec's order),
``constants`` the run-time constants by name. Each candidate (components it does not name
keep the parent's values) starts one minimal solve; every solution that passes is scored.
No candidate means that no parameter of the model passes through the sample (a seven-point
F whose focal lengths are imaginary): the sample is skipped. The final refinement on the
inliers also starts from the candidates and keeps the fit of least cost.

This module is the generic machinery: the registry and how a model's starts are chosen. The
closed forms themselves are plugins that :func:`register` their entries: the two-view ones
(:mod:`~kanagen.runtime.two_view_starts`) are imported the first time one of their names
is looked up (:data:`PROVIDERS`), so a family that names none of them never loads them.

The same registry holds the *admission tests* a model may name (``admissible:
calibrated_in_front``, entries of kind ``"admission"``): ``f(q, rows, info, constants) ->
bool array``, ``q`` the parameter by name, ``rows`` a channel's measures, ``info`` their
information (one matrix or one per measure). A measure the test refuses is an outlier of
the model whatever its error (:func:`admission`): a match behind a camera fits the epipolar
equation but not the motion.
"""

from __future__ import annotations

import importlib
import itertools
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass

import numpy as np

Candidates = list[dict[str, float]]
InitializerFn = Callable[[np.ndarray, Mapping[str, float]], Candidates]

#: Where the registered initialisers are defined: name -> the module (relative to
#: ``kanagen.runtime``, or absolute) that registers it (:func:`register`) when imported. The
#: registry knows these names without importing anything, and imports a module the first
#: time one of its names is looked up: a family whose models name none of the two-view
#: closed forms never loads them, nor :mod:`~kanagen.runtime.geometry`.
PROVIDERS: dict[str, str] = {
    "two_view_fundamental": ".two_view_starts",
    "two_view_homography": ".two_view_starts",
    "two_view_rotation": ".two_view_starts",
    "two_view_translation": ".two_view_starts",
    "two_view_zoom": ".two_view_starts",
    "two_view_retinal_translation": ".two_view_starts",
    "two_view_retinal_displacement": ".two_view_starts",
    "calibrated_five_point": ".calibrated_starts",
    "calibrated_rotation": ".calibrated_starts",
    "calibrated_translation": ".calibrated_starts",
    "calibrated_retinal_translation": ".calibrated_starts",
    "calibrated_retinal_displacement": ".calibrated_starts",
    "calibrated_homography": ".calibrated_starts",
    "calibrated_in_front": ".calibrated_admission",
}
#: The kind of the names of :data:`PROVIDERS` that are not initialisers (known without
#: importing their providers).
PROVIDED_KINDS: dict[str, str] = {"calibrated_in_front": "admission"}


@dataclass(frozen=True)
class Kernel:
    """A closed form compiled for the robust search's samples
    (:func:`kanagen.runtime.engine.sample.sample`): the address of a C-callable
    ``int64 (int64 s, double *X, double *k, double *out)`` — ``s`` sample rows ``X`` of the
    sampled channel, the family's ``constants`` in this order, candidates written one a
    row of :data:`~kanagen.runtime.engine.sample.WIDTH` values into ``out``, their count
    returned (−1: the sample is left to the Python) — made on first use, and which
    parameter each value of a candidate's row is (``names``: ``(column, parameter)``)."""

    address: Callable[[], int]
    names: tuple[tuple[int, str], ...]
    constants: tuple[str, ...]


@dataclass(frozen=True)
class Initializer:
    """A registered closed form and what it needs of the family."""

    name: str
    fn: InitializerFn
    parameters: tuple[str, ...]
    constants: tuple[str, ...]
    width: int  # components of the sampled channel
    doc: str
    #: the candidates parameterise one estimate (the two decompositions of one homography
    #: give the same errors): a random sample scores only the first whose solve passes
    equivalent: bool = False
    #: "initializer" (a model's ``initializer:``) or "admission" (its ``admissible:``)
    kind: str = "initializer"
    #: the same closed form compiled for the samples of a search (None: the Python's)
    kernel: Kernel | None = None

    def missing(self, parameter, constants, channels: Mapping[str, tuple[str, ...]]) -> str:
        """What the family lacks for this initializer ('' when nothing)."""
        lacks = [f"parameter {p!r}" for p in self.parameters if p not in parameter]
        lacks += [f"constant {c!r}" for c in self.constants if c not in constants]
        if not any(len(comps) == self.width for comps in channels.values()):
            lacks.append(f"a channel of {self.width} components")
        return ", ".join(lacks)


_REGISTERED: dict[str, Initializer] = {}


def register(entry: Initializer) -> Initializer:
    """Add ``entry`` to the registry under ``entry.name`` (a provider of
    :data:`PROVIDERS` calls it when imported; a plugin may call it directly). Registering
    the same function again (or its module reloaded) is harmless; another function under a
    taken name is an error."""
    known = _REGISTERED.get(entry.name)
    if known is not None and _qualified(known.fn) != _qualified(entry.fn):
        raise ValueError(f"initializer {entry.name!r} is registered already "
                         f"({known.fn.__module__}.{known.fn.__qualname__})")
    _REGISTERED[entry.name] = entry
    return entry


def _qualified(fn) -> tuple[str, str]:
    return getattr(fn, "__module__", ""), getattr(fn, "__qualname__", repr(fn))


class Registry(Mapping[str, Initializer]):
    """The registered initialisers by name: those registered and those a module of
    :data:`PROVIDERS` provides. Listing the names (iteration, ``in``, ``len``) imports
    nothing; looking one up imports its provider on first use."""

    def __getitem__(self, name: str) -> Initializer:
        entry = _REGISTERED.get(name)
        if entry is None and name in PROVIDERS:
            importlib.import_module(PROVIDERS[name], __package__)
            entry = _REGISTERED.get(name)
            if entry is None:
                raise LookupError(f"module {PROVIDERS[name]!r} does not register the "
                                  f"initializer {name!r} it is listed for")
        if entry is None:
            raise KeyError(name)
        return entry

    def __contains__(self, name: object) -> bool:
        return name in _REGISTERED or name in PROVIDERS

    def __iter__(self) -> Iterator[str]:
        return iter(dict.fromkeys([*PROVIDERS, *_REGISTERED]))

    def __len__(self) -> int:
        return len(PROVIDERS.keys() | _REGISTERED.keys())

    def __repr__(self) -> str:
        return f"<initializer registry: {', '.join(self)}>"

    def names_of(self, kind: str) -> list[str]:
        """The names of the entries of ``kind`` (imports nothing)."""
        return named(kind)


#: The registry that specs name initialisers from (``initializer: two_view_fundamental``).
INITIALIZERS = Registry()


def named(kind: str) -> list[str]:
    """The registry's names of entries of ``kind`` (imports nothing)."""
    def kind_of(name: str) -> str:
        entry = _REGISTERED.get(name)
        return entry.kind if entry is not None else PROVIDED_KINDS.get(name, "initializer")

    return sorted(n for n in INITIALIZERS if kind_of(n) == kind)


def lookup(name: str, kind: str = "initializer") -> Initializer | None:
    """The registered entry ``name`` of ``kind``, or None."""
    entry = INITIALIZERS.get(name)
    return entry if entry is not None and entry.kind == kind else None


def resolve(choice) -> InitializerFn | None:
    """A registry name, a callable or None → the initializer function (or None)."""
    if choice is None or callable(choice):
        return choice
    entry = lookup(choice)
    if entry is None:
        raise ValueError(f"unknown initializer {choice!r} (known: "
                         f"{', '.join(named('initializer'))}, or a callable)")
    return entry.fn


def admission(fam, model: str) -> Callable | None:
    """The model's admission test (its spec's ``admissible:``) as ``admit(problem, q) ->
    per-channel bool arrays`` (None for a channel it does not test: every measure
    admitted), or None when the model names none."""
    name = fam.model(model).admissible
    if name is None:
        return None
    entry = lookup(name, "admission")
    if entry is None:
        raise ValueError(f"model {model!r}: unknown admission test {name!r} (known: "
                         f"{', '.join(named('admission'))})")
    names = fam.parameter_names

    def admit(problem, q: np.ndarray) -> tuple:
        values = dict(zip(names, np.asarray(q, dtype=float).tolist(), strict=True))
        constants = dict(zip(fam.constant_names, np.asarray(problem.k).tolist(),
                             strict=True))
        return tuple(entry.fn(values, ch.X, ch.Q, constants)
                     if ch.size and ch.X.shape[1] == entry.width else None
                     for ch in problem.channels)

    return admit


def label_candidates(labels: Mapping[str, tuple[float, ...]]) -> InitializerFn:
    """The starts of a model with qualitative variables (``x in {a, b, ...}``): one per
    combination of labels. A local solver stays on the label it starts at, so every label
    is tried and the data choose (the best-scoring sample, the least-cost refinement)."""
    names = sorted(labels)
    combos = [dict(zip(names, values, strict=True))
              for values in itertools.product(*(labels[n] for n in names))]

    def candidates(rows, constants) -> Candidates:
        return [dict(c) for c in combos]

    return candidates


def model_initializers(fam, overrides: Mapping | None = None) -> dict[str, InitializerFn]:
    """Each model's initializer: the spec's choice, overridden by ``overrides``; a model
    with qualitative variables and no closed form starts on each of its labels. A
    registered closed form with a compiled :class:`Kernel` carries it (``fn.kernel``: the
    robust search's samples call it); a callable override runs as given."""
    out = {}
    overrides = dict(overrides or {})
    for name in overrides:
        fam.model(name)  # a clear error for an unknown model
    for name, info in fam.models.items():
        choice = overrides[name] if name in overrides else info.initializer
        fn = resolve(choice)
        if isinstance(choice, str) and INITIALIZERS[choice].equivalent:
            fn.equivalent = True  # read by equivalent()
        if isinstance(choice, str) and INITIALIZERS[choice].kernel is not None:
            fn.kernel = INITIALIZERS[choice].kernel  # read by the search's sampler
        if fn is None and info.labels and overrides.get(name, "") is not None:
            fn = label_candidates(info.labels)
        if fn is not None:
            out[name] = fn
    return out


def equivalent(fn: InitializerFn | None) -> bool:
    """Do the candidates of the initializer ``fn`` parameterise one estimate (a registered
    closed form flagged :attr:`Initializer.equivalent`)?"""
    return bool(getattr(fn, "equivalent", False))


def start_from(fam, candidate: Mapping[str, float], start: np.ndarray) -> np.ndarray | None:
    """``start`` with the candidate's named components replaced (None if one is unknown or
    not finite)."""
    q = np.array(start, dtype=float)
    for name, value in candidate.items():
        if name not in fam.parameter_names or not np.isfinite(value):
            return None
        q[fam.parameter_names.index(name)] = value
    return q
