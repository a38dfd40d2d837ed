"""Simulate a nonlinear (ODE) plant itself rather than its linearised modes: the equations are
integrated with scipy's solve_ivp through a mode schedule (each mode's parameters apply while it
lasts), inputs held over each sample, with the process and measurement noise of the compiled model.
The result is the same Simulation as the linear simulator's, so its CSV feeds `jmlgdsl run` alike."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp

from .compile.ode import OdeSystem, check_ode_file, linearise, mode_parameters, ode_system
from .errors import DataError
from .infer.kalman import psd_sqrt
from .model import Model
from .simulate import Simulation, _mode_sequence, parse_schedule

RTOL, ATOL = 1e-9, 1e-12  # integration tolerances: far below any noise level the language can express


@dataclass(frozen=True)
class NonlinearPlant:
    """An ODE plant: its equations, the compiled mode bank, and each mode's parameter vector (K, np)."""

    system: OdeSystem
    model: Model
    params: np.ndarray

    def step(self, x: np.ndarray, u: np.ndarray, k: int) -> np.ndarray:
        """The noise-free state one sample after x, with the input u held and mode k's parameters."""
        p = self.params[k]
        span = self.model.dt / self.system.seconds_per_unit
        sol = solve_ivp(lambda _, s: self.system.derivative(s, u, p), (0.0, span), x, method="LSODA",
                        jac=lambda _, s: self.system.evaluate("f_x", s, u, p), rtol=RTOL, atol=ATOL)
        if not sol.success:
            raise DataError(f"the ODE integration failed in mode {self.model.modes[k]!r} from state "
                            f"{np.array2string(x, precision=6)}: {sol.message}")
        return sol.y[:, -1]


def load_nonlinear(path) -> NonlinearPlant:
    """Parse, check and compile a spec with an `ode` block, keeping its equations for simulation."""
    plant, report = check_ode_file(path, "a nonlinear simulation")
    system = ode_system(plant, report)
    model = linearise(plant, system, report)
    report.finish()
    return NonlinearPlant(system, model, mode_parameters(plant, system, report)[1])


def simulate_nonlinear(plant, T: int | None = None, seed=None, rng=None, modes=None, u=None) -> Simulation:
    """Simulate T steps of the ODEs (`plant`: a spec path or a NonlinearPlant). Arguments and the order
    of the random draws are those of jmlgdsl.simulate.simulate, so one seed gives both simulators the
    same modes and noise: x_t = Phi_k(x_{t-1}, u_t) + B_k w_t, y_t = h_k(x_t, u_t) + D_k v_t."""
    plant = plant if isinstance(plant, NonlinearPlant) else load_nonlinear(plant)
    model = plant.model
    rng = rng if rng is not None else np.random.default_rng(seed)
    if T is None:
        if modes is None and u is None:
            raise DataError("give the number of steps, a mode schedule or the inputs")
        T = len(parse_schedule(modes, model)) if isinstance(modes, str) else len(modes if modes is not None else u)
    u = model.resolve_inputs(u, T)
    z0, seq = _mode_sequence(model, T, modes, rng)
    x0 = model.mu0[z0] + psd_sqrt(model.Sigma0) @ rng.standard_normal(model.nx)
    w = rng.standard_normal((T, model.B.shape[2]))
    v = rng.standard_normal((T, model.D.shape[2]))
    x, y = np.empty((T, model.nx)), np.empty((T, model.ny))
    prev = x0
    for t, k in enumerate(seq):
        prev = x[t] = plant.step(prev, u[t], k) + model.B[k] @ w[t]
        y[t] = plant.system.output(prev, u[t], plant.params[k]) + model.D[k] @ v[t]
    return Simulation(model, seq, x, y, u, z0, x0)

