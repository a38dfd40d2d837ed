"""A run of a store written out (`jmlgdsl export`): its result table, byte for byte what `jmlgdsl
run -o` writes for the same rows, and the rows it diagnosed as a data file that `jmlgdsl run`
diagnoses again; both through the store's queries, leaving out (and naming) the rows of a damaged
store that cannot be read."""

from __future__ import annotations

import csv
import math
from typing import NamedTuple

import numpy as np

from ...infer.table import TableWriter
from ...names import plural, spans
from .records import Run


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


def write_table(store, run: Run, stream) -> Exported:
    """The result table of a run's finished rows in `store`, as `jmlgdsl run -o` writes it for the
    same rows; rows that cannot be read (a damaged store) are left out and named."""
    writer, exported = None, Exported(0, [])
    for step, time, alarm in store.steps(run, exported.damaged):
        if writer is None:
            writer = TableWriter(stream, _Names(run), time is not None, lag=run.options.get("lag", 0))
        writer.write(step, time, alarm)
        exported = exported._replace(rows=exported.rows + 1)
    return exported


def write_samples(store, run: Run, stream) -> Exported:
    """The rows a run of `store` diagnosed as a data file (their times as the source wrote them,
    outputs, inputs and the labels they carry), every number in its shortest exact form, so `jmlgdsl
    run` on it diagnoses the same rows; rows that cannot be read (a damaged store, a time beyond the
    calendar) are left out and named."""
    exported, writer, times = Exported(0, []), None, run.times
    labels = store.labels(run)
    for sample in store.samples(run, exported.damaged):
        try:
            time = None if sample.time is None or sample.time != sample.time else times.write(sample.time)
        except ValueError:
            exported.damaged.append(sample.t)
            continue
        row = ([_cell(v) for v in np.concatenate([sample.y, sample.u])]
               + ["" if getattr(sample, name) is None else getattr(sample, name) for name in labels])
        if writer is None:
            writer, timed = csv.writer(stream, lineterminator="\n"), time is not None
            writer.writerow(([times.column] if timed else []) + run.outputs + run.inputs + labels)
        writer.writerow(([time] if timed else []) + row)
        exported = exported._replace(rows=exported.rows + 1)
    return exported


def _cell(value) -> str:
    """A data file's cell: empty for a reading not measured."""
    return "" if math.isnan(value) else repr(float(value))


class _Names:
    """What the table writer needs of a model, from the names a run recorded."""

    def __init__(self, run: Run):
        self.modes, self.states, self.outputs = run.modes, run.states, run.outputs
