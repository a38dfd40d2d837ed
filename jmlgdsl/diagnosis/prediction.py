"""The spread of the one-step prediction of each output, for a band around the predicted reading.

From the estimate after row t-1 (the mode posterior and the state's mean and covariance, as every
filter reports them), each mode k predicts y_t as N(y_k, S_k) with y_k = C_k (A_k m + b_k) + c_k and
S_k = C_k (A_k P A_k' + Q_k) C_k' + R_k; weighted by the predicted mode probabilities w = p' P, the
prediction's variance per output is sum_k w_k (S_k,ii + (y_k,i - y_i)^2), y = sum_k w_k y_k. For the
IMM filter this is the prediction from the moment-matched state rather than from each mode's own
mixed moments; the two agree once the posterior settles on a mode.

    >>> import jmlgdsl
    >>> model = jmlgdsl.load("specs/dryer.jmlg")
    >>> sim = jmlgdsl.simulate(model, 50, seed=1)
    >>> steps = jmlgdsl.filter(model, sim.y, sim.u)
    >>> sd = predictive_sd(model, steps.mode_posterior[48], steps.state_mean[48], steps.state_cov[48], sim.u[49])
    >>> bool(abs(sim.y[49, 0] - steps.y_pred[49, 0]) < 3 * sd[0])
    True
"""

from __future__ import annotations

import numpy as np

from ..infer import kalman
from ..infer.engine import offsets


def predictive_sd(model, posterior, mean, cov, u) -> np.ndarray:
    """(ny,) standard deviation of the one-step prediction of each output of the row with inputs u,
    from the estimate after the row before it (mode posterior (K,), state mean (nx,), covariance
    (nx, nx)); for many units at once, (n, ny) from (n, K), (n, nx), (n, nx, nx) and (n, nu)."""
    w = (posterior[..., None, :] @ model.P)[..., 0, :]  # (..., K); P (K, K), or a unit's own (n, K, K)
    b, c = offsets(model, u)  # (..., K, nx), (..., K, ny)
    S, _ = kalman.innovation_cov(kalman.predict_cov(cov[..., None, :, :], model.A, model.Q), model.C, model.R)
    means = (model.C @ (model.A @ mean[..., None, :, None])[..., 0][..., None] + b[..., None])[..., 0] + c
    spread = (means - (w[..., None, :] @ means)) ** 2
    return np.sqrt((w[..., None, :] @ (np.diagonal(S, axis1=-2, axis2=-1) + spread))[..., 0, :])
