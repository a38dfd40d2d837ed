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
from .statespace import StateSpace

#: Eigenvalues of fitted covariances are kept at least this fraction of the largest one.
SPD_FLOOR = 1e-10


@dataclass(frozen=True)
class StepMatrices:
    """Per-step matrices kept once per run of equal ones: step t's matrix is distinct[index[t]].
    Settled Kalman covariances repeat for most steps, so storing, reading and summing them costs
    per run, not per step (at 50 states a step's covariance is 20 kB)."""

    distinct: np.ndarray  # (runs, a, b)
    index: np.ndarray  # (T,) non-decreasing

    @classmethod
    def of(cls, distinct, new) -> "StepMatrices":
        """The steps' matrices from the distinct ones and a mask (T,) that is True where a new one starts."""
        return cls(np.asarray(distinct), np.cumsum(new) - 1)

    @classmethod
    def concatenate(cls, parts) -> "StepMatrices":
        """The steps of several StepMatrices one after another."""
        offsets = np.cumsum([0] + [len(p.distinct) for p in parts[:-1]])
        return cls(np.concatenate([p.distinct for p in parts]), np.concatenate([p.index + o for p, o in zip(parts, offsets)]))

    def __len__(self) -> int:
        return len(self.index)

    def __getitem__(self, t) -> np.ndarray:
        """Step t's matrix (or the stacked matrices of a slice or mask of steps)."""
        return self.distinct[self.index[t]]

    def part(self, steps: slice) -> "StepMatrices":
        """The same matrices for a slice of the steps."""
        return StepMatrices(self.distinct, self.index[steps])

    def sum(self, where=None) -> np.ndarray:
        """The sum of the steps' matrices (of the steps where `where` is True)."""
        counts = np.bincount(self.index if where is None else self.index[where], minlength=len(self.distinct))
        return np.tensordot(counts.astype(float), self.distinct, 1)


@dataclass(frozen=True)
class SmoothedStates:
    """E-step output: smoothed means (T+1, nx) and covariances of x_0..x_T, lag-one
    cross-covariances Cov(x_t, x_{t-1}) for t = 1..T, and the log-likelihood log p(y_1:T)."""

    mean: np.ndarray
    cov: StepMatrices
    cross: StepMatrices
    loglik: float


@dataclass(frozen=True)
class Moments:
    """What the M-step takes from the E-step of one or more segments (experiments): for every step
    t >= 1 of every segment, stacked as the segments' data are, the smoothed means and covariances
    of x_{t-1} (prev) and x_t and their cross-covariance; each segment's smoothed x_0; the summed
    log-likelihood."""

    prev: np.ndarray
    prev_cov: StepMatrices
    mean: np.ndarray
    cov: StepMatrices
    cross: StepMatrices
    first: np.ndarray
    first_cov: np.ndarray
    loglik: float

    @classmethod
    def of(cls, parts: list[SmoothedStates]) -> "Moments":
        """The moments of segments smoothed one by one."""
        return cls(np.concatenate([e.mean[:-1] for e in parts]),
                   StepMatrices.concatenate([e.cov.part(slice(None, -1)) for e in parts]),
                   np.concatenate([e.mean[1:] for e in parts]),
                   StepMatrices.concatenate([e.cov.part(slice(1, None)) for e in parts]),
                   StepMatrices.concatenate([e.cross for e in parts]), np.array([e.mean[0] for e in parts]),
                   np.array([e.cov[0] for e in parts]), sum(e.loglik for e in parts))

    def initial(self) -> tuple[np.ndarray, np.ndarray]:
        """The initial state's mean and covariance: one segment's smoothed x_0, or the moments of the
        segments' x_0 taken together."""
        mu0 = self.first.mean(axis=0)
        spread = self.first - mu0
        return mu0, spd(self.first_cov.mean(axis=0) + spread.T @ spread / len(spread))


@dataclass(frozen=True)
class EMResult:
    """The fitted model, the log-likelihood of every parameter set visited, and how it stopped:
    converged (the last gain below `tolerance`, in log-likelihood units), at the iteration cap, or
    because the log-likelihood fell (`fell`)."""

    model: StateSpace
    loglik: np.ndarray
    converged: bool
    tolerance: float = np.nan
    fell: bool = False

    @property
    def iterations(self) -> int:
        """EM iterations whose parameters were kept."""
        return len(self.loglik) - 1

    @property
    def gain(self) -> float:
        """The last iteration's gain in log-likelihood (NaN before any)."""
        return float(self.loglik[-1] - self.loglik[-2]) if len(self.loglik) > 1 else np.nan

    @property
    def remaining(self) -> float:
        """What EM would still gain were it run to the end, projected from its last three
        log-likelihoods (Aitken): near a maximum the gains shrink by a steady ratio r, so what
        remains is gain r / (1 - r). Infinite when the gains are not shrinking."""
        if len(self.loglik) < 3:
            return np.inf
        before, last = np.diff(self.loglik[-3:])
        ratio = last / before if before > 0 else np.inf
        return float(last * ratio / (1 - ratio)) if 0 <= ratio < 1 else np.inf


@dataclass(frozen=True)
class Filtered:
    """Forward pass: predicted means/covariances of x_1..x_T, filtered ones of x_0..x_T, the
    innovations y_t - E[y_t | y_1:t-1] (NaN where not measured), the log-likelihood, and the steps
    whose covariances were reused once settled."""

    mean_pred: np.ndarray
    cov_pred: StepMatrices
    mean: np.ndarray
    cov: StepMatrices
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
    measured step leaves the predicted covariance unchanged (`kalman.settled`), the filter reuses
    that step's covariances, gain and innovation factor until an output goes missing. The means
    then follow x_t|t = M x_t-1|t-1 + d_t with M and the gain fixed over each run of reused steps,
    so a step costs one matrix-vector product.
    """
    y = np.asarray(y, float)
    T, nx = len(y), ss.nx
    b = u @ ss.F.T + ss.f
    c = u @ ss.G.T + ss.g
    measured = ~np.isnan(y)
    full = measured.all(axis=1)
    new = np.ones(T, bool)  # step t's covariance work was done afresh (else: as at t - 1)
    pred, filt, pieces = [], [np.asarray(ss.Sigma0, float)], []
    steady = False
    for t in range(T):
        if steady and full[t]:
            new[t] = False
            continue
        m = measured[t]
        Sig_p = kalman.predict_cov(filt[-1], ss.A, ss.Q)
        S, CS = kalman.innovation_cov(Sig_p, ss.C[m], ss.R if full[t] else ss.R[np.ix_(m, m)])
        gain_t, Linv, logdet = kalman.gain(S, CS)
        steady = bool(full[t] and t and full[t - 1] and kalman.settled(Sig_p, pred[-1]))
        pred.append(Sig_p)
        filt.append(kalman.symmetrize(Sig_p - CS.T @ gain_t))
        pieces.append((m, gain_t.T, Linv, logdet))
    starts = np.flatnonzero(new)
    runs = list(zip(starts, np.r_[starts[1:], T], pieces))
    mu_f = np.empty((T + 1, nx))
    mu_f[0] = ss.mu0
    for s, e, (m, G, _, _) in runs:
        Cm = ss.C[m]
        M = ss.A - G @ (Cm @ ss.A)
        d = b[s:e] + (y[s:e, m] - c[s:e, m] - b[s:e] @ Cm.T) @ G.T
        for t in range(s, e):
            mu_f[t + 1] = M @ mu_f[t] + d[t - s]
    mu_p = mu_f[:-1] @ ss.A.T + b
    innov = y - mu_p @ ss.C.T - c  # NaN where not measured
    loglik = 0.0
    for s, e, (m, _, Linv, logdet) in runs:
        z = innov[s:e, m] @ Linv.T
        loglik -= 0.5 * (np.einsum("ij,ij->", z, z) + (e - s) * (logdet + int(m.sum()) * kalman.LOG_2PI))
    return Filtered(mu_p, StepMatrices.of(pred, new), mu_f, StepMatrices.of(filt, np.r_[True, new]), innov, loglik,
                    ~new)


def smooth(ss: StateSpace, y, u) -> SmoothedStates:
    """Rauch-Tung-Striebel smoother over the forward pass for y (T, ny) and inputs u (T, nu).

    Where the forward covariances have settled, the smoothed covariance settles too (going back
    from the end); once it stops changing it is reused like the forward ones, and the means follow
    x_t|T = J x_t+1|T + e_t with the smoother gain J fixed over each run.
    """
    fw = forward(ss, y, u)
    T = len(fw.mean_pred)
    constant = fw.settled & np.r_[False, fw.settled[:-1]]  # Sig_f[t], Sig_p[t] and so J[t] as at t - 1
    # Smoother gains J_t = Sig_f[t] A' Sig_p[t]^-1 (Sig_p symmetric), one per run, solved at once.
    starts = np.flatnonzero(~constant)
    J = np.swapaxes(np.linalg.solve(fw.cov_pred[starts], ss.A @ fw.cov[starts]), 1, 2)
    gains = StepMatrices.of(J, ~constant)
    mu_s = fw.mean.copy()
    for k, (s, e) in reversed(list(enumerate(zip(starts, np.r_[starts[1:], T])))):
        Jk = J[k]
        offset = fw.mean[s:e] - fw.mean_pred[s:e] @ Jk.T
        for t in range(e - 1, s - 1, -1):
            mu_s[t] = Jk @ mu_s[t + 1] + offset[t - s]
    smoothed = [fw.cov[T]]  # Sig_s[T], then each one computed going back, as distinct values
    computed = np.zeros(T + 1, bool)  # else Sig_s[t] == Sig_s[t + 1], reused
    computed[T] = True
    steady = False
    for t in range(T - 1, -1, -1):
        if steady and constant[t]:
            continue
        Jt, later = gains[t], smoothed[-1]
        smoothed.append(kalman.symmetrize(fw.cov[t] + Jt @ (later - fw.cov_pred[t]) @ Jt.T))
        computed[t] = True
        steady = bool(constant[t] and t + 1 < T and constant[t + 1]
                      and kalman.settled(smoothed[-1], later))
    cov = StepMatrices.of(smoothed[::-1], np.r_[True, computed[:-1]])
    # Cov(x_{t+1}, x_t) = Sig_s[t+1] J_t': one per run of equal factors.
    pairs = np.stack([cov.index[1:], gains.index])
    changes = np.diff(pairs, axis=1, prepend=-1).any(axis=0)
    cross = cov.distinct[pairs[0, changes]] @ np.swapaxes(J[pairs[1, changes]], 1, 2)
    return SmoothedStates(mu_s, cov, StepMatrices.of(cross, changes), fw.loglik)


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
    W, Q = regress(X, Z, e.cov.sum(), e.prev_cov.sum(), e.cross.sum())
    nx, nu = ss.nx, u.shape[1]
    A, F = W[:, :nx], W[:, nx:nx + nu]
    f = W[:, nx + nu] if offset else ss.f
    # Output equation on the fully measured steps: y_t on r_t = [x_t, u_t, 1] (or x_t alone).
    o = ~np.isnan(y).any(axis=1)
    xs, Sx = e.mean[o], e.cov.sum(where=o)
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

    Relative to the log-likelihood's scale: the larger of |log-lik| and the number of measured
    values (it is a sum of one term per value; a log-likelihood that passes near zero would otherwise
    never let EM stop).

    y, u: one experiment's arrays, or lists of several experiments (segments) of the same model,
    each smoothed on its own; their moments are pooled in the M-step. `update(ss, y, u, moments)` replaces the free M-step (`m_step` with offset and feedthrough) by
    one that keeps a structure, such as the lagged basis's.

    The log-likelihood cannot decrease in exact arithmetic; if it falls by more than rounding, the
    last good parameters are kept and a warning says so.
    """
    parts = segments(y, u)
    y, u = np.vstack([p[0] for p in parts]), np.vstack([p[1] for p in parts])
    values = int((~np.isnan(y)).sum())

    def expect(model):
        return Moments.of([smooth(model, yk, uk) for yk, uk in parts])

    e = expect(ss)
    history = [e.loglik]
    converged = fell = False
    for _ in range(max_iter):
        new = m_step(ss, y, u, e, offset, feedthrough) if update is None else update(ss, y, u, e)
        e_new = expect(new)
        gain = e_new.loglik - history[-1]
        if gain < -1e-9 * max(1.0, abs(history[-1])):
            warnings.warn(f"EM log-likelihood fell from {history[-1]:.10g} to {e_new.loglik:.10g}; "
                          "keeping the previous parameters", RuntimeWarning, stacklevel=2)
            fell = True
            break
        ss, e = new, e_new
        history.append(e.loglik)
        if gain < tol * max(abs(history[-2]), values):
            converged = True
            break
    return EMResult(ss, np.array(history), converged, tol * max(abs(history[-1]), values), fell)
