"""Lower a checked plant to the Model: write every mode's evaluated statements into its matrices (or
linearise the ODEs), fill in initial means, and stack the modes."""

from __future__ import annotations

import numpy as np

from ..lang.check import check_spec_file, check_text
from ..lang.plant import Layout, Plant
from ..lang.diagnostics import Report
from ..model import Model
from .assemble import shift_inputs, stack, steady_mean, steady_state
from .blocks import Lowering, ModeArrays


def compile_file(path) -> Model:
    """Parse, check and compile a .jmlg file (SpecError on any problem, SpecWarning for warnings)."""
    return compile_plant(*check_spec_file(path))


def compile_text(text: str, path: str = "<spec>") -> Model:
    """Compile spec text; `path` is only used in messages."""
    return compile_plant(*check_text(text, path))


def compile_plant(plant: Plant, report: Report) -> Model:
    """Lower a checked plant: ODE plants are linearised, the others lowered block by block."""
    if plant.equations is not None:
        from .ode import lower_ode  # only ODE plants pay for importing scipy's solvers (half a second)

        model = lower_ode(plant, report)
    else:
        model = lower_linear(plant, report)
    report.finish()
    return model


def lower_linear(plant: Plant, report: Report) -> Model:
    """Lower a plant written with statements, matrices and blocks, mode by mode."""
    layout = plant.layout
    modes = []
    for mode in plant.modes:
        arrays = ModeArrays.empty(layout, mode.process, 0.0 if np.isnan(mode.measurement) else mode.measurement)
        Lowering(layout, plant.dt, mode.process).lower(arrays, mode.statements)
        _shift_mode_inputs(arrays, layout, mode.shift)
        modes.append(arrays)
    for m in modes:
        _fill_initial_mean(m, plant.initial, layout.input_defaults)
    return stack(plant, modes, report)


def _shift_mode_inputs(m: ModeArrays, layout: Layout, shift: np.ndarray):
    """A mode's own input values: its offsets act on the shifted inputs, and its blocks' operating points
    (their states' initial means) move by the steady-state change the shift causes."""
    shift_inputs(m, shift)
    if not shift.any():
        return
    for names in layout.block_states.values():  # block rows use only their own states and the inputs
        held = [layout.states.index(s) for s in names]
        try:
            m.x0[held] += steady_state(m.A[np.ix_(held, held)], m.F[held], np.zeros(len(held)), shift)
        except np.linalg.LinAlgError:
            pass  # a block with no single steady state (an integrator) keeps its operating point


def _fill_initial_mean(m: ModeArrays, declared: np.ndarray, u_default: np.ndarray):
    """Initial mean where the mode gives none: the declared value, else the mode's steady state under
    the default inputs (when it has one), else zero."""
    missing = np.isnan(m.x0)
    if not missing.any():
        return
    fill = declared.copy()
    if np.isnan(fill).any() and not np.isnan(u_default).any():
        steady = steady_mean(m, u_default)
        if steady is not None:
            fill = np.where(np.isnan(fill), steady, fill)
    m.x0 = np.where(missing, np.nan_to_num(fill), m.x0)
