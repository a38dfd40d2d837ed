"""Throughput, latency, memory and store size of `jmlgdsl monitor` over MQTT (BENCHMARKS.md).

    python benchmarks/bench_monitor.py                       # 180 s of a 20-sensor bank
    python benchmarks/bench_monitor.py --seconds 30 --profile

A spec of 20 temperatures driven by one heater current (two modes) is written to a temporary
folder, a mosquitto (from PATH or /usr/sbin) is started on 127.0.0.1, and a publisher process sends
one message per tag and row (`{"t": ..., "v": ...}` on PREFIX/NAME, QoS 1) as fast as the broker
takes them. The monitor runs in this process on the IMM filter, so its time stamps are exact: a
row's latency runs from the arrival of its last reading to the end of the store commit that holds
its posterior. Memory is this process's resident set size, sampled as rows are committed.
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
from jmlgdsl.monitor import Monitor, Store, monitor_options, read_tags
from jmlgdsl.monitor.mqtt import MqttSource

SENSORS = 20

PUBLISHER = """
import json, sys, time
import paho.mqtt.client as mqtt
port, seconds, names = int(sys.argv[1]), float(sys.argv[2]), sys.argv[3].split(",")
client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="bench-publisher")
client.max_inflight_messages_set(1000)
client.max_queued_messages_set(0)
client.connect("127.0.0.1", port)
client.loop_start()
end, t, last = time.monotonic() + seconds, 0, None
while time.monotonic() < end:
    t += 1
    for i, name in enumerate(names):
        value = 15.0 if name == "current" else 50.0 + i + 0.1 * ((t * 7919 + i) % 13)
        last = client.publish("bank/" + name, json.dumps({"t": t, "v": value}), qos=1)
    if t % 50 == 0:
        last.wait_for_publish(30)  # keep the broker's pace, not the client's buffer's
last.wait_for_publish(30)
print(t)
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
    config.write_text(f"listener {port} 127.0.0.1\nuser {getpass.getuser()}\npersistence false\n"
                      "max_queued_messages 0\nmax_inflight_messages 0\nallow_anonymous true\n")
    process = subprocess.Popen([mosquitto, "-c", str(config)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    for _ in range(500):
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1).close()
            return process, port
        except OSError:
            time.sleep(0.02)
    raise SystemExit("mosquitto did not start")


class Timed(Monitor):
    """The monitor with time stamps: each row's last reading's arrival and its commit's end."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.arrived, self.latencies, self.memory = {}, [], []
        self.started = None

    def _handle(self, item):
        if item[0] == "readings":
            self.started = self.started or time.time()
            for _, _, stamp in item[1]:
                self.arrived[stamp] = item[2]
        return super()._handle(item)

    def commit(self):
        times = [row.time for _, row in self.samples]
        super().commit()
        done = time.time()
        self.latencies += [done - self.arrived.pop(t) for t in times if t in self.arrived]
        if times and (not self.memory or self.rows - self.memory[-1][0] >= 10_000):
            self.memory.append((self.rows, _rss()))


def _rss() -> float:
    """This process's resident set size, MiB."""
    with open("/proc/self/status") as status:
        return next(int(line.split()[1]) for line in status if line.startswith("VmRSS")) / 1024


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=180.0, help="how long the publisher publishes")
    parser.add_argument("--profile", action="store_true", help="print where the monitor's time goes")
    args = parser.parse_args(argv)
    folder = Path(tempfile.mkdtemp(prefix="bench-monitor-"))
    spec = folder / "bank.jmlg"
    spec.write_text(spec_text(SENSORS))
    model = jmlgdsl.load(str(spec))
    tags = read_tags(None, model)
    mosquitto, port = broker(folder)
    store_path = folder / "bank.db"
    try:
        with Store(store_path) as store:
            source = MqttSource(f"mqtt://127.0.0.1:{port}/bank", model, tags, client_id="jmlgdsl-bench")
            monitor = Timed(model, store, source, spec=spec.read_text(), options=monitor_options(), tags=tags)
            stop = threading.Event()
            names = ",".join(list(model.outputs) + list(model.inputs))
            publisher = subprocess.Popen([sys.executable, "-c", PUBLISHER, str(port), str(args.seconds), names],
                                         stdout=subprocess.PIPE, text=True)

            def watch():
                """Stop the monitor once it has every row published (the last two wait for their grace),
                or has made no progress for 10 s."""
                published = int(publisher.communicate()[0])
                seen, since = monitor.rows, time.time()
                while monitor.rows < published - 2 and time.time() - since < 10:
                    time.sleep(0.05)
                    if monitor.rows != seen:
                        seen, since = monitor.rows, time.time()
                stop.set()
            threading.Thread(target=watch, daemon=True).start()
            profile = cProfile.Profile() if args.profile else None
            if profile:
                profile.enable()
            stopped = monitor.run(stop)
            if profile:
                profile.disable()
            elapsed = time.time() - monitor.started
    finally:
        mosquitto.terminate()
        mosquitto.wait(30)
    rows = stopped.rows
    latency = np.array(monitor.latencies) * 1000
    size = store_path.stat().st_size + sum(p.stat().st_size for p in folder.glob("bank.db-*"))
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores (nproc {len(os.sched_getaffinity(0))}), "
          f"Python {platform.python_version()}, {platform.system()} {platform.release()}")
    print(f"{SENSORS}-sensor bank, {len(tags)} tags, one message per tag and row, IMM filter, {args.seconds:g} s")
    print(f"rows {rows}, {elapsed:.1f} s: {rows / elapsed:,.0f} rows/s, {rows * len(tags) / elapsed:,.0f} tag updates/s")
    print(f"latency, last reading to committed posterior: median {np.median(latency):.1f} ms, "
          f"p99 {np.percentile(latency, 99):.1f} ms, max {latency.max():.1f} ms")
    print("memory (RSS, MiB) by rows: " + ", ".join(f"{r}: {m:.1f}" for r, m in monitor.memory))
    print(f"store: {size / rows:,.0f} bytes per row ({size / 2**20:.1f} MiB); events {stopped.events}")
    if profile:
        pstats.Stats(profile).sort_stats("cumulative").print_stats(25)
    shutil.rmtree(folder)
    return 0


if __name__ == "__main__":
    sys.exit(main())
