"""ARX least squares: y_t + a1 y_{t-1} + ... + a_na y_{t-na} = sum_j b_j u_{t-nk-j} + c + e_t.

The b0 term (nk = 0) lets u_t act on y_t in the same step, as in the model's x_t = A x_{t-1} + F u_t.
Solved by a QR-based least-squares solve (never the normal equations), with the parameter
covariance; orders chosen by AIC or BIC over a grid; converted to observer canonical state space.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from scipy.linalg import qr, solve_triangular

from ..errors import DataError
from .statespace import StateSpace, companion


@dataclass(frozen=True)
class ArxFit:
    """Fitted coefficients a (na,), b (nb, nu) for lags nk..nk+nb-1, offset c, their covariance
    (in the order a, b row by row, c), residual variance, and the information criteria."""

    a: np.ndarray
    b: np.ndarray
    nk: int
    c: float
    cov: np.ndarray
    sigma2: float
    n: int
    aic: float
    bic: float

    @property
    def order(self) -> tuple[int, int, int]:
        """(na, nb, nk)."""
        return len(self.a), len(self.b), self.nk

    def to_statespace(self, u0, y0, n=None) -> StateSpace:
        """This model in observer canonical form (see `observer_form`), starting at output y0 under u0."""
        return observer_form(self.a, self.b, self.nk, self.c, self.sigma2, u0, y0, n)


def observer_form(a, b, nk, c, noise_var, u0, y0, n=None) -> StateSpace:
    """State space of y_t + a1 y_{t-1} + ... = sum_j b_j u_{t-nk-j} + c with n >= max(na, nk+nb) states.

    Observer canonical form: C = [1 0 ...], so x1 is the noise-free output. The equation-error
    variance is split evenly between process and measurement noise (EM's starting point), and the
    initial state is the steady state at input u0 with x1 moved to the first output y0.
    """
    b = np.atleast_2d(np.asarray(b, float))
    n = n or max(len(a), nk + len(b))
    a_full = np.zeros(n)
    a_full[:len(a)] = a
    F = np.zeros((n, b.shape[1]))
    F[nk:nk + len(b)] = b
    f = np.eye(n)[0] * c
    ss = StateSpace(A=companion(a_full), F=F, f=f, C=np.eye(1, n), G=np.zeros((1, b.shape[1])),
                    g=np.zeros(1), Q=0.5 * noise_var * np.eye(n), R=np.array([[0.5 * noise_var]]),
                    mu0=np.zeros(n), Sigma0=noise_var * np.eye(n))
    x0 = ss.steady_state(u0)
    x0[0] = y0
    return ss.replace(mu0=x0)


def fit(y, u, na, nb, nk=0, start=None) -> ArxFit:
    """Least-squares ARX fit of one output y (T,) on inputs u (T, nu); `start` is the first equation's
    time index (defaults to the largest lag, so that fits of different orders can share it).
    Equations touching a missing value (NaN) are left out."""
    y = np.asarray(y, float).ravel()
    u = np.asarray(u, float).reshape(len(y), -1)
    lag = max(na, nk + nb - 1)
    start = lag if start is None else start
    rows = np.arange(start, len(y))
    cols = [-y[rows - i] for i in range(1, na + 1)]
    cols += [u[rows - nk - j, m] for j in range(nb) for m in range(u.shape[1])]
    X = np.column_stack(cols + [np.ones(len(rows))])
    complete = np.isfinite(X).all(axis=1) & np.isfinite(y[rows])
    X, rows = X[complete], rows[complete]
    n, p = X.shape
    if n <= p:
        raise DataError(f"ARX({na},{nb},{nk}) has {p} parameters but only {n} complete equations")
    Qm, Rm = qr(X, mode="economic")
    theta = solve_triangular(Rm, Qm.T @ y[rows])
    rss = float(np.sum((y[rows] - X @ theta) ** 2))
    sigma2 = rss / (n - p)
    Rinv = solve_triangular(Rm, np.eye(p))
    nu = u.shape[1]
    return ArxFit(a=theta[:na], b=theta[na:na + nb * nu].reshape(nb, nu), nk=nk, c=float(theta[-1]),
                  cov=sigma2 * Rinv @ Rinv.T, sigma2=sigma2, n=n,
                  aic=n * np.log(rss / n) + 2 * p, bic=n * np.log(rss / n) + p * np.log(n))


def select_order(data, max_na=4, max_nb=4, max_nk=0, criterion="bic") -> tuple[int, int, int]:
    """The order (na >= 1, nb >= 1, nk) minimising AIC or BIC summed over experiments [(y, u), ...].

    Every order is fitted on the same equations of each experiment, so the criteria compare.
    One order for all experiments keeps a mode bank's modes the same size.
    """
    if criterion not in ("aic", "bic"):
        raise ValueError(f"criterion must be 'aic' or 'bic', not {criterion!r}")
    start = max(max_na, max_nk + max_nb - 1)
    grid = itertools.product(range(1, max_na + 1), range(1, max_nb + 1), range(max_nk + 1))
    return min(grid, key=lambda order: sum(getattr(fit(y, u, *order, start=start), criterion) for y, u in data))
