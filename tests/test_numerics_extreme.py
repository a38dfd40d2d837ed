"""Extreme numbers: an indefinite covariance from rounding is repaired, a run whose arithmetic
overflows stops with an error naming the row, and values beyond 1e150 are refused where written."""

import math

import numpy as np
import pytest
from infer_models import dryer

import jmlgdsl
from jmlgdsl.compile.lower import compile_text
from jmlgdsl.infer import FilterError, kalman


def test_a_covariance_rounding_made_indefinite_is_repaired():
    S = np.array([[1e18, 1e18], [1e18, 1e18 - 1e3]])  # rank one up to rounding: Cholesky refuses it
    with pytest.raises(np.linalg.LinAlgError):
        np.linalg.cholesky(S)
    Linv, logdet = kalman.inverse_cholesky(S)
    assert np.isfinite(Linv).all() and np.isfinite(logdet)
    # S^-1 = Linv' Linv; inverting it back loses about cond(S) * eps = 1e12 * 1e-16 of relative precision
    np.testing.assert_allclose(np.linalg.inv(Linv.T @ Linv), S, rtol=1e-4)


ALGORITHMS = ["imm", "exact", "pf", "rbpf", "la-rbpf", "fc-rbpf"]


def overflow_row(a, sigma0, q):
    """The first row t at which the variance recursion s_t = a^2 s_t-1 + q from s_0 = sigma0 overflows
    (in Python floats: no BLAS, and each step multiplies by a^2, so no rounding decides the row)."""
    s, q, t = float(sigma0), float(q), 0
    while math.isfinite(s):
        s, t = a * a * s + q, t + 1
    return t


def test_a_state_that_runs_away_with_no_readings_stops_at_its_row():
    # every mode the same and never left, with A = 1e9 and no offsets: the means stay 0, the variance
    # grows by 1e18 a step, and with no readings the log-likelihood is 0 at every step
    model = dryer().replace(A=np.full((4, 1, 1), 1e9), F=np.zeros((4, 1, 1)), mu0=np.zeros((4, 1)),
                            P=np.eye(4), p0=np.array([1.0, 0, 0, 0]))
    row = overflow_row(1e9, model.Sigma0[0, 0], model.Q[0, 0, 0])
    assert row == 19
    for algorithm in ALGORITHMS:
        with pytest.raises(FilterError, match=rf"^t={row}: the filter's arithmetic overflowed"), \
                np.errstate(all="ignore"):
            jmlgdsl.filter(model, np.full((40, 1), np.nan), algorithm=algorithm, seed=1)


def test_a_state_the_readings_do_not_see_that_runs_away_stops_at_its_row():
    # x1 is measured and stable, x2 is never seen and grows by 1e9 a step: its variance overflows at a
    # row the readings cannot change, while the log-likelihood (of x1's readings) stays finite
    rng = np.random.default_rng(1)
    model = jmlgdsl.Model.from_arrays(
        A=np.array([np.diag([0.9, 1e9]), np.diag([0.5, 1e9])]), B=0.05 * np.eye(2), C=np.array([[1.0, 0.0]]), D=0.05,
        P=np.eye(2), p0=[0.5, 0.5], mu0=np.zeros(2), Sigma0=np.diag([1.0, 1e-6]))
    row = overflow_row(1e9, model.Sigma0[1, 1], model.Q[0, 1, 1])
    assert row == 18
    y = rng.normal(size=(40, 1))
    for algorithm in ALGORITHMS:
        # the bootstrap PF draws x2: resampling on x1's readings leaves few values of it, so when their
        # spread (or, once it is below their rounding, their mean) overflows depends on its draws
        at = r"\d+" if algorithm == "pf" else row
        with pytest.raises(FilterError, match=rf"^t={at}: the filter's arithmetic overflowed"), \
                np.errstate(all="ignore"):
            jmlgdsl.filter(model, y, algorithm=algorithm, seed=1)


def test_a_value_beyond_the_limit_is_a_located_error():
    text = "plant p\nsample 1 s\noutput y\nstate x\nmode m { x[t] ~ Normal(0.5 * x[t-1] + 1e160, 1); y ~ Normal(x[t], 1) }\n"
    with pytest.raises(jmlgdsl.SpecError, match=r"p.jmlg:5:6: mode .m. has entries larger than 1e\+150 in f, x0"):
        compile_text(text, "p.jmlg")
