"""Every user error in a spec is reported as file:line:col with the source line and a caret."""

import textwrap

import pytest
from conftest import assert_located
from conftest import errors_of as shared_errors_of

from jmlgdsl.compile.lower import compile_text
from jmlgdsl.errors import SpecError, SpecWarning

BASE = """\
plant p
sample 1 s
input u = 1
output y
state x
modes normal, fault
transitions stay 0.99, otherwise uniform
noise process 0.1, measurement 0.2
mode normal { x[t] ~ Normal(0.9 * x[t-1] + u, 0.1); y ~ Normal(x[t], 0.2) }
mode fault like normal { x[t] ~ Normal(0.8 * x[t-1] + u, 0.1) }
"""


def errors_of(text):
    return shared_errors_of(text, "plant.jmlg")


def replace(old, new):
    assert old in BASE
    return BASE.replace(old, new)


CASES = [
    # (spec text, line, column, message fragment)
    ("syntax", replace("0.9 * x[t-1] + u, 0.1)", "0.9 * x[t-1] + , 0.1)"), 9, 44, "unexpected ','; expected"),
    ("misspelt mode", replace("mode fault like", "mode fualt like"), 10, 6, "unknown mode 'fualt'; did you mean 'fault'?"),
    ("misspelt like", replace("like normal", "like normla"), 10, 17, "unknown mode 'normla'; did you mean 'normal'?"),
    ("duplicate", replace("state x\n", "state x\ninput y\n"), 6, 7, "'y' is already declared as an output at line 4"),
    ("matrix size", replace("{ x[t] ~ Normal(0.8 * x[t-1] + u, 0.1) }", "{ A = [0.8 0; 0 1] }"), 10, 30,
     "A must be 1 x 1 (nx = 1, nu = 1, ny = 1), got 2 x 2"),
    ("row sum", replace("transitions stay 0.99, otherwise uniform", "transitions [0.9 0.2; 0.1 0.9]"), 7, 14,
     "transition row 1 (normal) sums to 1.1, not 1"),
    ("short row", replace("transitions stay 0.99, otherwise uniform", "transitions [0.9 0.05; 0.1 0.9]"), 7, 14,
     "sums to 0.95, not 1; add 'otherwise uniform' or the missing entries"),
    ("negative prior", replace("modes normal, fault\n", "modes normal, fault\ninitial [1.2 -0.2]\n"), 7, 9,
     "the initial distribution has a negative entry -0.2"),
    ("negative sd", replace("u, 0.1) }\n", "u, -0.1) }\n"), 10, 58, "a standard deviation cannot be negative (got -0.1)"),
    ("nonlinear", replace("0.8 * x[t-1] + u", "0.8 * x[t-1]^2 + u"), 10, 40, "0.8*x[t-1]^2 is not linear in the states and inputs"),
    ("bilinear", replace("0.8 * x[t-1] + u", "0.8 * x[t-1] * u"), 10, 40, "0.8*u*x[t-1] is not linear"),
    ("unknown name", replace("0.8 * x[t-1] + u", "0.8 * x[t-1] + uu"), 10, 55, "unknown name 'uu'; did you mean 'u'?"),
    ("state time", replace("0.8 * x[t-1] + u", "0.8 * x[t] + u"), 10, 46, "a state equation uses states at t-1: write x[t-1]"),
    ("time unit", replace("sample 1 s", "sample 1 secs"), 2, 10, "unknown time unit 'secs'; use s, min or h"),
    ("no sample", replace("sample 1 s\n", ""), 1, 1, "missing sample time: add a line such as 'sample 1 s'"),
    ("noise kind", replace("noise process 0.1", "noise proces 0.1"), 8, 7, "unknown noise kind 'proces'; use 'process', 'measurement' or 'scale'; did you mean 'process'?"),
    ("no equation", replace("{ x[t] ~ Normal(0.8 * x[t-1] + u, 0.1) }", "{ }").replace("like normal ", ""), 6, 15,
     "state 'x' has no equation in mode 'fault'"),
    ("distribution", replace("0.8 * x[t-1] + u, 0.1)", "0.8 * x[t-1] + u, 0.1, 2)"), 10, 33,
     "Normal takes two arguments: Normal(mean, standard deviation)"),
    ("unknown block", replace("x[t] ~ Normal(0.8", "x[t] ~ Gauss(0.8"), 10, 33, "unknown distribution or block 'Gauss'"),
    ("fopdt keyword", replace("y ~ Normal(x[t], 0.2)", "y ~ fopdt(u, gian 2, tau 5 s)"), 9, 66,
     "fopdt has no argument 'gian'; it takes gain, tau, delay; did you mean 'gain'?"),
    ("fopdt delay without a value", replace("y ~ Normal(x[t], 0.2)", "y ~ fopdt(u, gain 2, tau 5 s, delay s)"), 9, 89,
     "unknown name 's'"),
    ("operating point arrow", replace("y ~ Normal(x[t], 0.2)", "y ~ fopdt(u, gain 2, tau 5 s, at u 1 2)"), 9, 90,
     "unexpected '2'; expected '->'"),
    ("huge dead time", replace("y ~ Normal(x[t], 0.2)", "y ~ fopdt(u, gain 2, tau 5 s, delay 100 min)"), 9, 89,
     "a dead time of 6000 samples needs as many input registers; at most 1000 are allowed"),
    ("fopdt tau", replace("y ~ Normal(x[t], 0.2)", "y ~ fopdt(u, gain 2)"), 9, 57, "fopdt needs 'tau VALUE'"),
    ("measurement", replace("noise process 0.1, measurement 0.2", "noise process 0.1").replace(
        "y ~ Normal(x[t], 0.2)", "y[t] = x[t]"), 6, 7, "output 'y' has no measurement noise in mode 'normal'"),
    ("like cycle", replace("mode normal {", "mode normal like fault {"), 10, 17, "mode 'fault' is 'like' itself through normal -> fault -> normal"),
    ("probability", replace("stay 0.99", "stay 1.5"), 7, 18, "a probability cannot exceed 1 (got 1.5)"),
    ("stay and a name", replace("stay 0.99,", "stay 0.98, fault 0.01,"), 7, 24,
     "probability for 'fault' given twice ('stay' gives it in its own row)"),
    ("arrows in initial", replace("modes normal, fault\n", "modes normal, fault\ninitial normal -> fault 0.1\n"), 7, 1,
     "arrows ('a -> b p') belong in 'transitions'; write 'initial a p, otherwise uniform'"),
    ("prior mode", replace("modes normal, fault\n", "modes normal, fault\ninitial normal 0.9, falt 0.1\n"), 7, 21,
     "unknown mode 'falt'; did you mean 'fault'?"),
    ("bad index", replace("x[t-1] + u, 0.1) }\n", "x[k-1] + u, 0.1) }\n"), 10, 48, "a time index is t, t-1, ... or a whole number, not 'k'"),
    ("linearize", replace("noise process", "linearize at steady state of each mode\nnoise process"), 8, 1,
     "'linearize' applies to nonlinear plants: this spec has no 'ode' block"),
    ("let cycle", replace("noise process", "let k = 2 * j, j = k\nnoise process").replace("0.8 * x[t-1] + u", "k * x[t-1] + u"),
     8, 20, "'let k' depends on itself through k -> j -> k"),
    ("let cycle in a matrix", replace("noise process", "let k = k\nnoise process").replace(
        "{ x[t] ~ Normal(0.8 * x[t-1] + u, 0.1) }", "{ A = [k] }"), 8, 9, "'let k' depends on itself through k -> k"),
    ("division by zero", replace("0.8 * x[t-1] + u", "x[t-1] / 0 + u"), 10, 40, "division by zero"),
    ("log of zero", replace("0.8 * x[t-1] + u", "log(0) * x[t-1] + u"), 10, 40, "this is not a finite real number"),
    ("overflow", replace("process 0.1,", "process 10^400,"), 8, 15, "this is not a finite real number (an overflow"),
    ("root of a negative parameter", replace("transitions", "param a = (-8)^(1/3)\ntransitions"), 7, 11,
     "this is not a finite real number"),
    ("infinite literal", replace("0.8 * x[t-1]", "1e999 * x[t-1]"), 10, 40, "this is not a finite real number"),
    ("overflowing coefficient", replace("0.8 * x[t-1]", "1e300 * 1e300 * x[t-1]"), 10, 40,
     "this is not a finite real number"),
    ("zeros size", replace("u, 0.1) }\n", "u, 0.1); B = zeros(-1) }\n"), 10, 68,
     "zeros() takes sizes: whole numbers, 0 or more"),
    ("no output", replace("output y\n", "").replace("; y ~ Normal(x[t], 0.2)", ""), 1, 1,
     "a plant needs at least one output: declare it with 'output NAME'"),
    ("no state", "plant p\nsample 1 s\ninput u = 1\noutput y\nmode n { y ~ Normal(u, 0.2) }\n", 1, 1,
     "a plant needs at least one state"),
    ("unknown function", replace("0.8 * x[t-1]", "sqr(0.8) * x[t-1]"), 10, 40, "unknown function 'sqr'; did you mean 'sqrt'?"),
]


@pytest.mark.parametrize("name,text,line,column,message", CASES, ids=[c[0] for c in CASES])
def test_error_is_located(name, text, line, column, message):
    assert_located(text, "plant.jmlg", line, column, message)


def test_several_errors_are_reported_together():
    text = replace("sample 1 s", "sample 1 secs").replace("stay 0.99", "stay 1.5").replace("mode fault like", "mode fualt like")
    lines = sorted((d.line, d.column) for d in errors_of(text))
    assert (2, 10) in lines and (7, 18) in lines and (10, 6) in lines


def test_row_close_to_one_is_renormalised_with_a_warning():
    text = replace("transitions stay 0.99, otherwise uniform", "transitions [0.9995 0.0010; 0.01 0.99]")
    with pytest.warns(SpecWarning, match=r"plant.jmlg:7:14: warning: transition row 1 \(normal\) sums to 1.0005; renormalised"):
        m = compile_text(text, "plant.jmlg")
    assert m.P[0].sum() == pytest.approx(1.0, abs=1e-15)
    assert m.P[0, 0] == pytest.approx(0.9995 / 1.0005)


def test_unreadable_file_is_a_spec_error(tmp_path):
    from jmlgdsl import load

    with pytest.raises(SpecError, match="cannot read spec"):
        load(tmp_path / "missing.jmlg")


def test_misspelt_mode_in_the_dryer_gives_a_suggestion(tmp_path):
    import pathlib

    text = (pathlib.Path(__file__).resolve().parents[1] / "specs" / "dryer.jmlg").read_text()
    bad = tmp_path / "dryer.jmlg"
    bad.write_text(text.replace("mode fan_grill:", "mode fan_gril:"))
    from jmlgdsl import load

    with pytest.raises(SpecError) as info:
        load(bad)
    d = info.value.diagnostics[0]
    assert (d.line, d.column) == (24, 6)
    assert d.message == "unknown mode 'fan_gril'; did you mean 'fan_grill'?"


def test_cli_check_prints_located_errors_without_traceback(tmp_path, capsys):
    from jmlgdsl.cli import main

    bad = tmp_path / "bad.jmlg"
    bad.write_text(textwrap.dedent(replace("mode fault like", "mode fualt like")))
    assert main(["check", str(bad)]) == 2
    err = capsys.readouterr().err
    assert f"{bad}:10:6: unknown mode 'fualt'; did you mean 'fault'?" in err
    assert "Traceback" not in err
    assert "\n    mode fualt like normal" in err and "\n         ^" in err
