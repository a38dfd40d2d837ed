"""Blocks with several inputs, a mode's own input values, an output's initial sd and the warning for
identical modes: each compiles to matrices worked out here by hand, or fails with a located message."""

import pathlib
import re
import warnings

import numpy as np
import pytest
from conftest import assert_located

from jmlgdsl.compile.lower import compile_file, compile_text
from jmlgdsl.errors import SpecWarning
from jmlgdsl.simulation.nonlinear import simulate_nonlinear

ROOT = pathlib.Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "language.md"
DOC_BLOCKS = {re.search(r"plant (\w+)", b).group(1): b
              for b in re.findall(r"```jmlg\n(.*?)```", DOC.read_text(), flags=re.S) if "plant " in b}


def close(actual, expected):
    np.testing.assert_allclose(actual, expected, rtol=1e-12, atol=1e-12)


def run(m, k, u, x0):
    """Noise-free outputs of mode k for the inputs u (T, nu), from the state x0."""
    x, ys = np.array(x0, float), []
    for ut in u:
        x = m.A[k] @ x + m.F[k] @ ut + m.f[k]
        ys.append(m.C[k] @ x + m.G[k] @ ut + m.g[k])
    return np.array(ys)[:, 0]


def compiled_quietly(text, path="<spec>"):
    """Compile, failing on any warning."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return compile_text(text, path)


# ------------------------------------------------------------------ 1. blocks with several inputs

TWO_INPUT_FOPDT = """plant two
sample 1 s
input  u1 = 15, u2 = 3
output y
noise  process 0.1, measurement 0.2
mode only: y ~ fopdt(u1, u2, gain [1.2 -0.5], tau [10 20] s, delay [{d1} {d2}] s, u_ss [15 3], y_ss 50)
"""


def test_two_input_fopdt_without_dead_time_has_the_hand_computed_matrices():
    m = compiled_quietly(TWO_INPUT_FOPDT.format(d1=0, d2=0))
    assert m.states == ("y", "y_u2")  # the output, and the part of it due to u2
    a1, a2 = np.exp(-1 / 10), np.exp(-1 / 20)
    # y_t = a1 (y - p2)_{t-1} + a2 p2_{t-1} + K1 (1 - a1) u1 + K2 (1 - a2) u2 + (1 - a1)(y_ss - K.u_ss)
    close(m.A[0], [[a1, a2 - a1], [0, a2]])
    close(m.F[0], [[1.2 * (1 - a1), -0.5 * (1 - a2)], [0, -0.5 * (1 - a2)]])
    close(m.f[0], [(1 - a1) * (50 - 1.2 * 15 + 0.5 * 3), 0])
    close(m.mu0[0], [50, -0.5 * 3])  # the operating point: the part due to u2 is K2 u2_ss
    close(m.C[0], [[1, 0]])
    close(m.B[0], [[0.1, 0], [0, 0]])  # the process noise is on the output, not on the parts
    close(m.D[0], [[0.2]])


@pytest.mark.parametrize("d1, d2", [(0, 0), (2.5, 0), (0, 3), (1.25, 4.5)])
def test_two_input_fopdt_step_responses_are_the_sum_of_the_continuous_ones(d1, d2):
    m = compiled_quietly(TWO_INPUT_FOPDT.format(d1=d1, d2=d2))
    T = 60
    t = np.arange(1, T + 1)
    u = np.tile([16.0, 5.0], (T, 1))  # both inputs step at t = 0 from the operating point

    def response(gain, step, tau, delay):
        return gain * step * np.clip(1 - np.exp(-(t - delay) / tau), 0, None)

    expected = 50 + response(1.2, 1.0, 10, d1) + response(-0.5, 2.0, 20, d2)
    close(run(m, 0, u, m.mu0[0]), expected)


def test_fopdt_registers_belong_to_their_input_so_modes_may_name_the_inputs_in_any_order():
    m = compiled_quietly("""plant order
sample 1 s
input  u1 = 0, u2 = 0
output y
noise  process 0.1, measurement 0.2
modes  a, b
transitions stay 0.9, otherwise uniform
mode a: y ~ fopdt(u1, u2, gain 2, tau [4 8] s, delay [1 2] s)
mode b: y ~ fopdt(u2, u1, gain [1 3], tau 5 s, delay 1 s)
""")
    assert m.states == ("y", "y_u2", "y_u1_u0", "y_u2_u0", "y_u2_u1", "y_u1")
    u1_0, u2_0, u2_1 = 2, 3, 4
    for k in range(2):  # in both modes u1 enters y_u1_u0 and u2 enters y_u2_u0, then y_u2_u1
        close(m.F[k, u1_0], [1, 0])
        close(m.F[k, u2_0], [0, 1])
        assert m.A[k, u2_1, u2_0] == 1.0
    a = np.exp(-1 / 5)
    # mode b: the output less the u1 part is u2's part; u1 (gain 3, one sample late) reaches both
    close(m.A[1, 0, [0, 5, 2, 3]], [a, 0, 3 * (1 - a), 1 * (1 - a)])
    close(m.A[1, 5, [5, 2]], [a, 3 * (1 - a)])
    assert not m.A[1, 1].any() and not m.A[0, 5].any()  # each mode leaves the other's part at zero


def test_a_scalar_gain_holds_for_every_input_and_a_vector_must_have_one_per_input():
    one = compiled_quietly(TWO_INPUT_FOPDT.replace("gain [1.2 -0.5]", "gain 2").format(d1=0, d2=0))
    two = compiled_quietly(TWO_INPUT_FOPDT.replace("gain [1.2 -0.5]", "gain [2 2]").format(d1=0, d2=0))
    close(one.F, two.F)
    assert_located(TWO_INPUT_FOPDT.replace("tau [10 20] s", "tau [10 20 30] s").format(d1=0, d2=0),
                   "two.jmlg", 6, 51, "'tau' takes one value for every input or one per input (2 here), got 1 x 3")


MULTI_ERRORS = [
    ("at names one input", "at u1 15 -> 50", 6, 80,
     "a block with several inputs gives its operating point as 'u_ss [...], y_ss VALUE', "
     "with one u_ss value per input"),
    ("u_ss alone", "u_ss [15 3]", 6, 82,
     "an operating point needs both 'u_ss [...]' (the inputs) and 'y_ss VALUE' (the output)"),
]


@pytest.mark.parametrize("label, point, line, column, message", MULTI_ERRORS, ids=[e[0] for e in MULTI_ERRORS])
def test_the_operating_point_of_several_inputs_is_u_ss_and_y_ss(label, point, line, column, message):
    text = TWO_INPUT_FOPDT.replace("u_ss [15 3], y_ss 50", point).format(d1=0, d2=0)
    assert_located(text, "two.jmlg", line, column, message)


def test_u_ss_on_a_single_input_block_says_to_use_at():
    text = TWO_INPUT_FOPDT.replace("fopdt(u1, u2, gain [1.2 -0.5], tau [10 20] s, delay [{d1} {d2}] s,",
                                   "fopdt(u1, gain 1.2, tau 10 s,")
    assert_located(text, "one.jmlg", 6, 46, "fopdt has no argument 'u_ss'; it takes gain, tau, delay; a block with "
                                             "one input gives its operating point as 'at INPUT VALUE -> OUTPUT'")


def test_an_input_named_twice_is_located():
    text = TWO_INPUT_FOPDT.replace("fopdt(u1, u2,", "fopdt(u1, u1,").format(d1=0, d2=0)
    assert_located(text, "two.jmlg", 6, 26, "input 'u1' is named twice in the fopdt block")


def test_state_names_that_would_hold_two_things_are_an_error():
    # output y's single-input block keeps u_{t-1} in y_u1; the second mode's part for input u1 is y_u1 too
    text = """plant clash
sample 1 s
input  u0 = 0, u1 = 0
output y
noise  process 0.1, measurement 0.2
modes  a, b
transitions stay 0.9, otherwise uniform
mode a: y ~ fopdt(u0, gain 1, tau 5 s, delay 2 s)
mode b: y ~ fopdt(u0, u1, gain 1, tau 5 s)
"""
    assert_located(text, "clash.jmlg", 9, 13, "the fopdt block needs a state 'y_u1' for the part of output 'y' due "
                   "to input 'u1', but that name already holds a past value of the block input (output 'y'); "
                   "rename an input or output")


TWO_INPUT_ARX = """plant mix
sample 1 s
input  u1 = 1, u2 = 2
output y
noise  process 0.1, measurement 0.2
mode only: y ~ arx(u1, u2, a [-0.5 0.1], b [0.4 0.3 0; 0.2 0 -0.1], u_ss [1 2], y_ss 4)
"""


def test_two_input_arx_has_one_row_of_b_per_input():
    m = compiled_quietly(TWO_INPUT_ARX)
    assert m.states == ("y", "y_y1", "y_u1_u0", "y_u1_u1", "y_u2_u0", "y_u2_u1")
    close(m.A[0, 0], [0.5, -0.1, 0.3, 0, 0, -0.1])
    close(m.F[0, 0], [0.4, 0.2])
    close(m.f[0, 0], 4 * (1 - 0.5 + 0.1) - (1 * 0.7 + 2 * 0.1))
    close(m.mu0[0], [4, 4, 1, 1, 2, 2])
    for first, second, k in ((2, 3, 0), (4, 5, 1)):  # each input shifts through its own registers
        assert m.F[0, first, k] == 1.0 and m.A[0, second, first] == 1.0


def test_two_input_arx_reproduces_its_difference_equation():
    m = compiled_quietly(TWO_INPUT_ARX)
    rng = np.random.default_rng(3)
    u = rng.normal(size=(40, 2))
    y = run(m, 0, u, np.zeros(m.nx))
    yp, up = np.concatenate([[0, 0], y]), np.concatenate([np.zeros((2, 2)), u])
    for t in range(2, 42):
        rhs = (0.5 * yp[t - 1] - 0.1 * yp[t - 2] + 0.4 * up[t, 0] + 0.3 * up[t - 1, 0]
               + 0.2 * up[t, 1] - 0.1 * up[t - 2, 1] + m.f[0, 0])
        assert yp[t] == pytest.approx(rhs, abs=1e-12)


def test_arx_b_needs_one_row_per_input():
    text = TWO_INPUT_ARX.replace("b [0.4 0.3 0; 0.2 0 -0.1]", "b [0.4 0.3]")
    assert_located(text, "mix.jmlg", 6, 44, "'b' has one row of coefficients per input: 2 rows here, got 1")


# ------------------------------------------------------------------ 2. a mode's own input values

SUPPLY = """plant press
sample 1 s
input  supply [V] = 230, load = 1
output y
state  x
param  c = 0.02
noise  process 0.1, measurement 0.1
modes
  normal
  sag  "supply at 200 V": supply = 200
  deep "supply lowered with c": c = 0.03; supply = 230 - 1000 * c
transitions stay 0.98, otherwise uniform
mode normal {
  x[t] ~ Normal(0.9 * x[t-1] + c * supply - 2 * load + 1, 0.1)
  y ~ Normal(2 * x[t] + 0.5 * supply + 3, 0.1)
}
mode sag like normal
mode deep like normal
"""


def test_a_mode_input_value_shifts_the_offsets_by_the_input_columns():
    m = compiled_quietly(SUPPLY)
    close(m.F[:, 0], [[0.02, -2], [0.02, -2], [0.03, -2]])
    close(m.f[:, 0], [1, 1 + 0.02 * (200 - 230), 1 + 0.03 * (200 - 230)])  # f + F[:, supply] * shift
    close(m.g[:, 0], [3, 3 + 0.5 * (200 - 230), 3 + 0.5 * (200 - 230)])  # g + G[:, supply] * shift
    close(m.A[:, 0, 0], 0.9)
    # initial means: each mode's steady state with the declared inputs, i.e. with its own supply
    close(m.mu0[:, 0], [(0.02 * 230 - 2 + 1) / 0.1, (0.02 * 200 - 2 + 1) / 0.1, (0.03 * 200 - 2 + 1) / 0.1])
    close(m.input_defaults, [230, 1])


def test_a_mode_block_statement_sets_an_input_value_too():
    block = SUPPLY.replace('  sag  "supply at 200 V": supply = 200\n', "  sag\n").replace(
        "mode sag like normal", "mode sag like normal { supply = 200 }")
    close(compiled_quietly(block).f, compiled_quietly(SUPPLY).f)


def test_a_block_operating_point_moves_with_the_mode_input():
    m = compiled_quietly(DOC_BLOCKS["heater_sag"])
    a = np.exp(-1 / 45)
    close(m.f[:, 0], [(1 - a) * (90 - 0.3 * 230), (1 - a) * (90 - 0.3 * 230) + 0.3 * (1 - a) * (200 - 230)])
    close(m.mu0[:, 0], [90, 81])
    close(m.A[1] @ m.mu0[1] + m.F[1] @ [230] + m.f[1], m.mu0[1])  # at rest under the declared supply


def test_a_delayed_block_in_a_mode_with_its_own_input_starts_at_rest_with_shifted_registers():
    text = DOC_BLOCKS["furnace"].replace("modes cold, hot", 'modes cold, hot, lean "fuel reads 5 % high": fuel = 35') \
        + "mode lean like cold\n"
    m = compiled_quietly(text)
    close(m.mu0[2], [320 + 3.1 * (35 - 40), 35, 35, 35, 35])  # the output by K shift, the registers by the shift
    close(m.A[2] @ m.mu0[2] + m.F[2] @ [40] + m.f[2], m.mu0[2])  # at rest with the fuel at its declared 40
    close(m.f[2, 1:], [-5, 0, 0, 0])  # the first register holds the input the mode feels


def test_a_mode_input_value_needs_a_declared_value():
    text = SUPPLY.replace("input  supply [V] = 230, load = 1", "input  supply [V], load = 1")
    assert_located(text, "press.jmlg", 10, 27, "mode 'sag' sets input 'supply', which has no declared value to "
                   "differ from: declare it as 'input supply = VALUE'")


TANK = """plant tank
sample 1 s
input  q [l/s] = 2
output h
state  h = 10
param  k = 0.5, area = 2
ode
  der(h) = (q - k * sqrt(h)) / area
noise process 0.01, measurement 0.05
modes
  normal
  sag "the pump sags": q = 1.5
transitions stay 0.99, otherwise uniform
"""


def test_an_ode_mode_with_its_own_input_sits_at_its_own_steady_state():
    m = compiled_quietly(TANK)
    close(m.mu0[:, 0], [16, 9])  # sqrt(h) = q / k: 2 / 0.5 and 1.5 / 0.5
    J = -0.5 / (2 * 3 * 2)  # d der(h) / dh at h = 9
    A = np.exp(J)
    close(m.A[1], [[A]])
    close(m.F[1], [[(A - 1) / J * 0.5]])
    # offset of the linearisation at (9, 1.5), then shifted by F (1.5 - 2) to act on the declared input
    close(m.f[1], [(A - 1) / J * (0 - J * 9 - 0.5 * 1.5) + (A - 1) / J * 0.5 * (1.5 - 2)])
    close(m.A[1] @ m.mu0[1] + m.F[1] @ [2] + m.f[1], m.mu0[1])


def test_an_ode_mode_linearised_elsewhere_still_acts_on_its_own_input():
    m = compiled_quietly(TANK + "linearize at steady state of normal\n")
    J = -0.5 / (2 * 4 * 2)
    A, F = np.exp(J), (np.exp(J) - 1) / J * 0.5
    close(m.A[:, 0, 0], A)
    close(m.f[:, 0], [(A - 1) / J * (-J * 16 - 1), (A - 1) / J * (-J * 16 - 1) + F * (1.5 - 2)])
    close(m.mu0[:, 0], [16, 16 + (2 * 4 / 0.5) * (1.5 - 2)])  # the tangent's rest: dh/dq = 2 sqrt(h) / k


def test_a_nonlinear_simulation_feeds_each_mode_its_own_input(tmp_path):
    """The integrated equations see the sag: from the normal steady state the level falls towards the
    sag mode's own steady state, 9, with the declared input 2 in the data."""
    spec = tmp_path / "tank.jmlg"
    spec.write_text(TANK.replace("noise process 0.01, measurement 0.05", "noise process 0, measurement 1e-9"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sim = simulate_nonlinear(str(spec), modes="1-1200:sag", seed=0)  # 25 time constants of about 48 s
    np.testing.assert_allclose(sim.x[-1], [9.0], rtol=1e-6)


# ------------------------------------------------------------------ 3. an output's initial sd

def test_output_sd_sets_the_blocks_output_states_and_not_the_registers():
    fopdt = compiled_quietly(DOC_BLOCKS["dryer_two_inputs"])
    close(np.diag(fopdt.Sigma0), [4, 0, 0, 0, 0])
    arx = compiled_quietly(DOC_BLOCKS["mixing_arx"])
    close(np.diag(arx.Sigma0), [0.25, 0.25, 0, 0])  # y and y_{t-1}; not the registers
    furnace = compiled_quietly(DOC_BLOCKS["furnace"].replace("output temp [degC]", "output temp [degC] sd 3"))
    close(np.diag(furnace.Sigma0), [9, 0, 0, 0, 0])


def test_output_sd_without_a_block_is_an_error_that_says_what_it_is_for():
    text = SUPPLY.replace("output y", "output y sd 2")
    assert_located(text, "press.jmlg", 4, 13, "an output's 'sd' is the initial standard deviation of its fopdt or "
                   "arx block, and no mode gives 'y' one; a state takes its own: 'state NAME = MEAN sd SD'")
    assert_located(TANK.replace("output h", "output h sd 2"), "tank.jmlg", 4, 13, "no mode gives 'h' one")


# ------------------------------------------------------------------ 4. identical modes

LEAK = """plant leak
sample 1 s
output y
param k = 0.5, unused = 1
modes normal, leak "a leak": unused = 2
transitions stay 0.99, otherwise uniform
mode normal { y ~ fopdt(one, gain k, tau 5 s) }
mode leak like normal
input one = 1
noise process 0.1, measurement 0.1
"""


def test_a_mode_identical_to_an_earlier_one_is_warned_about_at_the_later_mode():
    with pytest.warns(SpecWarning) as caught:
        compile_text(LEAK, "leak.jmlg")
    assert [str(w.message.diagnostic.format()).splitlines()[0] for w in caught] == [
        "leak.jmlg:5:15: warning: mode 'leak' compiles to exactly the same model as mode 'normal' (the same "
        "matrices and initial mean): what it changes reaches no matrix, so the data cannot tell the two apart"]


@pytest.mark.parametrize("change", ["unused = 2; k = 0.6", "unused = 2; one = 2"])
def test_a_mode_that_changes_a_used_parameter_or_input_is_not_warned_about(change):
    compiled_quietly(LEAK.replace('"a leak": unused = 2', f'"a leak": {change}'))


def test_modes_differing_only_in_noise_or_initial_mean_are_not_warned_about():
    compiled_quietly(LEAK.replace("mode leak like normal", "mode leak like normal { noise scale 2 }"))
    compiled_quietly(LEAK.replace("mode leak like normal", "mode leak like normal { y[0] = 3 }"))


@pytest.mark.parametrize("path", sorted((ROOT / "specs").glob("*.jmlg")), ids=lambda p: p.name)
def test_no_shipped_spec_has_identical_modes(path):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        warnings.simplefilter("ignore", ResourceWarning)  # a file another test left open, collected now
        compile_file(path)
    assert not [w for w in caught if "exactly the same model" in str(w.message)]


# ------------------------------------------------------------------ the documented examples of these features

def check_dryer_two_inputs(m):
    a1, a2 = np.exp(-1 / 30.45), np.exp(-1 / 12)
    assert m.states == ("temp", "temp_fan", "temp_fan_u0", "temp_fan_u1", "temp_fan_u2")
    close(m.A[0, :2], [[a1, a2 - a1, 0, 0, -0.12 * (1 - a2)], [0, a2, 0, 0, -0.12 * (1 - a2)]])
    close(m.A[0, 2:], [[0, 0, 0, 0, 0], [0, 0, 1, 0, 0], [0, 0, 0, 1, 0]])  # the fan's registers shift
    close(m.F[0], [[1.94 * (1 - a1), 0], [0, 0], [0, 1], [0, 0], [0, 0]])
    close(m.f[0], [(1 - a1) * (50.52 - 1.94 * 15 + 0.12 * 50), 0, 0, 0, 0])
    close(m.mu0[0], [50.52, -0.12 * 50, 50, 50, 50])
    close(m.Sigma0, np.diag([4.0, 0, 0, 0, 0]))
    close(m.B[0], np.diag([0.05, 0, 0, 0, 0]))


def check_mixing_arx(m):
    assert m.states == ("temp", "temp_y1", "temp_hot_u0", "temp_cold_u0") and m.dt == 10.0
    close(m.A[0], [[1.3, -0.4, 0.03, 0], [1, 0, 0, 0], [0, 0, 0, 0], [0, 0, 0, 0]])
    close(m.F[0], [[0.05, -0.02], [0, 0], [1, 0], [0, 1]])
    close(m.f[0], [35 * (1 - 1.3 + 0.4) - (40 * 0.08 - 60 * 0.02), 0, 0, 0])
    close(m.mu0[0], [35, 35, 40, 60])
    close(m.Sigma0, np.diag([0.25, 0.25, 0, 0]))


def check_heater_sag(m):
    assert m.modes == ("normal", "sag") and m.descriptions == {"sag": "Supply sags to 200 V"}
    a = np.exp(-1 / 45)
    close(m.A[:, 0, 0], a)
    close(m.F[:, 0, 0], 0.3 * (1 - a))
    close(m.f[:, 0], [(1 - a) * 21, (1 - a) * 12])  # 90 - 0.3 * 230 = 21; 21 + 0.3 * (200 - 230) = 12
    close(m.mu0[:, 0], [90, 81])
    close(m.P, [[0.99, 0.01], [0.01, 0.99]])


DOC_CHECKS = {name[len("check_"):]: fn for name, fn in globals().items() if name.startswith("check_")}
