"""What each part of a conic fit's kernel costs, timed inside numba (docs/engine.md, "What a
conic fit's kernel spends").

A fit's parts are linked kernels (``kanagen.common.link``); called from Python each would
pay for boxing its named tuples of arrays, more than some of them cost. Here a compiled
loop calls each part ``--calls`` times at one fit's returned point (a restored point, its
linearisation and the Lagrangian's model there), the loops interleaved over ``--rounds``
rounds and the fastest round kept (this machine's runs of the same code differ by tens of
per cent). How often a fit calls each part is counted apart: ``NUMBA_DISABLE_JIT=1 python
experiments/kernel_parts.py --count`` (interpreted: slow) traces 30 fits of the
``conic_odr`` benchmark's draws (``--sigma 0.5``: all at one noise level), the projector's
points and the restorations also by the engine function calling them. ``--phases`` times
whole fits instead (50 draws, ``--sigma`` 1 unless given), with the end's checks, the
report at the returned point and the iterations switched off in turn: the differences are
what each phase costs in a fit (docs/engine.md, "A fit by its parts"). ``--layers`` times
``kanagen.fit`` as a user calls it and its layers underneath, each on the same 50 draws in a
loop: the kernel alone (the problems made beforehand), then with the problem and its engine
arrays made, with ``iterate``'s Python, with the result (``fit_problem``), ``kanagen.fit``
itself — the differences are what each layer's Python costs where it runs, after a kernel
has left the interpreter's caches cold (two to three times what the same code costs timed
alone in a loop).

Run ``python experiments/kernel_parts.py`` (about a minute once the kernels are cached).
"""

from __future__ import annotations

import argparse
import collections
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))
import conic_odr as bench  # noqa: E402

import kanagen  # noqa: E402
from kanagen.common.jit import NUMBA, jit  # noqa: E402
from kanagen.common.link import link  # noqa: E402
from kanagen.runtime import fit as fitting  # noqa: E402
from kanagen.runtime.engine import curvature, points, verify  # noqa: E402
from kanagen.runtime.engine import iterate as engine  # noqa: E402
from kanagen.runtime.engine.data import arrays, pack_measures  # noqa: E402
from kanagen.runtime.iterate import iterate, unpack_point  # noqa: E402

#: The engine's kernels a conic fit calls, for ``--count``.
PARTS = ("project_point", "restored", "lagrangian", "step", "lost_direction", "nearer_points",
         "verify", "profile_hessian", "tangent_basis")


def problems(count: int, sigma: float = 1.0):
    """``count`` conic problems of the benchmark (30 points, noise ``sigma``): their arrays
    and Taubin starts."""
    fam = kanagen.load("conic")
    out = []
    for xy, start in draws(count, sigma):
        problem = fitting.make_problem(fam, "conic", {"point": xy}, {"point": 1 / sigma**2},
                                       start, None, None)
        out.append((arrays(problem), np.ascontiguousarray(start)))
    return out


def draws(count: int, sigma: float) -> list:
    """The benchmark's first ``count`` conic draws at ``sigma``: the points and their Taubin
    starts."""
    truth = bench.SCENE.points(bench.N_POINTS)
    return [(truth + noise, bench.taubin(truth + noise))
            for noise in bench.noise_draws(sigma, count)]


def _timed(part):
    """A compiled loop calling the compiled ``part(A, x, lin, proj, W, model, model_proj)``
    (a number back) ``calls`` times."""
    @NUMBA.njit
    def loop(A, x, lin, proj, W, model, model_proj, calls):
        total = 0.0
        for _ in range(calls):
            total += part(A, x, lin, proj, W, model, model_proj)
        return total
    return loop


def _parts() -> dict:
    """The parts, each a compiled call returning a number (so that it is not optimised
    away): at a restored point ``x``, its linearisation and projector's point ``lin,
    proj``, its tangent basis ``W`` and the Lagrangian's model there."""
    njit = NUMBA.njit
    return {
        "project_point": njit(lambda A, x, lin, proj, W, m, mp: 1.0 if points.project_point(
            A, x, 0.0, np.zeros(0))[0] else 0.0),
        "restored (at a restored point)": njit(lambda A, x, lin, proj, W, m, mp: points.restored(
            A, x.q, x.mt, np.zeros((0, 0)), 30, True)[1]),
        "lagrangian": njit(lambda A, x, lin, proj, W, m, mp: points.lagrangian(
            A, x, lin, proj)[0].info[0, 0]),
        "lost_direction": njit(lambda A, x, lin, proj, W, m, mp: float(
            verify.lost_direction(A, x, lin)[1].size)),
        "nearer_points": njit(lambda A, x, lin, proj, W, m, mp: 1.0 if points.nearer_points(
            A, x)[0] else 0.0),
        "tangent_basis": njit(lambda A, x, lin, proj, W, m, mp: float(
            verify.tangent_basis(x, lin.info).size)),
        "profile_hessian": njit(lambda A, x, lin, proj, W, m, mp: curvature.profile_hessian(
            A, x, lin, W)[1][0, 0]),
        "verify": njit(lambda A, x, lin, proj, W, m, mp: verify.verify(
            A, x, lin, proj, np.zeros(0), False, m, mp).curvature),
    }


def timings(calls: int, rounds: int) -> dict[str, float]:
    """Each part's fastest time a call (µs), at the first problem's returned point."""
    A, start = problems(1)[0]
    out = engine.run_flat(A, start, 100, 1e-10, True, True)
    returned, _ = unpack_point(A, out[9], out[7], 5)  # the fit's point (after 5 numbers)
    x, _ = points.restored(A, returned.q, pack_measures(A, returned.mt), np.zeros((0, 0)), 30,
                           True)
    _, lin, proj = points.project_point(A, x, 0.0, np.zeros(0))
    context = (A, x, lin, proj, verify.tangent_basis(x, lin.info),
               *points.lagrangian(A, x, lin, proj))
    link()
    loops = {name: _timed(part) for name, part in _parts().items()}
    best = dict.fromkeys(loops, np.inf)
    fit_best = np.inf
    for _ in range(rounds):
        for name, loop in loops.items():
            loop(*context, 2)
            began = time.perf_counter()
            loop(*context, calls)
            best[name] = min(best[name], (time.perf_counter() - began) / calls * 1e6)
        began = time.perf_counter()
        for _ in range(calls // 20):
            engine.run_flat(A, start, 100, 1e-10, True, True)
        fit_best = min(fit_best, (time.perf_counter() - began) / (calls // 20) * 1e6)
    best["a whole fit (run_flat, from Python)"] = fit_best
    return best


#: The fits of :func:`phases`: ``(label, max_iter, checks of the end, report)``.
PHASES = (("a whole fit", 100, True, True), ("without the report", 100, True, False),
          ("without the report and the checks", 100, False, False),
          ("the start alone (max_iter 0, neither)", 0, False, False))


def phases(count: int, sigma: float, rounds: int) -> dict[str, float]:
    """The kernel of ``count`` conic fits at ``sigma`` (µs a fit, fastest of ``rounds``
    interleaved loops) as :data:`PHASES` runs them, and what each phase costs: the report
    (its covariance), the end's checks, the iterations — the differences of the loops."""
    made = problems(count, sigma)
    best = {label: np.inf for label, *_ in PHASES}
    for _ in range(rounds):
        for label, max_iter, checks, report in PHASES:
            began = time.perf_counter()
            for A, start in made:
                engine.run_flat(A, start, max_iter, 1e-10, checks, report)
            best[label] = min(best[label], (time.perf_counter() - began) / len(made) * 1e6)
    whole, bare, unchecked, start = best.values()
    return {**best, "the report (difference)": whole - bare,
            "the end's checks (difference)": bare - unchecked,
            "the iterations (difference)": unchecked - start}


def layers(count: int, sigma: float, rounds: int) -> dict[str, float]:
    """``kanagen.fit`` on ``count`` conic draws at ``sigma`` and the layers under it (µs a
    fit, fastest of ``rounds`` interleaved loops), each layer's difference after them."""
    fam = kanagen.load("conic")
    info = {"point": 1 / sigma**2}
    made = draws(count, sigma)

    def problem(xy, start):
        return fitting.make_problem(fam, "conic", {"point": xy}, info, start, None, None)

    before = [(arrays(problem(xy, start)), start) for xy, start in made]

    def kernel():
        for A, start in before:
            engine.run_flat(A, start.copy(), 100, 1e-10, True, True)

    def with_arrays():
        for xy, start in made:
            made_now = problem(xy, start)
            engine.run_flat(arrays(made_now), made_now.q0.copy(), 100, 1e-10, True, True)

    def with_iterate():
        for xy, start in made:
            made_now = problem(xy, start)
            iterate(made_now, made_now.q0, report=True)

    def with_result():
        for xy, start in made:
            fitting.fit_problem(fam, "conic", problem(xy, start))

    def whole():
        for xy, start in made:
            kanagen.fit(fam, "conic", data={"point": xy}, info=info, q0=start)

    loops = {"the kernel (problems made before)": kernel,
             "+ the problem and its arrays made": with_arrays,
             "+ iterate's Python": with_iterate, "+ the result (fit_problem)": with_result,
             "kanagen.fit": whole}
    best = dict.fromkeys(loops, np.inf)
    for _ in range(rounds):
        for label, loop in loops.items():
            began = time.perf_counter()
            loop()
            best[label] = min(best[label], (time.perf_counter() - began) / count * 1e6)
    steps = list(best.values())
    names = ("the problem and its arrays", "iterate's Python", "the result",
             "kanagen.fit's checks")
    return {**best, **{f"{name} (difference)": b - a
                       for name, a, b in zip(names, steps[:-1], steps[1:], strict=True)}}


def counts(fits: int, sigma: float | None = None) -> dict[str, float]:
    """How many times a fit calls each part (interpreted, traced), on average, over
    ``fits`` draws (spread over the benchmark's noise levels, or all at ``sigma``); the
    projector's points and the restorations also by the engine function that calls them
    (``restored < joint_start``)."""
    seen: collections.Counter = collections.Counter()

    def trace(frame, event, arg):
        if event == "call" and frame.f_code.co_name in PARTS and \
                "engine" in frame.f_code.co_filename:
            name = frame.f_code.co_name
            seen[name] += 1
            if name in _BY_CALLER:
                seen[f"{name} < {frame.f_back.f_code.co_name}"] += 1

    levels = bench.SIGMAS if sigma is None else (sigma,)
    made = [p for level in levels for p in problems(fits // len(levels), level)]
    for A, start in made:
        sys.setprofile(trace)
        try:
            engine.run_flat(A, start, 100, 1e-10, True, True)
        finally:
            sys.setprofile(None)
    return {name: seen[name] / len(made) for name in sorted(seen, key=_order)}


#: The parts :func:`counts` also counts by their calling engine function.
_BY_CALLER = ("project_point", "restored")


def _order(name: str) -> tuple:
    part = name.split(" < ")[0]
    return PARTS.index(part), name


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=1000)
    parser.add_argument("--rounds", type=int, default=24)
    parser.add_argument("--count", action="store_true",
                        help="count the parts' calls per fit (with NUMBA_DISABLE_JIT=1)")
    parser.add_argument("--sigma", type=float, default=None,
                        help="--count's draws all at this noise level (default: the "
                             "benchmark's levels, a third each; --phases: 1)")
    parser.add_argument("--phases", action="store_true",
                        help="whole fits with the checks, the report and the iterations "
                             "switched off in turn")
    parser.add_argument("--layers", action="store_true",
                        help="kanagen.fit and the layers of Python around its kernel")
    args = parser.parse_args(argv)
    if args.count:
        for name, value in counts(30, args.sigma).items():
            print(f"{name:40s} {value:6.2f} a fit")
        return
    if NUMBA is None or jit.disabled:
        sys.exit("the timings need numba's compiled kernels (unset NUMBA_DISABLE_JIT)")
    if args.phases or args.layers:
        sigma = 1.0 if args.sigma is None else args.sigma
        measure = phases if args.phases else layers
        for name, value in measure(50, sigma, min(args.rounds, 12)).items():
            print(f"{name:40s} {value:8.1f} µs")
        return
    for name, value in timings(args.calls, args.rounds).items():
        print(f"{name:40s} {value:8.2f} µs")


if __name__ == "__main__":
    main()
