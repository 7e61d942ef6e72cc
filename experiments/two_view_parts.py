"""Where a two-view search's time goes: its fits by role and its samples by size, timed
around the engine's kernels (docs/performance.md, twenty-fourth session).

Runs the two-view benchmark's scenes (``kanagen.scenes.two_view_scene``, 200 inliers, 30 %
outliers, σ 0.5 px; ``--scenes`` of them, the eight motions in turn) through
``kanagen.Estimator`` at its defaults, twice (the first warms the caches), and times the
second: every fit's kernel (``engine.iterate.run_flat``) by the refinement step that asked
for it — LO-RANSAC's refinement (``refined``), a round's race of starts (``_race``), a
round verified (``_verified``), a lap past a cap (``_go_on``), a deletion test
(``_pruned``), a cross-check (``_cross_checked``), the rounds after them (``_rounds``) — and
every burst of samples (``Sampler.burst``) by the parameter's size and the sample's:
calls, time, the kernel's share of the search. The rest is the search's Python.

Run ``python experiments/two_view_parts.py [--scenes 24]`` (about a minute).
"""

from __future__ import annotations

import argparse
import collections
import sys
import time

import kanagen
from kanagen.runtime import fastsample
from kanagen.runtime.engine import iterate as engine
from kanagen.scenes import MOTIONS, two_view_scene

#: The refinement steps a fit is made for, innermost first (their function names).
ROLES = ("refined", "_verified", "_race", "_go_on", "_pruned", "_cross_checked", "_rounds")


def scenes(count: int) -> list:
    """The benchmark's first ``count`` scenes, the motions in turn (and their seeds)."""
    out = []
    for k in range(count):
        j, trial = k % len(MOTIONS), k // len(MOTIONS)
        seed = 1000 * j + trial
        out.append((two_view_scene(MOTIONS[j], n=200, outliers=0.3, sigma=0.5, seed=seed),
                    seed))
    return out


def search(fam, scene, seed: int) -> None:
    est = kanagen.Estimator(fam, seed=seed, constants=scene.constants)
    est.add_measures("match", scene.data, info=1.0 / scene.sigma**2)
    est.run(max_samples=10_000)


def role(frame) -> str:
    """The refinement step that asked for a fit: the innermost of :data:`ROLES` on the
    stack, else the first function above the fit's own (``iterate``, ``fit_problem``)."""
    names = []
    while frame is not None and len(names) < 8:
        names.append(frame.f_code.co_name)
        frame = frame.f_back
    return next((n for n in names if n in ROLES),
                next((n for n in names if n not in ("iterate", "fit_problem")), names[0]))


def measure(count: int) -> tuple[float, dict, dict]:
    """The second run's total seconds, the fits' ``{role: [calls, seconds, iterations]}``
    and the bursts' ``{(n, sample size): [samples, without a solution, seconds]}``."""
    fam = kanagen.load("two_view")
    made = scenes(count)
    fits: dict = collections.defaultdict(lambda: [0, 0.0, 0])
    bursts: dict = collections.defaultdict(lambda: [0, 0, 0.0])
    run_flat, burst = engine.run_flat, fastsample.Sampler.burst

    def timed_fit(*args):
        t0 = time.perf_counter()
        out = run_flat(*args)
        entry = fits[role(sys._getframe(1))]
        entry[0] += 1
        entry[1] += time.perf_counter() - t0
        entry[2] += int(out[1])
        return out

    def timed_burst(self, limit, best, pool, kpool, base, kbase, rng):
        t0 = time.perf_counter()
        out = burst(self, limit, best, pool, kpool, base, kbase, rng)
        entry = bursts[(self.A.q0.size, kpool + kbase)]
        entry[0] += out[0]
        entry[1] += out[1]
        entry[2] += time.perf_counter() - t0
        return out

    engine.run_flat, fastsample.Sampler.burst = timed_fit, timed_burst
    try:
        for scene, seed in made:  # caches warmed, then timed
            search(fam, scene, seed)
        fits.clear()
        bursts.clear()
        t0 = time.perf_counter()
        for scene, seed in made:
            search(fam, scene, seed)
        total = time.perf_counter() - t0
    finally:
        engine.run_flat, fastsample.Sampler.burst = run_flat, burst
    return total, dict(fits), dict(bursts)


def report(count: int, total: float, fits: dict, bursts: dict) -> str:
    lines = [f"{count} scenes: {1e3 * total / count:.1f} ms a scene"]
    lines.append(f"{'fits by role':16s} {'a scene':>8s} {'µs each':>8s} {'iter.':>6s} "
                 f"{'share':>6s}")
    for name, (calls, seconds, iterations) in sorted(fits.items(), key=lambda kv: -kv[1][1]):
        lines.append(f"{name:16s} {calls / count:8.1f} {1e6 * seconds / calls:8.0f} "
                     f"{iterations / calls:6.1f} {100 * seconds / total:5.1f}%")
    lines.append(f"{'samples (n, k)':16s} {'a scene':>8s} {'µs each':>8s} {'none':>6s} "
                 f"{'share':>6s}")
    for (n, k), (samples, none, seconds) in sorted(bursts.items(), key=lambda kv: -kv[1][2]):
        lines.append(f"{f'({n}, {k})':16s} {samples / count:8.1f} "
                     f"{1e6 * seconds / max(samples, 1):8.1f} "
                     f"{100 * none / max(samples, 1):5.0f}% {100 * seconds / total:5.1f}%")
    kernels = sum(v[1] for v in fits.values()) + sum(v[2] for v in bursts.values())
    lines.append(f"fits' and samples' kernels {100 * kernels / total:.0f} % of the search, "
                 f"the rest (the search's Python, the errors' kernels) "
                 f"{100 * (1 - kernels / total):.0f} %")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", type=int, default=24)
    args = parser.parse_args(argv)
    print(report(args.scenes, *measure(args.scenes)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
