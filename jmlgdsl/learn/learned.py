"""From experiment files to a learned mode bank and its spec: what `jmlgdsl learn` does, as a library.

`learn` reads each mode's experiments (a whole file, or the rows its `mode` column labels with the
mode), takes names, units, sample time, transitions and prior from a template Model or from plain
options (the first mode the healthy one), fits every mode (`bank.learn_modes`), assembles the Model
and writes it as commented .jmlg text. The `LearnedBank` it returns reports on every mode, writes
the spec whole or not at all, and draws each mode's figures.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..data import Columns, read_csv
from ..errors import DataError, JmlgError
from ..model import Model
from ..names import plural
from ..output import writing
from . import validate
from .bank import (AUTO, Experiment, LearnedMode, assemble, default_transitions, healthy_prior, learn_modes,
                   with_catch_all)
from .detector import choose_detector
from .relative import Reference
from .resolution import RELATIVE, resolution
from .writer import write_spec


@dataclass(frozen=True)
class LearnedBank:
    """A learned bank: every mode as learned (structure, EM run, validation), in the bank's order,
    the assembled Model and its spec text."""

    learned: tuple[LearnedMode, ...]
    model: Model
    text: str

    def report(self) -> str:
        """One line per mode: structure, EM, poles, gain, noise, fit and the residual tests (the
        spec's comments say the same)."""
        return "\n".join(lm.summary(self.model.outputs) for lm in self.learned)

    def write(self, path) -> None:
        """Write the spec to `path` ('-': standard output), whole or not at all."""
        with writing(path) as stream:
            stream.write(self.text)

    def write_figures(self, folder) -> list[Path]:
        """Draw each mode's validation figure, and its step-test fit when it has one, into `folder`
        (made when missing); returns the paths written."""
        from . import figures  # matplotlib is loaded only when figures are asked for

        out = Path(folder)
        out.mkdir(parents=True, exist_ok=True)
        ylabel, xname = self.model.outputs[0], (self.model.inputs or ("input",))[0]
        paths = []
        for lm in self.learned:
            paths.append(figures.plot_validation(lm, out / f"validation_{lm.name}.png", self.model.dt, ylabel, xname))
            if lm.fopdt is not None:
                paths.append(figures.plot_step(lm.fopdt, lm.experiment.y, out / f"step_{lm.name}.png",
                                               f"Step test, mode {lm.name}", ylabel))
        return paths


def learn(experiments: dict, template: Model | None = None, *, outputs=(), inputs=(), dt: float = 1.0,
          name: str = "plant", stay: float = 0.99, initial: float = 0.99, order="auto", fopdt: bool = False,
          criterion: str = "bic", max_order: int = 4, max_delay: int = 0, max_iter: int = 100, tol: float = 1e-5,
          relative_to: str | None = AUTO, catch_all=AUTO, progress=None) -> LearnedBank:
    """Learn a mode bank from experiments of every mode (docs/learning.md).

    experiments: {mode: source or [source, ...]}. A source is a CSV path, read by the bank's column
    names (when the file has a `mode` column, only the rows labelled with the mode count, each
    unbroken stretch of them a run), or an `Experiment` (arrays). A mode's runs are pooled in one fit.

    template: a Model (`jmlgdsl.load(SPEC)`) that gives names, units, sample time, input defaults, mode
    descriptions, transitions and prior; it must have exactly the experiments' modes, and its order
    wins. Without one, `outputs` and `inputs` name the columns (a name or a list of them), `dt` is the
    sample time and `name` the plant's; the transitions are `stay STAY, otherwise uniform`, and the
    first mode is the healthy one: the prior is `initial FIRST INITIAL, otherwise uniform`.

    Structure: `order` "auto" (EM fits of orders 1 up to the ARX order that `criterion`, "bic" or
    "aic", picks over na, nb <= max_order and nk <= max_delay, the best kept mode by mode), N for
    ARX(N, N, 0), or (na, nb, nk), either also as text ("2", "2,2,1"); `fopdt`: each mode's one
    experiment is a step test. EM stops after `max_iter` iterations or when the log-likelihood gains
    less than `tol` relative. `progress(text)`, when given, hears of each mode as it is learned.

    `relative_to`: a mode (the normal one) whose dynamics and covariance every other mode is learned
    relative to, with its own offset and scale and changes shrunk as cross-validation on its own
    rows says (`relative`): for short fault recordings over many sensors. "auto" (the default): the
    first mode, when cross-validation says relative learning beats each mode's own regression
    (`bank.learn_modes`); None: every mode on its own.

    `catch_all` = (NAME, SCALE): one more mode, the first mode with its noise times SCALE
    (`bank.with_catch_all`), with which the first mode alone detects anything unlike it; `run`
    then detects with the two and names the fault with the others. SCALE None: the scale chosen by
    cross-validation together with an inflation of the first mode's own noise: of the pairs that
    stay quiet on the first mode's rows held out, the one that detects the most of the other
    modes' rows (without other modes, the smallest quiet scale; `detector.choose_detector`). "auto" (the
    default): ("anomaly", None) for a bank of a healthy mode and fault modes learned without a
    template, none otherwise; None: none. Not with a template, whose transitions and prior have no
    place for it.
    """
    arx_order = _arx_order(order)
    if catch_all == AUTO:
        catch_all = (CATCH_ALL, None) if template is None and len(experiments) > 1 else None
    if catch_all is not None and template is not None:
        raise JmlgError("catch_all takes no template: the template's transitions and prior have no place for it")
    if catch_all is not None and catch_all[0] in experiments:
        raise JmlgError(f"the catch-all mode {catch_all[0]!r} is already a mode of the bank; name it otherwise")
    for option, value, least in (("max_order", max_order, 1), ("max_delay", max_delay, 0),
                                 ("max_iter", max_iter, 0)):
        if value < least:
            raise JmlgError(f"{option} must be at least {least}, not {value}")
    if not (math.isfinite(dt) and dt > 0):
        raise JmlgError(f"dt must be a positive number of seconds, not {dt}")
    sources = {mode: list(given) if isinstance(given, (list, tuple)) else [given]
               for mode, given in experiments.items()}
    frame, modes = _frame(template, tuple(sources), _names(outputs), _names(inputs), dt, name, stay, initial)
    columns = Columns(outputs=frame["outputs"], inputs=frame["inputs"], input_defaults=frame["input_defaults"],
                      modes=modes, dt=frame["dt"])
    by_mode = {mode: [e for source in sources[mode] for e in _experiments(source, columns, mode, k)]
               for k, mode in enumerate(modes)}
    learned = learn_modes(by_mode, arx_order, fopdt, frame["dt"], max_order, max_delay, criterion, max_iter, tol,
                          progress, frame["outputs"], relative_to, float(np.mean(np.diag(frame["P"]))))
    defaults = frame["input_defaults"]
    model = assemble(learned, operating_input=defaults if np.isfinite(defaults).all() else None, **frame)
    chosen = None
    if catch_all is not None:
        name_, scale = catch_all
        inflation = 1.0
        if scale is None:
            chosen = _detector(model, learned[0], by_mode, name_, stay, initial)
            scale, inflation = chosen.scale, chosen.inflation
            if progress is not None:
                progress(chosen.describe(modes[0]))
        catch_all = name_, scale
        model = with_catch_all(model, name_, scale, stay=stay, initial=initial, inflation=inflation)
    origins = dict.fromkeys(s.source if isinstance(s, Experiment) else str(s) for given in sources.values()
                            for s in given)
    reference = next((lm for lm in learned if lm.relative is None), None)
    if any(lm.relative is not None for lm in learned):
        how = (f"{reference.name} by least squares, {reference.structure.split(' least')[0]}; the other modes "
               f"relative to it (cross-validated shrinkage toward its dynamics and noise)")
    else:
        how = ("FOPDT fits of step tests" if fopdt else
               f"states chosen by {criterion.upper()} of the EM fits, started from ARX" if arx_order == "auto"
               else f"ARX order {_written(order)}")
    if catch_all is not None:
        how += f"; catch-all mode {catch_all[0]}: {model.modes[0]} with its noise x{catch_all[1]:g}"
        if chosen is not None:
            how += f", the {chosen.describe(model.modes[0])}"
    return LearnedBank(tuple(learned), model,
                       write_spec(model, _header(origins, how, max_iter, tol, learned, model.outputs)))


#: The name of the catch-all mode `learn` adds by default.
CATCH_ALL = "anomaly"


def _detector(model: Model, healthy: LearnedMode, by_mode: dict, name: str, stay, initial):
    """The catch-all's scale and the healthy mode's noise inflation chosen on the healthy mode's
    runs held out and the other modes' runs (`detector.choose_detector`), with the transitions and
    prior of the detector `run` splits from the bank with it; each output's resolution read from
    every mode's runs, as learning read it."""
    from ..diagnosis.alarms import sub_bank

    runs = by_mode[healthy.name]
    ys, us = [e.y for e in runs], [e.u for e in runs]
    trial = with_catch_all(model, name, 2.0, stay=stay, initial=initial)
    detector = sub_bank(trial, (model.modes[0], name))
    everything = [e for exps in by_mode.values() for e in exps]
    steps = resolution(np.vstack([np.hstack([e.y, e.u]) for e in everything]))[:model.ny]
    reference = Reference.of(ys, us, healthy.mode.lags, steps)
    faults = [([e.y for e in runs], [e.u for e in runs]) for mode, runs in by_mode.items() if mode != healthy.name]
    return choose_detector(reference, ys, us, faults, detector.P, detector.p0)


def experiments_of(data, mode: str, index: int) -> list[Experiment]:
    """The Experiments of one mode in a data file read by the bank's columns: the whole file, or,
    when it has a `mode` column, each unbroken stretch of rows labelled with that mode (`index`)."""
    if data.modes is None:
        return [Experiment(data.y, data.u, data.source)]
    rows = np.flatnonzero(data.modes == index)
    if not len(rows):
        raise DataError(f"{data.source}: no rows of mode {mode!r} in its 'mode' column")
    stretches = np.split(rows, np.flatnonzero(np.diff(rows) > 1) + 1)
    return [Experiment(data.y[r], data.u[r], f"{data.source} (rows of {mode}, {r[0] + 1}-{r[-1] + 1})")
            for r in stretches]


def mode_files(items) -> dict[str, list[str]]:
    """The experiments' files by mode, {name: [path, ...]} with the modes in the order first given, from
    NAME=CSV texts as `jmlgdsl learn --mode` takes them; a JmlgError for any other text."""
    modes = {}
    for item in items:
        name, sep, path = item.partition("=")
        if not (sep and name.isidentifier() and path):
            raise JmlgError(f"--mode takes NAME=CSV, not {item!r}")
        modes.setdefault(name, []).append(path)
    return modes


def _experiments(source, columns: Columns, mode: str, index: int) -> list[Experiment]:
    """One source's experiments of a mode: an Experiment as it is, a CSV file as `experiments_of` reads it."""
    if isinstance(source, Experiment):
        return [source]
    return experiments_of(read_csv(source, columns), mode, index)


def _names(given) -> tuple[str, ...]:
    """Column names from one name or a list of them."""
    return (given,) if isinstance(given, str) else tuple(given)


def _arx_order(order):
    """The order as `learn_modes` takes it: "auto", or (na, nb, nk) from N (na = nb = N, nk = 0),
    from (na, nb, nk), or from either written as text ("2", "2,2,1")."""
    if order == "auto":
        return "auto"
    items = order.split(",") if isinstance(order, str) else order if isinstance(order, (tuple, list)) else [order]
    try:
        parts = [int(v) for v in items]
    except (TypeError, ValueError):
        parts = []
    if len(parts) == 1 and parts[0] >= 1:
        return parts[0], parts[0], 0
    if len(parts) == 3 and parts[0] >= 1 and parts[1] >= 1 and parts[2] >= 0:
        return tuple(parts)
    raise JmlgError(f"order must be auto, N or NA,NB,NK (na, nb >= 1, nk >= 0), not {order!r}")


def _written(order) -> str:
    """An order as it was given: text as it is, N or NA,NB,NK otherwise."""
    return ",".join(map(str, order)) if isinstance(order, (tuple, list)) else str(order)


def _frame(template: Model | None, modes: tuple, outputs: tuple, inputs: tuple, dt, name, stay, initial):
    """(the Model's fields other than the matrices, the modes in the bank's order), from the
    template or from the options."""
    if template is not None:
        if set(modes) != set(template.modes):
            raise JmlgError(f"the template's plant {template.name} has modes {', '.join(template.modes)}; give one "
                            f"experiment for each (got {', '.join(modes)})")
        return dict(name=template.name, dt=template.dt, inputs=template.inputs, outputs=template.outputs,
                    engineering_units=template.engineering_units, input_defaults=template.input_defaults,
                    descriptions=template.descriptions, P=template.P, p0=template.p0), template.modes
    if not outputs:
        raise JmlgError("name the outputs (the output columns), or give a template")
    for option, value in (("stay", stay), ("initial", initial)):
        if not 0 <= value <= 1:
            raise JmlgError(f"{option} must be a probability, not {value}")
    K = len(modes)
    return dict(name=name, dt=dt, inputs=inputs, outputs=outputs, engineering_units={},
                input_defaults=np.full(len(inputs), np.nan), descriptions={}, P=default_transitions(K, stay),
                p0=healthy_prior(K, initial)), modes


def _header(origins, how: str, max_iter: int, tol: float, learned, outputs) -> str:
    """The comment block at the top of the written spec: where it came from and how well it fits."""
    lines = [f"Learned by jmlgdsl learn from {', '.join(origins)}",
             f"Structure: {how}; EM up to {plural(max_iter, 'iteration')}, relative tolerance {tol:g}.",
             "Every mode shares one state basis: the noise-free outputs of the last steps (NAME_lag1, ...)",
             "and the inputs before this step (NAME_lag1, ...); a mode's coefficients and offset are its",
             "first rows. B, D are Cholesky factors of the learned process and measurement noise",
             "covariances. Each mode starts at its steady state under the operating input (a mode that is",
             "not stable, where its experiment began).",
             "Both noise covariances are kept at least the rounding variance r^2/12 of each sensor's resolution",
             f"r (the smallest step between its recorded values, at least {RELATIVE:g} of its spread); a mode's",
             "lines below name the sensors where that floor models what its data cannot resolve.",
             f"Validation: residual autocorrelation (lags 1-{validate.MAX_LAG}) and input-residual "
             f"cross-correlation (lags 0-{validate.MAX_LAG}) pass when at most {validate.ALLOWED_OUTSIDE} "
             "lag of each lies outside the 99 % band.",
             ""] + [lm.summary(outputs) for lm in learned]
    return "\n".join(lines)
