"""ARX / VAR least squares for any number of outputs and inputs, in the lagged basis's terms:

    y_t = Phi_1 y_{t-1} + ... + Phi_na y_{t-na} + Psi_nk u_{t-nk} + ... + Psi_{nk+nb-1} u_{t-nk-nb+1} + c + e_t

with e_t ~ N(0, Sigma) across outputs. Lag 0 on the input (nk = 0) lets u_t act on y_t in the same
step, as in the model's x_t = A x_{t-1} + F u_t. All outputs share the regressors, so one
factorisation fits them all (never the normal equations): a singular value decomposition of the
centred regressors, each measured in steps of its variable's resolution (`resolution`). Directions
in which the regressors move no more than rounding alone would move them (variance below
step^2 / 12: a stuck sensor's lags, collinear sensors) are left out: the data cannot tell them
apart, and their coefficients stay at the minimum norm instead of growing without bound. The
parameter covariance is Sigma kron (X'X)^+ from the same factor ((X'X)^-1 when nothing is left
out). Orders are chosen by AIC or BIC over a grid.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from scipy.linalg import svd

from ..names import plural
from ..errors import DataError
from .em import columns, segments
from .basis import LaggedMode, Lags, lag_inputs
from .resolution import ROUNDING, at_least, noise_floor, resolution


@dataclass(frozen=True)
class ArxFit:
    """Coefficients theta (p, ny), one column per output, rows in regressor order (output lags
    1..na, each an ny-vector; input lags nk..nk+nb-1, each an nu-vector; the offset); the residual
    covariance (unbiased), (X'X)^+ (the inverse when the regressors are of full rank), the number of
    equations and the information criteria."""

    lags: Lags
    theta: np.ndarray
    noise: np.ndarray
    gram_inv: np.ndarray
    n: int
    aic: float
    bic: float

    @property
    def order(self) -> tuple[int, int, int]:
        """(na, nb, nk)."""
        return self.lags.na, self.lags.nb, self.lags.nk

    @property
    def cov(self) -> np.ndarray:
        """Covariance of theta stacked output by output (theta.T.ravel()): Sigma kron (X'X)^+."""
        return np.kron(self.noise, self.gram_inv)

    def lagged(self) -> LaggedMode:
        """This fit as a mode in the lagged basis of order lags.n: EM's starting point, with the
        equation-error covariance split evenly between process and measurement noise."""
        ny = self.theta.shape[1]
        n, (na, nb, nk) = self.lags.n, self.order
        nu = (len(self.theta) - 1 - na * ny) // nb if nb else 0
        Phi = np.zeros((ny, n * ny))
        Phi[:, :na * ny] = self.theta[:na * ny].T
        Psi = np.zeros((ny, n * nu))
        Psi[:, nk * nu:(nk + nb) * nu] = self.theta[na * ny:na * ny + nb * nu].T
        return LaggedMode(self.lags, Phi, Psi, self.theta[-1].copy(), 0.5 * self.noise, 0.5 * self.noise)


def regressors(y, u, lags: Lags, start: int) -> tuple[np.ndarray, np.ndarray]:
    """(X, Y) for the equations t = start..T-1 with every value measured (rows with NaN left out)."""
    n = lags.n
    rows = np.arange(start, len(y))
    ylags = np.hstack([y[rows - i] for i in range(1, lags.na + 1)] or [np.empty((len(rows), 0))])
    ulags = lag_inputs(u, n)[rows][:, lags.nk * u.shape[1]:(lags.nk + lags.nb) * u.shape[1]]
    X = np.hstack([ylags, ulags, np.ones((len(rows), 1))])
    Y = y[rows]
    complete = np.isfinite(X).all(axis=1) & np.isfinite(Y).all(axis=1)
    return X[complete], Y[complete]


def fit_arx(y, u, na, nb, nk=0, start=None, steps=None) -> ArxFit:
    """Least-squares ARX fit of outputs y (T, ny) or (T,) on inputs u (T, nu), or of several
    experiments of one model (lists of such arrays), whose equations are pooled; `start` is each
    experiment's first equation's time index (default: the largest lag, so that fits of different
    orders can share it). Equations touching a missing value (NaN) are left out.

    `steps`: the resolution of each output and input (ny + nu,), by default read from these data.
    Regressor directions that move no more than rounding are left out, and the residual covariance
    is kept at least the rounding variance (its log-determinant stays finite for a constant output).
    """
    parts = segments(y, u)
    nu = parts[0][1].shape[1]
    lags = Lags(na, nb if nu else 0, nk if nu else 0)
    start = max(na, nk + nb - 1) if start is None else start
    X, Y = (np.vstack(blocks) for blocks in zip(*(regressors(yk, uk, lags, start) for yk, uk in parts)))
    N, p = X.shape
    if N <= p:
        raise DataError(f"ARX({na},{nb},{nk}) has {p} parameters per output but only {plural(N, 'complete equation')}")
    ny = Y.shape[1]
    if steps is None:
        steps = resolution([np.hstack(part) for part in parts])
    scale = np.r_[np.tile(steps[:ny], na), np.tile(steps[ny:], lags.nb)]
    centre, level = X[:, :-1].mean(axis=0), Y.mean(axis=0)
    U, s, Vt = svd((X[:, :-1] - centre) / scale / np.sqrt(N), full_matrices=False)
    keep = s ** 2 > ROUNDING  # in steps: directions that move more than rounding to them would
    V = Vt[keep].T / scale[:, None]  # back to the regressors' own units
    slopes = V @ ((U[:, keep].T @ (Y - level)) / s[keep, None]) / np.sqrt(N)
    theta = np.vstack([slopes, level - centre @ slopes])
    # (X'X)^+ for [slopes; offset]: the centred slopes' own, and the offset through the means.
    to_theta = np.vstack([np.eye(p - 1), -centre])
    gram_inv = to_theta @ (V / s[keep] ** 2) @ V.T @ to_theta.T / N
    gram_inv[-1, -1] += 1.0 / N
    E = Y - X @ theta
    _, logdet = np.linalg.slogdet(at_least(E.T @ E / N, noise_floor(steps[:ny])))
    k = p * ny
    return ArxFit(lags=lags, theta=theta, noise=(E.T @ E) / (N - p), gram_inv=gram_inv, n=N,
                  aic=N * logdet + 2 * k, bic=N * logdet + k * np.log(N))


def select_order(data, max_na=4, max_nb=4, max_nk=0, criterion="bic", steps=None) -> tuple[int, int, int]:
    """The order (na >= 1, nb >= 1, nk) minimising AIC or BIC summed over experiments [(y, u), ...].

    Every order is fitted on the same equations of each experiment, so the criteria compare; `steps`
    is the outputs' and inputs' resolution, by default read from all the experiments.
    """
    if criterion not in ("aic", "bic"):
        raise ValueError(f"criterion must be 'aic' or 'bic', not {criterion!r}")
    start = max(max_na, max_nk + max_nb - 1)
    if steps is None:
        steps = resolution([np.hstack(columns(y, u)) for y, u in data])
    grid = itertools.product(range(1, max_na + 1), range(1, max_nb + 1), range(max_nk + 1))
    return min(grid, key=lambda order: sum(getattr(fit_arx(y, u, *order, start=start, steps=steps), criterion)
                                           for y, u in data))
