"""Conic fitting on half an ellipse: kanagen vs ``scipy.odr`` (implicit mode) and the KCR bound.

The issue's floor: 30 points on half an ellipse, iid Gaussian noise of standard deviation
``sigma`` in {0.5, 1, 2} px, 300 trials per ``sigma``. kanagen must

* reach an RMS error of the unit conic vector within 3 % of ``scipy.odr``'s (implicit mode) in
  the same run -- i.e. sit at the KCR lower bound, since both compute the maximum-likelihood
  (geometric distance) estimate -- without failing more often than ODR, and
* fit in a median time at most 1/20 of ``scipy.odr``'s or ``odrpack``'s (issue 17, at the
  defaults): the floor applies to ``kanagen.load("conic")`` as a user calls it, whose default
  backend is ``"compiled"`` (the family's vectorised functions from its compiled CasADi
  library; the estimator's kernels are the same numba kernels on every backend,
  docs/engine.md); the table also reports the NumPy backend (``kan``, ``backend="numpy"``)
  and, with ``--backends``, the uncompiled CasADi one.

Set-up
------
The conic is ``A x² + 2B xy + C y² + 2 f0 (D x + E y) + f0² F = 0`` with ``f0 = 100`` (the
shipped ``conic`` family, ``examples/conic.yaml``), i.e. ``θ · ξ(x, y) = 0`` with
``θ = (A, B, C, D, E, F)`` of unit norm and the carrier
``ξ = (x², 2xy, y², 2 f0 x, 2 f0 y, f0²)``. The true vector ``θ*`` is normalised with ``A > 0``;
every estimate is normalised and its sign chosen so that ``θ̂ · θ* > 0`` before the error
``‖θ̂ − θ*‖`` is taken.

Every method starts from the same algebraic estimate, Taubin's (:func:`taubin`), and is given
exact derivatives:

* kanagen: ``kanagen.fit(fam, "conic", data={"point": xy}, info={"point": 1/sigma**2},
  q0=start)`` with its default tolerances;
* ``scipy.odr`` in implicit mode with ``fjacb``/``fjacd`` (``deriv=3``). The homogeneous
  vector is degenerate for ODR (nothing stops it from shrinking to zero), so the scale is
  fixed the usual way: the start is divided by its component of largest magnitude, which is
  then held at 1 with ``ifixb``; the result is normalised afterwards. ODR's default
  tolerances and covariance computation are kept (kanagen computes its covariance too).
* ``odrpack`` (the maintained successor on PyPI, optional extra ``bench``), set up the same
  way with ``task="implicit-ODR"``, when it is installed; skipped otherwise.

A fit *fails* when the solver says so (kanagen ``res.success`` false; ODR ``info`` not in
{1, 2, 3}; ``odrpack`` ``success`` false) or returns non-finite numbers. RMS errors are taken
over the trials that every method fitted, so that the ratios compare the same draws.

The KCR bound
-------------
For isotropic noise ``sigma`` on the points, the KCR lower bound on the covariance of any
unbiased estimator of the unit vector ``θ`` is (Kanatani)

    V_KCR = sigma² (Σ_i ξ̄_i ξ̄_iᵀ / (θ*ᵀ V0[ξ̄_i] θ*))⁻,

with ``ξ̄_i`` the carriers of the true points, ``V0[ξ] = T Tᵀ``, ``T = ∂ξ/∂(x, y)`` (6 × 2),
and ``⁻`` the rank-5 pseudo-inverse: the matrix has the null vector ``θ*`` (the true points
lie on the conic), so its inverse is taken on the tangent space of the unit sphere at ``θ*``,
which is where ``θ`` can move under the constraint ``‖θ‖ = 1``. The bound on the RMS error is
``sqrt(tr V_KCR)`` (:func:`kcr_covariance`). The same matrix is kanagen's constrained
covariance at the truth (the top-left block of the inverse bordered information
``[[Σ ξ̄ξ̄ᵀ/(sigma² θᵀV0θ), 2θ], [2θᵀ, 0]]``), obtained by fitting the noise-free points from
``θ*`` (:func:`kcr_covariance_kanagen`); the table prints the relative difference of the two.
Because an RMS over a few hundred draws is itself noisy, the table also gives the RMS of the
first-order (KCR-attaining) error ``-M̄⁻ Σ_i ξ̄_i (θ*ᵀ T̄_i e_i) / (θ*ᵀ V0[ξ̄_i] θ*)`` on the
same noise draws ``e_i`` (:func:`first_order_errors`).

Timing: the methods run interleaved on every trial (the same machine load for all), and
each fit is timed ``--repeats`` times back to back (default 3), its fastest time kept: every
method is timed warm, as a loop of fits runs. ``--repeats 1`` times one cold call per method
(it then pays for the caches the previous method evicted: the compiled kanagen, ~30 µs, loses
~20 µs that way, ODR ~5 %).

Run ``python benchmarks/conic_odr.py`` (``--trials 30`` for a quick run; ``--profile`` prints
where kanagen's time goes, from ``cProfile``).
"""

from __future__ import annotations

import argparse
import cProfile
import functools
import importlib.util
import io
import pstats
import statistics
import sys
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as sla

import kanagen

with warnings.catch_warnings():
    # scipy.odr is deprecated (SciPy 1.17) but is the reference the issue names.
    warnings.simplefilter("ignore", DeprecationWarning)
    import scipy.odr as scipy_odr

#: The scale constant of the shipped ``conic`` family.
F0 = 100.0
#: Noise levels (pixels).
SIGMAS: tuple[float, ...] = (0.5, 1.0, 2.0)
#: Points per trial.
N_POINTS = 30
#: Trials per noise level.
TRIALS = 300
#: Base seed; the noise of each ``sigma`` comes from ``default_rng((SEED, 1000 * sigma))``.
SEED = 4050
#: Accuracy floor: kanagen's RMS error at most ``1 + ACCURACY_TOL`` times ODR's.
ACCURACY_TOL = 0.03
#: Speed floor: ODR's median fit time at least this many times kanagen's (the default backend).
SPEED_FLOOR = 20.0
#: kanagen's backends, as method names: ``kanagen`` is the NumPy one, ``kanagen[compiled]`` the
#: default (``kanagen.load``'s).
KANAGEN = {"numpy": "kanagen", "compiled": "kanagen[compiled]", "casadi": "kanagen[casadi]"}
#: The backend the speed floor is about: the default one.
FLOOR_BACKEND = "compiled"
#: Short method names for the timing table.
SHORT = {"kanagen": "kan", "kanagen[compiled]": "kanC", "kanagen[casadi]": "kanX",
         "scipy.odr": "odr", "odrpack": "odrpk"}


@dataclass(frozen=True)
class Ellipse:
    """An ellipse in pixel coordinates.

    Parameters
    ----------
    cx, cy : float
        Centre.
    a, b : float
        Semi-axes.
    angle : float
        Rotation of the ``a`` axis from the x axis, radians.
    """

    cx: float
    cy: float
    a: float
    b: float
    angle: float

    def points(self, n: int, start: float = 0.0, stop: float = np.pi) -> np.ndarray:
        """``n`` points at evenly spaced eccentric angles in ``[start, stop]``.

        Parameters
        ----------
        n : int
            Number of points.
        start, stop : float
            Range of the eccentric angle; the default is half the ellipse.

        Returns
        -------
        ndarray, shape (n, 2)
        """
        t = np.linspace(start, stop, n)
        c, s = np.cos(self.angle), np.sin(self.angle)
        u, v = self.a * np.cos(t), self.b * np.sin(t)
        return np.column_stack([self.cx + c * u - s * v, self.cy + s * u + c * v])

    def matrix(self) -> np.ndarray:
        """The symmetric 3 × 3 matrix ``M`` with ``[x y 1] M [x y 1]ᵀ = 0`` on the ellipse.

        Returns
        -------
        ndarray, shape (3, 3)
        """
        c, s = np.cos(self.angle), np.sin(self.angle)
        R = np.array([[c, -s], [s, c]])
        Q = R @ np.diag([1.0 / self.a**2, 1.0 / self.b**2]) @ R.T
        z = np.array([self.cx, self.cy])
        M = np.empty((3, 3))
        M[:2, :2] = Q
        M[:2, 2] = M[2, :2] = -Q @ z
        M[2, 2] = z @ Q @ z - 1.0
        return M

    def conic_vector(self, f0: float = F0) -> np.ndarray:
        """The unit vector ``θ = (A, B, C, D, E, F)`` of the spec's parametrisation, ``A > 0``.

        Parameters
        ----------
        f0 : float
            Scale constant of the parametrisation.

        Returns
        -------
        ndarray, shape (6,)
        """
        return conic_vector_from_matrix(self.matrix(), f0)


#: The scene: a realistic ellipse in a 640 × 480 image, 30 points on its upper half.
SCENE = Ellipse(cx=330.0, cy=250.0, a=220.0, b=130.0, angle=np.deg2rad(25.0))


def conic_vector_from_matrix(M: np.ndarray, f0: float = F0) -> np.ndarray:
    """Unit conic vector (``A > 0``) of the spec from the pixel-coordinate conic matrix.

    Parameters
    ----------
    M : ndarray, shape (3, 3)
        Symmetric conic matrix, ``[x y 1] M [x y 1]ᵀ = 0``.
    f0 : float
        Scale constant.

    Returns
    -------
    ndarray, shape (6,)
    """
    theta = np.array([M[0, 0], M[0, 1], M[1, 1], M[0, 2] / f0, M[1, 2] / f0, M[2, 2] / f0**2])
    theta /= np.linalg.norm(theta)
    return theta if theta[0] > 0 else -theta


def carriers(xy: np.ndarray, f0: float = F0) -> np.ndarray:
    """Carriers ``ξ = (x², 2xy, y², 2 f0 x, 2 f0 y, f0²)`` of the points, ``θ · ξ = 0``.

    Parameters
    ----------
    xy : ndarray, shape (M, 2)
    f0 : float

    Returns
    -------
    ndarray, shape (M, 6)
    """
    x, y = xy[:, 0], xy[:, 1]
    return np.column_stack(
        [x * x, 2 * x * y, y * y, 2 * f0 * x, 2 * f0 * y, np.full_like(x, f0 * f0)]
    )


def carrier_jacobians(xy: np.ndarray, f0: float = F0) -> np.ndarray:
    """Jacobians ``T = ∂ξ/∂(x, y)`` of the carriers; ``V0[ξ] = T Tᵀ``.

    Parameters
    ----------
    xy : ndarray, shape (M, 2)
    f0 : float

    Returns
    -------
    ndarray, shape (M, 6, 2)
    """
    x, y = xy[:, 0], xy[:, 1]
    T = np.zeros((xy.shape[0], 6, 2))
    T[:, 0, 0] = 2 * x
    T[:, 1, 0] = 2 * y
    T[:, 1, 1] = 2 * x
    T[:, 2, 1] = 2 * y
    T[:, 3, 0] = 2 * f0
    T[:, 4, 1] = 2 * f0
    return T


def taubin(xy: np.ndarray, f0: float = F0) -> np.ndarray:
    """Taubin's algebraic conic estimate (unit norm, ``A >= 0``).

    Minimises ``θᵀ M θ / θᵀ N θ`` with ``M = Σ ξξᵀ`` and ``N = Σ V0[ξ]``: the generalised
    eigenvector of ``N θ = μ M θ`` of the largest ``μ``.

    Parameters
    ----------
    xy : ndarray, shape (M, 2)
        At least 5 points not all on one conic-degenerate set.
    f0 : float

    Returns
    -------
    ndarray, shape (6,)
    """
    xi = carriers(xy, f0)
    T = carrier_jacobians(xy, f0)
    M = xi.T @ xi
    N = np.einsum("mik,mjk->ij", T, T)
    _, vectors = sla.eigh(N, M)
    theta = vectors[:, -1] / np.linalg.norm(vectors[:, -1])
    return theta if theta[0] >= 0 else -theta


def align(theta: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """``theta`` normalised to unit norm, with the sign that makes ``θ · reference >= 0``.

    Parameters
    ----------
    theta, reference : ndarray, shape (6,)

    Returns
    -------
    ndarray, shape (6,)
    """
    theta = np.asarray(theta, dtype=float) / np.linalg.norm(theta)
    return theta if theta @ reference >= 0 else -theta


def _moment(xy: np.ndarray, theta: np.ndarray, f0: float) -> tuple[np.ndarray, np.ndarray]:
    """``M̄ = Σ ξ ξᵀ / (θᵀ V0[ξ] θ)`` and the weights ``1 / (θᵀ V0[ξ] θ)``."""
    xi = carriers(xy, f0)
    Ttheta = np.einsum("mik,i->mk", carrier_jacobians(xy, f0), theta)  # (T_iᵀ θ)
    weights = 1.0 / np.einsum("mk,mk->m", Ttheta, Ttheta)
    return (xi * weights[:, None]).T @ xi, weights


def _tangent_pinv(Mbar: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Rank-5 pseudo-inverse of ``M̄`` on the tangent space ``θ⊥`` of the unit sphere."""
    P = np.eye(theta.size) - np.outer(theta, theta)
    values, vectors = np.linalg.eigh(P @ Mbar @ P)
    values, vectors = values[1:], vectors[:, 1:]  # drop the null direction θ
    return (vectors / values) @ vectors.T


def kcr_covariance(
    xy_true: np.ndarray, theta: np.ndarray, sigma: float, f0: float = F0
) -> np.ndarray:
    """The KCR lower bound on the covariance of the unit conic vector.

    Parameters
    ----------
    xy_true : ndarray, shape (M, 2)
        Noise-free points (on the conic ``theta``).
    theta : ndarray, shape (6,)
        True unit conic vector.
    sigma : float
        Standard deviation of the iid isotropic noise on each coordinate.
    f0 : float

    Returns
    -------
    ndarray, shape (6, 6)
        ``sigma² (Σ ξ̄ξ̄ᵀ / θᵀV0[ξ̄]θ)⁻``, the pseudo-inverse taken on the tangent space ``θ⊥``;
        ``sqrt(trace)`` bounds the RMS of ``‖θ̂ − θ‖``.
    """
    Mbar, _ = _moment(xy_true, theta, f0)
    return sigma**2 * _tangent_pinv(Mbar, theta)


def kcr_covariance_kanagen(
    fam: kanagen.ModelFamily, xy_true: np.ndarray, theta: np.ndarray, sigma: float
) -> np.ndarray:
    """kanagen's constrained covariance at the truth: the KCR bound through kanagen.

    Fitting the noise-free points from ``θ*`` converges at once; the covariance is the inverse
    bordered information ``[[Q̃, C0ᵀ], [C0, 0]]⁻¹`` at the true point (its top-left block), with
    ``Q̃ = Σ ξ̄ξ̄ᵀ / (sigma² θᵀV0[ξ̄]θ)`` and ``C0 = 2θᵀ``: the same matrix as
    :func:`kcr_covariance`.

    Parameters
    ----------
    fam : kanagen.ModelFamily
        The ``conic`` family.
    xy_true : ndarray, shape (M, 2)
    theta : ndarray, shape (6,)
    sigma : float

    Returns
    -------
    ndarray, shape (6, 6)
    """
    res = kanagen.fit(
        fam, "conic", data={"point": xy_true}, info={"point": 1.0 / sigma**2}, q0=theta
    )
    return res.covariance


def first_order_errors(
    xy_true: np.ndarray, theta: np.ndarray, noise: np.ndarray, f0: float = F0
) -> np.ndarray:
    """First-order error of the ML estimate for given noise draws (it attains the KCR bound).

    ``Δθ = −M̄⁻ Σ_i ξ̄_i (θᵀ T̄_i e_i) / (θᵀ V0[ξ̄_i] θ)``: its covariance is exactly
    :func:`kcr_covariance`.

    Parameters
    ----------
    xy_true : ndarray, shape (M, 2)
    theta : ndarray, shape (6,)
    noise : ndarray, shape (trials, M, 2)
        Noise added to the true points in each trial.
    f0 : float

    Returns
    -------
    ndarray, shape (trials, 6)
    """
    Mbar, weights = _moment(xy_true, theta, f0)
    xi = carriers(xy_true, f0)
    Ttheta = np.einsum("mik,i->mk", carrier_jacobians(xy_true, f0), theta)
    h = np.einsum("tmk,mk->tm", noise, Ttheta) * weights  # θᵀ T̄_i e_i / w_i
    return -(h @ xi) @ _tangent_pinv(Mbar, theta)


# -- the three fitters --------------------------------------------------------------------------


@dataclass(frozen=True)
class Fit:
    """One method's answer on one trial."""

    theta: np.ndarray
    ok: bool
    seconds: float
    iterations: int


def fit_kanagen(
    fam: kanagen.ModelFamily,
    xy: np.ndarray,
    sigma: float,
    start: np.ndarray,
    xtol: float | None = None,
) -> Fit:
    """kanagen's geometric (ML) conic fit, timed.

    Parameters
    ----------
    fam : kanagen.ModelFamily
        The ``conic`` family.
    xy : ndarray, shape (M, 2)
    sigma : float
        Noise level; the information of each point is ``1 / sigma²``.
    start : ndarray, shape (6,)
        Starting unit vector.
    xtol : float, optional
        Step tolerance; kanagen's default when ``None``.

    Returns
    -------
    Fit
    """
    options = {} if xtol is None else {"xtol": xtol}
    t0 = time.perf_counter()
    res = kanagen.fit(
        fam, "conic", data={"point": xy}, info={"point": 1.0 / sigma**2}, q0=start, **options
    )
    seconds = time.perf_counter() - t0
    ok = bool(res.success and np.all(np.isfinite(res.q)) and np.linalg.norm(res.q) > 0)
    return Fit(res.q, ok, seconds, res.iterations)


def _odr_f(beta: np.ndarray, x: np.ndarray) -> np.ndarray:
    xx, yy = x
    return (
        beta[0] * xx * xx
        + 2 * beta[1] * xx * yy
        + beta[2] * yy * yy
        + 2 * F0 * (beta[3] * xx + beta[4] * yy)
        + F0 * F0 * beta[5]
    )


def _odr_jacb(beta: np.ndarray, x: np.ndarray) -> np.ndarray:
    xx, yy = x
    return np.stack(
        [xx * xx, 2 * xx * yy, yy * yy, 2 * F0 * xx, 2 * F0 * yy, np.full_like(xx, F0 * F0)]
    )


def _odr_jacd(beta: np.ndarray, x: np.ndarray) -> np.ndarray:
    xx, yy = x
    return np.stack(
        [
            2 * (beta[0] * xx + beta[1] * yy + F0 * beta[3]),
            2 * (beta[1] * xx + beta[2] * yy + F0 * beta[4]),
        ]
    )


def fixed_scale(start: np.ndarray) -> tuple[np.ndarray, int]:
    """ODR's start: ``start`` divided by its component of largest magnitude, and its index.

    Parameters
    ----------
    start : ndarray, shape (6,)

    Returns
    -------
    beta0 : ndarray, shape (6,)
        ``beta0[j] == 1``.
    j : int
        The component to hold fixed.
    """
    j = int(np.argmax(np.abs(start)))
    return start / start[j], j


def fit_scipy_odr(xy: np.ndarray, start: np.ndarray) -> Fit:
    """``scipy.odr`` in implicit mode with exact derivatives and a fixed scale, timed.

    Parameters
    ----------
    xy : ndarray, shape (M, 2)
    start : ndarray, shape (6,)

    Returns
    -------
    Fit
        ``iterations`` is ODR's iteration count (the ``NITER`` entry of ``iwork``).
    """
    beta0, j = fixed_scale(start)
    ifixb = np.ones(6, dtype=int)
    ifixb[j] = 0
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        model = scipy_odr.Model(_odr_f, fjacb=_odr_jacb, fjacd=_odr_jacd, implicit=True)
        solver = scipy_odr.ODR(scipy_odr.Data(xy.T, 1), model, beta0=beta0, ifixb=ifixb)
        solver.set_job(deriv=3)
        out = solver.run()
    seconds = time.perf_counter() - t0
    ok = bool(out.info in (1, 2, 3) and np.all(np.isfinite(out.beta)))
    iterations = int(out.iwork[_NITER])
    return Fit(out.beta, ok, seconds, iterations)


#: 0-based index of NITER in ODRPACK's integer work array: ODRPACK's DIWINF puts it at
#: (1-based) ``NQ*NP + NQ*M + NP + 15``, here with NQ = 1 response, NP = 6, M = 2 inputs.
_NITER = 1 * 6 + 1 * 2 + 6 + 14


def odrpack_available() -> bool:
    """Whether the ``odrpack`` package (PyPI) is installed."""
    return importlib.util.find_spec("odrpack") is not None


def fit_odrpack(xy: np.ndarray, start: np.ndarray) -> Fit:
    """``odrpack.odr_fit`` with ``task="implicit-ODR"``, set up like :func:`fit_scipy_odr`.

    Parameters
    ----------
    xy : ndarray, shape (M, 2)
    start : ndarray, shape (6,)

    Returns
    -------
    Fit
    """
    from odrpack import odr_fit

    beta0, j = fixed_scale(start)
    fix = np.zeros(6, dtype=bool)
    fix[j] = True
    t0 = time.perf_counter()
    out = odr_fit(
        lambda x, b: _odr_f(b, x),
        xy.T,
        np.zeros(xy.shape[0]),
        beta0,
        task="implicit-ODR",
        fix_beta=fix,
        jac_beta=lambda x, b: _odr_jacb(b, x),
        jac_x=lambda x, b: _odr_jacd(b, x),
    )
    seconds = time.perf_counter() - t0
    ok = bool(out.success and np.all(np.isfinite(out.beta)))
    return Fit(out.beta, ok, seconds, int(out.niter))


# -- the benchmark --------------------------------------------------------------------------------


@dataclass
class MethodStats:
    """One method's results over the trials of one noise level."""

    name: str
    errors: list[float] = field(default_factory=list)  # ‖θ̂ − θ*‖ per trial (nan if failed)
    seconds: list[float] = field(default_factory=list)
    iterations: list[int] = field(default_factory=list)
    failures: int = 0

    def add(self, fit: Fit, truth: np.ndarray) -> None:
        """Record one fit against the true vector."""
        self.seconds.append(fit.seconds)
        self.iterations.append(fit.iterations)
        if fit.ok:
            self.errors.append(float(np.linalg.norm(align(fit.theta, truth) - truth)))
        else:
            self.failures += 1
            self.errors.append(float("nan"))

    def rms(self, mask: np.ndarray) -> float:
        """RMS error over the trials selected by ``mask``."""
        e = np.asarray(self.errors)[mask]
        return float(np.sqrt(np.mean(e**2))) if e.size else float("nan")

    @property
    def median_ms(self) -> float:
        """Median fit time, milliseconds."""
        return 1e3 * statistics.median(self.seconds)


@dataclass
class LevelResult:
    """All methods at one noise level."""

    sigma: float
    trials: int
    kcr: float  # sqrt(tr V_KCR), formula
    kcr_kanagen_reldiff: float  # |tr(kanagen cov at truth) / tr(V_KCR) - 1|
    first_order_rms: float  # RMS of the first-order error on the same draws
    methods: dict[str, MethodStats]

    @property
    def common(self) -> np.ndarray:
        """Trials that every method fitted."""
        ok = np.ones(self.trials, dtype=bool)
        for m in self.methods.values():
            ok &= np.isfinite(np.asarray(m.errors))
        return ok


FitterFn = Callable[[np.ndarray, float, np.ndarray], Fit]


def _fit_kanagen_args(
    fam: kanagen.ModelFamily, xtol: float | None, xy: np.ndarray, sigma: float, start: np.ndarray
) -> Fit:
    return fit_kanagen(fam, xy, sigma, start, xtol)


def fitters(
    fams: dict[str, kanagen.ModelFamily], with_odrpack: bool, xtol: float | None = None
) -> dict[str, FitterFn]:
    """The methods to compare, by name, as ``(xy, sigma, start) -> Fit``.

    Parameters
    ----------
    fams : dict
        The ``conic`` family per kanagen backend (``numpy`` first).
    with_odrpack : bool
        Include ``odrpack``.
    xtol : float, optional
        kanagen's step tolerance (its default when ``None``).

    Returns
    -------
    dict
    """
    out: dict[str, FitterFn] = {
        KANAGEN[b]: functools.partial(_fit_kanagen_args, f, xtol) for b, f in fams.items()
    }
    out["scipy.odr"] = lambda xy, s, q: fit_scipy_odr(xy, q)
    if with_odrpack:
        out["odrpack"] = lambda xy, s, q: fit_odrpack(xy, q)
    return out


def noise_draws(
    sigma: float, trials: int, seed: int = SEED, n_points: int = N_POINTS
) -> np.ndarray:
    """The noise of every trial at one level, reproducible per ``(seed, sigma)``.

    Parameters
    ----------
    sigma : float
    trials, seed, n_points : int

    Returns
    -------
    ndarray, shape (trials, n_points, 2)
    """
    rng = np.random.default_rng((seed, round(1000 * sigma)))
    return sigma * rng.standard_normal((trials, n_points, 2))


def run_level(
    fam: kanagen.ModelFamily,
    sigma: float,
    trials: int,
    methods: dict[str, FitterFn],
    scene: Ellipse = SCENE,
    seed: int = SEED,
    repeats: int = 1,
) -> LevelResult:
    """Fit every trial at one noise level with every method; each fit is run ``repeats``
    times back to back and its fastest time kept (warm: its code and data in cache).

    Parameters
    ----------
    fam : kanagen.ModelFamily
    sigma : float
    trials : int
    methods : dict
        From :func:`fitters`.
    scene : Ellipse
    seed : int
    repeats : int

    Returns
    -------
    LevelResult
    """
    truth_xy = scene.points(N_POINTS)
    theta = scene.conic_vector()
    noise = noise_draws(sigma, trials, seed)
    V = kcr_covariance(truth_xy, theta, sigma)
    Vk = kcr_covariance_kanagen(fam, truth_xy, theta, sigma)
    stats = {name: MethodStats(name) for name in methods}
    xy0 = truth_xy + noise[0]  # warm-up: first calls pay for imports and caches
    for fn in methods.values():
        fn(xy0, sigma, taubin(xy0))
    for e in noise:
        xy = truth_xy + e
        start = taubin(xy)
        for name, fn in methods.items():
            fits = [fn(xy, sigma, start) for _ in range(repeats)]
            best = min(f.seconds for f in fits)
            stats[name].add(Fit(fits[0].theta, fits[0].ok, best, fits[0].iterations), theta)
    lin = first_order_errors(truth_xy, theta, noise)
    return LevelResult(
        sigma=sigma,
        trials=trials,
        kcr=float(np.sqrt(np.trace(V))),
        kcr_kanagen_reldiff=float(abs(np.trace(Vk) / np.trace(V) - 1.0)),
        first_order_rms=float(np.sqrt(np.mean(np.sum(lin**2, axis=1)))),
        methods=stats,
    )


def accuracy_ratio(level: LevelResult, method: str = "kanagen") -> float:
    """A kanagen backend's RMS error over ODR's, on the trials both (all) fitted."""
    mask = level.common
    return level.methods[method].rms(mask) / level.methods["scipy.odr"].rms(mask)


def time_ratio(level: LevelResult, peer: str = "scipy.odr", method: str = "kanagen") -> float:
    """Median fit time of ``peer`` over a kanagen backend's."""
    return level.methods[peer].median_ms / level.methods[method].median_ms


def format_tables(levels: Sequence[LevelResult]) -> str:
    """The accuracy and timing tables.

    Parameters
    ----------
    levels : sequence of LevelResult

    Returns
    -------
    str
    """
    names = list(levels[0].methods)
    peers = [n for n in names if not n.startswith("kanagen")]
    ours = [n for n in names if n.startswith("kanagen")]
    lines = [
        f"Conic fit, {N_POINTS} points on half an ellipse (centre ({SCENE.cx:g}, {SCENE.cy:g}), "
        f"semi-axes {SCENE.a:g}/{SCENE.b:g} px, {np.rad2deg(SCENE.angle):g} deg), f0 = {F0:g}",
        "",
        "Accuracy: RMS of ||theta_hat - theta*|| over the trials every method fitted",
    ]
    head = f"{'sigma':>5} {'trials':>6} {'KCR':>10} {'1st-ord':>10}"
    head += "".join(f" {n:>10}" for n in names)
    head += f" {'kan/odr':>8} {'kan/KCR':>8} {'KCR chk':>8}"
    lines += [head, "-" * len(head)]
    for lv in levels:
        mask = lv.common
        row = f"{lv.sigma:>5g} {int(mask.sum()):>6d} {lv.kcr:>10.4e} {lv.first_order_rms:>10.4e}"
        row += "".join(f" {lv.methods[n].rms(mask):>10.4e}" for n in names)
        row += (
            f" {accuracy_ratio(lv):>8.4f} {lv.methods['kanagen'].rms(mask) / lv.kcr:>8.4f}"
            f" {lv.kcr_kanagen_reldiff:>8.1e}"
        )
        lines.append(row)
    lines += [
        "  KCR = sqrt(tr V_KCR); 1st-ord = RMS of the first-order (KCR) error on the same draws;",
        "  KCR chk = |tr(kanagen covariance at the truth) / tr(V_KCR) - 1|",
        "",
        "Time: median per fit (ms), peer/kanagen ratio of the medians (per kanagen backend:",
        "kan NumPy, kanC compiled, kanX CasADi), failures out of the trials, mean iterations",
    ]
    short = [SHORT.get(n, n) for n in names]
    pairs = [(p, m) for m in ours for p in peers]
    head = f"{'sigma':>5}" + "".join(f" {s + ' ms':>9}" for s in short)
    head += "".join(f" {SHORT.get(p, p) + '/' + SHORT[m]:>10}" for p, m in pairs)
    head += "".join(f" {s + ' fail':>10}" for s in short)
    head += "".join(f" {s + ' it':>8}" for s in short)
    lines += [head, "-" * len(head)]
    for lv in levels:
        row = f"{lv.sigma:>5g}" + "".join(f" {lv.methods[n].median_ms:>9.3f}" for n in names)
        row += "".join(f" {time_ratio(lv, p, m):>10.3f}" for p, m in pairs)
        row += "".join(f" {lv.methods[n].failures:>10d}" for n in names)
        row += "".join(f" {np.mean(lv.methods[n].iterations):>8.2f}" for n in names)
        lines.append(row)
    return "\n".join(lines)


def verdicts(levels: Sequence[LevelResult]) -> list[tuple[str, bool, str]]:
    """The floors: accuracy of every kanagen backend, speed of the compiled one
    (``(name, passed, detail)``).

    Parameters
    ----------
    levels : sequence of LevelResult

    Returns
    -------
    list of tuple
    """
    out = []
    for method in [m for m in levels[0].methods if m.startswith("kanagen")]:
        acc = [(accuracy_ratio(lv, method), lv.methods[method].failures,
                lv.methods["scipy.odr"].failures) for lv in levels]
        out.append((
            f"accuracy: RMS({method}) <= {1 + ACCURACY_TOL:.2f} x RMS(scipy.odr), no more "
            "failures",
            all(r <= 1 + ACCURACY_TOL and fk <= fo for r, fk, fo in acc),
            ", ".join(f"sigma {lv.sigma:g}: {r:.4f} (fail {fk} vs {fo})"
                      for lv, (r, fk, fo) in zip(levels, acc, strict=True)),
        ))
    method = KANAGEN[FLOOR_BACKEND]
    if method in levels[0].methods:
        # the floor names scipy.odr "(or odrpack)": each peer gets its own line
        for peer in [p for p in ("scipy.odr", "odrpack") if p in levels[0].methods]:
            spd = [time_ratio(lv, peer, method) for lv in levels]
            out.append((
                f"speed: median t({peer}) / t({method}) >= {SPEED_FLOOR:g}",
                all(r >= SPEED_FLOOR for r in spd),
                ", ".join(f"sigma {lv.sigma:g}: {r:.2f}x"
                          for lv, r in zip(levels, spd, strict=True)),
            ))
    return out


def profile_kanagen(
    fam: kanagen.ModelFamily, sigma: float, trials: int, top: int = 25, xtol: float | None = None
) -> str:
    """``cProfile`` of kanagen's fits at one noise level: where the time goes.

    Parameters
    ----------
    fam : kanagen.ModelFamily
    sigma : float
    trials : int
    top : int
        Rows of each listing.
    xtol : float, optional
        kanagen's step tolerance.

    Returns
    -------
    str
        The listings sorted by own time and by cumulative time.
    """
    truth_xy = SCENE.points(N_POINTS)
    noise = noise_draws(sigma, trials)
    starts = [taubin(truth_xy + e) for e in noise]
    fit_kanagen(fam, truth_xy + noise[0], sigma, starts[0], xtol)
    profiler = cProfile.Profile()
    profiler.enable()
    for e, q in zip(noise, starts, strict=True):
        fit_kanagen(fam, truth_xy + e, sigma, q, xtol)
    profiler.disable()
    out = io.StringIO()
    stats = pstats.Stats(profiler, stream=out)
    stats.strip_dirs()
    out.write(f"cProfile of {trials} kanagen fits at sigma = {sigma:g}, by own time\n")
    stats.sort_stats("tottime").print_stats(top)
    out.write("by cumulative time\n")
    stats.sort_stats("cumulative").print_stats(top)
    return out.getvalue()


def main(argv: Sequence[str] | None = None) -> int:
    """Command line entry point: print the tables and the PASS/FAIL lines.

    Parameters
    ----------
    argv : sequence of str, optional

    Returns
    -------
    int
        0 when both floors pass, 1 otherwise.
    """
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=TRIALS, help="trials per noise level")
    parser.add_argument(
        "--sigmas", type=float, nargs="+", default=list(SIGMAS), help="noise levels in pixels"
    )
    parser.add_argument("--seed", type=int, default=SEED)
    parser.add_argument(
        "--xtol", type=float, default=None, help="kanagen's step tolerance (default: kanagen.fit's)"
    )
    parser.add_argument("--no-odrpack", action="store_true", help="skip odrpack even if installed")
    parser.add_argument(
        "--repeats", type=int, default=3,
        help="time each fit this many times back to back and keep the fastest (1: one cold "
             "call per method, interleaved)")
    parser.add_argument(
        "--backends", nargs="+", default=["numpy", "compiled"], choices=list(KANAGEN),
        help="kanagen backends to time (numpy first: accuracy ratios and KCR check use it)")
    parser.add_argument(
        "--profile",
        action="store_true",
        help="also print a cProfile of kanagen's fits at sigma = 1",
    )
    args = parser.parse_args(argv)
    if args.trials < 1:
        parser.error("--trials must be positive")
    fams = {}
    for backend in args.backends:
        fam = kanagen.load("conic", backend=backend)
        if fam.backend != backend:
            print(f"kanagen[{backend}]: not available here (backend {fam.backend!r}), skipped")
            continue
        fams[backend] = fam
    fam = kanagen.load("conic")
    with_odrpack = odrpack_available() and not args.no_odrpack
    if not with_odrpack:
        print(
            "odrpack: "
            + (
                "skipped (--no-odrpack)"
                if args.no_odrpack
                else "not installed (pip install 'kanagen[bench]'), skipped"
            )
        )
    methods = fitters(fams, with_odrpack, args.xtol)
    levels = [run_level(fam, s, args.trials, methods, seed=args.seed, repeats=args.repeats)
              for s in args.sigmas]
    print(format_tables(levels))
    print()
    passed = True
    for name, ok, detail in verdicts(levels):
        print(f"{'PASS' if ok else 'FAIL'}  {name}  [{detail}]")
        passed &= ok
    if args.profile:
        print()
        print(profile_kanagen(fam, 1.0, min(args.trials, 100), xtol=args.xtol))
    return 0 if passed else 1


if __name__ == "__main__":
    sys.exit(main())
