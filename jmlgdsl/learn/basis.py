"""The state basis every mode of a learned bank shares, and EM inside it.

A mode of order n is written over its recent noise-free outputs s and its inputs u,

    x_t = (s_t, s_{t-1}, ..., s_{t-n+1}, u_t, ..., u_{t-n+2}),
    s_t = Phi_1 s_{t-1} + ... + Phi_n s_{t-n} + Psi_0 u_t + ... + Psi_{n-1} u_{t-n+1} + c + w_t,   w ~ N(0, Q)
    y_t = s_t + v_t,                                                                               v ~ N(0, R)

with the mode's coefficients and offset in the first ny rows and pure shifts below. A state then
means the same thing in every mode, so a jump Markov filter that carries it through a switch hands
the new mode what it needs; a mode of lower order has zero coefficients on the older lags.

EM fits the output lags alone: the inputs are known, so their lags enter as extra inputs
(`lag_inputs`), and the M-step updates only the first rows' free coefficients, Q and R.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from functools import partial

import numpy as np
from scipy.linalg import block_diag

from .em import EMResult, em, regress, segments
from .resolution import at_least, noise_floor, resolution
from .statespace import StateSpace


@dataclass(frozen=True)
class Lags:
    """Which coefficients a mode may use: output lags 1..na and input lags nk..nk+nb-1 (0: same step)."""

    na: int
    nb: int = 0
    nk: int = 0

    @property
    def n(self) -> int:
        """The order: how many output lags the state holds."""
        return max(self.na, self.nk + self.nb, 1)

    def free(self, ny: int, nu: int) -> np.ndarray:
        """Mask over the regressors [s_{t-1}..s_{t-n}, u_t..u_{t-n+1}, 1] of the fitted coefficients."""
        lag = np.arange(self.n)
        return np.concatenate([np.repeat(lag < self.na, ny),
                               np.repeat((lag >= self.nk) & (lag < self.nk + self.nb), nu), [True]])


def lag_inputs(u, n: int) -> np.ndarray:
    """(T, n nu): row t holds u_t, u_{t-1}, ..., u_{t-n+1}; inputs before the first sample repeat it."""
    u = np.asarray(u, float)
    T = len(u)
    padded = np.vstack([np.repeat(u[:1], n - 1, axis=0), u])
    return np.hstack([padded[n - 1 - j:n - 1 - j + T] for j in range(n)])


def state_names(outputs, inputs, n: int) -> tuple[str, ...]:
    """Names of the shared basis of order n: OUTPUT_lag1..n, then INPUT_lag1..n-1. In x_t = A x_{t-1}
    + F u_t the state read by A is one step old, so `temp_lag1` holds the noise-free temp of the
    previous step when the next is predicted."""
    return (tuple(f"{y}_lag{i}" for i in range(1, n + 1) for y in outputs)
            + tuple(f"{u}_lag{i}" for i in range(1, n) for u in inputs))


@dataclass(frozen=True)
class LaggedMode:
    """One mode of order n: Phi (ny, n ny) on s_{t-1}..s_{t-n}, Psi (ny, n nu) on u_t..u_{t-n+1},
    offset c (ny,), noise covariances Q, R (ny, ny), the free coefficients (lags) and the mean and
    covariance of the initial output lags (s_0..s_{1-n}; None until EM has estimated them)."""

    lags: Lags
    Phi: np.ndarray
    Psi: np.ndarray
    c: np.ndarray
    Q: np.ndarray
    R: np.ndarray
    mu0: np.ndarray | None = None
    Sigma0: np.ndarray | None = None

    @property
    def ny(self) -> int:
        """Number of outputs."""
        return self.Phi.shape[0]

    @property
    def n(self) -> int:
        """The order (output lags in the state)."""
        return self.Phi.shape[1] // self.ny

    @property
    def nu(self) -> int:
        """Number of inputs."""
        return self.Psi.shape[1] // self.n

    def reduced(self) -> StateSpace:
        """The model EM fits: the output lags as the state, `lag_inputs(u, n)` as the input."""
        ny, m = self.ny, self.n * self.ny
        A = np.eye(m, k=-ny)
        A[:ny] = self.Phi
        F = np.zeros((m, self.Psi.shape[1]))
        F[:ny] = self.Psi
        return StateSpace(A=A, F=F, f=np.r_[self.c, np.zeros(m - ny)], C=np.eye(ny, m), G=np.zeros((ny, F.shape[1])),
                          g=np.zeros(ny), Q=block_diag(self.Q, np.zeros((m - ny, m - ny))), R=self.R,
                          mu0=self.mu0, Sigma0=self.Sigma0)

    def from_reduced(self, ss: StateSpace) -> "LaggedMode":
        """The coefficients, noise and initial lags of a fitted `reduced` model."""
        ny = self.ny
        return LaggedMode(self.lags, ss.A[:ny].copy(), ss.F[:ny].copy(), ss.f[:ny].copy(), ss.Q[:ny, :ny].copy(),
                          ss.R, ss.mu0, ss.Sigma0)

    def poles(self) -> np.ndarray:
        """Eigenvalues of the output-lag dynamics, by decreasing modulus."""
        return self.reduced().poles()

    def statespace(self, u0, n: int | None = None) -> StateSpace:
        """The realisation in the shared basis of order n (default: the mode's own), input u.

        The initial output lags are the mode's own (the oldest repeated to fill a larger basis) and
        the input lags start known, at u0, as `lag_inputs` assumes.
        """
        n = self.n if n is None else n
        ny, nu, extra = self.ny, self.nu, n - self.n
        Phi = np.hstack([self.Phi, np.zeros((ny, extra * ny))])
        Psi = np.hstack([self.Psi, np.zeros((ny, extra * nu))])
        m, k = n * ny, (n - 1) * nu
        A = np.zeros((m + k, m + k))
        A[:m, :m] = np.eye(m, k=-ny)
        A[:ny, :m], A[:ny, m:] = Phi, Psi[:, nu:]
        F = np.zeros((m + k, nu))
        F[:ny] = Psi[:, :nu]
        if k:  # u_t enters the first input lag; older input lags shift down
            F[m:m + nu] = np.eye(nu)
            A[m + nu:, m:m + k - nu] = np.eye(k - nu)
        mu0 = np.r_[self.mu0, np.tile(self.mu0[-ny:], extra), np.tile(np.asarray(u0, float), n - 1)]
        Sigma0 = block_diag(self.Sigma0, *[self.Sigma0[-ny:, -ny:]] * extra, np.zeros((k, k)))
        return StateSpace(A=A, F=F, f=np.r_[self.c, np.zeros(m + k - ny)], C=np.eye(ny, m + k),
                          G=np.zeros((ny, nu)), g=np.zeros(ny), Q=block_diag(self.Q, np.zeros((m + k - ny,) * 2)),
                          R=self.R, mu0=mu0, Sigma0=Sigma0)


#: Where a learned mode whose poles EM left on or outside the unit circle has its largest pole.
MAX_RADIUS = 0.999


def stabilised(mode: LaggedMode, level) -> LaggedMode:
    """The mode with every pole scaled by MAX_RADIUS / (its largest modulus): Phi_i -> rho^i Phi_i
    scales the poles of the lag polynomial by rho. The offset moves so that the one-step prediction
    from the outputs' mean `level` at every lag is unchanged, so the mode keeps its level and now
    has a steady state near it."""
    rho = MAX_RADIUS / np.abs(mode.poles()).max()
    ny = mode.ny
    Phi = mode.Phi * np.repeat(rho ** np.arange(1, mode.n + 1), ny)
    c = mode.c + (mode.Phi - Phi) @ np.tile(np.asarray(level, float), mode.n)
    return LaggedMode(mode.lags, Phi, mode.Psi, c, mode.Q, mode.R, mode.mu0, mode.Sigma0)


def m_step(ss: StateSpace, y, v, e, free, floor) -> StateSpace:
    """EM's M-step inside the lagged structure (y, v: the segments' outputs and lagged inputs
    stacked; e: their `Moments`): the first ny rows' free coefficients on [s_{t-1}.., u_t.., 1]
    with Q by expected least squares, R from the expected output residuals (on the fully measured
    steps), both kept at least diag(floor), the rounding variance, and the initial lags from the
    smoothed s_0..s_{1-n}. Raising the eigenvalues of the floor-whitened covariance to 1 is the
    exact maximiser under that bound, so EM still cannot lower the likelihood."""
    ny, nx = ss.C.shape
    k = int(free[:nx].sum())  # the free output lags come first
    Z = np.hstack([e.prev, v, np.ones((len(v), 1))])[:, free]
    W, Q = regress(e.mean[:, :ny], Z, e.cov.sum()[:ny, :ny], e.prev_cov.sum()[:k, :k], e.cross.sum()[:ny, :k])
    Q = at_least(Q, floor)
    coef = np.zeros((ny, len(free)))
    coef[:, free] = W
    A, F, f = ss.A.copy(), ss.F.copy(), ss.f.copy()
    A[:ny], F[:ny], f[:ny] = coef[:, :nx], coef[:, nx:-1], coef[:, -1]
    o = ~np.isnan(y).any(axis=1)
    r = y[o] - e.mean[o][:, :ny]
    R = at_least((r.T @ r + e.cov.sum(where=o)[:ny, :ny]) / max(int(o.sum()), 1), floor)
    mu0, Sigma0 = e.initial()
    return ss.replace(A=A, F=F, f=f, Q=block_diag(Q, np.zeros((nx - ny,) * 2)), R=R, mu0=mu0, Sigma0=Sigma0)


def transformed(mode: LaggedMode, dy, my, du, mu) -> LaggedMode:
    """The same mode for outputs dy * y + my and inputs du * u + mu (dy, du > 0, one per channel).

    Exact in both directions, so the data can be standardised for fitting and the fitted mode
    mapped back: Phi_i -> D Phi_i D^-1, Psi_j -> D Psi_j E^-1, Q -> D Q D, R -> D R D, with the
    offset absorbing the shifts.
    """
    dy, my, du, mu = (np.asarray(v, float) for v in (dy, my, du, mu))
    n = mode.n
    ky = np.tile(dy, n)
    Phi = dy[:, None] * mode.Phi / ky
    Psi = dy[:, None] * mode.Psi / np.tile(du, n)
    c = dy * mode.c + my - Phi @ np.tile(my, n) - Psi @ np.tile(mu, n)
    scale = np.outer(dy, dy)
    mu0 = None if mode.mu0 is None else ky * mode.mu0 + np.tile(my, n)
    Sigma0 = None if mode.Sigma0 is None else np.outer(ky, ky) * mode.Sigma0
    return LaggedMode(mode.lags, Phi, Psi, c, scale * mode.Q, scale * mode.R, mu0, Sigma0)


def fit_em(start: LaggedMode, y, u, max_iter=100, tol=1e-5, steps=None) -> tuple[LaggedMode, EMResult]:
    """EM from `start` inside its structure, on one experiment (arrays) or several of the same mode
    (lists), standardised so that sensors in very different units are fitted alike (the SPD floor of
    the covariances is relative to their largest eigenvalue); the result is mapped back exactly,
    and the log-likelihood with it. Without initial lags, they start at the first measured output
    with the noise's spread at every lag.

    `steps`: each output's resolution (by default read from these data). Both noises are kept at
    least its rounding variance (`resolution.noise_floor`): the data cannot tell a smaller process
    noise from none, nor a smaller measurement noise from rounding. An output is scaled by its
    standard deviation or, when it moves less (a constant output), by its resolution.
    """
    parts = segments(y, u)
    ys, us = np.vstack([p[0] for p in parts]), np.vstack([p[1] for p in parts])
    steps = resolution(ys) if steps is None else np.asarray(steps, float)
    my, sy = np.nanmean(ys, axis=0), np.maximum(np.nanstd(ys, axis=0), steps)
    mu, su = us.mean(axis=0), us.std(axis=0)
    su = np.where(su > 0, su, 1.0)
    floor = noise_floor(steps / sy)
    scaled = transformed(start, 1 / sy, -my / sy, 1 / su, -mu / su)
    Q, R = at_least(scaled.Q, floor), at_least(scaled.R, floor)
    if start.mu0 is None:
        first = np.array([column[np.isfinite(column)][0] for column in parts[0][0].T])
        mu0, Sigma0 = np.tile((first - my) / sy, start.n), np.kron(np.eye(start.n), Q + R)
    else:
        mu0, Sigma0 = scaled.mu0, scaled.Sigma0
    scaled = LaggedMode(start.lags, scaled.Phi, scaled.Psi, scaled.c, Q, R, mu0, Sigma0)
    free = start.lags.free(start.ny, len(mu))
    result = em(scaled.reduced(), [(yk - my) / sy for yk, _ in parts],
                [lag_inputs((uk - mu) / su, start.n) for _, uk in parts], max_iter, tol,
                update=partial(m_step, free=free, floor=floor))
    fitted = transformed(scaled.from_reduced(result.model), sy, my, su, mu)
    measured = sum((~np.isnan(yk)).sum(axis=0) for yk, _ in parts)
    jacobian = float(np.log(sy) @ measured)  # log |d y_scaled / d y| over the data
    return fitted, dataclasses.replace(result, model=fitted.reduced(), loglik=result.loglik - jacobian)
