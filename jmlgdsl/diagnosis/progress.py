"""Progress of long work on a stream (standard error by default): a bar with the time left when the
total is known, a running count and its rate when it is not (a file read as a stream)."""

from __future__ import annotations

import sys
import time


class Progress:
    """Counts finished units of work and shows them. On a terminal the line is redrawn in place (a
    count without a total at most once a second); on any other stream a bar prints a line at every
    further 10 %, and a count without a total prints nothing (it would only fill a log). With no
    stream (None) nothing is shown."""

    def __init__(self, total=None, stream=sys.stderr, unit="runs", width=30, clock=time.perf_counter):
        self.total, self.stream, self.unit, self.width, self.clock = total, stream, unit, width, clock
        self.done, self.shown = 0, -1
        self.start = self.drawn = clock()  # drawn: when the count was last shown
        self.live = hasattr(stream, "isatty") and stream.isatty()

    def update(self, n=1):
        """Count n more finished units."""
        self.done += n
        if self.stream is None:
            return
        if self.total is None:
            if self.live and self.clock() - self.drawn >= 1.0:
                self._count()
            return
        percent = 100 * self.done // self.total
        if not self.live and percent < self.shown + 10 and self.done < self.total:
            return
        self.shown = percent
        elapsed = self.clock() - self.start
        left = elapsed * (self.total - self.done) / self.done
        bar = "#" * (self.width * self.done // self.total)
        line = (f"[{bar:<{self.width}}] {self.done}/{self.total} {self.unit}, {_clock(elapsed)} elapsed, "
                f"~{_clock(left)} left")
        self.stream.write(("\r" + line) if self.live else line + "\n")
        if self.live and self.done == self.total:
            self.stream.write("\n")
        self.stream.flush()

    def collect(self, _row):
        """Count one finished row: a Progress is a sink of a diagnosis (jmlgdsl.diagnosis)."""
        self.update()

    def close(self):
        """End a count shown on a terminal (its last line stays, finished)."""
        if self.total is None and self.live and self.drawn > self.start:
            self._count()
            self.stream.write("\n")
            self.stream.flush()

    def _count(self):
        self.drawn = now = self.clock()
        elapsed = now - self.start
        rate = self.done / elapsed if elapsed > 0 else 0.0
        self.stream.write(f"\r{self.done} {self.unit}, {_clock(elapsed)} elapsed, {rate:.0f} {self.unit}/s")
        self.stream.flush()


def _clock(seconds):
    """Seconds as minutes and seconds, e.g. 2m05s."""
    minutes, seconds = divmod(int(round(seconds)), 60)
    return f"{minutes}m{seconds:02d}s"
