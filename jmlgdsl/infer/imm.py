"""Interacting multiple models: one Kalman filter per mode, mixed through the transition matrix;
and MMAE, the same filters never mixed.

The classical deterministic baseline: K Kalman steps per time step, no sampling, but biased because
the mixture over histories is collapsed to one Gaussian per mode at every step.

The covariance half of those Kalman steps never sees the data. Once the mode posterior is sure of
its mode and the filters have settled, a mode's mixed covariance repeats from step to step (to
kalman.tolerance: SETTLED, or the covariance step's own rounding error where that is larger), so its
factor, gain and filtered covariance are kept and a step costs the mixing and the means: on a wide
bank most steps then skip the O(K nx^3) work.

The arithmetic of a step (`mix`, `predict`, `whitened`, `refresh`, `moments`) broadcasts over
leading axes: `IMM` calls it for one plant, and `jmlgdsl.infer.units` for many units of one plant
at once, with a leading unit axis, so both run the same operations matrix by matrix.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import numpy as np

from . import kalman
from .engine import OPEN, Estimate, mixture_moments, offsets, screen
from .resample import normalize
from .result import Predictive

LOG_FLOOR = np.finfo(float).min  # below every finite log-probability
# Mass off the most probable mode below which the mixed covariances may repeat (to kalman.tolerance).
SURE = 1e-12


def transition(log_mu, logP):
    """The modes' step through the transition matrix, from mode log-probabilities log_mu (..., K):
    (log_pred, mix_t) with log_pred[j] = log p(z_t = j | y_1:t-1) and mix_t[j, i] = p(z_t-1 = i |
    z_t = j, y_1:t-1)."""
    joint = log_mu[..., :, None] + logP  # (i, j): log p(z_t-1 = i, z_t = j | y_1:t-1)
    # the log-sum over i, shifted by the largest term: a mode that cannot be reached (every term
    # -inf) has its shift floored to a finite number, so its terms are 0, their total 0 and log_pred
    # -inf, and it mixes nothing. Every reachable total is at least 1 (its largest term).
    top = np.maximum.reduce(joint, axis=-2, initial=LOG_FLOOR)
    w = np.exp(joint - top[..., None, :])
    total = np.add.reduce(w, axis=-2)  # along i, one term after the other (not the innermost axis)
    with np.errstate(divide="ignore"):
        log_pred = top + np.log(total)
    return log_pred, np.swapaxes(w / np.maximum(total, 1.0)[..., None, :], -1, -2)


def mix(log_mu, logP, means, covs):
    """The mixing of one step, from mode log-probabilities log_mu (..., K) and per-mode moments means
    (..., K, nx) and covs (..., K, nx, nx): (log_pred, mixed means, mixed covariances), where
    log_pred is `transition`'s and mode j starts from sum_i p(z_t-1 = i | z_t = j) N_i."""
    log_pred, mix_t = transition(log_mu, logP)
    mixed = mix_t @ means
    # deviations d[j, :, i] of each mode's mean from mode j's mixed mean, the previous mode innermost
    # (a broadcast with an inner axis of nx runs 3 times slower at nx = 3)
    d = np.ascontiguousarray(np.swapaxes(means, -1, -2))[..., None, :, :] - mixed[..., :, :, None]
    K, nx = means.shape[-2:]
    # sum_i mix[j, i] (covs[i] + d[j, :, i] d[j, :, i]'), as matrix products (a three-operand einsum
    # loops in C without BLAS: most of a step with 50 states)
    spread = (d * mix_t[..., None, :]) @ np.swapaxes(d, -1, -2)
    lead = covs.shape[:-3]
    covs = (mix_t @ covs.reshape(lead + (K, nx * nx))).reshape(lead + (K, nx, nx)) + spread
    return log_pred, mixed, covs


def predict(model, C, mixed, u):
    """Per-mode predicted states (..., K, nx) and outputs (..., K, ny) from mixed means (..., K, nx)
    under inputs u (nu,), or (units, nu) with one row per unit (C as in kalman: a matrix or a slice)."""
    b, c = offsets(model, u)
    mu_p = (model.A @ mixed[..., None])[..., 0] + b
    return mu_p, (mu_p[..., C] if kalman.picks(C) else (C @ mu_p[..., None])[..., 0]) + c


def whitened(y, mask, y_pred, Linv):
    """(residuals, their squared Mahalanobis distances) of the readings y (..., ny) measured where
    mask (ny,) is True against every mode's prediction y_pred (..., K, ny)."""
    r = y[..., None, :] - y_pred if mask.all() else y[..., None, mask] - y_pred[..., mask]
    return r, kalman.quad_form((Linv @ r[..., None])[..., 0])


class Gauge(NamedTuple):
    """How `refresh` tells which covariances may keep the pieces computed from the last ones: `measure(base,
    Linv, A, C, mask)` what the comparison of each mode needs, once per pieces (base: the covariances
    the pieces came from, Linv their whitening, A and C the modes' matrices as the step used them),
    and `same(covs, base, measured)` (..., K) True where covs may keep them."""

    measure: Callable
    same: Callable


# IMM's: a covariance within its rounding of the one the pieces came from (kalman.tolerance), so
# keeping them moves the results by about what the step's own rounding does.
ROUNDING = Gauge(lambda base, Linv, A, C, mask: kalman.tolerance(base, Linv), kalman.settled)


def _whitened_dynamics(base, Linv, A, C, mask):
    """(..., K) ||Linv C A||_F^2 over the read outputs: a change D of a filtered covariance moves the
    whitened innovation covariance Linv S Linv' by at most that times ||D||_F (2-norm)."""
    CA = A[..., C, :] if kalman.picks(C) else C @ A
    M = Linv @ CA[..., mask, :]
    return np.einsum("...ij,...ij->...", M, M)


# MMAE's (its covariances follow no data, so they converge and then wander by their rounding, which
# kalman.tolerance underestimates where correlated outputs make S ill-conditioned: by 2,000 times in
# a learned bank of 52 sensors): a covariance whose change moves the whitened innovation covariance
# by at most DENSITIES_SETTLED (2-norm), so each log-density of a step by at most DENSITIES_SETTLED
# (m + quad) / 2 nats, m readings at squared distance quad. On the Tennessee Eastman bank's
# training recordings its posteriors are within 4e-8 of those kept to kalman.tolerance, every row
# named the same, at 0.27 ms a row against 0.82.
DENSITIES_SETTLED = 1e-6


def _moves_densities_little(covs, base, bound):
    """(..., K) True where covs moves from base by at most DENSITIES_SETTLED / bound (Frobenius)."""
    change = covs - base
    return np.sqrt(np.einsum("...ij,...ij->...", change, change)) * bound <= DENSITIES_SETTLED


DENSITIES = Gauge(_whitened_dynamics, _moves_densities_little)


def refresh(model, C, covs, mask, kept, reusable, gauge=ROUNDING):
    """(Linv, log det S, gain', filtered covariance) per mode for mixed covariances covs (..., K, nx,
    nx), and what to keep for the next step: (covs the pieces belong to, the pieces, the gauge's
    measure of them, or None until a comparison needs it: a posterior that is never sure never pays
    for it). kept is that of the last step (None: nothing kept); reusable (...) says where
    it may serve, for the same mask, after a posterior sure of its mode. Only the covariances that
    moved beyond what the gauge allows there, or everywhere else, are computed afresh: under IMM a
    covariance can only repeat when the last posterior sat on one mode (else the spread of the
    means, which follows the data, enters the mixing), so only then is it compared."""
    if kept is None or not reusable.any():
        pieces = kalman.covariance_step(covs, model.A, model.Q, C, model.R, mask)
        return pieces, (covs, pieces, None)
    base, pieces, measured = kept
    if measured is None:
        measured = gauge.measure(base, pieces[0], model.A, C, mask)
    fresh = ~(reusable[..., None] & gauge.same(covs, base, measured))
    if not fresh.any():
        return pieces, (base, pieces, measured)
    shape = covs.shape[:-2]
    C = C if kalman.picks(C) else np.broadcast_to(C, shape + C.shape[-2:])[fresh]
    A, Q, R = (np.broadcast_to(M, shape + M.shape[-2:])[fresh] for M in (model.A, model.Q, model.R))
    new = kalman.covariance_step(covs[fresh], A, Q, C, R, mask)
    base, measured, pieces = base.copy(), measured.copy(), tuple(p.copy() for p in pieces)
    base[fresh], measured[fresh] = covs[fresh], gauge.measure(covs[fresh], new[0], A, C, mask)
    for p, n in zip(pieces, new):
        p[fresh] = n
    return pieces, (base, pieces, measured)


def within_closest(gate, mask, r, quad, Linv) -> bool:
    """Whether every reading is within the gate under the mode whose prediction is closest (the
    smallest squared distance quad): then none is beyond it under every mode, and `screen` would flag
    nothing. One mode's standard deviations where the closer look takes every mode's: on a bank of
    many modes over many outputs, a fault puts most modes' predictions beyond the gate's bound while
    the mode that fits stays within."""
    j = np.argmin(quad)
    return not (np.abs(r[j]) > gate.limit[mask] * kalman.standard_deviations(Linv[j])).any()


def moments(post, means, covs):
    """The mixture's mean and covariance over the modes: posterior post (..., K), per-mode moments."""
    lead, (K, nx) = covs.shape[:-3], covs.shape[-3:-1]
    weighted = (post[..., None, :] @ covs.reshape(lead + (K, nx * nx))).reshape(lead + (nx, nx))
    return mixture_moments(post, means, weighted)


class IMM:
    """Mode probabilities and one moment-matched Gaussian per mode."""

    gauge = ROUNDING  # when a step's covariances keep the last step's pieces (`refresh`)

    def __init__(self, model):
        self.model = model
        with np.errstate(divide="ignore"):
            self.log_mu = np.log(model.p0)
        self.means = model.mu0.copy()
        self.covs = np.broadcast_to(model.Sigma0, (model.K,) + model.Sigma0.shape).copy()
        self._C = model.C if model.output_states is None else model.output_states  # see kalman
        # the mask and `refresh`'s kept pieces of the last step
        self._kept = None
        self._sure = False  # the last posterior put all but SURE of its mass on one mode

    def _pieces(self, covs, mask):
        """`refresh` for this filter's last kept pieces."""
        mask_kept, kept = (None, None) if self._kept is None else self._kept
        reusable = np.bool_(self._sure and kept is not None and np.array_equal(mask_kept, mask))
        pieces, kept = refresh(self.model, self._C, covs, mask, kept, reusable, self.gauge)
        self._kept = mask.copy(), kept
        return pieces

    def _mixed(self):
        """(log_pred, each mode's starting mean and covariance) of the next step: the mixing."""
        return mix(self.log_mu, self.model.logP, self.means, self.covs)

    def _repeatable(self, post) -> bool:
        """Whether the next step's starting covariances may repeat this step's (then its pieces are
        compared with the kept ones): only after a posterior on one mode, as the spread of the
        modes' means enters the mixing otherwise."""
        return post.max() >= 1.0 - SURE

    def step(self, y, mask, u, gate=OPEN) -> Estimate:
        model = self.model
        log_pred, mixed, covs = self._mixed()
        Linv, logdet, gain_t, covs = self._pieces(covs, mask)
        mu_p, y_pred = predict(model, self._C, mixed, u)
        r, quad = whitened(y, mask, y_pred, Linv)
        flagged = None
        if gate.closer_look(quad) and not within_closest(gate, mask, r, quad, Linv):
            screened, flagged = screen(self, y, mask, u, gate, r, kalman.standard_deviations(Linv))
            if screened is not None:
                return screened
        self.predictive = Predictive(np.arange(len(log_pred)), log_pred, r, Linv, mask)
        means = mu_p + (r[..., None, :] @ gain_t)[..., 0, :]
        post, loglik = normalize(log_pred + kalman.log_density(quad, logdet, r.shape[-1]))
        self.log_mu = np.log(post, out=np.full_like(post, -np.inf), where=post > 0)
        self._sure = self._repeatable(post)
        self.means, self.covs = means, covs
        mean, cov = moments(post, means, covs)
        return Estimate(post, mean, cov, np.exp(log_pred) @ y_pred, loglik, np.nan, flagged=flagged)


class MMAE(IMM):
    """Multiple-model adaptive estimation: IMM's Kalman filter per mode, each started at a step from
    its own last moments, never mixed with the others; the mode posterior still goes through the
    transition matrix, from the filters' one-step likelihoods.

    Its covariances never see the data nor the posterior, so they settle (to its gauge, DENSITIES)
    after a few steps whatever the posterior does, and a step then costs the means: no O(K nx^3)
    work. IMM's mixing repeats its covariances only while the posterior is sure of one mode, and a
    namer of many fault modes over many states is seldom that (18 modes over 52 states on a
    Tennessee Eastman fault: 3.5 ms a step under IMM, 0.4 under MMAE). Where every mode's filter
    follows the outputs closely (outputs read almost exactly, as in learned banks) the mixing moves
    little, and the two name the same modes; where a mode's state is hidden, its filter drifts with
    its own model instead of being pulled back to the others'."""

    gauge = DENSITIES

    def _mixed(self):
        return transition(self.log_mu, self.model.logP)[0], self.means, self.covs

    def _repeatable(self, post) -> bool:
        return True
