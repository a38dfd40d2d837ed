"""Evaluate expression trees: numerically (numbers and matrices) or symbolically (sympy), for
linear-coefficient extraction and ODE Jacobians."""

from __future__ import annotations

import numpy as np

from ..names import suggest
from .limits import MAX_EXPONENT, MAX_LET_CHAIN, MAX_SIZE
from .diagnostics import Report
from .symbolic import sp
from .syntax import Expr, NumberRows


class EvalError(Exception):
    """An expression that cannot be evaluated; carries the node where it went wrong."""

    def __init__(self, message: str, node: Expr):
        super().__init__(message)
        self.node = node


class UnknownName(EvalError):
    """A name the spec does not declare: `pi` and `e` then stand for their constants."""


CONSTANTS = {"pi": (np.pi, "pi"), "e": (np.e, "E")}  # (numeric, sympy's name); a declared name wins
BINARY = ("add", "sub", "mul", "div")  # left-associative: a run of them is folded without recursion


SCALAR_FUNCTIONS = {
    "exp": (np.exp, "exp"), "log": (np.log, "log"), "sqrt": (np.sqrt, "sqrt"),
    "sin": (np.sin, "sin"), "cos": (np.cos, "cos"), "tan": (np.tan, "tan"),
    "tanh": (np.tanh, "tanh"), "abs": (np.abs, "Abs"), "min": (np.minimum, "Min"),
    "max": (np.maximum, "Max"), "pow": (np.power, "Pow"),
}
ARITY = {"min": (2, 2), "max": (2, 2), "pow": (2, 2)}


def _zeros(m, n=None):
    return np.zeros((int(m), int(m if n is None else n)))


def _ones(m, n=None):
    return np.ones((int(m), int(m if n is None else n)))


def _diag(v):
    return np.diag(np.ravel(v))


MATRIX_FUNCTIONS = {"eye": (lambda n: np.eye(int(n)), (1, 1)), "zeros": (_zeros, (1, 2)),
                    "ones": (_ones, (1, 2)), "diag": (_diag, (1, 1))}
SIZED = ("eye", "zeros", "ones")  # the matrix functions whose arguments are sizes
FUNCTION_NAMES = sorted([*SCALAR_FUNCTIONS, *MATRIX_FUNCTIONS])


def _check_arity(node: Expr, name: str, lo: int, hi: int):
    n = len(node.args) - 1
    if not lo <= n <= hi:
        want = str(lo) if lo == hi else f"{lo} or {hi}"
        raise EvalError(f"{name}() takes {want} argument{'s' if hi > 1 else ''}, got {n}", node)


def _name_value(node: Expr, lookup, kind: int):
    """lookup(node), or the constant (numeric kind 0, symbolic kind 1) an undeclared `pi` or `e` means."""
    try:
        return lookup(node)
    except UnknownName:
        if node.op == "var" and node.args[0] in CONSTANTS:
            numeric, symbolic = CONSTANTS[node.args[0]]
            return getattr(sp, symbolic) if kind else numeric
        raise


def _fold(node: Expr, evaluate, combine):
    """A left-leaning run of + - * / evaluated left to right: evaluate(operand) for each operand,
    combine(link, left, right) for each operator node, with no recursion down the run."""
    run = []
    while node.op in BINARY:
        run.append(node)
        node = node.args[0]
    value = evaluate(node)
    for link in reversed(run):
        value = combine(link, value, evaluate(link.args[1]))
    return value


def numeric(node: Expr, lookup):
    """Value of an expression as a float or a 2-D array. `lookup(node)` gives a name's value."""
    op, args = node.op, node.args
    if op == "number":
        return args[0]
    if op in ("var", "indexed"):
        return _name_value(node, lookup, 0)
    if op in BINARY:
        return _fold(node, lambda e: numeric(e, lookup), _numeric_binary)
    if op == "matrix":
        if isinstance(args, NumberRows):
            values = args.values()
            if len({len(row) for row in values}) == 1:
                return np.array(values, float)
        elif _plain(args):
            return np.array([[e.args[0] for e in row] for row in args], float)
        rows = [[numeric(e, lookup) for e in row] for row in args]
        try:
            return np.block([[np.atleast_2d(np.asarray(v, float)) for v in row] for row in rows]) if rows else np.zeros((0, 0))
        except ValueError:
            raise EvalError("matrix rows have different lengths", node) from None
    if op == "call":
        name = args[0]
        values = [numeric(a, lookup) for a in args[1:]]
        if name in MATRIX_FUNCTIONS:
            fn, (lo, hi) = MATRIX_FUNCTIONS[name]
            _check_arity(node, name, lo, hi)
            if name in SIZED and not all(np.ndim(v) == 0 and float(v).is_integer() and v >= 0 for v in values):
                raise EvalError(f"{name}() takes sizes: whole numbers, 0 or more", node)
            if name in SIZED and max(values) > MAX_SIZE:
                raise EvalError(f"{name}() of size {max(values):.0f} is too large: at most {MAX_SIZE}", node)
            return fn(*values)
        if name in SCALAR_FUNCTIONS:
            lo, hi = ARITY.get(name, (1, 1))
            _check_arity(node, name, lo, hi)
            return SCALAR_FUNCTIONS[name][0](*values)
        raise EvalError(unknown_function(name), node)
    vals = [numeric(a, lookup) for a in args]
    if op == "neg":
        return -vals[0]
    a, b = vals  # a power: the grammar has no other operators
    if np.ndim(a) or np.ndim(b):
        raise EvalError("powers of matrices are not supported", node)
    return np.power(float(a), float(b))  # real: NaN for a negative base and a fractional power


def _plain(rows) -> bool:
    """Whether a matrix literal's rows are all numbers, in rows of one length: the array np.block would
    make of it is then one np.array call instead of a numeric() and a block per entry."""
    return (bool(rows) and len({len(row) for row in rows}) == 1
            and all(e.op == "number" for row in rows for e in row))


def _numeric_binary(node: Expr, a, b):
    """a + b, a - b, a * b (a matrix product between matrices) or a / b, as `node` says."""
    op = node.op
    if op == "add" or op == "sub":
        try:
            return a + b if op == "add" else a - b
        except ValueError:
            raise EvalError(f"cannot {op} matrices of shapes {np.shape(a)} and {np.shape(b)}", node) from None
    if op == "mul":
        if np.ndim(a) and np.ndim(b):
            if np.shape(a)[1] != np.shape(b)[0]:
                raise EvalError(f"cannot multiply matrices of shapes {np.shape(a)} and {np.shape(b)}", node)
            return a @ b
        return a * b
    if op == "div":
        if np.ndim(b):
            raise EvalError("cannot divide by a matrix", node)
        if b == 0:
            raise EvalError("division by zero", node)
        return a / b


def symbolic(node: Expr, lookup) -> sp.Expr:
    """A sympy expression; `lookup(node)` gives the sympy value of a name (a Symbol or a number).
    Numbers fold in floating point, as numeric() computes them: an exact 1e308^1e308 or 2^(10^9) would
    take sympy minutes, and a value beyond a float is an EvalError where it is computed."""
    op, args = node.op, node.args
    if op == "number":
        return _finite(sp.Integer(int(args[0])) if float(args[0]).is_integer() else sp.Float(args[0]), node)
    if op in ("var", "indexed"):
        return _name_value(node, lookup, 1)
    if op in BINARY:
        return _fold(node, lambda e: symbolic(e, lookup), _symbolic_binary)
    if op == "matrix":
        raise EvalError("a matrix is not allowed here", node)
    if op == "call":
        name = args[0]
        if name not in SCALAR_FUNCTIONS:
            raise EvalError(unknown_function(name) if name not in MATRIX_FUNCTIONS
                            else f"{name}() makes a matrix, which is not allowed here", node)
        lo, hi = ARITY.get(name, (1, 1))
        _check_arity(node, name, lo, hi)
        values = [symbolic(a, lookup) for a in args[1:]]
        if all(v.is_Number for v in values):
            with np.errstate(all="ignore"):
                return _finite(sp.Float(SCALAR_FUNCTIONS[name][0](*map(float, values))), node)
        return getattr(sp, SCALAR_FUNCTIONS[name][1])(*values)
    vals = [symbolic(a, lookup) for a in args]
    if op == "neg":
        return -vals[0]
    a, b = vals  # a power: the grammar has no other operators
    if a.is_Number and b.is_Number:
        with np.errstate(all="ignore"):
            value = np.power(float(a), float(b))
        exact = a.is_Integer and b.is_Integer and b >= 0 and abs(value) < 2 ** 53
        return sp.Integer(a) ** int(b) if exact else _finite(sp.Float(value), node)
    if b.is_Integer and abs(b) > MAX_EXPONENT:
        raise EvalError(f"a power of {b} is too large for an expression in variables: at most {MAX_EXPONENT}", node)
    return a ** b


def _finite(value: sp.Expr, node: Expr) -> sp.Expr:
    """value, when it is not a number that a float cannot hold (an overflow, a NaN): else an EvalError."""
    if value.is_Number:
        try:
            finite = np.isfinite(float(value))
        except OverflowError:
            finite = False
        if not finite:
            raise EvalError(NOT_FINITE, node)
    return value


def _symbolic_binary(node: Expr, a: sp.Expr, b: sp.Expr) -> sp.Expr:
    """a + b, a - b, a * b or a / b; a divisor that is zero (a parameter set to 0, say) is an error here."""
    if node.op == "div":
        if b.is_zero:
            raise EvalError("division by zero", node)
        return _finite(a / b, node)
    return _finite(a + b if node.op == "add" else a - b if node.op == "sub" else a * b, node)


class LetExpander:
    """Expands `let` names in expressions, one at a time, so that a let depending on itself (directly
    or through other lets), or a chain of more than MAX_LET_CHAIN lets, is a located error instead of
    endless or too deep recursion."""

    def __init__(self, lets: dict):
        self.lets = lets  # name -> Assign
        self.expanding: list[str] = []

    def __call__(self, node: Expr, evaluate):
        """The value of the let named at `node`, as `evaluate(expression)` gives it."""
        name = node.args[0]
        if name in self.expanding:
            chain = " -> ".join(self.expanding[self.expanding.index(name):] + [name])
            raise EvalError(f"'let {name}' depends on itself through {chain}", node)
        if len(self.expanding) >= MAX_LET_CHAIN:
            raise EvalError(f"lets nested too deeply: at most {MAX_LET_CHAIN} lets may use one another in a chain "
                            f"({' -> '.join(self.expanding[:3])} -> ...)", node)
        self.expanding.append(name)
        try:
            return evaluate(self.lets[name].expr)
        except RecursionError:  # deep expressions inside each of the lets of a long chain
            raise EvalError(f"'let {name}' is nested too deeply: write it with fewer levels", node) from None
        finally:
            self.expanding.pop()


def finite_numeric(node: Expr, lookup):
    """numeric() for a value the user wrote: no floating-point warnings, and an EvalError at `node`
    when the value is not finite although every name it uses is (such a name is reported where it is
    defined, not again at each use)."""
    inherited = False

    def watched(name_node: Expr):
        nonlocal inherited
        value = lookup(name_node)
        inherited = inherited or not np.all(np.isfinite(value))
        return value

    with np.errstate(all="ignore"):
        value = numeric(node, watched)
        if not inherited and not np.all(np.isfinite(value)):
            raise EvalError(NOT_FINITE, _first_not_finite(node, watched))
    return value


def _first_not_finite(node: Expr, lookup) -> Expr:
    """The entry of a matrix literal (within matrices, the innermost) whose value is not finite, so
    the error points at what to fix; the node itself when it is no matrix (or no entry alone is)."""
    if node.op == "matrix":
        for entry in (e for row in node.args for e in row):
            if not np.all(np.isfinite(numeric(entry, lookup))):
                return _first_not_finite(entry, lookup)
    return node


NOT_FINITE = ("this is not a finite real number (an overflow, a division by zero, or a log, root or power "
              "out of its domain?)")


def finite_real(e: sp.Expr) -> bool:
    """False when a symbolic expression holds an infinity, a NaN or the imaginary unit, which no
    numeric coefficient or compiled function can carry."""
    return not e.has(sp.zoo, sp.oo, -sp.oo, sp.nan, sp.I)


def unknown_function(name: str) -> str:
    """The message for a call of a function the language does not have, with a did-you-mean."""
    return f"unknown function {name!r}{suggest(name, FUNCTION_NAMES)}"


def evaluate_number(expr: Expr, env: dict, report: Report, what: str) -> float:
    """A scalar value from known names in env; reports unknown names and non-scalars."""
    def lookup(node):
        name = node.args[0]
        if node.op == "indexed":
            raise EvalError(f"{what} cannot refer to a time-indexed value", node)
        if name not in env:
            raise UnknownName(f"unknown name {name!r} in {what}{suggest(name, env)}", node)
        return env[name]

    try:
        value = finite_numeric(expr, lookup)
    except EvalError as exc:
        report.error(str(exc), exc.node.pos)
        return float("nan")
    if np.ndim(value):
        report.error(f"{what} must be a number, not a matrix", expr.pos)
        return float("nan")
    return float(value)
