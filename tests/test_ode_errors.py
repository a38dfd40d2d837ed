"""The mistakes a user meets in an ODE plant, each reported at file:line:col with a clear message."""

import subprocess

import pytest
from conftest import ROOT, assert_located, jmlgdsl_command
from conftest import errors_of as shared_errors_of

import jmlgdsl.compile.ode as ode
from jmlgdsl.compile.lower import compile_text
from jmlgdsl.errors import SpecWarning

BASE = """\
plant tank
sample 1 s
param k = 0.5, area = 2
let   out = k * sqrt(h)
input q = 1
state h = 3
output h
ode
  der(h) = (q - out) / area
noise process 0.01, measurement 0.1
modes normal, leak "a leak": k = 0.6
transitions stay 0.99, otherwise uniform
"""


def errors_of(text):
    return shared_errors_of(text, "tank.jmlg")


def replace(old, new):
    assert old in BASE
    return BASE.replace(old, new)


CASES = [
    # (case, spec text, line, column, message fragment)
    ("state without der", replace("state h = 3", "state h = 3, v = 1"), 6, 14,
     "state 'v' has no equation: add 'der(v) = ...' to the ode block"),
    ("der of an undeclared name", replace("  der(h) = (q - out) / area\n", "  der(h) = (q - out) / area\n  der(hh) = 0\n"),
     10, 7, "der(hh): 'hh' is not declared, not a state; did you mean 'h'?"),
    ("der of a parameter", replace("  der(h) = (q - out) / area\n", "  der(h) = (q - out) / area\n  der(k) = 0\n"),
     10, 7, "der(k): 'k' is a parameter, not a state; declare it with 'state k = GUESS'"),
    ("duplicate der", replace("  der(h) = (q - out) / area\n", "  der(h) = (q - out) / area\n  der(h) = 0\n"),
     10, 7, "der(h) is given twice (first at line 9)"),
    ("overflowing linearisation", replace("area = 2", "area = 1e-300"), 11, 7,
     "mode 'normal' has entries that are not finite numbers in A"),
    ("infinite literal", replace("(q - out) / area", "(q - out) / area * 1e999"), 9, 31, "this is not a finite real number"),
    ("division by zero", replace("(q - out) / area", "(q - out) / 0"), 9, 12, "division by zero"),
    ("output at a pole", replace("output h", "output h, z = 1 / (h - h)"), 7, 15, "division by zero"),
    ("unknown function", replace("k * sqrt(h)", "k * sqrtt(h)"), 4, 17, "unknown function 'sqrtt'; did you mean 'sqrt'?"),
    ("unknown name", replace("(q - out) / area", "(q - out) / aera"), 9, 24, "unknown name 'aera'; did you mean 'area'?"),
    ("time index", replace("(q - out) / area", "(q[t] - out) / area"), 9, 13,
     "an ODE uses values at the current time: write q, not q[...]"),
    ("let cycle", replace("let   out = k * sqrt(h)", "let   out = k * sqrt(h) + out2, out2 = out"), 4, 40,
     "'let out' depends on itself through out -> out2 -> out"),
    ("output without a state", replace("output h", "output y = 2 * k"), 7, 12,
     "output 'y' depends on no state, so it measures nothing of the plant; write it in terms of the states (h)"),
    ("output that is not a state", replace("output h", "output level"), 7, 8,
     "output 'level' is not a state: measure a state ('output STATE') or give its expression"),
    ("no steady state", replace("(q - out) / area", "1 + h^2"), 11, 7,
     "no steady state found for mode 'normal': der(h) is still"),
    ("input without operating value", replace("input q = 1", "input q"), 5, 7,
     "input 'q' needs an operating value to linearise around: input q = VALUE"),
    ("state without guess", replace("state h = 3", "state h"), 6, 7,
     "state 'h' needs a guess of its steady state: state h = VALUE"),
    ("unknown linearisation mode", BASE + "linearize at steady state of norml\n", 13, 30,
     "unknown mode 'norml'; did you mean 'normal'?"),
    ("point without every state", replace("state h = 3", "state h = 3, v = 1").replace(
        "/ area\n", "/ area\n  der(v) = h - v\n") + "linearize at h = 4\n", 14, 1,
     "the operating point needs every state: add v = ..."),
    ("point with an unknown name", BASE + "linearize at h = 4, qq = 1\n", 13, 21,
     "'qq' is not a state or an input; did you mean 'q'?"),
    ("two linearize statements", BASE + "linearize at h = 4\nlinearize at steady state of each mode\n", 14, 1,
     "'linearize' is given more than once (first at line 13)"),
    ("linear statement in a mode", BASE + "mode leak { h[t] ~ Normal(h[t-1], 1) }\n", 13, 13,
     "in an ODE plant a mode changes parameters (e.g. 'U = 1.1') or noise; 'h' is not a parameter"),
    ("unknown derivative unit", replace("ode\n", "ode [days]\n"), 8, 5, "unknown time unit 'days'; use s, min or h"),
]


@pytest.mark.parametrize("case, text, line, column, fragment", CASES, ids=[c[0] for c in CASES])
def test_located_error(case, text, line, column, fragment):
    assert_located(text, "tank.jmlg", line, column, fragment)


@pytest.mark.parametrize("text, message", [
    (replace("input q = 1", "input q = nope"), "unknown name 'nope' in the value of q"),
    (replace("state h = 3", "state h = nope"), "unknown name 'nope' in the value of h"),
    (BASE + "linearize at h = nope\n", "unknown name 'nope' in the value of h"),
], ids=["input", "guess", "point"])
def test_a_value_that_cannot_be_evaluated_is_not_also_missing(text, message):
    """A written value with an error is reported once, not also as 'needs an operating value', 'needs a
    guess' or 'the operating point needs every state'."""
    assert [d.message for d in errors_of(text)] == [message]


def test_no_steady_state_says_the_residual_and_what_to_try():
    d = errors_of(replace("(q - out) / area", "1 + h^2"))[0]
    residual = float(d.message.split("is still ")[1].split(" ")[0])
    assert residual >= 1.0  # 1 + h^2 never falls below 1
    assert "give better guesses ('state h = ...')" in d.message
    assert "linearize at h = ..." in d.message


NO_STEADY_STATE = replace("(q - out) / area", "1 + h^2")  # settling runs away: h grows without bound


def test_no_steady_state_prints_only_the_located_error(tmp_path):
    """The command's output is the located error alone: nothing on standard output, no integrator
    messages on standard error (LSODA's Fortran code in older scipy releases printed dozens of lines)."""
    path = tmp_path / "tank.jmlg"
    path.write_text(NO_STEADY_STATE)
    done = subprocess.run([*jmlgdsl_command(), "check", str(path)], cwd=ROOT, capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 2
    assert done.stdout == ""
    expected = [d.format() for d in shared_errors_of(NO_STEADY_STATE, str(path))]
    assert done.stderr.rstrip("\n") == "\n".join(expected)


def test_the_steady_state_search_does_not_integrate_with_lsoda(monkeypatch):
    """Whatever scipy's version, the search settles the plant with an integrator that cannot write to the
    terminal: LSODA's Fortran code writes its warnings to the process's own standard output."""
    methods = []

    def solve_ivp(*args, **kwargs):
        methods.append(kwargs["method"])
        return real(*args, **kwargs)

    real = ode.solve_ivp
    monkeypatch.setattr(ode, "solve_ivp", solve_ivp)
    errors_of(NO_STEADY_STATE)
    assert methods and "LSODA" not in methods


def test_unstable_linearisation_is_a_warning_with_the_eigenvalue():
    text = replace("(q - out) / area", "0.1 * (h - 2) - q + 1")  # steady at h = 2, growing at rate 0.1
    with pytest.warns(SpecWarning) as caught:  # the leak changes k, which the equation no longer uses
        model = compile_text(text, "tank.jmlg")
    assert model.mu0[0, 0] == pytest.approx(2.0)
    unstable = [w.message.diagnostic for w in caught if "unstable" in str(w.message)]
    assert [(d.line, d.column) for d in unstable] == [(11, 7), (11, 15)]
    assert all("eigenvalue of modulus 1.10517" in d.message for d in unstable)  # e^{0.1 dt}, in both modes


def test_modes_in_blocks_override_parameters():
    """`mode leak { k = 0.6 }` is the same plant as the override in the modes list."""
    block = replace('modes normal, leak "a leak": k = 0.6', 'modes normal, leak\nmode leak { k = 0.6 }')
    a, b = compile_text(BASE), compile_text(block)
    assert a.A[1, 0, 0] == b.A[1, 0, 0] != a.A[0, 0, 0]


def test_a_number_that_makes_the_equations_infinite_is_a_located_error():
    """10.8 -> 1e+308 in the CSTR's feed concentration makes its derivatives infinite: the steady-state
    search says so at each mode, where scipy's integrator raised 'array must not contain infs or NaNs'."""
    text = (ROOT / "specs" / "cstr10.jmlg").read_text().replace("10.8", "1e+308")
    found = shared_errors_of(text, "cstr10.jmlg")
    assert found and found[0].message.startswith("no steady state found for mode 'normal': der(CA) is still inf")
    assert (found[0].file, found[0].line, found[0].column) == ("cstr10.jmlg", 36, 3)
