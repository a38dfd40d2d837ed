"""The engine contract every filtering algorithm follows, and the small weighted helpers they share.

An engine is one algorithm's state after t steps plus `step(y, mask, u, gate) -> Estimate`; the `Filter`
front end (online.py) validates data, keeps the clock and the log-likelihood, and turns estimates
into records. Algorithms are registered by name in algorithms.py.
"""

from __future__ import annotations

import functools
from typing import NamedTuple, Protocol

import numpy as np

from ..errors import JmlgError
from . import kalman
from .resample import ess, systematic_points


class FilterError(JmlgError, ValueError):
    """A filter asked for something it cannot do (unknown algorithm, too many Gaussians, ...)."""


class Estimate(NamedTuple):
    """One time step's output of an engine (the Filter adds the clock and the residuals)."""

    mode_posterior: np.ndarray  # (K,) p(z_t = k | y_1:t)
    state_mean: np.ndarray  # (nx,) mixture mean of x_t | y_1:t
    state_cov: np.ndarray  # (nx, nx) mixture covariance
    y_pred: np.ndarray  # (ny,) one-step predictive mean E[y_t | y_1:t-1]
    loglik: float  # log p(y_t | y_1:t-1) (an estimate for particle filters)
    ess: float  # effective sample size of the particle weights (NaN for deterministic filters)
    rejected: np.ndarray | None = None  # (ny,) readings left out as gross errors, None when none were
    flagged: np.ndarray | None = None  # (ny,) readings beyond the gate, not absurd (screen); None when none were


class Estimates(NamedTuple):
    """The Estimates of many engines stepped together (the units of a fleet), as arrays with a leading
    engine axis: row i is engine i's Estimate, its `rejected` and `flagged` rows all False where the
    Estimate has None (`screen` gives None for no reading, never an array all False)."""

    mode_posterior: np.ndarray  # (g, K)
    state_mean: np.ndarray  # (g, nx)
    state_cov: np.ndarray  # (g, nx, nx)
    y_pred: np.ndarray  # (g, ny)
    loglik: np.ndarray  # (g,)
    ess: np.ndarray  # (g,)
    rejected: np.ndarray  # (g, ny) bool
    flagged: np.ndarray  # (g, ny) bool

    @classmethod
    def empty(cls, g: int, K: int, nx: int, ny: int) -> "Estimates":
        """Room for g engines' Estimates, nothing rejected or flagged."""
        return cls(np.empty((g, K)), np.empty((g, nx)), np.empty((g, nx, nx)), np.empty((g, ny)), np.empty(g),
                   np.empty(g), np.zeros((g, ny), dtype=bool), np.zeros((g, ny), dtype=bool))

    def put(self, rows, other: "Estimates"):
        """Write other's engines into rows (an index array) of these."""
        for mine, theirs in zip(self, other):
            mine[rows] = theirs

    def put_one(self, i: int, est: Estimate):
        """Write one engine's Estimate into row i."""
        for mine, theirs in zip(self, est):
            if theirs is not None:
                mine[i] = theirs

    def one(self, i: int) -> Estimate:
        """Row i as one engine's Estimate."""
        rejected, flagged = self.rejected[i], self.flagged[i]
        return Estimate(self.mode_posterior[i], self.state_mean[i], self.state_cov[i], self.y_pred[i],
                        float(self.loglik[i]), float(self.ess[i]), rejected if rejected.any() else None,
                        flagged if flagged.any() else None)


class Genealogy(NamedTuple):
    """How a particle engine's last step went from its particles to the next ones, for smoothing:
    candidate j descends from particle parent[j] with mode[j] at this step and weight q[j], and the
    next particle i is candidate kept[i]."""

    parent: np.ndarray
    mode: np.ndarray
    q: np.ndarray
    kept: np.ndarray


class Gate(NamedTuple):
    """The gross-error gate of one step: `limit` (ny,) in predicted standard deviations (inf: off),
    `enforce` (ny,) whether a reading beyond it is left out (or only flagged), and `bound` =
    min(limit)^2. A reading beyond its limit has a Mahalanobis distance beyond the limit too
    (Cauchy-Schwarz), so a step whose smallest distance over the hypotheses is within `bound`
    needs no closer look."""

    limit: np.ndarray
    enforce: np.ndarray
    bound: float

    @classmethod
    def of(cls, limit, enforce=None) -> "Gate":
        limit = np.asarray(limit, dtype=float)
        enforce = np.ones(limit.shape, dtype=bool) if enforce is None else enforce
        return cls(limit, enforce, float(limit.min()) ** 2 if limit.size else np.inf)

    def closer_look(self, quad) -> bool:
        """Whether a step whose squared Mahalanobis distances over the hypotheses are quad needs the
        closer look of `screen` (never, and at no cost, when the gate is open)."""
        return self.bound < np.inf and quad.min() > self.bound

    @staticmethod
    def closer_looks(gates, quad) -> np.ndarray:
        """The positions of the gates (one per engine stepped together) whose steps need the closer
        look, each engine's squared distances a row of quad: `closer_look` of each, in one call."""
        return np.flatnonzero(quad.min(axis=-1) > np.array([gate.bound for gate in gates]))


OPEN = Gate(np.empty(0), np.empty(0, dtype=bool), np.inf)  # nothing is ever flagged


class Engine(Protocol):
    """One algorithm's filtering state, advanced one observation at a time."""

    def step(self, y: np.ndarray, mask: np.ndarray, u: np.ndarray, gate: Gate = OPEN) -> Estimate:
        """Condition on y (ny,), of which the entries where mask (ny,) is True were measured, under
        input u (nu,); a measured reading beyond `gate` under every hypothesis is left out (see
        `screen`)."""


# A reading farther than this many times the gate plus `mode_span` from every hypothesis's
# prediction is absurd. A lasting real change beyond the modes can go well past the gate plus the
# span (up to 6.8 times on the SKAB benchmark's anomalies, which the cap must let through); a failed
# sensor's +-1e9 goes millions of times past it on every published plant.
ABSURD = 100.0


def beyond(r, distance) -> np.ndarray:
    """(m,) True for the readings whose residuals r (J, m) exceed distance (J, m) under every one of the
    J hypotheses."""
    return (np.abs(r) > distance).all(axis=0)


def mode_span(model, u) -> np.ndarray:
    """(ny,) the largest distance between two modes' steady-state outputs under inputs u: the farthest
    a switch of mode can take the plant's outputs from where the filter expects them. Infinite when
    a mode has no steady state it settles to (an unstable or integrating mode can take its outputs
    anywhere)."""
    if not model.settles:
        return np.full(model.ny, np.inf)
    b, c = offsets(model, u)
    x = np.linalg.solve(np.eye(model.nx) - model.A, b[:, :, None])
    return np.ptp((model.C @ x)[:, :, 0] + c, axis=0)


def screen(engine: Engine, y, mask, u, gate: Gate, r, sd):
    """(the step's Estimate with the rejected readings left out, or None to go on; the flagged readings
    (ny,), or None): the closer look at residuals r (J, m) with standard deviations sd (J, m).

    A reading beyond the gate under every hypothesis is flagged, and left out while the gate is
    enforced on it. One ABSURD times farther than the gate plus `mode_span` is absurd: far beyond
    where any switch of mode, or a lasting change the modes do not describe, takes the plant, so it
    is the sensor, however long it lasts. It is left out like a missing reading and is not flagged:
    it neither counts towards a change that lasts nor lifts the gate, so a burst of garbage leaves
    the filter where a gap in the data would."""
    gated = gate.limit[mask] * sd
    flags = beyond(r, gated)
    if not flags.any():
        return None, None
    absurd = beyond(r, ABSURD * (gated + mode_span(engine.model, u)[mask]))
    measured = np.flatnonzero(mask)
    flagged = np.zeros(len(mask), dtype=bool)
    flagged[measured[flags & ~absurd]] = True
    rejected = flagged & gate.enforce
    rejected[measured[absurd]] = True
    flagged = flagged if flagged.any() else None
    if not rejected.any():
        return None, flagged
    keep = mask & ~rejected
    estimate = engine.step(np.where(keep, y, np.nan), keep, u)
    return estimate._replace(rejected=rejected, flagged=flagged), flagged


def offsets(model, u):
    """Per-mode constant terms of the state and output equations F u + f and G u + g: (K, nx) and
    (K, ny) for one input u (nu,), (T, K, nx) and (T, K, ny) for every step of u (T, nu)."""
    if u.ndim == 1:
        return model.F @ u + model.f, model.G @ u + model.g
    u = u[:, None, :, None]
    return (model.F @ u)[..., 0] + model.f, (model.G @ u)[..., 0] + model.g


def mixture_moments(w, means, weighted_cov):
    """Mean and covariance of a Gaussian mixture with weights w (..., J), component means (..., J, n)
    and sum_j w_j Sig_j (..., n, n)."""
    mean = (w[..., None, :] @ means)[..., 0, :]
    d = means - mean[..., None, :]
    return mean, kalman.symmetrize(weighted_cov + (np.swapaxes(d, -1, -2) * w[..., None, :]) @ d)


def joined(arrays) -> np.ndarray:
    """np.stack of equally long 1-d arrays (one per engine), or of (n, nx) arrays flattened to (g, n * nx):
    one concatenation, without np.stack's steps per array (the most of its time at thousands of units)."""
    return np.concatenate(arrays).reshape(len(arrays), -1)


def sample_rows(probs, rng):
    """One categorical draw per row of non-negative (unnormalised) probabilities (M, K): the first k
    with cdf_k > u for u uniform on [0, total), so a zero-probability category is never drawn."""
    return rows_drawn(probs, rng.random(len(probs)))


def rows_drawn(probs, uniforms):
    """`sample_rows` with its uniforms on [0, 1) given, one per row of probs (..., M, K): the same
    draws row by row over any leading axes (many units' particles, each with its own numbers)."""
    return cdf_drawn(cumulated(probs), uniforms)


def cumulated(a) -> np.ndarray:
    """a.cumsum(axis=-1), bit for bit (each sum the one before it plus the next entry), in one call
    per column where a has many short rows: numpy accumulates row by row, its cost per row the most
    of its time at thousands of rows of a few (a fleet's particles, each row its modes)."""
    K = a.shape[-1]
    if K > 8 or a.size < 1000 * K:
        return a.cumsum(axis=-1)
    out = a.copy()
    for k in range(1, K):
        np.add(out[..., k - 1], out[..., k], out=out[..., k])
    return out


def cdf_drawn(cdf, uniforms):
    """`rows_drawn` of the rows whose cumulated sums are cdf (..., M, K) (written to): a table's rows
    cumulated once serve every draw from them, bit for bit as each row cumulated."""
    u = uniforms * cdf[..., -1]
    cdf[..., -1] = np.inf  # at most K - 1, even where u rounds up to the total
    above = cdf > u[..., None]
    K = cdf.shape[-1]
    if K > 8 or u.size < 1000:
        return above.argmax(axis=-1)
    # argmax over a short axis of many rows, one call per column (numpy's reduction loops row by row)
    return functools.reduce(lambda first, k: np.where(above[..., k], k, first), range(K - 1, -1, -1),
                            np.zeros(u.shape, np.int64))


def systematic_rows(w, n, offsets):
    """Systematic resampling (`resample.systematic`) of n draws from each row of normalised weights w
    (..., J) with its uniform offset on [0, 1): the ancestors (..., n), as the scheme gives them row by row."""
    cdf = cumulated(w)
    cdf[..., -1] = 1.0  # as resample._inverse_cdf
    points = systematic_points(n) + offsets[..., None] / n
    if cdf.shape[-1] * n <= 1024:  # a few particles: every comparison at once
        return (cdf[..., :, None] <= points[..., None, :]).sum(axis=-2)  # searchsorted(points, side="right")
    # many (pf's 200: 40,000 comparisons a row): a search a row, the scheme's own
    flat = (cdf.reshape(-1, cdf.shape[-1]), points.reshape(-1, n))
    return np.array([c.searchsorted(p, side="right") for c, p in zip(*flat)]).reshape(points.shape)


def resampling(threshold, n, size, held):
    """Whether particles of ESS `size` and `held` copies in all are resampled by a resampler of
    `threshold` keeping n (`Resampler.resamples`); element by element over arrays (many units at once):
    always at a threshold of 1 or more, else below threshold * n or when the copies are not n."""
    return (threshold >= 1.0) | (size < threshold * n) | (held != n)


class Resampler:
    """The resampling policy of a particle filter: a scheme, a target count and an ESS threshold.

    Resampling happens when ESS < threshold * n, or when the copies do not number n (la-rbpf's first
    step starts from one weighted atom per initial mode); a threshold of 1 resamples at every step.
    A particle may stand for several identical copies (`copies`): they count in the ESS, and when no
    resampling happens each copy comes back as an entry of its own, holding its share of the weight.
    """

    def __init__(self, scheme, n, rng, threshold=1.0):
        if not 0.0 < threshold <= 1.0:
            raise FilterError(f"the ESS threshold must be in (0, 1], got {threshold}")
        self.scheme, self.n, self.rng, self.threshold = scheme, n, rng, threshold
        self.uniform = np.full(n, -np.log(n))  # the log-weights after resampling (never written to)

    def resamples(self, size, copies) -> bool:
        """Whether particles of this ESS and copy counts are resampled."""
        return bool(resampling(self.threshold, self.n, size, copies.sum()))

    def __call__(self, w, copies=None):
        """(ancestor indices, their new log-weights, ESS) for normalised weights w."""
        if copies is None:
            copies = np.ones(len(w), dtype=np.int64)
        size = ess(w, copies)
        if self.resamples(size, copies):
            return self.scheme(w, self.n, self.rng), self.uniform, size
        ancestors = np.repeat(np.arange(len(w)), copies)
        with np.errstate(divide="ignore"):
            return ancestors, np.log(w / copies)[ancestors], size
