"""Readings from an MQTT broker (paho-mqtt 2): each spec name NAME from topic PREFIX/NAME (or the tag
file's topic), and objects of several names per sample on PREFIX itself. For the units of a fleet
(jmlgdsl.monitor.units) the topics are PREFIX/UNIT/NAME and PREFIX/UNIT, all on one connection.

The session is persistent (a fixed client id, clean session off) and subscribed at QoS 1, so the
broker keeps what is published while the monitor is down and delivers it when it is back. Messages
are acknowledged by hand, only once the monitor has committed them to its store: a crash between
the two leaves them unacknowledged, and the broker delivers them again. A broker that is down, at
start or later, is retried with a growing delay (1 s to 30 s), each attempt an event; a refused
user name or password, or an mqtts:// broker whose certificate --ca-file (or the system) does not
trust, stops the monitor with a message that says so.
"""

from __future__ import annotations

import sys
import threading
import time

import paho.mqtt.client as mqtt

from . import bus
from ..units import PLACEHOLDER, for_unit, unit_tags
from .contract import Fatal, Readings, Unreadable
from .payload import Malformed, decode
from .urls import address

REFUSED = (134, 135)  # bad user name or password, not authorized: trying again would not help


def open_source(connection, model, tags, units=None):
    """The broker a connection names, in a persistent session of client id --client-id (default
    jmlgdsl-PLANT; a fleet's shard's with its index)."""
    client_id = connection.client_id or f"jmlgdsl-{model.name}"
    if connection.shard is not None:  # a persistent session of its own
        client_id = f"{client_id}-{connection.shard}"
    return MqttSource(connection.url, model, tags, client_id=client_id, credentials=connection.credentials,
                      ca_file=connection.ca_file, units=units)


class MqttSource:
    """A broker's messages as Readings, Unreadables and Events (jmlgdsl.monitor.sources.contract),
    the messages acknowledged after the commit that holds them. With `units`, every item is handed
    over as (unit index, item) (None: the connection's, for every unit)."""

    rows = False
    persistent = True  # a persistent session whose messages are acknowledged after their commit

    def __init__(self, url, model, tags, *, client_id: str, credentials=None, ca_file=None, units=None):
        self.tls = url.startswith("mqtts://")
        self.host, self.port, prefix = address(url, 8883 if self.tls else 1883)
        self.name = f"{'mqtts' if self.tls else 'mqtt'}://{self.host}:{self.port}/{prefix}"
        self.names = list(model.outputs) + list(model.inputs)
        self.units = units
        self.topics = {}  # topic -> (unit index or None, spec name or None: an object of several names)
        template = prefix if PLACEHOLDER in prefix else "/".join(filter(None, (prefix, PLACEHOLDER)))  # PREFIX/{unit}
        for i, unit in enumerate([None] if units is None else units):
            where = prefix if unit is None else for_unit(template, unit)
            for name, tag in (tags if unit is None else unit_tags(tags, unit)).items():
                self.topics[tag.topic or (f"{where}/{name}" if where else name)] = (i, name)
            if where:
                self.topics[where] = (i, None)
        self.client_id, self.credentials, self.ca_file = client_id, credentials, ca_file
        self.client = None

    def start(self, put, position):
        # A message's packet id means that message only on the connection it came on: the broker gives
        # the id to another message once the first is acknowledged. So a token names its connection
        # (a count of them), and the connection may not change between that check and the ack.
        self.connection, self.acking = 0, threading.Lock()
        client = paho_client(self.client_id, self.credentials, self.ca_file, clean_session=not self.persistent,
                             tls=self.tls)
        client.manual_ack_set(self.persistent)
        where = f"{self.host}:{self.port}"

        def hand(item, unit=None):
            put(item if self.units is None else (unit, item))

        waits = Waits()

        def on_connect(client, userdata, flags, reason, properties):
            if reason.is_failure:
                if reason.value in REFUSED:
                    client.disconnect()
                    hand(Fatal(bus.refused(self.name, "broker", reason)))
                else:
                    hand(bus.unreachable(where, f"it refused the connection: {reason}", waits.next()))
                return
            waits.connected()
            with self.acking:
                self.connection += 1
            self.connected(client, flags, hand)

        def on_connect_fail(client, userdata):
            error = sys.exc_info()[1]  # paho calls this while it handles the connection's OSError
            fatal = bus.untrusted(self.name, self.port, error)
            hand(Fatal(fatal) if fatal else bus.unreachable(where, error or "no answer", waits.next()))

        def on_disconnect(client, userdata, flags, reason, properties):
            if self.client is not None:
                hand(bus.lost(where, closed(reason), waits.next()))

        def on_message(client, userdata, message):
            # Every message is handed on, as readings or as one `malformed` event, and so acknowledged
            # with the next commit: an exception here would end paho's network thread, and the message,
            # never acknowledged, would be delivered again after every restart to end it again.
            try:
                self.received(message, hand)
            except Exception as exc:  # what no reading should raise: reported as the message's fault, not fatal
                hand(Unreadable(f"topic {_topic(message)}: cannot read the message ({type(exc).__name__}: {exc})",
                                self.token(message)))

        client.on_connect, client.on_connect_fail = on_connect, on_connect_fail
        client.on_disconnect, client.on_message = on_disconnect, on_message
        self.client = client
        self.prepare(client)
        client.connect_async(self.host, self.port, keepalive=30)
        client.loop_start()

    def prepare(self, client):
        """Set what the connection needs before it is made: nothing here (a subclass sets its will)."""

    def connected(self, client, flags, hand):
        """The connection is up: subscribe to the tags' topics and say so. `hand(item, unit)` hands an
        item over."""
        client.subscribe([(topic, 1) for topic in self.topics])
        resumed = "resumed its session" if flags.session_present else "a new session"
        hand(bus.connected(f"{self.host}:{self.port}", f"as {self.client_id}, {resumed}"))

    def received(self, message, hand):
        """A message from the broker as readings (or malformed), acknowledged after their commit."""
        token, topic = self.token(message), _topic(message)
        unit, name = self.topics.get(topic, (None, None))
        try:
            if topic not in self.topics:  # a subscription left in the session by an earlier run
                raise Malformed("not a topic of this monitor's tags")
            item = Readings(decode(message.payload, name, self.names), time.time(), token)
        except Malformed as exc:
            item = Unreadable(f"topic {topic}: {exc}", token)
        hand(item, unit)

    def token(self, message):
        """What acknowledges `message` after its commit: its connection, packet id and QoS."""
        return self.connection, message.mid, message.qos

    def acknowledge(self, tokens):
        """Acknowledge the messages of the connection that is up. One that came on an earlier
        connection is left: the broker sends it again on this one (the session is persistent), and
        that copy is acknowledged after its own commit; acknowledging its old packet id here could
        acknowledge another message, not yet committed, that the broker has since given the id."""
        with self.acking:
            for connection, mid, qos in tokens:
                if connection == self.connection:
                    self.client.ack(mid, qos)

    def stop(self):
        client, self.client = self.client, None
        if client is not None:
            client.disconnect()
            client.loop_stop()


def _topic(message) -> str:
    """A message's topic, or what stands for it when its bytes are not UTF-8 text (paho decodes on reading)."""
    try:
        return message.topic
    except UnicodeDecodeError:
        return "(not UTF-8 text)"


class Waits:
    """The waits of a paho client made by paho_client between its attempts to connect (1 s, doubling
    to 30 s, from 1 s again once connected), so that an event can say when the next attempt is."""

    def __init__(self):
        self.connected()

    def connected(self):
        self._delays = bus.delays()

    def next(self) -> float:
        """The wait before the next attempt, after one that failed or a connection lost."""
        return next(self._delays)


def closed(reason) -> str:
    """Why paho says a connection ended, in words: a connection the broker closed (a broker stopped
    or restarted, a network that dropped it) is its 'Unspecified error'."""
    if reason == "Unspecified error":
        return "the broker closed the connection: it stopped or restarted, or the network between dropped it"
    if reason == "Keep alive timeout":
        return "no answer from the broker within the keep-alive time"
    return str(reason)


def paho_client(client_id: str, credentials, ca_file, clean_session: bool = True, tls: bool = False) -> mqtt.Client:
    """A paho client (MQTT 3.1.1) as the monitor's connections use it: its retry delays, the
    credentials (name, password) or None, and with `tls` TLS under the certificate authority
    `ca_file` (None: the system's)."""
    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=client_id, clean_session=clean_session,
                         protocol=mqtt.MQTTv311)
    client.reconnect_delay_set(int(bus.FIRST_RETRY), int(bus.LAST_RETRY))
    if credentials is not None:
        client.username_pw_set(*credentials)
    if tls:
        client.tls_set(ca_certs=ca_file)
    return client
