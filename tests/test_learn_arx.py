"""ARX least squares: exact coefficients, the covariance formula, several outputs, order
selection, and the lagged form it hands to EM."""

from dataclasses import replace

import numpy as np
import pytest

from jmlgdsl.errors import DataError
from jmlgdsl.learn import arx

PHI_TRUE = np.array([1.2, -0.5])        # y_t = 1.2 y_{t-1} - 0.5 y_{t-2}
PSI_TRUE = np.array([0.8, 0.3])         #     + 0.8 u_{t-1} + 0.3 u_{t-2}  (nk = 1)
C_TRUE = 0.4


def arx_data(T=800, noise=0.0, seed=0):
    rng = np.random.default_rng(seed)
    u = rng.choice([-1.0, 1.0], size=(T, 1))
    y = np.zeros(T)
    for t in range(2, T):
        y[t] = PHI_TRUE @ y[t - 2:t][::-1] + PSI_TRUE @ u[t - 2:t, 0][::-1] + C_TRUE + noise * rng.standard_normal()
    return y, u


def test_noise_free_coefficients_are_exact():
    y, u = arx_data()
    fit = arx.fit_arx(y, u, 2, 2, 1)
    assert np.allclose(fit.theta[:, 0], np.r_[PHI_TRUE, PSI_TRUE, C_TRUE], atol=1e-10)
    assert fit.order == (2, 2, 1)


def test_covariance_is_sigma2_times_inverse_gram_and_errors_are_within_it():
    y, u = arx_data(noise=0.1, seed=1)
    fit = arx.fit_arx(y, u, 2, 2, 1)
    rows = np.arange(2, len(y))
    X = np.column_stack([y[rows - 1], y[rows - 2], u[rows - 1, 0], u[rows - 2, 0], np.ones(len(rows))])
    assert np.allclose(fit.cov, fit.noise[0, 0] * np.linalg.inv(X.T @ X), rtol=1e-8)
    z = (fit.theta[:, 0] - np.r_[PHI_TRUE, PSI_TRUE, C_TRUE]) / np.sqrt(np.diag(fit.cov))
    assert np.abs(z).max() < 4  # five estimates, each N(0,1) in large samples
    assert fit.noise[0, 0] == pytest.approx(0.01, rel=4 * np.sqrt(2 / fit.n))


def test_several_outputs_share_one_factor_and_fit_a_var():
    """A two-output VAR(1) with cross-coupling, correlated noise and one input: the coefficients
    within 4 standard errors (from the Kronecker covariance) and the noise covariance within 4 of
    its own (each entry's standard error is about sqrt((s_ii s_jj + s_ij^2) / N))."""
    rng = np.random.default_rng(5)
    Phi = np.array([[0.7, 0.2], [-0.1, 0.5]])
    Psi = np.array([[1.0], [0.3]])
    c = np.array([0.5, -1.0])
    L = np.linalg.cholesky(np.array([[0.04, 0.015], [0.015, 0.09]]))
    T = 3000
    u = rng.choice([-1.0, 1.0], size=(T, 1))
    y = np.zeros((T, 2))
    for t in range(1, T):
        y[t] = Phi @ y[t - 1] + Psi @ u[t] + c + L @ rng.standard_normal(2)
    fit = arx.fit_arx(y, u, 1, 1, 0)
    truth = np.vstack([Phi.T, Psi.T, c])
    z = (fit.theta.T.ravel() - truth.T.ravel()) / np.sqrt(np.diag(fit.cov))
    assert np.abs(z).max() < 4
    S = L @ L.T
    se = np.sqrt((np.outer(np.diag(S), np.diag(S)) + S ** 2) / fit.n)
    assert np.all(np.abs(fit.noise - S) < 4 * se)
    mode = fit.lagged()
    assert np.allclose(mode.Phi, Phi, atol=0.05) and np.allclose(mode.Q + mode.R, fit.noise)


def test_bic_finds_the_true_order():
    y, u = arx_data(T=2000, noise=0.1, seed=2)
    assert arx.select_order([(y, u)], max_na=3, max_nb=3, max_nk=2) == (2, 2, 1)
    with pytest.raises(ValueError, match="'aic' or 'bic'"):
        arx.select_order([(y, u)], criterion="r2")


def test_lagged_form_has_the_arx_impulse_response():
    """In the lagged basis of order max(na, nk + nb) = 3 the state holds 3 output lags and 2 input
    lags, and the noise-free realisation has the difference equation's impulse response."""
    y, u = arx_data(noise=0.05, seed=4)
    fit = arx.fit_arx(y, u, 2, 2, 1)
    mode = fit.lagged()
    assert mode.n == 3 and np.array_equal(mode.Psi[0, :1], [0.0])
    ss = replace(mode, c=np.zeros(1), mu0=np.zeros(3), Sigma0=np.zeros((3, 3))).statespace([0.0])
    assert np.array_equal(ss.C, [[1, 0, 0, 0, 0]])
    impulse = np.zeros((12, 1))
    impulse[0] = 1.0
    h = ss.free_run(impulse)[:, 0]
    phi, psi = fit.theta[:2, 0], fit.theta[2:4, 0]
    g = np.zeros(12)  # the same impulse response from the difference equation
    for t in range(12):
        g[t] = (sum(phi[i] * g[t - 1 - i] for i in range(2) if t - 1 - i >= 0)
                + sum(psi[j] * impulse[t - 1 - j, 0] for j in range(2) if t - 1 - j >= 0))
    assert np.allclose(h, g, atol=1e-12)
    assert ss.gain()[0, 0] == pytest.approx(psi.sum() / (1 - phi.sum()))


def test_equations_with_missing_values_are_left_out():
    y, u = arx_data()
    y[[10, 300]] = np.nan  # each missing output spoils the three equations it appears in
    fit = arx.fit_arx(y, u, 2, 2, 1)
    assert fit.n == len(y) - 2 - 6
    assert np.allclose(fit.theta[:, 0], np.r_[PHI_TRUE, PSI_TRUE, C_TRUE], atol=1e-10)


def test_too_little_data_is_a_data_error():
    with pytest.raises(DataError, match="only 3 complete equations"):
        arx.fit_arx(np.arange(6.0), np.ones((6, 1)), 3, 3, 0)
