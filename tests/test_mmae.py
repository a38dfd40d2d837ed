"""MMAE (`--filter mmae`, the namer of a detect-then-name run): one Kalman filter per mode that never
mixes with the others, and the mode posterior a forward pass over their one-step likelihoods through
the transition matrix. Checked against both written out here from their definitions, on random
models of two shapes."""

import numpy as np
import pytest
from infer_models import random_model
from scipy.special import logsumexp

import jmlgdsl
from jmlgdsl.infer.imm import DENSITIES_SETTLED, MMAE, ROUNDING
from jmlgdsl.simulation.linear import simulate


def lone_filters_and_forward_pass(model, y, u):
    """(T, K) p(mode | y_1:t) from each mode's own Kalman filter, started at its mu0 and Sigma0, and
    the forward recursion of a hidden Markov chain whose emission at t is that filter's N(y_t;
    y_pred, S); (T, K) the squared distances r' S^-1 r."""
    K = model.K
    means = model.mu0.copy()
    covs = np.array([model.Sigma0.copy() for _ in range(K)])
    log_mu, logP = np.log(model.p0), np.log(model.P)
    posterior, quads = [], []
    for t in range(len(y)):
        log_pred = logsumexp(log_mu[:, None] + logP, axis=0)
        loglik, quad = np.empty(K), np.empty(K)
        for k in range(K):
            A, C = model.A[k], model.C[k]
            Q, R = model.B[k] @ model.B[k].T, model.D[k] @ model.D[k].T
            m = A @ means[k] + model.F[k] @ u[t] + model.f[k]
            P = A @ covs[k] @ A.T + Q
            S = C @ P @ C.T + R
            r = y[t] - (C @ m + model.G[k] @ u[t] + model.g[k])
            K_gain = np.linalg.solve(S, C @ P).T
            means[k] = m + K_gain @ r
            covs[k] = (np.eye(len(m)) - K_gain @ C) @ P
            quad[k] = r @ np.linalg.solve(S, r)
            loglik[k] = -0.5 * (quad[k] + np.linalg.slogdet(2 * np.pi * S)[1])
        quads.append(quad)
        log_mu = log_pred + loglik
        log_mu -= logsumexp(log_mu)
        posterior.append(np.exp(log_mu))
    return np.array(posterior), np.array(quads)


@pytest.mark.parametrize("seed, K, nx, ny", [(3, 3, 2, 2), (11, 4, 3, 1)])
def test_mmae_is_each_modes_filter_alone_and_a_forward_pass_over_their_likelihoods(seed, K, nx, ny):
    # without the gross-error gate, which the definitions below do not have (a switch of mode puts
    # some readings beyond it under every mode)
    model = random_model(np.random.default_rng(seed), K=K, nx=nx, ny=ny, stay=0.9)
    model = model.replace(outlier_gate=np.full(ny, np.inf))
    sim = simulate(model, 60, seed=seed)
    expected, quads = lone_filters_and_forward_pass(model, sim.y, sim.u)
    # pieces kept only while the covariances repeat to their rounding (IMM's gauge): the same
    # arithmetic up to its order
    engine = MMAE(model)
    engine.gauge = ROUNDING
    exact = np.array([engine.step(y, np.ones(ny, bool), u).mode_posterior for y, u in zip(sim.y, sim.u)])
    assert np.allclose(exact, expected, rtol=1e-9, atol=1e-12)
    # MMAE's own gauge moves each log-density of a step by at most DENSITIES_SETTLED (m + quad) / 2:
    # a forward pass's log-posteriors by at most twice their sum over the steps, D, and the
    # posterior by at most exp(2 D) - 1
    got = jmlgdsl.filter(model, sim.y, sim.u, algorithm="mmae")
    D = 2 * (DENSITIES_SETTLED * (ny + quads) / 2).max(axis=1).sum()
    assert np.abs(got.mode_posterior - exact).max() <= np.expm1(2 * D)
    # IMM mixes the filters, and its posterior is another (the test tells the two apart)
    imm = jmlgdsl.filter(model, sim.y, sim.u, algorithm="imm").mode_posterior
    assert np.abs(imm - expected).max() > 1e-4


def test_mmae_covariances_settle_whatever_the_posterior_does():
    """After its covariances settle, a step of MMAE makes no covariance step, however unsure the
    posterior: the pieces it keeps serve every later step (IMM's only while the posterior is sure)."""
    from jmlgdsl.infer import kalman

    model = random_model(np.random.default_rng(5), K=3, nx=2, ny=2, stay=0.6)
    sim = simulate(model, 200, seed=5)
    engine = jmlgdsl.infer.Filter(model, "mmae")
    for t in range(100):
        engine.step(sim.y[t], sim.u[t])
    calls = []
    step = kalman.covariance_step
    kalman.covariance_step = lambda *args: calls.append(1) or step(*args)
    try:
        posts = [engine.step(sim.y[t], sim.u[t]).mode_posterior for t in range(100, 200)]
    finally:
        kalman.covariance_step = step
    assert min(p.max() for p in posts) < 0.9  # the posterior was unsure on some of these steps
    assert calls == []
