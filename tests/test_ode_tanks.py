"""The two-tank plant (tests/data/tanks.jmlg) against its closed-form steady state and Jacobian, the
fixed-point linearisations, and the nonlinear simulator against the linearised model and the filters."""

from pathlib import Path

import numpy as np
import pytest
from scipy.linalg import expm, solve_discrete_lyapunov

import jmlgdsl
from jmlgdsl.compile.lower import compile_text
from jmlgdsl.compile.ode import zoh
from jmlgdsl.errors import SpecError
from jmlgdsl.simulation.nonlinear import load_nonlinear, simulate_nonlinear
from jmlgdsl.simulation.linear import simulate

DATA = Path(__file__).resolve().parent / "data"
SPECS = Path(__file__).resolve().parent.parent / "specs"
AREA1, AREA2, K1, INFLOW, DT = 2.0, 4.0, 0.5, 1.0, 2.0
K2 = {"normal": 0.4, "clogged": 0.3}


def closed_form(k2: float, h1: float, h2: float, q: float = INFLOW):
    """Continuous Jacobians and affine terms of the tanks at (h1, h2) with inflow q, by hand."""
    J = np.array([[-K1 / (2 * AREA1 * np.sqrt(h1)), 0.0],
                  [K1 / (2 * AREA2 * np.sqrt(h1)), -k2 / (2 * AREA2 * np.sqrt(h2))]])
    Ju = np.array([[1 / AREA1], [0.0]])
    rates = np.array([(q - K1 * np.sqrt(h1)) / AREA1, (K1 * np.sqrt(h1) - k2 * np.sqrt(h2)) / AREA2])
    c = rates - J @ [h1, h2] - Ju[:, 0] * q
    H = np.array([[1.0, 0.0], [0.0, k2 / (2 * np.sqrt(h2))]])
    g = np.array([h1, k2 * np.sqrt(h2)]) - H @ [h1, h2]
    return J, Ju, c, H, g


def discrete(J, Ju, c):
    """Zero-order hold by the textbook formulas: A = e^{J dt}, integral of e^{Js} = J^{-1}(A - I)."""
    A = expm(J * DT)
    S = np.linalg.solve(J, A - np.eye(2))
    return A, S @ Ju, S @ c


@pytest.fixture(scope="module")
def tanks():
    return jmlgdsl.load(DATA / "tanks.jmlg")


def test_steady_states_are_the_closed_form(tanks):
    for k, mode in enumerate(tanks.modes):
        np.testing.assert_allclose(tanks.mu0[k], [(INFLOW / K1) ** 2, (INFLOW / K2[mode]) ** 2], rtol=1e-10)


def test_modes_are_the_closed_form_linearisation(tanks):
    for k, mode in enumerate(tanks.modes):
        J, Ju, c, H, g = closed_form(K2[mode], *tanks.mu0[k])
        A, F, f = discrete(J, Ju, c)
        np.testing.assert_allclose(tanks.A[k], A, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(tanks.F[k], F, rtol=1e-12)
        np.testing.assert_allclose(tanks.f[k], f, rtol=1e-12)
        np.testing.assert_allclose(tanks.C[k], H, rtol=1e-12)
        np.testing.assert_allclose(tanks.g[k], g, rtol=1e-12, atol=1e-15)
        np.testing.assert_array_equal(tanks.G[k], 0.0)
    assert tanks.dt == DT and list(tanks.inputs) == ["inflow"] and list(tanks.input_defaults) == [INFLOW]


def test_zoh_of_a_scalar_system():
    """dx/dt = a x + b u + c over dt: A = e^{a dt}, F = b (A - 1) / a, f = c (A - 1) / a."""
    a, b, c, dt = -0.3, 2.0, 0.5, 1.5
    A, F, f = zoh(np.array([[a]]), np.array([[b]]), np.array([c]), dt)
    e = np.exp(a * dt)
    np.testing.assert_allclose([A[0, 0], F[0, 0], f[0]], [e, b * (e - 1) / a, c * (e - 1) / a], rtol=1e-14)


def test_linearising_at_a_given_point_uses_it_for_every_mode(tanks):
    text = (DATA / "tanks.jmlg").read_text()
    at_point = compile_text(text + "\nlinearize at h1 = 4, h2 = 6.25, inflow = 1.2\n")
    for k, mode in enumerate(at_point.modes):
        J, Ju, c, H, g = closed_form(K2[mode], 4.0, 6.25, q=1.2)
        A, F, f = discrete(J, Ju, c)
        np.testing.assert_allclose(at_point.A[k], A, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(at_point.f[k], f, rtol=1e-12)
        np.testing.assert_allclose(at_point.g[k], g, rtol=1e-12, atol=1e-15)
        # the initial mean is where the linearised mode settles under the operating input 1
        np.testing.assert_allclose(at_point.A[k] @ at_point.mu0[k] + at_point.F[k] @ [1.0] + at_point.f[k],
                                   at_point.mu0[k], rtol=1e-12)
    np.testing.assert_allclose(at_point.input_defaults, [INFLOW])


def test_linearising_at_one_modes_steady_state(tanks):
    """`linearize at steady state of normal`: the normal mode is unchanged, the clogged mode is taken
    at the normal steady state (4, 6.25) with its own parameters."""
    text = (DATA / "tanks.jmlg").read_text()
    shared = compile_text(text + "\nlinearize at steady state of normal\n")
    np.testing.assert_allclose(shared.A[0], tanks.A[0], rtol=1e-12)
    np.testing.assert_allclose(shared.f[0], tanks.f[0], rtol=1e-12)
    J, Ju, c, _, _ = closed_form(K2["clogged"], 4.0, 6.25)
    A, F, f = discrete(J, Ju, c)
    np.testing.assert_allclose(shared.A[1], A, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(shared.f[1], f, rtol=1e-12)
    assert not np.allclose(shared.A[1], tanks.A[1])


def test_small_perturbations_agree_to_second_order():
    """Step the inflow by delta from the operating point: the linearised model's response is first
    order in delta, its gap to the nonlinear one second order (halving delta quarters the gap)."""
    plant = load_nonlinear(DATA / "tanks.jmlg")
    m = plant.model
    gaps, moves = [], []
    for delta in (0.02, 0.01, 0.005):
        u = np.array([INFLOW + delta])
        x_nl = x_lin = m.mu0[0]
        gap = move = 0.0
        for _ in range(40):
            x_nl = plant.step(x_nl, u, 0)
            x_lin = m.A[0] @ x_lin + m.F[0] @ u + m.f[0]
            gap, move = max(gap, np.abs(x_nl - x_lin).max()), max(move, np.abs(x_lin - m.mu0[0]).max())
        gaps.append(gap)
        moves.append(move)
    assert moves[0] / moves[1] == pytest.approx(2.0, rel=1e-9)  # exactly linear
    for big, small in zip(gaps, gaps[1:]):
        assert big / small == pytest.approx(4.0, rel=0.05)  # O(delta^3) relative corrections
    assert gaps[-1] < 2 * 0.005 / INFLOW * moves[-1]  # relative gap ~ dh/h ~ 2 delta/inflow


def test_nonlinear_simulation_shares_modes_and_noise_with_the_linear_one():
    """One seed, one schedule: the same modes, and the same process and measurement noise draws."""
    plant = load_nonlinear(SPECS / "cstr4.jmlg")
    m = plant.model
    schedule = "1-30:normal,31-80:fouling3,81-100:fouling1"
    nl = simulate_nonlinear(plant, seed=7, modes=schedule)
    lin = simulate(m, seed=7, modes=schedule)
    np.testing.assert_array_equal(nl.modes, lin.modes)
    np.testing.assert_array_equal(nl.x0, lin.x0)
    np.testing.assert_allclose(nl.y - nl.x, lin.y - lin.x, atol=1e-12)  # C = I: y - x is D v
    prev_nl, prev_lin = np.vstack([nl.x0, nl.x[:-1]]), np.vstack([lin.x0, lin.x[:-1]])
    w_nl = [x - plant.step(p, u, k) for x, p, u, k in zip(nl.x, prev_nl, nl.u, nl.modes)]
    w_lin = [x - (m.A[k] @ p + m.f[k]) for x, p, k in zip(lin.x, prev_lin, lin.modes)]
    np.testing.assert_allclose(w_nl, w_lin, atol=1e-10)
    assert list(nl.columns()) == list(lin.columns())


def test_nonlinear_simulation_follows_the_mode_parameters():
    """Without noise reaching far from it, a long stay in a mode ends at that mode's own steady
    state: the nonlinear plant, not the first mode's."""
    plant = load_nonlinear(DATA / "tanks.jmlg")
    sim = simulate_nonlinear(plant, seed=1, modes="1-5:normal,6-400:clogged")
    m = plant.model
    sd = np.sqrt(np.diag(solve_discrete_lyapunov(m.A[1], m.Q[1])))  # stationary spread in the mode
    assert np.all(np.abs(sim.x[-20:].mean(0) - m.mu0[1]) < 5 * sd)  # 395 steps is 9 time constants
    assert abs(sim.x[-1, 1] - m.mu0[0, 1]) > 3.0


def test_nonlinear_simulation_is_reproducible():
    plant = load_nonlinear(DATA / "tanks.jmlg")
    a = simulate_nonlinear(plant, 50, seed=3)
    b = simulate_nonlinear(plant, 50, seed=np.random.default_rng(3))
    np.testing.assert_array_equal(a.y, b.y)
    np.testing.assert_array_equal(a.modes, b.modes)


def test_nonlinear_simulation_of_a_linear_plant_is_an_error():
    with pytest.raises(SpecError, match="a nonlinear simulation needs a nonlinear plant"):
        simulate_nonlinear(SPECS / "dryer.jmlg", 10, seed=0)


def test_the_linearised_bank_diagnoses_the_nonlinear_reactor():
    """The purpose of the nonlinear simulator: the IMM filter on the linearised CSTR bank, fed the
    nonlinear plant's measurements, holds normal before the fault and settles on 15 % fouling well
    within 2 min (20 samples) after it; over seeds 0-5 it settles within 5 samples."""
    plant = load_nonlinear(SPECS / "cstr4.jmlg")
    for seed in (0, 1):
        sim = simulate_nonlinear(plant, seed=seed, modes="1-150:normal,151-300:fouling3")
        found = jmlgdsl.filter(plant.model, sim.y, algorithm="imm").map_modes
        assert np.all(found[:150] == 0)
        assert np.all(found[170:] == plant.model.mode_index("fouling3"))


def test_guesses_that_root_finding_overshoots_are_let_settle():
    """From h1 = 100 the first Newton step empties the tank (h1 < 0, sqrt undefined); the compiler
    then lets the plant settle from the guesses and finds the steady state from there."""
    text = (DATA / "tanks.jmlg").read_text().replace("h1 [m] = 3, h2 [m] = 5", "h1 [m] = 100, h2 [m] = 100")
    model = compile_text(text)
    for k, mode in enumerate(model.modes):
        np.testing.assert_allclose(model.mu0[k], [(INFLOW / K1) ** 2, (INFLOW / K2[mode]) ** 2], rtol=1e-10)
