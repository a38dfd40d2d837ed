"""Throughput of a fleet's monitor: one process, and shards on a local Ray cluster (BENCHMARKS.md,
"A fleet's monitor on Ray").

    python benchmarks/bench_shards.py                          # 40 dryers, 2,000 rows each
    python benchmarks/bench_shards.py --units 200 --rows 500 --shards 1 2
    python benchmarks/bench_shards.py --units 1000 --rows 200 --shards --key fleet/monitor/1000   # one process only

Every unit's record is simulated from the dryer bank (its own seed) and written to UNIT.csv in a
temporary folder; `jmlgdsl monitor SPEC --units u001..uNNN --source DIR/{unit}.csv --no-follow`
then diagnoses every file to its end into a fresh SQLite store, in one process and with `--cluster
auto --shards S` for each S asked for. A figure is rows stored per second, from the command's
start to its end, so the start (Python, the spec, Ray's local cluster and its actors) is in it;
the steady rate beside it leaves the start out: the same command on files of one row each
measures the start, and the steady rate is the other rows over the rest of the time. The per-row
cost of the source, actor and store path is the steady time per row and shard less the diagnosis's
own (a Fleet fed the same rows in this process, its units in one vectorised filter with their
evidence, as the monitor keeps them). The memory a unit holds is what tracemalloc sees a monitor
of 2,000 units hold beyond one of 200 (its diagnosis, alarm rule, its share of the filter), per unit.

The figures go into the results ledger (benchmarks/ledger.json) as `fleet/monitor` (or --key), with the
sizing table of docs/fleet.md ("How much machine a fleet needs") worked out from them: rows a
second per shard, store bytes per row and memory per unit, for plants of 200 to 100,000 units.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import sqlite3
import subprocess
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import jmlgdsl
from jmlgdsl.data import iter_rows, open_source
from jmlgdsl.diagnosis import Options
from jmlgdsl.diagnosis.fleet import Fleet
from jmlgdsl.monitor import Monitor, MonitorOptions, Store
from jmlgdsl.monitor import sources

from ledger import ledger_argument, record

SPEC = Path(__file__).resolve().parent.parent / "specs" / "dryer.jmlg"
#: The plants docs/fleet.md sizes: (units, seconds between samples).
PLANTS = ((200, 1), (1_000, 1), (10_000, 1), (10_000, 10), (100_000, 1), (100_000, 60))


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
    Fleet(model, len(records), Options(explain=True), scored=False).run(records)
    return (time.perf_counter() - start) / sum(map(len, records))


def held(folder: Path, count: int) -> int:
    """Bytes tracemalloc sees a monitor of `count` units (files of one row each, not yet read) hold."""
    units = [f"m{k:05d}" for k in range(count)]
    write_units(folder, units, 1)
    model = jmlgdsl.load(SPEC)
    with Store(folder / "store.db") as store:
        source = sources.open_source(sources.Connection(str(folder / "{unit}.csv"), follow=False), model, {}, units)
        tracemalloc.start()
        before = tracemalloc.get_traced_memory()[0]
        monitor = Monitor(model, store, source, spec=None, options=MonitorOptions(), tags={}, units=units)
        size = tracemalloc.get_traced_memory()[0] - before
        tracemalloc.stop()
        del monitor
    return size


def per_unit_memory(folder: Path, small: int = 200, large: int = 2000) -> float:
    """Bytes a monitor holds per unit: a monitor of `large` units against one of `small`."""
    return (held(folder / "memory-large", large) - held(folder / "memory-small", small)) / (large - small)


def sizing(rate: float, store_bytes: float, memory: float) -> str:
    """docs/fleet.md's table: for each plant, rows a second, the shards (cores) at `rate` rows a second
    each, the store a day at `store_bytes` a row, and the memory at `memory` bytes a unit."""
    def size(value, units, step=1000):
        for unit in units[:-1]:
            if value < step * 0.95:
                return f"{value:.1f} {unit}" if value < 10 else f"{value:,.0f} {unit}"
            value /= step
        return f"{value:.1f} {units[-1]}" if value < 10 else f"{value:,.0f} {units[-1]}"
    lines = [f"| units | sampled every | rows/s | shards (cores) at {rate:,.0f} rows/s each | store per day | memory |",
             "|---:|---:|---:|---:|---:|---:|"]
    for units, every in PLANTS:
        rows = units / every
        shards = math.ceil(rows / rate)
        load = f" ({rows / rate:.0%} of a core)" if shards == 1 else ""
        lines.append(f"| {units:,} | {every} s | {rows:,.0f} | {shards}{load} | "
                     f"{size(rows * 86400 * store_bytes, ('B', 'kB', 'MB', 'GB', 'TB'))} | "
                     f"{size(units * memory, ('B', 'KiB', 'MiB', 'GiB'), 1024)} |")
    return "\n".join(lines)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--units", type=int, default=40)
    parser.add_argument("--rows", type=int, default=2000, help="rows per unit")
    parser.add_argument("--shards", type=int, nargs="*", default=[1, 2], help="none: the one process only")
    parser.add_argument("--key", default="fleet/monitor", help="the ledger entry")
    ledger_argument(parser)
    args = parser.parse_args()
    units = [f"u{k:0{max(3, len(str(args.units)))}d}" for k in range(1, args.units + 1)]
    found = {}
    with tempfile.TemporaryDirectory() as name:
        folder, short = Path(name) / "records", Path(name) / "one-row"
        write_units(folder, units, args.rows)
        write_units(short, units, 1)
        per_row = filter_cost(folder, units)
        memory = per_unit_memory(Path(name))
        print(f"machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}; "
              f"{args.units} dryers x {args.rows} rows; the diagnosis alone: {per_row * 1e6:.0f} us per row; "
              f"a monitor holds {memory / 1024:.1f} KiB per unit\n")
        print("| monitor | wall s | rows/s (command) | rows/s (steady) | us per row beyond the diagnosis | store bytes/row |")
        print("|---|---:|---:|---:|---:|---:|")
        for shards in [None, *args.shards]:
            seconds, rows, size = monitor(folder, units, shards)
            begun, first, _ = monitor(short, units, shards)
            steady = (rows - first) / (seconds - begun)
            what = "one process" if shards is None else f"Ray, {shards} shard{'s' if shards > 1 else ''}"
            key = "process" if shards is None else f"ray{shards}"
            found |= {f"{key}_rows_per_s": round(steady), f"{key}_us_per_row": round(1e6 * (shards or 1) / steady),
                      f"{key}_us_beyond_diagnosis": round(((shards or 1) / steady - per_row) * 1e6),
                      f"{key}_store_bytes_per_row": round(size / rows)}
            print(f"| {what} | {seconds:.1f} (start {begun:.1f}) | {rows / seconds:,.0f} | {steady:,.0f} | "
                  f"{found[f'{key}_us_beyond_diagnosis']:,} | {size / rows:,.0f} |", flush=True)
    found |= {"diagnosis_us_per_row": round(per_row * 1e6, 1), "memory_kib_per_unit": round(memory / 1024, 1),
              "sizing": sizing(found["process_rows_per_s"], found["process_store_bytes_per_row"], memory)}
    if {"ray1_rows_per_s", "ray2_rows_per_s"} <= set(found):
        found["two_shards_over_one"] = round(found["ray2_rows_per_s"] / found["ray1_rows_per_s"], 2)
    print("\n" + found["sizing"])
    record(args.key, found, "python benchmarks/bench_shards.py " + " ".join(sys.argv[1:]), path=args.ledger)


if __name__ == "__main__":
    main()
