"""One mode's matrices from its evaluated statements (lang.plant): the coefficients of generative `~`
statements, literal matrices, initial values, and the realisations of first-order-plus-dead-time
and ARX blocks. `jmlgdsl.compile.lower` stacks the modes into a Model."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..lang.plant import (Arx, Equation, Fopdt, Initial, Layout, Matrix, history_name, part_name,
                          register_name)


@dataclass
class ModeArrays:
    """One mode's matrices while they are being filled in."""

    A: np.ndarray
    F: np.ndarray
    f: np.ndarray
    B: np.ndarray
    C: np.ndarray
    G: np.ndarray
    g: np.ndarray
    D: np.ndarray
    x0: np.ndarray  # NaN where the mode does not say

    @classmethod
    def empty(cls, layout: Layout, process: float, measurement: float):
        nx, nu, ny = layout.nx, len(layout.inputs), len(layout.outputs)
        B = process * np.eye(nx)
        for names in layout.block_states.values():
            for s in names:  # internal block states carry no noise unless their block says so
                i = layout.states.index(s)
                B[i, i] = 0.0
        return cls(A=np.zeros((nx, nx)), F=np.zeros((nx, nu)), f=np.zeros(nx), B=B,
                   C=np.zeros((ny, nx)), G=np.zeros((ny, nu)), g=np.zeros(ny),
                   D=measurement * np.eye(ny), x0=np.full(nx, np.nan))


class Lowering:
    """Writes the evaluated statements of one mode into its arrays, in order: a later statement for
    the same variable replaces an earlier one."""

    def __init__(self, layout: Layout, dt: float, process: float):
        self.layout, self.dt = layout, dt
        self.process = process  # the mode's process noise sd, for the state a block drives

    def lower(self, m: ModeArrays, statements: list):
        for st in statements:
            if isinstance(st, Equation):
                self._equation(m, st)
            elif isinstance(st, Matrix):
                self._matrix(m, st)
            elif isinstance(st, Initial):
                m.x0[st.state] = st.value
            elif isinstance(st, Fopdt):
                self._fopdt(m, st)
            else:
                self._arx(m, st)

    @staticmethod
    def _equation(m: ModeArrays, eq: Equation):
        if eq.state is not None:
            i = eq.state
            m.A[i], m.F[i], m.f[i] = eq.on_states, eq.on_inputs, eq.constant
            m.B[i] = 0.0
            m.B[i, i] = eq.sd
        else:
            j = eq.output
            m.C[j], m.G[j], m.g[j] = eq.on_states, eq.on_inputs, eq.constant
            m.D[j] = 0.0
            m.D[j, j] = eq.sd

    @staticmethod
    def _matrix(m: ModeArrays, st: Matrix):
        if st.name in ("B", "D", "x0"):  # B and D of any width: a copy, which later statements may change
            setattr(m, st.name, st.value.copy())
        else:
            getattr(m, st.name)[...] = st.value

    def _block_rows(self, m: ModeArrays, j: int, ks: list[int], u_ss: np.ndarray, y_ss: float) -> dict[str, int]:
        """Claim the internal states of output j's blocks (the union over modes): every output and input
        history register keeps shifting in every mode, so a mode switch finds the true past values.
        Returns the state indices by name; the caller fills the rows of the output and its parts."""
        lay, out = self.layout, self.layout.outputs[j]
        names = lay.block_states[out]
        idx = {s: lay.states.index(s) for s in names}
        inputs = [lay.inputs[k] for k in ks]
        for s, i in idx.items():
            m.A[i] = m.F[i] = m.f[i] = m.B[i] = 0.0
            _, kind, key, n = lay.block_roles[s]
            if kind == "history":
                m.x0[i] = y_ss
                if n:
                    m.A[i, idx[history_name(out, n - 1)]] = 1.0
            elif kind == "register":
                feed = key if key is not None else inputs[0] if len(inputs) == 1 else lay.single_inputs[out]
                m.x0[i] = u_ss[inputs.index(feed)] if feed in inputs else math.nan
                if n:
                    m.A[i, idx[register_name(out, key, n - 1)]] = 1.0
                else:
                    m.F[i, lay.inputs.index(feed)] = 1.0
        return idx

    @staticmethod
    def _measure(m: ModeArrays, j: int, state: int):
        """The output reads the block's state directly."""
        m.C[j] = m.G[j] = m.g[j] = 0.0
        m.C[j, state] = 1.0

    def _fopdt(self, m: ModeArrays, b: Fopdt):
        """The sum over the inputs of K e^{-θs}/(τs+1), with zero-order hold: exact for any dead time
        (modified z-transform). The output's state holds the whole response; each input after the first
        has a state holding its part, so that every part relaxes at its own rate."""
        j, ks, gain, u_ss = b.output, b.inputs, b.gain, b.u_ss
        n = len(ks)
        out, names = self.layout.outputs[j], [self.layout.inputs[k] for k in ks]
        idx = self._block_rows(m, j, ks, u_ss, b.y_ss)
        y = idx[out]
        a = [math.exp(-self.dt / t) for t in b.tau]
        m.A[y, y] = a[0]
        for i, k in enumerate(ks):
            rows = [y]
            if i:  # the first input's part is the output less the other parts
                part = idx[part_name(out, names[i])]
                rows.append(part)
                m.A[part, part] = a[i]
                m.A[y, part] = a[i] - a[0]
                m.x0[part] = gain[i] * u_ss[i]
            for lag, w in zip(b.lags[i], fopdt_weights(self.dt, b.tau[i], b.fractions[i], a[i], gain[i])):
                if lag == 0:
                    m.F[rows, k] += w
                else:  # u_{t-lag}: the register holding u_{t-lag+1}, at t-1
                    m.A[rows, idx[register_name(out, None if n == 1 else names[i], lag - 1)]] += w
        m.f[y] = (1 - a[0]) * np.nan_to_num(b.y_ss - gain @ u_ss)
        m.B[y, y] = self.process
        self._measure(m, j, y)

    def _arx(self, m: ModeArrays, b: Arx):
        """y_t + a1 y_{t-1} + ... + a_na y_{t-na} = sum over the inputs of b0 u_t + ... + b_nb u_{t-nb}, plus
        e_t, realised on the states (y_t, ..., y_{t-na+1}, then u_t, ..., u_{t-nb+1} for each input), so the
        process noise is the equation error e_t."""
        j, ks, a, coef = b.output, b.inputs, b.a, b.b
        out = self.layout.outputs[j]
        idx = self._block_rows(m, j, ks, b.u_ss, b.y_ss)
        y = idx[out]
        m.A[y, [idx[history_name(out, n)] for n in range(a.size)]] = -a  # y_{t-1}.. are these states at t-1
        for i, k in enumerate(ks):
            key = None if len(ks) == 1 else self.layout.inputs[k]
            m.A[y, [idx[register_name(out, key, n)] for n in range(coef.shape[1] - 1)]] = coef[i, 1:]
            m.F[y, k] = coef[i, 0]
        m.f[y] = np.nan_to_num(b.y_ss * (1 + a.sum()) - b.u_ss @ coef.sum(axis=1))
        m.B[y, y] = self.process
        self._measure(m, j, y)


def fopdt_weights(dt: float, tau: float, fraction: float, a: float, gain: float) -> list[float]:
    """Input weights for u_{t-d} (and u_{t-d-1} when the dead time is d samples plus a fraction)."""
    if fraction == 0.0:
        return [gain * (1 - a)]
    part = math.exp(-(dt - fraction) / tau)
    return [gain * (1 - part), gain * (part - a)]
