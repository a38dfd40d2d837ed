"""Random state: every stochastic function takes one `seed` argument that is a seed or a Generator.

As the Scientific Python recommendation for random state (SPEC 7) describes: None draws fresh
entropy, a non-negative whole number (or a SeedSequence) reproduces a run bit for bit, and a
`numpy.random.Generator` is used as it is, so a caller can thread one stream through many calls.
"""

from __future__ import annotations

import numpy as np

from .errors import DataError


def generator(seed=None) -> np.random.Generator:
    """A Generator for `seed`: the Generator itself, or one seeded with it (None = fresh entropy)."""
    if isinstance(seed, np.random.Generator):
        return seed
    if isinstance(seed, bool):
        raise DataError(f"the seed must be a non-negative whole number, got {seed!r}")
    try:
        return np.random.default_rng(seed)
    except (TypeError, ValueError):
        raise DataError(f"the seed must be a non-negative whole number, got {seed!r}") from None
