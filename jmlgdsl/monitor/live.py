"""The live monitor: rows from a source (or readings from a data bus, assembled into rows) diagnosed
one at a time and committed to the store in batches, each batch in one transaction with the state
it leaves (the Diagnosis checkpoint, the assembler, the source's position); only then is what the
batch holds acknowledged to the source. Killed at any moment and started again, it resumes from the
last commit: no row lost, none diagnosed twice, and no new prior (so no burst of alarms).
"""

from __future__ import annotations

import dataclasses
import json
import pickle
import queue
import threading
import time as clock

import numpy as np

from ..diagnosis.alarms import AlarmRule
from ..diagnosis import Diagnosis, fingerprint
from ..diagnosis.prediction import predictive_sd
from ..infer import DEFAULT_ALGORITHM
from ..errors import JmlgError
from .assemble import Assembler, Event
from .store import Store

IDLE = 0.1  # seconds without input before the monitor commits and moves the wall clock on
QUEUE = 10_000  # items a source may hand over ahead of the diagnosis
BATCH = 1_000  # rows (or acknowledgements held back) before a commit even while input keeps coming
# Seconds a handled reading or event may wait for the commit that acknowledges it while no finished
# row waits: a row is committed as soon as the input pauses, the readings between rows in groups.
GROUP = 0.05


class MonitorError(JmlgError):
    """A monitor that cannot start or go on: a store of another run, a source that refuses it."""


@dataclasses.dataclass(frozen=True)
class Stopped:
    """How a monitor ended: rows diagnosed here and in the store, events here by kind, and whether
    the data ended (an unfollowed file, standard input) or the monitor was stopped."""

    run: int
    rows: int
    stored: int
    events: dict
    ended: bool


def monitor_options(*, algorithm: str = DEFAULT_ALGORITHM, particles: int | None = None, seed: int | None = None,
                    resampling: str = "systematic", ess_threshold: float = 1.0, lag: int = 0,
                    prefilter: int | None = None, healthy=None, threshold: float = 0.5, persistence: int = 1,
                    grace: float | None = None, stale: float | None = None, max_gap: float = 3600.0) -> dict:
    """A monitor's options, with `run`'s defaults: the filter's, the alarm rule's (healthy None: the
    spec's first mode) and the assembler's (grace and stale None: 2 and 10 sample times)."""
    return dict(locals())


class Monitor:
    """Diagnose what a source delivers, into a store. `options` are the Diagnosis's (algorithm,
    particles, seed, resampling, ess_threshold, lag, prefilter), the alarm rule's (healthy, threshold,
    persistence) and the assembler's (grace, stale, max_gap); they are recorded with the run, and a
    restart with others is refused, as is another model, unless `new_run`."""

    def __init__(self, model, store: Store, source, *, spec: str | None, options: dict, tags: dict,
                 new_run: bool = False, log=None):
        self.model, self.store, self.source, self.log = model, store, source, log or (lambda text: None)
        self.options = dict(options, healthy=list(options["healthy"] or model.modes[:1]), source=source.name,
                            tags={name: dataclasses.asdict(tag) for name, tag in tags.items()})
        self.tags = tags
        self.run_info = self._run(spec, new_run)
        saved = store.saved(self.run_info.id)
        if saved is None:
            options = self.options
            rule = AlarmRule(tuple(options["healthy"]), options["threshold"], options["persistence"])
            keys = ("algorithm", "particles", "seed", "resampling", "ess_threshold", "lag", "prefilter")
            self.diagnosis = Diagnosis(model, rule=rule, scored=False, explain=True, sinks=[self],
                                       **{k: options[k] for k in keys})
            self.assembler = None if source.rows else Assembler(model, tags, options["grace"], options["stale"],
                                                                options["max_gap"])
            self.previous = None  # the last finished row's estimate, for the next row's predictive band
            self.rows, self.position = 0, None
        else:
            self.diagnosis = Diagnosis.resume(saved.checkpoint, model, sinks=[self])
            # saved by this version with the checkpoint (Diagnosis.resume refuses another version's)
            state = pickle.loads(saved.monitor)
            self.assembler, self.previous = state["assembler"], state["previous"]
            self.rows, self.position = saved.rows, saved.position
        self.resumed = saved is not None
        self.samples, self.results, self.events, self.tokens = [], [], [], []
        self.nan_sd = np.full(model.ny, np.nan)
        self.dirty = False
        self.committed = clock.monotonic()
        self.counts = {}
        self.started_rows = self.rows

    def _run(self, spec, new_run):
        run = self.store.run()
        model_sha = fingerprint(self.model)
        if run is not None and not new_run:
            if run.model_sha256 != model_sha:
                raise MonitorError(f"the store {self.store.path} holds a run of another model (plant {run.plant!r}, "
                                   f"fingerprint {run.model_sha256[:12]}) than this spec (plant "
                                   f"{self.model.name!r}, fingerprint {model_sha[:12]}); give the spec it was "
                                   f"started with, or --new-run to start a new run in the store")
            for key in sorted(set(run.options) | set(self.options)):
                if run.options.get(key) != _plain(self.options.get(key)):
                    raise MonitorError(f"the store {self.store.path} holds a run started with {key} "
                                       f"{run.options.get(key)!r}, not {self.options.get(key)!r}; restart it with "
                                       f"the same options, or --new-run to start a new run in the store")
            return run
        return self.store.begin_run(spec, self.model, model_sha, self.options)

    # ----------------------------------------------------------------- the loop
    def run(self, stop: threading.Event | None = None) -> Stopped:
        """Diagnose until the data end or `stop` is set; every handled item is committed on return."""
        stop = stop or threading.Event()
        items = queue.Queue(maxsize=QUEUE)
        self.source.start(items.put, self.position)
        self._event(Event("resume" if self.resumed else "start", None,
                          f"run {self.run_info.id} {'resumed after' if self.resumed else 'started at'} row {self.rows}"))
        self.dirty, ended = True, False
        try:
            while not stop.is_set() and not ended:
                try:
                    item = items.get(timeout=IDLE)
                except queue.Empty:
                    if self.assembler is not None:
                        self._assembled(*self.assembler.advance(clock.time()))
                    self.commit()
                    continue
                ended = self._handle(item)
                if len(self.samples) >= BATCH or len(self.tokens) >= BATCH or items.empty() and (
                        self.results or clock.monotonic() - self.committed >= GROUP):
                    self.commit()
            if ended:
                self.diagnosis.finish()
                self.dirty = True
        finally:
            try:
                self.commit()
            finally:
                self.source.stop()
        return Stopped(self.run_info.id, self.rows - self.started_rows, self.rows, dict(self.counts), ended)

    def _handle(self, item) -> bool:
        """Take one item from the source; True at the end of the data."""
        kind = item[0]
        if kind == "row":
            _, row, self.position = item
            self._feed(row)
        elif kind == "readings":
            _, readings, arrival, token = item
            own = [stamp is not None and self.tags[name].time == "source" for name, _, stamp in readings]
            self._assembled(*self.assembler.add([(name, self.tags[name].value(value), stamp if mine else arrival)
                                                 for (name, value, stamp), mine in zip(readings, own)],
                                                not any(own)))
            self.tokens.append(token)
        elif kind == "malformed":
            _, message, token = item
            self._event(Event("malformed", None, message))
            self.tokens.append(token)
        elif kind == "event":
            self._event(item[1])
        elif kind == "fatal":
            raise MonitorError(item[1])
        self.dirty = True
        return kind == "end"

    def _assembled(self, rows, events):
        for event in events:
            self._event(event)
        for row in rows:
            self._feed(row)

    def _feed(self, row):
        self.rows += 1
        self.samples.append((self.rows, row))
        self.diagnosis.feed(row)

    def collect(self, done):
        """The diagnosis's sink: a finished row, stored with the next commit with the spread of its
        one-step prediction (from the row before it)."""
        last = self.previous
        sd = (self.nan_sd if last is None else
              predictive_sd(self.model, last.mode_posterior, last.state_mean, last.state_cov, done.row.u))
        self.results.append((done, sd))
        self.previous = done.step

    def _event(self, event: Event):
        self.events.append(event)
        self.counts[event.kind] = self.counts.get(event.kind, 0) + 1
        self.log(f"{event.kind}: {event.tag + ': ' if event.tag else ''}{event.detail}")

    def commit(self):
        """Store what was handled since the last commit with the state after it, in one transaction;
        then acknowledge it to the source."""
        if not self.dirty:
            return
        self.store.save(self.run_info.id, self.samples, self.results, self.events, self.rows,
                        self.diagnosis.checkpoint(), pickle.dumps({"assembler": self.assembler,
                                                                   "previous": self.previous}), self.position)
        self.samples, self.results, self.events, self.dirty = [], [], [], False
        self.committed = clock.monotonic()
        tokens, self.tokens = self.tokens, []
        self.source.acknowledge(tokens)


def _plain(value):
    """A value as the store's JSON gives it back (tuples as lists)."""
    return json.loads(json.dumps(value))
