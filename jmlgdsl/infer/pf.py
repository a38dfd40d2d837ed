"""Bootstrap particle filter over (mode, state): everything sampled from the prior, weighted by the data."""

from __future__ import annotations

import numpy as np

from ..gaussian import psd_sqrt
from .engine import (OPEN, Estimate, Estimates, Gate, Genealogy, Resampler, cdf_drawn, joined, mixture_moments,
                     offsets, sample_rows, screen, systematic_rows)
from .kalman import inverse_cholesky, log_density, quad_form
from .resample import normalize_rows, row_extreme, systematic
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

    @property
    def particles_held(self) -> int:
        """How many particles the engine holds (as `RaoBlackwellised.particles_held`, whose particles
        merge into copies)."""
        return len(self.z)

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
        model = self.model
        b, c = offsets(model, u)
        z = sample_rows(model.P[self.z], self.rng)
        w = self.rng.standard_normal((len(z), model.B.shape[2]))
        x, y_pred = propagate(model, self.x, z, w, b[z], c[z])
        Linv, logdet = self._measurement_noise(mask)
        Linv = Linv[z]
        r, quad = whitened(y, mask, y_pred, Linv)
        flagged = None
        if gate.closer_look(quad):
            screened, flagged = screen(self, y, mask, u, gate, *self._every_mode(y, mask, b, c))
            if screened is not None:
                return screened
        q, loglik, mean, cov, posterior, yp = weigh(model, self.logw, z, x, y_pred, quad, logdet[z], r.shape[-1])
        size = self.advance(mask, z, x, r, Linv, q, self.resampler(q))
        return Estimate(posterior, mean, cov, yp, float(loglik), size, flagged=flagged)

    def advance(self, mask, z, x, r, Linv, q, resampled) -> float:
        """Take the particles `resampled` (ancestors, log-weights, ESS, as the resampler gives them)
        from this step's (modes z, states x, weights q), the step's predictive and genealogy kept; the ESS."""
        ancestors, logw, size = resampled
        self.predictive = Predictive(z, self.logw, r, Linv, mask)
        self.genealogy = Genealogy(np.arange(len(z)), z, q, ancestors)
        self.z, self.x, self.logw = z[ancestors], x[ancestors], logw
        return size


def propagate(model, x, z, w, b, c):
    """States drawn from the state equation and their predicted outputs, over any leading axes: from
    states x (..., N, nx) into modes z (..., N) with process noise w (..., N, nw) and the offsets b
    (..., N, nx) and c (..., N, ny) of each particle's mode."""
    x = np.einsum("...nij,...nj->...ni", model.A[z], x) + b + np.einsum("...nij,...nj->...ni", model.B[z], w)
    return x, np.einsum("...nij,...nj->...ni", model.C[z], x) + c


def whitened(y, mask, y_pred, Linv):
    """(residuals, squared Mahalanobis distances) of the readings y (..., ny) measured where mask is
    True against every particle's predicted outputs (..., N, ny), Linv (..., N, m, m) the inverse
    Cholesky factor of the measurement noise under its mode."""
    r = y[..., None, mask] - y_pred[..., mask]
    return r, quad_form(np.einsum("...nab,...nb->...na", Linv, r))


def weigh(model, log_prior, z, x, y_pred, quad, logdet, m):
    """What the readings make of the particles, over any leading axes (one filter's, or many units'
    side by side, each the same operations on its own arrays): (normalised weights, log-likelihood,
    the mixture's mean and covariance, the mode posterior, the predicted readings)."""
    q, loglik = normalize_rows(log_prior + log_density(quad, logdet, m))
    mean, cov = mixture_moments(q, x, np.zeros((model.nx, model.nx)))
    if q.ndim == 1:
        posterior = np.bincount(z, weights=q, minlength=model.K)
    else:
        posterior = np.bincount((np.arange(len(q))[:, None] * model.K + z).ravel(), weights=q.ravel(),
                                minlength=len(q) * model.K).reshape(len(q), model.K)
    prior = np.exp(log_prior - row_extreme(np.maximum, log_prior)[..., None])
    return q, loglik, mean, cov, posterior, (prior[..., None, :] @ y_pred)[..., 0, :] / prior.sum(axis=-1)[..., None]


def step_together(engines, y, mask, u, gates) -> Estimates:
    """`BootstrapPF.step` of several engines of one model with as many particles (units of a fleet):
    readings y (g, ny) measured where mask (ny,) is True, inputs u (g, nu), a gate each; their
    Estimates, row i engine i's. Each draws from its own Generator what it would alone, and their
    arithmetic runs with a leading axis over the engines, each engine's the same operations on its own
    arrays as its own step's, so each gets, bit for bit, what it would get alone."""
    model, g = engines[0].model, len(engines)
    N, nx, nw = len(engines[0].z), model.nx, model.B.shape[2]
    if (u == u[0]).all():  # units under the same inputs (the usual case) share their offsets, computed once
        b, c = (np.broadcast_to(a, (g,) + a.shape) for a in offsets(model, u[0]))
    else:
        b, c = (np.stack(a) for a in zip(*(offsets(model, x) for x in u)))
    uniforms, w = np.empty((g, N)), np.empty((g, N, nw))
    for e, drawn, noise in zip(engines, uniforms, w):  # sample_rows' numbers, then the process noise's, as alone
        e.rng.random(out=drawn)
        e.rng.standard_normal(out=noise)
    z = joined([e.z for e in engines])
    z = cdf_drawn(model.P.cumsum(axis=-1)[z], uniforms)  # each particle's row of P, cumulated
    each = np.arange(g)[:, None]
    x, y_pred = propagate(model, joined([e.x for e in engines]).reshape(g, N, nx), z, w, b[each, z], c[each, z])
    Linv, logdet = engines[0]._measurement_noise(mask)
    Linv, logdet = Linv[z], logdet[z]
    r, quad = whitened(y, mask, y_pred, Linv)
    out = Estimates.empty(g, model.K, nx, model.ny)
    screened, flagged = [], np.zeros_like(out.flagged)
    for i in Gate.closer_looks(gates, quad):
        e = engines[i]
        est, found = screen(e, y[i], mask, u[i], gates[i], *e._every_mode(y[i], mask, b[i], c[i]))
        if found is not None:
            flagged[i] = found
        if est is not None:
            out.put_one(i, est)
            screened.append(i)
    kept = np.setdiff1d(np.arange(g), screened) if screened else np.arange(g)
    if not len(kept):
        out.flagged[:] = flagged
        return out
    if screened:  # the engines whose step screening redid are done (every array here is its own)
        z, x, y_pred, r, quad, Linv, logdet = (a[kept] for a in (z, x, y_pred, r, quad, Linv, logdet))
    es = [engines[i] for i in kept.tolist()]
    q, loglik, mean, cov, posterior, yp = weigh(model, joined([e.logw for e in es]), z, x, y_pred, quad, logdet,
                                                r.shape[-1])
    resampled = [done or e.resampler(qj) for e, qj, done in zip(es, q, systematic_together(es, q))]
    sizes = advance_together(es, mask, z, x, r, Linv, q, resampled)
    out.put(kept, Estimates(posterior, mean, cov, yp, loglik, np.array(sizes, dtype=float), False, False))
    out.flagged[:] = flagged
    return out


def advance_together(engines, mask, z, x, r, Linv, q, resampled) -> list:
    """`BootstrapPF.advance` of engines side by side, each step's arrays with a leading engine axis and
    `resampled` what each one's resampler gave: their particles taken in one call, each engine's as
    alone; the ESS of each."""
    ancestors, logws, sizes = zip(*resampled)
    each = np.arange(len(engines))[:, None]
    ancestors = np.stack(ancestors)
    zs, xs = z[each, ancestors], x[each, ancestors]
    candidates = np.arange(z.shape[-1])
    for e, a, zj, xj, new_z, new_x, logw, rj, Lj, qj in zip(engines, ancestors, z, x, zs, xs, logws, r, Linv, q):
        e.predictive = Predictive(zj, e.logw, rj, Lj, mask)
        e.genealogy = Genealogy(candidates, zj, qj, a)
        e.z, e.x, e.logw = new_z, new_x, logw
    return list(sizes)


def systematic_together(engines, q) -> list:
    """The resampling of engines whose particles' weights are the rows of q (g, N), side by side:
    (ancestors, log-weights, ESS) for each that resamples this step with the systematic scheme, with
    the one number it draws from its own Generator; None for the others (they resample on their own)."""
    size = 1.0 / (q[:, None, :] @ q[:, :, None])[:, 0, 0]  # ess(w), row by row
    ones = np.ones(q.shape[-1], dtype=np.int64)
    going = [i for i, e in enumerate(engines) if e.resampler.scheme is systematic and e.resampler.resamples(size[i], ones)]
    out = [None] * len(engines)
    if going:
        n = engines[going[0]].resampler.n
        ancestors = systematic_rows(q[going], n, np.array([engines[i].rng.random() for i in going]))
        for j, i in enumerate(going):
            out[i] = ancestors[j], engines[i].resampler.uniform, size[i]
    return out
