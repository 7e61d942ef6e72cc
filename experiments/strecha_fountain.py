"""The Strecha fountain pair with known intrinsics (issue 19): the calibrated two-view lattice at
its defaults beside OpenCV, pycolmap and PoseLib on the same tentative matches.

Data: ``../shared/data/magsac_cmp/essential_matrix`` (MAGSAC's comparison set, see its
PROVENANCE.txt; :func:`kanagen.datasets.strecha_fountain`): the two cameras' K
(``fountain1.K``, ``fountain2.K``) and 270 tentative matches ``x1 y1 x2 y2`` in pixels, no
labels and no ground-truth pose. So the methods are
compared with one another: each one's rotation (axis, angle) and translation direction, the
mutual rotation and direction differences (degrees), and each one's error on its own inliers
— the RMS Sampson distance (px) of its essential matrix, mapped to a fundamental matrix by the
two K, over the matches it calls inliers, and over the matches every method calls inliers.

* kanagen: ``kanagen.load("two_view_calibrated")``, ``Estimator`` at its defaults with the
  constants of the two K (``kanagen.scenes.calibrated_constants``) and ``info = 1/σ²`` with
  σ = 1 px (the reduced χ² printed says how right that σ is), ten seeds: the motion named by
  each, the pose of seed 0 with its standard deviations;
* OpenCV ``findEssentialMat`` (USAC_MAGSAC) on normalised coordinates, then ``recoverPose``;
* pycolmap ``estimate_calibrated_two_view_geometry`` then ``estimate_two_view_geometry_pose``;
* PoseLib ``estimate_relative_pose``.
The peers' inlier threshold is 1.5 px (``benchmarks/calibrated.py``'s). Peers that are not
installed are skipped (the ``bench`` extra has them).

Run: ``python experiments/strecha_fountain.py [--data ROOT] [--seeds K]``.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import calibrated as peers  # noqa: E402

import kanagen  # noqa: E402
from kanagen import datasets  # noqa: E402
from kanagen.runtime import geometry as g  # noqa: E402
from kanagen.scenes import calibrated_constants  # noqa: E402

SIGMA = 1.0  # px, the information given to kanagen (1/σ²)


class Pair:
    """The pair as ``benchmarks/calibrated.py``'s peers read a scene."""

    def __init__(self, root: Path | None):
        pair = datasets.strecha_fountain(root)
        self.K1, self.K2, self.data = pair.K1, pair.K2, pair.matches
        self.x1, self.x2 = pair.matches[:, :2].copy(), pair.matches[:, 2:4].copy()
        self.size = pair.image_size
        self.sigma = SIGMA
        self.constants = calibrated_constants(self.K1, self.K2)


def ours(fam, pair: Pair, seed: int):
    est = kanagen.Estimator(fam, seed=seed, constants=pair.constants)
    est.add_measures("match", pair.data, info=1.0 / SIGMA**2)
    t0 = time.perf_counter()
    best = est.run()
    return est, best, time.perf_counter() - t0


def with_pycolmap(pair: Pair):
    import pycolmap

    def camera(K):
        return pycolmap.Camera(model="PINHOLE", width=pair.size[0], height=pair.size[1],
                               params=[K[0, 0], K[1, 1], K[0, 2], K[1, 2]])

    c1, c2 = camera(pair.K1), camera(pair.K2)
    opts = pycolmap.TwoViewGeometryOptions()
    opts.ransac.max_error = peers.THRESHOLD
    opts.ransac.random_seed = 0
    matches = np.c_[np.arange(len(pair.x1)), np.arange(len(pair.x1))].astype(np.uint32)
    t0 = time.perf_counter()
    geometry = pycolmap.estimate_calibrated_two_view_geometry(c1, pair.x1, c2, pair.x2,
                                                              matches, opts)
    ok = pycolmap.estimate_two_view_geometry_pose(c1, pair.x1, c2, pair.x2, geometry)
    seconds = time.perf_counter() - t0
    if not ok:
        return None, seconds
    pose = geometry.cam2_from_cam1
    return (np.asarray(pose.rotation.matrix()), np.asarray(pose.translation)), seconds


def sampson(pose, pair: Pair) -> np.ndarray:
    """Each match's Sampson distance (px) to the pose's epipolar geometry."""
    R, t = pose
    E = g.skew(t / np.linalg.norm(t)) @ R
    F = np.linalg.inv(pair.K2).T @ E @ np.linalg.inv(pair.K1)
    y1 = np.c_[pair.x1, np.ones(len(pair.x1))]
    y2 = np.c_[pair.x2, np.ones(len(pair.x2))]
    Fx1, Ftx2 = y1 @ F.T, y2 @ F
    num = np.einsum("ij,ij->i", y2, Fx1)
    den = Fx1[:, 0]**2 + Fx1[:, 1]**2 + Ftx2[:, 0]**2 + Ftx2[:, 1]**2
    return np.abs(num) / np.sqrt(den)


def describe(R, t) -> tuple[float, np.ndarray, np.ndarray]:
    angle = float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))))
    axis = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    axis /= np.linalg.norm(axis)
    return angle, axis, t / np.linalg.norm(t)


def differences(a, b) -> tuple[float, float]:
    Ra, ta = a
    Rb, tb = b
    rot = np.degrees(np.arccos(np.clip((np.trace(Ra.T @ Rb) - 1) / 2, -1, 1)))
    cos = ta @ tb / np.linalg.norm(ta) / np.linalg.norm(tb)
    return float(rot), float(np.degrees(np.arccos(np.clip(cos, -1, 1))))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=None,
                        help="the data root (default: $KANAGEN_DATA or ../shared/data)")
    parser.add_argument("--seeds", type=int, default=10)
    args = parser.parse_args()
    if not datasets.available("magsac_cmp", args.data):
        raise SystemExit(f"no shared data at {datasets.data_root(args.data)}")
    pair = Pair(args.data)
    fam = kanagen.load("two_view_calibrated")
    print(f"Strecha fountain: {len(pair.data)} tentative matches, images {pair.size[0]}x"
          f"{pair.size[1]}, f = {pair.K1[0, 0]:.1f} / {pair.K2[0, 0]:.1f} px; kanagen at its "
          f"defaults (info = 1/σ², σ = {SIGMA} px), peers' threshold {peers.THRESHOLD} px")
    chosen = []
    first = None
    for seed in range(args.seeds):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            est, best, seconds = ours(fam, pair, seed)
        chosen.append(best.model)
        if seed == 0:
            first = (est, best, seconds)
    est, best, seconds = first
    counts = {m: chosen.count(m) for m in sorted(set(chosen))}
    print(f"\nkanagen: motion named over {args.seeds} seeds: {counts}")
    print(f"seed 0: '{best.model}', {best.inliers.size} inliers, reduced chi2 "
          f"{best.reduced_chi2:.3f}, {seconds:.2f} s")
    for name in ("rotation_angle", "rotation_axis", "translation_direction"):
        if name in best.derived:
            d = best.derived[name]
            print(f"  {name:<22} {np.array2string(np.asarray(d.value), precision=5)} ± "
                  f"{np.array2string(np.asarray(d.std), formatter={'float': '{:.2g}'.format})}"
                  f" {best.units.get(name, '')}")
    poses = {"kanagen": peers.ours_pose(est, best)}
    times = {"kanagen": seconds}
    inliers = {"kanagen": np.isin(np.arange(len(pair.data)), best.inliers)}
    runs = [("OpenCV", peers.with_opencv if peers.cv2 is not None else None),
            ("pycolmap", with_pycolmap), ("PoseLib",
                                          peers.with_poselib if peers.poselib else None)]
    for name, run in runs:
        if run is None:
            continue
        try:
            pose, secs = run(pair)
        except ImportError:
            continue
        if pose is not None:
            poses[name], times[name] = pose, secs
            inliers[name] = sampson(pose, pair) < peers.THRESHOLD
    common = np.logical_and.reduce(list(inliers.values()))
    print(f"\n{'method':<9} {'angle deg':>10} {'axis':>28} {'direction':>28} {'inliers':>8} "
          f"{'RMS own px':>11} {'RMS common':>11} {'time s':>8}")
    for name, pose in poses.items():
        angle, axis, direction = describe(*pose)
        d = sampson(pose, pair)
        own = inliers[name]
        print(f"{name:<9} {angle:>10.4f} {np.array2string(axis, precision=4):>28} "
              f"{np.array2string(direction, precision=4):>28} {int(own.sum()):>8} "
              f"{np.sqrt(np.mean(d[own]**2)):>11.4f} {np.sqrt(np.mean(d[common]**2)):>11.4f} "
              f"{times[name]:>8.4f}")
    print(f"(common inliers: {int(common.sum())}; kanagen's inliers are its own threshold's, "
          f"the peers' those under {peers.THRESHOLD} px at their pose)")
    names = list(poses)
    print("\nmutual differences, rotation / direction (deg)")
    print(" " * 9 + "".join(f"{n:>18}" for n in names))
    for a in names:
        cells = []
        for b in names:
            r, d = differences(poses[a], poses[b])
            cells.append(f"{r:>8.4f} / {d:<7.4f}")
        print(f"{a:<9}" + "".join(f"{c:>18}" for c in cells))


if __name__ == "__main__":
    main()
