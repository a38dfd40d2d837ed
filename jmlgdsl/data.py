"""CSV data bound to a model by column name: read measured sequences (also row by row from a
stream, for on-line monitoring) and write result tables.

Columns named after the model's outputs and inputs are used; `time` (seconds) or `datetime` (ISO
time stamps), `mode` (the true mode names) and 0/1 `anomaly` / `changepoint` labels are optional;
any other column is ignored. Cells are separated by commas, or by semicolons when the header line
has semicolons and no commas (as many loggers write). A number is written as loggers write it
(ASCII digits, sign, decimal point, exponent: not 5_0.1); an empty cell (or NA / NaN) is a missing
value: an output that was not measured, or an input that takes its default; a blank `mode` cell is a
row without a label. Files are UTF-8 text; lines end in LF, CR LF or CR. Every problem is a
DataError naming the file, the CSV line and the column (a time column that goes backwards is one);
a problem that leaves the data readable but probably not what was meant (an input column absent, a
time that repeats or steps by other than the sample time, an output never measured) is a
DataWarning naming the column.
"""

from __future__ import annotations

import csv
import functools
import io
import math
import re
import sys
import warnings
import weakref
from dataclasses import asdict, dataclass, field
from datetime import datetime, timedelta, timezone
from typing import Iterator

import numpy as np

from .errors import DataError
from .names import plural, suggest
from .output import check_file, writing

MISSING = {"", "na", "nan", "n/a"}
PLAIN = re.compile(r"[0-9.eE+\-,\n]*")  # lines of plain numbers (RowParser.numbers)
DECIMAL_COMMA = re.compile(r"[-+]?\d+,\d+")


class DataWarning(UserWarning):
    """Data that read but look wrong (the command line prints these as `warning: ...`)."""


def with_defaults(u, defaults) -> np.ndarray:
    """Inputs u (..., nu) with each missing (NaN) value taking its input's default from `defaults`
    (nu,): NaN stays only where an input has neither. Every reader of inputs fills them so."""
    return np.where(np.isnan(u), defaults, u)


@dataclass(frozen=True)
class Columns:
    """The names a data file is read by: outputs, inputs with their defaults (NaN: none) and modes.

    A Model lends its own (`Columns.of(model)`); a bank still being learned, or a figure that only
    needs the `mode` column, states them directly."""

    outputs: tuple[str, ...] = ()
    inputs: tuple[str, ...] = ()
    input_defaults: np.ndarray = field(default_factory=lambda: np.zeros(0))
    modes: tuple[str, ...] = ()
    dt: float | None = None  # the sample time a `time` column should step by (None: not checked)

    @classmethod
    def of(cls, model) -> "Columns":
        """The columns of a Model (or Columns themselves)."""
        if isinstance(model, Columns):
            return model
        return cls(tuple(model.outputs), tuple(model.inputs), np.asarray(model.input_defaults, float),
                   tuple(model.modes), getattr(model, "dt", None))

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
    modes: np.ndarray | None  # (T,) true mode indices, -1 where a row has no label
    source: str
    anomaly: np.ndarray | None = None  # (T,) 0/1 labels
    changepoint: np.ndarray | None = None  # (T,) 0/1 labels


@dataclass(frozen=True)
class TimeFormat:
    """How a source writes its rows' times, so that they are written back as it wrote them: seconds
    in a `time` column, or clock times in a `datetime` column as ISO 8601 text, the date and the time
    of day joined by `separator`, with `zone` after them ('' for none: UTC, 'Z', or an offset such as
    '+01:00', the times then written at that offset) and `fraction` digits of a second (more where a
    time needs them: nothing is rounded away)."""

    column: str = "time"  # "time" (seconds) or "datetime" (clock times)
    separator: str = "T"
    zone: str = "Z"
    fraction: int = 0

    @classmethod
    def of_stamp(cls, text: str) -> "TimeFormat":
        """The format of an ISO time stamp as a file writes it ('2020-03-09 10:14:33')."""
        text = text.strip()
        stamp = datetime.fromisoformat(text)
        offset = stamp.utcoffset()
        if offset is None:
            zone = ""
        elif text.endswith("Z"):
            zone = "Z"
        else:
            sign, minutes = "-" if offset < timedelta(0) else "+", abs(offset) // timedelta(minutes=1)
            zone = f"{sign}{minutes // 60:02d}:{minutes % 60:02d}"
        fraction = re.search(r":\d\d[.,](\d+)", text)
        extended = len(text) > 10 and text[4] == "-"
        return cls("datetime", text[10] if extended else "T", zone, min(len(fraction.group(1)), 6) if fraction else 0)

    @classmethod
    def from_json(cls, value) -> "TimeFormat":
        """The format as_json wrote; seconds for anything else (a store that recorded none)."""
        try:
            found = cls(**value)
        except TypeError:
            return cls()
        usable = (found.column in ("time", "datetime") and isinstance(found.separator, str)
                  and len(found.separator) == 1 and re.fullmatch(r"|Z|[-+]\d\d:\d\d", str(found.zone))
                  and type(found.fraction) is int and 0 <= found.fraction <= 6)
        return found if usable else cls()

    def as_json(self) -> dict:
        return asdict(self)

    def write(self, seconds: float) -> str:
        """A time (seconds; since 1970, UTC, for clock times) as the source writes it: whole seconds
        without a fraction ('1583752474', not '1583752474.0'); a clock time with the source's digits of
        a second, or 3 or 6 where they do not hold it. A ValueError for a clock time beyond the
        calendar's years."""
        if self.column == "time":
            return repr(float(seconds)).removesuffix(".0")
        zone = (timezone.utc if self.zone in ("", "Z") else
                datetime.fromisoformat("2000-01-01T00:00:00" + self.zone).tzinfo)
        try:
            stamp = datetime.fromtimestamp(seconds, zone)
        except (OverflowError, OSError, ValueError):
            raise ValueError(f"{seconds!r} s is not a time of the calendar") from None
        micro = f"{stamp.microsecond:06d}"
        digits = next(d for d in (self.fraction, 3, 6) if micro[d:].strip("0") == "" or d == 6)
        return (stamp.strftime("%Y-%m-%d") + self.separator + stamp.strftime("%H:%M:%S")
                + ("." + micro[:digits] if digits else "") + self.zone)


_READING = weakref.WeakSet()  # the files open for reading, which no table may be written over


class DataFile:
    """The lines of a data file or of standard input ('-'), decoded one at a time, so that a byte that
    is not UTF-8, a binary or UTF-16 file, or a closed standard input is a DataError naming the file
    and line (and a pipe is still read line by line, as the rows arrive). A line ends at LF, CR LF or
    a CR alone (as old Mac files have it), on a pipe too."""

    def __init__(self, path):
        self.name, self.line = ("<stdin>" if str(path) == "-" else str(path)), 0
        self._lines, self._next, self._rest, self._after_cr = [], 0, bytearray(), False
        self._offered, self._ended = True, False  # whether `pending` gave the lines read last; at the end
        if str(path) == "-":
            if sys.stdin is None:
                raise DataError("<stdin>: standard input is closed")
            self._stream, self._owned = getattr(sys.stdin, "buffer", sys.stdin), False
        else:
            try:
                self._stream, self._owned = open(path, "rb"), True
            except OSError as exc:
                raise DataError(f"cannot read {path}: {exc.strerror}") from None
            _READING.add(self)
        # a pipe hands over what has arrived (read1); a stream without it is read a line at a time
        self._read = getattr(self._stream, "read1", None) or (lambda size: self._stream.readline())

    def readline(self) -> str:
        """The next line as text, ending in the line end it had ('' at the end)."""
        raw = self._raw()
        if not raw:
            return ""
        self.line += 1
        return self._decode(raw)

    def pending(self) -> str:
        """The whole lines read from the file and not yet taken, as one text, for a reader that reads
        them in one pass (then `skip`s them): each read's lines once, '' where they were offered
        already, there are none or they are not all ASCII (which `readline` decodes, or refuses)."""
        if not self._fill() or self._offered:
            return ""
        self._offered = True
        raw = b"".join(self._lines[self._next:])
        return raw.decode("ascii") if raw.isascii() else ""

    def skip(self, count: int):
        """Take the next `count` lines as read (by a reader of what `pending` gave)."""
        self._next += count
        self.line += count

    def _raw(self):
        """The bytes of the next line, with its line end (b'' at the end)."""
        if not self._fill():
            rest, self._rest = bytes(self._rest), bytearray()
            return rest
        line = self._lines[self._next]
        self._next += 1
        return line

    def _fill(self) -> bool:
        """Read on while no whole line is left to take (lines left: none were offered yet); False at the
        end of the file, where `_rest` holds a last line without its line end."""
        while self._next == len(self._lines):
            if self._ended:
                return False
            try:
                chunk = self._read(1 << 16)
            except (OSError, ValueError) as exc:
                reason = getattr(exc, "strerror", None) or exc
                raise DataError(f"{self.name}: cannot read: {reason}") from None
            if isinstance(chunk, str):  # a text stream in place of standard input
                chunk = chunk.encode("utf-8", "surrogateescape")
            if not chunk:
                self._ended = True
                return False
            if self._after_cr and chunk[:1] == b"\n":  # the LF of a CR LF that came in two pieces
                chunk = chunk[1:]
            self._after_cr = chunk[-1:] == b"\r"
            self._rest += chunk
            if b"\n" not in chunk and b"\r" not in chunk:
                continue
            lines = self._rest.splitlines(keepends=True)  # at LF, CR LF and CR alone
            self._rest = lines.pop() if not lines[-1].endswith((b"\n", b"\r")) else bytearray()
            self._lines, self._next, self._offered = lines, 0, False
        return True

    def _decode(self, raw) -> str:
        where = f"{self.name}:{self.line}"
        if self.line == 1 and raw[:2] in (b"\xff\xfe", b"\xfe\xff"):
            raise DataError(f"{where}: the file is UTF-16 text; save it as UTF-8 CSV")
        if b"\0" in raw:
            raise DataError(f"{where}: binary data (a NUL byte), not CSV text")
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            column = len(raw[:exc.start].decode("utf-8", "replace")) + 1
            raise DataError(f"{where}:{column}: byte 0x{raw[exc.start]:02x} is not UTF-8 text; save the "
                            "file as UTF-8 (it may be Latin-1 or a binary file)") from None
        return text.lstrip("\ufeff") if self.line == 1 else text

    def __iter__(self):
        return iter(self.readline, "")

    def close(self):
        if self._owned:
            self._stream.close()
            _READING.discard(self)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def open_source(path) -> DataFile:
    """The lines of a data file, or of standard input for '-'."""
    return DataFile(path)


def open_target(path):
    """`with open_target(path) as stream:` a text stream to write a table to, or standard output for
    '-': the file appears (or replaces the old one) only when the block completes, so an interrupted
    write never leaves half a table; a file this process is reading is refused."""
    check_file(path, inputs=[source.name for source in _READING])
    return writing(path)


def _records(stream, source):
    """(line number, cells, separator) for each line that is neither blank nor a # comment, read one
    at a time; the separator is chosen on the first such line (the header). A stream that numbers its
    own lines (a `number` attribute: a followed file read on from the middle) gives the line numbers."""
    delimiter = None
    numbered = hasattr(stream, "number")
    for count, line in enumerate(iter(stream.readline, ""), start=1):
        number = stream.number if numbered else count
        if is_record(line):
            if delimiter is None:
                delimiter = delimiter_of(line)
            yield number, cells_of(line, delimiter, f"{source}:{number}"), delimiter


def is_record(line: str) -> bool:
    """Whether a line holds cells: it is neither blank nor a # comment."""
    return bool(line.strip()) and not line.lstrip().startswith("#")


def delimiter_of(header: str) -> str:
    """The cells' separator of a file whose header line is `header`: a semicolon where it has
    semicolons and no commas (as many loggers write), else a comma."""
    return ";" if ";" in header and "," not in header else ","


def cells_of(line: str, delimiter: str, where: str) -> list:
    """The cells of a CSV line; a DataError naming `where` (file:line) where it is not CSV."""
    try:
        return next(csv.reader([line], delimiter=delimiter))
    except csv.Error as exc:
        limit = csv.field_size_limit()
        reason = f"a cell longer than {limit:,} characters" if "field limit" in str(exc) else f"not CSV ({exc})"
        raise DataError(f"{where}: {reason}") from None


def _timestamp(cells, col, where):
    """Seconds since 1970 (UTC) from an ISO time stamp cell; None when the column is absent."""
    if col is None:
        return None
    text = cells[col].strip()
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
    """The number in cell `col` (NaN when the column is absent or the cell is missing). Only what a
    logger writes is read: ASCII digits, a sign, a decimal point and an exponent; float() would also
    take digit separators (5_0.1) and other scripts' digits."""
    if col is None:
        return math.nan
    text = cells[col].strip()
    if text.lower() in MISSING:
        return math.nan
    try:
        value = float(text)
        if "_" in text or not text.isascii():
            raise ValueError
    except ValueError:
        hint = "; write decimal points, not commas" if DECIMAL_COMMA.fullmatch(text) else ""
        raise DataError(f"{where}: column {name!r}: {text!r} is not a number{hint}") from None
    if math.isinf(value):
        raise DataError(f"{where}: column {name!r}: {text!r} is not a finite number")
    return value


def _warn(message, stacklevel=3):
    """A DataWarning, from where warnings.warn's `stacklevel` counted from here says (the default:
    the caller's caller)."""
    warnings.warn(message, DataWarning, stacklevel=stacklevel)


class _TimeCheck:
    """Stops at a row whose time is before the last one (the time axis must not go backwards: the
    detection delays, false alarms per hour and the table's time column would mean nothing), and
    warns (once each) when a time repeats or steps by other than the model's sample time. The
    messages name the column as the header does and show the times as the file writes them."""

    def __init__(self, name, dt, resolution=0.0):
        self.name, self.dt, self.resolution = name, dt, resolution  # resolution: of the written times
        self.first = self.last = self.cell = None
        self.consecutive, self.said = False, set()

    def __call__(self, time, cell, where):
        if time is None or time != time:  # no time column, or a missing time
            self.consecutive = False
            return
        last, last_cell, consecutive = self.last, self.cell, self.consecutive
        self.last, self.cell, self.consecutive = time, cell, True
        if last is None:
            self.first = time
            return
        step, dt = time - last, self.dt
        if step < 0:
            raise DataError(f"{where}: column {self.name!r} goes backwards ({last_cell.strip()} then "
                            f"{cell.strip()}); the rows must be in time order")
        if step == 0:
            kind = "repeat"
        elif dt and consecutive and abs(step - dt) > 1e-3 * dt and abs(step - dt) > self.slack(time):
            kind = "step"
        else:
            return
        if kind in self.said:
            return
        self.said.add(kind)
        _warn(f"{where}: column {self.name!r} repeats {cell.strip()}" if kind == "repeat" else
              f"{where}: column {self.name!r} steps by {step:g} s but the model's sample time is {dt:g} s")

    def slack(self, time):
        """What a step may be off the sample time by: 1e-3 of it, 10 significant digits of the time
        since the first row, the rounding of a large time (seconds since 1970) to a float, and the
        resolution of the written times."""
        return 1e-3 * self.dt + 1e-9 * (time - self.first) + 4 * math.ulp(time) + self.resolution


def iter_rows(stream, model, source="<data>", outputs=True) -> "RowReader":
    """Rows of a CSV stream as they arrive (lines are read one at a time, so a pipe works on-line).

    `model` is a Model or the Columns to read by. With outputs=False the output columns may be
    absent (input-only files, for simulation).
    """
    return RowReader(stream, model, source, outputs)


class RowReader:
    """The rows iter_rows reads, one at a time, and `times`: how the stream writes its times (a
    TimeFormat once a row with a time has been read; None before, and for a stream without times).
    With whole=True (`read_data`: the file is wanted as arrays) a data file's block of plain lines
    that are all rows needing no word (`RowParser.takes`) comes as one Numbers instead of a Row each."""

    def __init__(self, stream, model, source: str, outputs: bool, whole: bool = False):
        self.times = None
        self._rows = self._read(stream, Columns.of(model), source, outputs, whole)

    def __iter__(self) -> Iterator[Row]:
        return self

    def __next__(self) -> Row:
        return next(self._rows)

    def _read(self, stream, model, source, outputs, whole):
        records = _records(stream, source)
        number, header, delimiter = next(records, (0, None, None))
        if header is None:
            raise DataError(f"{source}: no header line (expected columns {', '.join(model.outputs)})")
        parser = RowParser(header, model, source, outputs)
        rows = (self._blocks(stream, parser, delimiter, number - stream.line, whole) if isinstance(stream, DataFile)
                else (parser.row(line, cells) for line, cells, _ in records))
        for row in rows:
            self.times = parser.times
            yield row
        parser.finish()

    @staticmethod
    def _blocks(stream: DataFile, parser: "RowParser", delimiter: str, base: int, whole: bool):
        """The rows of a data file's lines after its header: each read's lines in one pass where they
        are plain (RowParser.numbers), else one at a time as `row` reads them. `base`: what a line's
        number is past the file's count of lines read (lines read before the reader began). `whole`:
        a block that the parser takes whole comes as its Numbers."""
        while True:
            text = stream.pending()
            numbers = parser.numbers(text, delimiter) if text else None
            if numbers is not None:
                first = stream.line + base + 1
                stream.skip(len(numbers.y))
                if whole and parser.takes(numbers):
                    yield numbers
                    continue
                for i in range(len(numbers.y)):
                    yield parser.numbered(first + i, numbers, i)
                continue
            line = stream.readline()
            if not line:
                return
            if is_record(line):
                number = stream.line + base
                yield parser.row(number, cells_of(line, delimiter, f"{parser.source}:{number}"))


class RowParser:
    """Rows from the cells of a CSV file's lines, given one at a time after its header's cells: what
    iter_rows does with each line, for a reader that gets its lines its own way (a fleet's files read
    in one thread, jmlgdsl.monitor.sources.files). `times` is how the file writes its times (a
    TimeFormat once a row with a time has been read)."""

    def __init__(self, header, model, source: str, outputs: bool = True):
        model = Columns.of(model)
        self.model, self.source, self.times = model, source, None
        names = [name.strip().lstrip("\ufeff") for name in header]  # spreadsheets may add a BOM
        index = {name: i for i, name in enumerate(names)}

        def column(name, required):
            """The cell index of a column the model uses; None when it is absent and not required."""
            if names.count(name) > 1:
                raise DataError(f"{source}: column {name!r} appears {names.count(name)} times in the header")
            if name in index:
                return index[name]
            spelled = [i for i, h in enumerate(names) if re.sub(r"\W", "_", h) == name]
            if len(spelled) == 1:  # a header such as 'Volume Flow Rate' for the name Volume_Flow_Rate
                return spelled[0]
            if required:
                raise DataError(f"{source}: missing column {name!r}; the header has {', '.join(header)}"
                                f"{suggest(name, header)}")
            return None

        self.names = names
        self.y_cols = [column(n, outputs) for n in model.outputs]
        self.u_cols = [column(n, math.isnan(d)) for n, d in zip(model.inputs, model.input_defaults)]
        self.t_col, self.stamp_col, self.mode_col = column("time", False), column("datetime", False), column("mode", False)
        self.anomaly_col, self.change_col = column("anomaly", False), column("changepoint", False)
        self.time_col = self.stamp_col if self.t_col is None else self.t_col  # with both, `time` is the time axis
        self.check_time = (None if self.time_col is None else  # time stamps are kept to the microsecond
                           _TimeCheck(names[self.time_col], model.dt, 1e-6 if self.t_col is None else 0.0))
        self._mode_index = {name: k for k, name in enumerate(model.modes)} | {"": None}  # a `mode` cell's index
        self.measured = np.zeros(model.ny, bool)  # the outputs with a value in a row read so far
        self.all_measured = False  # whether every output has: `numbered` looks no further

    def row(self, line: int, cells: list) -> Row:
        """The row of CSV line `line`, its cells split; a DataError naming the file, line and column
        where it is not a valid row."""
        model, names, t_col = self.model, self.names, self.t_col
        where = f"{self.source}:{line}"
        if len(cells) < len(names) or any(c.strip() for c in cells[len(names):]):
            hint = "; decimal commas (1,5) split numbers in two: write 1.5" if len(cells) > len(names) else ""
            raise DataError(f"{where}: {plural(len(cells), 'cell')}, but the header has "
                            f"{plural(len(names), 'column')}{hint}")
        y = np.array([_number(cells, c, n, where) for c, n in zip(self.y_cols, model.outputs)])
        u = self._inputs(np.array([_number(cells, c, n, where) for c, n in zip(self.u_cols, model.inputs)]), where)
        time = _timestamp(cells, self.stamp_col, where) if t_col is None else _number(cells, t_col, "time", where)
        self._timed(time, None if self.time_col is None else cells[self.time_col],
                    None if t_col is not None or self.stamp_col is None else cells[self.stamp_col], where)
        self.measured |= ~np.isnan(y)
        return Row(line, time, y, u, _mode(cells, self.mode_col, model.modes, where),
                   _label(cells, self.anomaly_col, "anomaly", where), _label(cells, self.change_col, "changepoint", where))

    def _inputs(self, u, where):
        """Inputs as read with their defaults where missing; a DataError for one missing without a default."""
        model = self.model
        u = with_defaults(u, model.input_defaults)
        lacking = np.isnan(u)
        if lacking.any():
            name = model.inputs[int(np.argmax(lacking))]
            raise DataError(f"{where}: column {name!r}: missing value and the input has no default")
        return u

    def _timed(self, time, time_cell, stamp, where):
        """A row's time: how the file writes its times, from the first row with one (`stamp`: its time
        stamp cell, None for seconds), and the time axis checked."""
        if self.times is None and time is not None and time == time:
            self.times = TimeFormat() if stamp is None else TimeFormat.of_stamp(stamp)
        if self.check_time is not None:
            self.check_time(time, time_cell, where)

    def numbers(self, text: str, delimiter: str) -> "Numbers | None":
        """Whole lines of a file (`text`, each line ending in a line end) read in one pass, for rows
        of them one at a time by `numbered`. None where the lines need reading one at a time as `row`
        reads them: a file with time stamps or a column of an output missing, or lines with anything
        but plain numbers (ASCII digits, point, sign, exponent) and commas (a comment, a blank line,
        spaces, a missing-value word, a line with another number of cells than the header, a number
        too large for a float) other than a known mode's name or nothing in the `mode` column, and
        0, 1 or nothing in the `anomaly` and `changepoint` columns."""
        count, mode_col = len(self.names), self.mode_col
        if (delimiter != "," or None in self.y_cols or self.stamp_col is not None
                or (mode_col is not None and mode_col in (*self.y_cols, *self.u_cols, self.t_col))):
            return None
        lines = text.split("\n")
        lines.pop()  # after the last line end
        if any(line.count(",") != count - 1 for line in lines):
            return None
        cells = ",".join(lines).split(",")
        modes = None
        if mode_col is not None:
            try:
                modes = [self._mode_index[cell] for cell in cells[mode_col::count]]
            except KeyError:  # a name to strip, or not a mode: as `row` reads it
                return None
            cells[mode_col::count] = [""] * len(lines)
        if not PLAIN.fullmatch(text if modes is None else ",".join(cells)):
            return None
        try:
            values = np.array([cell or "0" for cell in cells], dtype=float).reshape(len(lines), count)
        except ValueError:
            return None
        if np.isinf(values).any():
            return None
        values[np.array([not cell for cell in cells]).reshape(values.shape)] = math.nan  # empty: missing
        labels = []
        for col in (self.anomaly_col, self.change_col):
            label = None if col is None else values[:, col]
            if label is not None and not ((label == 0) | (label == 1) | np.isnan(label)).all():
                return None
            labels.append(None if label is None else [None if v != v else int(v) for v in label.tolist()])
        values = np.hstack([values, np.full((len(lines), 1), math.nan)])  # the column of an absent input
        last = len(self.names)
        u = with_defaults(values[:, [last if c is None else c for c in self.u_cols]], self.model.input_defaults)
        return Numbers(values[:, self.y_cols], u, np.isnan(u).any(axis=1).tolist(),
                       None if self.t_col is None else values[:, self.t_col].tolist(),
                       None if self.t_col is None else cells[self.t_col::count], modes, *labels)

    def numbered(self, line: int, numbers: "Numbers", i: int) -> Row:
        """The row of CSV line `line` from the `i`th line of `numbers`; a DataError as `row` gives one
        where it is not a valid row."""
        where = f"{self.source}:{line}"
        y, u = numbers.y[i], numbers.u[i]
        if numbers.lacking[i]:
            self._inputs(u, where)
        time = None if numbers.time is None else numbers.time[i]
        self._timed(time, None if time is None else numbers.time_cells[i], None, where)
        if not self.all_measured:
            self.measured |= ~np.isnan(y)
            self.all_measured = bool(self.measured.all())
        return Row(line, time, y, u, None if numbers.modes is None else numbers.modes[i],
                   None if numbers.anomaly is None else numbers.anomaly[i],
                   None if numbers.changepoint is None else numbers.changepoint[i])

    def takes(self, numbers: "Numbers") -> bool:
        """Whether every line of `numbers` is a row that `numbered` gives without a word: no input
        lacks a value, and the times (none missing) go on from the last row's by the model's sample
        time to within 1e-3 of it (or only forward, without one), so no check could stop or warn.
        Then the parser is taken past them as `numbered` takes it a line at a time; else nothing
        changes, the lines left to `numbered`."""
        check = self.check_time
        if any(numbers.lacking):
            return False
        if numbers.time is not None:
            times = np.array(numbers.time if check.last is None else [check.last, *numbers.time])
            steps, dt = np.diff(times), check.dt
            if (np.isnan(times).any() or (check.last is not None and not check.consecutive) or not (steps > 0).all()
                    or (dt and not (np.abs(steps - dt) <= 1e-3 * dt).all())):
                return False
            if check.last is None:
                check.first = times[0]
            check.last, check.cell, check.consecutive = numbers.time[-1], numbers.time_cells[-1], True
            if self.times is None:
                self.times = TimeFormat()
        if not self.all_measured:
            self.measured |= ~np.isnan(numbers.y).all(axis=0)
            self.all_measured = bool(self.measured.all())
        return True

    def finish(self):
        """At the file's end: warn of an input column absent and of an output never measured (as from
        the frame above the caller's, as iter_rows's reader warns from where its rows were taken)."""
        model = self.model
        for name, col, default in zip(model.inputs, self.u_cols, model.input_defaults):
            if col is None:
                _warn(f"{self.source}: no column {name!r}: input {name} took its default {default:g} throughout", 4)
        for name, col, seen in zip(model.outputs, self.y_cols, self.measured):
            if col is not None and not seen:
                _warn(f"{self.source}: column {name!r} has no values: output {name} was never measured", 4)


@dataclass(frozen=True)
class Numbers:
    """Lines of plain numbers as RowParser.numbers reads them: each line's outputs and inputs (their
    defaults where missing), whether an input lacks a value with no default, its time and time cell."""

    y: np.ndarray  # (lines, ny)
    u: np.ndarray  # (lines, nu)
    lacking: list
    time: list | None
    time_cells: list | None
    modes: list | None = None  # true mode indices, None where a line has no label
    anomaly: list | None = None  # 0/1 labels, None where a line has none
    changepoint: list | None = None


def _mode(cells, col, modes, where):
    """The true mode index in cell `col`; None when the column is absent or the cell is blank."""
    name = "" if col is None else cells[col].strip()
    if not name:
        return None
    if name not in modes:
        raise DataError(f"{where}: column 'mode': unknown mode {name!r}; modes are "
                        f"{', '.join(modes)}{suggest(name, modes)}")
    return modes.index(name)


def read_csv(path, model, outputs=True) -> Data:
    """Read a whole data file ('-' = standard input) into arrays bound to the names of `model`, a
    Model or the Columns to read by."""
    with open_source(path) as stream:
        return read_data(stream, model, stream.name, outputs)


def read_data(stream, model, source: str, outputs=True) -> Data:
    """`read_csv` of a data stream already open, named `source` in errors."""
    model = Columns.of(model)
    y, u, columns = [], [], {name: [] for name in ("time", "mode", "anomaly", "changepoint")}
    for piece in RowReader(stream, model, source, outputs, whole=True):  # a Row, or a block's Numbers
        if isinstance(piece, Row):
            y.append(piece.y[np.newaxis])
            u.append(piece.u[np.newaxis])
            for name, values in columns.items():
                values.append(getattr(piece, name))
            continue
        y.append(piece.y)
        u.append(piece.u)
        lines = len(piece.y)
        for values, block in zip(columns.values(), (piece.time, piece.modes, piece.anomaly, piece.changepoint)):
            values += [None] * lines if block is None else block
    if not y:
        raise DataError(f"{source}: no data rows")

    def labels(name):
        values = columns[name]
        return None if values[0] is None else np.array(values)

    modes = columns["mode"]
    return Data(time=labels("time"), y=np.concatenate(y).reshape(len(modes), model.ny),
                u=np.concatenate(u).reshape(len(modes), model.nu),
                modes=None if modes.count(None) == len(modes) else np.array([-1 if m is None else m for m in modes]),
                source=source, anomaly=labels("anomaly"), changepoint=labels("changepoint"))


def format_cell(value) -> str:
    """A CSV cell: text as is, numbers in 10 significant digits, NaN as an empty cell."""
    if isinstance(value, str):
        return value
    value = float(value)
    return "" if math.isnan(value) else f"{value:.10g}"


def joined_numbers(values: list) -> str:
    """The cells `format_cell` makes of a list of numbers (Python's own), joined by commas: formatted in
    one call of one format, each NaN's 'nan' (no number's cell holds those letters) then emptied."""
    return (_format_of(len(values)) % tuple(values)).replace("nan", "")


@functools.lru_cache(maxsize=64)
def _format_of(count: int) -> str:
    """The format of `count` numbers in 10 significant digits, comma-separated (as f"{value:.10g}")."""
    return ",".join(["%.10g"] * count)


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

    def write_line(self, cells: str):
        """A row of cells already joined by commas: numbers as `joined_numbers` formats them and text as
        `csv_cell` quotes it (a result table's rows, most of what `run` on many files writes), the line
        `write` makes of them."""
        self._stream.write(cells + "\n")
        if self._flush:
            self._stream.flush()


def csv_cell(text: str) -> str:
    """A text cell as a CSV writer writes it among others: quoted where it holds a comma, a quote or
    a line end."""
    line = io.StringIO()
    csv.writer(line, lineterminator="").writerow([text, ""])
    return line.getvalue()[:-1]


def write_columns(path, columns: dict):
    """Write equal-length columns (name -> array of numbers or strings) to a CSV file ('-' = stdout)."""
    with open_target(path) as stream:
        writer = CsvWriter(stream, list(columns))
        for row in zip(*columns.values()):
            writer.write(row)
