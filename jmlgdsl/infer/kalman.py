"""Batched Kalman kernel shared by every filter and by learning.

Every function broadcasts over leading axes (particles, modes, ...): means are (..., n), covariances
(..., n, n), matrices (..., rows, cols). Gaussian log-densities go through a Cholesky factor of the
innovation covariance (inverted only as a triangular factor shared by many residuals), never an
explicit inverse or determinant of the covariance, and covariances are symmetrised after every update.
"""

from __future__ import annotations

import numpy as np

from ..gaussian import symmetrize

LOG_2PI = np.log(2.0 * np.pi)
# Squared Mahalanobis distances are capped here, so an absurd outlier gets a tiny but finite
# log-density (the same for every hypothesis) instead of -inf, which would turn weights into NaN.
MAX_QUAD = 1e300


def _t(M):
    return np.swapaxes(M, -1, -2)


def predict_cov(Sig, A, Q):
    """Covariance time update A Sig A' + Q (it never depends on the data)."""
    return symmetrize(A @ Sig @ _t(A) + Q)


def predict(mu, Sig, A, b, Q):
    """Time update: mean A mu + b and covariance A Sig A' + Q (b holds F u + f)."""
    mu_p = np.einsum("...ij,...j->...i", A, mu) + b
    return mu_p, predict_cov(Sig, A, Q)


def innovation_cov(Sig_p, C, R):
    """Innovation covariance S = C Sig_p C' + R and C Sig_p (for the gain)."""
    CS = C @ Sig_p
    return symmetrize(CS @ _t(C) + R), CS


def innovation(mu_p, Sig_p, C, c, R):
    """Predicted output C mu_p + c, its covariance S = C Sig_p C' + R, and C Sig_p (for the gain)."""
    y_pred = np.einsum("...ij,...j->...i", C, mu_p) + c
    S, CS = innovation_cov(Sig_p, C, R)
    return y_pred, S, CS


def log_normal(r, S):
    """log N(r; 0, S) for residuals r (..., n) and covariances S (..., n, n), via Cholesky."""
    if r.shape[-1] == 0:
        return np.zeros(np.broadcast_shapes(r.shape[:-1], S.shape[:-2]))
    Linv, logdet = inverse_cholesky(S)
    return whitened_log_normal(np.einsum("...ij,...j->...i", Linv, r), logdet)


def inverse_cholesky(S):
    """(Linv, log det S) with Linv = L^-1 for the Cholesky factor L of S (..., n, n): the one
    factorisation of an innovation covariance, reused for its density (z = Linv r) and for the
    gain (S^-1 = Linv' Linv), and kept where one S whitens the residuals of many particles."""
    Linv = np.linalg.inv(np.linalg.cholesky(S))
    return Linv, -2.0 * np.log(np.diagonal(Linv, axis1=-2, axis2=-1)).sum(-1)


def whitened_log_normal(z, logdet):
    """log N(r; 0, S) from the whitened residuals z = L^-1 r (..., n) and log det S."""
    quad = np.minimum(np.einsum("...i,...i->...", z, z), MAX_QUAD)
    return -0.5 * (quad + logdet + z.shape[-1] * LOG_2PI)


def update(mu_p, Sig_p, y_pred, S, CS, y):
    """Measurement update with the innovation pieces (mu_p (..., nx), Sig_p (..., nx, nx), y_pred
    (..., m), S (..., m, m), CS = C Sig_p (..., m, nx), y (m,)): returns the filtered mean and
    covariance and log N(y; y_pred, S), all from one Cholesky factorisation of S."""
    if y.shape[-1] == 0:
        return mu_p, Sig_p, np.zeros(np.broadcast_shapes(y_pred.shape[:-1], S.shape[:-2]))
    Linv, logdet = inverse_cholesky(S)
    z = np.einsum("...ij,...j->...i", Linv, y - y_pred)  # whitened innovation
    W = Linv @ CS  # whitened C Sig_p: the gain is W' Linv, and C' S^-1 C = W' W
    mu = mu_p + np.einsum("...ji,...j->...i", W, z)
    Sig = symmetrize(Sig_p - _t(W) @ W)
    return mu, Sig, whitened_log_normal(z, logdet)


def observed(y):
    """Boolean mask of the measured entries of one observation vector (NaN = not measured)."""
    return ~np.isnan(y)


def step(mu, Sig, A, b, Q, C, c, R, y):
    """One full Kalman step with a possibly partial observation y (NaN entries skipped).

    Returns (mu_filtered, Sig_filtered, log p(y_obs | past), y_pred over all outputs, S over all outputs).
    """
    mu_p, Sig_p = predict(mu, Sig, A, b, Q)
    y_pred, S, CS = innovation(mu_p, Sig_p, C, c, R)
    m = observed(y)
    if m.all():
        mu_f, Sig_f, ll = update(mu_p, Sig_p, y_pred, S, CS, y)
    else:
        mu_f, Sig_f, ll = update(mu_p, Sig_p, y_pred[..., m], S[..., m, :][..., :, m], CS[..., m, :], y[m])
    return mu_f, Sig_f, ll, y_pred, S
