"""A monitor as `jmlgdsl monitor` starts it: the fleet's options checked, each unit's own spec read,
one Monitor (or a fleet's shards on a Ray cluster) run until the data end or a signal stops it, and
what it did in a line.
"""

from __future__ import annotations

import signal
import threading
from pathlib import Path

from ..errors import JmlgError
from ..names import plural
from .live import Monitor, MonitorOptions, Stopped
from .sources import Connection
from .store import Store


def check_fleet(units, *, cluster: str | None, shards: int | None, unit_specs: str | None):
    """Refuse the options of a fleet (--cluster, --shards, --unit-specs) without its --units, and
    --shards without --cluster."""
    if (cluster or shards) and units is None:
        raise JmlgError(f"{'--cluster' if cluster else '--shards'} spreads the units of a fleet: give --units")
    if shards is not None and cluster is None:
        raise JmlgError("--shards needs --cluster")
    if unit_specs is not None and units is None:
        raise JmlgError("--unit-specs gives each unit of a fleet its own spec: give --units")


def unit_spec_banks(model, spec: str, folder: str | None, units, log) -> list | None:
    """Each unit's (model, spec text), its own spec FOLDER/UNIT.jmlg or the plant's `spec` (None
    without a folder); `log` says how many units have their own."""
    if folder is None:
        return None
    from ..diagnosis.fleet import unit_banks

    models, missing = unit_banks(model, folder, units)
    log(f"unit specs for {len(units) - len(missing)} of {plural(len(units), 'unit')} from {folder}"
        + (f"; {', '.join(missing)} with {spec}" if missing else ""))
    return [(bank, spec_text(spec if unit in missing else Path(folder) / f"{unit}.jmlg"))
            for unit, bank in zip(units, models)]


def watch(model, spec: str, store: str, password: str | None, source, connection: Connection, *,
          options: MonitorOptions, tags: dict, units=None, banks=None, sinks=(), new_run: bool = False,
          cluster: str | None = None, shards: int | None = None, stop: threading.Event, log) -> tuple[Stopped, int]:
    """Monitor `source` (opened from `connection`) into the store until the data end or `stop` is set,
    or with `cluster` the fleet's units in shards on that Ray cluster: what it did, and in how many
    shards (1 without a cluster)."""
    if cluster:
        return _sharded(model, spec, store, password, connection, options=options, tags=tags, units=units,
                        banks=banks, new_run=new_run, cluster=cluster, shards=shards, stop=stop, log=log)
    with Store(store, password=password) as opened:
        monitor = Monitor(model, opened, source, spec=spec_text(spec), options=options, tags=tags, units=units,
                          new_run=new_run, banks=banks, sinks=sinks, log=log)
        return monitor.run(stop), 1


def _sharded(model, spec, store, password, connection, *, options, tags, units, banks, new_run, cluster, shards,
             stop, log):
    from ..diagnosis.cluster import joined
    from .shards import ray_told, run_shards

    with joined(cluster, report=ray_told(log)) as ray:
        stop = stopped_by_signals(stop)  # Ray puts its own handlers in when it starts
        count = min(len(units), shards or max(1, int(ray.cluster_resources().get("CPU", 1))))
        log(f"{plural(len(units), 'unit')} in {plural(count, 'shard')} on the Ray cluster {cluster}")
        return run_shards(ray, model, store, password, spec=spec_text(spec), options=options, tags=tags, units=units,
                          count=count, source=connection, new_run=new_run, stop=stop, banks=banks), count


def summary(model, stopped: Stopped, store: str, units=None, cluster: str | None = None, count: int = 1) -> str:
    """What a monitor did, in a line: rows diagnosed here and in all, in which runs, and its events."""
    events = ", ".join(f"{kind} {n}" for kind, n in sorted(stopped.events.items()))
    runs = sorted(stopped.runs)
    where = f"run {runs[0]}" if units is None else f"the runs of {plural(len(units), 'unit')} ({runs[0]}..{runs[-1]})"
    shards = f" by {plural(count, 'shard')}" if cluster else ""
    return (f"{model.name}: {stopped.rows} rows diagnosed in {where} of {store}{shards} ({stopped.stored} in all)"
            f"{'; events: ' + events if events else ''}")


def stopped_by_signals(stop: threading.Event | None = None) -> threading.Event:
    """An event (`stop`, or a new one) that SIGTERM and Ctrl-C set."""
    stop = stop or threading.Event()
    for signum in (signal.SIGTERM, signal.SIGINT):
        signal.signal(signum, lambda *_: stop.set())
    return stop


def spec_text(path) -> str | None:
    """A spec file's text, to keep with the run (None for a binary compiled model)."""
    try:
        with open(path, encoding="utf-8") as stream:
            return stream.read()
    except UnicodeDecodeError:
        return None
