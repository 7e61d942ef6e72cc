"""One scenario per shipped spec, for the tests that compare two ways of computing the same
estimate (backends, elimination of linear constraints): cases that converge, with weights,
starts and constants."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scenes import arc, kasa_circle

import kanagen
from kanagen.scenes import calibrated_scene, two_view_scene

ROOT = Path(__file__).resolve().parents[1]
SPECS = sorted((ROOT / "examples").glob("*.yaml"))
RTOL = 1e-10


#: Two channels (one with an exact component), a constraint on a sphere: the engine's
#: per-measure paths on more than one channel.
TWOCHAN = """\
name: twochan
constants: {s: 2.0}
parameter: {a: 1.0, b: 0.5, c: 0.1}
channels:
  pts:
    components: [x, y]
    equations: [y - a*x**2 - b*x - c]
  obs:
    components: [t, u, v]
    exact: [t]
    equations: [u - a*t - b, v - s*c*t - exp(-b*t)]
models:
  free:
    constraints: []
    alternatives: [tied, sphere]
  tied:
    constraints: [a - 2*b]
  sphere:
    constraints: [a**2 + b**2 + c**2 - 1.61]
"""


def twochan_data(seed: int, M1: int, M2: int, noise: float = 0.05):
    """Measures of :data:`TWOCHAN` at ``a, b, c = 0.8, 0.4, 0.9``: ``M1`` points, ``M2``
    observations, Gaussian noise."""
    rng = np.random.default_rng(seed)
    a, b, c = 0.8, 0.4, 0.9
    x = rng.uniform(-2, 2, M1)
    t = rng.uniform(0, 3, M2)
    pts = np.c_[x, a * x**2 + b * x + c] + rng.normal(0, noise, (M1, 2))
    obs = np.c_[t, a * t + b, 2.0 * c * t + np.exp(-b * t)]
    obs[:, 1:] += rng.normal(0, noise, (M2, 2))
    return {"pts": pts, "obs": obs}


def close(a, b, rtol=RTOL, scale=0.0):
    """``a`` equals the reference ``b`` to ``rtol`` relative to ``b``'s magnitude (or to
    ``scale`` if larger); infinite and NaN entries must sit at the same places."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    assert a.shape == b.shape
    finite = np.isfinite(b)
    np.testing.assert_array_equal(np.isfinite(a), finite)
    np.testing.assert_array_equal(a[~finite], b[~finite])
    scale = max(scale, float(np.max(np.abs(b[finite]), initial=0.0)))
    np.testing.assert_allclose(a[finite], b[finite], rtol=rtol, atol=rtol * max(scale, 1e-300))


def _line_start(xy: np.ndarray, f0: float = 100.0) -> np.ndarray:
    """The conic vector of the total-least-squares line through ``xy`` (A = B = C = 0)."""
    centre = xy.mean(axis=0)
    normal = np.linalg.svd(xy - centre)[2][-1]
    q = np.array([0, 0, 0, normal[0], normal[1], -2 * normal @ centre / f0])
    return q / np.linalg.norm(q)  # the slack components follow from it


def conic_cases():
    xy, _ = arc("ellipse", 3, n=30, outliers=0.0, sigma=0.5)
    start = kasa_circle(xy)
    return [("circle", {"point": xy}, {"point": 4.0}, start, None),
            ("conic", {"point": xy}, {"point": 4.0}, start, None)]


def conic_lattice_cases():
    cases = []
    for kind, model in (("line", "line"), ("circle", "circle"), ("ellipse", "ellipse"),
                        ("ellipse", "conic")):
        xy, _ = arc(kind, 3, n=40, outliers=0.0)
        start = _line_start(xy) if model == "line" else kasa_circle(xy)
        info = np.random.default_rng(1).uniform(0.5, 2.0, len(xy)) if model != "line" else 1.0
        cases.append((model, {"point": xy}, {"point": info}, start, None))
    return cases


def line_cases():
    rng = np.random.default_rng(1)
    x = np.linspace(0, 10, 20)
    xy = np.c_[x, 0.5 * x + 2] + rng.normal(0, 0.1, (20, 2))
    Q = np.array([[2.0, 0.3], [0.3, 1.0]])
    return [("horizontal", {"point": xy}, {"point": Q}, None, None),
            ("line", {"point": xy}, {"point": Q}, None, None)]


def hysteresis_cases():
    cases = []
    fam = kanagen.load("hysteresis")
    for t, s_prev in ((0.0, 1.0), (2.5, 1.0), (-2.5, -1.0)):
        consts = {"t": t, "s_prev": s_prev}
        start = fam.with_slacks(np.array([t - s_prev, s_prev]), fam.constant_vector(consts),
                                "hysteresis")
        r = np.array([[t - s_prev + 0.01], [t - s_prev - 0.02]])
        cases.append(("hysteresis", {"reading": r}, None, start, consts))
    return cases


def two_view_cases():
    """Scenes of both kinds of equations (H-type: zoom, rotation, planar; F-type: general),
    noisy, from the truth moved off its constraints. Covariances are compared to 1e-10, so
    the scenes have information conditioned well enough for it: the focal lengths of the
    general model from 30 matches can be conditioned at 1e7 (seed 3: its covariance moves
    by 3e-10 between two converged points 5e-14 apart)."""
    fam = kanagen.load("two_view")
    cases = []
    for motion, seed in (("zoom", 5), ("rotation", 4), ("planar", 2), ("general", 4)):
        s = two_view_scene(motion, n=30, sigma=0.5, seed=seed)
        p = s.params()
        q = np.array([p[n] for n in fam.parameter_names])
        start = q + np.random.default_rng(seed).normal(0, 1e-3, q.size)
        cases.append((motion, {"match": s.data}, {"match": 4.0}, start, s.constants))
    return cases


def calibrated_cases():
    """Calibrated views: H-type (rotation, planar) and F-type (retinal displacement, general)
    scenes, noisy, from the truth moved off its constraints."""
    fam = kanagen.load("two_view_calibrated")
    cases = []
    for motion, seed in (("rotation", 4), ("planar", 2), ("retinal_displacement", 3),
                         ("general", 4)):
        s = calibrated_scene(motion, n=30, sigma=0.5, seed=seed)
        p = s.params()
        q = np.array([p[n] for n in fam.parameter_names])
        start = q + np.random.default_rng(seed).normal(0, 1e-3, q.size)
        cases.append((motion, {"match": s.data}, {"match": 4.0}, start, s.constants))
    return cases


def pga_cases():
    """Readings at gain 4 (no glitches): the qualitative model from a start near the setting
    (its quartic constraint pulls the gain onto 4), from the setting 1 (a local solve stays
    there), and the general linear model with a per-reading information."""
    rng = np.random.default_rng(7)
    v = rng.uniform(-1.0, 1.0, 25)
    data = {"reading": np.c_[v, 4.0 * v + 0.3 + rng.normal(0.0, 0.01, v.size)]}
    return [("pga", data, {"reading": 1e4}, np.array([3.9, 0.2]), None),
            ("pga", data, {"reading": 1e4}, np.array([1.0, 0.0]), None),
            ("linear", data, {"reading": rng.uniform(0.5e4, 2e4, v.size)}, None, None)]


#: The scenario fits that cannot reach their constraints (spec, case): the hysteresis's
#: second and third, whose readings (t − s_prev, the old state's) conflict with the state
#: their constants force — no feasible point near their start, the fit stops at its cap.
OFF_CONSTRAINTS = (("hysteresis.yaml", 1), ("hysteresis.yaml", 2))

#: spec file name -> cases (model, data, info, start, constants)
SCENARIOS = {"conic.yaml": conic_cases, "conic_lattice.yaml": conic_lattice_cases,
             "line.yaml": line_cases, "hysteresis.yaml": hysteresis_cases,
             "two_view.yaml": two_view_cases, "pga.yaml": pga_cases,
             "two_view_calibrated.yaml": calibrated_cases}


