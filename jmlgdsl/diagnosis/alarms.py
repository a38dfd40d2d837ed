"""Alarm rules: turn a filter's mode posterior into a causal 0/1 alarm series, in batch or on a stream.

An alarm is raised at step t when the probability of the non-healthy modes, P(not healthy), has been
above the threshold at each of the k steps t-k+1..t. The rule only looks back, so the same series comes
out whether a whole posterior is given at once (`AlarmRule.alarms`) or row by row (`AlarmStream.step`).
"""

from __future__ import annotations

import dataclasses
import time
from collections import deque
from dataclasses import dataclass

import numpy as np

from ..errors import DataError
from ..infer.algorithms import NAMER_ALGORITHM
from ..names import suggest


# Rows the namer of a detect-then-name run is given before an alarm's first row, and follows after
# its last: its mode posterior forgets its prior within a few rows of a fault's data (a Tennessee
# Eastman bank's names are the same from 10 rows up, on its training recordings).
WARM_UP = 20


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
        """(T,) 0/1 alarms of a (T, K) posterior: 1 at t when P(not healthy) > threshold at each of the
        steps t-k+1..t. A (T, n, K) posterior (n units side by side) gives each unit's (T, n)."""
        above = self.fault_probability(posterior, modes) > self.threshold
        steps = np.arange(len(above)).reshape(-1, *[1] * (above.ndim - 1))
        last_below = np.maximum.accumulate(np.where(above, -1, steps), axis=0)
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

    def step(self, posterior_row, fault: float | None = None) -> int:
        """The alarm (0/1) for the newest step, given its (K,) mode posterior; `fault` is its posterior
        mass of the faulty modes where that is known already (a fleet sums every unit's in one call,
        `AlarmRule.fault_probability`: the same sums)."""
        if fault is None:
            fault = _fault_probability(posterior_row, self.faulty)
        above = fault > self.rule.threshold
        self.run = self.run + 1 if above else 0
        self.raised += self.run == self.rule.persistence
        return int(self.run >= self.rule.persistence)


def _fault_probability(posterior, faulty: np.ndarray):
    """The posterior mass of the faulty modes, row by row (the same sums in batch and on a stream)."""
    return np.asarray(posterior, dtype=float)[..., faulty].sum(axis=-1)


def sub_bank(model, modes):
    """The Model restricted to some of its modes (names, kept in the model's order): their matrices,
    the transitions among them with each row renormalised (a mode that only ever left for the others
    stays), and the prior renormalised (uniform when it gives them nothing). How `run --detect`
    splits one bank into a detector and a namer."""
    index = sorted({model.mode_index(name) for name in modes})
    P = model.P[np.ix_(index, index)]
    sums = P.sum(axis=1, keepdims=True)
    p0 = model.p0[index]
    per_mode = ("A", "B", "C", "D", "F", "G", "f", "g", "mu0")
    return model.replace(**{key: getattr(model, key)[index] for key in per_mode},
                         P=np.where(sums > 0, P / np.where(sums > 0, sums, 1.0), np.eye(len(index))),
                         p0=p0 / p0.sum() if p0.sum() > 0 else np.full(len(index), 1.0 / len(index)),
                         modes=tuple(model.modes[k] for k in index),
                         descriptions={model.modes[k]: model.descriptions[model.modes[k]] for k in index
                                       if model.modes[k] in model.descriptions})


def catch_alls(model, healthy) -> list[str]:
    """The modes that are a healthy mode with every noise scaled up by one factor above 1, as `like
    HEALTHY { noise scale S }` writes a catch-all (`jmlgdsl learn` adds one): the same dynamics,
    inputs, offsets and start, B and D times S. With a healthy mode it makes a detector that no
    fault mode has to be right for, which `run` uses by itself when the bank also has fault modes."""
    same = ("A", "F", "f", "C", "G", "g", "mu0")
    found = []
    for j, mode in enumerate(model.modes):
        for h in (model.mode_index(name) for name in healthy):
            if mode in healthy or not all(np.array_equal(getattr(model, k)[j], getattr(model, k)[h]) for k in same):
                continue
            noise = np.concatenate([model.B[h].ravel(), model.D[h].ravel()])
            scaled = np.concatenate([model.B[j].ravel(), model.D[j].ravel()])
            big = np.argmax(np.abs(noise))
            factor = scaled[big] / noise[big] if noise[big] else np.nan
            if factor > 1 and np.allclose(scaled, factor * noise, rtol=1e-9, atol=0.0):
                found.append(mode)
                break
    return found


class DetectThenName:
    """Detect, then name, in one run over one bank: the alarm comes from the `detect` modes (default:
    the whole bank) as the rule says, and while it is up each row is named by the most probable of
    the `name` modes (default: the modes outside `detect`), the fault modes, filtered on their own.

    The namer follows the rows only around alarms: it starts when an alarm rises, from its prior at
    the WARM_UP rows before (kept while it rests), and rests again once the alarm has been down for
    WARM_UP rows. In normal operation it costs nothing (a bank of many fault modes over many states
    costs far more a row than its detector); what it names is what a namer filtering every row
    names, to the few rows its mode posterior needs to forget where it started.

    A bank of fault modes alone puts some fault on top in normal operation too, so it cannot raise
    the alarm; a detector (a healthy mode against a catch-all such as `like normal { noise scale 3
    }`, or the whole bank with its healthy and fault modes) need not name anything right. Each keeps
    to what it is good at. `detector` and `namer` are the two sub-banks (`sub_bank`); `rows(source)`
    passes the rows on to the detector's Diagnosis, its truth as a 0/1 anomaly (true mode not
    healthy), and keeps each row's true mode for the naming scores; the object is then a sink of that
    Diagnosis: `collect` steps the namer's Filter on each finished row it follows and names the row
    when its alarm is up. The detector's Filter is the one `options` (jmlgdsl.diagnosis.Options) say;
    the namer's is NAMER_ALGORITHM, without a lag. The healthy modes are the rule's (None: the first
    mode). `steps` and `seconds` count the namer's work.
    """

    def __init__(self, model, detect, name, options):
        healthy = options.healthy or model.modes[:1]
        detect = list(dict.fromkeys(detect or model.modes))
        name = list(dict.fromkeys(name or [m for m in model.modes if m not in detect]))
        for option, given in (("--detect", detect), ("--name", name)):
            unknown = [m for m in given if m not in model.modes]
            if unknown:
                raise DataError(f"{option}: unknown mode {unknown[0]!r}{suggest(unknown[0], model.modes)}")
        if not set(healthy) <= set(detect) or set(detect) <= set(healthy):
            raise DataError("--detect: the detecting modes must hold the healthy ones and at least one other")
        if not name or set(name) & set(healthy):
            raise DataError("--name: the naming modes are fault modes: at least one, and none of the healthy ones")
        self.whole = model
        self.detector = sub_bank(model, detect)
        self.namer = sub_bank(model, name)
        self.faults = np.array([self.namer.modes.index(m) if m in self.namer.modes else -1
                                for m in model.modes])  # the whole bank's mode index -> fault index (-1: none)
        self.healthy = np.array([m in healthy for m in model.modes])
        self.options = dataclasses.replace(options, algorithm=NAMER_ALGORITHM, particles=None, lag=0)
        self.filter = None  # the namer's Filter while it follows the rows
        self._recent = deque(maxlen=WARM_UP)  # the last rows (y, u), to start the namer from
        self._quiet = 0  # rows since the alarm was last up
        self._truth = deque()  # the true mode of each row passed on and not yet collected
        self.true, self.named = [], []
        self.steps, self.seconds = 0, 0.0

    def rows(self, rows):
        """The rows for the detector: the true mode taken out (its indices are the whole bank's),
        the truth left as a 0/1 anomaly label."""
        for row in rows:
            self._truth.append(row.mode)
            anomaly = row.anomaly
            if anomaly is None and row.mode is not None:
                anomaly = int(not self.healthy[row.mode])
            yield dataclasses.replace(row, mode=None, anomaly=anomaly)

    def collect(self, done):
        """Step the namer on a finished row of the detector (starting it at an alarm from the rows
        before, resting it after one); name the row when its alarm is up."""
        truth = self._truth.popleft()
        self.true.append(-1 if truth is None else int(self.faults[truth]))
        self._recent.append((done.row.y, done.row.u))
        self._quiet = 0 if done.alarm else self._quiet + 1
        if self.filter is None and not done.alarm:
            self.named.append(-1)
            return
        start = time.perf_counter()
        if self.filter is None:
            self.filter = self.options.filter(self.namer)
            steps = [self.filter.step(y, u) for y, u in self._recent]
            self.steps += len(steps)
        else:
            steps = [self.filter.step(done.row.y, done.row.u)]
            self.steps += 1
        self.seconds += time.perf_counter() - start
        self.named.append(int(np.argmax(steps[-1].mode_posterior)) if done.alarm else -1)
        if self._quiet >= WARM_UP:
            self.filter = None

    def counts(self):
        """The naming scores (`metrics.NamingCounts`), or None when the data carry no true mode."""
        from .metrics import naming_counts

        if all(t < 0 for t in self.true):
            return None
        return naming_counts(self.true, self.named, self.namer.K)
