"""Bias of the three scorers on Stewart's bimodal distribution (report §4, eq. 32, Fig. 8).

The report ("Evaluating the relevance indicator", after Stewart, PAMI 19(8), 1997) draws
scalar data from

    p = (1 − ε0) [ε1 G(μ1, σ1) + (1 − ε1) G(μ2, σ2)] + ε0 U(0, m0)            (eq. 32)

with ``m0 = 100``, ``μ1 = 10``, ``μ2 = μ1 + δ``, ``σ1 = σ2 = 5``: principal inliers around
``μ1``, secondary inliers around ``μ2`` and uniform outliers. Every candidate value ``ṽ`` on an
integer grid is scored from the errors of all the data, the best-scored candidate is the
estimate, and its bias is ``ṽ − μ1``. The ten settings (ε0, ε1, δ) are the columns of the
report's Fig. 8; the report's printed biases are shown beside ours.

The scorers are :mod:`kanagen.runtime.scoring`'s, on the per-measure error of eq. 24, which
for a scalar measure ``x`` of information ``1/σ1²`` is ``e = ((x − ṽ)/σ1)²``:

* relevance ``R`` (eq. 29): :func:`~kanagen.runtime.scoring.relevance` with ``L* = scale``
  (default 1, i.e. ``σ1²``: the same order of magnitude the report gives ``S_A``; the report
  does not say which ``L*`` it used; ``main`` prints the summary for other values too);
* ransac-like ``S_A``: :func:`~kanagen.runtime.scoring.ransac` with the threshold at the
  inliers' standard deviation (``e < 1``), as the report sets it "in its best conditions";
* trimmed median ``S_B``: :func:`~kanagen.runtime.scoring.trimmed` at the quantile
  ``ν = (1 − ε0) ε1 / 2``, as the report sets it.

Reading of the report, where it is loose:

* ε0 is the proportion of *outliers* (eq. 32 and the text). The Maple ``stewart`` procedure
  calls its first argument "Percentage of outliers" but then draws the inlier mixture with
  that probability (and ``rand() mod 101 < P`` gives ``P/101``, not ``P/100``); we follow
  eq. 32 with exact proportions.
* Candidates: the report says ``ṽ ∈ {0..μ2}``, which cannot give its positive biases at
  δ = 0 (μ2 = μ1 = 10); we use the integers of ``[μ1 − 2σ1, μ2 + 2σ1]`` = ``[0, μ2 + 10]``,
  the report's range widened symmetrically.
* The report's Maple scores integer-binned histograms; we score the errors themselves (the
  limit of thin bins). Exact ties of the best score (possible for the count ``S_A``) are
  resolved by the mean of the tied candidates, which favours neither side.
* The report does not give the number of data nor of runs (its table holds one run's
  integer biases). We draw ``n = 1000`` data per run and average ``ṽ − μ1`` over ``reps``
  runs per setting (same draws for the three scorers): the *bias* is that mean; the *mean
  |bias|* of a scorer is the mean over the settings of its absolute bias. The mean absolute
  error ``E|ṽ − μ1|`` (bias and spread together) is given as well.

Run ``python experiments/stewart.py`` (``--reps``, ``--n``, ``--seed``, ``--scale``).
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from kanagen.runtime.scoring import ransac, relevance, trimmed

#: Outliers are uniform on [0, M0].
M0 = 100.0
#: Mean of the principal inliers.
MU1 = 10.0
#: Standard deviation of both inlier populations.
SIGMA = 5.0
#: Half-width, in σ, by which the candidate grid extends beyond the two modes.
GRID_MARGIN = 2.0

#: Scorer names, in the table's order (the report's R, S_A, S_B).
SCORER_NAMES: tuple[str, ...] = ("relevance", "ransac", "trimmed")

#: Defaults of the printed table.
DEFAULT_REPS = 100
DEFAULT_N = 1000
DEFAULT_SEED = 4050
DEFAULT_SCALE = 1.0


@dataclass(frozen=True)
class Setting:
    """One column of the report's Fig. 8.

    Parameters
    ----------
    outliers : float
        ε0, the proportion of uniform outliers.
    main : float
        ε1, the proportion of the inliers in the principal population.
    distance : float
        δ = μ2 − μ1, the distance between the two modes.
    """

    outliers: float
    main: float
    distance: float

    @property
    def bimodal(self) -> bool:
        """Whether a second inlier population is present (ε1 < 1)."""
        return self.main < 1.0

    @property
    def quantile(self) -> float:
        """The trimmed median's quantile ``ν = (1 − ε0) ε1 / 2`` (report §4)."""
        return (1.0 - self.outliers) * self.main / 2.0


#: The report's Fig. 8 settings, in its column order.
SETTINGS: tuple[Setting, ...] = (
    Setting(0.1, 1.0, 0), Setting(0.2, 1.0, 0), Setting(0.5, 1.0, 0), Setting(0.8, 1.0, 0),
    Setting(0.2, 0.8, 50), Setting(0.2, 0.6, 50), Setting(0.2, 0.8, 20), Setting(0.2, 0.6, 20),
    Setting(0.2, 0.8, 10), Setting(0.2, 0.6, 10),
)

#: The report's printed biases (Fig. 8), per scorer, in the order of :data:`SETTINGS`.
REPORT_BIAS: dict[str, tuple[int, ...]] = {
    "relevance": (0, -1, -1, 1, 1, 1, 1, 1, 0, 1),
    "ransac": (0, 0, -1, 1, 2, 3, 1, 2, 0, 2),
    "trimmed": (0, 1, 1, 1, 5, 6, 4, 3, 2, 2),
}


def draw(rng: np.random.Generator, n: int, setting: Setting) -> np.ndarray:
    """``n`` data drawn from eq. 32.

    Parameters
    ----------
    rng : numpy.random.Generator
    n : int
    setting : Setting

    Returns
    -------
    numpy.ndarray
        Shape ``(n,)``.
    """
    kind = rng.random(n)
    mode = rng.random(n)
    outlier = rng.uniform(0.0, M0, n)
    principal = rng.normal(MU1, SIGMA, n)
    secondary = rng.normal(MU1 + setting.distance, SIGMA, n)
    inlier = np.where(mode < setting.main, principal, secondary)
    return np.where(kind < setting.outliers, outlier, inlier)


def candidates(setting: Setting) -> np.ndarray:
    """The integer candidates ``ṽ`` of ``[μ1 − 2σ, μ2 + 2σ]``.

    Parameters
    ----------
    setting : Setting

    Returns
    -------
    numpy.ndarray
    """
    lo = MU1 - GRID_MARGIN * SIGMA
    hi = MU1 + setting.distance + GRID_MARGIN * SIGMA
    return np.arange(np.ceil(lo), np.floor(hi) + 1.0)


def errors(data: np.ndarray, values: np.ndarray) -> np.ndarray:
    """The eq. 24 error of every datum for every candidate: ``((x − ṽ)/σ)²``.

    Parameters
    ----------
    data : numpy.ndarray
        Shape ``(n,)``.
    values : numpy.ndarray
        Candidates, shape ``(k,)``.

    Returns
    -------
    numpy.ndarray
        Shape ``(k, n)``.
    """
    return ((data[None, :] - values[:, None]) / SIGMA) ** 2


def select(errs: np.ndarray, values: np.ndarray, score: Callable[[np.ndarray], float]) -> float:
    """The best-scored candidate (the mean of the candidates tied at the best score).

    Parameters
    ----------
    errs : numpy.ndarray
        Shape ``(k, n)``, as :func:`errors`.
    values : numpy.ndarray
        Shape ``(k,)``.
    score : callable
        ``score(errors_of_one_candidate) -> float``, larger is better.

    Returns
    -------
    float
    """
    scores = np.array([score(row) for row in errs])
    return float(np.mean(values[scores == scores.max()]))


def scorers(setting: Setting, scale: float) -> dict[str, Callable[[np.ndarray], float]]:
    """The three scorers with the report's settings, as functions of the errors.

    Parameters
    ----------
    setting : Setting
    scale : float
        ``L*`` of the relevance, in units of ``σ²``.

    Returns
    -------
    dict
        Name to ``f(errors) -> float``.
    """
    nu = setting.quantile
    return {
        "relevance": lambda e: relevance(e, scale),
        "ransac": lambda e: ransac(e, 1.0),
        "trimmed": lambda e: trimmed(e, 1.0, quantile=nu),
    }


def simulate(settings: Sequence[Setting] = SETTINGS, reps: int = DEFAULT_REPS,
             n: int = DEFAULT_N, seed: int = DEFAULT_SEED, scale: float = DEFAULT_SCALE,
             names: Sequence[str] = SCORER_NAMES) -> list[dict[str, float]]:
    """The bias table: one row per setting.

    Parameters
    ----------
    settings : sequence of Setting, optional
        The report's ten by default.
    reps : int, optional
        Runs per setting.
    n : int, optional
        Data per run.
    seed : int, optional
        Seed of :func:`numpy.random.default_rng`; each setting gets its own stream, so a row
        does not depend on which other settings are run.
    scale : float, optional
        ``L*`` of the relevance, in units of ``σ²``.
    names : sequence of str, optional
        Which scorers to run.

    Returns
    -------
    list of dict
        Per setting: ``outliers`` (ε0), ``main`` (ε1), ``distance`` (δ), ``bimodal`` (1.0 or
        0.0), and per scorer ``name``: ``bias_<name>`` (mean of ``ṽ − μ1``), ``mae_<name>``
        (mean of ``|ṽ − μ1|``) and ``report_<name>`` (the report's Fig. 8 value, or nan for a
        setting not in the report).
    """
    rows = []
    for setting in settings:
        rng = np.random.default_rng([seed, *_setting_key(setting)])
        values = candidates(setting)
        funcs = scorers(setting, scale)
        picks: dict[str, list[float]] = {name: [] for name in names}
        for _ in range(reps):
            errs = errors(draw(rng, n, setting), values)
            for name in names:
                picks[name].append(select(errs, values, funcs[name]))
        row: dict[str, float] = {
            "outliers": setting.outliers, "main": setting.main,
            "distance": float(setting.distance), "bimodal": float(setting.bimodal),
        }
        where = SETTINGS.index(setting) if setting in SETTINGS else None
        for name in names:
            dev = np.asarray(picks[name]) - MU1
            row[f"bias_{name}"] = float(dev.mean())
            row[f"mae_{name}"] = float(np.abs(dev).mean())
            row[f"report_{name}"] = (float(REPORT_BIAS[name][where]) if where is not None
                                     else float("nan"))
        rows.append(row)
    return rows


def _setting_key(setting: Setting) -> tuple[int, int, int]:
    """Integers identifying a setting, to seed its random stream."""
    return (round(setting.outliers * 1000), round(setting.main * 1000),
            round(setting.distance * 1000))


def mean_abs_bias(rows: Sequence[dict[str, float]], name: str, bimodal_only: bool = False,
                  key: str = "bias") -> float:
    """Mean over the settings of ``|bias|`` (or of another column's absolute value).

    Parameters
    ----------
    rows : sequence of dict
        As returned by :func:`simulate`.
    name : str
        Scorer name.
    bimodal_only : bool, optional
        Only the settings with a second inlier population (ε1 < 1).
    key : str, optional
        ``"bias"`` (default), ``"mae"`` or ``"report"``.

    Returns
    -------
    float
    """
    vals = [abs(r[f"{key}_{name}"]) for r in rows if r["bimodal"] or not bimodal_only]
    return float(np.mean(vals))


def format_table(rows: Sequence[dict[str, float]],
                 names: Sequence[str] = SCORER_NAMES) -> str:
    """The table in the report's layout (settings as columns), ours above the report's.

    Parameters
    ----------
    rows : sequence of dict
        As returned by :func:`simulate`.
    names : sequence of str, optional

    Returns
    -------
    str
    """
    label = {"relevance": "R", "ransac": "S_A", "trimmed": "S_B"}
    lines = [f"{'ε0':16}" + "".join(f"{r['outliers']:6.1f}" for r in rows)
             + "   mean|b|  bimodal",
             f"{'ε1':16}" + "".join(f"{r['main']:6.1f}" for r in rows),
             f"{'δ':16}" + "".join(f"{r['distance']:6.0f}" for r in rows)]
    for key, title in (("bias", "bias"), ("mae", "E|ṽ−μ1|"), ("report", "report")):
        for name in names:
            lines.append(f"{label[name] + ' ' + title:16}"
                         + "".join(f"{r[f'{key}_{name}']:6.2f}" if key != "report"
                                   else f"{r[f'{key}_{name}']:6.0f}" for r in rows)
                         + f"   {mean_abs_bias(rows, name, key=key):7.3f}"
                         + f"  {mean_abs_bias(rows, name, True, key=key):7.3f}")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    """Print the bias table and a sensitivity of the relevance to ``L*``.

    Parameters
    ----------
    argv : sequence of str, optional

    Returns
    -------
    int
        0.
    """
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reps", type=int, default=DEFAULT_REPS, help="runs per setting")
    parser.add_argument("--n", type=int, default=DEFAULT_N, help="data per run")
    parser.add_argument("--seed", type=int, default=DEFAULT_SEED)
    parser.add_argument("--scale", type=float, default=DEFAULT_SCALE,
                        help="L* of the relevance, in units of σ²")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    rows = simulate(reps=args.reps, n=args.n, seed=args.seed, scale=args.scale)
    print(f"Stewart's bimodal distribution (eq. 32): m0 = {M0:g}, μ1 = {MU1:g}, "
          f"σ1 = σ2 = {SIGMA:g}; n = {args.n}, {args.reps} runs per setting, seed {args.seed}")
    print(f"R: L* = {args.scale:g} σ²; S_A: threshold σ; S_B: quantile (1−ε0)ε1/2. "
          "bias = mean(ṽ − μ1); mean|b| over all settings, bimodal = over ε1 < 1.\n")
    print(format_table(rows))
    print("\nmean |bias| (all settings / bimodal settings):")
    for name in SCORER_NAMES:
        print(f"  {name:9s} {mean_abs_bias(rows, name):6.3f} / "
              f"{mean_abs_bias(rows, name, True):6.3f}   "
              f"(report: {mean_abs_bias(rows, name, key='report'):.2f} / "
              f"{mean_abs_bias(rows, name, True, key='report'):.2f})")
    print("\nrelevance against L* (same draws): L*/σ², mean|bias| all / bimodal, "
          "mean E|ṽ−μ1| bimodal")
    for scale in (0.5, 1.0, 2.0, 4.0):
        alt = rows if scale == args.scale else simulate(
            reps=args.reps, n=args.n, seed=args.seed, scale=scale, names=("relevance",))
        print(f"  {scale:4g}  {mean_abs_bias(alt, 'relevance'):6.3f} / "
              f"{mean_abs_bias(alt, 'relevance', True):6.3f}   "
              f"{mean_abs_bias(alt, 'relevance', True, key='mae'):6.3f}")
    print(f"\n({time.perf_counter() - start:.1f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
