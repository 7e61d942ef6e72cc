"""First use on a fresh machine: what each shipped family's first fit costs (issue 17: a
first-use compile of at most 10 s per shipped family).

Every cache empty (a temporary ``XDG_CACHE_HOME``: numba's kernels and kanagen's compiled
family libraries), each shipped family is loaded and fitted once in a fresh process, in
order: the first pays the engine's compile (shared by every family, once per machine and
kanagen version), each pays its own C library and row kernels; then every family again in
a fresh process with the caches warm (what each later process pays: imports and loading
the cached code). The fits are the first case of each spec's scenarios
(``tests/scenarios.py``).

The children import the kanagen of the running interpreter, from a folder of their own (not
a source checkout's): an installed kanagen (``pip install .``) ships its kernels, compiled
when its wheel was built (kanagen/precompile.py), and its first use loads them; a source
checkout or an editable install compiles them at first use (the engine's ~40 s). The first
line says which was measured.

Run: ``python benchmarks/first_use.py`` (~30 s installed, ~2–3 minutes from a checkout).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FLOOR = 10.0  # seconds of first-use compile per shipped family, at most (issue 17)

CHILD = """
import json, sys, time
t0 = time.perf_counter()
sys.path.insert(0, {tests!r})
import numpy as np
import kanagen
from scenarios import SCENARIOS
fam = kanagen.load({spec!r})
model, data, info, q0, constants = SCENARIOS[{name!r}]()[0][:5]
res = kanagen.fit(fam, model, data=data, info=info, q0=q0, constants=constants)
print(json.dumps([time.perf_counter() - t0, res.status]))
"""


def run(spec: Path, cache: str, cwd: str) -> tuple[float, int]:
    """The first fit of ``spec``'s family in a fresh process whose caches are under
    ``cache``, started in the empty folder ``cwd`` (not ``cache``: the ``kanagen`` folder a
    first use writes there would shadow an editable install's package)."""
    env = dict(os.environ, XDG_CACHE_HOME=cache)
    env.pop("NUMBA_CACHE_DIR", None)
    env.pop("KANAGEN_CACHE", None)
    code = CHILD.format(tests=str(ROOT / "tests"), spec=str(spec), name=spec.name)
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, timeout=1800, cwd=cwd)
    if out.returncode:
        raise SystemExit(f"first use of {spec.name} failed:\n{out.stderr[-3000:]}")
    seconds, status = json.loads(out.stdout.strip().splitlines()[-1])
    return seconds, status


def shipped_kernels() -> str:
    """Which kanagen the children import, and whether it ships its kernels."""
    code = ("import kanagen, kanagen.common.jit as j; "
            "print(kanagen.__file__, (j.SHIPPED_KERNELS / j._sources_digest()).is_dir())")
    with tempfile.TemporaryDirectory() as folder:
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                             check=True, cwd=folder)
    where, shipped = out.stdout.split()
    return (f"kanagen from {Path(where).parent}: "
            + ("its kernels shipped (compiled when its wheel was built)" if shipped == "True"
               else "no kernels shipped (a source checkout or an editable install): the "
                    "first use compiles them"))


def main() -> None:
    specs = sorted((ROOT / "examples").glob("*.yaml"))
    print(shipped_kernels())
    with tempfile.TemporaryDirectory() as cache, tempfile.TemporaryDirectory() as cwd:
        cold = [run(spec, cache, cwd) for spec in specs]
        warm = [run(spec, cache, cwd) for spec in specs]
    print(f"{'family':28s} {'first use (s)':>14s} {'later process (s)':>18s}")
    for spec, (c, status), (w, _) in zip(specs, cold, warm, strict=True):
        print(f"{spec.stem:28s} {c:14.1f} {w:18.1f}" + ("" if status == 0 else
                                                          f"   (status {status})"))
    own = [c - w for (c, _), (w, _) in zip(cold, warm, strict=True)]
    engine = own[0] - max(own[1:], default=0.0)  # the first pays the engine besides its own
    total = sum(own)
    print(f"\nthe engine (shared, once per machine and kanagen version): ~{max(engine, 0):.0f} s "
          f"(the first family's first use less the largest other family's)")
    print(f"each family's own (its C library, row kernels): {min(own[1:]):.1f}–"
          f"{max(own[1:]):.1f} s")
    print(f"all {len(specs)} shipped families: {total:.0f} s, {total / len(specs):.1f} s a "
          f"family on average")
    verdict = "holds" if max(own) <= FLOOR else "not met"
    worst = max(range(len(own)), key=own.__getitem__)
    whose = specs[worst].stem + ("'s, the first family: with the engine" if worst == 0 else "'s")
    print(f"floor (first-use compile <= {FLOOR:.0f} s per shipped family, each): {verdict} "
          f"(the largest: {own[worst]:.1f} s, {whose})")


if __name__ == "__main__":
    main()
