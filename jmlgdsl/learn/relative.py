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
shape, scaled). A single fault mode takes the lam and g of its best blocked cross-validation on its
own rows: FOLDS contiguous blocks, each predicted one step ahead by the fit to the others, the
held-out Gaussian log-likelihood summed. A bank of faults shares the lam and g with which its modes
name held-out halves of their recordings best (`naming_setting`): the modes are there to be told
apart. `relative_wins` says from the blocks whether relative learning beats each mode's own
regression at all; the reference itself is written as its own regression (`Reference.mode`).

An output constant in the fault's data (a stuck sensor) reads its last value in the mode, at the
rounding floor: where it sticks changes from one occurrence to the next. Few rows then give a mode
close to normal with its own offset and scale, many rows a mode of its own.

The mode is written over the shared lagged basis with the equation error as process noise and the
measurement noise at the rounding floor: its one-step prediction is the regression's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import cho_factor, cho_solve, svd
from scipy.special import logsumexp
from scipy.stats import binomtest

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
#: The level of the sign test by which a bank is learned relative (`relative_wins`).
SIGNIFICANCE = 0.05


@dataclass(frozen=True)
class Reference:
    """The normal mode's part in every relative fit: its lags, the standardisation of the outputs
    (my, sy) and inputs (mu, su) by its recordings, its least-squares coefficients W (p, ny) on
    the standardised lagged regressors (offset left out, its own offset c), its residual covariance
    S and the rounding floor of every covariance."""

    lags: Lags
    my: np.ndarray
    sy: np.ndarray
    mu: np.ndarray
    su: np.ndarray
    W: np.ndarray
    S: np.ndarray
    floor: np.ndarray
    c: np.ndarray

    @classmethod
    def of(cls, ys, us, lags: Lags, steps) -> "Reference":
        """The reference from the normal mode's runs (lists of arrays) at its `lags`; `steps`: each
        output's resolution, whose rounding variance floors every covariance."""
        parts = segments(ys, us)
        y, u = np.vstack([p[0] for p in parts]), np.vstack([p[1] for p in parts])
        my, sy = np.nanmean(y, axis=0), np.maximum(np.nanstd(y, axis=0), steps)
        mu, su = u.mean(axis=0), u.std(axis=0)
        su = np.where(su > 0, su, 1.0)
        ref = cls(lags, my, sy, mu, su, None, None, noise_floor(steps / sy), None)
        X, Y = ref.equations(ys, us)
        D, c, S = ridge(X, Y, np.zeros((X.shape[1], Y.shape[1])), 0.0)
        return cls(lags, my, sy, mu, su, D, at_least(S, ref.floor), ref.floor, c)

    def written(self, W, Sigma, level) -> LaggedMode:
        """The regression with coefficients W (offset last) and equation error Sigma on the
        standardised variables as a mode in the sensors' own units, over the lagged basis: the
        equation error is the process noise, the measurement noise is at the rounding floor (so its
        one-step prediction is the regression's), and it starts at `level` (standardised)."""
        standard = ArxFit(self.lags, W, Sigma, None, 0, np.nan, np.nan).lagged()
        n = self.lags.n
        standard = LaggedMode(self.lags, standard.Phi, standard.Psi, standard.c, Sigma, np.diag(self.floor),
                              np.tile(level, n), np.kron(np.eye(n), Sigma))
        return transformed(standard, self.sy, self.my, self.su, self.mu)

    def mode(self) -> tuple[LaggedMode, str]:
        """The reference's own regression as a mode (`written`), and its structure in words."""
        na, nb, nk = self.lags.na, self.lags.nb, self.lags.nk
        order = f"ARX({na},{nb},{nk})" if len(self.mu) else f"AR({na})"
        return (self.written(np.vstack([self.W, self.c]), self.S, np.zeros(len(self.my))),
                f"{order} least squares, the reference of the modes learned relative to it")

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
    offset and scale, and the number of equations. `folds`: each block's held-out log-likelihood at
    the mode's own best setting (which a bank's shared one may differ from) and with no shrinkage
    nor pooling (the fault's own regression), (FOLDS, 2), from which `relative_wins` decides whether
    a bank is better learned relative at all."""

    shrinkage: float
    pooling: float
    scale: float
    heldout: float
    shared: float
    equations: int
    folds: np.ndarray | None = None

    def structure(self, reference: str) -> str:
        """The summary's structure text."""
        change = "normal's dynamics" if np.isinf(self.shrinkage) else f"dynamics shrunk (penalty {self.shrinkage:g})"
        return (f"relative to {reference}: {change}, own offset, covariance {self.pooling:g} of {reference}'s "
                f"shape at scale {self.scale:.3g}; cross-validated log-lik {self.heldout:.4g} per row "
                f"({self.shared:.4g} with {reference}'s dynamics and shape)")


def ridge(X, Y, W_ref, lam):
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


def pooled(S, S_ref, g, floor, factor=None) -> tuple[np.ndarray, float]:
    """(1 - g) S + g k S_ref, k = tr(S_ref^-1 S) / ny (the scale of S_ref that fits S best), kept at
    least diag(floor); and k. `factor`: S_ref's Cholesky factor (scipy's cho_factor), for a caller
    that pools many covariances with one S_ref."""
    k = float(np.trace(cho_solve(cho_factor(S_ref) if factor is None else factor, S))) / len(S)
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


def fit_relative(ref: Reference, ys, us, source="<data>", setting=None) -> tuple[LaggedMode, RelativeFit]:
    """A fault mode relative to the reference from the fault's runs (lists of arrays); the penalty
    and pooling are `setting` (indices into SHRINKAGE and POOLING, as `naming_setting` chooses them
    for a bank) or, by default, the mode's own best by blocked cross-validation of its one-step
    log-likelihood. Returns the mode in the sensors' own units."""
    X, Y = ref.equations(ys, us)
    N, ny = Y.shape
    if N < 2 * FOLDS:
        raise DataError(f"{source}: {plural(N, 'complete equation')}, too few to learn a mode relative to normal "
                        f"by {FOLDS}-fold cross-validation")
    blocks = np.array_split(np.arange(N), FOLDS)
    folds = np.zeros((FOLDS, len(SHRINKAGE), len(POOLING)))
    factor = cho_factor(ref.S)
    for f, block in enumerate(blocks):
        train = np.ones(N, bool)
        train[block] = False
        pieces = _svd(X[train], Y[train], ref.W)
        for i, lam in enumerate(SHRINKAGE):
            D, c, S = _solve(*pieces, lam)
            E = Y[block] - X[block] @ (ref.W + D) - c
            for j, g in enumerate(POOLING):
                folds[f, i, j] = _loglik(E, pooled(S, ref.S, g, ref.floor, factor)[0])
    heldout = folds.sum(axis=0)
    best = np.unravel_index(np.argmax(heldout), heldout.shape)
    i, j = best if setting is None else setting
    D, c, S = ridge(X, Y, ref.W, SHRINKAGE[i])
    Sigma, k = pooled(S, ref.S, POOLING[j], ref.floor, factor)
    W = np.vstack([ref.W + D, c])
    held = [group[0] for group in unresolved([(y - ref.my) / ref.sy for y, _ in segments(ys, us)],
                                             np.sqrt(ref.floor / ROUNDING)) if len(group) == 1]
    if held and ref.lags.na:
        W, Sigma = _holding(W, Sigma, held, ref.floor)
    mode = ref.written(W, Sigma, Y.mean(axis=0))
    fit = RelativeFit(SHRINKAGE[i], POOLING[j], k, heldout[i, j] / N, heldout[-1, -1] / N, N,
                      np.stack([folds[:, best[0], best[1]], folds[:, 0, 0]], axis=1))
    return mode, fit


def naming_setting(ref: Reference, runs: dict, stay: float) -> tuple[tuple[int, int], np.ndarray]:
    """The penalty and pooling (indices into SHRINKAGE and POOLING) that name a bank's modes best,
    and the share named right at each, (len(SHRINKAGE), len(POOLING)). `runs`: {mode: (ys, us)},
    lists of arrays. Cross-validation over two halves: every mode is fitted to one half of its
    equations, and the rows of every other half are named by a forward filter over the modes (one-
    step densities of the regressions, `stay` the probability of staying in a mode, the rest shared
    evenly), then the other way round.

    The modes' purpose is to tell the faults apart: each mode's own best one-step likelihood pulls
    toward covariances that fit its recording's transients (a fault that drives the plant far gets
    a covariance thousands of times normal's, and then names every large deviation), while the
    setting chosen here is the one that tells held-out rows of every fault apart (on the Tennessee
    Eastman recordings, docs/realdata.md)."""
    equations = [ref.equations(ys, us) for ys, us in runs.values()]
    for mode, (_, Y) in zip(runs, equations):
        if len(Y) < 2 * FOLDS:
            raise DataError(f"mode {mode}: {plural(len(Y), 'complete equation')}, too few to learn it relative to "
                            f"normal by cross-validation")
    K = len(runs)
    logP = np.log(np.where(np.eye(K, dtype=bool), stay, (1 - stay) / max(K - 1, 1)))
    right = np.zeros((len(SHRINKAGE), len(POOLING)))
    total = 0
    factor = cho_factor(ref.S)
    for half in (0, 1):
        fitted, tested = [], []
        for X, Y in equations:
            train, test = np.array_split(np.arange(len(Y)), 2)[::-1 if half else 1]
            fitted.append(_svd(X[train], Y[train], ref.W))
            tested.append((X[test], Y[test]))
        # every held-out half side by side, the shorter ones padded with rows that favour no mode
        X, Y = (np.vstack(part) for part in zip(*tested))
        sizes = [len(t[1]) for t in tested]
        where = np.concatenate([np.arange(n) + m * max(sizes) for m, n in enumerate(sizes)])
        total += len(Y)
        for i, lam in enumerate(SHRINKAGE):
            solved = [_solve(*pieces, lam) for pieces in fitted]
            for j, g in enumerate(POOLING):
                density = np.zeros((K * max(sizes), K))
                for m, (D, c, S) in enumerate(solved):
                    L = np.linalg.cholesky(pooled(S, ref.S, g, ref.floor, factor)[0])
                    density[where, m] = _densities(Y - X @ (ref.W + D) - c, L)
                named = forward(density.reshape(K, max(sizes), K), logP).argmax(axis=-1).ravel()[where]
                right[i, j] += np.sum(named == np.repeat(np.arange(K), sizes))
    right /= total
    return tuple(int(v) for v in np.unravel_index(np.argmax(right), right.shape)), right


def _densities(E, L) -> np.ndarray:
    """Each row's Gaussian log-density N(0, L L'), up to the constant every mode shares."""
    white = np.linalg.solve(L, E.T)
    return -0.5 * np.sum(white ** 2, axis=0) - np.log(np.diag(L)).sum()


def forward(density, logP, logp0=None) -> np.ndarray:
    """Filtered log-probabilities (..., T, K) of a hidden Markov chain's states from each row's
    log-densities (..., T, K), its log-transitions logP and log-prior logp0 (default uniform); the
    leading axes are chains filtered side by side."""
    out = np.empty_like(density)
    K = density.shape[-1]
    log_alpha = np.full(density.shape[:-2] + (K,), -np.log(K)) if logp0 is None else logp0
    for t in range(density.shape[-2]):
        e = density[..., t, :]
        log_alpha = (logsumexp(log_alpha[..., :, None] + logP, axis=-2) if t else log_alpha) + e
        log_alpha = log_alpha - logsumexp(log_alpha, axis=-1, keepdims=True)
        out[..., t, :] = log_alpha
    return out


def relative_wins(fits: list[RelativeFit]) -> tuple[bool, int, int]:
    """Whether a bank's other modes are better learned relative to the reference than each on its
    own, by their cross-validation: (the verdict, the held-out blocks on which the chosen settings
    beat the modes' own regressions, the blocks on which they differ). Each block of each mode is a
    paired comparison; relative learning wins when it is better on significantly more than half of
    them (a one-sided sign test at SIGNIFICANCE). Signs, not the sum: an own regression of a few
    rows can put a held-out row at a density of 1e-12, and one such row would decide a sum; and a
    choice that only tunes to the blocks (the own regression is one of the settings tried) wins
    about as often as it loses."""
    d = np.concatenate([f.folds[:, 0] - f.folds[:, 1] for f in fits])
    better, differ = int(np.sum(d > 0)), int(np.sum(d != 0))
    return bool(differ and binomtest(better, differ, alternative="greater").pvalue < SIGNIFICANCE), better, differ
