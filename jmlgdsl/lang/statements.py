"""A mode's statements evaluated into values (lang.plant): generative `~` statements as coefficients
(extracted with sympy), literal matrices, initial values, and first-order-plus-dead-time and ARX
blocks with their numbers; and the internal states that the blocks add to the plant's layout. Every
problem is reported where it is written; jmlgdsl.compile writes the values into the mode's matrices."""

from __future__ import annotations

import math

import numpy as np

from ..names import suggest
from .evaluate import NOT_FINITE, EvalError, LetExpander, UnknownName, finite_numeric, finite_real, symbolic
from .limits import MAX_DELAY_SAMPLES, MAX_ORDER, check_sd
from .plant import (MATRIX_NAMES, Arx, Equation, Fopdt, Initial, Layout, Matrix, history_name, part_name,
                    register_name, show)
from .diagnostics import Report
from .symbolic import sp
from .syntax import Dist, Expr, Name, Statement
from .durations import time_in_seconds

BLOCK_FORMS = ("Normal", "fopdt", "arx")
FOPDT_KEYS = ("gain", "tau", "delay")
ARX_KEYS = ("a", "b", "na", "nb")
OPERATING_KEYS = ("u_ss", "y_ss")  # the operating point of a block with several inputs (`at` names one)


class Statements:
    """Evaluates the statements of one mode, given the layout and the mode's parameter values."""

    def __init__(self, layout: Layout, params: dict, lets: dict, report: Report, dt: float, time_unit: str):
        self.layout, self.params, self.lets, self.report = layout, params, lets, report
        self.dt, self.time_unit = dt, time_unit
        self.expand_let = LetExpander(lets)

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

    # ------------------------------------------------------------- the blocks' internal states
    def reserve_block_states(self, statements: list[Statement], declared: dict[str, Name]):
        """Add the internal states of this mode's fopdt/arx blocks to the layout, per output the union
        over modes (by name); a name that would hold two different things, or a declared state's
        (`declared`: name -> where it is declared), is an error."""
        layout = self.layout
        for st in statements:
            out = st.target.name.text if st.kind == "sample" else None
            if out not in layout.outputs or st.dist.name.text not in ("fopdt", "arx"):
                continue
            roles = self.internal_states(out, st.dist)
            if roles is None:
                continue
            if len(st.dist.positional) == 1:
                layout.single_inputs.setdefault(out, st.dist.positional[0].args[0])
            block = layout.block_states.setdefault(out, [])
            for s, role in roles:
                held = layout.block_roles.get(s)
                if s in declared:
                    self.report.error(f"state {s!r} is also an internal state of the {st.dist.name.text} block for "
                                      f"output {out!r}; rename the state", declared[s].pos)
                elif held is not None and held != role:
                    self.report.error(f"the {st.dist.name.text} block needs a state {s!r} for {describe_role(role)}, "
                                      f"but that name already holds {describe_role(held)}; rename an input or output",
                                      st.dist.name.pos)
                elif held is None:
                    block.append(s)
                    layout.states.append(s)
                    layout.block_roles[s] = role

    # ------------------------------------------------------------- statements
    def evaluate(self, statements: list[Statement]) -> tuple[list, set, set]:
        """The mode's statements as values, in order, with the states and the outputs they give
        equations to. Each statement accounts for what it defines whether or not it evaluates: one with
        an error (reported there, or already reported for the mode it is `like`) is the root cause, not
        to be followed by 'has no equation'."""
        values, states_defined, outputs_defined = [], set(), set()
        for st in statements:
            states, outputs = self._defines(st)
            states_defined.update(states)
            outputs_defined.update(outputs)
            value = self._sample(st) if st.kind == "sample" else self._assign(st) if st.kind == "assign" else None
            if value is not None:
                values.append(value)
        return values, states_defined, outputs_defined

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

    def _sample(self, st: Statement):
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
            return self._normal(st, state=lay.states.index(name))
        elif name in lay.outputs:
            j = lay.outputs.index(name)
            if dist.name.text == "Normal":
                return self._normal(st, output=j)
            elif dist.name.text == "fopdt":
                return self._fopdt(dist, j)
            else:
                return self._arx(dist, j)
        else:
            self.report.error(f"{self._unknown(name)}: the left side of '~' is a state or an output",
                              st.target.name.pos)

    def _normal(self, st: Statement, state: int | None = None, output: int | None = None):
        d = st.dist
        if len(d.positional) != 2 or d.keywords or d.at:
            self.report.error("Normal takes two arguments: Normal(mean, standard deviation)", d.name.pos)
            return
        sd = self.number(d.positional[1], "a standard deviation")
        if sd < 0:
            self.report.error(f"a standard deviation cannot be negative (got {sd:g}); Normal takes (mean, sd)",
                              d.positional[1].pos)
        check_sd(sd, d.positional[1].pos, self.report)
        return self._equation(d.positional[0], sd, state, output)

    def _equation(self, mean: Expr, sd: float, state: int | None, output: int | None) -> Equation | None:
        coeffs = self.affine(mean, in_state_equation=state is not None)
        return None if coeffs is None else Equation(state, output, *coeffs, sd)

    def _assign(self, st: Statement):
        lay, t, name = self.layout, st.target, st.target.name.text
        if t.index is not None:
            if t.index != 0 or name not in lay.states:
                what = "an initial value is given as STATE[0] = value" if name in lay.states else \
                    f"{self._unknown(name)}: only states have an initial value NAME[0]"
                self.report.error(what, t.name.pos)
                return
            return Initial(lay.states.index(name), self.number(st.expr, "an initial value"))
        elif t.lag == 0:
            if name in lay.states:
                return self._equation(st.expr, 0.0, lay.states.index(name), None)
            elif name in lay.outputs:
                return self._equation(st.expr, 0.0, None, lay.outputs.index(name))
            else:
                self.report.error(self._unknown(name), t.name.pos)
        elif t.lag is not None:
            self.report.error(f"an equation defines {name}[t], not {name}[t{t.lag:+d}]", t.name.pos)
        elif name in MATRIX_NAMES:
            return self._matrix(name, st)
        else:
            self.report.error(f"{self._unknown(name)}; in a mode block, assign a matrix "
                              f"({', '.join(MATRIX_NAMES)}), a parameter, or write NAME[t] ~ ...", t.name.pos)

    def _matrix(self, name: str, st: Statement) -> Matrix | None:
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
        return Matrix(name, value)

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
            self.report.error("a block with several inputs gives its operating point as 'u_ss [...], y_ss VALUE', "
                              "with one u_ss value per input", d.at[0].pos)
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

    def _fopdt(self, d: Dist, j: int) -> Fopdt | None:
        """The sum over the inputs of K e^{-θs}/(τs+1): each input's gain, time constant and dead time,
        resolved into the whole-sample lags that reach the lag state and the fraction left over."""
        kw = self._keywords(d, self._allowed(d, FOPDT_KEYS), ("gain", "tau"))
        ks = self._block_inputs(d)
        if kw is None or ks is None:
            return None
        n = len(ks)
        gain = self._vector(kw["gain"][0], n, "gain", "a gain")
        tau, delay = self.fopdt_times(kw, n)
        if np.isnan(tau).any() or np.isnan(delay).any():
            return None  # a value that could not be evaluated is already reported
        if not (tau > 0).all():
            self.report.error(f"the time constant must be positive (got {tau[~(tau > 0)][0]:g} s)", kw["tau"][0].pos)
            return None
        if (delay < 0).any():
            self.report.error(f"the dead time cannot be negative (got {delay[delay < 0][0]:g} s)",
                              kw["delay"][0].pos)
            return None
        u_ss, y_ss = self._operating_point(d, kw, ks)
        lags, fractions = zip(*(fopdt_lags(self.dt, t, th) for t, th in zip(tau, delay)))
        return Fopdt(j, ks, gain, tau, list(lags), list(fractions), u_ss, y_ss)

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

    def _arx(self, d: Dist, j: int) -> Arx | None:
        """y_t + a1 y_{t-1} + ... + a_na y_{t-na} = sum over the inputs of b0 u_t + ... + b_nb u_{t-nb}, plus
        e_t: the coefficients, checked against `na` and `nb` when they are given, and the operating point."""
        kw = self._keywords(d, self._allowed(d, ARX_KEYS), ("a", "b"))
        ks = self._block_inputs(d)
        if kw is None or ks is None:
            return None
        coeffs = self.arx_coefficients(kw, len(ks))
        if coeffs is None:
            return None
        a, b = coeffs
        for key, count, extra in (("na", a.size, 0), ("nb", b.shape[1], -1)):
            if key in kw:
                order = self.number(kw[key][0], f"the order {key}")
                if order != count + extra:
                    self.report.error(f"{key} = {order:g} but {count} coefficients are given "
                                      f"({'a1..a_na' if key == 'na' else 'b0..b_nb'})", kw[key][0].pos)
                    return None
        u_ss, y_ss = self._operating_point(d, kw, ks)
        return Arx(j, ks, a, b, u_ss, y_ss)

    def internal_states(self, out: str, d: Dist) -> list[tuple[str, tuple]] | None:
        """The internal states of a fopdt or arx block on output `out`, with their roles; None when the
        block is not well formed (reported here or when it is evaluated) or its dead time is beyond the limit."""
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
