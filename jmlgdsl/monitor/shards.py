"""A fleet's monitor spread over a Ray cluster (`jmlgdsl monitor --units ... --cluster auto|HOST:PORT`):
the units split into shards, each shard a `Monitor` of its units in a Ray actor, with its own
connection to the source (an MQTT session of its own, its units' files or OPC UA sessions) and
to the store (PostgreSQL for a cluster of machines; an SQLite file serves the shards of one).

Every shard commits its units' rows with their state, and acknowledges to its source only after,
as a monitor on its own does. An actor that dies (its process killed, its machine gone) is started
again by Ray: its Monitor resumes its units' runs from their last commit, its source delivers again
what was not acknowledged, and its `run` call is made again, so no row is lost or diagnosed twice.
The driver makes (or checks) every unit's run before any shard starts, so a restarted shard only
ever resumes; `stop` ends every shard with a last commit.

    >>> split(["p1", "p2", "p3", "p4", "p5"], 2)
    [['p1', 'p2', 'p3'], ['p4', 'p5']]
"""

from __future__ import annotations

import dataclasses
import os
import re
import socket
import threading

from ..diagnosis.cluster import completed
from .live import Monitor, MonitorOptions, Stopped, open_runs, recorded_options
from .sources import Connection, open_source
from .store import Store, StoreError, is_url

STOPPING = 30.0  # seconds the shards have to commit and end once stopped
# Ray's message for the driver when a worker's process dies (Ray 2.x), with the fields said again
DIED = re.compile(r"A worker died or was killed\b.*?Worker PID: (\d+).*?Worker exit type: (\w+)"
                  r"(?:.*?Worker exit detail: (.*?)\.)?")
RETRIED = re.compile(r"Task Shard\.run failed\. There are infinite retries remaining")  # ... a shard died


def ray_told(log):
    """Ray's messages for a fleet's monitor (jmlgdsl.diagnosis.cluster.connect's `report`), in its log's words: a
    shard's process that died is one line that says what follows; that Ray tries the shard's task
    again says nothing more; anything else is Ray's own text."""

    def report(text):
        died = DIED.search(text)
        if died:
            pid, kind, detail = died.groups()
            log(f"a shard's process (pid {pid}) ended ({kind}{': ' + detail if detail else ''}); Ray starts it "
                "again, and its units resume from their last commit")
        elif not RETRIED.search(text):
            log(f"ray: {text}")
    return report


def split(units: list, count: int) -> list[list]:
    """`units` in `count` contiguous shards of sizes that differ by one at most (the first ones larger)."""
    size, extra = divmod(len(units), count)
    bounds = [0]
    for k in range(count):
        bounds.append(bounds[-1] + size + (k < extra))
    return [units[a:b] for a, b in zip(bounds, bounds[1:])]


class Shard:
    """A Monitor of some units of a fleet, as a Ray actor runs it: made (resumed from the store) when
    the actor starts or starts again, `run()` until `stop()`. `source` is the fleet's Connection,
    opened as this shard's (its `index`); `banks` its units' own (model, spec text), as Monitor
    takes them."""

    def __init__(self, model, location: str, password: str | None, spec: str | None, options: MonitorOptions,
                 tags: dict, units: list, index: int, source: Connection, banks=None):
        if not is_url(location) and not os.path.exists(location):
            raise StoreError(f"the store {location} is not on the machine of shard {index} ({socket.gethostname()}): "
                             "the shards of a cluster of machines share a PostgreSQL store (postgresql://...)")
        self.store = Store(location, password=password, create=False)  # made by the driver: never another here
        self.monitor = Monitor(model, self.store, open_source(dataclasses.replace(source, shard=index), model, tags,
                                                             units), spec=spec, options=options, tags=tags,
                               units=units, banks=banks)
        self.stopping = threading.Event()

    def run(self) -> Stopped:
        try:
            return self.monitor.run(self.stopping)
        finally:
            self.store.close()

    def stop(self):
        self.stopping.set()


def run_shards(ray, model, location: str, password: str | None, *, spec: str | None, options: MonitorOptions,
               tags: dict, units: list, count: int, source: Connection, new_run: bool = False,
               stop: threading.Event | None = None, banks=None) -> Stopped:
    """Monitor `units` in `count` shards on the joined Ray cluster until their data end or `stop` is
    set; what they did, counted in the store (a shard that Ray started again returns the count of its
    last start only). `source` is the fleet's Connection; `banks` each unit's own (model, spec text),
    as Monitor takes them."""
    banks = banks or [(model, spec)] * len(units)
    with Store(location, password=password) as store:  # every unit's run made or checked here, once
        name = open_source(source, model, tags, units).name
        runs = open_runs(store, model, spec, recorded_options(model, options, name, tags), units, new_run, banks)
        before, since = _rows(store, runs), store.newest_event()
    parts = _shards(ray, model, location, password, spec, options, tags, units, count, source, stop, banks)
    with Store(location, password=password, create=False) as store:
        stored, events = _rows(store, runs), {}
        for run in runs:
            for kind, n in store.counts(run.id, after=since).items():
                events[kind] = events.get(kind, 0) + n
    return Stopped(tuple(run.id for run in runs), stored - before, stored, events, all(p.ended for p in parts))


def _rows(store, runs) -> int:
    """Rows diagnosed in the store's `runs`, all together."""
    return sum(saved.rows for saved in map(store.saved, (run.id for run in runs)) if saved is not None)


def _shards(ray, model, location, password, spec, options, tags, units, count, source, stop, banks) -> list[Stopped]:
    """Run the shards until their data end or `stop` is set, each stopped with a last commit; each
    shard's Stopped, of its last start."""
    # started again whenever its process dies, its run() made again there; stop() is taken while run() runs
    actor = ray.remote(max_restarts=-1, max_task_retries=-1, max_concurrency=2, num_cpus=1)(Shard)
    parts = split(list(range(len(units))), min(count, len(units)))
    actors = [actor.remote(model, location, password, spec, options, tags, [units[i] for i in part], k, source,
                           [banks[i] for i in part]) for k, part in enumerate(parts)]
    running = [a.run.remote() for a in actors]
    try:
        for _ in completed(ray, running, stop or threading.Event()):
            pass  # a shard that fails (a refused password, a store that fails) stops the fleet with its error
    finally:
        stopping = [a.stop.remote() for a in actors]  # each commits what it handled, then ends
        ray.wait(running + stopping, num_returns=len(actors) * 2, timeout=STOPPING)
    try:
        ended = dict(completed(ray, running))
        return [ended[k] for k in range(len(running))]
    finally:
        for a in actors:
            ray.kill(a, no_restart=True)
