"""Generated scenes for the robust and lattice tests: arcs of lines, circles, ellipses."""

from __future__ import annotations

import numpy as np

#: the conic_lattice model each kind of arc should choose
LATTICE_MODEL = {"line": "line", "circle": "circle", "ellipse": "ellipse", "hyperbola": "conic"}


def arc(kind: str, seed: int, n: int = 150, outliers: float = 0.3, sigma: float = 1.0,
        radius: float = 120.0) -> tuple[np.ndarray, np.ndarray]:
    """Points on a line, a circle, an ellipse or one branch of a hyperbola (``kind``), with
    uniform outliers in a 640×480 image; returns the shuffled points and the inlier mask."""
    rng = np.random.default_rng(seed)
    th = rng.uniform(0, np.pi)
    if kind == "line":
        t = rng.uniform(-150, 150, n)
        xy = np.c_[320 + t * np.cos(th), 240 + t * np.sin(th)]
    elif kind in ("circle", "ellipse"):
        t = rng.uniform(0, np.pi, n) + rng.uniform(0, 2 * np.pi)
        a, b = (radius, radius) if kind == "circle" else (1.6 * radius, 0.8 * radius)
        u, v = a * np.cos(t), b * np.sin(t)
        xy = np.c_[320 + u * np.cos(th) - v * np.sin(th), 240 + u * np.sin(th) + v * np.cos(th)]
    elif kind == "hyperbola":  # x²/a² − y²/b² = 1, the branch x > 0, centred in the image
        t = rng.uniform(-1.3, 1.3, n)
        a, b = 0.6 * radius, 0.8 * radius
        u, v = a * np.cosh(t), b * np.sinh(t)
        u = u - u.mean()
        xy = np.c_[320 + u * np.cos(th) - v * np.sin(th), 240 + u * np.sin(th) + v * np.cos(th)]
    else:
        raise ValueError(f"unknown kind of arc {kind!r}")
    xy = xy + rng.normal(0, sigma, xy.shape)
    k = int(round(n * outliers / (1 - outliers)))
    pts = np.r_[xy, rng.uniform([0, 0], [640, 480], (k, 2))]
    truth = np.r_[np.ones(n, bool), np.zeros(k, bool)]
    order = rng.permutation(len(pts))
    return pts[order], truth[order]


def kasa_circle(xy: np.ndarray, f0: float = 100.0) -> np.ndarray:
    """Kåsa's algebraic circle ``x² + y² + a x + b y + c = 0`` as a unit conic vector
    (A, B, C, D, E, F) of the conic specs (scale ``f0``): a start for circle fits."""
    x, y = xy.T
    a, b, c = np.linalg.lstsq(np.c_[x, y, np.ones_like(x)], -(x * x + y * y), rcond=None)[0]
    q = np.array([1.0, 0.0, 1.0, a / (2 * f0), b / (2 * f0), c / f0**2])
    return q / np.linalg.norm(q)
