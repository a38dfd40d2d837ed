"""Temporary simulator for learning's tests and example: outputs of a Model along a given mode path.

To be replaced by `jmlgdsl.simulate` once that lands.
"""

from __future__ import annotations

import numpy as np


def simulate_path(model, z, u, rng: np.random.Generator):
    """States x_0..x_T and outputs y_1..y_T of `model` following modes z (T,) under inputs u (T, nu).

    x_0 is drawn from N(mu0[z_1], Sigma0).
    """
    z = np.asarray(z, int)
    T = len(z)
    u = np.asarray(u, float).reshape(T, model.nu)
    x = np.empty((T + 1, model.nx))
    y = np.empty((T, model.ny))
    x[0] = rng.multivariate_normal(model.mu0[z[0]], model.Sigma0)
    for t in range(T):
        k = z[t]
        x[t + 1] = (model.A[k] @ x[t] + model.F[k] @ u[t] + model.f[k]
                    + model.B[k] @ rng.standard_normal(model.B.shape[2]))
        y[t] = model.C[k] @ x[t + 1] + model.G[k] @ u[t] + model.g[k] + model.D[k] @ rng.standard_normal(model.D.shape[2])
    return x, y
