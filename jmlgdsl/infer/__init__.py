"""Inference: which mode is the plant in? Particle filters (pf, rbpf, la-rbpf, fc-rbpf) and the
deterministic baselines (imm, exact) over one batched Kalman kernel."""

from .engine import FilterError
from .algorithms import ALGORITHMS, DEFAULT_ALGORITHM, particle_bytes
from .online import Filter, filter, smooth
from .result import Result, Step

__all__ = ["filter", "smooth", "Filter", "Result", "Step", "FilterError", "ALGORITHMS", "DEFAULT_ALGORITHM",
           "particle_bytes"]
