"""The robust search at its defaults (issue 18): hard two-view scenes and seed stability.

* (a) two views with 70 % and 80 % outliers (``kanagen.scenes``, 200 inliers, σ = 0.5 px,
  the principal point and ``f0`` set, ``info = 1/σ²``), ``Estimator`` at its defaults (no
  ``scale``, adaptive budgets): the right motion class over the six classes (floor 90 %)
  and the median recall of the true inliers (floor 0.95);
* (b) seed stability: ten seeds on each of a set of conic-lattice scenes (30 % outliers,
  ``info = 1``, σ = 1 px) and two-view scenes (30 % outliers): the share of scenes where
  every seed chooses the same model (floor 98 %).

Run: ``python benchmarks/defaults.py [--part hard|seeds|all] [--trials N] [--seeds K]``;
``--scale L*`` and ``--fixed-budget`` measure the options the defaults replace.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from scenes import LATTICE_MODEL, arc  # noqa: E402

import kanagen  # noqa: E402
from kanagen.scenes import MOTIONS, two_view_scene  # noqa: E402


def options(args) -> dict:
    """The estimator's options: only those given (the rest: the library's defaults)."""
    out = {}
    if args.scale is not None:
        out["scale"] = args.scale
    if args.fixed_budget:
        out["adaptive"] = False
    return out


def two_view(fam, scene, seed, args):
    est = kanagen.Estimator(fam, seed=seed, constants=scene.constants, **options(args))
    ids = est.add_measures("match", scene.data, info=1.0 / scene.sigma**2)
    t0 = time.perf_counter()
    best = est.run(max_samples=args.max_samples)
    return est, best, ids, time.perf_counter() - t0


def conic(fam, xy, seed, args):
    est = kanagen.Estimator(fam, seed=seed, **options(args))
    est.add_measures("point", xy, info=1.0)
    return est.run(max_samples=5000)


def hard(args) -> None:
    fam = kanagen.load("two_view", backend=args.backend)
    print(f"(a) two views at the defaults {options(args) or ''}: {args.trials} scene(s) per "
          f"class and outlier share, max_samples {args.max_samples}")
    print(f"{'motion':<12}{'outliers':>9}{'chosen':>40}{'recall':>8}{'samples':>9}{'s':>7}")
    rights, recalls, seconds = [], [], []
    for share in (0.7, 0.8):
        for j, motion in enumerate(MOTIONS):
            for k in range(args.trials):
                seed = 5000 + 1000 * j + 100 * round(10 * share) + k
                scene = two_view_scene(motion, n=200, outliers=share, sigma=0.5, seed=seed)
                est, best, ids, s = two_view(fam, scene, seed, args)
                model = best.model if best is not None else "-"
                recall = float(np.isin(ids[scene.inliers], best.inliers).mean()) \
                    if best is not None else 0.0
                rights.append(model == motion)
                recalls.append(recall)
                seconds.append(s)
                print(f"{motion:<12}{share:>9.0%}{model:>40}{recall:>8.3f}"
                      f"{est.samples:>9}{s:>7.1f}", flush=True)
    right, recall = float(np.mean(rights)), float(np.median(recalls))
    print(f"{'PASS' if right >= 0.9 else 'FAIL'}  right motion class, 70–80 % outliers: "
          f"{right:.1%} of {len(rights)} (floor 90 %)")
    print(f"{'PASS' if recall >= 0.95 else 'FAIL'}  median recall of the true inliers: "
          f"{recall:.3f} (floor 0.95); min {min(recalls):.3f}; median time "
          f"{np.median(seconds):.2f} s")


def counts(chosen: list[str]) -> dict[str, int]:
    return {m: chosen.count(m) for m in sorted(set(chosen))}


def seeds(args) -> None:
    print(f"(b) seed stability, {args.seeds} seeds per scene {options(args) or ''}")
    agree = []
    fam = kanagen.load("conic_lattice")
    for j, kind in enumerate(LATTICE_MODEL):
        for k in range(args.scenes):
            xy, _ = arc(kind, 7000 + 97 * j + k, n=200, outliers=0.3)
            chosen = [conic(fam, xy, s, args).model for s in range(args.seeds)]
            agree.append(len(set(chosen)) == 1)
            print(f"conic {kind:<10} scene {k}: {counts(chosen)}", flush=True)
    fam = kanagen.load("two_view", backend=args.backend)
    for j, motion in enumerate(MOTIONS):
        for k in range(args.scenes):
            scene = two_view_scene(motion, n=200, outliers=0.3, sigma=0.5,
                                   seed=9000 + 100 * j + k)
            chosen = [two_view(fam, scene, s, args)[1].model for s in range(args.seeds)]
            agree.append(len(set(chosen)) == 1)
            print(f"two-view {motion:<12} scene {k}: {counts(chosen)}", flush=True)
    share = float(np.mean(agree))
    print(f"{'PASS' if share >= 0.98 else 'FAIL'}  all {args.seeds} seeds choose the same "
          f"model on {share:.1%} of {len(agree)} scenes (floor 98 %)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--part", choices=["hard", "seeds", "all"], default="all")
    parser.add_argument("--trials", type=int, default=2,
                        help="(a) scenes per motion class and outlier share")
    parser.add_argument("--scenes", type=int, default=2, help="(b) scenes per kind or class")
    parser.add_argument("--seeds", type=int, default=10, help="(b) seeds per scene")
    parser.add_argument("--max-samples", type=int, default=10_000)
    parser.add_argument("--scale", type=float, default=None, help="L* (default: the "
                        "estimator's, from the information)")
    parser.add_argument("--fixed-budget", action="store_true",
                        help="eq. 25 at an assumed half of inliers (adaptive=False)")
    parser.add_argument("--quantile", type=float, default=None,
                        help="the χ² quantile of the default L* (a measurement knob)")
    parser.add_argument("--backend", default=None, choices=["numpy", "compiled"],
                        help="kanagen's backend (default: kanagen.load's, compiled)")
    args = parser.parse_args()
    if args.quantile is not None:
        from kanagen.runtime import scoring

        scoring.SCALE_QUANTILE = args.quantile
    if args.part in ("hard", "all"):
        hard(args)
    if args.part in ("seeds", "all"):
        seeds(args)


if __name__ == "__main__":
    main()
