"""The filtering algorithms by name: one table that the API, `run` and `bench` all read."""

from __future__ import annotations

from dataclasses import dataclass

from ..model import Model
from .engine import Engine, Resampler
from .imm import IMM
from .pf import BootstrapPF
from .rbpf import RBPF, Exact, FearnheadCliffordRBPF, LookAheadRBPF


@dataclass(frozen=True)
class Algorithm:
    """A registered filter: its engine class and its default particle count (None: it has no particles,
    and its engine is built from the model alone)."""

    name: str
    engine: type
    default_particles: int | None
    summary: str

    @property
    def uses_particles(self) -> bool:
        return self.default_particles is not None

    def build(self, model, particles, rng, resampler: Resampler | None) -> Engine:
        """A fresh engine at t = 0."""
        if not self.uses_particles:
            return self.engine(model)
        return self.engine(model, particles, rng, resampler)


ALGORITHMS = {a.name: a for a in (
    Algorithm("pf", BootstrapPF, 200, "bootstrap particle filter over mode and state"),
    Algorithm("rbpf", RBPF, 100, "Rao-Blackwellised PF, modes drawn from the transition prior"),
    Algorithm("la-rbpf", LookAheadRBPF, 10, "look-ahead RBPF: every next mode weighed before resampling"),
    Algorithm("fc-rbpf", FearnheadCliffordRBPF, 4, "look-ahead RBPF with Fearnhead-Clifford optimal selection"),
    Algorithm("imm", IMM, None, "interacting multiple models: one moment-matched Gaussian per mode"),
    Algorithm("exact", Exact, None, "every mode history: the exact posterior, for short sequences"),
)}
# The lowest error per unit of time on every published plant (docs/filters.md).
DEFAULT_ALGORITHM = "imm"


def particle_bytes(model: Model) -> int:
    """Memory one particle takes in the largest filter (a Rao-Blackwellised particle keeps a Kalman
    mean and covariance, and its predictions for every mode, with a copy made by resampling)."""
    nx, ny = model.nx, model.ny
    return 16 * model.K * (nx + nx * nx + ny + ny * ny + nx * ny + 2)
