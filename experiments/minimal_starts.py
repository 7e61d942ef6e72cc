"""Minimal solves of the rotation and translation models (report eq. 21): from the parent's
estimate (the null model's q, as without a closed form) against from the candidates of
their closed-form initializers, on the compiled backend.

Two-match samples of generated scenes (σ = 0.5 px, 200 inliers, 30 % outliers), all-inlier
samples and uniform ones; per start: the time of one minimal solve (median), its iterations
(mean) and whether it succeeds at full rank; per sample: the initializer's time and whether
some start gives a solution. Run: ``python experiments/minimal_starts.py [--scenes N]``.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

import kanagen  # noqa: E402
from kanagen.runtime.fit import make_problem  # noqa: E402
from kanagen.runtime.initializers import model_initializers, start_from  # noqa: E402
from kanagen.runtime.minimal import minimal_solve_problem  # noqa: E402
from kanagen.scenes import two_view_scene  # noqa: E402


def measure(fam, model: str, init, pool_kind: str, scenes: int, samples: int,
            rng: np.random.Generator) -> str:
    """One line of figures for ``model`` from ``init``'s starts (None: the parent's)."""
    t_init, t_solve, iterations, solved, any_solved, starts_total = [], [], [], 0, 0, 0
    for s in range(scenes):
        scene = two_view_scene(model, n=200, outliers=0.3, sigma=0.5, seed=3000 + s)
        X, k = np.ascontiguousarray(scene.data), scene.constants
        pool = np.flatnonzero(scene.inliers) if pool_kind == "inliers" else np.arange(len(X))
        for _ in range(samples):
            rows = X[rng.choice(pool, 2, replace=False)]
            problem = make_problem(fam, model, {"match": rows}, None, constants=k)
            starts = [fam.q0]
            if init is not None:
                t0 = time.perf_counter()
                candidates = init(rows, k)
                t_init.append(time.perf_counter() - t0)
                starts = [start_from(fam, c, fam.q0) for c in candidates]
            starts_total += len(starts)
            found = False
            for q in starts:
                t0 = time.perf_counter()
                sol = minimal_solve_problem(problem, q)
                t_solve.append(time.perf_counter() - t0)
                iterations.append(sol.iterations)
                ok = sol.success and sol.rank >= fam.n
                solved += ok
                found |= ok
            any_solved += found
    n = scenes * samples
    head = f"{model:<12} {pool_kind:<8} {'closed form' if init else 'parent':<12}"
    return (f"{head} initializer {np.median(t_init) * 1e6 if t_init else 0.0:5.1f} µs, "
            f"solve {np.median(t_solve) * 1e6:6.1f} µs, {np.mean(iterations):5.2f} "
            f"iterations, {solved / max(len(t_solve), 1):6.1%} of starts solved, "
            f"{any_solved / n:6.1%} of samples, {starts_total / n:4.2f} starts per sample")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=10)
    parser.add_argument("--samples", type=int, default=200, help="per scene")
    args = parser.parse_args()
    fam = kanagen.load("two_view", backend="compiled")
    inits = model_initializers(fam)
    for model in ("rotation", "translation"):
        for pool_kind in ("inliers", "uniform"):
            for init in (None, inits[model]):
                rng = np.random.default_rng(0)  # the same samples for both starts
                print(measure(fam, model, init, pool_kind, args.scenes, args.samples, rng))


if __name__ == "__main__":
    main()
