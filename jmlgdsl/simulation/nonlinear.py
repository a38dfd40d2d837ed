"""Simulate a nonlinear (ODE) plant itself rather than its linearised modes: the equations are
integrated with scipy's solve_ivp through a mode schedule (each mode's parameters apply while it
lasts), inputs held over each sample, with the process and measurement noise of the compiled model.
The result is the same Simulation as the linear simulator's, so its CSV feeds `jmlgdsl run` alike."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..compile.ode import (OdeSystem, check_ode_file, flow, linearise, mode_input_shifts, mode_parameters,
                          ode_system)
from ..errors import DataError
from ..model import Model
from .linear import Simulation, simulate


@dataclass(frozen=True)
class NonlinearPlant:
    """An ODE plant: its equations, the compiled mode bank, each mode's parameter vector (K, np) and
    the shift of each mode's own input values from the declared ones (K, nu)."""

    system: OdeSystem
    model: Model
    params: np.ndarray
    shifts: np.ndarray

    def step(self, x: np.ndarray, u: np.ndarray, k: int) -> np.ndarray:
        """The noise-free state one sample after x, with the input u (shifted as mode k says) held and
        mode k's parameters."""
        end, why = flow(self.system, x, u + self.shifts[k], self.params[k],
                        self.model.dt / self.system.seconds_per_unit)
        if end is None:
            raise DataError(f"the ODE integration failed in mode {self.model.modes[k]!r} from state "
                            f"{np.array2string(x, precision=6)}: {why}")
        return end


def load_nonlinear(path) -> NonlinearPlant:
    """Parse, check and compile a spec with an `ode` block, keeping its equations for simulation."""
    plant, report = check_ode_file(path, "a nonlinear simulation")
    system = ode_system(plant)
    model = linearise(plant, system, report)
    report.finish()
    _, vectors = mode_parameters(plant, system)
    return NonlinearPlant(system, model, vectors, mode_input_shifts(plant))


def simulate_nonlinear(plant, T: int | None = None, seed=None, modes=None, u=None) -> Simulation:
    """Simulate T steps of the ODEs (`plant`: a spec path or a NonlinearPlant), with the arguments of
    jmlgdsl.simulation.linear.simulate: x_t = Phi_k(x_{t-1}, u_t) + B_k w_t, y_t = h_k(x_t, u_t) + D_k v_t.

    The modes, the initial state and the noise terms B_k w_t and D_k v_t are those of the linearised
    model's simulation with the same seed, so the two runs differ only by the linearisation."""
    plant = plant if isinstance(plant, NonlinearPlant) else load_nonlinear(plant)
    m, system = plant.model, plant.system
    lin = simulate(m, T, seed=seed, modes=modes, u=u)
    k, prev = lin.modes, np.vstack([lin.x0, lin.x[:-1]])
    process = lin.x - _apply(m.A[k], prev) - _apply(m.F[k], lin.u) - m.f[k]
    measurement = lin.y - _apply(m.C[k], lin.x) - _apply(m.G[k], lin.u) - m.g[k]
    x, y = np.empty_like(lin.x), np.empty_like(lin.y)
    state = lin.x0
    for t in range(len(k)):
        state = x[t] = plant.step(state, lin.u[t], k[t]) + process[t]
        y[t] = system.output(state, lin.u[t], plant.params[k[t]]) + measurement[t]
    return replace(lin, x=x, y=y)


def _apply(M: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Row-wise matrix-vector products: M (T, n, m) times v (T, m)."""
    return np.einsum("tij,tj->ti", M, v)
