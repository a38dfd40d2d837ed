"""The log-likelihood of recorded data under a Model, as a fit needs it.

Data whose every row names its mode have an exact likelihood: one Kalman filter that follows the
labelled modes (a mode sequence is a linear-Gaussian model), plus the log-probability of that
sequence under the chain. Unlabelled data take a filter's likelihood, IMM by default; `logliks`
takes the likelihoods of several models at once (the points of a finite-difference gradient), under
IMM as the units of one vectorised filter."""

from __future__ import annotations

import math

import numpy as np

from ..data import Data
from ..errors import JmlgError
from ..infer import kalman
from ..infer.algorithms import algorithm_named
from ..infer.engine import offsets
from ..infer.online import Filter
from ..infer.units import Units, stackable
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


def logliks(models, data: Data, algorithm: str = "imm", seed=0) -> list[float]:
    """`loglik` of each of `models` on one recording (-inf for None: values that make no model, and for
    a model whose filter fails). Under a vectorised filter (IMM) on unlabelled data, models of one shape
    are filtered side by side as the units of one vectorised filter (jmlgdsl.infer.units: each unit exactly as alone),
    one pass over the record for all of them."""
    out = [-math.inf] * len(models)
    valid = [i for i, m in enumerate(models) if m is not None]
    banks = [models[i] for i in valid]
    if len(banks) > 1 and algorithm_named(algorithm).vectorised and not labelled(data) and stackable(banks):
        try:
            fleet = Units(banks[0], len(banks), models=banks)
            n = len(banks)
            for y, u in zip(data.y, data.u):
                fleet.step(np.broadcast_to(y, (n, len(y))), np.broadcast_to(u, (n, len(u))))
            for i, value in zip(valid, fleet.loglik):
                out[i] = float(value)
            return out
        except (JmlgError, np.linalg.LinAlgError, ValueError):
            pass  # one model's filter failed: each on its own, below, so the others keep their values
    for i in valid:
        try:
            out[i] = loglik(models[i], data, algorithm, seed)
        except (JmlgError, np.linalg.LinAlgError, ValueError):
            pass
    return out


def labelled_loglik(model: Model, y: np.ndarray, u: np.ndarray, modes: np.ndarray) -> float:
    """log p(y_1:T, z_1:T) with the modes z known: a Kalman filter through the labelled modes (from
    x_0 ~ N(mu0[z_1], Sigma0)) and log p(z_1:T) under the chain. y (T, ny) with NaN where not
    measured, u (T, nu), modes (T,) indices.

    The covariance recursion does not depend on the data: once it has settled in a mode (to rounding,
    while every output is measured) its Kalman pieces are kept and each step costs a few
    matrix-vector products."""
    b, c = offsets(model, u)  # per step and mode, for the whole record at once
    A, Q, C, R = model.A, model.Q, model.C, model.R
    mu, Sig = model.mu0[modes[0]], model.Sigma0
    masks = ~np.isnan(y)
    complete = masks.all(axis=1)
    total, kept = 0.0, None  # kept: (mode, Linv, log det S, gain') of a settled covariance
    for t, k in enumerate(modes):
        if kept is not None and kept[0] == k and complete[t]:
            _, Linv, logdet, gain_t = kept
        else:
            Linv, logdet, gain_t, Sig_new = kalman.covariance_step(Sig, A[k], Q[k], C[k], R[k], masks[t])
            kept = (k, Linv, logdet, gain_t) if complete[t] and kalman.settled(Sig_new, Sig) else None
            Sig = Sig_new
        mu_p = A[k] @ mu + b[t, k]
        r = y[t] - C[k] @ mu_p - c[t, k]
        if not complete[t]:
            r = r[masks[t]]
        mu = mu_p + gain_t.T @ r
        z = Linv @ r
        total += float(kalman.log_density(z @ z, logdet, len(r)))
    with np.errstate(divide="ignore"):
        log_chain = np.log(model.p0 @ model.P)[modes[0]] + model.logP[modes[:-1], modes[1:]].sum()
    return total + float(log_chain)
