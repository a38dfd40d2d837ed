"""From one experiment per mode to a mode bank: a common structure (ARX orders by information
criterion, or FOPDT from step tests), EM from that start, validation, and the assembled Model."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import solve_discrete_lyapunov

from ..errors import DataError
from ..model import Model
from . import arx, steptest
from .em import EMResult, em
from .statespace import StateSpace
from .validate import Validation, validate


@dataclass(frozen=True)
class Experiment:
    """One mode's identification data: outputs y (T, ny) with NaN where not measured, inputs u (T, nu)."""

    y: np.ndarray
    u: np.ndarray
    source: str = "<data>"


@dataclass(frozen=True)
class LearnedMode:
    """Everything learned about one mode: its data, structure, EM's start and run, and the checks."""

    name: str
    experiment: Experiment
    structure: str
    start: StateSpace
    em: EMResult
    validation: Validation
    fopdt: steptest.FopdtFit | None = None

    @property
    def model(self) -> StateSpace:
        """The learned state-space model."""
        return self.em.model

    def summary(self) -> str:
        """One line: structure, EM, poles, gain, noise, fit and the residual tests."""
        m, v = self.model, self.validation
        poles = ", ".join(f"{p:.4g}" for p in m.poles())
        gain = f"gain {', '.join(f'{g:.4g}' for g in m.gain().ravel())}; " if m.F.shape[1] else ""
        verdict = "white residuals" if v.passed else "residual tests FAIL"
        return (f"{self.name}: {self.structure}, EM {self.em.iterations} iterations"
                f"{'' if self.em.converged else ' (not converged)'}, log-lik {self.em.loglik[-1]:.6g}; "
                f"poles {poles}; {gain}measurement sd {np.sqrt(np.diag(m.R)).max():.3g}; "
                f"fit {', '.join(f'{x:.1f}' for x in v.fit)} %; {verdict}")

    def criterion(self, kind="bic") -> float:
        """AIC or BIC of the fitted state-space model. It counts the identifiable parameters of an
        n-state single-output model in innovations form: n poles, n numerator coefficients per
        input, n noise-model coefficients, the offset and the innovation variance."""
        n, nu = self.model.nx, self.model.F.shape[1]
        p = n * (2 + nu) + 2
        N = int((~np.isnan(self.experiment.y)).all(axis=1).sum())
        return -2 * self.em.loglik[-1] + p * (np.log(N) if kind == "bic" else 2.0)


def learn_modes(experiments: dict, order="auto", fopdt=False, dt=1.0, max_order=4, max_delay=0,
                criterion="bic", max_iter=100, tol=1e-5) -> list[LearnedMode]:
    """Fit every mode's experiment with one structure: ARX order (na, nb, nk), "auto", or FOPDT step tests.

    "auto": the ARX order with the least criterion (over na, nb <= max_order, nk <= max_delay) bounds
    the number of states from above, since ARX spends extra lags imitating measurement noise; EM then
    fits 1..that many states and the bank with the least criterion summed over modes is kept.
    """
    for e in experiments.values():
        if e.y.shape[1] != 1:
            raise DataError(f"{e.source}: learning fits one output per plant; got {e.y.shape[1]}")
        if np.isnan(e.y).all():
            raise DataError(f"{e.source}: no measured output")
        for j, column in enumerate(e.u.T):
            if np.nanmin(column) == np.nanmax(column):
                raise DataError(f"{e.source}: input {j + 1} never changes, so its effect cannot be told "
                                "from the offset; excite it, e.g. with a PRBS")
    if fopdt:
        for e in experiments.values():
            if e.u.shape[1] != 1:
                raise DataError(f"{e.source}: a step test has one input; got {e.u.shape[1]}")
        fits = {k: _located(e, steptest.fit, e.y[:, 0], e.u[:, 0], dt) for k, e in experiments.items()}
        n = max(f.delay for f in fits.values()) + 1
        return _fit_all(experiments, {k: (f.to_statespace(n), f"FOPDT gain {f.gain:.4g}, tau {f.tau:.4g} s, "
                                          f"dead time {f.delay * f.dt:g} s", f) for k, f in fits.items()},
                        max_iter, tol)
    if order != "auto":
        return _fit_arx(experiments, order, max_iter, tol)
    na, nb, nk = arx.select_order([(e.y[:, 0], e.u) for e in experiments.values()], max_order, max_order,
                                  max_delay, criterion)
    banks = [_fit_arx(experiments, (n, n, 0), max_iter, tol) for n in range(1, max(na, nk + nb) + 1)]
    return min(banks, key=lambda bank: sum(lm.criterion(criterion) for lm in bank))


def _fit_arx(experiments, order, max_iter, tol):
    """Every mode from an ARX start of the given order, started at its first measured output."""
    na, nb, nk = order
    starts = {}
    for k, e in experiments.items():
        fit = _located(e, arx.fit, e.y[:, 0], e.u, na, nb, nk)
        first = e.y[np.isfinite(e.y[:, 0]), 0][0]
        structure = f"ARX({na},{nb},{nk})" if e.u.shape[1] else f"AR({na})"
        starts[k] = (fit.to_statespace(e.u[0], first), structure, None)
    return _fit_all(experiments, starts, max_iter, tol)


def _fit_all(experiments, starts, max_iter, tol):
    """EM from each mode's start (structure text and FOPDT fit alongside), then validation."""
    learned = []
    for name, e in experiments.items():
        start, structure, fit = starts[name]
        result = em(start, e.y, e.u, max_iter=max_iter, tol=tol, feedthrough=False)
        result = EMResult(readable(result.model), result.loglik, result.converged)
        learned.append(LearnedMode(name, e, structure, start, result, validate(result.model, e.y, e.u), fit))
    return learned


def _located(e: Experiment, fit, *args):
    """fit(*args), with a DataError naming the experiment's file."""
    try:
        return fit(*args)
    except DataError as exc:
        raise DataError(f"{e.source}: {exc}") from None


def readable(ss: StateSpace) -> StateSpace:
    """The observer canonical basis (state 1 = noise-free output) when the output observes every
    state and the change of basis keeps the steady-state gain; else the model as it is."""
    try:
        out = ss.observer_form()
    except np.linalg.LinAlgError:
        return ss
    return out if np.allclose(out.gain(), ss.gain(), rtol=1e-6) else ss


def default_transitions(K: int, stay: float) -> np.ndarray:
    """`stay p, otherwise uniform`: p on the diagonal, the rest of each row shared evenly."""
    if K == 1:
        return np.ones((1, 1))
    return np.full((K, K), (1 - stay) / (K - 1)) + (stay - (1 - stay) / (K - 1)) * np.eye(K)


def _stable(ss: StateSpace) -> bool:
    """Whether every pole lies inside the unit circle."""
    return bool(np.abs(ss.poles()).max() < 1)


def initial_spread(ss: StateSpace) -> np.ndarray:
    """Stationary state variances under the process noise (the Q diagonal for a mode that is not stable)."""
    return np.diag(solve_discrete_lyapunov(ss.A, ss.Q) if _stable(ss) else ss.Q)


def initial_state(lm: LearnedMode, operating_input=None) -> np.ndarray:
    """Where a mode starts: its steady state under the operating input (default: its experiment's
    mean input); a mode that is not stable has none, so it starts where its experiment began."""
    m = lm.model
    if not _stable(m):
        return m.mu0
    return m.steady_state(lm.experiment.u.mean(0) if operating_input is None else operating_input)


def assemble(learned: list[LearnedMode], *, P, p0, operating_input=None, **names) -> Model:
    """A Model from the learned modes: B, D as Cholesky factors of Q, R; each mode starts at its
    `initial_state`, with the widest stationary spread of any mode. `names` passes name, dt,
    inputs, outputs, units, ... on to the Model."""
    mods = [lm.model for lm in learned]
    x0 = [initial_state(lm, operating_input) for lm in learned]
    spread = np.max([initial_spread(m) for m in mods], axis=0)
    return Model.from_arrays(
        A=np.stack([m.A for m in mods]), F=np.stack([m.F for m in mods]), f=np.stack([m.f for m in mods]),
        C=np.stack([m.C for m in mods]), G=np.stack([m.G for m in mods]), g=np.stack([m.g for m in mods]),
        B=np.stack([np.linalg.cholesky(m.Q) for m in mods]), D=np.stack([np.linalg.cholesky(m.R) for m in mods]),
        P=P, p0=p0, mu0=np.stack(x0), Sigma0=np.diag(spread), modes=tuple(lm.name for lm in learned),
        **names)
