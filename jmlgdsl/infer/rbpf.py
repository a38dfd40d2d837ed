"""Rao-Blackwellised filters: particles are mode histories carrying an exact Kalman filter each.

They differ only in which (particle, next mode) candidates they evaluate and how they select the
next particle set from them:

- `rbpf`:    one candidate per particle, the mode drawn from the transition prior; resample.
- `la-rbpf`: all K candidates per particle (look-ahead); resample particles by their summed
             weight, then draw each survivor's mode from its exact posterior.
- `fc-rbpf`: all candidates; keep N distinct ones by Fearnhead-Clifford optimal selection.
- `exact`:   all candidates, all kept: every mode history, as long as their number stays bounded.

Kalman covariances live in a shared CovarianceGraph, so the per-step cost of the covariance work
does not grow with the number of particles. Identical particles (the same candidate selected more
than once) are kept once with a copy count, so the work per step grows with the number of distinct
mode histories, not with N.
"""

from __future__ import annotations

from itertools import repeat
from typing import NamedTuple

import numpy as np

from .covariances import CovarianceGraph, Representatives
from . import kalman
from .engine import (OPEN, Estimate, Estimates, FilterError, Gate, Genealogy, Resampler, joined, mixture_moments,
                     offsets, resampling, rows_drawn, sample_rows, screen, systematic_rows)
from .resample import ess, fearnhead_clifford, normalize, normalize_rows, systematic
from .result import Predictive


class Held:
    """An engine's field that an engine stepped with a group may hold as its row of the group's step
    (`StepRow`), so that a step writes nothing a unit but that row; read, the row is made into the
    field: by `make(row)` (its Predictive, its Genealogy), kept in the row's place, so later reads
    find it made; without `make`, the engine's slice of the step's array of the field's name (its
    particles' modes z, means mu, log-weights logw, copy counts copies or covariance nodes node), not
    kept, so the row stays and the group's next step takes the group's arrays as they are
    (`particles_together`). A value set is held as any attribute."""

    def __init__(self, make=None):
        self.make = make

    def __set_name__(self, owner, name):
        self.name = name

    def __get__(self, engine, owner=None):
        if engine is None:
            return self
        fields = vars(engine)
        if self.name not in fields:
            raise AttributeError(f"{type(engine).__name__} has no {self.name} before its first step")
        held = fields[self.name]
        if type(held) is not StepRow:
            return held
        if self.make is None:
            return held.particles(self.name)
        fields[self.name] = self.make(held)
        return fields[self.name]

    def __set__(self, engine, value):
        vars(engine)[self.name] = value


class RaoBlackwellised:
    """Shared state and step of the Rao-Blackwellised filters; subclasses choose candidates and selection.

    `exact` needs only the model; the particle filters also take their count, random numbers and
    resampling policy."""

    spare_nodes = 4096  # the covariance graph is compacted when it outgrows 4 nodes a particle + this
    z, mu, logw, copies, node = Held(), Held(), Held(), Held(), Held()
    predictive = Held(lambda row: row.predictive())  # the last step's Predictive
    genealogy = Held(lambda row: row.genealogy())  # the last step's Genealogy

    def __init__(self, model, particles=None, rng=None, resampler: Resampler | None = None):
        self.model, self.n, self.rng, self.resampler = model, particles, rng, resampler
        self.K, self.nx, self.ny = K, nx, ny = model.K, model.nx, model.ny
        self.graph = CovarianceGraph(model)
        root = self.graph.add(model.Sigma0[None])
        self.reps = Representatives(self.graph, root)
        # One stacked map from a particle mean to every mode's predicted state and output, side by
        # side per mode: (mu @ self._map).reshape(n * K, nx + ny) holds [A_k mu, C_k A_k mu] per row.
        self._map = np.concatenate([model.A, model.C @ model.A], axis=1).reshape(K * (nx + ny), nx).T
        # t = 0: one weighted atom per mode the prior allows.
        atoms = np.flatnonzero(model.p0 > 0)
        self.logw = np.log(model.p0[atoms])
        self.z = atoms
        self.mu = model.mu0[atoms]
        self.node = np.full(len(atoms), root[0])
        self.copies = np.ones(len(atoms), dtype=np.int64)
        self._pairs = {}  # particle count -> every (particle, mode) pair
        self._u = None  # the last input and its per-mode offsets (inputs rarely change)

    def _offsets(self, u):
        """Per-mode offsets of the predicted state and output means for input u, side by side: (K, nx + ny)."""
        key = u.tobytes()
        if key != self._u:
            b, c = offsets(self.model, u)
            self._u, self._bc = key, np.concatenate([b, np.einsum("kij,kj->ki", self.model.C, b) + c], axis=1)
        return self._bc

    # Subclasses: which candidates to evaluate, and how to select the next particles from them.
    def candidates(self):
        """(parent, mode, log share) of the candidates to evaluate: a candidate carries its parent's
        weight times P[z, mode] / exp(log share); None means every (particle, mode) pair in order."""
        n, K = len(self.z), self.K
        if n not in self._pairs:
            self._pairs[n] = np.repeat(np.arange(n), K), np.tile(np.arange(K), n)
        return (*self._pairs[n], None)

    @staticmethod
    def candidates_together(engines):
        """`candidates` of engines of this algorithm holding as many particles, side by side: the
        candidates of one, every (particle, mode) pair in order, serve them all (log share None);
        each (parent, mode, log share) a row (g, J) where each engine draws its own."""
        return engines[0].candidates()

    def select(self, q, parent, mode):
        """(chosen candidate indices, their log-weights, ESS) from normalised candidate weights q.
        A candidate chosen several times becomes one particle with that many copies."""
        raise NotImplementedError

    @staticmethod
    def select_together(engines, q, copies):
        """`select` of engines of this algorithm side by side, from their weights q (g, J) and their
        particles' copy counts (g, n): None when
        each selects on its own (always, here), else (the positions of the engines it served, which
        resampled to equal weights, their chosen candidates a row each, every engine's ESS (g,));
        the others select on their own."""
        return None

    def advance(self, rows, parent, mode, pairs, log_prior, r, Linv, q, mu_f, mask, selected=None) -> float:
        """Select the next particles from this step's candidates (candidate j: particle parent[j] into
        mode[j], weight q[j], filtered mean mu_f[j]; `pairs`: they are every (particle, mode) pair in
        order; `selected`: what `select` gives, if made already), the step's predictive and genealogy
        kept; the ESS. (`advance_together` is this for many engines side by side.)"""
        n = len(self.z)
        self.predictive = Predictive(mode, log_prior, r, Linv, mask)
        chosen, logw, size = self.select(q, parent, mode) if selected is None else selected
        key = chosen if pairs else parent[chosen] * self.K + mode[chosen]  # (parent, mode) as one number
        resampled = self.resampler is not None and logw is self.resampler.uniform  # all weights 1 / N
        chosen, self.logw, self.copies = merge_copies(key, chosen, logw, n * self.K, resampled)
        self.genealogy = Genealogy(parent, mode, q, chosen)
        self.z = mode[chosen]
        self.mu = mu_f[chosen]
        self.node = self.reps.pick(self.graph, self.graph.children(rows, self.node[parent[chosen]], self.z))
        self.tidy()
        return size

    @property
    def particles_held(self) -> int:
        """How many (distinct) particles the engine holds, len(z), without making its arrays."""
        held = vars(self)["z"]
        return held.step.held[held.i] if type(held) is StepRow else len(held)

    def tidy(self):
        """Keep the nodes in bounds after a step: forget the classes the particles left, as a graph of
        the engine's own would, and compact a graph of its own (a shared one: `share`)."""
        bound = 4 * len(self.node) + self.spare_nodes
        if self.reps.held > bound:
            self.reps.keep(self.graph, self.node)
        if not self.graph.shared and self.graph.size > bound:
            self.graph.compact([self])

    def join(self, graph):
        """Hold `graph` instead of the engine's own: the nodes and representatives move into it."""
        moved = graph.add(self.graph.Sig)
        self.node = moved[self.node]
        self.reps.renumber(graph, moved)
        self.graph = graph

    def step(self, y, mask, u, gate=OPEN) -> Estimate:
        model, K, nx, ny = self.model, self.K, self.nx, self.ny
        rows = self.graph.rows(mask)
        parent, mode, log_prop = self.candidates()
        n = len(self.z)
        pred = (self.mu @ self._map).reshape(n, K, nx + ny) + self._offsets(u)
        every = pred.reshape(n * K, nx + ny)  # every (particle, mode) pair, in order
        if log_prop is None:  # the candidates are every pair: rows of every mode of each node
            pred = every
            at = self.node
            log_prior = (self.logw[:, None] + model.logP[self.z]).reshape(n * K)
            prior = np.exp(log_prior)  # sums to 1: logw is normalised
        else:
            pred = pred[parent, mode]
            at = (self.node[parent], mode)
            log_prior = self.logw[parent] + model.logP[self.z[parent], mode] - log_prop
            prior, _ = normalize(log_prior)
        mu_p, y_pred = pred[:, :nx], pred[:, nx:]
        Linv, logdet, gain_t, Sig_f = rows.at(at)
        r = y - y_pred if rows.complete else y[mask] - y_pred[:, mask]
        quad = kalman.quad_form((Linv @ r[:, :, None])[:, :, 0])
        flagged = None
        if gate.closer_look(quad):  # under every mode of every particle
            Linv_every = Linv if log_prop is None else rows.at(self.node)[0]
            screened, flagged = screen(self, y, mask, u, gate, y[mask] - every[:, nx:][:, mask],
                                       kalman.standard_deviations(Linv_every))
            if screened is not None:
                return screened
        q, loglik, mu_f, mean, cov, posterior, yp = weigh(prior, log_prior, mode, K, quad, logdet, r, mu_p, y_pred,
                                                          gain_t, Sig_f)
        size = self.advance(rows, parent, mode, log_prop is None, log_prior, r, Linv, q, mu_f, mask)
        return Estimate(posterior, mean, cov, yp, float(loglik), size, flagged=flagged)


def step_together(engines, y, mask, u, gates) -> Estimates:
    """`RaoBlackwellised.step` of several engines of one model and algorithm that hold as many particles
    and weigh as many candidates (units of a fleet): readings y (g, ny) measured where mask (ny,) is
    True, inputs u (g, nu), a gate each; their Estimates, row i engine i's.

    Their arithmetic runs with a leading axis over the engines, each engine's the same operations on
    its own arrays as its own step's (a stack of matrix products is one product per matrix, and a
    row's sum is the sum of that row alone), so each gets, bit for bit, what it would get alone. Each
    then takes the closer look of its own gate, and selects its particles with its own random numbers.
    The engines share one covariance graph (`share`)."""
    first = engines[0]
    model, K, nx, ny = first.model, first.K, first.nx, first.ny
    n, g = first.particles_held, len(engines)
    rows = first.graph.rows(mask)
    parent_all, mode_all, log_prop_all = type(first).candidates_together(engines)
    pairs = log_prop_all is None  # the candidates are every (particle, mode) pair, the same for all

    def weighed(chosen):
        """The prior, predictions and Kalman pieces of the candidates of the engines at `chosen`, as
        views laid out as in each engine's own step (a matrix product's order of sums follows them)."""
        es, g = [engines[i] for i in chosen], len(chosen)
        z, mu, logw, copies, node = particles_together(es)
        # units under the same inputs (the usual case) share their offsets, computed once
        offsets = (first._offsets(u[0])[None] if (u == u[0]).all() else
                   np.stack([e._offsets(u[i]) for i, e in zip(chosen, es)]))
        pred = (mu @ first._map).reshape(g, n, K, nx + ny) + offsets[:, None]
        if pairs:  # every (particle, mode) pair in order, and rows of every mode of each node
            cand = pred.reshape(g, n * K, nx + ny)
            parent, mode = parent_all, mode_all
            packed = rows.packed.buffer[node].reshape(g, n * K, -1)
            log_prior = (logw[..., None] + model.logP[z]).reshape(g, n * K)
            prior = np.exp(log_prior)  # sums to 1: logw is normalised
        else:  # each engine's own candidates
            parent, mode, log_prop = (a[chosen] for a in (parent_all, mode_all, log_prop_all))
            each = np.arange(g)[:, None]
            cand = pred[each, parent, mode]
            packed = rows.packed.buffer[node[each, parent], mode]
            log_prior = logw[each, parent] + model.logP[z[each, parent], mode] - log_prop
            prior, _ = normalize_rows(log_prior)
        Linv, logdet, gain_t, Sig_f = rows.unpack(packed)
        y_pred = cand[..., nx:]
        r = y[chosen][:, None, :] - y_pred if mask.all() else y[chosen][:, None, mask] - y_pred[..., mask]
        quad = kalman.quad_form((Linv @ r[..., None])[..., 0])
        return (parent, mode, prior, log_prior, quad, logdet, r, cand[..., :nx], y_pred, gain_t, Sig_f, Linv, pred, node,
                copies)

    kept = np.arange(g)
    (parent, mode, prior, log_prior, quad, logdet, r, mu_p, y_pred, gain_t, Sig_f, Linv, pred, node,
     copies) = weighed(kept)
    screened, flagged = {}, np.zeros((g, ny), dtype=bool)
    for i in Gate.closer_looks(gates, quad):  # under every mode of every particle
        Linv_every = Linv[i] if pairs else rows.at(engines[i].node)[0]
        every = pred.reshape(g, n * K, nx + ny)[i]
        est, found = screen(engines[i], y[i], mask, u[i], gates[i], y[i, mask] - every[:, nx:][:, mask],
                            kalman.standard_deviations(Linv_every))
        if found is not None:
            flagged[i] = found
        if est is not None:
            screened[i] = est
    if screened:  # the engines whose step screening redid are done
        kept = np.array([i for i in range(g) if i not in screened], dtype=np.int64)
        if len(kept):
            (parent, mode, prior, log_prior, quad, logdet, r, mu_p, y_pred, gain_t, Sig_f, Linv, pred, node,
             copies) = weighed(kept)
    out = Estimates.empty(g, K, nx, ny)
    if len(kept):
        q, loglik, mu_f, mean, cov, posterior, yp = weigh(prior, log_prior, mode, K, quad, logdet, r, mu_p, y_pred,
                                                          gain_t, Sig_f)
        es = [engines[i] for i in kept.tolist()]
        sizes = advance_together(es, rows, node, parent, mode, pairs, log_prior, r, Linv, q, mu_f, mask,
                                 type(first).select_together(es, q, copies))
        if not screened:
            return Estimates(posterior, mean, cov, yp, loglik, np.array(sizes, dtype=float), out.rejected, flagged)
        out.put(kept, Estimates(posterior, mean, cov, yp, loglik, np.array(sizes, dtype=float), False, False))
    for i, est in screened.items():
        out.put_one(i, est)
    out.flagged[:] = flagged
    return out


def advance_together(engines, rows, nodes, parent, mode, pairs, log_prior, r, Linv, q, mu_f, mask, selected) -> list:
    """`RaoBlackwellised.advance` of engines that share one graph and weighed as many candidates, side
    by side: parent and mode (J,) when the candidates are every (particle, mode) pair (`pairs`), else
    one row (g, J) per engine; log_prior, r, Linv, q and mu_f with a leading engine axis; `selected`
    what their `select_together` gives; nodes (g, n) their particles' nodes. Their copies merge
    and their children are found in one call each, every engine's the same operations on its own
    numbers as alone; the ESS of each."""
    first = engines[0]
    graph, K, g, J, n = first.graph, first.K, len(engines), q.shape[-1], nodes.shape[1]
    parents, modes = (np.broadcast_to(a, (g, J)).reshape(-1) for a in (parent, mode))  # every candidate's
    going, rows_chosen, size = selected if selected is not None else (np.empty(0, np.int64), None, None)
    if len(going) == g:  # every engine resampled to equal weights (the usual step): n chosen each
        lengths = np.full(g, rows_chosen.shape[1])
        chosen, logws = rows_chosen.reshape(-1), np.broadcast_to(first.resampler.uniform, rows_chosen.shape).reshape(-1)
        resampled, sizes = np.ones(g, dtype=bool), size
    else:
        done = dict(zip(going.tolist(), rows_chosen if len(going) else ()))
        picks = [(done[j], e.resampler.uniform, size[j]) if j in done else
                 e.select(q[j], *((parent, mode) if pairs else (parent[j], mode[j]))) for j, e in enumerate(engines)]
        chosen, logws, sizes = zip(*picks)
        lengths = np.fromiter(map(len, chosen), np.int64, g)
        chosen, logws = np.concatenate(chosen), np.concatenate(logws)
        resampled = np.array([e.resampler is not None and logw is e.resampler.uniform  # all weights 1 / N
                              for e, logw in zip(engines, (p[1] for p in picks))])
    row = np.repeat(np.arange(g) * J, lengths) + chosen  # each chosen candidate's, among every candidate
    key = chosen if pairs else parents[row] * K + modes[row]  # (parent, mode) as one number
    kept, logw, copies, owner = merge_copies_together(key, chosen, logws, n * K, resampled, lengths)
    row = owner * J + kept
    z, mu = modes[row], mu_f.reshape(g * J, -1)[row]
    child = graph.children(rows, nodes.reshape(-1)[owner * n + parents[row]], z)
    node = Representatives.pick_together([e.reps for e in engines], graph, child, owner)
    held = np.bincount(owner, minlength=g)  # the particles each engine keeps
    # `tidy` is called only where it may act (an engine's classes, or a graph of its own, past its bound)
    bound = 4 * int(held.min()) + first.spare_nodes
    tidy = max(e.reps.held for e in engines) > bound or (not graph.shared and graph.size > bound)
    # the engines' new state: each holds its row of the group's step in place of its Predictive,
    # Genealogy and particles, made when read (one pass over the engines, no Python step of ours each)
    step = GroupStep(parent, mode, pairs, log_prior, r, Linv, mask, q, kept, z, mu, logw, copies, node,
                     np.concatenate([[0], np.cumsum(held)]).tolist(), held.tolist())
    for fields, row in zip(map(vars, engines), map(StepRow, repeat(step), range(g))):
        fields["predictive"] = fields["genealogy"] = row
        fields["z"] = fields["mu"] = fields["logw"] = fields["copies"] = fields["node"] = row
    if tidy:
        for e in engines:
            e.tidy()
    return sizes


class GroupStep(NamedTuple):
    """What engines stepped together weighed and kept at their step (`advance_together`'s arguments;
    each engine's chosen candidates and new particles, one engine's after the other's), from which
    each engine's Predictive, Genealogy and particles are made when read: row i, engine i's, is what
    its own step would have kept."""

    parent: np.ndarray
    mode: np.ndarray
    pairs: bool  # parent and mode (J,) serve every engine; else one row each
    log_prior: np.ndarray
    r: np.ndarray
    Linv: np.ndarray
    mask: np.ndarray
    q: np.ndarray
    kept: np.ndarray  # the chosen candidates
    z: np.ndarray  # the new particles' modes, means, log-weights, copy counts and nodes
    mu: np.ndarray
    logw: np.ndarray
    copies: np.ndarray
    node: np.ndarray
    starts: list  # where each engine's particles start in them, and where the last engine's end
    held: list  # how many particles each engine holds


class StepRow(NamedTuple):
    """An engine's row of its group's step, held in place of its Predictive, Genealogy and particles
    until read."""

    step: GroupStep
    i: int

    def predictive(self) -> Predictive:
        s, i = self
        return Predictive(s.mode if s.pairs else s.mode[i], s.log_prior[i], s.r[i], s.Linv[i], s.mask)

    def genealogy(self) -> Genealogy:
        s, i = self
        return Genealogy(*((s.parent, s.mode) if s.pairs else (s.parent[i], s.mode[i])), s.q[i], self.particles("kept"))

    def particles(self, name) -> np.ndarray:
        """The engine's slice of the step's array `name` (kept, z, mu, logw, copies or node)."""
        s, i = self
        return getattr(s, name)[s.starts[i]:s.starts[i + 1]]


def particles_together(engines) -> tuple:
    """The particles of engines holding as many, side by side: (z, mu, logw, copies, node), each
    (g, n) (mu (g, n, nx)), row i engine i's arrays as it reads them. Engines that hold their rows
    of group steps (the usual case) give their steps' arrays indexed once; else their own arrays are
    joined."""
    held = list(map(vars, engines))
    rows = [fields["z"] for fields in held]
    names = ("z", "mu", "logw", "copies", "node")
    if not all(type(row) is StepRow and fields["mu"] is fields["logw"] is fields["copies"] is fields["node"] is row
               for row, fields in zip(rows, held)):
        return tuple(joined(a).reshape((len(a),) + a[0].shape)
                     for a in ([getattr(e, name) for e in engines] for name in names))
    steps = list({id(row.step): row.step for row in rows}.values())
    offset = dict(zip(map(id, steps), np.cumsum([0] + [len(s.z) for s in steps[:-1]]).tolist()))
    start = np.fromiter((offset[id(s)] + s.starts[i] for s, i in rows), np.int64, len(rows))
    at = start[:, None] + np.arange(rows[0].step.held[rows[0].i])  # each engine's particles
    return tuple((getattr(steps[0], name) if len(steps) == 1 else
                  np.concatenate([getattr(s, name) for s in steps]))[at] for name in names)


def share(engines):
    """Let the engines of a fleet's units of one bank hold one covariance graph, so that a covariance
    any of them meets is worked out once for all; called before each step with every unit's engine.
    An engine joining moves its nodes and representatives in: its results stay bit for bit its own
    (a node is its covariance exactly, and each engine keeps its own representatives). A shared graph
    that has outgrown its engines' particles is compacted, every engine's nodes renumbered."""
    graph = engines[0].graph
    if graph.shared and all(e.graph is graph for e in engines):  # as at the last step: one bank, one graph
        groups = [engines]
    else:
        banks = {}
        for e in engines:
            banks.setdefault(id(e.model), []).append(e)
        groups = banks.values()
    for holders in groups:
        graph = next((e.graph for e in holders if e.graph.shared), None)
        if graph is None:
            graph = CovarianceGraph(holders[0].model)
            graph.shared = True
        for e in holders:
            if e.graph is not graph:
                e.join(graph)
        if graph.size > RaoBlackwellised.spare_nodes and graph.size > RaoBlackwellised.spare_nodes + 4 * sum(
                e.particles_held for e in holders):
            graph.compact(holders)


def weigh(prior, log_prior, mode, K, quad, logdet, r, mu_p, y_pred, gain_t, Sig_f):
    """What the readings make of the candidates, over any leading axes (one engine's, or many engines'
    side by side, each the same operations on its own arrays): (normalised weights q, log-likelihood,
    filtered means, the mixture's mean and covariance, the mode posterior, the predicted readings),
    from the candidates' prior weights (normalised and in logs), modes, squared Mahalanobis distances
    quad, log det S, residuals r and Kalman pieces."""
    nx = mu_p.shape[-1]
    ll = kalman.log_density(quad, logdet, r.shape[-1])
    mu_f = mu_p + (r[..., None, :] @ gain_t)[..., 0, :]
    q, loglik = normalize_rows(log_prior + ll)
    lead = q.shape[:-1]
    weighted = (q[..., None, :] @ Sig_f.reshape(lead + (-1, nx * nx)))[..., 0, :].reshape(lead + (nx, nx))
    mean, cov = mixture_moments(q, mu_f, weighted)
    if q.ndim == 1:
        posterior = np.bincount(mode, weights=q, minlength=K)
    else:
        posterior = np.bincount((np.arange(len(q))[:, None] * K + mode).ravel(), weights=q.ravel(),
                                minlength=len(q) * K).reshape(len(q), K)
    return q, loglik, mu_f, mean, cov, posterior, (prior[..., None, :] @ y_pred)[..., 0, :]


def merge_copies(key, chosen, logw, size, equal=False):
    """Chosen candidates with equal keys (same parent, same mode) are identical particles: keep one
    of each, in key order, with the summed weight. Keys lie in [0, size); `equal` says every logw
    is the same (as after resampling), so c copies weigh log c + logw[0].
    Returns (chosen, log-weights, copy counts). (`merge_copies_together`: many engines' at once.)"""
    counts = np.bincount(key, minlength=size)
    distinct = counts.nonzero()[0]
    if len(distinct) == len(key):
        return chosen, logw, counts[key]
    if key is chosen:  # a candidate is its own key
        kept = distinct
    else:
        first = np.empty(size, dtype=np.int64)
        first[key[::-1]] = chosen[::-1]  # the first chosen candidate with each key
        kept = first[distinct]
    counts = counts[distinct]
    if equal:
        return kept, np.log(counts) + logw[0], counts
    top = logw.max()
    summed = np.bincount(key, weights=np.exp(logw - top), minlength=size)[distinct]
    return kept, np.log(summed, out=np.full(len(summed), -np.inf), where=summed > 0) + top, counts


def merge_copies_together(key, chosen, logw, size, equal, lengths):
    """`merge_copies` of engines side by side, their chosen candidates one after the other (`lengths`
    (g,) of each, `equal` (g,) each one's `equal`), every engine's merged as alone.
    Returns (chosen, log-weights, copy counts, the engine of each), one after the other."""
    g = len(lengths)
    owner = np.repeat(np.arange(g), lengths)
    whole = owner * size + key  # keys of different engines apart
    counts = np.bincount(whole, minlength=g * size)
    distinct = counts.nonzero()[0]
    if len(distinct) == len(key):
        return chosen, logw, counts[whole], owner
    first = np.empty(g * size, dtype=np.int64)
    first[whole[::-1]] = chosen[::-1]  # the first chosen candidate with each key
    kept, counts, merged_owner = first[distinct], counts[distinct], distinct // size
    starts = np.cumsum(lengths) - lengths
    if equal.all():
        merged = np.log(counts) + logw[starts][merged_owner]
    else:
        top = np.maximum.reduceat(logw, starts)
        summed = np.bincount(whole, weights=np.exp(logw - top[owner]), minlength=g * size)[distinct]
        merged = np.log(summed, out=np.full(len(summed), -np.inf), where=summed > 0) + top[merged_owner]
        if equal.any():
            at = equal[merged_owner]
            merged[at] = np.log(counts[at]) + logw[starts][merged_owner[at]]
    found = np.bincount(merged_owner, minlength=g)
    if (found == lengths).any():  # those engines keep their candidates in their order, their weights
        at = (found == lengths)[merged_owner]
        source = starts[merged_owner[at]] + np.flatnonzero(at) - (np.cumsum(found) - found)[merged_owner[at]]
        kept[at], merged[at] = chosen[source], logw[source]
    return kept, merged, counts, merged_owner


class RBPF(RaoBlackwellised):
    """Rao-Blackwellised particle filter with the transition prior as proposal."""

    def __init__(self, model, particles, rng, resampler):
        super().__init__(model, particles, rng, resampler)
        # From the weighted prior atoms to N equally weighted particles.
        ancestors = resampler.scheme(np.exp(self.logw), particles, rng)
        self.logw = np.full(particles, -np.log(particles))
        self.z, self.mu, self.node = self.z[ancestors], self.mu[ancestors], self.node[ancestors]
        self.copies = np.ones(particles, dtype=np.int64)

    def candidates(self):
        # Every copy of a particle draws its own next mode, and takes its share of the weight.
        parent = np.repeat(np.arange(len(self.z)), self.copies)
        mode = sample_rows(self.model.P[self.z[parent]], self.rng)
        return parent, mode, self.model.logP[self.z[parent], mode] + np.log(self.copies[parent])

    @staticmethod
    def candidates_together(engines):
        return tuple(np.stack(a) for a in zip(*(e.candidates() for e in engines)))  # each from its own Generator

    def select(self, q, parent, mode):
        return self.resampler(q)


class LookAheadRBPF(RaoBlackwellised):
    """Look-ahead RBPF: select particles on p(y_t | history), then draw modes from their exact posterior."""

    def select(self, q, parent, mode):
        K = self.K
        q = q.reshape(-1, K)
        ancestors, logw, size = self.resampler(q.sum(axis=1), self.copies)
        return ancestors * K + sample_rows(q[ancestors], self.rng), logw, size

    @staticmethod
    def select_together(engines, q, copies):
        """`select` of the engines that resample this step with the systematic scheme, side by side:
        whether each resamples is decided for all at once as its `Resampler.resamples` decides it;
        each that does draws from its own Generator the numbers it would alone (one for the scheme,
        then one per particle for its mode: one call), and gets the same particles."""
        K, g = engines[0].K, len(engines)
        q = q.reshape(g, -1, K)
        w = q.sum(axis=-1)
        size = 1.0 / (w[:, None, :] @ (w / copies)[:, :, None])[:, 0, 0]  # ess(w, copies), row by row
        resamplers = [e.resampler for e in engines]
        threshold, n = (np.array([getattr(r, name) for r in resamplers]) for name in ("threshold", "n"))
        going = np.flatnonzero(np.array([r.scheme is systematic for r in resamplers])
                               & resampling(threshold, n, size, copies.sum(axis=1)))
        if not len(going):
            return None
        n = int(n[going[0]])
        draws = np.empty((len(going), n + 1))  # the scheme's, then sample_rows'
        for i, row in zip(going.tolist(), draws):
            engines[i].rng.random(out=row)
        ancestors = systematic_rows(w[going], n, draws[:, 0])
        q = q if len(going) == g else q[going]
        return going, ancestors * K + rows_drawn(q[np.arange(len(going))[:, None], ancestors], draws[:, 1:]), size


class FearnheadCliffordRBPF(RaoBlackwellised):
    """Look-ahead RBPF keeping N distinct successors chosen by Fearnhead-Clifford optimal selection."""

    def select(self, q, parent, mode):
        chosen, w = fearnhead_clifford(q, self.n, self.rng)
        w = w / w.sum()
        return chosen, np.log(w), ess(w)


class Exact(RaoBlackwellised):
    """Every mode history with positive probability: the exact posterior, for short sequences."""

    max_gaussians = 100_000

    def candidates(self):
        # Refused when the work is due, so the last step of a sequence never is.
        if len(self.z) * self.K > self.max_gaussians:
            raise FilterError(
                f"exact filtering would need {len(self.z) * self.K} Gaussians at this step, more than the "
                f"limit of {self.max_gaussians}; use fc-rbpf, which is exact while the particles outnumber "
                f"the mode histories")
        return super().candidates()

    def select(self, q, parent, mode):
        chosen = np.flatnonzero(q > 0)
        w = q[chosen]
        return chosen, np.log(w), ess(w)
