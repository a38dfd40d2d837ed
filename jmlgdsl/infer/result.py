"""What a filter reports: one `Step` record per time step on-line, a `Result` for a whole sequence,
and a `Summary` gathered step by step (constant memory, for streams of any length); and what every
engine keeps of its last step, its `Predictive`."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from ..model import Model


def diagnosis_error(map_modes, true_modes) -> float:
    """Percentage of steps whose diagnosed (MAP) mode index differs from the true one."""
    return 100.0 * float(np.mean(np.asarray(map_modes) != np.asarray(true_modes)))


class Predictive(NamedTuple):
    """A step's one-step predictive of the readings it measured, hypothesis by hypothesis, as the
    engine weighed them; every engine keeps its last step's as `engine.predictive` (the readings it
    used, when a gate left some out). Hypothesis j (a mode's Gaussian for imm, a (mode history,
    mode) candidate for the Rao-Blackwellised filters, a particle for pf) is in mode mode[j], weighs
    exp(log_weight[j]) before the readings (up to one factor shared by all), and predicts the
    readings where `mask` is True as y - residual[j] with covariance S_j, Linv[j] the inverse
    Cholesky factor of S_j. The evidence per sensor (jmlgdsl.diagnosis.evidence) is read from it."""

    mode: np.ndarray  # (J,)
    log_weight: np.ndarray  # (J,)
    residual: np.ndarray  # (J, m) for the m readings measured
    Linv: np.ndarray  # (J, m, m)
    mask: np.ndarray  # (ny,)


@dataclass(frozen=True, slots=True)
class Step:
    """The estimates after seeing y_t (t counts from 1)."""

    t: int
    mode_posterior: np.ndarray  # (K,) p(z_t = k | y_1:t)
    state_mean: np.ndarray  # (nx,)
    state_cov: np.ndarray  # (nx, nx)
    y_pred: np.ndarray  # (ny,) E[y_t | y_1:t-1]
    residual: np.ndarray  # (ny,) y_t - y_pred, NaN where not measured
    loglik: float  # log p(y_t | y_1:t-1)
    ess: float
    rejected: np.ndarray | None = None  # (ny,) readings left out as gross errors (None: none were)

    @property
    def map_mode(self) -> int:
        """Index of the most probable mode."""
        return int(self.mode_posterior.argmax())


@dataclass(frozen=True)
class Result:
    """A filtered sequence: arrays over time steps t = 1..T (row 0 is t = 1)."""

    model: Model
    algorithm: str
    particles: int | None
    mode_posterior: np.ndarray  # (T, K)
    state_mean: np.ndarray  # (T, nx)
    state_cov: np.ndarray  # (T, nx, nx)
    y_pred: np.ndarray  # (T, ny)
    residuals: np.ndarray  # (T, ny)
    loglik_steps: np.ndarray  # (T,) log p(y_t | y_1:t-1)
    ess: np.ndarray  # (T,)
    seconds: float  # wall-clock time spent filtering (and smoothing)
    rejected: np.ndarray | None = None  # (T, ny) readings left out as gross errors
    lag: int | None = 0  # row t is p(z_t | y_1:t+lag): 0 filtered, None smoothed off-line

    @classmethod
    def from_steps(cls, model: Model, algorithm: str, particles: int | None, steps, seconds: float) -> "Result":
        """Stack on-line step records into arrays."""
        return cls(model, algorithm, particles, seconds=seconds, **stacked(steps, model))

    @property
    def map_modes(self) -> np.ndarray:
        """(T,) index of the most probable mode at each step."""
        return np.argmax(self.mode_posterior, axis=1)

    @property
    def loglik(self) -> float:
        """log p(y_1:T) (an unbiased estimate of p for the particle filters, on the log scale)."""
        return float(self.loglik_steps.sum())

    @property
    def T(self) -> int:
        """Number of time steps filtered."""
        return len(self.mode_posterior)

    def diagnosis_error(self, true_modes) -> float:
        """Percentage of steps whose MAP mode differs from the true mode indices (T,)."""
        return diagnosis_error(self.map_modes, true_modes)


def stacked(steps, model: Model) -> dict:
    """The fields of Step records as arrays with a leading axis, a row per record (over time for a
    Result, over units for jmlgdsl.infer.units.UnitSteps), by the names both give them: a record's
    `residual` stacks into `residuals`, its `loglik` into `loglik_steps`, its `rejected` into rows that
    are all False where it left nothing out."""
    n, K, nx, ny = len(steps), model.K, model.nx, model.ny

    def stack(name, shape):
        return np.array([getattr(s, name) for s in steps]).reshape((n,) + shape)

    rejected = np.zeros((n, ny), dtype=bool)
    for i, s in enumerate(steps):
        if s.rejected is not None:
            rejected[i] = s.rejected
    return dict(mode_posterior=stack("mode_posterior", (K,)), state_mean=stack("state_mean", (nx,)),
                state_cov=stack("state_cov", (nx, nx)), y_pred=stack("y_pred", (ny,)),
                residuals=stack("residual", (ny,)), loglik_steps=stack("loglik", ()), ess=stack("ess", ()),
                rejected=rejected)


@dataclass
class Summary:
    """A run's figures, gathered one step at a time in constant memory: the segments of one MAP mode
    (the first `max_segments` kept, the rest counted), where the true mode is known the wrongly
    diagnosed steps and the confusion matrix, and the log-likelihood."""

    max_segments: int = 30
    T: int = 0
    loglik: float = 0.0
    segments: list = field(default_factory=list)  # [first t, last t, mode, summed posterior of that mode]
    more_segments: int = 0
    labelled: int = 0  # steps with a known true mode
    wrong: int = 0  # of those, steps whose MAP mode is not the true one
    current: int = -1  # the MAP mode of the last step
    confusion: np.ndarray | None = None  # (K, K) steps with true mode i diagnosed as j, once labelled

    def add(self, step: Step, true_mode: int | None = None):
        """Count one step (and its true mode index, when known)."""
        k = step.map_mode
        self.T = step.t
        self.loglik += step.loglik
        if true_mode is not None:
            if self.confusion is None:
                K = len(step.mode_posterior)
                self.confusion = np.zeros((K, K), dtype=np.int64)
            self.confusion[true_mode, k] += 1
            self.labelled += 1
            self.wrong += int(k != true_mode)
        if k != self.current:
            self.current = k
            if len(self.segments) < self.max_segments:
                self.segments.append([step.t, step.t, k, 0.0])
            else:
                self.more_segments += 1
        if not self.more_segments:
            segment = self.segments[-1]
            segment[1] = step.t
            segment[3] += float(step.mode_posterior[k])

    @property
    def diagnosis_error(self) -> float | None:
        """Percentage of the labelled steps diagnosed wrongly, None without labels."""
        return 100.0 * self.wrong / self.labelled if self.labelled else None
