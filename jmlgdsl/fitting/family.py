"""A spec whose unknowns are left open: the Model for any values of them, checked again without
re-reading the file, and for a nonlinear plant without rebuilding its equations or their symbolic
Jacobian (only re-linearised)."""

from __future__ import annotations

import numpy as np

from ..compile.lower import lower_linear
from ..compile.ode import linearise, ode_system, steady_states
from ..errors import JmlgError
from ..lang.check import check
from ..lang.declarations import declare
from ..lang.syntax import Spec
from ..lang.values import evaluate, ode_equations
from ..model import Model


class FitError(JmlgError):
    """A fit that cannot be made: no unknowns, no data, or no value of the unknowns that compiles."""


class Family:
    """The Models of one spec as its unknowns vary: `model(theta)` for theta in the order of `unknowns`."""

    def __init__(self, spec: Spec):
        declared, report = declare(spec)  # at the priors' medians: every unknown named, the structure checked
        if not declared.unknowns:
            raise FitError(f"{spec.path}: the spec has no unknowns to fit; give a parameter or a noise level a "
                           "prior, e.g. 'param U ~ LogNormal(log(1.2), 0.3)' (docs/fit.md)")
        self.spec, self.unknowns = spec, declared.unknowns
        self.names = [u.name for u in declared.unknowns]
        self.priors = [u.prior for u in declared.unknowns]
        self._equations = self._system = self._guesses = None
        if spec.ode:  # the equations once, for every model: zero divisors are refused as not finite numbers
            plant = evaluate(declared, report, ode_equations(declared, report))
            self._equations, self._system = plant.equations, ode_system(plant)
            # each mode's steady state at the priors' medians: where the others are looked for first
            # (the spec's guesses are for its nominal values; a plant far from them sends the root
            # search astray, and the integration to a steady state after it costs most of a fit)
            at_medians, report = check(spec, dict(zip(self.names, self.medians())), self._equations)
            try:
                self._guesses = steady_states(at_medians, self._system, report)
            except JmlgError:
                pass  # no steady state at the medians: the spec's guesses serve alone

    def model(self, theta) -> Model:
        """The compiled Model with the unknowns at theta (SpecError when those values make no model:
        a mode without a steady state, a negative noise level). The same theta gives the same Model,
        whatever was built before."""
        plant, report = check(self.spec, dict(zip(self.names, map(float, theta))), self._equations)
        return linearise(plant, self._system, report, self._guesses) if self._system else lower_linear(plant, report)

    def medians(self) -> np.ndarray:
        """Each unknown's prior median: what the spec runs with unfitted, and where a fit starts."""
        return np.array([p.median for p in self.priors])
