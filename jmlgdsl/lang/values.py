"""The second stage of checking a spec: every mode's values, evaluated from the checked declarations
(lang.declarations) into a Plant (lang.plant): its parameters, noise, own input values and statements
as numbers and arrays, with the internal states its blocks add (lang.statements); or an ODE plant's
equations as sympy expressions (lang.equations), each mode's parameters and where to linearise.
Every problem is reported with its position; the compiler (jmlgdsl.compile) lowers the values."""

from __future__ import annotations

import numpy as np

from ..model import DEFAULT_GATE
from ..names import suggest
from . import syntax as S
from .declarations import Declared, ModeInfo, noise_values
from .equations import check_divisors, equations, given_point
from .evaluate import evaluate_number
from .limits import MAX_STACKED, MAX_VARIABLES, check_sd
from .plant import Equations, Layout, Linearization, Mode, Plant
from .diagnostics import Report
from .statements import Statements


def evaluate(d: Declared, report: Report, ode: Equations | None = None) -> Plant:
    """Evaluate every mode's values into a Plant, in stages: SpecError with every error of the first
    stage that has any (a later stage would mostly report its consequences). The errors of the last
    stage, in the values the compiler applies last (initial means and spreads, outlier gates, an ODE
    plant's mode noise), are held back in the report (Report.holding) for the compiler to release where
    it applies them. `ode`: an ODE plant's equations from an earlier check of the same spec, as a fit
    passes at each new value of the unknowns (the equations do not depend on them): they are not built
    again, nor are zero divisors located mode by mode (the numbers those make are still refused as not
    finite)."""
    layout, modes, initial, ode, linearize = _ode_values(d, ode, report) if d.spec.ode else _linear_values(d, report)
    with report.holding():
        sd0 = initial_sd(d, layout, report)
        gates = outlier_gates(d, layout.outputs, report)
    engineering_units = {decl.name.text: decl.unit for decl in [*d.inputs, *d.outputs, *d.states] if decl.unit}
    return Plant(d.name, d.dt, layout, modes, d.P, d.p0, initial, sd0, gates, engineering_units, d.unknowns, ode,
                 linearize)


# ------------------------------------------------------------------ a plant without ODEs

def _linear_values(d: Declared, report: Report):
    """(layout, modes, initial means, None, None) of a plant written with statements, matrices and
    blocks: the modes' parameters, the declared inputs and the blocks' internal states; then each mode's
    noise, statements and input values; then the declared initial means (their errors held back)."""
    for how in d.spec.linearize:
        report.error("'linearize' applies to nonlinear plants: this spec has no 'ode' block", how.pos)
    params = [d.mode_params(m, report) for m in d.modes]
    layout = Layout(states=[s.name.text for s in d.states], inputs=[u.name.text for u in d.inputs],
                    outputs=[y.name.text for y in d.outputs],
                    input_defaults=declared_values(d.inputs, d.nominal, report))
    declared = {s.name.text: s.name for s in d.states}
    for mode, env in zip(d.modes, params):
        Statements(layout, env, d.lets, report, d.dt, d.time_unit).reserve_block_states(mode.statements, declared)
    check_size(len(d.modes), layout, d.modes[0].pos if d.modes else None, report)
    if not layout.outputs:
        report.error("a plant needs at least one output: declare it with 'output NAME'", S.Pos(1, 1))
    if not layout.states and not report.error_count:  # a block with an error reserves no states
        report.error("a plant needs at least one state: declare it with 'state NAME' (or give an output a "
                     "fopdt or arx block)", S.Pos(1, 1))
    report.raise_errors()
    modes = []
    for mode, env in zip(d.modes, params):
        process, measurement, scale = mode_noise(d, mode, env, report)
        statements, states, outputs = Statements(layout, env, d.lets, report, d.dt, d.time_unit).evaluate(
            mode.statements)
        shift = input_shifts(d, mode, env, layout.input_defaults, report)
        for s in layout.states:
            if s not in states:
                report.error(f"state {s!r} has no equation in mode {mode.name!r} "
                             f"(write {s}[t] ~ Normal(...) or a matrix A)", mode.pos)
        for y in layout.outputs:
            if y not in outputs:
                report.error(f"output {y!r} has no equation in mode {mode.name!r} "
                             f"(write {y} ~ Normal(...), a block such as fopdt, or a matrix C)", mode.pos)
        modes.append(Mode(mode.name, mode.description, mode.pos, env, process, measurement, scale, shift, statements))
    report.raise_errors()
    with report.holding():
        means = dict(zip((s.name.text for s in d.states), declared_values(d.states, d.nominal, report)))
    return layout, modes, np.array([means.get(s, np.nan) for s in layout.states]), None, None


# ------------------------------------------------------------------ an ODE plant

def _ode_values(d: Declared, ode: Equations | None, report: Report):
    """(layout, modes, steady-state guesses, equations, where to linearise) of an ODE plant: its
    equations (unless `ode` gives them); the modes' parameters, with the divisors that are zero in a
    mode, and the inputs' operating values; the modes' own input values; where to linearise; then the
    modes' noise (its errors held back)."""
    locate_divisors = ode is None
    if ode is None:
        ode = ode_equations(d, report)
    params = [d.mode_params(m, report) for m in d.modes]
    for mode, env in zip(d.modes, params) if locate_divisors else ():
        check_divisors(d.spec, d.lets, mode.name, env, report)
    u_bar = declared_values(d.inputs, d.nominal, report)
    for u in d.inputs:
        if u.value is None:
            report.error(f"input {u.name.text!r} needs an operating value to linearise around: "
                         f"input {u.name.text} = VALUE", u.name.pos)
    report.raise_errors()
    shifts = [input_shifts(d, mode, env, u_bar, report) for mode, env in zip(d.modes, params)]
    report.raise_errors()
    linearize, guesses = _linearize(d, ode, u_bar, report)
    report.raise_errors()
    layout = Layout(states=list(ode.states), inputs=list(ode.inputs), outputs=list(ode.outputs), input_defaults=u_bar)
    check_size(len(d.modes), layout, d.modes[0].pos if d.modes else None, report)
    with report.holding():
        modes = [Mode(mode.name, mode.description, mode.pos, env, *mode_noise(d, mode, env, report), shift)
                 for mode, env, shift in zip(d.modes, params, shifts)]
    return layout, modes, guesses, ode, linearize


def ode_equations(d: Declared, report: Report) -> Equations:
    """An ODE plant's equations (SpecError with every problem found in them, or in a mode that does more
    than change parameters or noise)."""
    ode = equations(d.spec, d.lets, d.time_unit, report)
    _check_mode_statements(d, report)
    report.raise_errors()
    return ode


def _check_mode_statements(d: Declared, report: Report):
    """In an ODE plant a mode changes parameters or noise; equations belong to the ode block."""
    for mode in d.modes:
        for st in mode.statements:
            if st.kind != "noise":
                name = st.target.name.text
                report.error(f"in an ODE plant a mode changes parameters (e.g. 'U = 1.1') or noise; {name!r} "
                             f"is not a parameter{suggest(name, [a.name.text for a in d.spec.params])}",
                             st.target.name.pos)


def _linearize(d: Declared, ode: Equations, u_bar: np.ndarray, report: Report) -> tuple[Linearization, np.ndarray]:
    """Where the modes are linearised, per the `linearize` statement (default: the steady state of each
    mode), and the declared state values that start the search for steady states (NaN at a given point,
    which needs none)."""
    spec = d.spec
    for extra in spec.linearize[1:]:
        report.error(f"'linearize' is given more than once (first at line {spec.linearize[0].pos.line})", extra.pos)
    how = spec.linearize[0] if spec.linearize else S.LinearizeAt("each", S.Pos())
    if how.kind == "point":
        x, u = given_point(how, ode.states, ode.inputs, u_bar, d.nominal, report)
        return Linearization("point", x=x, u=u), np.full(len(ode.states), np.nan)
    guesses = declared_values(d.states, d.nominal, report)
    for s in d.states:
        if s.value is None:
            report.error(f"state {s.name.text!r} needs a guess of its steady state: state {s.name.text} = VALUE",
                         s.name.pos)
    report.raise_errors()
    if how.kind == "each":
        return Linearization("each"), guesses
    names = [m.name for m in d.modes]
    if how.mode.text not in names:
        report.error(f"unknown mode {how.mode.text!r}{suggest(how.mode.text, names)}", how.mode.pos)
        return Linearization("mode", pos=how.mode.pos), guesses
    return Linearization("mode", names.index(how.mode.text), how.mode.pos), guesses


# ------------------------------------------------------------------ values of both kinds of plant

def declared_values(decls: list[S.Decl], nominal: dict, report: Report) -> np.ndarray:
    """Values written in declarations (input defaults, state initial means or guesses), evaluated with
    the nominal parameters: they belong to the plant, not to one mode. NaN where none is written."""
    return np.array([np.nan if d.value is None else
                     evaluate_number(d.value, nominal, report, what=f"the value of {d.name.text}")
                     for d in decls], dtype=float)


def mode_noise(d: Declared, mode: ModeInfo, params: dict, report: Report) -> tuple[float, float, float | None]:
    """(process, measurement, scale) of a mode: the plant's noise standard deviations with the mode's own
    `noise` lines over them (measurement NaN when neither gives one), and its `noise scale` (None)."""
    own = noise_values([st.noise for st in mode.statements if st.kind == "noise"], params, report, plant_level=False)
    values = {**d.noise, **own}
    return values.get("process", 0.0), values.get("measurement", np.nan), own.get("scale")


def input_shifts(d: Declared, mode: ModeInfo, params: dict, declared: np.ndarray, report: Report) -> np.ndarray:
    """Per input, the mode's own operating value (`supply = 200` in the mode) less the declared one, with
    the mode's parameters; 0 where the mode sets none. An input without a declared value is an error."""
    names = [u.name.text for u in d.inputs]
    shift = np.zeros(len(names))
    for a in mode.inputs:
        i = names.index(a.name.text)
        value = evaluate_number(a.expr, params, report, what=f"the value of {a.name.text} in mode {mode.name!r}")
        if d.inputs[i].value is None:
            report.error(f"mode {mode.name!r} sets input {a.name.text!r}, which has no declared value to differ from: "
                         f"declare it as 'input {a.name.text} = VALUE'", a.name.pos)
        elif np.isfinite(value - declared[i]):  # either NaN: not evaluated, reported
            shift[i] = value - declared[i]
    return shift


def check_size(modes: int, layout: Layout, where: S.Pos | None, report: Report):
    """Raise, before any array is made, when the compiled plant would be too large: at most
    MAX_VARIABLES states (declared and block-internal) and MAX_STACKED numbers in one stacked matrix."""
    n = max(layout.nx, len(layout.outputs))
    if layout.nx > MAX_VARIABLES:
        report.error(f"the plant has {layout.nx:,} states with the blocks' internal ones, at most "
                     f"{MAX_VARIABLES:,} are allowed", where)
    elif modes * n * n > MAX_STACKED:
        report.error(f"the plant is too large: {modes:,} modes of {n:,} x {n:,} matrices make {modes * n * n:,} "
                     f"numbers per stacked matrix, at most {MAX_STACKED:,} are allowed", where)
    report.raise_errors()


def initial_sd(d: Declared, layout: Layout, report: Report) -> np.ndarray:
    """The initial standard deviation of each state: a state's `sd`, and an output's `sd` for the states
    of its blocks that hold output values (the output and its past values; input registers and a fopdt
    block's per-input parts keep 0)."""
    sd0 = np.zeros(layout.nx)
    for decl in [*d.states, *d.outputs]:
        if decl.sd is None:
            continue
        sd = evaluate_number(decl.sd, d.nominal, report, what=f"the initial sd of {decl.name.text}")
        if sd < 0:
            report.error("a standard deviation cannot be negative", decl.sd.pos)
        check_sd(sd, decl.sd.pos, report)
        held = [decl.name.text] if decl.kind == "state" else \
            [s for s in layout.block_states.get(decl.name.text, ()) if layout.block_roles[s][1] == "history"]
        if not held:
            report.error(f"an output's 'sd' is the initial standard deviation of its fopdt or arx block, and no mode "
                         f"gives {decl.name.text!r} one; a state takes its own: 'state NAME = MEAN sd SD'", decl.sd.pos)
        for s in held:
            sd0[layout.states.index(s)] = sd
    return sd0


def outlier_gates(d: Declared, outputs: list[str], report: Report) -> np.ndarray:
    """Each output's gross-error gate in standard deviations (inf: `outliers off`); the model's
    default where the declaration says nothing."""
    gates = np.full(len(outputs), DEFAULT_GATE)
    for decl in d.outputs:
        if decl.gate is None or decl.name.text not in outputs:
            continue
        i = outputs.index(decl.name.text)
        if decl.gate == "off":
            gates[i] = np.inf
            continue
        gates[i] = evaluate_number(decl.gate, d.nominal, report, what=f"the outlier gate of {decl.name.text}")
        if gates[i] <= 0:  # NaN: not evaluated, reported
            report.error(f"an outlier gate is a positive number of standard deviations (or 'off'); got {gates[i]:g}",
                         decl.gate.pos)
    return gates
