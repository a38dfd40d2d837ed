"""Lower a checked plant to the Model: lay out the state vector, lower every mode's statements to
matrices (or linearise the ODEs), fill in initial means, and stack the modes."""

from __future__ import annotations

import numpy as np

from ..lang.check import Plant, check
from ..lang.parse import parse_file, parse_text
from ..lang.plant import Pos, Report
from ..lang.syntax import Spec
from ..model import Model
from .assemble import (check_size, declared_values, input_shifts, mode_noise, shift_inputs, stack, steady_mean,
                       steady_state)
from .blocks import Layout, Lowering, ModeArrays, describe_role


def compile_file(path) -> Model:
    """Parse, check and compile a .jmlg file (SpecError on any problem, SpecWarning for warnings)."""
    return compile_spec(parse_file(path))


def compile_text(text: str, path: str = "<spec>") -> Model:
    """Compile spec text; `path` is only used in messages."""
    return compile_spec(parse_text(text, path))


def compile_spec(spec: Spec) -> Model:
    """Check a parsed spec and lower it: ODE plants are linearised, the others lowered block by block."""
    plant, report = check(spec)
    report.raise_errors()
    if spec.ode:
        from .ode import lower_ode  # only ODE plants pay for importing scipy's solvers (half a second)

        model = lower_ode(plant, report)
    else:
        model = lower_linear(plant, report)
    report.finish()
    return model


def lower_linear(plant: Plant, report: Report) -> Model:
    """Lower a plant written with statements, matrices and blocks, mode by mode."""
    for how in plant.spec.linearize:
        report.error("'linearize' applies to nonlinear plants: this spec has no 'ode' block", how.pos)
    params = [plant.mode_params(m, report) for m in plant.modes]
    layout = Layout(states=[d.name.text for d in plant.states], inputs=[d.name.text for d in plant.inputs],
                    outputs=[d.name.text for d in plant.outputs],
                    input_defaults=declared_values(plant, plant.inputs, report))
    _add_block_states(plant, layout, params, report)
    check_size(plant, layout, report)
    if not layout.outputs:
        report.error("a plant needs at least one output: declare it with 'output NAME'", Pos(1, 1))
    if not layout.states and not report.error_count:  # a block with an error reserves no states
        report.error("a plant needs at least one state: declare it with 'state NAME' (or give an output a "
                     "fopdt or arx block)", Pos(1, 1))
    report.raise_errors()
    modes = []
    for mode, env in zip(plant.modes, params):
        process, measurement = mode_noise(plant, mode, env, report)
        arrays = ModeArrays.empty(layout, process, 0.0 if np.isnan(measurement) else measurement)
        Lowering(layout, env, plant.lets, report, plant.dt, plant.time_unit, process).lower(arrays, mode.statements)
        _shift_mode_inputs(arrays, layout, input_shifts(plant, mode, env, layout.input_defaults, report))
        for s in layout.states:
            if s not in arrays.states_defined:
                report.error(f"state {s!r} has no equation in mode {mode.name!r} "
                             f"(write {s}[t] ~ Normal(...) or a matrix A)", mode.pos)
        for y in layout.outputs:
            if y not in arrays.outputs_defined:
                report.error(f"output {y!r} has no equation in mode {mode.name!r} "
                             f"(write {y} ~ Normal(...), a block such as fopdt, or a matrix C)", mode.pos)
        modes.append(arrays)
    report.raise_errors()
    declared = dict(zip((d.name.text for d in plant.states), declared_values(plant, plant.states, report)))
    state_means = np.array([declared.get(s, np.nan) for s in layout.states])
    for m in modes:
        _fill_initial_mean(m, state_means, layout.input_defaults)
    return stack(plant, layout, modes, params, report)


def _add_block_states(plant: Plant, layout: Layout, params: list[dict], report: Report):
    """Reserve the internal states of fopdt/arx blocks, per output the union over modes (by name); a
    name that would hold two different things is an error."""
    declared = {d.name.text: d for d in plant.states}
    for mode, env in zip(plant.modes, params):
        low = Lowering(layout, env, plant.lets, report, plant.dt, plant.time_unit)
        for st in mode.statements:
            out = st.target.name.text if st.kind == "sample" else None
            if out not in layout.outputs or st.dist.name.text not in ("fopdt", "arx"):
                continue
            roles = low.internal_states(out, st.dist)
            if roles is None:
                continue
            if len(st.dist.positional) == 1:
                layout.single_inputs.setdefault(out, st.dist.positional[0].args[0])
            block = layout.block_states.setdefault(out, [])
            for s, role in roles:
                held = layout.block_roles.get(s)
                if s in declared:
                    report.error(f"state {s!r} is also an internal state of the {st.dist.name.text} block for output "
                                 f"{out!r}; rename the state", declared[s].name.pos)
                elif held is not None and held != role:
                    report.error(f"the {st.dist.name.text} block needs a state {s!r} for {describe_role(role)}, but "
                                 f"that name already holds {describe_role(held)}; rename an input or output",
                                 st.dist.name.pos)
                elif held is None:
                    block.append(s)
                    layout.states.append(s)
                    layout.block_roles[s] = role


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
