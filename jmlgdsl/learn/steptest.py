"""First-order-plus-dead-time fit of a step test: gain K, time constant tau, dead time theta.

The model is the sampled FOPDT K e^{-theta s}/(tau s + 1) with the input held over each sample, in
the model's timing (u_t acts on y_t): y_t = a y_{t-1} + K (1 - a) u_{t-d} + c with a = exp(-dt/tau),
so after a step of size du at sample s the response is y0 + K du (1 - a^(t-s-d+1)) for t >= s + d.
The dead time d runs over a whole-sample grid; for each d, (y0, K) are linear least squares given
tau and tau is found by a bounded one-dimensional search; the d with the least squared error wins.
A step the output does not answer is refused first: any curve fits noise, with a gain near zero
and a meaningless dead time, and the search over every dead time takes long.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize_scalar

from ..errors import DataError
from .basis import LaggedMode, Lags


@dataclass(frozen=True)
class FopdtFit:
    """Fitted gain, time constant (s), dead time (whole samples), initial level y0, and the step."""

    gain: float
    tau: float
    delay: int
    y0: float
    u0: float
    du: float
    step: int
    dt: float
    sse: float
    n: int

    @property
    def pole(self) -> float:
        """exp(-dt / tau), the sampled pole."""
        return float(np.exp(-self.dt / self.tau))

    def response(self, T: int) -> np.ndarray:
        """The fitted step response at samples 0..T-1."""
        return _response(self.step, self.delay, self.dt, self.tau, T) * self.gain * self.du + self.y0

    def lagged(self) -> LaggedMode:
        """The sampled FOPDT in the lagged basis (output lag 1, the input at lag d): EM's start, with
        the fit's residual variance split evenly between process and measurement noise."""
        a, lags = self.pole, Lags(1, 1, self.delay)
        Phi, Psi = np.zeros((1, lags.n)), np.zeros((1, lags.n))
        Phi[0, 0], Psi[0, self.delay] = a, self.gain * (1 - a)
        noise = np.array([[0.5 * self.sse / self.n]])
        return LaggedMode(lags, Phi, Psi, np.array([(1 - a) * (self.y0 - self.gain * self.u0)]), noise, noise)


def _response(step, delay, dt, tau, T):
    """Unit-gain, unit-step FOPDT response at samples 0..T-1."""
    k = np.arange(T) - step - delay + 1
    return np.where(k >= 1, 1.0 - np.exp(-np.maximum(k, 0) * dt / tau), 0.0)


def find_step(u) -> int:
    """Sample index at which a single-input step test's input changes (it must change exactly once)."""
    u = np.asarray(u, float).ravel()
    changes = np.flatnonzero(np.abs(np.diff(u)) > 1e-9 * max(1.0, np.abs(u).max()))
    if len(changes) != 1:
        raise DataError(f"a step test needs an input that changes exactly once; this one changes "
                        f"{len(changes)} times")
    return int(changes[0]) + 1


RESPONSE = 5.0  # standard errors the output's mean must move by for a step to count as answered


def check_response(y, step: int):
    """Refuse a step test whose output does not respond: the change of its mean across the step
    within RESPONSE standard errors of that change. The noise sd comes from the median absolute
    deviation of successive differences, which the step's own transient hardly moves."""
    steps = np.diff(y)
    noise = 1.4826 * np.median(np.abs(steps - np.median(steps))) / np.sqrt(2)
    change = y[step:].mean() - y[:step].mean()
    if not abs(change) > RESPONSE * noise * np.sqrt(1 / step + 1 / (len(y) - step)):
        raise DataError(f"the output does not respond to the input step at row {step + 1} of the experiment: "
                        f"its mean moves by {change:.3g} across the step, within its noise (sd {noise:.3g}); "
                        "a step test needs a step that the output answers")


def fit_fopdt(y, u, dt: float = 1.0, max_delay: int | None = None) -> FopdtFit:
    """FOPDT fit of output y (T,) to a single step in input u (T,); dead times 0..max_delay samples."""
    y = np.asarray(y, float).ravel()
    u = np.asarray(u, float).ravel()
    if np.isnan(y).any() or np.isnan(u).any():
        raise DataError("the step test has missing values")
    T = len(y)
    s = find_step(u)
    check_response(y, s)
    max_delay = (T - s) // 2 if max_delay is None else max_delay
    du, u0 = u[s] - u[s - 1], u[s - 1]
    best = None
    for d in range(max_delay + 1):
        def sse(log_tau, d=d):
            return _least_squares(y, _response(s, d, dt, np.exp(log_tau), T))[1]
        res = minimize_scalar(sse, bounds=(np.log(dt / 20), np.log(20 * T * dt)), method="bounded",
                              options={"xatol": 1e-10})
        if best is None or res.fun < best[0]:
            best = (res.fun, d, float(np.exp(res.x)))
    err, d, tau = best
    (y0, k), _ = _least_squares(y, _response(s, d, dt, tau, T))
    return FopdtFit(gain=float(k / du), tau=tau, delay=d, y0=float(y0), u0=float(u0), du=float(du),
                    step=s, dt=float(dt), sse=float(err), n=T)


def _least_squares(y, shape):
    """Best (y0, K du) for y ≈ y0 + K du * shape, and the squared error."""
    X = np.column_stack([np.ones_like(shape), shape])
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    r = y - X @ coef
    return coef, float(r @ r)
