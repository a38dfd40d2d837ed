"""Readings from UDP datagrams (udp://HOST:PORT): the monitor listens on HOST:PORT, and each datagram
is one sample's object of names, as on an MQTT source's PREFIX topic (`{"t": ..., "temp": ...,
"current": ...}`, jmlgdsl.monitor.sources.payload); one that is not is a `malformed` event.

UDP has no acknowledgement and no redelivery: a datagram sent while the monitor is away, or lost on
the way, is a gap of missing readings, as a change is with OPC UA.
"""

from __future__ import annotations

import socket
import threading
import time

from ...errors import JmlgError
from ..units import FleetError
from .contract import Event, Readings, Unreadable
from .payload import MAX_PAYLOAD, Malformed, decode
from .urls import address

POLL = 0.05  # seconds between looks at the stop flag while no datagram comes
RECEIVE_BUFFER = 4 << 20  # bytes of datagrams the kernel may hold for the source


def open_source(connection, model, tags, units=None):
    if units is not None:
        raise FleetError("--units with a UDP source: not supported; run a monitor for each unit, on a port of its own")
    return UdpSource(connection.url, model)


class UdpSource:
    """The datagrams sent to HOST:PORT, as readings; nothing to acknowledge."""

    rows = False

    def __init__(self, url: str, model):
        self.host, self.port, path = address(url, 0)
        if not self.port or path:
            raise JmlgError(f"--source {url}: give the host and port to listen on, udp://HOST:PORT")
        self.name = f"udp://{self.host}:{self.port}"
        self.names = list(model.outputs) + list(model.inputs)
        self._stop = threading.Event()
        self._thread = None

    def start(self, put, position):
        """Listen, and read the datagrams in a thread until stop()."""
        family, kind, proto, _, where = socket.getaddrinfo(self.host, self.port, type=socket.SOCK_DGRAM)[0]
        listener = socket.socket(family, kind, proto)
        try:
            listener.bind(where)
        except OSError as exc:
            listener.close()
            raise JmlgError(f"--source {self.name}: cannot listen there ({exc.strerror})") from None
        listener.settimeout(POLL)
        # A burst waits in the kernel while a commit runs; what overflows the buffer is lost, so ask for
        # a large one (the kernel caps it at net.core.rmem_max).
        listener.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECEIVE_BUFFER)
        put(Event("connect", None, f"listening on {self.host}:{self.port}"))
        self._thread = threading.Thread(target=self._read, args=(listener, put), name="udp source", daemon=True)
        self._thread.start()

    def _read(self, listener, put):
        with listener:
            while not self._stop.is_set():
                try:
                    data, sender = listener.recvfrom(MAX_PAYLOAD + 1)  # one byte more: a longer one is refused
                except socket.timeout:
                    continue
                try:
                    put(Readings(decode(data, None, self.names), time.time()))
                except Malformed as exc:
                    put(Unreadable(f"datagram from {sender[0]}: {exc}"))

    def acknowledge(self, tokens):
        """Nothing to acknowledge: UDP does not send a datagram again."""

    def stop(self):
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
