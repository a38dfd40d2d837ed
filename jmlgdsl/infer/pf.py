"""Bootstrap particle filter over (mode, state): everything sampled from the prior, weighted by the data."""

from __future__ import annotations

import numpy as np

from .engine import Estimate, Resampler, mixture_moments, offsets, predictive_mean, sample_rows, weighted_posterior
from .kalman import LOG_2PI, MAX_QUAD, psd_sqrt
from .resample import normalize


class BootstrapPF:
    """Particles (z, x): z_t from the transition matrix, x_t from the state equation, weight N(y; C x, R)."""

    default_particles = 200

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
            L = np.linalg.cholesky(self.model.R[:, mask][:, :, mask])
            self._noise[key] = (np.linalg.inv(L), 2.0 * np.log(np.diagonal(L, axis1=-2, axis2=-1)).sum(-1))
        return self._noise[key]

    def step(self, y, mask, u) -> Estimate:
        model, z = self.model, self.z
        b, c = offsets(model, u)
        log_prior = self.logw
        z = sample_rows(model.P[z], self.rng)
        w = self.rng.standard_normal((len(z), model.B.shape[2]))
        x = np.einsum("nij,nj->ni", model.A[z], self.x) + b[z] + np.einsum("nij,nj->ni", model.B[z], w)
        y_pred = np.einsum("nij,nj->ni", model.C[z], x) + c[z]
        Linv, logdet = self._measurement_noise(mask)
        r = np.einsum("nab,nb->na", Linv[z], y[mask] - y_pred[:, mask])
        quad = np.minimum(np.einsum("na,na->n", r, r), MAX_QUAD)
        q, loglik = normalize(log_prior - 0.5 * (quad + logdet[z] + mask.sum() * LOG_2PI))
        mean, cov = mixture_moments(q, x, np.zeros((model.nx, model.nx)))
        posterior = weighted_posterior(q, z, model.K)
        ancestors, self.logw, size = self.resampler(q)
        self.z, self.x = z[ancestors], x[ancestors]
        return Estimate(posterior, mean, cov, predictive_mean(log_prior, y_pred), loglik, size)
