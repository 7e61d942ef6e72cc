"""Generated scenes for the robust and lattice tests: arcs of lines, circles, ellipses."""

from __future__ import annotations

import numpy as np


def arc(kind: str, seed: int, n: int = 150, outliers: float = 0.3, sigma: float = 1.0,
        radius: float = 120.0) -> tuple[np.ndarray, np.ndarray]:
    """Points on a line, a circle or an ellipse (``kind``), with uniform outliers in a
    640×480 image; returns the shuffled points and the inlier mask."""
    rng = np.random.default_rng(seed)
    if kind == "line":
        t = rng.uniform(-150, 150, n)
        th = rng.uniform(0, np.pi)
        xy = np.c_[320 + t * np.cos(th), 240 + t * np.sin(th)]
    else:
        t = rng.uniform(0, np.pi, n) + rng.uniform(0, 2 * np.pi)
        a, b = (radius, radius) if kind == "circle" else (1.6 * radius, 0.8 * radius)
        th = rng.uniform(0, np.pi)
        xy = np.c_[320 + a * np.cos(t) * np.cos(th) - b * np.sin(t) * np.sin(th),
                   240 + a * np.cos(t) * np.sin(th) + b * np.sin(t) * np.cos(th)]
    xy = xy + rng.normal(0, sigma, xy.shape)
    k = int(round(n * outliers / (1 - outliers)))
    pts = np.r_[xy, rng.uniform([0, 0], [640, 480], (k, 2))]
    truth = np.r_[np.ones(n, bool), np.zeros(k, bool)]
    order = rng.permutation(len(pts))
    return pts[order], truth[order]
