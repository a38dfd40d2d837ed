"""The filtering algorithms by name: one table that the API, `run`, `bench`, a fleet and a fit all
read. A row says what its filter can do (particles, fixed-lag and off-line smoothing, how many units
step together), so nothing outside this table asks for a filter by its name."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from ..model import Model
from . import pf, rbpf
from .engine import Engine, FilterError, Resampler
from .imm import IMM, MMAE
from .lagged import Genealogies, ImmWindow
from .smooth import HistoryPass, KimPass


@dataclass(frozen=True)
class Algorithm:
    """A registered filter and what it can do.

    `engine` is its engine class and `default_particles` its particle count (None: it has no
    particles, and its engine is built from the model alone). `window` is the fixed-lag smoother a
    Filter with a lag keeps beside it (jmlgdsl.infer.lagged); `whole_record` how `smooth` smooths a
    whole record after one filter pass (jmlgdsl.infer.smooth: KimPass, HistoryPass; None: the
    filter's own window over the whole record). For many units (jmlgdsl.infer.units):
    `vectorised` says one engine with a unit axis steps every unit (each unit's numbers those of its
    Filter alone, bit for bit), `step_together` steps the engines of units with the same readings
    and as many particles in one call (None: each on its own), and `share`, given every unit's
    engine before each step, lets them share what they can (rbpf.share: one covariance graph)."""

    name: str
    engine: type
    default_particles: int | None
    summary: str
    window: type
    whole_record: type | None = None
    vectorised: bool = False
    step_together: Callable | None = None
    share: Callable | None = None

    @property
    def uses_particles(self) -> bool:
        return self.default_particles is not None

    @property
    def deterministic(self) -> bool:
        """Whether its results are the same whatever the seed: a filter without particles draws nothing."""
        return not self.uses_particles

    def build(self, model, particles, rng, resampler: Resampler | None) -> Engine:
        """A fresh engine at t = 0."""
        if not self.uses_particles:
            return self.engine(model)
        return self.engine(model, particles, rng, resampler)


ALGORITHMS = {a.name: a for a in (
    Algorithm("pf", pf.BootstrapPF, 200, "bootstrap particle filter over mode and state", Genealogies,
              step_together=pf.step_together),
    Algorithm("rbpf", rbpf.RBPF, 100, "Rao-Blackwellised PF, modes drawn from the transition prior", Genealogies,
              step_together=rbpf.step_together, share=rbpf.share),
    Algorithm("la-rbpf", rbpf.LookAheadRBPF, 10, "look-ahead RBPF: every next mode weighed before resampling",
              Genealogies, step_together=rbpf.step_together, share=rbpf.share),
    Algorithm("fc-rbpf", rbpf.FearnheadCliffordRBPF, 4, "look-ahead RBPF with Fearnhead-Clifford optimal selection",
              Genealogies, step_together=rbpf.step_together, share=rbpf.share),
    Algorithm("imm", IMM, None, "interacting multiple models: one moment-matched Gaussian per mode", ImmWindow,
              whole_record=KimPass, vectorised=True),
    Algorithm("mmae", MMAE, None, "multiple-model adaptive estimation: imm's Kalman filters never mixed", ImmWindow,
              whole_record=KimPass),
    Algorithm("exact", rbpf.Exact, None, "every mode history: the exact posterior, for short sequences", Genealogies,
              whole_record=HistoryPass, step_together=rbpf.step_together, share=rbpf.share),
)}


def algorithm_named(name: str) -> Algorithm:
    """The row of the filter called `name`; a FilterError naming the filters otherwise."""
    if name not in ALGORITHMS:
        raise FilterError(f"unknown filter {name!r}; choose from {', '.join(ALGORITHMS)}")
    return ALGORITHMS[name]


# The lowest error per unit of time on every published plant (docs/filters.md).
DEFAULT_ALGORITHM = "imm"
# The filter that names the fault while a detect-then-name run's alarm is up (jmlgdsl.diagnosis.
# alarms.DetectThenName): Kalman filters that never mix, whose covariances settle whatever the
# posterior does, so a step costs the means, where an IMM namer seldom sure of one fault pays the
# full covariance step of every mode at every row. On the Tennessee Eastman bank's training
# recordings (18 faults over 52 outputs) it names the faulty rows as IMM does (90.94 % against
# 90.96 % right), in a fifth of the time.
NAMER_ALGORITHM = "mmae"


def particle_bytes(model: Model) -> int:
    """Memory one particle takes in the largest filter (a Rao-Blackwellised particle keeps a Kalman
    mean and covariance, and its predictions for every mode, with a copy made by resampling)."""
    nx, ny = model.nx, model.ny
    return 16 * model.K * (nx + nx * nx + ny + ny * ny + nx * ny + 2)
