"""Parse .jmlg text into the typed syntax tree (jmlgdsl.lang.syntax) with the grammar shipped in
jmlgdsl.grammars; a syntax error becomes a located SpecError saying what was expected."""

from __future__ import annotations

import re
from functools import lru_cache
from importlib.resources import files
from pathlib import Path

from lark import Lark, Token, Transformer, Tree, v_args
from lark.exceptions import UnexpectedCharacters, UnexpectedEOF, UnexpectedInput, UnexpectedToken

from ..errors import Diagnostic, SpecError
from . import syntax as S
from .limits import MAX_NESTING, MAX_TIME_INDEX

# How the terminals that are not fixed text read in an error message; fixed text (keywords,
# punctuation, '->') is shown as written.
_READABLE = {
    "NAME": "a name", "NUMBER": "a number", "SIGNED_NUMBER": "a number", "INT": "a whole number",
    "STRING": "a quoted description", "UNIT": "a unit in brackets", "INDEXED": "a reference like h[t]",
    "$END": "end of file",
    "NUMERIC_MATRIX": "'['",  # a matrix of numbers only: expected wherever '[' is, and shown as it
}


@lru_cache(maxsize=1)
def grammar() -> Lark:
    """The LALR parser for the language, built once per process from the packaged grammar file."""
    text = files("jmlgdsl.grammars").joinpath("jmlg.lark").read_text(encoding="utf-8")
    return Lark(text, parser="lalr", lexer="contextual", propagate_positions=True, maybe_placeholders=False)


@lru_cache(maxsize=1)
def _number_or_semicolon() -> re.Pattern:
    """The entries and row breaks of a NUMERIC_MATRIX token: the grammar's SIGNED_NUMBER, or `;`."""
    return re.compile(f"(?:{grammar().get_terminal('SIGNED_NUMBER').pattern.to_regexp()})|;")


def _one_token(children) -> bool:
    """Whether a `matrix` node's children are a single NUMERIC_MATRIX token rather than rows."""
    return bool(children) and isinstance(children[0], Token)


def _numeric_rows(tok: Token) -> S.NumberRows:
    """The rows of a NUMERIC_MATRIX token as the `row` rule gives them: number entries, each placed at
    its own column of the token's line (the token holds no newline), made when first walked."""
    return S.NumberRows(str(tok), S.Pos(tok.line, tok.column), _number_or_semicolon())


# Rules that nest one expression inside another: the depth MAX_NESTING counts.
_NESTING_RULES = {"sum", "product", "plus", "minus", "times", "over", "neg", "pow", "call", "matrix", "row"}


def parse_text(text: str, path: str = "<spec>") -> S.Spec:
    """Parse a whole spec; raise SpecError with file:line:col and the expected tokens on bad syntax.
    A byte-order mark at the start (as some editors write) is not part of the spec."""
    text = text.removeprefix("\ufeff")
    lines = text.splitlines()
    try:
        tree = grammar().parse(text)
    except UnexpectedInput as exc:
        raise SpecError([_syntax_diagnostic(exc, path, lines)]) from None
    too_deep = _too_deep(tree)
    if too_deep is not None:
        line, column = too_deep
        raise SpecError([Diagnostic(f"expression nested too deeply: at most {MAX_NESTING} levels of operators, "
                                    "calls and signs inside one another", path, line, column, lines[line - 1])])
    spec = S.Spec(path=path, lines=lines)
    builder = _Builder(spec)
    builder.transform(tree)
    if builder.errors:
        raise SpecError(builder.errors)
    return spec


def parse_file(path) -> S.Spec:
    """Read and parse a spec file; an unreadable file is a SpecError too."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise SpecError([Diagnostic(f"cannot read spec: {exc.strerror}", str(path))]) from None
    except UnicodeDecodeError:
        raise SpecError([Diagnostic("cannot read spec: not UTF-8 text", str(path))]) from None
    return parse_text(text, str(path))


def _too_deep(tree: Tree) -> tuple[int, int] | None:
    """Where an expression first nests more than MAX_NESTING levels deep (line, column), or None.
    Walked with an explicit stack: the tree is checked before anything recurses into it."""
    stack = [(tree, 0)]
    while stack:
        node, depth = stack.pop()
        if node.data in _NESTING_RULES:
            depth += 1
            if depth > MAX_NESTING:
                return node.meta.line, node.meta.column
            if depth == MAX_NESTING and node.data == "matrix" and _one_token(node.children):
                # a one-token matrix stands for its rows, one level deeper: the last is walked first
                pos = _numeric_rows(node.children[0])[-1][0].pos
                return pos.line, pos.column
        stack.extend((child, depth) for child in node.children if isinstance(child, Tree))
    return None


def _expected(names) -> str:
    """'; expected a name, ')' or ','' for the terminals the parser would have accepted."""
    shown = sorted({text for text in map(_terminal_text, names) if text})
    if not shown:
        return ""
    return "; expected " + (shown[0] if len(shown) == 1 else ", ".join(shown[:-1]) + " or " + shown[-1])


def _terminal_text(name: str) -> str | None:
    """A terminal as an error message shows it: described, or its fixed text quoted."""
    if name in _READABLE:
        return _READABLE[name]
    try:
        return f"'{grammar().get_terminal(name).pattern.value}'"
    except KeyError:  # not a terminal of the grammar: leave it out
        return None


def _syntax_diagnostic(exc: UnexpectedInput, path: str, lines: list[str]) -> Diagnostic:
    line, column = exc.line, exc.column
    if isinstance(exc, UnexpectedToken):
        tok = exc.token
        what = "end of file" if tok.type == "$END" else f"{str(tok)!r}"
        msg = f"unexpected {what}{_expected(exc.accepts or exc.expected)}"
        if tok.type == "$END":
            line = len(lines) or 1
            column = len(lines[-1]) + 1 if lines else 1
    elif isinstance(exc, UnexpectedCharacters):
        msg = f"unexpected character {exc.char!r}{_expected(exc.allowed)}"
    elif isinstance(exc, UnexpectedEOF):
        msg = f"unexpected end of file{_expected(exc.expected)}"
        line = len(lines) or 1
        column = len(lines[-1]) + 1 if lines else 1
    else:  # pragma: no cover - lark has no other kinds
        msg = "syntax error"
    src = lines[line - 1] if 0 < line <= len(lines) else None
    return Diagnostic(msg, path, line, column, src)


def _pos(item) -> S.Pos:
    if isinstance(item, Token):
        return S.Pos(item.line, item.column)
    if isinstance(item, (S.Expr, S.Name)):
        return item.pos
    meta = item.meta if isinstance(item, Tree) else item
    return S.Pos(getattr(meta, "line", 0), getattr(meta, "column", 0))


def _statement(x) -> S.Statement:
    """A mode-block statement; a `noise` line or a `der()` equation written in a block is wrapped in one."""
    if isinstance(x, S.Noise):
        return S.Statement("noise", x.pos, noise=x)
    if isinstance(x, S.Derivative):
        return S.Statement("der", x.state.pos, target=S.Target(x.state), expr=x.expr)
    return x


def _name(tok: Token) -> S.Name:
    return S.Name(str(tok).rstrip("["), S.Pos(tok.line, tok.column))


@v_args(meta=True)
class _Builder(Transformer):
    """Turns the lark tree into syntax nodes; top-level statements are filed into the Spec."""

    def __init__(self, spec: S.Spec):
        super().__init__()
        self.spec = spec
        self.errors: list[Diagnostic] = []

    # ---------------------------------------------------------------- expressions
    def number(self, meta, c):
        return S.Expr("number", (float(c[0]),), _pos(c[0]))

    def var(self, meta, c):
        return S.Expr("var", (str(c[0]),), _pos(c[0]))

    def time_index(self, meta, c):
        """("abs", n) for x[n]; ("lag", -k) for x[t-k]."""
        if c[0].type == "INT":
            return ("abs", self._time_number(c[0]))
        if str(c[0]) != "t":
            self._error(f"a time index is t, t-1, ... or a whole number, not {str(c[0])!r}", c[0])
        return ("lag", -self._time_number(c[1]) if len(c) > 1 else 0)

    def _time_number(self, tok: Token) -> int:
        """The whole number written in a time index. One beyond MAX_TIME_INDEX is a located error
        (and 0 stands in for it), judged on its digits: int() of thousands of digits would raise."""
        digits = str(tok).lstrip("0") or "0"
        if len(digits) <= len(str(MAX_TIME_INDEX)) and int(digits) <= MAX_TIME_INDEX:
            return int(digits)
        shown = digits if len(digits) <= 12 else f"{digits[:3]}...{digits[-3:]} ({len(digits):,} digits)"
        self._error(f"time index {shown} is too large: write t, t-1 or 0 (the number in a time index is at most "
                    f"{MAX_TIME_INDEX:,})", tok)
        return 0

    def _error(self, message: str, tok: Token):
        """A located error at a token of the tree being built."""
        self.errors.append(Diagnostic(message, self.spec.path, tok.line, tok.column, self.spec.lines[tok.line - 1]))

    def indexed(self, meta, c):
        kind, value = c[1]
        name = str(c[0])[:-1]
        if kind == "abs":
            return S.Expr("indexed", (name, None), _pos(c[0]), index=value)
        return S.Expr("indexed", (name, value), _pos(c[0]))

    def call(self, meta, c):
        return S.Expr("call", (str(c[0]), *c[1:]), _pos(c[0]))

    def _op(name):
        def build(self, meta, c):
            return S.Expr(name, tuple(c), _pos(meta))
        return build

    pow, neg = _op("pow"), _op("neg")
    del _op

    def _operand(name):
        def build(self, meta, c):
            return name, c[0]
        return build

    plus, minus, times, over = _operand("add"), _operand("sub"), _operand("mul"), _operand("div")
    del _operand

    def sum(self, meta, c):
        """A flat run `a + b - c ...` (or `a * b / c ...`) folded left to right into binary nodes, each
        placed where the run starts, without recursion however long the run."""
        expr = c[0]
        for op, operand in c[1:]:
            expr = S.Expr(op, (expr, operand), _pos(meta))
        return expr

    product = sum

    def row(self, meta, c):
        return tuple(c)

    def matrix(self, meta, c):
        rows = _numeric_rows(c[0]) if _one_token(c) else tuple(c)
        return S.Expr("matrix", rows, _pos(meta))

    # ---------------------------------------------------------------- declarations
    def plant(self, meta, c):
        self._single("plant", meta)
        self.spec.plant = _name(c[0])

    def sample(self, meta, c):
        self._single("sample", meta)
        self.spec.sample = (float(c[0]), _name(c[1]) if len(c) > 1 else None, _pos(c[0]))

    def _item(kind):
        def build(self, meta, c):
            name, unit, value, sd, gate = _name(c[0]), None, None, None, None
            for x in c[1:]:
                if isinstance(x, Token) and x.type == "UNIT":
                    unit = str(x)[1:-1].strip()
                elif isinstance(x, tuple) and x[0] == "sd":
                    sd = x[1]
                elif isinstance(x, tuple) and x[0] == "gate":
                    gate = x[1]
                elif isinstance(x, tuple):
                    value = x[1]
                else:
                    value = x
            return S.Decl(kind, name, unit, value, sd, gate)
        return build

    input_item, output_item, state_item = _item("input"), _item("output"), _item("state")
    del _item

    def gate_off(self, meta, c):
        return ("gate", "off")

    def gate_value(self, meta, c):
        return ("gate", c[0])

    def state_value(self, meta, c):
        return ("value", c[0])

    def state_sd(self, meta, c):
        return ("sd", c[0])

    def input_decl(self, meta, c):
        self.spec.decls.extend(c)

    output_decl = state_decl = input_decl

    def assign(self, meta, c):
        return S.Assign(_name(c[0]), c[1])

    def prior(self, meta, c):
        return S.Assign(_name(c[0]), None, prior=c[1])

    def param_decl(self, meta, c):
        self.spec.params.extend(c)

    def let_decl(self, meta, c):
        self.spec.lets.extend(c)

    def mode_item(self, meta, c):
        desc = next((str(x)[1:-1] for x in c[1:] if isinstance(x, Token) and x.type == "STRING"), None)
        return S.ModeDecl(_name(c[0]), desc, tuple(x for x in c[1:] if isinstance(x, S.Assign)))

    def modes_decl(self, meta, c):
        self.spec.modes.extend(c)

    # ---------------------------------------------------------------- probabilities and noise
    def prob_named(self, meta, c):
        return S.ProbItem("named", _pos(c[0]), name=_name(c[0]), value=c[1])

    def prob_stay(self, meta, c):
        return S.ProbItem("stay", _pos(meta), value=c[0])

    def prob_otherwise(self, meta, c):
        return S.ProbItem("otherwise", _pos(meta), name=_name(c[0]))

    def prob_list(self, meta, c):
        return tuple(c)

    def arrow_row(self, meta, c):
        return (_name(c[0]), c[1])

    def _probabilities(keyword):
        def build(self, meta, c):
            body = c[0]
            if isinstance(body, S.Expr):
                p = S.Probabilities(keyword, _pos(meta), matrix=body)
            elif isinstance(body, tuple) and body and isinstance(body[0], S.Name):
                p = S.Probabilities(keyword, _pos(meta), arrows=tuple(c))
            else:
                p = S.Probabilities(keyword, _pos(meta), rules=body)
            getattr(self.spec, keyword).append(p)
        return build

    initial, transitions = _probabilities("initial"), _probabilities("transitions")
    del _probabilities

    def noise_item(self, meta, c):
        return (_name(c[0]), c[1])

    noise_prior = noise_item

    def noise(self, meta, c):
        return S.Noise(tuple(c), _pos(meta))

    # ---------------------------------------------------------------- modes
    def target(self, meta, c):
        if len(c) == 1:
            return S.Target(_name(c[0]))
        kind, value = c[1]
        if kind == "abs":
            return S.Target(_name(c[0]), index=value)
        return S.Target(_name(c[0]), lag=value)

    def arg_positional(self, meta, c):
        return ("pos", c[0])

    def arg_keyword(self, meta, c):
        return ("kw", _name(c[0]), c[1], str(c[2]) if len(c) > 2 else None)

    def arg_at(self, meta, c):
        return ("at", _name(c[0]), c[1], c[2])

    def dist_args(self, meta, c):
        return tuple(c)

    def dist(self, meta, c):
        args = c[1] if len(c) > 1 else ()
        return S.Dist(
            _name(c[0]),
            positional=tuple(a[1] for a in args if a[0] == "pos"),
            keywords=tuple((a[1], a[2], a[3]) for a in args if a[0] == "kw"),
            at=next((a[1:] for a in args if a[0] == "at"), None),
            end=S.Pos(meta.end_line, meta.end_column))

    def sample_stmt(self, meta, c):
        return S.Statement("sample", _pos(meta), target=c[0], dist=c[1])

    def assign_stmt(self, meta, c):
        return S.Statement("assign", _pos(meta), target=c[0], expr=c[1])

    def block(self, meta, c):
        return tuple(map(_statement, c))

    def like(self, meta, c):
        return _name(c[0])

    def mode_block(self, meta, c):
        like = next((x for x in c[1:] if isinstance(x, S.Name)), None)
        body = ()
        for x in c[1:]:
            if isinstance(x, tuple):
                body = x
            elif isinstance(x, (S.Statement, S.Noise, S.Derivative)):
                body = (_statement(x),)
        self.spec.blocks.append(S.ModeBlock(_name(c[0]), like, body, _pos(meta)))

    # ---------------------------------------------------------------- nonlinear plants
    def der_eq(self, meta, c):
        return S.Derivative(_name(c[0]), c[1])

    def ode_block(self, meta, c):
        if c and isinstance(c[0], Token) and c[0].type == "UNIT":
            self.spec.ode_unit = (str(c[0])[1:-1].strip(), _pos(c[0]))
            c = c[1:]
        self.spec.ode.extend(c)

    def linearize_each(self, meta, c):
        self.spec.linearize.append(S.LinearizeAt("each", _pos(meta)))

    def linearize_mode(self, meta, c):
        self.spec.linearize.append(S.LinearizeAt("mode", _pos(meta), mode=_name(c[0])))

    def linearize_point(self, meta, c):
        self.spec.linearize.append(S.LinearizeAt("point", _pos(meta), point=tuple(c)))

    def _single(self, what, meta):
        """Remember statements that may appear once, so the checker can report a repeat."""
        if (what == "plant" and self.spec.plant) or (what == "sample" and self.spec.sample):
            self.spec.repeated.append((what, _pos(meta)))

    def start(self, meta, c):
        self.spec.noise.extend(x for x in c if isinstance(x, S.Noise))  # plant-level noise defaults
        return self.spec
