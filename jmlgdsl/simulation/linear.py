"""Draw data from a model: a mode sequence (from the Markov chain or a given schedule), states and
outputs, as arrays and as the CSV table that `jmlgdsl run` reads back."""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from ..errors import DataError
from ..gaussian import psd_sqrt
from ..model import Model
from ..names import plural
from ..seeds import generator

_PIECE = re.compile(r"^\s*(\d+)\s*(?:-\s*(\d+))?\s*:\s*([A-Za-z_][\w]*)\s*$")


@dataclass(frozen=True)
class Simulation:
    """A simulated run over t = 1..T (row 0 is t = 1); `x0` and `z0` are the draws at t = 0."""

    model: Model
    modes: np.ndarray  # (T,) mode indices
    x: np.ndarray  # (T, nx)
    y: np.ndarray  # (T, ny)
    u: np.ndarray  # (T, nu)
    z0: int
    x0: np.ndarray

    def columns(self) -> dict:
        """Table columns: time, inputs, outputs, the true mode name and the true states (<state>_true)."""
        m = self.model
        cols = {"time": np.arange(1, len(self.modes) + 1) * m.dt}
        cols.update({n: self.u[:, i] for i, n in enumerate(m.inputs)})
        cols.update({n: self.y[:, i] for i, n in enumerate(m.outputs)})
        cols["mode"] = [m.modes[k] for k in self.modes]
        cols.update({f"{n}_true": self.x[:, i] for i, n in enumerate(m.states)})
        return cols


def parse_schedule(text: str, model: Model, T: int | None = None) -> np.ndarray:
    """Mode indices (T,) from a schedule such as "1-70:normal,71-238:fan" (1-based, inclusive).

    The pieces must cover 1..T in order without gaps; T defaults to the end of the last piece.
    """
    modes, expected = [], 1
    for piece in text.split(","):
        match = _PIECE.match(piece)
        if not match:
            raise DataError(f"mode schedule: cannot read {piece.strip()!r}; write pieces like 1-70:normal")
        start, end, name = int(match[1]), int(match[2] or match[1]), match[3]
        if start != expected or end < start:
            raise DataError(f"mode schedule: piece {piece.strip()!r} should start at step {expected}"
                            + (" and end after it starts" if end < start else ""))
        if name not in model.modes:
            raise DataError(f"mode schedule: unknown mode {name!r}; modes are {', '.join(model.modes)}")
        modes += [model.modes.index(name)] * (end - start + 1)
        expected = end + 1
    if T is not None and len(modes) != T:
        raise DataError(f"mode schedule covers steps 1-{len(modes)} but {plural(T, 'step')} were asked for")
    return np.array(modes, dtype=np.int64)


def _mode_sequence(model, T, modes, rng):
    """(z0, modes (T,)): drawn from the chain, or the given mode names/indices with z0 = the first."""
    if modes is None:
        z0 = int(rng.choice(model.K, p=model.p0))
        seq = np.empty(T, dtype=np.int64)
        z = z0
        for t in range(T):
            z = seq[t] = rng.choice(model.K, p=model.P[z])
        return z0, seq
    seq = np.asarray([model.mode_index(k) if isinstance(k, str) else int(k) for k in modes], dtype=np.int64)
    if len(seq) != T:
        raise DataError(f"{plural(len(seq), 'mode')} given for {plural(T, 'step')}")
    if ((seq < 0) | (seq >= model.K)).any():
        raise DataError(f"mode indices must lie in 0..{model.K - 1}")
    return int(seq[0]), seq


def step_bytes(model: Model) -> int:
    """Memory one simulated step takes: states, outputs, inputs, both noises, the mode, the time, and
    the table built from them (an estimate, to refuse a run that cannot fit before it starts)."""
    return 16 * (model.nx + model.ny + model.nu + model.B.shape[2] + model.D.shape[2] + 3)


def simulate(model: Model, T: int | None = None, seed=None, modes=None, u=None) -> Simulation:
    """Simulate T steps. `modes`: None (draw from the chain), a schedule string or a sequence of mode
    names/indices; `u`: (T, nu) inputs or None for the defaults. `seed` (a number or a numpy
    Generator) fixes the draws."""
    rng = generator(seed)
    if isinstance(modes, str):
        modes = parse_schedule(modes, model, T)
    if T is None:
        if modes is not None:
            T = len(modes)
        elif u is not None:
            T = len(u)
        else:
            raise DataError("give the number of steps, a mode schedule or the inputs")
    u = model.resolve_inputs(u, T)
    z0, seq = _mode_sequence(model, T, modes, rng)
    x0 = model.mu0[z0] + psd_sqrt(model.Sigma0) @ rng.standard_normal(model.nx)
    w = rng.standard_normal((T, model.B.shape[2]))
    v = rng.standard_normal((T, model.D.shape[2]))
    x, y = np.empty((T, model.nx)), np.empty((T, model.ny))
    prev = x0
    for t, k in enumerate(seq):
        prev = x[t] = model.A[k] @ prev + model.F[k] @ u[t] + model.f[k] + model.B[k] @ w[t]
        y[t] = model.C[k] @ prev + model.G[k] @ u[t] + model.g[k] + model.D[k] @ v[t]
    return Simulation(model, seq, x, y, u, z0, x0)
