"""Peak memory of an endless stream: rows piped into `jmlgdsl run SPEC -` (BENCHMARKS.md).

    python benchmarks/bench_stream.py                    # 10^4, 10^5 and 10^6 rows of the dryer
    python benchmarks/bench_stream.py --rows 100000 --filter la-rbpf

Rows are simulated from the spec in blocks and written to the command's standard input as it reads
them, so nothing but the command holds the data; its table goes to /dev/null. The peak resident
set size of the command comes from the operating system (getrusage of the finished child).
"""

from __future__ import annotations

import argparse
import platform
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

import jmlgdsl
from jmlgdsl.simulation.linear import simulate

ROOT = Path(__file__).resolve().parent.parent


def stream(spec, rows, algorithm, block=10_000):
    """(peak RSS in MiB, seconds) of `jmlgdsl run SPEC - -o /dev/null` fed `rows` simulated rows."""
    model = jmlgdsl.load(spec)
    command = [sys.executable, "-m", "jmlgdsl", "run", str(spec), "-", "--filter", algorithm, "-o", "/dev/null"]
    start = time.perf_counter()
    child = subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                             text=True)
    child.stdin.write(",".join(["time", *model.inputs, *model.outputs]) + "\n")
    for first in range(0, rows, block):
        sim = simulate(model, min(block, rows - first), seed=first)
        table = np.column_stack([(first + np.arange(1, len(sim.y) + 1)) * model.dt, sim.u, sim.y])
        child.stdin.write("\n".join(",".join(f"{v:.6g}" for v in row) for row in table) + "\n")
    child.stdin.close()
    if child.wait():
        raise SystemExit(f"{' '.join(command)} failed with status {child.returncode}")
    seconds = time.perf_counter() - start
    return resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024, seconds


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--spec", default=ROOT / "specs" / "dryer.jmlg")
    parser.add_argument("--rows", type=int, nargs="*", default=[10_000, 100_000, 1_000_000])
    parser.add_argument("--filter", default="imm")
    args = parser.parse_args()
    print(f"machine: {platform.machine()}, Python {platform.python_version()}, numpy {np.__version__}; "
          f"{time.strftime('%Y-%m-%d')}\n\n| rows | filter | peak RSS (MiB) | wall time (s) |\n|---|---|---|---|")
    for rows in sorted(args.rows):  # RUSAGE_CHILDREN keeps the largest child so far: smallest first
        rss, seconds = stream(args.spec, rows, args.filter)
        print(f"| {rows:,} | {args.filter} | {rss:.0f} | {seconds:.0f} |", flush=True)


if __name__ == "__main__":
    main()
