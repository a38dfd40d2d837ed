"""`Diagnosis`: the diagnosis of a source of data rows, as one object that can be saved and resumed.

It owns everything a diagnosis accumulates: the Filter (with its fixed-lag window), the pre-filter,
the alarm rule's persistence counter, the summary, the truth scoring, the scale check and (asked
for) the evidence per sensor of the rows held back. Each finished row goes to the sinks
(`collect(row)`): a result table, a figure's record, a store.
`checkpoint()` saves that whole state as bytes and `Diagnosis.resume` restores it in any process,
which then continues bit for bit as the uninterrupted diagnosis would. The bytes hold data only
(jmlgdsl.sealed: numbers, arrays and records of the diagnosis's own classes, with a checksum), so a
checkpoint read back from a store that others can write cannot make the process run code.
"""

from __future__ import annotations

import functools
import hashlib
import json
from collections import deque
from dataclasses import dataclass

from ..sealed import SealedError, header_of, is_sealed, seal, unseal
from .alarms import AlarmRule, AlarmStream
from ..data import Row
from .evidence import Evidence
from ..errors import JmlgError
from ..infer.online import SAVED_KINDS as FILTER_KINDS
from ..infer.result import Step, Summary
from ..model import Model
from .options import Options
from .prefilter import MovingAverage
from ..version import VERSION
from .scale import ScaleCheck
from .truth import Truth

MAX_SEGMENTS = 30  # mode segments the summary lists; the rest are counted
CHECKPOINT_FORMAT = 4  # 4: a covariance graph holds its classes' representatives (shared by a fleet's units); 3: data
#                        only (jmlgdsl.sealed); 2 and before: a Python pickle, never read back
PICKLED = b"jmlgdsl-checkpoint\n"  # how a checkpoint of format 2 or before begins
# the classes a diagnosis's state is made of: the only ones reading a checkpoint back may make
SAVED_KINDS = (*FILTER_KINDS, Row, AlarmRule, AlarmStream, Evidence, MovingAverage, ScaleCheck, Truth, Summary)


class CheckpointError(JmlgError):
    """Saved state that cannot be resumed here: not a checkpoint, another model or another version."""


@dataclass(frozen=True)
class Diagnosed:
    """One finished row: the filter's record of it, the data row it came from, its alarm (0/1) and,
    when the diagnosis explains, its evidence per sensor (computed when the row was filtered)."""

    step: Step
    row: Row
    alarm: int
    evidence: Evidence | None = None


class Diagnosis:
    """Diagnose a model's data rows one at a time: `feed(row)` as rows arrive, `finish()` at the end.

    `options` (jmlgdsl.diagnosis.Options) say how: the filter and its lag, the pre-filter, the alarm
    rule and whether to explain. Sinks see every finished row, in order. `scored` keeps every row's
    alarm and truth for the detection scores (a few bytes a row); a diagnosis that runs for ever on
    data without truth (a live plant) leaves it off, so its state stays small. Explaining gives every
    finished row its evidence per sensor (jmlgdsl.diagnosis.evidence) for the most probable
    non-healthy mode of the rule against its healthy modes.
    """

    def __init__(self, model: Model, options: Options = Options(), *, scored: bool = True, sinks=()):
        self.model = model
        rule = options.rule(model)  # a rule it cannot take is refused before the filter's options
        self.filter = options.filter(model)
        self.prefilter = None if options.prefilter is None else MovingAverage(options.prefilter)
        self.rule = rule
        self.alarms = self.rule.stream(model.modes)  # an unknown healthy mode is an error before any data
        self.summary = Summary(max_segments=MAX_SEGMENTS)
        self.truth = Truth(self.alarms.faulty, model.dt) if scored else None
        self.scale = ScaleCheck(model)
        self.sinks = list(sinks)
        self.explain = options.explain
        self._held = deque()  # data rows whose records the filter still holds back (with a lag)
        self._evidence = deque()  # with explain, the evidence of the rows held back

    def feed(self, row: Row) -> list[Diagnosed]:
        """Diagnose one data row; the rows this finishes (none while a lag holds them back)."""
        step = self.filter.step(self.hold(row), row.u)
        self.heard()
        return [] if step is None else [self.finished(step)]

    # A Fleet steps many units' filters in one call: it feeds each unit's Diagnosis through these three
    # steps, as `feed` does, with the filter stepped between `hold` and `heard`.
    def hold(self, row: Row):
        """Hold a data row until its filter's record of it comes back; the readings to filter (pre-filtered)."""
        self._held.append(row)
        return row.y if self.prefilter is None else self.prefilter(row.y)

    def heard(self, evidence: Evidence | None = None):
        """The filter has stepped on the row held last: with explain, keep its evidence per sensor (given
        by a fleet's vectorised filter, else read from the filter's engine); the engine's predictive
        is then dropped, no part of the saved state."""
        engine = self.filter.engine
        if self.explain:
            self._evidence.append(Evidence.of(engine.predictive, self.alarms.faulty) if evidence is None else evidence)
        engine.predictive = None

    def finish(self) -> list[Diagnosed]:
        """The end of the data: the rows still held back, smoothed with what arrived."""
        done = [self.finished(step) for step in self.filter.flush()]
        self.scale.finish()
        return done

    def run(self, rows) -> "Diagnosis":
        """Feed every row of an iterable, then finish; returns self (for its summary and report)."""
        for row in rows:
            self.feed(row)
        self.finish()
        return self

    def finished(self, step: Step, fault: float | None = None) -> Diagnosed:
        """The filter's record of the oldest row held: its alarm, counted in the summary and scores,
        handed to the sinks. `fault`: the step's posterior mass of the faulty modes, where a fleet has
        summed it already (for every unit in one call)."""
        row = self._held.popleft()
        alarm = self.alarms.step(step.mode_posterior, fault)
        self.summary.add(step, row.mode)
        if self.truth is not None:
            self.truth.add(row, alarm, step.t)
        self.scale.add(step)
        done = Diagnosed(step, row, alarm, self._evidence.popleft() if self.explain else None)
        for sink in self.sinks:
            sink.collect(done)
        return done

    def report(self) -> str:
        """The terminal report: mode segments, the diagnosis error and confusion where the data carry
        the true mode, the alarms and their detection scores, fit and speed."""
        from .report import report

        return report(self)

    # ----------------------------------------------------------------- checkpoint and resume
    def checkpoint(self) -> bytes:
        """The whole state of the diagnosis as bytes: filter (particles, weights, Kalman moments,
        covariance graph, random generator), fixed-lag window, pre-filter, alarm counter, summary,
        truth and the rows held back. The model and the sinks are not in it: `resume` is given them."""
        state = {key: value for key, value in vars(self).items() if key not in ("model", "sinks")}
        return seal(state, _identity(self.model), SAVED_KINDS, {"model": self.model})

    @classmethod
    def resume(cls, checkpoint: bytes, model: Model, sinks=()) -> "Diagnosis":
        """The diagnosis saved by `checkpoint`, continuing with `model` (the one it was saved with)
        and new sinks; a CheckpointError when the bytes are not such a state, are damaged (their
        checksum does not match), or were saved from another model or by another version of jmlgdsl."""
        if bytes(checkpoint[:len(PICKLED)]) == PICKLED:
            raise CheckpointError("a checkpoint of an earlier jmlgdsl, saved as a Python pickle: it is not read "
                                  "(reading a pickle can run any code its writer put in it)")
        if not is_sealed(checkpoint):
            raise CheckpointError("not a jmlgdsl checkpoint")
        try:
            identity = header_of(checkpoint)
        except SealedError as exc:
            raise CheckpointError(f"a damaged jmlgdsl checkpoint ({exc})") from None
        here = _identity(model)
        if identity.get("format") != here["format"] or identity.get("version") != here["version"]:
            raise CheckpointError(f"the checkpoint was saved by jmlgdsl {identity.get('version')} (format "
                                  f"{identity.get('format')}); this is jmlgdsl {VERSION}, which cannot resume it")
        if identity.get("model") != here["model"]:
            raise CheckpointError(f"the checkpoint was saved from another model (plant {identity.get('plant')!r}, "
                                  f"fingerprint {str(identity.get('model'))[:12]}) than this one (plant "
                                  f"{model.name!r}, fingerprint {here['model'][:12]})")
        try:
            state = unseal(checkpoint, SAVED_KINDS, {"model": model})
        except SealedError as exc:
            raise CheckpointError(f"a jmlgdsl checkpoint that does not read back ({exc})") from None
        if not isinstance(state, dict) or not all(isinstance(key, str) for key in state):
            raise CheckpointError("a jmlgdsl checkpoint that holds no diagnosis")
        diagnosis = cls.__new__(cls)
        vars(diagnosis).update(state, model=model, sinks=list(sinks))
        return diagnosis


@functools.lru_cache(maxsize=8)  # by identity: a monitor checkpoints the same model at every row
def fingerprint(model: Model) -> str:
    """A hash of everything a model holds (names, sample time, every matrix, exactly): two models
    with the same fingerprint filter data identically."""
    return hashlib.sha256(json.dumps(model.to_dict(), sort_keys=True).encode()).hexdigest()


def _identity(model: Model) -> dict:
    """What a checkpoint says of itself: its format, the version that wrote it and its model."""
    return {"format": CHECKPOINT_FORMAT, "version": VERSION, "plant": model.name, "model": fingerprint(model)}


def diagnose(model: Model, rows, options: Options = Options(), *, sinks=()) -> Diagnosis:
    """Diagnose every row of an iterable of data rows (see `jmlgdsl.data.iter_rows`) as `options` say,
    handing each finished row to the sinks; the finished Diagnosis (its summary, truth scores and
    report). This is `jmlgdsl.diagnose`:

        >>> import jmlgdsl
        >>> from jmlgdsl.data import iter_rows, open_source
        >>> from jmlgdsl.diagnosis import Kept
        >>> model = jmlgdsl.load("specs/dryer.jmlg")
        >>> kept = Kept()
        >>> with open_source("examples/dryer_seq1.csv") as source:
        ...     done = jmlgdsl.diagnose(model, iter_rows(source, model, source.name), sinks=[kept])
        >>> done.summary.T, model.modes[done.summary.current], done.alarms.raised, len(kept.rows)
        (1000, 'fan', 3, 1000)
    """
    return Diagnosis(model, options, sinks=sinks).run(rows)
