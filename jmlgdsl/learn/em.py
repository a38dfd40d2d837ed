"""Maximum-likelihood fit of one mode's state-space model by expectation-maximisation.

E-step: the shared Kalman kernel filters forward, a Rauch-Tung-Striebel pass smooths back and gives
the lag-one cross-covariances. M-step (Ghahramani & Hinton 1996, with inputs): closed-form
regressions of x_t on [x_{t-1}, u_t, 1] for [A F f] and of y_t on [x_t, u_t, 1] for [C G g], their
residual second moments for Q and R, and the smoothed x_0 for the initial state. Missing outputs
(NaN) are allowed: a partly measured vector informs the states; the output map is fitted on the
fully measured time steps.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from ..infer import kalman
from ..infer.kalman import SETTLED
from .statespace import StateSpace

#: Eigenvalues of fitted covariances are kept at least this fraction of the largest one.
SPD_FLOOR = 1e-10


@dataclass(frozen=True)
class Smoothed:
    """E-step output: smoothed means (T+1, nx) and covariances of x_0..x_T, lag-one
    cross-covariances Cov(x_t, x_{t-1}) for t = 1..T, and the log-likelihood log p(y_1:T)."""

    mean: np.ndarray
    cov: np.ndarray
    cross: np.ndarray
    loglik: float


@dataclass(frozen=True)
class Moments:
    """What the M-step takes from the E-step of one or more segments (experiments): for every step
    t >= 1 of every segment, stacked as the segments' data are, the smoothed means and covariances
    of x_{t-1} (prev) and x_t and their cross-covariance; each segment's smoothed x_0; the summed
    log-likelihood."""

    prev: np.ndarray
    prev_cov: np.ndarray
    mean: np.ndarray
    cov: np.ndarray
    cross: np.ndarray
    first: np.ndarray
    first_cov: np.ndarray
    loglik: float

    @classmethod
    def of(cls, parts: list[Smoothed]) -> "Moments":
        """The moments of segments smoothed one by one."""
        return cls(np.concatenate([e.mean[:-1] for e in parts]), np.concatenate([e.cov[:-1] for e in parts]),
                   np.concatenate([e.mean[1:] for e in parts]), np.concatenate([e.cov[1:] for e in parts]),
                   np.concatenate([e.cross for e in parts]), np.array([e.mean[0] for e in parts]),
                   np.array([e.cov[0] for e in parts]), sum(e.loglik for e in parts))

    def initial(self) -> tuple[np.ndarray, np.ndarray]:
        """The initial state's mean and covariance: one segment's smoothed x_0, or the moments of the
        segments' x_0 taken together."""
        mu0 = self.first.mean(axis=0)
        spread = self.first - mu0
        return mu0, spd(self.first_cov.mean(axis=0) + spread.T @ spread / len(spread))


@dataclass(frozen=True)
class EMResult:
    """The fitted model, the log-likelihood of every parameter set visited, and how it stopped."""

    model: StateSpace
    loglik: np.ndarray
    converged: bool

    @property
    def iterations(self) -> int:
        """EM iterations whose parameters were kept."""
        return len(self.loglik) - 1


@dataclass(frozen=True)
class Filtered:
    """Forward pass: predicted means/covariances of x_1..x_T, filtered ones of x_0..x_T, the
    innovations y_t - E[y_t | y_1:t-1] (NaN where not measured), the log-likelihood, and the steps
    whose covariances were reused once settled."""

    mean_pred: np.ndarray
    cov_pred: np.ndarray
    mean: np.ndarray
    cov: np.ndarray
    innovation: np.ndarray
    loglik: float
    settled: np.ndarray


def columns(y, u=None) -> tuple[np.ndarray, np.ndarray]:
    """Outputs as (T, ny) and inputs as (T, nu) float arrays; no inputs gives u of shape (T, 0)."""
    y = np.asarray(y, float).reshape(len(y), -1)
    return y, np.zeros((len(y), 0)) if u is None else np.asarray(u, float).reshape(len(y), -1)


def segments(y, u=None) -> list[tuple[np.ndarray, np.ndarray]]:
    """[(y, u), ...] as `columns` from one experiment (arrays) or several (lists of arrays)."""
    if isinstance(y, (list, tuple)):
        return [columns(yk, uk) for yk, uk in zip(y, [None] * len(y) if u is None else u)]
    return [columns(y, u)]


def forward(ss: StateSpace, y, u) -> Filtered:
    """Kalman filter with NaN-masked outputs over y (T, ny) with inputs u (T, nu).

    The covariances do not depend on the data, only on which outputs are measured: once a fully
    measured step leaves the predicted covariance unchanged to SETTLED relative, the filter reuses
    that step's covariances, gain and innovation factor until an output goes missing.
    """
    y = np.asarray(y, float)
    T, nx = len(y), ss.nx
    b = u @ ss.F.T + ss.f
    c = u @ ss.G.T + ss.g
    mu_p, Sig_p = np.empty((T, nx)), np.empty((T, nx, nx))
    mu_f, Sig_f = np.empty((T + 1, nx)), np.empty((T + 1, nx, nx))
    mu_f[0], Sig_f[0] = ss.mu0, ss.Sigma0
    innov = np.full(y.shape, np.nan)
    measured = ~np.isnan(y)
    full = measured.all(axis=1)
    settled = np.zeros(T, bool)
    steady = None
    quad, loglik = 0.0, 0.0
    for t in range(T):
        m = slice(None) if full[t] else measured[t]  # a view, not a copy, when every output is measured
        if steady is not None and full[t]:
            Sig_p[t], Sig_f[t + 1], gain_t, Linv, logdet = steady
            settled[t] = True
        else:
            Sig_p[t] = kalman.predict_cov(Sig_f[t], ss.A, ss.Q)
            S, CS = kalman.innovation_cov(Sig_p[t], ss.C[m], ss.R if full[t] else ss.R[np.ix_(m, m)])
            gain_t, Linv, logdet = kalman.gain(S, CS)
            Sig_f[t + 1] = kalman.symmetrize(Sig_p[t] - CS.T @ gain_t)
            steady = None
            if full[t] and t and full[t - 1] and (np.abs(Sig_p[t] - Sig_p[t - 1]).max()
                                                  <= SETTLED * np.abs(Sig_p[t]).max()):
                steady = Sig_p[t], Sig_f[t + 1], gain_t, Linv, logdet
        mu_p[t] = ss.A @ mu_f[t] + b[t]
        r = y[t, m] - ss.C[m] @ mu_p[t] - c[t, m]
        innov[t, m] = r
        mu_f[t + 1] = mu_p[t] + gain_t.T @ r
        z = Linv @ r
        quad += z @ z
        loglik -= 0.5 * (logdet + len(r) * kalman.LOG_2PI)
    return Filtered(mu_p, Sig_p, mu_f, Sig_f, innov, loglik - 0.5 * quad, settled)


def smooth(ss: StateSpace, y, u) -> Smoothed:
    """Rauch-Tung-Striebel smoother over the forward pass for y (T, ny) and inputs u (T, nu).

    Where the forward covariances have settled, the smoothed covariance settles too (going back
    from the end); once it stops changing it is reused like the forward ones.
    """
    fw = forward(ss, y, u)
    constant = fw.settled & np.r_[False, fw.settled[:-1]]  # Sig_f[t], Sig_p[t] and so J[t] as at t - 1
    # Smoother gains J_t = Sig_f[t] A' Sig_p[t]^-1 (Sig_p symmetric), solved at once where they change.
    J = np.empty_like(fw.cov_pred)
    solve = ~constant
    J[solve] = np.swapaxes(np.linalg.solve(fw.cov_pred[solve], ss.A @ fw.cov[:-1][solve]), 1, 2)
    J[constant] = J[np.maximum.accumulate(np.where(solve, np.arange(len(J)), 0))[constant]]
    mu_s, Sig_s = fw.mean.copy(), fw.cov.copy()
    reused = np.zeros(len(J) + 1, bool)  # Sig_s[t] copied from the settled one
    steady = None
    for t in range(len(J) - 1, -1, -1):
        mu_s[t] = fw.mean[t] + J[t] @ (mu_s[t + 1] - fw.mean_pred[t])
        if steady is not None and constant[t]:
            Sig_s[t], reused[t] = steady, True
            continue
        Sig_s[t] = kalman.symmetrize(fw.cov[t] + J[t] @ (Sig_s[t + 1] - fw.cov_pred[t]) @ J[t].T)
        steady = None
        if constant[t] and t + 1 < len(J) and constant[t + 1] and (
                np.abs(Sig_s[t] - Sig_s[t + 1]).max() <= SETTLED * np.abs(Sig_s[t]).max()):
            steady = Sig_s[t]
    # Cov(x_{t+1}, x_t) = Sig_s[t+1] J_t': the same wherever both factors are the settled ones.
    same = constant & reused[1:] & np.r_[constant[1:] & reused[2:], False]
    cross = np.empty_like(J)
    cross[~same] = Sig_s[1:][~same] @ np.swapaxes(J[~same], 1, 2)
    later = np.minimum.accumulate(np.where(same, len(J), np.arange(len(J)))[::-1])[::-1]
    cross[same] = cross[later[same]]
    return Smoothed(mu_s, Sig_s, cross, fw.loglik)


def m_step(ss: StateSpace, y, u, e: Moments, offset=True, feedthrough=True) -> StateSpace:
    """Closed-form parameter update from the smoothed moments (y, u: the segments' data stacked).

    offset: learn f (and g with feedthrough); feedthrough: learn G (else G, g stay as they are).
    Parameters not learned are held at their current values.
    """
    T = len(y)
    ones = np.ones((T, 1 if offset else 0))
    # State equation: x_t on z_t = [x_{t-1}, u_t, 1].
    Z = np.hstack([e.prev, u, ones])
    X = e.mean - (0 if offset else ss.f)
    W, Q = regress(X, Z, e.cov.sum(0), e.prev_cov.sum(0), e.cross.sum(0))
    nx, nu = ss.nx, u.shape[1]
    A, F = W[:, :nx], W[:, nx:nx + nu]
    f = W[:, nx + nu] if offset else ss.f
    # Output equation on the fully measured steps: y_t on r_t = [x_t, u_t, 1] (or x_t alone).
    o = ~np.isnan(y).any(axis=1)
    xs, Sx = e.mean[o], e.cov[o].sum(0)
    if feedthrough:
        H, R = regress(y[o] - (0 if offset else ss.g), np.hstack([xs, u[o], ones[o]]), None, Sx, None)
        C, G = H[:, :nx], H[:, nx:nx + nu]
        g = H[:, nx + nu] if offset else ss.g
    else:
        H, R = regress(y[o] - u[o] @ ss.G.T - ss.g, xs, None, Sx, None)
        C, G, g = H, ss.G, ss.g
    mu0, Sigma0 = e.initial()
    return StateSpace(A=A, F=F, f=f, C=C, G=G, g=g, Q=Q, R=R, mu0=mu0, Sigma0=Sigma0)


def regress(X, Z, Sxx_cov, Szz_cov, Sxz_cov):
    """Expected least squares of X (n, p) on Z (n, q) whose first columns are latent states.

    The *_cov terms add the summed posterior covariances to the moment matrices: Sxx_cov to X'X
    (None when X is observed), Szz_cov to the state block of Z'Z and Sxz_cov to the state block of
    X'Z. Returns the coefficients and the residual covariance (kept symmetric positive definite).
    """
    n, k = len(X), Szz_cov.shape[0]
    Szz = Z.T @ Z
    Szz[:k, :k] += Szz_cov
    Sxz = X.T @ Z
    if Sxz_cov is not None:
        Sxz[:, :k] += Sxz_cov
    Sxx = X.T @ X + (0 if Sxx_cov is None else Sxx_cov)
    W = np.linalg.solve(Szz, Sxz.T).T
    return W, spd((Sxx - W @ Sxz.T) / n)


def spd(S) -> np.ndarray:
    """Symmetric positive definite version of S: eigenvalues floored at SPD_FLOOR times the largest."""
    w, V = np.linalg.eigh(kalman.symmetrize(S))
    w = np.maximum(w, SPD_FLOOR * max(w.max(), np.finfo(float).tiny))
    return kalman.symmetrize((V * w) @ V.T)


def em(ss: StateSpace, y, u=None, max_iter=100, tol=1e-5, offset=True, feedthrough=True, update=None) -> EMResult:
    """Run EM from `ss` until the log-likelihood gains less than tol relative, or max_iter iterations.

    y, u: one experiment's arrays, or lists of several experiments (segments) of the same model,
    each smoothed on its own; their moments are pooled in the M-step. `update(ss, y, u, moments)` replaces the free M-step (`m_step` with offset and feedthrough) by
    one that keeps a structure, such as the lagged basis's.

    The log-likelihood cannot decrease in exact arithmetic; if it falls by more than rounding, the
    last good parameters are kept and a warning says so.
    """
    parts = segments(y, u)
    y, u = np.vstack([p[0] for p in parts]), np.vstack([p[1] for p in parts])

    def expect(model):
        return Moments.of([smooth(model, yk, uk) for yk, uk in parts])

    e = expect(ss)
    history = [e.loglik]
    converged = False
    for _ in range(max_iter):
        new = m_step(ss, y, u, e, offset, feedthrough) if update is None else update(ss, y, u, e)
        e_new = expect(new)
        gain = e_new.loglik - history[-1]
        if gain < -1e-9 * max(1.0, abs(history[-1])):
            warnings.warn(f"EM log-likelihood fell from {history[-1]:.10g} to {e_new.loglik:.10g}; "
                          "keeping the previous parameters", RuntimeWarning, stacklevel=2)
            break
        ss, e = new, e_new
        history.append(e.loglik)
        if gain < tol * abs(history[-2]):
            converged = True
            break
    return EMResult(ss, np.array(history), converged)
