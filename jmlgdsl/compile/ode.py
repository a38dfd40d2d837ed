"""Nonlinear plants: lower an `ode` block to a bank of linear-Gaussian modes.

The equations become sympy expressions once, with their exact Jacobians, compiled to numpy functions
(an `OdeSystem`). Each mode then only evaluates them with its own parameter values: steady state by
root finding, Jacobian and affine term there, and a zero-order hold through one matrix exponential of
the augmented matrix [[J_x, J_u, c], [0, 0, 0]], which gives A, F and the offset f together.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
import sympy as sp
from scipy.integrate import solve_ivp
from scipy.linalg import expm
from scipy.optimize import root

from ..errors import Diagnostic, SpecError
from ..lang import syntax as S
from ..lang.check import Plant, check
from ..lang.parse import parse_file
from ..lang.evaluate import (NOT_FINITE, EvalError, LetExpander, UnknownName, evaluate_number,
                                finite_real, show, symbolic)
from ..lang.plant import Report
from ..lang.units import time_in_seconds
from ..model import Model
from ..names import suggest
from .assemble import check_size, declared_values, input_shifts, mode_noise, shift_inputs, stack, steady_mean
from .blocks import Layout, ModeArrays

STEADY_TOLERANCE = 1e-8  # largest accepted |der(x)| at a steady state, relative to 1 + |x|
SETTLE_SPAN = 1e6  # how long (in the derivatives' unit) guesses are let settle when root finding fails
# How they settle: scipy's BDF, written in Python. LSODA's Fortran code (in older scipy releases) writes its
# warnings straight to the terminal, and a plant with no steady state to settle to makes dozens of them.
SETTLE_METHOD = "BDF"
RTOL, ATOL = 1e-9, 1e-12  # integration tolerances, far below the noise of any realistic plant
MAX_EVALUATIONS = 10_000  # an integration that needs more has run away (settling takes a few hundred)


@dataclass(frozen=True)
class OdeSystem:
    """A plant's derivatives f(x, u, p) (per `time_unit`) and outputs h(x, u, p) with their exact
    Jacobians: the Jacobians as sympy matrices (to show), all of them as numpy functions of (x, u, p)."""

    states: list[str]
    inputs: list[str]
    outputs: list[str]
    params: list[str]
    time_unit: str
    seconds_per_unit: float
    jacobians: dict  # "f_x", "f_u", "h_x", "h_u" -> sympy Matrix
    numeric: dict  # "f", "f_x", "f_u", "h", "h_x", "h_u" -> function of (x, u, p)

    def derivative(self, x, u, p) -> np.ndarray:
        """dx/dt per `time_unit` at the state x, input u and parameter vector p."""
        return self.numeric["f"](x, u, p).ravel()

    def output(self, x, u, p) -> np.ndarray:
        """Noise-free outputs at the state x, input u and parameter vector p."""
        return self.numeric["h"](x, u, p).ravel()

    def jacobian(self, name: str, x, u, p) -> np.ndarray:
        """A Jacobian ("f_x", "f_u", "h_x", "h_u") as a 2-D array."""
        shape = self.jacobians[name].shape
        return np.asarray(self.numeric[name](x, u, p), dtype=float).reshape(shape)


def lower_ode(plant: Plant, report: Report) -> Model:
    """The Model of a plant whose dynamics are an `ode` block (errors raised as SpecError)."""
    return linearise(plant, ode_system(plant, report), report)


# ------------------------------------------------------------------ building the symbolic system

def ode_system(plant: Plant, report: Report) -> OdeSystem:
    """Turn the ode block and the outputs into sympy expressions and compile them (once per plant)."""
    spec = plant.spec
    states = [d.name.text for d in plant.states]
    inputs = [d.name.text for d in plant.inputs]
    params = [a.name.text for a in plant.params]
    xs, us, ps = ([sp.Symbol(n, real=True) for n in names] for names in (states, inputs, params))
    lookup = _resolver(plant, dict(zip(states, xs)), dict(zip(inputs, us)), dict(zip(params, ps)))
    rates = _derivatives(spec, states, report)
    for d in plant.states:
        if d.name.text not in rates:
            report.error(f"state {d.name.text!r} has no equation: add 'der({d.name.text}) = ...' to the ode block",
                         d.name.pos)
    f = sp.Matrix([_symbolic(rates[s].expr, lookup, report) if s in rates else 0 for s in states])
    h = sp.Matrix([_output_expr(d, lookup, states, xs, report) for d in plant.outputs])
    if not plant.outputs:
        report.error("a plant needs at least one output: 'output STATE' measures a state", S.Pos(1, 1))
    unit, seconds = _derivative_unit(plant, report)
    _check_mode_statements(plant, report)
    report.raise_errors()
    args = [xs, us, ps]
    jacobians = {"f_x": _jacobian(f, xs), "f_u": _jacobian(f, us), "h_x": _jacobian(h, xs), "h_u": _jacobian(h, us)}
    numeric = {name: sp.lambdify(args, expr, modules="numpy", dummify=True)
               for name, expr in {"f": f, "h": h, **jacobians}.items()}
    return OdeSystem(states, inputs, [d.name.text for d in plant.outputs], params, unit, seconds, jacobians, numeric)


def _jacobian(M: sp.Matrix, symbols: list) -> sp.Matrix:
    """d M / d symbols, also when there are no symbols (a plant without inputs)."""
    return M.jacobian(symbols) if symbols else sp.zeros(M.rows, 0)


def _resolver(plant: Plant, xs: dict, us: dict, ps: dict):
    """The name lookup for symbolic(): states, inputs and parameters are symbols, lets are expanded."""
    known = [*xs, *us, *ps, *plant.lets]
    outputs = {d.name.text for d in plant.outputs} - set(xs)
    expand_let = LetExpander(plant.lets)

    def lookup(node: S.Expr):
        name = node.args[0]
        if node.op == "indexed":
            raise EvalError(f"an ODE uses values at the current time: write {name}, not {name}[...]", node)
        for table in (xs, us, ps):
            if name in table:
                return table[name]
        if name in plant.lets:
            return expand_let(node, lambda e: symbolic(e, lookup))
        if name in outputs:
            raise EvalError(f"{name!r} is an output; equations use states, inputs and parameters", node)
        raise UnknownName(f"unknown name {name!r}{suggest(name, known)}", node)

    return lookup


def _symbolic(expr: S.Expr, lookup, report: Report):
    """The sympy form of an equation or output, or NaN with the problem reported at its place."""
    try:
        value = symbolic(expr, lookup)
    except EvalError as exc:
        report.error(str(exc), exc.node.pos)
        return sp.nan
    if not finite_real(value):
        report.error(NOT_FINITE, expr.pos)
        return sp.nan
    return value


def _derivatives(spec: S.Spec, states: list[str], report: Report) -> dict[str, S.Derivative]:
    """der() equations by state; reports der() of a non-state and a state given twice."""
    declared = {d.name.text: d.kind for d in spec.decls} | {a.name.text: "parameter" for a in spec.params} \
        | {a.name.text: "let" for a in spec.lets}
    rates: dict[str, S.Derivative] = {}
    for eq in spec.ode:
        name = eq.state.text
        if name not in states:
            kind = declared.get(name)
            hint = (f"; declare it with 'state {name} = GUESS'" if kind else suggest(name, states)) \
                if kind != "output" else "; an output is measured, der() takes a state"
            report.error(f"der({name}): {name!r} is {f'a {kind}' if kind else 'not declared'}, not a state{hint}",
                         eq.state.pos)
        elif name in rates:
            report.error(f"der({name}) is given twice (first at line {rates[name].state.pos.line})", eq.state.pos)
        else:
            rates[name] = eq
    return rates


def _output_expr(d: S.Decl, lookup, states: list[str], xs: list, report: Report):
    """An output's expression: the state of the same name, or its own `= expr` depending on a state."""
    if d.value is None:
        if d.name.text in states:
            return xs[states.index(d.name.text)]
        report.error(f"output {d.name.text!r} is not a state: measure a state ('output STATE') or give its "
                     f"expression ('output {d.name.text} = ...'){suggest(d.name.text, states)}", d.name.pos)
        return sp.nan
    expr = _symbolic(d.value, lookup, report)
    if expr is not sp.nan and not expr.free_symbols & set(xs):
        report.error(f"output {d.name.text!r} depends on no state, so it measures nothing of the plant; "
                     f"write it in terms of the states ({', '.join(states)})", d.value.pos)
    return expr


def _derivative_unit(plant: Plant, report: Report) -> tuple[str, float]:
    """The time unit of the derivatives (`ode [min]`, else the sample's unit) and its length in seconds."""
    unit, pos = plant.spec.ode_unit or (plant.time_unit, plant.spec.sample[2] if plant.spec.sample else S.Pos())
    return unit, time_in_seconds(1.0, S.Name(unit, pos), report)


def _check_mode_statements(plant: Plant, report: Report):
    """In an ODE plant a mode changes parameters or noise; equations belong to the ode block."""
    for mode in plant.modes:
        for st in mode.statements:
            if st.kind != "noise":
                name = st.target.name.text
                report.error(f"in an ODE plant a mode changes parameters (e.g. 'U = 1.1') or noise; {name!r} "
                             f"is not a parameter{suggest(name, [a.name.text for a in plant.params])}",
                             st.target.name.pos)


# ------------------------------------------------------------------ per-mode linearisation

def linearise(plant: Plant, system: OdeSystem, report: Report, locate_divisors: bool = True) -> Model:
    """Linearise every mode of the plant at its operating point and discretise with a zero-order hold.
    A fit, which re-linearises a checked plant many times, skips locating zero divisors
    (`locate_divisors=False`): the numbers they make are still refused as not finite."""
    params, pvecs = mode_parameters(plant, system, report)
    for mode, env in zip(plant.modes, params) if locate_divisors else ():
        _check_divisors(plant, mode.name, env, report)
    u_bar = declared_values(plant, plant.inputs, report)
    for d in plant.inputs:
        if d.value is None:
            report.error(f"input {d.name.text!r} needs an operating value to linearise around: "
                         f"input {d.name.text} = VALUE", d.name.pos)
    report.raise_errors()
    shifts = mode_input_shifts(plant, params, u_bar, report)
    report.raise_errors()
    points, u_lins, per_mode = _operating_points(plant, system, pvecs, u_bar, shifts, report)
    report.raise_errors()
    layout = Layout(states=list(system.states), inputs=list(system.inputs), outputs=list(system.outputs),
                    input_defaults=u_bar)
    check_size(plant, layout, report)
    dt = plant.dt / system.seconds_per_unit
    modes = []
    for mode, env, p, x_bar, u_lin, shift in zip(plant.modes, params, pvecs, points, u_lins, shifts):
        process, measurement = mode_noise(plant, mode, env, report)
        m = ModeArrays.empty(layout, process, 0.0 if np.isnan(measurement) else measurement)
        f_x, f_u = system.jacobian("f_x", x_bar, u_lin, p), system.jacobian("f_u", x_bar, u_lin, p)
        c = system.derivative(x_bar, u_lin, p) - f_x @ x_bar - f_u @ u_lin
        m.A, m.F, m.f = zoh(f_x, f_u, c, dt)
        m.C, m.G = system.jacobian("h_x", x_bar, u_lin, p), system.jacobian("h_u", x_bar, u_lin, p)
        m.g = system.output(x_bar, u_lin, p) - m.C @ x_bar - m.G @ u_lin
        shift_inputs(m, shift)  # the data's input u acts as u + shift in this mode
        settled = None if per_mode else steady_mean(m, u_bar)
        m.x0 = x_bar if settled is None else settled
        modes.append(m)
    return stack(plant, layout, modes, params, report)


def _check_divisors(plant: Plant, mode: str, env: dict, report: Report):
    """The equations with one mode's parameter values: a divisor that is zero there (`x / a` with
    `a = 0` in the mode) is reported where it is written, as in a linear plant."""
    states, inputs = ({d.name.text: sp.Symbol(d.name.text, real=True) for d in decls}
                      for decls in (plant.states, plant.inputs))
    lookup = _resolver(plant, states, inputs, {name: sp.Float(value) for name, value in env.items()})
    for expr in [eq.expr for eq in plant.spec.ode] + [d.value for d in plant.outputs if d.value is not None]:
        try:
            symbolic(expr, lookup)
        except EvalError as exc:
            report.error(f"{exc} in mode {mode!r}", exc.node.pos)


def mode_parameters(plant: Plant, system: OdeSystem, report: Report) -> tuple[list[dict], np.ndarray]:
    """Each mode's parameter values: by name, and as the vectors p (K, n_params) the functions take."""
    params = [plant.mode_params(m, report) for m in plant.modes]
    return params, np.array([[env[n] for n in system.params] for env in params]).reshape(len(params), -1)


def mode_input_shifts(plant: Plant, params: list[dict], u_bar: np.ndarray, report: Report) -> np.ndarray:
    """(K, n_inputs): how far each mode's own input values are from the declared ones; the equations of
    mode k see the data's input u as u + shifts[k] (a nonlinear simulation must add them too)."""
    return np.array([input_shifts(plant, mode, env, u_bar, report)
                     for mode, env in zip(plant.modes, params)]).reshape(len(plant.modes), len(u_bar))


def zoh(f_x: np.ndarray, f_u: np.ndarray, c: np.ndarray, dt: float):
    """Zero-order hold of dx/dt = f_x x + f_u u + c over dt: (A, F, f) from one matrix exponential."""
    nx, nu = f_u.shape
    M = np.zeros((nx + nu + 1, nx + nu + 1))
    M[:nx, :nx], M[:nx, nx:nx + nu], M[:nx, -1] = f_x, f_u, c
    E = expm(M * dt)
    return E[:nx, :nx], E[:nx, nx:nx + nu], E[:nx, -1]


def _operating_points(plant: Plant, system: OdeSystem, pvecs, u_bar, shifts, report: Report):
    """Where each mode is linearised: (points, input values there, whether each mode has its own
    steady state), per the `linearize` statement (default: the steady state of each mode). A mode's
    inputs are the declared values shifted by the mode's own (`shifts`)."""
    spec = plant.spec
    for extra in spec.linearize[1:]:
        report.error(f"'linearize' is given more than once (first at line {spec.linearize[0].pos.line})", extra.pos)
    how = spec.linearize[0] if spec.linearize else S.Linearize("each", S.Pos())
    K = len(plant.modes)
    if how.kind == "point":
        x, u = _given_point(plant, system, how, u_bar, report)
        return [x] * K, [u] * K, False
    guess = _guesses(plant, report)
    report.raise_errors()
    u_modes = [u_bar + shift for shift in shifts]
    if how.kind == "each":
        return [steady_state(system, guess, u, p, mode.name, mode.pos, report)
                for mode, p, u in zip(plant.modes, pvecs, u_modes)], u_modes, True
    names = [m.name for m in plant.modes]
    if how.mode.text not in names:
        report.error(f"unknown mode {how.mode.text!r}{suggest(how.mode.text, names)}", how.mode.pos)
        return [guess] * K, [u_bar] * K, False
    k = names.index(how.mode.text)
    x = steady_state(system, guess, u_modes[k], pvecs[k], how.mode.text, how.mode.pos, report)
    return [x] * K, [u_modes[k]] * K, False


def _guesses(plant: Plant, report: Report) -> np.ndarray:
    """The declared state values, which an ODE plant uses as starting guesses for its steady states."""
    guess = declared_values(plant, plant.states, report)
    for d in plant.states:
        if d.value is None:
            report.error(f"state {d.name.text!r} needs a guess of its steady state: state {d.name.text} = VALUE",
                         d.name.pos)
    return guess


def _given_point(plant: Plant, system: OdeSystem, how: S.Linearize, u_bar, report: Report):
    """`linearize at x = v, ...`: every state given; inputs default to their operating values."""
    x, u = np.full(len(system.states), np.nan), np.array(u_bar, dtype=float)
    for a in how.point:
        name = a.name.text
        value = evaluate_number(a.expr, plant.nominal, report, what=f"the value of {name}")
        if name in system.states:
            x[system.states.index(name)] = value
        elif name in system.inputs:
            u[system.inputs.index(name)] = value
        else:
            report.error(f"{name!r} is not a state or an input{suggest(name, system.states + system.inputs)}",
                         a.name.pos)
    given = {a.name.text for a in how.point}
    missing = [s for s in system.states if s not in given]
    if missing:
        report.error(f"the operating point needs every state: add {', '.join(f'{s} = ...' for s in missing)}",
                     how.pos)
    return x, u


def steady_state(system: OdeSystem, guess, u, p, mode: str, pos: S.Pos, report: Report) -> np.ndarray:
    """The state where every derivative vanishes, by Powell's hybrid method with the exact Jacobian,
    from the guesses, else from where the plant settles when started at the guesses; a located error
    says the largest residual left when neither converges."""
    x, residual = _root(system, guess, u, p)
    if not _steady(x, residual):
        settled, _ = flow(system, guess, u, p, SETTLE_SPAN, SETTLE_METHOD)
        if settled is not None:
            x_settled, residual_settled = _root(system, settled, u, p)
            if _steady(x_settled, residual_settled):
                return x_settled
        scaled = np.abs(residual) / (1.0 + np.abs(x))
        i = int(np.argmax(np.where(np.isfinite(scaled), scaled, np.inf)))
        s = system.states[i]
        report.error(f"no steady state found for mode {mode!r}: der({s}) is still {residual[i]:.3g} per "
                     f"{system.time_unit} at {s} = {x[i]:.6g}; give better guesses ('state {s} = ...') "
                     f"or linearise at a given point ('linearize at {s} = ...')", pos)
    return x


def _root(system: OdeSystem, start, u, p) -> tuple[np.ndarray, np.ndarray]:
    """Powell's hybrid method on der(x) = 0 from `start`: the last iterate and the derivatives there."""
    with np.errstate(all="ignore"):
        sol = root(lambda x: system.derivative(x, u, p), start, jac=lambda x: system.jacobian("f_x", x, u, p),
                   method="hybr", options={"xtol": 1e-13})
        return sol.x, system.derivative(sol.x, u, p)


def _steady(x: np.ndarray, residual: np.ndarray) -> bool:
    return bool(np.all(np.abs(residual) <= STEADY_TOLERANCE * (1.0 + np.abs(x))))


class _OverBudget(Exception):
    """Raised inside an integration that needs more than MAX_EVALUATIONS evaluations."""


def flow(system: OdeSystem, x, u, p, span: float, method: str = "LSODA") -> tuple[np.ndarray | None, str]:
    """Integrate the equations from x over `span` (in the derivatives' unit) with u held, by scipy's
    `method` (LSODA, the fastest over a simulation's many short spans) with the exact Jacobian:
    (end state, "") or (None, why the integration failed)."""
    calls = itertools.count()

    def rate(_, state):
        if next(calls) > MAX_EVALUATIONS:
            raise _OverBudget
        return system.derivative(state, u, p)

    try:
        with np.errstate(all="ignore"):
            sol = solve_ivp(rate, (0.0, span), x, method=method, jac=lambda _, s: system.jacobian("f_x", s, u, p),
                            rtol=RTOL, atol=ATOL)
    except _OverBudget:
        return None, f"the equations needed more than {MAX_EVALUATIONS} evaluations"
    end = sol.y[:, -1]
    if not sol.success or not np.all(np.isfinite(end)):
        return None, sol.message if not sol.success else "the state left the equations' domain (NaN or inf)"
    return end, ""


# ------------------------------------------------------------------ showing the Jacobian

def jacobian_text(system: OdeSystem) -> str:
    """The symbolic Jacobians the modes are built from, one nonzero entry per line (zeros left out)."""
    per = f"per {system.time_unit}"
    sections = [
        (f"Derivatives ({per}) with respect to the states", "f_x", [f"der({s})" for s in system.states],
         system.states),
        (f"Derivatives ({per}) with respect to the inputs", "f_u", [f"der({s})" for s in system.states],
         system.inputs),
        ("Outputs with respect to the states", "h_x", system.outputs, system.states),
        ("Outputs with respect to the inputs", "h_u", system.outputs, system.inputs),
    ]
    lines = []
    for title, key, rows, cols in filter(lambda section: section[3], sections):
        J = system.jacobians[key]
        entries = [(f"d {rows[i]} / d {cols[j]}", show(J[i, j])) for i in range(J.rows) for j in range(J.cols)
                   if J[i, j] != 0]
        lines.append(f"{title}:")
        width = max((len(left) for left, _ in entries), default=0)
        lines += [f"  {left.ljust(width)} = {right}" for left, right in entries] or ["  (all zero)"]
    return "\n".join(lines)


def jacobian_report(path) -> str:
    """`jmlgdsl compile SPEC --show-jacobian`: the Jacobian text of the ODE plant in a spec file."""
    plant, report = check_ode_file(path, "--show-jacobian")
    return jacobian_text(ode_system(plant, report))


def check_ode_file(path, purpose: str) -> tuple[Plant, Report]:
    """Parse and check a spec file that must describe an ODE plant (SpecError otherwise)."""
    plant, report = check(parse_file(path))
    report.raise_errors()
    if not plant.spec.ode:
        raise SpecError([Diagnostic(f"{purpose} needs a nonlinear plant, and this spec has no 'ode' block",
                                    str(path))])
    return plant, report
