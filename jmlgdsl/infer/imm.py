"""Interacting multiple models: one Kalman filter per mode, mixed through the transition matrix.

The classical deterministic baseline: K Kalman steps per time step, no sampling, but biased because
the mixture over histories is collapsed to one Gaussian per mode at every step.

The covariance half of those Kalman steps never sees the data. Once the mode posterior is sure of
its mode and the filters have settled, a mode's mixed covariance repeats from step to step (to
kalman.SETTLED), so its factor, gain and filtered covariance are kept and a step costs the mixing
and the means: on a wide bank most steps then skip the O(K nx^3) work.
"""

from __future__ import annotations

import numpy as np

from . import kalman
from .engine import OPEN, Estimate, mixture_moments, offsets, screen
from .resample import normalize

LOG_FLOOR = np.finfo(float).min  # below every finite log-probability
# Mass off the most probable mode below which the mixed covariances may repeat to kalman.SETTLED.
SURE = 1e-12


class IMM:
    """Mode probabilities and one moment-matched Gaussian per mode."""

    def __init__(self, model):
        self.model = model
        with np.errstate(divide="ignore"):
            self.log_mu = np.log(model.p0)
        self.means = model.mu0.copy()
        self.covs = np.broadcast_to(model.Sigma0, (model.K,) + model.Sigma0.shape).copy()
        self._C = model.C if model.output_states is None else model.output_states  # see kalman
        # per mode, the mixed covariance and mask of the last Kalman pieces computed, the pieces, and
        # how far each covariance may move and still count as the same (kalman.tolerance)
        self._kept = None
        self._sure = False  # the last posterior put all but SURE of its mass on one mode

    def _pieces(self, covs, mask):
        """(Linv, log det S, gain', filtered covariance) per mode for mixed covariances covs, computed
        afresh only for the modes whose covariance or mask moved since they were last computed. A
        covariance can only repeat when the last posterior sat on one mode (else the spread of the
        means, which follows the data, enters the mixing), so only then is it compared."""
        kept, model = self._kept, self.model
        if self._sure and kept is not None and np.array_equal(kept[1], mask):
            base, _, pieces, tol = kept
            fresh = ~kalman.settled(covs, base, tol)
            if not fresh.any():
                return pieces
            if not fresh.all():
                C = self._C if kalman.picks(self._C) else self._C[fresh]
                new = kalman.covariance_step(covs[fresh], model.A[fresh], model.Q[fresh], C, model.R[fresh], mask)
                base, tol, pieces = base.copy(), tol.copy(), tuple(p.copy() for p in pieces)
                base[fresh], tol[fresh] = covs[fresh], kalman.tolerance(covs[fresh])
                for p, n in zip(pieces, new):
                    p[fresh] = n
                self._kept = base, mask.copy(), pieces, tol
                return pieces
        pieces = kalman.covariance_step(covs, model.A, model.Q, self._C, model.R, mask)
        self._kept = covs, mask.copy(), pieces, kalman.tolerance(covs)
        return pieces

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
        Linv, logdet, gain_t, covs = self._pieces(covs, mask)
        mu_p = (model.A @ mixed[:, :, None])[:, :, 0] + b
        y_pred = (mu_p[:, self._C] if kalman.picks(self._C) else (self._C @ mu_p[:, :, None])[:, :, 0]) + c
        r = y - y_pred if mask.all() else y[mask] - y_pred[:, mask]
        z = (Linv @ r[:, :, None])[:, :, 0]  # whitened innovations
        quad = kalman.quad_form(z)
        flagged = None
        if gate.closer_look(quad):
            screened, flagged = screen(self, y, mask, u, gate, r, kalman.standard_deviations(Linv))
            if screened is not None:
                return screened
        means = mu_p + (r[:, None, :] @ gain_t)[:, 0, :]
        post, loglik = normalize(log_pred + kalman.log_density(quad, logdet, r.shape[1]))
        self.log_mu = np.log(post, out=np.full_like(post, -np.inf), where=post > 0)
        self._sure = post.max() >= 1.0 - SURE
        self.means, self.covs = means, covs
        mean, cov = mixture_moments(post, means, (post @ covs.reshape(len(post), -1)).reshape(covs.shape[1:]))
        return Estimate(post, mean, cov, np.exp(log_pred) @ y_pred, loglik, np.nan, flagged=flagged)
