"""The monitor's store: one database holding runs, their rows, results, alarms, events and the
saved state they were diagnosed with: an SQLite file (WAL mode), or a PostgreSQL database
(postgresql://USER@HOST:PORT/DBNAME) that many monitors write and others read, with the same schema
(jmlgdsl/monitor/databases.py runs it on either).

Schema (vectors — y, u, posterior, state_mean, y_pred, residual, y_sd, evidence — are numbers in
the order the `run` row lists the names, each float64 as computed, NaN for a reading not measured:
in SQLite a BLOB of little-endian float64s, in PostgreSQL a double precision[]; see
jmlgdsl/monitor/databases.py):

    run     id, started (UTC ISO time), version, plant, spec (the spec file's text), spec_sha256,
            model_sha256 (the compiled model's fingerprint), options (JSON: filter, alarm rule, lag,
            source, ...; `times`, how the source writes times, added with the first rows), modes,
            states, outputs, inputs (JSON name lists), descriptions (JSON: mode name -> the spec's
            description), units (JSON: name -> physical unit), unit (the unit of a
            fleet this run diagnoses, e.g. pump07; NULL for a monitor of one plant)
    sample  run, t, time, y, u, mode, anomaly, changepoint: every row diagnosed, as assembled
    result  run, t, map_mode, posterior, state_mean, y_pred, residual, ess, loglik, alarm: every
            finished row (ess NULL for a filter without particles) (with --lag the posterior and state
            are smoothed over `lag` later rows); y_sd, the one-step predictive standard deviation per
            output; evidence_mode and evidence, the row's most probable unhealthy mode and each
            output's share of its log-likelihood ratio against the healthy modes (NULL when not kept)
    alarm   id, run, raised_t, raised_time, cleared_t, cleared_time (NULL while raised), mode (the
            most probable unhealthy mode when it was raised)
    action  id, run, alarm, at (UTC ISO time), who, kind (acknowledge, shelve, unshelve), reason:
            what operators did with the alarms (ISA-18.2), oldest first
    event   id, run, at (UTC ISO wall-clock time), time (the data time it concerns), kind, tag, detail
    state   run, rows (diagnosed so far), checkpoint (the Diagnosis), monitor (the row assembler),
            position (JSON: where the source resumes), saved (UTC ISO time); the checkpoint and the
            monitor's state are sealed (jmlgdsl.sealed: data only, with a checksum)
    delivery sink, run, t, action, saved: how far a sink of the monitor's conclusions (an MQTT
            broker, a webhook: jmlgdsl.monitor.outbox) has confirmed what it was handed, the rows
            up to result t and the actions up to action id `action`

Why packed vectors: a row of a 20-sensor bank holds 123 vector numbers, which as JSON text took
5,145 bytes of store (shortest round-trip digits, 17 of them for most floats); packed they take
1,272 (10.3 a number with the row's key, scalars and SQLite's pages; benchmarks/bench_monitor.py).
The writer packs them without formatting digits, `export` and the page read them back to the bit,
and a row stays one row of each table: a narrow run/t/tag/value layout would cost a key per number,
several times the bytes, and typed columns a column per sensor, a schema per model. float32 would
halve the probabilities and standard deviations but change the 10 digits `export` prints.

A store of an older schema (1: before y_sd, evidence, the alarm's mode, descriptions, units and
actions; 2: before the run's unit; 3: before the delivery marks; 4: vectors as JSON text) is
brought to schema 5 when it is opened, in one transaction: the columns it lacks are NULL for its old
rows, and its JSON vectors are converted in place to numbers (exactly: JSON kept each float's
shortest round-trip digits), so every reader reads one layout.

A fleet's monitor keeps a run per unit: every unit's rows, alarms and state are its run's, and the
`unit` column names the unit (SELECT ... FROM result JOIN run ON run.id = result.run WHERE
run.unit = 'pump07'). `Store.save` writes a batch of samples, results, alarms and events of any
number of runs together with their state in one transaction: the store never holds a row whose
state was not saved, nor state ahead of its rows.
"""

from __future__ import annotations

import csv
import dataclasses
import hashlib
import json
import math
from dataclasses import dataclass
from datetime import datetime, timezone
from typing import NamedTuple

import numpy as np

from ..data import TimeFormat
from ..infer.result import Step
from ..infer.table import TableWriter
from ..names import plural, spans
from ..version import VERSION
from .databases import StoreError, connect

SCHEMA_VERSION = 5
TIMES = "times"  # the key of a run's options that records how its source writes times (TimeFormat)
SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS run (
    id INTEGER PRIMARY KEY, started TEXT NOT NULL, version TEXT NOT NULL, plant TEXT NOT NULL,
    spec TEXT, spec_sha256 TEXT NOT NULL, model_sha256 TEXT NOT NULL, options TEXT NOT NULL,
    modes TEXT NOT NULL, states TEXT NOT NULL, outputs TEXT NOT NULL, inputs TEXT NOT NULL, descriptions TEXT,
    units TEXT, unit TEXT);
CREATE INDEX IF NOT EXISTS run_unit ON run (unit, id);
CREATE TABLE IF NOT EXISTS sample (
    run INTEGER NOT NULL, t INTEGER NOT NULL, time REAL, y VECTOR NOT NULL, u VECTOR NOT NULL,
    mode TEXT, anomaly INTEGER, changepoint INTEGER, PRIMARY KEY (run, t)) WITHOUT ROWID;
CREATE TABLE IF NOT EXISTS result (
    run INTEGER NOT NULL, t INTEGER NOT NULL, map_mode TEXT NOT NULL, posterior VECTOR NOT NULL,
    state_mean VECTOR NOT NULL, y_pred VECTOR NOT NULL, residual VECTOR NOT NULL, ess REAL,
    loglik REAL, alarm INTEGER NOT NULL, y_sd VECTOR, evidence_mode TEXT, evidence VECTOR,
    PRIMARY KEY (run, t)) WITHOUT ROWID;
CREATE TABLE IF NOT EXISTS alarm (
    id INTEGER PRIMARY KEY, run INTEGER NOT NULL, raised_t INTEGER NOT NULL, raised_time REAL,
    cleared_t INTEGER, cleared_time REAL, mode TEXT);
CREATE TABLE IF NOT EXISTS action (
    id INTEGER PRIMARY KEY, run INTEGER NOT NULL, alarm INTEGER NOT NULL, at TEXT NOT NULL, who TEXT NOT NULL,
    kind TEXT NOT NULL, reason TEXT);
CREATE TABLE IF NOT EXISTS event (
    id INTEGER PRIMARY KEY, run INTEGER NOT NULL, at TEXT NOT NULL, time REAL, kind TEXT NOT NULL,
    tag TEXT, detail TEXT NOT NULL);
CREATE INDEX IF NOT EXISTS event_kind ON event (run, kind);
CREATE TABLE IF NOT EXISTS state (
    run INTEGER PRIMARY KEY, rows INTEGER NOT NULL, checkpoint BLOB NOT NULL, monitor BLOB,
    position TEXT, saved TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS delivery (
    sink TEXT NOT NULL, run INTEGER NOT NULL, t INTEGER NOT NULL, action INTEGER NOT NULL, saved TEXT NOT NULL,
    PRIMARY KEY (sink, run));
"""


@dataclass(frozen=True)
class Run:
    """A run as the store records it."""

    id: int
    plant: str
    model_sha256: str
    options: dict
    modes: list
    states: list
    outputs: list
    inputs: list
    descriptions: dict  # mode name -> the spec's description
    engineering_units: dict  # name -> its unit of measure
    unit: str | None = None  # the unit of a fleet (None: a monitor of one plant)

    @property
    def times(self) -> TimeFormat:
        """How the run's source writes its rows' times (seconds where the run records none)."""
        return TimeFormat.from_json(self.options.get(TIMES))


ACTIONS = ("acknowledge", "shelve", "unshelve")
LONGEST = {"who": 100, "reason": 1000}  # characters of an action's name of who acts, and of its reason


@dataclass(frozen=True)
class Alarm:
    """An alarm episode with what operators did with it, in the ISA-18.2 states: active and
    unacknowledged, active and acknowledged, cleared but unacknowledged, cleared (and acknowledged:
    done), or shelved (hidden from the list of alarms to deal with, with a reason, until unshelved)."""

    id: int
    raised_t: int
    raised_time: float | None
    cleared_t: int | None
    cleared_time: float | None
    mode: str | None  # the most probable unhealthy mode when it was raised
    acknowledged: tuple | None  # (who, at) of the acknowledgement
    shelved: tuple | None  # (who, at, reason) while shelved

    @property
    def state(self) -> str:
        if self.shelved:
            return "shelved"
        return (("active" if self.cleared_t is None else "cleared") + ", "
                + ("acknowledged" if self.acknowledged else "unacknowledged"))


@dataclass
class Commit:
    """What one run's part of a commit writes: samples [(t, Row)], results [(Diagnosed, predictive sd
    (ny,))], events [Event], and the state after them (rows diagnosed, the Diagnosis checkpoint, the
    monitor's own state, the source position)."""

    run: int
    samples: list
    results: list
    events: list
    rows: int
    checkpoint: bytes
    monitor: bytes | None
    position: dict | None
    times: TimeFormat | None = None  # how the source writes the rows' times, to record with the run's options


@dataclass(frozen=True)
class Saved:
    """The state a run was last committed with."""

    rows: int
    checkpoint: bytes
    monitor: bytes | None
    position: dict | None
    at: str  # when it was committed (UTC ISO time)


UPGRADES = {"1": (("run", "descriptions"), ("run", "units"), ("result", "y_sd"), ("result", "evidence_mode"),
                  ("result", "evidence"), ("alarm", "mode")),
            "2": (("run", "unit"),), "3": (), "4": ()}  # the columns each older schema lacks (3: only a table)
VECTORS = {"sample": ("y", "u"), "result": ("posterior", "state_mean", "y_pred", "residual", "y_sd", "evidence")}


def now() -> str:
    """The wall-clock time, UTC, ISO 8601 to the microsecond."""
    return datetime.now(timezone.utc).isoformat()


def row_state(store: "Store", plant: str, record: Run, row, opened: int | None) -> dict:
    """A row's state as the sinks of the conclusions show it (jmlgdsl.monitor.outbox): `row` is the
    result's (t, time, map_mode, posterior, alarm) of the run `record` in `store`, `opened` the id of
    the alarm open at it (None: none)."""
    t, time, mode, posterior, alarm = row
    probabilities = store.db.unvector(posterior, len(record.modes)).tolist()
    return {"plant": plant, "unit": record.unit, "run": record.id, "t": t, "time": time, "mode": mode,
            "probability": probabilities[record.modes.index(mode)], "modes": dict(zip(record.modes, probabilities)),
            "alarm": bool(alarm), "alarm_id": opened}


def damaged(path: str, damage: list[str]) -> str:
    """What a damaged store says of itself, and what to do."""
    found = "; ".join(line for problem in damage for line in problem.splitlines() if not line.startswith("***"))
    return (f"{path}: the store's file is damaged (SQLite's check: {found}); 'sqlite3 {path} .recover' copies what "
            "it can into a new file, or restore the file from a backup")


class Exported(NamedTuple):
    """What an export wrote: its rows, and the t of the rows left out because they could not be read."""

    rows: int
    damaged: list

    def left_out(self) -> str:
        """What the export left out, in words ('' for nothing)."""
        if not self.damaged:
            return ""
        return (f"{plural(len(self.damaged), 'row')} could not be read and "
                f"{'is' if len(self.damaged) == 1 else 'are'} left out (t {spans(self.damaged)})")


class Store:
    """An open store at a location: an SQLite file's path or a PostgreSQL URL (with its user's
    `password`, or none to use libpq's PGPASSFILE or ~/.pgpass). `synchronous` is SQLite's: FULL
    makes every commit durable before the monitor acknowledges what it holds (PostgreSQL's commits
    are durable by default). Without `create`, a location that holds no store is refused."""

    def __init__(self, location, synchronous: str = "FULL", create: bool = True, password: str | None = None):
        self.path = str(location)
        self._runs = {}
        self.db = connect(self.path, password=password, synchronous=synchronous, create=create)
        try:
            if self._meta_schema() != str(SCHEMA_VERSION):
                self._make(create)
        except (StoreError, self.db.errors) as exc:
            damage = self.db.damage()
            self.db.close()
            if damage:
                raise StoreError(damaged(self.path, damage)) from None
            if isinstance(exc, StoreError):
                raise
            raise StoreError(f"{self.path}: not a usable jmlgdsl store ({exc})") from None

    def _meta_schema(self) -> str | None:
        """The schema version a store records (None for a database without a store)."""
        if self.db.execute(self.db.has_table, ("meta",)).fetchone() is None:
            return None
        found = self.db.execute("SELECT value FROM meta WHERE key = 'schema'").fetchone()
        return None if found is None else found[0]

    def _make(self, create: bool):
        """Make the store's tables, or bring an older store to this schema (the new columns, NULL for
        the rows already there, its JSON vectors as numbers, and the new tables), in one transaction
        that holds the lock, so monitors that open a new store at once make it once."""
        with self._transaction():
            self.db.lock_schema()
            found = self._meta_schema()
            if found is None and not create:
                raise StoreError(f"{self.path}: not a jmlgdsl store (it holds no store's tables)")
            if found in UPGRADES:
                for version in range(int(found), SCHEMA_VERSION):
                    for table, column in UPGRADES[str(version)]:
                        self.db.execute(f"ALTER TABLE {table} ADD COLUMN {column} TEXT")
                for table, columns in VECTORS.items():  # every older schema kept them as JSON text
                    self.db.vectors_from_json(table, columns, _create(table))
                self.db.execute("UPDATE meta SET value = ? WHERE key = 'schema'", (str(SCHEMA_VERSION),))
            elif found not in (None, str(SCHEMA_VERSION)):
                raise StoreError(f"{self.path}: a store of schema {found}; this jmlgdsl reads schema {SCHEMA_VERSION}")
            for statement in self.db.schema(SCHEMA).split(";")[:-1]:
                self.db.execute(statement)
            if found is None:
                self.db.execute("INSERT INTO meta VALUES ('schema', ?)", (str(SCHEMA_VERSION),))

    def close(self):
        self.db.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # ------------------------------------------------------------------ runs
    def run(self, id: int | None = None, unit: str | None = None) -> Run | None:
        """A run by id, or the latest (of a fleet's `unit`, when given); None when the store has none.
        A record that cannot be read (a damaged store) is a StoreError that names the runs that can."""
        try:
            return self._run(id, unit)
        except (self.db.errors, ValueError, TypeError) as exc:
            which = f"run {id}" if id is not None else "the latest run" + (f" of unit {unit}" if unit else "")
            readable = self.readable_runs()
            raise StoreError(f"{self.path}: the record of {which} cannot be read, the store is damaged ({_short(exc)}); "
                             + (f"runs that read: {', '.join(map(str, readable))} (--run N)" if readable else
                                "no run's record reads")) from None

    def _run(self, id, unit) -> Run | None:
        query = ("SELECT id, plant, model_sha256, options, modes, states, outputs, inputs, descriptions, units, unit "
                 "FROM run ")
        if id is not None:
            row = self.db.execute(query + "WHERE id = ?", (id,)).fetchone()
            if row is None:
                raise StoreError(f"{self.path}: no run {id}")
        elif unit is not None:
            row = self.db.execute(query + "WHERE unit = ? ORDER BY id DESC LIMIT 1", (unit,)).fetchone()
        else:
            row = self.db.execute(query + "ORDER BY id DESC LIMIT 1").fetchone()
        if row is None:
            return None
        found = Run(row[0], row[1], row[2], json.loads(row[3]), *(json.loads(v or "{}") for v in row[4:10]), row[10])
        if not all(isinstance(names, list) and all(isinstance(n, str) for n in names)
                   for names in (found.modes, found.states, found.outputs, found.inputs)):
            raise ValueError("its lists of names are not lists of names")
        return found

    def readable_runs(self) -> list[int]:
        """The runs whose records read back whole."""
        try:
            ids = [row[0] for row in self.db.execute("SELECT id FROM run ORDER BY id")]
        except self.db.errors:
            return []
        readable = []
        for id in ids:
            try:
                self._run(id, None)
                readable.append(id)
            except (self.db.errors, ValueError, TypeError):
                pass
        return readable

    def units(self) -> list[str]:
        """The units of a fleet that have runs in the store, in the order their first runs began."""
        return [row[0] for row in self.db.execute(
            "SELECT unit FROM run WHERE unit IS NOT NULL GROUP BY unit ORDER BY min(id)")]

    def begin_run(self, spec: str | None, model, fingerprint: str, options: dict, unit: str | None = None) -> Run:
        """Record a new run of a model with these options (of a fleet's `unit`, when given)."""
        names = [json.dumps(list(v)) for v in (model.modes, model.states, model.outputs, model.inputs)]
        sha = hashlib.sha256((spec or "").encode()).hexdigest()
        with self._transaction():
            new = self.db.insert("INSERT INTO run (started, version, plant, spec, spec_sha256, model_sha256, "
                                 "options, modes, states, outputs, inputs, descriptions, units, unit) "
                                 "VALUES (?,?,?,?,?,?,?,?,?,?,?,?,?,?)",
                                 (now(), VERSION, model.name, spec, sha, fingerprint,
                                  json.dumps(options, sort_keys=True), *names, json.dumps(model.descriptions),
                                  json.dumps(model.engineering_units), unit))
        return self.run(new)

    def saved(self, run: int) -> Saved | None:
        """The state last committed for a run (None before its first commit)."""
        try:
            row = self.db.execute("SELECT rows, checkpoint, monitor, position, saved FROM state WHERE run = ?",
                                  (run,)).fetchone()
            if row is None:
                return None
            stored = self.db.execute("SELECT coalesce(max(t), 0) FROM sample WHERE run = ?", (run,)).fetchone()[0]
            if row[0] != stored:
                raise ValueError(f"it counts {row[0]!r} rows diagnosed where the run's rows end at {stored}")
            return Saved(row[0], row[1], row[2], None if row[3] is None else json.loads(row[3]), row[4])
        except (self.db.errors, ValueError) as exc:
            raise StoreError(f"{self.path}: the saved state of run {run} cannot be read, the store is damaged "
                             f"({_short(exc)}); the run's rows that read can be exported ('jmlgdsl export'); start a new "
                             f"run with --new-run") from None

    def delivered(self, sink: str) -> dict:
        """{run: (t, action)}: how far a sink confirmed each run's conclusions (jmlgdsl.monitor.outbox)."""
        return {run: (t, action) for run, t, action in
                self.db.execute("SELECT run, t, action FROM delivery WHERE sink = ?", (sink,))}

    # ------------------------------------------------------------------ the one write
    def save(self, commits: list[Commit], marks=()):
        """Commit every run's part (a Commit each) in one transaction: all of them, or none; with the
        sinks' delivery `marks` (sink, run, t, action) when given."""
        try:
            with self._transaction():
                at = now()
                for commit in commits:
                    self._save(commit, at)
                self.db.executemany("INSERT INTO delivery VALUES (?,?,?,?,?) ON CONFLICT (sink, run) DO UPDATE SET "
                                    "t = excluded.t, action = excluded.action, saved = excluded.saved",
                                    [(*mark, at) for mark in marks])
        except self.db.errors as exc:
            raise StoreError(f"{self.path}: the store failed while saving ({exc}); nothing of this batch was kept, "
                             "and the monitor started again resumes from its last commit") from None

    def _save(self, commit: Commit, at: str):
        run, samples, results, events = commit.run, commit.samples, commit.results, commit.events
        modes, vector = self._modes(run), self.db.vector
        if commit.times is not None:
            recorded = self._recorded(run)
            options = dict(recorded.options, **{TIMES: commit.times.as_json()})
            self.db.execute("UPDATE run SET options = ? WHERE id = ?", (json.dumps(options, sort_keys=True), run))
            self._runs[run] = dataclasses.replace(recorded, options=options)
        self.db.executemany("INSERT INTO sample VALUES (?,?,?,?,?,?,?,?)", [
            (run, t, row.time, vector(row.y), vector(row.u), None if row.mode is None else modes[row.mode],
             row.anomaly, row.changepoint) for t, row in samples])
        self.db.executemany("INSERT INTO result (run, t, map_mode, posterior, state_mean, y_pred, residual, ess, "
                            "loglik, alarm, y_sd, evidence_mode, evidence) VALUES (?,?,?,?,?,?,?,?,?,?,?,?,?)", [
            (run, d.step.t, modes[d.step.map_mode], vector(d.step.mode_posterior), vector(d.step.state_mean),
             vector(d.step.y_pred), vector(d.step.residual), _real(d.step.ess), _real(d.step.loglik), d.alarm,
             vector(sd), *_evidence(d.evidence, modes, vector))
            for d, sd in results])
        self._alarms(run, [d for d, _ in results])
        self.db.executemany("INSERT INTO event (run, at, time, kind, tag, detail) VALUES (?,?,?,?,?,?)",
                            [(run, at, e.time, e.kind, e.tag, e.detail) for e in events])
        self.db.execute("INSERT INTO state VALUES (?,?,?,?,?,?) ON CONFLICT (run) DO UPDATE SET "
                        "rows = excluded.rows, checkpoint = excluded.checkpoint, monitor = excluded.monitor, "
                        "position = excluded.position, saved = excluded.saved",
                        (run, commit.rows, commit.checkpoint, commit.monitor,
                         None if commit.position is None else json.dumps(commit.position), at))

    def _alarms(self, run, results):
        """Alarm episodes from the results' 0/1 alarms, continuing the one open in the store; each
        names the most probable unhealthy mode of the row that raised it."""
        open_ = self.db.execute("SELECT id FROM alarm WHERE run = ? AND cleared_t IS NULL", (run,)).fetchone()
        for d in results:
            if d.alarm and open_ is None:
                modes, healthy = self._modes(run), self._recorded(run).options.get("healthy", [])
                unhealthy = [k for k, name in enumerate(modes) if name not in healthy]
                mode = modes[max(unhealthy, key=lambda k: d.step.mode_posterior[k])] if unhealthy else None
                open_ = (self.db.insert("INSERT INTO alarm (run, raised_t, raised_time, mode) VALUES (?,?,?,?)",
                                        (run, d.step.t, d.row.time, mode)),)
            elif not d.alarm and open_ is not None:
                self.db.execute("UPDATE alarm SET cleared_t = ?, cleared_time = ? WHERE id = ?",
                                (d.step.t, d.row.time, open_[0]))
                open_ = None

    def act(self, run: int, alarm: int, kind: str, who: str, reason: str | None = None):
        """Record what an operator did with an alarm (ISA-18.2: acknowledge, shelve with a reason,
        unshelve), committed before it returns; an action that does not apply is refused."""
        found = {a.id: a for a in self.alarms(run)}.get(alarm)
        if found is None:
            raise StoreError(f"run {run} has no alarm {alarm}")
        if kind not in ACTIONS:
            raise StoreError(f"unknown action {kind!r}; one of {', '.join(ACTIONS)}")
        for name, text in (("who", who), ("reason", reason)):
            if text is not None and (not isinstance(text, str) or len(text) > LONGEST[name]
                                     or not text.isprintable()):
                raise StoreError(f"{'who acts' if name == 'who' else 'the reason'} is one line of at most "
                                 f"{LONGEST[name]} printable characters")
        if not who.strip():
            raise StoreError("say who acts (a name or initials)")
        if kind == "acknowledge" and found.acknowledged:
            raise StoreError(f"alarm {alarm} is acknowledged already")
        if kind == "shelve" and (found.shelved or not (reason or "").strip()):
            raise StoreError(f"alarm {alarm} is shelved already" if found.shelved else "shelving needs a reason")
        if kind == "unshelve" and not found.shelved:
            raise StoreError(f"alarm {alarm} is not shelved")
        with self._transaction():
            self.db.execute("INSERT INTO action (run, alarm, at, who, kind, reason) VALUES (?,?,?,?,?,?)",
                            (run, alarm, now(), who.strip(), kind, (reason or "").strip() or None))

    def alarms(self, run: int, actions: int | None = None) -> list[Alarm]:
        """A run's alarms, oldest first, with their acknowledgement and shelving (as they stood after
        the action of id `actions`, when given)."""
        acknowledged, shelved = {}, {}
        for alarm, at, who, kind, reason in self.db.execute(
                "SELECT alarm, at, who, kind, reason FROM action WHERE run = ?"
                + ("" if actions is None else " AND id <= ?") + " ORDER BY id",
                (run,) if actions is None else (run, actions)):
            if kind == "acknowledge":
                acknowledged[alarm] = (who, at)
            elif kind == "shelve":
                shelved[alarm] = (who, at, reason)
            else:
                shelved.pop(alarm, None)
        return [Alarm(*row, acknowledged.get(row[0]), shelved.get(row[0])) for row in self.db.execute(
            "SELECT id, raised_t, raised_time, cleared_t, cleared_time, mode FROM alarm WHERE run = ? ORDER BY id",
            (run,))]

    def _modes(self, run):
        return self._recorded(run).modes

    def _recorded(self, run) -> Run:
        """A run as recorded, read once (it does not change once begun, but for the record of how its
        source writes times, which its first rows' commit adds)."""
        if run not in self._runs:
            self._runs[run] = self.run(run)
        return self._runs[run]

    def _transaction(self):
        return _Transaction(self.db)

    # ------------------------------------------------------------------ reading back
    def counts(self, run: int, after: int = 0) -> dict:
        """{kind: number} of a run's events (of those after the event of id `after`, when given)."""
        return dict(self.db.execute("SELECT kind, count(*) FROM event WHERE run = ? AND id > ? GROUP BY kind",
                                    (run, after)))

    def newest_event(self) -> int:
        """The id of the newest event in the store (0 for none): what comes after it is newer."""
        return self.db.execute("SELECT coalesce(max(id), 0) FROM event").fetchone()[0]

    def write_table(self, run: Run, stream) -> Exported:
        """The result table of a run's finished rows, as `jmlgdsl run -o` writes it for the same rows;
        rows that cannot be read (a damaged store) are left out and named."""
        lag, writer, exported = run.options.get("lag", 0), None, Exported(0, [])
        query = ("SELECT r.t, s.time, r.posterior, r.state_mean, r.y_pred, r.residual, r.loglik, r.ess, r.alarm "
                 "FROM result r JOIN sample s ON s.run = r.run AND s.t = r.t WHERE r.run = ? AND r.t > ? ORDER BY r.t")
        K, nx, ny, unvector = len(run.modes), len(run.states), len(run.outputs), self.db.unvector

        def step(row):
            t, time, posterior, mean, pred, residual, loglik, ess, alarm = row
            if alarm not in (0, 1):
                raise ValueError(f"an alarm of {alarm!r}")
            return Step(t, unvector(posterior, K), unvector(mean, nx), None, unvector(pred, ny),
                        unvector(residual, ny), _number(loglik), _number(ess)), _time(time), alarm

        for found, time, alarm in self.readable(query, run, step, exported.damaged):
            if writer is None:
                writer = TableWriter(stream, _Names(run), time is not None, lag=lag)
            writer.write(found, time, alarm)
            exported = exported._replace(rows=exported.rows + 1)
        return exported

    def write_samples(self, run: Run, stream) -> Exported:
        """The rows a run diagnosed as a data file (their times as the source wrote them, outputs,
        inputs and the labels they carry), every number in its shortest exact form, so `jmlgdsl run` on
        it diagnoses the same rows; rows that cannot be read (a damaged store) are left out and named."""
        exported, writer, times = Exported(0, []), None, run.times
        query = "SELECT t, time, y, u, mode, anomaly, changepoint FROM sample WHERE run = ? AND t > ? ORDER BY t"
        ny, nu, unvector = len(run.outputs), len(run.inputs), self.db.unvector
        labels = [name for name in ("mode", "anomaly", "changepoint") if self._labelled(run, name)]

        def cells(row):
            _, time, y, u, *marks = row
            known = dict(zip(("mode", "anomaly", "changepoint"), marks))
            if not (known["mode"] is None or known["mode"] in run.modes) or not all(
                    known[name] in (None, 0, 1) for name in ("anomaly", "changepoint")):
                raise ValueError("labels that are not a mode's name or 0/1")
            time = _time(time)
            values = [_cell(v) for v in np.concatenate([unvector(y, ny), unvector(u, nu)])]
            return (None if time is None or time != time else times.write(time),
                    values + ["" if known[name] is None else known[name] for name in labels])

        for time, row in self.readable(query, run, cells, exported.damaged):
            if writer is None:
                writer, timed = csv.writer(stream, lineterminator="\n"), time is not None
                writer.writerow(([times.column] if timed else []) + run.outputs + run.inputs + labels)
            writer.writerow(([time] if timed else []) + row)
            exported = exported._replace(rows=exported.rows + 1)
        return exported

    def _labelled(self, run: Run, name: str) -> bool:
        """Whether a run's rows carry a label (mode, anomaly, changepoint); not, when that cannot be read."""
        try:
            return self.db.execute(f"SELECT 1 FROM sample WHERE run = ? AND {name} IS NOT NULL LIMIT 1",
                                   (run.id,)).fetchone() is not None
        except self.db.errors:
            return False

    def readable(self, query: str, run: Run, decode, damaged: list, after: int = 0):
        """decode(row) of each row of a run that `query` gives (its parameters the run and a t to read
        after, its rows in order of t, t first), but of a row that cannot be read (a damaged page, text
        that is not UTF-8, a cell the store did not write): that one's t goes to `damaged` instead.
        A run's rows are t = 1, 2, ...: a row that does not read is stepped over, up to the last the
        run's state counts. `after`: the t to read after (0: from the first row)."""
        t, end = after, self._end(run)
        while True:
            try:
                for row in self.db.execute(query, (run.id, t)):
                    damaged += range(t + 1, row[0])  # rows a damaged page hides without an error
                    t = row[0]
                    try:
                        value = decode(row)
                    except (ValueError, TypeError):
                        damaged.append(t)
                        continue
                    yield value
                return
            except self.db.errors:
                if t >= end:
                    return
                t += 1
                damaged.append(t)

    def _end(self, run: Run) -> int:
        """The last row of a run that its state or its rows name (0 when neither reads)."""
        ends = []
        for query in ("SELECT rows FROM state WHERE run = ?", "SELECT max(t) FROM sample WHERE run = ?"):
            try:
                ends += [v for v in self.db.execute(query, (run.id,)).fetchone() or () if isinstance(v, int)]
            except self.db.errors:
                pass
        return max(ends, default=0)

    def damage(self) -> list[str]:
        """What a check of the store's file finds wrong with it (SQLite's quick check); [] for nothing."""
        return self.db.damage()


def _evidence(evidence, modes, vector) -> tuple:
    """(evidence_mode, evidence) columns of a row's Evidence (NULL, NULL without one), its terms as `vector` keeps them."""
    return (None, None) if evidence is None else (modes[evidence.mode], vector(evidence.terms))


def _create(table: str) -> str:
    """The schema's statement that makes a table."""
    return next(s for s in SCHEMA.split(";") if s.strip().startswith(f"CREATE TABLE IF NOT EXISTS {table} ("))


def _real(value) -> float | None:
    """A number for a REAL column: NaN, which SQLite cannot hold, as NULL."""
    return None if math.isnan(value) else float(value)


def _short(exc: Exception) -> str:
    """An error's text on one line, cut short (SQLite's decoding errors quote the whole cell)."""
    text = " ".join(str(exc).split())
    return text if len(text) <= 120 else text[:117] + "..."


def _number(value) -> float:
    """A REAL column's number (NULL: NaN); a ValueError for anything else."""
    if value is None:
        return math.nan
    if type(value) not in (int, float):
        raise ValueError(f"not a number: {value!r:.40}")
    return float(value)


def _time(value) -> float | None:
    """A row's time (NULL: none); a ValueError for anything else."""
    return None if value is None else _number(value)


def _cell(value) -> str:
    """A data file's cell: empty for a reading not measured."""
    return "" if math.isnan(value) else repr(float(value))


class _Names:
    """What the table writer needs of a model, from the names a run recorded."""

    def __init__(self, run: Run):
        self.modes, self.states, self.outputs = run.modes, run.states, run.outputs


class _Transaction:
    """BEGIN ... COMMIT, or ROLLBACK on an exception: whole or absent (SQLite's BEGIN IMMEDIATE
    takes the write lock at the start, so a transaction never fails halfway for want of it)."""

    def __init__(self, db):
        self.db = db

    def __enter__(self):
        self.db.execute(self.db.begin)

    def __exit__(self, kind, exc, traceback):
        if kind is None:
            self.db.execute("COMMIT")
            return
        try:
            self.db.execute("ROLLBACK")
        except self.db.errors:
            pass  # the connection is gone, and its transaction with it
