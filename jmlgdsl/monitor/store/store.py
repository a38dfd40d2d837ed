"""The monitor's store: one database holding runs, their rows, results, alarms, events and the
saved state they were diagnosed with: an SQLite file (WAL mode), or a PostgreSQL database
(postgresql://USER@HOST:PORT/DBNAME) that many monitors write and others read, with the same schema
(jmlgdsl/monitor/store/schema.py; jmlgdsl/monitor/store/databases.py runs it on either).

`Store` is the one place of the package that speaks SQL. What it offers:

- opening: a store made, or an older one upgraded, when opened (`Store(location)`), `damage`;
- runs: `run`, `readable_runs`, `units`, `begin_run`, and the state a run resumes from, `saved`;
- the one write, `save`: a batch of samples, results, alarms and events of any number of runs
  together with their state and the sinks' delivery marks, in one transaction; and `act`, an
  operator's action on an alarm;
- the queries readers need, as the values of jmlgdsl/monitor/store/records.py: a run's rows in a
  range (`results`, `steps`, `samples`, `labels`, `evidence`), its newest row (`newest`, `last_t`),
  the conclusions after a place (`verdicts`), its alarms and actions (`alarms`, `alarms_stamp`,
  `actions`, `newest_action`), its events (`counts`, `newest_event`) and the sinks' marks
  (`delivered`). A query of a damaged store leaves out the rows that cannot be read.

A fleet's monitor keeps a run per unit: every unit's rows, alarms and state are its run's, and the
`unit` column names the unit (SELECT ... FROM result JOIN run ON run.id = result.run WHERE
run.unit = 'pump07'). The store never holds a row whose state was not saved, nor state ahead of
its rows.
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
import math
from datetime import datetime, timezone

from ...infer.result import Step
from ...version import VERSION
from . import schema
from .databases import StoreError, connect
from .records import ACTIONS, LABELS, LONGEST, TIMES, Action, Alarm, Commit, Finished, Run, Sample, Saved, Verdict


def now() -> str:
    """The wall-clock time, UTC, ISO 8601 to the microsecond."""
    return datetime.now(timezone.utc).isoformat()


def damaged(path: str, damage: list[str]) -> str:
    """What a damaged store says of itself, and what to do."""
    found = "; ".join(line for problem in damage for line in problem.splitlines() if not line.startswith("***"))
    return (f"{path}: the store's file is damaged (SQLite's check: {found}); 'sqlite3 {path} .recover' copies what "
            "it can into a new file, or restore the file from a backup")


# a finished row with its sample, as the page shows it (Finished), and as its conclusion (Verdict)
FINISHED = ("SELECT r.t, s.time, r.map_mode, r.alarm, r.posterior, s.y, r.y_pred, r.y_sd, r.evidence_mode, r.evidence "
            "FROM result r JOIN sample s ON s.run = r.run AND s.t = r.t")
VERDICT = ("SELECT r.t, s.time, r.map_mode, r.posterior, r.alarm "
           "FROM result r JOIN sample s ON s.run = r.run AND s.t = r.t")


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
            if schema.recorded(self.db) != str(schema.SCHEMA_VERSION):
                with self._transaction():
                    schema.make(self.db, self.path, create)
        except (StoreError, self.db.errors) as exc:
            damage = self.db.damage()
            self.db.close()
            if damage:
                raise StoreError(damaged(self.path, damage)) from None
            if isinstance(exc, StoreError):
                raise
            raise StoreError(f"{self.path}: not a usable jmlgdsl store ({exc})") from None

    def close(self):
        self.db.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def damage(self) -> list[str]:
        """What a check of the store's file finds wrong with it (SQLite's quick check); [] for nothing."""
        return self.db.damage()

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
        """{run: (t, action)}: how far a sink confirmed each run's conclusions (jmlgdsl.monitor.sinks.outbox)."""
        return {run: (t, action) for run, t, action in
                self.db.execute("SELECT run, t, action FROM delivery WHERE sink = ?", (sink,))}

    # ------------------------------------------------------------------ the one write
    def save(self, commits: list[Commit], marks=()):
        """Commit every run's part (a Commit each) in one transaction: all of them, or none; with the
        sinks' delivery `marks` (sink, run, t, action) when given. Every run's rows go in with one
        statement a table: a fleet's commit holds a part of each of its units."""
        try:
            with self._transaction():
                at = now()
                self._save(commits, at)
                self.db.executemany("INSERT INTO delivery VALUES (?,?,?,?,?) ON CONFLICT (sink, run) DO UPDATE SET "
                                    "t = excluded.t, action = excluded.action, saved = excluded.saved",
                                    [(*mark, at) for mark in marks])
        except self.db.errors as exc:
            raise StoreError(f"{self.path}: the store failed while saving ({exc}); nothing of this batch was kept, "
                             "and the monitor started again resumes from its last commit") from None

    def _save(self, commits: list[Commit], at: str):
        vector = self.db.vector
        for commit in commits:
            if commit.times is not None:
                recorded = self._recorded(commit.run)
                options = dict(recorded.options, **{TIMES: commit.times.as_json()})
                self.db.execute("UPDATE run SET options = ? WHERE id = ?",
                                (json.dumps(options, sort_keys=True), commit.run))
                self._runs[commit.run] = dataclasses.replace(recorded, options=options)
        modes = {commit.run: self._modes(commit.run) for commit in commits}
        self.db.executemany("INSERT INTO sample VALUES (?,?,?,?,?,?,?,?)", [
            (c.run, t, row.time, vector(row.y), vector(row.u), None if row.mode is None else modes[c.run][row.mode],
             row.anomaly, row.changepoint) for c in commits for t, row in c.samples])
        self.db.executemany("INSERT INTO result (run, t, map_mode, posterior, state_mean, y_pred, residual, ess, "
                            "loglik, alarm, y_sd, evidence_mode, evidence) VALUES (?,?,?,?,?,?,?,?,?,?,?,?,?)", [
            (c.run, d.step.t, modes[c.run][d.step.map_mode], vector(d.step.mode_posterior), vector(d.step.state_mean),
             vector(d.step.y_pred), vector(d.step.residual), _real(d.step.ess), _real(d.step.loglik), d.alarm,
             vector(sd), *_evidence(d.evidence, modes[c.run], vector))
            for c in commits for d, sd in c.results])
        raised = {}  # each run's open alarm, in one look at them all
        for run, alarm in self.db.execute("SELECT run, id FROM alarm WHERE cleared_t IS NULL ORDER BY id").fetchall():
            raised.setdefault(run, alarm)
        for commit in commits:
            self._alarms(commit.run, [d for d, _ in commit.results], raised.get(commit.run))
        self.db.executemany("INSERT INTO event (run, at, time, kind, tag, detail) VALUES (?,?,?,?,?,?)",
                            [(c.run, at, e.time, e.kind, e.tag, e.detail) for c in commits for e in c.events])
        self.db.executemany("INSERT INTO state VALUES (?,?,?,?,?,?) ON CONFLICT (run) DO UPDATE SET "
                            "rows = excluded.rows, checkpoint = excluded.checkpoint, monitor = excluded.monitor, "
                            "position = excluded.position, saved = excluded.saved",
                            [(c.run, c.rows, c.checkpoint, c.monitor,
                              None if c.position is None else json.dumps(c.position), at) for c in commits])

    def _alarms(self, run, results, raised: int | None):
        """Alarm episodes from the results' 0/1 alarms, continuing the one open in the store (`raised`,
        its id); each names the most probable unhealthy mode of the row that raised it."""
        for d in results:
            if d.alarm and raised is None:
                modes, healthy = self._modes(run), self._recorded(run).options.get("healthy", [])
                unhealthy = [k for k, name in enumerate(modes) if name not in healthy]
                mode = modes[max(unhealthy, key=lambda k: d.step.mode_posterior[k])] if unhealthy else None
                raised = self.db.insert("INSERT INTO alarm (run, raised_t, raised_time, mode) VALUES (?,?,?,?)",
                                        (run, d.step.t, d.row.time, mode))
            elif not d.alarm and raised is not None:
                self.db.execute("UPDATE alarm SET cleared_t = ?, cleared_time = ? WHERE id = ?",
                                (d.step.t, d.row.time, raised))
                raised = None

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

    # ------------------------------------------------------------------ the queries readers need
    def last_t(self, run: int) -> int:
        """The t of a run's newest finished row (0 for none)."""
        return self.db.execute("SELECT coalesce(max(t), 0) FROM result WHERE run = ?", (run,)).fetchone()[0]

    def results(self, run: Run, first: int, last: int | None = None, every: int = 1,
                limit: int | None = None) -> list[Finished]:
        """A run's finished rows from t = `first` (to t = `last`, when given), every `every`-th from
        `first`, at most `limit` (None: all), in order of t; those that cannot be read (a damaged
        store, a cell edited by hand) are left out. One query, but for a store whose rows do not all read."""
        where, params = "r.run = ? AND r.t >= ?", [run.id, first]
        if last is not None:
            where += " AND r.t <= ?"
            params.append(last)
        if every > 1:
            where += " AND (r.t - ?) % ? = 0"
            params += [first, every]
        decode = self._finished(run)
        try:
            return [decode(row) for row in self.db.execute(
                f"{FINISHED} WHERE {where} ORDER BY r.t" + (f" LIMIT {int(limit)}" if limit else ""), params)]
        except (self.db.errors, ValueError, TypeError):  # a cell edited by hand, or damaged: the rows that read
            readable = self._readable(f"{FINISHED} WHERE r.run = ? AND r.t > ? ORDER BY r.t", run, decode, [],
                                      first - 1)
            window = itertools.takewhile(lambda row: last is None or row.t <= last,
                                         (row for row in readable if (row.t - first) % every == 0))
            return list(itertools.islice(window, limit))

    def _finished(self, run: Run):
        """decode(row) of a row of FINISHED: a ValueError for cells the store did not write."""
        ny = len(run.outputs)
        sizes = dict(zip((4, 5, 6, 7, 9), (len(run.modes), ny, ny, ny, ny)))  # its vectors' columns

        def decode(row):
            t, time, mode, alarm, *_ = row
            if not (isinstance(mode, str) and alarm in (0, 1) and (time is None or type(time) in (int, float))):
                raise ValueError("a row the store did not write")
            return Finished(*(self.db.unvector(cell, sizes[i]).tolist() if i in sizes and cell is not None else cell
                              for i, cell in enumerate(row)))
        return decode

    def evidence(self, run: Run, first: int, last: int):
        """(t, evidence_mode, each output's evidence or None) of a run's finished rows `first` <= t <=
        `last`, in order of t; those that cannot be read are left out."""
        ny = len(run.outputs)

        def decode(row):
            t, mode, terms = row
            return t, mode, None if terms is None else self.db.unvector(terms, ny).tolist()

        readable = self._readable("SELECT t, evidence_mode, evidence FROM result WHERE run = ? AND t > ? ORDER BY t",
                                  run, decode, [], first - 1)
        return itertools.takewhile(lambda row: row[0] <= last, readable)

    def newest(self, run: Run) -> Verdict | None:
        """What a run's newest finished row concludes (None before its first)."""
        row = self.db.execute(f"{VERDICT} WHERE r.run = ? ORDER BY r.t DESC LIMIT 1", (run.id,)).fetchone()
        return None if row is None else self._verdict(run, row)

    def verdicts(self, run: Run, after: int, limit: int) -> list[Verdict]:
        """What a run's finished rows after t = `after` conclude, at most `limit` of them, in order of t."""
        return [self._verdict(run, row) for row in self.db.execute(
            f"{VERDICT} WHERE r.run = ? AND r.t > ? ORDER BY r.t LIMIT ?", (run.id, after, limit)).fetchall()]

    def _verdict(self, run: Run, row) -> Verdict:
        t, time, mode, posterior, alarm = row
        return Verdict(t, time, mode, self.db.unvector(posterior, len(run.modes)).tolist(), alarm)

    def alarms(self, run: int, actions: int | None = None, during: tuple | None = None) -> list[Alarm]:
        """A run's alarms, oldest first, with their acknowledgement and shelving (as they stood after
        the action of id `actions`, when given); with `during` (t0, t1), only those open at some row
        t0 < t <= t1."""
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
        where, params = "run = ?", [run]
        if during is not None:
            where += " AND raised_t <= ? AND (cleared_t IS NULL OR cleared_t > ?)"
            params += [during[1], during[0]]
        return [Alarm(*row, acknowledged.get(row[0]), shelved.get(row[0])) for row in self.db.execute(
            f"SELECT id, raised_t, raised_time, cleared_t, cleared_time, mode FROM alarm WHERE {where} ORDER BY id",
            params)]

    def alarms_stamp(self, run: int) -> str:
        """A text that changes whenever a run's alarms do: raised, cleared, acknowledged, shelved or unshelved."""
        return self.db.execute(
            "SELECT (SELECT count(*) || ',' || coalesce(max(id), 0) FROM action WHERE run = ?) || ';' || "
            "(SELECT count(*) || ',' || count(cleared_t) FROM alarm WHERE run = ?)", (run, run)).fetchone()[0]

    def actions(self, run: int | None = None, after: int = 0, limit: int | None = None) -> list[Action]:
        """The operators' actions after the one of id `after`, oldest first: of every run, or of `run`
        when given; at most `limit` (None: all)."""
        where, params = ("x.id > ?", [after]) if run is None else ("x.run = ? AND x.id > ?", [run, after])
        return [Action(*row) for row in self.db.execute(
            "SELECT x.id, x.run, x.alarm, a.raised_t, x.at, x.who, x.kind, x.reason FROM action x JOIN alarm a "
            f"ON a.id = x.alarm WHERE {where} ORDER BY x.id" + ("" if limit is None else " LIMIT ?"),
            params + ([] if limit is None else [limit])).fetchall()]

    def newest_action(self, run: int) -> int:
        """The id of a run's newest action (0 for none): what comes after it is newer."""
        return self.db.execute("SELECT coalesce(max(id), 0) FROM action WHERE run = ?", (run,)).fetchone()[0]

    def counts(self, run: int, after: int = 0) -> dict:
        """{kind: number} of a run's events (of those after the event of id `after`, when given)."""
        return dict(self.db.execute("SELECT kind, count(*) FROM event WHERE run = ? AND id > ? GROUP BY kind",
                                    (run, after)))

    def newest_event(self) -> int:
        """The id of the newest event in the store (0 for none): what comes after it is newer."""
        return self.db.execute("SELECT coalesce(max(id), 0) FROM event").fetchone()[0]

    def steps(self, run: Run, damaged: list):
        """(Step, time, alarm) of each of a run's finished rows, in order of t, as the filter made it
        (the store keeps no state covariance); the t of a row that cannot be read goes to `damaged`."""
        query = ("SELECT r.t, s.time, r.posterior, r.state_mean, r.y_pred, r.residual, r.loglik, r.ess, r.alarm "
                 "FROM result r JOIN sample s ON s.run = r.run AND s.t = r.t WHERE r.run = ? AND r.t > ? ORDER BY r.t")
        K, nx, ny, unvector = len(run.modes), len(run.states), len(run.outputs), self.db.unvector

        def step(row):
            t, time, posterior, mean, pred, residual, loglik, ess, alarm = row
            if alarm not in (0, 1):
                raise ValueError(f"an alarm of {alarm!r}")
            return Step(t, unvector(posterior, K), unvector(mean, nx), None, unvector(pred, ny),
                        unvector(residual, ny), _number(loglik), _number(ess)), _time(time), alarm

        return self._readable(query, run, step, damaged)

    def samples(self, run: Run, damaged: list):
        """Each row a run diagnosed, in order of t, as assembled (a Sample); the t of a row that cannot
        be read goes to `damaged`."""
        query = "SELECT t, time, y, u, mode, anomaly, changepoint FROM sample WHERE run = ? AND t > ? ORDER BY t"
        ny, nu, unvector = len(run.outputs), len(run.inputs), self.db.unvector

        def sample(row):
            t, time, y, u, mode, anomaly, changepoint = row
            if not (mode is None or mode in run.modes) or not all(m in (None, 0, 1) for m in (anomaly, changepoint)):
                raise ValueError("labels that are not a mode's name or 0/1")
            return Sample(t, _time(time), unvector(y, ny), unvector(u, nu), mode, anomaly, changepoint)

        return self._readable(query, run, sample, damaged)

    def labels(self, run: Run) -> list[str]:
        """The labels of LABELS that some row of a run carries (not one whose column cannot be read)."""
        return [name for name in LABELS if self._labelled(run, name)]

    def _labelled(self, run: Run, name: str) -> bool:
        try:
            return self.db.execute(f"SELECT 1 FROM sample WHERE run = ? AND {name} IS NOT NULL LIMIT 1",
                                   (run.id,)).fetchone() is not None
        except self.db.errors:
            return False

    def _readable(self, query: str, run: Run, decode, damaged: list, after: int = 0):
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


def _evidence(evidence, modes, vector) -> tuple:
    """(evidence_mode, evidence) columns of a row's Evidence (NULL, NULL without one), its terms as `vector` keeps them."""
    return (None, None) if evidence is None else (modes[evidence.mode], vector(evidence.terms))


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
