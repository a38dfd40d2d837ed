"""Readings from an OPC UA server (asyncua): a subscription to the data changes of the node each tag
names (`node = "ns=2;s=..."` in the tag file), every change of value, status or source time stamp
reported, and queued by the server between its publish responses. A value whose status is not good
(the server has none yet, the sensor failed) is no reading: the tag's reading for that row is
missing, and it goes stale if that lasts.

OPC UA has no redelivery: a change that happens while the monitor is away is not sent again (the
first notification after a connect is each node's current value, a `late` event when its row has
been diagnosed). So what the store holds of the source (the rows committed and the assembler's open
rows) is all the monitor can promise: after a restart or an outage it reads on from the next change,
and the rows between are a gap of missing readings. A server that is down at start, or lost later,
is tried again with a growing delay (1 s to 30 s), each attempt a `disconnect` event; a refused user
name, password or certificate, a security policy the server does not offer, or a node it does not
have stops the monitor with a message.

A publish response holds its changes grouped by node (every change of one tag, then the next tag's);
they are handed on together, so that rows are assembled from all of them and not closed by one
tag's later readings before another's arrive.
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time
from datetime import datetime, timezone

from asyncua import Client, ua
from asyncua.crypto import security_policies

from ...errors import JmlgError
from . import bus
from ..units import PLACEHOLDER, FleetError, unit_tags
from .contract import Fatal, Readings, Unreadable
from .payload import Malformed, number
from .tags import TagError
from .units import UnitSources
from .urls import address

PUBLISH = 100.0  # milliseconds between the server's publish responses
QUEUE = 10_000  # changes the server keeps per node between two publish responses
TIMEOUT = 5.0  # seconds a request to the server may take
POLL = 0.05  # seconds between looks at the stop and connection-lost flags
MODES = ("Sign", "SignAndEncrypt")
REFUSED = (ua.uaerrors.BadUserAccessDenied, ua.uaerrors.BadIdentityTokenInvalid,
           ua.uaerrors.BadIdentityTokenRejected, ua.uaerrors.BadCertificateInvalid,
           ua.uaerrors.BadCertificateUntrusted, ua.uaerrors.BadSecurityChecksFailed,
           ua.uaerrors.BadSecurityPolicyRejected, ua.uaerrors.BadSecurityModeRejected)

logging.getLogger("asyncua").addHandler(logging.NullHandler())  # its warnings are the monitor's events


class Stop(Exception):
    """What trying again would not mend; its message is the monitor's."""


def open_source(connection, model, tags, units=None):
    """The server a connection names; for a fleet's units, a session per unit, each reading the nodes
    of its tags (node ids with {unit} in them)."""
    security = dict(credentials=connection.credentials, security=connection.security,
                    certificate=connection.certificate, private_key=connection.private_key)
    if units is None:
        return OpcuaSource(connection.url, model, tags, **security)
    plain = sorted(name for name, tag in tags.items() if PLACEHOLDER not in (tag.node or ""))
    if plain:
        raise FleetError(f"--units with an OPC UA source: the tag file's node id of {plain[0]} holds no "
                         f"{PLACEHOLDER}, so every unit would read the same node")
    return UnitSources([OpcuaSource(connection.url, model, unit_tags(tags, unit), **security) for unit in units],
                       connection.url)


class OpcuaSource:
    """A server's data changes as Readings (jmlgdsl.monitor.sources.contract); nothing to
    acknowledge. `security`: "POLICY,MODE" (e.g. "Basic256Sha256,SignAndEncrypt") with the client's
    `certificate` and `private_key` files."""

    rows = False

    def __init__(self, url, model, tags, *, credentials=None, security=None, certificate=None, private_key=None):
        host, port, path = address(url, 4840)
        self.where = f"{host}:{port}"
        self.name = self.url = f"opc.tcp://{host}:{port}/{path}"
        self.nodes = _nodes(tags)
        self.credentials = credentials
        self.security = security_options(security, certificate, private_key)
        self._stop = threading.Event()
        self._thread = None

    def start(self, put, position):
        """Connect and subscribe in a thread with its own event loop, until stop()."""
        self._thread = threading.Thread(target=asyncio.run, args=(self._serve(put),), name="opc ua source",
                                        daemon=True)
        self._thread.start()

    def acknowledge(self, tokens):
        """Nothing to acknowledge: a server does not send a change again."""

    def stop(self):
        self._stop.set()
        if self._thread is not None:
            self._thread.join(TIMEOUT)

    async def _serve(self, put):
        delays = bus.delays()
        while not self._stop.is_set():
            lost = []
            client = Client(self.url, timeout=TIMEOUT)
            client.connection_lost_callback = _append_to(lost)
            try:
                await self._connect(client)
                await self._subscribe(client, put)
            except Stop as exc:
                await _disconnect(client)
                put(Fatal(str(exc)))
                return
            except (OSError, asyncio.TimeoutError, ua.UaError) as exc:
                await _disconnect(client)
                delay = next(delays)
                put(bus.unreachable(self.where, _why(exc), delay))
                await self._wait(delay)
                continue
            delays = bus.delays()
            put(bus.connected(self.where, f"{len(self.nodes)} nodes, security "
                                          f"{self.security[0] if self.security else 'None'}"))
            await self._wait(None, lost)
            await _disconnect(client)
            if lost:
                put(bus.lost(self.where, _why(lost[0]), 0))

    async def _connect(self, client):
        if self.credentials is not None:
            client.set_user(self.credentials[0])
            client.set_password(self.credentials[1])
        try:
            if self.security:
                policy, mode, certificate, private_key = self.security
                await client.set_security(getattr(security_policies, f"SecurityPolicy{policy}"), certificate,
                                          private_key, mode=getattr(ua.MessageSecurityMode, mode))
            await client.connect()
        except REFUSED as exc:
            raise Stop(bus.refused(self.name, "server", type(exc).__name__)) from None
        except ua.UaError as exc:
            if isinstance(exc, ua.UaStatusCodeError):
                raise
            raise Stop(await self._no_endpoint(client)) from None  # no endpoint of this policy and mode

    async def _no_endpoint(self, client) -> str:
        """Why a server's endpoints do not fit --security, with the ones it offers."""
        asked = ",".join(self.security[:2]) if self.security else "None"
        try:
            offered = sorted({f"{ep.SecurityPolicyUri.rpartition('#')[2]},{ep.SecurityMode.name}"
                              for ep in await client.connect_and_get_server_endpoints()})
        except (OSError, asyncio.TimeoutError, ua.UaError):
            offered = []
        return (f"{self.name}: the server has no endpoint with security {asked}"
                + (f"; it offers {', '.join(offered)}" if offered else "")
                + " (see --security, --certificate and --private-key)")

    async def _subscribe(self, client, put):
        changes = _Changes(self.nodes, put)
        subscription = await client.create_subscription(PUBLISH, changes)
        requests = [_request(handle, node) for handle, (_, node, _) in changes.handles.items()]
        for (name, _, text), result in zip(changes.handles.values(),
                                           await subscription.create_monitored_items(requests)):
            if isinstance(result, ua.StatusCode):
                raise Stop(f"{self.name}: [tags.{name}]: node {text!r}: {result.name}")

    async def _wait(self, seconds, lost=()):
        """Until `seconds` have passed (None: for ever), the connection is lost or stop() is called."""
        end = None if seconds is None else time.monotonic() + seconds
        while not self._stop.is_set() and not lost and (end is None or time.monotonic() < end):
            await asyncio.sleep(POLL)


class _Changes:
    """The subscription's handler: the data changes of one publish response gathered (asyncua calls
    the handler once per change, all before the event loop's next round) and handed on together."""

    def __init__(self, nodes, put):
        self.handles = dict(enumerate(nodes, start=1))  # client handle -> (name, node id, its text)
        self.put, self.pending = put, []

    def datachange_notification(self, node, value, data):
        if not self.pending:
            asyncio.get_running_loop().call_soon(self.flush)
        self.pending.append((data.subscription_data.client_handle, data.monitored_item.Value))

    def flush(self):
        arrival, readings = time.time(), []
        for handle, value in self.pending:
            name, _, text = self.handles[handle]
            if value.StatusCode is not None and not value.StatusCode.is_good():
                continue  # no reading (say, waiting for its first value): missing, as a reading that never came
            try:
                readings.append((name, _value(name, value), _stamp(value.SourceTimestamp)))
            except Malformed as exc:
                self.put(Unreadable(f"node {text}: {exc}"))
        self.pending = []
        if readings:
            self.put(Readings(readings, arrival))


def _nodes(tags):
    """[(name, NodeId, text)] of the tags; each needs a node of its own."""
    nodes, seen = [], {}
    for name, tag in tags.items():
        if tag.node is None:
            raise TagError(f"[tags.{name}]: an OPC UA source reads each spec name from a node: give its node id "
                           f"in the tag file (--tags), e.g. node = \"ns=2;s=Plant.{name}\"")
        try:
            node = ua.NodeId.from_string(tag.node)
        except (ValueError, ua.UaError):
            raise TagError(f"[tags.{name}]: node {tag.node!r} is not an OPC UA node id (e.g. \"ns=2;s=Plant."
                           f"{name}\" or \"ns=2;i=1001\")") from None
        if node in seen:
            raise TagError(f"[tags.{name}]: node {tag.node!r} is also the node of [tags.{seen[node]}]")
        seen[node] = name
        nodes.append((name, node, tag.node))
    return nodes


def security_options(security, certificate, private_key, options: str = "--", whose: str = "client"):
    """(policy, mode, certificate, private key) from --security POLICY,MODE and the `whose` (the
    client's, or with `options` "--opcua-server-" the server's) --certificate and --private-key; None
    without it."""
    if security is None:
        if certificate or private_key:
            raise JmlgError(f"{options}certificate and {options}private-key go with {options}security POLICY,MODE")
        return None
    policy, _, mode = security.partition(",")
    policies = sorted(name[len("SecurityPolicy"):] for name in dir(security_policies)
                      if name.startswith("SecurityPolicy") and name not in ("SecurityPolicy", "SecurityPolicyNone",
                                                                             "SecurityPolicyFactory"))
    if policy not in policies or mode not in MODES:
        raise JmlgError(f"{options}security {security}: give POLICY,MODE with POLICY one of {', '.join(policies)} "
                        f"and MODE {' or '.join(MODES)}")
    if not certificate or not private_key:
        raise JmlgError(f"{options}security {security}: give the {whose}'s {options}certificate and "
                        f"{options}private-key files")
    for option, path in ((f"{options}certificate", certificate), (f"{options}private-key", private_key)):
        try:
            with open(path, "rb"):
                pass
        except OSError as exc:
            raise JmlgError(f"{option}: cannot read {path}: {exc.strerror}") from None
    return policy, mode, certificate, private_key


def _request(handle, node):
    """A monitored item for a node: every change of status, value or source time stamp, queued."""
    item = ua.ReadValueId()
    item.NodeId, item.AttributeId = node, ua.AttributeIds.Value
    parameters = ua.MonitoringParameters()
    parameters.ClientHandle, parameters.SamplingInterval, parameters.QueueSize = handle, 0.0, QUEUE
    parameters.DiscardOldest = True
    parameters.Filter = ua.DataChangeFilter(Trigger=ua.DataChangeTrigger.StatusValueTimestamp)
    request = ua.MonitoredItemCreateRequest()
    request.ItemToMonitor, request.MonitoringMode, request.RequestedParameters = item, ua.MonitoringMode.Reporting, \
        parameters
    return request


def _value(name, value) -> float:
    """A data value's number (None: NaN, not measured)."""
    raw = None if value.Value is None else value.Value.Value
    return number(raw, name, str(raw))


def _stamp(stamp) -> datetime | None:
    """A source time stamp, aware (a naive one is UTC); None without one."""
    if stamp is None:
        return None
    return stamp if stamp.tzinfo else stamp.replace(tzinfo=timezone.utc)


def _append_to(lost):
    async def connection_lost(exc):
        lost.append(exc)
    return connection_lost


async def _disconnect(client):
    try:
        await asyncio.wait_for(client.disconnect(), TIMEOUT)
    except Exception:  # a connection already gone has nothing left to close
        pass


def _why(exc) -> str:
    return str(exc) or type(exc).__name__
