"""The kernels of the shipped families compiled ahead of their first use.

A fit's kernels are compiled by numba on a machine's first use and cached
(:mod:`kanagen.common.jit`): about 40 s for the engine, 1–3 s for each family's own. Building
kanagen's wheel (``pip install .``) runs :func:`precompile` once, in a fresh cache, and ships
that cache inside the package (``kanagen/kernels/<digest>``, with a manifest of what it was
compiled for: :func:`kanagen.common.jit.kernel_target`); a process whose own cache is empty
seeds it from there when the manifest names that process (:func:`kanagen.common.jit.seed`).
Where it does not (another numba, another machine) the kernels are compiled at first use as
before, with the same answers.

``python -m kanagen.precompile [INTO]``: compile into the user's cache (or, with ``INTO``,
into a fresh cache copied to ``INTO/<digest>``: the wheel's build step).

What runs is what the shipped families' users run at the defaults, on small synthetic data:
a fit of every model and a robust lattice search of every family (the two-view families on
generated scenes with outliers).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

#: the shipped families (``kanagen.load(name)``), in the order they are compiled
SHIPPED = ("conic_lattice", "conic", "line", "hysteresis", "pga", "two_view",
           "two_view_calibrated")


def _points(rng) -> dict:
    """60 points, 42 on half an ellipse (σ 0.5 px), 18 outliers."""
    t = rng.uniform(0.0, np.pi, 42)
    on = np.c_[320 + 120 * np.cos(t), 240 + 70 * np.sin(t)] + rng.normal(0, 0.5, (42, 2))
    return {"point": np.vstack([on, rng.uniform(150, 450, (18, 2))])}


def _workload(name: str, rng) -> tuple[dict, dict]:
    """(data, constants) of a small synthetic dataset of the shipped family ``name``."""
    if name in ("conic_lattice", "conic", "line"):
        return _points(rng), {}
    if name == "hysteresis":
        return {"reading": np.array([[-1.0 + 0.01], [-1.0 - 0.02], [-0.99]])}, \
            {"t": 0.0, "s_prev": 1.0}
    if name == "pga":
        v = rng.uniform(-1.0, 1.0, 25)
        return {"reading": np.c_[v, 4.0 * v + 0.3 + rng.normal(0.0, 0.01, v.size)]}, {}
    from .scenes import calibrated_scene, two_view_scene

    make = two_view_scene if name == "two_view" else calibrated_scene
    scene = make("general", n=60, outliers=0.3, seed=0)
    return {"match": scene.data}, dict(scene.constants)


def _run_family(name: str) -> None:
    """A fit of every model of ``name``, then its robust lattice search (each on the first
    channel of its data)."""
    from . import Estimator, fit, load

    rng = np.random.default_rng(0)
    fam = load(name)
    data, constants = _workload(name, rng)
    for model in fam.models:
        fit(fam, model, data=data, constants=constants)
    channel, measures = next(iter(data.items()))
    est = Estimator(fam, channel=channel, constants=constants, seed=0)
    est.add_measures(channel, measures)
    est.run(max_samples=300)


def precompile(families=SHIPPED, *, echo=None) -> dict[str, str]:
    """Run every shipped family's work once in this process (its kernels compiled into the
    cache, or loaded from it); ``{family: "ok" or the error}`` — a family that fails is
    reported, not raised (the kernels compiled so far stay cached)."""
    outcome = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # synthetic data: assumed constants, poor fits
        for name in families:
            start = time.perf_counter()
            try:
                _run_family(name)
                outcome[name] = "ok"
            except Exception as exc:  # noqa: BLE001 - reported, the others still run
                outcome[name] = f"{type(exc).__name__}: {exc}"
            if echo is not None:
                echo(f"{name}: {outcome[name]} ({time.perf_counter() - start:.1f} s)")
    return outcome


def _into(target: Path) -> int:
    """Compile in a fresh cache (a child process: the cache folder is fixed at import, and
    numba's settings from the environment are left out: its cache does not key them), and
    copy that cache with its manifest (:func:`~kanagen.common.jit.kernel_target`) to
    ``target/<digest>``, replacing what ``target`` held; 0, or 1 when nothing could be
    compiled (``target`` then holds nothing)."""
    import subprocess

    shutil.rmtree(target, ignore_errors=True)  # first: no kernels to seed from at import
    from .common.jit import SHIPPED_MANIFEST, _cache_dir

    with tempfile.TemporaryDirectory(prefix="kanagen-kernels-") as cache:
        kernels = Path(cache) / "kanagen" / "numba"
        _reuse(Path(_cache_dir()), kernels)
        env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
        env.update(XDG_CACHE_HOME=cache, KANAGEN_CACHE=str(Path(cache) / "specs"))
        try:
            done = subprocess.run([sys.executable, "-m", "kanagen.precompile", "--manifest"],
                                  env=env, check=False, timeout=3600).returncode
        except subprocess.TimeoutExpired:
            done = "timed out"
        folders = [f for f in kernels.iterdir() if (f / SHIPPED_MANIFEST).is_file()] \
            if kernels.is_dir() else []
        if done != 0 or len(folders) != 1:
            print(f"kanagen.precompile: no kernels to ship (exit {done})", file=sys.stderr)
            return 1
        partial = target / f".{folders[0].name}.partial"  # inside target, then renamed:
        try:  # the digest's folder is all or none, and removing target removes any leftover
            shutil.copytree(folders[0], partial, ignore=_TRANSIENT)
            partial.rename(target / folders[0].name)
        except OSError as exc:
            shutil.rmtree(target, ignore_errors=True)
            print(f"kanagen.precompile: the kernels could not be copied ({exc})",
                  file=sys.stderr)
            return 1
    return 0


#: A cache's files that are not kernels: numba's locks and the temporary files it renames.
_TRANSIENT = shutil.ignore_patterns("*.lock", "*.tmp*")


def _reuse(mine: Path, into: Path) -> None:
    """Start the fresh cache ``into`` from the user's cache of the same sources, ``mine``
    (``kanagen/numba/<digest>``: an earlier build's kernels, seeded at that install's first
    use, or compiled there): building the wheel again (``pip install ".[test]"`` after
    ``pip install .``) then loads them instead of compiling them again (~4 minutes on two
    cores). The workload still runs, and numba checks every entry against its source's
    content and this machine (a stale or foreign entry is compiled again), so the kernels
    shipped are those a fresh cache would hold, and perhaps more signatures of them. Only
    the package's own folders (``kanagen_engine``, ``kanagen_runtime``,
    ``kanagen_generated``: common/jit.py's locator) are taken, not the kernels of the
    user's families. Never raises."""
    try:
        for folder in sorted(mine.glob("kanagen_*")) if mine.is_dir() else []:
            shutil.copytree(folder, into / mine.name / folder.name, ignore=_TRANSIENT)
    except OSError:  # unreadable, being written: compile as from nothing
        shutil.rmtree(into, ignore_errors=True)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m kanagen.precompile",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("into", nargs="?", type=Path,
                        help="compile in a fresh cache and copy it to INTO/<digest>")
    parser.add_argument("--manifest", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.into is not None:
        return _into(args.into)
    from .common.jit import NUMBA, SHIPPED_MANIFEST, kernel_target

    if NUMBA is None or NUMBA.config.DISABLE_JIT:
        print("kanagen.precompile: numba is not in use; nothing to compile", file=sys.stderr)
        return 1
    start = time.perf_counter()
    outcome = precompile(echo=lambda line: print(line, file=sys.stderr, flush=True))
    if args.manifest:  # what the kernels were compiled for (common/jit.py: seed reads it)
        Path(NUMBA.config.CACHE_DIR, SHIPPED_MANIFEST).write_text(
            json.dumps(kernel_target(), indent=1) + "\n")
    print(f"done in {time.perf_counter() - start:.0f} s (the kernels compiled, or loaded "
          f"where cached already); cached in {NUMBA.config.CACHE_DIR}", file=sys.stderr)
    return 0 if any(v == "ok" for v in outcome.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
