"""Calibrated two views (issue 19): which motion, how accurate a pose, how fast — on the
generated scenes of ``kanagen.scenes.calibrated_scene`` (640×480, σ = 0.5 px, 200 inliers,
two cameras of different known intrinsics), ``kanagen.Estimator`` at its defaults
(``constants`` = the intrinsics, ``info = 1/σ²``, nothing else):

* (a) the right motion class over the seven calibrated classes, 30 % outliers (floor 95 %);
* (b) on ``general`` scenes with 30 % and 60 % outliers: the median rotation error and
  translation-direction error (degrees) against the truth, for kanagen (the ``general``
  model of its search — the chosen one, or its state when another model is chosen),
  PoseLib (``estimate_relative_pose``, the cameras as dicts, its default options) and
  OpenCV (``findEssentialMat`` USAC_MAGSAC on the normalised points, then
  ``recoverPose``), the same scenes (floor: kanagen no worse than either); and the
  median time per scene as a ratio to PoseLib's.

The translation error is the angle between the unit directions, signs included (a
direction flipped by cheirality counts 180°).

Run: ``python benchmarks/calibrated.py [--part a|b|all] [--trials N] [--backend B]
[--motions m1,m2]`` (PoseLib and OpenCV: the ``bench`` extra; a missing one is skipped).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

import kanagen  # noqa: E402
from kanagen.runtime import geometry as g  # noqa: E402
from kanagen.scenes import CALIBRATED_MOTIONS, calibrated_scene  # noqa: E402

try:
    import poselib
except ImportError:  # the column is skipped
    poselib = None
try:
    import cv2
except ImportError:
    cv2 = None

THRESHOLD = 1.5  # px, PoseLib's and OpenCV's inlier threshold (3 σ)


def ours(fam, scene, seed):
    """kanagen at its defaults: the estimator, the chosen model, its time."""
    est = kanagen.Estimator(fam, seed=seed, constants=scene.constants)
    est.add_measures("match", scene.data, info=1.0 / scene.sigma**2)
    t0 = time.perf_counter()
    best = est.run()
    return est, best, time.perf_counter() - t0


def ours_pose(est, best):
    """``(R, t)`` of the general model of the search (None if it has none)."""
    state = best if best is not None and best.model == "general" else \
        next((s for s in est.states() if s.model == "general"), None)
    return None if state is None else _pose(state.params)


def _pose(p):
    """``(R, t)`` of the general model's parameters."""
    return (g.rotation_from_quaternion([p["qw"], p["qx"], p["qy"], p["qz"]]),
            np.array([p["tx"], p["ty"], p["tz"]]))


def _camera_dict(K, size):
    return {"model": "PINHOLE", "width": size[0], "height": size[1],
            "params": [K[0, 0], K[1, 1], K[0, 2], K[1, 2]]}


def with_poselib(scene):
    t0 = time.perf_counter()
    pose, _ = poselib.estimate_relative_pose(
        scene.x1, scene.x2, _camera_dict(scene.K1, scene.size),
        _camera_dict(scene.K2, scene.size), {"max_epipolar_error": THRESHOLD}, {})
    return (np.asarray(pose.R), np.asarray(pose.t)), time.perf_counter() - t0


def with_opencv(scene):
    def normalised(x, K):
        return (x - K[:2, 2]) / np.array([K[0, 0], K[1, 1]])

    n1, n2 = normalised(scene.x1, scene.K1), normalised(scene.x2, scene.K2)
    focal = 0.25 * (scene.K1[0, 0] + scene.K1[1, 1] + scene.K2[0, 0] + scene.K2[1, 1])
    t0 = time.perf_counter()
    E, mask = cv2.findEssentialMat(n1, n2, np.eye(3), method=cv2.USAC_MAGSAC, prob=0.999,
                                   threshold=THRESHOLD / focal)
    if E is None:
        return None, time.perf_counter() - t0
    _, R, t, _ = cv2.recoverPose(E[:3], n1, n2, np.eye(3), mask=mask)
    return (R, t.ravel()), time.perf_counter() - t0


def true_inliers_pose(fam, scene):
    """The general model fitted on the scene's true inliers alone, started at the truth:
    what the search would give with a perfect classification of the matches."""
    fit = kanagen.fit(fam, "general", data={"match": scene.data[scene.inliers]},
                      info={"match": 1.0 / scene.sigma**2}, constants=scene.constants,
                      q_start=scene.params())
    return _pose(fit.params)


def errors(pose, scene) -> tuple[float, float]:
    """Rotation error and translation-direction error (degrees) against the truth."""
    if pose is None:
        return 180.0, 180.0
    R, t = pose
    cos = np.clip((np.trace(R.T @ scene.R) - 1) / 2, -1.0, 1.0)
    truth = scene.t / np.linalg.norm(scene.t)
    cos_t = np.clip(t @ truth / np.linalg.norm(t), -1.0, 1.0)
    return float(np.degrees(np.arccos(cos))), float(np.degrees(np.arccos(cos_t)))


def classes(fam, args) -> None:
    motions = args.motions or CALIBRATED_MOTIONS
    print(f"(a) chosen model per calibrated motion class, {args.trials} scenes each "
          f"(200 inliers, {args.outliers:.0%} outliers, σ = {args.sigma} px, defaults)")
    short = {m: m[:10] for m in CALIBRATED_MOTIONS}
    print(f"{'motion':<22}" + "".join(f"{short[m]:>11}" for m in CALIBRATED_MOTIONS)
          + f"{'right':>7}{'s/scene':>9}")
    rights = []
    for j, motion in enumerate(CALIBRATED_MOTIONS):
        if motion not in motions:
            continue
        counts = dict.fromkeys(CALIBRATED_MOTIONS, 0)
        seconds = []
        for k in range(args.trials):
            seed = 1000 * j + k
            scene = calibrated_scene(motion, n=200, outliers=args.outliers, sigma=args.sigma,
                                     seed=seed)
            _, best, s = ours(fam, scene, seed)
            counts[best.model if best is not None else "none"] += 1
            rights.append(best is not None and best.model == motion)
            seconds.append(s)
        print(f"{motion:<22}" + "".join(f"{counts[m]:>11}" for m in CALIBRATED_MOTIONS)
              + f"{counts[motion] / args.trials:>7.0%}{np.median(seconds):>9.1f}", flush=True)
    right = float(np.mean(rights))
    print(f"{'PASS' if right >= 0.95 else 'FAIL'}  right motion class: {right:.1%} of "
          f"{len(rights)} scenes (floor 95 %)\n")


def accuracy(fam, args) -> None:
    methods = ["kanagen"] + (["PoseLib"] if poselib is not None else []) \
        + (["OpenCV"] if cv2 is not None else [])
    oracle = "ML@truth"  # a reference, not a peer: kanagen.fit on the true inliers alone
    print(f"(b) general calibrated motion: median errors against the truth (degrees), "
          f"{args.trials} scenes per outlier share; methods: {', '.join(methods)}")
    print(f"{'outliers':>8}{'method':>10}{'rot med':>10}{'dir med':>10}{'rot mean':>10}"
          f"{'dir mean':>10}{'s/scene':>10}")
    times = {m: [] for m in methods}
    floors = []
    for share in args.shares:
        err = {m: [] for m in methods + [oracle]}
        for k in range(args.trials):
            seed = 50_000 + 1000 * round(10 * share) + k
            scene = calibrated_scene("general", n=200, outliers=share, sigma=args.sigma,
                                     seed=seed)
            est, best, s = ours(fam, scene, seed)
            err["kanagen"].append(errors(ours_pose(est, best), scene))
            err[oracle].append(errors(true_inliers_pose(fam, scene), scene))
            times["kanagen"].append(s)
            if poselib is not None:
                pose, s = with_poselib(scene)
                err["PoseLib"].append(errors(pose, scene))
                times["PoseLib"].append(s)
            if cv2 is not None:
                pose, s = with_opencv(scene)
                err["OpenCV"].append(errors(pose, scene))
                times["OpenCV"].append(s)
        med = {}
        for m in methods + [oracle]:
            e = np.array(err[m])
            med[m] = np.median(e, axis=0)
            seconds = f"{np.median(times[m][-args.trials:]):>10.4f}" if m in times else ""
            print(f"{share:>8.0%}{m:>10}{med[m][0]:>10.4f}{med[m][1]:>10.4f}"
                  f"{np.mean(e[:, 0]):>10.4f}{np.mean(e[:, 1]):>10.4f}{seconds}", flush=True)
        for m in methods[1:]:
            floors.append((share, m, med["kanagen"], med[m]))
    for share, m, mine, theirs in floors:
        ok = mine[0] <= theirs[0] and mine[1] <= theirs[1]
        print(f"{'PASS' if ok else 'FAIL'}  {share:.0%} outliers: kanagen rotation "
              f"{mine[0]:.4f}°, direction {mine[1]:.4f}° vs {m} {theirs[0]:.4f}°, "
              f"{theirs[1]:.4f}° (floor: no worse)")
    if poselib is not None:
        ratio = np.median(times["kanagen"]) / np.median(times["PoseLib"])
        print(f"time per scene (median): kanagen {np.median(times['kanagen']):.3f} s, PoseLib "
              f"{np.median(times['PoseLib']):.4f} s: {ratio:.0f}x PoseLib's")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--part", choices=["a", "b", "all"], default="all")
    parser.add_argument("--trials", type=int, default=10, help="scenes per class / share")
    parser.add_argument("--outliers", type=float, default=0.3, help="(a) outlier share")
    parser.add_argument("--sigma", type=float, default=0.5)
    parser.add_argument("--motions", type=lambda s: s.split(","), default=None,
                        help="(a) the classes to run (default: all seven)")
    parser.add_argument("--shares", type=lambda s: [float(x) for x in s.split(",")],
                        default=[0.3, 0.6], help="(b) outlier shares (default 0.3,0.6)")
    parser.add_argument("--backend", default=None,
                        choices=["numpy", "casadi", "compiled"])
    args = parser.parse_args()
    fam = kanagen.load("two_view_calibrated", backend=args.backend)
    if args.part in ("a", "all"):
        classes(fam, args)
    if args.part in ("b", "all"):
        accuracy(fam, args)


if __name__ == "__main__":
    main()
