"""Small Gaussian linear algebra shared by every layer (simulation, filters, learning).

Functions broadcast over leading axes: matrices are (..., n, n).
"""

from __future__ import annotations

import numpy as np


def symmetrize(S):
    """(S + S') / 2 over the last two axes: keeps covariance updates exactly symmetric (1 x 1
    matrices already are, and come back as they are: a filter over one state does this at every step)."""
    if S.shape[-1] == 1:
        return S
    return 0.5 * (S + np.swapaxes(S, -1, -2))


def psd_sqrt(S):
    """A factor L with L L' = S for a symmetric positive semi-definite S (singular S allowed)."""
    vals, vecs = np.linalg.eigh(S)
    return vecs * np.sqrt(np.clip(vals, 0.0, None))
