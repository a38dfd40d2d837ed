"""Unknowns: the numbers a spec leaves to the data, written with a prior instead of a value.

    param U ~ LogNormal(log(1.2), 0.3)          # a parameter
    modes normal, fouled: U ~ Uniform(0.8, 1.2) # a mode's override (also `U ~ ...` in a mode block)
    noise measurement ~ HalfNormal(0.1)         # a noise level, plant-wide or in a mode

Before anything else is checked, each prior is replaced by a number: the value a fit asks for, or,
for a spec run as written, the prior's median (with a warning naming the unknown). The rest of the
checker and the compiler therefore only ever see numbers.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from ..names import suggest
from .priors import FAMILIES, Prior, PriorError
from . import syntax as S
from .evaluate import evaluate_number
from .diagnostics import Report


@dataclass(frozen=True)
class Unknown:
    """An unknown of a spec: its name ("U", "fouled.U", "noise.measurement", "fouled.noise.process"),
    its prior, and where it is written (from its name to the end of its prior, for rewriting)."""

    name: str
    prior: Prior
    pos: S.Pos
    end: S.Pos


def has_unknowns(spec: S.Spec) -> bool:
    """Whether the spec writes any prior (most do not, and then skip this module's work)."""
    params = {a.name.text for a in spec.params}
    overrides = [a for m in spec.modes for a in m.overrides]
    noise = [item for n in spec.noise for item in n.items]
    for b in spec.blocks:
        for st in b.statements:
            if st.kind == "noise":
                noise += st.noise.items
            elif st.kind == "sample" and st.target.lag is None and st.target.name.text in params:
                return True  # `U ~ ...` in a mode block: an override with a prior
    return any(a.prior is not None for a in spec.params + overrides) \
        or any(isinstance(v, S.Dist) for _, v in noise)


def resolve(spec: S.Spec, values: dict | None, report: Report) -> tuple[S.Spec, list[Unknown]]:
    """The spec with every prior replaced by a number, and its unknowns in source order.

    values: {unknown name: value} for every unknown (as a fit asks), or None: each prior's median,
    with a warning. A name in `values` that the spec does not have is a ValueError."""
    if not has_unknowns(spec):
        if values:
            raise ValueError(f"the spec has no unknowns, yet values were given for {', '.join(values)}")
        return spec, []
    resolver = _Resolver(spec, values, report)
    spec = resolver.run()
    seen: dict[str, Unknown] = {}
    for u in resolver.unknowns:
        if u.name in seen:
            report.error(f"{u.name} already has a prior at line {seen[u.name].pos.line}", u.pos)
        seen.setdefault(u.name, u)
    if values is None:
        for u in resolver.unknowns:
            report.warn(f"{u.name} is unknown: the spec runs with its prior's median {u.prior.median:.6g} "
                        f"({u.prior}); fit it to data with 'jmlgdsl fit'", u.pos)
    else:
        names = {u.name for u in resolver.unknowns}
        extra = [n for n in values if n not in names]
        if extra:
            raise ValueError(f"no unknown named {extra[0]!r}{suggest(extra[0], names)}")
    return spec, resolver.unknowns


class _Resolver:
    """Walks a spec once, replacing priors by values and collecting the unknowns."""

    def __init__(self, spec: S.Spec, values: dict | None, report: Report):
        self.spec, self.values, self.report = spec, values, report
        self.unknowns: list[Unknown] = []
        self.env: dict[str, float] = {}  # the parameters' values so far, for priors' arguments

    def run(self) -> S.Spec:
        spec = self.spec
        params = []
        for a in spec.params:
            if a.prior is not None:
                a = self._assign(a.name, a.name.text, a.prior)
            else:
                self.env[a.name.text] = evaluate_number(a.expr, self.env, self.report, what=f"parameter {a.name.text}")
            params.append(a)
        param_names = set(self.env)
        modes = [dataclasses.replace(m, overrides=tuple(
            self._assign(a.name, f"{m.name.text}.{a.name.text}", a.prior) if a.prior is not None else a
            for a in m.overrides)) for m in spec.modes]
        blocks = [dataclasses.replace(b, statements=tuple(self._statement(b.name.text, st, param_names)
                                                          for st in b.statements)) for b in spec.blocks]
        noise = [self._noise("", n) for n in spec.noise]
        self.unknowns.sort(key=lambda u: (u.pos.line, u.pos.column))
        return dataclasses.replace(spec, params=params, modes=modes, blocks=blocks, noise=noise)

    def _statement(self, mode: str, st: S.Statement, params: set[str]) -> S.Statement:
        if st.kind == "noise":
            return dataclasses.replace(st, noise=self._noise(f"{mode}.", st.noise))
        if st.kind == "sample" and st.target.lag is None and st.target.name.text in params:
            name = st.target.name
            a = self._assign(name, f"{mode}.{name.text}", st.dist)
            return S.Statement("assign", st.pos, target=st.target, expr=a.expr)
        return st

    def _noise(self, prefix: str, noise: S.Noise) -> S.Noise:
        items = tuple((name, self._value(name, f"{prefix}noise.{name.text}", v) if isinstance(v, S.Dist) else v)
                      for name, v in noise.items)
        return dataclasses.replace(noise, items=items)

    def _assign(self, name: S.Name, unknown: str, dist: S.Dist) -> S.Assign:
        value = self._value(name, unknown, dist)
        if "." not in unknown:
            self.env[unknown] = value.args[0]
        return S.Assign(name, value)

    def _value(self, name: S.Name, unknown: str, dist: S.Dist) -> S.Expr:
        """The number that stands for an unknown: asked for, or its prior's median (with a warning)."""
        prior = self._prior(dist)
        if prior is None:
            return S.Expr("number", (1.0,), dist.name.pos)  # the error is reported; any number will do
        self.unknowns.append(Unknown(unknown, prior, name.pos, dist.end))
        if self.values is None:
            value = prior.median
        elif unknown not in self.values:
            raise ValueError(f"no value given for the unknown {unknown!r}")
        else:
            value = float(self.values[unknown])
        return S.Expr("number", (value,), dist.name.pos)

    def _prior(self, dist: S.Dist) -> Prior | None:
        """The Prior a `~ Family(args)` writes; None, reported, when it makes none."""
        family = dist.name.text
        if family not in FAMILIES:
            self.report.error(f"unknown prior {family!r}: a parameter or noise level takes one of "
                              f"{', '.join(FAMILIES)}{suggest(family, FAMILIES)}", dist.name.pos)
            return None
        if dist.keywords or dist.at:
            self.report.error(f"{family} takes its arguments in order: {family}({', '.join(FAMILIES[family])})",
                              dist.name.pos)
            return None
        args = tuple(evaluate_number(e, self.env, self.report, what=f"an argument of {family}")
                     for e in dist.positional)
        try:
            return Prior(family, args)
        except PriorError as exc:
            if all(a == a for a in args):  # a NaN argument is already reported where it is written
                self.report.error(str(exc), dist.name.pos)
            return None
