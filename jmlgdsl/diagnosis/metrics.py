"""Detection metrics: the SKAB leaderboard's F1, FAR, MAR and NAB scores, episode detection rate and
delay, false alarms per hour, and the confusion matrix of diagnosed vs true modes.

Each file gives counts; counts pool across files by addition (`a + b`, `Scores.pool(files)`) and every
score is computed once from the pooled counts, as the leaderboard does, never averaged per file.
Series are 0/1 arrays over the scored rows. A time axis is seconds (floats) or numpy datetime64; a
number in its place is a regular sample time in seconds.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from ..errors import DataError
from ..names import plural

WINDOW = 60.0  # seconds: the NAB window to the right of each true change point (SKAB leaderboard)


def _ratio(num, den) -> float:
    """num / den as a float, NaN when the denominator is 0 (the score is undefined, not 0)."""
    return float(num) / den if den else float("nan")


def _statistic(function, values) -> float:
    """A statistic of some values as a float, NaN when there are none."""
    return float(function(values)) if len(values) else float("nan")


def _binary(series, name: str) -> np.ndarray:
    """A 1-D 0/1 series as int8; anything else is a DataError."""
    series = np.asarray(series, dtype=float)
    if series.ndim != 1 or not np.isin(series, (0.0, 1.0)).all():
        raise DataError(f"{name} must be a 1-D series of 0 and 1")
    return series.astype(np.int8)


def _pair(pred, truth, pred_name: str, truth_name: str):
    """Two 0/1 series of the same length."""
    pred, truth = _binary(pred, pred_name), _binary(truth, truth_name)
    if len(pred) != len(truth):
        raise ValueError(f"{pred_name} has {plural(len(pred), 'row')}, {truth_name} {len(truth)}")
    return pred, truth


def seconds(time, T: int) -> np.ndarray:
    """(T,) time axis in seconds from a seconds or datetime64 axis, or from a sample time (t = i * dt)."""
    if np.ndim(time) == 0:
        return np.arange(T) * float(time)
    time = np.asarray(time)
    if time.shape != (T,):
        raise ValueError(f"the time axis has shape {time.shape}, the series {T} rows")
    if np.issubdtype(time.dtype, np.datetime64):
        time = (time - time[:1]) / np.timedelta64(1, "s")
    t = time.astype(float)
    back = np.flatnonzero(np.diff(t) < 0)
    if len(back):
        i = int(back[0]) + 1
        raise DataError(f"the time axis goes backwards at row {i + 1} of {T} ({t[i - 1]:g} s then {t[i]:g} s)")
    return t


def monitored(time, T: int) -> float:
    """Seconds monitored: T * dt for a sample time; a time axis's span plus one median step, gaps
    included (0 for a single time stamp)."""
    if np.ndim(time) == 0:
        return T * float(time)
    t = seconds(time, T)
    return float(t[-1] - t[0] + np.median(np.diff(t))) if T > 1 else 0.0


def runs(series) -> np.ndarray:
    """(n, 2) start and end (exclusive) rows of each maximal run of 1s in a 0/1 series."""
    edges = np.diff(np.concatenate(([0], np.asarray(series, dtype=np.int8), [0])))
    return np.column_stack((np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)))


def changepoints(anomaly) -> np.ndarray:
    """Predicted change points from a 0/1 anomaly series as SKAB derives them: every rising and falling
    edge, cp[t] = |a[t] - a[t-1]|, and cp[0] = a[0] at the first scored row."""
    a = _binary(anomaly, "anomaly")
    return np.abs(np.diff(a, prepend=np.int8(0))).astype(np.int8)


def _first_within(points, lo, hi):
    """For each interval [lo_i, hi_i] (both inclusive), whether any of the sorted points lies in it,
    and the earliest such point for the intervals that have one."""
    first = np.searchsorted(points, lo)
    hit = first < len(points)
    hit[hit] = points[first[hit]] <= hi[hit]
    return hit, points[first[hit]]


class Pooled:
    """Counts of one file or many: `a + b` adds each field (tuples concatenate); `pool` sums a list."""

    def __add__(self, other):
        return type(self)(*(getattr(self, f.name) + getattr(other, f.name) for f in fields(self)))

    @classmethod
    def pool(cls, items):
        """The counts of several files pooled into one."""
        total = cls()
        for item in items:
            total = total + item
        return total


@dataclass(frozen=True)
class OutlierCounts(Pooled):
    """Row counts of the 0/1 alarm against the 0/1 anomaly label (SKAB's outlier problem)."""

    tp: int = 0
    fp: int = 0
    tn: int = 0
    fn: int = 0

    @property
    def f1(self) -> float:
        """F1 = TP / (TP + (FP + FN) / 2)."""
        return _ratio(self.tp, self.tp + (self.fp + self.fn) / 2)

    @property
    def far(self) -> float:
        """False-alarm rate, % of normal rows alarmed: 100 FP / (FP + TN)."""
        return _ratio(100 * self.fp, self.fp + self.tn)

    @property
    def mar(self) -> float:
        """Missed-alarm rate, % of anomalous rows not alarmed: 100 FN / (FN + TP)."""
        return _ratio(100 * self.fn, self.fn + self.tp)


def outlier_counts(alarm, anomaly) -> OutlierCounts:
    """TP, FP, TN, FN of a 0/1 alarm series against 0/1 anomaly labels, row by row."""
    alarm, anomaly = _pair(alarm, anomaly, "alarm", "anomaly")
    pos, neg = alarm == 1, alarm == 0
    return OutlierCounts(int((pos & (anomaly == 1)).sum()), int((pos & (anomaly == 0)).sum()),
                         int((neg & (anomaly == 0)).sum()), int((neg & (anomaly == 1)).sum()))


@dataclass(frozen=True)
class EventCounts(Pooled):
    """Anomaly episodes (runs of anomalous rows) detected and when, false alarms, time monitored."""

    episodes: int = 0
    detected: int = 0
    false_alarms: int = 0
    duration: float = 0.0  # seconds monitored
    delays: tuple = ()  # seconds from each detected episode's first row to its first alarmed row

    @property
    def detection_rate(self) -> float:
        """% of anomaly episodes with at least one alarmed row."""
        return _ratio(100 * self.detected, self.episodes)

    @property
    def mean_delay(self) -> float:
        """Mean detection delay over the detected episodes, seconds."""
        return _statistic(np.mean, self.delays)

    @property
    def median_delay(self) -> float:
        """Median detection delay over the detected episodes, seconds."""
        return _statistic(np.median, self.delays)

    @property
    def false_alarms_per_hour(self) -> float:
        """False alarms per hour monitored."""
        return _ratio(3600 * self.false_alarms, self.duration)


def event_counts(alarm, anomaly, time) -> EventCounts:
    """Episodes detected, their delays and the false alarms of a 0/1 alarm series against 0/1 labels.

    An episode is detected when an alarm is on at any of its rows; its delay runs from its first row to
    the first alarmed row within it (0 for an alarm already on). A false alarm is a run of alarmed rows
    that touches no anomalous row. The time monitored is as `monitored` says.
    """
    alarm, anomaly = _pair(alarm, anomaly, "alarm", "anomaly")
    t = seconds(time, len(alarm))
    episodes = runs(anomaly)
    hit, first = _first_within(np.flatnonzero(alarm), episodes[:, 0], episodes[:, 1] - 1)
    delays = t[first] - t[episodes[hit, 0]]
    anomalous = np.concatenate(([0], np.cumsum(anomaly)))
    false_alarms = sum(anomalous[end] == anomalous[start] for start, end in runs(alarm))
    return EventCounts(len(episodes), len(delays), int(false_alarms), monitored(time, len(alarm)),
                       tuple(delays.tolist()))


@dataclass(frozen=True)
class NabProfile:
    """The NAB weights of a true positive, a false positive and a false negative."""

    a_tp: float
    a_fp: float
    a_fn: float

    def sigmoid(self, e) -> np.ndarray:
        """The TP score at event index e = 0..999 across the window: A_tp at its left end, A_fp at 999."""
        x = -np.pi / 2 + np.asarray(e) * np.pi / 999
        half = (self.a_tp - self.a_fp) / 2
        return half * (-np.tanh(x) / np.tanh(np.pi / 2)) + half + self.a_fp


PROFILES = {
    "standard": NabProfile(1.0, -0.11, -1.0),
    "lowfp": NabProfile(1.0, -0.22, -1.0),
    "lowfn": NabProfile(1.0, -0.11, -2.0),
}


@dataclass(frozen=True)
class NabCounts(Pooled):
    """NAB windows, false positives, and the event index and delay of each detected window."""

    windows: int = 0
    fp: int = 0
    events: tuple = ()  # floor((p - l) / (r - l) * 1000), capped at 999, of each TP
    delays: tuple = ()  # p - l, seconds, of each TP

    @property
    def missed(self) -> int:
        """Windows with no predicted change point in them (false negatives)."""
        return self.windows - len(self.events)

    def score(self, profile: str | NabProfile = "standard") -> float:
        """NAB = 100 (S - S_null) / (S_perfect - S_null), unrounded (the leaderboard prints 2 decimals)."""
        w = PROFILES[profile] if isinstance(profile, str) else profile
        raw = w.a_fp * self.fp + w.a_fn * self.missed + float(np.sum(w.sigmoid(list(self.events))))
        null, perfect = self.windows * w.a_fn, self.windows * w.a_tp
        return _ratio(100 * (raw - null), perfect - null)

    @property
    def mean_delay(self) -> float:
        """Mean of p - l over the detected windows, seconds (the leaderboard's detection delay)."""
        return _statistic(np.mean, self.delays)


def nab_windows(changepoint, time, window: float = WINDOW) -> np.ndarray:
    """(n, 2) windows [l, r] in seconds after each true change point c: r = c + window, and overlaps cut
    in time order so that l_i = max(c_i, c_(i-1) + window). Windows are not clipped at the file's end."""
    cp = _binary(changepoint, "changepoint")
    c = seconds(time, len(cp))[cp == 1]
    return np.column_stack((np.maximum(c, np.concatenate(([-np.inf], c[:-1])) + window), c + window))


def nab_counts(cp_pred, changepoint, time, window: float = WINDOW) -> NabCounts:
    """Score predicted change points (0/1, e.g. `changepoints(alarm)`) against true ones, as SKAB does.

    Each window [l, r] (both ends inclusive) is a TP at its earliest predicted point p, else a miss;
    other points inside windows count for nothing; a point inside no window is an FP. A point on a
    shared boundary r_i = l_(i+1) thus detects both windows and is never an FP.
    """
    cp_pred, changepoint = _pair(cp_pred, changepoint, "predicted change points", "changepoint")
    lr = nab_windows(changepoint, time, window)
    p = seconds(time, len(cp_pred))[cp_pred == 1]
    hit, at = _first_within(p, lr[:, 0], lr[:, 1])
    l, r = lr[hit, 0], lr[hit, 1]
    width = np.where(r > l, r - l, 1.0)  # a window cut to one instant: its only point is its left end
    events = np.minimum(np.floor((at - l) / width * 1000), 999).astype(int)
    inside = ((lr[:, 0] <= p[:, None]) & (p[:, None] <= lr[:, 1])).any(axis=1)
    return NabCounts(len(lr), int((~inside).sum()), tuple(events.tolist()), tuple((at - l).tolist()))


def switch_delays(diagnosed_modes, true_modes, lag: int | None = 0) -> np.ndarray:
    """For each true mode switch: steps from the switch to the first row diagnosed as the new mode
    (the rest of its segment when none is), plus the lag a smoothed row is reported after."""
    diagnosed_modes, true_modes = np.asarray(diagnosed_modes), np.asarray(true_modes)
    switches = np.flatnonzero(true_modes[1:] != true_modes[:-1]) + 1
    ends = np.r_[switches[1:], len(true_modes)]
    delays = []
    for start, end in zip(switches, ends):
        found = np.flatnonzero(diagnosed_modes[start:end] == true_modes[start])
        delays.append((found[0] if len(found) else end - start) + (lag or 0))
    return np.array(delays, dtype=float)


def confusion(true_modes, diagnosed_modes, K: int) -> np.ndarray:
    """(K, K) counts of steps whose true mode is i and diagnosed mode is j, at [i, j]."""
    true_modes, diagnosed_modes = np.asarray(true_modes, dtype=int), np.asarray(diagnosed_modes, dtype=int)
    if true_modes.shape != diagnosed_modes.shape:
        raise ValueError(f"{true_modes.shape} true modes against {diagnosed_modes.shape} diagnosed")
    if ((true_modes < 0) | (true_modes >= K) | (diagnosed_modes < 0) | (diagnosed_modes >= K)).any():
        raise ValueError(f"mode indices must lie in 0..{K - 1}")
    return np.bincount(true_modes * K + diagnosed_modes, minlength=K * K).reshape(K, K)


@dataclass(frozen=True)
class Scores(Pooled):
    """Everything scored for one file, or pooled over many."""

    outlier: OutlierCounts = OutlierCounts()
    events: EventCounts = EventCounts()
    nab: NabCounts = NabCounts()

    def summary(self) -> dict:
        """The scores by name, unrounded (NaN where undefined, e.g. NAB without change-point labels)."""
        return {
            "f1": self.outlier.f1, "far": self.outlier.far, "mar": self.outlier.mar,
            **{f"nab_{name}": self.nab.score(name) for name in PROFILES},
            "missed_cp": self.nab.missed, "fp": self.nab.fp, "nab_mean_delay": self.nab.mean_delay,
            "detection_rate": self.events.detection_rate, "mean_delay": self.events.mean_delay,
            "median_delay": self.events.median_delay,
            "false_alarms_per_hour": self.events.false_alarms_per_hour,
        }


def score(alarm, anomaly, time, changepoint=None, window: float = WINDOW) -> Scores:
    """All the scores of one file's 0/1 alarm series against its labels; NAB only with change points."""
    nab = NabCounts() if changepoint is None else nab_counts(changepoints(alarm), changepoint, time, window)
    return Scores(outlier_counts(alarm, anomaly), event_counts(alarm, anomaly, time), nab)


@dataclass(frozen=True)
class NamingCounts:
    """How the rows of each true fault were named: `confusion` (F, F + 1) counts rows whose true
    mode is fault i and which were named fault j, the last column the rows not named (no alarm up).
    Counts pool by addition, as the other scores do."""

    confusion: np.ndarray

    def __add__(self, other: "NamingCounts") -> "NamingCounts":
        return NamingCounts(self.confusion + other.confusion)

    @property
    def rows(self) -> np.ndarray:
        """(F,) the rows of each true fault."""
        return self.confusion.sum(axis=1)

    @property
    def right(self) -> np.ndarray:
        """(F,) the rows of each true fault named right."""
        return np.diag(self.confusion[:, :-1])

    @property
    def accuracy(self) -> np.ndarray:
        """(F,) % of each fault's rows named right (NaN for a fault with no rows)."""
        return np.array([_ratio(100 * r, n) for r, n in zip(self.right, self.rows)])

    @property
    def alarmed_accuracy(self) -> np.ndarray:
        """(F,) % of each fault's rows named right among those named (the alarm up)."""
        return np.array([_ratio(100 * r, n) for r, n in zip(self.right, self.rows - self.confusion[:, -1])])

    @property
    def overall(self) -> float:
        """% of every fault's rows, together, named right."""
        return _ratio(100 * self.right.sum(), self.rows.sum())


def naming_counts(true_faults, named, F: int) -> NamingCounts:
    """The naming of rows whose true fault index is in 0..F-1 (other rows, e.g. normal ones, given as
    -1, are left out) by the named fault index, -1 where none was named."""
    true_faults, named = np.asarray(true_faults, dtype=int), np.asarray(named, dtype=int)
    if true_faults.shape != named.shape:
        raise ValueError(f"{true_faults.shape} true faults against {named.shape} named")
    if (true_faults >= F).any() or (named >= F).any() or (named < -1).any():
        raise ValueError(f"fault indices must lie in 0..{F - 1} (or -1)")
    scored = true_faults >= 0
    column = np.where(named[scored] < 0, F, named[scored])
    return NamingCounts(np.bincount(true_faults[scored] * (F + 1) + column, minlength=F * (F + 1)).reshape(F, F + 1))
