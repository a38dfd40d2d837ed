"""Rows from a CSV file followed as it grows, or from standard input ('-'), read as `jmlgdsl run`
reads them (jmlgdsl.data.iter_rows).

A followed file's position is the byte offset after the last row handed on, with its line number:
a restarted monitor reads the header again and continues there, with the same line numbers in its
messages. A line still being written (no line end yet) waits for its end. A line that is not a
valid row is reported as a malformed event and skipped; the rows after it are read on.
"""

from __future__ import annotations

import sys
import threading

from ...data import iter_rows
from ...errors import DataError
from ..units import PLACEHOLDER, FleetError, for_unit
from .contract import End, Event, Fatal, Times, WholeRow
from .units import UnitSources

POLL = 0.05  # seconds between looks at a followed file that has not grown


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
            self.header = self._header()
            stream.seek(offset)
            self.again()

    def again(self):
        self._again = True

    def _header(self):
        self.stream.seek(0)
        for number, raw in enumerate(self.stream, start=1):
            text = raw.decode("utf-8", "replace")
            if _content(text):
                return text, number
        raise DataError(f"{self.name}: the header line is gone from the file being followed")

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
        if self.header is None and _content(text):
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


def _content(text: str) -> bool:
    """A line iter_rows reads (not blank, not a # comment)."""
    return bool(text.strip()) and not text.lstrip().startswith("#")


def open_source(connection, model, tags, units=None):
    """The CSV file (or standard input) a connection names; for a fleet's units, the file of each,
    from a template with {unit} in it."""
    url = connection.url
    if units is not None:
        if PLACEHOLDER not in url:
            raise FleetError(f"--units with a CSV source: give the files as a template with {PLACEHOLDER} in it, "
                             f"e.g. data/{PLACEHOLDER}.csv, not {url}")
        return UnitSources([CsvSource(for_unit(url, unit), model, connection.follow) for unit in units], url)
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
