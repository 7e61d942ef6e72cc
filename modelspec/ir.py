"""The validated intermediate representation of a model family (frozen dataclasses).

A family declares one parameter vector ``q`` (ordered components with defaults ``q0``),
constants set at run time, input channels of measures with their implicit measurement
equations ``c_i(q, m_i) = 0``, and models that differ by their parameter constraints
``c0(q) = 0`` (report §2, §5). Code generators consume this IR only.
"""

from __future__ import annotations

from dataclasses import dataclass

import sympy as sp


def symbol(name: str) -> sp.Symbol:
    """The SymPy symbol kanagen uses for a declared name (all quantities are real)."""
    return sp.Symbol(name, real=True)


@dataclass(frozen=True)
class Channel:
    """An input channel: the columns of its data array and its measurement equations."""

    name: str
    components: tuple[str, ...]
    exact: tuple[str, ...]
    equations: tuple[sp.Expr, ...]

    @property
    def corrected(self) -> tuple[str, ...]:
        """Components that the estimator corrects (all but the exact ones), in order."""
        return tuple(c for c in self.components if c not in self.exact)


@dataclass(frozen=True)
class Alternative:
    """A more general model and the cost factor Φ(d, d') that it must beat (report eq. 46)."""

    model: str
    phi: float | str = 1.0


@dataclass(frozen=True)
class Model:
    """A model: parameter constraints, optional equation overrides, its alternatives, the
    derived quantities it reports (None: all), the name of its closed-form initialiser and
    the name of the test of which measures it admits besides its equations."""

    name: str
    constraints: tuple[sp.Expr, ...]
    equations: tuple[tuple[str, tuple[sp.Expr, ...]], ...] = ()
    alternatives: tuple[Alternative, ...] = ()
    derived: tuple[str, ...] | None = None
    initializer: str | None = None
    admissible: str | None = None


@dataclass(frozen=True)
class Derived:
    """A quantity derived from the parameter: scalar (shape ``()``), vector or matrix."""

    name: str
    shape: tuple[int, ...]
    expressions: tuple[sp.Expr, ...]


@dataclass(frozen=True)
class Family:
    """A validated model family."""

    name: str
    parameter: tuple[tuple[str, float], ...]
    constants: tuple[tuple[str, float], ...]
    channels: tuple[Channel, ...]
    models: tuple[Model, ...]
    derived: tuple[Derived, ...]
    null_model: str
    source: str
    sha256: str
    slack: tuple[str, ...] = ()  # parameter components added for inequalities (appendix F)
    slack_relations: tuple[tuple[str, sp.Expr], ...] = ()  # (kind, c) per slack, same order
    slack_owner: tuple[str, ...] = ()  # the model each slack belongs to, same order
    #: per model, its clauses made of inequalities only (slack indices): one must hold each
    slack_clauses: tuple[tuple[str, tuple[tuple[int, ...], ...]], ...] = ()
    #: (name, unit) of parameter components, derived quantities, constants and measured
    #: components, as the spec's ``units:`` says (display only: nothing is converted)
    units: tuple[tuple[str, str], ...] = ()
    #: (name, what its default stands for) of the constants a fit must say it assumed when
    #: not given (``constants: {cx: {value: 320, assume: ...}}``)
    assumed: tuple[tuple[str, str], ...] = ()

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """Every component of q, slacks included (they come last)."""
        return tuple(name for name, _ in self.parameter)

    def channel(self, name: str) -> Channel:
        for channel in self.channels:
            if channel.name == name:
                return channel
        raise KeyError(name)

    def model(self, name: str) -> Model:
        for model in self.models:
            if model.name == name:
                return model
        raise KeyError(name)

    def equations(self, model: str, channel: str) -> tuple[sp.Expr, ...]:
        """The measurement equations of ``channel`` under ``model`` (its override, if any)."""
        return dict(self.model(model).equations).get(channel, self.channel(channel).equations)
