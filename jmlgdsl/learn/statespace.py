"""One mode's linear-Gaussian state-space model with explicit covariances, as learning handles it.

    x_t = A x_{t-1} + F u_t + f + w_t,   w_t ~ N(0, Q)        x_0 ~ N(mu0, Sigma0)
    y_t = C x_t     + G u_t + g + v_t,   v_t ~ N(0, R)

Learning works with Q and R (what EM estimates); a bank of these becomes a Model with B, D as
Cholesky factors.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ..compile.assemble import steady_state


@dataclass(frozen=True)
class StateSpace:
    """Matrices of one mode; shapes A (nx,nx), F (nx,nu), f (nx,), C (ny,nx), G (ny,nu), g (ny,)."""

    A: np.ndarray
    F: np.ndarray
    f: np.ndarray
    C: np.ndarray
    G: np.ndarray
    g: np.ndarray
    Q: np.ndarray
    R: np.ndarray
    mu0: np.ndarray
    Sigma0: np.ndarray

    @property
    def nx(self) -> int:
        """Number of states."""
        return self.A.shape[0]

    def replace(self, **changes) -> "StateSpace":
        """A copy with some matrices changed."""
        return dataclasses.replace(self, **changes)

    def poles(self) -> np.ndarray:
        """Eigenvalues of A, sorted by decreasing modulus."""
        p = np.linalg.eigvals(self.A)
        return p[np.argsort(-np.abs(p), kind="stable")]

    def gain(self) -> np.ndarray:
        """Steady-state gain C (I - A)^-1 F + G from inputs to outputs, (ny, nu)."""
        return self.C @ np.linalg.solve(np.eye(self.nx) - self.A, self.F) + self.G

    def steady_state(self, u) -> np.ndarray:
        """The state the noise-free model settles at under a constant input u."""
        return steady_state(self.A, self.F, self.f, np.asarray(u, float))

    def free_run(self, u) -> np.ndarray:
        """Noise-free output y_1..y_T from the initial mean under inputs u (T, nu): the simulation fit."""
        x = self.mu0
        out = np.empty((len(u), self.C.shape[0]))
        for t, ut in enumerate(np.asarray(u, float)):
            x = self.A @ x + self.F @ ut + self.f
            out[t] = self.C @ x + self.G @ ut + self.g
        return out
