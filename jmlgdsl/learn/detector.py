"""The catch-all mode's noise scale, chosen on the healthy mode's own rows held out.

A catch-all (`like HEALTHY { noise scale S }`) and the healthy mode make the detector of a learned
bank: a row alarms when the catch-all is the more probable (`run` detects with those two, then names
the fault with the others). The smaller S, the sooner a fault shows, and the more often normal
operation itself looks unlike the fitted healthy mode. S is chosen as the smallest of SCALES whose
detector stays quiet on normal rows it was not fitted to: the healthy mode's regression at its
order is fitted to all but one of FOLDS contiguous blocks of its rows and predicts the block held
out one step ahead; with the residual e and its covariance Sigma, the catch-all's evidence on a row
is

    log N(e; 0, S^2 Sigma) - log N(e; 0, Sigma) = -ny log S + (1 - 1/S^2) e' Sigma^-1 e / 2,

and the detector's two-mode forward filter (its own transitions and prior, as `run` splits them
from the bank) runs over each block from its prior. The held-out share of rows where the catch-all
is the more probable must be at most QUIET; when no scale achieves it, the largest is kept, and the
learner says so.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .relative import FOLDS, Reference, forward, ridge
from .resolution import at_least

#: The catch-all noise scales tried, smallest (most sensitive) first.
SCALES = (1.25, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 7.0, 10.0, 15.0, 20.0, 30.0)
#: The largest share of held-out normal rows on which the chosen detector may alarm (half the 1 %
#: a plant's operators would accept, as a margin for normal operation the recordings did not see).
QUIET = 0.005


@dataclass(frozen=True)
class CatchAllScale:
    """The chosen scale, the held-out alarm share at every scale tried (SCALES' order), and whether
    the chosen one is quiet enough (False: even the largest alarms on more than QUIET)."""

    scale: float
    shares: tuple[float, ...]
    quiet: bool

    def describe(self, healthy: str) -> str:
        """A line for the learner's report."""
        share = self.shares[SCALES.index(self.scale)]
        held = f"{healthy}'s rows held out by {FOLDS}-fold cross-validation"
        if not self.quiet:
            return (f"catch-all noise scale {self.scale:g} (the largest tried: every scale of {SCALES[0]:g}-"
                    f"{SCALES[-1]:g} alarms on more than {QUIET:.1%} of {held}, this one on {share:.2%}; the "
                    f"normal mode does not describe its own recording well)")
        return (f"catch-all noise scale {self.scale:g} (the smallest of {SCALES[0]:g}-{SCALES[-1]:g} that alarms on "
                f"at most {QUIET:.1%} of {held}: {share:.2%})")


def catch_all_scale(reference: Reference, ys, us, P, p0) -> CatchAllScale:
    """The catch-all's scale from the healthy mode's runs (lists of arrays) in the regression of
    `reference` (`relative.Reference.of` those runs), P (2, 2) and p0 (2,) the detector's
    transitions and prior, healthy first."""
    X, Y = reference.equations(ys, us)
    N, ny = Y.shape
    logP, logp0 = np.log(np.asarray(P, float)), np.log(np.asarray(p0, float))
    alarms = np.zeros(len(SCALES))
    for block in np.array_split(np.arange(N), FOLDS):
        train = np.ones(N, bool)
        train[block] = False
        D, c, S = ridge(X[train], Y[train], np.zeros((X.shape[1], ny)), 0.0)
        L = np.linalg.cholesky(at_least(S, reference.floor))
        m = np.sum(np.linalg.solve(L, (Y[block] - X[block] @ D - c).T) ** 2, axis=0)
        scale = np.array(SCALES)[:, None]
        evidence = np.stack(np.broadcast_arrays(0.0, -ny * np.log(scale) + 0.5 * (1 - scale ** -2) * m), axis=-1)
        alarms += np.sum(forward(evidence, logP, logp0)[..., 1] > np.log(0.5), axis=-1)  # every scale at once
    shares = alarms / N
    quiet = shares <= QUIET
    i = int(np.argmax(quiet)) if quiet.any() else len(SCALES) - 1
    return CatchAllScale(SCALES[i], tuple(float(s) for s in shares), bool(quiet.any()))

