"""`Fleet`: the diagnosis of many units of one plant, each with its own data, side by side.

Every unit has its own `Diagnosis` (pre-filter, alarm rule, summary, truth scoring, scale check,
evidence and sinks), so each unit's finished rows are those of diagnosing it alone. Their filters
step together in a `Units` filter where they can (without a lag): imm as one vectorised filter, the
evidence per sensor of every unit in one call too; the particle filters and exact as the units' own
filters stepped together. A smoothing filter's Diagnosis filters its own rows.

`diagnose_files` is `jmlgdsl run SPEC a.csv b.csv ... -o OUTDIR/`: each file a unit, its table and
summary; with `cluster` the files are split into chunks, one per CPU of a Ray cluster, each chunk a
Fleet in a Ray task. Whole files under the vectorised imm with nothing kept per unit row by row (no
lag, pre-filter or evidence) skip the units' Diagnoses: their rows are filtered together into arrays
over (step, unit), the alarm rule and the tables made of those arrays. Every unit's rows are those of
diagnosing it alone, so the tables are the same bytes however the files are chunked.

    >>> import jmlgdsl
    >>> from jmlgdsl.data import iter_rows, open_source
    >>> from jmlgdsl.diagnosis.fleet import Fleet
    >>> model = jmlgdsl.load("specs/dryer.jmlg")
    >>> with open_source("examples/dryer_seq1.csv") as source:
    ...     rows = list(iter_rows(source, model, source.name))
    >>> fleet = Fleet(model, 2).run([rows, rows[:500]])     # one unit's record is cut short
    >>> [(d.summary.T, model.modes[d.summary.current], d.alarms.raised) for d in fleet.units]
    [(1000, 'fan', 3), (500, 'normal', 2)]
    >>> history = diagnose_files(model, ["examples/dryer_seq1.csv"])
    >>> unit = history.units[0]
    >>> (unit.steps, unit.last_mode, unit.alarms, unit.table.split(",")[:4])
    (1000, 'fan', 3, ['t', 'time', 'map_mode', 'p_normal'])
"""

from __future__ import annotations

import io
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..data import iter_rows, open_source, open_target, read_data
from ..errors import DataError, JmlgError
from ..infer import ALGORITHMS
from ..infer.table import TableWriter
from ..infer.units import Units, stackable
from ..model import Model
from ..names import plural
from ..output import check_folder, file_names
from .progress import Progress
from .evidence import Evidence
from .metrics import runs
from .options import Options
from .pipeline import Diagnosis
from .report import evidence_report
from .scale import ScaleCheck
from .sinks import Raised, TableSink


class Fleet:
    """Diagnose `count` units of one plant: `feed(rows)` with one data row per unit (None for a unit
    whose data have ended), `finish()` at the end. `options` and `scored` are every unit's Diagnosis's;
    `sinks` gives each unit its own list of sinks; `models` each unit its own bank (its fitted spec;
    default `model` for every unit). `units` takes the units' Diagnoses as they are instead (of the
    same options; resumed ones with `Units.restore` of their filters' states).

    Units whose banks are of one shape (`jmlgdsl.infer.units.stackable`: the same modes, outputs,
    inputs and states) step together, each under its own numbers; others each step alone."""

    def __init__(self, model: Model, count: int | None = None, options: Options = Options(), *, sinks=None,
                 units=None, models=None, scored: bool = True):
        self.model = model
        self.units = list(units) if units is not None else [
            Diagnosis(model if models is None else models[i], options, scored=scored,
                      sinks=() if sinks is None else sinks[i])
            for i in range(count)]
        first = self.units[0].filter
        banks = [unit.model for unit in self.units]
        self.filter = None  # None: each unit's Diagnosis filters its own rows
        if stepped_together(first) and stackable([model, *banks]):
            # one vectorised filter beside the units' where the algorithm has one; else their own stepped together
            self.filter = (Units(model, len(self.units), models=banks) if ALGORITHMS[first.algorithm].vectorised
                           else Units(model, len(self.units), filters=[unit.filter for unit in self.units]))

    def feed(self, rows):
        """Diagnose one data row of each unit (rows[i] for unit i; None: unit i has no row)."""
        on = [i for i, row in enumerate(rows) if row is not None]
        if self.filter is None:
            for i in on:
                self.units[i].feed(rows[i])
            return
        ys = [self.units[i].hold(rows[i]) for i in on]
        steps = self.filter.step(np.array(ys).reshape(len(on), self.model.ny),
                                 np.array([rows[i].u for i in on]).reshape(len(on), self.model.nu),
                                 None if len(on) == len(rows) else on)
        if not self.filter.vectorised:  # each unit's engine holds its predictive
            for i in on:
                self.units[i].heard()
        elif self.units[0].explain:  # every unit's evidence in one call
            faulty = self.units[0].alarms.faulty
            for positions, predictive in self.filter.predictives:
                for j, evidence in zip(positions, Evidence.of_units(predictive, faulty)):
                    self.units[on[j]].heard(evidence)
        # the alarm rule's sums of every unit at once (their rules are the one of `options`)
        faults = self.units[0].rule.fault_probability(steps.mode_posterior, self.model.modes).tolist()
        for i, step, fault in zip(on, steps.records(), faults):
            self.units[i].finished(step, fault)

    def finish(self):
        """The end of the data of every unit."""
        for unit in self.units:
            unit.finish()

    def run(self, records) -> "Fleet":
        """Diagnose whole records, one list of rows per unit (of any lengths), then finish; returns self."""
        for t in range(max((len(r) for r in records), default=0)):
            self.feed([r[t] if t < len(r) else None for r in records])
        self.finish()
        return self

    @property
    def seconds(self) -> float:
        """Time spent filtering, every unit together."""
        return self.filter.seconds if self.filter is not None else sum(u.filter.seconds for u in self.units)


class FleetSpecError(JmlgError):
    """A folder of unit specs that cannot serve the fleet."""


def unit_banks(model: Model, folder, units) -> tuple[list[Model], list[str]]:
    """Each unit's own bank, from its spec FOLDER/<unit>.jmlg (the plant's spec fitted to that unit:
    `jmlgdsl fit SPEC u1.csv u2.csv ... -o FOLDER/`), and the units that have none there, which take
    the plant's `model`. A unit spec that is not of the plant's shape (other modes, outputs, inputs or
    states, another gate) is a FleetSpecError naming it: it cannot be a copy of the plant's spec."""
    from ..compile.lower import compile_file

    folder = Path(folder)
    if not folder.is_dir():
        raise FleetSpecError(f"{folder}: no such folder of unit specs")
    banks, missing = [], []
    for unit in units:
        path = folder / f"{unit}.jmlg"
        if not path.exists():
            banks.append(model)
            missing.append(unit)
            continue
        bank = compile_file(path)
        if not stackable([model, bank]):
            raise FleetSpecError(f"{path}: unit {unit}'s spec is not of the plant {model.name}'s shape (modes "
                                 f"{', '.join(bank.modes)}; outputs {', '.join(bank.outputs)}): a unit spec is the "
                                 f"plant's spec with the unit's own numbers")
        banks.append(bank)
    return banks, missing


def file_banks(model: Model, folder, paths, spec) -> tuple[list[Model], str]:
    """Each data file's bank as a unit of a fleet (`unit_banks`, the unit named by its file's stem), and a
    line saying how many units have their own spec from `folder` and which take the plant's `spec`."""
    units = [Path(path).stem for path in paths]
    banks, missing = unit_banks(model, folder, units)
    return banks, (f"unit specs: {len(units) - len(missing)} of {plural(len(units), 'unit')} from {folder}"
                   + (f"; {', '.join(missing)} with {spec}" if missing else ""))


def stepped_together(f) -> bool:
    """Whether a Fleet steps units with filters like Filter f together: every algorithm without a lag
    (a smoothing filter holds its records back, each unit's as long as its own data ask)."""
    return f.lag == 0


@dataclass(frozen=True)
class Outcome:
    """One data file diagnosed as a unit of a fleet: what its summary line says, its table (the CSV
    text `jmlgdsl run -o` writes; None when no table was asked for) and, when the diagnosis explains,
    the lines on the evidence behind its alarms (`report.evidence_report`; else None)."""

    path: str
    steps: int
    last_mode: str
    alarms: int  # alarms raised
    error: float | None  # diagnosis error %, where the data carry the true mode
    table: str | None
    evidence: tuple[str, ...] | None = None


@dataclass(frozen=True)
class History:
    """Many data files diagnosed: an Outcome per file in the order given, whether the units' filters
    stepped together (`Fleet.filter`), and the seconds spent filtering, every unit together."""

    units: list[Outcome]
    batched: bool
    seconds: float

    def write(self, folder):
        """Each unit's table as FOLDER/NAME.csv for its NAME.csv (`jmlgdsl.output.file_names`), each whole or
        absent."""
        Path(folder).mkdir(parents=True, exist_ok=True)
        for name, unit in zip(file_names([unit.path for unit in self.units], ".csv", "table"), self.units):
            with open_target(Path(folder) / name) as out:
                out.write(unit.table)

    def report(self, model: Model, algorithm: str) -> str:
        """A line per unit (its steps, last mode, alarms, diagnosis error and evidence), then the
        fleet's: its units, filter and time per unit-step."""
        lines = []
        for unit in self.units:
            line = (f"{unit.path}: {plural(unit.steps, 'step')}, last mode {unit.last_mode}, "
                    f"{plural(unit.alarms, 'alarm')} raised")
            if unit.error is not None:
                line += f", diagnosis error {unit.error:.2f} %"
            lines += [line] + ["  " + evidence for evidence in unit.evidence or ()]
        steps = sum(unit.steps for unit in self.units)
        how = "the units stepped together" if self.batched else "unit after unit"
        lines.append(f"{model.name}: {plural(len(self.units), 'unit')}, filter {algorithm} ({how}), "
                     f"{1e6 * self.seconds / max(steps, 1):.2f} us per unit-step")
        return "\n".join(lines)


def check_tables(folder, paths, inputs=()) -> None:
    """Refuse, before any work, data files that cannot write a table each (`file_names`) and, unless
    `folder` is None (no tables), a folder those tables cannot go to: standard output, a folder that
    cannot be written or where a table would be one of the data files or the other `inputs`."""
    names = file_names(paths, ".csv", "table")
    if folder is None:
        return
    if folder == "-":
        raise JmlgError("-o -: several data files write a table each; give a folder")
    check_folder(folder, names, inputs=[*inputs, *paths])


def diagnose_files(model: Model, paths, options: Options = Options(), *, tables: bool = True,
                   cluster: str | None = None, progress=None, models=None) -> History:
    """Diagnose every data file in `paths` as a unit of a fleet as `options` say, with
    its table when `tables`; a file without data rows, or with a bad one, is a DataError naming it.
    `models` gives each file its unit's own bank (in the order of `paths`; default `model` for all).

    With `cluster` (an address as `jmlgdsl.diagnosis.cluster.connect` takes it: 'auto' or HOST:PORT) the files
    are split into as many contiguous chunks as the cluster has CPUs (at most one per file), each chunk
    a Fleet in a Ray task: every CPU busy, and each chunk's units as many as can share one vectorised
    filter. `progress` (a stream, or None) counts the files as their chunks finish. The process stays
    joined to the cluster (`jmlgdsl.diagnosis.cluster.disconnect()` leaves it). The tasks read the files where
    they run, a relative path taken from this process's working folder: a cluster of machines needs
    them in a folder every machine sees at the same path. A chunk that fails stops the others and
    raises its own error."""
    options.rule(model)  # a rule it cannot take refused before any file is read
    paths = list(paths)
    models = [model] * len(paths) if models is None else list(models)
    if cluster is None:
        return _diagnose_chunk(model, paths, models, "", tables, options)
    from .cluster import completed, connect

    ray = connect(cluster)
    count = max(1, min(len(paths), int(ray.cluster_resources().get("CPU", 1))))
    chunks = np.array_split(np.arange(len(paths)), count)
    task = ray.remote(num_cpus=1)(_diagnose_chunk)
    refs = [task.remote(model, [paths[i] for i in chunk], [models[i] for i in chunk], os.getcwd(), tables, options)
            for chunk in chunks]
    bar = Progress(len(paths), progress, "files")
    parts = [None] * len(refs)
    for i, part in completed(ray, refs):
        parts[i] = part
        bar.update(len(part.units))
    return History([unit for part in parts for unit in part.units], parts[0].batched,
                   sum(part.seconds for part in parts))


def _diagnose_chunk(model: Model, paths: list, models: list, folder: str, tables: bool, options: Options) -> History:
    """Some files diagnosed as one Fleet, each under its unit's bank in `models`: in this process, or in
    a Ray task on a cluster, whose working folder is not the driver's; a relative path is from `folder`
    ('': this process's own). Whole files that one vectorised filter steps together are diagnosed as
    arrays over (step, unit) (`_diagnose_together`), the rest row by row, each unit's own Diagnosis."""
    first = options.filter(model)  # options the filter cannot take refused as each unit's Diagnosis would
    if (ALGORITHMS[first.algorithm].vectorised and stepped_together(first) and options.prefilter is None
            and not options.explain and stackable([model, *models])):
        return _diagnose_together(model, paths, models, folder, tables, options)
    records = []
    for path, bank in zip(paths, models):
        with open_source(os.path.join(folder, path)) as source:
            records.append(list(iter_rows(source, bank, path)))
        if not records[-1]:
            raise DataError(f"{path}: no data rows")
    explain = options.explain
    texts = [io.StringIO() if tables else None for _ in paths]
    raised = [Raised() if explain else None for _ in paths]
    sinks = [([TableSink(text, bank, options.lag, explain=explain)] if tables else [])
             + ([alarms] if explain else []) for text, alarms, bank in zip(texts, raised, models)]
    run = Fleet(model, len(paths), options, sinks=sinks, models=models).run(records)
    units = [Outcome(path, unit.summary.T, bank.modes[unit.summary.current], unit.alarms.raised,
                     unit.summary.diagnosis_error if unit.summary.labelled else None,
                     text.getvalue() if tables else None,
                     tuple(evidence_report(bank, alarms)) if explain else None)
             for path, unit, text, alarms, bank in zip(paths, run.units, texts, raised, models)]
    return History(units, run.filter is not None, run.seconds)


def _diagnose_together(model: Model, paths: list, models: list, folder: str, tables: bool,
                       options: Options) -> History:
    """`_diagnose_chunk` of files whose units one vectorised filter steps together (imm, no lag), with
    nothing of a unit's own to keep row by row (no pre-filter, no evidence): each file read whole
    into arrays, every unit's step filtered at once and written into arrays over (step, unit), then
    the alarm rule applied to them all in one call and each unit's table written in one pass. Every
    unit's table, summary and warnings are those its own Diagnosis gives row by row (`Fleet`): the
    same filter, and the batch forms of its alarm rule (`AlarmRule.alarms`) and scale check
    (`ScaleCheck.add_rows`)."""
    records = []
    for path, bank in zip(paths, models):
        with open_source(os.path.join(folder, path)) as source:
            records.append(read_data(source, bank, path))
    lengths = np.array([len(record.y) for record in records])
    steps, count = int(lengths.max()), len(records)
    y, u = np.zeros((steps, count, model.ny)), np.zeros((steps, count, model.nu))
    for i, record in enumerate(records):
        y[:lengths[i], i], u[:lengths[i], i] = record.y, record.u
    posterior = np.empty((steps, count, len(model.modes)))
    mean, ess = np.empty((steps, count, model.nx)), np.empty((steps, count))
    y_pred, residuals = np.empty((steps, count, model.ny)), np.empty((steps, count, model.ny))
    units = Units(model, count, models=models)
    for t in range(steps):
        on = slice(None) if lengths.min() > t else np.flatnonzero(lengths > t)
        step = units.step(y[t, on], u[t, on], None if isinstance(on, slice) else on)
        posterior[t, on], mean[t, on], ess[t, on] = step.mode_posterior, step.state_mean, step.ess
        y_pred[t, on], residuals[t, on] = step.y_pred, step.residuals
    alarms = options.rule(model).alarms(posterior, model.modes)
    diagnosed = posterior.argmax(axis=2)
    checks = [ScaleCheck(bank) for bank in models]
    for i, (check, length) in enumerate(zip(checks, lengths)):
        check.add_rows(residuals[:length, i])
    for check in checks:  # records shorter than the check's rows: judged at their end
        check.finish()
    outcomes = []
    for i, (path, bank, record, length) in enumerate(zip(paths, models, records, lengths)):
        text = None
        if tables:
            stream = io.StringIO()
            TableWriter(stream, bank, record.time is not None, lag=options.lag).write_rows(
                np.arange(1, length + 1), posterior[:length, i], mean[:length, i], y_pred[:length, i],
                residuals[:length, i], ess[:length, i], record.time, alarms[:length, i])
            text = stream.getvalue()
        error = None
        if record.modes is not None:
            labelled = record.modes >= 0
            error = 100.0 * int((diagnosed[:length, i] != record.modes)[labelled].sum()) / int(labelled.sum())
        outcomes.append(Outcome(path, int(length), bank.modes[diagnosed[length - 1, i]], len(runs(alarms[:length, i])),
                                error, text))
    return History(outcomes, True, units.seconds)
