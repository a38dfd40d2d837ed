"""Many units of one plant in one filter: a fleet of pumps, dryers or gearboxes of the same design,
each unit with its own data, missing readings and gross errors.

A step of one small plant is mostly the cost of numpy calls on arrays of a few numbers; `Units`
steps every unit at once, with a leading unit axis on every array, so a call does the work of the
whole fleet. `imm` runs vectorised through the same arithmetic as `IMM` (jmlgdsl.infer.imm), matrix
by matrix, and each unit's results are those of a `Filter` on its data alone, bit for bit (its
mode posteriors, state moments, predictions, log-likelihoods and rejected readings).

The particle filters and `exact` keep one engine per unit, each with its particles and its own
Generator, because their banks are ragged: identical particles merge into copies and `exact` drops
the histories whose weight underflows, so units differ in their particle counts from step to step.
The Rao-Blackwellised units of one bank share one graph of Kalman covariances (`rbpf.share`), each
keeping its own representative of every class of nearly equal covariances it met. The units that
measured the same outputs and hold as many particles step together (`rbpf.step_together`,
`pf.step_together`): their predictions, Kalman pieces, weights and mixture moments in one call with
a leading unit axis, and their systematic resampling (and la-rbpf's draw of modes) too, each unit
with the numbers its own Generator gives; then their copies merge and their covariances' children
are found in one pass (`rbpf.advance_together`). Their Estimates come back as arrays with a unit
axis (`engine.Estimates`), from which the step's UnitSteps are made, each unit counted in its Filter
without a Step of its own (`Filter.accept_together`). Every unit gets, bit for bit, what a Filter
with the same seed gets alone.

Units of one design need not share their numbers: `models=` gives each unit its own bank (its fitted
spec: its own gain, settled temperature, sensor offsets). Banks of one shape (`stackable`) still step
together, as `Stacked` arrays with a leading unit axis; the particle filters step together the units
that share a bank.

    >>> import jmlgdsl
    >>> from jmlgdsl.infer.units import Units
    >>> model = jmlgdsl.load("specs/dryer.jmlg")
    >>> fleet = Units(model, 3)
    >>> for temp in (50.5, 50.4, 44.0, 44.1, 44.0):     # unit 0's fan fails; unit 2 reads nothing
    ...     steps = fleet.step([[temp], [50.5], [float("nan")]], [[15.0]] * 3)
    >>> [model.modes[k] for k in steps.map_modes]
    ['fan', 'normal', 'normal']
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np

from ..errors import DataError
from ..model import Model
from . import kalman
from .algorithms import ALGORITHMS, DEFAULT_ALGORITHM, algorithm_named
from .engine import Estimate, Estimates, FilterError, Gate, screen
from .imm import SURE, mix, moments, predict, refresh, whitened
from .online import MAX_REJECTIONS, Filter, _arrays, _inputs, _overflow, _readings
from .resample import normalize_rows, row_extreme
from .result import Predictive, Result, Step

ALL = slice(None)  # every unit, as an index that takes views, not copies


class Batch(NamedTuple):
    """One step of many units: what each reports (post ... flagged) and its new IMM state."""

    post: np.ndarray  # (n, K)
    mean: np.ndarray  # (n, nx)
    cov: np.ndarray  # (n, nx, nx)
    y_pred: np.ndarray  # (n, ny)
    loglik: np.ndarray  # (n,)
    rejected: np.ndarray  # (n, ny) bool
    flagged: np.ndarray  # (n, ny) bool
    log_mu: np.ndarray  # (n, K)
    means: np.ndarray  # (n, K, nx)
    covs: np.ndarray  # (n, K, nx, nx)
    sure: np.ndarray  # (n,) bool

    @classmethod
    def empty(cls, like: "Batch", n: int) -> "Batch":
        return cls(*(np.empty((n,) + a.shape[1:], a.dtype) for a in like))

    def put(self, rows, other: "Batch"):
        """Write other's units into rows of this batch."""
        for mine, theirs in zip(self, other):
            mine[rows] = theirs


SHAPED = ("modes", "outputs", "inputs", "nx", "output_states")  # what units stepped together must share
STACKED = ("P", "logP", "A", "Q", "R", "C", "F", "f", "G", "g")  # what a step of many units reads


def stackable(models) -> bool:
    """Whether these banks can step together as one `Stacked`: the same modes, outputs, inputs and
    states, the same gate and input defaults (a step screens and fills every unit alike)."""
    first = models[0]
    return all(m is first or (all(getattr(m, k) == getattr(first, k) for k in SHAPED)
                              and np.array_equal(m.outlier_gate, first.outlier_gate)
                              and np.array_equal(m.input_defaults, first.input_defaults, equal_nan=True))
               for m in models)


class Stacked:
    """The banks of many units of one shape, each with its own numbers, as one: every array a step
    of many units reads (STACKED: BatchIMM's, the predictive bands') with a leading unit axis, so
    the arithmetic, which broadcasts over leading axes, runs every unit under its own matrices in
    the same calls."""

    def __init__(self, models, arrays=None):
        self.models = models
        self.output_states = models[0].output_states
        for name in STACKED:
            setattr(self, name, np.stack([getattr(m, name) for m in models]) if arrays is None else arrays[name])

    def take(self, rows) -> "Stacked":
        """The units at positions `rows` (an index array; ALL: every one)."""
        if rows is ALL:
            return self
        return Stacked([self.models[i] for i in rows], {name: getattr(self, name)[rows] for name in STACKED})


class BatchIMM:
    """IMM over `count` units: mode log-probabilities (U, K), per-mode moments (U, K, nx[, nx]) and,
    for the units whose last posterior was sure of its mode, `refresh`'s kept pieces (each unit's
    own: its covariances follow its own data), stored in arrays padded to every output. After a
    step, `predictives` holds its one-step predictives as (rows of the step, Predictive with a unit
    axis) for the units that used the same readings, as `IMM.predictive` holds one unit's."""

    STATE = ("log_mu", "means", "covs", "sure", "_mask", "_base", "_tol", "_Sig", "_Linv", "_logdet", "_gain")

    def __init__(self, model: Model, count: int, models=None):
        K, nx, ny = model.K, model.nx, model.ny
        self.model, self.count = model, count
        # each unit's bank: one shared (every array as the model has it), or the units' own, stacked
        self.models = None if models is None or all(m is model for m in models) else list(models)
        self.bank = model if self.models is None else Stacked(self.models)
        banks = [model] * count if self.models is None else self.models
        with np.errstate(divide="ignore"):
            self.log_mu = np.log(np.array([m.p0 for m in banks]))
        self.means = np.array([m.mu0 for m in banks])
        self.covs = np.array([np.broadcast_to(m.Sigma0, (K, nx, nx)) for m in banks])
        self.sure = np.zeros(count, dtype=bool)
        self._gate = model.outlier_gate
        self._bound = Gate.of(self._gate).bound
        # kept pieces, valid where `sure`: the mask, the covariances they belong to and their
        # tolerance; Linv, log det S, gain' (the first m of ny rows for m readings) and filtered covs
        self._mask = np.zeros((count, ny), dtype=bool)
        self._base, self._tol, self._Sig = (np.zeros((count, K, nx, nx)) for _ in range(3))
        self._Linv, self._logdet, self._gain = (np.zeros((count, K, ny, ny)), np.zeros((count, K)),
                                                np.zeros((count, K, ny, nx)))
        self.predictives = []  # none before the first step

    def step(self, y, mask, u, enforce, units=ALL) -> Batch:
        """Condition the units `units` (all, or an index array) on readings y (n, ny), measured where
        mask (n, ny) is True, under inputs u (n, nu); enforce (n, ny) says where each unit's gate
        leaves out a gross error (None: no gate). Units sharing a mask share every call."""
        bank = self._bank(units)
        # the mode log-probabilities with the unit axis innermost in memory: numpy lays the mixing's
        # joint array out after them, so its reductions over the previous mode run over planes of
        # every unit instead of rows of K (the same operations, and mix_t's matrices the same but for
        # their leading dimension; a step at 1,000 units 10 to 25 % faster)
        log_pred, mixed, covs = mix(np.asfortranarray(self.log_mu[units]), bank.logP, self.means[units],
                                    self.covs[units])
        # units under the same inputs (the usual case) share their offsets, computed once
        mu_p, y_pred = predict(bank, _reads(bank), mixed, u[:1] if (u == u[0]).all() else u)
        prior = log_pred, covs, mu_p, y_pred
        if (mask == mask[0]).all():
            batch, self.predictives = self._group(_index(units, ALL), y, mask[0], u, prior, enforce)
        else:
            patterns, which = _groups(mask)
            batch, self.predictives = None, []
            for g, pattern in enumerate(patterns):
                rows = np.flatnonzero(which == g)
                part, heard = self._group(_index(units, rows), y[rows], pattern, u[rows],
                                          tuple(p[rows] for p in prior), None if enforce is None else enforce[rows])
                batch = Batch.empty(part, len(y)) if batch is None else batch
                batch.put(rows, part)
                self.predictives += [(rows[positions], predictive) for positions, predictive in heard]
        for name in ("log_mu", "means", "covs", "sure"):
            if units is ALL:
                setattr(self, name, getattr(batch, name))
            else:
                getattr(self, name)[units] = getattr(batch, name)
        return batch

    def _bank(self, units):
        """The banks of the units `units` (ALL, or an index array): the shared model, or theirs stacked."""
        return self.bank if self.models is None else self.bank.take(units)

    def _group(self, units, y, mask, u, prior, enforce) -> tuple[Batch, list]:
        """`step` for units that share one mask (ny,); prior holds their mixing and predictions. With the
        batch, its predictives as [(positions in the group, Predictive)]: one for the units that used
        every reading, one for each unit whose gate left readings out."""
        log_pred, covs, mu_p, y_pred = prior
        bank = self._bank(units)
        m = np.count_nonzero(mask)
        reusable = self.sure[units]
        if reusable.any() and (reusable := reusable & (self._mask[units] == mask).all(axis=-1)).any():
            kept = (self._base[units], tuple(np.ascontiguousarray(p) for p in (
                self._Linv[units][..., :m, :m], self._logdet[units], self._gain[units][..., :m, :], self._Sig[units])),
                self._tol[units])
            (Linv, logdet, gain_t, covs), kept = refresh(bank, _reads(bank), covs, mask, kept, reusable)
        else:  # `refresh` with nothing kept, less its tolerances: `_keep` takes them for the units it keeps
            pieces = kalman.covariance_step(covs, bank.A, bank.Q, _reads(bank), bank.R, mask)
            (Linv, logdet, gain_t, covs), kept = pieces, (covs, pieces, None)
        r, quad = whitened(y, mask, y_pred, Linv)
        heard = Predictive(np.arange(log_pred.shape[-1]), log_pred, r, Linv, mask)
        means = mu_p + (r[..., None, :] @ gain_t)[..., 0, :]
        post, loglik = normalize_rows(log_pred + kalman.log_density(quad, logdet, m))
        log_mu = np.log(post, out=np.full_like(post, -np.inf), where=post > 0)
        sure = row_extreme(np.maximum, post) >= 1.0 - SURE
        mean, cov = moments(post, means, covs)
        y_mix = (np.exp(log_pred)[..., None, :] @ y_pred)[..., 0, :]
        flags = np.zeros(y.shape, dtype=bool)
        batch = Batch(post, mean, cov, y_mix, loglik, flags.copy(), flags, log_mu, means, covs, sure)
        screened = np.zeros(len(y), dtype=bool)
        redone = []
        if enforce is not None and self._bound < np.inf:
            for j in np.flatnonzero(row_extreme(np.minimum, quad) > self._bound):  # a closer look, unit by unit
                unit = _Unit(self, _index(units, [j]), tuple(p[[j]] for p in prior))
                found, flagged = screen(unit, y[j], mask, u[j], Gate.of(self._gate, enforce[j]), r[j],
                                        kalman.standard_deviations(Linv[j]))
                if flagged is not None:
                    batch.flagged[j] = flagged
                if found is not None:
                    screened[j] = True
                    batch.put([j], unit.batch._replace(rejected=found.rejected[None], flagged=batch.flagged[[j]]))
                    redone.append((np.array([j]), unit.predictive))
        keep = np.flatnonzero(sure & ~screened)
        if len(keep):
            self._keep(_index(units, keep), mask, tuple(None if a is None else a[keep]
                                                           for a in (kept[0], *kept[1], kept[2])))
        if redone:
            whole = np.flatnonzero(~screened)
            heard = heard._replace(log_weight=log_pred[whole], residual=r[whole], Linv=Linv[whole])
            return batch, [(whole, heard)] + redone
        return batch, [(np.arange(len(y)), heard)]

    def _keep(self, units, mask, kept):
        """Store refresh's kept pieces for units whose posterior is sure (padded to every output)."""
        base, Linv, logdet, gain_t, Sig, tol = kept
        tol = kalman.tolerance(base, Linv) if tol is None else tol
        m = Linv.shape[-1]
        self._mask[units] = mask
        self._base[units], self._tol[units], self._Sig[units], self._logdet[units] = base, tol, Sig, logdet
        self._Linv[units, :, :m, :m] = Linv
        self._gain[units, :, :m, :] = gain_t


class _Unit:
    """One unit of a BatchIMM seen as an engine, for `screen`: its step with the readings it keeps
    redone from the same prior (its batch kept for the caller, the state left as it was)."""

    def __init__(self, batch: BatchIMM, unit, prior):
        self.model = batch.model if batch.models is None else batch.models[int(unit[0])]  # the unit's own bank
        self._batch, self._unit, self._prior = batch, unit, prior

    def step(self, y, mask, u, gate=None) -> Estimate:
        self.batch, [(_, self.predictive)] = self._batch._group(self._unit, y[None], mask, u[None], self._prior, None)
        b = self.batch
        return Estimate(b.post[0], b.mean[0], b.cov[0], b.y_pred[0], float(b.loglik[0]), np.nan)


def _reads(bank):
    """What the outputs read of the states, as kalman takes it: the slice of the states they are, or
    the bank's C (a unit axis first where the bank is Stacked)."""
    return bank.C if bank.output_states is None else bank.output_states


def _groups(mask):
    """(the distinct rows of mask (n, ny), which of them each row is): np.unique(mask, axis=0,
    return_inverse=True), with a row read as a binary number (the first output its highest bit, so
    the groups come in the same order) where it fits in one: 10 to 30 times faster at 1,000 units."""
    if mask.shape[1] > 62:
        patterns, which = np.unique(mask, axis=0, return_inverse=True)
        return patterns, which.ravel()
    _, first, which = np.unique(mask @ (1 << np.arange(mask.shape[1] - 1, -1, -1)), return_index=True,
                                return_inverse=True)
    return mask[first], which


def _index(units, rows):
    """The units at positions `rows` of `units` (ALL: every unit)."""
    if rows is ALL:
        return units
    return np.asarray(rows) if units is ALL else units[rows]


class UnitSteps(NamedTuple):
    """One step of many units, as arrays with a leading unit axis: the fields of `Step`, named as a
    `Result` (arrays over time) names them (`jmlgdsl.infer.result.stacked`), and each unit's t."""

    t: np.ndarray  # (n,)
    mode_posterior: np.ndarray  # (n, K)
    state_mean: np.ndarray  # (n, nx)
    state_cov: np.ndarray  # (n, nx, nx)
    y_pred: np.ndarray  # (n, ny)
    residuals: np.ndarray  # (n, ny)
    loglik_steps: np.ndarray  # (n,) log p(y_t | y_1:t-1), each unit's
    ess: np.ndarray  # (n,)
    rejected: np.ndarray  # (n, ny) bool

    @property
    def map_modes(self) -> np.ndarray:
        """(n,) each unit's most probable mode."""
        return self.mode_posterior.argmax(axis=1)

    def records(self) -> list[Step]:
        """Each unit's step, as a Filter would give it, made in one pass over the units."""
        rejected = self.rejected.any(axis=1).tolist()
        return [Step(t, self.mode_posterior[i], self.state_mean[i], self.state_cov[i], self.y_pred[i],
                     self.residuals[i], loglik, ess, self.rejected[i] if rejected[i] else None)
                for i, (t, loglik, ess) in enumerate(zip(self.t.tolist(), self.loglik_steps.tolist(),
                                                         self.ess.tolist()))]


class Units:
    """On-line filtering of `count` units of one model: `step(y, u)` with one row of readings (and
    inputs) per unit. The options are a Filter's; every unit gets the same seed, as it would alone.
    `units=` steps only some units (those whose data go on), leaving the others where they are.

    `models=` gives unit i its own bank models[i] (`stackable` with `model`, which names the outputs
    and inputs every unit reads).

    `filters=` steps the units' own Filters instead (one algorithm, no lag, banks stackable; their
    count is the count, imm's too unit after unit): each goes on as itself, so whatever saves a
    Filter (a Diagnosis's checkpoint) saves its unit."""

    def __init__(self, model: Model, count: int, algorithm: str = DEFAULT_ALGORITHM, particles: int | None = None,
                 seed=None, resampling: str = "systematic", ess_threshold: float = 1.0, filters=None, models=None):
        if filters is not None:
            filters = list(filters)
            count, algorithm, models = len(filters), filters[0].algorithm, [f.model for f in filters]
            if any(f.lag != 0 for f in filters):
                raise FilterError("the units' filters must have no lag: a step gives each unit's record of that row")
        if isinstance(count, bool) or not isinstance(count, (int, np.integer)) or count < 1:
            raise FilterError(f"the number of units must be a positive whole number, got {count!r}")
        if models is not None:
            models = list(models)
            if len(models) != count:
                raise FilterError(f"{len(models)} banks for {count} units: give one bank per unit")
            if not stackable([model, *models]):
                raise FilterError("the units' banks must have the model's modes, outputs, inputs, states, gate and "
                                  "input defaults to step together")
        self.model, self.count, self.algorithm = model, count, algorithm
        banks = models or [model] * count
        vectorised = filters is None and algorithm_named(algorithm).vectorised
        self._filters = filters or [Filter(banks[i], algorithm, particles, seed, resampling, ess_threshold)
                                    for i in range(1 if vectorised else count)]
        self.particles = self._filters[0].particles
        self._engine = BatchIMM(model, count, models) if vectorised else None
        self.t = np.array([f.t for f in self._filters] if filters else np.zeros(count), dtype=np.int64)
        self.loglik = np.array([f.loglik for f in self._filters] if filters else np.zeros(count), dtype=float)
        self.seconds = 0.0  # time spent inside step(), for every unit together
        self._flagged = np.zeros((count, model.ny), dtype=np.int64)  # consecutive steps beyond the gate

    def step(self, y, u=None, units=None) -> UnitSteps:
        """Advance the units `units` (an index array; None: all of them) one step with readings y (n, ny)
        and inputs u (n, nu), a row per unit (u=None or NaN entries: the spec's defaults)."""
        start = time.perf_counter()
        model = self.model
        index = ALL if units is None else np.asarray(units, dtype=np.int64)
        t = self.t[index] + 1
        n = len(t)
        y = _rows(y, n, model.outputs, "outputs")
        y, mask = _readings(y)
        u = _inputs(model, np.tile(model.input_defaults, (n, 1)) if u is None else _rows(u, n, model.inputs, "inputs"), t)
        if self._engine is None:
            steps = self._each(index, t, y, mask, u)
        else:
            steps = self._batched(index, t, y, mask, u)
        self.t[index] = t
        self.loglik[index] += steps.loglik_steps
        self.seconds += time.perf_counter() - start
        return steps

    @property
    def vectorised(self) -> bool:
        """Whether one engine steps every unit (its last step's predictives in `predictives`); else each
        unit's own Filter steps, its engine holding its own last predictive."""
        return self._engine is not None

    @property
    def predictives(self) -> list:
        """The last step's one-step predictives (imm): [(rows of the step, Predictive with a unit axis)],
        the units in each having used the same readings; jmlgdsl.diagnosis.evidence reads them."""
        return self._engine.predictives

    def state(self, i: int) -> dict | None:
        """Unit i's part of the filter (imm): its moments, kept pieces, step count, log-likelihood and
        gate counts, as copies; `restore` puts them back, so a saved fleet goes on bit for bit. None for
        the other algorithms: each unit's Filter is its whole state (given with `filters=`, its owner
        saves it)."""
        if self._engine is None:
            return None
        return {"t": int(self.t[i]), "loglik": float(self.loglik[i]), "flagged": self._flagged[i].copy(),
                **{name: getattr(self._engine, name)[i].copy() for name in BatchIMM.STATE}}

    def restore(self, i: int, state: dict | None):
        """Unit i's part of the filter, as `state` gave it."""
        if state is None:
            return
        self.t[i], self.loglik[i], self._flagged[i] = state["t"], state["loglik"], state["flagged"]
        for name in BatchIMM.STATE:
            getattr(self._engine, name)[i] = state[name]

    def _batched(self, index, t, y, mask, u) -> UnitSteps:
        counts = self._flagged[index]
        b = self._engine.step(y, mask, u, counts < MAX_REJECTIONS, index)
        if not (np.isfinite(b.loglik).all() and np.isfinite(b.cov).all()):  # the unit is looked for only then
            i = int(np.flatnonzero(~(np.isfinite(b.loglik) & np.isfinite(b.cov).all(axis=(-2, -1))))[0])
            raise _unit_error(index, i, _overflow(int(t[i]), Estimate(b.post[i], b.mean[i], b.cov[i], b.y_pred[i],
                                                                       float(b.loglik[i]), np.nan)))
        if b.flagged.any() or counts.any():
            # `Filter._count_flagged`, unit by unit: a count only goes on while its output stays beyond the gate
            self._flagged[index] = np.where(b.flagged, counts + 1, 0)
        return UnitSteps(t, b.post, b.mean, b.cov, b.y_pred, y - b.y_pred, b.loglik, np.full(len(t), np.nan),
                         b.rejected)

    def _each(self, index, t, y, mask, u) -> UnitSteps:
        """The units through their own Filters: the engines of the units of one bank that measured the
        same outputs and hold as many particles stepped together (their algorithm's `step_together`),
        each other one on its own; every unit's Estimate a row of arrays with a unit axis, counted in
        its Filter (`Filter.accept_together`) without a record of its own."""
        spec = ALGORITHMS[self.algorithm]
        if spec.share is not None:
            spec.share([f.engine for f in self._filters])
        filters = self._filters if index is ALL else [self._filters[i] for i in index.tolist()]
        n, model = len(filters), self.model
        est = Estimates.empty(n, model.K, model.nx, model.ny)
        failed = {}  # position -> the FilterError its step raised
        groups, alone = _together(filters, mask) if spec.step_together is not None else ([], range(n))
        for members in groups:
            try:
                est.put(members, spec.step_together([filters[i].engine for i in members], y[members],
                                                    mask[members[0]], u[members], [filters[i].gate for i in members]))
            except FilterError as exc:  # refused before any engine moved (exact's bank, as large for all)
                failed.update(dict.fromkeys(members.tolist(), exc))
        for i in alone:
            f = filters[i]
            try:
                est.put_one(i, f.engine.step(y[i], mask[i], u[i], f.gate))
            except FilterError as exc:
                failed[i] = exc
        ok = np.isfinite(est.loglik) & np.isfinite(est.state_cov).all(axis=(1, 2))
        ok[list(failed)] = False
        stop = n if ok.all() else int(np.flatnonzero(~ok)[0])  # the units after one that failed stay uncounted
        Filter.accept_together(filters[:stop], Estimates(*(a[:stop] for a in est)))
        if stop < n:  # named in the order the units would fail one after the other
            raise _unit_error(index, stop, failed.get(stop) or _overflow(int(t[stop]), est.one(stop)))
        return UnitSteps(t, est.mode_posterior, est.state_mean, est.state_cov, est.y_pred, y - est.y_pred, est.loglik,
                         est.ess, est.rejected)


def _together(filters, mask) -> tuple[list, list]:
    """(the positions of each group of two or more units that step together: one bank, one mask (n, ny)
    row, as many particles; in the order of their first units), and the positions of the others."""
    _, which = _groups(mask)
    models = [f.model for f in filters]
    bank = (np.zeros(len(filters), np.int64) if models.count(models[0]) == len(models) else
            np.unique(np.array(list(map(id, models))), return_inverse=True)[1])
    held = np.array([f.engine.particles_held for f in filters])
    # each unit's (bank, mask, particles) as one number, the groups in the order of their first units
    _, first, group = np.unique((bank * (which.max() + 1) + which) * (held.max() + 1) + held, return_index=True,
                                return_inverse=True)
    order = np.argsort(first)
    sizes = np.bincount(group)[order]
    members = np.split(np.argsort(np.argsort(order)[group], kind="stable"), np.cumsum(sizes)[:-1])
    return [m for m in members if len(m) > 1], first[order][sizes == 1].tolist()


def _unit_error(index, i, exc):
    """exc, its message prefixed with the unit it is about."""
    unit = i if index is ALL else int(index[i])
    return type(exc)(f"unit {unit}: {exc}")


def _rows(values, n, names, what):
    """One step's values for n units as an (n, len(names)) float array; a DataError otherwise."""
    v = np.asarray(values, dtype=float)
    if v.shape != (n, len(names)):
        raise DataError(f"{what} must have shape ({n}, {len(names)}) for {n} units and {', '.join(names) or 'none'}; "
                        f"got {v.shape}")
    return v


def filter_units(model: Model, ys, us=None, **options) -> list[Result]:
    """`jmlgdsl.filter` for many units at once: ys is a list of (T_i, ny) records (or a (U, T, ny)
    array), us the matching inputs (None: defaults); one Result per unit, as filtering it alone
    would give. Records of different lengths are fine: a unit whose record has ended stops."""
    data = [_arrays(model, y, None if us is None else us[i]) for i, y in enumerate(ys)]
    fleet = Units(model, len(data), **options)
    lengths = np.array([len(y) for y, _ in data])
    kept = [[] for _ in data]
    for t in range(int(lengths.max(initial=0))):
        on = np.flatnonzero(lengths > t)
        steps = fleet.step(np.array([data[i][0][t] for i in on]).reshape(len(on), model.ny),
                           np.array([data[i][1][t] for i in on]).reshape(len(on), model.nu),
                           None if len(on) == len(data) else on)
        for i, step in zip(on, steps.records()):
            kept[i].append(step)
    share = fleet.seconds / max(len(data), 1)
    return [Result.from_steps(model, fleet.algorithm, fleet.particles, steps, share) for steps in kept]
