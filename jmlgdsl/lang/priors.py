"""Prior distributions of a spec's unknowns: their densities, medians and the unconstrained
coordinate a fit moves in (identity on the real line, log on (0, inf), logit on an interval).

A prior is small and numeric on purpose: the language evaluates its arguments (jmlgdsl.lang.unknowns)
and the fit (jmlgdsl.fitting) only needs log p(theta), the map theta <-> z and its derivative.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import special

HALF_LOG_2PI = 0.5 * math.log(2.0 * math.pi)
PROBIT_HALF = 0.6744897501960817  # the 75th percentile of N(0, 1): the median of |N(0, 1)|

# name -> (argument names, what each must be); the order is the order of the positional arguments
FAMILIES = {
    "Normal": ("mean", "sd"),
    "LogNormal": ("mu", "sigma"),
    "HalfNormal": ("sd",),
    "Uniform": ("low", "high"),
}


class PriorError(ValueError):
    """Arguments that make no distribution (a negative sd, low >= high)."""


@dataclass(frozen=True)
class Prior:
    """One of FAMILIES with its arguments: Normal(mean, sd), LogNormal(mu, sigma) of log(theta),
    HalfNormal(sd) on theta > 0, Uniform(low, high)."""

    family: str
    args: tuple[float, ...]

    def __post_init__(self):
        if self.family not in FAMILIES:
            raise PriorError(f"unknown prior {self.family!r}; use {', '.join(FAMILIES)}")
        names = FAMILIES[self.family]
        if len(self.args) != len(names):
            raise PriorError(f"{self.family} takes {len(names)} argument{'s' * (len(names) > 1)}: "
                             f"{self.family}({', '.join(names)})")
        if not all(math.isfinite(a) for a in self.args):
            raise PriorError(f"the arguments of {self.family} must be finite numbers")
        if self.family in ("Normal", "LogNormal", "HalfNormal") and not self.args[-1] > 0:
            raise PriorError(f"the {names[-1]} of {self.family} must be positive (got {self.args[-1]:g})")
        if self.family == "Uniform" and not self.args[0] < self.args[1]:
            raise PriorError(f"Uniform(low, high) needs low < high (got {self.args[0]:g}, {self.args[1]:g})")

    def __str__(self) -> str:
        return f"{self.family}({', '.join(f'{a:.6g}' for a in self.args)})"

    @property
    def median(self) -> float:
        """The value a spec runs with before it is fitted."""
        a = self.args
        return {"Normal": lambda: a[0], "LogNormal": lambda: math.exp(a[0]),
                "HalfNormal": lambda: a[0] * PROBIT_HALF, "Uniform": lambda: 0.5 * (a[0] + a[1])}[self.family]()

    def contains(self, theta: float) -> bool:
        """Whether theta lies where the prior has density (the open interval for Uniform)."""
        if self.family == "Normal":
            return math.isfinite(theta)
        if self.family == "Uniform":
            return self.args[0] < theta < self.args[1]
        return 0.0 < theta < math.inf

    def logpdf(self, theta: float) -> float:
        """log p(theta); -inf outside the support."""
        if not self.contains(theta):
            return -math.inf
        a = self.args
        if self.family == "Normal":
            return -0.5 * ((theta - a[0]) / a[1]) ** 2 - math.log(a[1]) - HALF_LOG_2PI
        if self.family == "LogNormal":
            r = math.log(theta)
            return -0.5 * ((r - a[0]) / a[1]) ** 2 - math.log(a[1]) - HALF_LOG_2PI - r
        if self.family == "HalfNormal":
            return -0.5 * (theta / a[0]) ** 2 - math.log(a[0]) - HALF_LOG_2PI + math.log(2.0)
        return -math.log(a[1] - a[0])

    # --------------------------------------------------------------- the unconstrained coordinate z
    def to_z(self, theta: float) -> float:
        """z for theta: theta itself, log(theta), or the logit of its place in (low, high)."""
        if self.family == "Normal":
            return float(theta)
        if self.family == "Uniform":
            lo, hi = self.args
            return float(special.logit((theta - lo) / (hi - lo)))
        return math.log(theta)

    def from_z(self, z: float) -> float:
        """theta for z (the inverse of to_z)."""
        if self.family == "Normal":
            return float(z)
        if self.family == "Uniform":
            lo, hi = self.args
            return lo + (hi - lo) * float(special.expit(z))
        return math.exp(z)

    def dtheta_dz(self, z: float) -> float:
        """d theta / d z at z: how a step in z stretches into theta (for standard errors)."""
        if self.family == "Normal":
            return 1.0
        if self.family == "Uniform":
            lo, hi = self.args
            s = float(special.expit(z))
            return (hi - lo) * s * (1.0 - s)
        return math.exp(z)

    def log_jacobian(self, z: float) -> float:
        """log |d theta / d z|: what a density in z adds to p(theta) (for sampling in z)."""
        if self.family == "Normal":
            return 0.0
        if self.family == "Uniform":
            lo, hi = self.args
            return math.log(hi - lo) - np.logaddexp(0.0, z) - np.logaddexp(0.0, -z)
        return z

    def draw(self, rng: np.random.Generator) -> float:
        """One value from the prior (where a fit's extra starts begin)."""
        a = self.args
        if self.family == "Normal":
            return float(rng.normal(a[0], a[1]))
        if self.family == "LogNormal":
            return math.exp(rng.normal(a[0], a[1]))
        if self.family == "HalfNormal":
            return abs(float(rng.normal(0.0, a[0])))
        return float(rng.uniform(a[0], a[1]))
