"""Alarm rules: turn a filter's mode posterior into a causal 0/1 alarm series, in batch or on a stream.

An alarm is raised at step t when the probability of the non-healthy modes, P(not healthy), has been
above the threshold at each of the k steps t-k+1..t. The rule only looks back, so the same series comes
out whether a whole posterior is given at once (`AlarmRule.alarms`) or row by row (`AlarmStream.step`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import DataError
from ..names import suggest


@dataclass(frozen=True)
class AlarmRule:
    """Which modes count as healthy, the threshold on P(not healthy), and the persistence k >= 1 steps.

    With k > 1 the alarm starts on the k-th consecutive step above the threshold, not the first: at the
    first step an on-line monitor cannot know yet that the excursion will last, and marking the earlier
    steps afterwards would need look-ahead. The alarm ends at the first step at or below the threshold.
    """

    healthy: tuple[str, ...]
    threshold: float = 0.5
    persistence: int = 1

    def __post_init__(self):
        object.__setattr__(self, "healthy", tuple(self.healthy))
        if not self.healthy:
            raise DataError("an alarm rule needs at least one healthy mode")
        if not 0.0 <= self.threshold < 1.0:
            raise DataError(f"alarm threshold {self.threshold} is not in [0, 1)")
        if int(self.persistence) != self.persistence or self.persistence < 1:
            raise DataError(f"alarm persistence {self.persistence} is not a whole number of steps >= 1")

    def faulty_modes(self, modes) -> np.ndarray:
        """(K,) True for the modes, named in the model's order, that are not healthy."""
        modes = list(modes)
        for name in self.healthy:
            if name not in modes:
                raise DataError(f"alarm rule: unknown healthy mode {name!r}{suggest(name, modes)}")
        return np.array([name not in self.healthy for name in modes], dtype=bool)

    def fault_probability(self, posterior, modes) -> np.ndarray:
        """P(not healthy) for a (T, K) posterior (or one (K,) row): the sum over the non-healthy modes."""
        return _fault_probability(posterior, self.faulty_modes(modes))

    def alarms(self, posterior, modes) -> np.ndarray:
        """(T,) 0/1 alarms: 1 at t when P(not healthy) > threshold at each of the steps t-k+1..t."""
        above = self.fault_probability(posterior, modes) > self.threshold
        steps = np.arange(len(above))
        last_below = np.maximum.accumulate(np.where(above, -1, steps))
        return ((steps - last_below) >= self.persistence).astype(np.int8)

    def stream(self, modes) -> "AlarmStream":
        """An on-line form of this rule for a model whose modes have these names."""
        return AlarmStream(self, self.faulty_modes(modes))

    def truth(self, true_modes, modes) -> np.ndarray:
        """(T,) 0/1 labels from true mode indices: 1 where the true mode is not healthy."""
        return self.faulty_modes(modes)[np.asarray(true_modes, dtype=int)].astype(np.int8)


class AlarmStream:
    """The rule applied one posterior row at a time; gives exactly the series of `AlarmRule.alarms`."""

    def __init__(self, rule: AlarmRule, faulty: np.ndarray):
        self.rule = rule
        self.faulty = faulty
        self.run = 0  # consecutive steps so far with P(not healthy) above the threshold
        self.raised = 0  # alarms raised so far

    def step(self, posterior_row) -> int:
        """The alarm (0/1) for the newest step, given its (K,) mode posterior."""
        above = _fault_probability(posterior_row, self.faulty) > self.rule.threshold
        self.run = self.run + 1 if above else 0
        self.raised += self.run == self.rule.persistence
        return int(self.run >= self.rule.persistence)


def _fault_probability(posterior, faulty: np.ndarray):
    """The posterior mass of the faulty modes, row by row (the same sums in batch and on a stream)."""
    return np.asarray(posterior, dtype=float)[..., faulty].sum(axis=-1)
