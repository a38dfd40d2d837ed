"""Throughput, latency, memory and store size of `jmlgdsl monitor` over MQTT (BENCHMARKS.md).

    python benchmarks/bench_monitor.py                              # both phases, one message per tag
    python benchmarks/bench_monitor.py --payload row --backlog 1000000 --rate 0
    python benchmarks/bench_monitor.py --backlog 5000 --rate 300 --seconds 30 --profile
    python benchmarks/bench_monitor.py --pages 2                    # with the operator's page open twice

A spec of 20 temperatures driven by one heater current (two modes) is written to a temporary
folder with a record simulated from it, and a mosquitto (from PATH or /usr/sbin) is started on
127.0.0.1. A publisher process sends the record's rows, either one message per tag and row
(`{"t": ..., "v": ...}` on PREFIX/NAME) or one JSON object per row on PREFIX, at QoS 1.

Two phases, because on a small machine the publisher's own CPU would otherwise set the pace:
- throughput: the monitor connects once (so the broker keeps a persistent session for it), stops,
  the publisher sends `--backlog` rows, and the monitor started again drains them as fast as the
  broker delivers them; rows and tag updates per second are counted from its first reading to its
  last commit, with the memory (resident set size) sampled every 10,000 rows;
- latency: the publisher sends at `--rate` rows per second for `--seconds`, a pace the monitor
  keeps, and a row's latency runs from the arrival of its last reading to the end of the store
  commit that holds its posterior (the monitor runs in this process, so both stamps are exact).
"""

from __future__ import annotations

import argparse
import cProfile
import getpass
import os
import platform
import pstats
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

import jmlgdsl
from jmlgdsl.monitor import Monitor, MonitorOptions, Store, read_tags
from jmlgdsl.monitor.mqtt import MqttSource
from jmlgdsl.page import Page

SENSORS = 20
STALL = 60  # seconds without progress after which a phase ends (and says how far it got)

PUBLISHER = """
import json, sys, time
import numpy as np
import paho.mqtt.client as mqtt
port, first, count, rate = int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]), float(sys.argv[4])
names, values, per_row = sys.argv[5].split(","), np.load(sys.argv[6], mmap_mode="r"), sys.argv[7] == "row"
client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="bench-publisher")
client.max_inflight_messages_set(1000)
client.max_queued_messages_set(0)
client.connect("127.0.0.1", port)
client.loop_start()
start, last = time.monotonic(), None
for t in range(first, first + count):
    row = values[t - 1].tolist()
    if per_row:
        last = client.publish("bank", json.dumps({"t": t, **dict(zip(names, row))}), qos=1)
    else:
        for name, value in zip(names, row):
            last = client.publish("bank/" + name, json.dumps({"t": t, "v": value}), qos=1)
    if t % 50 == 0:
        last.wait_for_publish(60)  # keep the broker's pace, not the client's buffer's
    if rate:
        time.sleep(max(0.0, start + (t - first + 1) / rate - time.monotonic()))
last.wait_for_publish(60)
client.disconnect()
client.loop_stop()
"""


def spec_text(sensors: int) -> str:
    """A bank of `sensors` first-order temperatures of one heater current, in a normal and a fan mode."""
    lines = ["plant bank", "sample 1 s", "", "input current [%] = 15"]
    lines += [f"output t{i} [degC]" for i in range(sensors)]
    lines += ["", "modes", "  normal", "  fan", "", "initial normal 0.99, otherwise uniform",
              "transitions stay 0.995, otherwise uniform", "", "noise process 0.05, measurement 0.05", ""]
    for mode, gain in (("normal", 1.9), ("fan", 1.4)):
        lines.append(f"mode {mode} {{")
        lines += [f"  t{i} ~ fopdt(current, gain {gain + 0.01 * i:.2f}, tau {20 + i} s, delay 0 s, "
                  f"at current 15 -> {50 + i + (0 if mode == 'normal' else -6):.1f})" for i in range(sensors)]
        lines.append("}")
    return "\n".join(lines) + "\n"


def broker(folder: Path):
    mosquitto = shutil.which("mosquitto") or "/usr/sbin/mosquitto"
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    config = folder / "mosquitto.conf"
    # a backlog of any size is kept; the window of messages sent ahead of their acknowledgement is the
    # broker's default (20): unlimited, a deep backlog delays the broker's keepalive answer
    config.write_text(f"listener {port} 127.0.0.1\nuser {getpass.getuser()}\npersistence false\n"
                      "max_queued_messages 0\nallow_anonymous true\n")
    process = subprocess.Popen([mosquitto, "-c", str(config)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    for _ in range(500):
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1).close()
            return process, port
        except OSError:
            time.sleep(0.02)
    raise SystemExit("mosquitto did not start")


class Timed(Monitor):
    """The monitor with the time of its first reading and last commit, its memory every 10,000 rows,
    and with `latency`, each row's latency: from its last reading's arrival to its commit's end (kept
    per row, so not in the run that measures memory)."""

    def __init__(self, *args, latency: bool, **kwargs):
        super().__init__(*args, **kwargs)
        self.latency, self.arrived, self.latencies, self.memory = latency, {}, [], []
        self.started = None

    @property
    def rows(self) -> int:
        """Rows diagnosed so far, every unit's."""
        return sum(watch.rows for watch in self.units)

    def _handle(self, unit, item):
        if item[0] == "readings":
            self.started = self.started or time.time()
            if self.latency:
                for _, _, stamp in item[1]:
                    self.arrived[stamp] = item[2]
        return super()._handle(unit, item)

    def commit(self):
        self.step()  # the rows of this commit (the monitor's commit steps first: then nothing is left)
        samples = [sample for watch in self.units for sample in watch.samples]
        times = [row.time for _, row in samples] if self.latency else []
        super().commit()
        done = time.time()
        self.latencies += [done - self.arrived.pop(t) for t in times if t in self.arrived]
        if samples:
            self.finished = done
            if not self.memory or self.rows - self.memory[-1][0] >= 10_000:
                self.memory.append((self.rows, _rss()))


def _rss() -> float:
    """This process's resident set size, MiB."""
    with open("/proc/self/status") as status:
        return next(int(line.split()[1]) for line in status if line.startswith("VmRSS")) / 1024


READER = """
import json, os, sys, threading, urllib.request
url, pages, tally = sys.argv[1], int(sys.argv[2]), sys.argv[3]
received = [0] * pages

def read(i):
    with urllib.request.urlopen(url + "api/stream", timeout=600) as stream:
        for line in stream:
            if line.startswith(b"data: {\\"t\\""):
                received[i] += len(json.loads(line[6:])["t"])
                with open(tally + ".new", "w") as out:
                    out.write(str(sum(received) / pages))
                os.replace(tally + ".new", tally)  # whole: read at any moment
threads = [threading.Thread(target=read, args=(i,), daemon=True) for i in range(pages)]
for thread in threads:
    thread.start()
for thread in threads:
    thread.join()
"""


class Pages:
    """The page served from the monitor's process, as `monitor --http` serves it, with `pages`
    readers of its live feed in another process (as browsers would hold it open)."""

    def __init__(self, store_path, pages: int, folder: Path):
        self.page = Page(store_path, "127.0.0.1", 0).start()
        self.tally = folder / "pages.txt"
        self.readers = subprocess.Popen([sys.executable, "-c", READER, self.page.url, str(pages), str(self.tally)])

    def stop(self) -> float:
        """Stop the readers and the page; the rows each reader was sent, on average."""
        self.readers.terminate()
        self.readers.wait(30)
        self.page.stop()
        return float(self.tally.read_text()) if self.tally.exists() else 0.0


def publish(port, first, count, rate, names, record, payload) -> subprocess.Popen:
    """The publisher process, sending rows first .. first + count - 1 of the record."""
    return subprocess.Popen([sys.executable, "-c", PUBLISHER, str(port), str(first), str(count), str(rate),
                             ",".join(names), str(record), payload])


def run_until(monitor, rows: int, publisher=None):
    """Run the monitor until it has diagnosed `rows` rows (the last waits for its grace), or made no
    progress for STALL seconds after the publisher ended."""
    stop = threading.Event()

    def watch():
        seen, since = monitor.rows, time.time()
        while monitor.rows < rows:
            time.sleep(0.02)
            if monitor.rows != seen or (publisher is not None and publisher.poll() is None):
                seen, since = monitor.rows, time.time()
            elif time.time() - since > STALL:
                break
        stop.set()
    threading.Thread(target=watch, daemon=True).start()
    return monitor.run(stop)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--payload", choices=("tag", "row"), default="tag",
                        help="one message per tag and row (PREFIX/NAME), or one JSON object per row on PREFIX")
    parser.add_argument("--backlog", type=int, default=20_000, help="rows published while the monitor is down "
                                                                    "(the throughput phase; 0 skips it)")
    parser.add_argument("--rate", type=float, default=300.0, help="rows per second of the latency phase (0 skips it)")
    parser.add_argument("--seconds", type=float, default=60.0, help="how long the latency phase publishes")
    parser.add_argument("--pages", type=int, default=0, metavar="N",
                        help="also serve the operator's page from the monitor's process, with N pages open on its "
                             "live feed (each reading every row the page is sent)")
    parser.add_argument("--profile", action="store_true", help="print where the monitor's time goes")
    parser.add_argument("--keep", action="store_true", help="keep the temporary folder (the store, the broker's "
                                                            "configuration) and say where it is")
    args = parser.parse_args(argv)
    folder = Path(tempfile.mkdtemp(prefix="bench-monitor-"))
    spec = folder / "bank.jmlg"
    spec.write_text(spec_text(SENSORS))
    model = jmlgdsl.load(str(spec))
    live = int(args.rate * args.seconds)
    sim = jmlgdsl.simulate(model, args.backlog + live + 2, seed=1)
    record = folder / "record.npy"
    np.save(record, np.hstack([sim.y, sim.u]))
    del sim  # the publisher reads the record from its file: none of it in the monitor's memory
    names = list(model.outputs) + list(model.inputs)
    tags = read_tags(None, model)
    mosquitto, port = broker(folder)
    store_path = folder / "bank.db"
    profile = cProfile.Profile() if args.profile else None
    page = None
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores (nproc {len(os.sched_getaffinity(0))}), "
          f"Python {platform.python_version()}, {platform.system()} {platform.release()}")
    print(f"{SENSORS}-sensor bank, {len(tags)} tags, "
          f"{'one message per tag and row' if args.payload == 'tag' else 'one message per row'}, IMM filter")

    def monitor(store, latency=False):
        nonlocal page
        source = MqttSource(f"mqtt://127.0.0.1:{port}/bank", model, tags, client_id="jmlgdsl-bench")
        made = Timed(model, store, source, spec=spec.read_text(), options=MonitorOptions(), tags=tags,
                     latency=latency)
        if args.pages and page is None:  # the pages, once the store holds the run they show
            page = Pages(store_path, args.pages, folder)
        return made

    try:
        with Store(store_path) as store:
            first = 1
            if args.backlog:
                run_until(monitor(store), 0)  # the persistent session, then down while the backlog is sent
                started = time.time()
                publish(port, first, args.backlog, 0, names, record, args.payload).wait()
                print(f"backlog: {args.backlog} rows published in {time.time() - started:.1f} s")
                drain = monitor(store)
                if profile:
                    profile.enable()
                stopped = run_until(drain, args.backlog - 1)
                if profile:
                    profile.disable()
                elapsed = drain.finished - drain.started
                print(f"throughput: {stopped.rows} rows in {elapsed:.1f} s: {stopped.rows / elapsed:,.0f} rows/s, "
                      f"{stopped.rows * len(tags) / elapsed:,.0f} tag updates/s"
                      if args.payload == "tag" else
                      f"throughput: {stopped.rows} rows in {elapsed:.1f} s: {stopped.rows / elapsed:,.0f} rows/s")
                print("memory (RSS, MiB) by rows: " + ", ".join(f"{r}: {m:.1f}" for r, m in drain.memory))
                print(f"events: {stopped.events}")
                first = drain.rows + 1
            if args.rate:
                paced = monitor(store, latency=True)
                publisher = publish(port, first, live, args.rate, names, record, args.payload)
                stopped = run_until(paced, first + live - 2, publisher)
                publisher.wait()
                latency = np.array(paced.latencies) * 1000
                print(f"latency at {args.rate:g} rows/s for {args.seconds:g} s ({stopped.rows} rows): median "
                      f"{np.median(latency):.1f} ms, p99 {np.percentile(latency, 99):.1f} ms, max {latency.max():.1f} ms")
            rows = store.db.execute("SELECT count(*) FROM result").fetchone()[0]
            if page is not None:
                print(f"{args.pages} pages open on the live feed, each sent {page.stop():.0f} rows")
    finally:
        mosquitto.terminate()
        mosquitto.wait(30)
    size = store_path.stat().st_size + sum(p.stat().st_size for p in folder.glob("bank.db-*"))
    print(f"store: {size / rows:,.0f} bytes per row ({size / 2**20:.1f} MiB for {rows} rows)")
    if profile:
        pstats.Stats(profile).sort_stats("cumulative").print_stats(25)
    if args.keep:
        print(f"kept {folder}")
    else:
        shutil.rmtree(folder)
    return 0


if __name__ == "__main__":
    sys.exit(main())
