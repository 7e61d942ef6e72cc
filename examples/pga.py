"""A qualitative variable resolved from data: calibrating a programmable-gain amplifier.

``examples/pga.yaml`` states the gain as one of the amplifier's settings, ``g in {1, 2, 4,
8}`` (appendix F: compiled into ``(g − 1)(g − 2)(g − 4)(g − 8) = 0``), with a free offset.
The robust search starts a solve on each setting and keeps what the data support; a reading
taken at a gain that is no setting (a fault) makes the more general ``linear`` model win.
A local fit, by contrast, stays on the setting it starts at.

Run: ``python examples/pga.py``.
"""

from __future__ import annotations

import numpy as np

import kanagen


def readings(gain: float, offset: float = 0.3, sigma: float = 0.01, outliers: float = 0.3,
             count: int = 120, seed: int = 0) -> np.ndarray:
    """Readings ``(v, r)`` of known inputs ``v`` at ``gain``, a fraction of them glitches."""
    rng = np.random.default_rng(seed)
    v = rng.uniform(-1.0, 1.0, count)
    r = gain * v + offset + rng.normal(0.0, sigma, count)
    bad = rng.random(count) < outliers
    r[bad] = rng.uniform(-9.0, 9.0, bad.sum())
    return np.c_[v, r]


def calibrate(data: np.ndarray, sigma: float = 0.01, seed: int = 0):
    """The robust lattice search (pga → linear) on the readings: its best model."""
    est = kanagen.Estimator(kanagen.load("pga"), scale=4.0, seed=seed)
    est.add_measures("reading", data, info=1.0 / sigma**2)
    return est.run(max_samples=500)


def main() -> None:
    for gain in (4.0, 3.3):
        best = calibrate(readings(gain))
        print(f"readings at gain {gain}: model {best.model!r}, g = {best.params['g']:.6f}, "
              f"o = {best.params['o']:.4f}, {len(best.inliers)} inliers")


if __name__ == "__main__":
    main()
