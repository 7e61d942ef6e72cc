"""Multi-structure fitting on AdelaideRMF (Wong et al., ICCV 2011): misclassification per scene.

H scenes: several planes, kanagen's ``planar`` model of the ``two_view`` family, one per
plane; F scenes: several rigid motions, its ``general`` model. Each scene is fitted by
:func:`kanagen.find_structures` with the known number of structures (local samples, then
assignment of each match to the structure that explains it best), and in the same run by
sequential OpenCV MAGSAC (``cv2.findHomography`` / ``cv2.findFundamentalMat`` with
``cv2.USAC_MAGSAC``: find, remove the inliers, repeat, as many times as there are
structures) at several thresholds.

The error is :func:`kanagen.evaluation.misclassification`: the share of matches given the
wrong class under the best one-to-one matching of found structures to labelled ones
(Hungarian method), gross outliers being a class of their own on both sides.

Published reference (not rerun here): Progressive-X (Barath & Matas, ICCV 2019) reports a
mean misclassification of 6.6 % on the AdelaideRMF homography scenes.

Figures (both seeds, per-scene tables, where we lose): ``docs/real_data.md``.

``--defaults`` gives only the number of structures and the model (the library's defaults for
the rest, issue 18's floors); ``--defaults --unknown`` gives only the model.

Run ``python experiments/adelaide.py [--kind H|F|both] [--scenes a,b] [--json out.json]``
(needs ``pip install "kanagen[examples]"`` for OpenCV and the shared data folder).
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np

import kanagen
from kanagen import datasets
from kanagen.evaluation import labels_from_structures, misclassification

#: The model of one structure, per kind of scene.
MODEL = {"H": "planar", "F": "general"}
#: OpenCV MAGSAC thresholds tried (pixels; for MAGSAC the largest noise σ considered).
MAGSAC_THRESHOLDS = (1.0, 1.5, 2.0, 3.0, 4.0, 5.0, 8.0)
#: Progressive-X's published mean misclassification on the AdelaideRMF H scenes (%).
PROGRESSIVE_X_H = 6.6
#: kanagen's settings: L* (squared px over the equations of a match, info = 1 / px²), the
#: random samples per structure, the share of local samples, the assignment rounds, and the
#: ceiling of a structure's outlier threshold in units of L* (neighbouring planes of one
#: facade leave no minimum in the error histogram between them).
SCALE = 4.0
SAMPLES = 1000
LOCAL = 0.5
REASSIGN = 5
CEILING = 2.0
RETRIES = 2  # a search that finds nothing is repeated this many times (known structures)
RESTARTS = 3  # extractions per scene, the one of least truncated error kept


@dataclass(frozen=True)
class SceneResult:
    kind: str
    scene: str
    matches: int
    structures: int
    outliers: float  # share of gross outliers
    kanagen: float  # misclassification
    kanagen_found: int
    kanagen_seconds: float
    magsac: dict[str, float]  # threshold -> misclassification
    magsac_seconds: float


def kanagen_labels(fam, scene: datasets.MultiStructureScene, samples: int = SAMPLES,
                   scale: float = SCALE, local: float = LOCAL, reassign: int = REASSIGN,
                   ceiling: float = CEILING, retries: int = RETRIES,
                   restarts: int = RESTARTS, seed: int = 0,
                   defaults: bool = False, unknown: bool = False) -> tuple[np.ndarray, int]:
    """Per-match classes from :func:`kanagen.find_structures` (0 = outlier), and the number
    of structures found. ``defaults``: only the number of structures and the model given
    (issue 18's floor), the other options at the library's defaults; ``unknown`` (with
    ``defaults``): the number not given either (``max_structures`` at its default)."""
    constants = datasets.nominal_constants(scene)
    if defaults:
        count = {} if unknown else {"max_structures": scene.structures}
        found = kanagen.find_structures(
            fam, data={"match": scene.matches}, info={"match": 1.0}, **count,
            model=MODEL[scene.kind], seed=seed, constants=constants)
        return labels_from_structures(len(scene.matches), [s.inliers for s in found]), \
            len(found)
    found = kanagen.find_structures(
        fam, data={"match": scene.matches}, info={"match": 1.0},
        max_structures=scene.structures, model=MODEL[scene.kind], scale=scale,
        samples_per_model=samples, max_samples=samples * 10, local=local, reassign=reassign,
        max_threshold=ceiling * scale, retries=retries, restarts=restarts, seed=seed,
        constants=constants)
    return labels_from_structures(len(scene.matches), [s.inliers for s in found]), len(found)


def magsac_labels(scene: datasets.MultiStructureScene, threshold: float) -> np.ndarray:
    """Sequential OpenCV MAGSAC: find one model, remove its inliers, repeat (known number
    of structures); per-match classes, 0 = outlier."""
    import cv2

    labels = np.zeros(len(scene.matches), dtype=int)
    rest = np.arange(len(scene.matches))
    needed = 4 if scene.kind == "H" else 8
    for k in range(1, scene.structures + 1):
        if rest.size < needed:
            break
        a = np.ascontiguousarray(scene.matches[rest, :2])
        b = np.ascontiguousarray(scene.matches[rest, 2:])
        if scene.kind == "H":
            model, mask = cv2.findHomography(a, b, cv2.USAC_MAGSAC, threshold,
                                             maxIters=10000, confidence=0.999)
        else:
            model, mask = cv2.findFundamentalMat(a, b, cv2.USAC_MAGSAC, threshold, 0.999,
                                                 10000)
        if model is None or mask is None:
            break
        inlier = mask.ravel() > 0
        labels[rest[inlier]] = k
        rest = rest[~inlier]
    return labels


def run_scene(fam, scene: datasets.MultiStructureScene, **options) -> SceneResult:
    t0 = time.perf_counter()
    ours, found = kanagen_labels(fam, scene, **options)
    t1 = time.perf_counter()
    magsac = {f"{t:g}": misclassification(scene.labels, magsac_labels(scene, t))
              for t in MAGSAC_THRESHOLDS}
    t2 = time.perf_counter()
    return SceneResult(scene.kind, scene.name, len(scene.matches), scene.structures,
                       float(np.mean(scene.labels == 0)),
                       misclassification(scene.labels, ours), found, t1 - t0, magsac,
                       (t2 - t1) / len(MAGSAC_THRESHOLDS))


def report(results: list[SceneResult]) -> tuple[str, dict[str, dict[str, float]]]:
    """The per-scene table and the means (%) per kind; the floor compares kanagen's mean with
    sequential MAGSAC's best mean over the thresholds tried, in the same run."""
    lines, means = [], {}
    head = (f"{'scene':<18}{'N':>5}{'K':>3}{'out%':>6}{'kanagen%':>10}{'found':>6}{'s':>7}"
            + "".join(f"{'M@' + t:>8}" for t in map("{:g}".format, MAGSAC_THRESHOLDS))
            + f"{'M s':>7}")
    for kind in ("H", "F"):
        rows = [r for r in results if r.kind == kind]
        if not rows:
            continue
        lines += [f"AdelaideRMF {kind} ({MODEL[kind]} model), misclassification %", head]
        for r in rows:
            lines.append(f"{r.scene:<18}{r.matches:>5}{r.structures:>3}{100 * r.outliers:>6.1f}"
                         f"{100 * r.kanagen:>10.1f}{r.kanagen_found:>6}{r.kanagen_seconds:>7.1f}"
                         + "".join(f"{100 * v:>8.1f}" for v in r.magsac.values())
                         + f"{r.magsac_seconds:>7.2f}")
        mean = {"kanagen": 100 * float(np.mean([r.kanagen for r in rows]))}
        for t in rows[0].magsac:
            mean[f"magsac@{t}"] = 100 * float(np.mean([r.magsac[t] for r in rows]))
        best_t = min((k for k in mean if k.startswith("magsac")), key=mean.get)
        mean["magsac_best"] = mean[best_t]
        means[kind] = mean
        lines.append(f"{'mean':<32}{mean['kanagen']:>10.1f}{'':>13}"
                     + "".join(f"{mean['magsac@' + t]:>8.1f}" for t in rows[0].magsac))
        median = [100 * float(np.median([r.kanagen for r in rows]))] + [
            100 * float(np.median([r.magsac[t] for r in rows])) for t in rows[0].magsac]
        mean["kanagen_median"] = median[0]
        lines.append(f"{'median':<32}{median[0]:>10.1f}{'':>13}"
                     + "".join(f"{v:>8.1f}" for v in median[1:]))
        verdict = "met" if mean["kanagen"] < mean["magsac_best"] else "NOT met"
        lines.append(f"floor: kanagen {mean['kanagen']:.1f} % < sequential MAGSAC "
                     f"{mean['magsac_best']:.1f} % (best threshold, {best_t}): {verdict}")
        if kind == "H":
            lines.append(f"published Progressive-X mean on the H scenes: {PROGRESSIVE_X_H} %")
        lines.append("")
    return "\n".join(lines), means


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kind", choices=("H", "F", "both"), default="both")
    parser.add_argument("--scenes", default="", help="comma-separated names (default all)")
    parser.add_argument("--samples", type=int, default=SAMPLES, help="samples per structure")
    parser.add_argument("--scale", type=float, default=SCALE, help="L*")
    parser.add_argument("--local", type=float, default=LOCAL, help="share of local samples")
    parser.add_argument("--reassign", type=int, default=REASSIGN, help="assignment rounds")
    parser.add_argument("--ceiling", type=float, default=CEILING,
                        help="ceiling of the outlier threshold, in units of L*")
    parser.add_argument("--retries", type=int, default=RETRIES,
                        help="repeats of a search that finds nothing")
    parser.add_argument("--restarts", type=int, default=RESTARTS,
                        help="extractions per scene (the least truncated error kept)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--defaults", action="store_true",
                        help="only the number of structures and the model given (the "
                             "library's defaults for the rest; the options above ignored)")
    parser.add_argument("--unknown", action="store_true",
                        help="with --defaults: the number of structures not given either")
    parser.add_argument("--json", help="write the per-scene results here")
    args = parser.parse_args(argv)
    fam = kanagen.load("two_view")
    wanted = set(filter(None, args.scenes.split(",")))
    results = []
    for kind in (("H", "F") if args.kind == "both" else (args.kind,)):
        names = datasets.ADELAIDE_H if kind == "H" else datasets.ADELAIDE_F
        for name in names:
            if wanted and name not in wanted:
                continue
            scene = datasets.adelaide_scene(kind, name)
            r = run_scene(fam, scene, samples=args.samples, scale=args.scale,
                          local=args.local, reassign=args.reassign, ceiling=args.ceiling,
                          retries=args.retries, restarts=args.restarts, seed=args.seed,
                          defaults=args.defaults, unknown=args.unknown)
            results.append(r)
            print(f"{kind} {name}: kanagen {100 * r.kanagen:.1f} % ({r.kanagen_seconds:.1f} s), "
                  f"MAGSAC " + ", ".join(f"{t}: {100 * v:.1f} %" for t, v in r.magsac.items()),
                  flush=True)
    text, means = report(results)
    print()
    print(text)
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump({"scenes": [asdict(r) for r in results], "means": means}, fh, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
