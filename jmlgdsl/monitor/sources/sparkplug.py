"""Readings from Sparkplug B edge nodes: the monitor as a Sparkplug host application
(sparkplug://HOST:PORT/GROUP[/EDGE_NODE[/DEVICE]], sparkplugs:// over TLS), on MqttSource's
connection (credentials, TLS, retries and refusals alike).

Each spec name is the metric of that name (or the tag file's `metric = "..."`) of the edge nodes and
devices the URL names: with a device, that device's metrics; with an edge node only, the node's and
all its devices'; with a group only, every node's and device's in it. A metric is bound to its spec
name by the NBIRTH or DBIRTH that declares it (name, alias, datatype, and the current value, which
is a reading); NDATA and DDATA then give its values by alias (or by name), each at its metric's
timestamp (milliseconds since 1970; the payload's when the metric has none). Two places that declare
the same bound metric are not mixed: the first to be born keeps it until its death, and the other's
birth is a `malformed` event. NDEATH (of the bdSeq its NBIRTH declared) and DDEATH end a node's and
a device's bindings (a `death` event; the tags then go stale).

Sparkplug data are published at QoS 0 and a host connects with a clean session, so nothing is
delivered twice and nothing is kept for a monitor that is away: a message lost on the way is a gap
in its node's `seq` numbers (0 to 255, wrapping, one sequence per node for the node's and its devices'
messages). A message that comes ahead of the next number is held until the ones before it arrive
(an out-of-order pair is put back in order), for at most `reorder` seconds after the first held one,
or until HOLD messages have come after the gap; then the held messages go on in order, the numbers
that never came are a `sequence` event, and the node is asked for a rebirth (an NCMD of
`Node Control/Rebirth` = true), whose NBIRTH and DBIRTH bring the current values again. A node whose
data come before its birth (the monitor started, or restarted, after it) is asked for one as well,
and its data are not read until the birth says what its aliases are: each request is a `rebirth`
event, at most one per node every ASK_AGAIN seconds. Nothing of this is saved with the store: a
restarted monitor asks the nodes for their births again.

Metrics flagged `is_historical` are backfill (what an edge node stored while it was cut off): they
are handed over before the message's live metrics, in the order of their timestamps (so that of two
in one row the earlier stands, as it would have live), as readings of their own times; the assembler
uses them in their rows while those are open (up to `--grace`; each is `out_of_order`, as it comes
after the newer values of the node's new birth) and counts them `late` otherwise. A tag read at its
arrival time (`time = "arrival"`) cannot place them, so they are dropped with a `late` event.

The host's state is published as Sparkplug 3.0 asks: `spBv1.0/STATE/HOST_ID` (HOST_ID the
--client-id), JSON `{"online": true, "timestamp": MS}`, retained, at QoS 1, after each connection's
subscriptions; the connection's will is the same with `"online": false`, and a monitor that stops
publishes that itself. A STATE of its own that says offline (the broker sent the will of a
connection it took for lost) is answered by publishing online again.
"""

from __future__ import annotations

import json
import threading
import time

from ...errors import JmlgError
from . import bus
from ..units import FleetError
from .contract import Event, Readings, Unreadable
from .mqtt import MqttSource
from .payload import Malformed
from .sparkplug_b import BOOLEAN, Metric, Payload, decode, encode, reading
from .tags import TagError
from .urls import address

NAMESPACE = "spBv1.0"
REBIRTH = "Node Control/Rebirth"
BDSEQ = "bdSeq"
REORDER = 2.0  # default seconds a gap in a node's seq numbers waits for its messages
HOLD = 64  # messages held after a gap at most: its numbers are then given up (half the window below)
WINDOW = 128  # a seq number this far or further ahead of the next one is behind it (the numbers wrap at 256)
ASK_AGAIN = 10.0  # seconds before a node is asked for a rebirth again
TICK = 0.1  # seconds between looks at the held messages' deadlines
TIMEOUT = 5.0  # seconds the offline STATE may take to be published at the end
DATA = ("NDATA", "DDATA")


class Sequence:
    """An edge node's messages in the order of their seq numbers (0 to 255, wrapping; the NBIRTH's is
    0): `add` returns those ready to go on, in order; one ahead of the next number is held until the
    numbers before it come, or `timeout` seconds after the first one held (`expire`), or HOLD messages
    after it, when the held ones go on and the numbers missing are given up. A number behind the next
    one (a message whose gap was given up, or one sent again) goes on at once."""

    def __init__(self, timeout: float):
        self.timeout = timeout
        self.next = 1
        self.held = {}  # seq -> message
        self.since = None  # when the first message held now came (monotonic seconds)

    def add(self, seq: int, message, now: float):
        """(messages ready, in order; seq numbers given up) after a message of number `seq`."""
        ahead = (seq - self.next) % 256
        if ahead == 0:
            self.next = (seq + 1) % 256
            ready = [message]
            while self.next in self.held:
                ready.append(self.held.pop(self.next))
                self.next = (self.next + 1) % 256
            if not self.held:
                self.since = None
            return ready, []
        if ahead >= WINDOW:
            return [message], []
        if ahead >= HOLD and self.held:
            ready, missing = self.give_up()
            more, also = self.add(seq, message, now)
            return ready + more, missing + also
        self.held[seq] = message
        self.since = now if self.since is None else self.since
        return [], []

    def expire(self, now: float):
        """(messages ready, seq numbers given up) once the held ones have waited `timeout` seconds."""
        if self.since is None or now - self.since < self.timeout:
            return [], []
        return self.give_up()

    def give_up(self):
        """The held messages in order and the numbers missing before and between them."""
        ready, missing = [], []
        for _ in range(1 + max((seq - self.next) % 256 for seq in self.held)):
            if self.next in self.held:
                ready.append(self.held.pop(self.next))
            else:
                missing.append(self.next)
            self.next = (self.next + 1) % 256
        self.since = None
        return ready, missing


class _Node:
    """What a host knows of a born edge node: its bdSeq, the order of its messages, and per place
    (None: the node itself; else a device) its metrics' datatypes by name and names by alias."""

    def __init__(self, bdseq, timeout):
        self.bdseq = bdseq
        self.sequence = Sequence(timeout)
        self.types = {}  # place -> {metric name: datatype}
        self.aliases = {}  # place -> {alias: metric name}


def open_source(connection, model, tags, units=None):
    """The Sparkplug B edge nodes a connection names, read as the host application of id --client-id
    (default jmlgdsl-PLANT)."""
    if units is not None:
        raise FleetError("--units with a Sparkplug B source: not supported; run a monitor for each edge node "
                         "or device (--source sparkplug://HOST:PORT/GROUP/EDGE_NODE/DEVICE)")
    return SparkplugSource(connection.url, model, tags, host_id=connection.client_id or f"jmlgdsl-{model.name}",
                           credentials=connection.credentials, ca_file=connection.ca_file,
                           reorder=REORDER if connection.reorder is None else connection.reorder)


class SparkplugSource(MqttSource):
    """Sparkplug B edge nodes' metrics as Readings (jmlgdsl.monitor.sources.contract); nothing to
    acknowledge. `host_id` is the host application's id, also its MQTT client id; `reorder` the
    seconds a gap in a node's seq numbers waits for its messages."""

    persistent = False

    def __init__(self, url, model, tags, *, host_id: str, credentials=None, ca_file=None, reorder=REORDER):
        self.tls = url.startswith("sparkplugs://")
        self.host, self.port, path = address(url, 8883 if self.tls else 1883)
        self.name = f"{'sparkplugs' if self.tls else 'sparkplug'}://{self.host}:{self.port}/{path}"
        parts = path.split("/") if path else []
        if not 1 <= len(parts) <= 3 or not all(map(_identifier, parts)):
            raise JmlgError(f"--source {url}: give sparkplug://HOST:PORT/GROUP, .../GROUP/EDGE_NODE or "
                            ".../GROUP/EDGE_NODE/DEVICE, each id without '+', '#' or '/'")
        self.group, self.edge, self.device = parts + [None] * (3 - len(parts))
        if not _identifier(host_id):
            raise JmlgError(f"--client-id {host_id!r}: a Sparkplug host id is a topic level: no '+', '#' or '/'")
        if not reorder > 0:
            raise JmlgError(f"--reorder-timeout {reorder:g}: give a positive number of seconds")
        self.metrics = {}  # metric name -> spec name
        for name, tag in tags.items():
            metric = tag.metric or name
            if metric in self.metrics:
                raise TagError(f"[tags.{name}]: metric {metric!r} is also the metric of [tags.{self.metrics[metric]}]")
            self.metrics[metric] = name
        self.by_arrival = {name for name, tag in tags.items() if tag.time == "arrival"}
        self.client_id, self.credentials, self.ca_file, self.reorder = host_id, credentials, ca_file, reorder
        self.state = f"{NAMESPACE}/STATE/{host_id}"
        self.units = self.client = None
        self.nodes = {}  # edge node id -> _Node, while born
        self.owners = {}  # spec name -> (edge node, place) whose birth bound it
        self.asked = {}  # edge node id -> when it was last asked for a rebirth (monotonic seconds)
        self.stamp = None  # the timestamp of this connection's STATE (ms since 1970)
        self.lock = threading.Lock()  # the nodes, between the client's thread and the clock's
        self.stopped = threading.Event()
        self.put = None

    # ------------------------------------------------------------------ the connection
    def start(self, put, position):
        self.put = put
        threading.Thread(target=self._clock, name="sparkplug reorder clock", daemon=True).start()
        super().start(put, position)

    def prepare(self, client):
        client.on_pre_connect = self._will

    def _will(self, client, userdata):
        """Before each connection attempt: its STATE timestamp, and the will that says offline."""
        self.stamp = int(time.time() * 1000)
        client.will_set(self.state, self._state(False), qos=1, retain=True)

    def _state(self, online: bool) -> str:
        return json.dumps({"online": online, "timestamp": self.stamp})

    def connected(self, client, flags, hand):
        base = f"{NAMESPACE}/{self.group}"
        client.subscribe([(f"{base}/#" if self.edge is None else f"{base}/+/{self.edge}/#", 1), (self.state, 1)])
        client.publish(self.state, self._state(True), qos=1, retain=True)
        hand(bus.connected(f"{self.host}:{self.port}", f"as Sparkplug host {self.client_id}, STATE online"))

    def acknowledge(self, tokens):
        """Nothing to acknowledge: a host's session is clean, and Sparkplug data come at QoS 0."""

    def stop(self):
        """Say offline (STATE), then close the connection."""
        self.stopped.set()
        client = self.client
        if client is not None and client.is_connected():
            info = client.publish(self.state, self._state(False), qos=1, retain=True)
            try:
                info.wait_for_publish(TIMEOUT)
            except (RuntimeError, ValueError):  # the connection went meanwhile: the will says it
                pass
        super().stop()

    # ------------------------------------------------------------------ messages
    def received(self, message, hand):
        arrival = time.time()
        if message.topic == self.state:
            self._own_state(message.payload)
            return
        parts = message.topic.split("/")
        if len(parts) not in (4, 5) or parts[2] not in ("NBIRTH", "NDEATH", "DBIRTH", "DDEATH") + DATA:
            return  # commands (this host's own included), and what is not Sparkplug
        verb, edge, device = parts[2], parts[3], parts[4] if len(parts) == 5 else None
        try:
            payload = decode(message.payload)
        except Malformed as exc:
            hand(Unreadable(f"topic {message.topic}: {exc}"))
            return
        with self.lock:
            for item in self._take(verb, edge, device, payload, arrival):
                hand(item)

    def _own_state(self, payload):
        """A STATE of this host's: one that says offline, of this connection or an earlier one, is the
        will of a connection the broker took for lost, so say online again."""
        try:
            state = json.loads(payload)
            stamp = state.get("timestamp")
            offline = state.get("online") is False and isinstance(stamp, int) and stamp <= self.stamp
        except (ValueError, AttributeError):
            return
        if offline and not self.stopped.is_set() and self.client is not None:  # not the one stop() sent
            self.client.publish(self.state, self._state(True), qos=1, retain=True)

    def _take(self, verb, edge, device, payload, arrival):
        """The items a message of an edge node brings (the lock held)."""
        node = self.nodes.get(edge)
        if verb == "NBIRTH":
            items = self._end(edge) if node is not None else []
            bdseq = _bdseq(payload)
            node = self.nodes[edge] = _Node(bdseq, self.reorder)
            node.sequence.next = ((payload.seq or 0) + 1) % 256
            return items + self._born(node, edge, None, payload, arrival)
        if verb == "NDEATH":
            if node is None or _bdseq(payload) != node.bdseq:
                return []  # the death of a session this host has not seen born, or an earlier one
            items = self._end(edge)
            return items + [Event("death", None, f"edge node {edge} is offline (NDEATH, bdSeq {node.bdseq})")]
        if node is None:
            return self._rebirth(edge, f"its {verb} came before its NBIRTH")
        if payload.seq is None:
            return [Unreadable(f"edge node {edge}: a {verb} without a seq number")]
        ready, missing = node.sequence.add(payload.seq, (verb, device, payload, arrival), time.monotonic())
        return self._gave_up(edge, missing) + self._ordered(node, edge, ready)

    def _ordered(self, node, edge, messages):
        """The items of a node's messages taken in the order of their seq numbers."""
        items = []
        for verb, device, payload, arrival in messages:
            if verb == "DBIRTH":
                items += self._born(node, edge, device, payload, arrival)
            elif verb == "DDEATH":
                self._unbind(node, edge, device)
                items.append(Event("death", None, f"device {edge}/{device} is offline (DDEATH)"))
            elif device is not None and device not in node.types:
                items += self._rebirth(edge, f"a DDATA of device {device} came before its DBIRTH")
            else:
                items += self._readings(node, edge, device, payload, arrival)
        return items

    def _born(self, node, edge, place, payload, arrival):
        """A birth (NBIRTH: place None; DBIRTH: the device): its metrics, their bindings, its values."""
        self._unbind(node, edge, place)
        node.types[place] = {m.name: m.datatype for m in payload.metrics if m.name is not None}
        node.aliases[place] = {m.alias: m.name for m in payload.metrics if m.name is not None and m.alias is not None}
        what = f"edge node {edge}" if place is None else f"device {edge}/{place}"
        bound, items = [], []
        if self._watched(edge, place):
            for metric, name in self.metrics.items():
                if metric not in node.types[place]:
                    continue
                owner = self.owners.get(name)
                if owner is not None and owner != (edge, place):
                    other = f"edge node {owner[0]}" if owner[1] is None else f"device {owner[0]}/{owner[1]}"
                    items.append(Unreadable(f"{what}: its metric {metric!r} of {name} is also {other}'s, which "
                                            "keeps it (name the edge node and device in --source)"))
                    continue
                self.owners[name] = (edge, place)
                bound.append(name)
        kind = "NBIRTH" if place is None else "DBIRTH"
        items.append(Event("birth", None, f"{what} is online ({kind}{f', bdSeq {node.bdseq}' if place is None else ''}"
                                          f"): {', '.join(bound) if bound else 'no metric of the tags'}"))
        return items + self._readings(node, edge, place, payload, arrival)

    def _readings(self, node, edge, place, payload, arrival):
        """The readings of the bound metrics in a birth or data message: the historical ones first, in
        the order of their times, then the live ones; a metric that is no number is malformed."""
        live, history, items, unknown = [], [], [], []
        for metric in payload.metrics:
            name = metric.name if metric.name is not None else node.aliases.get(place, {}).get(metric.alias)
            if name is None:
                unknown.append(metric.alias)
                continue
            spec = self.metrics.get(name)
            if spec is None or self.owners.get(spec) != (edge, place):
                continue
            stamp = metric.timestamp if metric.timestamp is not None else payload.timestamp
            try:
                value = reading(metric, metric.datatype or node.types[place].get(name), spec)
                if metric.historical and stamp is None:
                    raise Malformed(f"{spec}: historical metric {name!r} without a timestamp")
            except Malformed as exc:
                items.append(Unreadable(f"{edge if place is None else f'{edge}/{place}'}: {exc}"))
                continue
            (history if metric.historical else live).append((spec, value, None if stamp is None else stamp / 1000))
        dropped = [r for r in history if r[0] in self.by_arrival]
        if dropped:
            items.append(Event("late", dropped[0][0] if len({r[0] for r in dropped}) == 1 else None,
                               f"{len(dropped)} historical readings of {', '.join(sorted({r[0] for r in dropped}))} "
                               "not used: a tag read at its arrival time cannot place them", dropped[0][2]))
        history = sorted((r for r in history if r[0] not in self.by_arrival), key=lambda r: r[2])
        items += [Readings(group, arrival) for group in (history, live) if group]
        if unknown:
            items += self._rebirth(edge, f"its metrics of aliases {', '.join(map(str, unknown))} are not in its birth")
        return items

    def _unbind(self, node, edge, place):
        """A place's metrics are no longer its (a death, or a new birth)."""
        node.types.pop(place, None)
        node.aliases.pop(place, None)
        self.owners = {name: owner for name, owner in self.owners.items() if owner != (edge, place)}

    def _end(self, edge):
        """The end of a node's session (a death, or a new birth): what it holds goes on first."""
        node, items = self.nodes.pop(edge), []
        if node.sequence.held:
            ready, missing = node.sequence.give_up()
            items = self._gave_up(edge, missing, ask=False) + self._ordered(node, edge, ready)
        for place in list(node.types):
            self._unbind(node, edge, place)
        return items

    def _gave_up(self, edge, missing, ask=True):
        """The event of seq numbers that never came, and the rebirth that brings the values again."""
        if not missing:
            return []
        numbers = ", ".join(map(str, missing)) if len(missing) < 4 else f"{missing[0]}, ... {missing[-1]}"
        event = Event("sequence", None, f"edge node {edge}: seq {numbers} lost (not there within {self.reorder:g} s "
                                        f"or {HOLD} messages); the ones after went on in order")
        return [event] + (self._rebirth(edge, "messages were lost", force=True) if ask else [])

    def _rebirth(self, edge, why, force=False):
        """Ask a node for a rebirth (at most once every ASK_AGAIN seconds unless `force`): an NCMD of
        Node Control/Rebirth = true; its `rebirth` event."""
        now = time.monotonic()
        if not force and now - self.asked.get(edge, -ASK_AGAIN) < ASK_AGAIN:
            return []
        self.asked[edge] = now
        stamp = int(time.time() * 1000)
        command = Payload(stamp, None, (Metric(REBIRTH, timestamp=stamp, datatype=BOOLEAN, value=True),))
        client = self.client
        if client is not None:  # None once stopped
            client.publish(f"{NAMESPACE}/{self.group}/NCMD/{edge}", encode(command), qos=0)
        return [Event("rebirth", None, f"asked edge node {edge} for a rebirth: {why}")]

    def _watched(self, edge, place) -> bool:
        """Whether the URL names this node's (place None) or this device's metrics."""
        return self.edge in (None, edge) and self.device in (None, place)

    def _clock(self):
        """Give up the gaps whose held messages have waited the reorder timeout."""
        while not self.stopped.wait(TICK):
            with self.lock:
                for edge, node in list(self.nodes.items()):
                    ready, missing = node.sequence.expire(time.monotonic())
                    for item in self._gave_up(edge, missing) + self._ordered(node, edge, ready):
                        self.put(item)


def _bdseq(payload) -> int | None:
    """The bdSeq metric of an NBIRTH or NDEATH (None without one)."""
    return next((m.value for m in payload.metrics if m.name == BDSEQ), None)


def _identifier(text) -> bool:
    """A Sparkplug id: a topic level without MQTT's wildcards."""
    return bool(text) and not set(text) & set("+#/")
