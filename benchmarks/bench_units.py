"""Unit-steps per second of many units of one plant in one filter (jmlgdsl.infer.units), against
the unit count, beside the same units filtered one after the other (BENCHMARKS.md, "Fleets").

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_units.py                  # dryer and cstr10, imm and la-rbpf:10
    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_units.py --counts 1 10 100 --plants dryer

Every unit filters its own simulated record (16 records, simulated once, taken in turn); a figure is
the best of --repeats runs of the filtering alone (`Units.seconds`: no I/O), over enough steps for
about --seconds of work. The loop column runs one Filter per unit (what one process per unit does,
less its start-up). Memory per unit is the filter's state plus the largest transient of a step, as
tracemalloc sees it at the largest count, divided by the count. Tables are printed as Markdown and
each filter's figures recorded in the results ledger as fleet/units/NAME[:PARTICLES] (timings: never
compared, only quoted).
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

import jmlgdsl
from jmlgdsl.infer import Filter
from jmlgdsl.infer.online import _readings
from jmlgdsl.infer.units import Units
from jmlgdsl.simulation.linear import simulate

sys.path.insert(0, str(Path(__file__).resolve().parent))
import ledger  # noqa: E402  (benchmarks/ledger.py, the results ledger)

SPECS = Path(__file__).resolve().parent.parent / "specs"
RECORDS = 16


def records(model, T):
    """(y, u) of RECORDS simulated records of T steps: (RECORDS, T, ny) and (RECORDS, T, nu)."""
    sims = [simulate(model, T, seed=s) for s in range(RECORDS)]
    return np.array([s.y for s in sims]), np.array([s.u for s in sims])


def batched(model, algorithm, particles, y, u, count, T):
    """Seconds of `Units.step` over T steps of `count` units."""
    fleet = Units(model, count, algorithm, particles, seed=1)
    pick = np.arange(count) % RECORDS
    for t in range(T):
        fleet.step(y[pick, t], u[pick, t])
    return fleet.seconds


def loop(model, algorithm, particles, y, u, count, T):
    """Seconds of one Filter per unit over T steps, unit after unit."""
    seconds = 0.0
    for i in range(count):
        f = Filter(model, algorithm, particles, seed=1)
        ys, mask = _readings(y[i % RECORDS, :T])
        for t in range(T):
            f._advance(ys[t], mask[t], u[i % RECORDS, t])
        seconds += f.seconds
    return seconds


def rate(run, count, budget, repeats, *args):
    """Unit-steps per second of run(..., count, T): T sized from a first short run to take about
    `budget` seconds, the best of `repeats` runs."""
    probe = max(2, min(50, int(2000 / count)))
    per_unit_step = run(*args, count, probe) / (count * probe)
    T = int(np.clip(budget / (per_unit_step * count), 3, 400))
    return max(count * T / run(*args, count, T) for _ in range(repeats))


def memory_per_unit(model, algorithm, particles, y, u, count) -> float:
    """Bytes per unit: a fleet's arrays and the peak of a step, from tracemalloc."""
    tracemalloc.start()
    fleet = Units(model, count, algorithm, particles, seed=1)
    pick = np.arange(count) % RECORDS
    for t in range(3):
        fleet.step(y[pick, t], u[pick, t])
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return peak / count


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--plants", nargs="+", default=["dryer", "cstr10"])
    p.add_argument("--filters", nargs="+", default=["imm", "la-rbpf:10"],
                   help="filters, each NAME or NAME:PARTICLES (la-rbpf:10, pf:20)")
    p.add_argument("--counts", nargs="+", type=int, default=[1, 10, 100, 1000, 10000])
    p.add_argument("--loop-up-to", type=int, default=1000, help="the largest count the loop is timed at")
    p.add_argument("--seconds", type=float, default=1.0, help="work per figure")
    p.add_argument("--repeats", type=int, default=3)
    ledger.ledger_argument(p)
    args = p.parse_args()
    figures = {given: {} for given in args.filters}
    print(f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, numpy {np.__version__}\n")
    for plant in args.plants:
        model = jmlgdsl.load(SPECS / f"{plant}.jmlg")
        y, u = records(model, 400)
        for given in args.filters:
            algorithm, _, count = given.partition(":")
            particles = int(count) if count else None
            name = algorithm + (f", {particles}" if particles else "")
            print(f"### {plant}, {name} (K {model.K}, nx {model.nx}, ny {model.ny})\n")
            print("| units | batched, unit-steps/s | loop, unit-steps/s | speed-up |")
            print("|---|---|---|---|")
            for count in args.counts:
                fast = rate(batched, count, args.seconds, args.repeats, model, algorithm, particles, y, u)
                figures[given][f"{plant}_{count}_batched"] = round(fast)
                if count <= args.loop_up_to:
                    slow = rate(loop, count, args.seconds, args.repeats, model, algorithm, particles, y, u)
                    figures[given][f"{plant}_{count}_loop"] = round(slow)
                    print(f"| {count:,} | {fast:,.0f} | {slow:,.0f} | {fast / slow:.1f} |", flush=True)
                else:
                    print(f"| {count:,} | {fast:,.0f} | - | - |", flush=True)
            big = max(args.counts)
            kib = memory_per_unit(model, algorithm, particles, y, u, big) / 1024
            figures[given][f"{plant}_{big}_kib_per_unit"] = round(kib, 1)
            print(f"\nmemory per unit at {big:,} units: {kib:.1f} KiB\n", flush=True)
    for given, found in figures.items():
        ledger.record(f"fleet/units/{given}", found, "OPENBLAS_NUM_THREADS=1 python benchmarks/bench_units.py "
                      f"--plants {' '.join(args.plants)} --filters {given} --counts {' '.join(map(str, args.counts))} "
                      f"--repeats {args.repeats}", path=args.ledger)


if __name__ == "__main__":
    start = time.perf_counter()
    main()
    print(f"({time.perf_counter() - start:.0f} s)")
