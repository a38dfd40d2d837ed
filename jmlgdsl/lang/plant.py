"""The checked plant: what the checker (jmlgdsl.lang.check) hands to the compiler (jmlgdsl.compile).
It holds values, not syntax: names, numbers, numpy arrays and, for a plant written as ODEs, sympy
expressions, with the source positions of what the compiler may still have to report (a mode, an
operating point). Besides these types, the positions and report of lang.diagnostics and the checker's
entry points (lang.check: a spec file or text to a checked plant), the compiler imports nothing else
of the language."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .limits import MAX_MAGNITUDE  # noqa: F401  (MAX_MAGNITUDE bounds what the compiler makes)
from .diagnostics import Pos


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
class Linearization:
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
    engineering_units: dict[str, str]  # variable name -> its unit of measure
    unknowns: list = field(default_factory=list)  # lang.unknowns.Unknown: numbers left to the data
    equations: Equations | None = None  # an ODE plant's
    linearize: Linearization | None = None  # an ODE plant's
