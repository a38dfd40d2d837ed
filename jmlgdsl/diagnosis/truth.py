"""Truth scoring: the alarms of a diagnosis against the truth its data carry, one path for a stream
(`Truth`, row by row, a few bytes a row) and for a whole series (`detection_scores`)."""

from __future__ import annotations

from array import array

import numpy as np

from .metrics import Scores, changepoints, score


def detection_scores(alarm, anomaly, time, changepoint=None) -> Scores:
    """Every detection score of 0/1 alarms (T,) against 0/1 anomaly labels (T,) at `time` (T,
    seconds, or one sample time); the true change points are the labels' edges unless given."""
    return score(alarm, anomaly, time, changepoints(anomaly) if changepoint is None else changepoint)


class Truth:
    """What the detection metrics need, kept row by row: the alarms, the 0/1 truth (from an
    'anomaly' column, else from the true mode and the alarm rule's healthy modes), the true change
    points and the time."""

    def __init__(self, faulty: np.ndarray, dt: float):
        self.faulty, self.dt = faulty, dt  # (K,) which true modes are anomalies
        self.alarm, self.anomaly, self.changepoint = bytearray(), bytearray(), bytearray()
        self.time = array("d")
        self.has_anomaly = self.has_changepoint = True

    def add(self, row, alarm: int, t: int):
        """Keep one data row's alarm, time and truth (t: its step, for the time when the row has none)."""
        self.alarm.append(alarm)
        self.time.append(row.time if row.time is not None else t * self.dt)
        anomaly = row.anomaly
        if anomaly is None and row.mode is not None:
            anomaly = int(self.faulty[row.mode])
        self.has_anomaly &= anomaly is not None
        self.has_changepoint &= row.changepoint is not None
        self.anomaly.append(anomaly or 0)
        self.changepoint.append(row.changepoint or 0)

    def alarms(self) -> np.ndarray:
        """(T,) the 0/1 alarms so far."""
        return np.frombuffer(self.alarm, dtype=np.uint8)

    def scores(self) -> Scores | None:
        """The detection scores, or None when the data carry no truth."""
        if not self.has_anomaly or not self.alarm:
            return None
        changepoint = np.frombuffer(self.changepoint, dtype=np.uint8) if self.has_changepoint else None
        return detection_scores(self.alarms(), np.frombuffer(self.anomaly, dtype=np.uint8), np.array(self.time),
                                changepoint)
