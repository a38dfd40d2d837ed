"""Throughput of a fleet's monitor: one process, and shards on a local Ray cluster (BENCHMARKS.md,
"A fleet's monitor on Ray").

    python benchmarks/bench_shards.py                          # 40 dryers, 2,000 rows each
    python benchmarks/bench_shards.py --units 200 --rows 500 --shards 1 2

Every unit's record is simulated from the dryer bank (its own seed) and written to UNIT.csv in a
temporary folder; `jmlgdsl monitor SPEC --units u001..uNNN --source DIR/{unit}.csv --no-follow`
then diagnoses every file to its end into a fresh SQLite store, in one process and with `--cluster
auto --shards S` for each S asked for. A figure is rows stored per second, from the command's
start to its end, so the start (Python, the spec, Ray's local cluster and its actors) is in it;
the steady rate beside it leaves the start out: the same command on files of one row each
measures the start, and the steady rate is the other rows over the rest of the time. The per-row
cost of the source, actor and store path is the steady time per row and shard less the diagnosis's
own (a Fleet fed the same rows in this process, its units in one vectorised filter with their
evidence, as the monitor keeps them).
"""

from __future__ import annotations

import argparse
import os
import platform
import sqlite3
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import jmlgdsl
from jmlgdsl.data import iter_rows, open_source
from jmlgdsl.diagnosis.fleet import Fleet

SPEC = Path(__file__).resolve().parent.parent / "specs" / "dryer.jmlg"


def write_units(folder: Path, units: list[str], rows: int):
    model = jmlgdsl.load(SPEC)
    folder.mkdir()
    for k, unit in enumerate(units):
        sim = jmlgdsl.simulate(model, rows, seed=k)
        with open(folder / f"{unit}.csv", "w") as out:
            out.write(",".join(["time", *model.outputs, *model.inputs]) + "\n")
            for t in range(rows):
                out.write(",".join(repr(float(v)) for v in (t * model.dt, *sim.y[t], *sim.u[t])) + "\n")


def monitor(folder: Path, units: list[str], shards: int | None) -> tuple[float, int, int]:
    """(seconds, rows stored, store bytes) of the monitor over every unit's file."""
    store = folder / f"store-{shards or 0}.db"
    command = [sys.executable, "-m", "jmlgdsl", "monitor", str(SPEC), "--units", f"{units[0]}..{units[-1]}",
               "--source", str(folder / "{unit}.csv"), "--store", str(store), "--no-follow"]
    if shards:
        command += ["--cluster", "auto", "--shards", str(shards)]
    start = time.perf_counter()
    subprocess.run(command, check=True, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    with sqlite3.connect(store) as db:
        stored = db.execute("SELECT count(*) FROM result").fetchone()[0]
    return seconds, stored, os.path.getsize(store)


def filter_cost(folder: Path, units: list[str]) -> float:
    """Seconds per row of the fleet's diagnosis alone (one vectorised filter, evidence on, as the
    monitor has it), in this process, over every unit's rows."""
    model = jmlgdsl.load(SPEC)
    records = []
    for unit in units:
        with open_source(str(folder / f"{unit}.csv")) as source:
            records.append(list(iter_rows(source, model, source.name)))
    start = time.perf_counter()
    Fleet(model, len(records), explain=True, scored=False).run(records)
    return (time.perf_counter() - start) / sum(map(len, records))


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--units", type=int, default=40)
    parser.add_argument("--rows", type=int, default=2000, help="rows per unit")
    parser.add_argument("--shards", type=int, nargs="+", default=[1, 2])
    args = parser.parse_args()
    units = [f"u{k:03d}" for k in range(1, args.units + 1)]
    with tempfile.TemporaryDirectory() as name:
        folder, short = Path(name) / "records", Path(name) / "one-row"
        write_units(folder, units, args.rows)
        write_units(short, units, 1)
        per_row = filter_cost(folder, units)
        print(f"machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}; "
              f"{args.units} dryers x {args.rows} rows; the diagnosis alone: {per_row * 1e6:.0f} us per row\n")
        print("| monitor | wall s | rows/s (command) | rows/s (steady) | us per row beyond the diagnosis | store bytes/row |")
        print("|---|---:|---:|---:|---:|---:|")
        for shards in [None, *args.shards]:
            seconds, rows, size = monitor(folder, units, shards)
            begun, first, _ = monitor(short, units, shards)
            steady = (rows - first) / (seconds - begun)
            what = "one process" if shards is None else f"Ray, {shards} shard{'s' if shards > 1 else ''}"
            print(f"| {what} | {seconds:.1f} (start {begun:.1f}) | {rows / seconds:,.0f} | {steady:,.0f} | "
                  f"{((shards or 1) / steady - per_row) * 1e6:,.0f} | {size / rows:,.0f} |", flush=True)


if __name__ == "__main__":
    main()
