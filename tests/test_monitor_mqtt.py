"""`jmlgdsl monitor` on a real MQTT broker (Debian's mosquitto, started here on 127.0.0.1): the dryer
recording published as one JSON object per sample is diagnosed into the store and exported as the
very table `jmlgdsl run -o` writes for it; killed with SIGKILL mid-stream, the monitor's persistent
session keeps what is published while it is down, and the restarted monitor loses and repeats no
row; a broker down at start is tried again, and one stopped mid-stream and started again leaves a
gap of missing readings for what could not be published meanwhile; an mqtts:// broker is trusted
through --ca-file and refused by name without it; malformed and late readings are
counted events; a wrong password is refused by name."""

import datetime
import ipaddress
import os
import signal
import sqlite3
import subprocess
import time

import numpy as np
import pytest
from conftest import jmlgdsl_command
from monitor_servers import (MOSQUITTO, NO_MOSQUITTO, SPEC, WAIT, exported, expected_table, free_port, publish, query,
                             samples, stop, until)

from jmlgdsl.monitor.store.databases import SQLite


paho = pytest.importorskip("paho.mqtt.client")
pytestmark = pytest.mark.skipif(MOSQUITTO is None, reason=NO_MOSQUITTO)


def monitor(port, store, *extra, env=None):
    return subprocess.Popen([*jmlgdsl_command(), "monitor", SPEC, "--source", f"mqtt://127.0.0.1:{port}/dryer",
                             "--store", store, *extra], stderr=subprocess.PIPE, text=True,
                            env=None if env is None else {**os.environ, **env})


def connected(store, times=1):
    return lambda: (query(store, "SELECT count(*) FROM event WHERE kind = 'connect'") or 0) >= times


def stored(store, rows):
    return lambda: query(store, "SELECT count(*) FROM result") == rows


def test_published_recording_is_diagnosed_as_run_diagnoses_it(broker, tmp_path):
    port, store = broker(), str(tmp_path / "dryer.db")
    process = monitor(port, store)
    try:
        until(connected(store), "the monitor to connect", process)
        publish(port, samples() + [("dryer/temp", "hot"), ("dryer/current", "1e300"),
                                   ("dryer/temp", '{"t": 5, "v": 50.1}')])
        until(lambda: query(store, "SELECT count(*) FROM event WHERE kind IN ('late', 'malformed')") == 3,
              "the late and malformed readings", process)
        err = stop(process)
    finally:
        process.kill()
    assert exported(tmp_path, store) == expected_table(tmp_path)
    kinds = dict(sqlite3.connect(store).execute("SELECT kind, count(*) FROM event GROUP BY kind"))
    assert kinds == {"start": 1, "connect": 1, "malformed": 2, "late": 1}
    assert "monitor: malformed: topic dryer/temp: temp: payload 'hot' is neither a number nor JSON" in err
    assert "1000 rows diagnosed in run 1" in err


def test_bad_messages_cost_only_themselves_and_are_not_delivered_again(broker, tmp_path):
    """A stamp in the year 9999, a bare value stamped on arrival in a stream of stamped readings,
    brackets nested 5,000 deep and a 400-digit time, each published once mid-stream: each one event,
    every other row diagnosed as `run -o` diagnoses the recording; the network thread lives on, and
    the bad messages, acknowledged, are not delivered again to the monitor started after it."""
    port, store = broker(), str(tmp_path / "dryer.db")
    messages = samples()
    bad = ['{"t": "9999-12-31T23:59:59Z", "temp": 50.0}', ("dryer/temp", "50.6"), "[" * 5000,
           '{"t": 1' + "0" * 399 + ', "temp": 50.0}']
    process = monitor(port, store)
    try:
        until(connected(store), "the monitor to connect", process)
        publish(port, messages[:500] + bad + messages[500:])
        until(stored(store, 1000), "every row stored", process)
        stop(process)
    finally:
        process.kill()
    assert exported(tmp_path, store) == expected_table(tmp_path)
    events = "SELECT kind, count(*) FROM event WHERE kind IN ('future', 'malformed', 'ahead', 'late') GROUP BY kind"
    assert dict(sqlite3.connect(store).execute(events)) == {"future": 1, "malformed": 3}
    again = monitor(port, store)
    try:
        until(connected(store, 2), "the monitor to connect again", again)
        time.sleep(1)  # what the broker had not seen acknowledged it delivers at once
        stop(again)
    finally:
        again.kill()
    assert dict(sqlite3.connect(store).execute(events)) == {"future": 1, "malformed": 3}


def test_killed_monitor_resumes_from_its_persistent_session(broker, tmp_path):
    port, store = broker(), str(tmp_path / "dryer.db")
    messages = samples()
    first = monitor(port, store)
    second = None
    try:
        until(connected(store), "the monitor to connect", first)
        publish(port, messages[:600])
        until(lambda: (query(store, "SELECT count(*) FROM result") or 0) >= 300, "300 rows stored", first)
        first.send_signal(signal.SIGKILL)
        first.wait(WAIT)
        publish(port, messages[600:])  # while the monitor is down: the broker keeps them for its session
        second = monitor(port, store)
        until(lambda: query(store, "SELECT count(*) FROM result") == 1000, "every row stored", second)
        err = stop(second)
    finally:
        for process in (first, second):
            if process is not None:
                process.kill()
    assert "resumed its session" in err
    assert exported(tmp_path, store) == expected_table(tmp_path)
    assert query(store, "SELECT count(*) FROM sample") == 1000


def test_wrong_password_is_refused(broker, tmp_path):
    port, store = broker(password=True), str(tmp_path / "dryer.db")
    secret = tmp_path / "password"
    secret.write_text("wrong\n")
    done = subprocess.run([*jmlgdsl_command(), "monitor", SPEC, "--source", f"mqtt://127.0.0.1:{port}/dryer",
                           "--store", store, "--username", "plant", "--password-file", str(secret)],
                          capture_output=True, text=True, timeout=WAIT)
    assert done.returncode == 2
    assert (f"error: mqtt://127.0.0.1:{port}/dryer: the broker refused the connection (Not authorized); check "
            "--username and the password" in done.stderr)
    assert "wrong" not in done.stderr
    process = monitor(port, store, "--username", "plant", "--password-env", "PLANT_PASSWORD",
                      env={"PLANT_PASSWORD": "secret"})
    try:
        until(connected(store), "the monitor to connect with the right password", process)
        stop(process)
    finally:
        process.kill()
    assert "secret" not in (query(store, "SELECT group_concat(options) FROM run") or "")


def test_broker_down_at_start_is_tried_again(broker, tmp_path):
    port, store = free_port(), str(tmp_path / "dryer.db")
    process = monitor(port, store)
    try:
        until(lambda: (query(store, "SELECT count(*) FROM event WHERE kind = 'disconnect'") or 0) >= 3,
              "the monitor to find no broker three times", process)
        broker(port=port)
        until(connected(store), "the monitor to connect", process)
        publish(port, samples())
        until(stored(store, 1000), "every row stored", process)
        err = stop(process)
    finally:
        process.kill()
    for delay in (1, 2, 4):  # each attempt says when the next is, as paho's waits double
        assert (f"monitor: disconnect: cannot reach 127.0.0.1:{port} ([Errno 111] Connection refused); trying "
                f"again in {delay} s\n") in err
    assert exported(tmp_path, store) == expected_table(tmp_path)


def test_broker_stopped_mid_stream_leaves_a_gap(broker, tmp_path):
    """The broker (without persistence) forgets the session when it stops, and what the plant could not
    publish meanwhile never arrives: the rows of the outage are a gap of missing readings."""
    port, store = broker(), str(tmp_path / "dryer.db")
    messages = samples()
    process = monitor(port, store)
    try:
        until(connected(store), "the monitor to connect", process)
        publish(port, messages[:500])
        until(stored(store, 500), "500 rows stored", process)
        broker.stop(port)
        until(lambda: (query(store, "SELECT count(*) FROM event WHERE kind = 'disconnect'") or 0) >= 1,
              "the lost connection", process)
        broker(port=port)  # rows 501 to 600 were not published while it was down
        until(connected(store, 2), "the monitor to connect again", process)
        publish(port, messages[600:])
        until(stored(store, 1000), "every row stored", process)
        stop(process)
    finally:
        process.kill()
    db = sqlite3.connect(store)
    # the first two samples after the outage came 100 s ahead of the stream and were held; the third
    # showed it had moved on, and the three were used
    assert dict(db.execute("SELECT kind, count(*) FROM event WHERE kind != 'disconnect' GROUP BY kind")) == {
        "start": 1, "connect": 2, "stale": 2, "gap": 1, "fresh": 2, "ahead": 2, "jump": 1}
    assert db.execute("SELECT detail FROM event WHERE kind = 'gap'").fetchall() == [
        ("no readings for 100 s from 501 s: 100 rows of missing readings",)]
    # a broker stopped cleanly: said in words (paho's own words are 'Unspecified error'), and when it is tried
    assert db.execute("SELECT detail FROM event WHERE kind = 'disconnect' ORDER BY id LIMIT 1").fetchone()[0] == (
        f"lost the connection to 127.0.0.1:{port} (the broker closed the connection: it stopped or restarted, or "
        "the network between dropped it); reconnecting in 1 s")
    unmeasured = [time for time, y in db.execute("SELECT time, y FROM sample") if np.isnan(SQLite.unvector(y, 1)).all()]
    assert (min(unmeasured), max(unmeasured), len(set(unmeasured))) == (501.0, 600.0, 100)
    assert db.execute("SELECT count(*), count(DISTINCT time) FROM sample").fetchone() == (1000, 1000)
    expected = expected_table(tmp_path).splitlines()
    assert exported(tmp_path, store).splitlines()[:501] == expected[:501]


def certificates(folder):
    """A certificate authority and a server certificate for 127.0.0.1 that it signed: (ca, cert, key) files."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    def name(text):
        return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, text)])

    def signed(subject, key, issuer, issuer_key, ca):
        now = datetime.datetime.now(datetime.timezone.utc)
        builder = (x509.CertificateBuilder().subject_name(name(subject)).issuer_name(name(issuer))
                   .public_key(key.public_key()).serial_number(x509.random_serial_number())
                   .not_valid_before(now - datetime.timedelta(minutes=5)).not_valid_after(now + datetime.timedelta(days=1))
                   .add_extension(x509.BasicConstraints(ca=ca, path_length=None), critical=True))
        if not ca:
            builder = builder.add_extension(x509.SubjectAlternativeName(
                [x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]), critical=False)
        return builder.sign(issuer_key, hashes.SHA256())

    ca_key, server_key = ec.generate_private_key(ec.SECP256R1()), ec.generate_private_key(ec.SECP256R1())
    ca = signed("jmlgdsl test authority", ca_key, "jmlgdsl test authority", ca_key, True)
    server = signed("127.0.0.1", server_key, "jmlgdsl test authority", ca_key, False)
    files = folder / "ca.pem", folder / "server.pem", folder / "server.key"
    files[0].write_bytes(ca.public_bytes(serialization.Encoding.PEM))
    files[1].write_bytes(server.public_bytes(serialization.Encoding.PEM))
    files[2].write_bytes(server_key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                                  serialization.NoEncryption()))
    return tuple(str(f) for f in files)


def test_mqtts_broker_is_trusted_through_its_certificate_authority(broker, tmp_path):
    ca, cert, key = certificates(tmp_path)
    port, store = broker(tls=(cert, key)), str(tmp_path / "dryer.db")
    url = f"mqtts://127.0.0.1:{port}/dryer"
    done = subprocess.run([*jmlgdsl_command(), "monitor", SPEC, "--source", url, "--store", store],
                          capture_output=True, text=True, timeout=WAIT)
    assert done.returncode == 2
    assert (f"error: {url}: the broker's certificate is not trusted (unable to get local issuer certificate); "
            "give the certificate authority that signed it with --ca-file") in done.stderr
    process = subprocess.Popen([*jmlgdsl_command(), "monitor", SPEC, "--source", url, "--store", store, "--ca-file",
                                ca], stderr=subprocess.PIPE, text=True)
    try:
        until(connected(store), "the monitor to connect over TLS", process)
        publish(port, samples(), ca_file=ca)
        until(stored(store, 1000), "every row stored", process)
        stop(process)
    finally:
        process.kill()
    assert exported(tmp_path, store) == expected_table(tmp_path)


def test_a_message_of_an_earlier_connection_is_left_for_its_copy_on_this_one(monkeypatch):
    """A packet id names a message on its connection only: once the broker has it acknowledged, it
    gives the id to the next message. A commit that holds a message which came before a reconnection
    must not acknowledge that id on the new connection (it could be another message, not yet
    committed); the broker sends the message again on the new connection, and that copy's token is
    the one acknowledged."""
    import types

    import jmlgdsl
    from jmlgdsl.monitor.sources import mqtt as source_module

    class Client:  # paho's side of the connection, played by hand
        def __init__(self):
            self.acked = []

        def __getattr__(self, name):  # connect_async, loop_start, subscribe, manual_ack_set, ...
            return lambda *args, **kwargs: None

        def ack(self, mid, qos):
            self.acked.append(mid)

    client = Client()
    monkeypatch.setattr(source_module, "paho_client", lambda *args, **kwargs: client)
    source = source_module.MqttSource("mqtt://127.0.0.1:1883/dryer", jmlgdsl.load(SPEC), {}, client_id="test")
    items = []
    source.start(items.append, None)
    up = types.SimpleNamespace(is_failure=False)
    resumed = types.SimpleNamespace(session_present=True)

    def message(mid):
        return types.SimpleNamespace(mid=mid, qos=1, topic="dryer/temp", payload=b"50.1")

    client.on_connect(client, None, resumed, up, None)
    client.on_message(client, None, message(7))
    client.on_connect(client, None, resumed, up, None)  # the connection dropped and came back
    client.on_message(client, None, message(7))  # the broker's copy, on the new connection
    first, copy = [item.token for item in items if hasattr(item, "token")]
    source.acknowledge([first])
    assert client.acked == []
    source.acknowledge([copy])
    assert client.acked == [7]
