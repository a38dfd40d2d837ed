"""The shared lagged basis: its realisation, the change of units, EM inside the structure."""

from dataclasses import replace

import numpy as np
import pytest

from jmlgdsl.learn import arx, basis
from jmlgdsl.learn.em import forward


def two_output_mode():
    """Order 2, two outputs, one input, with the input acting from lag 0 and lag 1."""
    Phi = np.array([[0.9, 0.1, -0.2, 0.0], [0.05, 0.6, 0.0, 0.1]])
    Psi = np.array([[0.5, 0.2], [0.0, -0.3]])
    return basis.LaggedMode(basis.Lags(2, 2, 0), Phi, Psi, np.array([1.0, -2.0]),
                             np.array([[0.04, 0.01], [0.01, 0.02]]), np.array([[0.01, 0.0], [0.0, 0.03]]),
                             np.array([3.0, -4.0, 2.5, -3.5]), 0.1 * np.eye(4))


def data(mode, T=400, seed=0):
    rng = np.random.default_rng(seed)
    u = rng.choice([-1.0, 1.0], size=(T, 1)).repeat(3, axis=0)[:T]
    ss = mode.statespace(u[0])
    x, y = ss.mu0.copy(), np.empty((T, mode.ny))
    for t in range(T):
        x = ss.A @ x + ss.F @ u[t] + ss.f + np.r_[np.linalg.cholesky(mode.Q) @ rng.standard_normal(mode.ny),
                                                  np.zeros(ss.nx - mode.ny)]
        y[t] = x[:mode.ny] + np.linalg.cholesky(mode.R) @ rng.standard_normal(mode.ny)
    return y, u


def test_the_realisation_and_the_reduced_model_have_the_same_likelihood():
    """The shared-basis realisation (input lags as states) and EM's reduced model (input lags as
    inputs) are the same model: equal log-likelihoods on the same data."""
    mode = two_output_mode()
    y, u = data(mode)
    full = forward(mode.statespace(u[0]), y, u).loglik
    reduced = forward(mode.reduced(), y, basis.lag_inputs(u, mode.n)).loglik
    assert full == pytest.approx(reduced, rel=1e-12)
    assert mode.statespace(u[0]).nx == 2 * 2 + 1


def test_a_larger_basis_pads_with_zeros_and_keeps_the_response():
    mode = two_output_mode()
    _, u = data(mode, T=60)
    small, large = mode.statespace(u[0]), mode.statespace(u[0], n=4)
    assert large.nx == 4 * 2 + 3
    assert np.allclose(small.free_run(u), large.free_run(u), atol=1e-12)
    assert np.allclose(small.gain(), large.gain())


def test_a_change_of_units_is_exact_both_ways():
    mode = two_output_mode()
    dy, my, du, mu = np.array([1e3, 1e-2]), np.array([5.0, -7.0]), np.array([4.0]), np.array([15.0])
    scaled = basis.transformed(mode, dy, my, du, mu)
    _, u = data(mode, T=80)
    y_scaled = scaled.statespace(du * u[0] + mu).free_run(du * u + mu)
    assert np.allclose(y_scaled, dy * mode.statespace(u[0]).free_run(u) + my, rtol=1e-12, atol=1e-9)
    back = basis.transformed(scaled, 1 / dy, -my / dy, 1 / du, -mu / du)
    for name in ("Phi", "Psi", "c", "Q", "R", "mu0", "Sigma0"):
        assert np.allclose(getattr(back, name), getattr(mode, name), rtol=1e-12, atol=1e-12), name


def test_em_fits_sensors_in_any_units_alike():
    """Learning 1000 y + 5 (and one sensor in thousandths) gives the mode learned from y mapped to
    those units, and the log-likelihood moves by exactly the Jacobian."""
    mode = two_output_mode()
    y, u = data(mode, seed=3)
    start = arx.fit_arx(y, u, 2, 2, 0).lagged()
    fitted, result = basis.fit_em(start, y, u, max_iter=15, tol=0.0)
    dy, my = np.array([1e3, 1e-3]), np.array([5.0, 0.0])
    fitted2, result2 = basis.fit_em(basis.transformed(start, dy, my, [1.0], [0.0]), dy * y + my, u, max_iter=15, tol=0.0)
    back = basis.transformed(fitted2, 1 / dy, -my / dy, [1.0], [0.0])
    assert np.allclose(back.Phi, fitted.Phi, atol=1e-8) and np.allclose(back.Q, fitted.Q, rtol=1e-6)
    assert result2.loglik[-1] == pytest.approx(result.loglik[-1] - len(y) * np.log(dy).sum(), rel=1e-9)
    assert np.all(np.diff(result.loglik) >= -1e-9 * np.abs(result.loglik[:-1]))


def test_em_keeps_the_structure_and_finds_at_least_the_truths_likelihood():
    """Coefficients the structure leaves out stay zero; the maximum-likelihood fit is at least as
    likely as the true mode (a point of the same structure), and the steady-state gains, which the
    PRBS pins down, land near the truth."""
    mode = replace(two_output_mode(), lags=basis.Lags(2, 1, 0))
    mode = replace(mode, Psi=mode.Psi * [1.0, 0.0])
    y, u = data(mode, T=2000, seed=4)
    fitted, result = basis.fit_em(arx.fit_arx(y, u, 2, 1, 0).lagged(), y, u)
    assert np.array_equal(fitted.Psi[:, 1], [0.0, 0.0])
    assert result.converged
    truth = forward(mode.statespace(u[0]), y, u).loglik
    assert result.loglik[-1] >= truth
    assert np.allclose(fitted.statespace(u[0]).gain(), mode.statespace(u[0]).gain(), atol=0.1)


def test_state_names_say_which_lag():
    assert basis.state_names(("temp", "flow"), ("current",), 2) == (
        "temp_lag1", "flow_lag1", "temp_lag2", "flow_lag2", "current_lag1")
    assert basis.state_names(("y",), (), 1) == ("y_lag1",)
