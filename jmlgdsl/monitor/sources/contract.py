"""The one contract between a source and the monitor: what a source is, and the items it hands over.

A source (a module of jmlgdsl.monitor.sources per protocol) reads a plant's data in threads of its
own and hands the monitor typed items; the monitor commits what they hold to its store and only then
acknowledges them, so that a source whose far side delivers again (an MQTT broker) loses nothing
and a source that reads on from a place (a file) reads on from the last commit.

    WholeRow(row, position)         a whole row, and where to read on after it
    Readings(readings, arrival, token)  readings of tags at their own moments, put on the sample
                                    clock by jmlgdsl.monitor.rows
    Unreadable(message, token)      a message that holds no reading: a `malformed` event
    Event(kind, tag, detail)        what befell the source (connected, lost, a bad line, ...)
    Times(format)                   how a source of rows writes their times, before the first
    End()                           the data end (standard input, an unfollowed file)
    Fatal(message)                  what trying again cannot mend: the monitor stops with it

A source of a fleet's units (jmlgdsl.monitor.units) hands over (unit index, item) pairs instead
(None: an item of every unit, say its one connection's event), or a list of such pairs at once: a
round of its units' items, read in one thread (the monitor holds a few rounds ahead, no more).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Protocol

from ...data import Row
from ...data import TimeFormat


@dataclass(frozen=True)
class Event:
    """Something the store keeps beside the rows: its kind, the tag (or None) and what happened."""

    kind: str  # connect, disconnect, gap, stale, fresh, late, malformed, ... (docs/monitor.md)
    tag: str | None
    detail: str
    time: float | None = None  # the data time it concerns, seconds


@dataclass(frozen=True)
class WholeRow:
    """A whole row, and the source's position after it (saved with it: where a restart reads on)."""

    row: Row
    position: dict | None


@dataclass(frozen=True)
class Readings:
    """The readings of one message: (spec name, value as read, its own time or None), the time in
    seconds or a datetime where the source writes clock times; the wall-clock time it arrived (None:
    not known); and the token that acknowledges it after the commit that holds it."""

    readings: list
    arrival: float | None
    token: object = None


@dataclass(frozen=True)
class Unreadable:
    """A message that holds no reading (kept as a `malformed` event), and its token."""

    message: str
    token: object = None


@dataclass(frozen=True)
class Times:
    """How a source of rows writes their times."""

    format: TimeFormat


@dataclass(frozen=True)
class End:
    """The data end: nothing more will come."""


@dataclass(frozen=True)
class Fatal:
    """What trying again cannot mend (a refused password, an unreadable file): the monitor stops."""

    message: str


Item = WholeRow | Readings | Unreadable | Event | Times | End | Fatal


class Source(Protocol):
    """What the monitor needs of a source."""

    name: str  # what the run records of it: its URL (never with credentials) or file
    rows: bool  # True: it hands over WholeRows; False: Readings, which the monitor assembles into rows

    def start(self, put: Callable[[Item], None], position) -> None:
        """Hand items over with `put` from threads of its own, reading on from `position` (what the last
        commit saved of its WholeRows' positions; None: from the start; a list of them for a fleet's units)."""

    def acknowledge(self, tokens: list) -> None:
        """The tokens of the Readings and Unreadables a commit holds, once it is committed."""

    def stop(self) -> None:
        """Stop handing items over and close."""
