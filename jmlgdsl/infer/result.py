"""What a filter reports: one `Step` record per time step on-line, a `Result` for a whole sequence."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
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

    @property
    def map_mode(self) -> int:
        """Index of the most probable mode."""
        return int(np.argmax(self.mode_posterior))


@dataclass(frozen=True)
class Result:
    """A filtered sequence: arrays over time steps t = 1..T (row 0 is t = 1)."""

    model: object
    algorithm: str
    particles: int | None
    mode_posterior: np.ndarray  # (T, K)
    state_mean: np.ndarray  # (T, nx)
    state_cov: np.ndarray  # (T, nx, nx)
    y_pred: np.ndarray  # (T, ny)
    residuals: np.ndarray  # (T, ny)
    loglik_steps: np.ndarray  # (T,) log p(y_t | y_1:t-1)
    ess: np.ndarray  # (T,)
    seconds: float  # wall-clock time spent filtering

    @classmethod
    def from_steps(cls, model, algorithm, particles, steps, seconds) -> "Result":
        """Stack on-line step records into arrays."""
        fields = ("mode_posterior", "state_mean", "state_cov", "y_pred", "residual", "loglik", "ess")
        stacked = {f: np.array([getattr(s, f) for s in steps]) for f in fields}
        if not steps:
            K, nx, ny = model.K, model.nx, model.ny
            stacked = {f: np.zeros(shape) for f, shape in zip(fields, ((0, K), (0, nx), (0, nx, nx), (0, ny),
                                                                      (0, ny), (0,), (0,)))}
        return cls(model, algorithm, particles, stacked["mode_posterior"], stacked["state_mean"],
                   stacked["state_cov"], stacked["y_pred"], stacked["residual"], stacked["loglik"],
                   stacked["ess"], seconds)

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
        return 100.0 * float(np.mean(self.map_modes != np.asarray(true_modes)))
