"""The local estimator: ``fit`` runs the iterated projector on one model (SPEC §2)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import replace

import numpy as np

from .engine.data import arrays, model_rows
from .family import ModelFamily
from .hyper import corrected
from .inputs import channel_data, data_hint, describe, parameter_vector, prior_information
from .iterate import CONVERGED, Projected, iterate
from .minimal import minimal_solve_problem
from .projector import Problem, evaluate, project
from .reduce import reduced_problem
from .results import DerivedQuantities, FitResult, constrained_covariance
from .sqrt import EPS


def make_problem(fam: ModelFamily, model: str, data: Mapping | None = None,
                 info: Mapping | None = None, q0=None, Q0=None, constants=None,
                 eps: float = EPS, exact: Mapping | None = None, *,
                 channels: tuple | None = None, checked: bool = False) -> Problem:
    """Validate the inputs and bundle everything the projector needs.

    ``channels``: the measures validated already (:func:`channel_data`'s), instead of
    ``data``, ``info`` and ``exact``; ``checked``: ``q0`` and ``Q0`` are validated arrays
    already (the estimator's, one problem per model)."""
    fam.model(model)
    if channels is None:
        channels = tuple(channel_data(fam, {} if data is None else data, info, exact))
    k = fam.constant_vector(constants)
    c0, measures, strict, rows = _model_parts(fam, model, tuple(ch.name for ch in channels))
    return Problem(
        c0=c0,
        measures=measures,
        channels=channels,
        q0=q0 if checked else parameter_vector(fam, q0),
        Q0=Q0 if checked else prior_information(Q0, fam.n),
        k=k,
        eps=eps,
        relations=(lambda q: fam.relations_hold(model, q, k)) if fam.slack_names else None,
        strict_slacks=strict,
        names=fam.parameter_names,
        rows=rows,
    )


def _model_parts(fam: ModelFamily, model: str, channels: tuple[str, ...]) -> tuple:
    """What a problem of ``model`` on ``channels`` takes from the family — the constraints'
    and the channels' functions, the strict slacks, the row kernels — looked up once per
    model and channels (the Python before a fit's kernel runs with the interpreter's caches
    cold: every lookup saved counts two to three times)."""
    cache = fam.__dict__.setdefault("_model_parts", {})
    key = (model, channels)
    parts = cache.get(key)
    if parts is None:
        parts = cache[key] = (
            fam.c0_function(model),
            tuple(fam.measurement_function(model, name) for name in channels),
            fam.strict_slacks(model), model_rows(fam, model))
    return parts



def fit(fam: ModelFamily, model: str | None = None, data: Mapping | None = None,
        info: Mapping | None = None, q0=None, Q0=None, constants=None, *, q_start=None,
        exact: Mapping | None = None, max_iter: int = 100, xtol: float = 1e-10,
        eps: float = EPS, correct_bias: bool | str = False) -> FitResult:
    """Estimate the parameter of one model and correct the measures (report §2–3).

    Parameters
    ----------
    fam : ModelFamily
        From :func:`kanagen.load`.
    model : str, optional
        Model name; default the family's null model.
    data : dict
        ``{channel: array (M, components)}``, columns in the spec's component order.
    info : dict, optional
        ``{channel: Q}`` with Q a scalar, a (k, k) matrix, (M,) scalars or (M, k, k), over the
        corrected components; default identity.
    q0 : array or dict, optional
        Prior / starting parameter; default the spec's values.
    Q0 : optional
        Prior information on q (scalar, diagonal or matrix); default 0.
    constants : dict, optional
        Run-time values of the spec's constants.
    q_start : array, optional
        Starting point of the iteration when it should differ from ``q0``.
    exact : dict, optional
        Measured values known exactly (ODRPACK's ``ifixx``): ``{channel: {component: mask}}``
        with a mask of (M,) booleans or measure indices, or ``{channel: (M, components)
        booleans}``. Their corrections stay zero; the other components of those measures are
        corrected with the information of the free components.
    max_iter, xtol, eps
        Iteration cap, step tolerance, square-root pivot threshold.
    correct_bias : bool or "relative"
        Remove the second-order bias of the ML estimate (Kanatani's hyperaccurate
        correction, :mod:`kanagen.runtime.hyper`): the noise from ``info`` as given
        (True), or from the fit's reduced χ² when ``info`` is only relative
        (``"relative"``). The result's ``bias`` holds what was removed; its covariance is
        the ML one.

    Returns
    -------
    FitResult

    Examples
    --------
    >>> import numpy as np, kanagen
    >>> fam = kanagen.load("examples/line.yaml")  # doctest: +SKIP
    >>> res = kanagen.fit(fam, "line", data={"point": np.array([[0., 1.], [1., 3.], [2., 5.]])})
    ... # doctest: +SKIP
    """
    if model is not None and not isinstance(model, str):  # fit(fam, X): measures as model
        raise ValueError(f"model must be a model name (family {fam.name!r} has "
                         f"{list(fam.models)}), got {describe(model)}; pass the measures "
                         f"as {data_hint(fam)}")
    model = model or fam.null_model
    check_options(max_iter, xtol, eps)
    check_correct_bias(correct_bias)
    problem = make_problem(fam, model, {} if data is None else data, info, q0, Q0, constants,
                           eps, exact)
    if not any(ch.size for ch in problem.channels) and not np.any(problem.Q0):
        raise ValueError("nothing to estimate: no measures (data has no rows) and no prior "
                         "information (Q0)")
    check_determined(fam, model, problem, constants)
    start = problem.q0 if q_start is None else parameter_vector(fam, q_start, "q_start")
    assumed = fam.warn_assumed(constants)
    res = fit_problem(fam, model, problem, q_start=start, max_iter=max_iter, xtol=xtol)
    if correct_bias:
        res = corrected(fam, model, problem, res, relative=correct_bias == "relative")
    return replace(res, assumed=assumed) if assumed else res


def check_determined(fam: ModelFamily, model: str, problem: Problem, constants) -> None:
    """Fewer equations than the parameter's free degrees of freedom, and no prior: the
    estimate is not determined (a continuum of exact fits). A ValueError, as ODRPACK's and
    MINPACK's refusals of fewer observations than parameters."""
    measures = sum(ch.size for ch in problem.channels)
    if measures >= problem.q0.size or np.any(problem.Q0):  # an equation at least each
        return
    A = arrays(problem)  # made once: the fit's own
    count = int(A.P @ A.size)
    free = fam.free_dof(model, constants)
    if count < free:
        raise ValueError(f"too few measures for model {model!r}: {measures} measure(s) give "
                         f"{count} equation(s), fewer than the {free} degrees of freedom of "
                         f"its parameter; the estimate would not be determined (add "
                         f"measures, or prior information Q0)")


def check_correct_bias(correct_bias) -> None:
    """``correct_bias`` is False, True or ``"relative"``."""
    if correct_bias is not False and correct_bias is not True and correct_bias != "relative":
        raise ValueError(f"correct_bias must be False, True or 'relative', got "
                         f"{correct_bias!r}")


def check_options(max_iter, xtol, eps) -> None:
    """The local estimator's options: an iteration cap (an integer, at least 0), a step
    tolerance and a pivot threshold (positive and finite)."""
    if type(max_iter) is int and max_iter >= 0 and isinstance(xtol, float) and \
            0 < xtol < math.inf and isinstance(eps, float) and 0 < eps < math.inf:
        return  # the common case: Python numbers (or NumPy's: the default eps is one)
    if isinstance(max_iter, bool) or not isinstance(max_iter, int | np.integer) or \
            max_iter < 0:
        raise ValueError(f"max_iter must be an integer >= 0, got {max_iter!r}")
    for name, value in (("xtol", xtol), ("eps", eps)):
        if isinstance(value, bool) or not isinstance(value, int | float | np.floating) or \
                not 0 < value < np.inf:
            raise ValueError(f"{name} must be a positive finite number, got {value!r}")


def fit_problem(fam: ModelFamily, model: str, problem: Problem, q_start=None, q0=None,
                Q0=None, max_iter: int = 100, xtol: float = 1e-10,
                verify: bool = True, brief: bool = False, derive: bool = True) -> FitResult:
    """:func:`fit` on a validated problem (optionally with another prior ``q0``, ``Q0``);
    ``verify=False``: its end is not checked (:func:`~.iterate.iterate`; never a success).
    ``brief``: a hypothesis whose estimate alone is used (a robust search's local
    optimisation): nothing is projected at the returned point — its information and
    covariance are NaN, its ranks 0, no derived quantities — and it is never a success.
    ``derive=False``: no derived quantities (a fit that may be superseded: the caller
    derives them for the one it keeps, :func:`~kanagen.runtime.results.derived_values`)."""
    if (q0 is not None and q0 is not problem.q0) or (Q0 is not None and Q0 is not problem.Q0):
        problem = replace(problem, q0=problem.q0 if q0 is None else q0,
                          Q0=problem.Q0 if Q0 is None else Q0)
    start = problem.q0 if q_start is None else np.asarray(q_start, dtype=float)
    start = fam.with_slacks(start, problem.k, model)  # its slacks consistent with the start
    start = _inside(problem, start)
    red = fam.reduction(model)
    if red is None:
        out = iterate(problem, start, max_iter=max_iter, xtol=xtol, verify=verify,
                      report=not brief)
        x, projected = out, out.projected  # x: the returned point's q, mt, cost, delta
    else:  # iterate in the free components (report §6); outputs from the full model
        out = iterate(reduced_problem(fam, model, problem, red), start[red.free],
                      max_iter=max_iter, xtol=xtol, verify=verify)
        with np.errstate(all="ignore"):
            x = evaluate(problem, red.full(out.q), out.mt)
        projected = None
    if brief:  # a hypothesis: no outputs at the returned point
        projected, derive = None, False
    elif projected is None:  # the outputs are taken at the returned point
        projected = _projected(problem, out.point if x is out else x)
    n = fam.n
    if projected is not None:
        info_q, rank0, ranks, residual = (projected.info, projected.rank0, projected.ranks,
                                          projected.residual)
        covariance = projected.covariance if projected.covariance is not None else \
            constrained_covariance(info_q, projected.C0)
    else:
        info_q, rank0, residual = np.full((n, n), np.nan), 0, np.nan
        ranks = tuple(np.zeros(ch.size, dtype=int) for ch in problem.channels)
        covariance = np.full((n, n), np.nan)
    kept, every = _kept(ranks)
    dof = n - rank0 + kept
    success = not brief and out.status == CONVERGED and \
        _feasible(x, out.start_violation, residual, every)
    measures = {ch.name: ch.with_corrected(m) for ch, m in zip(problem.channels, x.mt,
                                                                 strict=True)}
    return FitResult(
        model=model,
        params=fam.params_dict(x.q),
        q=x.q.copy(),
        measures=measures,
        info=info_q,
        covariance=covariance,
        cost=x.cost,
        dof=dof,
        residual=residual,
        constraint_violation=x.delta,
        iterations=out.iterations,
        success=bool(success),
        status=out.status,
        message=out.message,
        ranks={ch.name: r for ch, r in zip(problem.channels, ranks, strict=True)},
        derived=DerivedQuantities(fam, x.q, covariance, problem.k, model) if derive else {},
        slacks=fam.slack_dict(x.q),
        units=fam.units,
        pinned=fam.pinned(model),
    )


def _projected(problem: Problem, x) -> Projected | None:
    """:class:`~.iterate.Projected` at ``x`` from the projector (None where it fails)."""
    try:
        with np.errstate(all="ignore"):
            lin, proj = project(problem, x)
    except (np.linalg.LinAlgError, ValueError):
        return None
    return Projected(lin.info, lin.ranks, proj.C0, proj.rank0, proj.residual)


def _inside(problem: Problem, start: np.ndarray) -> np.ndarray:
    """A start where the model's inequalities (appendix F) do not hold is first moved onto
    its constraints: the closest point satisfying ``c0`` (eq. 21 with no measures). From
    outside, a squared slack cannot follow: linearised, ``c − s² = 0`` with ``c < 0`` asks
    the free slack to absorb the violation, and it oscillates about zero instead."""
    if problem.relations is None or problem.relations(start):
        return start
    sol = minimal_solve_problem(problem.subset(tuple(np.zeros(0, dtype=int)
                                             for _ in problem.channels)), start)
    return sol.q if sol.success and problem.relations(sol.q) else start


def _kept(ranks) -> tuple[int, bool]:
    """The equations the measures keep (``Σ pᵢ``, per channel's ranks ``ranks``) and
    whether every measure keeps one."""
    kept, every = 0, True
    for r in ranks:  # as Python integers: a few measures' ranks, summed without NumPy's calls
        values = r.tolist()
        kept += sum(values)
        every = every and 0 not in values
    return kept, every


def _feasible(x, start_violation: float, residual: float, every: bool) -> bool:
    """The equations hold at ``x``. With every measure keeping its equations (``every``),
    the whitened violation E² must be negligible against the cost (scale-free); when a
    vanishing gradient dropped some equation (E² no longer sees it), the raw violation must
    have fallen by six orders of magnitude from the start."""
    if x.delta == 0.0:
        return True
    if every:
        return math.isfinite(residual) and residual <= 1e-10 * max(1.0, x.cost)
    return x.delta <= 1e-6 * start_violation
