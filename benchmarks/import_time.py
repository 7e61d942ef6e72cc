"""What ``import kanagen`` costs, against ``import scipy.optimize`` (and ``import numpy``).

Issue 17's floor: ``import kanagen`` at most 3 times ``import scipy.optimize``. Each import
runs in a fresh interpreter, the modules interleaved (kanagen, scipy.optimize, numpy, kanagen,
...) so that a busy machine slows them alike; each figure is the median of ``--runs`` (5)
processes. Three measures, each in its own processes:

* ``importtime``: the cumulative microseconds of the last line of ``python -X importtime -c
  "import X"`` (the module's own import with everything it imports; for ``scipy.optimize``
  without the ``scipy`` package itself, which makes the floor slightly stricter);
* ``in-process``: ``time.perf_counter()`` around ``import X`` in a fresh interpreter;
* ``wall``: the wall time of ``python -c "import X"`` (the interpreter's start included).

The ratio and the floor are on ``importtime``. Run ``python benchmarks/import_time.py``; the
exit status is 1 when the floor does not hold.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FLOOR = 3.0
MODULES = ("kanagen", "scipy.optimize", "numpy")
MEASURES = ("importtime", "in-process", "wall")


def importtime(module: str) -> float:
    """Seconds: the last line of ``-X importtime`` (cumulative microseconds)."""
    done = subprocess.run([sys.executable, "-X", "importtime", "-c", f"import {module}"],
                          capture_output=True, text=True, check=True, cwd=ROOT)
    last = done.stderr.strip().splitlines()[-1]
    _, cumulative, name = (part.strip() for part in last.split("|"))
    assert name == module, last
    return int(cumulative) * 1e-6


def in_process(module: str) -> float:
    """Seconds: ``perf_counter`` around the import, in a fresh interpreter."""
    code = f"import time; t = time.perf_counter(); import {module}; " \
           "print(time.perf_counter() - t)"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=True, cwd=ROOT)
    return float(done.stdout)


def wall(module: str) -> float:
    """Seconds: the wall time of ``python -c "import X"``."""
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", f"import {module}"], check=True, cwd=ROOT)
    return time.perf_counter() - t0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=5, help="processes per module and measure")
    args = parser.parse_args(argv)
    measure = {"importtime": importtime, "in-process": in_process, "wall": wall}
    times = {(m, k): [] for m in MODULES for k in MEASURES}
    for _ in range(args.runs):
        for kind in MEASURES:
            for module in MODULES:  # interleaved: a load spike hits every module alike
                times[module, kind].append(measure[kind](module))
    median = {key: statistics.median(values) for key, values in times.items()}
    print(f"median of {args.runs} fresh processes each, seconds ({sys.version.split()[0]})")
    print(f"{'import':<16}" + "".join(f"{k:>12}" for k in MEASURES))
    for module in MODULES:
        print(f"{module:<16}" + "".join(f"{median[module, k]:>12.3f}" for k in MEASURES))
    for kind in MEASURES:
        print(f"kanagen / scipy.optimize ({kind}): "
              f"{median['kanagen', kind] / median['scipy.optimize', kind]:.2f}")
    ratio = median["kanagen", "importtime"] / median["scipy.optimize", "importtime"]
    holds = ratio <= FLOOR
    print(f"floor (importtime ratio <= {FLOOR:g}): {'holds' if holds else 'FAILS'} "
          f"({ratio:.2f})")
    return 0 if holds else 1


if __name__ == "__main__":
    sys.exit(main())
