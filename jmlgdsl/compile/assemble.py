"""Assembly shared by both lowerings (statements and blocks in lower.py, ODEs in ode.py): the values a
plant declares, each mode's noise, the steady state of a mode, and the stacking of the modes' arrays
into a validated Model."""

from __future__ import annotations

import hashlib

import numpy as np

from ..lang.check import ModeInfo, Plant, noise_values
from ..lang.evaluate import evaluate_number
from ..lang.limits import MAX_MAGNITUDE, MAX_STACKED, MAX_VARIABLES, check_sd
from ..lang.plant import Report
from ..model import DEFAULT_GATE, Model
from .blocks import MATRIX_NAMES, Layout, ModeArrays


def mode_noise(plant: Plant, mode: ModeInfo, params: dict, report: Report) -> tuple[float, float]:
    """(process, measurement) noise standard deviations in a mode: plant defaults, mode overrides."""
    values = {**plant.noise, **_own_noise(mode, params, report)}
    return values.get("process", 0.0), values.get("measurement", np.nan)


def _own_noise(mode: ModeInfo, params: dict, report: Report) -> dict[str, float]:
    """A mode's own `noise` lines, by kind."""
    return noise_values([st.noise for st in mode.statements if st.kind == "noise"], params, report,
                        plant_level=False)


def outlier_gates(plant: Plant, outputs: list[str], report: Report) -> np.ndarray:
    """Each output's gross-error gate in standard deviations (inf: `outliers off`); the model's
    default where the declaration says nothing."""
    gates = np.full(len(outputs), DEFAULT_GATE)
    for d in plant.outputs:
        if d.gate is None or d.name.text not in outputs:
            continue
        i = outputs.index(d.name.text)
        if d.gate == "off":
            gates[i] = np.inf
            continue
        gates[i] = evaluate_number(d.gate, plant.nominal, report, what=f"the outlier gate of {d.name.text}")
        if gates[i] <= 0:  # NaN: not evaluated, reported
            report.error(f"an outlier gate is a positive number of standard deviations (or 'off'); got {gates[i]:g}",
                         d.gate.pos)
    return gates


def declared_values(plant: Plant, decls, report: Report) -> np.ndarray:
    """Values written in declarations (input defaults, state initial means or guesses), evaluated with
    the nominal parameters: they belong to the plant, not to one mode. NaN where none is written."""
    return np.array([np.nan if d.value is None else
                     evaluate_number(d.value, plant.nominal, report, what=f"the value of {d.name.text}")
                     for d in decls], dtype=float)


def input_shifts(plant: Plant, mode: ModeInfo, params: dict, declared: np.ndarray, report: Report) -> np.ndarray:
    """Per input, the mode's own operating value (`supply = 200` in the mode) less the declared one, with
    the mode's parameters; 0 where the mode sets none. An input without a declared value is an error."""
    names = [d.name.text for d in plant.inputs]
    shift = np.zeros(len(names))
    for a in mode.inputs:
        i = names.index(a.name.text)
        value = evaluate_number(a.expr, params, report, what=f"the value of {a.name.text} in mode {mode.name!r}")
        if plant.inputs[i].value is None:
            report.error(f"mode {mode.name!r} sets input {a.name.text!r}, which has no declared value to differ from: "
                         f"declare it as 'input {a.name.text} = VALUE'", a.name.pos)
        elif np.isfinite(value - declared[i]):  # either NaN: not evaluated, reported
            shift[i] = value - declared[i]
    return shift


def shift_inputs(m: ModeArrays, shift: np.ndarray):
    """Make a mode act as if its inputs were shifted by `shift` from the data: f += F shift, g += G shift."""
    if shift.any():
        m.f = m.f + m.F @ shift
        m.g = m.g + m.G @ shift


def check_size(plant: Plant, layout: Layout, report: Report):
    """Raise, before any array is made, when the compiled plant would be too large: at most
    MAX_VARIABLES states (declared and block-internal) and MAX_STACKED numbers in one stacked matrix."""
    K, n = len(plant.modes), max(layout.nx, len(layout.outputs))
    where = plant.modes[0].pos if plant.modes else None
    if layout.nx > MAX_VARIABLES:
        report.error(f"the plant has {layout.nx:,} states with the blocks' internal ones, at most "
                     f"{MAX_VARIABLES:,} are allowed", where)
    elif K * n * n > MAX_STACKED:
        report.error(f"the plant is too large: {K:,} modes of {n:,} x {n:,} matrices make {K * n * n:,} numbers "
                     f"per stacked matrix, at most {MAX_STACKED:,} are allowed", where)
    report.raise_errors()


def steady_state(A: np.ndarray, F: np.ndarray, f: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Where x = A x + F u + f settles with the inputs held at u: (I - A)^-1 (F u + f).
    LinAlgError when I - A is singular (no single steady state)."""
    return np.linalg.solve(np.eye(len(A)) - A, F @ u + f)


def steady_mean(m: ModeArrays, u: np.ndarray) -> np.ndarray | None:
    """A mode's steady state under the inputs u, or None when it has none."""
    try:
        return steady_state(m.A, m.F, m.f, u)
    except np.linalg.LinAlgError:
        return None


def stack(plant: Plant, layout: Layout, modes: list[ModeArrays], params: list[dict], report: Report) -> Model:
    """Stack per-mode arrays into a Model; noise factors are padded to a common width, and scaled by
    each mode's `noise scale`."""
    for mode, m, env in zip(plant.modes, modes, params):
        scale = _own_noise(mode, env, report).get("scale")
        if scale is not None:
            m.B, m.D = m.B * scale, m.D * scale
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
        huge = [k for k in MATRIX_NAMES if (np.abs(getattr(m, k)) > MAX_MAGNITUDE).any()]
        if huge:
            report.error(f"mode {mode.name!r} has entries larger than {MAX_MAGNITUDE:g} in {', '.join(huge)}: at most "
                         f"{MAX_MAGNITUDE:g}, so that the filters' squares and products stay finite numbers", mode.pos)
            continue
        R = m.D @ m.D.T
        if R.size and np.linalg.eigvalsh(R).min() <= 0:
            bad = [layout.outputs[j] for j in range(len(R)) if R[j, j] <= 0] or layout.outputs
            report.error(f"output {', '.join(map(repr, bad))} has no measurement noise in mode {mode.name!r}: "
                         "add 'noise measurement SD' (or an output equation Normal(mean, sd) with sd > 0)", mode.pos)
        eig = np.abs(np.linalg.eigvals(m.A)) if m.A.size else np.zeros(0)
        if eig.size and eig.max() > 1 + 1e-9:
            report.warn(f"mode {mode.name!r} is unstable: eigenvalue of modulus {eig.max():.6g} > 1", mode.pos)
    sd0 = initial_sd(plant, layout, report)
    gates = outlier_gates(plant, layout.outputs, report)
    report.raise_errors()
    B, D = [pad(m.B, nw) for m in modes], [pad(m.D, nv) for m in modes]
    _warn_identical(plant, [[m.A, b, m.C, d, m.F, m.G, m.f, m.g, m.x0] for m, b, d in zip(modes, B, D)], report)
    units = {d.name.text: d.unit for d in [*plant.inputs, *plant.outputs, *plant.states] if d.unit}
    return Model(
        A=np.stack([m.A for m in modes]), B=np.stack(B), C=np.stack([m.C for m in modes]), D=np.stack(D),
        F=np.stack([m.F for m in modes]), G=np.stack([m.G for m in modes]),
        f=np.stack([m.f for m in modes]), g=np.stack([m.g for m in modes]),
        P=plant.P, p0=plant.p0, mu0=np.stack([m.x0 for m in modes]), Sigma0=np.diag(sd0 ** 2),
        input_defaults=layout.input_defaults, modes=[m.name for m in plant.modes],
        states=layout.states, inputs=layout.inputs, outputs=layout.outputs, dt=plant.dt, name=plant.name,
        descriptions={m.name: m.description for m in plant.modes if m.description}, units=units,
        outlier_gate=gates)


def initial_sd(plant: Plant, layout: Layout, report: Report) -> np.ndarray:
    """The initial standard deviation of each state: a state's `sd`, and an output's `sd` for the states
    of its blocks that hold output values (the output and its past values; input registers and a fopdt
    block's per-input parts keep 0)."""
    sd0 = np.zeros(layout.nx)
    for d in [*plant.states, *plant.outputs]:
        if d.sd is None:
            continue
        sd = evaluate_number(d.sd, plant.nominal, report, what=f"the initial sd of {d.name.text}")
        if sd < 0:
            report.error("a standard deviation cannot be negative", d.sd.pos)
        check_sd(sd, d.sd.pos, report)
        held = [d.name.text] if d.kind == "state" else \
            [s for s in layout.block_states.get(d.name.text, ()) if layout.block_roles[s][1] == "history"]
        if not held:
            report.error(f"an output's 'sd' is the initial standard deviation of its fopdt or arx block, and no mode "
                         f"gives {d.name.text!r} one; a state takes its own: 'state NAME = MEAN sd SD'", d.sd.pos)
        for s in held:
            sd0[layout.states.index(s)] = sd
    return sd0


def _warn_identical(plant: Plant, arrays: list[list[np.ndarray]], report: Report):
    """Warn about a mode whose matrices and initial mean are exactly those of an earlier mode: what it
    changes reaches no matrix (a parameter or input that nothing uses), so no data can tell them apart."""
    for later, earlier in twins(arrays):
        report.warn(f"mode {plant.modes[later].name!r} compiles to exactly the same model as mode "
                    f"{plant.modes[earlier].name!r} (the same matrices and initial mean): what it changes reaches "
                    "no matrix, so the data cannot tell the two apart", plant.modes[later].pos)


def twins(arrays: list[list[np.ndarray]]) -> list[tuple[int, int]]:
    """(later, earlier) pairs of modes whose arrays (one list per mode) are exactly equal, each later
    mode paired with the first one it equals; -0.0 counts as 0.0."""
    first: dict[bytes, int] = {}
    pairs = []
    for k, mats in enumerate(arrays):
        digest = hashlib.sha256(b"".join((np.asarray(M, float) + 0.0).tobytes() for M in mats)).digest()
        if digest in first:
            pairs.append((k, first[digest]))
        else:
            first[digest] = k
    return pairs
