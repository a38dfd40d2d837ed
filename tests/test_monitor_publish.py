"""The monitor's conclusions sent on (`monitor --publish mqtt://...`, `--notify URL`), against a real
mosquitto and a webhook receiver on 127.0.0.1 started here: a subscriber gets one state message
per diagnosed row and every alarm transition (the operators' actions included), one that comes later
the retained latest state; a monitor killed with SIGKILL while its broker is frozen, and started
again, loses nothing and publishes nothing twice without marking it; a webhook receiver gets every
transition, and one that is down holds nothing up, is an event, and is sent what it missed when it
is back, by the same monitor or by the next."""

import contextlib
import json
import signal
import socket
import sqlite3
import subprocess
import threading
import time

import pytest
from conftest import jmlgdsl_command
from monitor_servers import LINES, MOSQUITTO, NO_MOSQUITTO, SPEC, WAIT, Receiver, free_port, query, stop, until

from jmlgdsl.monitor import Store
from jmlgdsl.monitor.store.databases import SQLite

paho = pytest.importorskip("paho.mqtt.client")
mosquitto = pytest.mark.skipif(MOSQUITTO is None, reason=NO_MOSQUITTO)  # the webhook's tests need none
PREFIX = "diagnosis/dryer"


class Subscriber:
    """An MQTT client on PREFIX/# that keeps every message as (topic, JSON body, retained)."""

    def __init__(self, port, client_id):
        self.messages, self.subscribed = [], threading.Event()
        self.client = paho.Client(paho.CallbackAPIVersion.VERSION2, client_id=client_id)
        self.client.on_message = lambda client, userdata, m: self.messages.append(
            (m.topic, json.loads(m.payload), m.retain))
        self.client.on_subscribe = lambda *_: self.subscribed.set()
        self.client.connect("127.0.0.1", port)
        self.client.subscribe(f"{PREFIX}/#", qos=1)
        self.client.loop_start()
        assert self.subscribed.wait(WAIT)

    def states(self):
        return [body for topic, body, _ in list(self.messages) if topic == f"{PREFIX}/state"]

    def transitions(self):
        return [body for topic, body, _ in list(self.messages) if topic == f"{PREFIX}/alarm"]

    def close(self):
        self.client.disconnect()
        self.client.loop_stop()


def monitor(data, store, *extra):
    return subprocess.Popen([*jmlgdsl_command(), "monitor", SPEC, "--source", str(data), "--store", store, *extra],
                            stderr=subprocess.PIPE, text=True)


def stored(store, rows):
    return lambda: query(store, "SELECT count(*) FROM result") == rows


def expected_transitions(store):
    """(alarm, transition) of the store's alarms, in the order of their rows, then of the actions."""
    db = sqlite3.connect(store)
    rows = sorted([(raised, id, "raised") for id, raised, _ in db.execute("SELECT id, raised_t, cleared_t FROM alarm")]
                  + [(cleared, id, "cleared") for id, cleared in db.execute(
                      "SELECT id, cleared_t FROM alarm WHERE cleared_t IS NOT NULL")])
    actions = db.execute("SELECT alarm, kind FROM action ORDER BY id").fetchall()
    names = {"acknowledge": "acknowledged", "shelve": "shelved", "unshelve": "unshelved"}
    return [(id, kind) for _, id, kind in rows] + [(id, names[kind]) for id, kind in actions]


@mosquitto
def test_subscribers_get_every_row_every_transition_and_the_latest_state(broker, tmp_path):
    port, store, data = broker(), str(tmp_path / "dryer.db"), tmp_path / "dryer.csv"
    data.write_text("".join(LINES))
    early = Subscriber(port, "early")
    process = monitor(data, store, "--publish", f"mqtt://127.0.0.1:{port}/{PREFIX}")
    late = None
    try:
        until(lambda: len(early.states()) == 1000 and len(early.transitions()) == 5, "every row's state", process)
        with Store(store) as opened:  # as the operator's page does, from another process
            opened.act(1, 3, "acknowledge", "ann")
            opened.act(1, 1, "shelve", "ann", "fan under repair")
        until(lambda: len(early.transitions()) == 7, "the operators' actions", process)
        late = Subscriber(port, "late")
        until(lambda: late.messages, "the retained state", process)
        stop(process)
    finally:
        process.kill()
        for subscriber in (early, late):
            if subscriber is not None:
                subscriber.close()
    db = sqlite3.connect(store)
    modes = json.loads(db.execute("SELECT modes FROM run").fetchone()[0])
    rows = db.execute("SELECT r.t, s.time, r.map_mode, r.posterior, r.alarm FROM result r JOIN sample s "
                      "USING (run, t) ORDER BY t").fetchall()
    states = early.states()
    assert [(s["t"], s["time"], s["mode"], list(s["modes"]), list(s["modes"].values()), s["alarm"]) for s in states] == [
        (t, time, mode, modes, SQLite.unvector(posterior, len(modes)).tolist(), bool(alarm))
        for t, time, mode, posterior, alarm in rows]
    assert {s["redelivered"] for s in states} == {False}
    assert states[516]["alarm_id"] == 3 and states[515]["alarm_id"] is None  # raised at row 517
    transitions = early.transitions()
    assert [(x["alarm"], x["transition"]) for x in transitions] == expected_transitions(store) == [
        (1, "raised"), (1, "cleared"), (2, "raised"), (2, "cleared"), (3, "raised"), (3, "acknowledged"),
        (1, "shelved")]
    assert transitions[0] == {"plant": "dryer", "unit": None, "run": 1, "alarm": 1, "transition": "raised",
                              "mode": "fan", "t": 72, "time": 72.0, "state": "active, unacknowledged",
                              "text": "dryer: alarm 1 (fan) raised; now active, unacknowledged",
                              "redelivered": False}
    assert (transitions[5]["who"], transitions[5]["state"]) == ("ann", "active, acknowledged")
    assert (transitions[6]["reason"], transitions[6]["state"]) == ("fan under repair", "shelved")
    assert [(topic, retained) for topic, _, retained in late.messages] == [(f"{PREFIX}/state", True)]
    assert late.messages[0][1] == states[-1]


@mosquitto
def test_killed_monitor_loses_nothing_and_marks_what_it_publishes_again(broker, tmp_path):
    """Rows committed while the broker is frozen (SIGSTOP) are published but never acknowledged; the
    monitor killed then, and started again, publishes them again marked "redelivered", and each row
    once unmarked."""
    port, store, data = broker(), str(tmp_path / "dryer.db"), tmp_path / "dryer.csv"
    command = ["--publish", f"mqtt://127.0.0.1:{port}/{PREFIX}"]
    data.write_text("".join(LINES[:501]))
    subscriber = Subscriber(port, "subscriber")
    first = monitor(data, store, *command)
    second = None
    frozen = broker.running[port]
    try:
        until(lambda: query(store, "SELECT max(t) FROM delivery") == 500, "rows 1-500 acknowledged by the broker", first)
        frozen.send_signal(signal.SIGSTOP)
        with open(data, "a") as out:
            out.writelines(LINES[501:801])
        until(stored(store, 800), "800 rows stored", first)
        time.sleep(0.5)  # published to the frozen broker
        first.send_signal(signal.SIGKILL)
        first.wait(WAIT)
        frozen.send_signal(signal.SIGCONT)
        with open(data, "a") as out:
            out.writelines(LINES[801:])
        second = monitor(data, store, *command)
        until(lambda: query(store, "SELECT max(t) FROM delivery") == 1000, "every row acknowledged", second)
        until(lambda: len(subscriber.states()) >= 1000 and subscriber.states()[-1]["t"] == 1000, "the last row",
              second)
        stop(second)
    finally:
        frozen.send_signal(signal.SIGCONT)
        for process in (first, second):
            if process is not None:
                process.kill()
        subscriber.close()
    states = subscriber.states()
    by_row = {}
    for state in states:
        by_row.setdefault(state["t"], []).append(state)
    assert sorted(by_row) == list(range(1, 1001))  # none lost
    assert all(sum(not s["redelivered"] for s in copies) <= 1 for copies in by_row.values())  # none twice unmarked
    assert all(dict(s, redelivered=None) == dict(copies[0], redelivered=None)
               for copies in by_row.values() for s in copies)  # a copy is the same conclusion
    again = sorted(s["t"] for s in states if s["redelivered"])
    assert again and again[0] > 500 and again[-1] == 800  # published again: what the broker had not acknowledged
    transitions = subscriber.transitions()
    seen = {}
    for x in transitions:
        seen.setdefault((x["alarm"], x["transition"]), []).append(x["redelivered"])
    assert sorted(seen) == sorted(expected_transitions(store))
    assert all(marks.count(False) <= 1 for marks in seen.values())
    assert seen[(3, "raised")][-1] is True  # raised at row 517, while the broker was frozen


def test_webhook_gets_every_transition(tmp_path):
    store, data = str(tmp_path / "dryer.db"), tmp_path / "dryer.csv"
    data.write_text("".join(LINES))
    receiver = Receiver()
    process = monitor(data, store, "--notify", f"http://127.0.0.1:{receiver.port}/hooks/alarms")
    try:
        until(lambda: len(receiver.posts) == 5, "the alarms raised and cleared", process)
        with Store(store) as opened:
            opened.act(1, 2, "acknowledge", "ann")
        until(lambda: len(receiver.posts) == 6, "the acknowledgement", process)
        stop(process)
    finally:
        process.kill()
        receiver.close()
    assert receiver.transitions() == expected_transitions(store)
    assert {kind for kind, _ in receiver.posts} == {"application/json"}
    assert receiver.posts[5][1]["text"] == "dryer: alarm 2 (grill) acknowledged by ann; now cleared, acknowledged"


def test_webhook_that_hangs_holds_no_row_up(tmp_path):
    """A receiver that takes the first request and never answers it: every row is diagnosed and stored
    while that request still waits (a diagnosis that waited on it would stop at the first alarm until
    the request's own time limit, and its retry would be a second connection)."""
    data, store = tmp_path / "dryer.csv", str(tmp_path / "dryer.db")
    data.write_text("".join(LINES))
    accepted = []
    with socket.create_server(("127.0.0.1", 0)) as hanging:

        def take():
            with contextlib.suppress(OSError):  # the listening socket closed: the test is over
                while True:
                    accepted.append(hanging.accept()[0])

        threading.Thread(target=take, daemon=True).start()
        process = monitor(data, store, "--notify", f"http://127.0.0.1:{hanging.getsockname()[1]}/hook")
        try:
            until(lambda: accepted and stored(store, 1000)(), "every row and the first alarm's request", process)
            assert len(accepted) == 1  # that request still unanswered, never tried again
            stop(process)
        finally:
            process.kill()
            for connection in accepted:
                connection.close()


def test_webhook_down_is_an_event_and_is_sent_what_it_missed(tmp_path):
    data = tmp_path / "dryer.csv"
    data.write_text("".join(LINES))
    port, store = free_port(), str(tmp_path / "dryer.db")
    hook = ["--notify", f"http://127.0.0.1:{port}/hook"]
    done = subprocess.run([*jmlgdsl_command(), "monitor", SPEC, "--source", str(data), "--store", store,
                           "--no-follow", *hook], capture_output=True, text=True, timeout=WAIT)
    assert done.returncode == 0, done.stderr
    err = done.stderr
    assert query(store, "SELECT count(*) FROM result") == 1000
    assert "refused" in query(store, "SELECT detail FROM event WHERE kind = 'delivery'")
    assert "monitor: delivery: notify http://127.0.0.1:" in err
    assert query(store, "SELECT max(t) FROM delivery") == 0  # nothing delivered: all of it waits in the store
    receiver = Receiver(port)
    process = monitor(data, store, *hook)  # started again, the receiver back: sent what it missed, marked
    try:
        until(lambda: len(receiver.posts) == 5, "the transitions the receiver missed", process)
        stop(process)
    finally:
        process.kill()
        receiver.close()
    assert receiver.transitions() == expected_transitions(store)
    assert {body["redelivered"] for _, body in receiver.posts} == {True}


def test_webhook_back_while_the_monitor_runs_is_sent_what_it_missed(tmp_path):
    store, data = str(tmp_path / "dryer.db"), tmp_path / "dryer.csv"
    data.write_text("".join(LINES))
    port = free_port()
    process = monitor(data, store, "--notify", f"http://127.0.0.1:{port}/hook")
    receiver = None
    try:
        until(stored(store, 1000), "every row stored", process)
        until(lambda: query(store, "SELECT count(*) FROM event WHERE kind = 'delivery'"), "a failed delivery", process)
        receiver = Receiver(port)
        until(lambda: len(receiver.posts) == 5, "the transitions", process)
        until(lambda: query(store, "SELECT max(t) FROM delivery") == 1000, "the delivery recorded", process)
        stop(process)
    finally:
        process.kill()
        if receiver is not None:
            receiver.close()
    assert receiver.transitions() == expected_transitions(store)
    assert {body["redelivered"] for _, body in receiver.posts} == {False}
    details = [d for d, in sqlite3.connect(store).execute("SELECT detail FROM event WHERE kind = 'delivery'")]
    assert "alarm 1 raised: [Errno 111] Connection refused; trying again in 1 s" in details[0]
    assert "delivered after" in details[-1]


@mosquitto
def test_fleet_units_publish_under_their_own_topics(broker, tmp_path):
    port, store = broker(), str(tmp_path / "fleet.db")
    for unit in ("d1", "d2"):
        (tmp_path / f"{unit}.csv").write_text("".join(LINES[:201]))
    subscriber = Subscriber(port, "fleet")
    done = subprocess.run([*jmlgdsl_command(), "monitor", SPEC, "--source", str(tmp_path / "{unit}.csv"), "--store",
                           store, "--units", "d1,d2", "--no-follow", "--publish", f"mqtt://127.0.0.1:{port}/{PREFIX}"],
                          capture_output=True, text=True, timeout=WAIT)
    assert done.returncode == 0, done.stderr
    deadline = time.monotonic() + WAIT
    while len(subscriber.messages) < 2 * 201 and time.monotonic() < deadline:  # 200 rows and a raised alarm each
        time.sleep(0.02)
    subscriber.close()
    for unit, run in (("d1", 1), ("d2", 2)):
        mine = [body for topic, body, _ in subscriber.messages if topic == f"{PREFIX}/{unit}/state"]
        assert [(s["unit"], s["run"], s["t"]) for s in mine] == [(unit, run, t) for t in range(1, 201)]
    transitions = [(topic, body["unit"], body["transition"], body["t"]) for topic, body, _ in subscriber.messages
                   if topic.endswith("/alarm")]
    assert sorted(transitions) == [(f"{PREFIX}/{unit}/alarm", unit, "raised", 72) for unit in ("d1", "d2")]


@mosquitto
def test_publish_broker_that_refuses_the_password_stops_the_monitor(broker, tmp_path):
    port, store, data = broker(password=True), str(tmp_path / "dryer.db"), tmp_path / "dryer.csv"
    data.write_text("".join(LINES[:101]))
    secret = tmp_path / "password"
    secret.write_text("wrong\n")
    url = f"mqtt://127.0.0.1:{port}/{PREFIX}"
    done = subprocess.run([*jmlgdsl_command(), "monitor", SPEC, "--source", str(data), "--store", store, "--publish",
                           url, "--publish-username", "plant", "--publish-password-file", str(secret)],
                          capture_output=True, text=True, timeout=WAIT)
    assert done.returncode == 2
    assert (f"error: --publish {url}: the broker refused the connection (Not authorized); check --publish-username "
            "and the password (--publish-password-env, --publish-password-file)") in done.stderr
    assert "wrong" not in done.stderr
    done = subprocess.run([*jmlgdsl_command(), "monitor", SPEC, "--source", str(data), "--store", store, "--publish",
                           url, "--publish-password-file", str(secret)], capture_output=True, text=True, timeout=WAIT)
    assert done.returncode == 2
    assert "error: --publish-password-file: a password needs --publish-username" in done.stderr


@mosquitto
def test_node_red_flow_in_the_docs_reads_what_the_monitor_publishes(broker, tmp_path):
    """docs/monitor.md's Node-RED flow subscribes to the topics of the --publish it shows and reads
    fields the messages have."""
    import re
    from conftest import ROOT

    doc = (ROOT / "docs" / "monitor.md").read_text()
    flow = json.loads(next(block for block in re.findall(r"```json\n(.*?)```", doc, flags=re.S)
                           if '"mqtt-broker"' in block))
    prefix = re.search(r"--publish mqtt://127\.0\.0\.1:1883/(\S+)", doc).group(1)
    topics = {node["name"]: node["topic"] for node in flow if node["type"] == "mqtt in"}
    assert topics == {"state": f"{prefix}/state", "alarm": f"{prefix}/alarm"}
    port, store, data = broker(), str(tmp_path / "dryer.db"), tmp_path / "dryer.csv"
    data.write_text("".join(LINES[:101]))
    subscriber = Subscriber(port, "node-red")
    done = subprocess.run([*jmlgdsl_command(), "monitor", SPEC, "--source", str(data), "--store", store, "--no-follow",
                           "--publish", f"mqtt://127.0.0.1:{port}/{PREFIX}"], capture_output=True, text=True,
                          timeout=WAIT)
    assert done.returncode == 0, done.stderr
    deadline = time.monotonic() + WAIT
    while not subscriber.transitions() and time.monotonic() < deadline:
        time.sleep(0.02)
    subscriber.close()
    read = {"state": subscriber.states()[-1], "alarm": subscriber.transitions()[0]}
    wired = {node["id"]: node for node in flow}
    for name, body in read.items():  # every payload.FIELD the nodes after each MQTT input read
        after = [wired[i] for i in next(n for n in flow if n.get("name") == name and n["type"] == "mqtt in")["wires"][0]]
        fields = set(re.findall(r"payload\.(\w+)", json.dumps(after)))
        assert fields and fields <= set(body), (name, fields - set(body))
