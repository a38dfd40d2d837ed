"""Interacting multiple models: one Kalman filter per mode, mixed through the transition matrix.

The classical deterministic baseline: K Kalman steps per time step, no sampling, but biased because
the mixture over histories is collapsed to one Gaussian per mode at every step.
"""

from __future__ import annotations

import numpy as np

from . import kalman
from .engine import OPEN, Estimate, mixture_moments, offsets, screen

LOG_FLOOR = np.finfo(float).min  # below every finite log-probability
from .resample import normalize


class IMM:
    """Mode probabilities and one moment-matched Gaussian per mode."""

    def __init__(self, model):
        self.model = model
        with np.errstate(divide="ignore"):
            self.log_mu = np.log(model.p0)
        self.means = model.mu0.copy()
        self.covs = np.broadcast_to(model.Sigma0, (model.K,) + model.Sigma0.shape).copy()
        self._C = model.C if model.output_states is None else model.output_states  # see kalman

    def step(self, y, mask, u, gate=OPEN) -> Estimate:
        model = self.model
        b, c = offsets(model, u)
        # Mixing: mix[i, j] = p(z_{t-1} = i | z_t = j, y_1:t-1); log_pred[j] = log p(z_t = j | y_1:t-1).
        joint = self.log_mu[:, None] + model.logP
        log_pred = np.logaddexp.reduce(joint, axis=0)
        # a mode that cannot be reached (log_pred = -inf) mixes nothing: -inf less a finite floor is -inf
        mix = np.exp(joint - np.maximum(log_pred, LOG_FLOOR))
        mixed = mix.T @ self.means
        d = self.means[None, :, :] - mixed[:, None, :]  # (j, i, nx)
        K, nx = self.means.shape
        # sum_i mix[i, j] (covs[i] + d[j, i] d[j, i]'), as matrix products (a three-operand einsum
        # loops in C without BLAS: most of a step with 50 states)
        spread = np.swapaxes(d * mix.T[:, :, None], 1, 2) @ d
        covs = (mix.T @ self.covs.reshape(K, nx * nx)).reshape(K, nx, nx) + spread
        mu_p, Sig_p = kalman.predict(mixed, covs, model.A, b, model.Q)
        y_pred, S, CS = kalman.innovation(mu_p, Sig_p, self._C, c, model.R)
        means, covs, ll, quad = kalman.update(mu_p, Sig_p, y_pred, S, CS, y, mask)
        flagged = None
        if quad.min() > gate.bound:
            sd = np.sqrt(np.maximum(np.diagonal(S, axis1=1, axis2=2)[:, mask], 0.0))  # rounding can make it < 0
            screened, flagged = screen(self, y, mask, u, gate, y[mask] - y_pred[:, mask], sd)
            if screened is not None:
                return screened
        post, loglik = normalize(log_pred + ll)
        self.log_mu = np.log(post, out=np.full_like(post, -np.inf), where=post > 0)
        self.means, self.covs = means, covs
        mean, cov = mixture_moments(post, means, (post @ covs.reshape(len(post), -1)).reshape(covs.shape[1:]))
        return Estimate(post, mean, cov, np.exp(log_pred) @ y_pred, loglik, np.nan, flagged=flagged)
