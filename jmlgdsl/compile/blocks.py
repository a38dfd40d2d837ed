"""Block forms lowered to one mode's matrices: generative `~` statements (coefficients extracted
with sympy), literal matrices, first-order-plus-dead-time blocks and ARX blocks.

Each lowering writes rows of a ModeArrays; `jmlgdsl.compile.lower` stacks the modes into a Model.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import sympy as sp

from ..lang.evaluate import (NOT_FINITE, EvalError, LetExpander, UnknownName, finite_numeric,
                                finite_real, show, symbolic)
from ..lang.limits import MAX_DELAY_SAMPLES, MAX_ORDER, check_sd
from ..lang.plant import Report
from ..lang.syntax import Dist, Expr, Name, Statement
from ..lang.units import time_in_seconds
from ..names import suggest

MATRIX_NAMES = ("A", "B", "C", "D", "F", "G", "f", "g", "x0")
BLOCK_FORMS = ("Normal", "fopdt", "arx")
FOPDT_KEYS = ("gain", "tau", "delay")
ARX_KEYS = ("a", "b", "na", "nb")
OPERATING_KEYS = ("u_ss", "y_ss")  # the operating point of a block with several inputs (`at` names one)


@dataclass
class Layout:
    """Variable names of the compiled plant; blocks add internal states after the declared ones."""

    states: list[str]
    inputs: list[str]
    outputs: list[str]
    input_defaults: np.ndarray
    block_states: dict[str, list[str]] = field(default_factory=dict)  # output -> its internal states
    block_roles: dict[str, tuple] = field(default_factory=dict)  # internal state -> (output, kind, key, n)
    single_inputs: dict[str, str] = field(default_factory=dict)  # output -> input of its single-input blocks

    @property
    def nx(self):
        return len(self.states)


@dataclass
class ModeArrays:
    """One mode's matrices while they are being filled in, and the states and outputs its statements define."""

    A: np.ndarray
    F: np.ndarray
    f: np.ndarray
    B: np.ndarray
    C: np.ndarray
    G: np.ndarray
    g: np.ndarray
    D: np.ndarray
    x0: np.ndarray  # NaN where the mode does not say
    states_defined: set = field(default_factory=set)
    outputs_defined: set = field(default_factory=set)

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
    """Lowers the statements of one mode, given the layout and the mode's parameter values."""

    def __init__(self, layout: Layout, params: dict, lets: dict, report: Report, dt: float, time_unit: str,
                 process: float = 0.0):
        self.layout, self.params, self.lets, self.report = layout, params, lets, report
        self.dt, self.time_unit = dt, time_unit
        self.expand_let = LetExpander(lets)
        self.process = process  # the mode's process noise sd, for the state a block drives

    # ------------------------------------------------------------- names in expressions
    def _numeric_lookup(self, node: Expr):
        name = node.args[0]
        if node.op == "var" and name in self.params:
            return self.params[name]
        if node.op == "var" and name in self.lets:
            return self.expand_let(node, lambda e: finite_numeric(e, self._numeric_lookup))
        if name in self.layout.states or name in self.layout.inputs or name in self.layout.outputs:
            raise EvalError(f"{name!r} is a variable, but a number is needed here", node)
        raise UnknownName(self._unknown(name), node)

    def _unknown(self, name):
        known = [*self.params, *self.lets, *self.layout.states, *self.layout.inputs]
        return f"unknown name {name!r}{suggest(name, known)}"

    def number(self, expr: Expr, what: str) -> float:
        try:
            v = finite_numeric(expr, self._numeric_lookup)
        except EvalError as exc:
            self.report.error(str(exc), exc.node.pos)
            return math.nan
        if np.ndim(v):
            self.report.error(f"{what} must be a number, not a matrix", expr.pos)
            return math.nan
        return float(v)

    def matrix(self, expr: Expr) -> np.ndarray | None:
        try:
            return np.atleast_2d(np.asarray(finite_numeric(expr, self._numeric_lookup), float))
        except EvalError as exc:
            self.report.error(str(exc), exc.node.pos)
            return None

    def affine(self, expr: Expr, in_state_equation: bool):
        """Coefficients of an expression affine in the states (at t-1 for a state equation, at t for an
        output) and the inputs at t: returns (state coefficients, input coefficients, constant)."""
        lay = self.layout
        xs = [sp.Symbol(f"{s}[t-1]" if in_state_equation else f"{s}[t]") for s in lay.states]
        us = [sp.Symbol(u) for u in lay.inputs]

        def lookup(node: Expr):
            name = node.args[0]
            if name in lay.states:
                lag = node.args[1] if node.op == "indexed" else None
                if node.index is not None or lag is None:
                    want = "t-1" if in_state_equation else "t"
                    raise EvalError(f"write the state with its time, {name}[{want}]", node)
                if in_state_equation and lag != -1:
                    raise EvalError(f"a state equation uses states at t-1: write {name}[t-1]", node)
                if not in_state_equation and lag != 0:
                    raise EvalError(f"an output uses states at t: write {name}[t]", node)
                return xs[lay.states.index(name)]
            if name in lay.inputs:
                if node.op == "indexed" and (node.index is not None or node.args[1] != 0):
                    raise EvalError(f"inputs enter at time t only: write {name} or {name}[t]", node)
                return us[lay.inputs.index(name)]
            if node.op == "var" and name in self.params:
                return sp.Float(self.params[name])
            if node.op == "var" and name in self.lets:
                return self.expand_let(node, lambda e: symbolic(e, lookup))
            if name in lay.outputs:
                raise EvalError(f"{name!r} is an output; a mean may use states and inputs only", node)
            raise UnknownName(self._unknown(name), node)

        try:
            e = sp.expand(symbolic(expr, lookup))
        except EvalError as exc:
            self.report.error(str(exc), exc.node.pos)
            return None
        if not finite_real(e):
            self.report.error(NOT_FINITE, expr.pos)
            return None
        symbols = xs + us
        for term in sp.Add.make_args(e):
            present = term.free_symbols & set(symbols)
            if present and not (sp.Poly(term, *present).total_degree() == 1 if term.is_polynomial(*present) else False):
                self.report.error(f"{show(term)} is not linear in the states and inputs", expr.pos)
                return None
        if e.free_symbols - set(symbols):
            self.report.error(f"cannot use {', '.join(map(str, e.free_symbols - set(symbols)))} here", expr.pos)
            return None
        ax = np.array([float(e.coeff(s)) for s in xs])
        au = np.array([float(e.coeff(s)) for s in us])
        const = float(e.subs({s: 0 for s in symbols}))
        return ax, au, const

    # ------------------------------------------------------------- statements
    def lower(self, arrays: ModeArrays, statements: list[Statement]):
        """Write the mode's statements into its arrays, in order. Each statement accounts for what it
        defines whether or not it lowers: one with an error (reported there, or already reported for
        the mode it is `like`) is the root cause, not to be followed by 'has no equation'."""
        for st in statements:
            states, outputs = self._defines(st)
            arrays.states_defined.update(states)
            arrays.outputs_defined.update(outputs)
            if st.kind == "sample":
                self._sample(arrays, st)
            elif st.kind == "assign":
                self._assign(arrays, st)

    def _defines(self, st: Statement) -> tuple[list[str], list[str]]:
        """The states and outputs a statement gives equations to: its target (an output's block states
        with it) for `~` and `NAME[t] = ...`, every state for a matrix A, every output for a matrix C."""
        lay, target = self.layout, st.target
        if st.kind not in ("sample", "assign") or target.index is not None:
            return [], []
        name = target.name.text
        if st.kind == "assign" and target.lag is None:
            return lay.states if name == "A" else [], lay.outputs if name == "C" else []
        if name in lay.block_states:
            return lay.block_states[name], [name]
        return ([name], []) if name in lay.states else ([], [name])

    def _sample(self, m: ModeArrays, st: Statement):
        lay, name = self.layout, st.target.name.text
        dist = st.dist
        if dist.name.text not in BLOCK_FORMS:
            self.report.error(f"unknown distribution or block {dist.name.text!r}; use Normal, fopdt or arx"
                              f"{suggest(dist.name.text, BLOCK_FORMS)}", dist.name.pos)
            return
        if st.target.index is not None or (st.target.lag not in (None, 0)):
            self.report.error(f"the left side of '~' is a variable at time t: write {name}[t]", st.target.name.pos)
            return
        if name in lay.states and name not in lay.block_states.get(name, ()):
            if dist.name.text != "Normal":
                self.report.error(f"{dist.name.text} defines an output; use Normal(mean, sd) for the state {name}",
                                  dist.name.pos)
                return
            self._normal(m, st, state=lay.states.index(name))
        elif name in lay.outputs:
            j = lay.outputs.index(name)
            if dist.name.text == "Normal":
                self._normal(m, st, output=j)
            elif dist.name.text == "fopdt":
                self._fopdt(m, dist, j)
            else:
                self._arx(m, dist, j)
        else:
            self.report.error(f"{self._unknown(name)}: the left side of '~' is a state or an output",
                              st.target.name.pos)

    def _normal(self, m: ModeArrays, st: Statement, state: int | None = None, output: int | None = None):
        d = st.dist
        if len(d.positional) != 2 or d.keywords or d.at:
            self.report.error("Normal takes two arguments: Normal(mean, standard deviation)", d.name.pos)
            return
        sd = self.number(d.positional[1], "a standard deviation")
        if sd < 0:
            self.report.error(f"a standard deviation cannot be negative (got {sd:g}); Normal takes (mean, sd)",
                              d.positional[1].pos)
        check_sd(sd, d.positional[1].pos, self.report)
        self._equation(m, d.positional[0], sd, state, output)

    def _equation(self, m: ModeArrays, mean: Expr, sd: float, state: int | None, output: int | None):
        coeffs = self.affine(mean, in_state_equation=state is not None)
        if coeffs is None:
            return
        ax, au, c = coeffs
        if state is not None:
            m.A[state], m.F[state], m.f[state] = ax, au, c
            m.B[state] = 0.0
            m.B[state, state] = sd
        else:
            m.C[output], m.G[output], m.g[output] = ax, au, c
            m.D[output] = 0.0
            m.D[output, output] = sd

    def _assign(self, m: ModeArrays, st: Statement):
        lay, t, name = self.layout, st.target, st.target.name.text
        if t.index is not None:
            if t.index != 0 or name not in lay.states:
                what = "an initial value is given as STATE[0] = value" if name in lay.states else \
                    f"{self._unknown(name)}: only states have an initial value NAME[0]"
                self.report.error(what, t.name.pos)
                return
            m.x0[lay.states.index(name)] = self.number(st.expr, "an initial value")
        elif t.lag == 0:
            if name in lay.states:
                self._equation(m, st.expr, 0.0, lay.states.index(name), None)
            elif name in lay.outputs:
                self._equation(m, st.expr, 0.0, None, lay.outputs.index(name))
            else:
                self.report.error(self._unknown(name), t.name.pos)
        elif t.lag is not None:
            self.report.error(f"an equation defines {name}[t], not {name}[t{t.lag:+d}]", t.name.pos)
        elif name in MATRIX_NAMES:
            self._matrix(m, name, st)
        else:
            self.report.error(f"{self._unknown(name)}; in a mode block, assign a matrix "
                              f"({', '.join(MATRIX_NAMES)}), a parameter, or write NAME[t] ~ ...", t.name.pos)

    def _matrix(self, m: ModeArrays, name: str, st: Statement):
        value = self.matrix(st.expr)
        if value is None:
            return
        lay = self.layout
        nx, nu, ny = lay.nx, len(lay.inputs), len(lay.outputs)
        shapes = {"A": (nx, nx), "B": (nx, None), "C": (ny, nx), "D": (ny, None), "F": (nx, nu),
                  "G": (ny, nu), "f": (nx,), "g": (ny,), "x0": (nx,)}
        want = shapes[name]
        if value.size == 1 and name in ("B", "D"):
            value = value.item() * np.eye(want[0])
        if len(want) == 1 and 1 in value.shape:
            value = value.ravel()
        if value.shape[0] != want[0] or (len(want) == 2 and want[1] is not None and value.shape[1] != want[1]):
            sizes = f"nx = {nx}, nu = {nu}, ny = {ny}"
            shown = " x ".join("any" if w is None else str(w) for w in want)
            self.report.error(f"{name} must be {shown} ({sizes}), got {' x '.join(map(str, value.shape))}",
                              st.expr.pos)
            return
        if name in ("B", "D"):
            check_sd(np.abs(value).max(initial=0.0), st.expr.pos, self.report)
            setattr(m, name, value)
        elif name == "x0":
            m.x0 = value
        else:
            getattr(m, name)[...] = value

    # ------------------------------------------------------------- block forms
    def _keywords(self, d: Dist, allowed: tuple, required: tuple) -> dict | None:
        """Keyword arguments as {key: (Expr, unit Name or None)}; reports unknown, repeated, missing."""
        got, ok = {}, True
        for key, value, unit in d.keywords:
            if key.text not in allowed:
                hint = ("; a block with one input gives its operating point as 'at INPUT VALUE -> OUTPUT'"
                        if key.text in OPERATING_KEYS else suggest(key.text, allowed))
                self.report.error(f"{d.name.text} has no argument {key.text!r}; it takes {', '.join(allowed)}{hint}",
                                  key.pos)
                ok = False
            elif key.text in got:
                self.report.error(f"{key.text!r} is given twice", key.pos)
                ok = False
            got[key.text] = (value, unit)
        for key in required:
            if key not in got:
                self.report.error(f"{d.name.text} needs '{key} VALUE'", d.name.pos)
                ok = False
        return got if ok else None

    @staticmethod
    def _allowed(d: Dist, keys: tuple) -> tuple:
        """A block's keywords: with several inputs, the operating point is `u_ss [...], y_ss VALUE`."""
        return keys + OPERATING_KEYS if len(d.positional) > 1 else keys

    def _block_inputs(self, d: Dist) -> list[int] | None:
        """Indices of the inputs a block names first, fopdt(u1, u2, ...); None, reported, if one is wrong."""
        if not d.positional or any(e.op != "var" for e in d.positional):
            self.report.error(f"{d.name.text} starts with the name of its input, e.g. {d.name.text}(u, ...)",
                              d.name.pos)
            return None
        ks = []
        for e in d.positional:
            name = e.args[0]
            if name not in self.layout.inputs:
                self.report.error(f"unknown input {name!r}{suggest(name, self.layout.inputs)}", e.pos)
                return None
            if self.layout.inputs.index(name) in ks:
                self.report.error(f"input {name!r} is named twice in the {d.name.text} block", e.pos)
                return None
            ks.append(self.layout.inputs.index(name))
        return ks

    def _vector(self, expr: Expr, n: int, key: str, what: str) -> np.ndarray:
        """A keyword's value for each of a block's n inputs: one number for all of them, or one per input
        (NaN, reported, otherwise)."""
        if n == 1:
            return np.array([self.number(expr, what)])
        v = self.matrix(expr)
        if v is None:
            return np.full(n, np.nan)
        if v.size == 1:
            return np.full(n, v.item())
        if v.size != n or 1 not in v.shape:
            self.report.error(f"'{key}' takes one value for every input or one per input ({n} here), got "
                              f"{' x '.join(map(str, v.shape))}", expr.pos)
            return np.full(n, np.nan)
        return v.ravel()

    def _operating_point(self, d: Dist, kw: dict, ks: list[int]) -> tuple[np.ndarray, float]:
        """(u_ss per input, y_ss) from `at INPUT u -> y` (one input) or `u_ss [...], y_ss y` (several);
        NaN without one (deviations 0, initial mean left open)."""
        n = len(ks)
        none = np.full(n, math.nan), math.nan
        if n == 1:
            if d.at is None:
                return none
            name, u_expr, y_expr = d.at
            if name.text != self.layout.inputs[ks[0]]:
                self.report.error(f"the operating point names the block's input: 'at {self.layout.inputs[ks[0]]} "
                                  f"VALUE -> OUTPUT'", name.pos)
            return (np.array([self.number(u_expr, "an operating input")]),
                    self.number(y_expr, "an operating output"))
        if d.at is not None:
            self.report.error(f"a block with several inputs gives its operating point as 'u_ss [...], y_ss VALUE', "
                              f"with one u_ss value per input", d.at[0].pos)
            return none
        given = [k for k in OPERATING_KEYS if k in kw]
        if len(given) == 1:
            self.report.error("an operating point needs both 'u_ss [...]' (the inputs) and 'y_ss VALUE' "
                              "(the output)", kw[given[0]][0].pos)
        if len(given) < 2:
            return none
        return (self._vector(kw["u_ss"][0], n, "u_ss", "an operating input"),
                self.number(kw["y_ss"][0], "an operating output"))

    def _durations(self, value: Expr, unit, n: int, key: str, what: str) -> np.ndarray:
        """Times in seconds, one per input; without a unit, in the unit of the sample time."""
        v = self._vector(value, n, key, what)
        return time_in_seconds(v, unit if isinstance(unit, Name) else Name(unit or self.time_unit, value.pos),
                               self.report)

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

    def _measure(self, m: ModeArrays, j: int, state: int):
        """The output reads the block's state directly."""
        m.C[j] = m.G[j] = m.g[j] = 0.0
        m.C[j, state] = 1.0

    def _fopdt(self, m: ModeArrays, d: Dist, j: int):
        """The sum over the inputs of K e^{-θs}/(τs+1), with zero-order hold: exact for any dead time
        (modified z-transform). The output's state holds the whole response; each input after the first
        has a state holding its part, so that every part relaxes at its own rate."""
        kw = self._keywords(d, self._allowed(d, FOPDT_KEYS), ("gain", "tau"))
        ks = self._block_inputs(d)
        if kw is None or ks is None:
            return
        n = len(ks)
        gain = self._vector(kw["gain"][0], n, "gain", "a gain")
        tau, delay = self.fopdt_times(kw, n)
        if np.isnan(tau).any() or np.isnan(delay).any():
            return  # a value that could not be evaluated is already reported
        if not (tau > 0).all():
            self.report.error(f"the time constant must be positive (got {tau[~(tau > 0)][0]:g} s)", kw["tau"][0].pos)
            return
        if (delay < 0).any():
            self.report.error(f"the dead time cannot be negative (got {delay[delay < 0][0]:g} s)",
                              kw["delay"][0].pos)
            return
        u_ss, y_ss = self._operating_point(d, kw, ks)
        out, names = self.layout.outputs[j], [self.layout.inputs[k] for k in ks]
        idx = self._block_rows(m, j, ks, u_ss, y_ss)
        y = idx[out]
        a = [math.exp(-self.dt / t) for t in tau]
        m.A[y, y] = a[0]
        for i, k in enumerate(ks):
            rows = [y]
            if i:  # the first input's part is the output less the other parts
                part = idx[part_name(out, names[i])]
                rows.append(part)
                m.A[part, part] = a[i]
                m.A[y, part] = a[i] - a[0]
                m.x0[part] = gain[i] * u_ss[i]
            lags, fraction = fopdt_lags(self.dt, tau[i], delay[i])
            for lag, b in zip(lags, fopdt_weights(self.dt, tau[i], fraction, a[i], gain[i])):
                if lag == 0:
                    m.F[rows, k] += b
                else:  # u_{t-lag}: the register holding u_{t-lag+1}, at t-1
                    m.A[rows, idx[register_name(out, None if n == 1 else names[i], lag - 1)]] += b
        m.f[y] = (1 - a[0]) * np.nan_to_num(y_ss - gain @ u_ss)
        m.B[y, y] = self.process
        self._measure(m, j, y)

    def fopdt_times(self, kw, n: int) -> tuple[np.ndarray, np.ndarray]:
        """Time constants and dead times of a fopdt block with n inputs, in seconds."""
        tau = self._durations(*kw["tau"], n, "tau", "a time constant")
        delay = self._durations(*kw["delay"], n, "delay", "a dead time") if "delay" in kw else np.zeros(n)
        return tau, delay

    def arx_coefficients(self, kw, n: int) -> tuple[np.ndarray, np.ndarray] | None:
        """The a (a1..a_na) vector and b (b0..b_nb, one row per input) matrix of an arx block with n
        inputs, each of at most MAX_ORDER coefficients; None, reported, otherwise."""
        a, b = self.matrix(kw["a"][0]), self.matrix(kw["b"][0])
        if a is None or b is None:
            return None
        a = a.ravel()
        if n == 1:
            b = b.reshape(1, -1)  # one input: its coefficients, as a row or a column
        elif b.shape[0] != n:
            self.report.error(f"'b' has one row of coefficients per input: {n} rows here, got {b.shape[0]}",
                              kw["b"][0].pos)
            return None
        for key, count, first in (("a", a.size, "a1"), ("b", b.shape[1], "b0")):
            if count == 0:
                hint = "; without output feedback write 'a [0]'" if key == "a" else ""
                self.report.error(f"arx needs at least {first} in '{key} [...]'{hint}", kw[key][0].pos)
                return None
            if count > MAX_ORDER:
                self.report.error(f"{count} coefficients in '{key}' are too many: at most {MAX_ORDER}",
                                  kw[key][0].pos)
                return None
        return a, b

    def _arx(self, m: ModeArrays, d: Dist, j: int):
        """y_t + a1 y_{t-1} + ... + a_na y_{t-na} = sum over the inputs of b0 u_t + ... + b_nb u_{t-nb}, plus
        e_t, realised on the states (y_t, ..., y_{t-na+1}, then u_t, ..., u_{t-nb+1} for each input), so the
        process noise is the equation error e_t."""
        kw = self._keywords(d, self._allowed(d, ARX_KEYS), ("a", "b"))
        ks = self._block_inputs(d)
        if kw is None or ks is None:
            return
        coeffs = self.arx_coefficients(kw, len(ks))
        if coeffs is None:
            return
        a, b = coeffs
        for key, count, extra in (("na", a.size, 0), ("nb", b.shape[1], -1)):
            if key in kw:
                order = self.number(kw[key][0], f"the order {key}")
                if order != count + extra:
                    self.report.error(f"{key} = {order:g} but {count} coefficients are given "
                                      f"({'a1..a_na' if key == 'na' else 'b0..b_nb'})", kw[key][0].pos)
                    return
        u_ss, y_ss = self._operating_point(d, kw, ks)
        out = self.layout.outputs[j]
        idx = self._block_rows(m, j, ks, u_ss, y_ss)
        y = idx[out]
        m.A[y, [idx[history_name(out, n)] for n in range(a.size)]] = -a  # y_{t-1}.. are these states at t-1
        for i, k in enumerate(ks):
            key = None if len(ks) == 1 else self.layout.inputs[k]
            m.A[y, [idx[register_name(out, key, n)] for n in range(b.shape[1] - 1)]] = b[i, 1:]
            m.F[y, k] = b[i, 0]
        m.f[y] = np.nan_to_num(y_ss * (1 + a.sum()) - u_ss @ b.sum(axis=1))
        m.B[y, y] = self.process
        self._measure(m, j, y)

    def internal_states(self, out: str, d: Dist) -> list[tuple[str, tuple]] | None:
        """The internal states of a fopdt or arx block on output `out`, with their roles; None when the
        block is not well formed (reported here or by its lowering) or its dead time is beyond the limit."""
        kw = {k.text: (v, u) for k, v, u in d.keywords}
        ks = self._block_inputs(d)
        if ks is None:
            return None
        inputs, n = [self.layout.inputs[k] for k in ks], len(ks)
        if d.name.text == "fopdt" and "tau" in kw:
            tau, delay = self.fopdt_times(kw, n)
            if np.isnan(delay).any():
                return None  # a value that could not be evaluated is already reported
            if (delay > MAX_DELAY_SAMPLES * self.dt).any():
                self.report.error(f"a dead time of {delay.max() / self.dt:.6g} samples needs as many input registers; "
                                  f"at most {MAX_DELAY_SAMPLES} are allowed: check the unit, or lengthen the "
                                  f"sample time", kw["delay"][0].pos)
                return None
            registers = [max(fopdt_lags(self.dt, t, max(th, 0.0))[0]) for t, th in zip(tau, delay)]
            return block_roles(out, inputs, registers, history=1, parts=True)
        if d.name.text == "arx" and "a" in kw and "b" in kw and (coeffs := self.arx_coefficients(kw, n)):
            a, b = coeffs
            return block_roles(out, inputs, [b.shape[1] - 1] * n, history=a.size, parts=False)
        return None


def fopdt_lags(dt: float, tau: float, delay: float) -> tuple[list[int], float]:
    """Sample lags of the input that reach the lag state, and the fractional part of the dead time."""
    whole = math.floor(delay / dt + 1e-9)
    fraction = delay - whole * dt
    if fraction <= 1e-9 * max(dt, delay):
        return [whole], 0.0
    return [whole, whole + 1], fraction


def fopdt_weights(dt: float, tau: float, fraction: float, a: float, gain: float) -> list[float]:
    """Input weights for u_{t-d} (and u_{t-d-1} when the dead time is d samples plus a fraction)."""
    if fraction == 0.0:
        return [gain * (1 - a)]
    part = math.exp(-(dt - fraction) / tau)
    return [gain * (1 - part), gain * (part - a)]


def history_name(out: str, n: int) -> str:
    """The state holding output `out` n samples back: the output's own name for n = 0, then out_y1, ..."""
    return out if n == 0 else f"{out}_y{n}"


def register_name(out: str, key: str | None, n: int) -> str:
    """The state holding an input n samples back: out_u0, out_u1, ... in a block with one input (key
    None), out_INPUT_u0, ... for each input of a block with several."""
    return f"{out}_u{n}" if key is None else f"{out}_{key}_u{n}"


def part_name(out: str, u: str) -> str:
    """The state holding the part of output `out` due to input u, in a fopdt block with several inputs."""
    return f"{out}_{u}"


def block_roles(out: str, inputs: list[str], registers: list[int], history: int, parts: bool):
    """A block's internal states as (name, (output, kind, key, n)): the output and its past values
    (kind "history"), the part due to each input after the first (a fopdt block with several inputs)
    and the past values of each input (registers, as many per input as `registers` says)."""
    key = {u: None if len(inputs) == 1 else u for u in inputs}
    roles = [(history_name(out, n), (out, "history", None, n)) for n in range(history)]
    if parts:
        roles += [(part_name(out, u), (out, "part", u, 0)) for u in inputs[1:]]
    for u, count in zip(inputs, registers):
        roles += [(register_name(out, key[u], n), (out, "register", key[u], n)) for n in range(count)]
    return roles


def describe_role(role: tuple) -> str:
    """What an internal block state holds, for messages."""
    out, kind, key, n = role
    if kind == "history":
        return f"output {out!r}" + (f" {n} samples back" if n else "")
    if kind == "part":
        return f"the part of output {out!r} due to input {key!r}"
    return f"a past value of {'the block input' if key is None else f'input {key!r}'} (output {out!r})"
