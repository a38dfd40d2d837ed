"""ARX least squares: exact coefficients, the covariance formula, order selection, state-space form."""

import numpy as np
import pytest

from jmlgdsl.errors import DataError
from jmlgdsl.learn import arx

A_TRUE = np.array([-1.2, 0.5])          # y_t - 1.2 y_{t-1} + 0.5 y_{t-2}
B_TRUE = np.array([[0.8], [0.3]])       # 0.8 u_{t-1} + 0.3 u_{t-2}  (nk = 1)
C_TRUE = 0.4


def arx_data(T=800, noise=0.0, seed=0):
    rng = np.random.default_rng(seed)
    u = rng.choice([-1.0, 1.0], size=(T, 1))
    y = np.zeros(T)
    for t in range(2, T):
        y[t] = (-A_TRUE @ y[t - 2:t][::-1] + B_TRUE[:, 0] @ u[t - 2:t, 0][::-1] + C_TRUE
                + noise * rng.standard_normal())
    return y, u


def test_noise_free_coefficients_are_exact():
    y, u = arx_data()
    fit = arx.fit(y, u, 2, 2, 1)
    assert np.allclose(fit.a, A_TRUE, atol=1e-10)
    assert np.allclose(fit.b, B_TRUE, atol=1e-10)
    assert fit.c == pytest.approx(C_TRUE, abs=1e-10)
    assert fit.order == (2, 2, 1)


def test_covariance_is_sigma2_times_inverse_gram_and_errors_are_within_it():
    y, u = arx_data(noise=0.1, seed=1)
    fit = arx.fit(y, u, 2, 2, 1)
    rows = np.arange(2, len(y))
    X = np.column_stack([-y[rows - 1], -y[rows - 2], u[rows - 1, 0], u[rows - 2, 0], np.ones(len(rows))])
    assert np.allclose(fit.cov, fit.sigma2 * np.linalg.inv(X.T @ X), rtol=1e-8)
    theta = np.r_[fit.a, fit.b.ravel(), fit.c]
    z = (theta - np.r_[A_TRUE, B_TRUE.ravel(), C_TRUE]) / np.sqrt(np.diag(fit.cov))
    assert np.abs(z).max() < 4  # five estimates, each N(0,1) in large samples
    assert fit.sigma2 == pytest.approx(0.01, rel=4 * np.sqrt(2 / fit.n))


def test_bic_finds_the_true_order():
    y, u = arx_data(T=2000, noise=0.1, seed=2)
    assert arx.select_order([(y, u)], max_na=3, max_nb=3, max_nk=2) == (2, 2, 1)
    with pytest.raises(ValueError, match="'aic' or 'bic'"):
        arx.select_order([(y, u)], criterion="r2")


def test_observer_form_has_the_arx_impulse_response():
    y, u = arx_data(noise=0.05, seed=4)
    fit = arx.fit(y, u, 2, 2, 1)
    ss = fit.to_statespace(u0=[0.0], y0=0.0)
    assert np.allclose(ss.C, [[1, 0, 0]]) and ss.nx == 3
    impulse = np.zeros((12, 1))
    impulse[0] = 1.0
    h = ss.replace(f=np.zeros(3), mu0=np.zeros(3)).free_run(impulse)[:, 0]
    g = np.zeros(12)  # the same impulse response from the difference equation
    for t in range(12):
        g[t] = (-sum(fit.a[i] * g[t - 1 - i] for i in range(2) if t - 1 - i >= 0)
                + sum(fit.b[j, 0] * impulse[t - 1 - j, 0] for j in range(2) if t - 1 - j >= 0))
    assert np.allclose(h, g, atol=1e-12)
    assert ss.gain()[0, 0] == pytest.approx(fit.b.sum() / (1 + fit.a.sum()))


def test_equations_with_missing_values_are_left_out():
    y, u = arx_data()
    y[[10, 300]] = np.nan  # each missing output spoils the three equations it appears in
    fit = arx.fit(y, u, 2, 2, 1)
    assert fit.n == len(y) - 2 - 6
    assert np.allclose(fit.a, A_TRUE, atol=1e-10) and np.allclose(fit.b, B_TRUE, atol=1e-10)


def test_too_little_data_is_a_data_error():
    with pytest.raises(DataError, match="only 3 complete equations"):
        arx.fit(np.arange(6.0), np.ones((6, 1)), 3, 3, 0)
