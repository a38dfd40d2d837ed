"""The log posterior a fit climbs, as a function of the unknowns' unconstrained coordinates z, and the
BFGS search over it that both the fit itself and its labelling rounds (jmlgdsl.fitting.labels) use."""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import minimize

from ..errors import JmlgError
from .family import Family
from .likelihood import loglik, logliks

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
        return self._negative(theta, self.loglik(theta))

    def _negative(self, theta, loglik: float) -> float:
        """-log p(theta | data) up to a constant, from log p(data | theta); inf where it is not finite."""
        value = loglik + sum(p.logpdf(t) for p, t in zip(self.family.priors, theta))
        return -value if math.isfinite(value) else math.inf

    def many(self, zs) -> np.ndarray:
        """The objective at several points, their likelihoods computed together (`logliks`: under IMM,
        one pass over each record for all of them), each the value `self(z)` gives."""
        thetas = [self.theta(z) for z in zs]
        self.evaluations += len(zs)
        models = []
        for theta in thetas:
            try:
                models.append(self.family.model(theta))
            except (JmlgError, np.linalg.LinAlgError, ValueError):
                models.append(None)
        with np.errstate(all="ignore"):
            per_data = [logliks(models, d, self.algorithm) for d in self.datasets]
        return np.array([self._negative(theta, sum(values[i] for values in per_data))
                         for i, theta in enumerate(thetas)])

    def gradient(self, z, f0=None) -> np.ndarray:
        """Forward differences in z, the shifted points' likelihoods computed together (`many`)."""
        f0 = self(z) if f0 is None else f0
        steps = np.eye(len(z)) * GRADIENT_STEP
        with np.errstate(invalid="ignore"):  # inf - inf: no gradient where no model, as with Python's floats
            return (self.many([z + s for s in steps]) - f0) / GRADIENT_STEP


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

    def many(self, zs) -> np.ndarray:
        """The objective at several points, those not asked before computed together (Posterior.many)."""
        new = list({z.tobytes(): z for z in zs if z.tobytes() not in self.values}.values())
        if len(new) == 1:
            self(new[0])
        elif new:
            self.values.update(zip((z.tobytes() for z in new), self.post.many(new)))
        return np.array([self.values[z.tobytes()] for z in zs])


def bfgs(objective: Cached, z: np.ndarray, callback=None):
    """scipy's BFGS on a cached posterior from z, with forward-difference gradients: its result."""
    post = objective.post
    return minimize(objective, z, jac=lambda v: post.gradient(v, objective(v)), method="BFGS", callback=callback,
                    options={"gtol": GTOL, "maxiter": MAX_ITERATIONS})
