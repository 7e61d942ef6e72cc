"""NIST StRD nonlinear least-squares suite: kanagen against ``scipy.optimize.least_squares``.

The 27 problems of the NIST Statistical Reference Datasets for nonlinear regression, each with
its two official starting values (54 cases), are fitted by

* kanagen (:func:`run_kanagen`): the response is a *corrected* component with unit information,
  the predictors are *exact*, so the Kanatani cost ``1/2 sum (y - f(x; b))**2`` is the ordinary
  least-squares cost NIST certifies;
* SciPy's trust-region reflective solver (:func:`run_scipy`), fed with the exact residual and
  Jacobian that kanagen generated for the same spec (:meth:`Family.measurement`).

Accuracy is NIST's log relative error (:func:`lre`); a case is *solved* when every parameter
agrees with the certified value to at least :data:`SOLVED_DIGITS` significant digits.

Nelson is the one problem whose fitted response is transformed: NIST minimises
``sum (log(y) - f)**2``. Its spec, as written by :func:`spec_text`, has the equation
``log(y) - (f) = 0`` with ``y`` corrected; kanagen then solves the *errors-in-y* maximum
likelihood problem ``min 1/2 sum info*(y_hat - y)**2`` subject to ``log(y_hat) = f`` -- a
different estimator, whose minimiser is not NIST's (no weighting makes them equal: ``log`` is
not linear). The certified comparison therefore poses Nelson exactly as NIST does, with
``transformed=True``: the data column is ``logy = log(y)`` and the equation ``logy - (f)``.
The literal ``log(y)`` spec is checked against its own optimum, :func:`run_scipy` with
``objective="ml"``.

The data are the original NIST ``.dat`` files, never copied into the repository. They are read
from ``<repo>/../shared/data/nist_strd_nls/`` or from ``$KANAGEN_DATA/nist_strd_nls/`` (or
``$KANAGEN_DATA`` itself when it holds the ``.dat`` files).

Run ``python benchmarks/nist_strd.py`` (options: ``--repeats``, ``--problems``) for the table.
"""

from __future__ import annotations

import argparse
import functools
import math
import os
import re
import statistics
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

#: Environment variable overriding the shared data root (the folder holding ``nist_strd_nls``).
DATA_ENV = "KANAGEN_DATA"
#: Folder of the NIST files inside the data root.
SUBDIR = "nist_strd_nls"
#: Significant digits every parameter must reach for a case to count as solved.
SOLVED_DIGITS = 6.0
#: Cap of :func:`lre` (the certified values carry 11 significant digits).
LRE_CAP = 11.0
#: Name of the kanagen model and channel in every generated spec.
MODEL = "nls"
CHANNEL = "obs"

#: The 27 StRD nonlinear regression problems, in NIST's order of difficulty (lower, average,
#: higher), alphabetical within a level.
PROBLEMS: tuple[str, ...] = (
    # lower difficulty
    "Misra1a",
    "Chwirut2",
    "Chwirut1",
    "Lanczos3",
    "Gauss1",
    "Gauss2",
    "DanWood",
    "Misra1b",
    # average difficulty
    "Kirby2",
    "Hahn1",
    "Nelson",
    "MGH17",
    "Lanczos1",
    "Lanczos2",
    "Gauss3",
    "Misra1c",
    "Misra1d",
    "Roszman1",
    "ENSO",
    # higher difficulty
    "MGH09",
    "Thurber",
    "BoxBOD",
    "Rat42",
    "MGH10",
    "Eckerle4",
    "Rat43",
    "Bennett5",
)

#: Model functions ``f(x; b)`` transcribed from the "Model:" lines of the ``.dat`` files, in
#: kanagen expression syntax (NIST's ``[]`` are parentheses, ``arctan`` is ``atan``).
MODELS: dict[str, str] = {
    "Bennett5": "b1*(b2 + x)**(-1/b3)",
    "BoxBOD": "b1*(1 - exp(-b2*x))",
    "Chwirut1": "exp(-b1*x)/(b2 + b3*x)",
    "Chwirut2": "exp(-b1*x)/(b2 + b3*x)",
    "DanWood": "b1*x**b2",
    "ENSO": (
        "b1 + b2*cos(2*pi*x/12) + b3*sin(2*pi*x/12)"
        " + b5*cos(2*pi*x/b4) + b6*sin(2*pi*x/b4)"
        " + b8*cos(2*pi*x/b7) + b9*sin(2*pi*x/b7)"
    ),
    "Eckerle4": "(b1/b2)*exp(-0.5*((x - b3)/b2)**2)",
    "Gauss1": "b1*exp(-b2*x) + b3*exp(-(x - b4)**2/b5**2) + b6*exp(-(x - b7)**2/b8**2)",
    "Gauss2": "b1*exp(-b2*x) + b3*exp(-(x - b4)**2/b5**2) + b6*exp(-(x - b7)**2/b8**2)",
    "Gauss3": "b1*exp(-b2*x) + b3*exp(-(x - b4)**2/b5**2) + b6*exp(-(x - b7)**2/b8**2)",
    "Hahn1": "(b1 + b2*x + b3*x**2 + b4*x**3)/(1 + b5*x + b6*x**2 + b7*x**3)",
    "Kirby2": "(b1 + b2*x + b3*x**2)/(1 + b4*x + b5*x**2)",
    "Lanczos1": "b1*exp(-b2*x) + b3*exp(-b4*x) + b5*exp(-b6*x)",
    "Lanczos2": "b1*exp(-b2*x) + b3*exp(-b4*x) + b5*exp(-b6*x)",
    "Lanczos3": "b1*exp(-b2*x) + b3*exp(-b4*x) + b5*exp(-b6*x)",
    "MGH09": "b1*(x**2 + x*b2)/(x**2 + x*b3 + b4)",
    "MGH10": "b1*exp(b2/(x + b3))",
    "MGH17": "b1 + b2*exp(-x*b4) + b3*exp(-x*b5)",
    "Misra1a": "b1*(1 - exp(-b2*x))",
    "Misra1b": "b1*(1 - (1 + b2*x/2)**(-2))",
    "Misra1c": "b1*(1 - (1 + 2*b2*x)**(-0.5))",
    "Misra1d": "b1*b2*x*((1 + b2*x)**(-1))",
    "Nelson": "b1 - b2*x1*exp(-b3*x2)",
    "Rat42": "b1/(1 + exp(b2 - b3*x))",
    "Rat43": "b1/((1 + exp(b2 - b3*x))**(1/b4))",
    "Roszman1": "b1 - b2*x - atan(b3/(x - b4))/pi",
    "Thurber": "(b1 + b2*x + b3*x**2 + b4*x**3)/(1 + b5*x + b6*x**2 + b7*x**3)",
}

#: Transformed responses: NIST fits ``log[y]`` for Nelson; every other problem fits ``y``.
RESPONSES: dict[str, str] = {"Nelson": "log(y)"}
#: Transformed response -> (name of the data column holding it, function computing it).
TRANSFORMS: dict[str, tuple[str, Any]] = {"log(y)": ("logy", np.log)}


# --------------------------------------------------------------------------------------------
# Data
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Problem:
    """One NIST StRD nonlinear regression problem.

    Attributes
    ----------
    name : str
        NIST dataset name, e.g. ``"Misra1a"``.
    y : numpy.ndarray, shape (N,)
        Response.
    x : numpy.ndarray, shape (N, nx)
        Predictors, columns in the order of :attr:`predictors`.
    starts : numpy.ndarray, shape (2, nb)
        NIST's "Start 1" and "Start 2" parameter vectors.
    certified : numpy.ndarray, shape (nb,)
        Certified parameter values.
    certified_std : numpy.ndarray, shape (nb,)
        Certified standard deviations of the parameters.
    certified_rss : float
        Certified residual sum of squares.
    certified_rsd : float
        Certified residual standard deviation.
    dof : int
        Degrees of freedom ``N - nb``.
    expression : str
        The equation ``response - (model) = 0`` in kanagen syntax, e.g.
        ``"y - (b1*(1 - exp(-b2*x)))"`` or, for Nelson, ``"log(y) - (b1 - b2*x1*exp(-b3*x2))"``.
    predictors : list of str
        Predictor names (``["x"]``, or ``["x1", "x2"]`` for Nelson).
    difficulty : str
        NIST's level of difficulty: ``"lower"``, ``"average"`` or ``"higher"``.
    model : str
        The model function ``f`` alone (:data:`MODELS`).
    response : str
        The fitted response: ``"y"``, or ``"log(y)"`` for Nelson (:data:`RESPONSES`).
    """

    name: str
    y: np.ndarray
    x: np.ndarray
    starts: np.ndarray
    certified: np.ndarray
    certified_std: np.ndarray
    certified_rss: float
    certified_rsd: float
    dof: int
    expression: str
    predictors: list[str] = field(default_factory=list)
    difficulty: str = ""
    model: str = ""
    response: str = "y"

    @property
    def parameter_names(self) -> list[str]:
        """Parameter names ``b1 .. bk``."""
        return [f"b{i + 1}" for i in range(self.certified.size)]

    @property
    def components(self) -> list[str]:
        """Components of the kanagen channel: the predictors, then ``y``."""
        return [*self.predictors, "y"]

    @property
    def transformed(self) -> bool:
        """Whether NIST fits a transform of ``y`` (Nelson)."""
        return self.response != "y"

    def columns(self, transformed: bool = False) -> list[str]:
        """Channel components; with ``transformed``, the transformed response replaces ``y``."""
        if transformed and self.transformed:
            return [*self.predictors, TRANSFORMS[self.response][0]]
        return self.components

    def equation(self, transformed: bool = False) -> str:
        """The equation; with ``transformed``, written on the transformed response column."""
        if transformed and self.transformed:
            return f"{TRANSFORMS[self.response][0]} - ({self.model})"
        return self.expression

    def data_array(self, transformed: bool = False) -> np.ndarray:
        """Return the data as an ``(N, nx + 1)`` array in :meth:`columns` order."""
        if transformed and self.transformed:
            return np.column_stack([self.x, TRANSFORMS[self.response][1](self.y)])
        return np.column_stack([self.x, self.y])


def data_dir() -> Path:
    """Return the folder holding the NIST ``.dat`` files (it may not exist).

    ``$KANAGEN_DATA/nist_strd_nls`` when the variable is set (or ``$KANAGEN_DATA`` itself when
    it directly holds the files), else ``<repo root>/../shared/data/nist_strd_nls``.
    """
    env = os.environ.get(DATA_ENV)
    if env:
        root = Path(env).expanduser()
        if not (root / SUBDIR).is_dir() and (root / "Misra1a.dat").is_file():
            return root
        return root / SUBDIR
    return Path(__file__).resolve().parents[1].parent / "shared" / "data" / SUBDIR


def data_available() -> bool:
    """Return whether all 27 ``.dat`` files are present."""
    folder = data_dir()
    return all((folder / f"{name}.dat").is_file() for name in PROBLEMS)


_RANGE = re.compile(r"(Starting|Certified)\s+Values\s*\(lines\s+(\d+)\s+to\s+(\d+)\)", re.I)
_DATA_RANGE = re.compile(r"Data\s*\(lines\s+(\d+)\s+to\s+(\d+)\)", re.I)
_PARAM_LINE = re.compile(r"^\s*(b\d+)\s*=\s*(.*)$")
_DIFFICULTY = re.compile(r"(Lower|Average|Higher)\s+Level\s+of\s+Difficulty", re.I)


def _certified_scalar(lines: Sequence[str], label: str, path: Path) -> float:
    for line in lines:
        if line.strip().lower().startswith(label.lower()):
            return float(line.split(":", 1)[1])
    raise ValueError(f"{path}: no '{label}' line in the certified values block")


def parse_dat(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Parse a NIST StRD nonlinear regression ``.dat`` file.

    The header gives the 1-based line ranges of the starting values, the certified values and
    the data block; those ranges are followed exactly.

    Parameters
    ----------
    path : path-like
        The ``.dat`` file.

    Returns
    -------
    dict
        ``starts`` (2, nb), ``certified`` (nb,), ``certified_std`` (nb,), ``certified_rss``,
        ``certified_rsd``, ``dof`` (``N - nb``), ``stated_dof`` (as printed), ``n_obs``,
        ``columns`` (names of the data columns, response first), ``data`` (N, ncol) and
        ``difficulty``.
    """
    path = Path(path)
    lines = path.read_text(encoding="ascii").splitlines()
    header = "\n".join(lines[:40])
    ranges = {
        m.group(1).lower(): (int(m.group(2)), int(m.group(3))) for m in _RANGE.finditer(header)
    }
    data_match = _DATA_RANGE.search(header)
    if set(ranges) != {"starting", "certified"} or data_match is None:
        raise ValueError(f"{path}: header does not give the three line ranges")

    s0, s1 = ranges["starting"]
    rows = []
    for line in lines[s0 - 1 : s1]:
        match = _PARAM_LINE.match(line)
        if match is None:
            raise ValueError(f"{path}: not a parameter line: {line!r}")
        values = [float(v) for v in match.group(2).split()]
        if len(values) != 4 or match.group(1) != f"b{len(rows) + 1}":
            raise ValueError(f"{path}: malformed parameter line: {line!r}")
        rows.append(values)
    table = np.array(rows)

    c0, c1 = ranges["certified"]
    block = lines[c0 - 1 : c1]
    n_obs = int(_certified_scalar(block, "Number of Observations", path))
    dof = int(_certified_scalar(block, "Degrees of Freedom", path))

    d0, d1 = int(data_match.group(1)), int(data_match.group(2))
    title = lines[d0 - 2].split()
    if not title or title[0] != "Data:":
        raise ValueError(f"{path}: line {d0 - 1} is not the 'Data:' column header")
    columns = title[1:]
    data = np.array([[float(v) for v in line.split()] for line in lines[d0 - 1 : d1]])
    if data.shape != (n_obs, len(columns)):
        raise ValueError(f"{path}: data block is {data.shape}, expected ({n_obs}, {len(columns)})")
    # The stated degrees of freedom are not trusted: Rat43.dat says 9 where N - nb = 11 (its
    # certified residual standard deviation is sqrt(RSS/11)).
    stated_dof, dof = dof, n_obs - table.shape[0]

    difficulty = _DIFFICULTY.search(header)
    return {
        "starts": table[:, :2].T.copy(),
        "certified": table[:, 2].copy(),
        "certified_std": table[:, 3].copy(),
        "certified_rss": _certified_scalar(block, "Residual Sum of Squares", path),
        "certified_rsd": _certified_scalar(block, "Residual Standard Deviation", path),
        "dof": dof,
        "stated_dof": stated_dof,
        "n_obs": n_obs,
        "columns": columns,
        "data": data,
        "difficulty": difficulty.group(1).lower() if difficulty else "",
    }


@functools.cache
def load_problem(name: str) -> Problem:
    """Load one problem from its NIST ``.dat`` file.

    Parameters
    ----------
    name : str
        One of :data:`PROBLEMS` (case-sensitive, NIST spelling).

    Returns
    -------
    Problem
        The parsed problem; its arrays are shared between calls (the result is cached), do not
        modify them.

    Raises
    ------
    KeyError
        If ``name`` is not a StRD problem.
    FileNotFoundError
        If the data file is absent (see :func:`data_dir`).
    """
    if name not in MODELS:
        raise KeyError(f"unknown NIST StRD problem {name!r}; choose from {', '.join(PROBLEMS)}")
    parsed = parse_dat(data_dir() / f"{name}.dat")
    columns = parsed["columns"]
    if columns[0] != "y":
        raise ValueError(f"{name}: first data column is {columns[0]!r}, expected 'y'")
    data = parsed["data"]
    response = RESPONSES.get(name, "y")
    return Problem(
        name=name,
        y=data[:, 0].copy(),
        x=data[:, 1:].copy(),
        starts=parsed["starts"],
        certified=parsed["certified"],
        certified_std=parsed["certified_std"],
        certified_rss=parsed["certified_rss"],
        certified_rsd=parsed["certified_rsd"],
        dof=parsed["dof"],
        expression=f"{response} - ({MODELS[name]})",
        predictors=list(columns[1:]),
        difficulty=parsed["difficulty"],
        model=MODELS[name],
        response=response,
    )


# --------------------------------------------------------------------------------------------
# Spec and solvers
# --------------------------------------------------------------------------------------------


def yaml_float(value: float) -> str:
    """Format a float so that it is exact (``repr``) and read back as a float by YAML 1.1.

    PyYAML reads ``1e-05`` as a string (its float pattern needs a dot), so a mantissa without a
    dot gets ``.0``: ``1e-05`` -> ``1.0e-05``.
    """
    text = repr(float(value))
    if not math.isfinite(value):
        raise ValueError(f"not a finite float: {value!r}")
    mantissa, sep, exponent = text.partition("e")
    if sep and "." not in mantissa:
        text = f"{mantissa}.0e{exponent}"
    return text


def spec_text(problem: Problem, start_index: int, *, transformed: bool = False) -> str:
    """Return the kanagen YAML spec of ``problem`` with the chosen NIST start as defaults.

    Parameters
    ----------
    problem : Problem
        The problem.
    start_index : int
        0 for NIST's "Start 1", 1 for "Start 2".
    transformed : bool
        For a transformed response (Nelson) only: use the data column of the transformed
        response (``logy``) instead of ``log(y)`` in the equation, which makes kanagen's cost
        NIST's. Ignored for the other problems.

    Returns
    -------
    str
        A spec with one channel ``obs`` (components: predictors then the response; predictors
        exact) carrying the equation :meth:`Problem.equation`, and one model ``nls`` without
        constraints.
    """
    start = problem.starts[start_index]
    params = ", ".join(
        f"{n}: {yaml_float(v)}" for n, v in zip(problem.parameter_names, start, strict=True)
    )
    suffix = "_" + TRANSFORMS[problem.response][0] if transformed and problem.transformed else ""
    return (
        f"name: nist_{problem.name.lower()}{suffix}\n"
        f"parameter: {{{params}}}\n"
        "channels:\n"
        f"  {CHANNEL}:\n"
        f"    components: [{', '.join(problem.columns(transformed))}]\n"
        f"    exact: [{', '.join(problem.predictors)}]\n"
        "    equations:\n"
        f"      - {problem.equation(transformed)}\n"
        "models:\n"
        f"  {MODEL}:\n"
        "    constraints: []\n"
    )


def family(name: str, start_index: int, transformed: bool = False) -> Any:
    """Build (once per process) the kanagen family of one problem and start.

    Parameters
    ----------
    name : str
        Problem name.
    start_index : int
        0 or 1.
    transformed : bool
        See :func:`spec_text`.

    Returns
    -------
    kanagen.Family
        ``kanagen.load_text(spec_text(...), source=f"nist_{name}.yaml")``.
    """
    return _family(name, int(start_index), bool(transformed and load_problem(name).transformed))


@functools.cache
def _family(name: str, start_index: int, transformed: bool) -> Any:
    import kanagen

    text = spec_text(load_problem(name), start_index, transformed=transformed)
    suffix = "_" + TRANSFORMS[RESPONSES[name]][0] if transformed else ""
    return kanagen.load_text(text, source=f"nist_{name}{suffix}.yaml")


def kanagen_info(problem: Problem, transformed: bool = False) -> float | np.ndarray:
    """Return the information (inverse variance) given to kanagen for the response column.

    1 in general, so that ``2 * cost`` is the residual sum of squares. For Nelson's literal spec
    (equation ``log(y) - (f)``, ``y`` corrected) it is ``1/y**2`` per measure: the first-order
    variance of ``log(y)`` is then 1, which makes the two estimators agree to first order in the
    residuals (they do not agree exactly; see the module docstring).
    """
    if problem.transformed and not transformed:
        return 1.0 / problem.y**2
    return 1.0


@dataclass
class RunResult:
    """Outcome of one solver run on one case.

    Attributes
    ----------
    solver : str
        ``"kanagen"`` or ``"scipy-trf"``.
    problem, start : str, int
        The case (start is 0 or 1).
    params : numpy.ndarray
        Final estimate (NaN when the solver raised).
    rss : float
        Residual sum of squares reported by the solver (kanagen: ``2*res.cost``).
    lre : numpy.ndarray
        :func:`lre` of each parameter against the certified value.
    time : float
        Best wall time of the repeats, seconds (fit only, family build excluded).
    success : bool
        The solver's own success flag.
    status : object
        The solver's status code.
    message : str
        The solver's message, or the exception text.
    iterations : int
        Iterations (kanagen) or function evaluations (scipy).
    raw : object
        The solver's result object (None on exception).
    """

    solver: str
    problem: str
    start: int
    params: np.ndarray
    rss: float
    lre: np.ndarray
    time: float
    success: bool
    status: object
    message: str
    iterations: int
    raw: object = None

    @property
    def lre_min(self) -> float:
        """Smallest parameter LRE (0 when the run failed)."""
        return float(np.min(self.lre)) if self.lre.size else 0.0

    @property
    def solved(self) -> bool:
        """Whether every parameter has at least :data:`SOLVED_DIGITS` correct digits."""
        return self.lre_min >= SOLVED_DIGITS


def lre(
    estimate: np.ndarray | Sequence[float],
    certified: np.ndarray | Sequence[float],
    cap: float = LRE_CAP,
) -> np.ndarray:
    """NIST's log relative error: the number of significant digits that agree.

    ``LRE = -log10(|estimate - certified| / |certified|)`` (absolute error when the certified
    value is 0), clipped to ``[0, cap]``; an exact match gives ``cap``, a NaN gives 0.

    Parameters
    ----------
    estimate, certified : array_like
        Estimated and certified values, same shape.
    cap : float
        Upper bound (11: the certified values carry 11 significant digits).

    Returns
    -------
    numpy.ndarray
        LRE of each element.

    Examples
    --------
    >>> float(lre([1.0000001], [1.0])[0]) > 6.9
    True
    """
    est = np.asarray(estimate, dtype=float)
    cert = np.asarray(certified, dtype=float)
    err = np.abs(est - cert)
    scale = np.where(cert == 0.0, 1.0, np.abs(cert))
    with np.errstate(divide="ignore", invalid="ignore"):
        digits = -np.log10(err / scale)
    digits = np.where(err == 0.0, cap, digits)
    digits = np.where(np.isnan(digits), 0.0, digits)
    return np.clip(digits, 0.0, cap)


def _timed(call: Any, repeats: int) -> tuple[Any, float]:
    best = math.inf
    out = None
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        out = call()
        best = min(best, time.perf_counter() - t0)
    return out, best


def _failed(solver: str, problem: Problem, start: int, exc: Exception) -> RunResult:
    nb = problem.certified.size
    return RunResult(
        solver=solver,
        problem=problem.name,
        start=start,
        params=np.full(nb, np.nan),
        rss=math.nan,
        lre=np.zeros(nb),
        time=math.nan,
        success=False,
        status="exception",
        message=f"{type(exc).__name__}: {exc}",
        iterations=0,
    )


def run_kanagen(
    problem: Problem,
    start: int,
    *,
    transformed: bool = False,
    max_iter: int = 500,
    xtol: float | None = None,
    repeats: int = 1,
) -> RunResult:
    """Fit one case with :func:`kanagen.fit`.

    Parameters
    ----------
    problem : Problem
        The problem.
    start : int
        0 for NIST's "Start 1", 1 for "Start 2" (it becomes the spec's parameter defaults).
    transformed : bool
        See :func:`spec_text`; ``True`` poses Nelson as NIST does (no effect on the others).
    max_iter : int
        Passed to :func:`kanagen.fit`.
    xtol : float, optional
        Passed to :func:`kanagen.fit` when given; default kanagen's own.
    repeats : int
        Timing repeats; the best time is kept.

    Returns
    -------
    RunResult
        ``rss = 2 * res.cost``; :attr:`RunResult.lre` against the certified values. Exceptions
        raised by the fit are caught and reported with ``success=False``.
    """
    import kanagen

    fam = family(problem.name, start, transformed and problem.transformed)
    arr = problem.data_array(transformed)
    info = kanagen_info(problem, transformed)

    options: dict[str, Any] = {"max_iter": max_iter}
    if xtol is not None:
        options["xtol"] = xtol

    def call() -> Any:
        return kanagen.fit(fam, model=MODEL, data={CHANNEL: arr}, info={CHANNEL: info}, **options)

    try:
        res, elapsed = _timed(call, repeats)
    except Exception as exc:  # a benchmark records failures
        return _failed("kanagen", problem, start, exc)
    q = np.array([res.params[n] for n in problem.parameter_names], dtype=float)
    return RunResult(
        solver="kanagen",
        problem=problem.name,
        start=start,
        params=q,
        rss=2.0 * float(res.cost),
        lre=lre(q, problem.certified),
        time=elapsed,
        success=bool(res.success),
        status=res.status,
        message=str(res.message),
        iterations=int(res.iterations),
        raw=res,
    )


def residual_and_jacobian(
    problem: Problem, start: int = 0, objective: str = "nist"
) -> tuple[Any, Any]:
    """Return ``(fun, jac)`` for SciPy, from kanagen's generated measurement derivatives.

    Parameters
    ----------
    problem : Problem
        The problem.
    start : int
        Which start's family to use (the generated code does not depend on it).
    objective : {"nist", "ml"}
        ``"nist"``: ``fun(q) = c[:, 0]`` (the equation ``response - f(x; q)`` at the measured
        data, NIST's residual) and ``jac(q) = C[:, 0, :]``, where
        ``c, C, D = fam.measurement("nls", "obs", q, data)`` on the literal spec.
        ``"ml"``: the residual whose sum of squares kanagen minimises on the literal spec. The
        same as ``"nist"`` except for Nelson, where the exact correction of ``y`` is
        ``y_hat = y*exp(-c)`` and, with information ``1/y**2``, the residual is
        ``(y_hat - y)/y = exp(-c) - 1`` with Jacobian ``-exp(-c) C``.

    Returns
    -------
    fun, jac : callable
        The last evaluation is memoised, SciPy asks for both at the same point.
    """
    if objective not in ("nist", "ml"):
        raise ValueError(f"objective must be 'nist' or 'ml', not {objective!r}")
    if problem.transformed and problem.response != "log(y)":
        raise NotImplementedError(f"no ML residual for the response {problem.response!r}")
    ml = objective == "ml" and problem.transformed
    fam = family(problem.name, start)
    arr = problem.data_array()
    memo: dict[str, Any] = {"q": None}

    def evaluate(q: np.ndarray) -> None:
        if memo["q"] is None or not np.array_equal(memo["q"], q):
            c, big_c, _ = fam.measurement(MODEL, CHANNEL, q, arr)
            r, jac = np.asarray(c)[:, 0], np.asarray(big_c)[:, 0, :]
            if ml:
                scale = np.exp(-r)
                r, jac = scale - 1.0, -scale[:, None] * jac
            memo.update(q=np.array(q, copy=True), r=r, jac=jac)

    def fun(q: np.ndarray) -> np.ndarray:
        evaluate(q)
        return memo["r"]

    def jac(q: np.ndarray) -> np.ndarray:
        evaluate(q)
        return memo["jac"]

    return fun, jac


def run_scipy(
    problem: Problem,
    start: int,
    *,
    objective: str = "nist",
    repeats: int = 1,
    tol: float = 1e-15,
    max_nfev: int = 20_000,
) -> RunResult:
    """Fit one case with ``scipy.optimize.least_squares(method="trf")`` and the exact Jacobian.

    Parameters
    ----------
    problem : Problem
        The problem.
    start : int
        0 or 1 (NIST's start).
    objective : {"nist", "ml"}
        See :func:`residual_and_jacobian`.
    repeats : int
        Timing repeats; the best time is kept.
    tol : float
        ``ftol = xtol = gtol`` (1e-15 is above machine epsilon, the tightest SciPy honours).
    max_nfev : int
        Budget of function evaluations.

    Returns
    -------
    RunResult
        ``rss = 2 * cost``; :attr:`RunResult.lre` against the certified values.
    """
    from scipy.optimize import least_squares

    fun, jac = residual_and_jacobian(problem, start, objective)
    x0 = problem.starts[start].astype(float)

    def call() -> Any:
        # Overflowing trial steps are rejected by TRF (non-finite cost): no need to warn.
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            return least_squares(
                fun, x0, jac=jac, method="trf", ftol=tol, xtol=tol, gtol=tol, max_nfev=max_nfev
            )

    try:
        res, elapsed = _timed(call, repeats)
    except Exception as exc:  # a benchmark records failures
        return _failed("scipy-trf", problem, start, exc)
    return RunResult(
        solver="scipy-trf",
        problem=problem.name,
        start=start,
        params=np.asarray(res.x, dtype=float),
        rss=2.0 * float(res.cost),
        lre=lre(res.x, problem.certified),
        time=elapsed,
        success=bool(res.success),
        status=res.status,
        message=str(res.message),
        iterations=int(res.nfev),
        raw=res,
    )


def cases(problems: Sequence[str] = PROBLEMS) -> list[tuple[str, int]]:
    """Return the ``(problem, start)`` cases, two per problem."""
    return [(name, start) for name in problems for start in (0, 1)]


# --------------------------------------------------------------------------------------------
# Script
# --------------------------------------------------------------------------------------------


def _row(problem: Problem, start: int, kg: RunResult, sc: RunResult) -> str:
    ratio = kg.time / sc.time if sc.time > 0 else math.nan
    note = "" if kg.solved else f"status={kg.status} {kg.message}"[:70]
    return (
        f"{problem.name:<9} {problem.difficulty:<7} {start + 1:>2}  {kg.lre_min:7.2f} "
        f"{sc.lre_min:9.2f}  {1e3 * kg.time:8.2f} {1e3 * sc.time:8.2f} {ratio:6.2f}  "
        f"{kg.iterations:>6} {sc.iterations:>5}  {note}"
    )


def main(argv: Sequence[str] | None = None) -> int:
    """Run the benchmark and print the table; return the process exit code."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3, help="timing repeats (best kept)")
    parser.add_argument("--problems", nargs="*", default=list(PROBLEMS), help="subset")
    parser.add_argument("--max-iter", type=int, default=500, help="kanagen max_iter")
    args = parser.parse_args(argv)
    if not data_available():
        print(f"NIST StRD data not found in {data_dir()} (set ${DATA_ENV})", file=sys.stderr)
        return 2

    header = (
        f"{'problem':<9} {'level':<7} {'st':>2}  {'kan LRE':>7} {'scipy LRE':>9}  "
        f"{'kan ms':>8} {'scipy ms':>8} {'ratio':>6}  {'kan it':>6} {'nfev':>5}  kanagen note"
    )
    print(header)
    print("-" * len(header))
    results: list[tuple[RunResult, RunResult]] = []
    literal: list[tuple[RunResult, RunResult]] = []
    for name, start in cases(args.problems):
        problem = load_problem(name)
        family(name, start, problem.transformed)  # build outside the timing
        kg = run_kanagen(
            problem, start, transformed=True, max_iter=args.max_iter, repeats=args.repeats
        )
        sc = run_scipy(problem, start, repeats=args.repeats)
        results.append((kg, sc))
        print(_row(problem, start, kg, sc), flush=True)
        if problem.transformed:
            family(name, start)
            kl = run_kanagen(problem, start, max_iter=args.max_iter, repeats=args.repeats)
            ml = run_scipy(problem, start, objective="ml", repeats=args.repeats)
            literal.append((kl, ml))

    n = len(results)
    kan_solved = sum(kg.solved for kg, _ in results)
    sc_solved = sum(sc.solved for _, sc in results)
    finite = [(kg.time, sc.time) for kg, sc in results if math.isfinite(kg.time * sc.time)]
    both = [kg.time / sc.time for kg, sc in results if kg.solved and sc.solved]
    print()
    print(f"kanagen solved {kan_solved}/{n}, scipy trf solved {sc_solved}/{n}")
    if finite:
        line = f"median time ratio kanagen/scipy: {statistics.median(a / b for a, b in finite):.2f}"
        if both:
            line += f" (all cases), {statistics.median(both):.2f} (cases both solve)"
        print(line)
    only_scipy = [f"{kg.problem}/{kg.start + 1}" for kg, sc in results if sc.solved > kg.solved]
    only_kanagen = [f"{kg.problem}/{kg.start + 1}" for kg, sc in results if kg.solved > sc.solved]
    print("solved by scipy only:", ", ".join(only_scipy) or "none")
    print("solved by kanagen only:", ", ".join(only_kanagen) or "none")
    for kl, ml in literal:
        agree = float(np.min(lre(kl.params, ml.params)))
        print(
            f"{kl.problem} start {kl.start + 1}, literal log(y) spec (errors in y, info 1/y**2): "
            f"LRE vs certified {kl.lre_min:.2f}, vs its ML optimum (scipy) {agree:.2f}; "
            f"status={kl.status} iterations={kl.iterations}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
