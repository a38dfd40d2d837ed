"""Validation of a learned mode: are its one-step residuals white and independent of the input,
and does it reproduce the output when simulated from the input alone?

Pass rule: with white residuals each correlation leaves its 99 % band with probability 1 %, so two
or more of 25 lags outside happen in under 3 % of white sequences. A mode passes when, for every
output, at most one of the residual autocorrelations at lags 1..25 and, for every input, at most one
of the input-residual cross-correlations at lags 0..25 lie outside the band +-2.576/sqrt(N).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import binom

from .em import columns, forward
from .statespace import StateSpace

MAX_LAG = 25
Z_99 = 2.5758293035489004  # two-sided 99 % normal quantile
ALLOWED_OUTSIDE = 1


@dataclass(frozen=True)
class Validation:
    """Residual autocorrelation (ny, 25) at lags 1..25, input-residual cross-correlation
    (ny, nu, 26) at lags 0..25 (NaN for a constant input), the 99 % band, the simulated output and
    its fit per output (NRMSE %), and the one-step residuals."""

    autocorr: np.ndarray
    crosscorr: np.ndarray
    band: float
    simulated: np.ndarray
    fit: np.ndarray
    residuals: np.ndarray

    @property
    def outside(self) -> tuple[np.ndarray, np.ndarray]:
        """How many autocorrelation lags per output and cross-correlation lags per (output, input)
        lie outside the band."""
        return (np.abs(self.autocorr) > self.band).sum(-1), (np.abs(self.crosscorr) > self.band).sum(-1)

    @property
    def failing(self) -> np.ndarray:
        """The outputs whose residual tests fail: more than ALLOWED_OUTSIDE lags outside the band in
        the autocorrelation or in a cross-correlation with some input."""
        auto, cross = self.outside
        return np.flatnonzero((auto > ALLOWED_OUTSIDE) | (cross > ALLOWED_OUTSIDE).any(axis=1))

    @property
    def passed(self) -> bool:
        """The pass rule of the module docstring: at most ALLOWED_OUTSIDE lags outside the band per test."""
        return not len(self.failing)

    @property
    def by_chance(self) -> float:
        """How many outputs a right model fails on average: each test of white residuals fails with
        the probability that more than ALLOWED_OUTSIDE of its lags leave the 99 % band, so with many
        outputs some failures are expected (about 1.3 of 52 autoregressive outputs)."""
        auto, cross = self.autocorr.shape[-1], self.crosscorr.shape[-1]
        nu = self.crosscorr.shape[1]
        return self.autocorr.shape[0] * (1 - _within(auto) * _within(cross) ** nu)


def _within(lags: int) -> float:
    """The probability that at most ALLOWED_OUTSIDE of `lags` independent correlations leave the 99 % band."""
    return float(binom.cdf(ALLOWED_OUTSIDE, lags, 0.01))


def correlation(a, b, lags) -> np.ndarray:
    """Normalised cross-correlation sum_t a_t b_{t+k} / sqrt(sum a^2 sum b^2) of centred series;
    NaN (a missing sample) counts as zero, and the result is NaN when either series is constant,
    and at a lag the series are too short for."""
    a = np.nan_to_num(a - np.nanmean(a))
    b = np.nan_to_num(b - np.nanmean(b))
    scale = np.sqrt((a @ a) * (b @ b))
    if scale == 0:
        return np.full(len(lags), np.nan)
    n = len(a)
    return np.array([a[:n - k] @ b[k:] if k < n else np.nan for k in lags]) / scale


def nrmse_fit(y, y_hat) -> np.ndarray:
    """Fit in percent per output, 100 (1 - |y - y_hat| / |y - mean y|), over the measured samples
    (NaN for an output that never moves: there is no variation to reproduce)."""
    fits = []
    for yi, hi in zip(np.asarray(y, float).T, np.asarray(y_hat, float).T):
        m = ~np.isnan(yi)
        spread = np.linalg.norm(yi[m] - yi[m].mean())
        fits.append(100.0 * (1 - np.linalg.norm(yi[m] - hi[m]) / spread) if spread > 0 else np.nan)
    return np.array(fits)


def validate(ss: StateSpace, y, u=None) -> Validation:
    """Residual whiteness, input-residual independence and free-run fit of `ss` on data y, u."""
    y, u = columns(y, u)
    e = forward(ss, y, u).innovation
    lags = np.arange(1, MAX_LAG + 1)
    xlags = np.arange(0, MAX_LAG + 1)
    auto = np.array([correlation(ei, ei, lags) for ei in e.T])
    cross = np.array([[correlation(ui, ei, xlags) for ui in u.T] for ei in e.T]).reshape(y.shape[1], u.shape[1], len(xlags))
    n = int((~np.isnan(e)).all(axis=1).sum())
    simulated = ss.free_run(u)
    return Validation(auto, cross, Z_99 / np.sqrt(n), simulated, nrmse_fit(y, simulated), e)
