"""The store's tables and the in-place upgrades of an older store to them.

Schema (vectors — y, u, posterior, state_mean, y_pred, residual, y_sd, evidence — are numbers in
the order the `run` row lists the names, each float64 as computed, NaN for a reading not measured:
in SQLite a BLOB of little-endian float64s, in PostgreSQL a double precision[]; see
jmlgdsl/monitor/store/databases.py):

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
            broker, a webhook: jmlgdsl.monitor.sinks.outbox) has confirmed what it was handed, the rows
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
"""

from __future__ import annotations

from .databases import StoreError

SCHEMA_VERSION = 5
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
UPGRADES = {"1": (("run", "descriptions"), ("run", "units"), ("result", "y_sd"), ("result", "evidence_mode"),
                  ("result", "evidence"), ("alarm", "mode")),
            "2": (("run", "unit"),), "3": (), "4": ()}  # the columns each older schema lacks (3: only a table)
VECTORS = {"sample": ("y", "u"), "result": ("posterior", "state_mean", "y_pred", "residual", "y_sd", "evidence")}


def recorded(db) -> str | None:
    """The schema version a database's store records (None for a database without a store)."""
    if db.execute(db.has_table, ("meta",)).fetchone() is None:
        return None
    found = db.execute("SELECT value FROM meta WHERE key = 'schema'").fetchone()
    return None if found is None else found[0]


def make(db, path: str, create: bool):
    """Make a store's tables in the database `db` (at `path`), or bring an older store to this schema
    (the new columns, NULL for the rows already there, its JSON vectors as numbers, and the new
    tables); in the caller's transaction, with the lock that makes monitors that open a new store at
    once make it once. Without `create`, a database that holds no store is refused."""
    db.lock_schema()
    found = recorded(db)
    if found is None and not create:
        raise StoreError(f"{path}: not a jmlgdsl store (it holds no store's tables)")
    if found in UPGRADES:
        for version in range(int(found), SCHEMA_VERSION):
            for table, column in UPGRADES[str(version)]:
                db.execute(f"ALTER TABLE {table} ADD COLUMN {column} TEXT")
        for table, columns in VECTORS.items():  # every older schema kept them as JSON text
            db.vectors_from_json(table, columns, _create(table))
        db.execute("UPDATE meta SET value = ? WHERE key = 'schema'", (str(SCHEMA_VERSION),))
    elif found not in (None, str(SCHEMA_VERSION)):
        raise StoreError(f"{path}: a store of schema {found}; this jmlgdsl reads schema {SCHEMA_VERSION}")
    for statement in db.schema(SCHEMA).split(";")[:-1]:
        db.execute(statement)
    if found is None:
        db.execute("INSERT INTO meta VALUES ('schema', ?)", (str(SCHEMA_VERSION),))


def _create(table: str) -> str:
    """The schema's statement that makes a table."""
    return next(s for s in SCHEMA.split(";") if s.strip().startswith(f"CREATE TABLE IF NOT EXISTS {table} ("))
