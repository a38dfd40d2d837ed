"""An ODE plant's `ode` block and outputs as sympy expressions (lang.plant.Equations), in the symbols of
its states, inputs and parameters, with lets expanded; and the checks that need the equations: a
divisor that is zero with one mode's parameter values, the point given to `linearize at`. The
compiler differentiates and linearises them (jmlgdsl.compile.ode)."""

from __future__ import annotations

import numpy as np

from ..names import suggest
from . import syntax as S
from .evaluate import NOT_FINITE, EvalError, LetExpander, UnknownName, evaluate_number, finite_real, symbolic
from .plant import Equations
from .diagnostics import Report
from .symbolic import sp
from .durations import time_in_seconds


def equations(spec: S.Spec, lets: dict, time_unit: str, report: Report) -> Equations:
    """The derivatives and outputs of an ODE plant (`time_unit`: the sample's, for derivatives without
    `ode [unit]`); problems are reported where they are written."""
    decls = {"input": [], "output": [], "state": []}
    for d in spec.decls:
        decls[d.kind].append(d)
    states, inputs = [d.name.text for d in decls["state"]], [d.name.text for d in decls["input"]]
    params = [a.name.text for a in spec.params]
    xs, us, ps = ([sp.Symbol(n, real=True) for n in names] for names in (states, inputs, params))
    lookup = resolver(decls["output"], lets, dict(zip(states, xs)), dict(zip(inputs, us)), dict(zip(params, ps)))
    rates = _derivatives(spec, states, report)
    for d in decls["state"]:
        if d.name.text not in rates:
            report.error(f"state {d.name.text!r} has no equation: add 'der({d.name.text}) = ...' to the ode block",
                         d.name.pos)
    f = sp.Matrix([_symbolic(rates[s].expr, lookup, report) if s in rates else 0 for s in states])
    h = sp.Matrix([_output_expr(d, lookup, states, xs, report) for d in decls["output"]])
    if not decls["output"]:
        report.error("a plant needs at least one output: 'output STATE' measures a state", S.Pos(1, 1))
    unit, pos = spec.ode_unit or (time_unit, spec.sample[2] if spec.sample else S.Pos())
    seconds = time_in_seconds(1.0, S.Name(unit, pos), report)
    return Equations(states, inputs, [d.name.text for d in decls["output"]], params, (xs, us, ps), f, h, unit,
                     seconds)


def resolver(outputs: list[S.Decl], lets: dict, xs: dict, us: dict, ps: dict):
    """The name lookup for symbolic(): states, inputs and parameters are symbols (or a parameter's
    value), lets are expanded."""
    known = [*xs, *us, *ps, *lets]
    measured = {d.name.text for d in outputs} - set(xs)
    expand_let = LetExpander(lets)

    def lookup(node: S.Expr):
        name = node.args[0]
        if node.op == "indexed":
            raise EvalError(f"an ODE uses values at the current time: write {name}, not {name}[...]", node)
        for table in (xs, us, ps):
            if name in table:
                return table[name]
        if name in lets:
            return expand_let(node, lambda e: symbolic(e, lookup))
        if name in measured:
            raise EvalError(f"{name!r} is an output; equations use states, inputs and parameters", node)
        raise UnknownName(f"unknown name {name!r}{suggest(name, known)}", node)

    return lookup


def _symbolic(expr: S.Expr, lookup, report: Report):
    """The sympy form of an equation or output, or NaN with the problem reported at its place."""
    try:
        value = symbolic(expr, lookup)
    except EvalError as exc:
        report.error(str(exc), exc.node.pos)
        return sp.nan
    if not finite_real(value):
        report.error(NOT_FINITE, expr.pos)
        return sp.nan
    return value


def _derivatives(spec: S.Spec, states: list[str], report: Report) -> dict[str, S.Derivative]:
    """der() equations by state; reports der() of a non-state and a state given twice."""
    declared = {d.name.text: d.kind for d in spec.decls} | {a.name.text: "parameter" for a in spec.params} \
        | {a.name.text: "let" for a in spec.lets}
    rates: dict[str, S.Derivative] = {}
    for eq in spec.ode:
        name = eq.state.text
        if name not in states:
            kind = declared.get(name)
            hint = (f"; declare it with 'state {name} = GUESS'" if kind else suggest(name, states)) \
                if kind != "output" else "; an output is measured, der() takes a state"
            report.error(f"der({name}): {name!r} is {f'a {kind}' if kind else 'not declared'}, not a state{hint}",
                         eq.state.pos)
        elif name in rates:
            report.error(f"der({name}) is given twice (first at line {rates[name].state.pos.line})", eq.state.pos)
        else:
            rates[name] = eq
    return rates


def _output_expr(d: S.Decl, lookup, states: list[str], xs: list, report: Report):
    """An output's expression: the state of the same name, or its own `= expr` depending on a state."""
    if d.value is None:
        if d.name.text in states:
            return xs[states.index(d.name.text)]
        report.error(f"output {d.name.text!r} is not a state: measure a state ('output STATE') or give its "
                     f"expression ('output {d.name.text} = ...'){suggest(d.name.text, states)}", d.name.pos)
        return sp.nan
    expr = _symbolic(d.value, lookup, report)
    if expr is not sp.nan and not expr.free_symbols & set(xs):
        report.error(f"output {d.name.text!r} depends on no state, so it measures nothing of the plant; "
                     f"write it in terms of the states ({', '.join(states)})", d.value.pos)
    return expr


def check_divisors(spec: S.Spec, lets: dict, mode: str, env: dict, report: Report):
    """The equations with one mode's parameter values: a divisor that is zero there (`x / a` with
    `a = 0` in the mode) is reported where it is written, as in a plant without ODEs."""
    states, inputs = ({d.name.text: sp.Symbol(d.name.text, real=True) for d in spec.decls if d.kind == kind}
                      for kind in ("state", "input"))
    outputs = [d for d in spec.decls if d.kind == "output"]
    lookup = resolver(outputs, lets, states, inputs, {name: sp.Float(value) for name, value in env.items()})
    for expr in [eq.expr for eq in spec.ode] + [d.value for d in outputs if d.value is not None]:
        try:
            symbolic(expr, lookup)
        except EvalError as exc:
            report.error(f"{exc} in mode {mode!r}", exc.node.pos)


def given_point(how: S.LinearizeAt, states: list[str], inputs: list[str], u_bar: np.ndarray, nominal: dict,
                report: Report) -> tuple[np.ndarray, np.ndarray]:
    """`linearize at x = v, ...`: every state given; inputs default to their operating values."""
    x, u = np.full(len(states), np.nan), np.array(u_bar, dtype=float)
    for a in how.point:
        name = a.name.text
        value = evaluate_number(a.expr, nominal, report, what=f"the value of {name}")
        if name in states:
            x[states.index(name)] = value
        elif name in inputs:
            u[inputs.index(name)] = value
        else:
            report.error(f"{name!r} is not a state or an input{suggest(name, states + inputs)}", a.name.pos)
    given = {a.name.text for a in how.point}
    missing = [s for s in states if s not in given]
    if missing:
        report.error(f"the operating point needs every state: add {', '.join(f'{s} = ...' for s in missing)}",
                     how.pos)
    return x, u
