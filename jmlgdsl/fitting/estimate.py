"""Maximum a posteriori values of a spec's unknowns, their Laplace standard errors, and optionally
draws from the posterior by random-walk Metropolis.

Every unknown moves in its unconstrained coordinate z (jmlgdsl.lang.priors): the log posterior
log p(data | theta) + log p(theta) is maximised by BFGS over z, so no bound is ever crossed. Data
without labels first go through rounds of labelling by their most probable modes (jmlgdsl.fitting.labels),
which bring the search into the basin the data decide. At the maximum the gradient vanishes, so the
curvature in z maps to theta through the diagonal derivative d theta / d z alone (the delta method) and
correlations are the same in both coordinates. Checks on the peak and its curvature
(jmlgdsl.fitting.convergence) say when the search did not get there.
"""

from __future__ import annotations

import itertools
import math
import os
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from ..compile.assemble import twins
from ..model import Model
from ..output import writing
from ..seeds import generator
from . import convergence
from .family import Family, FitError
from .labels import label_rounds
from .likelihood import labelled
from .posterior import MAX_ITERATIONS, Cached, Posterior, bfgs

HESSIAN_STEP = 0.3  # central-difference step for the curvature, in posterior standard deviations of z
FIRST_STEP = 1e-3  # the step in z of the first, diagonal pass that finds those standard deviations
CORRELATED = 0.95  # |correlation| beyond which two unknowns are reported as hard to tell apart
AT_EDGE = 8.0  # |z| beyond which an unknown sits at an edge of its prior's support (Uniform, or 0)
PRIOR_SHARE = 1.25  # posterior curvature below this multiple of the prior's: the data added little


@dataclass
class Fit:
    """What `maximise` found: estimates with Laplace standard errors, the fitted Model and how it went."""

    names: list[str]
    priors: list
    estimate: np.ndarray  # (d,) maximum a posteriori values
    se: np.ndarray  # (d,) Laplace standard errors (NaN where the curvature says nothing)
    correlation: np.ndarray  # (d, d)
    loglik_start: float  # log p(data) with the unknowns at their priors' medians
    loglik: float  # log p(data) at the estimate
    model: Model
    notes: list[str] = field(default_factory=list)  # unidentifiable unknowns, estimates at an edge
    warnings: list[str] = field(default_factory=list)  # why the estimate or its curvature cannot be trusted
    evaluations: int = 0
    seconds: float = 0.0
    samples: np.ndarray | None = None  # (N, d) posterior draws with --samples
    acceptance: float = math.nan
    text: str = ""  # the spec rewritten with the fitted values

    def write(self, path) -> None:
        """Write the fitted spec, whole or not at all ('-': standard output)."""
        with writing(path) as stream:
            stream.write(self.text)

    @property
    def converged(self) -> bool:
        """Whether the fit passed every check on its peak and curvature (no warnings)."""
        return not self.warnings

    def status(self) -> str:
        """How the fit went, in a line: its likelihood evaluations and seconds, and converged or its warnings."""
        return (f"{self.evaluations} likelihood evaluations in {self.seconds:.1f} s, "
                + ("warnings: " + "; ".join(self.warnings) if self.warnings else "converged"))

    def values(self) -> dict[str, float]:
        """{unknown: estimate}."""
        return dict(zip(self.names, map(float, self.estimate)))

    def report(self) -> str:
        """The fit as a reader wants it: a table of unknowns, the likelihood before and after, notes."""
        rows = [["unknown", "prior", "estimate", "se", "prior median"]]
        rows += [[n, str(p), f"{v:.6g}", f"{s:.2g}", f"{p.median:.6g}"]
                 for n, p, v, s in zip(self.names, self.priors, self.estimate, self.se)]
        if self.samples is not None:
            lo, hi = np.percentile(self.samples, [2.5, 97.5], axis=0)
            rows[0] += ["posterior mean", "sd", "95 % interval"]
            for row, m, s, a, b in zip(rows[1:], self.samples.mean(0), self.samples.std(0), lo, hi):
                row += [f"{m:.6g}", f"{s:.2g}", f"[{a:.6g}, {b:.6g}]"]
        widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
        lines = ["  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows]
        lines.append(f"log-likelihood {self.loglik_start:.6g} at the priors' medians, {self.loglik:.6g} fitted "
                     f"({self.loglik - self.loglik_start:+.4g})")
        if self.samples is not None:
            lines.append(f"{len(self.samples)} posterior draws by random-walk Metropolis, "
                         f"acceptance {self.acceptance:.0%}")
        lines += [f"warning: {w}" for w in self.warnings]
        lines += [f"note: {n}" for n in self.notes]
        lines.append(f"{self.evaluations} likelihood evaluations in {self.seconds:.1f} s")
        return "\n".join(lines)


def maximise(family: Family, datasets, algorithm: str = "imm", samples: int = 0, seed=None, progress=None,
             starts: int | None = None, rounds: bool = True, jobs: int | None = None) -> Fit:
    """The maximum a posteriori values of the family's unknowns given the datasets (jmlgdsl.data.Data),
    with Laplace standard errors; `samples` > 0 adds that many Metropolis draws. The search starts
    (`starts`, `_begins`) at the priors' medians, for unlabelled data also at the medians with every
    row taken for the first mode, then at draws from the priors, keeping the highest peak found; where
    some data are unlabelled, each start first goes through rounds of labelling
    (jmlgdsl.fitting.labels) unless `rounds` is False. Default: one start for labelled data, two for
    unlabelled. `progress(text)` hears of each round and optimiser iteration."""
    start = time.perf_counter()
    rng = generator(seed)
    post = Posterior(family, datasets, algorithm)
    z0 = np.array([p.to_z(p.median) for p in family.priors])
    loglik_start = post.loglik(post.theta(z0))
    if not math.isfinite(loglik_start):
        raise FitError("the spec makes no model at the priors' medians, or the data have no likelihood under it")
    say = progress or (lambda text: None)
    alike = _look_alike(family.model(post.theta(z0))) if not all(map(labelled, datasets)) else []
    for note in alike:
        say(f"note: {note}")
    objective = Cached(post)
    rounds = rounds and not all(map(labelled, datasets))
    starts = (2 if rounds else 1) if starts is None else starts
    results = _search(post, objective, _begins(post, z0, starts, rng, rounds), say, rounds, jobs)
    z_start, result = min(results, key=lambda r: r[1].fun)
    z = result.x
    say("curvature at the estimate (Laplace)")
    f0 = objective(z)
    H, gradient = hessian(objective, z, f0)
    theta = post.theta(z)
    cov_z, notes = _covariance(H, family.names)
    J = np.array([p.dtheta_dz(v) for p, v in zip(family.priors, z)])
    cov = cov_z * np.outer(J, J)
    se = np.sqrt(np.where(np.diag(cov) >= 0, np.diag(cov), np.nan))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov_z / np.sqrt(np.outer(np.diag(cov_z), np.diag(cov_z)))
    own = _prior_curvature(z, family)
    informed = np.diag(H) > PRIOR_SHARE * own
    notes = alike + notes + _correlated(corr, family.names) + _uninformed(informed, own, family.names) + [
        f"{n} sits at an edge of its prior ({p}): its standard error is not meaningful"
        for n, p, v in zip(family.names, family.priors, z) if abs(v) > AT_EDGE and p.family != "Normal"]
    if starts > 1:
        peaks = ", ".join(f"{-r.fun:.8g}" for _, r in results)
        notes.append(f"the best of {starts} starts (their log posteriors: {peaks})")
    loglik = -f0 - sum(p.logpdf(t) for p, t in zip(family.priors, theta))
    model = family.model(theta)
    say("checks on the peak and its curvature")
    warnings = ([f"the optimiser stopped early: {result.message}"] if result.nit >= MAX_ITERATIONS else []) \
        + convergence.not_at_peak(cov_z, gradient, family.names) \
        + convergence.curvature_mismatch(objective, z, f0, H, family.names) + convergence.ill_conditioned(H) \
        + convergence.unmoved(z, z_start, ~np.isclose(np.diag(H), own, rtol=PRIOR_SHARE - 1, atol=0), family) \
        + convergence.misfit(model, datasets, algorithm, loglik)
    draws, acceptance = (None, math.nan)
    if samples:
        draws, acceptance = metropolis(post, z, cov_z, samples, rng, say)
    return Fit(list(family.names), list(family.priors), theta, se, corr, loglik_start, loglik, model, notes,
               warnings, post.evaluations, time.perf_counter() - start, draws, acceptance)


class Start(NamedTuple):
    """Where one search begins: the unknowns' values (in z), whether they were drawn from the priors
    (else the medians), and whether its first labelling round takes every unlabelled row for the
    spec's first mode instead of the smoother's labels."""

    z: np.ndarray
    drawn: bool = False
    healthy: bool = False

    def describe(self) -> str:
        return ("drawn from the priors" if self.drawn else "the priors' medians") + (
            ", every row first taken for the first mode" if self.healthy else "")


def _begins(post: Posterior, z0: np.ndarray, starts: int, rng: np.random.Generator, rounds: bool) -> list[Start]:
    """The starts: the priors' medians; with labelling rounds, the medians again with every row first
    taken for the first mode (a record is mostly normal operation: a start that a look-alike fault,
    such as a biased sensor over a shifted level, cannot capture from the first round); then draws
    from the priors."""
    begins = [Start(z0)] + ([Start(z0, healthy=True)] if rounds and starts > 1 else [])
    return begins + [Start(np.array([p.to_z(p.draw(rng)) for p in post.family.priors]), drawn=True)
                     for _ in range(starts - len(begins))]


def _search(post: Posterior, objective: Cached, begins: list[Start], say, rounds: bool,
            jobs: int | None = None) -> list:
    """BFGS from each start, after rounds of labelling if `rounds`, and `released` from the edges: (the
    start's z, scipy's result) per start. With several starts, up to `jobs` of them (default: one per
    core) search side by side in their own processes, each exactly as it would alone, so the peaks do
    not depend on how many run at once; what each start said (its rounds, its iterations) is told
    when it ends, each line after its start's number."""
    starts = len(begins)
    jobs = max(1, min(starts, jobs or os.cpu_count() or 1))
    if jobs == 1:
        results = []
        for i, begin in enumerate(begins):
            if starts > 1:
                say(f"start {i + 1} of {starts} ({begin.describe()})")
            results.append((begin.z, _climb(post, objective, begin, rounds, say)))
        return results
    say(f"{starts} starts, {jobs} at a time: " + "; ".join(b.describe() for b in begins))
    with ProcessPoolExecutor(jobs) as pool:
        futures = [pool.submit(_start, post.family.spec, post.datasets, post.algorithm, begin, rounds)
                   for begin in begins]
        results = []
        for i, (begin, future) in enumerate(zip(begins, futures)):
            result, evaluations, said = future.result()
            post.evaluations += evaluations
            for line in said:
                say(f"start {i + 1}: {line}")
            say(f"start {i + 1} of {starts}: log posterior {-result.fun:.8g} after {evaluations} likelihood evaluations")
            results.append((begin.z, result))
    return results


def _climb(post: Posterior, objective: Cached, begin: Start, rounds: bool, say):
    """One start's search: the labelling rounds (never below the start), BFGS, `released`."""
    iterations = itertools.count(1)

    def report_iteration(v):
        say(f"iteration {next(iterations)}: log posterior {-objective(v):.8g}")

    z = begin.z
    if rounds:
        z = min((label_rounds(post, z, say, begin.healthy), z), key=objective)
    return released(objective, bfgs(objective, z, report_iteration), say, report_iteration)


def _start(spec, datasets, algorithm: str, begin: Start, rounds: bool):
    """One start searched in a process of its own: (scipy's result, likelihood evaluations, what it said)."""
    post = Posterior(Family(spec), datasets, algorithm)
    said = []
    return _climb(post, Cached(post), begin, rounds, said.append), post.evaluations, said


def released(objective: Cached, result, say, callback=None):
    """BFGS's result, searched again from the peak with every unknown it pushed against an edge of its
    prior's support (|z| > AT_EDGE: a Uniform's bound, zero for a positive unknown) put back at its
    prior's median, for as long as that climbs higher.

    An unknown that the first iterations push to an edge stays there: far out, theta hardly moves with
    z (d theta / d z falls as exp(-|z|)), so its gradient vanishes and BFGS calls the point a peak even
    where, with the other unknowns since fitted, the data want it well inside. A leak coefficient
    pushed to zero while two flow coefficients were still far off is the case: its log-likelihood
    there was 2,000 below the truth's, with labelled data."""
    priors = objective.post.family.priors
    for _ in range(len(priors)):
        edge = [i for i, (p, v) in enumerate(zip(priors, result.x)) if abs(v) > AT_EDGE and p.family != "Normal"]
        if not edge:
            break
        z = result.x.copy()
        for i in edge:
            z[i] = priors[i].to_z(priors[i].median)
        names = ", ".join(objective.post.family.names[i] for i in edge)
        say(f"{names} at an edge of {'its' if len(edge) == 1 else 'their'} prior: searching again from "
            f"{'its' if len(edge) == 1 else 'their'} median")
        again = bfgs(objective, z, callback)
        if not again.fun < result.fun:
            break
        result = again
    return result


def hessian(f, z: np.ndarray, f0: float) -> tuple[np.ndarray, np.ndarray]:
    """The curvature and the gradient of f at z by central differences, with per-coordinate steps of
    HESSIAN_STEP standard deviations, found by a first diagonal pass (so the steps suit tight and loose
    unknowns). The gradient, from the same evaluations, says whether z is a peak at that scale."""
    d = len(z)
    first = _diagonal(f, z, f0, np.full(d, FIRST_STEP))[0]
    with np.errstate(divide="ignore", invalid="ignore"):
        sd = 1.0 / np.sqrt(first)
    step = np.where(first > 0, np.minimum(HESSIAN_STEP * sd, 1.0), FIRST_STEP)
    diagonal, gradient = _diagonal(f, z, f0, step)
    H = np.diag(diagonal)
    E = np.diag(step)
    pairs = [(i, j) for i in range(d) for j in range(i + 1, d)]
    corners = _many(f, [z + a * E[i] + b * E[j] for i, j in pairs for a, b in ((1, 1), (1, -1), (-1, 1), (-1, -1))])
    for (i, j), (pp, pm, mp, mm) in zip(pairs, corners.reshape(len(pairs), 4)):
        H[i, j] = H[j, i] = (pp - pm - mp + mm) / (4 * step[i] * step[j])
    return H, gradient


def _many(f, points) -> np.ndarray:
    """f at several points: together where f can (`Cached.many`), else one after the other."""
    return f.many(points) if hasattr(f, "many") else np.array([f(v) for v in points])


def _diagonal(f, z: np.ndarray, f0: float, step: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(d2 f / d z_i^2, d f / d z_i) by central differences with the given steps."""
    d = len(z)
    values = _many(f, [z + e for e in np.diag(step)] + [z - e for e in np.diag(step)])
    up, down = values[:d], values[d:]
    with np.errstate(invalid="ignore"):
        return (up - 2 * f0 + down) / step ** 2, (up - down) / (2 * step)


def _covariance(H: np.ndarray, names: list[str]) -> tuple[np.ndarray, list[str]]:
    """The inverse curvature, or, where the posterior is flat or bent the wrong way in some direction,
    the pseudo-inverse of its positive part, with a note naming the unknowns that direction moves.
    Unknowns whose curvature could not be computed (the model fails next to the estimate) get NaN."""
    bad = ~np.isfinite(H).all(axis=1)
    if bad.any():
        cov = np.full(H.shape, np.nan)
        good = np.flatnonzero(~bad)
        inner, notes = _covariance(H[np.ix_(good, good)], [names[i] for i in good])
        cov[np.ix_(good, good)] = inner
        missing = ", ".join(names[i] for i in np.flatnonzero(bad))
        return cov, notes + [f"no standard error for {missing}: the model cannot be built just beside the estimate"]
    vals, vecs = np.linalg.eigh(0.5 * (H + H.T))
    flat = vals <= 1e-9 * max(vals.max(initial=0.0), 1e-300)
    notes = []
    for v in vecs[:, flat].T:
        moved = [names[i] for i in np.argsort(-np.abs(v)) if abs(v[i]) > 0.3]
        notes.append(f"the data do not determine {' and '.join(moved)}: the posterior is flat along a "
                     f"combination of them (fix one, or give it a narrower prior)")
    inv = np.where(flat, 0.0, 1.0 / np.where(flat, 1.0, vals))
    cov = (vecs * inv) @ vecs.T
    if flat.any():
        idx = {i for v in vecs[:, flat].T for i in np.flatnonzero(np.abs(v) > 0.3)}
        for i in idx:
            cov[i, :] = cov[:, i] = np.nan
    return cov, notes


def _look_alike(model: Model) -> list[str]:
    """Notes on modes that are the same model where the fit starts: unlabelled data cannot say which is
    which, so the fit may swap or merge them (the label switching of every mixture)."""
    arrays = [[getattr(model, name)[k] for name in ("A", "B", "C", "D", "F", "G", "f", "g", "mu0")]
              for k in range(model.K)]
    return [f"at the priors' medians modes {model.modes[b]!r} and {model.modes[a]!r} are the same model: data "
            "without a mode column cannot say which is which, and the fit may swap or merge them; give their "
            "unknowns priors with different medians, or label some of the data" for a, b in twins(arrays)]


def _prior_curvature(z: np.ndarray, family: Family) -> np.ndarray:
    """(d,) each prior's own curvature of -log p(theta) in z at z (0 for a Uniform, flat in theta)."""
    return np.array([_diagonal(lambda x: -p.logpdf(p.from_z(x[0])), np.array([v]), -p.logpdf(p.from_z(v)),
                               np.array([FIRST_STEP]))[0][0] for p, v in zip(family.priors, z)])


def _uninformed(informed: np.ndarray, own: np.ndarray, names: list[str]) -> list[str]:
    """Notes on unknowns whose curvature is mostly their prior's `own` (not `informed`): the data hardly
    speak of them (a mode that never occurs in the data, say), so their estimate and standard error are
    the prior's. A Uniform, flat in theta, has no curvature of its own to compare with."""
    return [f"the data say little about {name}: its estimate and standard error are mostly its prior's"
            for name, c, i in zip(names, own, informed) if c > 0 and not i]


def _correlated(corr: np.ndarray, names: list[str]) -> list[str]:
    """Notes on pairs of unknowns the data hardly tell apart."""
    d = len(names)
    return [f"{names[i]} and {names[j]} are strongly correlated ({corr[i, j]:+.3f}): the data mostly fix a "
            f"combination of them" for i in range(d) for j in range(i + 1, d)
            if np.isfinite(corr[i, j]) and abs(corr[i, j]) > CORRELATED]


def metropolis(post: Posterior, z: np.ndarray, cov_z: np.ndarray, n: int, rng: np.random.Generator, say):
    """n draws of theta from the posterior by random-walk Metropolis in z, from the estimate, with the
    Laplace covariance scaled by 2.38^2/d as the proposal; a burn-in of n/4 draws is discarded first."""
    d = len(z)
    cov = np.where(np.isfinite(cov_z), cov_z, 0.0) + 1e-12 * np.eye(d)
    L = np.linalg.cholesky((2.38 ** 2 / d) * cov)
    priors = post.family.priors

    def target(v):
        return -post(v) + sum(p.log_jacobian(x) for p, x in zip(priors, v))

    current, value = z.copy(), target(z)
    burn = n // 4
    draws, accepted = np.empty((n, d)), 0
    for i in range(burn + n):
        proposal = current + L @ rng.standard_normal(d)
        new = target(proposal)
        if math.log(rng.uniform()) < new - value:
            current, value = proposal, new
            accepted += i >= burn
        if i >= burn:
            draws[i - burn] = post.theta(current)
        if (i + 1) % 100 == 0:
            say(f"draw {i + 1 - burn if i >= burn else 0} of {n}" + (" (burn-in)" if i < burn else ""))
    return draws, accepted / n
