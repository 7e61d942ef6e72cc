"""How the cost of one projector iteration and of one robust sample grows with the measures.

Issue 5 asks that both grow linearly in the number of measures M, from 10² to 10⁵. The
scene: the shipped ``conic`` family, points on an ellipse (σ = 1 px) with 30 % uniform
outliers in a 640 × 480 image.

* *projector iteration*: one application of the projector at a point near the solution —
  the equations evaluated, linearised, whitened and solved (``evaluate``, ``linearise``,
  ``solve`` of :mod:`kanagen.runtime.projector`).
* *robust sample*: one step of the random search (:class:`kanagen.runtime.robust.
  ModelSearch`): draw a minimal sample, solve it (eq. 21), score every measure (eq. 24,
  29). Steps that improve the best estimate also refine it (LO-RANSAC); the median over
  the steps is the plain sample.

Every figure is the median, over blocks of runs in this process, of the time per run: wall
time and user CPU time (the process's own work; the kernel's time, mostly page faults on
the fresh memory of large arrays, is the difference, and it is large in some virtual
machines). The table prints the time per measure and the growth factor from the previous M
(10 for linear growth; fixed costs make it smaller at small M).

Run ``python benchmarks/scaling.py`` (``--sizes 100 1000`` for a quick run); the table in
docs/performance.md comes from it.
"""

from __future__ import annotations

import argparse
import resource
import statistics
import sys
import time
from collections.abc import Callable, Sequence

import numpy as np

import kanagen
from kanagen.runtime.fit import make_problem
from kanagen.runtime.projector import evaluate, linearise, solve
from kanagen.runtime.robust import ModelSearch

SIZES = (100, 1_000, 10_000, 100_000)
#: A conic close to the scene's ellipse: the linearisation point.
A, B, CX, CY = 220.0, 130.0, 330.0, 250.0


def scene(M: int, seed: int = 0) -> np.ndarray:
    """M points: 70 % on the ellipse (σ = 1 px), 30 % uniform outliers."""
    rng = np.random.default_rng(seed)
    k = int(0.7 * M)
    t = rng.uniform(0, 2 * np.pi, k)
    on = np.c_[CX + A * np.cos(t), CY + B * np.sin(t)] + rng.normal(0, 1, (k, 2))
    return np.r_[on, rng.uniform([0, 0], [640, 480], (M - k, 2))]


def ellipse_vector(f0: float = 100.0) -> np.ndarray:
    """The unit conic vector of the scene's ellipse (axis-aligned)."""
    a, c = 1 / A**2, 1 / B**2
    q = np.array([a, 0.0, c, -a * CX / f0, -c * CY / f0, (a * CX**2 + c * CY**2 - 1) / f0**2])
    return q / np.linalg.norm(q)


def median_time(fn: Callable[[], object], repeats: int, block: float = 0.1
                ) -> tuple[float, float]:
    """Median seconds per call, wall and user CPU, over ``repeats`` blocks of calls lasting
    at least ``block`` seconds each (after one warm-up)."""
    fn()
    t0 = time.perf_counter()
    fn()
    per_block = max(1, int(block / max(time.perf_counter() - t0, 1e-9)))
    walls, users = [], []
    for _ in range(repeats):
        u0, t0 = resource.getrusage(resource.RUSAGE_SELF).ru_utime, time.perf_counter()
        for _ in range(per_block):
            fn()
        walls.append((time.perf_counter() - t0) / per_block)
        users.append((resource.getrusage(resource.RUSAGE_SELF).ru_utime - u0) / per_block)
    return statistics.median(walls), statistics.median(users)


def projector_iteration(fam: kanagen.ModelFamily, xy: np.ndarray, repeats: int
                        ) -> tuple[float, float]:
    """Seconds of one projector iteration at the ellipse (see the module docstring)."""
    q = ellipse_vector()
    problem = make_problem(fam, "conic", {"point": xy}, None, q0=q)

    def step():
        x = evaluate(problem, q, (problem.channels[0].m,))
        solve(problem, linearise(problem, x))

    with np.errstate(all="ignore"):
        return median_time(step, repeats)


def robust_sample(fam: kanagen.ModelFamily, xy: np.ndarray, repeats: int
                  ) -> tuple[float, float]:
    """Median seconds of one step of the random search on the conic model."""
    problem = make_problem(fam, "conic", {"point": xy}, None)
    search = ModelSearch(fam, "conic", problem, 0, ellipse_vector(), np.random.default_rng(0),
                         scale=4.0)
    return median_time(search.step, repeats)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=list(SIZES))
    parser.add_argument("--backends", nargs="+", default=["numpy", "compiled"],
                        choices=["numpy", "casadi", "compiled"])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)
    rows = []
    for backend in args.backends:
        fam = kanagen.load("conic", backend=backend)
        for M in args.sizes:
            xy = scene(M)
            rows.append((fam.backend, M, projector_iteration(fam, xy, args.repeats),
                         robust_sample(fam, xy, args.repeats)))
    head = (f"{'backend':>9} {'M':>7} | {'iteration: wall us/m':>20} {'user us/m':>9} "
            f"{'growth':>6} | {'sample: wall us/m':>17} {'user us/m':>9} {'growth':>6}")
    print(head)
    print("-" * len(head))
    previous: dict = {}
    for backend, M, (wi, ui), (ws, us) in rows:
        gi = ui / previous[backend][0] if backend in previous else float("nan")
        gs = us / previous[backend][1] if backend in previous else float("nan")
        previous[backend] = (ui, us)
        print(f"{backend:>9} {M:>7} | {wi / M * 1e6:>20.4f} {ui / M * 1e6:>9.4f} {gi:>6.2f} | "
              f"{ws / M * 1e6:>17.4f} {us / M * 1e6:>9.4f} {gs:>6.2f}")
    print("us/m: microseconds per measure; growth: user time over the previous M's "
          "(10 when linear)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
