"""The typed syntax tree of a .jmlg file: small immutable nodes, each with its source position."""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass, field

from .diagnostics import Pos


@dataclass(frozen=True)
class Expr:
    """An expression node. `op` is one of: number (args = (value,)), var (name,),
    indexed (name, lag) with lag an int offset from t or None for an absolute index in `index`,
    call (name, *args), add, sub, mul, div, pow, neg (operands), matrix (rows of entries: a NumberRows
    for a one-line literal of numbers only)."""

    op: str
    args: tuple
    pos: Pos = Pos()
    index: int | None = None  # absolute time index for indexed nodes such as h[0]


class NumberRows(Sequence):
    """The rows of a one-line matrix literal of numbers only, `[0.12 -3.4e-05; 1, 2]` (the grammar's
    NUMERIC_MATRIX token), as a matrix node's args: read when first walked into the number nodes the
    general `row` rule gives, each at its own column; `values()` reads the numbers alone. A learned
    spec's matrices hold hundreds of thousands of entries, and only an error that points at one of them
    needs its node."""

    def __init__(self, text: str, pos: Pos, entries: re.Pattern):
        self.text = text  # the whole token, brackets included, on one line
        self.pos = pos  # where the token starts
        self._entries = entries  # matches each entry and each `;` of the text
        self._rows = None

    def values(self) -> list[list[float]]:
        """The entries' values row by row (rows may differ in length, as written): the floats the
        number nodes hold."""
        return [[float(x) for x in row.replace(",", " ").split()] for row in self.text[1:-1].split(";")]

    @property
    def rows(self) -> tuple:
        """The rows as tuples of number nodes (made once)."""
        if self._rows is None:
            line, column = self.pos.line, self.pos.column
            rows, row = [], []
            for m in self._entries.finditer(self.text):
                if m.group() == ";":
                    rows.append(tuple(row))
                    row = []
                else:
                    row.append(Expr("number", (float(m.group()),), Pos(line, column + m.start())))
            rows.append(tuple(row))
            self._rows = tuple(rows)
        return self._rows

    def __getitem__(self, index):
        return self.rows[index]

    def __len__(self):
        return self.text.count(";") + 1

    def __eq__(self, other):
        return self.rows == (other.rows if isinstance(other, NumberRows) else other)

    def __hash__(self):
        return hash(self.rows)

    def __repr__(self):
        return repr(self.rows)


@dataclass(frozen=True)
class Name:
    """A name as written, with where it was written."""

    text: str
    pos: Pos


@dataclass(frozen=True)
class Target:
    """Left side of a mode statement: `h[t]`, `h[0]`, `level`, or a matrix name such as `A`."""

    name: Name
    lag: int | None = None  # 0 for x[t]; None when not indexed by t
    index: int | None = None  # absolute index, as in h[0]


@dataclass(frozen=True)
class Decl:
    """An input, output or state declaration."""

    kind: str  # "input" | "output" | "state"
    name: Name
    unit: str | None = None
    value: Expr | None = None
    sd: Expr | None = None
    gate: Expr | str | None = None  # an output's gross-error gate in standard deviations, or "off"


@dataclass(frozen=True)
class Assign:
    """`name = expr` in param/let declarations, mode overrides and linearisation points; or, for a
    parameter, `name ~ Prior(...)`: unknown, with a prior (expr None until the checker gives it a value)."""

    name: Name
    expr: Expr | None
    prior: Dist | None = None


@dataclass(frozen=True)
class ModeDecl:
    """A mode in a `modes` list: its name, quoted description and parameter overrides."""

    name: Name
    description: str | None = None
    overrides: tuple[Assign, ...] = ()


@dataclass(frozen=True)
class ProbItem:
    """One entry of a probability rule list: `name p`, `stay p` or `otherwise uniform`."""

    kind: str  # "named" | "stay" | "otherwise"
    pos: Pos
    name: Name | None = None
    value: Expr | None = None


@dataclass(frozen=True)
class Probabilities:
    """An `initial` or `transitions` statement in one of its forms."""

    keyword: str  # "initial" | "transitions"
    pos: Pos
    matrix: Expr | None = None
    rules: tuple[ProbItem, ...] = ()
    arrows: tuple[tuple[Name, tuple[ProbItem, ...]], ...] = ()


@dataclass(frozen=True)
class Noise:
    """`noise process s, measurement s`: standard deviations by kind, plant-wide or in a mode; a
    `measurement ~ HalfNormal(0.1)` item is unknown, with a prior, until the checker gives it a value."""

    items: tuple[tuple[Name, Expr | Dist], ...]
    pos: Pos


@dataclass(frozen=True)
class Dist:
    """Right side of `~`: Normal(mean, sd), fopdt(...), arx(...)."""

    name: Name
    positional: tuple[Expr, ...] = ()
    keywords: tuple[tuple[Name, Expr, str | None], ...] = ()  # (key, value, unit)
    at: tuple[Name, Expr, Expr] | None = None  # operating point: input value -> output value
    end: Pos = Pos()  # just after the closing parenthesis (where a fitted value's text ends)


@dataclass(frozen=True)
class Statement:
    """A statement inside a mode: `target ~ dist`, `target = expr` or a mode-level `noise`."""

    kind: str  # "sample" | "assign" | "noise" | "der" (an ODE equation in a mode block: refused by the checker)
    pos: Pos
    target: Target | None = None
    dist: Dist | None = None
    expr: Expr | None = None
    noise: Noise | None = None


@dataclass(frozen=True)
class ModeBlock:
    """`mode NAME like BASE { ... }`: the statements that define (or change) one mode."""

    name: Name
    like: Name | None
    statements: tuple[Statement, ...]
    pos: Pos


@dataclass(frozen=True)
class Derivative:
    """`der(state) = expr` in an `ode` block."""

    state: Name
    expr: Expr


@dataclass(frozen=True)
class LinearizeAt:
    """`linearize at ...` as written: each mode's steady state, one mode's, or a given point."""

    kind: str  # "each" | "mode" | "point"
    pos: Pos
    mode: Name | None = None
    point: tuple[Assign, ...] = ()


@dataclass
class Spec:
    """A whole parsed file, statements grouped by kind in source order."""

    path: str
    lines: list[str]
    plant: Name | None = None
    sample: tuple[float, Name | None, Pos] | None = None
    decls: list[Decl] = field(default_factory=list)
    params: list[Assign] = field(default_factory=list)
    lets: list[Assign] = field(default_factory=list)
    modes: list[ModeDecl] = field(default_factory=list)
    initial: list[Probabilities] = field(default_factory=list)
    transitions: list[Probabilities] = field(default_factory=list)
    noise: list[Noise] = field(default_factory=list)
    blocks: list[ModeBlock] = field(default_factory=list)
    ode: list[Derivative] = field(default_factory=list)
    ode_unit: tuple[str, Pos] | None = None
    linearize: list[LinearizeAt] = field(default_factory=list)
    repeated: list[tuple[str, Pos]] = field(default_factory=list)  # single statements given twice
