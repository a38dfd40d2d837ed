"""Property tests (issue 14): malformed data files and generated or mutated specs either work or fail
with the package's own error, never another exception, and never hang; any spec that loads gives a
model that simulates and filters with finite posteriors summing to one.

A bounded, reproducible number of examples runs by default; JMLGDSL_FUZZ=1 runs many more, drawn
afresh each time (`JMLGDSL_FUZZ=1 python -m pytest tests/test_fuzz.py`).
"""

import contextlib
import io
import json
import math
import os
import signal
import tempfile
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.lark import from_lark
from infer_models import dryer
from lark import Lark
from lark.lexer import PatternStr

import jmlgdsl
from jmlgdsl.cli import main
from jmlgdsl.compile.lower import compile_text
from jmlgdsl.data import read_csv
from jmlgdsl.errors import DataError, SpecError
from jmlgdsl.infer import FilterError
from jmlgdsl.monitor.sources.payload import Malformed, decode

ROOT = Path(__file__).resolve().parents[1]
LONG = os.environ.get("JMLGDSL_FUZZ") == "1"
SPEC_SECONDS = 10  # CPU seconds a spec may take to load, simulate and filter


def budget(examples):
    """Settings for `examples` reproducible examples by default, fifty times as many fresh ones with
    JMLGDSL_FUZZ=1."""
    return settings(max_examples=examples * 50 if LONG else examples, derandomize=not LONG, database=None,
                    deadline=None, suppress_health_check=list(HealthCheck))


class Timeout(BaseException):
    """Raised into code that runs past its time limit (a BaseException, so no handler swallows it)."""


@contextlib.contextmanager
def time_limit(seconds):
    """Interrupt the block with Timeout after `seconds` of CPU time (so a machine busy with other work
    does not look like a hang), and again every 0.5 s, in case the first lands where Python ignores
    exceptions, such as a garbage-collector callback."""
    def expire(signum, frame):
        raise Timeout(f"still running after {seconds} s of CPU time")

    previous = signal.signal(signal.SIGPROF, expire)
    signal.setitimer(signal.ITIMER_PROF, seconds, 0.5)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_PROF, 0)
        signal.signal(signal.SIGPROF, previous)


# Data files ------------------------------------------------------------------------------------

FOLDER = Path(tempfile.mkdtemp(prefix="jmlgdsl-fuzz-"))
MODEL = FOLDER / "dryer.json"
dryer().save(MODEL)

CELLS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-10**30, 10**30).map(str),
    st.sampled_from(["", " ", "NA", "nan", "inf", "-inf", "1e309", "1,5", "normal", "fan", "grill", "Normal",
                     '"q,uoted"', '"', "2020-03-09 10:14:33", "2020-13-40", "#", "\ufeff", "\x00", "0", "1"]),
    st.text(max_size=8),
)
NAMES = st.sampled_from(["time", "temp", "one", "mode", "datetime", "anomaly", "changepoint", "x", "", " temp "])


@st.composite
def csv_files(draw):
    """The bytes of a CSV-like file: a header of likely and unlikely names, ragged rows of odd cells,
    either separator and line ending, in one of several encodings."""
    header = draw(st.lists(st.one_of(NAMES, st.text(max_size=6)), min_size=1, max_size=6))
    rows = draw(st.lists(st.lists(CELLS, max_size=len(header) + 2), max_size=6))
    separator, ending = draw(st.sampled_from([",", ";"])), draw(st.sampled_from(["\n", "\r\n", "\r"]))
    text = ending.join(separator.join(cells) for cells in [header, *rows]) + draw(st.sampled_from(["", ending]))
    encoding = draw(st.sampled_from(["utf-8", "utf-8-sig", "latin-1", "utf-16", "cp1252"]))
    return text.encode(encoding, errors="replace")


DATA = st.one_of(st.binary(max_size=200), csv_files())


def written(content: bytes, name="data.csv") -> Path:
    path = FOLDER / name
    path.write_bytes(content)
    return path


def command(argv):
    """(exit status, standard error) of the command line, with its output kept off the terminal."""
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()), warnings.catch_warnings():
        status = main([str(a) for a in argv])
    return status, err.getvalue()


def assert_clean(status, err):
    """Success, or exit 2 with exactly one `error:` line, last, and no traceback."""
    assert status in (0, 2), (status, err)
    assert "Traceback" not in err
    if status == 2:
        lines = err.rstrip("\n").split("\n")
        errors = [line for line in lines if line.startswith("error: ")]
        assert len(errors) == 1 and lines[-1] == errors[0] and all(c.isprintable() for c in lines[-1]), err


@budget(60)
@given(DATA)
def test_reading_any_file_gives_data_or_a_data_error(content):
    path = written(content)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            data = read_csv(path, dryer())
    except DataError as exc:
        assert str(exc).startswith(str(path)), str(exc)
        return
    assert data.y.shape == (len(data.y), 1) and data.u.shape == (len(data.y), 1)
    assert not np.isinf(data.y).any() and np.isfinite(data.u).all()


@budget(15)
@given(DATA)
def test_run_on_any_file_succeeds_or_says_why(content):
    assert_clean(*command(["run", MODEL, written(content)]))


@budget(10)
@given(DATA)
def test_plot_of_any_file_succeeds_or_says_why(content):
    assert_clean(*command(["plot", written(content, "result.csv"), "-o", FOLDER / "figure.png"]))


# Data-bus payloads -----------------------------------------------------------------------------

KEYS = st.sampled_from(["t", "v", "temp", "current", "other", ""])
SCALARS = st.one_of(
    st.none(), st.booleans(), st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**60, 10**60),
    st.text(max_size=12), st.sampled_from(["2020-03-09T11:14:34Z", "9999-12-31T23:59:59-14:00", "0001-01-01",
                                           "2020-03-09 11:14:34+99:00", "1e400"]))
JSON = st.recursive(SCALARS, lambda inner: st.lists(inner, max_size=4) | st.dictionaries(KEYS, inner, max_size=4),
                    max_leaves=12)


def _nested(depth):
    return ("[" * depth + "]" * depth).encode()


PAYLOADS = st.one_of(
    st.binary(max_size=64),
    JSON.map(lambda value: json.dumps(value).encode()),
    st.builds(lambda digits, key: f'{{"t": {"9" * digits}, "{key}": 50}}'.encode(), st.integers(1, 500), KEYS),
    st.builds(lambda depth, tail: _nested(depth)[:depth] + tail, st.integers(1, 6000), st.binary(max_size=4)),
    st.sampled_from([b"1" * 100_000, b"\xed\xa0\x80", b'{"v": "\\ud800"}', b"-" + b"9" * 400, b"1e999999"]))


@budget(300)
@given(PAYLOADS, st.sampled_from(["temp", None]))
def test_any_payload_is_readings_or_one_malformed(payload, name):
    """A payload of a data bus is readings of known names with finite values and times, or Malformed
    with a short printable message: never another exception, whatever its nesting, size or numbers."""
    try:
        readings = decode(payload, name, ["temp", "current"])
    except Malformed as exc:
        assert len(str(exc)) < 400 and str(exc).isprintable(), str(exc)
        return
    assert readings and all(n in ("temp", "current") for n, _, _ in readings)
    assert all(math.isnan(v) or abs(v) < 1e100 for _, v, _ in readings)
    assert all(t is None or math.isfinite(t if isinstance(t, float) else t.timestamp()) for _, _, t in readings)


# Specs -----------------------------------------------------------------------------------------

SPECS = {p.name: p.read_text() for p in sorted((ROOT / "specs").glob("*.jmlg"))}
QUICK = [name for name in SPECS if not name.startswith("cstr")]  # the ODE plants take a second or more
ODD_NUMBERS = ["0", "-1", "1e308", "1e-320", "nan", "inf", "99999999999999999999", "1e160", "0.5", "2",
               "18446744073709551616", "46341", "1e9"]
SYNTAX = list("{}[]()=,;:~-+*/^#\"\n") + ["->", "der(", "eye(", "mode ", "sample ", " otherwise uniform"]


@st.composite
def mutated_specs(draw):
    """A bundled spec with one to three edits: a number replaced by an odd one, a line deleted,
    doubled or swapped, a piece of syntax inserted, or the text cut short."""
    text = SPECS[draw(st.sampled_from(list(SPECS) if LONG else QUICK))]
    for _ in range(draw(st.integers(1, 3))):
        lines = text.splitlines(keepends=True) or [""]
        i, j = draw(st.integers(0, len(lines) - 1)), draw(st.integers(0, len(lines) - 1))
        kind = draw(st.sampled_from(["number", "delete", "double", "swap", "insert", "cut"]))
        if kind == "number":
            import re

            numbers = list(re.finditer(r"\d+\.?\d*(?:[eE][+-]?\d+)?", text))
            if numbers:
                m = numbers[draw(st.integers(0, len(numbers) - 1))]
                text = text[:m.start()] + draw(st.sampled_from(ODD_NUMBERS)) + text[m.end():]
            continue
        if kind == "delete":
            del lines[i]
        elif kind == "double":
            lines.insert(i, lines[i])
        elif kind == "swap":
            lines[i], lines[j] = lines[j], lines[i]
        text = "".join(lines)
        if kind in ("insert", "cut"):
            at = draw(st.integers(0, len(text)))
            text = text[:at] + draw(st.sampled_from(SYNTAX)) + text[at:] if kind == "insert" else text[:at]
    return text


def _grammar_specs():
    """Texts the grammar derives, with every token followed by a space (so tokens do not run
    together) and comments ended by a newline."""
    grammar = Lark((ROOT / "grammars" / "jmlg.lark").read_text(), parser="lalr", lexer="contextual")

    def terminal(t):
        if isinstance(t.pattern, PatternStr):
            return st.just(t.pattern.value + " ")
        return st.from_regex(t.pattern.to_regexp(), fullmatch=True,
                             alphabet=st.characters(max_codepoint=127)).map(lambda s: s + " ")

    explicit = {t.name: terminal(t) for t in grammar.terminals}
    explicit.update(COMMENT=st.just("# note\n"), WS=st.just(" "))
    return from_lark(grammar, explicit=explicit)


GRAMMAR_SPECS = _grammar_specs()


@st.composite
def spliced_specs(draw):
    """A bundled spec with a statement the grammar derives put in at a line boundary."""
    lines = SPECS[draw(st.sampled_from(QUICK))].splitlines(keepends=True)
    at = draw(st.integers(0, len(lines)))
    return "".join(lines[:at]) + draw(GRAMMAR_SPECS) + "\n" + "".join(lines[at:])


MATRICES = ("A", "B", "C", "D", "F", "G", "f", "g", "mu0", "Sigma0", "P", "p0")
GOOD = ("spec error", "filtered", "overflowed", "filter error")  # outcomes a spec may have


def spec_outcome(text, seconds=SPEC_SECONDS) -> str:
    """Load the text, and if it loads simulate 20 steps and filter them with IMM, all within
    `seconds`: 'spec error', 'filtered', 'overflowed' (an unstable mode left the finite numbers in
    20 steps), 'filter error' (the filter stopped with its own error naming the row), or what went wrong: 'hang', 'non-finite model', 'NaN posterior'. Any other exception
    propagates."""
    try:
        with time_limit(seconds), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                model = compile_text(text, "fuzz.jmlg")
            except SpecError:
                return "spec error"
            if not (np.isfinite(model.dt) and model.dt > 0
                    and all(np.isfinite(getattr(model, key)).all() for key in MATRICES)):
                return "non-finite model"
            u = np.tile(np.nan_to_num(np.asarray(model.input_defaults, float)), (20, 1))
            sim = jmlgdsl.simulate(model, 20, seed=0, u=u)
            if not (np.isfinite(sim.y).all() and np.isfinite(sim.u).all()):
                return "overflowed"
            try:
                posterior = jmlgdsl.filter(model, sim.y, sim.u, algorithm="imm").mode_posterior
            except FilterError:  # the filter's own clean error naming the row where numbers overflowed
                return "filter error"
    except Timeout:
        return "hang"
    finite = np.isfinite(posterior).all() and np.allclose(posterior.sum(axis=1), 1.0, atol=1e-9)
    return "filtered" if finite else "NaN posterior"


@budget(40)
@given(mutated_specs())
def test_a_mutated_spec_loads_and_filters_or_is_a_spec_error(text):
    assert spec_outcome(text) in GOOD


@budget(15)
@given(st.one_of(GRAMMAR_SPECS, spliced_specs()))
def test_a_spec_the_grammar_derives_loads_and_filters_or_is_a_spec_error(text):
    assert spec_outcome(text) in GOOD


@pytest.mark.parametrize("name, old, new", [
    ("dryer.jmlg", "at current 15 -> 54.76", "at current 15 -> 1e160"),
    ("robot_smooth.jmlg", "v0 = 0.5037", "v0 = 1e308"),
    ("robot8.jmlg", "0.7385 * v[t-1] + 0.1317", "0.7385 * v[t-1] + 1e308"),
    ("level_tank4.jmlg", "0.9829 * h[t-1] + 0.5368, 0.008", "0.9829 * h[t-1] + 0.5368, 1e9"),
    ("level_tank4.jmlg", "0.9801 * h[t-1] + 0.3099", "1e9 * h[t-1] + 0.3099"),
    ("robot8.jmlg", "v[0] = 0.4265", "v[0] = 1e9"),
])
def test_huge_values_are_refused_or_filtered(name, old, new):
    assert old in SPECS[name]
    assert spec_outcome(SPECS[name].replace(old, new)) in GOOD


def test_the_time_limit_interrupts():
    with pytest.raises(Timeout), time_limit(0.05):
        while True:
            pass
