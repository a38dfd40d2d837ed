"""Rows from a CSV file followed as it grows, or from standard input ('-'), read as `jmlgdsl run`
reads them (jmlgdsl.data.iter_rows); and a fleet's files, one a unit, read the same way in one
thread (UnitFiles).

A followed file's position is the byte offset after the last row handed on, with its line number:
a restarted monitor reads the header again and continues there, with the same line numbers in its
messages. A line still being written (no line end yet) waits for its end. A line that is not a
valid row is reported as a malformed event and skipped; the rows after it are read on.
"""

from __future__ import annotations

import sys
import threading
from dataclasses import dataclass

from ...data import RowParser, cells_of, delimiter_of, is_record, iter_rows
from ...errors import DataError
from ..units import PLACEHOLDER, FleetError, for_unit
from .contract import End, Event, Fatal, Times, WholeRow

POLL = 0.05  # seconds between looks at a followed file that has not grown
# Bytes of a unit's file read at a time by a fleet's reader; rows of each unit handed on in a round
# (the monitor steps the units' filters together, so each round brings a row of every unit).
BLOCK, ROUND = 1 << 14, 4


def header_line(stream, name: str):
    """(text, line number) of the header line of the file `stream` (a followed file, read again from
    its start: a restarted reader needs it before its saved offset)."""
    stream.seek(0)
    for number, raw in enumerate(stream, start=1):
        text = raw.decode("utf-8", "replace")
        if is_record(text):
            return text, number
    raise DataError(f"{name}: the header line is gone from the file being followed")


class Lines:
    """A stream's lines, decoded, for iter_rows, from a byte offset on (with the line number there):
    at the end it waits for more while `follow`, and ends when `stop` is set. `number` is the line
    number of the line last handed out, which iter_rows takes for its messages. `again()` hands the
    header line out once more, so that a new iter_rows reads on (after a bad line, or from a saved
    offset)."""

    def __init__(self, stream, name: str, follow: bool, stop: threading.Event, offset: int = 0, line: int = 0):
        self.stream, self.name, self.follow, self.stop = stream, name, follow, stop
        self.offset, self.line = offset, line  # just after the last line read
        self.number = line
        self.header = None  # (text, line number) of the header line
        self._again, self._rest = False, b""
        if offset:
            self.header = header_line(self.stream, self.name)
            stream.seek(offset)
            self.again()

    def again(self):
        self._again = True

    def readline(self) -> str:
        if self._again:
            self._again = False
            text, self.number = self.header
            return text
        raw = self._next()
        if not raw:
            return ""
        self.offset += len(raw)
        self.line = self.number = self.line + 1
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError:
            raise DataError(f"{self.name}:{self.line}: not UTF-8 text") from None
        if self.header is None and is_record(text):
            self.header = (text, self.line)
        return text

    def _next(self) -> bytes:
        """The bytes of the next whole line (b'' at the end)."""
        read = getattr(self.stream, "read1", self.stream.read)
        while True:
            cut = self._rest.find(b"\n")
            if cut >= 0:
                raw, self._rest = self._rest[:cut + 1], self._rest[cut + 1:]
                return raw
            chunk = read(1 << 16)
            if chunk:
                self._rest += chunk
            elif self.stop.is_set() or not self.follow:
                raw, self._rest = (b"" if self.stop.is_set() else self._rest), b""
                return raw  # a last line without a line end, unless stopping
            else:
                self.stop.wait(POLL)


def open_source(connection, model, tags, units=None):
    """The CSV file (or standard input) a connection names; for a fleet's units, the file of each,
    from a template with {unit} in it."""
    url = connection.url
    if units is not None:
        if PLACEHOLDER not in url:
            raise FleetError(f"--units with a CSV source: give the files as a template with {PLACEHOLDER} in it, "
                             f"e.g. data/{PLACEHOLDER}.csv, not {url}")
        return UnitFiles([for_unit(url, unit) for unit in units], model, connection.follow, url)
    return CsvSource(url, model, connection.follow)


class CsvSource:
    """A CSV file (followed as it grows unless follow=False) or standard input ('-'), as rows."""

    rows = True  # hands on whole rows, not readings to assemble

    def __init__(self, path, model, follow: bool = True):
        self.path, self.model, self.follow = str(path), model, follow
        self.name = "<stdin>" if self.path == "-" else self.path
        self._stop = threading.Event()
        self._thread = None

    def start(self, put, position: dict | None):
        """Read rows in a thread: a WholeRow for each, an Event for a bad line, End at the end (of standard
        input, or of an unfollowed file), and before the first row with a time, Times: how the file
        writes its times."""
        if self.path == "-":
            stream = sys.stdin.buffer
        else:
            try:
                stream = open(self.path, "rb")
            except OSError as exc:
                raise DataError(f"--source: cannot read {self.path}: {exc.strerror}") from None
        offset, line = (position["offset"], position["line"]) if position and self.path != "-" else (0, 0)
        self._thread = threading.Thread(target=self._read, args=(stream, offset, line, put),
                                        name="csv source", daemon=True)
        self._thread.start()

    def _read(self, stream, offset, line, put):
        try:
            lines = Lines(stream, self.name, self.follow and self.path != "-", self._stop, offset, line)
            failed = None  # the line of the last bad one: the same again means the header is at fault
            told = None  # how the file writes its times, once put
            while not self._stop.is_set():
                try:
                    rows = iter_rows(lines, self.model, self.name)
                    for row in rows:
                        if self._stop.is_set():
                            return
                        if told is None and rows.times is not None:
                            told = rows.times
                            put(Times(told))
                        put(WholeRow(row, {"offset": lines.offset, "line": lines.line}))
                    break
                except DataError as exc:
                    put(Event("malformed", None, str(exc)))
                    if lines.header is None or lines.line in (lines.header[1], failed):
                        raise
                    failed = lines.line
                    lines.again()  # read on after the bad line
            if not self._stop.is_set():
                put(End())
        except DataError as exc:
            put(Fatal(str(exc)))
        finally:
            if stream is not sys.stdin.buffer:
                stream.close()

    def acknowledge(self, tokens):
        """Nothing to acknowledge: the position saved with the rows is where a restart reads on."""

    def stop(self):
        self._stop.set()


class UnitFiles:
    """A fleet's CSV files, one a unit (followed as they grow unless follow=False), read in one
    thread: a block of bytes of a unit's file at a time, its whole lines read as CsvSource reads
    them, and the units' rows handed on in rounds, a few of each unit a round, each round at once
    (a list of (unit index, item) pairs; the data end, once every unit's file has ended, as
    (None, End())). One thread, not one a unit:
    a thousand threads woken each for its unit's next rows cost ten times the reading. A unit's
    position is its file's, as CsvSource's; `positions` the list of them."""

    rows = True

    def __init__(self, paths, model, follow: bool, name: str):
        self.paths, self.model, self.follow, self.name = [str(path) for path in paths], model, follow, name
        self._stop = threading.Event()
        self._thread = None

    def start(self, put, positions):
        files = []
        try:
            for path, position in zip(self.paths, positions):
                files.append(UnitFile(path, self.model, position))
        except DataError:
            for file in files:
                file.stream.close()
            raise
        self._thread = threading.Thread(target=self._read, args=(files, put), name="csv sources", daemon=True)
        self._thread.start()

    def _read(self, files, put):
        try:
            live = list(enumerate(files))
            while live and not self._stop.is_set():
                handed = [(i, item) for i, file in live for item in file.items(ROUND, self.follow)]
                if handed:
                    put(handed)
                if any(isinstance(item, Fatal) for _, item in handed):
                    return
                live = [(i, file) for i, file in live if not file.ended]
                if not handed and live:
                    self._stop.wait(POLL)
            if not self._stop.is_set():
                put((None, End()))
        finally:
            for file in files:
                file.stream.close()

    def acknowledge(self, tokens):
        """Nothing to acknowledge: the positions saved with the rows are where a restart reads on."""

    def stop(self):
        self._stop.set()


class UnitFile:
    """One unit's file of a fleet, read a block of bytes at a time from a position on: its items
    (WholeRows, a malformed Event for a bad line, Times before the first row with a time, a Fatal
    where the header is at fault) a few rows at a time. `ended` once an unfollowed file is read to
    its end."""

    def __init__(self, path: str, model, position: dict | None):
        try:
            self.stream = open(path, "rb")
        except OSError as exc:
            raise DataError(f"--source: cannot read {path}: {exc.strerror}") from None
        self.name, self.model = path, model
        self.offset, self.line = (position["offset"], position["line"]) if position else (0, 0)
        self.header = self.parser = self.delimiter = None  # header: (text, line number)
        self.told = self.ended = False  # told: Times put
        self.lines, self.rest = [], b""  # whole lines read and not yet handled (reversed); a line being written
        self.block, self.fresh = None, False  # lines read in one pass (_Block); whether `lines` are newly read
        self.saved = self.offset > 0

    def items(self, rows: int, follow: bool) -> list:
        """The items of the next lines, up to `rows` rows (fewer where the file has no more whole lines now)."""
        if self.saved:  # read on from a saved position: the header again first
            self.saved = False
            try:
                header = header_line(self.stream, self.name)
            except DataError as exc:
                self.ended = True
                return [Fatal(str(exc))]
            self.stream.seek(self.offset)
            try:
                self._begin(*header)
            except DataError as exc:
                self.ended = True
                return [Event("malformed", None, str(exc)), Fatal(str(exc))]
        items = []
        while rows and (self.block or self.lines or self._more(follow)):
            if self.fresh and self.parser is not None and not self.block:
                self._numbers()
            try:
                row = self._next()
            except DataError as exc:
                items.append(Event("malformed", None, str(exc)))
                if self.header is None:  # the header is at fault: no row can be read
                    self.ended = True
                    return items + [Fatal(str(exc))]
                self._begin(*self.header)  # read on after the bad line, as a new reader from the header
                continue
            if row is None:
                continue
            if not self.told and self.parser.times is not None:
                self.told = True
                items.append(Times(self.parser.times))
            items.append(WholeRow(row, {"offset": self.offset, "line": self.line}))
            rows -= 1
        if self.ended and not self.lines and not self.block:
            if self.header is None:
                message = f"{self.name}: no header line (expected columns {', '.join(self.model.outputs)})"
                return items + [Event("malformed", None, message), Fatal(message)]
            self.parser.finish()
        return items

    def _numbers(self):
        """Read the whole lines not yet handled in one pass into `block` where they are plain numbers
        (RowParser.numbers), their rows then made one at a time."""
        self.fresh = False
        raw = b"".join(reversed(self.lines))
        read = raw.isascii() and self.parser.numbers(raw.decode("ascii"), self.delimiter)
        if read:
            self.block = _Block(read, [len(line) for line in reversed(self.lines)])
            self.lines = []

    def _next(self):
        """The row of the next line (None: a blank line, a comment, the header)."""
        block = self.block
        if block:
            i = block.next
            block.next += 1
            self.offset += block.lengths[i]
            self.line += 1
            return self.parser.numbered(self.line, block.numbers, i)
        raw = self.lines.pop()
        self.offset += len(raw)
        self.line += 1
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError:
            raise DataError(f"{self.name}:{self.line}: not UTF-8 text") from None
        if not is_record(text):
            return None
        if self.header is None:
            self._begin(text, self.line)
            self.fresh = True  # the lines after the header may be read in one pass
            return None
        return self.parser.row(self.line, cells_of(text, self.delimiter, f"{self.name}:{self.line}"))

    def _begin(self, text: str, line: int):
        """Read the rows that follow by the header line `text` (line number `line`)."""
        delimiter = delimiter_of(text)
        self.parser = RowParser(cells_of(text, delimiter, f"{self.name}:{line}"), self.model, self.name)
        self.header, self.delimiter = (text, line), delimiter

    def _more(self, follow: bool) -> bool:
        """Read a block: whether it brought a whole line (or, at the end of an unfollowed file, a last
        line without a line end); at that end, `ended`."""
        pieces = [self.rest]  # of a line longer than a block, joined once its end is read
        while True:
            block = self.stream.read(BLOCK)
            if not block:
                self.rest = b"".join(pieces)
                if follow or self.ended:
                    return False
                self.ended = True
                if not self.rest:
                    return False
                self.lines, self.rest = [self.rest], b""
                return True
            pieces.append(block)
            if b"\n" in block:
                lines = b"".join(pieces).split(b"\n")
                self.rest = lines.pop()
                self.lines, self.fresh = [line + b"\n" for line in reversed(lines)], True
                return True


@dataclass
class _Block:
    """Lines of a file read in one pass: their numbers (jmlgdsl.data.Numbers), their lengths in
    bytes, and the index of the next line to make a row of."""

    numbers: object
    lengths: list
    next: int = 0

    def __bool__(self):
        return self.next < len(self.lengths)
