"""Batched Kalman kernel shared by every filter and by learning.

Every function broadcasts over leading axes (particles, modes, ...): means are (..., n), covariances
(..., n, n), matrices (..., rows, cols). Gaussian log-densities go through a Cholesky factor of the
innovation covariance (inverted only as a triangular factor shared by many residuals), never an
explicit inverse or determinant of the covariance, and covariances are symmetrised after every update.
Where the outputs read a run of states directly (`Model.output_states`), C may be given as that
slice: C Sig C' is then a view of a block of Sig, taken without products and exactly symmetric.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import blas

from ..gaussian import symmetrize

LOG_2PI = np.log(2.0 * np.pi)
# Squared Mahalanobis distances are capped here, so an absurd outlier gets a tiny but finite
# log-density (the same for every hypothesis) instead of -inf, which would turn weights into NaN.
MAX_QUAD = 1e300
# Kalman covariances count as settled when a step changes them by less than this, relative: they never
# depend on the data, so a filter that follows fixed matrices may keep its gain from then on.
SETTLED = 1e-13
EPS = np.finfo(float).eps


def transpose(M):
    """Transpose over the last two axes (a stack of matrices, matrix by matrix)."""
    return np.swapaxes(M, -1, -2)


def predict_cov(Sig, A, Q):
    """Covariance time update A Sig A' + Q (it never depends on the data)."""
    return symmetrize(A @ Sig @ transpose(A) + Q)


def predict(mu, Sig, A, b, Q):
    """Time update: mean A mu + b and covariance A Sig A' + Q (b holds F u + f)."""
    mu_p = np.einsum("...ij,...j->...i", A, mu) + b
    return mu_p, predict_cov(Sig, A, Q)


def picks(C) -> bool:
    """Whether C is given as the slice of the states the outputs read."""
    return isinstance(C, slice)


def innovation_cov(Sig_p, C, R):
    """Innovation covariance S = C Sig_p C' + R and C Sig_p (for the gain)."""
    if picks(C):
        CS = Sig_p[..., C, :]
        return CS[..., C] + R, CS
    CS = C @ Sig_p
    return symmetrize(CS @ transpose(C) + R), CS


def innovation(mu_p, Sig_p, C, c, R):
    """Predicted output C mu_p + c, its covariance S = C Sig_p C' + R, and C Sig_p (for the gain)."""
    y_pred = (mu_p[..., C] if picks(C) else np.einsum("...ij,...j->...i", C, mu_p)) + c
    S, CS = innovation_cov(Sig_p, C, R)
    return y_pred, S, CS


def cholesky(S):
    """(L, log det S) for the lower Cholesky factor L of S (..., n, n): the one factorisation of an
    innovation covariance, for its density and its gain."""
    if S.shape[-1] == 1 and (S > 0).all():  # one output: the factor is a square root
        return np.sqrt(S), np.log(S[..., 0, 0])
    try:
        L = np.linalg.cholesky(S)
    except np.linalg.LinAlgError:  # rounding made a huge covariance indefinite: floor its spectrum
        L = np.linalg.cholesky(_positive_definite(S))
    return L, 2.0 * np.log(np.diagonal(L, axis1=-2, axis2=-1)).sum(-1)


# Past this many rows a BLAS triangular solve, matrix by matrix, beats numpy's batched general
# inverse (3x at 50 rows, measured); below it the batch wins.
_BATCHED_ROWS = 10
# Up to this many rows a triangular factor is inverted by forward substitution, entry by entry over
# the whole stack at once: numpy's batched inverse makes a LAPACK call per matrix, 20 times slower for
# 10,000 3x3 factors (a fleet's step) and as fast for ten (one unit's), measured.
_SUBSTITUTED_ROWS = 4


def triangular_inverse(L):
    """L^-1 for lower-triangular L (..., n, n), n <= _BATCHED_ROWS: by forward substitution up to
    _SUBSTITUTED_ROWS rows, else numpy's batched inverse. The arithmetic of each matrix is the same
    however many are stacked, so a fleet's units get what each would alone.

        >>> triangular_inverse(np.array([[2.0, 0.0], [1.0, 4.0]]))
        array([[ 0.5  ,  0.   ],
               [-0.125,  0.25 ]])
    """
    n = L.shape[-1]
    if n > _SUBSTITUTED_ROWS:
        return np.linalg.inv(L)
    X = np.zeros_like(L)
    d = 1.0 / np.diagonal(L, axis1=-2, axis2=-1)
    for i in range(n):
        X[..., i, i] = d[..., i]
        for j in range(i):
            s = L[..., i, j] * X[..., j, j]
            for k in range(j + 1, i):
                s = s + L[..., i, k] * X[..., k, j]
            X[..., i, j] = -s * d[..., i]
    return X


def whiten(L, *Ms):
    """L^-1 M for lower-triangular L (..., n, n) and each M (..., n, m): whitened residuals and gains,
    all from one pass over L (small n: one batched inverse; large n: one solve of the Ms side by side)."""
    n = L.shape[-1]
    if n == 1:
        return tuple(M / L for M in Ms)
    if n <= _BATCHED_ROWS:
        Linv = triangular_inverse(L)
        return tuple(Linv @ M for M in Ms)
    lead = np.broadcast_shapes(L.shape[:-2], *(M.shape[:-2] for M in Ms))
    out = np.concatenate([np.broadcast_to(M, lead + M.shape[-2:]) for M in Ms], axis=-1)  # solved in place
    factors = np.ascontiguousarray(np.broadcast_to(L, lead + (n, n))).reshape(-1, n, n)
    for Lk, Zk in zip(factors, out.reshape(-1, n, out.shape[-1])):
        # Z' L' = M' in BLAS's column order is Z = L^-1 M in numpy's row order: no copies
        solved = blas.dtrsm(1.0, Lk.T, Zk.T, side=1, lower=0, overwrite_b=1)
        if not np.may_share_memory(solved, Zk):
            Zk.T[...] = solved
    return tuple(np.split(out, np.cumsum([M.shape[-1] for M in Ms[:-1]]), axis=-1))


def inverse_cholesky(S):
    """(Linv, log det S) with Linv = L^-1 for the Cholesky factor L of S (..., n, n), kept where one S
    whitens the residuals of many particles (z = Linv r) and gives the gain (S^-1 = Linv' Linv)."""
    L, logdet = cholesky(S)
    n = L.shape[-1]
    Linv = triangular_inverse(L) if 1 < n <= _BATCHED_ROWS else whiten(L, np.eye(n))[0]
    return Linv, logdet


def _positive_definite(S):
    """S with its eigenvalues raised to at least 1e-12 of the largest (and to the smallest normal
    float): the nearest covariance a Cholesky factorisation accepts, when rounding has broken one."""
    vals, vecs = np.linalg.eigh(symmetrize(S))
    floor = np.maximum(1e-12 * np.abs(vals).max(axis=-1, keepdims=True), np.finfo(float).tiny)
    return symmetrize((vecs * np.maximum(vals, floor)[..., None, :]) @ np.swapaxes(vecs, -1, -2))


def gain(S, CS):
    """(gain', Linv, log det S): gain' = S^-1 C Sig_p (..., ny, nx) from the innovation covariance S and
    C Sig_p, with the inverse Cholesky factor of S (to whiten innovations) and its log-determinant,
    all from one factorisation of S; kept where one gain serves many steps or particles."""
    if S.shape[-1] == 0:  # nothing measured
        return CS, S, np.zeros(S.shape[:-2])
    Linv, logdet = inverse_cholesky(S)
    return transpose(Linv) @ (Linv @ CS), Linv, logdet


def covariance_step(Sig, A, Q, C, R, mask):
    """The half of a Kalman step that never sees the data: from filtered covariances Sig (..., nx, nx),
    for the outputs where mask (ny,) is True, (Linv, log det S, gain' = S^-1 C Sig_p (..., m, nx),
    the next filtered covariance). Filters that meet the same covariance again keep these."""
    Sig_p = predict_cov(Sig, A, Q)
    S, CS = innovation_cov(Sig_p, C, R)
    if not mask.all():
        S, CS = S[..., mask, :][..., :, mask], CS[..., mask, :]
    gain_t, Linv, logdet = gain(S, CS)
    return Linv, logdet, gain_t, joseph(Sig_p, gain_t, C, R, mask)


def joseph(Sig_p, gain_t, C, R, mask):
    """The filtered covariance (I - K C) Sig_p (I - K C)' + K R K' (K = gain_t', the rows of C and
    R where mask is True): a sum of two positive semidefinite terms, so rounding cannot make it
    indefinite. The shorter Sig_p - K C Sig_p cancels to the measurement noise's size when that is
    far below the predicted spread (outputs read almost exactly, R / Q of 1e-7 in a learned bank of
    many sensors), and its rounding then leaves eigenvalues below zero that a bank's mixing turns
    into a diverging filter."""
    K = transpose(gain_t)
    nx = Sig_p.shape[-1]
    if picks(C) and K.shape[-1] == nx:  # every state read: K C = K
        KC = K
    elif picks(C):
        KC = np.zeros(K.shape[:-1] + (nx,))
        KC[..., np.arange(nx)[C][mask]] = K
    else:
        KC = K @ C[..., mask, :]
    I_KC = np.eye(nx) - KC
    R = R[..., mask, :][..., :, mask]
    return symmetrize(I_KC @ Sig_p @ transpose(I_KC) + times(K, R) @ transpose(K))


def times(M, R):
    """M @ R for a noise covariance R (..., m, m): for a diagonal R of many outputs (as learned banks
    have), M's columns scaled by R's diagonal, the same numbers without the matrix product (each
    entry's other terms are exact zeros), laid out as the product's (which the next product's
    arithmetic follows)."""
    if R.shape[-1] > _BATCHED_ROWS:
        diagonal = np.diagonal(R, axis1=-2, axis2=-1)
        if np.count_nonzero(R) == np.count_nonzero(diagonal):  # every entry off the diagonal is zero
            return np.multiply(M, diagonal[..., None, :], order="C")
    return M @ R


def tolerance(Sig, Linv=None):
    """How far each entry of covariances Sig (..., n, n) may move and still count as the same:
    SETTLED * sqrt(Sig_ii Sig_jj), so a state in small units keeps its own precision beside one in
    large units. Given the inverse Cholesky factor Linv (..., m, m) of the innovation covariance S of
    the covariance step taken from Sig, the step's own rounding error instead where it is larger:
    eps * kappa relative, for kappa = max_i (S^-1)_ii L_ii^2, which no scaling of the outputs changes
    and which is at most the condition number of S scaled to a unit diagonal. The gain and the
    filtered covariance go through S^-1 and are computed only to about that, so keeping the pieces of
    a covariance nearer than that moves the results by about what the step's own rounding does (the
    densities by up to kappa times as much, relative). A learned bank of 52 sensors (kappa near 5e6)
    never settles to SETTLED: its covariances wander by about 1e-9 from step to step, their rounding."""
    sd = np.sqrt(np.abs(np.diagonal(Sig, axis1=-2, axis2=-1)))
    relative = SETTLED
    if Linv is not None and Linv.shape[-1] > 1:
        # (S^-1)_ii is the squared length of Linv's column i, and L_ii = 1 / Linv_ii
        inverse_diagonal = np.einsum("...ki,...ki->...i", Linv, Linv)
        kappa = (inverse_diagonal / np.diagonal(Linv, axis1=-2, axis2=-1) ** 2).max(axis=-1)
        relative = np.maximum(SETTLED, EPS * kappa)[..., None, None]
    return relative * (sd[..., :, None] * sd[..., None, :])


def settled(new, old, tol=None):
    """(...) True where covariances new (..., n, n) equal old to their `tolerance` (of new, unless
    given: a filter comparing many covariances with the same old ones keeps it)."""
    return (np.abs(new - old) <= (tolerance(new) if tol is None else tol)).all(axis=(-2, -1))


def quad_form(z):
    """Squared length of whitened residuals z (..., n): the Mahalanobis distance r' S^-1 r."""
    return (z * z).sum(axis=-1)


def log_density(quad, logdet, n):
    """log N(r; 0, S) from quad = r' S^-1 r, log det S and the dimension n (quad capped at MAX_QUAD)."""
    return -0.5 * (np.minimum(quad, MAX_QUAD) + logdet + n * LOG_2PI)


def standard_deviations(Linv):
    """sqrt(diag S) (..., n) from the inverse Cholesky factor of S (rarely needed: for gating)."""
    L, = whiten(Linv, np.eye(Linv.shape[-1]))
    return np.sqrt(np.einsum("...ij,...ij->...i", L, L))


def update(mu_p, Sig_p, y_pred, S, CS, y, mask):
    """Measurement update with the innovation pieces (mu_p (..., nx), Sig_p (..., nx, nx), y_pred
    (..., ny), S (..., ny, ny), CS = C Sig_p (..., ny, nx)) and the entries of y (ny,) where mask is
    True. Returns the filtered mean and covariance, log N(y; y_pred, S) and the Mahalanobis distance
    of the measured entries, all from one Cholesky factorisation of S."""
    if not mask.all():
        y_pred, S, CS, y = y_pred[..., mask], S[..., mask, :][..., :, mask], CS[..., mask, :], y[mask]
    if y.shape[-1] == 0:
        zero = np.zeros(np.broadcast_shapes(y_pred.shape[:-1], S.shape[:-2]))
        return mu_p, Sig_p, zero, zero
    L, logdet = cholesky(S)
    # whitened C Sig_p and innovation in one solve: the gain is W' L^-1, and C' S^-1 C = W' W
    W, z = whiten(L, CS, (y - y_pred)[..., None])
    z = z[..., 0]
    mu = mu_p + np.einsum("...ji,...j->...i", W, z)
    Sig = symmetrize(Sig_p - transpose(W) @ W)
    quad = quad_form(z)
    return mu, Sig, log_density(quad, logdet, y.shape[-1]), quad


def observed(y):
    """Boolean mask of the measured entries of one observation vector (NaN = not measured)."""
    return ~np.isnan(y)


def step(mu, Sig, A, b, Q, C, c, R, y):
    """One full Kalman step with a possibly partial observation y (NaN entries skipped).

    Returns (mu_filtered, Sig_filtered, log p(y_obs | past), y_pred over all outputs, S over all outputs).
    """
    mu_p, Sig_p = predict(mu, Sig, A, b, Q)
    y_pred, S, CS = innovation(mu_p, Sig_p, C, c, R)
    mu_f, Sig_f, ll, _ = update(mu_p, Sig_p, y_pred, S, CS, y, observed(y))
    return mu_f, Sig_f, ll, y_pred, S
