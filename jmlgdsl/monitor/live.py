"""The live monitor: rows from a source (or readings from a data bus, assembled into rows) diagnosed
one at a time and committed to the store in batches, each batch in one transaction with the state
it leaves (the Diagnosis checkpoint, the assembler, the source's position); only then is what the
batch holds acknowledged to the source. Killed at any moment and started again, it resumes from the
last commit: no row lost, none diagnosed twice, and no new prior (so no burst of alarms).
"""

from __future__ import annotations

import collections
import dataclasses
import json
import queue
import threading
import time as clock

import numpy as np

from ..sealed import SealedError, header_of, seal, unseal
from ..diagnosis import CheckpointError, Diagnosis, Options, fingerprint
from ..diagnosis.fleet import Fleet, stepped_together
from ..diagnosis.prediction import predictive_sd
from ..infer.result import Step
from ..infer.units import Stacked
from ..errors import JmlgError
from .rows import Assembler
from .sources.contract import End, Event, Fatal, Readings, Source, WholeRow, Times, Unreadable
from .sinks.outbox import Outbox
from .store import TIMES, Commit, Store
from ..version import VERSION

IDLE = 0.1  # seconds without input before the monitor commits and moves the wall clock on
QUEUE = 10_000  # items a source may hand over ahead of the diagnosis
BATCH = 1_000  # rows (or acknowledgements held back) before a commit even while input keeps coming
# Rows of each unit of a fleet a commit holds at least while input keeps coming: a unit's part of a
# commit (its state, sealed, and its own statements) costs as much as tens of its rows, so a commit of
# a 1,000-unit fleet every BATCH rows would save every unit's state for about one row of each.
ROUNDS = 16
# Seconds a handled reading or event may wait for the commit that acknowledges it while no finished
# row waits: a row is committed as soon as the input pauses, the readings between rows in groups.
GROUP = 0.05
# Items of one unit of a fleet the queue holds before its source waits for the monitor to take them:
# 40 dryers catching up on their files stepped 38 units at a time with 16 (7 with none, 21 with 64),
# and the rows went fastest.
LEAD = 16
# Rounds of a fleet's items (a list of (unit index, item) pairs, handed over at once by a source that
# reads every unit's data in one thread) the queue holds before the source waits for the monitor.
ROUNDS_AHEAD = 2
# Seconds a fleet's row may wait for the other units' rows of its sample, so that their filters step
# together (a commit steps every row first).
GATHER = 0.02
# The monitor's own saved state beside a unit's checkpoint (its assembler, its last estimate, its part
# of a fleet's filter), sealed (jmlgdsl.sealed) with these kinds in it and this header.
MONITOR_KINDS = (Assembler, Step)
MONITOR_STATE = {"monitor": 1, "version": VERSION}
# Sample times (of the wall clock, and at least STALL_LEAST seconds) without a row diagnosed while
# messages keep arriving before a unit's diagnosis is said to stall: every message late, in the
# future or held ahead, say, while the page would go on showing the last mode.
STALL, STALL_LEAST = 10, 10.0


class MonitorError(JmlgError):
    """A monitor that cannot start or go on: a store of another run, a source that refuses it."""


@dataclasses.dataclass(frozen=True)
class Stopped:
    """How a monitor ended: its runs (one per unit of a fleet), rows diagnosed here and in the store,
    events here by kind, and whether the data ended (an unfollowed file, standard input) or the
    monitor was stopped."""

    runs: tuple
    rows: int
    stored: int
    events: dict
    ended: bool


@dataclasses.dataclass(frozen=True)
class MonitorOptions:
    """A monitor's options: its diagnosis's (jmlgdsl.diagnosis.Options, with `run`'s defaults; a
    monitor always explains) and the assembler's, which puts readings on the sample clock (grace and
    stale None: 2 and 10 sample times; catch_up: the seconds of the wall clock its rows are held after
    the source connects, not recorded with the run, as it says how long to wait, not what to compute)."""

    diagnosis: Options = Options()
    grace: float | None = None
    stale: float | None = None
    max_gap: float = 3600.0
    catch_up: float = 5.0


class Monitor:
    """Diagnose what a source delivers, into a store. `options` (MonitorOptions) are the diagnosis's
    and the assembler's; they are recorded with the run, and a restart with others is refused, as is
    another model, unless `new_run`.

    `units` names the units of a fleet (jmlgdsl.monitor.units): each has its run in the store, its
    own diagnosis, assembler and source position, and every commit holds every unit's rows and
    state. The source then hands over (unit index, item) pairs (None: an item for every unit); a
    source of one plant hands over items. Without a lag the units' filters step together
    (jmlgdsl.diagnosis.fleet.Fleet): the rows that arrived since the last step, a row per unit at a
    time, are stepped together when the input pauses and before every commit. `banks` gives each
    unit its own (model, spec text), its spec fitted to it (`jmlgdsl.diagnosis.fleet.unit_banks`;
    default `model` and `spec` for every unit): its run records them, a restart with another is
    refused, and the units still step together, each under its own numbers. `sinks` (jmlgdsl.monitor.
    outbox) are sent what each commit holds, and the operators' actions on its alarms."""

    def __init__(self, model, store: Store, source: Source, *, spec: str | None, options: MonitorOptions, tags: dict,
                 units=None, new_run: bool = False, log=None, banks=None, sinks=()):
        self.model, self.store, self.source, self.log = model, store, source, log or (lambda text: None)
        self.options = options
        self.tags = tags
        self.named = units is not None
        self.banks = banks or [(model, spec)] * (1 if units is None else len(units))
        # the units' own banks as one, for their predictive bands (None: every unit has the model)
        self.stacked = None if all(bank is model for bank, _ in self.banks) else Stacked([b for b, _ in self.banks])
        runs = open_runs(store, model, spec, recorded_options(model, options, source.name, tags), units, new_run,
                         self.banks)
        self.units = [self._unit(run, i) for i, run in enumerate(runs)]
        self.outbox = Outbox(store, sinks, runs, model.name)
        self.fleet = None  # the units' diagnoses as one Fleet, when their filters step together
        if self.named and stepped_together(self.units[0].diagnosis.filter):
            self.fleet = Fleet(model, units=[watch.diagnosis for watch in self.units])
            for i, watch in enumerate(self.units):
                if watch.filter_state is not None:
                    self.fleet.filter.restore(i, watch.filter_state)
        # rows handed to the fleet's filter and not yet stepped; units with such rows, the first since `waited`
        self.unstepped = self.ready = 0
        self.waited = clock.monotonic()
        self.tokens = []
        self.late_unlogged = None  # late events since the first one logged in this batch (None: none logged)
        self.finished = 0  # rows finished since the last commit
        self.batch = max(BATCH, ROUNDS * len(self.units)) if self.named else BATCH  # rows before a commit
        self.committed = clock.monotonic()
        self.counts = {}
        self.started_rows = self.stored

    def _unit(self, run, index) -> "Watch":
        """A unit's part of the monitor for its run, resumed from the run's saved state."""
        watch = Watch(self, run.unit, run, index)
        saved = self.store.saved(run.id)
        model = self.banks[index][0]
        if saved is None:
            options = self.options
            watch.diagnosis = Diagnosis(model, dataclasses.replace(options.diagnosis, explain=True), scored=False,
                                        sinks=[watch])
            watch.assembler = None if self.source.rows else Assembler(self.model, self.tags, options.grace,
                                                                      options.stale, options.max_gap)
        else:
            try:
                watch.diagnosis = Diagnosis.resume(saved.checkpoint, model, sinks=[watch])
                # sealed by this version with the checkpoint (Diagnosis.resume refuses another version's)
                if header_of(saved.monitor or b"") != MONITOR_STATE:
                    raise SealedError("the monitor's part of it is of another kind or version")
                state = unseal(saved.monitor, MONITOR_KINDS)
                watch.assembler, watch.previous = state["assembler"], state["previous"]
                watch.filter_state = state.get("filter")
            except (CheckpointError, SealedError, TypeError, KeyError) as exc:
                raise MonitorError(unresumable(self.store, run, saved, exc)) from None
            watch.rows, watch.position = saved.rows, saved.position
        watch.resumed = saved is not None
        if watch.assembler is not None and watch.assembler.held:  # saved while held: its source connects anew
            watch.connection(True)
        return watch

    @property
    def stored(self) -> int:
        """Rows diagnosed in the store's runs of this monitor, every unit together."""
        return sum(watch.rows for watch in self.units)

    # ----------------------------------------------------------------- the loop
    def run(self, stop: threading.Event | None = None) -> Stopped:
        """Diagnose until the data end or `stop` is set; every handled item is committed on return."""
        stop = stop or threading.Event()
        items = queue.Queue(maxsize=QUEUE)
        # a fleet's units share the queue: a unit's items wait for the monitor to take its earlier
        # ones, so a unit's source catching up (a file read in one thread's time slice) cannot fill the
        # queue alone, and the other units' rows come in beside its own for their filters to step together
        credits = [threading.Semaphore(LEAD) for _ in self.units] if self.named else None
        rounds = threading.Semaphore(ROUNDS_AHEAD)  # a fleet's rounds handed over and not yet taken
        closing = threading.Event()  # set when the monitor takes no more items: a source's thread gives up

        def put(item):
            held = rounds if isinstance(item, list) else credits[item[0]] if credits and item[0] is not None else None
            if held is not None:
                while not held.acquire(timeout=IDLE):
                    if closing.is_set():
                        return
            if not closing.is_set():
                items.put(item)

        if self.named:
            self.source.start(put, [watch.position for watch in self.units])
        else:
            self.source.start(lambda item: items.put((0, item)), self.units[0].position)
        for watch in self.units:
            watch.event(Event("resume" if watch.resumed else "start", None,
                              f"run {watch.run.id} {'resumed after' if watch.resumed else 'started at'} row "
                              f"{watch.rows}"))
        ended = False
        try:
            self.outbox.start()
            while not stop.is_set() and not ended:
                try:
                    taken = items.get(timeout=IDLE)
                except queue.Empty:
                    for watch in self.units:
                        if watch.assembler is not None:
                            watch.assembled(*watch.assembler.advance(clock.time()))
                    self.commit()
                    continue
                if isinstance(taken, list):  # a round of a fleet's items
                    rounds.release()
                elif credits is not None and taken[0] is not None:
                    credits[taken[0]].release()
                for unit, item in taken if isinstance(taken, list) else (taken,):
                    ended = self._handle(unit, item)
                    if self.ready == len(self.units):
                        self.step(len(self.units))  # the rounds every unit has a row for
                    elif self.unstepped >= 4 * BATCH:
                        self.step()
                    elif self.ready and clock.monotonic() - self.waited >= GATHER:
                        self.step(max(1, self.ready // 2))  # rounds of many units; the rows of the others wait on
                        self.waited = clock.monotonic()
                if self.finished >= self.batch or len(self.tokens) >= BATCH or items.empty() and (
                        self.finished or clock.monotonic() - self.committed >= GROUP):
                    self.commit()
            if ended:
                self.step()
                for watch in self.units:
                    watch.diagnosis.finish()
                    watch.dirty = True
        finally:
            closing.set()
            try:
                self.commit()
                self.outbox.close()
                self.commit()  # how far the sinks got while they closed
            finally:
                self.outbox.close(0)
                self.source.stop()
        return Stopped(tuple(watch.run.id for watch in self.units), self.stored - self.started_rows, self.stored,
                       dict(self.counts), ended)

    def _handle(self, unit, item) -> bool:
        """Take one item from the source (jmlgdsl.monitor.sources.contract) for a unit (None: for every
        unit); True at the end of the data."""
        watches = self.units if unit is None else [self.units[unit]]
        match item:
            case WholeRow():
                watches[0].position = item.position
                watches[0].feed(item.row)
            case Readings():
                watches[0].assembled(*watches[0].assembler.add(
                    [(name, self.tags[name].value(value), stamp) for name, value, stamp in item.readings],
                    item.arrival))
                watches[0].dirty = True  # the assembler holds the readings: it is saved before they are acknowledged
                watches[0].arrived()
                self.tokens.append(item.token)
            case Unreadable():
                self._event(watches, unit, Event("malformed", None, item.message))
                for watch in watches:
                    watch.arrived()
                self.tokens.append(item.token)
            case Event():
                if item.kind in ("connect", "disconnect"):
                    for watch in watches:
                        watch.connection(item.kind == "connect")
                self._event(watches, unit, item)
            case Times():
                watches[0].times = item.format
            case Fatal():
                raise MonitorError(item.message)
        return isinstance(item, End)

    def _event(self, watches, unit, event: Event):
        """A source's event for a unit, or (unit None) for every unit (their one connection's): kept in
        each unit's run, and logged once, as the monitor's."""
        for watch in watches:
            watch.event(event, logged=unit is not None)
        if unit is None:
            self.tell(event)

    def tell(self, event: Event, name: str | None = None):
        """Log an event (of unit `name`, when given): of the late ones between two commits (a broker
        delivering again what a killed monitor had not acknowledged: up to a batch), only the first."""
        if event.kind == "late" and self.late_unlogged is not None:
            self.late_unlogged += 1
            return
        self.late_unlogged = 0 if event.kind == "late" else self.late_unlogged
        self.log(f"{name + ': ' if name else ''}{event.kind}: {event.tag + ': ' if event.tag else ''}{event.detail}")

    def step(self, least: int = 1):
        """Step the fleet's filter over the rows handed to it, a row of each unit that has one at a time,
        for as long as at least `least` units have one."""
        model = self.model
        while self.ready >= least:
            rows = [watch.pending.popleft() if watch.pending else None for watch in self.units]
            self.unstepped -= sum(row is not None for row in rows)
            self.ready -= sum(row is not None and not watch.pending for row, watch in zip(rows, self.units))
            banded = [i for i, row in enumerate(rows) if row is not None and self.units[i].previous is not None]
            if banded:  # every unit's predictive band in one call, from its last estimate
                last = [self.units[i].previous for i in banded]
                sd = predictive_sd(model if self.stacked is None else self.stacked.take(banded),
                                   np.array([s.mode_posterior for s in last]),
                                   np.array([s.state_mean for s in last]), np.array([s.state_cov for s in last]),
                                   np.array([rows[i].u for i in banded]).reshape(len(banded), model.nu))
                for i, band in zip(banded, sd):
                    self.units[i].band = band
            self.fleet.feed(rows)

    def commit(self):
        """Store what was handled since the last commit with the state after it, every unit's in one
        transaction (with how far the sinks have delivered); then acknowledge it to the source, and hand
        it to the sinks. The rows of a source that has caught up are released first."""
        for watch in self.units:
            watch.caught_up()
        self.step()
        reports, marks = self.outbox.collect()
        for unit, item in reports:  # the sinks' events, kept with this commit
            self._handle(unit, item)
        dirty = [watch for watch in self.units if watch.dirty]
        if not dirty and not self.tokens and not marks:
            self.outbox.hand()  # the operators' actions
            return
        self.store.save([watch.commit() for watch in dirty], marks)
        for watch in dirty:
            watch.samples, watch.results, watch.events, watch.dirty = [], [], [], False
        self.finished = 0
        if self.late_unlogged:
            self.log(f"late: {self.late_unlogged} more messages came after their rows were diagnosed (each an event "
                     "in the store)")
        self.late_unlogged = None
        self.committed = clock.monotonic()
        tokens, self.tokens = self.tokens, []
        self.source.acknowledge(tokens)
        self.outbox.hand({watch.run.id for watch in dirty})


class Watch:
    """One unit's part of a monitor (the whole of it for one plant): its run, diagnosis, row
    assembler, last estimate, rows and source position, and what waits for the next commit. It is
    its diagnosis's sink."""

    def __init__(self, monitor: Monitor, name: str | None, run, index: int):
        self.monitor, self.name, self.run, self.index = monitor, name, run, index
        self.diagnosis = self.assembler = None
        self.filter_state = None  # saved with a fleet's filter: this unit's part of it
        self.band = None  # the next row's predictive sd, when the fleet's step computed it
        self.pending = collections.deque()  # rows for the fleet's filter
        self.previous = None  # the last finished row's estimate, for the next row's predictive band
        self.rows, self.position, self.resumed = 0, None, False
        self.times = None  # how a source of rows writes their times (TimeFormat), once it says
        self.timed = TIMES in run.options  # whether the run records that (an assembler's source: its own)
        self.samples, self.results, self.events = [], [], []
        self.dirty = False
        self.nan_sd = np.full(monitor.model.ny, np.nan)
        self.stall = max(STALL * float(monitor.model.dt), STALL_LEAST)  # seconds
        self.last_row = clock.monotonic()  # when the last row was diagnosed (or the monitor started)
        self.since = {}  # messages since that row, and its events by kind
        self.stalled = False  # whether the stall since that row was told
        self.held_until = None  # when its assembler's rows are released (monotonic; None: not on a clock)

    def connection(self, up: bool):
        """The source connected (`up`) or lost its connection: the assembler holds its rows while it is
        down and for the catch-up time after it is back, as what was kept meanwhile comes in."""
        if self.assembler is None:
            return
        self.assembler.hold()
        self.held_until = clock.monotonic() + self.monitor.options.catch_up if up else None

    def caught_up(self):
        """Release the assembler's rows once the catch-up time after a connection has passed."""
        if self.held_until is not None and clock.monotonic() >= self.held_until:
            self.held_until = None
            self.assembled(*self.assembler.release())
            self.dirty = True

    def arrived(self):
        """A message for this unit was handled: a `stall` event (once until the next row) when no row
        has been diagnosed for `stall` seconds while messages keep arriving, with what became of them."""
        self.since["message"] = self.since.get("message", 0) + 1
        waited = clock.monotonic() - self.last_row
        if self.stalled or waited < self.stall:
            return
        self.stalled = True
        counts = ", ".join(f"{kind} {count}" for kind, count in self.since.items() if kind != "message")
        self.event(Event("stall", None, f"no row diagnosed for {waited:.0f} s while {self.since['message']} "
                                        f"messages arrived ({counts or 'none of them an event'}); the page shows "
                                        "the last row's mode until a row is diagnosed again"))

    def assembled(self, rows, events):
        for event in events:
            self.event(event)
        for row in rows:
            self.feed(row)

    def feed(self, row):
        """A row of this unit: diagnosed now, or handed to the fleet's filter for its next step."""
        monitor = self.monitor
        self.rows += 1
        self.samples.append((self.rows, row))
        self.last_row, self.since, self.stalled = clock.monotonic(), {}, False
        if monitor.fleet is None:
            self.diagnosis.feed(row)
        else:
            if not monitor.ready:
                monitor.waited = clock.monotonic()
            if not self.pending:
                monitor.ready += 1
            self.pending.append(row)
            monitor.unstepped += 1
        self.dirty = True

    def collect(self, done):
        """The diagnosis's sink: a finished row, stored with the next commit with the spread of its
        one-step prediction (from the row before it)."""
        last, sd, self.band = self.previous, self.band, None
        if sd is None:
            sd = (self.nan_sd if last is None else
                  predictive_sd(self.diagnosis.model, last.mode_posterior, last.state_mean, last.state_cov, done.row.u))
        self.results.append((done, sd))
        self.monitor.finished += 1
        self.previous = done.step

    def event(self, event: Event, logged: bool = True):
        """Keep an event for the next commit, and log it (unless `logged` is False: the monitor logs it)."""
        monitor = self.monitor
        self.events.append(event)
        self.dirty = True
        monitor.counts[event.kind] = monitor.counts.get(event.kind, 0) + 1
        self.since[event.kind] = self.since.get(event.kind, 0) + 1
        if logged:
            monitor.tell(event, self.name)

    def commit(self) -> Commit:
        """This unit's part of the next commit: its rows, results and events, and its state after them."""
        fleet = self.monitor.fleet
        state = {"assembler": self.assembler, "previous": self.previous}
        if fleet is not None:
            state["filter"] = fleet.filter.state(self.index)
        times = None
        if not self.timed and self.samples:
            times = self.times if self.assembler is None else self.assembler.times
            self.timed = times is not None
        return Commit(self.run.id, self.samples, self.results, self.events, self.rows, self.diagnosis.checkpoint(),
                      seal(state, MONITOR_STATE, MONITOR_KINDS), self.position, times)


def unresumable(store, run, saved, reason) -> str:
    """Why a run cannot be resumed from the state the store holds for it, and what to do."""
    whose = "" if run.unit is None else f" of unit {run.unit}"
    return (f"the store {store.path} cannot resume run {run.id}{whose} from its saved state (after row "
            f"{saved.rows}, saved {saved.at}): {reason}. A store keeps one saved state a run, the last one "
            f"committed, so there is no earlier one to go back to; the run's rows stay readable ('jmlgdsl "
            f"export'). Start a new run with --new-run (a new prior: the first rows may alarm while it settles)")


def recorded_options(model, options: MonitorOptions, source: str, tags: dict) -> dict:
    """What a run records of its monitor's options, its source's name and its tags (explain left out:
    a monitor always explains); a restart with others is refused."""
    diagnosis = {key: value for key, value in dataclasses.asdict(options.diagnosis).items() if key != "explain"}
    return dict(diagnosis, healthy=list(options.diagnosis.healthy or model.modes[:1]), grace=options.grace,
                stale=options.stale, max_gap=options.max_gap, source=source,
                tags={name: dataclasses.asdict(tag) for name, tag in tags.items()})


def open_runs(store, model, spec, options: dict, units=None, new_run: bool = False, banks=None) -> list:
    """The run of each of a fleet's `units` (None: the one run of one plant), found again or begun;
    `options` as recorded_options gives them; `banks` each unit's own (model, spec text) (default:
    `model` and `spec` for every unit)."""
    names = [None] if units is None else units
    banks = banks or [(model, spec)] * len(names)
    return [_open_run(store, bank, text, options, unit, new_run) for unit, (bank, text) in zip(names, banks)]


def _open_run(store, model, spec, options, unit, new_run):
    """A unit's run (None: one plant's): the latest, checked against this model and these options, or
    a new one; a store of the other kind (a fleet's, one plant's) is refused unless `new_run`."""
    run = store.run(unit=unit)
    model_sha = fingerprint(model)
    kind = run if run is not None or unit is None else store.run()  # a unit's first run: the store's kind
    if kind is not None and not new_run and (kind.unit is None) != (unit is None):
        raise MonitorError(f"the store {store.path} holds the runs of "
                           f"{'a fleet' if unit is None else 'one plant'}, not of "
                           f"{'a fleet' if unit is not None else 'one plant'}; give another store, or "
                           "--new-run to start a new run in the store")
    if run is not None and not new_run:
        whose = "" if unit is None else f" of unit {unit}"
        if run.model_sha256 != model_sha:
            raise MonitorError(f"the store {store.path} holds a run{whose} of another model (plant "
                               f"{run.plant!r}, fingerprint {run.model_sha256[:12]}) than this spec (plant "
                               f"{model.name!r}, fingerprint {model_sha[:12]}); give the spec it was "
                               f"started with, or --new-run to start a new run in the store")
        for key in sorted(set(run.options) - {TIMES} | set(options)):  # TIMES: the store's own record
            if run.options.get(key) != _plain(options.get(key)):
                raise MonitorError(f"the store {store.path} holds a run{whose} started with {key} "
                                   f"{run.options.get(key)!r}, not {options.get(key)!r}; restart it with "
                                   f"the same options, or --new-run to start a new run in the store")
        return run
    return store.begin_run(spec, model, model_sha, options, unit)


def _plain(value):
    """A value as the store's JSON gives it back (tuples as lists)."""
    return json.loads(json.dumps(value))
