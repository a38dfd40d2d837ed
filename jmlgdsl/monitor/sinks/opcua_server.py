"""The monitor's conclusions served over OPC UA (`monitor --opcua-server opc.tcp://HOST:PORT/PATH`):
a sink of jmlgdsl.monitor.sinks.outbox, an asyncua server in a thread with its own event loop, for a
SCADA, an HMI or a historian to read, to subscribe to, and to acknowledge and shelve alarms on.

Its namespace urn:jmlgdsl:diagnosis holds under Objects an object for the plant (ns=2;s=PLANT)
and, for the units of a fleet, one under it for each (ns=2;s=PLANT.UNIT), with the variables

    Mode          String    the most probable mode of the newest row
    Probability   Double    its probability
    Modes/NAME    Double    every mode's probability, by the spec's mode names
    Alarm         Boolean   whether the alarm rule holds an alarm at that row
    AlarmId       Int64     that alarm's id, the store's and the page's (0: none)
    Run, T        Int64     the store's run, the row's number in it
    Time          Double    the row's time in seconds, as the store holds it (none for rows without)

and under its Alarms object each alarm that is not done (still active, unacknowledged or shelved) as
an Alarms & Conditions OffNormalAlarm, ns=2;s=PLANT[.UNIT].AlarmID, with its ISA-18.2 state in
words (State). Each transition (raised, cleared, acknowledged, shelved, unshelved) is an event of
the Server object of type OffNormalAlarmType, with the condition's states after it (ActiveState,
AckedState, ShelvingState, Retain: false once it is done, and the condition is gone);
ConditionRefresh sends the conditions that are not done again.

A client's Acknowledge(EventId, Comment), OneShotShelve2(Comment), Unshelve() and Unshelve2(Comment)
are the page's Acknowledge, Shelve (the comment is its reason, which shelving needs: OneShotShelve
without one is refused) and Unshelve: recorded in the store's action table (Store.act) as done by
the client's user (or, for an anonymous session, by its address), so the page shows them; the
event of the new state follows when the monitor hands the action on, as it does for the page's.
The page's shelving lasts until it is undone, so TimedShelve is refused.

An OPC UA server keeps no history for its clients: the server of a monitor started again shows at
once the store's state (each unit's newest row, the alarms not done), and passes over, as
delivered, the conclusions that state already holds; the events of a time it was not running are
not sent.
"""

from __future__ import annotations

import asyncio
import collections
import contextvars
import copy
import hmac
import logging
import queue
import threading
import time

from asyncua import Server, ua
from asyncua.crypto.permission_rules import User, UserRole
from asyncua.server.internal_server import InternalServer
from asyncua.server.internal_session import InternalSession

from ...errors import JmlgError
from ..sources import bus
from ..sources.contract import Event, Fatal
from ..sources.opcua import security_options
from ..store import LONGEST, Store, StoreError, row_state
from ..sources.urls import address

logging.getLogger("asyncua").addHandler(logging.NullHandler())  # its warnings are the monitor's events

NAMESPACE = "urn:jmlgdsl:diagnosis"
QUEUE = 1_000  # conclusions handed and not yet applied, at most (the rest wait in the store)
TIMEOUT = 5.0  # seconds the server has to stop, beyond the outbox's wait
SEVERITY = 800  # of every alarm (1 to 1000)
WAITING = ua.StatusCode(ua.StatusCodes.BadWaitingForInitialData)
# a unit's variables: name, type, and a value of that type to make it with (shown as waiting for a first row)
STATE = [("Mode", ua.VariantType.String, ""), ("Probability", ua.VariantType.Double, 0.0),
         ("Alarm", ua.VariantType.Boolean, False), ("AlarmId", ua.VariantType.Int64, 0),
         ("Run", ua.VariantType.Int64, 0), ("T", ua.VariantType.Int64, 0), ("Time", ua.VariantType.Double, 0.0)]
SHELVED = {True: ("OneShotShelved", ua.ObjectIds.ShelvedStateMachineType_OneShotShelved),
           False: ("Unshelved", ua.ObjectIds.ShelvedStateMachineType_Unshelved)}
# the condition's variables that show its last event (its A&C state), beside the event itself
SHOWN = ("EventId", "Time", "ReceiveTime", "Message", "Severity", "LastSeverity", "Retain", "ConditionName",
         "EnabledState", "EnabledState/Id", "ActiveState", "ActiveState/Id", "AckedState", "AckedState/Id",
         "ShelvingState/CurrentState", "ShelvingState/CurrentState/Id", "SuppressedOrShelved", "Comment",
         "ClientUserId")
CALLER = contextvars.ContextVar("caller")  # the session whose method call is running


class OpcuaServer:
    """A sink (jmlgdsl.monitor.sinks.outbox) that serves each unit's newest state and its alarms over OPC UA.
    `store` and `password`: the monitor's store, which it reads its runs from and writes the clients'
    actions to; `units`: the fleet's (None: one plant); `credentials`: the one (user, password) let
    in (None: anonymous clients); `security`: "POLICY,MODE" with the server's `certificate` and
    `private_key` files (None: no security)."""

    takes_states = True

    def __init__(self, url: str, *, store: str, password: str | None = None, units=None, credentials=None,
                 security: str | None = None, certificate: str | None = None, private_key: str | None = None):
        if not url.startswith("opc.tcp://"):
            raise JmlgError(f"--opcua-server {url}: use opc.tcp://HOST:PORT/PATH")
        self.host, self.port, path = address(url, 4840, "--opcua-server")
        self.name = self.url = f"opc.tcp://{self.host}:{self.port}/{path}"
        self.location, self.password, self.units, self.credentials = store, password, units, credentials
        self.security = security_options(security, certificate, private_key, "--opcua-server-", "server")
        self.inbox = collections.deque()  # handed by the monitor's thread, applied by the server's
        self.done = queue.SimpleQueue()
        self.handed = self.applied = 0
        self.closing, self.deadline = False, None
        self.loop = self.thread = self.wake = None
        self.served = {}  # run id -> _Unit
        self.targets = {}  # the node id a client calls a condition's method on -> (_Unit, _Condition)

    def start(self, report):
        self.loop, self.wake = asyncio.new_event_loop(), asyncio.Event()
        self.thread = threading.Thread(target=self.loop.run_until_complete, args=(self._serve(report),),
                                       name="opc ua server", daemon=True)
        self.thread.start()

    def room(self) -> int:
        return QUEUE - (self.handed - self.applied)

    def send(self, conclusion):
        self.inbox.append(conclusion)
        self.handed += 1
        self.loop.call_soon_threadsafe(self.wake.set)

    def delivered(self) -> list:
        return bus.drained(self.done)

    def stop(self, wait: float):
        """Apply what was handed for up to `wait` seconds, then stop the server."""
        if self.thread is None:
            return
        self.deadline = time.monotonic() + wait
        self.loop.call_soon_threadsafe(self._close)
        self.thread.join(wait + TIMEOUT)
        if not self.thread.is_alive():
            self.loop.close()
        self.thread = None

    def _close(self):
        self.closing = True
        self.wake.set()

    # ------------------------------------------------------------------ the server's thread
    async def _serve(self, report):
        """Start the server with the store's state, then apply each conclusion handed, in order."""
        self.store = server = None
        try:
            server = await self._open()
        except (OSError, StoreError, ua.UaError, asyncio.TimeoutError) as exc:
            report(Fatal(f"--opcua-server {self.name}: cannot serve ({getattr(exc, 'strerror', None) or exc})"))
        except Exception as exc:  # what the thread would otherwise take with it unseen
            report(Fatal(f"--opcua-server {self.name}: cannot serve ({type(exc).__name__}: {exc})"))
        if server is None:
            if self.store is not None:
                self.store.close()
            return
        report(Event("delivery", None, f"opcua-server {self.name}: serving {len(self.served)} "
                                       f"unit{'s' * (len(self.served) != 1)}, security "
                                       f"{','.join(self.security[:2]) if self.security else 'None'}"))
        try:
            while not self.closing:
                await self.wake.wait()
                self.wake.clear()
                while self.inbox and not (self.closing and time.monotonic() > self.deadline):
                    conclusion = self.inbox.popleft()
                    await self._apply(conclusion)
                    self.applied += 1
                    self.done.put(conclusion)
        except Exception as exc:  # what the thread would otherwise take with it unseen
            report(Fatal(f"--opcua-server {self.name}: stopped serving ({type(exc).__name__}: {exc})"))
        finally:
            await server.stop()
            self.store.close()

    async def _open(self) -> Server:
        """The server with a unit's nodes for each of the monitor's runs, showing the store's state."""
        self.store = Store(self.location, password=self.password, create=False)
        runs = [self.store.run(unit=unit) for unit in self.units] if self.units else [self.store.run()]
        self.server = server = Server(iserver=_Sessions(user_manager=_Users(self.credentials)))
        await server.init()
        server.set_endpoint(self.url)
        server.set_server_name(f"jmlgdsl {runs[0].plant}")
        if self.security:
            policy, mode, certificate, private_key = self.security
            await server.load_certificate(certificate)
            await server.load_private_key(private_key)
            server.set_security_policy([getattr(ua.SecurityPolicyType, f"{policy}_{mode}")])
        else:
            server.set_security_policy([ua.SecurityPolicyType.NoSecurity])
        server.set_identity_tokens([ua.UserNameIdentityToken if self.credentials else ua.AnonymousIdentityToken])
        self.ns = await server.register_namespace(NAMESPACE)
        self.generator = await server.get_event_generator(ua.ObjectIds.OffNormalAlarmType, ua.ObjectIds.Server)
        self.template = self.generator.event
        self.template.add_property("ShelvingState/CurrentState", None, ua.VariantType.LocalizedText)
        self.template.add_property("ShelvingState/CurrentState/Id", None, ua.VariantType.NodeId)
        for methods, callback in METHODS:
            for method in methods:
                server.link_method(server.get_node(ua.NodeId(method)), getattr(self, callback))
        plant = await server.nodes.objects.add_object(ua.NodeId(runs[0].plant, self.ns), runs[0].plant)
        for run in runs:
            self.served[run.id] = await self._unit(plant, run)
        await server.start()
        for unit in self.served.values():
            await self._show_stored(unit)
        return server

    async def _unit(self, plant, run) -> "_Unit":
        """A unit's object (the plant's own for one plant) with its variables, waiting for a first row."""
        parent, base = (plant, run.plant) if run.unit is None else (
            await plant.add_object(ua.NodeId(f"{run.plant}.{run.unit}", self.ns), run.unit), f"{run.plant}.{run.unit}")
        unit = _Unit(run, parent, base)
        modes = await parent.add_object(ua.NodeId(f"{base}.Modes", self.ns), "Modes")
        for name, kind, blank in STATE:
            unit.nodes[name] = (await parent.add_variable(ua.NodeId(f"{base}.{name}", self.ns), name, blank,
                                                          kind)).nodeid
        for mode in run.modes:
            unit.nodes[f"Modes.{mode}"] = (await modes.add_variable(ua.NodeId(f"{base}.Modes.{mode}", self.ns), mode,
                                                                    0.0, ua.VariantType.Double)).nodeid
        for nodeid in unit.nodes.values():
            await self._write(nodeid, ua.DataValue(StatusCode=WAITING))
        await self._write(unit.nodes["Run"], run.id, ua.VariantType.Int64)
        unit.alarms = await parent.add_object(ua.NodeId(f"{base}.Alarms", self.ns), "Alarms")
        return unit

    async def _show_stored(self, unit):
        """Show a unit's newest row and its alarms that are not done as the store holds them now; the
        conclusions this covers are passed over when they are handed."""
        run = unit.run
        unit.actions = self.store.newest_action(run.id)
        row = self.store.newest(run)
        unit.t = 0 if row is None else row.t
        alarms = [a for a in self.store.alarms(run.id, unit.actions) if a.raised_t <= unit.t]
        active = {a.id: a.cleared_t is None or a.cleared_t > unit.t for a in alarms}
        if row is not None:
            opened = next((a.id for a in alarms if active[a.id]), None)
            await self._show_state(unit, row_state(run.plant, run, row, opened))
        for a in alarms:
            if active[a.id] or not a.acknowledged or a.shelved:
                condition = await self._condition(unit, a.id, a.mode, active[a.id], bool(a.acknowledged),
                                                  bool(a.shelved))
                await self._fire(unit, condition, a.state, f"{unit.source}: alarm {a.id} ({a.mode}) {a.state}")

    # ------------------------------------------------------------------ conclusions into the address space
    async def _apply(self, conclusion):
        body, unit = conclusion.body, self.served.get(conclusion.run)
        if unit is None or ("action" in body and body["action"] <= unit.actions) or (
                "action" not in body and body["t"] <= unit.t):
            return  # not a run of this server's, or what it shows already
        if conclusion.kind == "state":
            await self._show_state(unit, body)
            return
        alarm, transition = body["alarm"], body["transition"]
        condition = unit.conditions.get(alarm)
        if condition is None:
            if transition == "raised":
                condition = await self._condition(unit, alarm, body["mode"], True, False, False)
            else:  # an alarm done before (acknowledged and cleared) that is shelved now
                found = {a.id: a for a in self.store.alarms(unit.run.id)}[alarm]
                condition = await self._condition(unit, alarm, found.mode, found.cleared_t is None,
                                                  bool(found.acknowledged), bool(found.shelved))
        if transition in ("raised", "cleared"):
            condition.active = transition == "raised"
        elif transition == "acknowledged":
            condition.acked = True
        else:
            condition.shelved = transition == "shelved"
        await self._fire(unit, condition, body["state"], body["text"], body.get("who"), body.get("reason"))

    async def _show_state(self, unit, body):
        """A row's state in the unit's variables."""
        values = {"Mode": body["mode"], "Probability": body["probability"], "Alarm": body["alarm"],
                  "AlarmId": body["alarm_id"] or 0, "T": body["t"], "Time": body["time"]}
        for name, kind, _ in STATE:
            if values.get(name) is not None:
                await self._write(unit.nodes[name], values[name], kind)
        for mode, probability in body["modes"].items():
            await self._write(unit.nodes[f"Modes.{mode}"], probability, ua.VariantType.Double)

    async def _condition(self, unit, alarm: int, mode, active: bool, acked: bool, shelved: bool) -> "_Condition":
        """An alarm's condition node under the unit's Alarms, its methods linked."""
        name = f"Alarm{alarm}"
        node = await unit.alarms.add_object(ua.NodeId(f"{unit.base}.{name}", self.ns), name,
                                            objecttype=ua.NodeId(ua.ObjectIds.OffNormalAlarmType))
        condition = _Condition(alarm, mode, node, active, acked, shelved)
        await node.add_property(ua.NodeId(f"{unit.base}.{name}.State", self.ns), "State", "", ua.VariantType.String)
        shelving = ua.NodeId(f"{unit.base}.{name}.ShelvingState", self.ns)
        for target in (node.nodeid, shelving):
            self.targets[target] = unit, condition
        for path, callback in (("Acknowledge", "_acknowledge"), ("ShelvingState.OneShotShelve", "_one_shot_shelve"),
                               ("ShelvingState.TimedShelve", "_timed_shelve"), ("ShelvingState.Unshelve", "_unshelve")):
            self.server.link_method(self.server.get_node(ua.NodeId(f"{unit.base}.{name}.{path}", self.ns)),
                                    getattr(self, callback))
        unit.conditions[alarm] = condition
        return condition

    async def _fire(self, unit, condition, words: str, text: str, who: str | None = None, reason: str | None = None):
        """The condition's event with its state now, shown on its node too; a condition done is removed."""
        done = not condition.active and condition.acked and not condition.shelved
        event = copy.deepcopy(self.template)
        shelving, shelving_id = SHELVED[condition.shelved]
        fields = {"NodeId": condition.node.nodeid, "SourceNode": unit.node.nodeid, "SourceName": unit.source,
                  "ConditionName": f"Alarm{condition.alarm}", "BranchId": ua.NodeId(), "Retain": not done,
                  "ConditionClassId": ua.NodeId(ua.ObjectIds.ProcessConditionClassType),
                  "ConditionClassName": ua.LocalizedText("Process"), "Severity": SEVERITY, "LastSeverity": SEVERITY,
                  "Quality": ua.StatusCode(), "EnabledState": ua.LocalizedText("Enabled"), "EnabledState/Id": True,
                  "ActiveState": ua.LocalizedText("Active" if condition.active else "Inactive"),
                  "ActiveState/Id": condition.active,
                  "AckedState": ua.LocalizedText("Acknowledged" if condition.acked else "Unacknowledged"),
                  "AckedState/Id": condition.acked, "ShelvingState/CurrentState": ua.LocalizedText(shelving),
                  "ShelvingState/CurrentState/Id": ua.NodeId(shelving_id), "SuppressedOrShelved": condition.shelved,
                  "InputNode": unit.nodes["Mode"], "Comment": ua.LocalizedText(reason or ""), "ClientUserId": who or ""}
        for name, value in fields.items():
            setattr(event, name, value)
        self.generator.event = event
        await self.generator.trigger(message=text)
        if done:
            await self.server.delete_nodes([condition.node], recursive=True)
            del unit.conditions[condition.alarm]
            self.targets = {k: v for k, v in self.targets.items() if v[1] is not condition}
            return
        condition.events.add(event.EventId.Value)
        for name in SHOWN:
            kind = event.data_types[name]
            await self._write(ua.NodeId(f"{condition.node.nodeid.Identifier}.{name.replace('/', '.')}", self.ns),
                              getattr(event, name), kind if isinstance(kind, ua.VariantType) else None)
        await self._write(ua.NodeId(f"{condition.node.nodeid.Identifier}.State", self.ns), words, ua.VariantType.String)

    async def _write(self, nodeid, value, kind=None):
        """Write a value (a DataValue, a Variant, or a value of the variant type `kind`) to a node."""
        if not isinstance(value, (ua.DataValue, ua.Variant)):
            value = ua.Variant(value, kind) if kind is not None else ua.Variant(value)
        data = value if isinstance(value, ua.DataValue) else ua.DataValue(value)
        await self.server.write_attribute_value(nodeid, data)

    # ------------------------------------------------------------------ the clients' methods
    async def _acknowledge(self, target, event_id, comment):
        """Acknowledge(EventId, Comment): the page's Acknowledge, the comment its reason."""
        found = self.targets.get(target)
        if found is not None and event_id.Value not in found[1].events:
            return ua.StatusCode(ua.StatusCodes.BadEventIdUnknown)
        return self._act(target, "acknowledge", _text(comment))

    async def _one_shot_shelve(self, target, comment=None):
        """OneShotShelve2(Comment): the page's Shelve, the comment its reason (OneShotShelve gives none)."""
        return self._act(target, "shelve", _text(comment))

    async def _timed_shelve(self, target, *_):
        return ua.StatusCode(ua.StatusCodes.BadNotSupported)  # the page's shelving lasts until it is undone

    async def _unshelve(self, target, comment=None):
        """Unshelve(), Unshelve2(Comment): the page's Unshelve."""
        return self._act(target, "unshelve", _text(comment))

    def _act(self, target, kind: str, reason: str | None) -> ua.StatusCode:
        """Record a client's action on the alarm whose condition (or its ShelvingState) is `target` as
        the page does (Store.act); the status code of what does not apply."""
        found = self.targets.get(target)
        if found is None:
            return ua.StatusCode(ua.StatusCodes.BadNodeIdUnknown)
        unit, condition = found
        alarm = {a.id: a for a in self.store.alarms(unit.run.id)}[condition.alarm]
        refused = {"acknowledge": alarm.acknowledged and ua.StatusCodes.BadConditionBranchAlreadyAcked,
                   "shelve": alarm.shelved and ua.StatusCodes.BadConditionAlreadyShelved,
                   "unshelve": not alarm.shelved and ua.StatusCodes.BadConditionNotShelved}[kind]
        if refused:
            return ua.StatusCode(refused)
        try:
            self.store.act(unit.run.id, condition.alarm, kind, _who(CALLER.get()), reason)
        except StoreError:  # a reason the page would not take either: none for shelving, too long
            return ua.StatusCode(ua.StatusCodes.BadInvalidArgument)
        return ua.StatusCode()


# the type's methods a client may call on a condition (or its ShelvingState), and what answers them
# (the methods of OPC UA 1.05 that take a comment are ShelvedStateMachineType's only, in asyncua's nodes)
METHODS = [((ua.ObjectIds.AcknowledgeableConditionType_Acknowledge,), "_acknowledge"),
           ((ua.ObjectIds.ShelvedStateMachineType_OneShotShelve, ua.ObjectIds.ShelvedStateMachineType_OneShotShelve2,
             ua.ObjectIds.AlarmConditionType_ShelvingState_OneShotShelve), "_one_shot_shelve"),
           ((ua.ObjectIds.ShelvedStateMachineType_TimedShelve, ua.ObjectIds.ShelvedStateMachineType_TimedShelve2,
             ua.ObjectIds.AlarmConditionType_ShelvingState_TimedShelve), "_timed_shelve"),
           ((ua.ObjectIds.ShelvedStateMachineType_Unshelve, ua.ObjectIds.ShelvedStateMachineType_Unshelve2,
             ua.ObjectIds.AlarmConditionType_ShelvingState_Unshelve), "_unshelve")]


class _Unit:
    """A unit's part of the address space: its object and variables, its alarms' conditions, and the
    row and action up to which it shows the store (`t`, `actions`)."""

    def __init__(self, run, node, base: str):
        self.run, self.node, self.base = run, node, base
        self.source = run.plant if run.unit is None else f"{run.plant} {run.unit}"
        self.nodes, self.conditions, self.alarms = {}, {}, None
        self.t = self.actions = 0


class _Condition:
    """An alarm's condition: its node, its A&C states, and the ids of the events it was shown in."""

    def __init__(self, alarm: int, mode, node, active: bool, acked: bool, shelved: bool):
        self.alarm, self.mode, self.node = alarm, mode, node
        self.active, self.acked, self.shelved = active, acked, shelved
        self.events = set()


class _Users:
    """The server's user manager: the one (user name, password) of `credentials`, or (None) anyone,
    anonymously."""

    def __init__(self, credentials):
        self.credentials = credentials

    def get_user(self, iserver, username=None, password=None, certificate=None):
        if self.credentials is None:
            return User(role=UserRole.User)
        user, secret = self.credentials
        if username == user and hmac.compare_digest((password or "").encode(), secret.encode()):
            return User(role=UserRole.User, name=username)
        return None


class _Sessions(InternalServer):
    """asyncua's server, with sessions that say whose method call is running (CALLER), so an action
    is recorded as the client's user's; and ConditionRefresh answered (its RefreshStartEvent and
    RefreshEndEvent of severity 1)."""

    def __init__(self, user_manager):
        super().__init__(user_manager=user_manager)
        self.bind_condition_methods = 1

    def create_session(self, name, user=User(role=UserRole.Anonymous), external=False):
        return _Session(self, self.aspace, self.subscription_service, name, user=user, external=external)


class _Session(InternalSession):
    async def call(self, params):
        token = CALLER.set(self)
        try:
            return await super().call(params)
        finally:
            CALLER.reset(token)


def _who(session) -> str:
    """Who acts: the session's user, or for an anonymous session the client's address."""
    user = session.user.name if session.user is not None and session.user.name else None
    if user is None:  # the session's name is the client's address, (host, port, ...)
        user = f"anonymous OPC UA client at {session.name[0] if isinstance(session.name, tuple) else session.name}"
    return "".join(ch for ch in str(user) if ch.isprintable())[:LONGEST["who"]]


def _text(comment) -> str | None:
    """A method's comment argument (a LocalizedText) as text; None without one."""
    value = None if comment is None else comment.Value
    return value.Text if isinstance(value, ua.LocalizedText) else value
