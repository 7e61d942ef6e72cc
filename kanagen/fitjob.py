"""One estimation job: a dataset, the options of ``kanagen fit``, and its JSON record.

``kanagen fit`` and ``kanagen batch`` share this: the options (:class:`FitOptions`, validated
here once), the run of one dataset (:func:`run_job`) and the record it makes — the JSON that
``kanagen fit --json`` writes and that ``kanagen batch`` stores per dataset — so a dataset
estimated by either gives the same record, bit for bit.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field

import numpy as np

from .runtime.estimator import Estimator
from .runtime.family import ModelFamily
from .runtime.inputs import parameter_vector
from .runtime.phi import phi as get_phi
from .runtime.scoring import SCORERS

#: Format of the JSON record; extensions add keys, never change existing ones.
RECORD_FORMAT = 2


@dataclass(frozen=True)
class FitOptions:
    """The options of one estimation (``kanagen fit`` / ``kanagen batch``), validated.

    Parameters
    ----------
    scale : float, optional
        ``L*``, the order of magnitude of an inlier's error (eq. 29); default (None): each
        model's χ² quantile of its equations per measure, ``χ²_p(0.999)/p``
        (:func:`~kanagen.runtime.scoring.default_scale`; the record says the one used).
    scorer : str
        ``"relevance"``, ``"ransac"`` or ``"trimmed"``.
    phi : float or str, optional
        Cost factor of every edge of the lattice (default: the spec's factor per edge).
    seed, max_samples : random seed and sample budget of the robust search.
    adaptive : bool
        Each model's samples follow the inlier ratio of its best estimate (eq. 25 as
        samples come; default); False: eq. 25 at an assumed half of inliers.
    model : str, optional
        Robust: search this model only; with ``local``: the model to fit.
    local : bool
        Fit one model to all the measures with the local estimator (no sampling).
    sigma : float or mapping, optional
        Standard deviation of each measured component (info ``1/σ²``; default 1): one
        number for all, or one per component by name (``{"dose": 0.02, "response": 3}``;
        ``"*"``: every component not named), a number or the name of the data's column
        holding one per measure (``{"response": "sd"}``: :func:`read_sigmas`).
    constants : mapping or pairs
        Constants of the spec set at run time.
    max_iter : int
        Iterations of the local estimator (``local`` only).
    start : mapping or pairs
        Starting values of parameters by name (the others keep the spec's): where the local
        fit starts, or the null model's estimate before the robust search's first sample.
    correct_bias : bool
        The hyperaccurate correction (``kanagen.fit(..., correct_bias=True)``) of the local
        fit, or of the chosen model of a search refitted on its inliers.

    Examples
    --------
    >>> FitOptions(scale=4, phi="0.5", constants={"f0": 100}).phi
    0.5
    >>> FitOptions(scale=0)
    Traceback (most recent call last):
    ...
    ValueError: scale (L*) must be positive and finite, got 0
    """

    scale: float | None = None
    scorer: str = "relevance"
    phi: float | str | None = None
    seed: int = 0
    max_samples: int = 2000
    model: str | None = None
    local: bool = False
    sigma: float | tuple[tuple[str, float | str], ...] | None = None
    constants: tuple[tuple[str, float], ...] = field(default=())
    max_iter: int = 100
    start: tuple[tuple[str, float], ...] = field(default=())
    adaptive: bool = True
    correct_bias: bool = False

    def __post_init__(self):
        def put(name, value):
            object.__setattr__(self, name, value)

        if self.scale is not None:
            put("scale", _positive(self.scale, "scale (L*)"))
        put("adaptive", bool(self.adaptive))
        if isinstance(self.sigma, Mapping) or isinstance(self.sigma, list | tuple):
            put("sigma", _sigmas(self.sigma))
        elif self.sigma is not None:
            put("sigma", _positive(self.sigma, "sigma"))
        if self.scorer not in SCORERS:
            raise ValueError(f"unknown scorer {self.scorer!r} (choose from {sorted(SCORERS)})")
        put("phi", _phi_choice(self.phi))
        for name, low in (("seed", 0), ("max_samples", 1), ("max_iter", 1)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer) \
                    or value < low:
                raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
            put(name, int(value))
        put("local", bool(self.local))
        put("correct_bias", bool(self.correct_bias))
        for name in ("constants", "start"):
            put(name, _pairs(getattr(self, name), name))

    def check(self, fam: ModelFamily) -> None:
        """Raise ValueError when the options do not fit the family (model, constants)."""
        if self.model is not None:
            fam.model(self.model)
        fam.constant_vector(dict(self.constants))
        parameter_vector(fam, dict(self.start), "--start")

    def plain_sigma(self) -> float | dict[str, float | str] | None:
        """``sigma`` as JSON data: a number, or a mapping by component."""
        return dict(self.sigma) if isinstance(self.sigma, tuple) else self.sigma

    def q0(self) -> dict[str, float] | None:
        """The start as :func:`kanagen.fit` and :class:`Estimator` take it (``q0``)."""
        return dict(self.start) or None

    def to_dict(self) -> dict:
        """Plain JSON data (constants and start as mappings)."""
        out = asdict(self)
        out["constants"] = dict(self.constants)
        out["start"] = dict(self.start)
        out["sigma"] = self.plain_sigma()
        if not self.correct_bias:  # the keys of results databases written before it
            del out["correct_bias"]
        return out

    def key(self, channel: str) -> str:
        """Canonical JSON of the options with the channel: the same options, the same text
        (what a batch run's resume matches on)."""
        return json.dumps({**self.to_dict(), "channel": channel}, sort_keys=True,
                          separators=(",", ":"))


def _pairs(value, what: str) -> tuple[tuple[str, float], ...]:
    """A mapping or pairs of names and finite numbers, sorted (one canonical form)."""
    items = value.items() if isinstance(value, Mapping) else value
    try:
        pairs = tuple(sorted((str(k), float(v)) for k, v in items))
    except (TypeError, ValueError):
        raise ValueError(f"{what} must map names to numbers, got {value!r}") from None
    for name, number in pairs:
        if not math.isfinite(number):
            raise ValueError(f"{what} {name}: the value must be finite, got {number}")
    return pairs


def _sigmas(value) -> tuple[tuple[str, float | str], ...]:
    """σ by component name, sorted: a positive number, or a data column's name (a string
    that is not a number)."""
    items = value.items() if isinstance(value, Mapping) else value
    try:
        pairs = [(str(name), sigma) for name, sigma in items]
    except (TypeError, ValueError):
        raise ValueError(f"sigma must map component names to numbers or column names, got "
                         f"{value!r}") from None
    out = {}
    for name, sigma in pairs:
        column = _column(sigma, name)
        out[name] = column if column is not None else _positive(sigma, f"sigma {name}")
    return tuple(sorted(out.items()))


def _column(sigma, name: str) -> str | None:
    """The column a σ names (a string that is not a number), else None."""
    if not isinstance(sigma, str):
        return None
    try:
        float(sigma)
    except ValueError:
        if not sigma.strip():
            raise ValueError(f"sigma {name}: an empty column name") from None
        return sigma.strip()
    return None


def _positive(value, what: str) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError):
        out = math.nan
    if not (out > 0 and math.isfinite(out)):
        raise ValueError(f"{what} must be positive and finite, got {value!r}")
    return out


def _phi_choice(choice):
    """A number stays a number ("0.5" too); a named factor is checked now: the estimator
    would only meet a bad one in the middle of the search."""
    if choice is None:
        return None
    if isinstance(choice, str):
        try:
            choice = float(choice)
        except ValueError:
            choice = choice.strip()
    elif not isinstance(choice, int | float) or isinstance(choice, bool):
        raise ValueError(f"phi must be a number or a name, got {choice!r}")
    try:
        get_phi(choice)
    except ValueError as exc:
        raise ValueError(f"phi: {exc}") from None
    return float(choice) if not isinstance(choice, str) else choice


def resolve_channel(fam: ModelFamily, channel: str | None) -> str:
    """The channel named, or the family's only one; ValueError otherwise."""
    if channel is None:
        if len(fam.channels) != 1:
            raise ValueError(f"a channel is required: the family has channels "
                             f"{list(fam.channels)}")
        return next(iter(fam.channels))
    fam.channel(channel)
    return channel


def make_estimator(fam: ModelFamily, X: np.ndarray, channel: str,
                   opts: FitOptions, sigmas: np.ndarray | None = None) -> Estimator:
    """The robust lattice search of one dataset, measures in, not yet run (``sigmas``:
    :func:`read_sigmas`' columns, if any)."""
    est = Estimator(fam, scale=opts.scale, scorer=opts.scorer, phi=opts.phi, seed=opts.seed,
                    channel=channel, constants=dict(opts.constants), model=opts.model,
                    q0=opts.q0(), adaptive=opts.adaptive)
    est.add_measures(channel, X, info=channel_info(opts, fam, channel, sigmas))
    return est


def channel_info(opts: FitOptions, fam: ModelFamily, channel: str,
                 sigmas: np.ndarray | None = None) -> float | np.ndarray | None:
    """The channel's information of ``opts.sigma``: ``1/σ²``, or the diagonal matrix of
    each component's (``"*"``: the components not named; else 1), one per measure where a
    component's σ is a column (``sigmas``: those columns, in :func:`sigma_columns`' order)."""
    if opts.sigma is None or not isinstance(opts.sigma, tuple):
        return None if opts.sigma is None else opts.sigma**-2
    components = list(fam.channel(channel).components)
    given = dict(opts.sigma)
    unknown = sorted(set(given) - set(components) - {"*"})
    if unknown:
        raise ValueError(f"sigma names {', '.join(map(repr, unknown))}, not a component of "
                         f"channel {channel!r} (its components: {components}; '*': the "
                         "others)")
    default = given.get("*", 1.0)
    if isinstance(default, str):
        raise ValueError("sigma '*' (the components not named) must be a number")
    columns = sigma_columns(opts)
    if columns and (sigmas is None or sigmas.shape[1] != len(columns)):
        raise ValueError(f"sigma of {list(columns)} from the data's columns "
                         f"{list(columns.values())}: not read")
    per = np.empty((len(sigmas) if columns else 1, len(components)))
    for a, name in enumerate(components):
        value = given.get(name, default)
        per[:, a] = sigmas[:, list(columns).index(name)] if isinstance(value, str) else value
    info = per**-2.0
    return info[:, :, None] * np.eye(len(components)) if columns else np.diag(info[0])


def sigma_columns(opts: FitOptions) -> dict[str, str]:
    """The components whose σ is a column of the data: ``{component: column}``."""
    if not isinstance(opts.sigma, tuple):
        return {}
    return {name: value for name, value in opts.sigma if isinstance(value, str)}


def read_sigmas(path, opts: FitOptions, channel: str) -> np.ndarray | None:
    """Each measure's σ of the components named by a column (:func:`sigma_columns`), from
    the data file's columns of those names (a CSV with a header, or JSON rows of named
    values); None when there is none. Raises ``DataError`` naming the file, the column
    and the row where a σ is not a positive number."""
    from .dataio import DataError, read_measures

    columns = sigma_columns(opts)
    if not columns:
        return None
    if str(path).lower().endswith(".npz"):
        raise DataError(f"{path}: sigma from columns {list(columns.values())} needs a file "
                        "with named columns (CSV with a header, or JSON)")
    try:
        values = read_measures(path, tuple(columns.values()), channel)
    except DataError as exc:
        raise DataError(f"{exc} (the sigma columns {list(columns.values())})") from None
    bad = ~(values > 0)  # NaN too (read_measures refuses the infinite already)
    if bad.any():
        row, col = (int(v) for v in np.argwhere(bad)[0])
        raise DataError(f"{path}: column {list(columns.values())[col]!r}, measure {row}: "
                        f"sigma {values[row, col]} is not a positive number")
    return values


def search(est: Estimator, max_samples: int,
           on_sample: Callable[[Estimator], None] | None = None) -> int:
    """Run the estimator up to ``max_samples`` samples (:meth:`Estimator.run`: the adaptive
    budgets share them); returns the samples drawn. ``on_sample(est)``: called after each
    sample (the samples then go one at a time)."""
    before = est.samples
    if on_sample is None:
        est.run(max_samples=max_samples)
    else:
        def until(history) -> bool:
            on_sample(est)
            return False

        est.run(max_samples=max_samples, until=until)
    return est.samples - before


def corrected_choice(est: Estimator, fam: ModelFamily, opts: FitOptions, channel: str,
                     X: np.ndarray, sigmas: np.ndarray | None = None):
    """``--correct-bias`` after a search: the chosen model refitted on its inliers from its
    estimate, less its second-order bias (a FitResult; None without a chosen model)."""
    from .runtime.fit import fit

    best = est.best()
    if not _found(best):
        return None
    rows = np.asarray(best.inliers, dtype=int)
    info = {channel: channel_info(opts, fam, channel,
                                  None if sigmas is None else sigmas[rows])}
    return fit(fam, best.model, data={channel: X[rows]}, info=info,
               constants=dict(opts.constants), q_start=best.q, max_iter=opts.max_iter,
               correct_bias=True)


def _found(best) -> bool:
    """A search chose a model: a state grown from samples, with a finite estimate."""
    return best is not None and best.samples > 0 and bool(np.all(np.isfinite(best.q)))


def robust_record(est: Estimator, fam: ModelFamily, opts: FitOptions, *, channel: str,
                  X: np.ndarray, samples: int, spec: str, data: str,
                  interrupted: bool = False, corrected=None) -> dict:
    """The JSON record of a robust search (``kanagen fit --json``); ``"found"`` says whether
    a model was found. ``corrected``: the chosen model's :func:`corrected_choice`, whose
    estimate the record then carries, with the ``bias`` removed."""
    best = est.best()
    found = _found(best)
    status = f"interrupted ({est.status})" if interrupted else est.status
    if not interrupted and samples >= opts.max_samples and est.status != "done":
        status = f"stopped at --max-samples {opts.max_samples} ({est.status})"
    record = estimator_to_json(est, best.model if found else None, len(X))
    record.update(record_header(fam, channel, spec, data, X))
    # L*: the chosen model's (given, or its default), each model's, and whether given
    chosen = best.model if best is not None else None
    scale = opts.scale if opts.scale is not None else est.scales.get(chosen)
    record.update({"scale": scale, "scales": dict(est.scales),
                   "scale_given": opts.scale is not None, "adaptive": opts.adaptive,
                   "planned_samples": est.planned, "scorer": opts.scorer, "phi": opts.phi,
                   "seed": opts.seed, "max_samples": opts.max_samples, "measures": len(X),
                   "start": dict(opts.start), "sigma": opts.plain_sigma(),
                   "total_samples": samples, "status": est.status, "stop_reason": status,
                   "found": found})
    if found and corrected is not None:
        record.update(estimate_json(corrected))
        record.update({"bias": np.asarray(corrected.bias), "model_status": corrected.message})
    return record


def local_record(fam: ModelFamily, X: np.ndarray, channel: str, opts: FitOptions, *,
                 spec: str, data: str, sigmas: np.ndarray | None = None):
    """The local fit of one model to all the measures: ``(FitResult, JSON record)``."""
    from .runtime.coherence import coherence
    from .runtime.fit import fit

    info = {channel: channel_info(opts, fam, channel, sigmas)}
    constants = dict(opts.constants)
    res = fit(fam, opts.model, data={channel: X}, info=info, constants=constants,
              q0=opts.q0(), max_iter=opts.max_iter, correct_bias=opts.correct_bias)
    record = result_to_json(res)
    errors = np.full(len(X), np.nan)
    if np.all(np.isfinite(res.q)):
        errors = coherence(fam, res.model, res.q, {channel: X}, info, constants)[channel]
    record.update(record_header(fam, channel, spec, data, X))
    record.update({"local": True, "errors": errors, "found": bool(res.success),
                   "stop_reason": res.message, "max_iter": opts.max_iter,
                   "start": dict(opts.start), "sigma": opts.plain_sigma()})
    return res, record


def measures_sha256(X: np.ndarray) -> str:
    """The hash of a dataset's measures as read (float64): a record names its data file with
    it, so a report reads only a file that holds those very measures."""
    return hashlib.sha256(np.ascontiguousarray(X, dtype=float).tobytes()).hexdigest()


def record_header(fam: ModelFamily, channel: str, spec: str, data: str,
                  X: np.ndarray) -> dict:
    """What every record of a dataset says first: the family, spec and data (with their
    SHA-256), the channel and the lattice's edges."""
    return {"format": RECORD_FORMAT, "family": fam.name, "spec": str(spec),
            "spec_sha256": fam.sha256, "data": str(data),
            "data_sha256": measures_sha256(X), "channel": channel,
            "channel_components": list(fam.channel(channel).components),
            "edges": [[m, alt, phi] for m, info in fam.models.items()
                      for alt, phi in info.alternatives],
            "null_model": fam.null_model}


def run_job(fam: ModelFamily, X: np.ndarray, channel: str, opts: FitOptions, *,
            spec: str, data: str, sigmas: np.ndarray | None = None) -> dict:
    """Estimate one dataset without a terminal (``kanagen batch``): the record that
    ``kanagen fit --json`` writes for the same dataset and options, made plain JSON data."""
    if opts.local:
        return finite(local_record(fam, X, channel, opts, spec=spec, data=data,
                                   sigmas=sigmas)[1])
    est = make_estimator(fam, X, channel, opts, sigmas)
    samples = search(est, opts.max_samples)
    corrected = corrected_choice(est, fam, opts, channel, X, sigmas) \
        if opts.correct_bias else None
    return finite(robust_record(est, fam, opts, channel=channel, X=X, samples=samples,
                                spec=spec, data=data, corrected=corrected))


def finite(obj):
    """Plain JSON data: arrays as lists, inf and NaN as null."""
    if isinstance(obj, dict):
        return {str(k): finite(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [finite(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return finite(obj.tolist())
    if isinstance(obj, np.generic):
        return finite(obj.item())
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def estimator_to_json(est: Estimator, chosen: str | None, measures: int | None = None) -> dict:
    """An Estimator's lattice and chosen model as JSON data (inf and NaN as null after
    :func:`finite`); ``errors[i]`` is measure ``i``'s error under the chosen model (eq. 24;
    ``measures`` long, ids from 0). The costs mean what they mean on every result (and in
    :func:`result_to_json`): ``cost`` is L~^2, ``normalized_cost`` L~^2/d (the lattice's
    comparison); the chosen model also has ``chi2`` = 2 L~^2, ``chi2_dof``, ``reduced_chi2``
    and ``chi2_pvalue``, and ``false_alarms``, its NFA (at most 1: more than chance)."""
    lattice = [{"model": s.model, "parent": s.parent, "dof": s.dof, "cost": s.cost,
                "normalized_cost": s.normalized_cost, "reduced_chi2": s.reduced_chi2,
                "relevance": s.relevance, "inliers": len(s.inliers), "outliers": len(s.outliers),
                "samples": s.samples, "accepted": s.accepted, "threshold": s.threshold,
                "status": s.status, "chosen": s.model == chosen}
               for s in est.states()]
    out = {"model": chosen, "lattice": lattice, "probes": est.probes,
           "history": [[int(n), float(r)] for n, r in est.history]}
    best = est.best() if chosen is not None else None
    if best is None:
        return out
    errors = np.full(measures if measures is not None else best.measure_ids.size, np.nan)
    inside = best.measure_ids < errors.size
    errors[best.measure_ids[inside]] = best.errors[inside]
    out.update({
        **estimate_json(best),
        "relevance": best.relevance,
        "false_alarms": best.false_alarms,
        "threshold": best.threshold,
        "samples": best.samples,
        "inliers": np.asarray(best.inliers, dtype=int),
        "outliers": np.asarray(best.outliers, dtype=int),
        "errors": errors,
        "model_status": best.status,
    })
    return out


def estimate_json(res) -> dict:
    """What every result's record says (the result protocol): the estimate and its std by
    name (the components the model pins apart, in ``pinned``), covariance and information
    over ``components``, the costs and χ² statistics, the derived quantities, the spec's
    units."""
    def arr(a):
        return np.asarray(a).tolist()

    return {
        "params": dict(res.params),
        "std": dict(zip(res.params, arr(res.std), strict=False)),
        "slacks": dict(res.slacks),
        "pinned": dict(res.pinned),
        "units": dict(res.units),
        "assumed": dict(res.assumed),  # constants' defaults the fit relied on (not given)
        "components": [*res.params, *res.slacks],  # rows of covariance and info
        "covariance": arr(res.covariance),
        "info": arr(res.info),
        **res.goodness_of_fit(),  # cost (L~^2), normalized_cost, dof, chi2, ...
        "derived": {k: {"value": arr(v.value), "std": arr(v.std)}
                    for k, v in res.derived.items()},
    }


def result_to_json(res) -> dict:
    """A FitResult as JSON data (inf and NaN as null after :func:`finite`): the protocol's
    record (:func:`estimate_json`), then the local fit's own fields."""
    def arr(a):
        return np.asarray(a).tolist()

    return {
        "model": res.model,
        **estimate_json(res),
        "residual": res.residual,
        "iterations": res.iterations,
        "success": res.success,
        "status": res.status,
        "message": res.message,
        "measures": {k: arr(v) for k, v in res.measures.items()},
    }
