"""Whether a fit can be trusted. Each check looks at the peak the search ended on, or at the curvature
there, and says in words what went wrong; the report and the fitted spec carry these warnings, and
`jmlgdsl fit --strict` exits non-zero on any of them.

A search can end without finding a peak (a likelihood too rough for its finite differences, an
iteration limit), and a curvature taken by finite differences can be noise where the posterior is not
smooth; neither shows in the estimates and standard errors themselves, which then look confident.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from ..data import Data
from ..errors import JmlgError
from ..model import Model
from ..simulation.linear import simulate
from .likelihood import labelled, loglik

NEWTON_LIMIT = 0.5  # a Newton step from the estimate longer than this many standard errors: not at the peak
CURVATURE_CHECK = (1 / 3, 3.0)  # one sd out, the fall of the log posterior over the 1/2 its curvature predicts
ILL_CONDITIONED = 1e8  # condition number of the curvature scaled to a unit diagonal
UNMOVED = 1e-3  # an informed unknown that ends within this many prior sds (in z) of its start has not moved
# Squared standardised residuals this much above their expected 1 per reading, on average, beyond what
# the data the fitted model simulates itself score: a wrong peak. The fits of a random family of tank
# trains (benchmarks/fit/family.py) at a peak the truth beats lay 0.8 to 1.5 above; fits at the right
# peak near 0 (-0.14 to 0), and 0.27 where the spec linearises nonlinear data.
MISFIT = 0.5
MISFIT_SDS = 4  # ... and this many of the excess's own standard deviations, sqrt(2 / readings), for short records
SIMULATION_SEED = 0  # the record the fitted model simulates for its own expected log-likelihood


def not_at_peak(cov_z: np.ndarray, gradient: np.ndarray, names) -> list[str]:
    """A warning when a Newton step from the estimate (with the gradient and inverse curvature of
    -log posterior in z) would move some unknown by more than NEWTON_LIMIT standard errors."""
    known = np.isfinite(np.diag(cov_z)) & (np.diag(cov_z) > 0) & np.isfinite(gradient)
    if not known.any():
        return []
    cov = cov_z[np.ix_(known, known)]
    step = np.abs(cov @ gradient[known]) / np.sqrt(np.diag(cov))
    if step.max() <= NEWTON_LIMIT:
        return []
    worst = [n for n, k in zip(names, known) if k][int(step.argmax())]
    return [f"the search did not reach the peak: the log posterior still rises from the estimate (a Newton "
            f"step would move {worst} by {step.max():.3g} standard errors)"]


def curvature_mismatch(f, z: np.ndarray, f0: float, H: np.ndarray, names) -> list[str]:
    """A warning when the curvature H of f = -log posterior at z does not predict f one standard
    deviation out along its own principal directions (where it should rise by 1/2 each way): the
    finite differences measured noise, or the peak is far from quadratic."""
    if not np.isfinite(H).all():
        return []
    vals, vecs = np.linalg.eigh(0.5 * (H + H.T))
    for lam, v in zip(vals, vecs.T):
        if lam <= 1e-9 * max(vals.max(), 1e-300):  # a flat direction: noted with the standard errors
            continue
        s = v / np.sqrt(lam)
        rise = 0.5 * (f(z + s) + f(z - s)) - f0
        if not CURVATURE_CHECK[0] < rise / 0.5 < CURVATURE_CHECK[1]:
            moved = " and ".join(names[i] for i in np.argsort(-np.abs(v)) if abs(v[i]) > 0.3)
            return [f"the curvature cannot be trusted: one standard error from the estimate along a direction "
                    f"that moves {moved} the log posterior falls by {rise:.3g}, where the curvature says 0.5; "
                    "the standard errors are not meaningful"]
    return []


def ill_conditioned(H: np.ndarray) -> list[str]:
    """A warning when the curvature, scaled to a unit diagonal, is nearly singular or not that of a
    maximum (the unknowns with no finite or no positive curvature of their own are left to the notes)."""
    keep = np.isfinite(H).all(axis=1) & (np.diag(H) > 0)
    if keep.sum() < 2:
        return []
    d = np.sqrt(np.diag(H)[keep])
    vals = np.linalg.eigvalsh(H[np.ix_(keep, keep)] / np.outer(d, d))
    if vals[0] <= 0:
        return ["the curvature at the estimate is not that of a maximum (it bends upwards along some "
                "combination of the unknowns): the search stopped short of a peak"]
    if vals[-1] / vals[0] > ILL_CONDITIONED:
        return [f"the curvature is ill-conditioned (condition number {vals[-1] / vals[0]:.2g} once scaled): the "
                "standard errors are not reliable"]
    return []


def unmoved(z: np.ndarray, start: np.ndarray, touched, family) -> list[str]:
    """A warning naming the unknowns that ended within UNMOVED prior standard deviations (in z) of where
    the search began though the data bear on them (`touched`: their curvature is not their prior's): a
    search that never left its start. An unknown the data do not touch rightly stays at its prior's
    median."""
    names = [n for n, p, a, b, t in zip(family.names, family.priors, z, start, touched)
             if t and abs(a - b) < UNMOVED * (p.args[1] if p.family in ("Normal", "LogNormal") else 1.0)]
    if not names:
        return []
    return [f"{', '.join(names)} did not move from where the search started, though the data bear on "
            f"{'it' if len(names) == 1 else 'them'}: the search did not find a peak"]


def misfit(model: Model, datasets, algorithm: str, fitted: float) -> list[str]:
    """A warning when the fitted model explains the data far worse than data it simulates itself (the
    same inputs, missing readings and labels; modes from its chain where the data have none): the
    squared standardised residuals average more than 1 + MISFIT per reading (and more than MISFIT_SDS
    of that average's own spread under the model above it, for short records)."""
    readings = sum(int(np.isfinite(d.y).sum()) for d in datasets)
    try:
        expected = sum(loglik(model, _simulated(model, d), algorithm) for d in datasets)
    except (JmlgError, np.linalg.LinAlgError, ValueError):
        return []
    excess = 2 * (expected - fitted) / max(readings, 1)
    if not excess > max(MISFIT, MISFIT_SDS * math.sqrt(2 / max(readings, 1))):
        return []
    return [f"the fitted model explains the data far worse than it expects to: log-likelihood {fitted:.6g}, "
            f"where data it simulates itself score {expected:.6g} ({excess:.3g} more per reading in squared "
            "standardised residuals); the search stopped far from the peak, or the spec cannot describe the data"]


def _simulated(model: Model, data: Data) -> Data:
    """A record like `data` drawn from the model: its inputs, its labels if it has them all, its gaps."""
    sim = simulate(model, seed=SIMULATION_SEED, modes=data.modes if labelled(data) else None, u=data.u,
                   T=len(data.y))
    return replace(data, y=np.where(np.isnan(data.y), np.nan, sim.y), modes=sim.modes if labelled(data) else None)
