"""`jmlgdsl monitor` as a Sparkplug B host application on a real MQTT broker (mosquitto on 127.0.0.1):
an edge node written here with paho and the monitor's own payload code sends its births, the dryer
recording as device data with an out-of-order pair and a dropped seq number, and its deaths; the
export equals `jmlgdsl run -o` on the rows it sent, the pair is put back in order, the gap is an
event and the rebirth request an NCMD on the broker, and the host's STATE is online while it runs
and offline after. A node whose data come before its birth is asked for one; backfill
(`is_historical`) sent in reverse fills its rows in time order. The seq ordering and the payloads
are also tested on their own."""

import json
import math
import queue
import random
import sqlite3
import sys
import subprocess
import threading
import time

import pytest
from conftest import jmlgdsl_command
from monitor_servers import LINES, MOSQUITTO, NO_MOSQUITTO, SPEC, WAIT, exported, expected_table, query, stop, until

from jmlgdsl.cli import main

paho = pytest.importorskip("paho.mqtt.client")
pytest.importorskip("google.protobuf")

from jmlgdsl.monitor.sources.payload import Malformed  # noqa: E402
from jmlgdsl.monitor.sources.sparkplug import Sequence  # noqa: E402
from jmlgdsl.monitor.sources.sparkplug_b import (BOOLEAN, DOUBLE, INT8, INT64, STRING, UINT64, Metric, Payload,  # noqa: E402
                                         decode, encode, reading)

ROWS = [line.split(",") for line in LINES[1:]]  # time, current, temp, mode, temp_true


# ---------------------------------------------------------------------------------- seq order
def test_sequence_puts_a_swapped_pair_back_in_order_across_the_wrap():
    sequence = Sequence(timeout=1.0)
    sequence.next = 254
    assert sequence.add(254, "a", 0.0) == (["a"], [])
    assert sequence.add(0, "c", 0.1) == ([], [])  # 255 is not here yet
    assert sequence.add(255, "b", 0.2) == (["b", "c"], [])
    assert sequence.next == 1 and sequence.since is None


def test_sequence_gives_up_a_gap_after_its_timeout_and_reports_the_missing_numbers():
    sequence = Sequence(timeout=1.0)
    assert sequence.add(3, "c", 10.0) == ([], [])
    assert sequence.add(5, "e", 10.5) == ([], [])
    assert sequence.expire(10.9) == ([], [])
    assert sequence.expire(11.0) == (["c", "e"], [1, 2, 4])
    assert sequence.add(6, "f", 11.1) == (["f"], [])
    assert sequence.add(2, "b", 11.2) == (["b"], [])  # behind: its gap was given up, it goes on at once


def test_sequence_gives_up_a_gap_that_too_many_messages_came_after():
    sequence = Sequence(timeout=60.0)
    for seq in range(2, 65):
        assert sequence.add(seq, seq, 0.0) == ([], [])
    ready, missing = sequence.add(65, 65, 0.0)  # the 64th after the gap: it is given up
    assert (ready, missing) == (list(range(2, 66)), [1])


# ---------------------------------------------------------------------------------- payloads
def test_payload_round_trip_and_readings_by_datatype():
    sent = Payload(1_000, 7, (Metric("temp", 1, 1_000, DOUBLE, 50.25), Metric(alias=2, datatype=INT8, value=-3),
                              Metric("count", 3, datatype=INT64, value=-2**40),
                              Metric("on", 4, datatype=BOOLEAN, value=True),
                              Metric("label", 5, datatype=STRING, value="dryer"),
                              Metric("off", 6, datatype=DOUBLE, null=True)))
    got = decode(encode(sent))
    assert (got.timestamp, got.seq) == (1_000, 7)
    assert [reading(m, m.datatype, "x") for m in got.metrics[:4]] == [50.25, -3.0, -2.0**40, 1.0]
    assert math.isnan(reading(got.metrics[5], DOUBLE, "x"))  # null: not measured
    with pytest.raises(Malformed, match="x: metric label is of type String, not a number"):
        reading(got.metrics[4], STRING, "x")
    with pytest.raises(Malformed, match="x: metric alias 9 has no datatype, in its birth or here"):
        reading(Metric(alias=9, value=3), None, "x")


def test_any_bytes_decode_to_a_payload_or_are_malformed():
    draw = random.Random(20260309)
    for _ in range(5_000):
        data = bytes(draw.getrandbits(8) for _ in range(draw.randint(0, 40)))
        try:
            decode(data)
        except Malformed as exc:
            assert "is not a Sparkplug B payload" in str(exc)
    with pytest.raises(Malformed, match="metric name b'\\\\xff' is not UTF-8"):
        decode(b"\x12\x03\x0a\x01\xff")


# ---------------------------------------------------------------------------------- an edge node
class Edge:
    """A Sparkplug B edge node `node` of `group` on the broker at `port`: its NDEATH will (bdSeq),
    births and data at QoS 0 with seq numbers 0-255, a device's too; the NCMDs sent to it."""

    def __init__(self, port, group, node):
        self.topic = f"spBv1.0/{group}/{{}}/{node}"
        self.bdseq, self.seq = 0, 0
        self.commands = queue.Queue()
        self.client = paho.Client(paho.CallbackAPIVersion.VERSION2, client_id=f"edge-{node}")
        self.client.will_set(self.topic.format("NDEATH"), encode(Payload(None, None, (
            Metric("bdSeq", datatype=UINT64, value=self.bdseq),))), qos=1)
        self.client.on_message = lambda client, userdata, message: self.commands.put(decode(message.payload))
        self.client.connect("127.0.0.1", port)
        self.client.loop_start()
        self.client.subscribe(self.topic.format("NCMD"), qos=1)

    def send(self, verb, metrics, device=None, seq=None, timestamp=None):
        """Publish a message; its seq is the next one unless given (NBIRTH: 0)."""
        if verb == "NBIRTH":
            self.seq = 0
        seq = self.seq if seq is None else seq
        self.seq = (seq + 1) % 256
        topic = self.topic.format(verb) + (f"/{device}" if device else "")
        self.client.publish(topic, encode(Payload(timestamp, None if verb == "NDEATH" else seq, tuple(metrics))),
                            qos=0).wait_for_publish(WAIT)

    def skip(self):
        """A message lost on its way: its seq number is used and never arrives."""
        self.seq = (self.seq + 1) % 256

    def nbirth(self, metrics=()):
        self.send("NBIRTH", [Metric("bdSeq", datatype=UINT64, value=self.bdseq),
                             Metric("Node Control/Rebirth", 100, datatype=BOOLEAN, value=False), *metrics])

    def rebirth_asked(self):
        command = self.commands.get(timeout=WAIT)
        return [(m.name, m.datatype, m.value) for m in command.metrics]

    def close(self):
        self.client.disconnect()
        self.client.loop_stop()


def values(row, names=("temp", "current"), historical=False, by_name=False):
    """The metrics of one recorded row: temp (alias 1) and current (alias 2), Doubles at the row's time
    in ms, by alias (data) or by name and alias (births)."""
    stamp = round(float(row[0]) * 1000)
    return [Metric(name if by_name else None, alias, stamp, DOUBLE, value, historical)
            for name, alias, value in zip(names, (1, 2), (float(row[2]), float(row[1])))]


class Listener:
    """Every message on `topics` (wildcards allowed), in order, as (topic, payload, retained)."""

    def __init__(self, port, *topics):
        self.messages = []
        self.client = paho.Client(paho.CallbackAPIVersion.VERSION2)
        self.client.on_message = lambda client, userdata, m: self.messages.append((m.topic, m.payload, m.retain))
        self.client.connect("127.0.0.1", port)
        self.client.loop_start()
        subscribed = threading.Event()
        self.client.on_subscribe = lambda *args: subscribed.set()
        self.client.subscribe([(topic, 1) for topic in topics])
        assert subscribed.wait(WAIT)

    def on(self, prefix):
        return [(payload, retained) for topic, payload, retained in list(self.messages) if topic.startswith(prefix)]

    def close(self):
        self.client.disconnect()
        self.client.loop_stop()


def host(port, store, url, *extra):
    return subprocess.Popen([*jmlgdsl_command(), "monitor", SPEC, "--source", f"sparkplug://127.0.0.1:{port}/{url}",
                             "--store", store, *extra], stderr=subprocess.PIPE, text=True)


def online(listener, host_id):
    return lambda: any(json.loads(p).get("online") for p, _ in listener.on(f"spBv1.0/STATE/{host_id}"))


def kinds(store):
    return dict(sqlite3.connect(store).execute("SELECT kind, count(*) FROM event GROUP BY kind"))


def details(store, kind):
    return [d for (d,) in sqlite3.connect(store).execute("SELECT detail FROM event WHERE kind = ? ORDER BY id",
                                                         (kind,))]


@pytest.mark.skipif(MOSQUITTO is None, reason=NO_MOSQUITTO)
def test_device_data_in_seq_order_with_a_gap_a_rebirth_and_deaths(broker, tmp_path):
    port, store = broker(), str(tmp_path / "dryer.db")
    listener = Listener(port, "spBv1.0/STATE/#", "spBv1.0/plant/NCMD/#")
    process = host(port, store, "plant/gateway/dryer", "--client-id", "control-room", "--reorder-timeout", "0.5")
    edge = None
    try:
        until(online(listener, "control-room"), "the host's STATE online", process)
        edge = Edge(port, "plant", "gateway")
        edge.nbirth([Metric("uptime", 101, datatype=DOUBLE, value=1.0)])
        edge.send("DBIRTH", values(ROWS[0], by_name=True), device="dryer")
        for i in range(1, 310):  # rows 2 to 310: row 101 sent before row 100, row 300 lost
            if i == 99:
                edge.send("DDATA", values(ROWS[100]), device="dryer", seq=(edge.seq + 1) % 256)
                edge.send("DDATA", values(ROWS[99]), device="dryer", seq=(edge.seq - 2) % 256)
                edge.seq = (edge.seq + 1) % 256
            elif i == 100:
                continue
            elif i == 299:
                edge.skip()
            else:
                edge.send("DDATA", values(ROWS[i]), device="dryer")
        assert edge.rebirth_asked() == [("Node Control/Rebirth", BOOLEAN, True)]
        edge.nbirth()
        edge.send("DBIRTH", values(ROWS[310], by_name=True), device="dryer")
        for row in ROWS[311:]:
            edge.send("DDATA", values(row), device="dryer")
        edge.send("DDEATH", [], device="dryer")
        edge.send("NDEATH", [Metric("bdSeq", datatype=UINT64, value=0)])
        until(lambda: query(store, "SELECT count(*) FROM result") == 1000 and kinds(store).get("death") == 2,
              "every row and both deaths", process)
        stop(process)
    finally:
        process.kill()
        if edge is not None:
            edge.close()
        listener.close()
    # what the edge sent: the recording without row 300
    sent = tmp_path / "sent.csv"
    lines = list(LINES)
    cells = lines[300].split(",")
    lines[300] = ",".join(cells[:2] + [""] + cells[3:])
    sent.write_text("".join(lines))
    assert main(["run", SPEC, str(sent), "-o", str(tmp_path / "run.csv")]) == 0
    assert exported(tmp_path, store) == (tmp_path / "run.csv").read_text()
    assert kinds(store) == {"start": 1, "connect": 1, "birth": 4, "sequence": 1, "rebirth": 1, "gap": 1, "death": 2}
    assert details(store, "sequence") == ["edge node gateway: seq 44 lost (not there within 0.5 s or 64 messages); "
                                          "the ones after went on in order"]
    assert details(store, "birth")[:2] == ["edge node gateway is online (NBIRTH, bdSeq 0): no metric of the tags",
                                           "device gateway/dryer is online (DBIRTH): temp, current"]
    commands = [decode(payload) for payload, _ in listener.on("spBv1.0/plant/NCMD/gateway")]
    assert [[(m.name, m.value) for m in c.metrics] for c in commands] == [[("Node Control/Rebirth", True)]]
    states = [json.loads(payload) for payload, _ in listener.on("spBv1.0/STATE/control-room")]
    assert [s["online"] for s in states] == [True, False]
    assert states[0]["timestamp"] == states[1]["timestamp"]
    late = Listener(port, "spBv1.0/STATE/control-room")  # a subscriber after the monitor stopped: the retained STATE
    deadline = time.monotonic() + WAIT
    while not late.messages and time.monotonic() < deadline:
        time.sleep(0.02)
    late.close()
    assert late.messages[0][2] and json.loads(late.messages[0][1])["online"] is False


@pytest.mark.skipif(MOSQUITTO is None, reason=NO_MOSQUITTO)
def test_node_asked_for_its_birth_and_backfill_in_time_order(broker, tmp_path):
    """Node metrics bound through the tag file in a group's URL; data before the birth ask for one; a
    node that comes back sends what it stored (`is_historical`, newest first) after its new birth,
    and with --grace covering it the rows are diagnosed as if it had never been away: its readings
    taken in time order, so that of two in one row the earlier stands, as it would have live."""
    port, store = broker(), str(tmp_path / "dryer.db")
    tags = tmp_path / "tags.toml"
    tags.write_text('[tags.temp]\nmetric = "Dryer/Air temperature"\n[tags.current]\nmetric = "Dryer/Heater current"\n')
    names = ("Dryer/Air temperature", "Dryer/Heater current")
    listener = Listener(port, "spBv1.0/STATE/#")
    process = host(port, store, "plant", "--tags", str(tags), "--grace", "60")
    edge = None
    try:
        until(online(listener, "jmlgdsl-dryer"), "the host's STATE online", process)
        edge = Edge(port, "plant", "line4")
        edge.send("NDATA", values(ROWS[0]), seq=17)  # a node born before the monitor started
        assert edge.rebirth_asked() == [("Node Control/Rebirth", BOOLEAN, True)]
        edge.nbirth(values(ROWS[0], names, by_name=True))
        for row in ROWS[1:100]:
            edge.send("NDATA", values(row, names))
        edge.client.publish("spBv1.0/plant/NDATA/line4", b"\x08\xff", qos=0).wait_for_publish(WAIT)
        edge.send("NDEATH", [Metric("bdSeq", datatype=UINT64, value=0)])  # cut off for rows 101 to 150
        edge.bdseq = 1
        edge.nbirth(values(ROWS[150], names, by_name=True))
        stored = [m for row in reversed(ROWS[100:150]) for m in values(row, names, historical=True)]
        at = stored.index(values(ROWS[119], names, historical=True)[0])  # row 120's temp, read again 0.3 s on:
        stored.insert(at, Metric(None, 1, 120_300, DOUBLE, 99.0, True))  # the first in its row (120.0) stands
        edge.send("NDATA", stored)
        for row in ROWS[151:200]:
            edge.send("NDATA", values(row, names))
        until(lambda: query(store, "SELECT count(*) FROM result") == 200, "200 rows", process)
        edge.send("NDEATH", [Metric("bdSeq", datatype=UINT64, value=0)])  # an earlier session's: not this one's
        edge.send("NDEATH", [Metric("bdSeq", datatype=UINT64, value=1)])
        until(lambda: kinds(store).get("death") == 2, "the second death", process)
        err = stop(process)
    finally:
        process.kill()
        if edge is not None:
            edge.close()
        listener.close()
    assert exported(tmp_path, store).splitlines() == expected_table(tmp_path).splitlines()[:201]
    # every reading of the backfill is older than the birth's before it: used, and out of order
    assert kinds(store) == {"start": 1, "connect": 1, "rebirth": 1, "birth": 2, "malformed": 1, "death": 2,
                            "out_of_order": 101, "duplicate": 1}
    assert details(store, "duplicate") == ["a second reading for 120.3 s (the first stands)"]
    assert details(store, "rebirth") == ["asked edge node line4 for a rebirth: its NDATA came before its NBIRTH"]
    assert details(store, "birth")[0] == "edge node line4 is online (NBIRTH, bdSeq 0): temp, current"
    assert "monitor: malformed: topic spBv1.0/plant/NDATA/line4: payload b'\\x08\\xff' is not a Sparkplug B" in err


def test_a_source_url_without_a_group_and_a_fleet_are_refused(tmp_path):
    for url, message in [("sparkplug://127.0.0.1:1883", "give sparkplug://HOST:PORT/GROUP"),
                         ("sparkplug://127.0.0.1:1883/a/b/c/d", "give sparkplug://HOST:PORT/GROUP"),
                         ("sparkplug://127.0.0.1:1883/plant/+", "each id without '+', '#' or '/'"),
                         ("sparkplug://127.0.0.1:1883/plant --reorder-timeout 0", "--reorder-timeout 0: give a "
                                                                                  "positive number of seconds"),
                         ("sparkplug://127.0.0.1:1883/plant --units a,b", "--units with a Sparkplug B source: not "
                                                                          "supported; run a monitor for each")]:
        done = subprocess.run([*jmlgdsl_command(), "monitor", SPEC, "--source", *url.split(), "--store",
                               str(tmp_path / "x.db")], capture_output=True, text=True, timeout=WAIT)
        assert done.returncode == 2 and message in done.stderr, done.stderr
    done = subprocess.run([*jmlgdsl_command(), "monitor", SPEC, "--source", "mqtt://127.0.0.1:1883/dryer",
                           "--reorder-timeout", "1", "--store", str(tmp_path / "x.db")],
                          capture_output=True, text=True, timeout=WAIT)
    assert done.returncode == 2 and "an MQTT source takes no --reorder-timeout" in done.stderr



def test_a_metric_two_devices_declare_historical_readings_by_arrival_and_unknown_aliases(tmp_path):
    """Without a broker: the first device born with a bound metric keeps it; backfill of a tag read at
    its arrival time is dropped, not placed at its arrival; an alias no birth declared asks for one."""
    import types

    import jmlgdsl
    from jmlgdsl.monitor import read_tags
    from jmlgdsl.monitor.sources.contract import Event, Readings, Unreadable
    from jmlgdsl.monitor.sources.sparkplug import SparkplugSource

    tags = tmp_path / "tags.toml"
    tags.write_text('[tags.current]\ntime = "arrival"\n')
    model = jmlgdsl.load(SPEC)
    source = SparkplugSource("sparkplug://127.0.0.1/plant/gateway", model, read_tags(tags, model), host_id="h")
    sent = []
    source.client = types.SimpleNamespace(publish=lambda topic, payload, qos: sent.append((topic, decode(payload))))
    items = []

    def message(verb, seq, metrics, device=None):
        topic = f"spBv1.0/plant/{verb}/gateway" + (f"/{device}" if device else "")
        source.received(types.SimpleNamespace(topic=topic, payload=encode(Payload(5_000, seq, tuple(metrics)))),
                        items.append)

    message("NBIRTH", 0, [Metric("bdSeq", datatype=UINT64, value=3)])
    message("DBIRTH", 1, values(ROWS[0], by_name=True), device="a")
    message("DBIRTH", 2, [Metric("temp", 1, 1_000, DOUBLE, 20.0)], device="b")
    message("DDATA", 3, values(ROWS[1], historical=True) + [Metric(None, 7, 3_000, DOUBLE, 1.0)], device="a")
    events = [(item.kind, item.detail) for item in items if isinstance(item, Event)]
    assert events == [("birth", "edge node gateway is online (NBIRTH, bdSeq 3): no metric of the tags"),
                      ("birth", "device gateway/a is online (DBIRTH): temp, current"),
                      ("birth", "device gateway/b is online (DBIRTH): no metric of the tags"),
                      ("late", "1 historical readings of current not used: a tag read at its arrival time cannot "
                               "place them"),
                      ("rebirth", "asked edge node gateway for a rebirth: its metrics of aliases 7 are not in its "
                                  "birth")]
    assert [item.message for item in items if isinstance(item, Unreadable)] == [
        "device gateway/b: its metric 'temp' of temp is also device gateway/a's, which keeps it (name the edge node "
        "and device in --source)"]
    assert [item.readings for item in items if isinstance(item, Readings)] == [
        [("temp", 50.60301681, 1.0), ("current", 15.0, 1.0)], [("temp", 50.57489308, 2.0)]]
    assert [(topic, [(m.name, m.value) for m in command.metrics]) for topic, command in sent] == [
        ("spBv1.0/plant/NCMD/gateway", [("Node Control/Rebirth", True)])]


def test_without_protobuf_the_source_says_what_to_install(monkeypatch):
    import jmlgdsl
    from jmlgdsl.errors import JmlgError
    from jmlgdsl.monitor import read_tags
    from jmlgdsl.monitor.sources import Connection, open_source

    monkeypatch.setitem(sys.modules, "google.protobuf", None)  # as if it were not installed
    for name in ("jmlgdsl.monitor.sources.sparkplug", "jmlgdsl.monitor.sources.sparkplug_b"):
        monkeypatch.delitem(sys.modules, name)
    model = jmlgdsl.load(SPEC)
    with pytest.raises(JmlgError, match=r"a Sparkplug B source needs the protobuf package: pip install "
                                        r"'jmlgdsl\[sparkplug\]'"):
        open_source(Connection("sparkplug://127.0.0.1/plant"), model, read_tags(None, model))
