"""From experiments to a mode bank: each mode's structure (ARX orders by information criterion, or
FOPDT from step tests), EM inside the shared lagged basis from that start, validation, and the
assembled Model, whose modes all speak of the same states (see `basis`)."""

from __future__ import annotations

import time
from functools import partial
import warnings
from dataclasses import dataclass

import numpy as np
from scipy.linalg import LinAlgWarning, solve_discrete_lyapunov

from ..names import plural
from ..errors import DataError, JmlgError
from ..lang.probabilities import otherwise_uniform
from ..model import Model
from . import arx, basis, steptest
from .resolution import noise_floor, resolution, unresolved
from .relative import POOLING, SHRINKAGE, Reference, RelativeFit, fit_relative, naming_setting, relative_wins
from .em import EMResult
from .basis import LaggedMode, Lags
from .statespace import StateSpace
from .validate import Validation, validate


@dataclass(frozen=True)
class Experiment:
    """One mode's identification data: outputs y (T, ny) with NaN where not measured, inputs u (T, nu)."""

    y: np.ndarray
    u: np.ndarray
    source: str = "<data>"


@dataclass(frozen=True)
class LearnedMode:
    """Everything learned about one mode: its experiments, structure, EM's start and run, the fitted
    mode in the lagged basis, and the checks (on the longest experiment)."""

    name: str
    experiments: tuple[Experiment, ...]
    structure: str
    start: LaggedMode
    em: EMResult
    mode: LaggedMode
    validation: Validation
    fopdt: steptest.FopdtFit | None = None
    notes: tuple[str, ...] = ()
    relative: RelativeFit | None = None

    @property
    def experiment(self) -> Experiment:
        """The longest experiment: the one validated and plotted."""
        return max(self.experiments, key=lambda e: len(e.y))

    @property
    def inputs(self) -> np.ndarray:
        """The inputs of every experiment, stacked."""
        return np.vstack([e.u for e in self.experiments])

    @property
    def model(self) -> StateSpace:
        """The mode at its own order, started where its experiment began (what validation filtered)."""
        return self.mode.statespace(self.experiment.u[0])

    def summary(self, outputs=None) -> str:
        """A line of structure, EM, poles, gain, noise, fit and the residual tests, then a line for
        each thing learning did about this mode's data (a noise floor, poles scaled inside the unit
        circle). `outputs` names the outputs (default y1, y2, ...)."""
        v, ny = self.validation, self.mode.ny
        outputs = outputs or [f"y{i + 1}" for i in range(ny)]
        gain = f"gain {_listed(self.model.gain().ravel())}; " if self.mode.nu else ""
        if not self.mode.nu:
            fit = "no simulation fit (without inputs a free run only settles at the mean)"
        elif ny <= LISTED:
            fit = f"fit {', '.join(f'{x:.1f}' for x in v.fit)} %"
        else:
            fit = f"fit {np.nanmin(v.fit):.1f} to {np.nanmax(v.fit):.1f} % (median {np.nanmedian(v.fit):.1f} %)"
        failing = [outputs[i] for i in v.failing]
        if not failing:
            verdict = "white residuals"
        elif ny == 1:
            verdict = "residual tests FAIL"
        else:
            verdict = (f"residual tests fail for {_listed(failing, str)} ({len(failing)} of {ny} outputs; "
                       f"a right model fails about {v.by_chance:.2g} by chance)")
        fitted = (f", EM {plural(self.em.iterations, 'iteration')}{self._stop()}, log-lik {self.em.loglik[-1]:.6g}"
                  if self.by_em else "")
        line = (f"{self.name}: {self.structure}{fitted}; "
                f"poles {_listed(self.mode.poles())}; {gain}measurement sd {np.sqrt(np.diag(self.mode.R)).max():.3g}; "
                f"{fit}; {verdict}")
        return "\n".join([line] + [f"  {note}" for note in self.notes])

    def _stop(self) -> str:
        """Why EM stopped, when not by its tolerance: the log-likelihood fell, or the iteration cap
        came first; then its last gain against the tolerance, and what the gains, shrinking as
        they do, project is left in all and per free parameter (a fit is as good as finished when
        that is a small fraction of a nat per parameter)."""
        em = self.em
        if em.converged:
            return ""
        if em.fell:
            return " (stopped: the log-likelihood fell by more than rounding; the last good parameters kept)"
        if em.iterations == 0:
            return " (no iterations)"
        left = (f", about {em.remaining:.3g} more to come, {em.remaining / self.parameters:.2g} per free parameter"
                if np.isfinite(em.remaining) else ", gains not yet shrinking")
        return f" (not converged: last gain {em.gain:.3g}, tolerance {em.tolerance:.3g}{left})"

    @property
    def by_em(self) -> bool:
        """Whether EM fitted the mode (not so a least-squares reference and the modes relative to it)."""
        return bool(np.isfinite(self.em.loglik).any())

    @property
    def parameters(self) -> int:
        """The free parameters of the fitted mode: its free coefficients, and Q and R."""
        m = self.mode
        return m.ny * int(m.lags.free(m.ny, m.nu).sum()) + m.ny * (m.ny + 1)

    def criterion(self, kind="bic") -> float:
        """AIC or BIC of the fitted mode: its free coefficients, and Q and R."""
        N = sum(int((~np.isnan(e.y)).all(axis=1).sum()) for e in self.experiments)
        return -2 * self.em.loglik[-1] + self.parameters * (np.log(N) if kind == "bic" else 2.0)


def learn_modes(experiments: dict, order="auto", fopdt=False, dt=1.0, max_order=4, max_delay=0,
                criterion="bic", max_iter=100, tol=1e-5, progress=None, outputs=None,
                relative_to: str | None = None, stay: float = 0.99) -> list[LearnedMode]:
    """Fit every mode: `experiments` maps a mode's name to its Experiment, or to a list of them (runs
    of the same mode, pooled: their equations in least squares, their moments in EM). Structure:
    ARX order (na, nb, nk), "auto", or FOPDT step tests (one per mode).

    "auto": the ARX order with the least criterion summed over modes (over na, nb <= max_order,
    nk <= max_delay) bounds the order from above, since ARX spends extra lags imitating measurement
    noise; EM then fits orders 1..that bound to each mode and keeps, mode by mode, the one with
    the least criterion (the shared basis lets modes of different orders sit in one bank).

    Each output's resolution is read from every mode's data (`resolution`); before any fitting,
    `progress(text)`, when given, hears of every output of every mode that moves no more than
    rounding to it would (a stuck sensor, collinear sensors: their measurement noise is floored at
    that rounding), and then of each mode as it is learned (a bank can take minutes). `outputs`
    names the outputs in those lines (default y1, y2, ...).

    `relative_to` names a mode (the normal one), written as its least-squares regression at the
    order given (or the one the criterion picks); every other mode is then learned relative to it
    (`relative`): its dynamics, offset and covariance, shrunk toward the reference's, for fault
    recordings too short for a model of their own. One such mode takes the shrinkage its own rows
    say by cross-validation; several share the one with which they name held-out halves of their
    recordings best (`relative.naming_setting`, a forward filter that stays in a mode with
    probability `stay`). AUTO (the default of `jmlgdsl learn`) lets the data choose: the first mode
    is the reference, the others are learned relative to it, and they are kept so when their
    cross-validation says that beats their own regressions (`relative.relative_wins`); otherwise
    each is learned on its own as above. None: each on its own. Step tests (`fopdt`) are always
    learned on their own.
    """
    if relative_to == AUTO:
        relative_to = None if fopdt or len(experiments) < 2 else AUTO
    elif relative_to is not None and relative_to not in experiments:
        raise JmlgError(f"relative_to: no mode {relative_to!r} among {', '.join(experiments)}")
    if relative_to is not None and fopdt:
        raise JmlgError("modes relative to another are regressions, not step-test fits: relative_to takes no fopdt")
    by_mode = {k: tuple(v) if isinstance(v, (list, tuple)) else (v,) for k, v in experiments.items()}
    for name, exps in by_mode.items():
        sources = ", ".join(e.source for e in exps)
        if np.isnan(np.vstack([e.y for e in exps])).all(axis=0).any():
            raise DataError(f"{sources}: an output of mode {name} is never measured")
        for j, column in enumerate(np.vstack([e.u for e in exps]).T):
            if np.nanmin(column) == np.nanmax(column):
                raise DataError(f"{sources}: input {j + 1} never changes, so its effect cannot be told "
                                "from the offset; excite it, e.g. with a PRBS")
    everything = [e for exps in by_mode.values() for e in exps]
    steps = resolution(np.vstack([np.hstack([e.y, e.u]) for e in everything]))
    ny = everything[0].y.shape[1]
    outputs = list(outputs or [f"y{i + 1}" for i in range(ny)])
    notes = {k: _unresolved(exps, steps[:ny], outputs) for k, exps in by_mode.items()}
    for k, lines in notes.items():
        for line in lines if progress is not None else ():
            progress(f"mode {k}: {line}")
    if fopdt:
        for exps in by_mode.values():
            if len(exps) != 1 or exps[0].u.shape[1] != 1 or exps[0].y.shape[1] != 1:
                raise DataError(f"{exps[0].source}: a mode's step test is one experiment with one input and one output")
        fits = {k: _located(e, steptest.fit_fopdt, e.y[:, 0], e.u[:, 0], dt) for k, (e,) in by_mode.items()}

        def learn_mode(k, exps):
            fit = fits[k]
            return _refine(k, exps, fit.lagged(), f"FOPDT gain {fit.gain:.4g}, tau {fit.tau:.4g} s, "
                                                  f"dead time {fit.delay * fit.dt:g} s", max_iter, tol, steps,
                           notes[k], fit)
    elif order != "auto":
        def learn_mode(k, exps):
            return _refine_arx(k, exps, order, max_iter, tol, steps, notes[k])
    else:
        order = arx.select_order([(e.y, e.u) for e in everything], max_order, max_order, max_delay, criterion, steps)
        orders = range(1, max(order[0], order[2] + order[1]) + 1)

        def learn_mode(k, exps):
            return min((_refine_arx(k, exps, (n, n, 0), max_iter, tol, steps, notes[k]) for n in orders),
                       key=lambda lm: lm.criterion(criterion))
    start = time.perf_counter()
    learned = (_relative_bank(by_mode, relative_to, order, steps, notes, progress, stay) if relative_to is not None
               else None) or {}
    for i, k in enumerate(learned or by_mode, 1):
        if k not in learned:
            learned[k] = learn_mode(k, by_mode[k])
        if progress is not None:
            lm = learned[k]
            fitted = f", EM {plural(lm.em.iterations, 'iteration')}" if lm.by_em else ""
            progress(f"learned mode {i} of {len(by_mode)}, {k}: {lm.structure}{fitted} "
                     f"({time.perf_counter() - start:.1f} s so far)")
            for line in lm.notes[len(notes[k]):]:
                progress(f"mode {k}: {line}")
    return [learned[k] for k in by_mode]


def _relative_bank(by_mode, relative_to, order, steps, notes, progress, stay) -> dict | None:
    """{mode: LearnedMode}, the reference first: the reference mode as its least-squares regression
    at `order` (na, nb, nk) and every other mode relative to it; or, with relative_to AUTO (the
    first mode the reference), None when cross-validation prefers each mode on its own
    (`relative.relative_wins`) or a mode has too few rows to cross-validate."""
    auto = relative_to == AUTO
    if auto:
        relative_to = next(iter(by_mode))
    exps = by_mode[relative_to]
    ny = exps[0].y.shape[1]
    reference = Reference.of([e.y for e in exps], [e.u for e in exps], Lags(*order), steps[:ny])
    others = [k for k in by_mode if k != relative_to]
    setting, learned = None, {}
    try:
        if len(others) > 1:  # a bank of faults: their shrinkage and pooling chosen to tell them apart
            setting, named = naming_setting(reference, {k: ([e.y for e in by_mode[k]], [e.u for e in by_mode[k]])
                                                        for k in others}, stay)
        for k in others:
            learned[k] = _relative(k, by_mode[k], reference, relative_to, steps, notes[k], setting)
    except DataError:
        if auto:  # too few rows to cross-validate: each mode on its own
            return None
        raise
    if auto:
        wins, better, differ = relative_wins([lm.relative for lm in learned.values()])
        if progress is not None:
            progress(f"the other modes relative to {relative_to}, or each on its own: relative learning predicts "
                     f"{better} of {differ} held-out blocks better than their own regressions, so "
                     + ("relative" if wins else "each on its own"))
        if not wins:
            return None
    if setting is not None and progress is not None:
        progress(f"the modes relative to {relative_to} share the penalty {SHRINKAGE[setting[0]]:g} on their change "
                 f"of dynamics and the weight {POOLING[setting[1]]:g} of {relative_to}'s covariance shape: "
                 f"cross-validated over the halves of their recordings, they name {named[setting]:.1%} of the "
                 "held-out rows right")
    mode, structure = reference.mode()
    mode, kept = _stable_mode(mode, exps, notes[relative_to])
    longest = max(exps, key=lambda e: len(e.y))
    first = LearnedMode(relative_to, exps, structure, mode, _unfitted(mode), mode,
                        validate(mode.statespace(longest.u[0]), longest.y, longest.u), None, kept)
    return {relative_to: first, **learned}


def _unfitted(mode: LaggedMode) -> EMResult:
    """The EMResult of a mode written from least squares without EM (no iterations, no log-likelihood)."""
    return EMResult(mode.reduced(), np.array([np.nan]), True)


#: `learn_modes(relative_to=AUTO)`: the other modes relative to the first one or each on its own, as
#: cross-validation says.
AUTO = "auto"


def _relative(name, exps, reference: Reference, reference_name, steps, notes, setting=None) -> LearnedMode:
    """One mode learned relative to the reference (`relative.fit_relative`, at `setting` when the
    bank chose one), kept stable and validated."""
    mode, fit = _located(exps[0], fit_relative, reference, [e.y for e in exps], [e.u for e in exps],
                         exps[0].source, setting)
    mode, notes = _stable_mode(mode, exps, notes)
    longest = max(exps, key=lambda e: len(e.y))
    return LearnedMode(name, exps, fit.structure(reference_name), mode, _unfitted(mode), mode,
                       validate(mode.statespace(longest.u[0]), longest.y, longest.u), None, notes, fit)


def _refine_arx(name, exps, order, max_iter, tol, steps, notes) -> LearnedMode:
    """One mode refined by EM from an ARX start of the given order."""
    start = _located(exps[0], partial(arx.fit_arx, steps=steps), [e.y for e in exps], [e.u for e in exps], *order)
    na, nb, nk = start.order
    structure = f"ARX({na},{nb},{nk})" if exps[0].u.shape[1] else f"AR({na})"
    return _refine(name, exps, start.lagged(), structure, max_iter, tol, steps, notes)


def _refine(name, exps, start: LaggedMode, structure, max_iter, tol, steps, notes, fopdt=None) -> LearnedMode:
    """EM inside the lagged basis from `start` (the outputs' noise floored at the rounding to their
    resolution, `steps`), its poles brought inside the unit circle when EM left any outside, then
    validation on the mode's longest experiment. `notes`: what the data check found, to which the
    scaling of the poles is added."""
    ny = start.ny
    mode, result = basis.fit_em(start, [e.y for e in exps], [e.u for e in exps], max_iter=max_iter, tol=tol,
                                steps=steps[:ny])
    mode, notes = _stable_mode(mode, exps, notes)
    longest = max(exps, key=lambda e: len(e.y))
    return LearnedMode(name, exps, structure, start, result, mode,
                       validate(mode.statespace(longest.u[0]), longest.y, longest.u), fopdt, notes)


def _stable_mode(mode: LaggedMode, exps, notes) -> tuple[LaggedMode, tuple[str, ...]]:
    """The mode with its poles brought inside the unit circle when the fit left any on or outside
    it (`basis.stabilised`), and the notes with a line saying so."""
    radius = float(np.abs(mode.poles()).max())
    if radius < 1:
        return mode, notes
    level = np.nanmean(np.vstack([e.y for e in exps]), axis=0)
    return basis.stabilised(mode, level), notes + (
        f"poles scaled from modulus {radius:.6g} to {basis.MAX_RADIUS:g}: the data drift as if integrating (not "
        "stationary over the recording), which no stable mode reproduces; one-step predictions at the data's mean "
        "level are unchanged",)


def _unresolved(exps, steps, outputs) -> tuple[str, ...]:
    """What a mode's data cannot resolve, a line per group of outputs (`resolution.unresolved`):
    a constant output, one that moves less than rounding, or outputs that move together exactly;
    each says the measurement noise floor that models it (the sd of rounding to the resolution)."""
    lines = []
    for group in unresolved([e.y for e in exps], steps):
        floors = ", ".join(f"{outputs[j]} {np.sqrt(noise_floor(steps[j])):.3g}" for j in group)
        if len(group) > 1:
            what = f"{', '.join(outputs[j] for j in group)} move together exactly (collinear to their resolution)"
        else:
            (j,) = group
            values = np.unique(np.concatenate([e.y[:, j] for e in exps]))
            values = values[np.isfinite(values)]
            what = (f"{outputs[j]} is constant at {values[0]:g} (a stuck sensor or valve)" if len(values) == 1 else
                    f"{outputs[j]} moves no more than rounding to its resolution {steps[j]:.3g}")
        lines.append(f"{what}: measurement noise floored at rounding, sd {floors}")
    return tuple(lines)


def _located(e: Experiment, estimate, *args):
    """estimate(*args), with a DataError naming the experiment's file."""
    try:
        return estimate(*args)
    except DataError as exc:
        raise DataError(f"{e.source}: {exc}") from None


#: How many numbers (poles, gains, fits) a summary lists before it shortens the list.
LISTED = 4


def _listed(values, style=lambda x: f"{x:.4g}") -> str:
    """Up to LISTED values in full, more as the first LISTED and how many there are."""
    shown = ", ".join(style(x) for x in values[:LISTED])
    return shown if len(values) <= LISTED else f"{shown}, ... ({len(values)} in all)"


def default_transitions(K: int, stay: float) -> np.ndarray:
    """`stay p, otherwise uniform`: p on the diagonal, the rest of each row shared evenly, exactly as
    the language reads those words."""
    if K == 1:
        return np.ones((1, 1))
    return np.array([otherwise_uniform(np.where(np.arange(K) == k, stay, np.nan)) for k in range(K)])


def healthy_prior(K: int, p: float) -> np.ndarray:
    """The first mode (the healthy one) with probability p, the rest shared evenly: written back as
    `initial NAME p, otherwise uniform`, so the first rows of a run do not alarm."""
    if K == 1:
        return np.ones(1)
    return np.r_[p, np.full(K - 1, (1 - p) / (K - 1))]


def _stable(ss: StateSpace) -> bool:
    """Whether every pole lies inside the unit circle."""
    return bool(np.abs(ss.poles()).max() < 1)


def assemble(learned: list[LearnedMode], *, P, p0, operating_input=None, **names) -> Model:
    """A Model over the shared lagged basis whose order is the largest of the modes'.

    Each mode starts at its steady state under the operating input (default: its experiments' mean
    input); a mode that is not stable has none and starts where its experiment began. Every output
    lag's initial sd is the widest stationary spread any mode's process noise gives it; an input
    lag's is the widest spread of that input in the experiments. B and D are Cholesky factors of the
    learned Q and R (B has a row per state, zero below the first ny). `names` passes name, dt,
    inputs, outputs, units, ... on to the Model.
    """
    n = max(lm.mode.n for lm in learned)
    ny, nu = learned[0].mode.ny, learned[0].mode.nu
    outputs = names.setdefault("outputs", tuple(f"y{i + 1}" for i in range(ny)))
    inputs = names.setdefault("inputs", tuple(f"u{i + 1}" for i in range(nu)))
    mods, x0, spread = [], [], []
    for lm in learned:
        u_op = lm.inputs.mean(0) if operating_input is None else np.asarray(operating_input, float)
        m = lm.mode.statespace(u_op, n)
        mods.append(m)
        x0.append(m.steady_state(u_op) if _stable(m) else m.mu0)
        with warnings.catch_warnings():
            # near a unit root the Lyapunov system is ill-conditioned; its answer is only a starting spread
            warnings.simplefilter("ignore", LinAlgWarning)
            spread.append(np.diag(solve_discrete_lyapunov(m.A, m.Q)) if _stable(m)
                          else np.r_[np.tile(np.diag(lm.mode.Q), n), np.zeros((n - 1) * nu)])
    spread = np.max(spread, axis=0)
    spread[n * ny:] = np.tile(np.max([lm.inputs.var(0) for lm in learned], axis=0), n - 1)
    B = np.stack([np.vstack([np.linalg.cholesky(m.Q[:ny, :ny]), np.zeros((m.nx - ny, ny))]) for m in mods])
    return Model.from_arrays(
        A=np.stack([m.A for m in mods]), F=np.stack([m.F for m in mods]), f=np.stack([m.f for m in mods]),
        C=np.stack([m.C for m in mods]), G=np.stack([m.G for m in mods]), g=np.stack([m.g for m in mods]),
        B=B, D=np.stack([np.linalg.cholesky(m.R) for m in mods]), P=P, p0=p0, mu0=np.stack(x0),
        Sigma0=np.diag(spread), modes=tuple(lm.name for lm in learned),
        states=basis.state_names(outputs, inputs, n), **names)


def with_catch_all(model: Model, name: str, scale: float, *, stay: float, initial: float,
                   inflation: float = 1.0) -> Model:
    """The bank and one more mode, `name`: the first (healthy) mode with every noise standard
    deviation times `scale`, as `like HEALTHY { noise scale S }` writes it. Anything unlike normal
    operation is more probable under it than under the healthy mode, so with the healthy mode alone
    it makes a detector that no fault mode has to be right for (`run --detect`). `inflation` (at
    least 1) first multiplies the healthy mode's own noise sd: a fit's residuals are smaller on its
    own rows than on rows it has not seen, and the detector's level is set by the latter
    (`detector`). The transitions become `stay STAY, otherwise uniform` and the prior `initial
    HEALTHY INITIAL, otherwise uniform` over the larger bank."""
    if name in model.modes:
        raise JmlgError(f"the catch-all mode {name!r} is already a mode of the bank")
    if not scale > 1:
        raise JmlgError(f"the catch-all's noise scale must be above 1, not {scale}")
    if not inflation >= 1:
        raise JmlgError(f"the healthy mode's noise inflation must be at least 1, not {inflation}")
    healthy = model.modes[0]
    noise = {key: np.concatenate([getattr(model, key)[:1] * inflation, getattr(model, key)[1:]]) for key in "BD"}
    model = model.replace(**noise)
    grown = {key: np.concatenate([getattr(model, key), getattr(model, key)[:1] * factor])
             for key, factor in (("A", 1), ("F", 1), ("f", 1), ("C", 1), ("G", 1), ("g", 1), ("mu0", 1),
                                 ("B", scale), ("D", scale))}
    K = model.K + 1
    return model.replace(**grown, P=default_transitions(K, stay), p0=healthy_prior(K, initial),
                         modes=model.modes + (name,),
                         descriptions={**model.descriptions, name: f"anything unlike {healthy}: its noise x{scale:g}"})
