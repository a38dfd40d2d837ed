"""Fault modes learned relative to the normal mode, for recordings too short for a model of their own.

A fault recording of a few hundred rows over tens of sensors cannot pin down a full model per fault:
a VAR(1) of 52 sensors has 2,700 coefficients and 1,400 covariance entries, from 480 rows. Most of a
fault's plant is the normal plant, so each fault mode is written as the normal one plus what the
data show, in the sensors standardised by the normal recording (so one penalty fits every unit):

    z_t = (W_ref + D)' x_t + c + e_t,      e_t ~ N(0, Sigma),
    Sigma = (1 - g) S + g k S_ref,         k = tr(S_ref^-1 S) / ny,

x_t the lagged outputs (and inputs) at the reference's order, W_ref and S_ref the least-squares
coefficients and residual covariance of the normal recording at that order. The offset c is the
fault's own (a bias or a leak is an offset); the change of dynamics D is ridge-shrunk toward zero,
min |E|^2 + lam N |D|^2 (lam = inf: the normal dynamics exactly); the covariance is the fault's own
residual covariance S pooled with the normal one at the fault's own scale k (g = 1: the normal
shape, scaled). lam and g are chosen by blocked cross-validation on the fault's own rows: FOLDS
contiguous blocks, each predicted one step ahead by the fit to the others, the held-out Gaussian
log-likelihood summed. An output constant in the fault's data (a stuck sensor) reads its last value
in the mode, at the rounding floor: where it sticks changes from one occurrence to the next. Few rows then give a mode close to normal with its own offset and scale, many
rows a mode of its own.

The mode is written over the shared lagged basis with the equation error as process noise and the
measurement noise at the rounding floor: its one-step prediction is the regression's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import cho_factor, cho_solve, svd

from ..errors import DataError
from ..names import plural
from .arx import ArxFit, regressors
from .basis import LaggedMode, Lags, transformed
from .em import segments
from .resolution import ROUNDING, at_least, noise_floor, unresolved

#: The change of dynamics' ridge penalty per equation tried by cross-validation (inf: none at all).
SHRINKAGE = (0.0, 0.01, 0.03, 0.1, 0.3, 1.0, 3.0, 10.0, np.inf)
#: The weight of the normal covariance's shape tried by cross-validation.
POOLING = (0.0, 0.1, 0.25, 0.5, 0.75, 0.9, 1.0)
#: Contiguous blocks of a fault's rows in the cross-validation.
FOLDS = 5


@dataclass(frozen=True)
class Reference:
    """The normal mode's part in every relative fit: its lags, the standardisation of the outputs
    (my, sy) and inputs (mu, su) by its recordings, its least-squares coefficients W (p, ny) on
    the standardised lagged regressors (offset left out) and its residual covariance S."""

    lags: Lags
    my: np.ndarray
    sy: np.ndarray
    mu: np.ndarray
    su: np.ndarray
    W: np.ndarray
    S: np.ndarray
    floor: np.ndarray

    @classmethod
    def of(cls, ys, us, lags: Lags, steps) -> "Reference":
        """The reference from the normal mode's runs (lists of arrays) at its `lags`; `steps`: each
        output's resolution, whose rounding variance floors every covariance."""
        parts = segments(ys, us)
        y, u = np.vstack([p[0] for p in parts]), np.vstack([p[1] for p in parts])
        my, sy = np.nanmean(y, axis=0), np.maximum(np.nanstd(y, axis=0), steps)
        mu, su = u.mean(axis=0), u.std(axis=0)
        su = np.where(su > 0, su, 1.0)
        ref = cls(lags, my, sy, mu, su, None, None, noise_floor(steps / sy))
        X, Y = ref.equations(ys, us)
        D, c, S = _ridge(X, Y, np.zeros((X.shape[1], Y.shape[1])), 0.0)
        return cls(lags, my, sy, mu, su, D, at_least(S, ref.floor), ref.floor)

    def equations(self, ys, us) -> tuple[np.ndarray, np.ndarray]:
        """The standardised regressors (offset left out) and targets of some runs, pooled."""
        start = max(self.lags.na, self.lags.nk + self.lags.nb - 1)
        blocks = [regressors((y - self.my) / self.sy, (u - self.mu) / self.su, self.lags, start)
                  for y, u in segments(ys, us)]
        return np.vstack([b[0][:, :-1] for b in blocks]), np.vstack([b[1] for b in blocks])


@dataclass(frozen=True)
class RelativeFit:
    """How a fault mode was learned relative to normal: the penalty on its change of dynamics per
    equation (inf: normal's dynamics), the weight of normal's covariance shape, its scale, the
    held-out log-likelihood per row at that choice and at the normal dynamics with the fault's own
    offset and scale, and the number of equations."""

    shrinkage: float
    pooling: float
    scale: float
    heldout: float
    shared: float
    equations: int

    def structure(self, reference: str) -> str:
        """The summary's structure text."""
        change = "normal's dynamics" if np.isinf(self.shrinkage) else f"dynamics shrunk (penalty {self.shrinkage:g})"
        return (f"relative to {reference}: {change}, own offset, covariance {self.pooling:g} of {reference}'s "
                f"shape at scale {self.scale:.3g}; cross-validated log-lik {self.heldout:.4g} per row "
                f"({self.shared:.4g} with {reference}'s dynamics and shape)")


def _ridge(X, Y, W_ref, lam):
    """(D, c, S): the change D of the coefficients from W_ref minimising |Y - X (W_ref + D) - c|^2
    + lam N |D|^2 by one SVD of the centred regressors (directions that do not move at all are left
    out), the offset c and the residual covariance S."""
    return _solve(*_svd(X, Y, W_ref), lam)


def _svd(X, Y, W_ref):
    """The centred regression's SVD and what every penalty's solution needs from it."""
    N = len(X)
    xm, ym = X.mean(axis=0), Y.mean(axis=0)
    Xc = X - xm
    U, s, Vt = svd(Xc, full_matrices=False)
    keep = s > 1e-10 * max(s.max(initial=0.0), 1.0)
    target = Y - ym - Xc @ W_ref
    return N, xm, ym, W_ref, Xc, U[:, keep], s[keep], Vt[keep], U[:, keep].T @ target, target


def _solve(N, xm, ym, W_ref, Xc, U, s, Vt, projected, target, lam):
    """The penalised solution from `_svd`'s pieces: (D, c, S)."""
    if np.isinf(lam):
        D = np.zeros_like(W_ref)
    else:
        D = Vt.T @ ((s / (s ** 2 + lam * N))[:, None] * projected)
    E = target - Xc @ D
    W = W_ref + D
    return D, ym - xm @ W, E.T @ E / N


def pooled(S, S_ref, g, floor) -> tuple[np.ndarray, float]:
    """(1 - g) S + g k S_ref, k = tr(S_ref^-1 S) / ny (the scale of S_ref that fits S best), kept at
    least diag(floor); and k."""
    k = float(np.trace(cho_solve(cho_factor(S_ref), S))) / len(S)
    return at_least((1 - g) * S + g * k * S_ref, floor), k


def _holding(W, Sigma, held, floor):
    """Coefficients and covariance in which the outputs `held` (constant in the fault's data: a stuck
    sensor or valve) read their last value, at the rounding floor. The data cannot tell a constant's
    own lag from the offset; the value a sensor sticks at changes from one occurrence to the next,
    so the mode that names it predicts the last reading rather than the recording's level."""
    W, Sigma = W.copy(), Sigma.copy()
    W[:, held] = 0.0
    W[held, held] = 1.0
    Sigma[held, :] = Sigma[:, held] = 0.0
    return W, at_least(Sigma, floor)


def _loglik(E, Sigma) -> float:
    """Sum of the Gaussian log-densities N(0, Sigma) of the rows of E, by Cholesky."""
    L = np.linalg.cholesky(Sigma)
    white = np.linalg.solve(L, E.T)
    return float(-0.5 * (np.sum(white ** 2) + len(E) * (2 * np.log(np.diag(L)).sum() + len(Sigma) * np.log(2 * np.pi))))


def fit_relative(ref: Reference, ys, us, source="<data>") -> tuple[LaggedMode, RelativeFit]:
    """A fault mode relative to the reference from the fault's runs (lists of arrays), the penalty
    and pooling chosen by blocked cross-validation; returns the mode in the sensors' own units."""
    X, Y = ref.equations(ys, us)
    N, ny = Y.shape
    if N < 2 * FOLDS:
        raise DataError(f"{source}: {plural(N, 'complete equation')}, too few to learn a mode relative to normal "
                        f"by {FOLDS}-fold cross-validation")
    blocks = np.array_split(np.arange(N), FOLDS)
    heldout = np.zeros((len(SHRINKAGE), len(POOLING)))
    for block in blocks:
        train = np.ones(N, bool)
        train[block] = False
        pieces = _svd(X[train], Y[train], ref.W)
        for i, lam in enumerate(SHRINKAGE):
            D, c, S = _solve(*pieces, lam)
            E = Y[block] - X[block] @ (ref.W + D) - c
            for j, g in enumerate(POOLING):
                heldout[i, j] += _loglik(E, pooled(S, ref.S, g, ref.floor)[0])
    i, j = np.unravel_index(np.argmax(heldout), heldout.shape)
    D, c, S = _ridge(X, Y, ref.W, SHRINKAGE[i])
    Sigma, k = pooled(S, ref.S, POOLING[j], ref.floor)
    W = np.vstack([ref.W + D, c])
    held = [group[0] for group in unresolved([(y - ref.my) / ref.sy for y, _ in segments(ys, us)],
                                             np.sqrt(ref.floor / ROUNDING)) if len(group) == 1]
    if held and ref.lags.na:
        W, Sigma = _holding(W, Sigma, held, ref.floor)
    standard = ArxFit(ref.lags, W, Sigma, None, N, np.nan, np.nan).lagged()
    n = ref.lags.n
    standard = LaggedMode(ref.lags, standard.Phi, standard.Psi, standard.c, Sigma, np.diag(ref.floor),
                          np.tile(Y.mean(axis=0), n), np.kron(np.eye(n), Sigma))
    mode = transformed(standard, ref.sy, ref.my, ref.su, ref.mu)
    fit = RelativeFit(SHRINKAGE[i], POOLING[j], k, heldout[i, j] / N, heldout[-1, -1] / N, N)
    return mode, fit
