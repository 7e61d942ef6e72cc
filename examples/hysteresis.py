"""The hysteresis of the report's appendix F, evaluated on a ramp up and down.

``examples/hysteresis.yaml`` states hys(t) = sat(t − s) with the state ``s ∈ {−1, 1}`` and its
switching rule as formulas; ``kanagen`` compiles them into equations with slack components.
Evaluating at an input ``t`` is a minimal solve (report eq. 21) with no measures: the point
closest to the start that satisfies every equation.

A local solver follows the branch it starts on; at a switch (the state flips, the output
leaves a saturation) it has to start on the other branch. So each step tries, in order,
the previous solution (continuation), then a start on each branch of the formula: each
value of the qualitative state and each branch of sat. The first start that solves the
equations wins; a step no start solves is reported as such, never guessed.

Run: ``python examples/hysteresis.py [--plot hysteresis.svg]``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import kanagen

SPEC = Path(__file__).with_name("hysteresis.yaml")


def evaluate(fam, t: float, s_prev: float, q_prev: np.ndarray):
    """(y, s, q) at input ``t`` after state ``s_prev``; None where no start solves."""
    constants = {"t": float(t), "s_prev": float(s_prev)}
    k = fam.constant_vector(constants)
    starts = [q_prev[:2]] + [np.array([y, s]) for s in (s_prev, -s_prev)
                             for y in (-1.0, 1.0, t - s)]
    for start in starts:
        sol = kanagen.minimal_solve(fam, "hysteresis", data={},
                                    q_start=fam.with_slacks(start, k, "hysteresis"),
                                    constants=constants)
        if sol.success:
            return float(sol.q[0]), float(sol.q[1]), sol.q
    return None


def ramp(fam, low: float = -2.95, high: float = 2.95, step: float = 0.1):
    """Inputs from ``low`` up to ``high`` and back; the outputs and the states."""
    up = np.arange(low, high + step / 2, step)
    ts = np.r_[up, up[::-1]]
    q, s_prev = fam.q0, 1.0
    ys, states = [], []
    for t in ts:
        out = evaluate(fam, t, s_prev, q)
        if out is None:
            raise RuntimeError(f"no start solves the hysteresis at t = {t:g}")
        y, s, q = out
        s_prev = float(round(s))
        ys.append(y)
        states.append(int(s_prev))
    return ts, np.array(ys), np.array(states)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plot", help="write the loop to this image (needs matplotlib)")
    args = parser.parse_args()
    fam = kanagen.load(SPEC)
    ts, ys, states = ramp(fam)
    half = len(ts) // 2
    print(f"{'t':>6} {'up: y':>8} {'s':>3}   {'down: y':>8} {'s':>3}")
    for i in range(0, half, 5):
        j = len(ts) - 1 - i
        print(f"{ts[i]:6.2f} {ys[i]:8.3f} {states[i]:3d}   {ys[j]:8.3f} {states[j]:3d}")
    if args.plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(5, 3.5))
        ax.plot(ts[:half], ys[:half], "-o", ms=3, label="ramp up (s = 1 → −1)")
        ax.plot(ts[half:], ys[half:], "-s", ms=3, label="ramp down (s = −1 → 1)")
        ax.set(xlabel="input t", ylabel="output y", title="hysteresis (report app. F)")
        ax.legend()
        fig.tight_layout()
        fig.savefig(args.plot)
        print(f"wrote {args.plot}")


if __name__ == "__main__":
    main()
