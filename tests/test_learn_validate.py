"""Validation: correlation formula, NRMSE fit, the pass rule on a true and on a wrong model."""

import numpy as np
import pytest

from jmlgdsl.learn.statespace import StateSpace
from jmlgdsl.learn.validate import ALLOWED_OUTSIDE, MAX_LAG, Z_99, correlation, nrmse_fit, validate


def first_order(a=0.9, b=0.5, q=0.01, r=0.04):
    return StateSpace(A=np.array([[a]]), F=np.array([[b]]), f=np.zeros(1), C=np.eye(1), G=np.zeros((1, 1)),
                      g=np.zeros(1), Q=np.array([[q]]), R=np.array([[r]]), mu0=np.zeros(1), Sigma0=np.eye(1) * q)


def simulate(ss, u, rng):
    x, y = 0.0, np.empty((len(u), 1))
    for t, ut in enumerate(u[:, 0]):
        x = ss.A[0, 0] * x + ss.F[0, 0] * ut + np.sqrt(ss.Q[0, 0]) * rng.standard_normal()
        y[t] = x + np.sqrt(ss.R[0, 0]) * rng.standard_normal()
    return y


def test_correlation_is_the_normalised_lagged_product():
    rng = np.random.default_rng(0)
    a, b = rng.standard_normal(50), rng.standard_normal(50)
    ac, bc = a - a.mean(), b - b.mean()
    expected = [ac[:50 - k] @ bc[k:] / np.sqrt((ac @ ac) * (bc @ bc)) for k in (0, 1, 5)]
    assert np.allclose(correlation(a, b, [0, 1, 5]), expected)
    assert correlation(a, a, [0])[0] == pytest.approx(1.0)
    assert np.isnan(correlation(np.ones(10), b[:10], [0, 1])).all()


def test_nrmse_fit():
    y = np.array([[1.0], [2.0], [np.nan], [4.0]])
    assert nrmse_fit(y, y) == pytest.approx([100.0])
    assert nrmse_fit(y, np.full((4, 1), np.nanmean(y))) == pytest.approx([0.0])


def test_true_model_passes_and_a_wrong_one_fails():
    rng = np.random.default_rng(1)
    u = rng.choice([-1.0, 1.0], size=(2000, 1))
    truth = first_order()
    y = simulate(truth, u, rng)
    good = validate(truth, y, u)
    assert good.band == pytest.approx(Z_99 / np.sqrt(2000))
    assert good.autocorr.shape == (1, MAX_LAG) and good.crosscorr.shape == (1, 1, MAX_LAG + 1)
    assert good.passed
    # Free run misses the noise: error variance (q/(1-a^2) + r) against output variance
    # (b^2/(1-a^2) + q/(1-a^2) + r) gives a fit of 100 (1 - sqrt(0.0926/1.408)) = 74.4 %.
    assert good.fit[0] == pytest.approx(74.4, abs=3)
    # Pole and gain wrong: residuals remember the input and each other.
    bad = validate(first_order(a=0.6, b=0.3), y, u)
    auto, cross = bad.outside
    assert not bad.passed and (auto[0] > ALLOWED_OUTSIDE or cross[0, 0] > ALLOWED_OUTSIDE)
    assert bad.fit[0] < good.fit[0]


def test_a_model_without_inputs_has_only_the_autocorrelation_test():
    rng = np.random.default_rng(2)
    truth = first_order(b=0.0)
    y = simulate(truth, np.zeros((500, 1)), rng)
    v = validate(truth.replace(F=np.zeros((1, 0)), G=np.zeros((1, 0))), y)
    assert v.crosscorr.shape == (1, 0, MAX_LAG + 1)
    assert v.passed
