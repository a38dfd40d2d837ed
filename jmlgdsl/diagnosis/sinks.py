"""Sinks: where a diagnosis hands each finished row. A sink is any object with `collect(row)`, called
with a `Diagnosed` row (step, data row, alarm) in order; it owns whatever it writes to."""

from __future__ import annotations

import dataclasses

import numpy as np

from ..infer import Result
from ..infer.table import TableWriter
from ..output import replacing
from .prediction import predictive_sd


class TableSink:
    """The result table (`jmlgdsl run -o`), written to a text stream row by row; flush=True sends each
    row on at once (a stream's reader sees it as soon as it is computed), explain=True adds the
    evidence per sensor (of a Diagnosis that explains). The header waits for the first row, which
    says whether the data have a time column."""

    def __init__(self, stream, model, lag=0, flush=False, explain=False):
        self.stream, self.model, self.lag, self.flush, self.explain = stream, model, lag, flush, explain
        self._writer = None

    def collect(self, done):
        if self._writer is None:
            self._writer = TableWriter(self.stream, self.model, done.row.time is not None, self.flush, lag=self.lag,
                                       explain=self.explain)
        self._writer.write(done.step, done.row.time, done.alarm, done.evidence)


class Raised:
    """The rows that raised an alarm (their alarm is 1, the row before's 0), for the report of the
    evidence behind them: the first `most` kept, the rest counted."""

    def __init__(self, most=30):
        self.most, self.rows, self.more = most, [], 0
        self._alarm = 0  # the last row's alarm

    def collect(self, done):
        if done.alarm and not self._alarm:
            if len(self.rows) < self.most:
                self.rows.append(done)
            else:
                self.more += 1
        self._alarm = done.alarm


class Kept:
    """Every finished row kept in memory, for a figure or a Result (a stream of unbounded length
    should not use it)."""

    def __init__(self):
        self.rows = []

    def collect(self, done):
        self.rows.append(done)

    def result(self, diagnosis) -> Result:
        """The kept rows as a Result of the diagnosis's filter."""
        f = diagnosis.filter
        return dataclasses.replace(Result.from_steps(f.model, f.algorithm, f.particles, [d.step for d in self.rows],
                                                     f.seconds), lag=f.lag)

    def draw(self, diagnosis, path):
        """The figure of the kept rows (`figure.result_figure`), with their residuals standardised
        and the data's anomaly labels, written whole or not at all."""
        from .figure import result_figure

        result = self.result(diagnosis)
        with replacing(path) as temporary:
            result_figure(result, temporary, true_modes=self.labels("mode"), y_sd=self.predictive_sd(result),
                          anomaly=self.labels("anomaly"))

    def predictive_sd(self, result) -> np.ndarray:
        """(T, ny) the standard deviation of each row's one-step prediction, from the estimate after the
        row before it (NaN for the first row)."""
        sd = np.full(result.y_pred.shape, np.nan)
        if result.T > 1:
            u = np.array([d.row.u for d in self.rows[1:]]).reshape(result.T - 1, result.model.nu)
            sd[1:] = predictive_sd(result.model, result.mode_posterior[:-1], result.state_mean[:-1],
                                   result.state_cov[:-1], u)
        return sd

    def labels(self, name: str) -> np.ndarray | None:
        """(T,) a label of every kept row (mode, anomaly), or None unless every row has one."""
        values = [getattr(d.row, name) for d in self.rows]
        return None if any(v is None for v in values) else np.array(values)
