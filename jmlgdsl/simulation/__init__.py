"""Simulated data from a plant: its Model's linear modes (linear: `jmlgdsl.simulate`), or an ODE
plant's own equations integrated through a mode schedule (nonlinear: `jmlgdsl.simulate_nonlinear`).
Both give a Simulation, whose columns `jmlgdsl run` reads like a plant's recording."""
