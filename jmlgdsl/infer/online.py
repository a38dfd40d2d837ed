"""The filtering front end: `Filter` steps through data on-line; `filter` runs it over a whole array.

This is the one filtering loop: the batch call, `jmlgdsl run` and a live stream all advance a
`Filter` one `step` at a time, and the Filter keeps the clock, the log-likelihood and the time spent.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections import deque

import numpy as np

from ..data import with_defaults
from ..errors import DataError
from ..model import Model
from ..seeds import generator
from . import covariances
from .algorithms import ALGORITHMS, DEFAULT_ALGORITHM, algorithm_named
from .engine import Estimates, FilterError, Gate, Genealogy, Resampler
from .resample import SCHEMES
from .result import Result, Step

# Readings this large (or infinite) cannot be measurements: their squares would overflow the
# Kalman arithmetic, so they are treated as not measured.
MAX_READING = 1e100
# A reading beyond the model's outlier gate under every hypothesis is left out as a gross error at
# most this many steps in a row, unless it is absurd (beyond the reach of every mode: engine.screen),
# which is left out every time (docs/filters.md, "Gross errors").
MAX_REJECTIONS = 2


class Filter:
    """On-line mode and state estimation: feed one observation at a time with `step(y_t, u_t)`.

    `particles=None` takes the algorithm's default; `seed` (a number, or a numpy Generator to draw
    from) makes runs reproducible bit for bit. Resampling happens when the effective sample size
    falls below `ess_threshold` times the particle count (1, the default, resamples at every step).

    With `lag=L` > 0 the filter smooths on-line: `step` returns nothing for the first L rows, then
    the record of row t-L with its mode posterior (and, for imm, state moments) given the data up to
    row t; `flush()` returns the last L rows smoothed with what arrived. `lag=None` holds every row
    back for `flush()`: off-line smoothing. The one-step predictions and residuals stay the filter's.
    """

    def __init__(self, model: Model, algorithm: str = DEFAULT_ALGORITHM, particles: int | None = None,
                 seed=None, resampling: str = "systematic", ess_threshold: float = 1.0, lag: int | None = 0):
        spec = algorithm_named(algorithm)
        if resampling not in SCHEMES:
            raise FilterError(f"unknown resampling scheme {resampling!r}; choose from {', '.join(SCHEMES)}")
        if lag is not None and (isinstance(lag, bool) or not isinstance(lag, (int, np.integer)) or lag < 0):
            raise FilterError(f"the lag must be a whole number of steps >= 0 (or None: off-line), got {lag!r}")
        if particles is None or not spec.uses_particles:
            particles = spec.default_particles
        elif isinstance(particles, bool) or not isinstance(particles, (int, np.integer)) or particles < 1:
            raise FilterError(f"the number of particles must be a positive whole number, got {particles!r}")
        self.model, self.algorithm, self.particles = model, algorithm, particles
        self.rng = generator(seed)
        resampler = Resampler(SCHEMES[resampling], particles, self.rng, ess_threshold) if particles else None
        self.engine = spec.build(model, particles, self.rng, resampler)
        self.t = 0
        self.loglik = 0.0
        self.seconds = 0.0  # time spent inside step()
        self.lag = lag
        self._pending = deque()  # records held back until the rows after them have arrived
        self._smoother = None if lag == 0 else spec.window(model, lag, self.engine)
        self._gate = Gate.of(model.outlier_gate)
        self._flagged = np.zeros(model.ny, dtype=np.int64)  # consecutive steps beyond the gate, per output
        self._watching = False  # some output was beyond the gate at the last step

    def step(self, y, u=None) -> Step | None:
        """Advance one time step with outputs y (ny,) and inputs u (nu,); the record of this row, or
        with a lag the smoothed record of the row `lag` steps back (None while there is none yet).

        NaN outputs are not measured (as are infinite ones or any beyond MAX_READING in size);
        NaN inputs (all of them with u=None) take the spec's defaults.
        """
        start = time.perf_counter()
        model, t = self.model, self.t + 1
        y, mask = _readings(_vector(y, model.outputs, "outputs", t))
        u = _inputs(model, model.input_defaults if u is None else _vector(u, model.inputs, "inputs", t), t)
        self.seconds += time.perf_counter() - start
        return self._advance(y, mask, u)

    def _feed(self, y, u):
        """The records of whole arrays y (T, ny) and u (T, nu), checked all at once (as `step` checks a row)."""
        start = time.perf_counter()
        y, mask = _readings(y)
        u = _inputs(self.model, u, self.t + 1)
        self.seconds += time.perf_counter() - start
        for row in zip(y, mask, u):
            yield self._advance(*row)

    def _advance(self, y, mask, u) -> Step | None:
        """`step` on checked readings y (ny,), measured where mask (ny,) is True, and inputs u (nu,)."""
        start = time.perf_counter()
        record = self.accept(self.engine.step(y, mask, u, self._gate), y, u)
        self.seconds += time.perf_counter() - start
        return record

    @property
    def gate(self) -> Gate:
        """The outlier gate this filter's next step applies: the model's, less the outputs whose
        readings have been beyond it MAX_REJECTIONS steps in a row (taken whatever they say)."""
        return self._gate

    def accept(self, est, y, u) -> Step | None:
        """The record of a step its engine made under `gate` from outside this filter (jmlgdsl.infer.
        units steps many units' engines in one call): `est` of checked readings y and inputs u, counted
        in this filter's clock, log-likelihood, gate counts and lag window as `step` counts its own."""
        t = self.t + 1
        if not (math.isfinite(est.loglik) and np.isfinite(est.state_cov).all()):
            raise _overflow(t, est)
        self._counted(est.loglik, est.flagged)
        record = Step(t, est.mode_posterior, est.state_mean, est.state_cov, est.y_pred, y - est.y_pred,
                      est.loglik, est.ess, est.rejected)
        return record if self._smoother is None else self._hold(record, u)

    @staticmethod
    def accept_together(filters, est: Estimates):
        """`accept` of many filters without a lag (the units of a fleet, jmlgdsl.infer.units), their
        steps' estimates the rows of `est`, none overflowed: each counted in its filter's clock,
        log-likelihood and gate counts as `accept` counts it. Their records are the caller's to make
        (as arrays, without a Step each)."""
        flagged = est.flagged.any(axis=1).tolist()
        for f, loglik, found, row in zip(filters, est.loglik.tolist(), flagged, est.flagged):
            f._counted(loglik, row if found else None)

    def _counted(self, loglik, flagged):
        """A step counted: the clock, the log-likelihood and the gate counts (flagged: the readings
        beyond the gate (ny,), None when none were)."""
        if flagged is not None or self._watching:
            self._count_flagged(flagged)
        self.t += 1
        self.loglik += loglik

    def _hold(self, record, u):
        """Keep the new record back; give out the oldest one, smoothed, once `lag` rows follow it."""
        self._smoother.update(self.engine, u)
        self._pending.append(record)
        if self.lag is None or len(self._pending) <= self.lag:
            return None
        return self._release(1)[0]

    def _release(self, count):
        """The oldest `count` held records with their smoothed estimates, taken off the queue."""
        post, mean, cov = self._smoother.rows(len(self._pending))
        return [dataclasses.replace(self._pending.popleft(), mode_posterior=post[i], state_mean=mean[i],
                                    state_cov=cov[i]) for i in range(count)]

    def flush(self) -> list[Step]:
        """The records still held back, smoothed with the data that arrived (none without a lag)."""
        start = time.perf_counter()
        records = self._release(len(self._pending)) if self._pending else []
        self.seconds += time.perf_counter() - start
        return records

    def _count_flagged(self, flagged):
        """Count the steps in a row each output's reading was beyond the gate. After MAX_REJECTIONS
        such steps its readings are taken whatever they say, unless absurd, until one is within the
        gate again: a change that lasts, within the reach of the modes, is the plant, not a glitch.
        An absurd or missing reading (never flagged) ends the count."""
        self._flagged = np.zeros_like(self._flagged) if flagged is None else np.where(flagged, self._flagged + 1, 0)
        self._watching = flagged is not None
        self._gate = Gate.of(self.model.outlier_gate, self._flagged < MAX_REJECTIONS)


# What a Filter's state is made of: the classes and functions its saved state (jmlgdsl.sealed) may
# hold, and the only ones reading it back may make.
SAVED_KINDS = (Filter, Step, Gate, Genealogy, Resampler, covariances.CovarianceGraph, covariances._Growing,
               covariances._Rows, covariances.Representatives, *(a.engine for a in ALGORITHMS.values()),
               *dict.fromkeys(a.window for a in ALGORITHMS.values()), *SCHEMES.values())


def _overflow(t, est) -> FilterError:
    """The error of a step whose log-likelihood or state covariance is not finite: the model's numbers
    overflowed. Both are checked because either can go alone: with no readings the log-likelihood
    is 0 while an unstable state's variance runs away, and a state the readings never see runs away
    while their log-likelihood stays finite. The covariance stands for the mean too: it is the
    mixture's, built from every hypothesis's deviation from the mean (engine.mixture_moments), so it
    is not finite whenever the mean is not."""
    cov = "" if np.isfinite(est.state_cov).all() else ", state covariance not finite"
    return FilterError(f"t={t}: the filter's arithmetic overflowed (log-likelihood {est.loglik}{cov}); the "
                       "model's numbers are too large for this data (an unstable mode, or a huge noise?)")


def _vector(values, names, what, t):
    """One step's values as a float vector (len(names),); a DataError naming the columns otherwise."""
    v = np.asarray(values, dtype=float)
    if v.shape == (len(names),):
        return v
    if v.size != len(names):
        raise DataError(f"t={t}: {v.size} {what} given, expected {len(names)} ({', '.join(names)})")
    return v.reshape(len(names))


def _readings(y):
    """(y, mask) for readings y (..., ny): mask is False where a reading is NaN, infinite or beyond
    MAX_READING in size (not measured), and y is NaN there."""
    mask = np.abs(y) < MAX_READING
    return (y if mask.all() else np.where(mask, y, np.nan)), mask


def _inputs(model: Model, u, t):
    """Inputs u (..., nu) with NaN entries taking the spec's defaults; a DataError naming the first
    row with an input that has neither a value nor a default: row i is step t + i of one record (t a
    number), or step t[i] of unit i (t an array: a row per unit, jmlgdsl.infer.units)."""
    if np.isfinite(u).all():
        return u
    u = with_defaults(u, model.input_defaults)
    bad = ~np.isfinite(np.atleast_2d(u))
    if bad.any():
        row = int(np.flatnonzero(bad.any(axis=1))[0])
        names = [n for n, b in zip(model.inputs, bad[row]) if b]
        where = f"t={t + row}" if np.ndim(t) == 0 else f"unit {row}, t={t[row]}"
        raise DataError(f"{where}: no value and no default for input {', '.join(names)}")
    return u


def _arrays(model: Model, y, u):
    """y as (T, ny) and u as (T, nu), checked against the model."""
    y = np.asarray(y, dtype=float)
    if y.ndim == 1:
        y = y[:, None] if model.ny == 1 else y[None]
    if y.ndim != 2 or y.shape[1] != model.ny:
        raise DataError(f"y must have shape (T, {model.ny}) for outputs {', '.join(model.outputs)}; got {y.shape}")
    return y, model.resolve_inputs(u, len(y))


def filter(model: Model, y, u=None, *, algorithm: str = DEFAULT_ALGORITHM, particles: int | None = None,
           seed=None, resampling: str = "systematic", ess_threshold: float = 1.0) -> Result:
    """Filter a whole sequence: y (T, ny) with NaN for unmeasured entries, u (T, nu) or None for defaults.
    Row t of the result is p(z_t | y_1:t) and the matching state moments."""
    y, u = _arrays(model, y, u)
    f = Filter(model, algorithm, particles, seed, resampling, ess_threshold)
    steps = list(f._feed(y, u))
    return Result.from_steps(model, algorithm, f.particles, steps, f.seconds)


def smooth(model: Model, y, u=None, *, algorithm: str = DEFAULT_ALGORITHM, lag: int | None = None,
           particles: int | None = None, seed=None, resampling: str = "systematic",
           ess_threshold: float = 1.0) -> Result:
    """Smooth a whole sequence: row t of the result is p(z_t | y_1:min(T, t+lag)) (lag=None: all the
    data) with the matching state moments where the algorithm gives them (exact and imm; NaN for
    the particle filters); predictions, residuals and the log-likelihood are the filter's.

    Lag 0 is `filter` itself. `exact` smooths over every mode history and `imm` with a lag runs
    Kim's backward pass over every window at once, both over the readings the filter used; `imm`
    off-line runs Kim's pass once over the filter's own per-mode moments, and the particle filters
    trace their candidates' ancestral lines back (see jmlgdsl.infer.lagged).
    """
    if lag == 0:
        return filter(model, y, u, algorithm=algorithm, particles=particles, seed=seed, resampling=resampling,
                      ess_threshold=ess_threshold)
    y, u = _arrays(model, y, u)
    whole_record = algorithm_named(algorithm).whole_record
    if whole_record is not None:  # one filter pass, what its backward pass needs kept as it goes
        f = Filter(model, algorithm, particles, seed, resampling, ess_threshold)
        backward, steps = whole_record(model, len(y)), []
        for t, record in enumerate(f._feed(y, u)):
            steps.append(record)
            backward.record(t, f.engine)
        result = Result.from_steps(model, algorithm, f.particles, steps, f.seconds)
        start = time.perf_counter()
        smoothed = backward.smoothed(model, y, u, result.rejected, lag)
        return dataclasses.replace(result, mode_posterior=smoothed.mode_posterior, state_mean=smoothed.state_mean,
                                   state_cov=smoothed.state_cov, lag=lag,
                                   seconds=result.seconds + time.perf_counter() - start)
    f = Filter(model, algorithm, particles, seed, resampling, ess_threshold, lag=lag)
    steps = [s for s in f._feed(y, u) if s is not None] + f.flush()
    return dataclasses.replace(Result.from_steps(model, algorithm, f.particles, steps, f.seconds), lag=lag)
