"""``kanagen build`` of every shipped example: wall time of the command, a fresh process each.

Issue 5's floor: under 10 s per example. Each example is built with both backends (NumPy and
CasADi modules) into a temporary folder, then again with ``--compile`` (CasADi's C code
generator, the family's tables and the compiled estimator, through the system C compiler)
into an empty cache. The times include starting Python and importing kanagen (SymPy, SciPy,
CasADi).

Run ``python benchmarks/build_time.py``.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FLOOR = 10.0


def timed(args: list[str], env: dict) -> tuple[float, int]:
    t0 = time.perf_counter()
    done = subprocess.run(args, env=env, capture_output=True, text=True)
    if done.returncode:
        print(done.stderr, file=sys.stderr)
    return time.perf_counter() - t0, done.returncode


def main() -> int:
    specs = sorted((ROOT / "examples").glob("*.yaml"))
    kanagen = [sys.executable, "-m", "kanagen"]
    print(f"{'example':<22} {'build s':>8} {'--compile s':>12}")
    worst = 0.0
    with tempfile.TemporaryDirectory() as tmp:
        for spec in specs:
            env = dict(os.environ, KANAGEN_CACHE=str(Path(tmp) / f"cache-{spec.stem}"))
            out = str(Path(tmp) / "gen")
            plain, rc1 = timed([*kanagen, "build", str(spec), "-o", out, "--backend", "numpy",
                                "--backend", "casadi"], env)
            compiled, rc2 = timed([*kanagen, "build", str(spec), "-o", out, "--backend",
                                   "casadi", "--compile"], env)
            worst = max(worst, plain, compiled)
            flag = "" if rc1 == rc2 == 0 else "  (failed)"
            print(f"{spec.name:<22} {plain:>8.2f} {compiled:>12.2f}{flag}")
    ok = worst < FLOOR
    print(f"{'PASS' if ok else 'FAIL'}  kanagen build of every shipped example < {FLOOR:g} s "
          f"[slowest {worst:.2f} s]")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
