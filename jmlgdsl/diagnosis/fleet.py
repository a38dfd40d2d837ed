"""`Fleet`: the diagnosis of many units of one plant, each with its own data, side by side.

Every unit has its own `Diagnosis` (pre-filter, alarm rule, summary, truth scoring, scale check and
sinks), so each unit's finished rows are those of diagnosing it alone. Their filters run as one
vectorised `Units` filter where there is one (imm, without a lag); otherwise each unit's Diagnosis
filters its own rows. `jmlgdsl run SPEC a.csv b.csv ... -o OUTDIR/` is a fleet with a table per unit.

    >>> import jmlgdsl
    >>> from jmlgdsl.data import iter_rows, open_source
    >>> from jmlgdsl.diagnosis.fleet import Fleet
    >>> model = jmlgdsl.load("specs/dryer.jmlg")
    >>> with open_source("examples/dryer_seq1.csv") as source:
    ...     rows = list(iter_rows(source, model, source.name))
    >>> fleet = Fleet(model, 2).run([rows, rows[:500]])     # one unit's record is cut short
    >>> [(d.summary.T, model.modes[d.summary.current], d.alarms.raised) for d in fleet.units]
    [(1000, 'fan', 3), (500, 'normal', 2)]
"""

from __future__ import annotations

import numpy as np

from ..infer.units import Units
from ..model import Model
from .pipeline import Diagnosis


class Fleet:
    """Diagnose `count` units of one model: `feed(rows)` with one data row per unit (None for a unit
    whose data have ended), `finish()` at the end. The options are a Diagnosis's; `sinks` gives each
    unit its own list of sinks."""

    def __init__(self, model: Model, count: int, *, sinks=None, **options):
        self.model = model
        self.units = [Diagnosis(model, sinks=() if sinks is None else sinks[i], **options) for i in range(count)]
        first = self.units[0].filter
        batched = first.algorithm == "imm" and first.lag == 0 and not self.units[0].explain
        self.filter = Units(model, count, first.algorithm) if batched else None

    def feed(self, rows):
        """Diagnose one data row of each unit (rows[i] for unit i; None: unit i has no row)."""
        on = [i for i, row in enumerate(rows) if row is not None]
        if self.filter is None:
            for i in on:
                self.units[i].feed(rows[i])
            return
        ys = []
        for i in on:
            unit, row = self.units[i], rows[i]
            unit._held.append(row)
            ys.append(row.y if unit.prefilter is None else unit.prefilter(row.y))
        steps = self.filter.step(np.array(ys).reshape(len(on), self.model.ny),
                                 np.array([rows[i].u for i in on]).reshape(len(on), self.model.nu),
                                 None if len(on) == len(rows) else on)
        for j, i in enumerate(on):
            self.units[i]._finished(steps.record(j))

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
