"""Pseudo-random binary sequences from maximal-length shift registers, for identification experiments.

A register of n cells whose feedback is the XOR of the tap cells below runs through all 2^n - 1
non-zero states, so its output bit repeats with period 2^n - 1 and its longest run of equal bits is
n clocks: that run must outlast the plant's settling time for the data to show the steady-state gain.
"""

from __future__ import annotations

import warnings

import numpy as np

from ..errors import JmlgError

#: Feedback cells (1-based) of a maximal-length register for each length 2..20.
TAPS = {
    2: (2, 1), 3: (3, 2), 4: (4, 3), 5: (5, 3), 6: (6, 5), 7: (7, 6), 8: (8, 6, 5, 4), 9: (9, 5),
    10: (10, 7), 11: (11, 9), 12: (12, 11, 10, 4), 13: (13, 12, 11, 8), 14: (14, 13, 12, 2),
    15: (15, 14), 16: (16, 15, 13, 4), 17: (17, 14), 18: (18, 11), 19: (19, 18, 17, 14), 20: (20, 17),
}


def period(cells: int) -> int:
    """Length in clocks of one period of the sequence from `cells` cells."""
    return 2 ** cells - 1


def mls(cells: int) -> np.ndarray:
    """One period of the maximal-length sequence of a `cells`-cell register started at all ones (0/1 bits)."""
    if cells not in TAPS:
        raise JmlgError(f"shift-register length must be between 2 and 20 cells, not {cells}")
    state = (1 << cells) - 1  # bit i-1 holds cell i
    mask = sum(1 << (tap - 1) for tap in TAPS[cells])
    bits = np.empty(period(cells), dtype=np.int8)
    for i in range(len(bits)):
        bits[i] = (state >> (cells - 1)) & 1
        feedback = (state & mask).bit_count() & 1
        state = ((state << 1) | feedback) & ((1 << cells) - 1)
    return bits


def prbs(cells: int, clock: int = 1, amplitude: float = 1.0, around: float = 0.0, periods: int = 1,
         samples: int | None = None) -> np.ndarray:
    """Input signal: each register bit held for `clock` samples, mapped to around ± amplitude.

    Whole periods by default; `samples` cuts or repeats the sequence to an exact length instead.
    """
    if min(clock, periods, 1 if samples is None else samples) < 1:
        raise JmlgError("clock, periods and samples must be at least 1")
    one = np.repeat(mls(cells), clock)
    n = samples if samples is not None else periods * len(one)
    bits = np.resize(one, n)
    return around + amplitude * (2.0 * bits - 1.0)


def longest_pulse(cells: int, clock: int = 1) -> int:
    """Samples in the longest constant stretch of the signal (a run of `cells` equal bits)."""
    return cells * clock


def warn_if_short(cells: int, clock: int, dt: float, settling: float) -> bool:
    """Warn (and return True) when no pulse lasts the settling time, in seconds."""
    longest = longest_pulse(cells, clock) * dt
    if longest < settling:
        warnings.warn(f"the longest pulse lasts {longest:g} s, shorter than the settling time "
                      f"{settling:g} s: use more cells or a slower clock", stacklevel=2)
        return True
    return False
