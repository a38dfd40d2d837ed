"""The checked plant: what the checker (jmlgdsl.lang.check) hands to the compiler (jmlgdsl.compile).
It holds values, not syntax: names, numbers, numpy arrays and, for a plant written as ODEs, sympy
expressions, with the source positions of what the compiler may still have to report (a mode, an
operating point); and the positions and the Report that located diagnostics go to. Besides the
checker's entry points (lang.check: a spec file or text to a checked plant), the compiler imports
nothing else of the language."""

from __future__ import annotations

import warnings
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from ..errors import Diagnostic, SpecError, SpecWarning
from .limits import MAX_ERRORS, MAX_MAGNITUDE  # noqa: F401  (MAX_MAGNITUDE bounds what the compiler makes)


@dataclass(frozen=True)
class Pos:
    """A 1-based line and column in the source file."""

    line: int = 0
    column: int = 0


class Report:
    """Diagnostics for one source file."""

    def __init__(self, path: str, lines: list[str]):
        self.path = path
        self.lines = lines
        self.errors: list[Diagnostic] = []  # the first MAX_ERRORS distinct errors, in the order reported
        self.warnings: list[Diagnostic] = []
        self._seen: set[Diagnostic] = set()  # every distinct error: repeats are dropped in constant time
        self.held: list[tuple[str, Pos | None]] = []  # errors held back (holding()) until release()
        self._holding = False

    def _diagnostic(self, message: str, pos: Pos | None, severity: str) -> Diagnostic:
        pos = pos or Pos()
        src = self.lines[pos.line - 1] if 0 < pos.line <= len(self.lines) else None
        return Diagnostic(message, self.path, pos.line, pos.column, src, severity)

    def error(self, message: str, pos: Pos | None = None):
        """Record an error; a repeat of one already recorded is dropped."""
        if self._holding:
            self.held.append((message, pos))
            return
        d = self._diagnostic(message, pos, "error")
        if d not in self._seen:
            self._seen.add(d)
            if len(self.errors) < MAX_ERRORS:
                self.errors.append(d)

    @contextmanager
    def holding(self):
        """Hold back the errors reported inside, until release(): the checker's, in the values the compiler
        applies last, so that one that fails before it gets there (a mode without a steady state)
        reports that alone."""
        self._holding = True
        try:
            yield
        finally:
            self._holding = False

    def release(self):
        """Record the errors held back."""
        held, self.held = self.held, []
        for message, pos in held:
            self.error(message, pos)

    @property
    def error_count(self) -> int:
        """How many distinct errors have been reported, shown or not."""
        return len(self._seen)

    def warn(self, message: str, pos: Pos | None = None):
        self.warnings.append(self._diagnostic(message, pos, "warning"))

    def raise_errors(self):
        """Raise SpecError holding the errors reported so far, in source order: at most MAX_ERRORS of
        them, and a last line that counts the others."""
        if self.errors:
            shown = sorted(self.errors, key=lambda d: (d.line, d.column))
            more = self.error_count - len(self.errors)
            if more:
                shown.append(Diagnostic(f"... and {more:,} more error{'s' if more > 1 else ''}", self.path))
            raise SpecError(shown)

    def finish(self):
        """Raise the errors, if any; otherwise issue the warnings as SpecWarning."""
        self.raise_errors()
        for w in self.warnings:
            warnings.warn(SpecWarning(w), stacklevel=3)


@dataclass
class Layout:
    """Variable names of the compiled plant; blocks add internal states after the declared ones."""

    states: list[str]
    inputs: list[str]
    outputs: list[str]
    input_defaults: np.ndarray  # each input's declared value, NaN where none is written
    block_states: dict[str, list[str]] = field(default_factory=dict)  # output -> its internal states
    block_roles: dict[str, tuple] = field(default_factory=dict)  # internal state -> (output, kind, key, n)
    single_inputs: dict[str, str] = field(default_factory=dict)  # output -> input of its single-input blocks

    @property
    def nx(self):
        return len(self.states)


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


# ------------------------------------------------------------------ a mode's statements, evaluated

MATRIX_NAMES = ("A", "B", "C", "D", "F", "G", "f", "g", "x0")  # a mode's matrices, as a spec names them


@dataclass(frozen=True)
class Equation:
    """`x[t] ~ Normal(mean, sd)`, `y ~ Normal(mean, sd)` or `x[t] = mean`: the row of a state (or of an
    output), the mean's coefficients on the states (at t-1 for a state, t for an output) and on the
    inputs, its constant part, and the noise standard deviation (0 for `=`)."""

    state: int | None
    output: int | None
    on_states: np.ndarray
    on_inputs: np.ndarray
    constant: float
    sd: float


@dataclass(frozen=True)
class Matrix:
    """`A = [...]` and the like (one of MATRIX_NAMES): the value, of the size the layout needs (B and D
    any width; f, g and x0 vectors)."""

    name: str
    value: np.ndarray


@dataclass(frozen=True)
class Initial:
    """`x[0] = value`: the mode's initial mean of one state."""

    state: int
    value: float


@dataclass(frozen=True)
class Fopdt:
    """A fopdt block on output `output` from the inputs `inputs` (indices): per input its gain, time
    constant (seconds) and dead time as the whole-sample lags of the input that reach the lag state
    with the fractional part of the dead time (seconds); the operating point (NaN without one)."""

    output: int
    inputs: list[int]
    gain: np.ndarray
    tau: np.ndarray
    lags: list[list[int]]
    fractions: list[float]
    u_ss: np.ndarray
    y_ss: float


@dataclass(frozen=True)
class Arx:
    """An arx block on output `output` from the inputs `inputs` (indices): a (a1..a_na), b (b0..b_nb,
    one row per input) and the operating point (NaN without one)."""

    output: int
    inputs: list[int]
    a: np.ndarray
    b: np.ndarray
    u_ss: np.ndarray
    y_ss: float


@dataclass
class Mode:
    """One mode's values: its parameters, its noise standard deviations (measurement NaN when nothing
    gives one; `noise scale` None when not written), how far its own input values lie from the
    declared ones, and (a plant without ODEs) its statements, evaluated, in the order written."""

    name: str
    description: str
    pos: Pos
    params: dict[str, float]
    process: float
    measurement: float
    scale: float | None
    shift: np.ndarray
    statements: list = field(default_factory=list)  # Equation, Matrix, Initial, Fopdt, Arx


# ------------------------------------------------------------------ an ODE plant

@dataclass(frozen=True)
class Equations:
    """An ODE plant's derivatives f (per `time_unit`) and outputs h as sympy expressions in the symbols
    of its states, inputs and parameters, in the order of the names."""

    states: list[str]
    inputs: list[str]
    outputs: list[str]
    params: list[str]
    symbols: tuple  # (states, inputs, parameters): lists of sympy Symbols
    f: object  # sympy Matrix
    h: object  # sympy Matrix
    time_unit: str
    seconds_per_unit: float


def show(expr) -> str:
    """A sympy expression as the language writes it (powers with ^)."""
    return str(expr).replace("**", "^")


@dataclass(frozen=True)
class Linearize:
    """Where an ODE plant's modes are linearised: "each" mode's steady state, the steady state of
    mode number `mode` (written at `pos`), or a given "point" (x, u)."""

    kind: str
    mode: int | None = None
    pos: Pos = Pos()
    x: np.ndarray | None = None
    u: np.ndarray | None = None


# ------------------------------------------------------------------ the plant

@dataclass
class Plant:
    """A checked plant, ready to be lowered to a Model."""

    name: str
    dt: float  # seconds
    layout: Layout
    modes: list[Mode]
    P: np.ndarray
    p0: np.ndarray
    initial: np.ndarray  # per state, its declared value (an ODE plant's steady-state guess), NaN where none
    sd0: np.ndarray  # per state, its initial standard deviation
    gates: np.ndarray  # per output, its gross-error gate in standard deviations
    units: dict[str, str]
    unknowns: list = field(default_factory=list)  # lang.unknowns.Unknown: numbers left to the data
    equations: Equations | None = None  # an ODE plant's
    linearize: Linearize | None = None  # an ODE plant's
