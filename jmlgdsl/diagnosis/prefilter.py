"""Pre-filters for noisy measurements, applied before diagnosis.

With very noisy signals a one-step look-ahead sees little of a mode change; a short causal moving
average restores la-RBPF's advantage (§7.3.2 of the source study). Causal means each output uses
only the readings up to now, so the same pre-filter runs on-line, row by row.
"""

from __future__ import annotations

import re
from collections import deque

import numpy as np

from ..errors import DataError

_MA = re.compile(r"^\s*ma\s*:\s*(\d+)\s*$")
MAX_WINDOW = 10_000  # readings; each row averages over the whole window


class MovingAverage:
    """Causal moving average over the last `window` readings of each output, for on-line use.

    Missing readings (NaN) are left out of the average; an output with no reading in the window
    stays missing. Before `window` rows have arrived the average runs over the rows seen so far.
    """

    def __init__(self, window: int):
        if isinstance(window, bool) or not isinstance(window, (int, np.integer)) or window < 1:
            raise DataError(f"moving-average window must be a positive whole number, got {window!r}")
        self.window = int(window)
        self._rows = deque(maxlen=self.window)

    def __call__(self, y) -> np.ndarray:
        """Push one row of readings (ny,) and return its averaged row."""
        self._rows.append(np.asarray(y, dtype=float))
        rows = np.array(self._rows)
        seen = ~np.isnan(rows)
        counts = seen.sum(axis=0)
        with np.errstate(invalid="ignore"):
            return np.where(seen, rows, 0.0).sum(axis=0) / np.where(counts, counts, np.nan)


def moving_average(y, window: int) -> np.ndarray:
    """A whole (T, ny) array through the causal moving average, exactly as on-line."""
    average = MovingAverage(window)
    y = np.asarray(y, dtype=float)
    return np.array([average(row) for row in y]).reshape(y.shape)


def parse(text: str | None) -> int | None:
    """The window of a pre-filter written "ma:K" (K readings); None or "none" means no pre-filter."""
    if text is None or text.strip().lower() in ("", "none"):
        return None
    match = _MA.match(text)
    digits = match[1].lstrip("0") if match else ""
    if not digits:
        raise DataError(f"pre-filter {text!r}: write ma:K for a moving average over K readings, e.g. ma:5")
    if len(digits) > len(str(MAX_WINDOW)) or int(digits) > MAX_WINDOW:  # no int() of a huge digit string
        raise DataError(f"pre-filter {text!r}: the window is at most {MAX_WINDOW:,} readings")
    return int(digits)
