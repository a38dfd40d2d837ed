"""`Options`: how a diagnosis runs, as one value that `Diagnosis`, `Fleet`, the file runs
(`diagnose_files`) and the live monitor all take, and the command line builds once from its flags."""

from __future__ import annotations

from dataclasses import dataclass

from ..infer import DEFAULT_ALGORITHM, Filter
from ..model import Model
from .alarms import AlarmRule


@dataclass(frozen=True)
class Options:
    """The filter (algorithm, particles: None for its default, seed, resampling scheme, ess_threshold;
    see jmlgdsl.infer.Filter), its smoothing lag (0: none; None: off-line), the causal moving-average
    window `prefilter` (None: off), the alarm rule (the `healthy` modes, None for the spec's first,
    the threshold on P(not healthy) and the persistence in steps) and `explain`: every finished row
    with its evidence per sensor. Nothing is checked here: the Filter and the AlarmRule a diagnosis
    makes of them refuse what they cannot take, in words."""

    algorithm: str = DEFAULT_ALGORITHM
    particles: int | None = None
    seed: int | None = None
    resampling: str = "systematic"
    ess_threshold: float = 1.0
    lag: int | None = 0
    prefilter: int | None = None
    healthy: tuple[str, ...] | None = None
    threshold: float = 0.5
    persistence: int = 1
    explain: bool = False

    def rule(self, model: Model) -> AlarmRule:
        """The alarm rule for a model's modes (its first mode healthy unless `healthy` names others)."""
        return AlarmRule(tuple(self.healthy or model.modes[:1]), self.threshold, self.persistence)

    def filter(self, model: Model) -> Filter:
        """A fresh Filter of these options over a model."""
        return Filter(model, self.algorithm, self.particles, self.seed, self.resampling, self.ess_threshold,
                      self.lag)
