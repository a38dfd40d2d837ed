"""Lower a checked plant to the Model: lay out the state vector, lower every mode's statements to
matrices (or linearise the ODEs), fill in initial means, and stack the modes."""

from __future__ import annotations

import numpy as np

from ..lang.check import ModeInfo, Plant, check, evaluate_number, noise_values
from ..lang.parse import parse_file, parse_text
from ..lang.report import Report
from ..lang.syntax import Pos, Spec
from ..model import Model
from .blocks import MATRIX_NAMES, Layout, Lowering, ModeArrays, arx_states, fopdt_states


MAX_DELAY_SAMPLES = 1000  # a fopdt dead time becomes one state per sample: more is almost surely a unit slip


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
        from .ode import lower_ode

        model = lower_ode(plant, report)
    else:
        model = lower_linear(plant, report)
    report.finish()
    return model


def mode_noise(plant: Plant, mode: ModeInfo, params: dict, report: Report) -> tuple[float, float]:
    """(process, measurement) noise standard deviations in a mode: plant defaults, mode overrides."""
    own = noise_values([st.noise for st in mode.statements if st.kind == "noise"], params, report,
                       plant_level=False)
    values = {**plant.noise, **own}
    return values.get("process", 0.0), values.get("measurement", np.nan)


def declared_values(plant: Plant, decls, report: Report) -> np.ndarray:
    """Values written in declarations (input defaults, state initial means or guesses), evaluated with
    the nominal parameters: they belong to the plant, not to one mode. NaN where none is written."""
    return np.array([np.nan if d.value is None else
                     evaluate_number(d.value, plant.nominal, report, what=f"the value of {d.name.text}")
                     for d in decls], dtype=float)


def lower_linear(plant: Plant, report: Report) -> Model:
    """Lower a plant written with statements, matrices and blocks, mode by mode."""
    for how in plant.spec.linearize:
        report.error("'linearize' applies to nonlinear plants: this spec has no 'ode' block", how.pos)
    params = [plant.mode_params(m, report) for m in plant.modes]
    layout = Layout(states=[d.name.text for d in plant.states], inputs=[d.name.text for d in plant.inputs],
                    outputs=[d.name.text for d in plant.outputs],
                    input_defaults=declared_values(plant, plant.inputs, report))
    _add_block_states(plant, layout, params, report)
    if not layout.outputs:
        report.error("a plant needs at least one output: declare it with 'output NAME'", Pos(1, 1))
    if not layout.states:
        report.error("a plant needs at least one state: declare it with 'state NAME' (or give an output a "
                     "fopdt or arx block)", Pos(1, 1))
    report.raise_errors()
    modes = []
    for mode, env in zip(plant.modes, params):
        process, measurement = mode_noise(plant, mode, env, report)
        arrays = ModeArrays.empty(layout, process, 0.0 if np.isnan(measurement) else measurement)
        Lowering(layout, env, plant.lets, report, plant.dt, plant.time_unit, process).lower(arrays, mode.statements)
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
    return stack(plant, layout, modes, report)


def _add_block_states(plant: Plant, layout: Layout, params: list[dict], report: Report):
    """Reserve the internal states of fopdt/arx blocks, per output the union over modes (by name)."""
    declared = {d.name.text: d for d in plant.states}
    for mode, env in zip(plant.modes, params):
        low = Lowering(layout, env, plant.lets, report, plant.dt, plant.time_unit)
        for st in mode.statements:
            out = st.target.name.text if st.kind == "sample" else None
            if out not in layout.outputs:
                continue
            form, kw = st.dist.name.text, {k.text: (v, u) for k, v, u in st.dist.keywords}
            if form == "fopdt" and "tau" in kw:
                tau, delay = low.fopdt_times(kw)
                if np.isnan(delay):
                    continue  # a value that could not be evaluated is already reported
                if delay > MAX_DELAY_SAMPLES * plant.dt:
                    report.error(f"a dead time of {delay / plant.dt:.6g} samples needs as many input registers; "
                                 f"at most {MAX_DELAY_SAMPLES} are allowed: check the unit, or lengthen the "
                                 f"sample time", kw["delay"][0].pos)
                    continue
                names = fopdt_states(out, plant.dt, tau, max(delay, 0.0))
            elif form == "arx" and "a" in kw and "b" in kw and (coeffs := low.arx_coefficients(kw)):
                names = arx_states(out, len(coeffs[0]), max(len(coeffs[1]) - 1, 0))
            else:
                continue
            block = layout.block_states.setdefault(out, [])
            for s in names:
                if s in declared:
                    report.error(f"state {s!r} is also an internal state of the {form} block for output "
                                 f"{out!r}; rename the state", declared[s].name.pos)
                elif s not in block:
                    block.append(s)
                    layout.states.append(s)


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


def steady_mean(m: ModeArrays, u: np.ndarray) -> np.ndarray | None:
    """Where a mode's mean settles with the inputs held at u: (I - A)^-1 (F u + f); None if nowhere."""
    try:
        return np.linalg.solve(np.eye(len(m.A)) - m.A, m.F @ u + m.f)
    except np.linalg.LinAlgError:
        return None


def stack(plant: Plant, layout: Layout, modes: list[ModeArrays], report: Report) -> Model:
    """Stack per-mode arrays into a Model; noise factors are padded to a common width."""
    nw = max(m.B.shape[1] for m in modes)
    nv = max(m.D.shape[1] for m in modes)
    pad = lambda M, n: np.pad(M, ((0, 0), (0, n - M.shape[1])))  # noqa: E731
    for mode, m in zip(plant.modes, modes):
        overflowed = [k for k in MATRIX_NAMES if not np.isfinite(getattr(m, k)).all()]
        if overflowed:
            report.error(f"mode {mode.name!r} has entries that are not finite numbers in {', '.join(overflowed)}: "
                         "a value overflowed (values too large, or equations too stiff for the sample time?)",
                         mode.pos)
            continue
        R = m.D @ m.D.T
        if R.size and np.linalg.eigvalsh(R).min() <= 0:
            bad = [layout.outputs[j] for j in range(len(R)) if R[j, j] <= 0] or layout.outputs
            report.error(f"output {', '.join(map(repr, bad))} has no measurement noise in mode {mode.name!r}: "
                         "add 'noise measurement SD' (or an output equation Normal(mean, sd) with sd > 0)", mode.pos)
        eig = np.abs(np.linalg.eigvals(m.A)) if m.A.size else np.zeros(0)
        if eig.size and eig.max() > 1 + 1e-9:
            report.warn(f"mode {mode.name!r} is unstable: eigenvalue of modulus {eig.max():.6g} > 1", mode.pos)
    report.raise_errors()
    sd0 = np.zeros(layout.nx)
    lookup = {d.name.text: d for d in plant.states}
    for i, s in enumerate(layout.states):
        d = lookup.get(s)
        if d is not None and d.sd is not None:
            sd0[i] = evaluate_number(d.sd, plant.nominal, report, what=f"the initial sd of {s}")
            if sd0[i] < 0:
                report.error("a standard deviation cannot be negative", d.sd.pos)
    units = {d.name.text: d.unit for d in [*plant.inputs, *plant.outputs, *plant.states] if d.unit}
    return Model(
        A=np.stack([m.A for m in modes]), B=np.stack([pad(m.B, nw) for m in modes]),
        C=np.stack([m.C for m in modes]), D=np.stack([pad(m.D, nv) for m in modes]),
        F=np.stack([m.F for m in modes]), G=np.stack([m.G for m in modes]),
        f=np.stack([m.f for m in modes]), g=np.stack([m.g for m in modes]),
        P=plant.P, p0=plant.p0, mu0=np.stack([m.x0 for m in modes]), Sigma0=np.diag(sd0 ** 2),
        input_defaults=layout.input_defaults, modes=[m.name for m in plant.modes],
        states=layout.states, inputs=layout.inputs, outputs=layout.outputs, dt=plant.dt, name=plant.name,
        descriptions={m.name: m.description for m in plant.modes if m.description}, units=units)
