"""Time of `jmlgdsl run specs/dryer.jmlg FILES -o DIR/` on a few and on many dryer files, and the
ratio of the two (BENCHMARKS.md, "run on many files"; docs/fleet.md).

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_run_files.py                # 20 and 200 files
    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_run_files.py --counts 10 100 --repeats 3

Each file is a simulated dryer record of --steps rows (`jmlgdsl simulate specs/dryer.jmlg --steps N
--seed S` for S = 0, 1, ...: time, inputs, outputs and the true mode), written once. A figure is the
median of --repeats whole commands, each in its own process (its start, imports and spec included):
wall clock, and CPU (user + system) from the operating system's account of the child. The figures
are recorded in the results ledger as fleet/run-files.
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import jmlgdsl
from jmlgdsl.data import write_columns
from jmlgdsl.simulation.linear import simulate

sys.path.insert(0, str(Path(__file__).resolve().parent))
import ledger  # noqa: E402  (benchmarks/ledger.py, the results ledger)

SPEC = Path(__file__).resolve().parent.parent / "specs" / "dryer.jmlg"


def timed_run(files, folder: Path) -> tuple[float, float]:
    """(wall s, CPU s) of one `jmlgdsl run` over the files, its tables into `folder`."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    subprocess.run([sys.executable, "-m", "jmlgdsl", "run", str(SPEC), *map(str, files), "-o", f"{folder}/"],
                   check=True, stdout=subprocess.DEVNULL, env={**os.environ, "OPENBLAS_NUM_THREADS": "1"})
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--counts", type=int, nargs=2, default=[20, 200], metavar=("FEW", "MANY"),
                   help="how many files in the smaller and the larger run (default 20 200)")
    p.add_argument("--steps", type=int, default=1000, help="rows in each file (default 1000)")
    p.add_argument("--repeats", type=int, default=5, help="whole commands timed per count (default 5)")
    p.add_argument("--ledger", type=Path, default=ledger.LEDGER, help="the ledger file (default benchmarks/ledger.json)")
    args = p.parse_args(argv)
    model = jmlgdsl.load(SPEC)
    figures = {}
    with tempfile.TemporaryDirectory() as work:
        work = Path(work)
        files = []
        for seed in range(max(args.counts)):
            files.append(work / f"d{seed}.csv")
            write_columns(str(files[-1]), simulate(model, args.steps, seed=seed).columns())
        for count in args.counts:
            times = np.array([timed_run(files[:count], work / f"out{count}") for _ in range(args.repeats)])
            wall, cpu = np.median(times, axis=0)
            figures[f"run_{count}_files_wall_s"] = round(float(wall), 2)
            figures[f"run_{count}_files_cpu_s"] = round(float(cpu), 2)
            print(f"{count} files of {args.steps} rows: wall {wall:.2f} s, CPU {cpu:.2f} s (median of {args.repeats})")
    few, many = args.counts
    for kind in ("wall", "cpu"):
        figures[f"ratio_{kind}"] = round(figures[f"run_{many}_files_{kind}_s"] / figures[f"run_{few}_files_{kind}_s"], 1)
    print(f"{many} files against {few}: {figures['ratio_wall']} times the wall clock, {figures['ratio_cpu']} the CPU")
    ledger.record("fleet/run-files", figures, "OPENBLAS_NUM_THREADS=1 python benchmarks/bench_run_files.py --counts "
                  f"{few} {many} --steps {args.steps} --repeats {args.repeats}", path=args.ledger)
    return 0


if __name__ == "__main__":
    sys.exit(main())
