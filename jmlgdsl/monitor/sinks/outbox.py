"""The monitor's conclusions sent on to the plant's own systems (`--publish`, `--notify`,
`--opcua-server`), read back from the store after each commit: the store is the outbox, so nothing
is sent that a crash could take back, and nothing committed is lost to a crash.

**The sink contract.** A sink (jmlgdsl.monitor.sinks.publish's MQTT publisher, jmlgdsl.monitor.sinks.webhook's
webhook, jmlgdsl.monitor.sinks.opcua_server's OPC UA server; another later) is an object with

    name            the key of its delivery marks in the store (no secret in it) and of its events
    takes_states    True: every row's state and every alarm transition; False: the transitions only
    start(report)   connect, in threads of its own; report(Event, run) tells what befell its
                    delivery (an event of that run; without a run, of every run), report(Fatal(message))
                    what trying again cannot mend (jmlgdsl.monitor.sources.contract's items, as the
                    monitor takes a source's); `report` may be called from any thread
    room()          how many more conclusions it takes now (its queue is bounded: the rest wait in
                    the store)
    send(c)         take a Conclusion, in order; never waits for the far side
    delivered()     the Conclusions the far side confirmed since the last call (an MQTT PUBACK, an
                    HTTP 2xx), called by the monitor's thread
    stop(wait)      deliver what it can within `wait` seconds, then close

and the Outbox does the rest: after each commit it reads what was committed since (rows, alarms
raised and cleared, and the operators' actions, which the page writes from any process) and hands
it to each sink within its room; it records in the store, with the next commit, how far each sink
has confirmed each run (the `delivery` table: the rows up to t and the actions up to an id). A
monitor started again hands each sink what it had not confirmed once more, from its mark, with
"redelivered": true on every conclusion the store held when it started (the far side may have had
it already: a subscriber drops one it has seen, by its run and t, or its run, alarm and
transition, or action); every other conclusion is handed once with "redelivered": false. A sink
new to a run begins at the store's end: what was diagnosed before it was first given is not sent.
"""

from __future__ import annotations

import collections
import dataclasses
import json
import queue

from ..sources import bus
from ..store import row_state


TRANSITIONS = {"acknowledge": "acknowledged", "shelve": "shelved", "unshelve": "unshelved"}  # an action's name
FLUSH = 3.0  # seconds the sinks have to deliver what they were handed when the monitor stops


@dataclasses.dataclass(frozen=True)
class Conclusion:
    """One message for the sinks: a row's `state` or an alarm's `transition`, of a run (one plant's,
    or a fleet's `unit`'s), as the JSON object `body`. `position` is the outbox's: (t, action) once
    it is delivered."""

    run: int
    unit: str | None
    kind: str
    body: dict
    position: tuple

    def json(self) -> bytes:
        return json.dumps(self.body).encode()


class Outbox:
    """The sinks of a monitor's runs (`runs`: the store's Run records, `plant` the plant's name): `start()`
    before the first commit, `collect()` and `hand(moved)` around each commit, `close()` at the end."""

    def __init__(self, store, sinks, runs, plant: str):
        self.store, self.sinks, self.plant = store, list(sinks), plant
        self.runs = {run.id: run for run in runs}
        self.index = {run.id: i for i, run in enumerate(runs)}
        self.reports = queue.SimpleQueue()
        self.feeds = [Feed(sink) for sink in self.sinks]
        self.actions = 0  # the newest action id seen
        self.started = self.closed = False

    def start(self):
        """Each sink's place in each run (its mark, or the store's end for a sink new to the run, recorded
        at once), and the sinks started."""
        if not self.sinks:
            return
        self.started = True
        ends = {run: self._end(run) for run in self.runs}
        self.actions = max([action for _, action in ends.values()], default=0)
        fresh = []
        for feed in self.feeds:
            marks = self.store.delivered(feed.sink.name)
            for run, end in ends.items():
                if run not in marks:
                    marks[run] = end
                    fresh.append((feed.sink.name, run, *end))
                feed.begin(run, marks[run], end)
                if marks[run] != end:
                    feed.behind.add(run)  # what it had not confirmed: handed again before anything moves
        if fresh:
            self.store.save([], fresh)
        for sink in self.sinks:
            sink.start(self._report)

    def _report(self, item, run: int | None = None):
        """A sink's report (an Event or a Fatal, of a run or of every run), from any thread."""
        self.reports.put((item, run))

    def _end(self, run) -> tuple:
        """(newest row t, newest action id) of a run in the store."""
        return self.store.last_t(run), self.store.newest_action(run)

    def collect(self) -> tuple[list, list]:
        """What the sinks reported since the last call, as the monitor takes a source's items: [(index
        of the unit in `runs` or None for every unit, an Event or a Fatal)]; and the delivery marks
        that moved, as (sink, run, t, action) for Store.save."""
        items = [(self.index.get(run), item) for item, run in bus.drained(self.reports)]
        return items, [mark for feed in self.feeds for mark in feed.confirmed()]

    def hand(self, moved=()):
        """Hand each sink what was committed since it was last handed anything, within its room: the
        rows of the runs in `moved` (or of runs it is behind in) and the operators' new actions."""
        if not self.started or self.closed:
            return
        new = self.store.actions(after=self.actions)
        self.actions = max([action.id for action in new], default=self.actions)
        acted = {action.run for action in new if action.run in self.runs}
        for feed in self.feeds:
            for run in sorted(set(moved) | acted | feed.behind):
                room = feed.sink.room()
                conclusions, more = self._read(feed, run, room) if room > 0 else ([], True)
                for conclusion in conclusions:
                    feed.sink.send(conclusion)
                (feed.behind.add if more else feed.behind.discard)(run)

    def close(self, wait: float = FLUSH):
        """Give the sinks `wait` seconds to deliver what they were handed, then stop them (a last
        `collect` records how far they got); again, nothing."""
        if self.closed:
            return
        self.closed = True
        for sink in self.sinks if self.started else ():
            sink.stop(wait)

    # ------------------------------------------------------------------ reading back
    def _read(self, feed, run: int, room: int) -> tuple[list, bool]:
        """The conclusions of a run after a sink's place, about `room` of them at most, in order: each
        row's state and the alarm raised or cleared at it, then the operators' actions; the sink's
        place moved past them. And whether more may wait (for the next call)."""
        (t0, a0), record = feed.handed[run], self.runs[run]
        if feed.sink.takes_states:
            rows = self.store.verdicts(record, t0, room)
            t1 = rows[-1].t if rows else t0
        else:
            rows = []
            t1 = self.store.last_t(run)
        # the alarms open at some row of (t0, t1]: at most one at a time, so one transition a row at most
        alarms = self.store.alarms(run, during=(t0, t1))
        steps = {}  # row t -> (transition, alarm id, data time)
        for a in alarms:
            if a.raised_t > t0:
                steps[a.raised_t] = ("raised", a.id, a.raised_time)
            if a.cleared_t is not None and a.cleared_t <= t1:
                steps[a.cleared_t] = ("cleared", a.id, a.cleared_time)
        more = len(rows) == room
        if not rows and len(steps) > room:  # transitions only: those of the rows before the first left out
            t1, more = sorted(steps)[room] - 1, True
        out, by_t = [], {row.t: row for row in rows}
        for t in sorted(set(by_t) | {t for t in steps if t <= t1}):
            if t in by_t:
                opened = next((a.id for a in alarms if a.raised_t <= t and (a.cleared_t is None or a.cleared_t > t)),
                              None)
                out.append(self._state(feed, record, by_t[t], opened))
            if t in steps:
                transition, alarm, time = steps[t]
                out.append(self._transition(feed, record, alarm, transition, (t, a0), a0, t=t, time=time))
        a1, limit = a0, max(room - len(out), 1)
        actions = self.store.actions(run, after=a0, limit=limit)
        for action in actions:
            if action.raised_t > t1:
                break  # its alarm's raising is not handed yet: the action waits for it (more is True)
            a1 = action.id
            out.append(self._transition(feed, record, action.alarm, TRANSITIONS[action.kind], (t1, action.id),
                                        action.id, action=action.id, at=action.at, who=action.who,
                                        reason=action.reason))
        feed.hand(run, out, (t1, a1))
        return out, more or len(actions) == limit

    def _state(self, feed, record, row, opened) -> Conclusion:
        """A row's state (`row`, the store's Verdict): its mode, every mode's probability and the alarm."""
        body = {**row_state(self.plant, record, row, opened), "redelivered": feed.redelivered(record.id, t=row.t)}
        return Conclusion(record.id, record.unit, "state", body, (row.t, feed.handed[record.id][1]))

    def _transition(self, feed, record, alarm: int, transition: str, position, actions: int, **facts) -> Conclusion:
        """An alarm's transition with its ISA-18.2 state after it (the rows handed so far and the actions
        up to `actions`) and a line for people (`text`, which a chat hook shows); `facts` are the row
        (t, time) of a raising or a clearing, or the action (its id, at, who, reason)."""
        found = next(a for a in self.store.alarms(record.id, actions) if a.id == alarm)
        if found.cleared_t is not None and found.cleared_t > position[0]:
            found = dataclasses.replace(found, cleared_t=None, cleared_time=None)
        who = f" by {facts['who']}" if facts.get("who") else ""
        why = f" ({facts['reason']})" if facts.get("reason") else ""
        unit = f" {record.unit}" if record.unit else ""
        text = f"{self.plant}{unit}: alarm {alarm} ({found.mode}) {transition}{who}{why}; now {found.state}"
        body = {"plant": self.plant, "unit": record.unit, "run": record.id, "alarm": alarm, "transition": transition,
                "mode": found.mode, **facts, "state": found.state, "text": text,
                "redelivered": feed.redelivered(record.id, **({"action": facts["action"]} if "action" in facts
                                                               else {"t": position[0]}))}
        return Conclusion(record.id, record.unit, "transition", body, position)


class Feed:
    """Where one sink stands in each run: how far it was handed (`handed`), what it was handed and has
    not confirmed, the mark last recorded, and what the store held when the monitor started (a
    conclusion of it after the sink's mark is a redelivery)."""

    def __init__(self, sink):
        self.sink = sink
        self.handed, self.recorded, self.began, self.held = {}, {}, {}, {}
        self.waiting = {}  # run -> deque of [position, confirmed] in the order handed
        self.entries = {}  # id(conclusion) -> (conclusion, its entry in waiting) until confirmed
        self.behind = set()  # runs it was not handed all of for want of room

    def begin(self, run: int, mark: tuple, end: tuple):
        self.handed[run] = self.recorded[run] = self.began[run] = tuple(mark)
        self.held[run] = tuple(end)
        self.waiting[run] = collections.deque()

    def redelivered(self, run: int, t: int | None = None, action: int | None = None) -> bool:
        """Whether the conclusion of row t (or of action id `action`) was in the store when the monitor
        started, after the sink's mark then: an earlier monitor may have sent it."""
        k, value = (0, t) if action is None else (1, action)
        return self.began[run][k] < value <= self.held[run][k]

    def hand(self, run: int, conclusions: list, to: tuple):
        """Conclusions handed to the sink, and its place `to` after them (past rows that held none)."""
        for conclusion in conclusions:
            entry = [conclusion.position, False]
            self.waiting[run].append(entry)
            self.entries[id(conclusion)] = conclusion, entry
        self.waiting[run].append([to, True])
        self.handed[run] = to

    def confirmed(self) -> list:
        """The marks (sink, run, t, action) that moved since the last call, as far as the sink has
        confirmed everything handed to it before."""
        for conclusion in self.sink.delivered():
            self.entries.pop(id(conclusion))[1][1] = True
        marks = []
        for run, waiting in self.waiting.items():
            done = None
            while waiting and waiting[0][1]:
                done = waiting.popleft()[0]
            if done is not None and done != self.recorded[run]:
                self.recorded[run] = done
                marks.append((self.sink.name, run, *done))
        return marks
