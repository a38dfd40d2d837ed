"""CSV data bound to a model by column name: read measured sequences (also row by row from a
stream, for on-line monitoring) and write result tables.

Columns named after the model's outputs and inputs are used; `time` (seconds) or `datetime` (ISO
time stamps), `mode` (the true mode names) and 0/1 `anomaly` / `changepoint` labels are optional;
any other column is ignored. Cells are separated by commas, or by semicolons when the header line
has semicolons and no commas (as many loggers write). An empty cell (or NA / NaN) is a missing value:
an output that was not measured, or an input that takes its default. Every problem is a DataError
naming the file, the CSV line and the column.
"""

from __future__ import annotations

import csv
import math
import sys
from dataclasses import dataclass, field
from datetime import datetime, timezone
from typing import Iterator

import numpy as np

from .errors import DataError
from .names import suggest

MISSING = {"", "na", "nan", "n/a"}


@dataclass(frozen=True)
class Columns:
    """The names a data file is read by: outputs, inputs with their defaults (NaN: none) and modes.

    A Model lends its own (`Columns.of(model)`); a bank still being learned, or a figure that only
    needs the `mode` column, states them directly."""

    outputs: tuple[str, ...] = ()
    inputs: tuple[str, ...] = ()
    input_defaults: np.ndarray = field(default_factory=lambda: np.zeros(0))
    modes: tuple[str, ...] = ()

    @classmethod
    def of(cls, model) -> "Columns":
        """The columns of a Model (or Columns themselves)."""
        if isinstance(model, Columns):
            return model
        return cls(tuple(model.outputs), tuple(model.inputs), np.asarray(model.input_defaults, float),
                   tuple(model.modes))

    @property
    def ny(self) -> int:
        return len(self.outputs)

    @property
    def nu(self) -> int:
        return len(self.inputs)


@dataclass(frozen=True)
class Row:
    """One data row: its CSV line, the optional time, outputs and inputs, and the labels it carries."""

    line: int
    time: float | None  # seconds (from a `datetime` column: seconds since 1970, UTC)
    y: np.ndarray  # (ny,), NaN where not measured
    u: np.ndarray  # (nu,), NaN where the default applies
    mode: int | None  # true mode index
    anomaly: int | None = None  # 0/1 label
    changepoint: int | None = None  # 0/1 label


@dataclass(frozen=True)
class Data:
    """A whole data file as arrays over time steps."""

    time: np.ndarray | None  # (T,)
    y: np.ndarray  # (T, ny)
    u: np.ndarray  # (T, nu), defaults filled in
    modes: np.ndarray | None  # (T,) true mode indices
    source: str
    anomaly: np.ndarray | None = None  # (T,) 0/1 labels
    changepoint: np.ndarray | None = None  # (T,) 0/1 labels


def open_source(path):
    """A text stream for a path, or standard input for '-'."""
    if str(path) == "-":
        return sys.stdin
    try:
        return open(path, newline="")
    except OSError as exc:
        raise DataError(f"cannot read {path}: {exc.strerror}") from None


def open_target(path):
    """A text stream to write a table to: the file (created or replaced), or standard output for '-'."""
    if str(path) == "-":
        return sys.stdout
    try:
        return open(path, "w", newline="")
    except OSError as exc:
        raise DataError(f"cannot write {path}: {exc.strerror}") from None


def _records(stream):
    """(line number, cells) for each line that is neither blank nor a # comment, read one at a time;
    the separator is chosen on the first such line (the header)."""
    delimiter = None
    for number, line in enumerate(iter(stream.readline, ""), start=1):
        if line.strip() and not line.lstrip().startswith("#"):
            if delimiter is None:
                delimiter = ";" if ";" in line and "," not in line else ","
            yield number, next(csv.reader([line], delimiter=delimiter))


def _timestamp(cells, col, where):
    """Seconds since 1970 (UTC) from an ISO time stamp cell; None when the column is absent."""
    if col is None:
        return None
    text = cells[col].strip() if col < len(cells) else ""
    try:
        stamp = datetime.fromisoformat(text)
    except ValueError:
        raise DataError(f"{where}: column 'datetime': {text!r} is not an ISO time stamp "
                        "(such as 2020-03-09 10:14:33)") from None
    if stamp.tzinfo is None:
        stamp = stamp.replace(tzinfo=timezone.utc)
    return stamp.timestamp()


def _label(cells, col, name, where):
    """A 0/1 label cell (None when the column is absent or the cell is missing)."""
    value = _number(cells, col, name, where)
    if math.isnan(value):
        return None
    if value not in (0.0, 1.0):
        raise DataError(f"{where}: column {name!r}: {cells[col].strip()!r} is not a 0/1 label")
    return int(value)


def _number(cells, col, name, where):
    """The number in cell `col` (NaN when the column is absent or the cell is missing)."""
    if col is None:
        return math.nan
    text = cells[col].strip() if col < len(cells) else ""
    if text.lower() in MISSING:
        return math.nan
    try:
        value = float(text)
    except ValueError:
        raise DataError(f"{where}: column {name!r}: {text!r} is not a number") from None
    if math.isinf(value):
        raise DataError(f"{where}: column {name!r}: {text!r} is not a finite number")
    return value


def iter_rows(stream, model, source="<data>", outputs=True) -> Iterator[Row]:
    """Rows of a CSV stream as they arrive (lines are read one at a time, so a pipe works on-line).

    `model` is a Model or the Columns to read by. With outputs=False the output columns may be
    absent (input-only files, for simulation).
    """
    model = Columns.of(model)
    records = _records(stream)
    _, header = next(records, (0, None))
    if header is None:
        raise DataError(f"{source}: no header line (expected columns {', '.join(model.outputs)})")
    names = [name.strip().lstrip("\ufeff") for name in header]  # spreadsheets may add a BOM
    index = {name: i for i, name in enumerate(names)}

    def column(name, required):
        """The cell index of a column the model uses; None when it is absent and not required."""
        if names.count(name) > 1:
            raise DataError(f"{source}: column {name!r} appears {names.count(name)} times in the header")
        if name in index:
            return index[name]
        if required:
            raise DataError(f"{source}: missing column {name!r}; the header has {', '.join(header)}"
                            f"{suggest(name, header)}")
        return None

    y_cols = [column(n, outputs) for n in model.outputs]
    u_cols = [column(n, math.isnan(d)) for n, d in zip(model.inputs, model.input_defaults)]
    t_col, stamp_col, mode_col = column("time", False), column("datetime", False), column("mode", False)
    anomaly_col, change_col = column("anomaly", False), column("changepoint", False)
    defaults = model.input_defaults

    for line, cells in records:
        where = f"{source}:{line}"
        y = np.array([_number(cells, c, n, where) for c, n in zip(y_cols, model.outputs)])
        u = np.array([_number(cells, c, n, where) for c, n in zip(u_cols, model.inputs)])
        lacking = np.isnan(u) & np.isnan(defaults)
        if lacking.any():
            name = model.inputs[int(np.argmax(lacking))]
            raise DataError(f"{where}: column {name!r}: missing value and the input has no default")
        time = _timestamp(cells, stamp_col, where) if t_col is None else _number(cells, t_col, "time", where)
        mode = None
        if mode_col is not None:
            name = cells[mode_col].strip() if mode_col < len(cells) else ""
            if name not in model.modes:
                raise DataError(f"{where}: column 'mode': unknown mode {name!r}; modes are "
                                f"{', '.join(model.modes)}{suggest(name, model.modes)}")
            mode = model.modes.index(name)
        yield Row(line, time, y, np.where(np.isnan(u), defaults, u), mode,
                  _label(cells, anomaly_col, "anomaly", where), _label(cells, change_col, "changepoint", where))


def read_csv(path, model, outputs=True) -> Data:
    """Read a whole data file ('-' = standard input) into arrays bound to the names of `model`, a
    Model or the Columns to read by."""
    model = Columns.of(model)
    source = "<stdin>" if str(path) == "-" else str(path)
    stream = open_source(path)
    try:
        rows = list(iter_rows(stream, model, source, outputs))
    finally:
        if stream is not sys.stdin:
            stream.close()
    if not rows:
        raise DataError(f"{source}: no data rows")
    def labels(name):
        values = [getattr(r, name) for r in rows]
        return None if values[0] is None else np.array(values)

    return Data(time=labels("time"), y=np.array([r.y for r in rows]).reshape(len(rows), model.ny),
                u=np.array([r.u for r in rows]).reshape(len(rows), model.nu), modes=labels("mode"),
                source=source, anomaly=labels("anomaly"), changepoint=labels("changepoint"))


def format_cell(value) -> str:
    """A CSV cell: text as is, numbers in 10 significant digits, NaN as an empty cell."""
    if isinstance(value, str):
        return value
    value = float(value)
    return "" if math.isnan(value) else f"{value:.10g}"


class CsvWriter:
    """Writes rows of a table; with flush=True every row reaches the reader at once (on-line use)."""

    def __init__(self, stream, header, flush=False):
        self._stream, self._flush = stream, flush
        self._writer = csv.writer(stream, lineterminator="\n")
        self.write(header)

    def write(self, cells):
        self._writer.writerow([format_cell(c) for c in cells])
        if self._flush:
            self._stream.flush()


def write_columns(path, columns: dict):
    """Write equal-length columns (name -> array of numbers or strings) to a CSV file ('-' = stdout)."""
    names = list(columns)
    stream = open_target(path)
    try:
        writer = CsvWriter(stream, names)
        for row in zip(*columns.values()):
            writer.write(row)
    finally:
        if stream is not sys.stdout:
            stream.close()
