"""The log-likelihood of recorded data under a Model, as a fit needs it.

Data whose every row names its mode have an exact likelihood: one Kalman filter that follows the
labelled modes (a mode sequence is a linear-Gaussian model), plus the log-probability of that
sequence under the chain. Unlabelled data take a filter's likelihood, IMM by default."""

from __future__ import annotations

import numpy as np

from ..data import Data
from ..infer import kalman
from ..infer.online import Filter
from ..model import Model


def labelled(data: Data) -> bool:
    """Whether every row of the data names its mode (the likelihood is then exact)."""
    return data.modes is not None and bool((data.modes >= 0).all())


def loglik(model: Model, data: Data, algorithm: str = "imm", seed=0) -> float:
    """log p(y | model) for one recording: exact when labelled, else the filter's (with a fixed seed,
    so a particle filter's likelihood is a deterministic function of the model)."""
    if labelled(data):
        return labelled_loglik(model, data.y, data.u, data.modes)
    f = Filter(model, algorithm, seed=seed)
    for y, u in zip(data.y, data.u):
        f.step(y, u)
    return f.loglik


def labelled_loglik(model: Model, y: np.ndarray, u: np.ndarray, modes: np.ndarray) -> float:
    """log p(y_1:T, z_1:T) with the modes z known: a Kalman filter through the labelled modes (from
    x_0 ~ N(mu0[z_1], Sigma0)) and log p(z_1:T) under the chain. y (T, ny) with NaN where not
    measured, u (T, nu), modes (T,) indices.

    The covariance recursion does not depend on the data: once it has settled in a mode (to rounding,
    while every output is measured) the gain is kept and each step costs a few matrix-vector products."""
    b = np.einsum("kij,tj->tki", model.F, u) + model.f  # F u_t + f per mode, for the whole record at once
    c = np.einsum("kij,tj->tki", model.G, u) + model.g
    A, Q, C, R = model.A, model.Q, model.C, model.R
    mu, Sig = model.mu0[modes[0]], model.Sigma0
    masks = ~np.isnan(y)
    complete = masks.all(axis=1)
    total, steady = 0.0, None  # steady: (mode, gain', whitening factor, log-density constant) once settled
    for t, k in enumerate(modes):
        if steady is not None and steady[0] == k and complete[t]:
            _, gain_t, Linv, constant = steady
            r = y[t] - C[k] @ (mu_p := A[k] @ mu + b[t, k]) - c[t, k]
            z = Linv @ r
            mu = mu_p + gain_t.T @ r
            total += constant - 0.5 * min(float(z @ z), kalman.MAX_QUAD)
            continue
        mu_p, Sig_p = kalman.predict(mu, Sig, A[k], b[t, k], Q[k])
        y_pred, S, CS = kalman.innovation(mu_p, Sig_p, C[k], c[t, k], R[k])
        mu, Sig_new, ll, _ = kalman.update(mu_p, Sig_p, y_pred, S, CS, y[t], masks[t])
        total += float(ll)
        settled = complete[t] and kalman.settled(Sig_new, Sig)
        steady = _steady(k, S, CS) if settled else None
        Sig = Sig_new
    with np.errstate(divide="ignore"):
        log_chain = np.log(model.p0 @ model.P)[modes[0]] + model.logP[modes[:-1], modes[1:]].sum()
    return total + float(log_chain)


def _steady(k: int, S: np.ndarray, CS: np.ndarray):
    """The settled update of mode k: its gain' S^-1 C Sig_p, the whitening factor of S and the
    constant part of the log-density."""
    gain_t, Linv, logdet = kalman.gain(S, CS)
    return k, gain_t, Linv, -0.5 * (logdet + len(S) * kalman.LOG_2PI)
