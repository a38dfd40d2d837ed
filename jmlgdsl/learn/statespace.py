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

from ..infer.kalman import symmetrize


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
        return np.linalg.solve(np.eye(self.nx) - self.A, self.F @ np.asarray(u, float) + self.f)

    def free_run(self, u) -> np.ndarray:
        """Noise-free output y_1..y_T from the initial mean under inputs u (T, nu): the simulation fit."""
        x = self.mu0
        out = np.empty((len(u), self.C.shape[0]))
        for t, ut in enumerate(np.asarray(u, float)):
            x = self.A @ x + self.F @ ut + self.f
            out[t] = self.C @ x + self.G @ ut + self.g
        return out

    def observer_form(self) -> "StateSpace":
        """For one output: the basis in which C = [1 0 ... 0] and A is in observer canonical form.

        The first state is then the noise-free output itself, so the spec reads like the plant.
        The new state is x' = T x with T mapping the observability matrix of (A, C) onto that of the
        canonical pair; T A T^-1 and C T^-1 are then the canonical A and C, written exactly (zeros
        and ones, not rounded ones) rather than computed through an inverse. Raises LinAlgError when
        T is singular to working precision (a state the output does not see).
        """
        if self.C.shape[0] != 1:
            return self
        A_can, C_can = companion(np.poly(self.A)[1:]), np.eye(1, self.nx)
        T = np.linalg.solve(_observability(A_can, C_can), _observability(self.A, self.C))
        if not np.linalg.cond(T) < 1 / np.finfo(float).eps:
            raise np.linalg.LinAlgError("the output does not observe every state")
        return self.replace(A=A_can, F=T @ self.F, f=T @ self.f, C=C_can, Q=symmetrize(T @ self.Q @ T.T),
                            mu0=T @ self.mu0, Sigma0=symmetrize(T @ self.Sigma0 @ T.T))


def companion(a) -> np.ndarray:
    """Observer canonical A for y_t + a1 y_{t-1} + ... + an y_{t-n}: first column -a, ones above the diagonal."""
    a = np.real_if_close(np.asarray(a))
    n = len(a)
    A = np.eye(n, k=1)
    A[:, 0] = -np.real(a)
    return A


def _observability(A, C):
    """[C; CA; ...; CA^(n-1)]."""
    rows = [C]
    for _ in range(A.shape[0] - 1):
        rows.append(rows[-1] @ A)
    return np.vstack(rows)
