"""Hostile and careless specs: every one gets a located error (or compiles) — never a traceback, a
hang or a model with non-finite numbers. Each test names the hardening item it pins."""

import time

import numpy as np
import pytest
from conftest import ROOT, assert_located, errors_of

from jmlgdsl.cli import main
from jmlgdsl.compile.lower import compile_text
from jmlgdsl.lang.limits import (MAX_ERRORS, MAX_LET_CHAIN, MAX_MODES, MAX_NESTING, MAX_ORDER, MAX_SIZE,
                                MAX_TIME_INDEX, MAX_VARIABLES)
from jmlgdsl.lang.parse import parse_file
from jmlgdsl.lang.diagnostics import Report
from jmlgdsl.lang.syntax import Pos

PATH = "plant.jmlg"
BASE = """\
plant p
sample 1 s
input u = 1
output y
state x
noise process 0.1, measurement 0.2
{decls}
mode m {{ x[t] ~ Normal({mean}, {sd}); y ~ Normal(x[t], 0.2) }}
"""


def spec(decls="", mean="0.5 * x[t-1] + u", sd="0.1"):
    return BASE.format(decls=decls, mean=mean, sd=sd)


def at(text, fragment):
    """(line, column) of the first occurrence of fragment in text, 1-based."""
    before = text[:text.index(fragment)]
    return before.count("\n") + 1, len(before) - before.rfind("\n")


def located(text, fragment, message):
    """The error `message` is reported where `fragment` is written."""
    assert_located(text, PATH, *at(text, fragment), message)


# ------------------------------------------------------------------ 1. long sums, deep nesting

def test_a_long_flat_sum_compiles():
    text = spec(decls="param total = " + " + ".join(["1"] * 600), mean="total / 1000 * x[t-1]")
    np.testing.assert_allclose(compile_text(text).A[0], [[0.6]])
    text = spec(mean=" + ".join(["0.001 * x[t-1]"] * 1000) + " - 2 * u")
    m = compile_text(text)
    np.testing.assert_allclose([m.A[0, 0, 0], m.F[0, 0, 0]], [1.0, -2.0])


def test_a_long_product_compiles():
    text = spec(decls="param p = " + " * ".join(["1.001"] * 600) + " / " + " / ".join(["1.001"] * 600))
    compile_text(text.replace("0.5 * x[t-1]", "0.5 * p * x[t-1]"))


@pytest.mark.parametrize("deep", [
    "-" * 490 + "1",
    "abs(" * 490 + "1" + ")" * 490,
    "^".join(["1"] * 490),
    "(" * 490 + "1" + " + 1)" * 490,
], ids=["signs", "calls", "powers", "parentheses"])
def test_deep_nesting_is_a_located_error(deep):
    text = spec(decls=f"param q = {deep}")
    diagnostics = errors_of(text, PATH)
    assert len(diagnostics) == 1 and "expression nested too deeply" in diagnostics[0].message
    assert diagnostics[0].line == 7 and diagnostics[0].column > 10


def test_nesting_up_to_the_limit_compiles():
    text = spec(decls="param q = " + "abs(" * MAX_NESTING + "0.5" + ")" * MAX_NESTING, mean="q * x[t-1]")
    np.testing.assert_allclose(compile_text(text).A[0], [[0.5]])


@pytest.mark.parametrize("length", [MAX_LET_CHAIN, 400])
def test_a_long_chain_of_lets_is_limited(length):
    """`length` lets, each using the one before it."""
    lets = "let l1 = 0.5\n" + "".join(f"let l{i} = l{i - 1} + 0\n" for i in range(2, length + 1))
    text = spec(decls=lets, mean=f"l{length} * x[t-1]")
    if length <= MAX_LET_CHAIN:
        np.testing.assert_allclose(compile_text(text).A[0], [[0.5]])
    else:
        located(text, f"l{length - MAX_LET_CHAIN} + 0", f"lets nested too deeply: at most {MAX_LET_CHAIN}")


def test_deep_expressions_in_a_chain_of_lets_are_an_error():
    deep = "abs(" * (MAX_NESTING - 1) + "{}" + ")" * (MAX_NESTING - 1)
    lets = "let l0 = 0.5\n" + "".join(f"let l{i} = {deep.format(f'l{i - 1}')}\n" for i in range(1, 20))
    diagnostics = errors_of(spec(decls=lets, mean="l19 * x[t-1]"), PATH)
    assert len(diagnostics) == 1 and "nested too deeply" in diagnostics[0].message


@pytest.mark.parametrize("mean, fragment, message", [
    ("1e308 ^ 1e308 * x[t-1]", "1e308 ^", "this is not a finite real number"),
    ("2 ^ 100000000 * x[t-1]", "2 ^", "this is not a finite real number"),
    ("exp(exp(exp(1000))) * x[t-1]", "exp(1000)", "this is not a finite real number"),
    ("(x[t-1] + 1) ^ 100000", "(x[t-1] + 1)", "a power of 100000 is too large for an expression in variables"),
    ("x[t-1] ^ 1000000000", "x[t-1] ^", "a power of 1000000000 is too large"),
])
def test_huge_constants_and_powers_are_errors_in_no_time(mean, fragment, message):
    start = time.perf_counter()
    located(spec(mean=mean), fragment, message)
    assert time.perf_counter() - start < 5


# ------------------------------------------------------------------ 2. sizes

@pytest.mark.parametrize("size", ["18446744073709551616", "46341", str(MAX_SIZE + 1)])
def test_huge_matrix_functions_are_located_errors(size):
    text = spec().replace("mode m {", f"mode m {{ C = eye({size});")
    located(text, f"eye({size})", f"eye() of size {size} is too large: at most {MAX_SIZE}")
    text = spec().replace("mode m {", f"mode m {{ B = zeros(1, {size});")
    located(text, f"zeros(1, {size})", "is too large")


def test_too_many_modes():
    names = [f"m{i}" for i in range(MAX_MODES + 1)]
    text = spec(decls="modes " + ", ".join(names))
    located(text, names[-1], f"too many modes: {MAX_MODES + 1:,}, at most {MAX_MODES:,}")


def test_too_many_states_declared():
    names = [f"s{i}" for i in range(MAX_VARIABLES + 1)]
    text = spec().replace("state x\n", "state x, " + ", ".join(names) + "\n")
    located(text, names[-2], f"too many states: {MAX_VARIABLES + 2:,}, at most {MAX_VARIABLES:,} are allowed")


def test_too_many_states_with_the_blocks_internal_ones():
    blocks = "".join(f"  y{i} ~ fopdt(u, gain 1, tau 2 s, delay 999 s)\n" for i in range(3))
    text = f"plant p\nsample 1 s\ninput u = 1\noutput y0, y1, y2\nnoise process 0.1, measurement 0.1\n" \
           f"mode m {{\n{blocks}}}\n"
    located(text, "m {", f"the plant has 3,000 states with the blocks' internal ones, at most {MAX_VARIABLES:,}")


def test_too_large_a_stacked_model():
    states = ", ".join(f"s{i}" for i in range(150))
    text = spec(decls=f"state {states}\nmodes " + ", ".join(f"m{i}" for i in range(1000))
                + "\ntransitions stay 0.9, otherwise uniform").replace("mode m {", "mode m0 {")
    located(text, "m0,", "the plant is too large: 1,000 modes of 151 x 151 matrices")


def test_arx_orders_are_limited():
    coefficients = " ".join(["0.001"] * (MAX_ORDER + 1))
    text = f"plant p\nsample 1 s\ninput u = 1\noutput y\nnoise process 0.1, measurement 0.1\n" \
           f"mode m: y ~ arx(u, a [{coefficients}], b [1])\n"
    located(text, "[0.001", f"{MAX_ORDER + 1} coefficients in 'a' are too many: at most {MAX_ORDER}")


# ------------------------------------------------------------------ 3. covariances that overflow

@pytest.mark.parametrize("change, fragment", [
    (("mode m {", "mode m { D = 1e160 * eye(1);"), "1e160"),
    (("noise process 0.1", "noise process 1e200"), "1e200"),
    (("Normal(0.5 * x[t-1] + u, 0.1)", "Normal(0.5 * x[t-1] + u, 1e151)"), "1e151"),
    (("state x\n", "state x sd 1e200\n"), "1e200"),
])
def test_standard_deviations_whose_variance_overflows_are_located(change, fragment):
    text = spec().replace(*change)
    located(text, fragment, "is too large: at most 1e+150, so that variances stay finite numbers")


def test_a_large_but_finite_covariance_compiles():
    text = spec().replace("mode m {", "mode m { D = 1e100 * eye(1);")
    assert np.isfinite(compile_text(text).D).all()


# ------------------------------------------------------------------ 4. arx without coefficients

def test_arx_with_no_a_coefficients_is_a_located_error():
    text = "plant p\nsample 1 s\ninput one = 1\noutput level\nnoise process 0.05, measurement 0.05\n" \
           "mode m: level ~ arx(one, a [], b [0.4 0.3])\n"
    diagnostics = errors_of(text, PATH)
    assert [d.message for d in diagnostics] == [
        "arx needs at least a1 in 'a [...]'; without output feedback write 'a [0]'"]
    assert (diagnostics[0].line, diagnostics[0].column) == at(text, "[]")
    m = compile_text(text.replace("a []", "a [0]"))  # the hint compiles: y_t = 0.4 u_t + 0.3 u_{t-1}
    np.testing.assert_allclose([m.F[0, 0, 0], m.A[0, 0, 1]], [0.4, 0.3])


# ------------------------------------------------------------------ 5. sample time

@pytest.mark.parametrize("sample, message", [
    ("1e308 min", "the sample time is not a finite number of seconds"),
    ("1e999 s", "the sample time is not a finite number of seconds"),
    ("0 s", "the sample time must be positive"),
    ("1e-400 s", "the sample time must be positive"),
])
def test_a_sample_time_that_is_not_a_positive_finite_number_is_an_error(sample, message):
    text = spec().replace("sample 1 s", f"sample {sample}")
    located(text, sample, message)


# ------------------------------------------------------------------ 6. initial standard deviation

@pytest.mark.parametrize("sd", ["1e999", "big * big"])
def test_a_non_finite_initial_sd_is_located(sd):
    text = spec(decls="param big = 1e200").replace("state x\n", f"state x sd {sd}\n")
    located(text, sd, "this is not a finite real number")


# ------------------------------------------------------------------ 7. many errors

def test_errors_are_deduplicated_in_linear_time_and_capped():
    report = Report(PATH, [])
    start = time.perf_counter()
    for i in range(20_000):
        report.error(f"error {i}", Pos(i + 1, 1))
        report.error(f"error {i}", Pos(i + 1, 1))  # a repeat is dropped
    assert time.perf_counter() - start < 2.0
    with pytest.raises(Exception) as info:
        report.raise_errors()
    diagnostics = info.value.diagnostics
    assert len(diagnostics) == MAX_ERRORS + 1
    assert diagnostics[-1].message == f"... and {20_000 - MAX_ERRORS:,} more errors"


def test_a_spec_with_hundreds_of_errors_shows_a_bounded_number():
    modes = [f"m{i}" for i in range(300)]
    text = "plant p\nsample 1 s\noutput y\nstate x\nnoise process 0.1, measurement 0.1\n" \
        + "modes " + ", ".join(modes) + "\ntransitions stay 0.9, otherwise uniform\n" \
        + "".join(f"mode {name}: y ~ Normal(x[t] + nope, 0.1)\n" for name in modes)
    start = time.perf_counter()
    diagnostics = errors_of(text, PATH)
    assert time.perf_counter() - start < 30
    assert len(diagnostics) == MAX_ERRORS + 1
    assert diagnostics[-1].message == f"... and {600 - MAX_ERRORS} more errors"  # each mode: 'nope', no state equation


# ------------------------------------------------------------------ 8. byte-order mark

def test_a_byte_order_mark_is_not_part_of_the_spec(tmp_path):
    path = tmp_path / "bom.jmlg"
    path.write_text("\ufeff" + spec(), encoding="utf-8")
    assert parse_file(path).plant.text == "p"
    np.testing.assert_allclose(compile_text("\ufeff" + spec()).A[0], [[0.5]])
    located("\ufeff" + spec(mean="0.5 * x[t-1] + nope"), "nope", "unknown name 'nope'")


# ------------------------------------------------------------------ 9. division by zero through a parameter

def test_division_by_a_zero_parameter_is_located_where_written():
    text = spec(decls="param a = 0", mean="0.5 * x[t-1] + 2.5 / a * u")
    located(text, "2.5 / a", "division by zero")


def test_division_by_a_parameter_a_mode_sets_to_zero_is_located_where_written():
    text = spec(decls="param a = 1\nmodes m: a = 0", mean="0.5 * x[t-1] + 2.5 / a * u")
    located(text, "2.5 / a", "division by zero")


def test_division_by_zero_in_one_mode_of_an_ode_plant_is_located_where_written():
    text = ("plant o\nsample 1 s\nparam a = 1\nstate x = 1\noutput x\node\n  der(x) = 1 - x / a\n"
            "noise process 0.1, measurement 0.1\nmodes n, f: a = 0\ntransitions stay 0.9, otherwise uniform\n")
    located(text, "x / a", "division by zero in mode 'f'")


# ------------------------------------------------------------------ 10. der() in a mode block

@pytest.mark.parametrize("ode", [False, True])
def test_der_in_a_mode_block_says_it_belongs_in_the_ode_block(ode):
    text = ("plant o\nsample 1 s\nparam a = 1\nstate w = 1\noutput w\n"
            + ("ode\n  der(w) = 1 - w / a\n" if ode else "mode n { w[t] ~ Normal(w[t-1], 0.1) }\n")
            + "noise process 0.1, measurement 0.1\nmode m { der(w) = 0 }\n")
    text = text if ode else text.replace("mode n {", "modes n, m\ntransitions stay 0.9, otherwise uniform\nmode n {")
    diagnostics = errors_of(text, PATH)
    assert diagnostics[0].message.startswith("der(w) belongs in the 'ode' block")
    assert (diagnostics[0].line, diagnostics[0].column) == at(text, "w) = 0")


# ------------------------------------------------------------------ 11. root causes, constants

@pytest.mark.parametrize("mean, message", [
    ("0.5 * x[t-1] + foo", "unknown name 'foo'"),
    ("0.5 * x[t-1] + expp(u)", "unknown function 'expp'"),
])
def test_one_bad_term_is_one_error_without_a_cascade(mean, message):
    diagnostics = errors_of(spec(mean=mean), PATH)
    assert [d.message.split(";")[0] for d in diagnostics] == [message]


TWO_MODES = """\
plant p
sample 1 s
input u = 1
output y
state x1, x2, x3
noise process 0.1, measurement 0.2
modes m, n
transitions [0.9 0.1; 0.1 0.9]
initial [0.5 0.5]
mode m { A = 0.5 * eye(3); F = [1; 0; 0]; C = [1 0 0] }
mode n like m { u = 2 }
"""


@pytest.mark.parametrize("change, message", [
    (("A = 0.5 * eye(3)", "A = eye(2^64)"), "eye() of size 18446744073709551616 is too large: at most 1000"),
    (("C = [1 0 0]", "C = [1 0 nope]"), "unknown name 'nope'"),
    (("A = 0.5 * eye(3);", "x1[t] ~ Normal(nope * x1[t-1], 0.1); x2[t] ~ Normal(x2[t-1], 0.1); "
                           "x3[t] ~ Normal(x3[t-1], 0.1);"), "unknown name 'nope'"),  # also in mode n, like m
    (("[0.9 0.1; 0.1 0.9]", "[0.9 nope; 0.1 0.9]"), "unknown name 'nope'"),
    (("[0.9 0.1; 0.1 0.9]", "[0.9 0.1 0; 0.1 0.9 0]"), "the transition matrix must be 2 x 2 for 2 modes, got 2 x 3"),
    (("[0.5 0.5]", "[0.5 nope]"), "unknown name 'nope'"),
    (("initial [0.5 0.5]", "initial m nope, n 0.5"), "unknown name 'nope' in a probability"),
    (("[0.9 0.1; 0.1 0.9]", "n nope, otherwise uniform"), "unknown name 'nope' in a probability"),
    (("output y", "output y outliers nope"), "unknown name 'nope' in the outlier gate of y"),
    (("{ u = 2 }", "{ noise scale nope }"), "unknown name 'nope' in scale noise"),
    (("input u = 1", "input u = nope"), "unknown name 'nope' in the value of u"),
], ids=["eye", "matrix", "like", "transitions", "shape", "initial", "initial-rules", "transition-rules", "gate",
        "scale", "input"])
def test_a_value_that_cannot_be_evaluated_is_one_error(change, message):
    """The value's error is the only one: its statement still counts as written (no 'has no equation',
    no probabilities that sum to 0, no 'got nan')."""
    text = TWO_MODES.replace(*change)
    assert text != TWO_MODES
    assert [d.message for d in errors_of(text, PATH)] == [message]


def test_a_lowercase_distribution_is_one_error():
    text = spec().replace("x[t] ~ Normal(", "x[t] ~ normal(")
    diagnostics = errors_of(text, PATH)
    assert len(diagnostics) == 1 and "did you mean 'Normal'?" in diagnostics[0].message


def test_a_broken_block_is_one_error():
    text = "plant p\nsample 1 s\ninput u = 1\noutput y\nnoise process 0.1, measurement 0.1\n" \
           "mode m: y ~ fopdt(u, gain 1, tau nope, delay 3 s)\n"
    assert len(errors_of(text, PATH)) == 1


def test_pi_and_e_are_constants_unless_declared():
    m = compile_text(spec(decls="param w = pi / 4", mean="w * x[t-1] + e * u"))
    np.testing.assert_allclose([m.A[0, 0, 0], m.F[0, 0, 0]], [np.pi / 4, np.e])
    m = compile_text(spec(decls="param e = 0.5", mean="e * x[t-1]"))
    np.testing.assert_allclose(m.A[0, 0, 0], 0.5)


def test_pi_in_an_ode():
    text = ("plant o\nsample 1 s\nstate x = 1\noutput x\node\n  der(x) = pi - x\n"
            "noise process 0.1, measurement 0.1\nmodes n\n")
    np.testing.assert_allclose(compile_text(text).mu0[0], [np.pi])


# ------------------------------------------------------------------ 12. numbers of thousands of digits

HUGE = "1" + "0" * 20_000  # beyond the 4,300 digits Python's int() converts from a string


@pytest.mark.parametrize("change", [
    ("0.5 * x[t-1]", f"0.5 * x[t-{HUGE}]"),           # a state equation
    ("Normal(x[t]", f"Normal(x[t-{HUGE}]"),             # an output
    ("mode m {", f"mode m {{ x[{HUGE}] = 1;"),          # an initial value
], ids=["state", "output", "initial"])
def test_a_time_index_of_thousands_of_digits_is_located_at_the_number(change):
    text = spec().replace(*change)
    located(text, HUGE, "time index 100...000 (20,001 digits) is too large: write t, t-1 or 0")


def test_a_time_index_beyond_the_limit_says_the_limit():
    text = spec(mean=f"0.5 * x[t-{MAX_TIME_INDEX + 1}]")
    located(text, str(MAX_TIME_INDEX + 1), f"the number in a time index is at most {MAX_TIME_INDEX:,}")
    located(spec(mean=f"0.5 * x[t-{MAX_TIME_INDEX}]"), f"x[t-{MAX_TIME_INDEX}]",
            "a state equation uses states at t-1")  # within the limit: what the equation needs


@pytest.mark.parametrize("change, message", [
    (("0.5 * x", f"{HUGE} * x"), "this is not a finite real number"),
    (("0.5 * x", f"{HUGE}.5 * x"), "this is not a finite real number"),
    (("0.5 * x", f"2 ^ {HUGE} * x"), "this is not a finite real number"),
    (("mode m {", f"mode m {{ C = [{HUGE}];"), "this is not a finite real number"),
    (("mode m {", f"mode m {{ C = [1, ({HUGE})];"), "this is not a finite real number"),
    (("sample 1 s", f"sample {HUGE} s"), "the sample time is not a finite number of seconds"),
    (("noise process 0.1", f"noise process {HUGE}"), "this is not a finite real number"),
    (("state x\n", f"state x = {HUGE}\n"), "this is not a finite real number"),
    (("y ~ Normal(x[t], 0.2)", f"y ~ arx(u, a [{HUGE}], b [1])"), "this is not a finite real number"),
    (("y ~ Normal(x[t], 0.2)", f"y ~ fopdt(u, gain 1, tau 1, delay {HUGE})"), "this is not a finite real number"),
], ids=["number", "decimal", "exponent", "matrix", "matrix-entry", "sample", "noise", "state", "arx", "fopdt"])
def test_a_number_of_thousands_of_digits_is_located_at_the_number(change, message):
    located(spec().replace(*change), HUGE, message)


# ------------------------------------------------------------------ the command line: exit 2, no traceback

@pytest.mark.parametrize("text", [
    spec(decls="param q = " + "-" * 600 + "1"),
    spec().replace("mode m {", "mode m { C = eye(18446744073709551616);"),
    spec(decls="param a = 0", mean="2.5 / a * u"),
    spec().replace("sample 1 s", "sample 1e308 min"),
    spec(mean=f"0.5 * x[t-{HUGE}]"),
], ids=["nesting", "eye", "division", "sample", "time index"])
def test_check_exits_2_with_a_located_message(tmp_path, capsys, text):
    path = tmp_path / "bad.jmlg"
    path.write_text(text)
    assert main(["check", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"{path}:") and "Traceback" not in err


def test_a_long_number_in_a_matrix_is_read_at_once():
    """A number of 20,000 digits in a matrix over several lines is one token (the number pattern
    cannot backtrack over its digits: it took minutes to parse)."""
    text = (ROOT / "specs" / "cstr4.jmlg").read_text().replace("0.99825 0.001", "0.99825 0." + "1" * 20000, 1)
    diagnostics = errors_of(text, "cstr4.jmlg")
    assert [d.message for d in diagnostics] == ["transition row 1 (normal) sums to 1.11011, not 1"]
