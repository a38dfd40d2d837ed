"""The detector of a learned bank, chosen by cross-validation: the healthy mode's noise inflation
and the catch-all's noise scale.

A catch-all (`like HEALTHY { noise scale S }`) and the healthy mode make the detector of a learned
bank: a row alarms when the catch-all is the more probable (`run` detects with those two, then names
the fault with the others). With the healthy mode's one-step residual e, its covariance Sigma
inflated by I^2 and the catch-all's by (I S)^2, the catch-all's evidence on a row is

    log N(e; 0, (I S)^2 Sigma) - log N(e; 0, I^2 Sigma) = -ny log S + (1 - 1/S^2) m / (2 I^2),

m = e' Sigma^-1 e, and the detector's two-mode forward filter adds it up over the rows. So every
pair ranks a single row by m alike; what they set is where the alarm fires. A row pushes toward the
alarm when m / ny exceeds about I^2 (exactly 2 I^2 log S / (1 - 1/S^2)), and S sets how fast such
rows add up against the chain's reluctance to switch: a large S alarms at once on a single wild row,
an S near 1 only on a run of rows above that level. The inflation I is there because a regression
over many sensors fits its own rows better than rows it has not seen: its residual covariance is
too small for the plant's next recording, and the detector's level is best placed by rows held out.

Each pair of INFLATIONS x SCALES is scored on rows the healthy fit has not seen. Normal rows: the
healthy mode's regression at its order is fitted to all but one of FOLDS contiguous blocks of its
rows and predicts the block held out one step ahead; the detector's two-mode forward filter (its
own transitions and prior, as `run` splits them from the bank) runs over each block from its prior,
and the held-out share of rows where the catch-all is the more probable is the pair's false-alarm
share. Fault rows, when the bank has fault modes: the regression fitted to every normal row
predicts each fault recording, the filter runs over it from its prior, and the share of its rows
alarmed is the pair's detection of that fault. The chosen pair is, of those that alarm on at most
QUIET of the held-out normal rows, the one that detects the most (the mean over the fault modes), the
quieter on a tie. Without fault rows the inflation stays 1 and the scale is the smallest quiet one
(the most sensitive to anything that makes the residuals larger). When no pair is quiet, the quietest
is kept, and the learner says so.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .relative import FOLDS, Reference, forward, ridge
from .resolution import at_least

#: The healthy mode's noise inflations tried (1: as fitted).
INFLATIONS = (1.0, 1.1, 1.2, 1.3, 1.4, 1.5, 1.7, 2.0, 2.5, 3.0)
#: The catch-all noise scales tried, smallest (most sensitive) first.
SCALES = (1.1, 1.25, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 7.0, 10.0, 15.0, 20.0, 30.0)
#: The largest share of held-out normal rows on which the chosen detector may alarm (half the 1 %
#: a plant's operators would accept, as a margin for normal operation the recordings did not see).
QUIET = 0.005


@dataclass(frozen=True)
class Detector:
    """The chosen inflation and scale; the held-out alarm share of every pair tried (INFLATIONS x
    SCALES), the mean detection of the fault recordings for every pair (None without fault rows);
    and whether the chosen pair is quiet enough (False: every pair alarms on more than QUIET)."""

    inflation: float
    scale: float
    shares: np.ndarray
    detected: np.ndarray | None
    quiet: bool

    def describe(self, healthy: str) -> str:
        """A line for the learner's report."""
        at = INFLATIONS.index(self.inflation), SCALES.index(self.scale)
        held = f"{healthy}'s rows held out by {FOLDS}-fold cross-validation"
        pair = (f"catch-all noise scale {self.scale:g}" if self.inflation == 1 else
                f"catch-all noise scale {self.scale:g} over {healthy}'s noise x{self.inflation:g}")
        if not self.quiet:
            return (f"{pair} (the quietest tried: every pair alarms on more than {QUIET:.1%} of {held}, this "
                    f"one on {self.shares[at]:.2%}; the normal mode does not describe its own recording well)")
        if self.detected is None:
            return (f"{pair} (the smallest of {SCALES[0]:g}-{SCALES[-1]:g} that alarms on at most {QUIET:.1%} "
                    f"of {held}: {self.shares[at]:.2%})")
        return (f"{pair} (of {healthy}'s noise x{INFLATIONS[0]:g}-{INFLATIONS[-1]:g} and scales {SCALES[0]:g}-"
                f"{SCALES[-1]:g}, the pair that alarms on at most {QUIET:.1%} of {held} ({self.shares[at]:.2%}) "
                f"and detects the most of the fault recordings' rows: {self.detected[at]:.1%})")


def choose_detector(reference: Reference, ys, us, faults, P, p0) -> Detector:
    """The detector from the healthy mode's runs (lists of arrays ys, us) in the regression of
    `reference` (`relative.Reference.of` those runs), the fault modes' runs `faults` ([(ys, us)
    per fault mode], empty for none), P (2, 2) and p0 (2,) the detector's transitions and prior,
    healthy first."""
    X, Y = reference.equations(ys, us)
    N, ny = Y.shape
    alarms = np.zeros((len(INFLATIONS), len(SCALES)))
    for block in np.array_split(np.arange(N), FOLDS):
        train = np.ones(N, bool)
        train[block] = False
        D, c, S = ridge(X[train], Y[train], np.zeros((X.shape[1], ny)), 0.0)
        alarms += np.sum(_alarmed(_distances(X[block], Y[block], D, c, at_least(S, reference.floor)), ny, P, p0),
                         axis=-1)
    shares = alarms / N
    quiet = shares <= QUIET
    if not faults:
        i = int(np.argmax(quiet[0])) if quiet[0].any() else len(SCALES) - 1
        return Detector(INFLATIONS[0], SCALES[i], shares, None, bool(quiet[0, i]))
    detected = np.mean([_detection(reference, fys, fus, ny, P, p0) for fys, fus in faults], axis=0)
    if quiet.any():  # the most detection first, the quieter on a tie, then the smaller inflation and scale
        ranked = np.lexsort((shares.ravel(), -detected.ravel()))
        best = ranked[quiet.ravel()[ranked]][0]
    else:
        best = np.argmin(shares)
    i, j = np.unravel_index(best, shares.shape)
    return Detector(INFLATIONS[i], SCALES[j], shares, detected, bool(quiet[i, j]))


def _distances(X, Y, D, c, S) -> np.ndarray:
    """Each row's squared Mahalanobis distance m of its residual under the regression (D, c, S)."""
    L = np.linalg.cholesky(S)
    return np.sum(np.linalg.solve(L, (Y - X @ D - c).T) ** 2, axis=0)


def _alarmed(m, ny, P, p0) -> np.ndarray:
    """(inflations, scales, rows) True where the detector's forward filter puts the catch-all on
    top, every pair at once, from the rows' distances m."""
    inflation, scale = np.array(INFLATIONS)[:, None, None], np.array(SCALES)[None, :, None]
    evidence = -ny * np.log(scale) + 0.5 * (1 - scale ** -2) * m / inflation ** 2
    density = np.stack(np.broadcast_arrays(0.0, evidence), axis=-1)
    logP, logp0 = np.log(np.asarray(P, float)), np.log(np.asarray(p0, float))
    return forward(density, logP, logp0)[..., 1] > np.log(0.5)


def _detection(reference: Reference, ys, us, ny, P, p0) -> np.ndarray:
    """(inflations, scales) the share of one fault mode's rows alarmed, its runs pooled, each
    predicted by the regression fitted to every healthy row and filtered from the prior."""
    alarmed = [_alarmed(_distances(*reference.equations([y], [u]), reference.W, reference.c, reference.S), ny, P, p0)
               for y, u in zip(ys, us)]
    return np.concatenate(alarmed, axis=-1).mean(axis=-1)
