"""A start for a fit to unlabelled data in the basin the data decide: expectation-maximisation over the
unknown modes, made hard (each row takes its most probable mode).

Far from the truth a filter's likelihood is no guide for a local search. Every mode misses the
readings by many standard deviations, so at each step the filter's posterior sits all on one mode,
and which one flips with the last digits of the unknowns: values a millionth apart differ by hundreds
in log-likelihood, a finite-difference gradient is noise, and BFGS stops where it started
(docs/fit.md, "Unlabelled data far from the truth"). The labelled likelihood has no such jumps: with
the modes known the outputs are jointly Gaussian and smooth in the unknowns. So each round labels every
unlabelled row with its most probable mode given the whole record under the current values (the IMM
smoother: the E-step), then fits the unknowns to the data so labelled (the M-step, exact and cheap),
until the labels repeat.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..data import Data
from ..errors import JmlgError
from ..infer import smooth
from ..model import Model
from .likelihood import labelled
from .posterior import Cached, Posterior, bfgs

MAX_ROUNDS = 20  # labels that still change after this many rounds are left as they are
STALE_ROUNDS = 2  # rounds in a row that fit their labels no better than the best round so far: the labels cycle
# The logit coordinate of a Uniform unknown a round pushed against an edge comes back within this, where
# the search that follows can still move it: d theta / d z shrinks as exp(-|z|) beyond.
LOGIT_LIMIT = 4.0
ROUND_GAIN = 0.01  # a round's fit stops after an iteration that raises its log posterior by less than this


def most_probable_modes(model: Model, data: Data) -> np.ndarray:
    """(T,) each row's own label where it has one, else its most probable mode given all the data
    (the IMM smoother, whatever filter the fit uses: it is deterministic and costs one pass)."""
    guess = smooth(model, data.y, data.u, algorithm="imm", lag=None).mode_posterior.argmax(axis=1)
    return guess if data.modes is None else np.where(data.modes >= 0, data.modes, guess)


def first_mode(data: Data) -> np.ndarray:
    """(T,) each row's own label where it has one, else the spec's first mode (index 0)."""
    return np.zeros(len(data.y), dtype=int) if data.modes is None else np.where(data.modes >= 0, data.modes, 0)


def label_rounds(post: Posterior, z: np.ndarray, say, healthy: bool = False) -> np.ndarray:
    """z after rounds of labelling the unlabelled rows of post's data by their most probable modes and
    fitting to the data so labelled, until the labels repeat, or cycle (STALE_ROUNDS rounds in a row
    no better than the best: the z of the best round is kept), or MAX_ROUNDS. Each round's smoother
    pass and likelihood evaluations are counted in post.evaluations. `healthy`: the first round labels
    every unlabelled row with the spec's first mode instead (a record is mostly normal operation).

    Hard labels are biased where a fault's first rows look like the mode before it (a leak that has
    not yet reached a measured level): the fit then blames the rows labelled with the fault for all of
    it and may push its unknown against an edge of its prior. The rounds are a start, not the
    estimate: the search on the data's own likelihood that follows corrects such a bias, from within
    LOGIT_LIMIT of an edge."""
    labels, best, stale = None, (np.inf, z), 0
    for round_ in range(1, MAX_ROUNDS + 1):
        if healthy and labels is None:
            new = [first_mode(d) for d in post.datasets]
        else:
            try:
                model = post.family.model(post.theta(z))
                with np.errstate(all="ignore"):
                    new = [d.modes if labelled(d) else most_probable_modes(model, d) for d in post.datasets]
            except (JmlgError, np.linalg.LinAlgError, ValueError):
                break  # the values make no model, or the smoother overflows: keep the last fit
            post.evaluations += sum(not labelled(d) for d in post.datasets)
        changed = None if labels is None else sum(int((a != b).sum()) for a, b in zip(new, labels))
        if changed == 0:
            break
        labels = new
        step = Posterior(post.family, [replace(d, modes=m) for d, m in zip(post.datasets, labels)], post.algorithm)
        objective = Cached(step)
        z = _fit_labelled(objective, z)
        post.evaluations += step.evaluations
        say(f"labelling round {round_}: " + ("" if changed is None else f"{changed} rows relabelled, ")
            + f"log posterior with those labels {-objective(z):.8g}")
        stale = stale + 1 if objective(z) > best[0] - ROUND_GAIN else 0
        best = min(best, (objective(z), z), key=lambda b: b[0])
        if stale >= STALE_ROUNDS:
            say(f"the labels cycle: the start is round {round_ - stale}'s")
            break
    z = best[1]
    return np.array([np.clip(v, -LOGIT_LIMIT, LOGIT_LIMIT) if p.family == "Uniform" else v
                     for p, v in zip(post.family.priors, z)])


class _Enough(Exception):
    """A round's fit has risen as far as a start needs."""


def _fit_labelled(objective, z: np.ndarray) -> np.ndarray:
    """BFGS on the labelled posterior from z, stopped once an iteration gains less than ROUND_GAIN: the
    rounds need a start in the right basin, not the last digits (which cost BFGS as many evaluations
    again, in line searches against the rounding of its finite differences)."""
    last = {"z": z, "value": objective(z)}

    def enough(v):
        value = objective(v)
        gain = last["value"] - value
        last.update(z=v.copy(), value=value)
        if gain < ROUND_GAIN:
            raise _Enough

    try:
        return bfgs(objective, z, enough).x
    except _Enough:
        return last["z"]
