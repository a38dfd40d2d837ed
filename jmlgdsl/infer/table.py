"""The result table: the one CSV layout for per-step results, written by `run -o`, read by `plot`.

Columns, in order: `t`, `time` (when the data had one), `map_mode`, `p_<mode>` for every mode,
`<state>_mean`, `<output>_pred`, `<output>_resid`, `ess`, `alarm` (0/1) when an alarm rule was
applied, and with the evidence per sensor (`run --explain`) `evidence_mode`, the row's most probable
non-healthy mode, and `evidence_<output>`, each output's evidence for it in nats. A smoothed table
starts with a `#` comment line that says what its probabilities are conditioned on. Rows are written as they are computed, so a stream is written on-line.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass

import numpy as np

from ..data import CsvWriter, csv_cell, joined_numbers, open_source, open_target
from ..errors import DataError
from ..model import Model
from ..names import plural
from .result import Result, Step


SMOOTHED = "smoothed"


def given(lag: int | None) -> str:
    """What a table's probabilities are conditioned on, in words."""
    return "the data so far" if lag == 0 else "all the data" if lag is None else f"the data up to {plural(lag, 'row')} later"


def columns(model: Model, with_time: bool, with_alarm: bool = True, explain: bool = False) -> list[str]:
    """The header of the result table."""
    return (["t"] + (["time"] if with_time else []) + ["map_mode"] + [f"p_{m}" for m in model.modes]
            + [f"{s}_mean" for s in model.states] + [f"{o}_pred" for o in model.outputs]
            + [f"{o}_resid" for o in model.outputs] + ["ess"] + (["alarm"] if with_alarm else [])
            + (["evidence_mode"] + [f"evidence_{o}" for o in model.outputs] if explain else []))


class TableWriter:
    """Writes result rows to a text stream, a row (`write`) or many (`write_rows`) at a time; with
    flush=True each row reaches the reader at once, and with explain=True each row ends with its
    evidence per sensor (empty where there is none).

    A row is its numbers formatted as `joined_numbers` formats them, in one pass of one format with the
    mode's cell left as a `%s` (each NaN's 'nan' emptied before any mode's name is in), then the mode's
    cell put in: the same bytes whether rows are written one at a time or many at once."""

    def __init__(self, stream, model: Model, with_time: bool, flush: bool = False, with_alarm: bool = True,
                 lag: int | None = 0, explain: bool = False):
        self.model, self.with_time, self.with_alarm, self.explain = model, with_time, with_alarm, explain
        if lag != 0:
            stream.write(f"# {SMOOTHED}: p_<mode>, <state>_mean given {given(lag)}; <output>_pred, "
                         "<output>_resid: one-step predictions of the filter\n")
        self._writer = CsvWriter(stream, columns(model, with_time, with_alarm, explain), flush)
        self._modes = [csv_cell(mode) for mode in model.modes]  # each mode's cell, quoted once
        after = len(model.modes) + len(model.states) + 2 * len(model.outputs) + 1 + with_alarm  # numbers after the mode
        self._row = ",".join(["%.10g"] * (1 + with_time) + ["%%s"] + ["%.10g"] * after)

    def write(self, step: Step, time: float | None = None, alarm: int | None = None, evidence=None):
        """One row: a filter step and, when the table has those columns, the data row's time, the alarm
        and the evidence (a jmlgdsl.diagnosis.evidence.Evidence, or None)."""
        numbers = ([step.t, time] if self.with_time else [step.t]) + [
            *step.mode_posterior.tolist(), *step.state_mean.tolist(), *step.y_pred.tolist(), *step.residual.tolist(),
            float(step.ess)] + ([alarm] if self.with_alarm else [])
        line = self._lines(self._row, numbers, (self._modes[step.map_mode],))
        self._writer.write_line(f"{line},{self._evidence(evidence)}" if self.explain else line)

    def write_rows(self, t, mode_posterior, state_mean, y_pred, residuals, ess, time=None, alarm=None):
        """Many rows at once, as `write` writes them one at a time: arrays over rows (t (T,), the mode
        posterior (T, K), the state means (T, nx), the predictions and residuals (T, ny), ess (T,)) and,
        when the table has those columns, the data rows' times (T,) and alarms (T,); a table without
        evidence (a Result's, or a fleet's run on whole files)."""
        if self.explain:
            raise ValueError("write_rows writes no evidence; a table that explains is written row by row")
        count = len(t)
        if not count:
            return
        numbers = np.column_stack([t] + ([time] if self.with_time else []) + [
            mode_posterior, state_mean, y_pred, residuals, ess] + ([alarm] if self.with_alarm else []))
        modes = [self._modes[k] for k in np.asarray(mode_posterior).argmax(axis=1).tolist()]
        self._writer.write_line(self._lines("\n".join([self._row] * count), numbers.ravel().tolist(), modes))

    @staticmethod
    def _lines(form: str, numbers: list, modes) -> str:
        """Rows of `form` (a row's format, repeated): the numbers formatted, NaN's cells emptied, then
        the modes' cells put in."""
        return (form % tuple(numbers)).replace("nan", "") % tuple(modes)

    def _evidence(self, evidence) -> str:
        """The evidence cells: the mode's name and each output's evidence (all empty without evidence)."""
        if evidence is None:
            return "," * self.model.ny
        return f"{self._modes[evidence.mode]},{joined_numbers(np.asarray(evidence.terms, float).ravel().tolist())}"


def write_result(path, result: Result, time=None, alarm=None):
    """Write a whole Result as a result table ('-' = standard output); `time` (T,) adds the time
    column and `alarm` (T,) 0/1 the alarm column."""
    with open_target(path) as stream:  # an error part way leaves no half table
        writer = TableWriter(stream, result.model, time is not None, with_alarm=alarm is not None, lag=result.lag)
        writer.write_rows(np.arange(1, result.T + 1), result.mode_posterior, result.state_mean, result.y_pred,
                          result.residuals, result.ess, time, alarm)


@dataclass(frozen=True)
class Table:
    """A result table read back: what a figure of the run needs."""

    modes: list[str]
    outputs: list[str]
    given: str  # what the probabilities are conditioned on, in words
    t: np.ndarray  # (T,)
    time: np.ndarray | None  # (T,) the data's time column, when it had one
    mode_posterior: np.ndarray  # (T, K)
    y_pred: np.ndarray  # (T, ny)
    residuals: np.ndarray  # (T, ny)

    @property
    def T(self) -> int:
        return len(self.t)


def read_table(path) -> Table:
    """Read a result table; a DataError naming the file (and line) when it is not one."""
    with open_source(path) as stream:
        lines = list(stream)
    comment = next((line for line in lines if line.startswith(f"# {SMOOTHED}: ")), None)
    rows = [row for row in csv.reader(line for line in lines if not line.startswith("#")) if row]
    if len(rows) < 2:
        raise DataError(f"{path}: no data rows")
    header, rows = [h.strip() for h in rows[0]], rows[1:]
    start = header.index("map_mode") + 1 if "map_mode" in header else len(header)
    modes = []
    while start + len(modes) < len(header) and header[start + len(modes)].startswith("p_"):
        modes.append(header[start + len(modes)][2:])
    outputs = [h[:-len("_resid")] for h in header if h.endswith("_resid")]
    if not modes or not outputs:
        raise DataError(f"{path}: no map_mode, p_<mode> or <output>_resid columns; "
                        "is this a table written by 'jmlgdsl run -o'?")

    def column(name):
        i = header.index(name)
        values = []
        for line, row in enumerate(rows, start=2):
            text = row[i].strip() if i < len(row) else ""
            try:
                values.append(float(text) if text else np.nan)
            except ValueError:
                raise DataError(f"{path}:{line}: column {name!r}: {text!r} is not a number") from None
        return np.array(values)

    def block(names):
        return np.column_stack([column(n) for n in names])

    conditioned = comment.split(" given ")[1].split(";")[0] if comment else given(0)
    return Table(modes, outputs, conditioned, column("t"), column("time") if "time" in header else None,
                 block([f"p_{m}" for m in modes]), block([f"{o}_pred" for o in outputs]),
                 block([f"{o}_resid" for o in outputs]))
