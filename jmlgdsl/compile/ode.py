"""Nonlinear plants: lower an `ode` block to a bank of linear-Gaussian modes.

The checker gives the equations as sympy expressions (lang.plant.Equations); they get their exact
Jacobians once, all compiled to numpy functions (an `OdeSystem`). Each mode then only evaluates them
with its own parameter values: steady state by root finding, Jacobian and affine term there, and a
zero-order hold through one matrix exponential of the augmented matrix [[J_x, J_u, c], [0, 0, 0]],
which gives A, F and the offset f together.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
import sympy as sp
from scipy.integrate import solve_ivp
from scipy.linalg import expm
from scipy.optimize import root

from ..lang.check import check_ode_file
from ..lang.plant import Plant, show
from ..lang.diagnostics import Pos, Report
from ..model import Model
from .assemble import shift_inputs, stack, steady_mean
from .blocks import ModeArrays

STEADY_TOLERANCE = 1e-8  # largest accepted |der(x)| at a steady state, relative to 1 + |x|
SETTLE_SPAN = 1e6  # how long (in the derivatives' unit) guesses are let settle when root finding fails
# How they settle: scipy's BDF, written in Python. LSODA's Fortran code (in older scipy releases) writes its
# warnings straight to the terminal, and a plant with no steady state to settle to makes dozens of them.
SETTLE_METHOD = "BDF"
RTOL, ATOL = 1e-9, 1e-12  # integration tolerances, far below the noise of any realistic plant
# Settling only brings the root search near the steady state, which then finds it to its own precision:
# integrated to RTOL it took a thousand times the root search, most of a fit of a nonlinear plant.
SETTLE_RTOL, SETTLE_ATOL = 1e-4, 1e-8
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
    return linearise(plant, ode_system(plant), report)


# ------------------------------------------------------------------ building the symbolic system

def ode_system(plant: Plant) -> OdeSystem:
    """Differentiate the checked equations and compile them to numpy functions (once per plant; the
    checker has reported every problem of the equations)."""
    eq = plant.equations
    args = list(eq.symbols)
    jacobians = {"f_x": _jacobian(eq.f, args[0]), "f_u": _jacobian(eq.f, args[1]), "h_x": _jacobian(eq.h, args[0]),
                 "h_u": _jacobian(eq.h, args[1])}
    numeric = {name: sp.lambdify(args, expr, modules="numpy", dummify=True)
               for name, expr in {"f": eq.f, "h": eq.h, **jacobians}.items()}
    return OdeSystem(eq.states, eq.inputs, eq.outputs, eq.params, eq.time_unit, eq.seconds_per_unit, jacobians,
                     numeric)


def _jacobian(M: sp.Matrix, symbols: list) -> sp.Matrix:
    """d M / d symbols, also when there are no symbols (a plant without inputs)."""
    return M.jacobian(symbols) if symbols else sp.zeros(M.rows, 0)


# ------------------------------------------------------------------ per-mode linearisation

def linearise(plant: Plant, system: OdeSystem, report: Report, guesses=None) -> Model:
    """Linearise every mode of the plant at its operating point and discretise with a zero-order hold.
    `guesses`: each mode's steady state at other values of the parameters (`steady_states`), tried
    first where the root is searched for (a fit builds the plant at many values near each other)."""
    _, pvecs = mode_parameters(plant, system)
    u_bar = plant.layout.input_defaults
    points, u_lins, per_mode = _operating_points(plant, system, pvecs, report, guesses)
    report.raise_errors()
    dt = plant.dt / system.seconds_per_unit
    modes = []
    for mode, p, x_bar, u_lin in zip(plant.modes, pvecs, points, u_lins):
        m = ModeArrays.empty(plant.layout, mode.process, 0.0 if np.isnan(mode.measurement) else mode.measurement)
        f_x, f_u = system.jacobian("f_x", x_bar, u_lin, p), system.jacobian("f_u", x_bar, u_lin, p)
        c = system.derivative(x_bar, u_lin, p) - f_x @ x_bar - f_u @ u_lin
        m.A, m.F, m.f = zoh(f_x, f_u, c, dt)
        m.C, m.G = system.jacobian("h_x", x_bar, u_lin, p), system.jacobian("h_u", x_bar, u_lin, p)
        m.g = system.output(x_bar, u_lin, p) - m.C @ x_bar - m.G @ u_lin
        shift_inputs(m, mode.shift)  # the data's input u acts as u + shift in this mode
        settled = None if per_mode else steady_mean(m, u_bar)
        m.x0 = x_bar if settled is None else settled
        modes.append(m)
    return stack(plant, modes, report)


def mode_parameters(plant: Plant, system: OdeSystem) -> tuple[list[dict], np.ndarray]:
    """Each mode's parameter values (the checker's): by name, and as the vectors p (K, n_params) the
    functions take."""
    params = [mode.params for mode in plant.modes]
    return params, np.array([[env[n] for n in system.params] for env in params]).reshape(len(params), -1)


def mode_input_shifts(plant: Plant) -> np.ndarray:
    """(K, n_inputs): how far each mode's own input values are from the declared ones (the checker's);
    the equations of mode k see the data's input u as u + shifts[k] (a nonlinear simulation must add
    them too)."""
    return np.array([mode.shift for mode in plant.modes]).reshape(len(plant.modes), len(plant.layout.inputs))


def zoh(f_x: np.ndarray, f_u: np.ndarray, c: np.ndarray, dt: float):
    """Zero-order hold of dx/dt = f_x x + f_u u + c over dt: (A, F, f) from one matrix exponential."""
    nx, nu = f_u.shape
    M = np.zeros((nx + nu + 1, nx + nu + 1))
    M[:nx, :nx], M[:nx, nx:nx + nu], M[:nx, -1] = f_x, f_u, c
    E = expm(M * dt)
    return E[:nx, :nx], E[:nx, nx:nx + nu], E[:nx, -1]


def steady_states(plant: Plant, system: OdeSystem, report: Report) -> list[np.ndarray] | None:
    """Each mode's operating point where it is a steady state (`linearize` of each mode, the default),
    as `linearise`'s guesses at other values of the parameters; None where the plant is linearised
    elsewhere."""
    _, pvecs = mode_parameters(plant, system)
    points, _, per_mode = _operating_points(plant, system, pvecs, report)
    return points if per_mode else None


def _operating_points(plant: Plant, system: OdeSystem, pvecs, report: Report, guesses=None):
    """Where each mode is linearised: (points, input values there, whether each mode has its own
    steady state), as the checked `linearize` says (default: the steady state of each mode). A mode's
    inputs are the declared values shifted by the mode's own."""
    how, K = plant.linearize, len(plant.modes)
    if how.kind == "point":
        return [how.x] * K, [how.u] * K, False
    u_modes = [plant.layout.input_defaults + mode.shift for mode in plant.modes]
    if how.kind == "each":
        return [steady_state(system, plant.initial, u, p, mode.name, mode.pos, report,
                             None if guesses is None else guesses[k])
                for k, (mode, p, u) in enumerate(zip(plant.modes, pvecs, u_modes))], u_modes, True
    k = how.mode
    x = steady_state(system, plant.initial, u_modes[k], pvecs[k], plant.modes[k].name, how.pos, report)
    return [x] * K, [u_modes[k]] * K, False


def steady_state(system: OdeSystem, guess, u, p, mode: str, pos: Pos, report: Report, first=None) -> np.ndarray:
    """The state where every derivative vanishes, by Powell's hybrid method with the exact Jacobian,
    from `first` (a nearby steady state) when given, else from the guesses, else from where the plant
    settles when started at the guesses; a located error says the largest residual left when none
    converges."""
    if first is not None:
        x, residual = _root(system, first, u, p)
        if _steady(x, residual):
            return x
    x, residual = _root(system, guess, u, p)
    if not _steady(x, residual):
        settled, _ = flow(system, guess, u, p, SETTLE_SPAN, SETTLE_METHOD, SETTLE_RTOL, SETTLE_ATOL)
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


def flow(system: OdeSystem, x, u, p, span: float, method: str = "LSODA", rtol: float = RTOL,
         atol: float = ATOL) -> tuple[np.ndarray | None, str]:
    """Integrate the equations from x over `span` (in the derivatives' unit) with u held, by scipy's
    `method` (LSODA, the fastest over a simulation's many short spans) with the exact Jacobian, to
    the tolerances given: (end state, "") or (None, why the integration failed)."""
    calls = itertools.count()

    def rate(_, state):
        if next(calls) > MAX_EVALUATIONS:
            raise _OverBudget
        return system.derivative(state, u, p)

    try:
        with np.errstate(all="ignore"):
            sol = solve_ivp(rate, (0.0, span), x, method=method, jac=lambda _, s: system.jacobian("f_x", s, u, p),
                            rtol=rtol, atol=atol)
    except _OverBudget:
        return None, f"the equations needed more than {MAX_EVALUATIONS} evaluations"
    except ValueError:  # scipy's check of a derivative or Jacobian that is not finite (a number such as 1e308)
        return None, "the equations gave a value that is not finite (inf or NaN)"
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
    return jacobian_text(ode_system(plant))
