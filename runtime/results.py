"""Results of an estimation, as frozen dataclasses that carry their uncertainty."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class DerivedValue:
    """A derived quantity with its covariance propagated from the parameter's (J Σ Jᵀ)."""

    value: np.ndarray
    covariance: np.ndarray  # (size, size) over the flattened value
    jacobian: np.ndarray

    @property
    def std(self) -> np.ndarray:
        """Standard deviation of each entry, shaped like ``value``."""
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None)).reshape(
            np.shape(self.value))

    # It behaves as its value: ``np.asarray(dv)``, ``float(dv)`` (one entry), ``2 * dv``.
    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        out = np.asarray(self.value, dtype=dtype)
        return out.copy() if copy else out

    def __float__(self) -> float:
        value = np.asarray(self.value, dtype=float)
        if value.size != 1:
            raise TypeError(f"only a derived value of one entry converts to float, this one "
                            f"has shape {value.shape}")
        return float(value.reshape(()))

    def __getitem__(self, index):
        return np.asarray(self.value)[index]

    def __neg__(self):
        return -np.asarray(self.value)

    def __pos__(self):
        return +np.asarray(self.value)

    def __abs__(self):
        return np.abs(np.asarray(self.value))


def _arithmetic(name: str):
    def method(self, other):
        other = np.asarray(other.value) if isinstance(other, DerivedValue) else other
        return getattr(np.asarray(self.value), name)(other)

    method.__name__ = name
    return method


for _name in ("__add__", "__radd__", "__sub__", "__rsub__", "__mul__", "__rmul__",
              "__truediv__", "__rtruediv__", "__pow__", "__rpow__", "__matmul__",
              "__rmatmul__", "__lt__", "__le__", "__gt__", "__ge__"):
    setattr(DerivedValue, _name, _arithmetic(_name))


def constrained_covariance(info: np.ndarray, C0: np.ndarray) -> np.ndarray:
    """Covariance of q̃: the top-left block of ``[[Q̃, C0ᵀ], [C0, 0]]⁻¹``.

    Computed as ``Z (Zᵀ Q̃ Z)⁻¹ Zᵀ`` with ``Z`` an orthonormal basis of the null space of
    ``C0`` (its rows independent: the reduced square root kept them), so components the
    constraints pin get exactly zero variance however many they are. Directions that
    neither the information nor the constraints fix are unobservable: the components they
    move get an infinite variance (not the pseudo-inverse's zero, which would claim
    certainty).
    """
    from .engine.covariance import constrained_covariance as kernel  # numba: on first use

    info = np.ascontiguousarray(info, dtype=float)
    return kernel(info, np.ascontiguousarray(C0, dtype=float).reshape(-1, info.shape[0]))


def propagate(J: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    """``J Σ Jᵀ``, with infinite variance wherever J touches an unobservable component."""
    if np.isfinite(covariance).all():
        return J @ covariance @ J.T
    free = ~np.isfinite(np.diag(covariance))
    finite = np.where(np.isfinite(covariance), covariance, 0.0)
    out = J @ finite @ J.T
    touched = np.any(J[:, free] != 0, axis=1)
    out[touched, :] = np.inf
    out[:, touched] = np.inf
    return out


def derived_values(fam, q: np.ndarray, covariance: np.ndarray,
                   k: np.ndarray, model: str | None = None) -> dict[str, DerivedValue]:
    """Derived quantities at ``q`` with covariances ``J Σ Jᵀ`` (those ``model`` reports;
    ``fam`` a :class:`~kanagen.runtime.family.ModelFamily`): one propagation of all their
    Jacobians stacked, each quantity's covariance its diagonal block."""
    wanted = fam.model(model).derived if model is not None else None
    with np.errstate(all="ignore"):
        items = [(name, value, jac) for name, (value, jac) in fam.derived(q, k).items()
                 if wanted is None or name in wanted]
        if not items:
            return {}
        rows = [jac.reshape(-1, fam.n) for _, _, jac in items]
        joint = propagate(np.concatenate(rows), covariance)
    out, at = {}, 0
    for (name, value, jac), J in zip(items, rows, strict=True):
        block = joint[at:at + J.shape[0], at:at + J.shape[0]].copy()
        out[name] = DerivedValue(value, block, jac)
        at += J.shape[0]
    return out


class DerivedQuantities(Mapping):
    """A result's derived quantities, computed when first read (:func:`derived_values` at
    the estimate): a fit whose caller reads only the parameter does not evaluate them. A
    read-only mapping ``{name: DerivedValue}``; it pickles and copies as a plain dict."""

    __slots__ = ("_inputs", "_values")

    def __init__(self, fam, q: np.ndarray, covariance: np.ndarray, k: np.ndarray,
                 model: str | None = None):
        self._inputs = (fam, q.copy(), covariance.copy(), k, model)  # as at the estimate
        self._values: dict[str, DerivedValue] | None = None

    def _computed(self) -> dict[str, DerivedValue]:
        if self._values is None:
            self._values = derived_values(*self._inputs)
            self._inputs = None
        return self._values

    def __getitem__(self, name: str) -> DerivedValue:
        return self._computed()[name]

    def __iter__(self):
        return iter(self._computed())

    def __len__(self) -> int:
        return len(self._computed())

    def __repr__(self) -> str:
        return repr(self._computed())

    def __reduce__(self):
        return dict, (self._computed(),)


class ParameterStd(dict):
    """Standard deviations by component name (the parameter's, then its slack components),
    from the diagonal of the covariance: 0 (to rounding) for a component the model's
    constraints pin,
    ``inf`` for an unobservable one, NaN when the covariance is undefined (a failed fit).

    A dict that also reads as the array of its values in ``q``'s order, as ``std`` was
    before it was a dict: ``std[0]``, ``np.asarray(std)``, ``np.max(std)``."""

    def __getitem__(self, key):
        if isinstance(key, int | np.integer | slice) and not isinstance(key, bool):
            return np.asarray(self)[key]
        return super().__getitem__(key)

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        return np.fromiter(self.values(), dtype=float, count=len(self)).astype(
            float if dtype is None else dtype, copy=False)


class Chance:
    """A search's number of false alarms (:func:`~kanagen.runtime.significance.false_alarms`)
    computed when first read (``compute()``): a result that carries one costs nothing until
    it is asked for. It pickles and copies as its value."""

    def __init__(self, compute: Callable[[], float] | None, value: float | None = None):
        self._compute, self._value = compute, value

    @property
    def value(self) -> float:
        if self._value is None:
            self._value = float(self._compute())
            self._compute = None  # the measures it held are no longer needed
        return self._value

    def __reduce__(self):
        return Chance, (None, self.value)

    def __repr__(self) -> str:
        return f"Chance({self.value:.3g})"


class ResultProtocol:
    """What every result (:class:`FitResult`, :class:`ModelState`,
    :class:`~kanagen.runtime.robust.RobustEstimate`) says, with one meaning on all three.

    ``model``, ``params`` (dict, slacks apart in ``slacks``), ``q``, ``covariance``,
    ``std`` (:class:`ParameterStd`), ``derived``, ``success``, ``dof`` = d = n − p + Σ pᵢ
    (eq. 7: the equations kept plus the free degrees of freedom), and the costs:

    - ``cost`` = ``total_cost`` = L̃² = ½‖q̃−q0‖²_Q0 + Σ ½‖m̃−m‖²_Q (with the ½ of eq. 2,
      as ``scipy.optimize.least_squares``' ``cost``);
    - ``normalized_cost`` = L̃²/d, about ½ when the weights are right: the lattice compares
      models by it;
    - ``chi2`` = 2 L̃², the sum of the squared whitened residuals; ``chi2_dof`` = ν, the
      redundancy: the equations kept minus the free degrees of freedom (Σ pᵢ − (n − p); a
      prior ``Q0`` is not counted); ``reduced_chi2`` = χ²/ν, about 1 when the weights are
      right (scipy.odr's ``res_var``, lmfit's ``redchi``); ``chi2_pvalue``: the chance of a
      χ² at least this large under the model with those weights.

    A robust search's results (:class:`ModelState`, ``RobustEstimate``) also say whether
    their structure is more than chance: ``false_alarms``, the number of false alarms (NFA,
    :mod:`~kanagen.runtime.significance`): at most 1, more than chance; above, measures
    uniform in their box show as much. Computed when first read; None for a plain fit.

    Subclasses provide ``model, params, q, covariance, cost, dof, derived, slacks`` and
    ``equations`` (Σ pᵢ).
    """

    chance: Chance | None = None  # a search's result: its NFA, computed when read

    @property
    def false_alarms(self) -> float | None:
        return None if self.chance is None else self.chance.value

    def _chance_line(self) -> str:
        """The summary's line on the NFA ("" without one)."""
        nfa = self.false_alarms
        if nfa is None:
            return ""
        if nfa <= 1:
            return f"\n  more than chance: {nfa:.3g} false alarm(s) (NFA)"
        return (f"\n  NOT more than chance: {nfa:.3g} false alarms (NFA > 1) — measures "
                "uniform in their box give as many inliers")

    @property
    def std(self) -> ParameterStd:
        cov = np.asarray(self.covariance, dtype=float)
        diag = np.diag(cov) if cov.ndim == 2 else np.full(len(self.q), np.nan)
        values = np.where(np.isnan(diag), np.nan, np.sqrt(np.clip(diag, 0.0, None)))
        names = [*self.params, *self.slacks]
        return ParameterStd(zip(names, (float(v) for v in values), strict=False))

    @property
    def total_cost(self) -> float:
        """L̃² (the same as ``cost``)."""
        return float(self.cost)

    @property
    def normalized_cost(self) -> float:
        """L̃²/d (eq. 7)."""
        return self.cost / self.dof if self.dof > 0 else float("inf")

    @property
    def chi2(self) -> float:
        """χ² = 2 L̃², the sum of the squared whitened residuals."""
        return 2.0 * float(self.cost)

    @property
    def chi2_dof(self) -> int:
        """ν = Σ pᵢ − (n − p): the equations kept minus the free degrees of freedom."""
        return 2 * int(self.equations) - int(self.dof)

    @property
    def reduced_chi2(self) -> float:
        """χ²/ν, about 1 when the weights are right (NaN when ν ≤ 0)."""
        nu = self.chi2_dof
        return self.chi2 / nu if nu > 0 else float("nan")

    @property
    def chi2_pvalue(self) -> float:
        """P(χ²_ν ≥ χ²), NaN when ν ≤ 0 or χ² is not finite."""
        nu, chi2 = self.chi2_dof, self.chi2
        if nu <= 0 or not np.isfinite(chi2):
            return float("nan")
        from .chisquare import tail  # lazily: import kanagen stays light

        return tail(chi2, nu)

    def goodness_of_fit(self) -> dict[str, float]:
        """The costs and χ² statistics as a dict (the JSON records carry them)."""
        return {"cost": float(self.cost), "normalized_cost": float(self.normalized_cost),
                "dof": int(self.dof), "chi2": self.chi2, "chi2_dof": self.chi2_dof,
                "reduced_chi2": self.reduced_chi2, "chi2_pvalue": self.chi2_pvalue}

    def _headline(self) -> str:
        return f"model {self.model!r}"

    def summary(self) -> str:
        """A short human-readable table: the fit's statistics, then ``name = value ± std``
        per parameter (slack components marked) and the derived quantities."""
        nu = self.chi2_dof
        lines = [self._headline(),
                 f"  cost L~^2 = {self.cost:.6g}, d = {self.dof}, L~^2/d = "
                 f"{self.normalized_cost:.6g}",
                 f"  chi2 = {self.chi2:.6g}, nu = {nu}, chi2/nu = {self.reduced_chi2:.4g}, "
                 f"p = {self.chi2_pvalue:.3g}"]
        if self.assumed:
            lines.append("  assumed (constants not given): " + ", ".join(
                f"{name} = {value:g}{' ' + self.units[name] if self.units.get(name) else ''}"
                for name, value in self.assumed.items()))
        lines += estimate_lines(self.params, self.slacks, np.asarray(self.std), self.derived,
                                self.units, self.pinned)
        return "\n".join(lines)

    def __repr__(self) -> str:
        params = ", ".join(f"{k}={v:.6g}" for k, v in list(self.params.items())[:8])
        if len(self.params) > 8:
            params += f", ... ({len(self.params)} in all)"
        return (f"{type(self).__name__}(model={self.model!r}, cost={self.cost:.6g}, "
                f"dof={self.dof}, reduced_chi2={self.reduced_chi2:.4g}, "
                f"success={bool(self.success)}, params={{{params}}})")


@dataclass(frozen=True, repr=False)
class FitResult(ResultProtocol):
    """The outcome of :func:`kanagen.fit` (SPEC §2 outputs); the fields common to every
    result are :class:`ResultProtocol`'s.

    Attributes
    ----------
    model : str
    params : dict[str, float]
        Estimated parameter by component name (without slack components).
    q : ndarray (n,)
        Every component, slacks last (their values also in ``slacks``).
    measures : dict[str, ndarray]
        Corrected measures per channel, all columns (exact ones unchanged).
    info : ndarray (n, n)
        Q̃ = Q0 + A at the solution (report eq. 6).
    covariance : ndarray (n, n)
        Covariance of q̃ under the constraints (inverse of the bordered information).
    std : ParameterStd
        Standard deviations by component name (reads as an array too).
    cost : float
        L̃² = ½‖q̃−q0‖²_Q0 + Σ ½‖m̃−m‖²_Q (also ``total_cost``).
    dof : int
        d = n − p + Σ p_i with the ranks kept by the reduced square roots (eq. 7).
    normalized_cost : float
        L̃² / d.
    chi2, chi2_dof, reduced_chi2, chi2_pvalue
        2 L̃², ν = Σ p_i − (n − p), χ²/ν (about 1 when the weights are right), P(χ²_ν ≥ χ²).
    residual : float
        E², the constraint violation in the whitened metric (eq. 13/17).
    iterations, success, status, message
        See :mod:`kanagen.runtime.iterate` for the status codes.
    """

    model: str
    params: dict[str, float]
    q: np.ndarray
    measures: dict[str, np.ndarray]
    info: np.ndarray
    covariance: np.ndarray
    cost: float
    dof: int
    residual: float
    constraint_violation: float
    iterations: int
    success: bool
    status: int
    message: str
    ranks: dict[str, np.ndarray] = field(default_factory=dict)
    derived: dict[str, DerivedValue] = field(default_factory=dict)
    slacks: dict[str, float] = field(default_factory=dict)  # appendix F's added components
    units: dict[str, str] = field(default_factory=dict)  # the spec's units: (display only)
    pinned: dict[str, float] = field(default_factory=dict)  # components the model fixes
    assumed: dict[str, float] = field(default_factory=dict)  # constants' defaults relied on
    #: the second-order bias removed (``correct_bias``: runtime/hyper.py), else None
    bias: np.ndarray | None = None

    @property
    def equations(self) -> int:
        """Σ pᵢ, the equations the measures keep."""
        return int(sum(int(np.sum(r)) for r in self.ranks.values()))

    def _headline(self) -> str:
        return (f"model {self.model!r}: {self.message} after {self.iterations} iteration(s), "
                f"residual E^2 = {self.residual:.3g}")


def estimate_lines(params: dict, slacks: dict, std, derived: dict,
                   units: dict | None = None, pinned: dict | None = None) -> list[str]:
    """Lines ``name = value ± std unit`` for the parameter, then its slack components
    (appendix F; ``std`` covers both, slacks last), then the derived quantities; the
    components the model pins (``pinned``) are no estimates: one line names them last."""
    std = np.asarray(std, dtype=float)
    units, pinned = units or {}, pinned or {}
    values = {**params, **slacks}
    width = max((len(k) for k in values if k not in pinned), default=0)
    lines = []
    for i, (name, value) in enumerate(values.items()):
        if name in pinned:
            continue
        tag = "  (slack)" if name in slacks else ""
        unit = f" {units[name]}" if units.get(name) else ""
        lines.append(f"  {name:<{width}} = {value: .10g}  ± {std[i]:.3g}{unit}{tag}")
    for name, d in derived.items():
        value = np.asarray(d.value)
        unit = f" {units[name]}" if units.get(name) else ""
        if value.ndim == 0:
            lines.append(f"  {name} = {float(value): .10g}  ± {float(d.std):.3g}{unit}")
        else:
            lines.append(f"  {name}{f' ({units[name]})' if unit else ''} =\n"
                         + _indent(np.array2string(value, precision=6)))
            lines.append(f"  {name} std =\n" + _indent(np.array2string(np.asarray(d.std),
                                                                          precision=3)))
    shown = {name: value for name, value in pinned.items() if name not in slacks}
    if shown:
        lines.append("  pinned by the model (not estimated): " + ", ".join(
            f"{name} = {value:.10g}" for name, value in shown.items()))
    return lines


def _indent(text: str, prefix: str = "    ") -> str:
    return "\n".join(prefix + line for line in text.splitlines())


@dataclass(frozen=True, repr=False)
class ModelState(ResultProtocol):
    """One model as estimated so far (report §5, "a model state"); the fields common to
    every result are :class:`ResultProtocol`'s.

    ``cost`` is L̃² (as on :class:`FitResult`; ``normalized_cost`` = L̃²/d is what the
    lattice compares), ``equations`` Σ pᵢ of the fit on the inliers, ``status``
    "estimated" (a verified minimum: ``success``), "null" (the first moment's placeholder)
    or the refinement's message."""

    model: str
    parent: str | None
    params: dict[str, float]
    q: np.ndarray
    info: np.ndarray
    covariance: np.ndarray
    inliers: np.ndarray  # measure ids
    outliers: np.ndarray  # measure ids
    cost: float  # L̃² of the fit on the inliers (L̃²/d: normalized_cost)
    dof: int
    relevance: float
    samples: int
    threshold: float
    accepted: bool  # it beat its parent by the cost factor Φ (the null model: always)
    derived: dict[str, DerivedValue] = field(default_factory=dict)
    status: str = "estimated"
    slacks: dict[str, float] = field(default_factory=dict)  # appendix F's added components
    # every measure's error at the estimate (eq. 24), aligned with the ascending measure ids
    measure_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    errors: np.ndarray = field(default_factory=lambda: np.zeros(0))
    equations: int = 0  # Σ pᵢ of the fit on the inliers
    units: dict[str, str] = field(default_factory=dict)  # the spec's units: (display only)
    pinned: dict[str, float] = field(default_factory=dict)  # components the model fixes
    assumed: dict[str, float] = field(default_factory=dict)  # constants' defaults relied on
    chance: Chance | None = field(default=None, compare=False)  # the NFA, when read

    @property
    def estimated(self) -> bool:
        """False for the placeholder of the first moment (the null model at ``q0``)."""
        return self.samples > 0

    @property
    def success(self) -> bool:
        """The refinement on the inliers reached a verified minimum."""
        return self.status == "estimated"

    def _headline(self) -> str:
        return (f"model {self.model!r} ({self.status}): {len(self.inliers)} inlier(s), "
                f"{len(self.outliers)} outlier(s), relevance {self.relevance:.4g}, "
                f"{self.samples} sample(s)") + self._chance_line()
