"""Evidence per sensor: how much each output's reading speaks for a mode against the healthy ones.

At row t the filter weighs every mode k by its one-step predictive p(y_t | z_t = k, y_1:t-1): one
Gaussian N(ŷ_k, S_k) for imm, a mixture of the Gaussians of its hypotheses in mode k for the other
filters (the exact mixture over mode histories for `exact`). The chain rule, in the spec's order of
the outputs, splits its log-density into one term per output,

    log p(y_t | k) = sum_i log p(y_t,i | y_t,1..i-1, k),

and for a Gaussian the terms come from the Cholesky factor L of S_k: with z = L^-1 (y_t - ŷ_k),

    term_i(k) = -(z_i^2 + log 2π) / 2 - log L_ii.

The evidence of output i for mode k against the healthy mode h is e_i = term_i(k) - term_i(h); the
e_i add up to the log-likelihood ratio log p(y_t | k) - log p(y_t | h), the factor by which row t
moves the odds of k against h. docs/filters.md, "Evidence per sensor", says how to read it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..infer.result import Predictive
from ..infer.kalman import log_density


@dataclass(frozen=True)
class Evidence:
    """The evidence of one row: `mode`, the most probable non-healthy mode after the row; `healthy`,
    the healthy mode that predicted the row best; `terms` (ny,), each output's evidence for `mode`
    against `healthy` in nats (NaN where not measured); `total`, their sum, the log-likelihood ratio.

        >>> e = Evidence(mode=1, healthy=0, terms=np.array([2.5, np.nan, -0.5]), total=2.0)
        >>> e.carriers()
        [(0, 2.5)]
    """

    mode: int
    healthy: int
    terms: np.ndarray
    total: float

    @classmethod
    def of(cls, predictive: Predictive, faulty) -> "Evidence | None":
        """The evidence of a step's readings for its most probable mode among the `faulty` ones (K,)
        (by the filtered posterior) against the healthy mode that predicted the readings best; None
        when the filter holds no hypothesis in a faulty mode or none in a healthy one.

            >>> import jmlgdsl
            >>> from jmlgdsl.diagnosis import AlarmRule
            >>> from jmlgdsl.infer import Filter
            >>> model = jmlgdsl.load("specs/dryer.jmlg")
            >>> f = Filter(model, "imm")
            >>> _ = f.step([45.0])
            >>> e = Evidence.of(f.engine.predictive, AlarmRule(("normal",)).faulty_modes(model.modes))
            >>> model.modes[e.mode], model.modes[e.healthy], round(e.total, 2)
            ('fan', 'normal', 2745.88)
        """
        prior, terms = mode_terms(predictive, len(faulty))
        return _chosen(prior[None], terms[None], predictive.mask, faulty)[0]

    @classmethod
    def of_units(cls, predictive: Predictive, faulty) -> "list[Evidence | None]":
        """`of` for n units of an imm filter at once, units that measured the same outputs: each mode
        one Gaussian, `predictive` holding arrays with a leading unit axis (log_weight (n, K),
        residual (n, K, m), Linv (n, K, m, m); mode and mask shared). The same numbers as `of` unit
        by unit."""
        return _chosen(*mode_terms(predictive, len(faulty)), predictive.mask, faulty)

    def carriers(self, most: int = 5) -> list[tuple[int, float]]:
        """(output index, evidence) of the outputs that carry the total, largest first: the fewest
        whose evidence reaches the total (at least one, at most `most`)."""
        order = [i for i in np.argsort(-self.terms, kind="stable") if not np.isnan(self.terms[i])]
        chosen, carried = [], 0.0
        for i in order[:most]:
            if chosen and carried >= self.total:
                break
            chosen.append((int(i), float(self.terms[i])))
            carried += self.terms[i]
        return chosen


def _chosen(prior, terms, mask, faulty) -> list[Evidence | None]:
    """The Evidence of each of n rows from its modes' log priors (n, K) and chain-rule terms (n, K, m),
    m the readings measured where mask (ny,) is True: the most probable faulty mode against the
    healthy mode that predicted the readings best (None where either kind has no hypothesis)."""
    faulty = np.asarray(faulty, dtype=bool)
    known = np.isfinite(prior)
    loglik = terms.sum(axis=-1)  # log p(y_t | z_t = k, y_1:t-1)
    valid = (known & faulty).any(axis=1) & (known & ~faulty).any(axis=1)
    mode = np.argmax(np.where(known & faulty, prior + loglik, -np.inf), axis=1)
    healthy = np.argmax(np.where(known & ~faulty, loglik, -np.inf), axis=1)
    rows = np.arange(len(mode))
    evidence = np.full((len(mode), len(mask)), np.nan)
    evidence[:, mask] = terms[rows, mode] - terms[rows, healthy]
    totals = np.nansum(evidence, axis=1)
    return [Evidence(int(mode[i]), int(healthy[i]), evidence[i], float(totals[i])) if valid[i] else None
            for i in rows]


def chain_terms(residual, Linv) -> np.ndarray:
    """(..., m) log p(r_i | r_1..i-1) of residuals r (..., m) under N(0, S), for Linv (..., m, m)
    the inverse Cholesky factor of S: they add up to log N(r; 0, S).

        >>> chain_terms(np.array([1.0, 0.0]), np.eye(2)).round(4)   # S = I: two independent N(0, 1)
        array([-1.4189, -0.9189])
    """
    z = (Linv @ residual[..., None])[..., 0]
    log_sd = -np.log(np.diagonal(Linv, axis1=-2, axis2=-1))  # log L_ii
    return log_density(z * z, 2.0 * log_sd, 1)


def mode_terms(predictive: Predictive, K: int) -> tuple[np.ndarray, np.ndarray]:
    """(log prior (K,), terms (K, m)): for each mode, log p(z_t = k | y_1:t-1) up to a constant shared
    by all modes, and the chain-rule terms log p(y_i | y_1..i-1, z_t = k, y_1:t-1) of the m readings
    measured. A mode's hypotheses form a mixture: its log-density of the first i readings is the
    log of the weighted sum of theirs, and term i is the step from i - 1 readings to i. A mode
    without hypotheses has log prior -inf and NaN terms. An imm filter's predictive (a Gaussian per
    mode) may carry a leading unit axis: then (n, K) and (n, K, m)."""
    terms = chain_terms(predictive.residual, predictive.Linv)
    m = terms.shape[-1]
    weighed = np.isfinite(predictive.log_weight)
    if len(predictive.mode) == K and (predictive.mode == np.arange(K)).all():  # a Gaussian per mode (imm)
        return np.where(weighed, predictive.log_weight, -np.inf), np.where(weighed[..., None], terms, np.nan)
    prior, out = np.full(K, -np.inf), np.full((K, m), np.nan)
    for k in np.unique(predictive.mode[weighed]):
        mine = weighed & (predictive.mode == k)
        a = predictive.log_weight[mine]
        prior[k] = np.logaddexp.reduce(a)
        if len(a) == 1:
            out[k] = terms[mine][0]
        else:  # log sum_j w_j p_j(y_1..i), for i = 0..m
            cumulative = np.concatenate([np.zeros((len(a), 1)), np.cumsum(terms[mine], axis=1)], axis=1)
            out[k] = np.diff(np.logaddexp.reduce((a - a.max())[:, None] + cumulative, axis=0))
    return prior, out
