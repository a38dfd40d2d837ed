"""Assembly shared by both lowerings (statements and blocks in lower.py, ODEs in ode.py): the steady
state of a mode, its own input values, and the stacking of the modes' arrays into a validated Model."""

from __future__ import annotations

import hashlib

import numpy as np

from ..lang.plant import MATRIX_NAMES, MAX_MAGNITUDE, Plant
from ..lang.diagnostics import Report
from ..model import Model
from .blocks import ModeArrays


def shift_inputs(m: ModeArrays, shift: np.ndarray):
    """Make a mode act as if its inputs were shifted by `shift` from the data: f += F shift, g += G shift."""
    if shift.any():
        m.f = m.f + m.F @ shift
        m.g = m.g + m.G @ shift


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


def stack(plant: Plant, modes: list[ModeArrays], report: Report) -> Model:
    """Stack per-mode arrays into a Model; noise factors are padded to a common width, and scaled by
    each mode's `noise scale`. Raises the errors found here with those the checker held back."""
    report.release()
    layout = plant.layout
    for mode, m in zip(plant.modes, modes):
        if mode.scale is not None:
            m.B, m.D = m.B * mode.scale, m.D * mode.scale
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
    report.raise_errors()
    B, D = [pad(m.B, nw) for m in modes], [pad(m.D, nv) for m in modes]
    _warn_identical(plant, [[m.A, b, m.C, d, m.F, m.G, m.f, m.g, m.x0] for m, b, d in zip(modes, B, D)], report)
    return Model(
        A=np.stack([m.A for m in modes]), B=np.stack(B), C=np.stack([m.C for m in modes]), D=np.stack(D),
        F=np.stack([m.F for m in modes]), G=np.stack([m.G for m in modes]),
        f=np.stack([m.f for m in modes]), g=np.stack([m.g for m in modes]),
        P=plant.P, p0=plant.p0, mu0=np.stack([m.x0 for m in modes]), Sigma0=np.diag(plant.sd0 ** 2),
        input_defaults=layout.input_defaults, modes=[m.name for m in plant.modes],
        states=layout.states, inputs=layout.inputs, outputs=layout.outputs, dt=plant.dt, name=plant.name,
        descriptions={m.name: m.description for m in plant.modes if m.description},
        engineering_units=plant.engineering_units, outlier_gate=plant.gates)


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
