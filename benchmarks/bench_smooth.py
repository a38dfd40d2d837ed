"""Smoothing on the dryer (BENCHMARKS.md): the time of smoothing a long run (IMM off-line and at a
lag of 10, fc-rbpf at a lag of 10, 10,000 steps), and the diagnosis error of the default filter and
of its lag-10 smoother over 25 simulations of the published sequence No. 1.

    python benchmarks/bench_smooth.py [--steps 10000] [--repeats 3] [--runs 25]
"""

from __future__ import annotations

import argparse
import platform
import sys
import time
from pathlib import Path

import numpy as np

import jmlgdsl
from jmlgdsl.simulation.linear import simulate

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks" / "studies"))
from studies import DRYER  # noqa: E402  (the published sequences, written once)

DRYER_SEQ1 = DRYER["seq1"]


def best(repeats, work):
    """The shortest wall-clock time of `repeats` calls (the least disturbed by other work)."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        work()
        times.append(time.perf_counter() - start)
    return min(times)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=10_000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--runs", type=int, default=25)
    args = parser.parse_args()
    model = jmlgdsl.load(ROOT / "specs" / "dryer.jmlg")
    sim = simulate(model, args.steps, seed=0)
    print(f"machine: {platform.machine()}, Python {platform.python_version()}, numpy {np.__version__}; "
          f"{time.strftime('%Y-%m-%d')}; dryer, {args.steps:,} steps, best of {args.repeats}\n")
    print("| what | seconds |\n|---|---|")
    cases = {
        "filter (imm)": lambda: jmlgdsl.filter(model, sim.y, sim.u),
        "smooth, imm, off-line (filter included)": lambda: jmlgdsl.smooth(model, sim.y, sim.u),
        "smooth, imm, lag 10 (filter included)": lambda: jmlgdsl.smooth(model, sim.y, sim.u, lag=10),
        "smooth, fc-rbpf N=4, lag 10": lambda: jmlgdsl.smooth(model, sim.y, sim.u, algorithm="fc-rbpf", lag=10),
    }
    for name, work in cases.items():
        print(f"| {name} | {best(args.repeats, work):.2f} |", flush=True)
    errors = {0: [], 10: []}
    for run in range(args.runs):
        sim = simulate(model, seed=run, modes=DRYER_SEQ1)
        for lag, found in errors.items():
            found.append(jmlgdsl.smooth(model, sim.y, sim.u, lag=lag).diagnosis_error(sim.modes))
    print(f"\n| dryer, sequence No. 1, {args.runs} runs | error % mean (SD) | largest |\n|---|---|---|")
    for lag, found in errors.items():
        print(f"| imm, {'filtered' if lag == 0 else f'lag {lag}'} | {np.mean(found):.3f} ({np.std(found):.3f}) | "
              f"{np.max(found):.2f} |")


if __name__ == "__main__":
    main()
