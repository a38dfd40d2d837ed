"""`jmlgdsl monitor` on an OPC UA server (asyncua, started here in a thread on 127.0.0.1): the dryer
recording written to the server's nodes row by row, each value with its source time stamp, is
diagnosed into the store and exported as the very table `jmlgdsl run -o` writes for it, even when the
server comes up only after the monitor, and through an endpoint that signs and encrypts; a monitor
killed with SIGKILL and started again diagnoses no row twice; a wrong password is refused by name."""

import asyncio
import csv
import os
import signal
import sqlite3
import subprocess
import threading
from datetime import datetime, timedelta, timezone

import pytest
from conftest import jmlgdsl_command
from monitor_servers import (DATA, SPEC, WAIT, certificate, exported, expected_table, free_port, query, stop,
                             until)


asyncua = pytest.importorskip("asyncua")
from asyncua import Server, ua  # noqa: E402
from asyncua.crypto.permission_rules import User, UserRole  # noqa: E402

EPOCH = datetime(1970, 1, 1, tzinfo=timezone.utc)
NODES = {"temp": "Dryer.Temp", "current": "Dryer.Current"}


class Passwords:
    """The server's user manager: user 'plant' with password 'secret', nobody else."""

    def get_user(self, iserver, username=None, password=None, certificate=None):
        return User(role=UserRole.User) if (username, password) == ("plant", "secret") else None


class Plant:
    """An asyncua server on 127.0.0.1 in a thread with its own event loop, with a node per dryer tag."""

    def __init__(self, port, password=False, certificate=None):
        self.port, self.password, self.certificate = port, password, certificate
        self.loop = asyncio.new_event_loop()
        self.ready, self.done = threading.Event(), None
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()
        self.call(self._start())

    def call(self, coroutine):
        return asyncio.run_coroutine_threadsafe(coroutine, self.loop).result(WAIT)

    async def _start(self):
        self.server = Server(user_manager=Passwords() if self.password else None)
        await self.server.init()
        self.server.set_endpoint(f"opc.tcp://127.0.0.1:{self.port}/dryer")
        if self.certificate:  # (certificate, key): only an endpoint that signs and encrypts
            await self.server.load_certificate(str(self.certificate[0]))
            await self.server.load_private_key(str(self.certificate[1]))
            self.server.set_security_policy([ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt])
        else:
            self.server.set_security_policy([ua.SecurityPolicyType.NoSecurity])
        if self.password:
            self.server.set_security_IDs(["Username"])
        ns = await self.server.register_namespace("urn:jmlgdsl:test:dryer")
        self.nodes = {name: await self.server.nodes.objects.add_variable(ua.NodeId(node, ns), name, 0.0)
                      for name, node in NODES.items()}
        for node in self.nodes.values():  # no value until the first row is written
            await self.server.write_attribute_value(node.nodeid, ua.DataValue(
                ua.Variant(0.0, ua.VariantType.Double), StatusCode=ua.StatusCode(ua.StatusCodes.BadWaitingForInitialData)))
        await self.server.start()

    def write(self, rows):
        """Each row's current, then its temp, stamped with the row's time."""
        async def write():
            for row in rows:
                stamp = EPOCH + timedelta(seconds=float(row["time"]))
                for name in ("current", "temp"):
                    value = ua.DataValue(ua.Variant(float(row[name]), ua.VariantType.Double), SourceTimestamp=stamp)
                    await self.server.write_attribute_value(self.nodes[name].nodeid, value)
        self.call(write())

    def stop(self):
        async def stop():
            await self.server.stop()
            rest = [task for task in asyncio.all_tasks() if task is not asyncio.current_task()]
            for task in rest:
                task.cancel()
            await asyncio.gather(*rest, return_exceptions=True)
        self.call(stop())
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(WAIT)
        self.loop.close()


@pytest.fixture
def plants():
    started = []

    def start(port=None, password=False, certificate=None):
        started.append(Plant(port or free_port(), password, certificate))
        return started[-1]
    yield start
    for plant in started:
        plant.stop()


@pytest.fixture
def tags(tmp_path):
    path = tmp_path / "tags.toml"
    path.write_text("".join(f'[tags.{name}]\nnode = "ns=2;s={node}"\n' for name, node in NODES.items()))
    return str(path)


def rows():
    with open(DATA) as stream:
        return list(csv.DictReader(stream))


def events(store, kind):
    return lambda: query(store, f"SELECT count(*) FROM event WHERE kind = '{kind}'") or 0


def late_readings(store):
    """The readings the store's late events count: 'a reading ...' or 'N readings (...) ...' each."""
    db = sqlite3.connect(store)
    try:
        details = db.execute("SELECT detail FROM event WHERE kind = 'late'").fetchall()
    finally:
        db.close()
    return sum(1 if detail.startswith("a reading") else int(detail.split()[0]) for detail, in details)


def monitor(port, store, tags, *extra, env=None):
    return subprocess.Popen([*jmlgdsl_command(), "monitor", SPEC, "--source", f"opc.tcp://127.0.0.1:{port}/dryer",
                             "--tags", tags, "--store", store, *extra], stderr=subprocess.PIPE, text=True,
                            env=None if env is None else {**os.environ, **env})


def diagnosed(process, plant, store) -> str:
    """Once the monitor is connected, the recording written to the server's nodes and every row
    stored: the monitor's standard error once stopped."""
    until(lambda: events(store, "connect")() == 1, "the monitor to connect", process)
    plant.write(rows())
    until(lambda: query(store, "SELECT count(*) FROM result") == 1000, "every row stored", process)
    return stop(process)


def test_recording_written_to_nodes_is_diagnosed_as_run_diagnoses_it(plants, tags, tmp_path):
    port, store = free_port(), str(tmp_path / "dryer.db")
    process = monitor(port, store, tags)
    try:
        until(lambda: events(store, "disconnect")() >= 1, "the monitor to find no server", process)
        plant = plants(port)  # the server comes up after the monitor: it is tried again
        err = diagnosed(process, plant, store)
    finally:
        process.kill()
    assert f"monitor: disconnect: cannot reach 127.0.0.1:{port} (" in err and "trying again in 1 s" in err
    assert exported(tmp_path, store) == expected_table(tmp_path)
    kinds = dict(sqlite3.connect(store).execute("SELECT kind, count(*) FROM event WHERE kind != 'disconnect' "
                                                "GROUP BY kind"))
    assert kinds == {"start": 1, "connect": 1}


def test_an_encrypting_endpoint_is_used_with_the_client_certificate_and_refused_without(plants, tags, tmp_path):
    plant = plants(certificate=certificate(tmp_path, "server", "SERVER_AUTH"))
    cert, key = certificate(tmp_path, "monitor", "CLIENT_AUTH")
    store = str(tmp_path / "dryer.db")
    done = subprocess.run([*jmlgdsl_command(), "monitor", SPEC, "--source", f"opc.tcp://127.0.0.1:{plant.port}/dryer",
                           "--tags", tags, "--store", store], capture_output=True, text=True, timeout=WAIT)
    assert done.returncode == 2, done.stderr
    assert (f"error: opc.tcp://127.0.0.1:{plant.port}/dryer: the server has no endpoint with security None; it "
            "offers Basic256Sha256,SignAndEncrypt (see --security, --certificate and --private-key)" in done.stderr)
    process = monitor(plant.port, store, tags, "--security", "Basic256Sha256,SignAndEncrypt",
                      "--certificate", str(cert), "--private-key", str(key))
    try:
        err = diagnosed(process, plant, store)
    finally:
        process.kill()
    assert "nodes, security Basic256Sha256" in err
    assert exported(tmp_path, store) == expected_table(tmp_path)


def test_killed_monitor_diagnoses_no_row_twice(plants, tags, tmp_path):
    plant, store = plants(), str(tmp_path / "dryer.db")
    recording = rows()
    first = monitor(plant.port, store, tags)
    second = None
    try:
        until(lambda: events(store, "connect")() == 1, "the monitor to connect", first)
        plant.write(recording[:600])
        until(lambda: query(store, "SELECT count(*) FROM result") == 600, "600 rows stored", first)
        first.send_signal(signal.SIGKILL)
        first.wait(WAIT)
        second = monitor(plant.port, store, tags)
        # on connecting, the server sends each node's current value: row 600's, diagnosed already (one
        # late event a notification, which may hold both)
        until(lambda: late_readings(store) == 2, "the current values, late", second)
        plant.write(recording[600:])
        until(lambda: query(store, "SELECT count(*) FROM result") == 1000, "every row stored", second)
        stop(second)
    finally:
        for process in (first, second):
            if process is not None:
                process.kill()
    assert query(store, "SELECT count(DISTINCT time) FROM sample") == 1000
    assert exported(tmp_path, store) == expected_table(tmp_path)


def test_wrong_password_is_refused(plants, tags, tmp_path):
    plant, store = plants(password=True), str(tmp_path / "dryer.db")
    secret = tmp_path / "password"
    secret.write_text("wrong\n")
    done = subprocess.run([*jmlgdsl_command(), "monitor", SPEC, "--source", f"opc.tcp://127.0.0.1:{plant.port}/dryer",
                           "--tags", tags, "--store", store, "--username", "plant", "--password-file", str(secret)],
                          capture_output=True, text=True, timeout=WAIT)
    assert done.returncode == 2, done.stderr
    assert (f"error: opc.tcp://127.0.0.1:{plant.port}/dryer: the server refused the connection "
            "(BadUserAccessDenied); check --username and the password" in done.stderr)
    assert "wrong" not in done.stderr
    process = monitor(plant.port, store, tags, "--username", "plant", "--password-env", "PLANT_PASSWORD",
                      env={"PLANT_PASSWORD": "secret"})
    try:
        until(lambda: events(store, "connect")() == 1, "the monitor to connect with the right password", process)
        stop(process)
    finally:
        process.kill()
    assert "secret" not in (query(store, "SELECT group_concat(options) FROM run") or "")
