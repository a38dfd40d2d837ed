"""What the monitor's tests against live servers share: the bundled dryer recording, free ports on
127.0.0.1, mosquitto brokers and a publisher, a webhook receiver, OPC UA certificates, bounded
waits on a running monitor, queries of its store, and the tables to compare. The fixtures that
start them (broker, dryer_store, store, page) are conftest.py's, so a test names them without an
import."""

import asyncio
import csv
import getpass
import http.server
import json
import os
import shutil
import signal
import socket
import sqlite3
import subprocess
import threading
import time

import pytest
from conftest import ROOT

from jmlgdsl.cli import main

SPEC = str(ROOT / "specs" / "dryer.jmlg")
DATA = ROOT / "examples" / "dryer_seq1.csv"
LINES = DATA.read_text().splitlines(keepends=True)  # the header and 1000 rows
WAIT = 30  # seconds any one wait may take before the test fails


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def query(store, sql):
    if not os.path.exists(store):
        return None
    db = sqlite3.connect(store)
    try:
        return db.execute(sql).fetchone()[0]
    except sqlite3.OperationalError:
        return None
    finally:
        db.close()


def until(condition, what, process):
    deadline = time.monotonic() + WAIT
    while not condition():
        if process.poll() is not None:
            pytest.fail(f"the monitor stopped while waiting for {what}: {process.stderr.read()}")
        assert time.monotonic() < deadline, f"gave up waiting for {what}"
        time.sleep(0.02)


def killed_mid_file(command, data, stored, env=None) -> str:
    """A monitor (`command`, following the file `data`, with --lag 2) while the dryer recording is
    appended to that file, killed with SIGKILL mid-file and started again with the same command as
    the file goes on growing: the restarted monitor's standard error once it has stored every row
    but the 2 its lag holds back, and it was stopped. `stored()` counts the rows in the store."""
    data.write_text("".join(LINES[:301]))
    killed, done = threading.Event(), threading.Event()

    def grow():  # the plant's logger: ten rows every 10 ms, going on through the kill and the restart
        with open(data, "a") as out:
            for start in range(301, 1001, 10):
                if start == 701:
                    killed.wait(WAIT)
                out.writelines(LINES[start:start + 10])
                out.flush()
                if done.wait(0.01):
                    return
    writer = threading.Thread(target=grow)
    first = subprocess.Popen(command, stderr=subprocess.PIPE, text=True, env=env)
    second = None
    try:
        until(lambda: stored() >= 200, "the first monitor to store 200 rows", first)
        writer.start()
        until(lambda: stored() >= 500, "the first monitor to store 500 rows", first)
        first.send_signal(signal.SIGKILL)
        first.wait(WAIT)
        assert stored() < 700  # mid-file
        killed.set()
        second = subprocess.Popen(command, stderr=subprocess.PIPE, text=True, env=env)
        until(lambda: stored() == 1000 - 2, "the restarted monitor to store every row", second)
        err = stop(second)
        writer.join(WAIT)
    finally:
        killed.set()
        done.set()
        for process in (first, second):
            if process is not None and process.poll() is None:
                process.kill()
    return err


def stop(process):
    process.send_signal(signal.SIGTERM)
    _, err = process.communicate(timeout=WAIT)
    assert process.returncode == 0, err
    return err


def expected_table(tmp_path):
    out = tmp_path / "run.csv"
    assert main(["run", SPEC, str(DATA), "-o", str(out)]) == 0
    return out.read_text()


def exported(tmp_path, store):
    out = tmp_path / "export.csv"
    assert main(["export", store, "-o", str(out)]) == 0
    return out.read_text()


MOSQUITTO = shutil.which("mosquitto") or next(
    (p for p in ("/usr/sbin/mosquitto",) if os.access(p, os.X_OK)), None)
NO_MOSQUITTO = "no mosquitto broker on PATH (.ci/run installs it: apt-get install mosquitto)"


class Brokers:
    """Mosquittos on 127.0.0.1, each on its own port (anonymous, or with user 'plant' and password
    'secret' when asked), stopped and started again on the same port when a test says so."""

    def __init__(self, folder):
        self.folder, self.running = folder, {}

    def __call__(self, password=False, port=None, tls=None, persistent=False):
        """Start one; `tls`: (certificate file, key file) of a TLS listener; `persistent`: it saves its
        sessions and the messages they hold when stopped, in the folder, and takes them up again when
        started again on the same port."""
        port = port or free_port()
        config = self.folder / f"mosquitto-{port}.conf"
        # run as this user (a broker started by root would drop to 'mosquitto', who cannot read the folder)
        lines = [f"listener {port} 127.0.0.1", f"user {getpass.getuser()}", "max_queued_messages 0"]
        lines += ["persistence true", f"persistence_location {self.folder}/",
                  f"persistence_file mosquitto-{port}.db"] if persistent else ["persistence false"]
        if tls:
            lines += [f"certfile {tls[0]}", f"keyfile {tls[1]}"]
        if password:
            passwords = self.folder / "passwords"
            passwords.write_text("")
            subprocess.run(["mosquitto_passwd", "-b", str(passwords), "plant", "secret"], check=True, timeout=WAIT)
            lines += ["allow_anonymous false", f"password_file {passwords}"]
        else:
            lines.append("allow_anonymous true")
        config.write_text("\n".join(lines) + "\n")
        process = subprocess.Popen([MOSQUITTO, "-c", str(config)], stdout=subprocess.DEVNULL,
                                   stderr=subprocess.DEVNULL)
        self.running[port] = process
        deadline = time.monotonic() + WAIT
        while True:
            try:
                socket.create_connection(("127.0.0.1", port), timeout=1).close()
                return port
            except OSError:
                assert process.poll() is None and time.monotonic() < deadline, "mosquitto did not start"
                time.sleep(0.02)

    def stop(self, port):
        process = self.running.pop(port)
        process.terminate()
        process.wait(WAIT)


def samples():
    """The recording as one JSON object per sample, every number as the file writes it."""
    with open(DATA) as stream:
        return [json.dumps({"t": float(r["time"]), "temp": float(r["temp"]), "current": float(r["current"])})
                for r in csv.DictReader(stream)]


def publish(port, messages, topic="dryer", ca_file=None):
    """Publish (topic, payload) pairs, or payloads to `topic`, at QoS 1, each one acknowledged (over TLS
    trusting `ca_file` when given)."""
    import paho.mqtt.client as paho

    client = paho.Client(paho.CallbackAPIVersion.VERSION2, client_id="recorder")
    if ca_file:
        client.tls_set(ca_certs=ca_file)
    client.connect("127.0.0.1", port)
    client.loop_start()
    try:
        sent = [client.publish(*(m if isinstance(m, tuple) else (topic, m)), qos=1) for m in messages]
        for info in sent:
            info.wait_for_publish(WAIT)
    finally:
        client.disconnect()
        client.loop_stop()


def certificate(folder, name, use):
    """A self-signed certificate (DER) and its private key (PEM) for 127.0.0.1, for OPC UA's `use`
    (SERVER_AUTH, CLIENT_AUTH)."""
    from asyncua.crypto.cert_gen import setup_self_signed_certificate
    from cryptography.x509.oid import ExtendedKeyUsageOID

    cert, key = folder / f"{name}.der", folder / f"{name}.pem"
    asyncio.run(setup_self_signed_certificate(key, cert, f"urn:jmlgdsl:test:{name}", "127.0.0.1",
                                              [getattr(ExtendedKeyUsageOID, use)], {"commonName": name}))
    return cert, key


class Receiver:
    """A webhook receiver on 127.0.0.1 (http.server in a thread) that keeps each POST's JSON body."""

    def __init__(self, port=None):
        posts = self.posts = []

        class Handler(http.server.BaseHTTPRequestHandler):
            def do_POST(self):
                body = self.rfile.read(int(self.headers["Content-Length"]))
                posts.append((self.headers["Content-Type"], json.loads(body)))
                self.send_response(204)
                self.end_headers()

            def log_message(self, *args):
                pass

        self.server = http.server.ThreadingHTTPServer(("127.0.0.1", port or 0), Handler)
        self.port = self.server.server_address[1]
        self.thread = threading.Thread(target=self.server.serve_forever, daemon=True)
        self.thread.start()

    def transitions(self):
        return [(body["alarm"], body["transition"]) for _, body in self.posts]

    def close(self):
        self.server.shutdown()
        self.server.server_close()
