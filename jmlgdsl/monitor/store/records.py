"""What the store takes and gives back, as values that say nothing of how it keeps them: a run, an
alarm and an operator's action, a row as assembled (`Sample`), a finished row as the page shows it
(`Finished`) and what it concludes (`Verdict`), a run's part of a commit, and the state it was saved
with."""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ...data import TimeFormat

TIMES = "times"  # the key of a run's options that records how its source writes times (TimeFormat)
ACTIONS = ("acknowledge", "shelve", "unshelve")
LONGEST = {"who": 100, "reason": 1000}  # characters of an action's name of who acts, and of its reason
LABELS = ("mode", "anomaly", "changepoint")  # what a row may carry besides its readings


@dataclass(frozen=True)
class Run:
    """A run as the store records it."""

    id: int
    plant: str
    model_sha256: str
    options: dict
    modes: list
    states: list
    outputs: list
    inputs: list
    descriptions: dict  # mode name -> the spec's description
    engineering_units: dict  # name -> its unit of measure
    unit: str | None = None  # the unit of a fleet (None: a monitor of one plant)

    @property
    def times(self) -> TimeFormat:
        """How the run's source writes its rows' times (seconds where the run records none)."""
        return TimeFormat.from_json(self.options.get(TIMES))


@dataclass(frozen=True)
class Alarm:
    """An alarm episode with what operators did with it, in the ISA-18.2 states: active and
    unacknowledged, active and acknowledged, cleared but unacknowledged, cleared (and acknowledged:
    done), or shelved (hidden from the list of alarms to deal with, with a reason, until unshelved)."""

    id: int
    raised_t: int
    raised_time: float | None
    cleared_t: int | None
    cleared_time: float | None
    mode: str | None  # the most probable unhealthy mode when it was raised
    acknowledged: tuple | None  # (who, at) of the acknowledgement
    shelved: tuple | None  # (who, at, reason) while shelved

    @property
    def state(self) -> str:
        if self.shelved:
            return "shelved"
        return (("active" if self.cleared_t is None else "cleared") + ", "
                + ("acknowledged" if self.acknowledged else "unacknowledged"))


class Action(NamedTuple):
    """What an operator did with an alarm (one of ACTIONS), with the row its alarm was raised at."""

    id: int
    run: int
    alarm: int
    raised_t: int
    at: str  # UTC ISO time
    who: str
    kind: str
    reason: str | None


class Sample(NamedTuple):
    """A row a run diagnosed, as assembled: its time (None: none), outputs and inputs (NaN: not
    measured) and its labels (None: not labelled)."""

    t: int
    time: float | None
    y: np.ndarray
    u: np.ndarray
    mode: str | None
    anomaly: int | None
    changepoint: int | None


class Finished(NamedTuple):
    """A finished row as the operator's page shows it: its vectors as lists of numbers (NaN for a
    reading not measured), None for a column the row does not hold."""

    t: int
    time: float | None
    map_mode: str
    alarm: int
    posterior: list
    y: list
    y_pred: list
    y_sd: list | None
    evidence_mode: str | None
    evidence: list | None


class Verdict(NamedTuple):
    """What a finished row concludes: its most probable mode, every mode's probability and the alarm."""

    t: int
    time: float | None
    mode: str
    posterior: list
    alarm: int


@dataclass
class Commit:
    """What one run's part of a commit writes: samples [(t, Row)], results [(Diagnosed, predictive sd
    (ny,))], events [Event], and the state after them (rows diagnosed, the Diagnosis checkpoint, the
    monitor's own state, the source position)."""

    run: int
    samples: list
    results: list
    events: list
    rows: int
    checkpoint: bytes
    monitor: bytes | None
    position: dict | None
    times: TimeFormat | None = None  # how the source writes the rows' times, to record with the run's options


@dataclass(frozen=True)
class Saved:
    """The state a run was last committed with."""

    rows: int
    checkpoint: bytes
    monitor: bytes | None
    position: dict | None
    at: str  # when it was committed (UTC ISO time)


def row_state(plant: str, record: Run, verdict: Verdict, opened: int | None) -> dict:
    """A row's state as the sinks of the conclusions show it (jmlgdsl.monitor.sinks.outbox): `verdict` is a
    row of the run `record`, `opened` the id of the alarm open at it (None: none)."""
    return {"plant": plant, "unit": record.unit, "run": record.id, "t": verdict.t, "time": verdict.time,
            "mode": verdict.mode, "probability": verdict.posterior[record.modes.index(verdict.mode)],
            "modes": dict(zip(record.modes, verdict.posterior)), "alarm": bool(verdict.alarm), "alarm_id": opened}
