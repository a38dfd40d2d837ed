"""Bootstrap particle filter over (mode, state): everything sampled from the prior, weighted by the data."""

from __future__ import annotations

import numpy as np

from ..gaussian import psd_sqrt
from .engine import OPEN, Estimate, Genealogy, Resampler, mixture_moments, offsets, sample_rows, screen
from .kalman import inverse_cholesky, log_density, quad_form
from .resample import normalize
from .result import Predictive


class BootstrapPF:
    """Particles (z, x): z_t from the transition matrix, x_t from the state equation, weight N(y; C x, R)."""

    def __init__(self, model, particles, rng, resampler: Resampler):
        self.model, self.rng, self.resampler = model, rng, resampler
        self.z = resampler.scheme(model.p0, particles, rng)
        noise = rng.standard_normal((particles, model.nx)) @ psd_sqrt(model.Sigma0).T
        self.x = model.mu0[self.z] + noise
        self.logw = np.full(particles, -np.log(particles))
        self._noise = {}  # observation mask -> (inverse Cholesky factors of R per mode, log-determinants)

    def _measurement_noise(self, mask):
        key = mask.tobytes()
        if key not in self._noise:
            self._noise[key] = inverse_cholesky(self.model.R[:, mask][:, :, mask])
        return self._noise[key]

    def _every_mode(self, y, mask, b, c):
        """Residuals and their one-step predictive spreads sqrt diag(C Q C' + R) of the measured
        readings under every mode from every particle's previous state (for the gate's closer look)."""
        model = self.model
        y_pred = np.einsum("kij,nj->nki", model.C @ model.A, self.x) + np.einsum("kij,kj->ki", model.C, b) + c
        var = np.diagonal(model.C @ model.Q @ np.swapaxes(model.C, 1, 2) + model.R, axis1=1, axis2=2)
        r = (y - y_pred)[:, :, mask].reshape(-1, int(mask.sum()))
        return r, np.broadcast_to(np.sqrt(var[:, mask]), y_pred[:, :, mask].shape).reshape(r.shape)

    def step(self, y, mask, u, gate=OPEN) -> Estimate:
        model, z = self.model, self.z
        b, c = offsets(model, u)
        log_prior = self.logw
        z = sample_rows(model.P[z], self.rng)
        w = self.rng.standard_normal((len(z), model.B.shape[2]))
        x = np.einsum("nij,nj->ni", model.A[z], self.x) + b[z] + np.einsum("nij,nj->ni", model.B[z], w)
        y_pred = np.einsum("nij,nj->ni", model.C[z], x) + c[z]
        Linv, logdet = self._measurement_noise(mask)
        Linv = Linv[z]
        r = y[mask] - y_pred[:, mask]
        white = np.einsum("nab,nb->na", Linv, r)
        quad = quad_form(white)
        flagged = None
        if gate.closer_look(quad):
            screened, flagged = screen(self, y, mask, u, gate, *self._every_mode(y, mask, b, c))
            if screened is not None:
                return screened
        self.predictive = Predictive(z, log_prior, r, Linv, mask)
        q, loglik = normalize(log_prior + log_density(quad, logdet[z], r.shape[1]))
        mean, cov = mixture_moments(q, x, np.zeros((model.nx, model.nx)))
        posterior = np.bincount(z, weights=q, minlength=model.K)
        ancestors, self.logw, size = self.resampler(q)
        self.genealogy = Genealogy(np.arange(len(z)), z, q, ancestors)
        self.z, self.x = z[ancestors], x[ancestors]
        prior = np.exp(log_prior - log_prior.max())
        return Estimate(posterior, mean, cov, prior @ y_pred / prior.sum(), loglik, size, flagged=flagged)
