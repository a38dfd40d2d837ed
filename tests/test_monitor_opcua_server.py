"""`jmlgdsl monitor --opcua-server`: an asyncua client of the monitor's own OPC UA server (on
127.0.0.1) reads the mode and every mode's probability, receives each alarm transition as an Alarms
& Conditions event, and acknowledges and shelves alarms through the conditions' methods: the actions
are in the store as the page's are, and the page shows them. A wrong password is refused; a server
started again on a store shows its state at once, through an endpoint that signs and encrypts; a
port taken stops the monitor with a message."""

import asyncio
import json
import os
import socket
import sqlite3
import subprocess
import time

import pytest
from conftest import jmlgdsl_command
from monitor_servers import LINES, SPEC, WAIT, certificate, free_port, stop

from jmlgdsl.cli import main
from jmlgdsl.monitor import Store
from jmlgdsl.monitor.store.databases import SQLite
from jmlgdsl.page import views

asyncua = pytest.importorskip("asyncua")
from asyncua import Client, ua  # noqa: E402

NAMESPACE = "urn:jmlgdsl:diagnosis"
OFF_NORMAL = ua.ObjectIds.OffNormalAlarmType
ACKNOWLEDGE = ua.NodeId(ua.ObjectIds.AcknowledgeableConditionType_Acknowledge)
ONE_SHOT_SHELVE2 = ua.NodeId(ua.ObjectIds.ShelvedStateMachineType_OneShotShelve2)
ONE_SHOT_SHELVED = ua.NodeId(ua.ObjectIds.ShelvedStateMachineType_OneShotShelved)


def monitor(data, store, port, *extra, env=None):
    return subprocess.Popen([*jmlgdsl_command(), "monitor", SPEC, "--source", str(data), "--store", store,
                             "--opcua-server", f"opc.tcp://127.0.0.1:{port}/jmlgdsl", *extra],
                            stderr=subprocess.PIPE, text=True, env=env)


class Events:
    """A subscription's handler that keeps every event."""

    def __init__(self):
        self.received = []

    def event_notification(self, event):
        self.received.append(event)


def summary(event):
    """(condition, active, acknowledged, retained) of an alarm's event."""
    return (event.ConditionName, getattr(event, "ActiveState/Id"), getattr(event, "AckedState/Id"), event.Retain)


async def waiting(condition, what, process):
    deadline = time.monotonic() + WAIT
    while not await condition():
        if process.poll() is not None:
            pytest.fail(f"the monitor stopped while waiting for {what}: {process.stderr.read()}")
        assert time.monotonic() < deadline, f"gave up waiting for {what}"
        await asyncio.sleep(0.05)


async def connect(port, process, user=None, password=None, security=None) -> Client:
    """A client connected to the monitor's server once it serves."""
    client = None

    async def connected():
        nonlocal client
        client = Client(f"opc.tcp://127.0.0.1:{port}/jmlgdsl", timeout=WAIT)
        if user:
            client.set_user(user)
            client.set_password(password)
        try:
            if security:  # (which asks the server for its certificate)
                await client.set_security_string(security)
            await client.connect()
            return True
        except (OSError, asyncio.TimeoutError):
            return False
    await waiting(connected, "the monitor's OPC UA server", process)
    return client


async def value(client, name):
    ns = await client.get_namespace_index(NAMESPACE)
    return await client.get_node(f"ns={ns};s=dryer.{name}").read_value()


def newest(store):
    """The store's newest row: (t, its mode, {mode: probability})."""
    db = sqlite3.connect(store)
    modes = json.loads(db.execute("SELECT modes FROM run").fetchone()[0])
    t, mode, posterior = db.execute("SELECT t, map_mode, posterior FROM result ORDER BY t DESC LIMIT 1").fetchone()
    return t, mode, dict(zip(modes, SQLite.unvector(posterior, len(modes)).tolist()))


def test_a_client_reads_the_mode_receives_the_alarms_and_acknowledges_one(tmp_path):
    data, store, port = tmp_path / "dryer.csv", str(tmp_path / "dryer.db"), free_port()
    data.write_text("".join(LINES[:51]))  # 50 rows, before the first alarm (row 72)
    process = monitor(data, store, port, "--opcua-server-username", "plant", "--opcua-server-password-env",
                      "SERVER_PASSWORD", env={**os.environ, "SERVER_PASSWORD": "secret"})

    async def client_side():
        client = await connect(port, process, "plant", "secret")
        try:
            with pytest.raises(ua.UaStatusCodeError, match="BadUserAccessDenied"):
                wrong = Client(f"opc.tcp://127.0.0.1:{port}/jmlgdsl", timeout=WAIT)
                wrong.set_user("plant")
                wrong.set_password("wrong")
                await wrong.connect()
            await waiting(lambda: _at(client, 50), "row 50 on the server", process)
            events = Events()
            subscription = await client.create_subscription(50, events)
            await subscription.subscribe_alarms_and_conditions(client.nodes.server, OFF_NORMAL)
            with open(data, "a") as out:
                out.writelines(LINES[51:])
            await waiting(lambda: _at(client, 1000), "row 1000 on the server", process)
            await waiting(lambda: _true(len(events.received) == 5), "the alarms' events", process)
            t, mode, modes = newest(store)
            shown = {name: await value(client, f"Modes.{name}") for name in modes}
            state = (await value(client, "Mode"), await value(client, "Probability"), await value(client, "Alarm"),
                     await value(client, "AlarmId"))
            raised = events.received[4]
            condition = client.get_node(raised.NodeId)
            await condition.call_method(ACKNOWLEDGE, ua.Variant(raised.EventId, ua.VariantType.ByteString),
                                        ua.LocalizedText("seen on the HMI"))
            await waiting(lambda: _true(len(events.received) == 6), "the acknowledgement's event", process)
            with pytest.raises(ua.UaStatusCodeError, match="BadConditionBranchAlreadyAcked"):
                await condition.call_method(ACKNOWLEDGE, ua.Variant(raised.EventId, ua.VariantType.ByteString),
                                            ua.LocalizedText("again"))
            acked = await client.get_node(f"{raised.NodeId.to_string()}.AckedState.Id").read_value()
            first = client.get_node(f"{events.received[0].NodeId.to_string()}.ShelvingState")
            with pytest.raises(ua.UaStatusCodeError, match="BadInvalidArgument"):  # shelving needs a reason
                await first.call_method("OneShotShelve")
            await first.call_method(ONE_SHOT_SHELVE2, ua.LocalizedText("fan under repair"))
            await waiting(lambda: _true(len(events.received) == 7), "the shelving's event", process)
            return events.received, shown, state, acked, (t, mode, modes)
        finally:
            await client.disconnect()

    try:
        received, shown, state, acked, (t, mode, modes) = asyncio.run(client_side())
        stop(process)
    finally:
        process.kill()
    assert [summary(e) for e in received[:5]] == [
        ("Alarm1", True, False, True), ("Alarm1", False, False, True), ("Alarm2", True, False, True),
        ("Alarm2", False, False, True), ("Alarm3", True, False, True)]
    assert received[0].Message.Text == "dryer: alarm 1 (fan) raised; now active, unacknowledged"
    assert shown == modes and state == (mode, modes[mode], True, 3) and t == 1000
    assert summary(received[5]) == ("Alarm3", True, True, True) and acked is True
    assert (received[5].ClientUserId, received[5].Comment.Text) == ("plant", "seen on the HMI")
    assert (received[6].ConditionName, getattr(received[6], "ShelvingState/CurrentState/Id")) == (
        "Alarm1", ONE_SHOT_SHELVED)
    with Store(store) as opened:  # what the page shows
        alarms = {a["id"]: a for a in views.alarms(opened, opened.run())}
    assert (alarms[3]["state"], alarms[3]["acknowledged"]["who"]) == ("active, acknowledged", "plant")
    assert alarms[1]["state"] == "shelved" and alarms[1]["shelved"]["who"] == "plant"
    assert alarms[1]["shelved"]["reason"] == "fan under repair"
    assert sqlite3.connect(store).execute("SELECT reason FROM action WHERE kind = 'acknowledge'").fetchall() == [
        ("seen on the HMI",)]


def test_a_server_started_again_shows_the_store_at_once_over_an_encrypting_endpoint(tmp_path):
    data, store, port = tmp_path / "dryer.csv", str(tmp_path / "dryer.db"), free_port()
    data.write_text("".join(LINES))
    assert main(["monitor", SPEC, "--source", str(data), "--store", store, "--no-follow"]) == 0
    with Store(store) as opened:
        opened.act(1, 2, "acknowledge", "ann")  # alarm 2: cleared and acknowledged, done
    server_cert, server_key = certificate(tmp_path, "server", "SERVER_AUTH")
    client_cert, client_key = certificate(tmp_path, "client", "CLIENT_AUTH")
    process = monitor(data, store, port, "--opcua-server-security", "Basic256Sha256,SignAndEncrypt",
                      "--opcua-server-certificate", str(server_cert), "--opcua-server-private-key", str(server_key))

    async def client_side():
        client = await connect(port, process, security=f"Basic256Sha256,SignAndEncrypt,{client_cert},{client_key}")
        try:
            t = await value(client, "T")
            events = Events()
            subscription = await client.create_subscription(50, events)
            await subscription.subscribe_alarms_and_conditions(client.nodes.server, OFF_NORMAL)
            await client.get_node(ua.ObjectIds.ConditionType).call_method(
                ua.NodeId(ua.ObjectIds.ConditionType_ConditionRefresh),
                ua.Variant(subscription.subscription_id, ua.VariantType.UInt32))
            await waiting(lambda: _true(len(events.received) >= 2), "the conditions", process)
            shelving = client.get_node(f"{events.received[0].NodeId.to_string()}.ShelvingState")
            with pytest.raises(ua.UaStatusCodeError, match="BadNotSupported"):
                await shelving.call_method("TimedShelve", ua.Variant(60_000.0, ua.VariantType.Double))
            with pytest.raises(ua.UaStatusCodeError, match="BadConditionNotShelved"):
                await shelving.call_method("Unshelve")
            return t, events.received
        finally:
            await client.disconnect()

    try:
        t, received = asyncio.run(client_side())
        err = stop(process)
    finally:
        process.kill()
    assert t == 1000
    assert sorted(summary(e) for e in received) == [("Alarm1", False, False, True), ("Alarm3", True, False, True)]
    assert "serving 1 unit, security Basic256Sha256,SignAndEncrypt" in err
    assert sqlite3.connect(store).execute("SELECT count(*) FROM action").fetchone()[0] == 1  # nothing refused written


def test_a_port_taken_stops_the_monitor_with_a_message(tmp_path):
    data, store = tmp_path / "dryer.csv", str(tmp_path / "dryer.db")
    data.write_text("".join(LINES[:51]))
    with socket.create_server(("127.0.0.1", 0)) as taken:
        port = taken.getsockname()[1]
        done = subprocess.run([*jmlgdsl_command(), "monitor", SPEC, "--source", str(data), "--store", store,
                               "--opcua-server", f"opc.tcp://127.0.0.1:{port}/jmlgdsl"],
                              capture_output=True, text=True, timeout=WAIT)
    assert done.returncode == 2, done.stderr
    assert f"error: --opcua-server opc.tcp://127.0.0.1:{port}/jmlgdsl: cannot serve (" in done.stderr
    assert "Traceback" not in done.stderr


def test_the_server_options_need_the_server(tmp_path, capsys):
    assert main(["monitor", SPEC, "--source", str(tmp_path / "dryer.csv"), "--store", str(tmp_path / "dryer.db"),
                 "--opcua-server-username", "plant"]) == 2
    assert "--opcua-server-username is for the --opcua-server: give --opcua-server" in capsys.readouterr().err


async def _at(client, t) -> bool:
    """Whether the server shows row t (its variables wait for a first row)."""
    try:
        return await value(client, "T") == t
    except ua.UaStatusCodeError:
        return False


async def _true(holds: bool) -> bool:
    return holds
