"""Rows on the spec's sample clock from readings that arrive at their own moments.

A reading of tag NAME at time t (seconds) belongs to the sample slot round(t / dt): the clock is
anchored at time 0, so a restarted monitor puts every reading in the same slot. Rows leave in slot
order. A row is complete when every output has a reading in its slot and every input has a reading
or a held value; it leaves then, or once the newest reading's time is `grace` seconds past its slot,
and whatever is still missing is missing (the filters handle missing readings; an input takes its
default). So the rows depend on the readings alone, not on when they were processed, and a replay
of the same readings gives the same rows.

An input holds its last value until it is stale (set points are often published on change: an input
read in the previous row is waited for, one that was not is taken as held); an output never does (a measurement is of its own moment). A tag without a reading for `stale` seconds
becomes stale, with an event, and fresh again with its next reading. What does not fit is counted
as an event and dropped, never reordered into a row already diagnosed: a reading whose row has left
(late; the late readings of one message are one event), a second reading of a tag in one slot (duplicate: the first stands), and a reading older
than its tag's previous one whose row is still open (out_of_order: it is used). Slots without any
reading are a gap; a gap longer than `max_gap` seconds is skipped (its rows are not diagnosed, the
clock restarts after it) rather than filled with rows of nothing.

The row clock moves on evidence, not on one message. A reading stamped more than AHEAD seconds past
the wall clock it arrived at is `future`: not used (a device whose clock is wrong, a test publisher).
In a stream whose readings carry their own times, a message more than `horizon` (the grace and
HORIZON sample times) past the stream's newest reading is `ahead`: held aside, and used only when
the stream follows it, FOLLOWED such messages in a row within `horizon` of each other with no
reading in between where the stream was (a `jump`: the source came back after an outage); a reading
where the stream was drops what is held. A reading without a time of its own in such a stream is
`malformed`, unless its tag says it takes its arrival time. So no single message, however stamped,
makes the rows after it `late`.

While the source is disconnected, and for a while after it connects again (`hold`, `release`: the
monitor says when), readings can still come for rows the stream has passed: a broker delivers what
it kept, a plant sends what it kept while cut off, often after the readings of the moment. Rows are
then held: a row leaves only when complete, whatever the grace, and a message held ahead of the
stream is not dropped by readings where the stream was but taken in once the stream comes within
the horizon of it. On release the grace rules again. A stream of readings stamped on arrival is
never held (what comes late is stamped late).
"""

from __future__ import annotations

import dataclasses
import math
from datetime import datetime

import numpy as np

from ..data import Row, TimeFormat, with_defaults
from .sources.contract import Event

AHEAD = 60.0  # seconds a reading may be stamped past the wall clock it arrives at
HORIZON = 10  # sample times (beyond the grace) a message may be stamped past the stream's newest reading
FOLLOWED = 3  # messages ahead of the stream, in a row, that show it has moved on


# the assembler's options on the command line (flag -> argparse's keywords)
COMMAND_LINE = {
    "--grace": dict(type=float, metavar="SECONDS", help="a row waits this long (in the readings' time) for its "
                    "missing readings (default 2 sample times)"),
    "--stale": dict(type=float, metavar="SECONDS", help="a tag without a reading for this long is stale (default 10 "
                    "sample times)"),
    "--max-gap": dict(type=float, default=3600.0, metavar="SECONDS", help="a gap without any reading up to this long "
                      "is diagnosed as rows of missing readings; a longer one is skipped (default 3600)"),
    "--catch-up": dict(type=float, default=5.0, metavar="SECONDS", help="while the source is disconnected, and this "
                       "long (of the wall clock) after it connects, rows wait for every missing reading: what was "
                       "kept meanwhile may still come (default 5)"),
}
CLOCK = TimeFormat("datetime")  # ISO 8601, UTC: events' clock times, and the rows' of a source that writes such


def clock_time(seconds: float) -> str:
    """Seconds since 1970 as an ISO 8601 time, UTC ('2026-11-27T02:35:18Z'; with the fraction of a
    second where there is one); a time beyond the calendar's years as seconds."""
    try:
        return CLOCK.write(seconds)
    except ValueError:
        return f"{seconds!r} s"


def _late(readings, at) -> Event:
    """One event for the readings of one message that came after their rows were diagnosed (a
    message of many tags, or one delivered again after a reconnection, is one event, not one a tag);
    `at` writes a time."""
    names = list(dict.fromkeys(name for name, _ in readings))
    low, high = min(t for _, t in readings), max(t for _, t in readings)
    when = at(low) if low == high else f"{at(low)} to {at(high)}"
    if len(readings) == 1:
        return Event("late", names[0], f"a reading for {when} came after its row was diagnosed", low)
    return Event("late", names[0] if len(names) == 1 else None,
                 f"{len(readings)} readings ({', '.join(names)}) for {when} came after their rows were diagnosed", low)


def _future(readings, arrival, at) -> Event:
    """One event for the readings of one message stamped past the wall clock they arrived at; `at`
    writes a time."""
    names = list(dict.fromkeys(name for name, _ in readings))
    high = max(t for _, t in readings)
    return Event("future", names[0] if len(names) == 1 else None,
                 f"a reading for {at(high)} arrived at {at(arrival)}, {high - arrival:g} s before its own time: not "
                 f"used (more than {AHEAD:g} s ahead of this computer's clock); check the clock of what stamps it",
                 high)


class Assembler:
    """Readings in, rows out (`add`, `advance`), with the events they raise; picklable, so its
    open rows and last values are saved with the diagnosis they feed."""

    def __init__(self, model, tags, grace: float | None = None, stale: float | None = None,
                 max_gap: float = 3600.0):
        self.dt = float(model.dt)
        self.outputs, self.inputs = list(model.outputs), list(model.inputs)
        self.defaults = np.asarray(model.input_defaults, float)
        self.grace = 2 * self.dt if grace is None else float(grace)
        default_stale = 10 * self.dt if stale is None else float(stale)
        self.stale_after = {name: tag.stale or default_stale for name, tag in tags.items()}
        self.max_gap = float(max_gap)
        self.next_slot = None  # the oldest slot not yet out as a row (None: no reading yet)
        self.origin = None  # the slot of the reading that started the row clock
        self.explained = False  # whether a late event has said why readings older than that one are late
        self.open = {}  # slot -> {name: value}
        self.newest = {}  # name -> the time of its newest reading
        self.last = {}  # name -> (time, value) of its reading in the newest row out that had one
        self.stale = set()
        self.gap = 0  # rows without any reading so far, up to the newest row out
        self.own_time = {name: tag.time == "source" for name, tag in tags.items()}
        self.horizon = self.grace + HORIZON * self.dt
        self.watermark = -math.inf  # the newest reading's time
        self.wall = True  # every reading so far took its arrival time: the wall clock may close rows
        self.ahead = []  # messages held ahead of the stream, [[(name, value, time)]], in a row
        self.iso = False  # the source writes its times as clock times (ISO 8601 text, OPC UA's stamps)
        self.held = False  # the source is disconnected or catching up: rows leave only when complete

    @property
    def holding(self) -> bool:
        """Whether rows are held now: while the monitor says so, in a stream whose readings carry their
        own times."""
        return self.held and not self.wall

    def hold(self):
        """The source is disconnected, or has just connected and may still deliver readings for rows
        the stream has passed: rows leave only when complete until `release`."""
        self.held = True

    def release(self):
        """The source has caught up: rows leave by the grace again; the rows and events that are due."""
        self.held = False
        return self._close() if self.next_slot is not None else ([], [])

    @property
    def times(self) -> TimeFormat:
        """How the source writes its rows' times: clock times where it writes them so or its readings
        take their arrival's (ISO 8601, UTC), else seconds."""
        return CLOCK if self.iso or self.wall else TimeFormat()

    def at(self, time: float) -> str:
        """A time as the source writes it, for events: ISO 8601 (UTC) where it writes clock times or
        the readings take their arrival's, else seconds in full ('1583752474 s', not '1.58375e+09 s')."""
        return clock_time(time) if self.iso or self.wall else f"{time!r}".removesuffix(".0") + " s"

    def add(self, readings, arrival: float | None = None):
        """The readings of one message, [(name, value, its own time or None)], taken in together, and
        the wall-clock time it arrived (None: not known; each reading then carries its time); the rows
        and events they complete: (rows, events). A time is seconds, or a datetime where the source
        writes clock times."""
        if any(isinstance(stamp, datetime) for _, _, stamp in readings):
            self.iso = True
            readings = [(name, value, stamp.timestamp() if isinstance(stamp, datetime) else stamp)
                        for name, value, stamp in readings]
        own = [stamp is not None and self.own_time[name] for name, _, stamp in readings]
        self.wall &= not any(own)
        events, late, future, ahead, taken, bare = [], [], [], [], False, []
        for (name, value, stamp), mine in zip(readings, own):
            time = stamp if mine else arrival
            if not mine and self.own_time[name] and not self.wall:
                bare.append(name)
            elif arrival is not None and time > arrival + AHEAD:
                future.append((name, time))
            elif self.next_slot is not None and round(time / self.dt) < self.next_slot:
                late.append((name, time))
            elif self.next_slot is not None and not self.wall and time > self.watermark + self.horizon:
                ahead.append((name, value, time))
            else:
                events += self._take(name, value, time)
                taken = True
        if bare:
            events.append(Event("malformed", bare[0] if len(bare) == 1 else None,
                                f"a reading of {', '.join(bare)} without a time of its own, in a stream whose "
                                "readings carry theirs: not used (publish {\"t\": ..., \"v\": ...}, or set "
                                "time = \"arrival\" for the tag in the tag file)"))
        if future:
            events.append(_future(future, arrival, self.at))
        if taken and self.holding:
            events += self._reached()
        elif taken:
            self.ahead = []  # the stream goes on where it was: what was held ahead of it was not followed
        if ahead:
            events += self._ahead(ahead)
        rows, closing = self._close() if self.next_slot is not None else ([], [])
        return rows, ([self._late(late)] if late else []) + events + closing

    def _late(self, readings) -> Event:
        """The event of a message's late readings; the first that are older than the reading that
        started the row clock say, once, why and what to do (a source that sends its current value
        first, as an OPC UA server does on connecting, then the plant's readings stamped before it)."""
        event = _late(readings, self.at)
        if self.explained or min(t for _, t in readings) >= self.origin * self.dt:
            return event
        self.explained = True
        return dataclasses.replace(event, detail=event.detail + (
            f"; they are older than the first reading of the run (for {self.at(self.origin * self.dt)}), which "
            "started its row clock, and none older is ever diagnosed. If the source sent a current value first "
            "(an OPC UA server does on connecting) and the plant's readings are stamped before it, correct the "
            "clock of what stamps them, or read the tags at their arrival (time = \"arrival\" in the tag file) "
            "and start a new run (--new-run)"))

    def _ahead(self, readings):
        """Hold a message's readings that are ahead of the stream; once FOLLOWED messages in a row are,
        within the horizon of each other, take them all in: the stream has moved on."""
        low = min(t for _, _, t in readings)
        if self.ahead and abs(low - max(t for message in self.ahead for _, _, t in message)) > self.horizon:
            self.ahead = []  # not the same place: what was held is not followed by this one
        self.ahead.append(readings)
        if len(self.ahead) < FOLLOWED:
            names = list(dict.fromkeys(name for name, _, _ in readings))
            return [Event("ahead", names[0] if len(names) == 1 else None,
                          f"{'readings' if len(readings) > 1 else 'a reading'} for {self.at(low)} came "
                          f"{low - self.watermark:g} s ahead of the stream (its newest reading is for "
                          f"{self.at(self.watermark)}): held, and used "
                          f"{'once the stream catches up with it, or ' if self.holding else 'only '}if "
                          f"{FOLLOWED - 1} more messages follow it there", low)]
        held, self.ahead = self.ahead, []
        start = min(t for _, _, t in held[0])
        events = [Event("jump", None, f"{len(held)} messages in a row came ahead of the stream: it moved on from "
                                      f"{self.at(self.watermark)} to {self.at(start)}, and their readings are used",
                        low)]
        for message in held:
            for reading in message:
                events += self._take(*reading)
        return events

    def _reached(self):
        """While rows are held: take in the messages held ahead that the stream has come within the
        horizon of (a source catching up sends its readings of the moment before those it kept)."""
        events = []
        while self.ahead and min(t for _, _, t in self.ahead[0]) <= self.watermark + self.horizon:
            for reading in self.ahead.pop(0):
                events += self._take(*reading)
        return events

    def _take(self, name, value, time):
        slot = round(time / self.dt)
        if self.next_slot is None:
            self.next_slot = self.origin = slot
        events = []
        newest = self.newest.get(name, -math.inf)
        if time < newest:
            events.append(Event("out_of_order", name, f"a reading for {self.at(time)} came after one for "
                                                     f"{self.at(newest)}", time))
        values = self.open.setdefault(slot, {})
        if name in values:
            return events + [Event("duplicate", name, f"a second reading for {self.at(time)} (the first stands)",
                                             time)]
        values[name] = value
        self.newest[name] = max(newest, time)
        self.watermark = max(self.watermark, time)
        return events

    def advance(self, now: float):
        """The wall clock moved on to `now` without readings; the rows that are due by it, when the
        readings are stamped with their arrival (otherwise only readings move the clock)."""
        if not self.wall or self.next_slot is None:
            return [], []
        self.watermark = max(self.watermark, now)
        return self._close()

    def _close(self):
        rows, events = [], []
        while True:
            slot = self.next_slot
            values = self.open.get(slot)
            if not self._complete(slot, values) and (self.holding or self.watermark < slot * self.dt + self.grace):
                return rows, events
            if values is None:
                later = [s for s in self.open if s > slot]
                if later and (min(later) - slot) * self.dt > self.max_gap:
                    self.next_slot = min(later)
                    events.append(Event("gap", None, f"no readings for {(self.next_slot - slot) * self.dt:g} s from "
                                                     f"{self.at(slot * self.dt)}: longer than the longest gap filled "
                                                     f"({self.max_gap:g} s), so its rows are not diagnosed",
                                        slot * self.dt))
                    continue
                self.gap += 1
            elif self.gap:
                start = (slot - self.gap) * self.dt
                events.append(Event("gap", None, f"no readings for {self.gap * self.dt:g} s from {self.at(start)}: "
                                                 f"{self.gap} rows of missing readings", start))
                self.gap = 0
            self.open.pop(slot, None)
            self.next_slot = slot + 1
            row, stale = self._row(slot, values or {})
            rows.append(row)
            events += stale

    def _complete(self, slot, values) -> bool:
        return values is not None and all(n in values for n in self.outputs) and all(
            n in values or self._quiet(n, slot) for n in self.inputs)

    def _quiet(self, name, slot) -> bool:
        """An input that holds a value and was not read in the previous row either: published on
        change, so its row need not wait for it (one read every sample is waited for)."""
        last = self.last.get(name)
        return self._held(name, slot) is not None and last[0] < (slot - 1) * self.dt

    def _held(self, name, slot):
        """An input's last value, while it is not stale at this slot."""
        last = self.last.get(name)
        if last is None or slot * self.dt - last[0] > self.stale_after[name]:
            return None
        return last[1]

    def _row(self, slot, values):
        time, events = slot * self.dt, []
        for name in self.outputs + self.inputs:
            last = self.last.get(name)
            if name in values:
                if name in self.stale:
                    self.stale.discard(name)
                    events.append(Event("fresh", name, f"read again at {self.at(time)}", time))
            elif name not in self.stale and last is not None and time - last[0] > self.stale_after[name]:
                self.stale.add(name)
                events.append(Event("stale", name, f"no reading since {self.at(last[0])}; missing from "
                                                        f"{self.at(time)}", time))
        y = np.array([values.get(n, math.nan) for n in self.outputs])
        u = np.array([values[n] if n in values else _or_nan(self._held(n, slot)) for n in self.inputs])
        u = with_defaults(u, self.defaults)
        self.last.update((name, (time, value)) for name, value in values.items())
        return Row(slot, time, y, u, None), events


def _or_nan(value):
    return math.nan if value is None else value
