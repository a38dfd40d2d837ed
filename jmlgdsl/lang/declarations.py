"""The first stage of checking a spec: its declarations (names, sample time, parameters, modes with
`like` and overrides resolved, transition matrix and prior, noise defaults), checked and evaluated
into what every mode's values are evaluated from (lang.values). Every problem is reported with its
position."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..names import suggest
from . import syntax as S
from .evaluate import evaluate_number
from .limits import MAX_MODES, MAX_VARIABLES, check_sd
from .probabilities import initial_distribution, transition_matrix
from .diagnostics import Report
from .durations import time_in_seconds
from .unknowns import Unknown, resolve

NOISE_KINDS = ("process", "measurement", "scale")


@dataclass
class ModeInfo:
    """One mode after resolving `like`: its parameter overrides and its model statements, in order."""

    name: str
    description: str
    pos: S.Pos
    overrides: list[S.Assign] = field(default_factory=list)
    statements: list[S.Statement] = field(default_factory=list)
    like: S.Name | None = None
    inputs: list[S.Assign] = field(default_factory=list)  # the mode's own operating values of inputs


@dataclass
class Declared:
    """A spec's declarations, checked: the plant-wide values, and what every mode's values are
    evaluated from."""

    spec: S.Spec
    name: str
    inputs: list[S.Decl]
    outputs: list[S.Decl]
    states: list[S.Decl]
    nominal: dict[str, float]  # the parameters' values without any mode's overrides
    lets: dict[str, S.Assign]
    modes: list[ModeInfo]
    P: np.ndarray
    p0: np.ndarray
    noise: dict[str, float]  # the plant-wide noise levels by kind
    dt: float  # seconds
    time_unit: str  # the unit the sample time was written in: time constants without a unit use it
    unknowns: list[Unknown]

    def mode_params(self, mode: ModeInfo, report: Report) -> dict[str, float]:
        """Parameter values in a mode: the nominal list re-evaluated with the mode's overrides."""
        overrides = {a.name.text: a for a in mode.overrides}
        values: dict[str, float] = {}
        for a in self.spec.params:
            src = overrides.get(a.name.text, a)
            env = self.nominal if src is not a else values
            values[a.name.text] = evaluate_number(src.expr, env, report, what=f"parameter {a.name.text}")
        return values


def evaluate_params(params: list[S.Assign], report: Report) -> dict[str, float]:
    """Nominal parameter values in declaration order: each may use the ones declared before it."""
    env: dict[str, float] = {}
    for a in params:
        env[a.name.text] = evaluate_number(a.expr, env, report, what=f"parameter {a.name.text}")
    return env


def declare(spec: S.Spec, values: dict | None = None) -> tuple[Declared, Report]:
    """Check a spec's declarations: names, sample time, parameters, modes with `like` and overrides
    resolved, transition matrix and prior, noise defaults. SpecError with every problem found; the
    returned Report keeps the warnings, and is where evaluate() goes on reporting. Unknowns take
    `values` as check() says."""
    report = Report(spec.path, spec.lines)
    _check_counts(spec, report)
    report.raise_errors()
    spec, unknowns = resolve(spec, values, report)
    for what, pos in spec.repeated:
        report.error(f"'{what}' is given more than once", pos)
    _check_declarations(spec, report)
    dt, unit = _sample_time(spec, report)
    nominal = evaluate_params(spec.params, report)
    modes = _modes(spec, report, set(nominal), {d.name.text for d in spec.decls if d.kind == "input"})
    names = [m.name for m in modes]
    P = transition_matrix(spec, names, nominal, report)
    p0 = initial_distribution(spec, names, nominal, report)
    noise = noise_values(spec.noise, nominal, report, plant_level=True)
    report.raise_errors()
    decls = {"input": [], "output": [], "state": []}
    for d in spec.decls:
        decls[d.kind].append(d)
    name = spec.plant.text if spec.plant else Path(spec.path).stem
    return Declared(spec, name, decls["input"], decls["output"], decls["state"], nominal,
                    {a.name.text: a for a in spec.lets}, modes, P, p0, noise, dt, unit, unknowns), report


def _check_counts(spec: S.Spec, report: Report):
    """At most MAX_MODES modes and MAX_VARIABLES inputs, outputs or states; the first one over is named."""
    modes = [m.name for m in spec.modes] or list({b.name.text: b.name for b in spec.blocks}.values())
    if len(modes) > MAX_MODES:
        report.error(f"too many modes: {len(modes):,}, at most {MAX_MODES:,} are allowed", modes[MAX_MODES].pos)
    for kind in ("input", "output", "state"):
        names = [d.name for d in spec.decls if d.kind == kind]
        if len(names) > MAX_VARIABLES:
            report.error(f"too many {kind}s: {len(names):,}, at most {MAX_VARIABLES:,} are allowed",
                         names[MAX_VARIABLES].pos)


def _check_declarations(spec: S.Spec, report: Report):
    """Every name is declared once; an output may share a state's name only to measure that state."""
    seen: dict[str, tuple[str, S.Name]] = {}
    entries = [(d.kind, d.name) for d in spec.decls] + [("param", a.name) for a in spec.params] \
        + [("let", a.name) for a in spec.lets] + [("mode", m.name) for m in spec.modes]
    for kind, name in entries:
        if name.text in seen:
            first_kind, first = seen[name.text]
            measured_state = {kind, first_kind} == {"state", "output"}
            if measured_state:
                out = next(d for d in spec.decls if d.kind == "output" and d.name.text == name.text)
                if out.value is None:
                    continue
            report.error(f"{name.text!r} is already declared as {_a(first_kind)} at line {first.pos.line}",
                         name.pos)
        else:
            seen[name.text] = (kind, name)
    for d in spec.decls:
        if d.sd is not None and d.kind == "input":
            report.error("only states and outputs (the states of their blocks) take an initial standard deviation "
                         "('sd')", d.sd.pos)
    if not spec.modes:  # mode blocks declare the modes
        for b in spec.blocks:
            if b.name.text in seen:
                report.error(f"{b.name.text!r} is declared as {_a(seen[b.name.text][0])}, not a mode", b.name.pos)


def _a(kind: str) -> str:
    """The kind with its indefinite article, for messages."""
    return f"an {kind}" if kind[0] in "aeiou" else f"a {kind}"


def _sample_time(spec: S.Spec, report: Report) -> tuple[float, str]:
    """The sample time in seconds and the unit it was written in (time constants without a unit use it)."""
    if spec.sample is None:
        report.error("missing sample time: add a line such as 'sample 1 s'", S.Pos(1, 1))
        return 1.0, "s"
    value, unit, pos = spec.sample
    if value <= 0:
        report.error("the sample time must be positive", pos)
        return 1.0, "s"
    if unit is None:
        report.error("the sample time needs a unit: s, min or h (e.g. 'sample 0.1 min')", pos)
        return value, "s"
    seconds = time_in_seconds(value, unit, report)
    if not np.isfinite(seconds):
        report.error("the sample time is not a finite number of seconds", pos)
        return 1.0, unit.text
    return seconds, unit.text


def _modes(spec: S.Spec, report: Report, params: set[str], inputs: set[str]) -> list[ModeInfo]:
    """Mode list in declaration order, with block statements attached and `like` resolved. A mode's
    `NAME = value` sets a parameter (an override) or an input's operating value in that mode."""
    infos: dict[str, ModeInfo] = {}
    for m in spec.modes:
        if m.name.text in infos:
            continue  # duplicate reported by _check_declarations
        _check_overrides(m.overrides, params | inputs, report)
        infos[m.name.text] = ModeInfo(m.name.text, m.description or "", m.name.pos,
                                      [a for a in m.overrides if a.name.text in params],
                                      inputs=[a for a in m.overrides if a.name.text in inputs])
    declared = bool(spec.modes)
    seen_blocks: dict[str, S.ModeBlock] = {}
    for b in spec.blocks:
        name = b.name.text
        if name in seen_blocks:
            report.error(f"mode {name!r} already has a block at line {seen_blocks[name].pos.line}", b.name.pos)
            continue
        seen_blocks[name] = b
        if name not in infos:
            if declared:
                report.error(f"unknown mode {name!r}{suggest(name, infos)}", b.name.pos)
                continue
            infos[name] = ModeInfo(name, "", b.name.pos)
        info = infos[name]
        info.like = b.like
        _check_defined_once(b, report)
        for st in b.statements:
            if st.kind == "der":
                report.error(f"der({st.target.name.text}) belongs in the 'ode' block: the equations are the "
                             "same in every mode, which changes parameters (e.g. 'U = 1.1') or noise",
                             st.target.name.pos)
                continue
            plain = st.kind == "assign" and st.target.lag is None and st.target.index is None
            if plain and st.target.name.text in params:
                info.overrides.append(S.Assign(st.target.name, st.expr))
            elif plain and st.target.name.text in inputs:
                info.inputs.append(S.Assign(st.target.name, st.expr))
            else:
                info.statements.append(st)
    if not infos:
        report.error("no modes: declare them with 'modes a, b, ...' or write 'mode NAME { ... }' blocks",
                     S.Pos(1, 1))
    for info in infos.values():
        _resolve_like(info, infos, report)
    return list(infos.values())


def _check_defined_once(block: S.ModeBlock, report: Report):
    """A block defines each state or output once: a second `y ~ ...` (or `y[t] = ...`) would silently
    replace the first. (A mode `like` another may redefine what it inherits: that is its purpose.)"""
    first: dict[str, S.Statement] = {}
    for st in block.statements:
        defines = st.kind == "sample" or (st.kind == "assign" and st.target.lag == 0)
        if not defines:
            continue
        name = st.target.name.text
        if name in first:
            report.error(f"{name} is already defined in mode {block.name.text!r} at line "
                         f"{first[name].target.name.pos.line}; a mode block defines each variable once",
                         st.target.name.pos)
        else:
            first[name] = st


def _check_overrides(overrides, names: set[str], report: Report):
    """A mode may only set declared parameters and inputs."""
    for a in overrides:
        if a.name.text not in names:
            report.error(f"{a.name.text!r} is not a parameter or an input{suggest(a.name.text, names)}", a.name.pos)


def _resolve_like(info: ModeInfo, infos: dict[str, ModeInfo], report: Report):
    """Prepend the base mode's overrides and statements, through the whole chain of bases, to this
    mode's own. The chain is walked with a loop, so a long chain of `like`s needs no deep recursion."""
    chain = [info]
    while chain[-1].like is not None:
        current, base_name = chain[-1], chain[-1].like.text
        names = [m.name for m in chain]
        if base_name in names:
            report.error(f"mode {current.name!r} is 'like' itself through {' -> '.join(names + [base_name])}",
                         current.like.pos)
        elif base_name not in infos:
            report.error(f"unknown mode {base_name!r}{suggest(base_name, infos)}", current.like.pos)
        else:
            chain.append(infos[base_name])
            continue
        current.like = None
    for derived, base in reversed(list(zip(chain, chain[1:]))):
        derived.overrides = base.overrides + derived.overrides
        derived.inputs = base.inputs + derived.inputs
        derived.statements = base.statements + derived.statements
        derived.description = derived.description or base.description
        derived.like = None


def noise_values(stmts: list[S.Noise], env, report: Report, plant_level: bool) -> dict[str, float]:
    """`noise process s, measurement s`: standard deviations by kind."""
    out: dict[str, float] = {}
    for st in stmts:
        for name, expr in st.items:
            if name.text not in NOISE_KINDS:
                report.error(f"unknown noise kind {name.text!r}; use 'process', 'measurement' or 'scale'"
                             f"{suggest(name.text, NOISE_KINDS)}", name.pos)
                continue
            if name.text == "scale" and plant_level:
                report.error("'noise scale' multiplies one mode's noise: write it in a mode, e.g. "
                             "'mode anomaly like normal { noise scale 3 }'", name.pos)
                continue
            value = evaluate_number(expr, env, report, what=f"{name.text} noise")
            if name.text == "scale" and value <= 0:  # NaN: not evaluated, reported
                report.error(f"a noise scale must be a positive number (got {value:g})", expr.pos)
            elif value < 0:
                report.error(f"a noise standard deviation cannot be negative (got {value:g})", expr.pos)
            check_sd(value, expr.pos, report)
            if name.text in out and plant_level:
                report.error(f"{name.text} noise is given more than once", name.pos)
            out[name.text] = value
    return out
