"""The monitor's conclusions published on an MQTT broker (`monitor --publish mqtt://HOST:PORT/PREFIX`,
or mqtts:// over TLS): a sink of jmlgdsl.monitor.sinks.outbox, on a connection of its own (client id the
source's with -publish, a clean session):

    PREFIX/state    each diagnosed row's state, retained (a subscriber that comes later is sent the latest)
    PREFIX/alarm    each alarm transition (raised, cleared, acknowledged, shelved, unshelved), not retained

and for the units of a fleet PREFIX/UNIT/state and PREFIX/UNIT/alarm (or where {unit} stands in
PREFIX). Every message is JSON at QoS 1, delivered once the broker acknowledges it (PUBACK); paho
keeps what it could not send while the broker is away and sends it when it is back. A broker that
is down is tried again after 1 to 30 s, each attempt an event; a refused user name or password, or a
certificate --publish-ca-file (or the system) does not trust, stops the monitor with a message.
"""

from __future__ import annotations

import queue
import sys
import time

from ..sources import bus
from ..sources.contract import Event, Fatal
from ..units import PLACEHOLDER, for_unit
from ..sources.mqtt import REFUSED, Waits, closed, paho_client
from ..sources.urls import address
from ...errors import JmlgError

WINDOW = 1_000  # messages sent and not yet acknowledged by the broker, at most (the rest wait in the store)
TOPICS = {"state": "state", "transition": "alarm"}  # a conclusion's kind -> the last level of its topic


class MqttPublisher:
    """A sink (jmlgdsl.monitor.sinks.outbox) that publishes each conclusion on an MQTT broker."""

    takes_states = True

    def __init__(self, url: str, *, client_id: str, credentials=None, ca_file: str | None = None):
        if not url.startswith(("mqtt://", "mqtts://")):
            raise JmlgError(f"--publish {url}: use mqtt://HOST:PORT/PREFIX or mqtts://HOST:PORT/PREFIX")
        self.tls = url.startswith("mqtts://")
        self.host, self.port, self.prefix = address(url, 8883 if self.tls else 1883, "--publish")
        self.name = f"{'mqtts' if self.tls else 'mqtt'}://{self.host}:{self.port}/{self.prefix}"
        self.template = (self.prefix if PLACEHOLDER in self.prefix
                         else "/".join(filter(None, (self.prefix, PLACEHOLDER))))  # a unit's PREFIX/{unit}
        self.client_id, self.credentials, self.ca_file = client_id, credentials, ca_file
        self.sent = {}  # message id -> Conclusion, until the broker acknowledges it
        self.acknowledged = queue.SimpleQueue()  # message ids, from paho's thread
        self.done = []  # acknowledged, for the next delivered()
        self.connected = False
        self.client = None

    def topic(self, conclusion) -> str:
        where = self.prefix if conclusion.unit is None else for_unit(self.template, conclusion.unit)
        return "/".join(filter(None, (where, TOPICS[conclusion.kind])))

    def start(self, report):
        client = paho_client(self.client_id, self.credentials, self.ca_file, tls=self.tls)
        where = f"{self.host}:{self.port}"

        def event(happened: Event):
            report(Event("delivery", None, f"publish {self.name}: {happened.detail}"))

        waits = Waits()

        def on_connect(client, userdata, flags, reason, properties):
            if reason.is_failure:
                if reason.value in REFUSED:
                    client.disconnect()
                    report(Fatal(bus.refused(f"--publish {self.name}", "broker", reason, "--publish-")))
                else:
                    event(bus.unreachable(where, f"it refused the connection: {reason}", waits.next()))
                return
            waits.connected()
            self.connected = True
            event(bus.connected(where, f"as {self.client_id}"))

        def on_connect_fail(client, userdata):
            error = sys.exc_info()[1]  # paho calls this while it handles the connection's OSError
            fatal = bus.untrusted(f"--publish {self.name}", self.port, error, "--publish-ca-file")
            if fatal:
                report(Fatal(fatal))
            else:
                event(bus.unreachable(where, error or "no answer", waits.next()))

        def on_disconnect(client, userdata, flags, reason, properties):
            self.connected = False
            if self.client is not None:
                event(bus.lost(where, closed(reason), waits.next()))

        def on_publish(client, userdata, mid, reason, properties):
            self.acknowledged.put(mid)  # paho holds its own lock here: nothing more

        client.on_connect, client.on_connect_fail = on_connect, on_connect_fail
        client.on_disconnect, client.on_publish = on_disconnect, on_publish
        self.client = client
        client.connect_async(self.host, self.port, keepalive=30)
        client.loop_start()

    def room(self) -> int:
        return WINDOW - len(self.sent)

    def send(self, conclusion):
        info = self.client.publish(self.topic(conclusion), conclusion.json(), qos=1, retain=conclusion.kind == "state")
        self.sent[info.mid] = conclusion

    def delivered(self) -> list:
        self._take()
        done, self.done = self.done, []
        return done

    def _take(self):
        """Move what the broker acknowledged from `sent` to `done`."""
        for mid in bus.drained(self.acknowledged):
            if mid in self.sent:
                self.done.append(self.sent.pop(mid))

    def stop(self, wait: float):
        """Wait up to `wait` seconds, while connected, for the broker to acknowledge what was sent; then
        disconnect."""
        client, deadline = self.client, time.monotonic() + wait
        while client is not None and self.sent and self.connected and time.monotonic() < deadline:
            time.sleep(0.01)
            self._take()
        self.client = None
        if client is not None:
            client.disconnect()
            client.loop_stop()
