"""Inference: which mode is the plant in? Particle filters (pf, rbpf, la-rbpf, fc-rbpf) and the
deterministic baselines (imm, mmae, exact) over one batched Kalman kernel.

`Filter` takes one row at a time (a live stream); `filter` and `smooth` a whole record.

    >>> import jmlgdsl
    >>> from jmlgdsl.infer import ALGORITHMS, Filter
    >>> list(ALGORITHMS)
    ['pf', 'rbpf', 'la-rbpf', 'fc-rbpf', 'imm', 'mmae', 'exact']
    >>> model = jmlgdsl.load("specs/dryer.jmlg")
    >>> f = Filter(model, "la-rbpf", particles=10, seed=1)
    >>> for temp in (50.5, 50.4, 44.0, 44.1, 44.0):   # the temperature drops: the fan has failed
    ...     step = f.step([temp], [15.0])
    >>> step.t, model.modes[step.map_mode]
    (5, 'fan')
"""

from .engine import FilterError
from .algorithms import ALGORITHMS, DEFAULT_ALGORITHM, particle_bytes
from .online import Filter, filter, smooth
from .result import Result, Step

__all__ = ["filter", "smooth", "Filter", "Result", "Step", "FilterError", "ALGORITHMS", "DEFAULT_ALGORITHM",
           "particle_bytes"]
