"""The log posterior a fit climbs, as a function of the unknowns' unconstrained coordinates z, and the
BFGS search over it that both the fit itself and its labelling rounds (jmlgdsl.fitting.labels) use."""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import minimize

from ..errors import JmlgError
from .family import Family
from .likelihood import loglik

GRADIENT_STEP = 1e-6  # forward-difference step in z (relative change of a positive unknown)
GTOL = 1e-3  # BFGS stops when no z-gradient entry exceeds this (far below one posterior sd's worth)
MAX_ITERATIONS = 200


class Posterior:
    """-log p(theta | data) up to a constant, as a function of z; counts its evaluations."""

    def __init__(self, family: Family, datasets, algorithm: str):
        self.family, self.datasets, self.algorithm = family, datasets, algorithm
        self.evaluations = 0

    def theta(self, z) -> np.ndarray:
        return np.array([p.from_z(v) for p, v in zip(self.family.priors, z)])

    def loglik(self, theta) -> float:
        """log p(data | theta); -inf where theta makes no model (a mode without a steady state, ...)."""
        self.evaluations += 1
        try:
            model = self.family.model(theta)
            with np.errstate(all="ignore"):
                return sum(loglik(model, d, self.algorithm) for d in self.datasets)
        except (JmlgError, np.linalg.LinAlgError, ValueError):
            return -math.inf

    def __call__(self, z) -> float:
        theta = self.theta(z)
        value = self.loglik(theta) + sum(p.logpdf(t) for p, t in zip(self.family.priors, theta))
        return -value if math.isfinite(value) else math.inf

    def gradient(self, z, f0=None) -> np.ndarray:
        """Forward differences in z."""
        f0 = self(z) if f0 is None else f0
        steps = np.eye(len(z)) * GRADIENT_STEP
        return np.array([(self(z + s) - f0) / GRADIENT_STEP for s in steps])


class Cached:
    """A posterior's objective, remembered for the points BFGS (and the curvature after it) ask about
    more than once."""

    def __init__(self, post: Posterior):
        self.post, self.values = post, {}

    def __call__(self, z) -> float:
        key = z.tobytes()
        if key not in self.values:
            self.values[key] = self.post(z)
        return self.values[key]


def bfgs(objective: Cached, z: np.ndarray, callback=None):
    """scipy's BFGS on a cached posterior from z, with forward-difference gradients: its result."""
    post = objective.post
    return minimize(objective, z, jac=lambda v: post.gradient(v, objective(v)), method="BFGS", callback=callback,
                    options={"gtol": GTOL, "maxiter": MAX_ITERATIONS})
